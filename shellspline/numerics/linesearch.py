"""Backtracking line search with the Armijo (sufficient decrease) test.

One implementation for every solver that takes a search direction: the Gauss–Newton
reconstruction, the discrete geodesic's Newton steps, the nonlinear spline's Newton–CG and
L-BFGS steps.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["ARMIJO", "LineSearchResult", "backtracking"]

#: Default Armijo constant ``c₁``: a step is accepted when ``φ(α) <= φ(0) + c₁ α φ'(0)``
#: (Nocedal & Wright, *Numerical Optimization*, §3.1, suggest 1e-4).
ARMIJO = 1e-4


@dataclass
class LineSearchResult:
    """What :func:`backtracking` returns.

    Attributes
    ----------
    accepted : bool
        A step passed the Armijo test.
    alpha : float
        The accepted step length, or the last one tried (``accepted`` False).
    value : float
        ``φ(alpha)`` (``inf`` for an infeasible trial).
    payload : object
        What ``phi`` returned alongside the value at ``alpha`` (e.g. the gradient there).
    evaluations : int
        Calls of ``phi``.
    """

    accepted: bool
    alpha: float
    value: float
    payload: Any = None
    evaluations: int = 0


def backtracking(phi, f0: float, slope: float, *, alpha: float = 1.0, c1: float = ARMIJO,
                 shrink: float = 0.5, max_steps: int = 30,
                 interpolate: bool = False) -> LineSearchResult:
    """Backtrack from ``alpha`` until ``φ(α) <= f0 + c1 α slope``.

    Parameters
    ----------
    phi : callable
        ``α -> (value, payload)``; ``value`` is ``inf`` or NaN for an infeasible trial (a
        collapsed triangle, a failed sub-solve), which is never accepted.
    f0 : float
        ``φ(0)``.
    slope : float
        ``φ'(0) < 0``.
    alpha : float
        First trial step.
    c1 : float
        Armijo constant.
    shrink : float
        Factor of the next trial after a rejected one.
    max_steps : int
        Trials at most.
    interpolate : bool
        After a feasible rejected trial, take the minimiser of the quadratic through
        ``φ(0)``, ``φ'(0)`` and ``φ(α)`` instead, safeguarded to ``[0.1 α, shrink α]``
        (infeasible trials still shrink by ``shrink``).

    Returns
    -------
    LineSearchResult

    Examples
    --------
    >>> r = backtracking(lambda a: ((a - 0.3) ** 2, None), 0.09, -0.6)
    >>> r.accepted, r.alpha
    (True, 0.5)
    """
    value, payload = np.inf, None
    for k in range(1, int(max_steps) + 1):
        value, payload = phi(alpha)
        if np.isfinite(value) and value <= f0 + c1 * alpha * slope:
            return LineSearchResult(True, alpha, value, payload, k)
        if interpolate and np.isfinite(value):
            curv = value - f0 - alpha * slope
            q = -0.5 * slope * alpha * alpha / curv if curv > 0 else shrink * alpha
            alpha = min(max(q, 0.1 * alpha), shrink * alpha)
        else:
            alpha *= shrink
    return LineSearchResult(False, alpha, value, payload, int(max_steps))

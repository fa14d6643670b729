"""One result shape for every iterative solver.

Every iterative solver of the library (Gauss–Newton reconstruction, discrete geodesics, the
nonlinear spline, the Krylov solvers) returns a :class:`SolverResult` or a subclass with
solver-specific extras. The fields mean the same everywhere:

- ``status``: ``"converged"`` (the solver's convergence criterion holds), ``"stalled"``
  (it stopped making progress before that: line search or trust region failed, the energy
  stopped decreasing), ``"limit"`` (an iteration or time limit stopped it) or ``"failed"``
  (it could not run: degenerate input, a factorization or a sub-solve failed);
- ``iterations``: outer iterations performed;
- ``energies``, ``grad_norms``: 1-D float arrays, the energy and gradient norm at the start
  and after every accepted iteration (so ``len == iterations + 1`` unless the solver stopped
  before its first evaluation); each solver documents which norm;
- ``message``: one line saying which test stopped it.

``success`` is ``status == "converged"``, never set on its own, so no result can report
success it did not reach.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["STATUSES", "SolverResult"]

#: The statuses of :class:`SolverResult`, best first.
STATUSES = ("converged", "stalled", "limit", "failed")


def _history(values) -> np.ndarray:
    return np.array([] if values is None else values, dtype=np.float64).ravel()


@dataclass(kw_only=True)
class SolverResult:
    """What an iterative solver returns (see the module docstring for the field meanings).

    Attributes
    ----------
    status : {"converged", "stalled", "limit", "failed"}
    iterations : int
    energies : (it+1,) float64 array
    grad_norms : (it+1,) float64 array
    message : str

    Examples
    --------
    >>> r = SolverResult(status="limit", iterations=2, energies=[3.0, 2.0, 1.5],
    ...                  grad_norms=[1.0, 0.5, 0.2], message="iteration limit (2) reached")
    >>> r.success, r.nit, r.energy, r.grad_reduction
    (False, 2, 1.5, 0.2)
    """

    status: str = "stalled"
    iterations: int = 0
    energies: np.ndarray = field(default_factory=lambda: np.zeros(0))
    grad_norms: np.ndarray = field(default_factory=lambda: np.zeros(0))
    message: str = ""

    def __post_init__(self):
        if self.status not in STATUSES:
            raise ValueError(f"`status` must be one of {STATUSES}, got {self.status!r}")
        self.energies = _history(self.energies)
        self.grad_norms = _history(self.grad_norms)
        self.iterations = int(self.iterations)

    # -- derived, never stored ---------------------------------------------------------------
    @property
    def success(self) -> bool:
        """``status == "converged"``."""
        return self.status == "converged"

    @property
    def nit(self) -> int:
        """Alias of :attr:`iterations` (scipy's name)."""
        return self.iterations

    @property
    def energy(self) -> float:
        """The last recorded energy (NaN when none was recorded)."""
        return float(self.energies[-1]) if self.energies.size else float("nan")

    @property
    def grad_reduction(self) -> float:
        """``grad_norms[-1] / grad_norms[0]`` (NaN when undefined)."""
        g = self.grad_norms
        return float(g[-1] / g[0]) if g.size and g[0] > 0 else float("nan")

    # -- building ----------------------------------------------------------------------------
    def record(self, energy=None, grad_norm=None) -> None:
        """Append one entry to the histories (``None`` leaves that history alone)."""
        if energy is not None:
            self.energies = np.append(self.energies, float(energy))
        if grad_norm is not None:
            self.grad_norms = np.append(self.grad_norms, float(grad_norm))

    def stop(self, status: str, message: str) -> None:
        """Set the final status and message (validated)."""
        if status not in STATUSES:
            raise ValueError(f"`status` must be one of {STATUSES}, got {status!r}")
        self.status, self.message = status, str(message)

    def summary(self) -> dict:
        """JSON-friendly record of the common fields (no arrays)."""
        e, g = self.energies, self.grad_norms
        return {"success": bool(self.success), "status": self.status,
                "nit": int(self.iterations), "message": self.message,
                "energy_initial": float(e[0]) if e.size else None,
                "energy_final": float(e[-1]) if e.size else None,
                "grad_norm_initial": float(g[0]) if g.size else None,
                "grad_norm_final": float(g[-1]) if g.size else None}

"""Nonlinear time-discrete splines in shell space (paper §5–6 and appendix).

Minimise the time-discrete elastic energy (eq. 7)::

    F^K[s_0, …, s_K] = 4K³ Σ_k W[s_k, s̃_k],
    s̃_k = argmin_s W[s_{k-1}, s] + W[s, s_{k+1}]          (geodesic midpoints, eq. 8)

over the free shells (all frames that are not keyframes), ``k = 1..K-1`` (natural, Hermite)
or cyclically ``k = 0..K-1`` (periodic, frame ``K`` is frame ``0``). Hermite conditions are
keyframes at frames ``0, 1, K-1, K`` (paper §8).

Gradient (adjoint method, eqs. 13–17): for every term ``k`` solve the midpoint problem by
Newton (:class:`~shellspline.shells.geodesic.PathSolver` with one inner shell, warm-started from the
previous evaluation), then one linear system with the midpoint Hessian
``A_k = W,22[s_{k-1}, s̃_k] + W,11[s̃_k, s_{k+1}]``::

    A_k p_k = −W,2[s_k, s̃_k]ᵀ                                         (16)
    ∂F/∂s_k     += 4K³ W,1[s_k, s̃_k]
    ∂F/∂s_{k-1} += 4K³ W,12[s_{k-1}, s̃_k] p_k
    ∂F/∂s_{k+1} += 4K³ W,21[s̃_k, s_{k+1}] p_k                            (17)

(``W,12`` has rows indexed by the first argument.) The outer problem is solved by
a pluggable optimiser and stopped when the gradient norm has dropped by ``gtol`` relative to the
initial one.

Rigid motions: ``F^K`` is invariant under a rigid motion of every single shell (``W`` is, in
both arguments, and so is the midpoint up to a rigid motion), so the problem is solved modulo
rigid motions: the gradient is orthogonal to them, L-BFGS therefore hardly moves along them,
and the midpoint Newton solver projects them out (see :mod:`shellspline.shells.geodesic`). At the end
every free frame is rigidly placed onto its initial pose (Kabsch), which makes the output
canonical. With ``pinned`` vertices these stay fixed in every shell and midpoint instead (no
placement).

The package is a solver with pluggable parts:

- :mod:`~.problem`: :class:`NonlinearSplineProblem` (``F^K``, its adjoint gradient, the
  keyframe and pin constraints); the default initialisation is the per-vertex linear blend
  (:func:`shellspline.timeline.linear_blend`);
- :mod:`~.models`: the Hessian model :class:`GaussNewtonModel`, the preconditioners, the LΘA
  retraction;
- :mod:`~.optimizers`: :class:`TrustRegionNewton` (default), :class:`LineSearchNewton`,
  :class:`LBFGS`;
- :mod:`~.solver`: :class:`NonlinearSplineSolver` (problem + optimiser + one
  :class:`StopPolicy`), :class:`NonlinearSplineResult` and :func:`nonlinear_spline`, the
  convenience function with the switches of the command line.
"""
from __future__ import annotations

from .models import (GaussNewtonModel, LTARetraction, ModelPreconditioner,
                     SpaceTimePreconditioner)
from .optimizers import LBFGS, LineSearchNewton, Optimizer, TrustRegionNewton
from .problem import NonlinearSplineProblem, TimeLimitReached
from .solver import (FTOL_WINDOW, NonlinearSplineResult, NonlinearSplineSolver, StopPolicy,
                     nonlinear_spline)

__all__ = ["FTOL_WINDOW", "GaussNewtonModel", "LBFGS", "LTARetraction", "LineSearchNewton",
           "ModelPreconditioner", "NonlinearSplineProblem", "NonlinearSplineResult",
           "NonlinearSplineSolver", "Optimizer", "SpaceTimePreconditioner", "StopPolicy",
           "TimeLimitReached", "TrustRegionNewton", "nonlinear_spline"]

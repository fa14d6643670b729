"""Outer optimisers of the nonlinear spline, as pluggable objects.

An optimiser gets a :class:`~shellspline.shells.nonlinear.solver.NonlinearSplineSolver`
(which evaluates ``F^K`` and its gradient, and applies the stop policy to every accepted
iterate) and the start point, and returns ``(x, verdict)``: ``verdict`` is ``None`` when the
stop policy ended the run (``solver.accept`` returned True), else ``(status, message)`` of
its own stop (``"stalled"``: no trial decreased the energy).

- :class:`TrustRegionNewton` (default): Steihaug–Toint trust region on the Gauss–Newton or
  exact reduced Hessian, trial points along the LΘA retraction, a final Newton phase;
- :class:`LineSearchNewton`: Newton–CG with Armijo backtracking;
- :class:`LBFGS`: limited-memory BFGS with Armijo backtracking.
"""
from __future__ import annotations

from abc import ABC, abstractmethod
from collections import deque

import numpy as np

from ...errors import ShellsplineError, tol
from ...numerics.krylov import pcg, steihaug
from ...numerics.linesearch import backtracking
from .models import (GaussNewtonModel, LTARetraction, ModelPreconditioner,
                     SpaceTimePreconditioner, project_rigid, step_cap)

__all__ = ["Optimizer", "TrustRegionNewton", "LineSearchNewton", "LBFGS", "HESSIANS"]

#: Hessian products of the Newton optimisers (see :class:`TrustRegionNewton`).
HESSIANS = ("auto", "exact", "gauss-newton")
#: Relative mismatch of the Gauss–Newton and the exact curvature along a step above which
#: ``hessian="auto"`` switches to exact Hessian products for the rest of the run.
GN_MISMATCH = 0.3
#: Truncation of the trust-region CG (Nash & Sofer 1990): stop when the last iteration's model
#: decrease, times the iteration count, is below this fraction of the total decrease. Measured
#: on the 1000-vertex cactus (K = 20, 300 s): gradient reduction 3.6e-4 against 1.4e-3 without
#: (CG runs of 6–7 products alternate with long ones instead of 130–200 every time).
NASH_SOFER = 0.25
#: The trust region's final Newton phase starts once exact products are in use and
#: ``‖∇F‖ <= FINAL_PHASE ‖∇F₀‖`` (mesh energies): :class:`~.models.SpaceTimePreconditioner`,
#: :meth:`~.models.GaussNewtonModel.accurate_matvec`, untruncated CG with forcing at most
#: :data:`FINAL_CG_TOL` (unless :attr:`TrustRegionNewton.gtol_margin` allows a looser one).
#: Earlier, far from the minimiser, the same choice took smaller steps than the first phase
#: (1000-vertex cactus: ``‖∇F‖`` 9e-3 of its start in 300 s against 2e-4). Switching at 0.1
#: instead of 2e-2: converged (4.2e-8) at 317 s instead of 3e-7 at 360 s; it needs
#: :data:`FINAL_MIDPOINT_TOL` (without it the 0.1 run stalled at 2.2e-6).
FINAL_PHASE = 0.1
#: Forcing term bound of the final phase's CG (see :data:`FINAL_PHASE`).
FINAL_CG_TOL = 0.05
#: Midpoint tolerance of the final phase. ``F`` is not stationary in the midpoints, so its
#: error follows theirs: with the default 1e-10 the cactus's last trial steps (predicted
#: decrease 7e-11) measured increases of 5e-11 and the trust region shrank to nothing.
FINAL_MIDPOINT_TOL = 1e-13
#: CG is never asked for a residual below ``GTOL_MARGIN · gtol · ‖∇F₀‖``: with an accurate
#: model the next gradient is about the CG residual, so that already meets ``gtol``. The
#: Eisenstat–Walker forcing ``√(‖∇F‖/‖∇F₀‖)`` would solve the cactus's last Newton system
#: (at 3.2e-6) to 1.8e-3 instead of 0.16 of its right-hand side.
GTOL_MARGIN = 0.5

_LINE_SEARCH_FAILED = "not converged: line search failed (energy does not decrease)"


def canonical_hessian(hessian) -> str:
    """``hessian`` as one of :data:`HESSIANS` (``_`` and case tolerated)."""
    h = str(hessian).strip().lower().replace("_", "-")
    if h not in HESSIANS:
        raise ShellsplineError(f"`hessian` must be 'auto', 'exact' or 'gauss-newton', got "
                               f"{hessian!r}")
    return h


class Optimizer(ABC):
    """An outer optimiser of ``F^K`` (see the module docstring)."""

    #: Name reported in :attr:`NonlinearSplineResult.optimizer`.
    name = ""
    #: Whether evaluations keep the midpoint factorizations (Newton models need them).
    keeps_factorizations = False

    def check(self, problem) -> None:
        """Raise :class:`~shellspline.errors.ShellsplineError` if this optimiser cannot run
        on ``problem`` (called before any computing)."""

    @abstractmethod
    def run(self, solver, x, F, g):
        """Minimise from ``x`` (energy ``F``, gradient ``g``); returns ``(x, verdict)``."""


def _projector(f, Q):
    return lambda v: project_rigid(v.reshape(f, -1), Q).ravel()


def _switch_to_exact(model, d) -> bool:
    """``hessian="auto"``: one exact product checks the Gauss–Newton curvature along ``d``.
    The Gauss–Newton model drops the adjoint-weighted third derivatives; far from the
    shells' midpoints (large η, large deformations) they dominate and the GN step is far too
    long."""
    cg, ce = float(d @ model.matvec(d)), float(d @ model.exact_matvec(d))
    return abs(ce - cg) > GN_MISMATCH * abs(ce)


class LineSearchNewton(Optimizer):
    """Gauss–Newton–CG on ``F^K`` with Armijo backtracking.

    Steps from :class:`~.models.GaussNewtonModel` by CG preconditioned with
    :class:`~.models.ModelPreconditioner`; the first trial is capped at two mean edge lengths
    per coordinate; midpoints of a trial start from their first-order prediction.

    Parameters
    ----------
    hessian : {"auto", "exact", "gauss-newton"}
        See :class:`TrustRegionNewton`.
    cg_tol : float
        Relative residual of CG (fixed).
    cg_max_iter : int
    inner : callable
        The Krylov solver, with the signature of :func:`shellspline.numerics.krylov.pcg`.
    """

    name = "gauss-newton"
    keeps_factorizations = True

    def __init__(self, *, hessian: str = "auto", cg_tol: float = 0.1, cg_max_iter: int = 200,
                 inner=pcg):
        self.hessian = canonical_hessian(hessian)
        self.cg_tol, self.cg_max_iter, self.inner = float(cg_tol), int(cg_max_iter), inner

    def run(self, solver, x, F, g):
        prob, S0, res = solver.problem, solver.S0, solver.result
        P = ModelPreconditioner(prob, prob.nodes_of(x, S0))
        f = len(prob.free_nodes)
        cap = step_cap(prob, S0, 2.0)
        exact = self.hessian == "exact"
        while True:
            S = prob.nodes_of(x, S0)
            Q = prob.rigid_bases(S)
            model = GaussNewtonModel(prob)

            def solve(matvec, Q=Q):
                return self.inner(matvec, -g, precond=lambda v: P.apply(v, Q=Q),
                                  project=_projector(f, Q), rtol=self.cg_tol,
                                  max_iter=self.cg_max_iter)

            kr = solve(model.exact_matvec if exact else model.matvec)
            d, ncg = kr.x, kr.iterations
            if not exact and self.hessian == "auto" and ncg and _switch_to_exact(model, d):
                exact = True
                res.cg_iterations.append(ncg)  # the discarded GN solve's work
                kr = solve(model.exact_matvec)
                d, ncg = kr.x, kr.iterations
            res.hessian.append("exact" if exact else "gauss-newton")
            res.cg_iterations.append(ncg)
            slope = float(g @ d)
            if not slope < 0:
                d = -P.apply(g, Q=Q)
                slope = float(g @ d)
                if not slope < 0:
                    d, slope = -g, -float(g @ g)
            dM = model.midpoint_change(d)
            M = prob.last["M"]

            def trial(alpha, x=x, d=d, M=M, dM=dM):
                xn = x + alpha * d
                Fn, gn = solver.evaluate(xn, warm=M + alpha * dM, trial=True)
                return Fn, (xn, gn)

            ls = backtracking(trial, F, slope,
                              alpha=min(1.0, cap / max(float(np.abs(d).max()), tol.zero)))
            res.step_lengths.append(ls.alpha)
            if not ls.accepted:
                return x, ("stalled", _LINE_SEARCH_FAILED)
            (x, g), F = ls.payload, ls.value
            if solver.accept(x):
                return x, None


class TrustRegionNewton(Optimizer):
    """Trust-region Newton–CG on ``F^K`` (the default optimiser).

    Steihaug–Toint CG in the norm of :class:`~.models.ModelPreconditioner` (in the final
    phase :class:`~.models.SpaceTimePreconditioner`) on the Gauss–Newton or exact reduced
    Hessian of :class:`~.models.GaussNewtonModel`; trial points along
    :class:`~.models.LTARetraction` when ``retract``. The radius shrinks to a quarter of the
    step when the actual decrease is below a quarter of the model's (or a midpoint solve
    fails) and doubles when a boundary step earns more than three quarters; a trial is
    accepted when ``ρ > 0.01``. A rejected trial writes the other set of kept
    factorizations, so the model survives it. Inexact Newton: the CG forcing term is
    ``min(cg_tol, √(‖∇F‖/‖∇F₀‖))``, floored at ``gtol_margin · gtol ‖∇F₀‖/‖∇F‖``.

    Parameters
    ----------
    hessian : {"auto", "exact", "gauss-newton"}
        CG on the Gauss–Newton model (cheap products, good while the midpoints are close to
        the shells), on the exact reduced Hessian (~10x the cost per product, includes the
        adjoint-weighted third derivatives) or ``"auto"``: Gauss–Newton until one exact
        product shows its curvature along a step off by more than :data:`GN_MISMATCH`,
        exact from then on. Measured: ellipsoids (η=0.1) stay Gauss–Newton; the hexagon
        folds at η=0.01 need exact products (Gauss–Newton underestimates the curvature 30x
        there: steps of 0.01, no convergence in 120 s; exact: 12 iterations).
    cg_tol : float
        Upper bound of the CG forcing term.
    cg_max_iter : int
    retract : bool, optional
        Trial steps along the LΘA retraction. Default: on for mesh energies.
    final_phase : bool
        On a mesh energy with exact products: once ``‖∇F‖ <= FINAL_PHASE ‖∇F₀‖``,
        continue with the space–time preconditioner, accurate products and CG to its
        forcing term (:data:`FINAL_PHASE`).
    gtol_margin : float
        See :data:`GTOL_MARGIN` (``0``: no floor).
    inner : callable
        The trust-region Krylov solver, with the signature of
        :func:`shellspline.numerics.krylov.steihaug`.
    """

    name = "gauss-newton"
    keeps_factorizations = True

    def __init__(self, *, hessian: str = "auto", cg_tol: float = 0.5, cg_max_iter: int = 200,
                 retract: bool | None = None, final_phase: bool = True,
                 gtol_margin: float = GTOL_MARGIN, inner=steihaug):
        self.hessian = canonical_hessian(hessian)
        if retract is not None and not isinstance(retract, (bool, np.bool_)):
            raise ShellsplineError(f"`retract` must be True, False or None, got {retract!r}")
        self.cg_tol, self.cg_max_iter = float(cg_tol), int(cg_max_iter)
        self.retract, self.final_phase = retract, bool(final_phase)
        self.gtol_margin, self.inner = float(gtol_margin), inner

    def forcing(self, gnorm: float, g0n: float, gtol: float, final: bool) -> float:
        """CG's relative residual at gradient norm ``gnorm`` (``g0n`` the first one).

        Inexact Newton (Eisenstat–Walker forcing): loose far away, tighter as ‖g‖ drops,
        ``min(cg_tol, max(√(‖g‖/‖g₀‖), 1e-3))`` (at most :data:`FINAL_CG_TOL` in the final
        phase), but no tighter than what meets ``gtol``: the next gradient is about the CG
        residual, so never below ``gtol_margin · gtol ‖g₀‖/‖g‖`` (itself capped at 0.5).
        """
        rtol = min(self.cg_tol if not final else min(self.cg_tol, FINAL_CG_TOL),
                   max(np.sqrt(gnorm / g0n), 1e-3))
        return max(rtol, min(self.gtol_margin * gtol * g0n / max(gnorm, tol.zero), 0.5))

    @staticmethod
    def ratio(F: float, Fn: float, dec: float) -> float:
        """Actual over predicted decrease ``ρ = (F − Fn) / dec`` (``−inf`` for a failed
        trial; ``1`` when both are below the energy's last digits: the model holds)."""
        rho = (F - Fn) / dec if np.isfinite(Fn) and dec > 0 else -np.inf
        noise = 1e-13 * max(abs(F), 1.0)
        if np.isfinite(Fn) and dec <= 10 * noise and Fn <= F + noise:
            rho = 1.0
        return rho

    @staticmethod
    def updated_radius(radius: float, rho: float, dnorm: float) -> float:
        """A quarter of the step below ``ρ = 0.25``, doubled after a boundary step
        (``‖d‖ >= 0.99 radius``) with ``ρ > 0.75``, else unchanged."""
        if rho < 0.25:
            return 0.25 * min(radius, dnorm)
        if rho > 0.75 and dnorm >= 0.99 * radius:
            return 2.0 * radius
        return radius

    def check(self, problem) -> None:
        if self.retract and not hasattr(problem.energy, "T"):
            raise ShellsplineError("`retract` needs a mesh energy (DiscreteShells)")

    def run(self, solver, x, F, g):
        prob, S0, res = solver.problem, solver.S0, solver.result
        retract = hasattr(prob.energy, "T") if self.retract is None else self.retract
        retraction = LTARetraction(prob, S0) if retract else None
        gtol = solver.stop.gtol
        f = len(prob.free_nodes)
        zero = np.zeros_like(S0)
        cap = step_cap(prob, S0, 2.0)

        def first_radius(P, Q):
            # the preconditioned gradient step scaled to two mean edge lengths, in P's norm
            z0 = P.apply(-g, Q=Q)
            scale = cap / max(float(np.abs(z0).max()), tol.zero) if np.isfinite(cap) else 1.0
            return scale * float(np.sqrt(max(float(-g @ z0), 0.0)))

        P = ModelPreconditioner(prob, prob.nodes_of(x, S0))
        radius = first_radius(P, prob.rigid_bases(prob.nodes_of(x, S0)))
        g0n = float(np.linalg.norm(g))
        current = 0
        final = False
        exact = self.hessian == "exact"
        last = None  # (last accepted step, radius / its length in the current norm)
        while True:
            S = prob.nodes_of(x, S0)
            Q = prob.rigid_bases(S)
            if self.final_phase and exact and not final and hasattr(prob.energy, "T") and \
                    float(np.linalg.norm(g)) <= FINAL_PHASE * g0n:
                # the final Newton phase: space–time preconditioner, accurate products, CG
                # run to its forcing term (no truncation), midpoints solved tighter so that F
                # resolves the small decreases of the last steps; F and g re-evaluated
                final = True
                res.final_phase_iteration = len(res.cg_iterations)
                prob.midpoint_tol = min(prob.midpoint_tol, FINAL_MIDPOINT_TOL)
                F, g = solver.evaluate(x, slot_set=current)
                P = SpaceTimePreconditioner(prob, S)
                radius = first_radius(P, Q)
                if last is not None:
                    # keep the trust the first phase had earned: its radius relative to its
                    # last step, measured in the new norm (the gradient-step guess alone can
                    # be far smaller and cost several boundary steps of radius doubling)
                    radius = max(radius, last[1] * P.norm(last[0]))
            model = GaussNewtonModel(prob)
            ncg_total = 0
            accepted = False
            rtol = self.forcing(float(np.linalg.norm(g)), g0n, gtol, final)
            for _trial in range(30):
                matvec = model.accurate_matvec if final else \
                    model.exact_matvec if exact else model.matvec
                # truncate only the expensive exact-product solves of the first phase (on the
                # ellipsoids, which stay with Gauss–Newton products, truncation cost 35 % more
                # time: 10.5 -> 14.3 s)
                kr = self.inner(matvec, -g, radius, precond=lambda v, Q=Q: P.apply(v, Q=Q),
                                project=_projector(f, Q), rtol=rtol,
                                max_iter=self.cg_max_iter,
                                truncate=NASH_SOFER if exact and not final else 0.0)
                d, dec, dnorm = kr.x, kr.model_decrease, kr.step_norm
                ncg_total += kr.iterations
                if not exact and self.hessian == "auto" and kr.iterations and \
                        float(d @ d) > 0 and _switch_to_exact(model, d):
                    exact = True
                    continue  # solve again with exact products
                if not dec > 0:  # no model decrease (round-off): the gradient step
                    d = -P.apply(g, Q=Q)
                    dec = -float(g @ d)
                    dnorm = float(np.sqrt(max(dec, 0.0)))  # ‖P⁻¹g‖_P² = gᵀP⁻¹g
                D = prob.nodes_of(d, zero)
                Sn = retraction(S, D) if retraction is not None else S + D
                xn = prob.x_of(Sn)
                warm = model.M + model.midpoint_change(d)
                Fn, gn = solver.evaluate(xn, warm=warm, trial=True, slot_set=1 - current)
                rho = self.ratio(F, Fn, dec)
                radius = self.updated_radius(radius, rho, dnorm)
                if rho > 0.01:
                    accepted = True
                    break
            res.hessian.append("exact" if exact else "gauss-newton")
            res.cg_iterations.append(ncg_total)
            if not accepted:
                return x, ("stalled", "not converged: trust region collapsed (no decrease of "
                                      "the energy)")
            res.step_lengths.append(float(np.abs(Sn - S).max()) / max(cap / 2, tol.zero)
                                    if np.isfinite(cap) else float(np.abs(d).max()))
            if dnorm > 0:
                last = (d, radius / dnorm)
            current = 1 - current
            x, F, g = xn, Fn, gn
            if solver.accept(x):
                return x, None


class LBFGS(Optimizer):
    """Preconditioned L-BFGS (two-loop recursion) with Armijo backtracking and
    curvature-checked updates.

    Parameters
    ----------
    memory : int
        Number of stored pairs.
    precondition : bool
        :class:`~.models.ModelPreconditioner` as the initial inverse Hessian (else the usual
        ``sᵀy/yᵀy`` scaling).
    """

    name = "lbfgs"

    def __init__(self, *, memory: int = 20, precondition: bool = True):
        self.memory, self.precondition = int(memory), bool(precondition)

    def run(self, solver, x, F, g):
        prob, S0 = solver.problem, solver.S0
        precond = ModelPreconditioner(prob, S0) if self.precondition else None
        hist = deque(maxlen=self.memory)
        gamma = 1.0
        cap = step_cap(prob, S0, 0.5)

        def H0(v, x):
            if precond is None:
                return gamma * v
            return gamma * precond.apply(v, prob.nodes_of(x, S0))

        while True:
            q = g.copy()
            alphas = []
            for s_, y_, rho in reversed(hist):
                a = rho * (s_ @ q)
                alphas.append(a)
                q -= a * y_
            r = H0(q, x)
            for (s_, y_, rho), a in zip(hist, reversed(alphas)):
                r += s_ * (a - rho * (y_ @ r))
            d = -r
            slope = float(g @ d)
            if slope >= 0:  # not a descent direction: restart with the preconditioned gradient
                hist.clear()
                d = -H0(g, x)
                slope = float(g @ d)
                if slope >= 0:
                    d, slope = -g, -float(g @ g)
            accepted_midpoints = None if prob.midpoints is None else prob.midpoints.copy()

            def trial(alpha, x=x, d=d, mids=accepted_midpoints):
                xn = x + alpha * d
                # warm starts from the accepted iterate, never from a rejected trial
                prob.midpoints = None if mids is None else mids.copy()
                Fn, gn = solver.evaluate(xn)
                return Fn, (xn, gn)

            # first trial: the full step, capped at half a mean edge length per coordinate
            ls = backtracking(trial, F, slope,
                              alpha=min(1.0, cap / max(float(np.abs(d).max()), tol.zero)))
            if not ls.accepted:
                return x, ("stalled", _LINE_SEARCH_FAILED)
            (xn, gn), Fn = ls.payload, ls.value
            s_, y_ = xn - x, gn - g
            sy = float(s_ @ y_)
            if sy > 1e-12 * np.linalg.norm(s_) * np.linalg.norm(y_):
                hist.append((s_, y_, 1.0 / sy))
                gamma = sy / float(y_ @ y_) if precond is None else 1.0
            x, F, g = xn, Fn, gn
            if solver.accept(x):
                return x, None

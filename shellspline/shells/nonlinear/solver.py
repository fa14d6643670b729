"""The nonlinear spline as a solver object: problem + initialisation + optimiser + one stop
policy, and :func:`nonlinear_spline`, the convenience function that assembles them."""
from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field

import numpy as np

from ...errors import ShellsplineError
from ...numerics.result import SolverResult
from ..geodesic import make_energy
from ..reconstruct import rigid_placement
from ...mesh.topology import Topology
from ...timeline import linear_blend
from .optimizers import (LBFGS, LineSearchNewton, Optimizer, TrustRegionNewton,
                         canonical_hessian)
from ..energy import checked_poses
from .problem import NonlinearSplineProblem, TimeLimitReached

__all__ = ["FTOL_WINDOW", "NonlinearSplineResult", "NonlinearSplineSolver", "StopPolicy",
           "nonlinear_spline"]

#: Outer iterations over which ``ftol`` measures the relative energy decrease.
FTOL_WINDOW = 3


@dataclass(kw_only=True)
class NonlinearSplineResult(SolverResult):
    """What :func:`nonlinear_spline` and :meth:`NonlinearSplineSolver.solve` return (a
    :class:`~shellspline.numerics.result.SolverResult`).

    Attributes
    ----------
    V : (K+1,n,3) float64 array
        The spline; ``V[frames[j]]`` is keyframe ``j`` bit for bit (periodic: ``V[K] = V[0]``).
    frames : (J,) int64 array
    status : {"converged", "stalled", "limit", "failed"}
        ``"converged"``: ``‖∇F‖ <= gtol ‖∇F₀‖``; ``"stalled"``: the energy stopped
        decreasing (``ftol``), or no trial step decreased it (trust region collapsed, line
        search failed); ``"limit"``: ``max_iter`` or ``max_time_s``. ``success`` is
        ``status == "converged"``.
    iterations : int
        Outer iterations (also ``nit``).
    energies : (it+1,) float64 array
        ``F^K`` (eq. 7) at the initial point and after every outer iteration
        (non-increasing); empty when ``max_time_s`` ran out before the first evaluation
        ended. ``energy`` is the last one (NaN when empty).
    grad_norms : (it+1,) float64 array
        Euclidean norm of the gradient at the same points.
    message : str
        Starts with ``"converged"`` or ``"not converged"`` and says which test stopped it.
    times : list of float
        Seconds since the start of the call at the same points.
    nfev : int
        Energy/gradient evaluations (each solves all midpoint problems).
    midpoints : (T,n,3) float64 array
        Geodesic midpoints ``s̃_k`` of the energy terms at the solution.
    time_s : float
        Wall time of the call (set-up included).
    optimizer : str
        ``"gauss-newton"`` or ``"lbfgs"``.
    cg_iterations : list of int
        Inner CG iterations per outer iteration (Gauss–Newton).
    step_lengths : list of float
        Accepted step length per outer iteration (Gauss–Newton; 1 = full step).
    midpoint_newton_iterations : int
        Newton iterations of all midpoint solves.
    hessian : list of str
        Hessian products used per outer iteration (``"gauss-newton"`` or ``"exact"``).
    final_phase_iteration : int or None
        Outer iteration at which the trust region's final Newton phase began (None: never).
    """

    V: np.ndarray
    frames: np.ndarray
    times: list = field(default_factory=list)
    nfev: int = 0
    midpoints: np.ndarray | None = None
    time_s: float = 0.0
    optimizer: str = ""
    cg_iterations: list = field(default_factory=list)
    step_lengths: list = field(default_factory=list)
    midpoint_newton_iterations: int = 0
    hessian: list = field(default_factory=list)
    final_phase_iteration: int | None = None


#: Energies below this fraction of the problem's energy scale (:func:`energy_scale` times
#: the spline's ``4 K³``) are round-off: the energy of shells that differ by a rigid motion
#: only computes to ~1e-28 of it.
ROUNDOFF = 1e-20


def energy_scale(energy, V) -> float:
    """The shell energy of a unit strain of the shell ``V (n,3)``: ``(μ + λ)`` times its
    area (membrane terms are ``μ d ρ²`` and ``λ (A − Ã)²/A`` summed over the surface), the
    parameters of ``energy`` where it has them (else 1)."""
    T = getattr(energy, "T", None)
    if T is None:
        return 1.0
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(T.F)
    area = 0.5 * float(np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]],
                                               V[F[:, 2]] - V[F[:, 0]]), axis=1).sum())
    return (float(getattr(energy, "mu", 1.0)) + float(getattr(energy, "lam", 1.0))) * area


class StopPolicy:
    """When the nonlinear spline stops, tested after every accepted iterate (and at the start).

    In this order: ``‖∇F‖ <= gtol ‖∇F₀‖`` → ``"converged"``; ``F`` fell by at most
    ``ftol · F`` over the last :data:`FTOL_WINDOW` iterations → ``"stalled"`` (the energy
    settled, the gradient criterion does not hold); the wall clock passed ``max_time_s``
    since :meth:`start` → ``"limit"``; ``max_iter`` iterations → ``"limit"``. The time limit
    is also checked inside the iterations (the problem's deadline), so that a long first
    evaluation or trial cannot overrun it by more than one midpoint solve or Hessian product.

    Parameters
    ----------
    gtol : float in (0, 1)
    ftol : float in [0, 1)
        ``0``: off.
    max_iter : int
    max_time_s : float, optional
        Wall-clock seconds from :meth:`start` (the set-up included when the caller starts
        the clock first, as :func:`nonlinear_spline` does).
    """

    def __init__(self, *, gtol: float = 1e-6, ftol: float = 0.0, max_iter: int = 500,
                 max_time_s: float | None = None):
        if isinstance(gtol, bool) or not (isinstance(gtol, (int, float)) and 0 < gtol < 1):
            raise ShellsplineError(f"`gtol` must be a number in (0, 1), got {gtol!r}")
        if isinstance(ftol, bool) or not (isinstance(ftol, (int, float)) and 0 <= ftol < 1):
            raise ShellsplineError(f"`ftol` must be a number in [0, 1), got {ftol!r}")
        if max_time_s is not None and not (isinstance(max_time_s, (int, float, np.number))
                                           and not isinstance(max_time_s, (bool, np.bool_))
                                           and 0 < max_time_s < np.inf):
            raise ShellsplineError(f"`max_time_s` must be a positive number of seconds, got "
                                   f"{max_time_s!r}")
        if isinstance(max_iter, bool) or not isinstance(max_iter, (int, np.integer)) or \
                max_iter < 0:
            raise ShellsplineError(f"`max_iter` must be a non-negative integer, got "
                                   f"{max_iter!r}")
        self.gtol, self.ftol = float(gtol), float(ftol)
        #: an energy at or below this is round-off (set by the solver from the problem's
        #: scale): converged whatever the gradient says
        self.f_floor = 0.0
        self.max_iter = int(max_iter)
        self.max_time_s = None if max_time_s is None else float(max_time_s)
        self.t0 = None

    def start(self, t0: float | None = None) -> None:
        """Start the clock: ``time.perf_counter()`` now, or the earlier value ``t0``."""
        self.t0 = time.perf_counter() if t0 is None else float(t0)

    @property
    def deadline(self) -> float | None:
        """``time.perf_counter()`` value of the time limit (None: no limit)."""
        return None if self.max_time_s is None else self.t0 + self.max_time_s

    def elapsed(self) -> float:
        return time.perf_counter() - self.t0

    def time_up_message(self) -> str:
        return f"not converged: time limit of {self.max_time_s:g} s reached"

    def check(self, result: SolverResult):
        """``(status, message)`` when ``result``'s last iterate stops the run, else None."""
        E, G = result.energies, result.grad_norms
        if E[-1] <= self.f_floor:
            # keyframes that differ by rigid motions only: the energy is round-off, and so
            # is its gradient, which no iteration reduces (500 iterations at 1e-28 before)
            return "converged", "converged: energy at round-off level"
        if G[-1] <= self.gtol * G[0]:
            return "converged", "converged: gradient norm reduced by gtol"
        if self.ftol > 0 and E.size > FTOL_WINDOW and \
                E[-1 - FTOL_WINDOW] - E[-1] <= self.ftol * abs(E[-1]):
            return "stalled", (f"not converged: energy changed by at most ftol over the last "
                               f"{FTOL_WINDOW} iterations (gradient reduced by "
                               f"{G[-1] / G[0]:.1e} of the gtol {self.gtol:g})")
        if self.max_time_s is not None and self.elapsed() > self.max_time_s:
            return "limit", self.time_up_message()
        if result.iterations >= self.max_iter:
            return "limit", "not converged: maximum number of iterations reached"
        return None


class NonlinearSplineSolver:
    """Minimise ``F^K`` of a :class:`~.problem.NonlinearSplineProblem` with a pluggable
    optimiser under one :class:`StopPolicy`.

    Parameters
    ----------
    problem : NonlinearSplineProblem
    optimizer : Optimizer, optional
        :class:`~.optimizers.TrustRegionNewton` (default),
        :class:`~.optimizers.LineSearchNewton` or :class:`~.optimizers.LBFGS`.
    stop : StopPolicy, optional
    callback : callable, optional
        ``callback(iteration, energy, grad_norm)`` after the first evaluation
        (``iteration = 0``) and after every outer iteration.

    Examples
    --------
    >>> import numpy as np, trimesh
    >>> from shellspline.mesh.topology import topology
    >>> from shellspline.shells.energy import DiscreteShells
    >>> m = trimesh.creation.icosphere(subdivisions=1)
    >>> V, T = np.asarray(m.vertices), topology(m.faces)
    >>> Vkey = np.stack([V * [1.3, 1, 1], V, V * [1, 1.3, 1]])
    >>> prob = NonlinearSplineProblem(DiscreteShells(T, eta=0.1), [0, 2, 4], 4)
    >>> res = NonlinearSplineSolver(prob, stop=StopPolicy(gtol=1e-4)).solve(Vkey)
    >>> res.status, res.V.shape
    ('converged', (5, 42, 3))
    """

    def __init__(self, problem: NonlinearSplineProblem, optimizer: Optimizer | None = None,
                 stop: StopPolicy | None = None, callback=None):
        self.problem = problem
        self.optimizer = TrustRegionNewton() if optimizer is None else optimizer
        if not isinstance(self.optimizer, Optimizer):
            raise ShellsplineError(f"`optimizer` must be an Optimizer, got "
                                   f"{type(self.optimizer).__name__}")
        self.stop = StopPolicy() if stop is None else stop
        self.callback = callback
        self.S0 = None
        self.result = None
        self._last = None      # (x, F, g) of the last evaluation with a gradient
        self._accepted = None  # (x, midpoints) of the last accepted iterate
        self._verdict = None

    # -- used by the optimisers ----------------------------------------------------------------
    def evaluate(self, x, warm=None, trial: bool = False, slot_set: int = 0):
        """``(F, g)`` at the flat variables ``x``; a ``trial`` is rejected cheaply
        (``(inf, None)``) when a midpoint solve does not converge in 10 Newton steps."""
        prob = self.problem
        keep = self.optimizer.keeps_factorizations
        S = prob.nodes_of(x, self.S0)
        if trial:
            F, G = prob.evaluate(S, keep=keep, warm=warm, max_newton=10, abort_on_failure=True,
                                 slot_set=slot_set)
            if G is None:
                return F, None
        else:
            F, G = prob.evaluate(S, keep=keep, warm=warm, slot_set=slot_set)
        g = prob.x_of(G)
        self._last = (x.copy(), F, g)
        return F, g

    def accept(self, x) -> bool:
        """Record the accepted iterate ``x``; True when the stop policy ends the run."""
        if self._last is not None and np.array_equal(self._last[0], x):
            F, g = self._last[1], self._last[2]
        else:
            F, g = self.evaluate(x)
        res = self.result
        res.iterations += 1
        self._accepted = (x, _copy(self.problem.midpoints))
        gn = float(np.linalg.norm(g))
        res.record(F, gn)
        res.times.append(self.stop.elapsed())
        if self.callback is not None:
            self.callback(res.iterations, F, gn)
        self._verdict = self.stop.check(res)
        return self._verdict is not None

    # -- the run -------------------------------------------------------------------------------
    def solve(self, Vkey, init=None, *, started: float | None = None,
              stacklevel: int = 2) -> NonlinearSplineResult:
        """Run from ``init`` (default: the per-vertex linear blend) through the keyframes.

        Every call is a fresh run: the stop policy's clock restarts, the problem's midpoints,
        counters and midpoint tolerance are those of a new problem.

        Parameters
        ----------
        Vkey : (J,n,3) float array
        init : (K+1,n,3) float array, optional
            Initial path; keyframes are taken from ``Vkey``.
        started : float, optional
            ``time.perf_counter()`` value from which ``max_time_s`` counts (default: now), so
            that a caller's set-up counts too.
        stacklevel : int
            Of the ``RuntimeWarning`` issued when the run did not converge.

        Returns
        -------
        NonlinearSplineResult
        """
        stop, prob = self.stop, self.problem
        stop.start(started)
        prob.deadline = stop.deadline
        prob.midpoints = prob.last = None
        prob.nfev = prob.midpoint_iterations = prob.midpoint_failures = 0
        tol0 = prob.midpoint_tol
        try:
            return self._solve(Vkey, init, stacklevel + 1)
        finally:
            prob.midpoint_tol = tol0  # the final phase tightens it for its run only

    def _solve(self, Vkey, init, stacklevel):
        stop, prob = self.stop, self.problem
        Vkey = checked_poses(Vkey, prob.n)
        K, frames = prob.K, prob.frames
        if len(frames) != len(Vkey):
            raise ShellsplineError(f"`frames` must have one entry per keyframe ({len(Vkey)}), "
                                   f"got {len(frames)}")
        self.optimizer.check(prob)
        if init is None:
            V0 = linear_blend(Vkey, frames, K, prob.bc)
        else:
            V0 = np.array(init, dtype=np.float64)
            if V0.shape != (K + 1, prob.n, 3):
                raise ShellsplineError(f"`init` must have shape (K+1,n,3) = ({K + 1},"
                                       f"{prob.n},3), got {V0.shape}")
            if not np.all(np.isfinite(V0)):
                raise ShellsplineError("`init` must be finite")
        V0[frames] = Vkey
        self.S0 = S0 = V0[:prob.n_nodes].copy()
        self.result = res = NonlinearSplineResult(V=V0, frames=frames, status="limit",
                                                  optimizer=self.optimizer.name)
        self._last = self._accepted = self._verdict = None
        if prob.n_variables == 0:
            res.record(prob.evaluate(S0, gradient=False), 0.0)
            res.stop("converged", "no free frames")
            return self._finish(S0, V0, Vkey, stacklevel)
        x0 = prob.x_of(S0)
        try:
            F0, g0 = self.evaluate(x0)
        except TimeLimitReached:  # the initial path is returned, its energy unknown
            prob.midpoints = prob.last = None
            res.stop("limit", stop.time_up_message() + " before the first evaluation "
                                                        "finished")
            return self._finish(S0, V0, Vkey, stacklevel)
        g0n = float(np.linalg.norm(g0))
        stop.f_floor = ROUNDOFF * prob.scale4 * energy_scale(prob.energy, Vkey[0])
        res.record(F0, g0n)
        res.times.append(stop.elapsed())
        if self.callback is not None:
            self.callback(0, F0, g0n)
        self._accepted = (x0, _copy(prob.midpoints))
        self._verdict = stop.check(res)
        x, timed_out = x0, False
        if self._verdict is None:
            try:
                x, verdict = self.optimizer.run(self, x0, F0, g0)
                self._verdict = verdict or self._verdict
            except TimeLimitReached:  # the last accepted iterate (its midpoints kept)
                x, prob.midpoints = self._accepted
                self._verdict, timed_out = ("limit", stop.time_up_message()), True
        res.stop(*self._verdict)
        if not timed_out and (self._last is None or not np.array_equal(self._last[0], x)):
            self.evaluate(x)  # the midpoints at the returned iterate
        prob.last = None  # release the kept factorizations and geometry
        if hasattr(prob.energy, "retain"):
            prob.energy.retain([])
        return self._finish(prob.nodes_of(x, S0), V0, Vkey, stacklevel)

    def _finish(self, S, V0, Vkey, stacklevel):
        prob, res = self.problem, self.result
        K = prob.K
        V = np.zeros((K + 1, prob.n, 3))
        V[:prob.n_nodes] = S
        periodic = prob.bc == "periodic"
        if periodic:
            V[K] = V[0]
        if prob.pinned is None and getattr(prob.energy, "rigid_invariant", False):
            for k in prob.free_nodes:
                V[k] = rigid_placement(V[k], V0[k])
        V[prob.frames] = Vkey
        if periodic:
            V[K] = Vkey[0]
        res.V = V
        res.nfev = prob.nfev
        res.midpoints = prob.midpoints
        res.midpoint_newton_iterations = prob.midpoint_iterations
        res.time_s = self.stop.elapsed()
        if not res.success:
            warnings.warn(f"nonlinear_spline: {res.message}", RuntimeWarning,
                          stacklevel=stacklevel + 1)
        return res


def _copy(a):
    return None if a is None else a.copy()


def nonlinear_spline(Vkey, frames, K, T: Topology | None = None, *, bc: str = "natural",
                     mu: float = 1.0, lam: float = 1.0, eta: float = 1e-3, pinned=None,
                     init=None, energy=None, max_iter: int = 500, gtol: float = 1e-6,
                     ftol: float = 0.0,
                     midpoint_tol: float = 1e-10, optimizer: str = "gauss-newton",
                     cg_tol: float | None = None, cg_max_iter: int = 200, memory: int = 20,
                     backend: str = "auto", precondition: bool = True,
                     max_time_s: float | None = None, hessian: str = "auto",
                     globalization: str = "trust-region", retract: bool | None = None,
                     final_phase: bool = True, callback=None) -> NonlinearSplineResult:
    """Nonlinear time-discrete spline through keyframe shells (paper eqs. 7, 8, 17).

    Parameters
    ----------
    Vkey : (J,n,3) float64 array
        Keyframe poses (one connectivity).
    frames : (J,) int array
        Strictly increasing keyframe frames, ``frames[0] == 0``, ``frames[-1] <= K``
        (``< K`` for periodic); Hermite needs frames ``0, 1, K-1, K``.
    K : int
        Last frame (``K+1`` frames).
    T : Topology
        Connectivity (not needed when ``energy`` is given).
    bc : {"natural", "periodic", "hermite"}
    mu, lam, eta : float
        Discrete Shells parameters (eq. 9).
    pinned : (p,) int array, optional
        Vertices fixed in every shell (e.g. the cactus base); they must coincide in all
        keyframes.
    init : (K+1,n,3) float array, optional
        Initial path (e.g. the LΘA spline); keyframes are taken from ``Vkey``. Default: the
        per-vertex linear blend.
    energy : DiscreteShells or EuclideanEnergy, optional
        A prebuilt energy (overrides ``T, mu, lam, eta``), e.g. ``EuclideanEnergy(n)`` for the
        Euclidean discrete cubic spline.
    max_iter : int
        Maximum number of outer (Gauss–Newton or L-BFGS) iterations.
    gtol : float
        Stop when ``‖∇F‖ <= gtol ‖∇F(init)‖``.
    ftol : float
        Also stop when ``F`` fell by at most ``ftol · F`` over the last :data:`FTOL_WINDOW`
        outer iterations, reported as ``"stalled"`` (not converged: the gradient criterion
        does not hold). ``0`` (default): off. The energy settles long
        before the gradient on stiff problems: on the 1000-vertex cactus (K = 20) ``F``
        has 5 digits at ~150 s while ``‖∇F‖`` is still ~2e-2 of its start.
    midpoint_tol : float
        Tolerance of the midpoint Newton solves (relative gradient max-norm).
    optimizer : {"gauss-newton", "lbfgs"} or Optimizer
        Outer optimiser (see Notes). ``"gauss-newton"`` (default) needs ~10 outer iterations
        to a gradient reduction of 1e-6 where L-BFGS needs hundreds. An
        :class:`~.optimizers.Optimizer` object is used as given (``globalization``,
        ``hessian``, ``cg_tol``, ``cg_max_iter``, ``retract``, ``final_phase``, ``memory``
        and ``precondition`` then configure nothing: they are the object's own).
    cg_tol, cg_max_iter : float, int
        Relative residual and iteration limit of the inner CG of ``"gauss-newton"``.
        Default ``cg_tol``: 0.5 with the trust region, where the forcing term is
        ``min(cg_tol, √(‖∇F‖/‖∇F₀‖))`` (tighter as the gradient drops) but never below
        ``0.5 gtol ‖∇F₀‖/‖∇F‖`` (``gtol_margin``: no solve beyond what meets ``gtol``,
        so near the end it may exceed ``cg_tol``); 0.1 (fixed) with the line search.
        (:attr:`TrustRegionNewton.gtol_margin <shellspline.shells.nonlinear.optimizers.
        TrustRegionNewton>`)
    globalization : {"trust-region", "line-search"}
        ``"gauss-newton"`` optimiser: Steihaug–Toint trust region (default) or Armijo
        backtracking along the CG step (see Notes).
    retract : bool, optional
        Trust region: take trial steps along the LΘA retraction (:class:`~.models.LTARetraction`)
        instead of straight lines in vertex space. Default: on for mesh energies.
    final_phase : bool
        Trust region on a mesh energy with exact products: once ``‖∇F‖`` is below
        ``0.1 ‖∇F₀‖``, continue with the space–time LΘA preconditioner and exact products
        that are accurate in soft directions, CG solved to its forcing term (
        :data:`~.optimizers.FINAL_PHASE`). ``False``: the first phase's choices to the end.
    memory : int
        L-BFGS memory.
    max_time_s : float, optional
        Wall-clock limit in seconds of the whole call, the set-up and the first evaluation
        included: checked before every midpoint solve, Hessian product, model term and
        retracted shell, so it is overrun by at most one of those (or one factorization of
        the preconditioner). When it is reached the result is the last accepted iterate,
        unconverged, with a warning and the message "time limit ... reached" (the initial
        path, with empty ``energies``, if the first evaluation did not finish).
    hessian : {"auto", "exact", "gauss-newton"}
        ``"gauss-newton"`` optimiser: CG on the Gauss–Newton model (cheap products, good
        while the midpoints are close to the shells), on the exact reduced Hessian
        (:meth:`GaussNewtonModel.exact_matvec`, ~10x the cost per product, includes the
        adjoint-weighted third derivatives) or ``"auto"``: Gauss–Newton until one exact
        product shows its curvature along a step off by more than 30 %, exact from then on.
        Measured: ellipsoids (η=0.1) stay Gauss–Newton; the hexagon folds at η=0.01 need
        exact products (Gauss–Newton underestimates the curvature 30x there: steps of
        0.01, no convergence in 120 s; exact: 12 iterations).
    precondition : bool
        ``"lbfgs"`` only: the quadratic-model preconditioner of the Notes as the initial
        inverse Hessian (else the usual ``sᵀy/yᵀy`` scaling).
    backend : {"auto", "cholmod", "splu"}
    callback : callable, optional
        ``callback(iteration, energy, grad_norm)`` after every outer iteration (and once with
        ``iteration = 0`` at the initial point).

    Returns
    -------
    NonlinearSplineResult
        Warns (``RuntimeWarning``) when the gradient criterion was not reached
        (``status != "converged"``).

    Raises
    ------
    ValueError
        Invalid ``Vkey``, ``frames``, ``K``, ``bc``, ``init``, ``pinned`` or parameters.

    Notes
    -----
    This function assembles a :class:`NonlinearSplineSolver` from a
    :class:`~.problem.NonlinearSplineProblem`, an optimiser (``optimizer`` and
    ``globalization`` pick :class:`~.optimizers.TrustRegionNewton`,
    :class:`~.optimizers.LineSearchNewton` or :class:`~.optimizers.LBFGS`) and a
    :class:`StopPolicy` (``gtol``, ``ftol``, ``max_iter``, ``max_time_s``).

    ``"gauss-newton"``: every outer iteration solves ``H d = −∇F`` approximately by CG on
    the Gauss–Newton model of :class:`GaussNewtonModel` (products reuse the midpoint
    factorizations of the evaluation, no new factorization) or on the exact reduced Hessian.
    With ``globalization="trust-region"`` CG is Steihaug–Toint's (stops at the trust-region
    boundary, also along negative curvature) and the trial point lies on the LΘA retraction:
    each shell's descriptor change ``J d`` is applied in LΘA space and the shell
    reconstructed, which bends thin parts without the second-order stretch of a straight
    step; a trial is accepted when the energy drops, the radius follows the ratio of actual to
    predicted decrease. Measured on the coarse cactus (1000 vertices, ``K = 20``, ``η = 1e-3``):
    the line search needed steps of 1/8–1/200 of the Newton step and had not reduced the
    gradient in 11 iterations (600 s); the trust region reduces it to 3.6e-4 in 300 s.
    With ``"line-search"`` it backtracks from the full step (Armijo). Either way the energy is
    non-increasing and the midpoints of a trial point start from their first-order
    prediction. CG is preconditioned by the
    quadratic model of ``F^K`` near a path of similar shells,
    ``P = 4K³ Σ_t g_t g_tᵀ ⊗ W,22[s_k, s_k]`` (``g_t`` the midpoint-residual stencil
    ``−½, 1, −½`` of term ``t``), a block-banded sparse matrix over all free frames factored
    once. Rigid motions of every frame (the kernel of both) are projected out.

    ``"lbfgs"``: L-BFGS (two-loop recursion) with Armijo backtracking and curvature-checked
    updates, ``P⁻¹`` as initial inverse Hessian when ``precondition``.

    Examples
    --------
    >>> import numpy as np, trimesh
    >>> from shellspline.mesh.topology import topology
    >>> m = trimesh.creation.icosphere(subdivisions=1)
    >>> V, T = np.asarray(m.vertices), topology(m.faces)
    >>> Vkey = np.stack([V * [1.3, 1, 1], V, V * [1, 1.3, 1]])
    >>> res = nonlinear_spline(Vkey, [0, 2, 4], 4, T, eta=0.1, gtol=1e-4)
    >>> res.success, res.V.shape
    (True, (5, 42, 3))
    """
    t0 = time.perf_counter()  # max_time_s covers the set-up and the first evaluation too
    stop = StopPolicy(gtol=gtol, ftol=ftol, max_iter=max_iter, max_time_s=max_time_s)
    W = make_energy(T, energy, mu, lam, eta)
    Vkey = checked_poses(Vkey, W.n_vertices)
    opt = _optimizer(optimizer, globalization, hessian=hessian, cg_tol=cg_tol,
                     cg_max_iter=cg_max_iter, retract=retract, final_phase=final_phase,
                     memory=memory, precondition=precondition)
    prob = NonlinearSplineProblem(W, frames, K, bc, pinned=pinned, midpoint_tol=midpoint_tol,
                                  backend=backend)
    return NonlinearSplineSolver(prob, opt, stop, callback).solve(Vkey, init, started=t0,
                                                                  stacklevel=3)


def _optimizer(optimizer, globalization, *, hessian, cg_tol, cg_max_iter, retract,
               final_phase, memory, precondition) -> Optimizer:
    """The optimiser object that :func:`nonlinear_spline`'s switches name."""
    if isinstance(optimizer, Optimizer):
        return optimizer
    name = str(optimizer).strip().lower().replace("_", "-")
    if name not in ("gauss-newton", "lbfgs"):
        raise ShellsplineError(f"`optimizer` must be 'gauss-newton' or 'lbfgs', got "
                               f"{optimizer!r}")
    glob = str(globalization).strip().lower().replace("_", "-")
    if glob not in ("trust-region", "line-search"):
        raise ShellsplineError(f"`globalization` must be 'trust-region' or 'line-search', "
                               f"got {globalization!r}")
    if retract is not None and not isinstance(retract, (bool, np.bool_)):
        raise ShellsplineError(f"`retract` must be True, False or None, got {retract!r}")
    if name == "lbfgs":
        canonical_hessian(hessian)
        return LBFGS(memory=memory, precondition=precondition)
    if glob == "line-search":
        return LineSearchNewton(hessian=hessian, cg_tol=0.1 if cg_tol is None else cg_tol,
                                cg_max_iter=cg_max_iter)
    return TrustRegionNewton(hessian=hessian, cg_tol=0.5 if cg_tol is None else cg_tol,
                             cg_max_iter=cg_max_iter, retract=retract,
                             final_phase=final_phase)

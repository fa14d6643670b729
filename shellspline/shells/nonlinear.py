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
Gauss–Newton–CG (:class:`GaussNewtonModel`, or L-BFGS; Armijo backtracking, see
:func:`nonlinear_spline`) and stopped when the gradient norm has dropped by ``gtol`` relative to
the initial one.

Rigid motions: ``F^K`` is invariant under a rigid motion of every single shell (``W`` is, in
both arguments, and so is the midpoint up to a rigid motion), so the problem is solved modulo
rigid motions: the gradient is orthogonal to them, L-BFGS therefore hardly moves along them,
and the midpoint Newton solver projects them out (see :mod:`shellspline.shells.geodesic`). At the end
every free frame is rigidly placed onto its initial pose (Kabsch), which makes the output
canonical. With ``pinned`` vertices these stay fixed in every shell and midpoint instead (no
placement).
"""
from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field

import numpy as np

from ..errors import ShellsplineError
from ..mesh.pinned import canonical_pinned
from ..mesh.rigid import rigid_modes
from .geodesic import PathSolver, make_energy
from ..timeline import canonical_bc, checked_frames, checked_K
from .reconstruct import rigid_placement
from ..mesh.topology import Topology

__all__ = ["NonlinearSplineProblem", "NonlinearSplineResult", "nonlinear_spline"]

#: Relative mismatch of the Gauss–Newton and the exact curvature along a step above which
#: ``hessian="auto"`` switches to exact Hessian products for the rest of the run.
_GN_MISMATCH = 0.3
#: Truncation of the trust-region CG (Nash & Sofer 1990): stop when the last iteration's model
#: decrease, times the iteration count, is below this fraction of the total decrease. Measured
#: on the 1000-vertex cactus (K = 20, 300 s): gradient reduction 3.6e-4 against 1.4e-3 without
#: (CG runs of 6–7 products alternate with long ones instead of 130–200 every time).
_NASH_SOFER = 0.25
#: Outer iterations over which ``ftol`` measures the relative energy decrease.
FTOL_WINDOW = 3
#: Iterative-refinement steps of the midpoint solves inside :meth:`GaussNewtonModel.
#: accurate_matvec`. The midpoint Hessians are factored with a relative shift of 1e-10
#: (:mod:`shellspline.shells.geodesic`); without refinement the products are wrong in the soft
#: directions that a late Newton step consists of. Measured on the 1000-vertex cactus at
#: ``‖∇F‖ = 6e-6 ‖∇F₀‖``: along a converged Newton step the predicted energy decrease was
#: 0.64 of the actual and the gradient change off by 67 % (linear in the step: a Hessian
#: error); with 1 refinement step 0.96, with 3 0.99 (the remaining gradient mismatch then
#: quadratic in the step, i.e. third order). :meth:`~GaussNewtonModel.matvec` and
#: :meth:`~GaussNewtonModel.exact_matvec` (the first phase) keep the unrefined solves: far
#: from the minimiser the stiffer soft modes act as damping, and with refined ones the
#: cactus run took boundary steps with ρ ≈ 0.6–0.8 and was slower (‖∇F‖ 45 instead of 0.7–2.7 at
#: 260 s).
_MODEL_REFINE = 2
#: The trust region's final Newton phase starts once exact products are in use and
#: ``‖∇F‖ <= _FINAL_PHASE ‖∇F₀‖`` (mesh energies): :class:`_SpaceTimePreconditioner`,
#: :meth:`GaussNewtonModel.accurate_matvec`, untruncated CG with forcing at most
#: ``_FINAL_CG_TOL`` (unless :data:`_GTOL_MARGIN` allows a looser one). Earlier, far from
#: the minimiser, the same choice took smaller steps than the first phase (1000-vertex
#: cactus: ``‖∇F‖`` 9e-3 of its start in 300 s against 2e-4).
#: Switching at 0.1 instead of 2e-2: converged (4.2e-8) at 317 s instead of 3e-7 at 360 s;
#: it needs :data:`_FINAL_MIDPOINT_TOL` (without it the 0.1 run stalled at 2.2e-6).
_FINAL_PHASE = 0.1
_FINAL_CG_TOL = 0.05
#: Midpoint tolerance of the final phase. ``F`` is not stationary in the midpoints, so its
#: error follows theirs: with the default 1e-10 the cactus's last trial steps (predicted
#: decrease 7e-11) measured increases of 5e-11 and the trust region shrank to nothing.
_FINAL_MIDPOINT_TOL = 1e-13
#: CG is never asked for a residual below ``_GTOL_MARGIN · gtol · ‖∇F₀‖``: with an accurate
#: model the next gradient is about the CG residual, so that already meets ``gtol``. The
#: Eisenstat–Walker forcing ``√(‖∇F‖/‖∇F₀‖)`` would solve the cactus's last Newton system
#: (at 3.2e-6) to 1.8e-3 instead of 0.16 of its right-hand side.
_GTOL_MARGIN = 0.5


@dataclass
class NonlinearSplineResult:
    """What :func:`nonlinear_spline` returns.

    Attributes
    ----------
    V : (K+1,n,3) float64 array
        The spline; ``V[frames[j]]`` is keyframe ``j`` bit for bit (periodic: ``V[K] = V[0]``).
    frames : (J,) int64 array
    energy : float
        Final ``F^K`` (eq. 7).
    energies : list of float
        ``F^K`` at the initial point and after every outer iteration (non-increasing); empty
        (and ``energy`` NaN) when ``max_time_s`` ran out before the first evaluation ended.
    grad_norms : list of float
        Euclidean norm of the gradient at the same points.
    times : list of float
        Seconds since the start of the optimisation at the same points.
    nit : int
        Outer iterations.
    nfev : int
        Energy/gradient evaluations (each solves all midpoint problems).
    success : bool
        The gradient norm dropped below ``gtol`` times the initial one, or (with ``ftol``)
        the energy stalled (``message`` says which).
    message : str
    midpoints : (T,n,3) float64 array
        Geodesic midpoints ``s̃_k`` of the energy terms at the solution.
    time_s : float
        Wall time of the optimisation.
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
    energy: float
    energies: list = field(default_factory=list)
    grad_norms: list = field(default_factory=list)
    times: list = field(default_factory=list)
    nit: int = 0
    nfev: int = 0
    success: bool = False
    message: str = ""
    midpoints: np.ndarray | None = None
    time_s: float = 0.0
    optimizer: str = ""
    cg_iterations: list = field(default_factory=list)
    step_lengths: list = field(default_factory=list)
    midpoint_newton_iterations: int = 0
    hessian: list = field(default_factory=list)
    final_phase_iteration: int | None = None


class _TimeUp(Exception):
    """Raised inside the solver when ``max_time_s`` has passed (:meth:`check_time`)."""


def _copy(a):
    return None if a is None else a.copy()


class NonlinearSplineProblem:
    """The constrained spline energy ``F^K`` and its adjoint gradient on a fixed time grid.

    Parameters
    ----------
    energy : DiscreteShells or EuclideanEnergy
        The deformation energy ``W``.
    frames : (J,) int array
        Keyframe frames (validated as in :class:`~shellspline.shells.lta_spline.LTASpline`).
    K : int
    bc : {"natural", "periodic", "hermite"}
    pinned : (p,) int array, optional
    midpoint_tol : float
        Gradient tolerance of the midpoint Newton solves (relative to the energy's scale).
    backend : str
        Sparse factorization backend.

    Attributes
    ----------
    n_nodes : int
        ``K+1`` (``K`` for periodic: frame ``K`` is frame ``0``).
    terms : (T,3) int64 array
        ``(k-1, k, k+1)`` node triples of the energy terms.
    free_nodes : (f,) int64 array
        Frames that are optimised.
    midpoints : (T,n,3) float64 array or None
        Midpoints of the last evaluation (warm starts of the next one).
    """

    def __init__(self, energy, frames, K, bc="natural", *, pinned=None,
                 midpoint_tol: float = 1e-10, backend: str = "auto"):
        self.energy = energy
        self.bc = canonical_bc(bc)
        self.K = checked_K(K)
        self.frames = checked_frames(frames, self.K, self.bc)
        if self.K < 2:
            raise ShellsplineError(f"`K` must be >= 2 for a spline, got {K!r}")
        K = self.K
        if self.bc == "periodic":
            self.n_nodes = K
            k = np.arange(K)
            self.terms = np.stack([(k - 1) % K, k, (k + 1) % K], axis=1)
        else:
            self.n_nodes = K + 1
            k = np.arange(1, K)
            self.terms = np.stack([k - 1, k, k + 1], axis=1)
        fixed = np.zeros(self.n_nodes, dtype=bool)
        fixed[self.frames] = True
        self.free_nodes = np.flatnonzero(~fixed)
        n = energy.n_vertices
        self.n = n
        self.pinned = canonical_pinned(pinned, n)
        mask = np.ones(3 * n, dtype=bool)
        if self.pinned is not None:
            mask[(3 * self.pinned[:, None] + np.arange(3)).ravel()] = False
        self.free_dofs = np.flatnonzero(mask)
        self.scale4 = 4.0 * K ** 3
        self.midpoint_tol = float(midpoint_tol)
        self.solver = PathSolver(energy, 1, pinned=self.pinned, backend=backend)
        if hasattr(energy, "cache_size"):
            energy.cache_size = max(energy.cache_size, 8)
        self.midpoints = None
        self.last = None
        self.nfev = 0
        self.midpoint_iterations = 0
        self.midpoint_failures = 0
        #: wall-clock limit (``time.perf_counter()`` value) checked by :meth:`check_time`
        self.deadline = None

    # -- variables ---------------------------------------------------------------------------
    @property
    def n_variables(self) -> int:
        return len(self.free_nodes) * len(self.free_dofs)

    def x_of(self, S) -> np.ndarray:
        """Flat variable vector of the node poses ``S (n_nodes,n,3)``."""
        S = np.asarray(S, dtype=np.float64)
        return S[self.free_nodes].reshape(len(self.free_nodes), -1)[:, self.free_dofs].ravel()

    def nodes_of(self, x, S_template) -> np.ndarray:
        """Node poses with the free entries replaced by ``x``."""
        S = np.array(S_template, dtype=np.float64, copy=True)
        flat = S.reshape(self.n_nodes, -1)
        sub = flat[self.free_nodes]
        sub[:, self.free_dofs] = np.asarray(x).reshape(len(self.free_nodes), -1)
        flat[self.free_nodes] = sub
        return S

    # -- energy and gradient ---------------------------------------------------------------------
    def solve_midpoints(self, S) -> np.ndarray:
        """Geodesic midpoints ``(T,n,3)`` of all terms for node poses ``S`` (eq. 8)."""
        M = self._warm(S)
        for t, (a, _, b) in enumerate(self.terms):
            self.check_time()
            res = self.solver.solve(S[a], S[b], M[t][None], tol=self.midpoint_tol,
                                    check=self.check_time)
            self.midpoint_iterations += res.nit
            self.midpoint_failures += not res.success
            M[t] = res.V[1]
        return M

    def _warm(self, S):
        if self.midpoints is None:
            return 0.5 * (S[self.terms[:, 0]] + S[self.terms[:, 2]])
        return self.midpoints.copy()

    def evaluate(self, S, *, gradient: bool = True, keep: bool = False, warm=None,
                 max_newton: int = 50, abort_on_failure: bool = False, slot_set: int = 0):
        """``F^K`` and its gradient for node poses ``S (n_nodes,n,3)``.

        Parameters
        ----------
        S : (n_nodes,n,3) float array
        gradient : bool
        keep : bool
            Keep every term's midpoint factorization and the point (:attr:`last`) for the
            Gauss–Newton model (:class:`GaussNewtonModel`).
        warm : (T,n,3) float array, optional
            Initial midpoints (default: those of the last evaluation).
        max_newton : int
            Newton iteration limit of each midpoint solve.
        abort_on_failure : bool
            Return ``F = inf`` (and ``G = None``) as soon as a midpoint solve fails (cheap
            rejection of line-search trials far from the current point).
        slot_set : int
            Which set of kept factorizations ``keep`` writes (a trust-region trial writes the
            other set than the model it is tested against, so a rejected trial leaves the
            model intact).

        Returns
        -------
        F : float
        G : (n_nodes,n,3) float64 array
            ``∂F/∂s_k`` (adjoint method, eqs. 13–17); zero on keyframes and pinned vertices.
            Only if ``gradient``.
        """
        S = np.asarray(S, dtype=np.float64)
        W = self.energy
        M = self._warm(S) if warm is None else np.array(warm, dtype=np.float64)
        F = 0.0
        G = np.zeros((self.n_nodes, 3 * self.n))
        ctxs, geos = [], []
        for t, (a, k, b) in enumerate(self.terms):
            self.check_time()
            res = self.solver.solve(S[a], S[b], M[t][None], tol=self.midpoint_tol,
                                    max_iter=max_newton, check=self.check_time)
            self.midpoint_iterations += res.nit
            if abort_on_failure and not res.success:
                self.nfev += 1
                return (np.inf, None) if gradient else np.inf
            self.midpoint_failures += not res.success
            m = res.V[1]
            # one more Newton step with the Hessian that the adjoint needs anyway: F is not
            # stationary in the midpoint, so its round-off level follows the midpoint's error
            ctx = self.solver.factor_at(S[a], m[None], S[b],
                                        slot=(slot_set, t) if keep else None)
            ctx["m"] = m
            if keep and hasattr(W, "geometry_of"):
                geos.append(W.geometry_of(m))
            gm = self.solver.gradient(S[a], m[None], S[b])
            m = m + self.solver.solve_factored(ctx, -gm)[0].reshape(m.shape)
            M[t] = m
            F += W.energy(S[k], m)
            ctxs.append(ctx)
            if not gradient:
                continue
            G[k] += W.gradient(S[k], m, 0)
            rhs = -W.gradient(S[k], m, 1)
            p = self.solver.solve_factored(ctx, rhs[None])[0]
            ctx["p"] = p
            G[a] += W.mixed_product(S[a], m, p, "12")
            G[b] += W.mixed_product(m, S[b], p, "21")
        self.midpoints = M
        self.nfev += 1
        self.last = {"S": S.copy(), "M": M.copy(), "ctx": ctxs} if keep else None
        if keep and hasattr(W, "retain"):
            # the Gauss–Newton model evaluates W at the shells and the factored midpoints
            # (their element Hessians were computed for the factorization: keep them)
            W.retain(list(S), geometries=geos)
        F *= self.scale4
        if not gradient:
            return F
        G *= self.scale4
        keep_nodes = np.zeros(self.n_nodes, dtype=bool)
        keep_nodes[self.free_nodes] = True
        G[~keep_nodes] = 0.0
        if self.pinned is not None:
            G[:, (3 * self.pinned[:, None] + np.arange(3)).ravel()] = 0.0
        return F, G.reshape(self.n_nodes, self.n, 3)

    def check_time(self) -> None:
        """Raise :class:`_TimeUp` once :attr:`deadline` has passed (checked in every loop of
        the solver that can take long: midpoint solves, Hessian products, retractions)."""
        if self.deadline is not None and time.perf_counter() > self.deadline:
            raise _TimeUp

    def rigid_bases(self, S) -> list:
        """Per free node: orthonormal basis ``(len(free_dofs), r)`` of the infinitesimal rigid
        motions of ``S[k]`` that the pins leave free (``r = 0`` for energies without rigid
        invariance or with three non-collinear pins)."""
        if not getattr(self.energy, "rigid_invariant", False):
            return [np.zeros((len(self.free_dofs), 0)) for _ in self.free_nodes]
        pd = np.setdiff1d(np.arange(3 * self.n), self.free_dofs)
        return [rigid_modes(np.asarray(S[k]), self.free_dofs, pd) for k in self.free_nodes]


def _checked_keyframes(Vkey, n=None):
    try:
        V = np.asarray(Vkey, dtype=np.float64)
    except (TypeError, ValueError):
        raise ShellsplineError(f"`Vkey` must be a float array, got {type(Vkey).__name__}") from None
    if V.ndim != 3 or V.shape[2] != 3:
        raise ShellsplineError(f"`Vkey` must have shape (J,n,3), got {V.shape}")
    if n is not None and V.shape[1] != n:
        raise ShellsplineError(f"`Vkey` must have n = {n} vertices, got {V.shape[1]}")
    if not np.all(np.isfinite(V)):
        raise ShellsplineError("`Vkey` must be finite")
    return V


def _blend(Vkey, frames, K, periodic):
    """Per-vertex linear blend ``(K+1,n,3)`` (frames after the last keyframe hold it)."""
    k = np.arange(K + 1, dtype=np.float64)
    fr = frames.astype(np.float64)
    J = len(frames)
    if periodic:
        fr = np.concatenate([fr, [K]])
        jj = np.concatenate([np.arange(J), [0]])
    else:
        jj = np.arange(J)
    pos = np.clip(np.searchsorted(fr, k, side="right") - 1, 0, len(fr) - 2)
    t = np.clip((k - fr[pos]) / (fr[pos + 1] - fr[pos]), 0.0, 1.0)[:, None, None]
    out = (1 - t) * Vkey[jj[pos]] + t * Vkey[jj[pos + 1]]
    out[frames] = Vkey
    return out


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
        Also stop (converged in energy) when ``F`` fell by at most ``ftol · F`` over the last
        :data:`FTOL_WINDOW` outer iterations. ``0`` (default): off. The energy settles long
        before the gradient on stiff problems: on the 1000-vertex cactus (K = 20) ``F``
        has 5 digits at ~150 s while ``‖∇F‖`` is still ~2e-2 of its start.
    midpoint_tol : float
        Tolerance of the midpoint Newton solves (relative gradient max-norm).
    optimizer : {"gauss-newton", "lbfgs"}
        Outer optimiser (see Notes). ``"gauss-newton"`` (default) needs ~10 outer iterations
        to a gradient reduction of 1e-6 where L-BFGS needs hundreds.
    cg_tol, cg_max_iter : float, int
        Relative residual and iteration limit of the inner CG of ``"gauss-newton"``.
        Default ``cg_tol``: 0.5 with the trust region, where the forcing term is
        ``min(cg_tol, √(‖∇F‖/‖∇F₀‖))`` (tighter as the gradient drops) but never below
        ``0.5 gtol ‖∇F₀‖/‖∇F‖`` (:data:`_GTOL_MARGIN`: no solve beyond what meets ``gtol``,
        so near the end it may exceed ``cg_tol``); 0.1 (fixed) with the line search.
    globalization : {"trust-region", "line-search"}
        ``"gauss-newton"`` optimiser: Steihaug–Toint trust region (default) or Armijo
        backtracking along the CG step (see Notes).
    retract : bool, optional
        Trust region: take trial steps along the LΘA retraction (:class:`_Retraction`)
        instead of straight lines in vertex space. Default: on for mesh energies.
    final_phase : bool
        Trust region on a mesh energy with exact products: once ``‖∇F‖`` is below
        ``0.1 ‖∇F₀‖``, continue with the space–time LΘA preconditioner and exact products
        that are accurate in soft directions, CG solved to its forcing term (
        :data:`_FINAL_PHASE`). ``False``: the first phase's choices to the end.
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
        Warns (``RuntimeWarning``) when the gradient criterion was not reached.

    Raises
    ------
    ValueError
        Invalid ``Vkey``, ``frames``, ``K``, ``bc``, ``init``, ``pinned`` or parameters.

    Notes
    -----
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
    if max_time_s is not None and not (isinstance(max_time_s, (int, float, np.number))
                                       and 0 < max_time_s < np.inf):
        raise ShellsplineError(f"`max_time_s` must be a positive number of seconds, got "
                               f"{max_time_s!r}")
    W = make_energy(T, energy, mu, lam, eta)
    Vkey = _checked_keyframes(Vkey, W.n_vertices)
    prob = NonlinearSplineProblem(W, frames, K, bc, pinned=pinned, midpoint_tol=midpoint_tol,
                                  backend=backend)
    if max_time_s is not None:
        prob.deadline = t0 + float(max_time_s)
    K, frames = prob.K, prob.frames
    if len(frames) != len(Vkey):
        raise ShellsplineError(f"`frames` must have one entry per keyframe ({len(Vkey)}), "
                               f"got {len(frames)}")
    if not (isinstance(gtol, (int, float)) and 0 < gtol < 1):
        raise ShellsplineError(f"`gtol` must be a number in (0, 1), got {gtol!r}")
    if not (isinstance(ftol, (int, float)) and 0 <= ftol < 1):
        raise ShellsplineError(f"`ftol` must be a number in [0, 1), got {ftol!r}")
    periodic = prob.bc == "periodic"
    if init is None:
        V0 = _blend(Vkey, frames, K, periodic)
    else:
        V0 = np.array(init, dtype=np.float64)
        if V0.shape != (K + 1, W.n_vertices, 3):
            raise ShellsplineError(f"`init` must have shape (K+1,n,3) = ({K + 1},"
                                   f"{W.n_vertices},3), got {V0.shape}")
        if not np.all(np.isfinite(V0)):
            raise ShellsplineError("`init` must be finite")
    V0[frames] = Vkey
    S0 = V0[:prob.n_nodes].copy()
    energies, norms, times = [], [], []
    last = {}

    optimizer = str(optimizer).strip().lower().replace("_", "-")
    if optimizer not in ("gauss-newton", "lbfgs"):
        raise ShellsplineError(f"`optimizer` must be 'gauss-newton' or 'lbfgs', got "
                               f"{optimizer!r}")
    keep = optimizer == "gauss-newton"
    globalization = str(globalization).strip().lower().replace("_", "-")
    if globalization not in ("trust-region", "line-search"):
        raise ShellsplineError(f"`globalization` must be 'trust-region' or 'line-search', "
                               f"got {globalization!r}")
    if retract is not None and not isinstance(retract, (bool, np.bool_)):
        raise ShellsplineError(f"`retract` must be True, False or None, got {retract!r}")
    if retract and not hasattr(W, "T"):
        raise ShellsplineError("`retract` needs a mesh energy (DiscreteShells)")
    hessian = str(hessian).strip().lower().replace("_", "-")
    if hessian not in ("auto", "exact", "gauss-newton"):
        raise ShellsplineError(f"`hessian` must be 'auto', 'exact' or 'gauss-newton', got "
                               f"{hessian!r}")

    def fun(x, warm=None, trial=False, slot_set=0):
        S = prob.nodes_of(x, S0)
        if trial:  # a line-search trial: cheap rejection when a midpoint does not converge
            F, G = prob.evaluate(S, keep=keep, warm=warm, max_newton=10, abort_on_failure=True,
                                 slot_set=slot_set)
            if G is None:
                return F, None
        else:
            F, G = prob.evaluate(S, keep=keep, warm=warm, slot_set=slot_set)
        g = prob.x_of(G)
        last["x"], last["F"], last["g"] = x.copy(), F, g
        return F, g

    if prob.n_variables == 0:
        F = prob.evaluate(S0, gradient=False)
        return _finish(prob, S0, V0, Vkey, [F], [0.0], 0, True, "no free frames", t0, periodic)

    x0 = prob.x_of(S0)
    try:
        F0, g0 = fun(x0)
    except _TimeUp:  # the initial path is returned, its energy unknown
        prob.midpoints = prob.last = None
        return _finish(prob, S0, V0, Vkey, [], [], 0, False, f"not converged: time limit of "
                       f"{max_time_s} s reached before the first evaluation finished", t0,
                       periodic)
    g0n = float(np.linalg.norm(g0))
    energies.append(F0)
    norms.append(g0n)
    times.append(time.perf_counter() - t0)
    if callback is not None:
        callback(0, F0, g0n)
    # the last accepted iterate and its midpoints: the result when the time limit interrupts
    state = {"nit": 0, "done": g0n == 0.0, "x": x0, "midpoints": _copy(prob.midpoints)}
    stats = {"cg_iterations": [], "step_lengths": [], "hessian": [], "exact": False}

    def cb(intermediate_result):
        x = intermediate_result.x
        if "x" in last and np.array_equal(last["x"], x):
            F, g = last["F"], last["g"]
        else:
            F, g = fun(x)
        state["nit"] += 1
        state["x"], state["midpoints"] = x, _copy(prob.midpoints)
        gn = float(np.linalg.norm(g))
        energies.append(F)
        norms.append(gn)
        times.append(time.perf_counter() - t0)
        if callback is not None:
            callback(state["nit"], F, gn)
        if gn <= gtol * g0n:
            state["done"] = True
            raise StopIteration
        if ftol > 0 and len(energies) > FTOL_WINDOW and \
                energies[-1 - FTOL_WINDOW] - F <= ftol * abs(F):
            state["done"] = state["stalled"] = True
            raise StopIteration
        if max_time_s is not None and time.perf_counter() - t0 > max_time_s:
            state["timeout"] = True
            raise StopIteration

    x = x0
    if state["done"]:
        message = "converged: gradient norm reduced by gtol"
    else:
        try:
            if cg_tol is None:
                cg_tol = 0.5 if globalization == "trust-region" else 0.1
            if optimizer == "gauss-newton" and globalization == "trust-region":
                if retract is None:
                    retract = hasattr(prob.energy, "T")
                retraction = _Retraction(prob, S0) if retract else None
                x, message = _trust_region(prob, fun, x0, F0, g0, S0, cb, max_iter, cg_tol,
                                           cg_max_iter, stats, hessian=hessian, gtol=gtol,
                                           retraction=retraction, final_phase=bool(final_phase))
            elif optimizer == "gauss-newton":
                x, message = _gauss_newton(prob, fun, x0, F0, g0, S0, cb, max_iter,
                                           _step_cap(prob, S0, 2.0), cg_tol, cg_max_iter, stats,
                                           hessian=hessian)
            else:
                precond = _Preconditioner(prob, S0) if precondition else None
                x, message = _lbfgs(prob, fun, x0, F0, g0, S0, precond, cb, max_iter, memory)
        except _TimeUp:  # the last accepted iterate (its midpoints kept in state)
            x, message = state["x"], ""
            state["timeout"] = True
            prob.midpoints = state["midpoints"]
        if state.get("stalled"):
            message = (f"converged: energy changed by at most ftol over the last "
                       f"{FTOL_WINDOW} iterations")
        elif state["done"]:
            message = "converged: gradient norm reduced by gtol"
        elif state.get("timeout"):
            message = f"not converged: time limit of {max_time_s} s reached"
    S = prob.nodes_of(x, S0)
    if not state.get("timeout") and ("x" not in last or not np.array_equal(last["x"], x)):
        fun(x)
    prob.last = None  # release the kept factorizations and geometry
    if hasattr(prob.energy, "retain"):
        prob.energy.retain([])
    res = _finish(prob, S, V0, Vkey, energies, norms, state["nit"], state["done"], message, t0,
                  periodic)
    res.optimizer = optimizer
    res.times = times
    res.cg_iterations = stats["cg_iterations"]
    res.step_lengths = stats["step_lengths"]
    res.hessian = stats["hessian"]
    res.final_phase_iteration = stats.get("final_phase")
    res.midpoint_newton_iterations = prob.midpoint_iterations
    return res


class GaussNewtonModel:
    """Gauss–Newton approximation of the Hessian of ``F^K`` at the last kept evaluation.

    With ``F = c Σ_t W[s_k, m_t]``, ``c = 4K³``, and the midpoints ``m_t(s_a, s_b)`` defined by
    ``∇_m (W[s_a, m] + W[m, s_b]) = 0``, the reduced Hessian is ``Zᵀ ∇²L Z``, where
    ``Z = [I; dm/ds]``, ``dm/ds = −A_t⁻¹ (W,21[s_a, m], W,12[m, s_b])`` and ``L`` the
    Lagrangian of the constrained problem. The model keeps the Hessian of ``Σ_t f_t``,
    ``f_t = c W[s_k, m_t]`` (all blocks ``W,11 W,12 W,22`` at ``(s_k, m_t)``), and drops the
    adjoint-weighted second derivatives of the midpoint constraints (third derivatives of
    ``W``). The dropped part is proportional to the adjoint states ``p_t = −A_t⁻¹ ∇_m f_t``,
    which vanish as the midpoints approach the shells; with ``W = ‖s − s̃‖²`` the model is the
    exact Hessian. A product costs two solves with each midpoint factorization (kept by
    ``evaluate(keep=True)``) and a few sparse mat-vecs.

    Parameters
    ----------
    prob : NonlinearSplineProblem
        Evaluated with ``keep=True`` at the point of the model.
    """

    def __init__(self, prob: NonlinearSplineProblem):
        if prob.last is None:
            raise ShellsplineError("GaussNewtonModel needs an evaluation with keep=True")
        self.prob = prob
        W = prob.energy
        S = self.S = prob.last["S"]
        self.M = prob.last["M"]
        self.ctx = prob.last["ctx"]
        self.idx = np.full(prob.n_nodes, -1, dtype=np.int64)
        self.idx[prob.free_nodes] = np.arange(len(prob.free_nodes))
        self.ops = []
        for t, (a, k, b) in enumerate(prob.terms):
            prob.check_time()
            m = self.ctx[t]["m"]  # the midpoint where A_t was factored
            self.ops.append((W.hessian(S[k], m, "11") if self.idx[k] >= 0 else None,
                             W.hessian(S[k], m, "22"), W.mixed_operator(S[k], m),
                             W.mixed_operator(S[a], m), W.mixed_operator(m, S[b])))
        self._base = None  # Lagrangian gradients at the model point (exact_matvec)
        self._cbase = None  # constraint products at the model point (accurate_matvec)
        #: finite-difference step (coordinates) of :meth:`exact_matvec`
        self.h = 1e-6 * (_step_cap(prob, S, 1.0) if np.isfinite(_step_cap(prob, S, 1.0))
                         else 1.0)

    def exact_matvec(self, x) -> np.ndarray:
        """Exact reduced Hessian of ``F^K`` times ``x``: ``Σ_t Z_tᵀ ∇²L_t Z_t x``.

        ``∇²L_t`` (the Lagrangian of term ``t`` with its adjoint state ``p_t`` frozen) is
        applied by a forward difference of the Lagrangian gradient along ``Z_t x`` (its value
        at the model point is computed once per model), with one step ``ε`` for all terms so
        that every perturbed shell ``s_k + ε x_k`` is shared by its three terms (its
        Jacobian computed once); the constraint part ``(W,22[s_a, m] + W,11[m, s_b]) p_t`` by
        a forward difference of the midpoint gradient along ``p_t``. Only gradients and
        mixed products (descriptor Jacobians, no element Hessians, no factorization) at
        perturbed shells: two new Jacobians per term and one per free shell. The third
        derivatives that :meth:`matvec` drops are included. Relative accuracy ~1e-6 in norm
        (test: far from the solution).

        In soft directions the nested difference (along ``p_t`` inside, along ``x`` outside)
        loses that accuracy to round-off, and the unrefined midpoint solves stiffen them: at a
        late iterate of the 1000-vertex cactus, for two vectors preconditioned by
        :class:`_SpaceTimePreconditioner`, ``xᵀHy`` and ``yᵀHx`` differed by 2.5×, and a 10×
        smaller ``h`` changed ``Hx`` by 350× its norm. :meth:`accurate_matvec` fixes both at
        about twice the cost; far from the minimiser this cheaper, stiffer product makes the
        faster progress (see :data:`_MODEL_REFINE`), so the trust region's first phase uses it.
        """
        self.prob.check_time()
        prob = self.prob
        W = prob.energy
        S = self.S
        V = self._full(x)
        out = np.zeros_like(V)
        n = prob.n
        if self._base is None:
            self._base = [self._lagrangian_gradient(t, S[a], S[k], S[b], self.ctx[t]["m"])
                          for t, (a, k, b) in enumerate(prob.terms)]
        DM, eps, Sp = self._perturbation(V, refine=0)
        if eps is None:
            return out[prob.free_nodes][:, prob.free_dofs].ravel()
        held = W.hold([Sp[k] for k in prob.free_nodes])
        try:
            for t, (a, k, b) in enumerate(prob.terms):
                ctx = self.ctx[t]
                m = ctx["m"]
                mm = m if DM[t] is None else m + eps * DM[t].reshape(n, 3)
                plus = self._lagrangian_gradient(t, Sp[a], Sp[k], Sp[b], mm)
                ua, uk, ub, um = ((u - v) / eps for u, v in zip(plus, self._base[t]))
                q = prob.solver.solve_factored(ctx, um[None], refine=0)[0]
                if self.idx[k] >= 0:
                    out[k] += uk
                if self.idx[a] >= 0:
                    out[a] += ua - self.ops[t][3].dot12(q)
                if self.idx[b] >= 0:
                    out[b] += ub - self.ops[t][4].dot21(q)
        finally:
            W.release(held)
        out *= prob.scale4
        return out[prob.free_nodes][:, prob.free_dofs].ravel()

    def _lagrangian_gradient(self, t, sa, sk, sb, mm):
        """Gradient of term ``t``'s Lagrangian ``W[s_k, m] + p_tᵀ ∇_m(W[s_a, m] + W[m, s_b])``
        (``p_t`` frozen) w.r.t. ``(s_a, s_k, s_b, m)``; the constraint's ``m`` derivative by
        a forward difference along ``p_t`` (its O(δ) error cancels in the forward difference
        of :meth:`exact_matvec`, which uses the same ``δ``)."""
        W = self.prob.energy
        p = self.ctx[t]["p"].reshape(self.prob.n, 3)
        dlt = self.h / max(float(np.abs(p).max()), 1e-300)
        ga = W.mixed_product(sa, mm, p, "12")
        gk = W.gradient(sk, mm, 0)
        gb = W.mixed_product(mm, sb, p, "21")
        c0 = W.gradient(sa, mm, 1) + W.gradient(mm, sb, 0)
        cp = W.gradient(sa, mm + dlt * p, 1) + W.gradient(mm + dlt * p, sb, 0)
        gm = W.gradient(sk, mm, 1) + (cp - c0) / dlt
        return ga, gk, gb, gm

    def accurate_matvec(self, x) -> np.ndarray:
        """Exact reduced Hessian of ``F^K`` times ``x``, accurate in soft directions too.

        The Hessian of ``f_t = c W[s_k, m_t]`` is applied analytically (the blocks of
        :meth:`matvec`); only the adjoint-weighted third derivatives of the midpoint
        constraint ``p_tᵀ ∇_m(W[s_a, m] + W[m, s_b])`` are differenced, once, along
        ``(x_a, Z_t x, x_b)``: the analytic products ``W,12[s_a,m] p``, ``W,21[m,s_b] p`` and
        ``(W,22[s_a,m] + W,11[m,s_b]) p``
        (:meth:`~shellspline.shells.energy.DiscreteShells.constraint_products`) at the
        perturbed point minus their values at the model point (computed once per model). One
        difference level instead of :meth:`exact_matvec`'s two: ``xᵀHy`` and ``yᵀHx`` agree
        to 1e-4 in the soft directions where the nested difference is off by 2.5×. Cost on the
        1000-vertex cactus: 0.22 s against 0.20 s (complex-step element terms, the work of
        the four constraint products shared). Used by the final Newton phase of the trust
        region (:data:`_FINAL_PHASE`).
        """
        self.prob.check_time()
        prob = self.prob
        W = prob.energy
        S, n = self.S, prob.n
        V = self._full(x)
        out = np.zeros_like(V)
        if self._cbase is None:
            self._cbase = [None] * len(prob.terms)
        DM, eps, Sp = self._perturbation(V, refine=_MODEL_REFINE)
        if eps is None:
            return out[prob.free_nodes][:, prob.free_dofs].ravel()
        held = W.hold([Sp[k] for k in prob.free_nodes])
        try:
            for t, (a, k, b) in enumerate(prob.terms):
                H11, H22, Mk, Ma, Mb = self.ops[t]
                ctx = self.ctx[t]
                m, p = ctx["m"], ctx["p"]
                dmv = np.zeros(3 * n) if DM[t] is None else DM[t]
                r = H22 @ dmv
                if self.idx[k] >= 0:
                    out[k] += H11 @ V[k] + Mk.dot12(dmv)
                    r = r + Mk.dot21(V[k])
                if self.idx[a] >= 0 or self.idx[b] >= 0:
                    if self._cbase[t] is None:
                        self._cbase[t] = W.constraint_products(S[a], m, S[b], p)
                    plus = W.constraint_products(Sp[a], m + eps * dmv.reshape(n, 3),
                                                     Sp[b], p)
                    ca, cm, cb = ((u - v) / eps for u, v in zip(plus, self._cbase[t]))
                    if self.idx[a] >= 0:
                        out[a] += ca
                    if self.idx[b] >= 0:
                        out[b] += cb
                    r = r + cm
                q = prob.solver.solve_factored(ctx, r[None], refine=_MODEL_REFINE)[0]
                if self.idx[a] >= 0:
                    out[a] -= Ma.dot12(q)
                if self.idx[b] >= 0:
                    out[b] -= Mb.dot21(q)
        finally:
            W.release(held)
        out *= prob.scale4
        return out[prob.free_nodes][:, prob.free_dofs].ravel()

    def _perturbation(self, V, refine):
        """Midpoint changes ``Z_t x`` of all terms, the one difference step ``ε`` shared by
        all terms (so each perturbed free shell's geometry is computed once) and the
        perturbed shells ``S + ε V``; ``ε = None`` for ``x = 0``."""
        DM = [self._dm(t, V, refine=refine) for t in range(len(self.prob.terms))]
        wmax = max([float(np.abs(V).max())] + [float(np.abs(d).max()) for d in DM
                                                if d is not None])
        if wmax == 0.0:
            return DM, None, None
        eps = self.h / wmax
        return DM, eps, self.S + eps * V.reshape(self.S.shape)

    def _full(self, x):
        prob = self.prob
        V = np.zeros((prob.n_nodes, 3 * prob.n))
        sub = np.zeros((len(prob.free_nodes), 3 * prob.n))
        sub[:, prob.free_dofs] = np.asarray(x).reshape(len(prob.free_nodes), -1)
        V[prob.free_nodes] = sub
        return V

    def _dm(self, t, V, refine=0):
        a, _, b = self.prob.terms[t]
        rhs = 0.0
        if self.idx[a] >= 0:
            rhs = rhs + self.ops[t][3].dot21(V[a])
        if self.idx[b] >= 0:
            rhs = rhs + self.ops[t][4].dot12(V[b])
        if np.isscalar(rhs):
            return None
        return -self.prob.solver.solve_factored(self.ctx[t], rhs[None], refine=refine)[0]

    def midpoint_change(self, x) -> np.ndarray:
        """First-order change ``(T,n,3)`` of the midpoints along the step ``x``."""
        V = self._full(x)
        out = np.zeros((len(self.prob.terms), 3 * self.prob.n))
        for t in range(len(self.prob.terms)):
            dm = self._dm(t, V)
            if dm is not None:
                out[t] = dm
        return out.reshape(len(self.prob.terms), self.prob.n, 3)

    def matvec(self, x) -> np.ndarray:
        """Model Hessian times ``x`` (flat over free nodes × free DOFs)."""
        self.prob.check_time()
        prob = self.prob
        V = self._full(x)
        out = np.zeros_like(V)
        for t, (a, k, b) in enumerate(prob.terms):
            H11, H22, Mk, Ma, Mb = self.ops[t]
            dm = self._dm(t, V)
            fk = self.idx[k] >= 0
            if dm is None and not fk:
                continue
            if fk:
                out[k] += H11 @ V[k]
                r = Mk.dot21(V[k])
                if dm is not None:
                    out[k] += Mk.dot12(dm)
                    r = r + H22 @ dm
            else:
                r = H22 @ dm
            q = prob.solver.solve_factored(self.ctx[t], r[None], refine=0)[0]
            if self.idx[a] >= 0:
                out[a] -= Ma.dot12(q)
            if self.idx[b] >= 0:
                out[b] -= Mb.dot21(q)
        out *= prob.scale4
        return out[prob.free_nodes][:, prob.free_dofs].ravel()


class _Preconditioner:
    """Approximate inverse of the quadratic model ``P = 4K³ Σ_t (g_t g_tᵀ) ⊗ H_t`` of ``F^K``.

    ``g_t`` has the entries ``−½, 1, −½`` at the nodes ``a, k, b`` of term ``t`` (the midpoint
    residual ``m_t − s_k`` of a quadratic energy), restricted to the free nodes;
    ``H_t = W,22[s_k, s_k]`` is the elastic Hessian of the term's centre shell on the free
    DOFs (positive semi-definite, zero on its rigid motions). With ``U`` the eigenvectors of
    the small time matrix ``Σ_t g_t g_tᵀ``, ``P`` is block diagonal in ``U ⊗ I`` when all
    ``H_t`` are equal; in general its diagonal blocks are ``B_i = 4K³ Σ_t (u_iᵀ g_t)² H_t``
    and the off-diagonal blocks are dropped. One sparse Cholesky factorization per free node
    (relative shift ``1e-8`` for the rigid motions), factored once. Measured on the Fig. 3
    ellipsoids: 1.3× the CG iterations of the exact ``P⁻¹`` at a tenth of its cost per
    application, and 5× fewer than a single averaged ``H``. :meth:`apply` projects out each
    node's rigid motions.
    """

    def __init__(self, prob: NonlinearSplineProblem, S, shift: float = 1e-8):
        import scipy.sparse as sp

        from ..numerics.linalg import SparseCholesky

        W = prob.energy
        fd = prob.free_dofs
        G = np.zeros((len(prob.terms), prob.n_nodes))
        for t, (a, k, b) in enumerate(prob.terms):
            G[t, a] -= 0.5
            G[t, b] -= 0.5
            G[t, k] += 1.0
        Gf = G[:, prob.free_nodes]
        _, self.U = np.linalg.eigh(Gf.T @ Gf)
        C = (Gf @ self.U) ** 2                   # (T, f) weight of term t in block i
        Hk: dict = {}
        for _, k, _ in prob.terms:
            if k not in Hk:
                H = W.hessian(S[k], S[k], "22")
                Hk[k] = sp.csc_matrix(H[fd][:, fd] if len(fd) < 3 * prob.n else H)
        nf = len(fd)
        I = sp.identity(nf, format="csc")
        self.factors = []
        for i in range(C.shape[1]):
            B = sum(C[t, i] * Hk[k] for t, (_, k, _) in enumerate(prob.terms) if C[t, i] > 0)
            d = float(np.abs(B.diagonal()).max())
            self.factors.append(SparseCholesky(prob.scale4 * (B + shift * d * I)))
        self.prob = prob
        self.f, self.nf = len(prob.free_nodes), nf

    def apply(self, v, S=None, Q=None) -> np.ndarray:
        """``≈ P⁺ v`` for ``v`` flat over free nodes × free DOFs; rigid motions of the nodes of
        ``S`` (or the bases ``Q`` of :meth:`NonlinearSplineProblem.rigid_bases`) removed."""
        Y = self.U.T @ np.asarray(v, dtype=np.float64).reshape(self.f, self.nf)
        X = self.U @ np.stack([c.solve(y) for c, y in zip(self.factors, Y)])
        if Q is None and S is not None:
            Q = self.prob.rigid_bases(S)
        return _project(X, Q).ravel()


class _SpaceTimePreconditioner:
    """The LΘA Gauss–Newton Hessian of the spline energy in space and time, factored whole.

    ``P = 4K³ Σ_t D_tᵀ Φ_t D_t`` with ``D_t = −½ J_a, J_k, −½ J_b`` (the descriptor
    Jacobians of the term's three shells at their current poses, restricted to the free
    nodes and DOFs) and ``Φ_t = 2 diag(w(s_k))`` the LΘA weights (paper eq. 10) at its
    centre shell: the Hessian of ``Σ_t ‖z(s_k) − ½(z(s_a) + z(s_b))‖²_w``, which
    approximates ``F^K`` to second order. Unlike :class:`_Preconditioner` (one elastic
    Hessian per term applied to all three of its shells) each shell's increment is measured
    in its own descriptors, so motions that rotate parts of the shells from frame to frame
    are priced right. One sparse Cholesky factorization of a matrix of
    ``(free frames × free DOFs)²`` (50k unknowns, 8.4M nonzeros, ~4 s on the 1000-vertex
    cactus; a solve ~0.08 s). Measured there at ``‖∇F‖ = 2e-2 ‖∇F₀‖``: preconditioned
    spectrum of the exact Hessian 1e-3–3.4 against 0.017–41 with :class:`_Preconditioner`,
    CG residual 0.02 after 60 iterations against 0.4. Relative shift ``1e-8`` for the rigid
    motions of unpinned shells (projected out by :meth:`apply`).
    """

    def __init__(self, prob: NonlinearSplineProblem, S, shift: float = 1e-8):
        import scipy.sparse as sp

        from ..numerics.linalg import SparseCholesky
        from .descriptors import lta_jacobian, lta_weights

        W = prob.energy
        fd, f = prob.free_dofs, len(prob.free_nodes)
        nf = len(fd)
        idx = np.full(prob.n_nodes, -1, dtype=np.int64)
        idx[prob.free_nodes] = np.arange(f)
        J = {k: lta_jacobian(S[k], W.T).tocsc()[:, fd].tocsr() for k in prob.free_nodes}
        rows = []
        for a, k, b in prob.terms:
            if idx[a] < 0 and idx[k] < 0 and idx[b] < 0:
                continue
            w = lta_weights(S[k], W.T, mu=max(W.mu, 1e-12), lam=max(W.lam, 1e-12),
                            eta=max(W.eta, 1e-12))
            sw = sp.diags(np.sqrt(2.0 * prob.scale4 * w))
            row = [None] * f
            for node, c in ((a, -0.5), (k, 1.0), (b, -0.5)):
                if idx[node] >= 0:
                    blk = c * (sw @ J[node])
                    row[idx[node]] = blk if row[idx[node]] is None else row[idx[node]] + blk
            rows.append([r if r is not None else sp.csr_matrix((len(w), nf)) for r in row])
        D = sp.bmat(rows, format="csr")
        H = (D.T @ D).tocsc()
        self._sigma = shift * float(np.abs(H.diagonal()).max())
        H = H + self._sigma * sp.identity(H.shape[0], format="csc")
        self.chol = SparseCholesky(H)
        self.prob, self.f = prob, f
        self._D = D

    def norm(self, v) -> float:
        """``‖v‖_P = √(vᵀ P v)`` of the factored ``P`` (shift included; ``v`` as in
        :meth:`apply`)."""
        v = np.asarray(v, dtype=np.float64)
        return float(np.sqrt(np.sum((self._D @ v) ** 2) + self._sigma * float(v @ v)))

    def apply(self, v, S=None, Q=None) -> np.ndarray:
        """``P⁻¹ v`` (``v`` flat over free nodes × free DOFs), rigid motions removed."""
        X = self.chol.solve(np.asarray(v, dtype=np.float64)).reshape(self.f, -1)
        if Q is None and S is not None:
            Q = self.prob.rigid_bases(S)
        return _project(X, Q).ravel()


def _project(X, Q):
    """Remove the rigid-motion components ``Q[i]`` from the rows ``X[i]`` (in place)."""
    if Q is not None:
        for i, q in enumerate(Q):
            if q.shape[1]:
                X[i] -= q @ (q.T @ X[i])
    return X


def _pcg(matvec, precond, b, Q, f, rtol, max_iter):
    """Preconditioned CG for ``H x = b`` on the complement of the rigid motions ``Q``,
    truncated at negative curvature (Steihaug). Returns ``(x, iterations, status)``."""
    def proj(v):
        return _project(v.reshape(f, -1), Q).ravel()

    r = proj(b.copy())
    x = np.zeros_like(r)
    bn = float(np.linalg.norm(r))
    if bn == 0.0:
        return x, 0, "zero right-hand side"
    z = precond(r)
    p = z.copy()
    rz = float(r @ z)
    for it in range(1, int(max_iter) + 1):
        Hp = proj(matvec(p))
        pHp = float(p @ Hp)
        if not pHp > 0:
            return (x if it > 1 else z), it, "negative curvature"
        alpha = rz / pHp
        x += alpha * p
        r -= alpha * Hp
        if np.linalg.norm(r) <= rtol * bn:
            return x, it, "converged"
        z = precond(r)
        rz_new = float(r @ z)
        p = z + (rz_new / rz) * p
        rz = rz_new
    return x, int(max_iter), "maximum iterations"


def _gauss_newton(prob, fun, x, F, g, S0, cb, max_iter, step_cap, cg_tol, cg_max_iter, stats,
                  hessian="auto"):
    """Gauss–Newton–CG on ``F^K``: steps from :class:`GaussNewtonModel` by preconditioned CG
    (:class:`_Preconditioner`), Armijo backtracking (monotone energy), midpoints warm-started
    from their first-order prediction. Returns ``(x, message)``."""
    P = _Preconditioner(prob, prob.nodes_of(x, S0))
    f = len(prob.free_nodes)
    for _ in range(int(max_iter)):
        S = prob.nodes_of(x, S0)
        Q = prob.rigid_bases(S)
        model = GaussNewtonModel(prob)
        exact = hessian == "exact" or stats["exact"]
        d, ncg, status = _pcg(model.exact_matvec if exact else model.matvec,
                              lambda v: P.apply(v, Q=Q), -g, Q, f, cg_tol, cg_max_iter)
        if not exact and hessian == "auto" and ncg:
            # the Gauss–Newton model drops the adjoint-weighted third derivatives; far from
            # the shells' midpoints (large η, large deformations) they dominate and the GN
            # step is far too long. One exact product checks the curvature along the step.
            cg, ce = float(d @ model.matvec(d)), float(d @ model.exact_matvec(d))
            if abs(ce - cg) > _GN_MISMATCH * abs(ce):
                stats["exact"] = exact = True
                stats["cg_iterations"].append(ncg)  # the discarded GN solve's work
                d, ncg, status = _pcg(model.exact_matvec, lambda v: P.apply(v, Q=Q), -g, Q,
                                      f, cg_tol, cg_max_iter)
        stats["hessian"].append("exact" if exact else "gauss-newton")
        stats["cg_iterations"].append(ncg)
        slope = float(g @ d)
        if not slope < 0:
            d = -P.apply(g, Q=Q)
            slope = float(g @ d)
            if not slope < 0:
                d, slope = -g, -float(g @ g)
        dM = model.midpoint_change(d)
        M = prob.last["M"]
        alpha, ok = min(1.0, step_cap / max(float(np.abs(d).max()), 1e-300)), False
        for ls in range(30):
            xn = x + alpha * d
            Fn, gn = fun(xn, warm=M + alpha * dM, trial=True)
            if np.isfinite(Fn) and Fn <= F + 1e-4 * alpha * slope:
                ok = True
                break
            alpha *= 0.5
        stats["step_lengths"].append(alpha)
        if not ok:
            return x, "not converged: line search failed (energy does not decrease)"
        x, F, g = xn, Fn, gn
        try:
            cb(_Iterate(x))
        except StopIteration:
            return x, "converged"
    return x, "not converged: maximum number of iterations reached"


def _steihaug(matvec, precond, b, Q, f, rtol, max_iter, radius, truncate=0.0):
    """Steihaug–Toint CG for the trust-region model ``m(d) = −bᵀd + ½ dᵀHd`` with
    ``‖d‖_P <= radius`` in the norm of the preconditioner ``P`` (``precond`` applies
    ``P⁻¹``), on the complement of the rigid motions ``Q``. Stops at the boundary (also along
    negative curvature), at relative residual ``rtol`` or, with ``truncate > 0``, when the
    model decrease stalls (:data:`_NASH_SOFER`). ``‖d‖_P`` is carried by the
    recurrences of Conn, Gould & Toint (*Trust-Region Methods*, 2000, §7.5.1), no products
    with ``P``. Returns ``(d, iterations, status, model decrease −m(d) >= 0, ‖d‖_P)``."""
    def proj(v):
        return _project(v.reshape(f, -1), Q).ravel()

    r = proj(b.copy())
    d = np.zeros_like(r)
    Hd = np.zeros_like(r)
    if float(np.linalg.norm(r)) == 0.0:
        return d, 0, "zero right-hand side", 0.0, 0.0
    bn = float(np.linalg.norm(r))
    z = precond(r)
    p = z.copy()
    rz = float(r @ z)
    dMd, dMp, pMp = 0.0, 0.0, rz

    it = 0
    for it in range(1, int(max_iter) + 1):
        Hp = proj(matvec(p))
        pHp = float(p @ Hp)
        alpha = rz / pHp if pHp > 0 else np.inf
        if not pHp > 0 or dMd + 2 * alpha * dMp + alpha * alpha * pMp >= radius * radius:
            # to the boundary along p: ‖d + τp‖_P = radius
            tau = (-dMp + np.sqrt(max(dMp * dMp + pMp * (radius * radius - dMd), 0.0))) / pMp
            d = d + tau * p
            Hd = Hd + tau * Hp
            dec = float(b @ d) - 0.5 * float(d @ Hd)
            return d, it, "negative curvature" if not pHp > 0 else "boundary", dec, radius
        q_old = float(b @ d) - 0.5 * float(d @ Hd) if truncate else 0.0
        d = d + alpha * p
        Hd = Hd + alpha * Hp
        dMd += 2 * alpha * dMp + alpha * alpha * pMp
        r = r - alpha * Hp
        if np.linalg.norm(r) <= rtol * bn:
            break
        if truncate:
            q_new = float(b @ d) - 0.5 * float(d @ Hd)
            if it > 5 and it * (q_new - q_old) < truncate * q_new:
                break
        z = precond(r)
        rz_new = float(r @ z)
        beta = rz_new / rz
        rz = rz_new
        dMp = beta * (dMp + alpha * pMp)
        pMp = rz + beta * beta * pMp
        p = z + beta * p
    status = "converged" if np.linalg.norm(r) <= rtol * bn else "maximum iterations"
    dec = float(b @ d) - 0.5 * float(d @ Hd)
    return d, it, status, dec, float(np.sqrt(max(dMd, 0.0)))


class _Retraction:
    """Curved trial steps for the free shells: the descriptor change ``J d`` of each shell
    ``s`` is applied in LΘA space and the shell reconstructed,
    ``R(s, d) = argmin_x ‖z(x) − (z(s) + J(s) d)‖²_w`` (Gauss–Newton from ``s + d``, LΘA
    weights ``w`` of the first keyframe, pinned vertices kept).

    ``R(s, 0) = s`` and ``dR/dd = I`` modulo rigid motions, so it is a first-order retraction
    and the trust-region test along it is valid; unlike ``s + d`` it bends thin parts
    (``η`` ≪ ``μ``) without the second-order stretch of a linearised rotation, which the
    spline energy (scaled by ``4K³``) punishes hardest. Measured on the coarse cactus
    (1000 vertices, ``K = 20``): along one Newton direction ``F`` at ¼ step 7.83 on the
    straight line and 2.00 retracted (1.97 at the start).
    """

    def __init__(self, prob: NonlinearSplineProblem, S0):
        from .descriptors import lta_weights
        from .reconstruct import GaussNewton

        W = prob.energy
        self.prob = prob
        self.T = W.T
        self.w = lta_weights(S0[prob.frames[0]], W.T, mu=max(W.mu, 1e-12),
                             lam=max(W.lam, 1e-12), eta=max(W.eta, 1e-12))
        self.gn = GaussNewton(W.T, pinned=prob.pinned, max_iter=20)

    def __call__(self, S, D) -> np.ndarray:
        """Node poses ``R(S[k], D[k])`` for the free nodes (others unchanged)."""
        from .descriptors import lta_jacobian

        out = S + D
        for k in self.prob.free_nodes:
            self.prob.check_time()
            J, z = lta_jacobian(S[k], self.T, return_values=True)
            r = self.gn.solve(z + J @ D[k].ravel(), self.w, S[k] + D[k])
            if np.all(np.isfinite(r.V)):
                out[k] = r.V
        return out


def _trust_region(prob, fun, x, F, g, S0, cb, max_iter, cg_tol, cg_max_iter, stats,
                  hessian="auto", retraction=None, final_phase=True, gtol=0.0):
    """Trust-region Newton–CG on ``F^K`` (Steihaug–Toint CG in the norm of
    :class:`_Preconditioner`), trial points along :class:`_Retraction` when given.

    The Hessian model is :class:`GaussNewtonModel` (switching to exact products like the
    line-search variant); the radius shrinks to a quarter of the step when the actual
    decrease is below a quarter of the model's (or a midpoint solve fails) and doubles when
    a boundary step earns more than three quarters. A rejected trial writes the other set of
    kept factorizations, so the model survives it. ``gtol`` (relative to the first gradient)
    floors the CG forcing term (:data:`_GTOL_MARGIN`). Returns ``(x, message)``."""
    f = len(prob.free_nodes)
    zero = np.zeros_like(S0)
    cap = _step_cap(prob, S0, 2.0)

    def first_radius(P, Q):
        # the preconditioned gradient step scaled to two mean edge lengths, in P's norm
        z0 = P.apply(-g, Q=Q)
        scale = cap / max(float(np.abs(z0).max()), 1e-300) if np.isfinite(cap) else 1.0
        return scale * float(np.sqrt(max(float(-g @ z0), 0.0)))

    P = _Preconditioner(prob, prob.nodes_of(x, S0))
    radius = first_radius(P, prob.rigid_bases(prob.nodes_of(x, S0)))
    g0n = float(np.linalg.norm(g))
    current = 0
    final = False
    last = None  # (last accepted step, radius / its length in the current norm)
    for _ in range(int(max_iter)):
        S = prob.nodes_of(x, S0)
        Q = prob.rigid_bases(S)
        exact = hessian == "exact" or stats["exact"]
        if final_phase and exact and not final and hasattr(prob.energy, "T") and \
                float(np.linalg.norm(g)) <= _FINAL_PHASE * g0n:
            # the final Newton phase: space–time preconditioner, accurate products, CG
            # run to its forcing term (no truncation), midpoints solved tighter so that F
            # resolves the small decreases of the last steps; F and g re-evaluated with them
            final = True
            stats["final_phase"] = len(stats["cg_iterations"])
            prob.midpoint_tol = min(prob.midpoint_tol, _FINAL_MIDPOINT_TOL)
            F, g = fun(x, slot_set=current)
            P = _SpaceTimePreconditioner(prob, S)
            radius = first_radius(P, Q)
            if last is not None:
                # keep the trust the first phase had earned: its radius relative to its last
                # step, measured in the new norm (the gradient-step guess alone can be far
                # smaller and cost several boundary steps of radius doubling)
                radius = max(radius, last[1] * P.norm(last[0]))
        model = GaussNewtonModel(prob)
        ncg_total = 0
        accepted = False
        # inexact Newton (Eisenstat–Walker forcing): loose far away, tighter as ‖g‖ drops
        gnorm = float(np.linalg.norm(g))
        rtol = min(cg_tol if not final else min(cg_tol, _FINAL_CG_TOL),
                   max(np.sqrt(gnorm / g0n), 1e-3))
        # ... but no tighter than what meets gtol (the next gradient ≈ the CG residual)
        rtol = max(rtol, min(_GTOL_MARGIN * gtol * g0n / max(gnorm, 1e-300), 0.5))
        for _trial in range(30):
            matvec = model.accurate_matvec if final else \
                model.exact_matvec if exact else model.matvec
            # truncate only the expensive exact-product solves of the first phase (on the
            # ellipsoids, which stay with Gauss–Newton products, truncation cost 35 % more
            # time: 10.5 -> 14.3 s)
            d, ncg, status, dec, dnorm = _steihaug(matvec, lambda v: P.apply(v, Q=Q), -g, Q, f,
                                                   rtol, cg_max_iter, radius,
                                                   truncate=_NASH_SOFER if exact and not final
                                                   else 0.0)
            ncg_total += ncg
            if not exact and hessian == "auto" and ncg and float(d @ d) > 0:
                cg_, ce = float(d @ model.matvec(d)), float(d @ model.exact_matvec(d))
                if abs(ce - cg_) > _GN_MISMATCH * abs(ce):
                    stats["exact"] = exact = True
                    continue  # solve again with exact products
            if not dec > 0:  # no model decrease (round-off): the gradient step
                d = -P.apply(g, Q=Q)
                dec = -float(g @ d)
                dnorm = float(np.sqrt(max(dec, 0.0)))  # ‖P⁻¹g‖_P² = gᵀP⁻¹g
            D = prob.nodes_of(d, zero)
            Sn = retraction(S, D) if retraction is not None else S + D
            xn = prob.x_of(Sn)
            warm = model.M + model.midpoint_change(d)
            Fn, gn = fun(xn, warm=warm, trial=True, slot_set=1 - current)
            rho = (F - Fn) / dec if np.isfinite(Fn) and dec > 0 else -np.inf
            noise = 1e-13 * max(abs(F), 1.0)
            if np.isfinite(Fn) and dec <= 10 * noise and Fn <= F + noise:
                rho = 1.0  # both decreases below the energy's last digits: the model holds
            if rho < 0.25:
                radius = 0.25 * min(radius, dnorm)
            elif rho > 0.75 and dnorm >= 0.99 * radius:
                radius = 2.0 * radius
            if rho > 0.01:
                accepted = True
                break
        stats["hessian"].append("exact" if exact else "gauss-newton")
        stats["cg_iterations"].append(ncg_total)
        if not accepted:
            return x, "not converged: trust region collapsed (no decrease of the energy)"
        stats["step_lengths"].append(float(np.abs(Sn - S).max()) / max(cap / 2, 1e-300)
                                     if np.isfinite(cap) else float(np.abs(d).max()))
        if dnorm > 0:
            last = (d, radius / dnorm)
        current = 1 - current
        x, F, g = xn, Fn, gn
        try:
            cb(_Iterate(x))
        except StopIteration:
            return x, "converged"
    return x, "not converged: maximum number of iterations reached"


def _lbfgs(prob, fun, x, F, g, S0, precond, cb, max_iter, memory):
    """Preconditioned L-BFGS with Armijo backtracking; returns ``(x, message)``."""
    from collections import deque

    hist = deque(maxlen=int(memory))
    gamma = 1.0
    step_cap = _step_cap(prob, S0, 0.5)

    def H0(v, x):
        if precond is None:
            return gamma * v
        return gamma * precond.apply(v, prob.nodes_of(x, S0))

    for _ in range(int(max_iter)):
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
        # first trial: the full step, capped at half a mean edge length per coordinate
        alpha, ok = min(1.0, step_cap / max(float(np.abs(d).max()), 1e-300)), False
        accepted_midpoints = None if prob.midpoints is None else prob.midpoints.copy()
        for _ in range(30):
            xn = x + alpha * d
            # warm starts from the accepted iterate, never from a rejected trial
            prob.midpoints = None if accepted_midpoints is None else accepted_midpoints.copy()
            Fn, gn = fun(xn)
            if np.isfinite(Fn) and Fn <= F + 1e-4 * alpha * slope:
                ok = True
                break
            alpha *= 0.5
        if not ok:
            return x, "not converged: line search failed (energy does not decrease)"
        s_, y_ = xn - x, gn - g
        sy = float(s_ @ y_)
        if sy > 1e-12 * np.linalg.norm(s_) * np.linalg.norm(y_):
            hist.append((s_, y_, 1.0 / sy))
            if precond is None:
                gamma = sy / float(y_ @ y_)
            else:
                gamma = 1.0
        x, F, g = xn, Fn, gn
        try:
            cb(_Iterate(x))
        except StopIteration:
            return x, "converged"
    return x, "not converged: maximum number of iterations reached"


def _step_cap(prob, S0, factor):
    """``factor`` mean edge lengths of the first keyframe (cap of a trial step's largest
    coordinate change), infinite for energies without a mesh."""
    from .descriptors import edge_lengths

    if not hasattr(prob.energy, "T"):
        return np.inf
    return factor * float(np.mean(edge_lengths(S0[prob.frames[0]], prob.energy.T)))


@dataclass
class _Iterate:
    x: np.ndarray


def _finish(prob, S, V0, Vkey, energies, norms, nit, success, message, t0, periodic):
    K = prob.K
    V = np.zeros((K + 1, prob.n, 3))
    V[:prob.n_nodes] = S
    if periodic:
        V[K] = V[0]
    if prob.pinned is None and getattr(prob.energy, "rigid_invariant", False):
        for k in prob.free_nodes:
            V[k] = rigid_placement(V[k], V0[k])
    V[prob.frames] = Vkey
    if periodic:
        V[K] = Vkey[0]
    if not success:
        warnings.warn(f"nonlinear_spline: {message}", RuntimeWarning, stacklevel=3)
    return NonlinearSplineResult(V=V, frames=prob.frames,
                                 energy=float(energies[-1]) if energies else float("nan"),
                                 energies=[float(e) for e in energies],
                                 grad_norms=[float(g) for g in norms], nit=int(nit),
                                 nfev=prob.nfev, success=bool(success), message=message,
                                 midpoints=prob.midpoints, time_s=time.perf_counter() - t0)

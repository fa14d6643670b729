"""Nonlinear time-discrete splines in shell space (paper §5–6 and appendix).

Minimise the time-discrete elastic energy (eq. 7)::

    F^K[s_0, …, s_K] = 4K³ Σ_k W[s_k, s̃_k],
    s̃_k = argmin_s W[s_{k-1}, s] + W[s, s_{k+1}]          (geodesic midpoints, eq. 8)

over the free shells (all frames that are not keyframes), ``k = 1..K-1`` (natural, Hermite)
or cyclically ``k = 0..K-1`` (periodic, frame ``K`` is frame ``0``). Hermite conditions are
keyframes at frames ``0, 1, K-1, K`` (paper §8).

Gradient (adjoint method, eqs. 13–17): for every term ``k`` solve the midpoint problem by
Newton (:class:`~shellspline.geodesic.PathSolver` with one inner shell, warm-started from the
previous evaluation), then one linear system with the midpoint Hessian
``A_k = W,22[s_{k-1}, s̃_k] + W,11[s̃_k, s_{k+1}]``::

    A_k p_k = −W,2[s_k, s̃_k]ᵀ                                         (16)
    ∂F/∂s_k     += 4K³ W,1[s_k, s̃_k]
    ∂F/∂s_{k-1} += 4K³ W,12[s_{k-1}, s̃_k] p_k
    ∂F/∂s_{k+1} += 4K³ W,21[s̃_k, s_{k+1}] p_k                            (17)

(``W,12`` has rows indexed by the first argument.) The outer problem is solved with a
preconditioned L-BFGS (Armijo backtracking, see :func:`nonlinear_spline`) and stopped when the
gradient norm has dropped by ``gtol`` relative to the initial one.

Rigid motions: ``F^K`` is invariant under a rigid motion of every single shell (``W`` is, in
both arguments, and so is the midpoint up to a rigid motion), so the problem is solved modulo
rigid motions: the gradient is orthogonal to them, L-BFGS therefore hardly moves along them,
and the midpoint Newton solver projects them out (see :mod:`shellspline.geodesic`). At the end
every free frame is rigidly placed onto its initial pose (Kabsch), which makes the output
canonical. With ``pinned`` vertices these stay fixed in every shell and midpoint instead (no
placement).
"""
from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field

import numpy as np

from ._errors import ShellsplineError
from .geodesic import PathSolver, _checked_pinned, _make_energy, _rigid_modes
from .lta_spline import _canonical_bc, _checked_frames, _checked_K
from .reconstruct import rigid_placement
from .topology import Topology

__all__ = ["NonlinearSplineProblem", "NonlinearSplineResult", "nonlinear_spline"]


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
        ``F^K`` at the initial point and after every outer iteration (non-increasing).
    grad_norms : list of float
        Euclidean norm of the gradient at the same points.
    nit : int
        Outer iterations.
    nfev : int
        Energy/gradient evaluations (each solves all midpoint problems).
    success : bool
        The gradient norm dropped below ``gtol`` times the initial one.
    message : str
    midpoints : (T,n,3) float64 array
        Geodesic midpoints ``s̃_k`` of the energy terms at the solution.
    time_s : float
        Wall time of the optimisation.
    """

    V: np.ndarray
    frames: np.ndarray
    energy: float
    energies: list = field(default_factory=list)
    grad_norms: list = field(default_factory=list)
    nit: int = 0
    nfev: int = 0
    success: bool = False
    message: str = ""
    midpoints: np.ndarray | None = None
    time_s: float = 0.0


class NonlinearSplineProblem:
    """The constrained spline energy ``F^K`` and its adjoint gradient on a fixed time grid.

    Parameters
    ----------
    energy : DiscreteShells or EuclideanEnergy
        The deformation energy ``W``.
    frames : (J,) int array
        Keyframe frames (validated as in :class:`~shellspline.lta_spline.LTASpline`).
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
        self.bc = _canonical_bc(bc)
        self.K = _checked_K(K)
        self.frames = _checked_frames(frames, self.K, self.bc)
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
        self.pinned = _checked_pinned(pinned, n)
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
        self.nfev = 0
        self.midpoint_iterations = 0
        self.midpoint_failures = 0

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
            res = self.solver.solve(S[a], S[b], M[t][None], tol=self.midpoint_tol)
            self.midpoint_iterations += res.nit
            self.midpoint_failures += not res.success
            M[t] = res.V[1]
        return M

    def _warm(self, S):
        if self.midpoints is None:
            return 0.5 * (S[self.terms[:, 0]] + S[self.terms[:, 2]])
        return self.midpoints.copy()

    def evaluate(self, S, *, gradient: bool = True):
        """``F^K`` and its gradient for node poses ``S (n_nodes,n,3)``.

        Returns
        -------
        F : float
        G : (n_nodes,n,3) float64 array
            ``∂F/∂s_k`` (adjoint method, eqs. 13–17); zero on keyframes and pinned vertices.
            Only if ``gradient``.
        """
        S = np.asarray(S, dtype=np.float64)
        W = self.energy
        M = self._warm(S)
        F = 0.0
        G = np.zeros((self.n_nodes, 3 * self.n))
        for t, (a, k, b) in enumerate(self.terms):
            res = self.solver.solve(S[a], S[b], M[t][None], tol=self.midpoint_tol)
            self.midpoint_iterations += res.nit
            self.midpoint_failures += not res.success
            m = res.V[1]
            # one more Newton step with the Hessian that the adjoint needs anyway: F is not
            # stationary in the midpoint, so its round-off level follows the midpoint's error
            ctx = self.solver.factor_at(S[a], m[None], S[b])
            gm = self.solver.gradient(S[a], m[None], S[b])
            m = m + self.solver.solve_factored(ctx, -gm)[0].reshape(m.shape)
            M[t] = m
            F += W.energy(S[k], m)
            if not gradient:
                continue
            G[k] += W.gradient(S[k], m, 0)
            rhs = -W.gradient(S[k], m, 1)
            p = self.solver.solve_factored(ctx, rhs[None])[0]
            G[a] += W.mixed_product(S[a], m, p, "12")
            G[b] += W.mixed_product(m, S[b], p, "21")
        self.midpoints = M
        self.nfev += 1
        F *= self.scale4
        if not gradient:
            return F
        G *= self.scale4
        keep = np.zeros(self.n_nodes, dtype=bool)
        keep[self.free_nodes] = True
        G[~keep] = 0.0
        if self.pinned is not None:
            G[:, (3 * self.pinned[:, None] + np.arange(3)).ravel()] = 0.0
        return F, G.reshape(self.n_nodes, self.n, 3)


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
                     midpoint_tol: float = 1e-10, memory: int = 20, backend: str = "auto",
                     precondition: bool = False, max_time_s: float | None = None,
                     callback=None) -> NonlinearSplineResult:
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
        Maximum number of L-BFGS iterations.
    gtol : float
        Stop when ``‖∇F‖ <= gtol ‖∇F(init)‖``.
    midpoint_tol : float
        Tolerance of the midpoint Newton solves (relative gradient max-norm).
    memory : int
        L-BFGS memory.
    max_time_s : float, optional
        Stop (unconverged, with a warning) after this many seconds of optimisation.
    precondition : bool
        Use the (experimental) metric preconditioner of the Notes; default plain L-BFGS
        with the usual ``sᵀy/yᵀy`` scaling, which was faster in our measurements.
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
    Outer optimiser: L-BFGS (two-loop recursion) with an Armijo backtracking line search
    (the energy is non-increasing) and curvature-checked updates. Its initial inverse Hessian
    is the inverse of the quadratic model of ``F^K`` near a path of similar shells,
    ``4K³ (GᵀG)_ff ⊗ W,22[s̄, s̄]``, where ``G`` is the (terms × frames) midpoint-residual
    matrix (rows ``−½, 1, −½``), ``ff`` its free frames and ``s̄`` the mean initial free shell.
    It is applied by diagonalising the small ``(GᵀG)_ff`` and factoring one sparse matrix per
    free frame once; rigid-motion components of each frame are projected out of the step.

    Examples
    --------
    >>> import numpy as np, trimesh
    >>> from shellspline.topology import topology
    >>> m = trimesh.creation.icosphere(subdivisions=1)
    >>> V, T = np.asarray(m.vertices), topology(m.faces)
    >>> Vkey = np.stack([V * [1.3, 1, 1], V, V * [1, 1.3, 1]])
    >>> res = nonlinear_spline(Vkey, [0, 2, 4], 4, T, eta=0.1, gtol=1e-4)
    >>> res.success, res.V.shape
    (True, (5, 42, 3))
    """
    W = _make_energy(T, energy, mu, lam, eta)
    Vkey = _checked_keyframes(Vkey, W.n_vertices)
    prob = NonlinearSplineProblem(W, frames, K, bc, pinned=pinned, midpoint_tol=midpoint_tol,
                                  backend=backend)
    K, frames = prob.K, prob.frames
    if len(frames) != len(Vkey):
        raise ShellsplineError(f"`frames` must have one entry per keyframe ({len(Vkey)}), "
                               f"got {len(frames)}")
    if not (isinstance(gtol, (int, float)) and 0 < gtol < 1):
        raise ShellsplineError(f"`gtol` must be a number in (0, 1), got {gtol!r}")
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
    t0 = time.perf_counter()
    energies, norms = [], []
    last = {}

    def fun(x):
        S = prob.nodes_of(x, S0)
        F, G = prob.evaluate(S)
        g = prob.x_of(G)
        last["x"], last["F"], last["g"] = x.copy(), F, g
        return F, g

    if prob.n_variables == 0:
        F = prob.evaluate(S0, gradient=False)
        return _finish(prob, S0, V0, Vkey, [F], [0.0], 0, True, "no free frames", t0, periodic)

    x0 = prob.x_of(S0)
    F0, g0 = fun(x0)
    g0n = float(np.linalg.norm(g0))
    energies.append(F0)
    norms.append(g0n)
    if callback is not None:
        callback(0, F0, g0n)
    state = {"nit": 0, "done": g0n == 0.0}

    def cb(intermediate_result):
        x = intermediate_result.x
        if "x" in last and np.array_equal(last["x"], x):
            F, g = last["F"], last["g"]
        else:
            F, g = fun(x)
        state["nit"] += 1
        gn = float(np.linalg.norm(g))
        energies.append(F)
        norms.append(gn)
        if callback is not None:
            callback(state["nit"], F, gn)
        if gn <= gtol * g0n:
            state["done"] = True
            raise StopIteration
        if max_time_s is not None and time.perf_counter() - t0 > max_time_s:
            state["timeout"] = True
            raise StopIteration

    x = x0
    if state["done"]:
        message = "converged: gradient norm reduced by gtol"
    else:
        precond = _Preconditioner(prob, S0) if precondition else None
        x, message = _lbfgs(prob, fun, x0, F0, g0, S0, precond, cb, max_iter, memory)
        if state["done"]:
            message = "converged: gradient norm reduced by gtol"
        elif state.get("timeout"):
            message = f"not converged: time limit of {max_time_s} s reached"
    S = prob.nodes_of(x, S0)
    if "x" not in last or not np.array_equal(last["x"], x):
        fun(x)
    return _finish(prob, S, V0, Vkey, energies, norms, state["nit"], state["done"], message, t0,
                   periodic)


class _Preconditioner:
    """``(4K³ (GᵀG)_ff ⊗ H̄ + δ I)⁻¹`` applied frame-wise via the eigenvectors of
    ``(GᵀG)_ff`` (see :func:`nonlinear_spline`, Notes)."""

    def __init__(self, prob: NonlinearSplineProblem, S0):
        from ._linalg import SparseCholesky
        import scipy.sparse as sp

        G = np.zeros((len(prob.terms), prob.n_nodes))
        for t, (a, k, b) in enumerate(prob.terms):
            G[t, a] -= 0.5
            G[t, b] -= 0.5
            G[t, k] += 1.0
        M = (G.T @ G)[np.ix_(prob.free_nodes, prob.free_nodes)]
        lam, self.U = np.linalg.eigh(M)
        W = prob.energy
        sbar = S0[prob.free_nodes].mean(axis=0)
        H = W.hessian(sbar, sbar, "22")
        fd = prob.free_dofs
        H = sp.csc_matrix(H[fd][:, fd])
        diag = float(np.abs(H.diagonal()).max())
        I = sp.identity(H.shape[0], format="csc")
        self.factors = [SparseCholesky(prob.scale4 * max(l, 1e-12) * H
                                       + prob.scale4 * max(l, 1e-12) * 1e-8 * diag * I)
                        for l in lam]
        self.prob = prob

    def apply(self, g, S):
        prob = self.prob
        f = len(prob.free_nodes)
        Y = self.U.T @ g.reshape(f, -1)
        Z = np.stack([c.solve(y) for c, y in zip(self.factors, Y)])
        X = self.U @ Z
        if getattr(prob.energy, "rigid_invariant", False):
            pd = np.setdiff1d(np.arange(3 * prob.n), prob.free_dofs)
            for i, k in enumerate(prob.free_nodes):
                Q = _rigid_modes(S[k], prob.free_dofs, pd)
                if Q.shape[1]:
                    X[i] -= Q @ (Q.T @ X[i])
        return X.ravel()


def _lbfgs(prob, fun, x, F, g, S0, precond, cb, max_iter, memory):
    """Preconditioned L-BFGS with Armijo backtracking; returns ``(x, message)``."""
    from collections import deque

    hist = deque(maxlen=int(memory))
    gamma = 1.0
    from .descriptors import edge_lengths

    step_cap = 0.5 * float(np.mean(edge_lengths(S0[prob.frames[0]], prob.energy.T))) \
        if hasattr(prob.energy, "T") else np.inf

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
    return NonlinearSplineResult(V=V, frames=prob.frames, energy=float(energies[-1]),
                                 energies=[float(e) for e in energies],
                                 grad_norms=[float(g) for g in norms], nit=int(nit),
                                 nfev=prob.nfev, success=bool(success), message=message,
                                 midpoints=prob.midpoints, time_s=time.perf_counter() - t0)

"""Discrete geodesics in shell space (paper §3) and piecewise geodesic interpolation.

A discrete geodesic between shells ``s_A`` and ``s_B`` minimises the time-discrete path energy
(paper eq. 3)::

    E^K[s_0, …, s_K] = K Σ_{k=1}^{K} W[s_{k-1}, s_k],   s_0 = s_A, s_K = s_B fixed,

over the inner shells ``s_1 … s_{K-1}``. :class:`PathSolver` is the precompute object (the
block-tridiagonal sparsity pattern of the Hessian over all inner shells, its symbolic
factorization); it runs projected Newton with an Armijo line search. It also solves the
geodesic-midpoint problems of the nonlinear spline (``K = 2``, paper eq. 8).

Projected Newton (Teran et al. 2005): away from the minimum the Hessian is indefinite
(compressed and strongly bent shells), and a damped Newton step needs a shift of up to 1e-2
of its largest entry, found by ~3 factorizations per step, and then crawls. The Newton matrix
is instead the sum of the element Hessians, each projected onto the positive semi-definite
cone (:meth:`~shellspline.shells.energy.DiscreteShells.chain_hessian_data`): positive
semi-definite by construction, one factorization per step. Once the true Hessian factors with
a shift of at most 1e-6 of its largest entry it is used instead (quadratic convergence near
the minimum). Adjoint solves (:meth:`PathSolver.factor_at`) always use the true Hessian.

Rigid motions: ``W`` is invariant under a rigid motion of each shell, so the Hessian has six
zero eigenvalues per inner shell. Without pinned vertices they are handled by a tiny
Levenberg–Marquardt shift ``ε I`` (``ε = 1e-10`` times the largest diagonal entry) plus the
projection of every Newton step onto the orthogonal complement of the infinitesimal rigid
motions of each shell: the gradient is orthogonal to them, so the iterates keep their centroid
exactly and their orientation up to second order (they stay rigidly aligned with the initial
path, the linear blend). Pinned vertices are held fixed; rigid motions they leave free (one or
two pinned vertices) are projected out in the same way.
"""
from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field

import numpy as np

from ..errors import ShellsplineError
from ..numerics.linalg import SparseCholesky
from ..numerics.linesearch import backtracking
from ..numerics.result import SolverResult
from ..timeline import canonical_bc, checked_frames, checked_K
from .energy import (DiscreteShells, HessianPattern, checked_pose, checked_poses,
                     checked_projection)
from ..mesh.pinned import canonical_pinned
from ..mesh.rigid import rigid_modes
from ..mesh.topology import Topology

__all__ = ["PathSolver", "GeodesicResult", "discrete_geodesic", "geodesic_interpolation",
           "GeodesicInterpolationResult", "lerp_inner_shells", "make_energy"]

#: A Newton step whose predicted decrease ``−gᵀd`` is below this fraction of the energy is
#: accepted when it lowers the gradient's max-norm instead of by the Armijo test, which cannot
#: resolve it: on the 1000-vertex cactus (η = 1e-3) midpoint solves at tolerance 1e-13 stalled
#: at a gradient of 5e-9 and failed the trust region's trial steps.
_ROUNDOFF_DECREASE = 1e-11
#: Projected Newton tries the true Hessian again only once the gradient's max-norm fell below
#: this fraction of its value when the true Hessian last failed to factor (was indefinite).
_EXACT_RETRY = 0.1
#: Relative shifts with which projected Newton tries the true Hessian (starting one below
#: the last one that worked); the rotations of each shell have curvature ~ |g| (not zero),
#: so away from the minimum the true Hessian needs a small shift even where it is
#: essentially convex.
_EXACT_TAUS = (0.0, 1e-8, 1e-6)
#: Relative Levenberg–Marquardt shift that makes the rigid-motion kernel invertible.
_EPS_SHIFT = 1e-10
#: Relative Levenberg–Marquardt shifts tried in turn (ratio ~3: a ladder of 100× steps
#: over-damps the indefinite Hessians of compressed paths by up to 100×, and Newton then
#: crawls like gradient descent; see :meth:`PathSolver._damped_factor`).
_TAUS = (0.0, 1e-8) + tuple(float(f"{10.0 ** (e / 2):.0e}") for e in range(-15, 5))


@dataclass(kw_only=True)
class GeodesicResult(SolverResult):
    """What :meth:`PathSolver.solve` and :func:`discrete_geodesic` return (a
    :class:`~shellspline.numerics.result.SolverResult`).

    Attributes
    ----------
    V : (K+1,n,3) float64 array
        The path including the end shells.
    status : {"converged", "stalled", "limit", "failed"}
        ``"limit"``: the iteration limit or the deadline; ``"stalled"``: the line search
        failed. ``success`` is ``status == "converged"``.
    iterations : int
        Newton iterations (also ``nit``).
    energies : (it+1,) float64 array
        Path energy ``E^K = K Σ_k W[s_{k-1}, s_k]`` (eq. 3) at the start and after every
        Newton iteration; ``energy`` is the last one (at ``V``).
    grad_norms : (it+1,) float64 array
        Max-norm of the gradient of ``Σ_k W[s_{k-1}, s_k]`` w.r.t. the inner shells at the
        same points.
    message : str
    factorizations : int
        Numeric factorizations of the Newton matrix (damping retries included).
    """

    V: np.ndarray
    factorizations: int = 0


class PathSolver:
    """Newton solver for discrete geodesics with a fixed number of inner shells.

    Parameters
    ----------
    energy : DiscreteShells or EuclideanEnergy
        The deformation energy ``W`` (anything with ``energy``, ``gradient``,
        ``hessian_data``, ``pattern``, ``rigid_invariant``, ``n_vertices``, ``scale``).
    n_inner : int
        Number of inner shells ``K - 1 >= 1``.
    pinned : (p,) int array, optional
        Vertices held fixed in every inner shell (at their initial positions).
    backend : {"auto", "cholmod", "splu"}
        Sparse factorization backend (:class:`~shellspline.numerics.linalg.SparseCholesky`).

    Notes
    -----
    The Hessian of ``Σ_k W[s_{k-1}, s_k]`` w.r.t. the inner shells is block tridiagonal:
    diagonal blocks ``W,22[s_{k-1}, s_k] + W,11[s_k, s_{k+1}]``, off-diagonal blocks
    ``W,12[s_k, s_{k+1}]`` (rows ``s_k``) and their transposes. It is assembled on a fixed
    pattern and factored with one symbolic analysis for all iterations (and all solves).
    """

    def __init__(self, energy, n_inner: int, *, pinned=None, backend: str = "auto"):
        self.energy = energy
        self.n_inner = m = int(n_inner)
        if m < 1:
            raise ShellsplineError(f"`n_inner` must be >= 1, got {n_inner!r}")
        n = energy.n_vertices
        self.n = n
        N1 = 3 * n
        pinned = canonical_pinned(pinned, n)
        self.pinned = pinned
        self.pinned_dofs = (3 * pinned[:, None] + np.arange(3)).ravel() if pinned is not None \
            else np.zeros(0, dtype=np.int64)
        mask = np.ones(N1, dtype=bool)
        mask[self.pinned_dofs] = False
        self.free = np.flatnonzero(mask)
        nf = len(self.free)
        self.nf = nf
        red = np.full(N1, -1, dtype=np.int64)
        red[self.free] = np.arange(nf)
        P = energy.pattern
        pr = np.repeat(np.arange(N1), np.diff(P.indptr))
        pc = P.indices.astype(np.int64)
        keep = (red[pr] >= 0) & (red[pc] >= 0)
        rr, cc = red[pr], red[pc]
        # blocks: diagonal k (m of them), upper (k, k+1), lower (k+1, k)
        rows, cols = [], []
        for k in range(m):
            rows.append(k * nf + rr[keep]), cols.append(k * nf + cc[keep])
        for k in range(m - 1):
            rows.append(k * nf + rr[keep]), cols.append((k + 1) * nf + cc[keep])
            rows.append((k + 1) * nf + rr[keep]), cols.append(k * nf + cc[keep])
        self.N = m * nf
        self.gpattern = HessianPattern(np.concatenate(rows), np.concatenate(cols), self.N)
        self._pos = [self.gpattern.positions(r, c) for r, c in zip(rows, cols)]
        self._keep = keep
        # transpose permutation of the (symmetric) single-shell pattern
        self._permT = P.positions(pc, pr)
        self._lower = self.gpattern.lower()
        indptr, indices, _ = self._lower
        self._diag_mask = indices == np.repeat(np.arange(self.N), np.diff(indptr))
        self._chol = None
        self._slots: dict = {}
        self._tau_hint = 0.0
        self._exact_hint = 0.0
        #: numeric factorizations so far (shifted retries included)
        self.factorizations = 0
        self.backend = backend
        if hasattr(energy, "cache_size"):
            energy.cache_size = max(energy.cache_size, m + 4)

    # -- evaluation ----------------------------------------------------------------------
    def path_energy(self, A, X, B) -> float:
        """``Σ_{k=1}^{K} W[s_{k-1}, s_k]`` for inner shells ``X (K-1,n,3)`` (no factor K)."""
        S = [A, *X, B]
        return float(sum(self.energy.energy(S[k], S[k + 1]) for k in range(len(S) - 1)))

    def gradient(self, A, X, B) -> np.ndarray:
        """Gradient ``(K-1, 3n)`` of :meth:`path_energy` w.r.t. the inner shells."""
        S = [A, *X, B]
        W = self.energy
        return np.stack([W.gradient(S[k], S[k + 1], 1) + W.gradient(S[k + 1], S[k + 2], 0)
                         for k in range(self.n_inner)])

    def hessian_data(self, A, X, B, projection=None) -> np.ndarray:
        """Data of the block-tridiagonal Hessian on :attr:`gpattern` (free DOFs only).

        ``projection`` (``"clamp"`` or ``"abs"``): the projected Newton matrix instead, a
        sum of element Hessians each projected onto the positive semi-definite cone
        (:meth:`~shellspline.shells.energy.DiscreteShells.chain_hessian_data`)."""
        S = [A, *X, B]
        W, keep = self.energy, self._keep
        vals = []
        if projection is not None:
            diag, upper = W.chain_hessian_data(np.stack(S), projection)
            vals = [d[keep] for d in diag]
            for d12 in upper:
                vals.append(d12[keep])
                vals.append(d12[self._permT][keep])
            return np.bincount(np.concatenate(self._pos), weights=np.concatenate(vals),
                               minlength=self.gpattern.nnz)
        for k in range(self.n_inner):
            vals.append(W.midpoint_hessian_data(S[k], S[k + 1], S[k + 2])[keep])
        for k in range(self.n_inner - 1):
            d12 = W.hessian_data(S[k + 1], S[k + 2], "12")
            vals.append(d12[keep])
            vals.append(d12[self._permT][keep])
        return np.bincount(np.concatenate(self._pos), weights=np.concatenate(vals),
                           minlength=self.gpattern.nnz)

    def _modes(self, X):
        if not getattr(self.energy, "rigid_invariant", False):
            return None
        return [rigid_modes(X[k], self.free, self.pinned_dofs) for k in range(self.n_inner)]

    def _project(self, v, modes):
        """Remove each shell's rigid-motion components from ``v (K-1, nf)`` in place."""
        if modes is not None:
            for k, Q in enumerate(modes):
                if Q.shape[1]:
                    v[k] -= Q @ (Q.T @ v[k])
        return v

    def _factor(self, data, shift):
        """Factor ``H + shift I`` (lower data); returns False when not positive definite."""
        indptr, indices, sel = self._lower
        low = data[sel] + shift * self._diag_mask
        self.factorizations += 1
        try:
            if self._chol is None:
                # the analysis once, even when this shift is not positive definite
                self._chol = SparseCholesky.from_lower_pattern(indptr, indices, self.N, low,
                                                               backend=self.backend,
                                                               numeric=False)
            self._chol.refactor_lower(low)
        except (ArithmeticError, RuntimeError, ValueError):
            return False
        return True

    def _damped_factor(self, data, scale, from_zero: bool = False):
        """Factor ``H + (ε + τ) I`` with the smallest ``τ`` in ``0, 1e-8, 1e-6, …`` (times
        ``scale``) that is positive definite; returns ``τ``."""
        eps = _EPS_SHIFT * scale
        taus = _TAUS
        start = 0 if from_zero else max(0, taus.index(self._tau_hint) - 2)
        for tau in taus[start:]:
            if self._factor(data, eps + tau * scale):
                self._tau_hint = tau
                return tau
        raise ArithmeticError("the path Hessian could not be factored")

    def solve_linear(self, A, X, B, rhs, *, refine: int = 3, data=None) -> np.ndarray:
        """Solve ``H p = rhs`` at the path ``(A, X, B)`` on the complement of the rigid modes.

        Parameters
        ----------
        A, B : (n,3) float arrays
        X : (K-1,n,3) float array
        rhs : (K-1, 3n) float array
            Orthogonal to each shell's infinitesimal rigid motions (e.g. a gradient of a
            rigid-invariant energy); pinned DOFs are ignored.

        Returns
        -------
        p : (K-1, 3n) float array, zero on pinned DOFs.

        Notes
        -----
        Factors ``H + ε I`` and applies iterative refinement, projecting out the rigid modes:
        ``H`` is singular exactly on them, and ``rhs`` has no component there, so the result
        converges to the pseudo-inverse solution ``H⁺ rhs`` (the adjoint equation 16 of the
        paper).
        """
        return self.solve_factored(self.factor_at(A, X, B, data=data), rhs, refine=refine)

    def factor_at(self, A, X, B, *, data=None, slot=None) -> dict:
        """Assemble and factor the Hessian at the path ``(A, X, B)`` for
        :meth:`solve_factored` (several right-hand sides, one factorization).

        ``slot`` (any hashable): keep the factorization in its own slot, valid until the next
        ``factor_at`` with the same slot (the symbolic analysis of the slot is reused);
        without it the factorization is the solver's working one, which the next
        factorization overwrites.
        """
        if data is None:
            data = self.hessian_data(A, X, B)
        scale = float(np.abs(data).max())
        if slot is None:
            tau = self._damped_factor(data, scale, from_zero=True)
            chol = self._chol
        else:
            work, self._chol = self._chol, self._slots.get(slot)
            try:
                tau = self._damped_factor(data, scale, from_zero=True)
                chol = self._slots[slot] = self._chol
            finally:
                self._chol = work
        return {"H": self.gpattern.matrix(data), "tau": tau, "modes": self._modes(X),
                "chol": chol}

    def solve_factored(self, ctx: dict, rhs, *, refine: int = 3) -> np.ndarray:
        """Solve with the factorization of :meth:`factor_at` (the latest one, or the latest
        one of its slot)."""
        H, modes = ctx["H"], ctx["modes"]
        b = self._project(np.asarray(rhs, np.float64).reshape(self.n_inner, -1)[:, self.free].copy(),
                          modes)
        p = np.zeros_like(b)
        for _ in range(1 + (refine if ctx["tau"] == 0.0 else 0)):
            r = b - (H @ p.ravel()).reshape(b.shape)
            p += self._project(ctx["chol"].solve(r.ravel()).reshape(b.shape), modes)
        out = np.zeros((self.n_inner, 3 * self.n))
        out[:, self.free] = p
        return out

    # -- Newton --------------------------------------------------------------------------
    def solve(self, A, B, X0, *, tol: float = 1e-9, max_iter: int = 50,
              check=None, deadline: float | None = None, progress=None,
              projection="clamp") -> GeodesicResult:
        """Minimise the path energy over the inner shells, starting from ``X0``.

        Parameters
        ----------
        A, B : (n,3) float arrays
            Fixed end shells.
        X0 : (K-1,n,3) float array
            Initial inner shells (pinned vertices keep these positions).
        tol : float
            Stop when the max-norm of the gradient is below ``tol * energy.scale(A)``.
        max_iter : int
        check : callable, optional
            Called before every Newton iteration; may raise to abandon the solve (the
            nonlinear spline's time limit).
        deadline : float, optional
            A ``time.perf_counter()`` value: no Newton iteration starts after it; the path
            reached so far is returned, unconverged, message ``"time limit reached"``.
        progress : callable, optional
            ``progress(iteration, path energy, gradient max-norm)`` at every iterate (a
            Newton step of a fine path takes seconds: logs get a line per step).
        projection : {"clamp", "abs", None}
            Projected Newton (default ``"clamp"``): the Newton matrix is the sum of the
            element Hessians, each projected onto the positive semi-definite cone
            (:meth:`hessian_data`), so it needs no damping shift; ``None``: the true Hessian,
            shifted until it is positive definite.

        Returns
        -------
        GeodesicResult
        """
        W = self.energy
        projection = checked_projection(projection)
        m, nf = self.n_inner, self.nf
        A = np.asarray(A, np.float64)
        B = np.asarray(B, np.float64)
        X = np.array(X0, dtype=np.float64).reshape(m, self.n, 3)
        gscale = tol * 0.5 * (W.scale(A) + W.scale(B))
        E = self.path_energy(A, X, B)
        K = m + 1
        res = GeodesicResult(V=X, status="limit", energies=[K * E],
                             message="maximum number of iterations reached")
        nit = 0
        nfact0 = self.factorizations
        exact_below = np.inf
        g_next = None  # the gradient at X when a round-off-level step already computed it
        for nit in range(max_iter + 1):
            if check is not None:
                check()
            g = self.gradient(A, X, B)[:, self.free] if g_next is None else g_next
            g_next = None
            gn = float(np.abs(g).max())
            res.record(grad_norm=gn)
            if nit:
                res.record(energy=K * E)
            if not (np.isfinite(gn) and np.isfinite(E)):
                # a shell with a collapsed triangle (an exact half-turn's straight average):
                # no Hessian to factor there (recorded first: one entry per iterate)
                res.stop("failed", "degenerate shell on the path (non-finite energy)")
                break
            if progress is not None:
                progress(nit, K * E, gn)
            norms = res.grad_norms
            if gn <= gscale:
                res.stop("converged", "converged")
                break
            if nit >= 2 and gn <= 1e3 * gscale and gn >= 0.5 * norms[-3]:
                # two steps without progress near the tolerance: the gradient is at its
                # round-off floor (Armijo accepts steps below the energy's last digit)
                res.stop("converged", "converged (gradient at round-off level)")
                break
            if nit == max_iter:
                break
            if deadline is not None and time.perf_counter() > deadline:
                res.stop("limit", "time limit reached")
                break
            modes = self._modes(X)
            data = None
            if projection is not None and gn < exact_below:
                # the true Hessian when it is positive definite up to a small shift
                # (quadratic convergence near the minimum); else the projected one, and the
                # true one again only after the gradient fell by _EXACT_RETRY (failed
                # factorizations cost time)
                exact = self.hessian_data(A, X, B)
                scale = float(np.abs(exact).max())
                start = max(0, _EXACT_TAUS.index(self._exact_hint) - 1)
                for tau in _EXACT_TAUS[start:]:
                    if self._factor(exact, (_EPS_SHIFT + tau) * scale):
                        data, self._exact_hint = exact, tau
                        break
                else:
                    exact_below = _EXACT_RETRY * gn
            if data is None:
                data = self.hessian_data(A, X, B, projection)
                scale = float(np.abs(data).max())
                tau = self._damped_factor(data, scale)
            d = -self._project(self._chol.solve(g.ravel()).reshape(m, nf), modes)
            slope = float(np.sum(g * d))
            while slope >= 0 and tau < 1e2:  # not a descent direction: damp harder
                tau = max(1e-6, 100 * tau)
                if not self._factor(data, (_EPS_SHIFT + tau) * scale):
                    continue
                d = -self._project(self._chol.solve(g.ravel()).reshape(m, nf), modes)
                slope = float(np.sum(g * d))
            if slope >= 0:
                d, slope = -g, -float(np.sum(g * g))
            if -slope <= _ROUNDOFF_DECREASE * abs(E):
                # the predicted decrease is below the energy's resolution, so Armijo cannot
                # tell a good step from a bad one: take the full Newton step if it lowers the
                # gradient (soft midpoints stalled ~1e4 above a 1e-13 tolerance without this)
                Xn = X.copy()
                Xn.reshape(m, -1)[:, self.free] += d
                if _valid(Xn):
                    gx = self.gradient(A, Xn, B)[:, self.free]
                    if float(np.abs(gx).max()) < gn:
                        X, E, g_next = Xn, self.path_energy(A, Xn, B), gx
                        continue
            def trial(alpha, X=X, d=d):
                Xn = X.copy()
                Xn.reshape(m, -1)[:, self.free] += alpha * d
                return (self.path_energy(A, Xn, B) if _valid(Xn) else np.inf), Xn

            ls = backtracking(trial, E, slope, max_steps=40)
            if not ls.accepted:
                # no decrease within round-off: accept if the gradient is already tiny
                if gn <= 1e3 * gscale:
                    res.stop("converged", "converged (energy stagnates at round-off level)")
                else:
                    res.stop("stalled", "line search failed")
                break
            X, E = ls.payload, ls.value
        res.V = np.concatenate([A[None], X, B[None]])
        res.iterations = nit
        res.factorizations = self.factorizations - nfact0
        return res


def lerp_inner_shells(A, B, K):
    """Inner shells ``(K-1,n,3)`` of the linear blend; coordinates equal in ``A`` and ``B``
    stay bit-identical (pinned vertices)."""
    t = (np.arange(1, K) / K)[:, None, None]
    return np.where(A == B, A, (1 - t) * A + t * B)


def _valid(X) -> bool:
    return bool(np.all(np.isfinite(X)))


def make_energy(T, energy, mu, lam, eta):
    if energy is not None:
        return energy
    if not isinstance(T, Topology):
        raise ShellsplineError(f"`T` must be a Topology, got {type(T).__name__}")
    return DiscreteShells(T, mu, lam, eta)


def discrete_geodesic(VA, VB, K: int, T: Topology | None = None, *, mu: float = 1.0,
                      lam: float = 1.0, eta: float = 1e-3, pinned=None, init=None, energy=None,
                      tol: float = 1e-9, max_iter: int = 50,
                      backend: str = "auto", projection="clamp") -> GeodesicResult:
    """Discrete geodesic ``(s_0 = VA, …, s_K = VB)`` minimising ``E^K`` (paper eq. 3).

    Parameters
    ----------
    VA, VB : (n,3) float64 arrays
        End shells.
    K : int
        Number of time steps (``K - 1`` inner shells), ``K >= 1``.
    T : Topology
        Connectivity (not needed when ``energy`` is given).
    mu, lam, eta : float
        Discrete Shells parameters (eq. 9).
    pinned : (p,) int array, optional
        Vertices held fixed (they should coincide in ``VA`` and ``VB``).
    init : (K-1,n,3) float array, optional
        Initial inner shells; default the per-vertex linear blend.
    energy : DiscreteShells or EuclideanEnergy, optional
        A prebuilt energy (overrides ``T, mu, lam, eta``).
    tol : float
        Gradient max-norm tolerance relative to ``energy.scale(VA)``.
    max_iter : int
    backend : {"auto", "cholmod", "splu"}
    projection : {"clamp", "abs", None}
        Projected Newton (default) or Newton on the true Hessian (``None``); see
        :meth:`PathSolver.solve`.

    Returns
    -------
    GeodesicResult

    Examples
    --------
    >>> import numpy as np, trimesh
    >>> from shellspline.mesh.topology import topology
    >>> m = trimesh.creation.icosphere(subdivisions=1)
    >>> V, T = np.asarray(m.vertices), topology(m.faces)
    >>> res = discrete_geodesic(V, 1.2 * V, 4, T, eta=0.1)
    >>> res.success, res.V.shape
    (True, (5, 42, 3))
    """
    W = make_energy(T, energy, mu, lam, eta)
    K = checked_K(K)
    n = W.n_vertices
    VA = checked_pose(VA, n, "VA")
    VB = checked_pose(VB, n, "VB")
    if K == 1:
        return GeodesicResult(V=np.stack([VA, VB]), status="converged",
                              energies=[W.energy(VA, VB)], grad_norms=[0.0],
                              message="no inner shells")
    if init is None:
        init = lerp_inner_shells(VA, VB, K)
    init = np.asarray(init, dtype=np.float64)
    if init.shape != (K - 1, n, 3):
        raise ShellsplineError(f"`init` must have shape (K-1,n,3) = ({K - 1},{n},3), "
                               f"got {init.shape}")
    return PathSolver(W, K - 1, pinned=pinned, backend=backend).solve(
        VA, VB, init, tol=tol, max_iter=max_iter, projection=checked_projection(projection))


@dataclass(kw_only=True)
class GeodesicInterpolationResult(SolverResult):
    """What :func:`geodesic_interpolation` returns (a
    :class:`~shellspline.numerics.result.SolverResult` over all segments).

    Attributes
    ----------
    V : (K+1,n,3) float64 array
        Piecewise discrete geodesic; ``V[frames[j]]`` is keyframe ``j``.
    frames : (J,) int64 array
    status : {"converged", "stalled", "limit", "failed"}
        ``"converged"`` when all segments converged, else the status of the first segment
        that did not. ``success`` is ``status == "converged"``.
    iterations : int
        Total Newton iterations over all segments (also ``nit``).
    energies : (it+1,) float64 array
        The sum ``Σ_j E^{K_j}`` of the segments' path energies at the start and after every
        Newton iteration of the solve. The segments are solved one after another, so
        iteration ``i`` moves one segment while the earlier ones are at their final paths and
        the later ones at their starts; ``energy`` (the last entry) is the sum at ``V``.
    grad_norms : (it+1,) float64 array
        Max-norm of the gradient w.r.t. the inner shells of all segments at the same points
        (the largest of the segments' gradient max-norms), so ``grad_reduction`` is the
        reduction of the whole solve. A segment without inner shells has no unknowns and
        counts 0; one the time limit kept from starting counts its initial gradient.
    message : str
    segment_energies : list of float
        Path energy ``E^{K_j}`` of every segment (eq. 3 with its own number of steps).
    segments : list of GeodesicResult
        Per-segment results, with their own histories.
    factorizations : int
        Numeric factorizations of the Newton matrices over all segments.
    time_limit_reached : bool
        ``max_time_s`` stopped a segment or kept one from starting (``status`` is then
        ``"limit"`` unless an earlier segment failed or stalled).
    """

    V: np.ndarray
    frames: np.ndarray
    factorizations: int = 0
    segment_energies: list = field(default_factory=list)
    segments: list = field(default_factory=list)
    time_limit_reached: bool = False


def _combined_histories(results) -> tuple[np.ndarray, np.ndarray]:
    """Energy and gradient max-norm histories ``(it+1,)`` of segments solved one after
    another: entry 0 is the start of all of them, then one entry per Newton iteration of
    each segment in turn (earlier segments at their last iterate, later ones at their
    first); energies add up, gradient max-norms take the largest (NaN propagates)."""
    E = np.array([r.energies[0] if r.energies.size else np.nan for r in results])
    G = np.array([r.grad_norms[0] if r.grad_norms.size else np.nan for r in results])
    energies, grads = [float(E.sum())], [float(G.max()) if G.size else 0.0]
    for s, r in enumerate(results):
        for i in range(1, min(r.energies.size, r.grad_norms.size)):
            E[s], G[s] = r.energies[i], r.grad_norms[i]
            energies.append(float(E.sum()))
            grads.append(float(G.max()))
    return np.array(energies), np.array(grads)


def geodesic_interpolation(Vkey, frames, K, T: Topology | None = None, *, mu: float = 1.0,
                           lam: float = 1.0, eta: float = 1e-3, pinned=None,
                           bc: str = "natural", energy=None, tol: float = 1e-9,
                           max_iter: int = 50, backend: str = "auto",
                           callback=None, progress=None, init=None,
                           max_time_s: float | None = None,
                           projection="clamp") -> GeodesicInterpolationResult:
    """Piecewise discrete geodesic interpolation of keyframes (the paper's baseline, §3).

    Consecutive keyframes ``j, j+1`` are joined by a discrete geodesic with
    ``frames[j+1] − frames[j]`` steps; with ``bc="periodic"`` the last keyframe is also joined
    to the first (``K − frames[-1]`` steps, frame ``K`` is frame ``0``). Frames after the last
    keyframe (non-periodic) hold the last keyframe.

    Parameters
    ----------
    Vkey : (J,n,3) float64 array
        Keyframe poses.
    frames : (J,) int array
        Strictly increasing keyframe frames, ``frames[0] == 0``.
    K : int
        Last frame index.
    T : Topology
    mu, lam, eta : float
    pinned : (p,) int array, optional
    bc : {"natural", "periodic", "hermite"}
        Only ``"periodic"`` changes the result (it adds the closing segment); ``"hermite"``
        checks that frames 0, 1, K-1, K are keyframes.
    energy : optional prebuilt energy object (see :func:`discrete_geodesic`).
    tol, max_iter, backend : see :func:`discrete_geodesic`.
    callback : callable, optional
        ``callback(segment_index, GeodesicResult)`` after each segment.
    progress : callable, optional
        ``progress(segment_index, iteration, path energy, gradient max-norm)`` at every
        Newton iterate of a segment.
    init : (K+1,n,3) float array, optional
        Initial sequence: each segment starts from its frames there (the pipeline passes its
        LΘA spline: a path of near-isometric shells, where the Hessian is close to positive
        definite); default the per-vertex linear blend of each segment's keyframes, whose
        compressed and folded triangles make the Hessian strongly indefinite on real meshes
        (the coarse horse: a damping shift of 0.3 × its largest entry in the first step, 17
        factorizations to find it).
    max_time_s : float, optional
        Wall-clock limit in seconds for all segments together: no Newton iteration starts
        after it, a segment stopped by it keeps the path reached so far, later segments keep
        their initial path (``init`` or the linear blend), and all of them are reported
        unconverged (``time_limit_reached``, status ``"limit"``). Default: none (each
        segment stops after ``max_iter`` Newton iterations; on the 1000-vertex coarse horse
        one 20-step segment takes ~11 s per projected Newton step on a loaded 2-core machine
        and does not converge: its minimising paths collapse sliver faces, see the README).
    projection : {"clamp", "abs", None}
        Projected Newton (default) or Newton on the true Hessian (``None``); see
        :meth:`PathSolver.solve`.

    Returns
    -------
    GeodesicInterpolationResult
        Warns (``RuntimeWarning``) when a segment did not converge.
    """
    t0 = time.perf_counter()
    Vkey = checked_poses(Vkey)
    bc = canonical_bc(bc)
    K = checked_K(K)
    frames = checked_frames(frames, K, bc)
    if len(frames) != len(Vkey):
        raise ShellsplineError(f"`frames` must have one entry per keyframe ({len(Vkey)}), "
                               f"got {len(frames)}")
    if max_time_s is not None and not (isinstance(max_time_s, (int, float, np.integer,
                                                                 np.floating))
                                       and not isinstance(max_time_s, (bool, np.bool_))
                                       and 0 < float(max_time_s) < np.inf):
        raise ShellsplineError(f"`max_time_s` must be a positive number of seconds, got "
                               f"{max_time_s!r}")
    deadline = None if max_time_s is None else t0 + float(max_time_s)
    projection = checked_projection(projection)
    W = make_energy(T, energy, mu, lam, eta)
    Vkey = checked_poses(Vkey, W.n_vertices)
    if init is not None:
        init = np.asarray(init, dtype=np.float64)
        if init.shape != (K + 1, W.n_vertices, 3) or not np.all(np.isfinite(init)):
            raise ShellsplineError(f"`init` must be a finite (K+1,n,3) = ({K + 1},"
                                   f"{W.n_vertices},3) array, got shape {init.shape}")
    J = len(frames)
    V = np.zeros((K + 1, Vkey.shape[1], 3))
    segs = [(j, j + 1, frames[j], frames[j + 1]) for j in range(J - 1)]
    if bc == "periodic":
        segs.append((J - 1, 0, frames[-1], K))
    solvers: dict = {}
    results, ok, nit, timed_out = [], True, 0, False
    for s, (ja, jb, fa, fb) in enumerate(segs):
        steps = int(fb - fa)
        if steps >= 2:
            if steps not in solvers:
                solvers[steps] = PathSolver(W, steps - 1, pinned=pinned, backend=backend)
            X0 = lerp_inner_shells(Vkey[ja], Vkey[jb], steps) if init is None else \
                init[fa + 1:fb]
            if deadline is not None and time.perf_counter() > deadline:
                solver = solvers[steps]
                E0 = solver.path_energy(Vkey[ja], X0, Vkey[jb])
                g0 = np.abs(solver.gradient(Vkey[ja], X0, Vkey[jb])[:, solver.free]).max()
                res = GeodesicResult(V=np.concatenate([Vkey[ja][None], X0, Vkey[jb][None]]),
                                     status="limit", energies=[steps * E0], grad_norms=[g0],
                                     message="time limit reached before the segment started "
                                             "(its initial path kept: " +
                                             ("the per-vertex blend)" if init is None else
                                              "the given start)"))
            else:
                res = solvers[steps].solve(
                    Vkey[ja], Vkey[jb], X0, tol=tol, max_iter=max_iter, deadline=deadline,
                    projection=projection,
                    progress=None if progress is None else
                    (lambda it, e, g, s=s: progress(s, it, e, g)))
            V[fa + 1:fb] = res.V[1:-1]
        else:
            res = GeodesicResult(V=np.stack([Vkey[ja], Vkey[jb]]), status="converged",
                                 energies=[W.energy(Vkey[ja], Vkey[jb])], grad_norms=[0.0],
                                 message="no inner shells")
        results.append(res)
        timed_out |= res.status == "limit" and res.message.startswith("time limit")
        ok &= res.success
        nit += res.nit
        if callback is not None:
            callback(s, res)
    V[frames] = Vkey
    if bc == "periodic":
        V[K] = Vkey[0]
    else:
        V[frames[-1]:] = Vkey[-1]
    message = "all segments converged" if ok else \
        "not converged: " + "; ".join(
            f"segment {i + 1} of {len(segs)} (frames {segs[i][2]}-{segs[i][3]}): {r.message} "
            f"after {r.nit} Newton iterations" for i, r in enumerate(results) if not r.success)
    if not ok:
        warnings.warn(f"geodesic_interpolation: {message}", RuntimeWarning, stacklevel=2)
    status = next((r.status for r in results if not r.success), "converged")
    energies, grad_norms = _combined_histories(results)
    return GeodesicInterpolationResult(V=V, frames=frames, status=status, iterations=nit,
                                       message=message, energies=energies,
                                       grad_norms=grad_norms,
                                       segment_energies=[r.energy for r in results],
                                       segments=results,
                                       factorizations=sum(r.factorizations for r in results),
                                       time_limit_reached=timed_out)

"""The nonlinear spline's problem: the constrained energy ``F^K`` and its adjoint gradient.

See :mod:`shellspline.shells.nonlinear` for the equations.
"""
from __future__ import annotations

import time

import numpy as np

from ...errors import ShellsplineError
from ...mesh.pinned import canonical_pinned
from ...mesh.rigid import rigid_modes
from ...timeline import canonical_bc, checked_frames, checked_K
from ..geodesic import PathSolver

__all__ = ["MIDPOINT_MAX_NEWTON", "NonlinearSplineProblem", "TimeLimitReached"]

#: Newton iteration limit of a midpoint solve in a full evaluation (trial points of the
#: optimisers use 10 and are rejected when a solve needs more). Measured on five horse poses
#: (1000-vertex coarse path, frames 0,12,...,48, LΘA start): 43 of 47 midpoints converge in
#: 9–49 iterations from the linear average of their neighbours; the four terms around the two
#: frames where a few small flaps snap by 2.6–3.2 rad in one step need 61–78 (energy still
#: falling at 50). With a limit of 50 they stayed unconverged, their adjoint solves gave a
#: gradient of 2e9 (1e6–2e7 elsewhere) and no trial step near them could be accepted.
MIDPOINT_MAX_NEWTON = 200


class TimeLimitReached(Exception):
    """Raised inside the solver when the problem's :attr:`~NonlinearSplineProblem.deadline`
    has passed (:meth:`NonlinearSplineProblem.check_time`); the solver catches it and
    returns its last accepted iterate."""


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
                                    max_iter=MIDPOINT_MAX_NEWTON, check=self.check_time)
            self.midpoint_iterations += res.nit
            self.midpoint_failures += not res.success
            M[t] = res.V[1]
        return M

    def _warm(self, S):
        """Initial midpoints: the last evaluation's, or the average of each term's two
        shells, except where that average collapses a triangle (two shells a half-turn
        apart average to a segment, where the midpoint solve has no Hessian): there the
        first of the two."""
        if self.midpoints is not None:
            return self.midpoints.copy()
        A, B = S[self.terms[:, 0]], S[self.terms[:, 2]]
        M = 0.5 * (A + B)
        T = getattr(self.energy, "T", None)   # shell energies; the Euclidean one has none
        if T is not None:
            F = T.F

            def areas(X):
                e1, e2 = X[:, F[:, 1]] - X[:, F[:, 0]], X[:, F[:, 2]] - X[:, F[:, 0]]
                return np.linalg.norm(np.cross(e1, e2), axis=-1)
            flat = (areas(M) <= 1e-3 * np.minimum(areas(A), areas(B))).any(axis=1)
            M[flat] = A[flat]
        return M

    def evaluate(self, S, *, gradient: bool = True, keep: bool = False, warm=None,
                 max_newton: int = MIDPOINT_MAX_NEWTON, abort_on_failure: bool = False, slot_set: int = 0):
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
            Newton iteration limit of each midpoint solve (default
            :data:`MIDPOINT_MAX_NEWTON`).
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
            # stationary in the midpoint, so its round-off level follows the midpoint's error.
            # Only after a converged solve: from an unconverged midpoint a full step of the
            # (damped, possibly indefinite) Hessian without line search is no refinement and
            # can jump far (horse, coarse, the unconverged midpoint of frame 44: a step of
            # 0.054, 1.4 mean edge lengths)
            ctx = self.solver.factor_at(S[a], m[None], S[b],
                                        slot=(slot_set, t) if keep else None)
            ctx["m"] = m
            if keep and hasattr(W, "geometry_of"):
                geos.append(W.geometry_of(m))
            if res.success:
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
        """Raise :class:`TimeLimitReached` once :attr:`deadline` has passed (checked in every loop of
        the solver that can take long: midpoint solves, Hessian products, retractions)."""
        if self.deadline is not None and time.perf_counter() > self.deadline:
            raise TimeLimitReached

    def rigid_bases(self, S) -> list:
        """Per free node: orthonormal basis ``(len(free_dofs), r)`` of the infinitesimal rigid
        motions of ``S[k]`` that the pins leave free (``r = 0`` for energies without rigid
        invariance or with three non-collinear pins)."""
        if not getattr(self.energy, "rigid_invariant", False):
            return [np.zeros((len(self.free_dofs), 0)) for _ in self.free_nodes]
        pd = np.setdiff1d(np.arange(3 * self.n), self.free_dofs)
        return [rigid_modes(np.asarray(S[k]), self.free_dofs, pd) for k in self.free_nodes]

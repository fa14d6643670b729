"""Time-coupled bridges over the seams of the reconstruction.

Each keyframe gap is reconstructed from both ends (:func:`~.reconstruction.reconstruction_runs`),
and on real meshes the two runs can settle into different local minima of the per-frame
energy: a skin fold at a joint formed in one, not yet formed in the other. Every sequence of
per-frame minimisers then jumps somewhere in the gap (:func:`~.reconstruction.seam_records`:
the horse, ``horse-reference, horse-03, horse-07`` at frames 0, 20, 40, jumps 1.6 and 2.7 times
the typical step at frames 7 and 32), because the minimiser itself jumps there: the energy
landscape of a frame folds over as the targets move, and the quasi-static path snaps.

A thin shell with mass does not snap from one frame to the next: it moves through the
transition over a few frames. The bridge re-solves the frames around a seam *together*,
minimising the sum of their reconstruction energies plus an acceleration penalty

    Φ(V_U) = Σ_{k ∈ U} f_k(V_k) + μ Σ_j ‖V_{j+1} − 2 V_j + V_{j−1}‖²_M,

over the window ``U`` of ``2 · half`` frames around the seam, with two solved frames held
fixed on each side (``M`` the lumped vertex masses, normalised to mean 1). The penalty's
weight is tiny against the stiffness of the membrane (``μ = β`` times the mean diagonal of
the Gauss–Newton matrix, :data:`BRIDGE_BETA`), so it only acts on the near-free modes of a
frame (its rigid motion, the buckling of a fold) and leaves lengths and areas where the
per-frame solve put them. Measured on the horse (3 keyframes, full resolution): pop 2.65 →
1.14, with β from 1e-6 to 1e-3 giving the same pop; β = 1e-3 also removed the 4 flipped faces
but let 16 edges fold (a cross-fade of the two runs, against their energies), β ≤ 1e-6 keeps
the flips and folds of the per-frame solutions.

The joint Gauss–Newton system ``blockdiag(J_kᵀ W_k J_k) + μ (DᵀD)_UU ⊗ M`` is solved by
conjugate gradients preconditioned by the per-frame blocks (each factored once per bridge,
with its share of the penalty on the diagonal), under the same line search and no-collapse
guard as the per-frame solver; the frames' status is the bridge's own (converged only by its
decrement or gradient criterion).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

from ..numerics.krylov import pcg
from ..numerics.linalg import SparseCholesky
from ..numerics.linesearch import backtracking
from ..shells.descriptors import face_areas, lta_descriptors, lta_jacobian
from ..shells.reconstruct import rigid_placement

__all__ = ["bridge_seam", "SeamBridge", "BridgeResult", "BRIDGE_BETA", "BRIDGE_HALF", "BRIDGE_DTOL",
           "BRIDGE_MAX_ITER"]

#: Weight of the acceleration penalty relative to the mean diagonal of the frames'
#: Gauss–Newton matrices (see the module notes).
BRIDGE_BETA = 1e-6
#: Frames re-solved on each side of a seam.
BRIDGE_HALF = 2
#: The bridge is converged when its Gauss–Newton decrement is below this fraction of the
#: objective. Looser than the per-frame solver's ``dtol``: the penalty's weight is a choice
#: within three orders of magnitude (see the module notes), and on the horse the objective is
#: within 0.1 % of its final value after two iterations; resolving its minimiser to 2e-6 took
#: 7–12 iterations more and moved no frame visibly.
BRIDGE_DTOL = 1e-4
#: Gauss–Newton iterations a bridge may take (as many as a frame's solver). It was 30: on
#: the sliver tube of ``data_synth.stress.dense_slivers(subdivisions=0)`` (1536 vertices,
#: slivers 1 % of the median area) both bridges stopped there with their objective already
#: at its final value (146.7 → 7.31), kept (flips 11 → 3), and their 8 frames were reported
#: unconverged (10/18); now they converge at 34 and 41 iterations (18/18, bridging
#: 6.4 → 7.2 s). The horse's bridges converge in a few iterations either way. A bridge that
#: cannot converge costs in proportion: the same tube subdivided once (6 080 vertices, whose
#: frames themselves do not converge, 3/18) bridged 321 s with a limit of 100, not kept.
BRIDGE_MAX_ITER = 60


@dataclass
class BridgeResult:
    """A bridged window: its frames, their solutions and the joint solve's record."""

    frames: np.ndarray
    V: np.ndarray
    energies: np.ndarray
    status: str = "stalled"
    message: str = ""
    iterations: int = 0
    cg_iterations: int = 0
    mu: float = 0.0
    objective: list = field(default_factory=list)

    def summary(self) -> dict:
        return {"frames": [int(k) for k in self.frames], "status": self.status,
                "message": self.message, "iterations": int(self.iterations),
                "cg_iterations": int(self.cg_iterations), "mu": float(self.mu),
                "objective_start": float(self.objective[0]) if self.objective else None,
                "objective_final": float(self.objective[-1]) if self.objective else None}


def _second_differences(ctx, U):
    """Rows ``j`` (as positions in ``ctx``) of the second differences whose stencil
    ``j−1, j, j+1`` lies in the context frames and touches the window ``U``."""
    pos = {k: i for i, k in enumerate(ctx)}
    rows = [pos[k] for k in ctx[1:-1] if {k - 1, k, k + 1} & set(U)]
    D = np.zeros((len(rows), len(ctx)))
    for r, j in enumerate(rows):
        D[r, j - 1:j + 2] = (1.0, -2.0, 1.0)
    return D


class SeamBridge:
    """The joint problem of the frames around one seam (see the module notes and
    :func:`bridge_seam`, which builds and solves it).

    Attributes
    ----------
    frames : (u,) int array
        The window: the frames re-solved.
    context : (c,) int array
        The window and up to two fixed frames on each side.
    X0 : (c, 3n) float64 array
        The context frames at the start (the window's frames rigidly placed on the cubic
        through the fixed ones, without pins).
    mu : float
        Weight of the acceleration penalty.
    """

    def __init__(self, gn, frame_of, K: int, s: int, a: int, b: int, Z, W_of, *,
                 half: int = BRIDGE_HALF, beta: float = BRIDGE_BETA, tube_of=None):
        U = list(range(max(a + 1, s - half), min(b - 1, s + half - 1) + 1))
        ctx = list(range(max(0, U[0] - 2), min(K, U[-1] + 2) + 1)) if U else []
        self.gn, self.T = gn, gn.T
        self.frames, self.context = np.array(U, dtype=np.int64), np.array(ctx, dtype=np.int64)
        if not U:
            return
        T = gn.T
        n = T.n_vertices
        sA = T.descriptor_slices()[2]
        self.D = _second_differences(ctx, U)
        self.DtD = self.D.T @ self.D
        self.iu = [ctx.index(k) for k in U]
        self.free = np.ones(3 * n, dtype=bool)
        if len(gn.pinned):
            self.free[(3 * gn.pinned[:, None] + np.arange(3)).ravel()] = False
        self.targets = [np.asarray(Z[k], dtype=np.float64) for k in U]
        # the weights and collapse floors of GaussNewton.solve
        self.weights = [gn.active_weights(z, W_of(k)) for k, z in zip(U, self.targets)]
        self.tubes = [None if tube_of is None else np.asarray(tube_of(k), dtype=np.float64)
                      for k in U]
        self.floors = [gn.area_floor(z) for z in self.targets]
        # lumped vertex masses from the first window frame's target areas, mean 1
        A0 = np.maximum(self.targets[0][sA], 0.0)
        M = np.bincount(T.F.ravel(), np.repeat(A0 / 3.0, 3), minlength=n)
        self.M3 = np.repeat(M / M.mean() if M.mean() > 0 else np.ones(n), 3)
        X = np.stack([np.asarray(frame_of(k), dtype=np.float64).ravel() for k in ctx])
        if not len(gn.pinned):
            # the frames' energies ignore rigid motions, and the two runs of a gap drift
            # apart rigidly: start each window frame rigidly placed on the cubic through the
            # fixed frames around it (most of the penalty at the start, and slow for CG)
            from scipy.interpolate import CubicSpline

            fixed = [i for i, k in enumerate(ctx) if k not in U]
            track = CubicSpline(np.array(ctx, dtype=float)[fixed], X[fixed], axis=0)
            for j in self.iu:
                X[j] = rigid_placement(X[j].reshape(-1, 3),
                                       track(float(ctx[j])).reshape(-1, 3)).ravel()
        self.X0 = X
        terms = self.terms(X)
        diag = np.mean([float((J.multiply(J).T @ w)[self.free].mean()) for _, J, _, w in terms])
        self.mu = beta * diag

    def terms(self, X) -> list:
        """Per window frame ``(f, J, r_eff, w_eff)`` at the context frames ``X (c, 3n)``
        (:meth:`GaussNewton.merit`)."""
        out = []
        for i, j in enumerate(self.iu):
            J, z = lta_jacobian(X[j].reshape(-1, 3), self.T, return_values=True)
            f, r, w = self.gn.merit(z, self.targets[i], self.weights[i], self.tubes[i])
            out.append((f, J, r, w))
        return out

    def penalty(self, X) -> float:
        """``Σ_j ‖V_{j+1} − 2 V_j + V_{j−1}‖²_M`` over the context frames ``X (c, 3n)``."""
        acc = self.D @ X
        return float(np.einsum("jd,d,jd->", acc, self.M3, acc))

    def value(self, X, terms=None) -> float:
        """The objective ``Φ`` at the context frames ``X (c, 3n)``; inf where a window
        frame's triangle is below the no-collapse floor."""
        if terms is None:
            for i, j in enumerate(self.iu):
                if not np.all(face_areas(X[j].reshape(-1, 3), self.T) > self.floors[i]):
                    return np.inf
            terms = [(self.gn.merit(lta_descriptors(X[j].reshape(-1, 3), self.T),
                                    self.targets[i], self.weights[i], self.tubes[i])[0],)
                     for i, j in enumerate(self.iu)]
        return sum(t[0] for t in terms) + self.mu * self.penalty(X)

    def half_gradient(self, X, terms=None) -> np.ndarray:
        """Half the gradient of ``Φ`` with respect to the window frames, ``(u, 3n)`` (zero on
        pinned coordinates)."""
        terms = self.terms(X) if terms is None else terms
        DX = self.DtD @ X
        g = np.stack([J.T @ (w * r) + self.mu * self.M3 * DX[j]
                      for (f, J, r, w), j in zip(terms, self.iu)])
        g[:, ~self.free] = 0.0
        return g

    def _factors(self, terms):
        """Per window frame, the factor of its Gauss–Newton block with its share of the
        penalty (the preconditioner)."""
        gn, free = self.gn, self.free
        out = []
        for (f, J, r, w), j in zip(terms, self.iu):
            H = (J.T @ sp.diags(w) @ J).tocsc()
            d = self.mu * self.DtD[j, j] * self.M3 + gn.damping * H.diagonal()[free].mean()
            out.append(SparseCholesky(H + sp.diags(np.where(free, d, 1.0)), backend=gn.backend))
        return out

    def solve(self, dtol: float = BRIDGE_DTOL, max_iter: int = BRIDGE_MAX_ITER) -> BridgeResult:
        """Gauss–Newton on ``Φ`` from :attr:`X0`: each step by CG on the joint system,
        preconditioned by the frames' blocks, then the line search with the no-collapse
        guard; converged when the decrement is below ``dtol`` times ``Φ`` or the gradient
        below the solver's ``gtol`` times the first."""
        gn, iu, free = self.gn, self.iu, self.free
        n = self.T.n_vertices
        nu = len(iu)
        X = self.X0.copy()
        terms = self.terms(X)
        phi = self.value(X, terms)
        res = BridgeResult(frames=self.frames, V=X[iu].reshape(nu, n, 3).copy(),
                           energies=np.array([t[0] for t in terms]), mu=self.mu,
                           objective=[phi])
        if not np.isfinite(phi):
            res.status, res.message = "failed", "non-finite energy at the start"
            return res
        g = self.half_gradient(X, terms)
        g0 = float(np.linalg.norm(g))
        chol = self._factors(terms)
        E = self.T.E
        Xe = X[iu[0]].reshape(-1, 3)
        h = float(np.mean(np.linalg.norm(Xe[E[:, 1]] - Xe[E[:, 0]], axis=1)))
        Duu = self.DtD[np.ix_(iu, iu)]
        for it in range(1, max_iter + 1):
            Js = [(t[1], t[3]) for t in terms]

            def matvec(v):
                V_ = v.reshape(nu, -1)
                out = np.stack([J.T @ (w * (J @ V_[i])) for i, (J, w) in enumerate(Js)])
                out += self.mu * self.M3 * (Duu @ V_)
                out[:, ~free] = 0.0
                return out.ravel()

            def precond(v):
                V_ = v.reshape(nu, -1)
                out = np.stack([c.solve(V_[i]) for i, c in enumerate(chol)])
                out[:, ~free] = 0.0
                return out.ravel()

            cg = pcg(matvec, -g.ravel(), precond=precond, rtol=gn.cg_tol,
                     max_iter=4 * gn.cg_max_iter)
            res.cg_iterations += cg.iterations
            p = cg.x
            slope = float(g.ravel() @ p)
            if slope >= 0:
                p = -precond(g.ravel())
                slope = float(g.ravel() @ p)
            if -slope <= dtol * phi and cg.status == "converged":
                res.status, res.message = "converged", "decrement below dtol"
                res.iterations = it - 1
                break
            P = p.reshape(nu, -1)

            def trial(alpha):
                Xn = X.copy()
                Xn[iu] += alpha * P
                return self.value(Xn), Xn

            ls = backtracking(trial, phi, 2.0 * slope, c1=1e-4, shrink=0.5, max_steps=40,
                              interpolate=True)
            res.iterations = it
            if not ls.accepted:
                res.message = (f"stalled: line search failed at |g|/|g0| = "
                               f"{float(np.linalg.norm(g)) / g0:.1e}")
                break
            X = ls.payload
            terms = self.terms(X)
            phi = self.value(X, terms)
            res.objective.append(phi)
            g = self.half_gradient(X, terms)
            if float(np.linalg.norm(g)) <= gn.gtol * g0:
                res.status, res.message = "converged", "gradient norm reduced below gtol"
                break
            step = (ls.alpha * P).reshape(nu, n, 3)
            moved = float(np.sqrt(np.einsum("fnc,fnc->fn", step, step).max())) > 0.25 * h
            if moved or cg.status != "converged" or cg.iterations > 2 * gn.refresh_cg:
                # a factor from before a large step preconditions the rotated membrane
                # poorly (horse: the second step took 78-111 CG iterations instead of ~9)
                chol = self._factors(terms)
        else:
            res.status = "limit"
            res.message = f"iteration limit ({max_iter}) reached"
        res.V = X[iu].reshape(nu, n, 3)
        res.energies = np.array([t[0] for t in terms])
        return res


def bridge_seam(gn, frame_of, K: int, s: int, a: int, b: int, Z, W_of, *,
                half: int = BRIDGE_HALF, beta: float = BRIDGE_BETA, dtol: float = BRIDGE_DTOL,
                max_iter: int = BRIDGE_MAX_ITER, tube_of=None) -> BridgeResult | None:
    """Re-solve the frames around the seam at frame ``s`` of the gap ``(a, b)`` jointly.

    Parameters
    ----------
    gn : GaussNewton
        The frames' solver (its merit, pins, tolerances and CG settings are used).
    frame_of : callable(int) -> (n,3) float64 array
        The current sequence: the keyframes at their frames, solved frames elsewhere.
    K : int
        Last frame of the sequence.
    s : int
        First frame after the seam (the step ``s−1 → s`` jumps).
    a, b : int
        The keyframes around the gap; the window stays strictly between them.
    Z : (K+1,d) float64 array, or anything whose rows ``Z[k]`` are the targets
    W_of : callable(int) -> (d,) float64 array
    half : int
        Frames re-solved on each side of the seam.
    beta : float
        Weight of the acceleration penalty (see the module notes).
    dtol : float
        Converged when the joint Gauss–Newton decrement is below ``dtol`` times the
        objective (or the gradient norm below the solver's ``gtol`` times the first).
    max_iter : int
    tube_of : callable(int) -> (i,) float64 array, optional
        Tube weights of frame ``k``'s dihedral angles
        (:meth:`~shellspline.shells.reconstruct.GaussNewton.merit`).

    Returns
    -------
    BridgeResult or None
        None when the gap has no frame to re-solve.
    """
    problem = SeamBridge(gn, frame_of, K, s, a, b, Z, W_of, half=half, beta=beta,
                         tube_of=tube_of)
    if not len(problem.frames):
        return None
    return problem.solve(dtol=dtol, max_iter=max_iter)

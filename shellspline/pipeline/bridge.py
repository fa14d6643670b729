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
decrement or gradient criterion). Everything but the coupling is per frame (Jacobians,
energies, factors, products, the line search's trial energies), so a bridge can share its
window's frames with a forked worker, the vectors passing through shared memory
(``SeamBridge.solve(split=True)``; the same arithmetic, the same result to the bit).
"""
from __future__ import annotations

import mmap
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
    #: numeric factorizations of the frames' blocks (one per window frame each time the
    #: preconditioner is refactored)
    factorizations: int = 0
    mu: float = 0.0
    objective: list = field(default_factory=list)

    def summary(self) -> dict:
        return {"frames": [int(k) for k in self.frames], "status": self.status,
                "message": self.message, "iterations": int(self.iterations),
                "cg_iterations": int(self.cg_iterations),
                "factorizations": int(self.factorizations), "mu": float(self.mu),
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


class _FrameTerms:
    """The per-frame pieces of a bridge's objective for some of its window frames
    (positions ``idx`` in the window): their Gauss–Newton terms, energies, gradients, factors
    and products. :class:`SeamBridge` sums and couples them; with ``split`` the frames are
    shared between this process and one forked worker (:class:`_SplitTerms`)."""

    def __init__(self, problem, idx):
        self.idx = list(idx)
        self.gn, self.T = problem.gn, problem.T
        self.targets = [problem.targets[i] for i in self.idx]
        self.weights = [problem.weights[i] for i in self.idx]
        self.tubes = [problem.tubes[i] for i in self.idx]
        self.floors = [problem.floors[i] for i in self.idx]
        self.M3, self.free = problem.M3, problem.free
        self._J, self._w, self._chol = [], [], []

    def evaluate(self, Xs):
        """Energies and ``Jᵀ W ρ`` of the frames ``Xs (q, 3n)``; keeps their ``J, W``."""
        self._J, self._w, out = [], [], []
        for i, x in enumerate(Xs):
            J, z = lta_jacobian(x.reshape(-1, 3), self.T, return_values=True)
            f, r, w = self.gn.merit(z, self.targets[i], self.weights[i], self.tubes[i])
            self._J.append(J)
            self._w.append(w)
            out.append((f, J.T @ (w * r)))
        return out

    def collapsed(self, Xs) -> bool:
        """Whether a triangle of a frame ``Xs (q, 3n)`` is below its no-collapse floor."""
        return not all(np.all(face_areas(x.reshape(-1, 3), self.T) > fl)
                       for x, fl in zip(Xs, self.floors))

    def energies(self, Xs) -> list:
        """The frames' energies at ``Xs (q, 3n)`` (no Jacobian)."""
        return [self.gn.merit(lta_descriptors(x.reshape(-1, 3), self.T), self.targets[i],
                              self.weights[i], self.tubes[i])[0] for i, x in enumerate(Xs)]

    def trial(self, Xs):
        """The frames' energies at ``Xs (q, 3n)``, or None where a triangle collapsed."""
        return None if self.collapsed(Xs) else self.energies(Xs)

    def diag_means(self) -> list:
        """Mean diagonal of each frame's Gauss–Newton matrix over the free coordinates."""
        return [float((J.multiply(J).T @ w)[self.free].mean()) for J, w in zip(self._J, self._w)]

    def factor(self, coefs) -> None:
        """Factor each frame's Gauss–Newton block plus ``coefs[i] M`` (its share of the
        penalty) and the damping on the diagonal."""
        free, gn = self.free, self.gn
        self._chol = []
        for J, w, c in zip(self._J, self._w, coefs):
            H = (J.T @ sp.diags(w) @ J).tocsc()
            d = c * self.M3 + gn.damping * H.diagonal()[free].mean()
            self._chol.append(SparseCholesky(H + sp.diags(np.where(free, d, 1.0)),
                                             backend=gn.backend))

    def matvec(self, Vs) -> list:
        """``Jᵀ W J v`` of each frame."""
        return [J.T @ (w * (J @ v)) for J, w, v in zip(self._J, self._w, Vs)]

    def precond(self, Vs) -> list:
        """Each frame's factor applied to its part of ``Vs``."""
        return [c.solve(v) for c, v in zip(self._chol, Vs)]


#: the worker's share of a split bridge and the shared memory of its vectors (both inherited
#: through fork)
_REMOTE: dict = {}


def _remote_init():
    from .reconstruction import single_blas_thread

    _REMOTE["blas"] = single_blas_thread()


def _remote_call(name, with_input, extra):
    """Run ``_FrameTerms.<name>`` on the worker's frames, its vector input read from and its
    vector output written to the shared buffers; returns the rest (energies, flags)."""
    inp, out = _REMOTE["io"]
    res = getattr(_REMOTE["terms"], name)(*(((inp,) if with_input else ()) + tuple(extra)))
    if name == "evaluate":
        out[:] = [g for _, g in res]
        return [f for f, _ in res]
    if name in ("matvec", "precond"):
        out[:] = res
        return None
    return res


class _SplitTerms:
    """:class:`_FrameTerms` of the first frames here and of the others in a forked worker:
    each call is sent to the worker first, computed here meanwhile, then joined (the same
    arithmetic as one process, so the same result to the bit). Vectors pass through memory
    shared with the worker (``io``: its input and output rows): pickled through the pool,
    two frames of the horse (8.4k vertices) cost 2.8 ms a round trip against 0.15 ms for a
    bare message, several times per CG iteration."""

    def __init__(self, local, pool, io):
        self.local, self.pool, self.h = local, pool, len(local.idx)
        self.inp, self.out = io

    def _both(self, name, parts=None):
        if parts is not None:
            np.copyto(self.inp, parts[self.h:])
        fut = self.pool.submit(_remote_call, name, parts is not None, ())
        mine = getattr(self.local, name)(*(() if parts is None else (parts[:self.h],)))
        return mine, fut.result()

    def evaluate(self, Xs):
        a, fs = self._both("evaluate", Xs)
        return a + [(f, g.copy()) for f, g in zip(fs, self.out)]

    def trial(self, Xs):
        a, b = self._both("trial", Xs)
        return None if a is None or b is None else a + b

    def diag_means(self):
        a, b = self._both("diag_means")
        return a + b

    def factor(self, coefs):
        fut = self.pool.submit(_remote_call, "factor", False, (coefs[self.h:],))
        self.local.factor(coefs[:self.h])
        fut.result()

    def matvec(self, Vs):
        a, _ = self._both("matvec", Vs)
        return a + list(self.out.copy())

    def precond(self, Vs):
        a, _ = self._both("precond", Vs)
        return a + list(self.out.copy())


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
        self._ops = _FrameTerms(self, range(len(U)))
        self.terms(X)
        self.mu = beta * np.mean(self._ops.diag_means())

    def terms(self, X) -> list:
        """Per window frame ``(f, Jᵀ W_eff r_eff)`` at the context frames ``X (c, 3n)``
        (:meth:`GaussNewton.merit`); the frames' ``J`` and ``W_eff`` are kept for the
        factors and products of the next Gauss–Newton step."""
        return self._ops.evaluate(X[self.iu])

    def penalty(self, X) -> float:
        """``Σ_j ‖V_{j+1} − 2 V_j + V_{j−1}‖²_M`` over the context frames ``X (c, 3n)``."""
        acc = self.D @ X
        return float(np.einsum("jd,d,jd->", acc, self.M3, acc))

    def value(self, X, terms=None) -> float:
        """The objective ``Φ`` at the context frames ``X (c, 3n)``; inf where a window
        frame's triangle is below the no-collapse floor."""
        if terms is None:
            fs = self._ops.trial(X[self.iu])
            if fs is None:
                return np.inf
            terms = [(f,) for f in fs]
        return sum(t[0] for t in terms) + self.mu * self.penalty(X)

    def half_gradient(self, X, terms=None) -> np.ndarray:
        """Half the gradient of ``Φ`` with respect to the window frames, ``(u, 3n)`` (zero on
        pinned coordinates)."""
        terms = self.terms(X) if terms is None else terms
        DX = self.DtD @ X
        g = np.stack([gr + self.mu * self.M3 * DX[j] for (f, gr), j in zip(terms, self.iu)])
        g[:, ~self.free] = 0.0
        return g

    def _factors(self):
        """Factor each window frame's Gauss–Newton block (at the last :meth:`terms`) with its
        share of the penalty (the preconditioner)."""
        self._ops.factor([self.mu * self.DtD[j, j] for j in self.iu])

    def solve(self, dtol: float = BRIDGE_DTOL, max_iter: int = BRIDGE_MAX_ITER,
              split: bool = False) -> BridgeResult:
        """Gauss–Newton on ``Φ`` from :attr:`X0`: each step by CG on the joint system,
        preconditioned by the frames' blocks, then the line search with the no-collapse
        guard; converged when the decrement is below ``dtol`` times ``Φ`` or the gradient
        below the solver's ``gtol`` times the first.

        ``split``: share the window's frames with one forked worker process (their
        Jacobians, factors, products and energies; the result is the same to the bit). A
        bridge is a few Gauss–Newton steps of its whole window, and without this the second
        core idles while a single seam is bridged (:func:`~.reconstruction.bridge_seams`).
        Where processes cannot be forked, or the window has one frame, it runs here."""
        from ..parallel import process_pool, start_method

        if not (split and len(self.iu) > 1 and start_method() == "fork"):
            return self._solve(dtol, max_iter)
        serial = self._ops
        nu = len(self.iu)
        h = (nu + 1) // 2
        size = (nu - h) * self.X0.shape[1]
        buf = mmap.mmap(-1, 2 * 8 * size)  # anonymous and shared with the forked worker
        io = tuple(np.frombuffer(buf, dtype=np.float64, count=size, offset=8 * size * i)
                   .reshape(nu - h, -1) for i in (0, 1))
        _REMOTE.update(terms=_FrameTerms(self, range(h, nu)), io=io)
        try:
            with process_pool(1, _remote_init, method="fork") as ex:
                self._ops = _SplitTerms(_FrameTerms(self, range(h)), ex, io)
                return self._solve(dtol, max_iter)
        finally:
            self._ops = serial
            _REMOTE.pop("terms", None)
            _REMOTE.pop("io", None)  # the buffer is unmapped with its last view

    def _solve(self, dtol: float, max_iter: int) -> BridgeResult:
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
        self._factors()
        res.factorizations += nu
        ops = self._ops
        E = self.T.E
        Xe = X[iu[0]].reshape(-1, 3)
        h = float(np.mean(np.linalg.norm(Xe[E[:, 1]] - Xe[E[:, 0]], axis=1)))
        Duu = self.DtD[np.ix_(iu, iu)]
        for it in range(1, max_iter + 1):
            def matvec(v):
                V_ = v.reshape(nu, -1)
                out = np.stack(ops.matvec(V_))
                out += self.mu * self.M3 * (Duu @ V_)
                out[:, ~free] = 0.0
                return out.ravel()

            def precond(v):
                out = np.stack(ops.precond(v.reshape(nu, -1)))
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
                self._factors()
                res.factorizations += nu
        else:
            res.status = "limit"
            res.message = f"iteration limit ({max_iter}) reached"
        res.V = X[iu].reshape(nu, n, 3)
        res.energies = np.array([t[0] for t in terms])
        return res


def bridge_seam(gn, frame_of, K: int, s: int, a: int, b: int, Z, W_of, *,
                half: int = BRIDGE_HALF, beta: float = BRIDGE_BETA, dtol: float = BRIDGE_DTOL,
                max_iter: int = BRIDGE_MAX_ITER, tube_of=None,
                split: bool = False) -> BridgeResult | None:
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
    split : bool
        Share the window's frames with one forked worker (:meth:`SeamBridge.solve`).

    Returns
    -------
    BridgeResult or None
        None when the gap has no frame to re-solve.
    """
    problem = SeamBridge(gn, frame_of, K, s, a, b, Z, W_of, half=half, beta=beta,
                         tube_of=tube_of)
    if not len(problem.frames):
        return None
    return problem.solve(dtol=dtol, max_iter=max_iter, split=split)

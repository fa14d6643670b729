"""Models of the nonlinear spline energy near an iterate: Hessian products, preconditioners,
the LΘA retraction and the step cap.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from ...errors import ShellsplineError, tol
from ...numerics.linalg import SparseCholesky
from ..descriptors import edge_lengths, lta_jacobian, lta_weights
from ..reconstruct import GaussNewton
from .problem import NonlinearSplineProblem

__all__ = ["GaussNewtonModel", "LTARetraction", "MODEL_REFINE", "ModelPreconditioner",
           "SpaceTimePreconditioner", "project_rigid", "step_cap"]

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
MODEL_REFINE = 2


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
        self._h = 1e-6 * (step_cap(prob, S, 1.0) if np.isfinite(step_cap(prob, S, 1.0))
                          else 1.0)

    @property
    def h(self) -> float:
        """Finite-difference step (coordinates) of :meth:`exact_matvec` and
        :meth:`accurate_matvec`; setting it drops the products cached at the model point."""
        return self._h

    @h.setter
    def h(self, value) -> None:
        self._h = float(value)
        self._base = self._cbase = None

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
        :class:`SpaceTimePreconditioner`, ``xᵀHy`` and ``yᵀHx`` differed by 2.5×, and a 10×
        smaller ``h`` changed ``Hx`` by 350× its norm. :meth:`accurate_matvec` fixes both at
        about twice the cost; far from the minimiser this cheaper, stiffer product makes the
        faster progress (see :data:`MODEL_REFINE`), so the trust region's first phase uses it.
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
        dlt = self.h / max(float(np.abs(p).max()), tol.zero)
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
        region (:class:`~shellspline.shells.nonlinear.optimizers.TrustRegionNewton`).
        """
        self.prob.check_time()
        prob = self.prob
        W = prob.energy
        S, n = self.S, prob.n
        V = self._full(x)
        out = np.zeros_like(V)
        if self._cbase is None:
            self._cbase = [None] * len(prob.terms)
        DM, eps, Sp = self._perturbation(V, refine=MODEL_REFINE)
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
                q = prob.solver.solve_factored(ctx, r[None], refine=MODEL_REFINE)[0]
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


class ModelPreconditioner:
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
        return project_rigid(X, Q).ravel()


class SpaceTimePreconditioner:
    """The LΘA Gauss–Newton Hessian of the spline energy in space and time, factored whole.

    ``P = 4K³ Σ_t D_tᵀ Φ_t D_t`` with ``D_t = −½ J_a, J_k, −½ J_b`` (the descriptor
    Jacobians of the term's three shells at their current poses, restricted to the free
    nodes and DOFs) and ``Φ_t = 2 diag(w(s_k))`` the LΘA weights (paper eq. 10) at its
    centre shell: the Hessian of ``Σ_t ‖z(s_k) − ½(z(s_a) + z(s_b))‖²_w``, which
    approximates ``F^K`` to second order. Unlike :class:`ModelPreconditioner` (one elastic
    Hessian per term applied to all three of its shells) each shell's increment is measured
    in its own descriptors, so motions that rotate parts of the shells from frame to frame
    are priced right. One sparse Cholesky factorization of a matrix of
    ``(free frames × free DOFs)²`` (50k unknowns, 8.4M nonzeros, ~4 s on the 1000-vertex
    cactus; a solve ~0.08 s). Measured there at ``‖∇F‖ = 2e-2 ‖∇F₀‖``: preconditioned
    spectrum of the exact Hessian 1e-3–3.4 against 0.017–41 with :class:`ModelPreconditioner`,
    CG residual 0.02 after 60 iterations against 0.4. Relative shift ``1e-8`` for the rigid
    motions of unpinned shells (projected out by :meth:`apply`).
    """

    def __init__(self, prob: NonlinearSplineProblem, S, shift: float = 1e-8):
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
        return project_rigid(X, Q).ravel()


def project_rigid(X, Q):
    """Remove the rigid-motion components ``Q[i]`` from the rows ``X[i]`` (in place)."""
    if Q is not None:
        for i, q in enumerate(Q):
            if q.shape[1]:
                X[i] -= q @ (q.T @ X[i])
    return X


class LTARetraction:
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
        W = prob.energy
        self.prob = prob
        self.T = W.T
        self.w = lta_weights(S0[prob.frames[0]], W.T, mu=max(W.mu, 1e-12),
                             lam=max(W.lam, 1e-12), eta=max(W.eta, 1e-12))
        self.gn = GaussNewton(W.T, pinned=prob.pinned, max_iter=20)

    def __call__(self, S, D) -> np.ndarray:
        """Node poses ``R(S[k], D[k])`` for the free nodes (others unchanged)."""
        out = S + D
        for k in self.prob.free_nodes:
            self.prob.check_time()
            J, z = lta_jacobian(S[k], self.T, return_values=True)
            r = self.gn.solve(z + J @ D[k].ravel(), self.w, S[k] + D[k])
            if np.all(np.isfinite(r.V)):
                out[k] = r.V
        return out


def step_cap(prob, S0, factor):
    """``factor`` mean edge lengths of the first keyframe (cap of a trial step's largest
    coordinate change), infinite for energies without a mesh."""
    if not hasattr(prob.energy, "T"):
        return np.inf
    return factor * float(np.mean(edge_lengths(S0[prob.frames[0]], prob.energy.T)))

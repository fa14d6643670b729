"""Second-order steps of the LΘA reconstruction (:meth:`GaussNewton.subspace_step`): the
gradient and Hessian products it uses against finite differences and against the exact Hessian
assembled from the element Hessians of :mod:`shellspline.shells.energy`, the step against the
minimiser of the model, and the iteration counts on large- and zero-residual problems."""
import numpy as np
import pytest

from data_synth import stress
from shellspline import GaussNewton, topology
from shellspline.shells.descriptors import lta_descriptors, lta_jacobian, lta_weights, wrap_angle
from shellspline.shells.energy import (dihedral_angle_hessians, edge_length_hessians,
                                       face_area_hessians)


@pytest.fixture(scope="module")
def problem():
    """A strip folded to within 4° of ±π (fold_over's last pose), perturbed; targets with
    angles wrapped across ±π and faces compressed below their target area (the barrier)."""
    d = stress.fold_over()
    T = topology(d["F"])
    rng = np.random.default_rng(3)
    V = d["V"][2] + 0.01 * rng.standard_normal(d["V"][2].shape)
    z = lta_descriptors(V, T)
    sL, sT, sA = T.descriptor_slices()
    zt = z.copy()
    zt[sL] *= 1 + 0.05 * rng.standard_normal(T.n_edges)
    zt[sT] = wrap_angle(zt[sT] + 0.2 * rng.standard_normal(T.n_interior))
    zt[sA] *= rng.uniform(0.8, 1.5, T.n_faces)
    w = lta_weights(d["V"][0], T)
    assert np.abs(z[sT]).max() > np.pi - 0.1               # angles near ±π ...
    assert np.any(np.abs(z[sT] - zt[sT]) > np.pi)          # ... whose residuals wrap
    assert np.mean(z[sA] < zt[sA]) > 0.3                   # compressed faces: the barrier
    return T, V.ravel(), zt, w


def _exact_half_hessian(gn, x, zt, w):
    """``½ ∇²f`` assembled densely: ``Jᵀ diag(w φ'² + w ρ φ'') J + Σ w ρ φ' ∇²z``, with
    ``ρ = φ(z)`` the residual of :meth:`GaussNewton.merit` (``φ(a) = (a − a*)√(a*/a)`` for a
    compressed face) and the element Hessians of :mod:`shellspline.shells.energy`."""
    T = gn.T
    V = x.reshape(-1, 3)
    J, z = lta_jacobian(V, T, return_values=True)
    _, r, w_eff = gn.merit(z, zt, w)
    c = w_eff * r                                          # w ρ φ'
    sL, sT, sA = T.descriptor_slices()
    a, at = z[sA], zt[sA]
    comp = (a < at) & (a > 0)
    rho = (a - at) * np.sqrt(at / a)
    phi2 = -0.25 * np.sqrt(at) * a ** -2.5 * (a + 3 * at)  # φ''(a)
    wd = w_eff.copy()
    wd[sA] += np.where(comp, w[sA] * rho * phi2, 0.0)
    Jd = J.toarray()
    H = Jd.T @ (wd[:, None] * Jd)
    for idx, Hk, ck in ((T.E, edge_length_hessians(V, T.E), c[sL]),
                        (T.flaps, dihedral_angle_hessians(V, T.flaps), c[sT]),
                        (T.F, face_area_hessians(V, T.F), c[sA])):
        dofs = (3 * idx[:, :, None] + np.arange(3)).reshape(len(idx), -1)
        np.add.at(H, (dofs[:, :, None], dofs[:, None, :]), ck[:, None, None] * Hk)
    return H


def test_barrier_second_derivative():
    # φ'' used by the exact Hessian above, against central differences of φ
    at, a, h = 2.0, 1.3, 1e-4
    phi = lambda a: (a - at) * np.sqrt(at / a)  # noqa: E731
    fd = (phi(a + h) - 2 * phi(a) + phi(a - h)) / h ** 2
    assert abs(-0.25 * np.sqrt(at) * a ** -2.5 * (a + 3 * at) - fd) < 1e-6


def test_half_gradient_is_half_the_gradient_of_the_merit(problem):
    T, x, zt, w = problem
    gn = GaussNewton(T)
    g = gn.half_gradient(x, zt, w)
    f = lambda y: gn.merit(lta_descriptors(y.reshape(-1, 3), T), zt, w)[0]  # noqa: E731
    rng = np.random.default_rng(0)
    for _ in range(3):
        v = rng.standard_normal(x.shape)
        h = 1e-7  # small: f'' jumps where a face crosses its target area (the barrier is C¹)
        fd = (f(x + h * v) - f(x - h * v)) / (2 * h)
        assert abs(2 * g @ v - fd) <= 1e-6 * abs(fd)


def test_exact_hessian_matches_differences_of_the_gradient(problem):
    # the composition of the Hessian (Gauss–Newton part, barrier curvature, the dropped term
    # Σ w ρ φ' ∇²z) against central differences of the gradient; the dropped term is large
    T, x, zt, w = problem
    gn = GaussNewton(T)
    H = _exact_half_hessian(gn, x, zt, w)
    J = lta_jacobian(x.reshape(-1, 3), T)
    _, r, w_eff = gn.merit(lta_descriptors(x.reshape(-1, 3), T), zt, w)
    rng = np.random.default_rng(1)
    for _ in range(3):
        v = rng.standard_normal(x.shape)
        h = 1e-6
        fd = (gn.half_gradient(x + h * v, zt, w) - gn.half_gradient(x - h * v, zt, w)) / (2 * h)
        assert np.linalg.norm(H @ v - fd) <= 1e-6 * np.linalg.norm(fd)
        gauss_newton = J.T @ (w_eff * (J @ v))
        assert np.linalg.norm(H @ v - gauss_newton) > 0.05 * np.linalg.norm(fd)


def test_subspace_step_minimises_the_model_on_the_plane(problem):
    T, x, zt, w = problem
    gn = GaussNewton(T)
    H = _exact_half_hessian(gn, x, zt, w)
    g = gn.half_gradient(x, zt, w)
    h = 0.05  # about the strip's edge length
    # a Gauss–Newton-like descent direction and a previous step with its exact secant
    lam, U = np.linalg.eigh(H)
    assert lam.min() < 0 < lam.max()  # indefinite: only the model on the plane is convex
    P = U @ np.diag(1.0 / np.maximum(np.abs(lam), 1e-3 * lam.max())) @ U.T
    p = -P @ g
    s = np.random.default_rng(2).standard_normal(x.shape) * 1e-3
    s = s - U[:, lam < 0] @ (U[:, lam < 0].T @ s)  # a convex plane
    d = gn.subspace_step(x, g, p, s, H @ s, zt, w, h)
    model_grad = g + H @ d
    scale = np.linalg.norm(g)
    assert abs(model_grad @ p) <= 1e-5 * scale * np.linalg.norm(p)
    assert abs(model_grad @ s) <= 1e-5 * scale * np.linalg.norm(s)
    assert g @ d < 0
    # no previous step: p rescaled to the model's minimum along it
    d1 = gn.subspace_step(x, g, p, None, None, zt, w, h)
    assert np.allclose(d1, p * (-(g @ p) / (p @ H @ p)), rtol=1e-5, atol=0)


def _blend_problem(case, t):
    """Reconstruct an in-between of a stress case from the linear blend of its first two
    keyframes' descriptors (not integrable: a large residual when they differ much),
    starting from the linear blend of their positions."""
    d = case()
    T = topology(d["F"])
    V = d["V"]
    z = (1 - t) * lta_descriptors(V[0], T) + t * lta_descriptors(V[1], T)
    return T, d["pinned"], z, lta_weights(V[0], T), (1 - t) * V[0] + t * V[1]


@pytest.mark.parametrize("case,t,gn_iters,sub_iters", [(stress.joint, 0.7, 14, 7),
                                                       (stress.slivers, 0.5, 33, 14)])
def test_subspace_steps_converge_in_fewer_iterations_at_a_large_residual(case, t, gn_iters,
                                                                          sub_iters):
    # a tube flexing 0 -> 150° at its joint, 70 % of the way: measured 14 Gauss–Newton
    # iterations against 7 with subspace steps; the same tube with sliver rings, halfway:
    # 33 against 14 (19 when only the secant-curvature test chose subspace steps, before
    # SUBSPACE_RATE)
    T, pinned, z, w, V0 = _blend_problem(case, t)
    a = GaussNewton(T, pinned=pinned, subspace=False).solve(z, w, V0)
    b = GaussNewton(T, pinned=pinned, subspace=True).solve(z, w, V0)
    assert a.success and b.success, (a.message, b.message)
    assert a.nit >= gn_iters - 2 and b.nit <= sub_iters + 2
    # as low an energy (the slivers: 2e-5 lower; Gauss–Newton stops at its decrement
    # test while its linear tail still has that much to go)
    assert b.energy <= (1 + 1e-5) * a.energy and a.energy <= (1 + 1e-4) * b.energy
    assert a.energy > 1e-3 * a.energies[0]  # a large residual at the solution


def test_subspace_steps_leave_zero_residual_problems_alone():
    # a fold the keyframes themselves make (integrable targets): Gauss–Newton converges fast
    # and its steps are kept (the secant curvature matches its model)
    T, pinned, z, w, V0 = _blend_problem(stress.fold_over, 0.3)
    a = GaussNewton(T, pinned=pinned, subspace=False).solve(z, w, V0)
    b = GaussNewton(T, pinned=pinned, subspace=True).solve(z, w, V0)
    assert a.success and b.success
    assert b.nit == a.nit
    assert b.energy <= 1e-9 * b.energies[0]

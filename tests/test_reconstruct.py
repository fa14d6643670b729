import numpy as np
import pytest

from shellspline import GaussNewton, reconstruct, rigid_placement, topology
from shellspline._linalg import SparseCholesky, available_backends
from shellspline.descriptors import face_areas, lta_descriptors, lta_weights
from conftest import grid_sheet, icosphere


def _rotation(seed):
    Q, _ = np.linalg.qr(np.random.default_rng(seed).standard_normal((3, 3)))
    return Q * np.sign(np.linalg.det(Q))


def test_rigid_placement_recovers_rigid_motion():
    V, _ = icosphere(1)
    V = V * [1, 2, 3]
    R = _rotation(0)
    Y = V @ R.T + [0.5, -1, 2]
    assert np.allclose(rigid_placement(V, Y), Y, atol=1e-12)


@pytest.mark.parametrize("backend", available_backends())
def test_describe_then_reconstruct_recovers_shape(backend):
    V, F = icosphere(2)
    V = V * [1.0, 1.5, 0.8]
    T = topology(F)
    z, w = lta_descriptors(V, T), lta_weights(V, T, eta=1e-2)
    rng = np.random.default_rng(1)
    V0 = (V + 0.03 * rng.standard_normal(V.shape)) @ _rotation(2).T
    res = reconstruct(z, w, V0, T, backend=backend, gtol=1e-10, ftol=1e-14)
    assert res.success, res.message
    assert np.abs(lta_descriptors(res.V, T) - z).max() < 1e-6
    # equal to the original up to a rigid motion
    assert np.abs(rigid_placement(res.V, V) - V).max() < 1e-6
    # the energy never increases
    assert np.all(np.diff(res.energy) <= 1e-15 * res.energy[0])


def test_backends_agree():
    if len(available_backends()) < 2:
        pytest.skip("only one factorization backend installed (cvxopt missing)")
    V, F = icosphere(2)
    T = topology(F)
    z, w = lta_descriptors(V * [1, 1.3, 1], T), lta_weights(V, T)
    a = reconstruct(z, w, V, T, backend="cholmod", gtol=1e-10, ftol=1e-14)
    b = reconstruct(z, w, V, T, backend="splu", gtol=1e-10, ftol=1e-14)
    assert np.abs(rigid_placement(a.V, b.V) - b.V).max() < 1e-6  # equal up to a rigid motion


def test_pinned_vertices_stay_and_remove_the_kernel():
    V, F = grid_sheet(7, 6)
    T = topology(F)
    # target: the sheet bent into a cylinder arc (isometric); pin the two left columns (one
    # column alone would leave a hinge rotation free), start from the flat sheet elsewhere
    theta = V[:, 0] * 1.2
    Vt = np.stack([np.sin(theta) / 1.2, V[:, 1], (1 - np.cos(theta)) / 1.2], axis=1)
    z, w = lta_descriptors(Vt, T), lta_weights(V, T, eta=1e-2)
    pinned = np.flatnonzero(V[:, 0] < 0.2)
    V0 = V.copy()
    V0[pinned] = Vt[pinned]
    res = GaussNewton(T, pinned=pinned, gtol=1e-10, ftol=1e-14).solve(z, w, V0)
    assert res.success, res.message
    assert np.array_equal(res.V[pinned], Vt[pinned])
    assert np.abs(res.V - Vt).max() < 1e-5  # pins fix the rigid motion: exact positions


def test_negative_targets_get_zero_weight():
    V, F = icosphere(1)
    T = topology(F)
    z, w = lta_descriptors(V, T), lta_weights(V, T)
    sL, sT, sA = T.descriptor_slices()
    z[sL.start] = -0.1
    z[sA.start] = -0.2
    res = reconstruct(z, w, V * 1.05, T)
    assert np.all(np.isfinite(res.V))
    assert res.success
    assert np.all(face_areas(res.V, T) > 0)


def test_iteration_limit_is_reported():
    V, F = icosphere(2)
    T = topology(F)
    z, w = lta_descriptors(V * [1, 2, 1], T), lta_weights(V, T)
    res = reconstruct(z, w, V, T, max_iter=1)
    assert not res.success and res.nit == 1 and "limit" in res.message
    assert set(res.summary()) >= {"success", "nit", "message", "energy_final"}


def test_factorization_reused_across_frames():
    V, F = icosphere(2)
    T = topology(F)
    gn = GaussNewton(T)
    w = lta_weights(V, T)
    for s in (1.02, 1.04, 1.06):
        r = gn.solve(lta_descriptors(V * [s, 1, 1], T), w, V)
        assert r.success
    assert gn._chol.n_factorizations < 3 * 2


def test_sparse_cholesky_solves():
    import scipy.sparse as sp

    rng = np.random.default_rng(0)
    A = sp.random(60, 60, density=0.05, random_state=1)
    A = (A @ A.T + sp.eye(60)).tocsc()
    for backend in available_backends():
        C = SparseCholesky(A, backend=backend)
        b = rng.standard_normal(60)
        assert np.allclose(A @ C.solve(b), b)
        C.refactor(2 * A)
        assert np.allclose(2 * (A @ C.solve(b)), b)
    with pytest.raises(ValueError, match="backend"):
        SparseCholesky(A, backend="magic")


@pytest.mark.parametrize("fixed", [[3], [3, 7], [3, 7, 20]])
def test_rigid_placement_with_fixed_vertices(fixed):
    V, _ = icosphere(1)
    V = V * [1, 2, 3]
    fixed = np.array(fixed)
    P = V[fixed]
    if len(fixed) == 1:  # rotate about the point
        R = _rotation(3)
        X = (V - P[0]) @ R.T + P[0]
    else:  # rotate about the line through the first two pins
        u = (P[1] - P[0]) / np.linalg.norm(P[1] - P[0])
        K = np.array([[0, -u[2], u[1]], [u[2], 0, -u[0]], [-u[1], u[0], 0]])
        R = np.eye(3) + np.sin(0.7) * K + (1 - np.cos(0.7)) * K @ K
        X = (V - P[0]) @ R.T + P[0]
    X[fixed] = V[fixed]
    out = rigid_placement(X, V, fixed=fixed)
    assert np.array_equal(out[fixed], X[fixed])  # pins bit-identical
    if len(fixed) < 3:
        assert np.abs(out - V).max() < 1e-9  # the free rotation is undone
    else:
        assert np.array_equal(out, X)  # three non-collinear pins: nothing may move


def test_partial_pins_leave_no_free_spin():
    # two pins leave the rotation about their axis free: steps must not spin the mesh
    V, F = icosphere(2)
    T = topology(F)
    target = V * [1.2, 1.0, 0.9]
    z, w = lta_descriptors(target, T), lta_weights(V, T)
    res = GaussNewton(T, pinned=[0, 5]).solve(z, w, V)
    placed = rigid_placement(res.V, V, fixed=[0, 5])
    assert np.abs(placed - res.V).max() < 1e-3 * np.abs(V).max()

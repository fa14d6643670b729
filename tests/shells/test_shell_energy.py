"""Discrete Shells energy: values, invariances, and every derivative against central differences."""
from __future__ import annotations

import numpy as np
import pytest
from conftest import grid_sheet, icosphere

from shellspline.shells.descriptors import dihedral_angles, face_areas, edge_lengths
from shellspline.shells.energy import (DiscreteShells, EuclideanEnergy, dihedral_angle_hessians,
                                      edge_length_hessians, face_area_hessians, shell_energy,
                                      shell_energy_gradient, shell_energy_hessian)
from shellspline.mesh.topology import topology

H = 1e-6


def _rotation(rng):
    Q, R = np.linalg.qr(rng.standard_normal((3, 3)))
    Q = Q * np.sign(np.diag(R))
    return Q if np.linalg.det(Q) > 0 else -Q


def _cases():
    """(name, V, Vt, T): a perturbed sphere and a nearly flat sheet (near-flat dihedrals)."""
    rng = np.random.default_rng(0)
    V, F = icosphere(1)
    T = topology(F)
    Vs = V + 0.05 * rng.standard_normal(V.shape)
    Vts = 1.1 * V + 0.1 * rng.standard_normal(V.shape)
    S, Fs = grid_sheet(4, 3)
    Ts = topology(Fs)
    Sf = S + 1e-4 * rng.standard_normal(S.shape)      # dihedral angles ~ 1e-4: near flat
    Stf = 1.05 * S + np.array([0, 0, 1.0]) * 0.05 * rng.standard_normal((len(S), 1))
    return [("sphere", Vs, Vts, T), ("sheet", Sf, Stf, Ts)]


CASES = _cases()


def _fd_grad(f, x):
    g = np.zeros(x.size)
    for k in range(x.size):
        e = np.zeros(x.size)
        e[k] = H
        g[k] = (f(x + e) - f(x - e)) / (2 * H)
    return g


def _fd_jac(g, x):
    cols = []
    for k in range(x.size):
        e = np.zeros(x.size)
        e[k] = H
        cols.append((g(x + e) - g(x - e)) / (2 * H))
    return np.stack(cols, axis=1)


def _rel(a, b):
    return np.abs(a - b).max() / np.abs(b).max()


@pytest.mark.parametrize("name,V,Vt,T", CASES, ids=[c[0] for c in CASES])
def test_gradients_match_central_differences(name, V, Vt, T):
    W = DiscreteShells(T, mu=1.0, lam=0.7, eta=0.3)
    n = len(V)
    g0 = _fd_grad(lambda x: W.energy(x.reshape(n, 3), Vt), V.ravel())
    g1 = _fd_grad(lambda y: W.energy(V, y.reshape(n, 3)), Vt.ravel())
    assert _rel(W.gradient(V, Vt, 0), g0) < 1e-6
    assert _rel(W.gradient(V, Vt, 1), g1) < 1e-6


@pytest.mark.parametrize("name,V,Vt,T", CASES, ids=[c[0] for c in CASES])
def test_hessian_blocks_match_central_differences(name, V, Vt, T):
    W = DiscreteShells(T, mu=1.0, lam=0.7, eta=0.3)
    n = len(V)

    def grad(wrt, arg):
        if arg == 0:
            return lambda x: W.gradient(x.reshape(n, 3), Vt, wrt)
        return lambda y: W.gradient(V, y.reshape(n, 3), wrt)

    fd = {"11": _fd_jac(grad(0, 0), V.ravel()), "22": _fd_jac(grad(1, 1), Vt.ravel()),
          "12": _fd_jac(grad(0, 1), Vt.ravel()), "21": _fd_jac(grad(1, 0), V.ravel())}
    for block, ref in fd.items():
        Hb = W.hessian(V, Vt, block)
        assert Hb.shape == (3 * n, 3 * n)
        assert _rel(Hb.toarray(), ref) < 1e-6, block
    assert np.abs((W.hessian(V, Vt, "11") - W.hessian(V, Vt, "11").T)).max() < 1e-9
    assert np.abs((W.hessian(V, Vt, "21") - W.hessian(V, Vt, "12").T)).max() == 0
    v = np.random.default_rng(3).standard_normal(3 * n)
    assert np.allclose(W.mixed_product(V, Vt, v, "12"), W.hessian(V, Vt, "12") @ v)
    assert np.allclose(W.mixed_product(V, Vt, v, "21"), W.hessian(V, Vt, "21") @ v)


@pytest.mark.parametrize("name,V,Vt,T", CASES, ids=[c[0] for c in CASES])
def test_element_hessians_match_central_differences(name, V, Vt, T):
    n = len(V)
    for fun, hess, stencil in ((edge_lengths, edge_length_hessians, T.E),
                               (face_areas, face_area_hessians, T.F),
                               (dihedral_angles, dihedral_angle_hessians, T.flaps)):
        H_el = hess(V, stencil)
        s = stencil.shape[1]
        # dense Hessian of the sum of c_i * q_i with random coefficients
        c = np.random.default_rng(1).standard_normal(len(stencil))
        ref = _fd_jac(lambda x: _fd_free_grad(fun, x.reshape(n, 3), T, c), V.ravel())
        dofs = (3 * stencil[:, :, None] + np.arange(3)).reshape(len(stencil), 3 * s)
        A = np.zeros((3 * n, 3 * n))
        for i in range(len(stencil)):  # test-only assembly loop
            A[np.ix_(dofs[i], dofs[i])] += c[i] * H_el[i]
        assert _rel(A, ref) < 1e-5, fun.__name__


def _fd_free_grad(fun, V, T, c):
    """Analytic gradient of Σ c_i q_i via the verified descriptor Jacobian."""
    from shellspline.shells.descriptors import lta_jacobian

    J = lta_jacobian(V, T)
    sL, sT, sA = T.descriptor_slices()
    sl = {edge_lengths: sL, face_areas: sA, dihedral_angles: sT}[fun]
    return J[sl].T @ c


def test_dihedral_hessian_through_flat_configuration():
    """A single flap folded through θ = 0: the closed form is smooth and exact there."""
    F = np.array([[0, 1, 2], [1, 0, 3]])
    T = topology(F)
    for z in (0.3, 1e-7, 0.0, -1e-7, -0.3):
        V = np.array([[0.1, -0.05, 0.02], [1.0, 0.1, 0.0], [0.4, 0.9, 0.05], [0.6, -0.8, z]])
        Hd, G = dihedral_angle_hessians(V, T.flaps, return_gradients=True)
        ref = _fd_jac(lambda x: _fd_free_grad(dihedral_angles, x.reshape(4, 3), T, np.ones(1)),
                      V.ravel())
        assert _rel(Hd[0], ref) < 1e-6
        assert np.allclose(G[0], _fd_free_grad(dihedral_angles, V, T, np.ones(1)))


@pytest.mark.parametrize("name,V,Vt,T", CASES, ids=[c[0] for c in CASES])
def test_zero_at_identity_and_rigid_invariance(name, V, Vt, T):
    W = DiscreteShells(T, eta=0.2)
    assert W.energy(V, V) == 0.0
    assert np.abs(W.gradient(V, V, 1)).max() < 1e-12
    assert np.abs(W.gradient(V, V, 0)).max() < 1e-12
    rng = np.random.default_rng(5)
    R, t = _rotation(rng), rng.standard_normal(3)
    e = W.energy(V, Vt)
    assert e > 0
    assert np.isclose(W.energy(V @ R.T + t, Vt), e, rtol=1e-10)
    assert np.isclose(W.energy(V, Vt @ R.T + t), e, rtol=1e-10)
    # the gradient is orthogonal to infinitesimal rigid motions
    for wrt, P in ((0, V), (1, Vt)):
        g = W.gradient(V, Vt, wrt).reshape(-1, 3)
        assert np.abs(g.sum(axis=0)).max() < 1e-10 * np.abs(g).max() * len(g)
        assert np.abs(np.cross(P, g).sum(axis=0)).max() < 1e-10 * np.abs(g).max() * len(g)


def test_energy_terms_by_hand():
    """Uniform scaling by s: W_L = Σ d_e (1-s)², W_A = Σ a_t (1-s²)², W_Θ = 0."""
    V, F = icosphere(1)
    T = topology(F)
    s = 1.1
    A = face_areas(V, T)
    d = (A[T.edge_faces[:, 0]] + A[T.edge_faces[:, 1]]) / 3
    expected = 2.0 * d.sum() * (1 - s) ** 2 + 3.0 * (A * (1 - s ** 2) ** 2).sum()
    assert np.isclose(shell_energy(V, s * V, T, mu=2.0, lam=3.0, eta=5.0), expected, rtol=1e-12)


def test_wrappers_and_validation(sphere):
    V, F = sphere
    T = topology(F)
    Vt = 1.05 * V
    W = DiscreteShells(T, eta=0.01)
    assert np.allclose(shell_energy_gradient(V, Vt, T, eta=0.01, wrt=0), W.gradient(V, Vt, 0))
    assert np.allclose(shell_energy_hessian(V, Vt, T, eta=0.01, block="12").toarray(),
                       W.hessian(V, Vt, "12").toarray())
    with pytest.raises(ValueError, match="`block`"):
        W.hessian(V, Vt, "13")
    with pytest.raises(ValueError, match="`wrt`"):
        W.gradient(V, Vt, 2)
    with pytest.raises(ValueError, match="`Vt`"):
        W.energy(V, Vt[:-1])
    with pytest.raises(ValueError, match="`eta`"):
        DiscreteShells(T, eta=-1.0)
    with pytest.raises(ValueError, match="`V`"):
        W.energy(np.full_like(V, np.nan), Vt)


def test_euclidean_energy_interface():
    rng = np.random.default_rng(2)
    V, Vt = rng.standard_normal((2, 5, 3))
    E = EuclideanEnergy(5)
    assert np.isclose(E.energy(V, Vt), np.sum((V - Vt) ** 2))
    assert np.allclose(E.gradient(V, Vt, 0), 2 * (V - Vt).ravel())
    assert np.allclose(E.hessian(V, Vt, "12").toarray(), -2 * np.eye(15))
    assert np.allclose(E.hessian(V, Vt, "22").toarray(), 2 * np.eye(15))


@pytest.mark.parametrize("name,V,Vt,T", CASES, ids=[c[0] for c in CASES])
def test_elementwise_assembly_equals_sparse_chain_rule(name, V, Vt, T):
    """W,11 / W,22 are assembled element by element (flap blocks, boundary-edge face blocks);
    they must equal the chain rule J^T Phi J + sum_i (Phi_z)_i hess z_i through sparse products
    to round-off (sheet: boundary edges; sphere: none)."""
    from shellspline.shells.descriptors import lta_descriptors, lta_jacobian

    W = DiscreteShells(T, mu=1.0, lam=0.7, eta=0.3)
    zX, zY = lta_descriptors(V, T), lta_descriptors(Vt, T)
    for block, P, wrt in (("11", V, 0), ("22", Vt, 1)):
        J = lta_jacobian(P, T)
        Phi = W.descriptor_hessian(zX, zY, block).tocsr()
        ref = (J.T @ Phi @ J).toarray()
        c = W.descriptor_gradient(zX, zY, wrt)
        Hl = [edge_length_hessians(P, T.E), dihedral_angle_hessians(P, T.flaps),
              face_area_hessians(P, T.F)]
        sL, sT, sA = T.descriptor_slices()
        stencils = [T.E, T.flaps, T.F]
        for H, cc, st in zip(Hl, (c[sL], c[sT], c[sA]), stencils):
            dofs = (3 * st[:, :, None] + np.arange(3)).reshape(len(st), -1)
            for k in range(len(st)):  # reference assembly: a loop is fine on a test mesh
                ref[np.ix_(dofs[k], dofs[k])] += cc[k] * H[k]
        got = W.hessian(V, Vt, block).toarray()
        assert np.abs(got - ref).max() <= 1e-12 * np.abs(ref).max(), block


@pytest.mark.parametrize("name,V,Vt,T", CASES, ids=[c[0] for c in CASES])
def test_hessian_product_equals_the_assembled_blocks(name, V, Vt, T):
    """Matrix-free W,11 v / W,22 v (and weighted sums) equal the assembled blocks times v,
    which the FD tests above check; also for poses whose element Hessians are not cached."""
    W = DiscreteShells(T, mu=1.0, lam=0.7, eta=0.3)
    rng = np.random.default_rng(5)
    v = rng.standard_normal(V.size)
    H11 = W.hessian(V, Vt, "11").toarray()
    H22 = W.hessian(V, Vt, "22").toarray()
    scale = max(np.abs(H11).max(), np.abs(H22).max()) * np.abs(v).max()
    Wf = DiscreteShells(T, mu=1.0, lam=0.7, eta=0.3)  # fresh caches
    for blocks, weights, ref in ((("22",), None, H22 @ v), (("11",), None, H11 @ v),
                                 (("11", "22"), (0.5, -2.0), 0.5 * H11 @ v - 2.0 * H22 @ v)):
        got = Wf.hessian_product(V, Vt, v, blocks, weights)
        assert np.abs(got - ref).max() <= 1e-12 * scale, blocks
    with pytest.raises(ValueError, match="`blocks`"):
        W.hessian_product(V, Vt, v, ("12",))
    E = EuclideanEnergy(len(V))
    assert np.allclose(E.hessian_product(V, Vt, v, ("11", "22"), (1.0, 3.0)), 8.0 * v)


@pytest.mark.parametrize("name,V,Vt,T", CASES, ids=[c[0] for c in CASES])
def test_midpoint_hessian_is_the_sum_of_the_two_blocks(name, V, Vt, T):
    """W,22[s_a, m] + W,11[m, s_b] in one scatter equals the two blocks assembled apart
    (checked against finite differences above), boundary edges included (sheet)."""
    rng = np.random.default_rng(7)
    Va, M = V, Vt
    Vb = V + 0.3 * (Vt - V) + 0.02 * rng.standard_normal(V.shape)
    W = DiscreteShells(T, mu=1.0, lam=0.7, eta=0.3)
    ref = W.hessian_data(Va, M, "22") + W.hessian_data(M, Vb, "11")
    got = DiscreteShells(T, mu=1.0, lam=0.7, eta=0.3).midpoint_hessian_data(Va, M, Vb)
    assert np.abs(got - ref).max() <= 1e-12 * np.abs(ref).max()
    E = EuclideanEnergy(len(V))
    assert np.array_equal(E.midpoint_hessian_data(Va, M, Vb),
                          E.hessian_data(Va, M, "22") + E.hessian_data(M, Vb, "11"))


@pytest.mark.parametrize("name,V,Vt,T", CASES, ids=[c[0] for c in CASES])
def test_constraint_products_equal_the_assembled_blocks(name, V, Vt, T):
    """The fused midpoint-constraint products (W,12[s_a,m] p, (W,22[s_a,m] + W,11[m,s_b]) p,
    W,21[m,s_b] p) equal the assembled Hessian blocks (checked against finite differences
    above) times p."""
    rng = np.random.default_rng(6)
    Va, M = V, Vt
    Vb = V + 0.3 * (Vt - V) + 0.02 * rng.standard_normal(V.shape)
    p = rng.standard_normal(V.size)
    W = DiscreteShells(T, mu=1.0, lam=0.7, eta=0.3)
    ref = (W.hessian(Va, M, "12") @ p,
           W.hessian(Va, M, "22") @ p + W.hessian(M, Vb, "11") @ p,
           W.hessian(M, Vb, "21") @ p)
    got = DiscreteShells(T, mu=1.0, lam=0.7, eta=0.3).constraint_products(Va, M, Vb, p)
    for r, g, what in zip(ref, got, ("a", "m", "b")):
        assert np.abs(g - r).max() <= 1e-12 * np.abs(r).max(), what
    E = EuclideanEnergy(len(V))
    oracle = (E.hessian(Va, M, "12") @ p, (E.hessian(Va, M, "22") + E.hessian(M, Vb, "11")) @ p,
              E.hessian(M, Vb, "21") @ p)
    for r, g in zip(oracle, E.constraint_products(Va, M, Vb, p)):
        assert np.allclose(g, r, rtol=0, atol=1e-14)


# --------------------------------------------------------------------------------------
# Projected Newton: element Hessians projected onto the PSD cone
# --------------------------------------------------------------------------------------
def _chain(V, Vt, rng):
    """Four poses: both ends fixed, two inner ones far from the minimum (indefinite)."""
    return np.stack([V, Vt, V + 0.3 * (Vt - V) + 0.02 * rng.standard_normal(V.shape),
                     0.9 * Vt + 0.01 * rng.standard_normal(V.shape)])


def _dense_chain(W, diag, upper):
    import scipy.sparse as sp

    P = W.pattern
    m = len(diag)
    blocks = [[None] * m for _ in range(m)]
    for j in range(m):
        blocks[j][j] = P.matrix(diag[j])
    for j in range(m - 1):
        blocks[j][j + 1] = P.matrix(upper[j])
        blocks[j + 1][j] = P.matrix(upper[j]).T
    return sp.bmat(blocks).toarray()


def test_psd_projection_against_per_matrix_eigendecomposition():
    """Batched projection = scipy's eigh per matrix with the eigenvalues clamped (or made
    absolute); PSD matrices are returned bit-identical; the clamped one is the nearest PSD
    matrix in the Frobenius norm (closer than any other PSD matrix tried)."""
    import scipy.linalg

    from shellspline.errors import ShellsplineError
    from shellspline.shells.energy import psd_projected

    rng = np.random.default_rng(4)
    M = rng.standard_normal((40, 7, 7))
    M = M + M.transpose(0, 2, 1)
    M[:8] = np.matmul(M[:8], M[:8].transpose(0, 2, 1))           # PSD ones
    Pc, Pa = psd_projected(M, "clamp"), psd_projected(M, "abs")
    assert np.array_equal(Pc[:8], M[:8]) and np.array_equal(Pa[:8], M[:8])
    for k in range(len(M)):
        w, U = scipy.linalg.eigh(M[k])
        assert np.allclose(Pc[k], (U * np.maximum(w, 0)) @ U.T, atol=1e-12)
        assert np.allclose(Pa[k], (U * np.abs(w)) @ U.T, atol=1e-12)
        assert np.linalg.eigvalsh(Pc[k]).min() > -1e-12
        for _ in range(5):
            Q = rng.standard_normal((7, 7))
            Q = Pc[k] + 0.1 * Q @ Q.T                                 # another PSD matrix
            assert np.linalg.norm(M[k] - Pc[k]) <= np.linalg.norm(M[k] - Q)
    with pytest.raises(ShellsplineError, match="projection"):
        DiscreteShells(CASES[0][3]).chain_hessian_data(np.stack([CASES[0][1]] * 3), "neg")


@pytest.mark.parametrize("name,V,Vt,T", CASES, ids=[c[0] for c in CASES])
def test_chain_hessian_is_the_true_hessian_and_its_projection_is_psd(name, V, Vt, T):
    """The element-wise chain Hessian without projection equals the blocks checked against
    finite differences above (diagonal: W,22 + W,11, upper: W,12); boundary edges included
    (sheet). Projected, it is symmetric positive semi-definite although the true one is
    indefinite, and the "abs" matrix exceeds the "clamp" one by a PSD matrix."""
    rng = np.random.default_rng(1)
    S = _chain(V, Vt, rng)
    W = DiscreteShells(T, mu=1.0, lam=0.7, eta=0.3)
    diag, upper = W.chain_hessian_data(S)
    ref = [W.midpoint_hessian_data(S[0], S[1], S[2]), W.midpoint_hessian_data(S[1], S[2], S[3])]
    scale = np.abs(ref[0]).max()
    for got, want in zip(diag + upper, ref + [W.hessian_data(S[1], S[2], "12")]):
        assert np.abs(got - want).max() <= 1e-12 * scale
    H = _dense_chain(W, diag, upper)
    assert np.linalg.eigvalsh(H)[0] < -1e-2 * np.abs(H).max()     # truly indefinite
    Hc = _dense_chain(W, *W.chain_hessian_data(S, "clamp"))
    Ha = _dense_chain(W, *W.chain_hessian_data(S, "abs"))
    for P in (Hc, Ha):
        assert np.abs(P - P.T).max() <= 1e-12 * np.abs(P).max()
        assert np.linalg.eigvalsh(P)[0] >= -1e-12 * np.abs(P).max()
    assert np.linalg.eigvalsh(Ha - Hc)[0] >= -1e-12 * np.abs(Ha).max()
    E = EuclideanEnergy(len(V))
    d, u = E.chain_hessian_data(S, "clamp")
    assert np.array_equal(d[0], E.midpoint_hessian_data(S[0], S[1], S[2]))
    assert np.array_equal(u[0], E.hessian_data(S[1], S[2], "12"))


@pytest.mark.parametrize("name,V,Vt,T", CASES, ids=[c[0] for c in CASES])
def test_projection_leaves_psd_elements_unchanged(name, V, Vt, T):
    """Where every element's Hessian is PSD the projection is the identity: a chain of
    rigidly moved copies puts every element at its minimum (descriptor gradients 0, each
    element's descriptor Hessian PSD), so the projected matrix equals the true one; the
    first and last pose fixed, only the free part of an end element is projected."""
    rng = np.random.default_rng(2)
    S = np.stack([V @ _rotation(rng).T + rng.standard_normal(3) for _ in range(4)])
    W = DiscreteShells(T, mu=1.0, lam=0.7, eta=0.3)
    d0, u0 = W.chain_hessian_data(S)
    for projection in ("clamp", "abs"):
        d, u = W.chain_hessian_data(S, projection)
        scale = np.abs(d0[0]).max()
        for got, want in zip(d + u, d0 + u0):
            assert np.abs(got - want).max() <= 1e-12 * scale
    # one inner shell (a geodesic midpoint), both neighbours fixed: the same holds
    d, _ = W.chain_hessian_data(S[:3], "clamp")
    assert np.abs(d[0] - W.midpoint_hessian_data(*S[:3])).max() <= 1e-12 * scale

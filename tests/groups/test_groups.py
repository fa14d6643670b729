"""SO(3), SE(3) and the product groups: closed forms against scipy, properties, conversions."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import expm, logm
from scipy.spatial.transform import Rotation

from shellspline.errors import ShellsplineError
from shellspline.groups import SE3, SO3, SO3dR3, SO3xR3, group, karcher_mean, se3, so3

GROUPS = [SO3, SE3, SO3xR3, SO3dR3(3)]


def _rotvecs(rng, n, max_angle=np.pi):
    w = rng.normal(size=(n, 3))
    return w * (rng.uniform(0, max_angle, n) / np.linalg.norm(w, axis=1))[:, None]


def test_so3_exp_log_match_scipy_rotvec():
    rng = np.random.default_rng(0)
    w = _rotvecs(rng, 2000)
    R = so3.exp(w)
    np.testing.assert_allclose(R, Rotation.from_rotvec(w).as_matrix(), atol=1e-14)
    np.testing.assert_allclose(so3.log(Rotation.from_rotvec(w).as_matrix()), w, atol=1e-12)


@pytest.mark.parametrize("angle", [0.0, 1e-12, 1e-8, 1e-4, 1e-3, 0.999e-3, 1.0, 2.4999, 2.5,
                                   2.5001, np.pi - 1e-4, np.pi - 1e-8, np.pi - 1e-12])
def test_so3_log_exp_identity_near_0_and_pi(angle):
    rng = np.random.default_rng(1)
    a = rng.normal(size=(50, 3))
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    w = angle * a
    back = so3.log(so3.exp(w))
    np.testing.assert_allclose(back, w, atol=1e-10 if angle > 3 else 1e-13)
    np.testing.assert_allclose(so3.exp(back), so3.exp(w), atol=1e-14)


def test_so3_log_at_pi_is_the_documented_representative():
    rng = np.random.default_rng(2)
    a = rng.normal(size=(200, 3))
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    R = 2 * a[:, :, None] * a[:, None, :] - np.eye(3)  # rotation by exactly pi about a
    w = so3.log(R)
    np.testing.assert_allclose(np.linalg.norm(w, axis=1), np.pi, atol=1e-12)
    np.testing.assert_allclose(so3.exp(w), R, atol=1e-12)
    big = np.take_along_axis(w, np.argmax(np.abs(w), axis=1)[:, None], axis=1)
    assert np.all(big > 0)
    np.testing.assert_array_equal(so3.log(np.diag([1.0, -1.0, -1.0])), [np.pi, 0, 0])


def test_so3_angle_is_accurate_where_arccos_is_not():
    # rotation by 1e-9: arccos((tr R - 1)/2) returns 0 or ~2e-8; atan2 is exact
    R = so3.exp([1e-9, 0, 0])
    assert abs(so3.angle(R) - 1e-9) < 1e-20
    assert abs(so3.angle(so3.exp([0, np.pi - 1e-9, 0])) - (np.pi - 1e-9)) < 1e-15


def test_so3_jacobians_against_finite_differences():
    rng = np.random.default_rng(3)
    w = _rotvecs(rng, 300, 3.0)
    x = rng.normal(size=(300, 3))
    e = 1e-6
    fd = so3.vee(np.swapaxes(so3.exp(w), -1, -2) @ (so3.exp(w + e * x) - so3.exp(w - e * x))
                 / (2 * e))
    np.testing.assert_allclose(so3.jac_right(w, x), fd, atol=1e-8)
    np.testing.assert_allclose(so3.jac_right_inv(w, so3.jac_right(w, x)), x, atol=1e-12)
    small = 1e-5 * w
    np.testing.assert_allclose(so3.jac_right_inv(small, so3.jac_right(small, x)), x, atol=1e-14)


def test_se3_exp_log_match_matrix_exponential_and_logarithm():
    rng = np.random.default_rng(4)
    xi = np.concatenate([_rotvecs(rng, 60, 3.0), rng.normal(size=(60, 3)) * 2], axis=1)
    T = se3.exp(xi)
    for x, t in zip(xi, T):
        np.testing.assert_allclose(t, expm(se3.hat(x)), atol=1e-12)
        np.testing.assert_allclose(se3.vee(np.real(logm(t))), x, atol=1e-9)
    np.testing.assert_allclose(se3.log(T), xi, atol=1e-12)
    tiny = xi * 1e-9
    np.testing.assert_allclose(se3.log(se3.exp(tiny)), tiny, atol=1e-20)


def test_se3_adjoint_and_jacobian():
    rng = np.random.default_rng(5)
    xi = np.concatenate([_rotvecs(rng, 100, 3.0), rng.normal(size=(100, 3))], axis=1)
    x = rng.normal(size=(100, 6))
    T = se3.exp(xi)
    np.testing.assert_allclose(se3.hat(se3.adjoint(T, x)), T @ se3.hat(x) @ se3.inverse(T),
                               atol=1e-13)
    e = 1e-6
    fd = se3.vee(se3.inverse(T) @ (se3.exp(xi + e * x) - se3.exp(xi - e * x)) / (2 * e))
    np.testing.assert_allclose(se3.jac_right(xi, x), fd, atol=1e-8)
    np.testing.assert_allclose(se3.jac_right_inv(xi, se3.jac_right(xi, x)), x, atol=1e-12)


@pytest.mark.parametrize("G", GROUPS, ids=str)
def test_group_axioms_and_log_exp(G):
    rng = np.random.default_rng(6)
    xi = rng.normal(size=(40, G.dim))
    xi[:, :3] = _rotvecs(rng, 40, 3.0)
    a, b = G.exp(xi), G.exp(rng.normal(size=(40, G.dim)) * 0.8)
    np.testing.assert_allclose(G.log(a), xi, atol=1e-11)
    np.testing.assert_allclose(G.compose(a, G.inverse(a)), G.identity((40,)), atol=1e-13)
    np.testing.assert_allclose(G.compose(G.compose(a, b), G.inverse(b)), a, atol=1e-12)
    # interp endpoints and the midpoint halves the distance
    np.testing.assert_allclose(G.interp(a, b, 0.0), a, atol=1e-13)
    np.testing.assert_allclose(G.interp(a, b, 1.0), b, atol=1e-12)
    m = G.interp(a, b, 0.5)
    np.testing.assert_allclose(G.distance(a, m), G.distance(m, b), rtol=1e-10)
    G.check(a)


@pytest.mark.parametrize("G", GROUPS, ids=str)
def test_kernel_matches_matrix_operations(G):
    rng = np.random.default_rng(7)
    a, b = G.exp(rng.normal(size=(30, G.dim))), G.exp(rng.normal(size=(30, G.dim)))
    K = G.kernel()
    A, B = K.pack(a), K.pack(b)
    np.testing.assert_allclose(K.unpack(A), a, atol=1e-14)
    np.testing.assert_allclose(K.unpack(K.compose(A, B)), G.compose(a, b), atol=1e-13)
    np.testing.assert_allclose(K.unpack(K.inverse(A)), G.inverse(a), atol=1e-13)
    np.testing.assert_allclose(K.log(K.compose(K.inverse(A), B)).T, G.between(a, b), atol=1e-12)
    for s in (-0.3, 0.0, 0.37, 1.0, 1.6):
        np.testing.assert_allclose(K.unpack(K.interp(A, B, s)), G.interp(a, b, s), atol=1e-12)
    np.testing.assert_allclose(K.unpack(K.interp(A, A, 0.4)), a, atol=1e-14)  # zero angle


def test_quaternions_scalar_last_and_sign_continuity():
    rng = np.random.default_rng(8)
    w = _rotvecs(rng, 500)
    R = so3.exp(w)
    q = so3.quat_from_matrix(R)
    ref = Rotation.from_rotvec(w).as_quat()  # scipy is scalar-last too
    np.testing.assert_allclose(np.abs(np.einsum("ni,ni->n", q, ref)), 1, atol=1e-13)
    assert np.all(q[:, 3] >= 0)
    np.testing.assert_allclose(so3.matrix_from_quat(-q), R, atol=1e-14)
    # a slow turn by 3 full revolutions: file quaternions flip at every half turn, continuity
    # removes every flip and keeps the rotations
    ang = np.linspace(0, 6 * np.pi, 301)
    qs = so3.quat_from_matrix(so3.exp(ang[:, None] * [0, 0, 1.0]))
    assert np.any(np.einsum("ni,ni->n", qs[1:], qs[:-1]) < 0)
    qc = so3.quat_continuous(qs)
    assert np.all(np.einsum("ni,ni->n", qc[1:], qc[:-1]) > 0)
    np.testing.assert_allclose(so3.matrix_from_quat(qc), so3.matrix_from_quat(qs), atol=1e-14)


def test_so3dr3_pack_unpack():
    G = SO3dR3(2)
    rng = np.random.default_rng(9)
    R = so3.exp(rng.normal(size=(5, 2, 3)))
    p = rng.normal(size=(5, 3))
    Rb, pb = G.unpack(G.pack(R, p))
    np.testing.assert_array_equal(Rb, R)
    np.testing.assert_array_equal(pb, p)
    with pytest.raises(ShellsplineError, match="pack"):
        G.pack(R[:, :1], p)
    # the largest joint rotation, not the first one
    xi = np.r_[0.1, 0, 0, 0, 2.5, 0, 7.0, 7.0, 7.0]
    assert G.rotation_angle(xi) == pytest.approx(2.5)
    assert SE3.rotation_angle(np.r_[0, 0.3, 0.4, 9, 9, 9]) == pytest.approx(0.5)


@pytest.mark.parametrize("G", [SO3, SE3, SO3xR3], ids=str)
def test_karcher_mean_is_a_critical_point(G):
    rng = np.random.default_rng(10)
    g = G.exp(rng.normal(size=(7, G.dim)) * 0.4)
    w = rng.uniform(0.1, 1, 7)
    m = karcher_mean(G, g, w)
    np.testing.assert_allclose(np.einsum("i,ij->j", w, G.between(m[None], g)), 0, atol=1e-12)
    # left invariance: the mean of h g_i is h m
    h = G.exp(rng.normal(size=G.dim))
    np.testing.assert_allclose(karcher_mean(G, G.compose(h, g), w), G.compose(h, m), atol=1e-10)


def test_karcher_mean_of_rotations_about_one_axis_is_the_mean_angle():
    ang = np.array([0.1, 0.5, 1.3])
    m = karcher_mean("so3", so3.exp(ang[:, None] * [0, 1.0, 0]))
    np.testing.assert_allclose(so3.log(m), [0, ang.mean(), 0], atol=1e-13)


def test_invalid_inputs_raise_one_line_errors():
    with pytest.raises(ShellsplineError, match="group must be one of"):
        group("so4")
    with pytest.raises(ShellsplineError, match=r"X\[1\]: the matrix is not a rotation"):
        SO3.check(np.stack([np.eye(3), 2 * np.eye(3)]), "X")
    with pytest.raises(ShellsplineError, match="last row"):
        bad = np.eye(4)
        bad[3, 0] = 1
        SE3.check(bad)
    with pytest.raises(ShellsplineError, match=r"shape \(\.\.\., 3, 3\)"):
        SO3.check(np.eye(4))
    with pytest.raises(ShellsplineError, match="weights"):
        karcher_mean(SO3, np.stack([np.eye(3)] * 2), [1, -1])
    with pytest.raises(ShellsplineError, match="no convergence"):
        karcher_mean(SO3, so3.exp(np.array([[0, 0, 3.1], [0, 0, -3.1], [3.1, 0, 0]])),
                     max_iter=3)

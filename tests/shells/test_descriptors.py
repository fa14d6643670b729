import numpy as np
import pytest

from shellspline import topology
from shellspline.shells.descriptors import (dihedral_angles, edge_lengths, face_areas, lta_descriptors,
                                     lta_jacobian, lta_weights, unwrap_angles, wrap_angle)
from conftest import grid_sheet, icosphere


def _random_mesh(seed=0, noise=0.05):
    V, F = icosphere(2)
    rng = np.random.default_rng(seed)
    return V * [1.0, 1.4, 0.7] + noise * rng.standard_normal(V.shape), F


def test_cube_dihedral_angles_are_zero_or_right():
    import trimesh

    m = trimesh.creation.box()
    T = topology(m.faces, len(m.vertices))
    th = dihedral_angles(np.asarray(m.vertices), T)
    # diagonals of the square sides are flat, the cube's edges are convex right angles
    assert np.allclose(np.sort(np.abs(th)), np.sort(th))  # convex: non-negative
    assert np.isclose(th, 0, atol=1e-12).sum() == 6
    assert np.isclose(th, np.pi / 2, atol=1e-12).sum() == 12


def test_signed_angle_through_flat():
    F = np.array([[0, 1, 2], [1, 0, 3]])
    T = topology(F)
    for phi in np.linspace(-3.0, 3.0, 13):
        V = np.array([[0, 0, 0], [1, 0, 0], [0.3, 1, 0],
                      [0.6, -np.cos(phi), -np.sin(phi)]], dtype=float)
        assert np.isclose(dihedral_angles(V, T)[0], phi, atol=1e-12)


def test_lengths_areas_closed_forms():
    V = np.array([[0, 0, 0], [3, 0, 0], [0, 4, 0.0]])
    T = topology(np.array([[0, 1, 2]]))
    assert np.allclose(np.sort(edge_lengths(V, T)), [3, 4, 5])
    assert np.isclose(face_areas(V, T)[0], 6.0)


def test_batched_equals_single():
    V, F = _random_mesh()
    T = topology(F)
    Vs = np.stack([V, 1.3 * V, V[:, [1, 2, 0]]])
    Z = lta_descriptors(Vs, T)
    for k in range(3):
        assert np.allclose(Z[k], lta_descriptors(Vs[k], T))


@pytest.mark.parametrize("mesh", ["sphere", "sheet", "near_flat"])
def test_jacobian_matches_central_differences(mesh):
    if mesh == "sphere":
        V, F = _random_mesh(1)
    else:
        V, F = grid_sheet(6, 5)
        rng = np.random.default_rng(2)
        V = V + (1e-4 if mesh == "near_flat" else 0.05) * rng.standard_normal(V.shape)
    T = topology(F)
    J, z = lta_jacobian(V, T, return_values=True)
    assert np.array_equal(z, lta_descriptors(V, T))
    rng = np.random.default_rng(3)
    for _ in range(3):
        dV = rng.standard_normal(V.shape)
        h = 1e-6
        fd = (lta_descriptors(V + h * dV, T) - lta_descriptors(V - h * dV, T)) / (2 * h)
        an = J @ dV.ravel()
        assert np.abs(fd - an).max() <= 1e-6 * np.abs(an).max()


def test_invariances():
    V, F = _random_mesh(4)
    T = topology(F)
    z = lta_descriptors(V, T)
    Q, _ = np.linalg.qr(np.random.default_rng(5).standard_normal((3, 3)))
    Q *= np.sign(np.linalg.det(Q))
    assert np.allclose(lta_descriptors(V @ Q.T + [1, -2, 3], T), z)
    J = lta_jacobian(V, T).toarray()
    # rigid motions are in the kernel of J (6 dims): translations and infinitesimal rotations
    for a in range(3):
        t = np.zeros_like(V)
        t[:, a] = 1
        assert np.abs(J @ t.ravel()).max() < 1e-10
        w = np.zeros(3)
        w[a] = 1
        assert np.abs(J @ np.cross(w, V).ravel()).max() < 1e-9
    # mirroring flips the sign of the dihedral angles and keeps lengths/areas
    sL, sT, sA = T.descriptor_slices()
    zm = lta_descriptors(V * [-1, 1, 1], T)
    assert np.allclose(zm[sT], -z[sT]) and np.allclose(zm[sL], z[sL])


def test_unwrap_across_full_twist():
    th = np.linspace(0, 3 * np.pi, 10)[:, None] * [1.0, -1.0]
    wrapped = wrap_angle(th)
    assert np.abs(np.diff(wrapped, axis=0)).max() > np.pi  # it jumps
    assert np.allclose(unwrap_angles(wrapped), th)


def test_weights_closed_form():
    V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0.0]])
    F = np.array([[0, 1, 2], [2, 1, 3]])
    T = topology(F)
    w = lta_weights(V, T, mu=2.0, lam=3.0, eta=5.0)
    sL, sT, sA = T.descriptor_slices()
    a = 0.5
    diag = int(np.flatnonzero((T.E == [1, 2]).all(1))[0])
    L = edge_lengths(V, T)
    de = np.where(np.arange(T.n_edges) == diag, 2 * a / 3, a / 3)
    assert np.allclose(w[sL], 2.0 * de / L**2)
    assert np.allclose(w[sA], 3.0 / a)
    assert np.allclose(w[sT], 5.0 * 2.0 / (2 * a / 3))  # diagonal: l² = 2


def test_unwrap_keeps_a_flap_folding_through_pi_continuous():
    # one flap folded past the fully-closed configuration: θ goes 150°, 175°, -160° (= 200°)
    F = np.array([[0, 1, 2], [1, 0, 3]])
    T = topology(F)
    poses = []
    for deg in (150.0, 175.0, 200.0):
        phi = np.radians(deg)
        poses.append([[0, 0, 0], [1, 0, 0], [0.3, 1, 0], [0.6, -np.cos(phi), -np.sin(phi)]])
    th = dihedral_angles(np.array(poses, dtype=float), T)
    assert th[2, 0] < 0  # the raw angle jumped to the other branch
    assert np.allclose(np.degrees(unwrap_angles(th))[:, 0], [150, 175, 200])


def test_wrap_angle_is_the_modulo_form_bit_for_bit():
    rng = np.random.default_rng(4)
    x = np.concatenate([rng.normal(0, 1, 500), rng.uniform(-40, 40, 500),
                        [np.pi, -np.pi, 3 * np.pi, -3 * np.pi, 0.0, -0.0, np.nextafter(np.pi, 0),
                         np.nan, np.inf, -np.inf]]).reshape(2, -1)
    with np.errstate(invalid="ignore"):
        ref = (x + np.pi) % (2 * np.pi) - np.pi
        got = wrap_angle(x)
    assert got.shape == x.shape and np.array_equal(got, ref, equal_nan=True)
    assert np.all((got[np.isfinite(got)] >= -np.pi) & (got[np.isfinite(got)] < np.pi))
    assert wrap_angle(3 * np.pi / 2) == -np.pi / 2 and np.ndim(wrap_angle(1.0)) == 0

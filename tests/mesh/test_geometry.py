"""shellspline.mesh.geometry and mesh.rigid.best_rotations against numpy, trimesh and scipy."""
from __future__ import annotations

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from shellspline.mesh.geometry import (coordinate_rows, cross, cross_rows, dot, dot_rows,
                                       face_areas, face_normals, normalized, norms,
                                       vertex_face_incidence, vertex_normals)
from shellspline.mesh.rigid import best_rotations


@pytest.fixture(scope="module")
def mesh():
    m = trimesh.creation.icosphere(subdivisions=2)
    rng = np.random.default_rng(0)
    V = np.stack([m.vertices * (1 + 0.2 * rng.random((len(m.vertices), 1))) for _ in range(3)])
    return V, np.asarray(m.faces, dtype=np.int64)


def test_cross_dot_norms_match_numpy():
    rng = np.random.default_rng(1)
    a, b = rng.normal(size=(2, 4, 7, 3)) * 10.0 ** rng.uniform(-6, 6, size=(2, 4, 7, 3))
    assert np.array_equal(cross(a, b), np.cross(a, b))  # the same operations: bit-identical
    assert np.array_equal(cross(a[0, 0], b[:, :1]), np.cross(a[0, 0], b[:, :1]))  # broadcasts
    np.testing.assert_allclose(dot(a, b), (a * b).sum(-1), rtol=1e-13)
    np.testing.assert_allclose(norms(a), np.linalg.norm(a, axis=-1), rtol=1e-15)
    u = normalized(np.concatenate([a, np.zeros((4, 1, 3))], axis=1))
    np.testing.assert_allclose(norms(u[:, :7]), 1.0, rtol=1e-15)
    assert not u[:, 7].any()  # a zero vector stays zero, no NaN


def test_coordinate_rows_cross_and_dot_match_the_last_axis_forms():
    rng = np.random.default_rng(2)
    a, b = rng.normal(size=(2, 4, 7, 3)) * 10.0 ** rng.uniform(-6, 6, size=(2, 4, 7, 3))
    X, Y = coordinate_rows(a), coordinate_rows(b)
    assert X.shape == (3, 4, 7) and X.flags.c_contiguous and np.array_equal(X[1], a[..., 1])
    assert np.array_equal(np.stack(cross_rows(X, Y), axis=-1), np.cross(a, b))
    np.testing.assert_allclose(dot_rows(X, Y), (a * b).sum(-1), rtol=1e-13)
    assert np.array_equal(dot_rows(X, Y), ((a[..., 0] * b[..., 0] + a[..., 2] * b[..., 2])
                                           + a[..., 1] * b[..., 1]))
    # complex input (complex-step derivatives of the descriptors): analytic, no conjugation
    z = X + 1j * Y
    assert np.allclose(dot_rows(z, z), (X * X - Y * Y + 2j * X * Y).sum(0), rtol=1e-12)


def test_face_normals_and_areas_match_trimesh(mesh):
    V, F = mesh
    N = face_normals(V, F)
    A = face_areas(V, F)
    assert N.shape == (3, len(F), 3) and A.shape == (3, len(F))
    for k in range(3):
        t = trimesh.Trimesh(V[k], F, process=False)
        np.testing.assert_allclose(A[k], t.area_faces, rtol=1e-12)
        np.testing.assert_allclose(face_normals(V[k], F, unit=True), t.face_normals, atol=1e-12)
        np.testing.assert_allclose(N[k], 2 * t.area_faces[:, None] * t.face_normals, atol=1e-12)
    flat = face_normals([[0.0, 0, 0], [1.0, 0, 0], [2.0, 0, 0]], [[0, 1, 2]], unit=True)
    assert not flat.any()  # a degenerate face: the zero vector


def test_vertex_normals_are_area_weighted(mesh):
    V, F = mesh
    inc = vertex_face_incidence(F, V.shape[1])
    assert inc.shape == (V.shape[1], len(F)) and inc.sum() == 3 * len(F)
    assert np.array_equal(np.asarray(inc.sum(axis=0)).ravel(), np.full(len(F), 3))
    NV = vertex_normals(V, F)
    np.testing.assert_array_equal(NV, vertex_normals(V, F, incidence=inc))
    for k in range(3):  # the oracle: a loop over the faces
        acc = np.zeros((V.shape[1], 3))
        for f in F:
            acc[f] += np.cross(V[k, f[1]] - V[k, f[0]], V[k, f[2]] - V[k, f[0]])
        np.testing.assert_allclose(NV[k], acc / np.linalg.norm(acc, axis=1, keepdims=True),
                                   atol=1e-12)


@pytest.mark.parametrize("n", [3, 50])
def test_best_rotations_match_scipy_and_never_reflect(n):
    rng = np.random.default_rng(n)
    X = rng.normal(size=(5, n, 3))
    X -= X.mean(axis=1, keepdims=True)
    R_true = Rotation.random(5, random_state=n).as_matrix()
    Y = np.einsum("tij,tnj->tni", R_true, X) + 0.01 * rng.normal(size=X.shape)
    Y -= Y.mean(axis=1, keepdims=True)
    R = best_rotations(X, Y)
    for t in range(5):
        ref, _ = Rotation.align_vectors(Y[t], X[t])
        np.testing.assert_allclose(R[t], ref.as_matrix(), atol=1e-9)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, rtol=1e-12)
    mirrored = X * np.array([1.0, 1.0, -1.0])  # best fit is a reflection: a rotation instead
    assert np.all(np.linalg.det(best_rotations(X, mirrored)) > 0)
    # one set against a batch (broadcast)
    np.testing.assert_allclose(best_rotations(X[0], Y[:1])[0], R[0], atol=1e-12)


def test_flap_angles_from_normals_are_the_dihedral_angles():
    # the defect checks take the angles from the face normals they already have: the same
    # angles as the descriptors' own (independent formula: two cross products per flap)
    import trimesh

    from shellspline.mesh.geometry import face_normals, flap_angles
    from shellspline.mesh.topology import topology
    from shellspline.shells.descriptors import dihedral_angles

    m = trimesh.creation.icosphere(subdivisions=2)
    T = topology(m.faces)
    rng = np.random.default_rng(3)
    V = np.asarray(m.vertices)[None] + 0.3 * rng.normal(size=(4,) + m.vertices.shape)
    th = flap_angles(V, face_normals(V, T.F), T)
    ref = dihedral_angles(V, T)
    assert th.shape == ref.shape == (4, T.n_interior)
    assert np.abs(np.angle(np.exp(1j * (th - ref)))).max() < 1e-12
    assert (np.abs(ref) > 3.0).any()            # folds near ±π are among them

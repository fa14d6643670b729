"""The skinned-body generator (data_synth.skinned)."""
from __future__ import annotations

import numpy as np
import pytest

import shellspline
from data_synth.skinned import (linear_blend_skinning, marching_tetrahedra, skinned_body,
                                skinned_sequence)
from shellspline.io.bvh import read_bvh

from conftest import shared_data


def _euler_characteristic(n, F):
    E = np.unique(np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1),
                  axis=0)
    return n - len(E) + len(F)


def _normals(V, F):
    return np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])


def _signed_volume(V, F):
    return np.einsum("ij,ij->i", V[F[:, 0]], np.cross(V[F[:, 1]], V[F[:, 2]])).sum() / 6.0


def test_marching_tetrahedra_sphere_closed_outward():
    h, r = 0.1, 1.0
    ax = np.arange(-1.4, 1.45, h)
    X = np.stack(np.meshgrid(ax, ax, ax, indexing="ij"), axis=-1)
    V, F = marching_tetrahedra(np.linalg.norm(X, axis=-1) - r, X[0, 0, 0], h)
    T = shellspline.topology(F, V.shape[0])  # raises on non-manifold / inconsistent input
    assert T.boundary_vertices.size == 0
    assert _euler_characteristic(V.shape[0], F) == 2
    # outward orientation: positive volume close to the ball's (linear interpolation
    # between samples of |x| - r, clamped crossings: within a few per cent)
    assert _signed_volume(V, F) == pytest.approx(4 / 3 * np.pi * r ** 3, rel=0.03)
    np.testing.assert_allclose(np.linalg.norm(V, axis=1), r, atol=h)


@pytest.fixture(scope="module")
def walk_body():
    m = read_bvh(shared_data("motion", "dataset-1_walk_normal_001.bvh")).frames(0, 60)
    return m, skinned_body(m, n_vertices=2500)


def test_body_is_one_closed_oriented_manifold(walk_body):
    m, body = walk_body
    V, F = body["V"], body["F"]
    assert V.shape == (2500, 3)
    b = body["bind_frame"]
    Vs = linear_blend_skinning(V, body["W"], body["P"][b], body["R"][b], body["P"], body["R"])
    kf = shellspline.keyframes_from_arrays(Vs[::10], F)  # validates manifold + orientation
    assert kf.V.shape == (6, 2500, 3)
    assert _euler_characteristic(V.shape[0], F) == 2  # a closed genus-0 surface
    assert _signed_volume(V, F) > 0  # outward normals
    # a smooth skin: no sharp fold, no sliver (marching tetrahedra alone gives both)
    T = shellspline.topology(F, V.shape[0])
    assert np.abs(shellspline.dihedral_angles(V[None], T)).max() < 2.0
    e2 = (np.linalg.norm(V[F] - V[np.roll(F, 1, axis=1)], axis=2) ** 2).sum(axis=1)
    quality = 2 * np.sqrt(3) * np.linalg.norm(_normals(V, F), axis=1) / e2  # 1: equilateral
    assert quality.min() > 0.1
    # every vertex is reachable from vertex 0 (one connected component)
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components
    g = sp.coo_matrix((np.ones(F.size), (F.ravel(), np.roll(F, 1, axis=1).ravel())),
                      shape=(2500, 2500))
    assert connected_components(g, directed=False)[0] == 1


def test_weights_are_a_partition_with_few_influences(walk_body):
    _, body = walk_body
    W = body["W"]
    np.testing.assert_allclose(W.sum(axis=1), 1.0, atol=1e-12)
    assert W.min() >= 0 and (W > 0).sum(axis=1).max() <= 3
    assert (W > 0).sum(axis=1).mean() > 1.5  # blended, not rigidly segmented
    # the ground-reference root (joint_Root, index 0) drives nothing
    assert np.all(W[:, 0] == 0)


def test_lbs_reproduces_bind_pose(walk_body):
    _, body = walk_body
    V, W, P, R, b = body["V"], body["W"], body["P"], body["R"], body["bind_frame"]
    np.testing.assert_allclose(linear_blend_skinning(V, W, P[b], R[b], P[b][None],
                                                     R[b][None])[0], V, atol=1e-10)
    # identity rotations and the bind positions: a rest pose given in world axes
    J = P.shape[1]
    I = np.broadcast_to(np.eye(3), (J, 3, 3))
    np.testing.assert_allclose(linear_blend_skinning(V, W, P[b], I, P[b][None], I[None])[0],
                               V, atol=1e-10)


def test_vertices_of_one_bone_move_rigidly(walk_body):
    _, body = walk_body
    V, P, R, b = body["V"], body["P"], body["R"], body["bind_frame"]
    # every vertex bound to one joint only (its strongest influence)
    owner = body["W"].argmax(axis=1)
    W1 = np.zeros_like(body["W"])
    W1[np.arange(V.shape[0]), owner] = 1.0
    Vs = linear_blend_skinning(V, W1, P[b], R[b], P, R)
    joints = np.unique(owner)
    assert joints.size >= 15
    for j in joints:
        idx = np.flatnonzero(owner == j)[:40]
        D0 = np.linalg.norm(V[idx, None] - V[None, idx], axis=2)
        Dt = np.linalg.norm(Vs[:, idx, None] - Vs[:, None, idx], axis=3)
        np.testing.assert_allclose(Dt, np.broadcast_to(D0, Dt.shape), atol=1e-9)
        # and they follow the joint: offsets from the joint, seen in its frame, are constant
        loc = np.einsum("tba,tnb->tna", R[:, j], Vs[:, idx] - P[:, j, None])
        np.testing.assert_allclose(loc, np.broadcast_to(loc[b], loc.shape), atol=1e-9)
    # the generator's own weights: vertices with a single influence are rigid as well
    Vg = linear_blend_skinning(V, body["W"], P[b], R[b], P, R)
    single = (body["W"] > 0).sum(axis=1) == 1
    np.testing.assert_allclose(Vg[:, single], Vs[:, single], atol=1e-9)
    assert single.sum() >= 10


def test_sequence_travels_and_flexes():
    Vs, F, fps = skinned_sequence(shared_data("motion", "dataset-1_walk_normal_001.bvh"),
                                  start=0, stop=90, n_vertices=2000)
    assert Vs.shape == (90, 2000, 3) and fps == pytest.approx(30.0, rel=1e-5)
    diag = np.linalg.norm(np.ptp(Vs[0], axis=0))
    assert np.linalg.norm(Vs[-1].mean(0) - Vs[0].mean(0)) > 0.5 * diag  # root motion
    # non-rigid: edge lengths change (skin stretches and compresses at the joints)
    e = np.linalg.norm(Vs[:, F[:, 0]] - Vs[:, F[:, 1]], axis=2)
    assert np.max(np.abs(e / e[0] - 1)) > 0.2


def test_deterministic_and_other_skeleton():
    p = shared_data("motion", "sinusoidal.bvh")
    Vs1, F1, fps = skinned_sequence(p, stop=40, n_vertices=500)
    Vs2, F2, _ = skinned_sequence(p, stop=40, n_vertices=500)
    assert fps == pytest.approx(60.0)
    np.testing.assert_array_equal(F1, F2)
    np.testing.assert_array_equal(Vs1, Vs2)
    shellspline.keyframes_from_arrays(Vs1[::13], F1)


def test_cli_writes_frames(tmp_path):
    from data_synth.__main__ import main

    p = shared_data("motion", "sinusoidal.bvh")
    assert main(["skinned", str(p), str(tmp_path / "out"), "--stop", "12", "--step", "3",
                 "--vertices", "400"]) == 0
    V, F, report = shellspline.read_sequence(tmp_path / "out")
    Vs, F2, fps = skinned_sequence(p, stop=12, step=3, n_vertices=400)
    np.testing.assert_array_equal(F, F2)
    np.testing.assert_array_equal(V, Vs)
    assert report["fps"] == pytest.approx(fps) == pytest.approx(20.0)


def test_bad_window_raises():
    p = shared_data("motion", "sinusoidal.bvh")
    with pytest.raises(shellspline.ShellsplineError, match="is empty"):
        skinned_sequence(p, start=500)
    with pytest.raises(shellspline.ShellsplineError, match="step must be a positive"):
        skinned_sequence(p, step=0)


def test_skeleton_without_bones_raises(tmp_path):
    from shellspline.io.bvh import Motion, write_bvh

    m = Motion(("root",), [-1], np.zeros((1, 3)), (("Xposition", "Yposition", "Zposition"),),
               0.1, np.zeros((3, 3)))
    p = write_bvh(m, tmp_path / "one.bvh")
    with pytest.raises(shellspline.ShellsplineError, match="has no bone"):
        skinned_sequence(p)

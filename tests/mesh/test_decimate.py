"""Simultaneous decimation: coarse meshes are valid, embedded, flip-free and pose-aware."""
import warnings

import numpy as np
import pytest

import data_synth
import data_synth.stress as stress
from shellspline import MeshError, topology
from shellspline.mesh.decimate import (Decimation, canonical_target, decimate, decimate_replay,
                                  hausdorff_fine_to_coarse)


def _euler(F, n):
    T = topology(F, n)
    return n - T.n_edges + T.n_faces, T


def _normals(V, F):
    N = np.cross(V[..., F[:, 1], :] - V[..., F[:, 0], :], V[..., F[:, 2], :] - V[..., F[:, 0], :])
    return N


@pytest.fixture(scope="module")
def bumpy():
    return data_synth.generate("bumpy", n_vertices=1000)


@pytest.fixture(scope="module")
def bumpy_dec(bumpy):
    return decimate(bumpy["V"], bumpy["F"], 150)


@pytest.fixture(scope="module")
def hexagon():
    return data_synth.generate("hexagon", n_vertices=600)


def test_closed_mesh_stays_closed_with_same_euler_characteristic(bumpy, bumpy_dec):
    dec = bumpy_dec
    assert isinstance(dec, Decimation)
    assert dec.n_vertices == 150 and dec.stats["reached"]
    chi_f, _ = _euler(bumpy["F"], bumpy["V"].shape[1])
    chi_c, Tc = _euler(dec.F, dec.n_vertices)
    assert chi_c == chi_f == 2
    assert Tc.boundary_vertices.size == 0
    assert dec.F.dtype == np.int64 and dec.F.min() == 0 and dec.F.max() == dec.n_vertices - 1


def test_coarse_poses_are_exact_restrictions(bumpy, bumpy_dec):
    dec = bumpy_dec
    assert (np.diff(dec.kept) > 0).all()
    assert dec.V.shape == (3, dec.n_vertices, 3)
    assert np.array_equal(dec.V, bumpy["V"][:, dec.kept])
    assert np.array_equal(dec.restrict(bumpy["V"]), dec.V)
    assert np.array_equal(dec.collapse_map[dec.kept], np.arange(dec.n_vertices))
    assert dec.collapse_map.min() >= 0 and dec.collapse_map.max() < dec.n_vertices
    # coarse faces are fine vertices' triangles: orientation agrees with the fine surface
    Vf = bumpy["V"]
    Nc = _normals(dec.V, dec.F)
    centroid_dir = dec.V[:, dec.F].mean(axis=2)            # star-shaped about the origin
    assert (np.einsum("jmi,jmi->jm", Nc, centroid_dir) > 0).all()
    assert Vf.shape[1] == dec.n_fine


def test_no_flipped_or_degenerate_faces_in_any_pose(bumpy, bumpy_dec):
    dec = bumpy_dec
    Vf, Ff = bumpy["V"], bumpy["F"]
    # fine vertex normals at the kept vertices vs the coarse faces around them
    Nf = _normals(Vf, Ff)
    vn = np.zeros_like(Vf)
    for c in range(3):
        np.add.at(vn, (slice(None), Ff[:, c]), Nf)
    Nc = _normals(dec.V, dec.F)
    for c in range(3):
        d = np.einsum("jmi,jmi->jm", Nc, vn[:, dec.kept[dec.F[:, c]]])
        assert (d > 0).all()
    area = 0.5 * np.linalg.norm(Nc, axis=-1)
    assert area.min() > 1e-3 * area.mean()


def test_open_mesh_keeps_its_boundary_on_the_boundary(hexagon):
    Vs, F = hexagon["V"], hexagon["F"]
    dec = decimate(Vs, F, 80)
    chi_f, Tf = _euler(F, Vs.shape[1])
    chi_c, Tc = _euler(dec.F, dec.n_vertices)
    assert chi_c == chi_f == 1
    fine_bnd = set(Tf.boundary_vertices.tolist())
    assert set(dec.kept[Tc.boundary_vertices].tolist()) <= fine_bnd
    # interior coarse vertices are interior fine vertices, and the six corners survive
    interior_c = np.setdiff1d(np.arange(dec.n_vertices), Tc.boundary_vertices)
    assert not set(dec.kept[interior_c].tolist()) & fine_bnd
    corners = np.argsort(np.linalg.norm(Vs[0], axis=1))[-6:]
    assert set(corners.tolist()) <= set(dec.kept.tolist())


def test_same_pose_repeated_gives_the_single_pose_result(bumpy):
    V0, F = bumpy["V"][1], bumpy["F"]
    one = decimate(V0, F, 200)
    two = decimate(np.stack([V0, V0]), F, 200)
    assert np.array_equal(one.kept, two.kept)
    assert np.array_equal(one.F, two.F)
    assert np.array_equal(one.collapse_map, two.collapse_map)


def test_pinned_vertices_only_merge_into_pinned_ones():
    d = data_synth.generate("cactus", n_vertices=1500)
    dec = decimate(d["V"], d["F"], 0.1, pinned=d["pinned"])
    pin = np.zeros(d["V"].shape[1], dtype=bool)
    pin[d["pinned"]] = True
    assert dec.n_vertices == canonical_target(0.1, d["V"].shape[1])
    assert np.array_equal(dec.pinned, np.flatnonzero(pin[dec.kept]))
    assert dec.pinned.size > 0
    # every pinned fine vertex ends in a pinned coarse vertex
    assert pin[dec.kept[dec.collapse_map[pin]]].all()


def test_summed_quadrics_beat_pose0_decimation_when_poses_differ(hexagon):
    """Each pose folds the hexagon along another diagonal: pose 0 alone cannot see the
    other creases, the summed quadrics keep all three."""
    Vs, F = hexagon["V"], hexagon["F"]
    target = 100
    dec = decimate(Vs, F, target)
    h_sum = hausdorff_fine_to_coarse(Vs, dec.V, dec.F).max()
    dec0 = decimate(Vs[0], F, target)
    h_0 = hausdorff_fine_to_coarse(Vs, Vs[:, dec0.kept], dec0.F).max()
    assert h_sum <= h_0
    assert h_sum < 0.5 * h_0
    try:
        Vr, Fr = decimate_replay(Vs, F, target)
    except ImportError:
        return
    h_r = hausdorff_fine_to_coarse(Vs, Vr, Fr).max()
    assert h_sum <= h_r


def test_replay_baseline_shapes(bumpy):
    pytest.importorskip("fast_simplification")
    Vr, Fr = decimate_replay(bumpy["V"], bumpy["F"], 200)
    assert Vr.shape[0] == 3 and Vr.shape[2] == 3
    assert Fr.shape[1] == 3 and Fr.max() < Vr.shape[1]


def test_hausdorff_measure():
    from conftest import grid_sheet

    V, F = grid_sheet(6, 5)
    assert hausdorff_fine_to_coarse(V, V, F).max() == pytest.approx(0.0, abs=1e-15)
    W = V.copy()
    W[:, 2] = 0.25
    assert hausdorff_fine_to_coarse(W, V, F)[0] == pytest.approx(0.25)


def test_target_forms():
    assert canonical_target(100, 1000) == 100
    assert canonical_target(0.05, 5261) == 264
    assert canonical_target(5000, 1000) == 1000
    assert canonical_target(1e-9, 1000) == 4
    for bad in (3, 0, -1, 0.0, 1.5, float("nan"), True, "10", None):
        with pytest.raises(ValueError, match="target"):
            canonical_target(bad, 1000)


def test_invalid_inputs_raise(bumpy):
    Vs, F = bumpy["V"], bumpy["F"]
    with pytest.raises(ValueError, match="Vs"):
        decimate(Vs[..., :2], F, 100)
    with pytest.raises(ValueError, match="Vs"):
        decimate(np.full_like(Vs, np.nan), F, 100)
    with pytest.raises(ValueError, match="pinned"):
        decimate(Vs, F, 100, pinned=[Vs.shape[1]])
    with pytest.raises(ValueError, match="min_normal_cos"):
        decimate(Vs, F, 100, min_normal_cos=2.0)
    with pytest.raises(MeshError):
        decimate(Vs[:, :4], np.array([[0, 1, 2], [0, 1, 3], [1, 0, 3]]), 4)


def test_unreachable_target_warns():
    V, F = data_synth.geodesic_sphere(2)
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        dec = decimate(V, F, 4, min_normal_cos=0.99)
    assert not dec.stats["reached"] and dec.n_vertices > 4
    assert any(issubclass(x.category, RuntimeWarning) for x in w)
    topology(dec.F, dec.n_vertices)


@pytest.mark.slow
def test_large_mesh_to_1000_vertices():
    d = data_synth.generate("cactus", n_vertices=100_000)
    dec = decimate(d["V"], d["F"], 1000, pinned=d["pinned"])
    assert dec.n_vertices == 1000 and dec.stats["reached"]
    chi, _ = _euler(dec.F, dec.n_vertices)
    assert chi == 2
    assert np.array_equal(dec.V, d["V"][:, dec.kept])


def test_prebuilt_topology_gives_the_same_decimation(bumpy, bumpy_dec):
    T = topology(bumpy["F"], bumpy["V"].shape[1])
    dec = decimate(bumpy["V"], T, 150)
    assert np.array_equal(dec.kept, bumpy_dec.kept)
    assert np.array_equal(dec.F, bumpy_dec.F)
    with pytest.raises(ValueError, match="Topology"):
        decimate(bumpy["V"][:, :-1], T, 100)


def test_compacted_rounds_keep_unreferenced_vertices(bumpy):
    """An isolated vertex is never collapsed (it has no edge) and stays a coarse vertex."""
    Vs = np.concatenate([bumpy["V"], np.full((3, 1, 3), 5.0)], axis=1)
    n = Vs.shape[1]
    dec = decimate(Vs, bumpy["F"], 150)
    assert n - 1 in dec.kept.tolist() and dec.n_vertices == 150
    assert dec.collapse_map[n - 1] == dec.n_vertices - 1
    chi, _ = _euler(dec.F, dec.n_vertices - 1)
    assert chi == 2


def _bipyramid(h=0.5):
    """Triangular bipyramid: every equator edge fails the link condition (three common
    neighbours), every pole collapse would turn a face against the fine vertex normals."""
    a = np.array([0.0, 2.0, 4.0]) * np.pi / 3.0
    V = np.r_[np.c_[np.cos(a), np.sin(a), np.zeros(3)], [[0, 0, h], [0, 0, -h]]]
    F = np.array([[0, 1, 3], [1, 2, 3], [2, 0, 3], [1, 0, 4], [2, 1, 4], [0, 2, 4]])
    return V, F


def test_round_whose_winners_all_fail_the_link_condition_stops_cleanly():
    """Regression (issue 13): a sweep whose tentative winners all failed the link condition
    called the face checks on an empty batch, which crashed in numpy ("cannot reshape array
    of size 0") instead of stopping with the unreachable-target warning."""
    V, F = _bipyramid()
    Vs = np.stack([V, V * [1.0, 1.0, 1.5]])
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        dec = decimate(Vs, F, 4)
    assert not dec.stats["reached"] and dec.n_vertices == 5
    assert any(issubclass(x.category, RuntimeWarning) for x in w)
    assert np.array_equal(np.sort(dec.F, axis=None), np.sort(F, axis=None))


def test_horse_keyframes_decimate_to_1000():
    """The real horse (boundary, slivers, creases) at the issue's keyframes: no crash, the
    target reached, a valid coarse manifold with the fine boundary's genus."""
    from conftest import shared_data
    from shellspline.io import read_mesh

    root = shared_data("horse")
    meshes = [read_mesh(root / f"{nm}.obj") for nm in ("horse-reference", "horse-03",
                                                        "horse-07")]
    Vs, F = np.stack([m[0] for m in meshes]), meshes[0][1]
    dec = decimate(Vs, F, 1000)
    assert dec.stats["reached"] and dec.n_vertices == 1000
    chi_f, Tf = _euler(F, Vs.shape[1])
    chi_c, Tc = _euler(dec.F, dec.n_vertices)
    assert chi_c == chi_f
    Nc = _normals(dec.V, dec.F)
    assert (np.linalg.norm(Nc, axis=-1) > 0).all()


def _z_fold(**kw):
    """:func:`data_synth.stress.z_fold`'s two poses and faces."""
    d = stress.z_fold(**kw)
    return d["V"], d["F"]


def _quality(V, F):
    """``4√3 a / Σ l²`` of every face in every pose ``V (J,n,3)``: (J,m)."""
    e = [V[:, F[:, (i + 1) % 3]] - V[:, F[:, i]] for i in range(3)]
    a2 = np.linalg.norm(np.cross(e[0], -e[2]), axis=-1)
    return 2.0 * np.sqrt(3.0) * a2 / sum((x * x).sum(-1) for x in e)


def test_fold_area_coarsens_a_fold_in_one_pose_like_the_rest():
    """Where a keyframe folds over (skin folding at a joint), the fine faces themselves fail
    the corner-normal rule, so no face touching a crease can be replaced: by default the
    fold keeps its fine resolution (here 284 untouched fine faces, 311 of the 317 coarse
    vertices in the fold, the target not reached; on the horse subdivided twice, faces of
    10⁻⁴ of the median area that keep the coarse Gauss–Newton from converging).
    ``fold_area`` waives the rule there for faces below half the target's mean face area."""
    Vs, F = _z_fold()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        dec = decimate(Vs, F, 150, fold_area=0.5)
    assert dec.stats["reached"] and dec.n_vertices == 150
    chi_f, _ = _euler(F, Vs.shape[1])
    chi_c, _ = _euler(dec.F, dec.n_vertices)
    assert chi_c == chi_f == 1
    fine = set(map(tuple, np.sort(F, axis=1).tolist()))
    untouched = [tuple(f) in fine for f in np.sort(dec.kept[dec.F], axis=1).tolist()]
    assert not any(untouched)
    # the fold zone (27 % of the strip, all its curvature) holds a part of the vertices only
    x = dec.V[0, :, 0]
    assert ((x > 1.1) & (x < 1.9)).sum() < 0.67 * dec.n_vertices
    # no sliver in either pose
    assert _quality(dec.V, dec.F).min() >= 0.05
    # the default keeps the fold's fine faces and stops short of the target
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        frozen = decimate(Vs, F, 150)
    assert not frozen.stats["reached"] and frozen.n_vertices > 250
    assert any(issubclass(x.category, RuntimeWarning) for x in w)
    untouched = [tuple(f) in fine for f in np.sort(frozen.kept[frozen.F], axis=1).tolist()]
    assert sum(untouched) > 200
    x = frozen.V[0, :, 0]
    assert ((x > 1.1) & (x < 1.9)).sum() > 0.9 * frozen.n_vertices


def test_fold_area_changes_nothing_without_folds(bumpy, bumpy_dec):
    """Bumpy has no vertex whose own faces fail the corner-normal rule: the waiver never
    applies and the coarse mesh is the default one."""
    waived = decimate(bumpy["V"], bumpy["F"], 150, fold_area=0.5)
    assert np.array_equal(waived.kept, bumpy_dec.kept)
    assert np.array_equal(waived.F, bumpy_dec.F)
    with pytest.raises(ValueError, match="fold_area"):
        decimate(bumpy["V"], bumpy["F"], 150, fold_area=-1.0)

"""The defect rules (shells.defects): the per-frame scan that skips the angles of edges that
cannot fold equals a dense evaluation of every rule on every element."""
import numpy as np
import pytest

from shellspline.mesh.geometry import dot, face_normals, norms
from shellspline.mesh.topology import topology
from shellspline.shells.defects import COLLAPSE_RATIO, DefectRules, step_defects


def dense_defects(V, T, frames, bc="natural"):
    """The rules written out on every face and edge of every frame, the dihedral angles from
    the descriptors' own formula (two cross products per flap, not the face normals)."""
    from shellspline.shells.descriptors import FOLD_BAND, dihedral_angles

    fr = np.asarray(frames)
    K = V.shape[0] - 1
    periodic = bc == "periodic"
    key = np.zeros(K + 1, dtype=bool)
    key[fr] = True
    key[K] |= periodic
    # keyframes around each step, by hand
    ext = np.r_[fr, K] if periodic else fr
    j0 = np.array([max(j for j in range(len(ext)) if ext[j] <= k) for k in range(K)])
    j0 = np.minimum(j0, len(ext) - 2)
    j1 = j0 + 1
    if periodic:
        j1 = np.where(j1 == len(fr), 0, j1)
    N = face_normals(V, T.F)
    th = dihedral_angles(V, T)
    band = np.pi - FOLD_BAND
    flipped = (dot(N[1:], N[:-1]) < 0) & ~(dot(N[fr][j0], N[fr][j1]) < 0)
    ta, tb = th[fr][j0], th[fr][j1]
    key_fold = ((np.abs(ta) > band) | (np.abs(tb) > band)) & (np.abs(tb - ta) > np.pi)
    held = (key[:-1, None] & (np.abs(th[:-1]) > band)) | (key[1:, None] & (np.abs(th[1:]) > band))
    folded = (np.abs(th[1:] - th[:-1]) > np.pi) & ~key_fold & ~held
    a = 0.5 * norms(N)
    collapsed = (a < COLLAPSE_RATIO * a[fr].min(axis=0)) & ~key[:, None]
    return {"flipped": flipped, "folded": folded, "collapsed": collapsed}


@pytest.fixture(scope="module")
def rough_sequence():
    """An icosphere shaken hard in every frame (faces turn over, edges pass through ±π),
    one face shrunk 200 times about its centre in two in-between frames, keyframes at 0, 4,
    9."""
    import trimesh

    m = trimesh.creation.icosphere(subdivisions=2)
    T = topology(m.faces)
    rng = np.random.default_rng(11)
    K = 12
    V = np.asarray(m.vertices)[None] + 0.35 * rng.normal(size=(K + 1,) + m.vertices.shape)
    f = T.F[7]
    for k in (2, 6):
        V[k, f] = V[k, f].mean(axis=0) + 0.005 * (V[k, f] - V[k, f].mean(axis=0))
    return V, T, np.array([0, 4, 9])


@pytest.mark.parametrize("bc", ["natural", "periodic"])
def test_scan_equals_the_dense_rules(rough_sequence, bc):
    V, T, fr = rough_sequence
    if bc == "periodic":
        V = V.copy()
        V[-1] = V[0]
    ref = dense_defects(V, T, fr, bc)
    got = step_defects(V, T, fr, bc=bc)
    for kind in ("flipped", "folded", "collapsed"):
        assert ref[kind].sum() > 0, kind                       # every rule has work to do
        assert got[kind].shape == ref[kind].shape
        assert np.array_equal(got[kind], ref[kind]), kind
    # the keyframes hold folds and flips of their own that are not counted
    assert (dot(face_normals(V[0], T.F), face_normals(V[4], T.F)) < 0).any()


def test_scan_of_some_steps_lists_what_the_full_scan_lists_there(rough_sequence):
    V, T, fr = rough_sequence
    R = DefectRules(V[fr], T, fr, V.shape[0] - 1)
    full = R.scan(V)
    part = R.scan(V, [1, 2, 7])
    assert part["frames"].tolist() == [1, 2, 3, 7, 8]
    for kind in ("flipped", "folded"):
        rows = full[kind][np.isin(full[kind][:, 0], [1, 2, 7])]
        assert rows.size and np.array_equal(part[kind], rows)
    rows = full["collapsed"][np.isin(full["collapsed"][:, 0], [1, 2, 3, 7, 8])]
    assert np.array_equal(part["collapsed"], rows)
    assert (part["collapsed"][:, 0] == 2).any()


def test_scan_of_a_rigid_motion_finds_nothing(rough_sequence):
    V, T, fr = rough_sequence
    from scipy.spatial.transform import Rotation

    R = Rotation.from_rotvec(np.linspace(0, 2.5, 13)[:, None] * [0.3, 0.8, 0.2]).as_matrix()
    Vr = np.einsum("kij,nj->kni", R, V[0])
    d = DefectRules(Vr[fr], T, fr, 12).scan(Vr)
    assert all(d[k].shape == (0, 2) for k in ("flipped", "folded", "collapsed"))


@pytest.mark.parametrize("bc", ["natural", "periodic"])
def test_sequence_defects_counts_the_dense_rules(rough_sequence, bc):
    from shellspline.metrics import sequence_defects

    V, T, fr = rough_sequence
    if bc == "periodic":
        V = V.copy()
        V[-1] = V[0]
    ref = dense_defects(V, T, fr, bc)
    d = sequence_defects(V, T, fr, bc=bc, chunk=5)
    assert d["per_frame"]["flipped"] == [0] + ref["flipped"].sum(axis=1).tolist()
    assert d["per_frame"]["folded"] == [0] + ref["folded"].sum(axis=1).tolist()
    assert d["per_frame"]["collapsed"] == ref["collapsed"].sum(axis=1).tolist()
    assert d["collapsed_faces"] == int(ref["collapsed"].sum()) > 0
    # the pop: largest vertex step over its neighbours', by hand at the worst step
    steps = np.linalg.norm(np.diff(V, axis=0), axis=-1).max(axis=1)
    k = d["pop_frame"] - 1
    nb = np.r_[steps[max(k - 2, 0):k], steps[k + 1:k + 3]]
    assert d["pop"] == pytest.approx(steps[k] / max(nb.mean(), 0.25 * np.median(steps)))

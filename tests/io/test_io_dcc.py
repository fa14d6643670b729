"""Real DCC exports (issue 13 item 5) and hostile read-side input (issue 14).

Quads and n-gons triangulated once for all keyframes, seams welded, fins and isolated vertices
set aside and carried along, the input's polygons and indexing written back; a byte-order
mark, a PLY header that lies, coordinates that overflow, ``read_sequence`` on a ``.glb``.
"""
from __future__ import annotations

import numpy as np
import pytest

import shellspline.io as sio
from data_synth.dcc import dcc_tube, write_dcc_obj, write_polygon_mesh
from shellspline.mesh.source_mesh import triangulate_polygons

from conftest import raises_mesh_error


def write_set(tmp_path, d, fmt="obj", **kw):
    paths = []
    for j, X in enumerate(d["V"]):
        p = tmp_path / f"pose_{j}.{fmt}"
        if fmt == "obj":
            write_dcc_obj(p, X, d["offsets"], d["indices"], d["uv"], **kw)
        else:
            write_polygon_mesh(p, X, d["offsets"], d["indices"])
        paths.append(p)
    return paths


def obj_polygons(path):
    """``v`` rows and the ``f`` lines' first indices (1-based as written) of an OBJ file:
    an independent, line-by-line reader."""
    V, faces = [], []
    for ln in path.read_text(encoding="utf-8-sig").splitlines():
        t = ln.split()
        if t and t[0] == "v":
            V.append([float(x) for x in t[1:4]])
        elif t and t[0] == "f":
            faces.append([int(c.split("/")[0]) for c in t[1:]])
    return np.array(V), faces


def polygon_list(d):
    o, i = d["offsets"], d["indices"]
    return [i[o[p]:o[p + 1]].tolist() for p in range(len(o) - 1)]


# ----------------------------------------------------------------------------------------
# reading real exports
# ----------------------------------------------------------------------------------------
def test_bom_does_not_shift_indices(tmp_path):
    """A UTF-8 byte-order mark used to hide the first ``v`` line: every face index shifted
    by one (silent garbage with one unused trailing vertex). The geometry must be the file's."""
    V = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [7, 8, 9]])
    F = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    text = "".join("v %r %r %r\r\n" % tuple(v) for v in V.tolist())
    text += "".join("f %d %d %d\r\n" % tuple(f + 1) for f in F)
    p = tmp_path / "bom.obj"
    p.write_bytes(b"\xef\xbb\xbf" + text.encode())
    V2, F2 = sio.read_mesh(p)
    assert np.array_equal(V2, V) and np.array_equal(F2, F)
    q = tmp_path / "bom2.obj"
    q.write_bytes(b"\xef\xbb\xbf" + text.replace("v 0.0 0.0 0.0", "v 0 0 0.5").encode())
    kf = sio.read_keyframes([p, q])
    assert np.array_equal(kf.V[0, :4], V[:4]) and np.array_equal(kf.F, F)


def test_dcc_obj_read_like_the_generator(tmp_path, tube):
    """BOM, CRLF, o/g/s/usemtl/mtllib/vt/vn/vp/l lines, v/vt/vn, v//vn and negative indices:
    the polygons and coordinates read are exactly the generator's."""
    paths = write_set(tmp_path, tube, bom=True, crlf=True)
    for j, p in enumerate(paths):
        V, off, idx, (uv, corner_uv) = sio.meshes.read_polygons(p)
        assert np.array_equal(V, tube["V"][j])
        assert np.array_equal(off, tube["offsets"]) and np.array_equal(idx, tube["indices"])
        # every corner names the texture coordinate written for its vertex (%.6f in the file)
        assert np.array_equal(corner_uv, tube["indices"])
        assert np.abs(uv - tube["uv"]).max() <= 5e-7


@pytest.mark.parametrize("fmt", ["obj", "ply", "off"])
def test_dcc_keyframes(tmp_path, tube, fmt):
    """Seams welded, the fin and the isolated vertex set aside, polygons triangulated: the
    solve mesh is an edge-manifold, consistently oriented triangle mesh with the seam inside."""
    kf = sio.read_keyframes(write_set(tmp_path, tube, fmt), frames=tube["frames"])
    src = kf.source
    n_src = tube["V"].shape[1]
    seam = tube["seam"]
    assert src.n_source == n_src and src.n_welded == len(seam)
    assert (src.to_solve[seam[:, 0]] == src.to_solve[seam[:, 1]]).all()
    assert sorted(src.set_aside.tolist()) == sorted([tube["fin_vertex"], tube["isolated"]])
    assert src.fin_polygons.tolist() == [tube["fin"]]
    assert kf.n == n_src - len(seam) - 2
    sizes = np.diff(tube["offsets"])
    kept = np.ones(len(sizes), dtype=bool)
    kept[tube["fin"]] = False
    assert kf.m == int((sizes[kept] - 2).sum())
    # every solve vertex holds the keyframe coordinates of its source vertices, exactly
    for s in range(n_src):
        if src.to_solve[s] >= 0:
            assert np.array_equal(kf.V[:, src.to_solve[s]], tube["V"][:, s])
    # the seam edges are interior: the only boundaries are the tube's open end and the patch
    assert kf.topology.boundary_vertices.size == 16 + 8
    # triangles cover each polygon with the polygon's orientation, in every keyframe
    for j in range(kf.J):
        X = kf.V[j]
        tri_n = np.cross(X[kf.F[:, 1]] - X[kf.F[:, 0]], X[kf.F[:, 2]] - X[kf.F[:, 0]])
        assert (np.linalg.norm(tri_n, axis=1) > 0).all()
    # two components are accepted
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    E = kf.topology.E
    ncomp, _ = connected_components(coo_matrix((np.ones(len(E)), (E[:, 0], E[:, 1])),
                                               shape=(kf.n, kf.n)), directed=False)
    assert ncomp == 2


def test_texture_coordinates_kept_only_when_every_corner_has_one(tmp_path):
    """A triangle OBJ with per-corner texture indices (seams in UV space, shared vertices, as
    Blender writes OBJ): not welded, but the texture coordinates are carried (so ``source``
    is set); one corner without a texture index: nothing carried, ``source`` stays None."""
    V = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]])
    head = "".join("v %r %r %r\n" % tuple(v) for v in V.tolist())
    head += "vt 0 0\nvt 1 0\nvt 0 1\nvt 1 1\nvt 0.5 0.5 0.0\n"  # an optional w: read (u, v)
    p = tmp_path / "uv.obj"
    p.write_text(head + "f 1/1 2/2 3/3\nf 2/5 4/4 3/-3\n")
    q = tmp_path / "uv2.obj"
    q.write_text(head.replace("v 1.0 1.0 0.0", "v 1.0 1.0 0.5") + "f 1/1 2/2 3/3\nf 2/5 4/4 3/-3\n")
    kf = sio.read_keyframes([p, q])
    assert kf.n == 4 and kf.source.n_welded == 0 and kf.source.set_aside.size == 0
    assert kf.source.corner_uv.tolist() == [0, 1, 2, 4, 3, 2]
    assert kf.source.uv[4].tolist() == [0.5, 0.5]
    p.write_text(head + "f 1/1 2/2 3/3\nf 2 4/4 3/3\n")
    q.write_text(head + "f 1/1 2/2 3/3\nf 2 4/4 3/3\n")
    with pytest.warns(UserWarning, match="1 of 6 face corners name no texture coordinate"):
        assert sio.read_keyframes([p, q]).source is None


def test_flipped_faces_are_reoriented_for_the_solve(tmp_path):
    """An icosphere with a third of its faces reversed (as after a careless edit in a DCC
    tool): the solve mesh gets the majority orientation back, face for face; the written
    output keeps the polygons as they were given."""
    import trimesh

    m = trimesh.creation.icosphere(subdivisions=2)
    F = np.array(m.faces)
    flip = np.random.default_rng(5).random(len(F)) < 0.33
    Fin = np.where(flip[:, None], F[:, [0, 2, 1]], F)
    kf = sio.keyframes_from_arrays([m.vertices, m.vertices * [1.3, 1, 1]], Fin)
    assert np.array_equal(kf.F, F) and kf.source.n_reoriented == flip.sum()
    out = sio.write_sequence(tmp_path / "o", kf.source.expand(kf.V, [0, 1]), None,
                             source=kf.source)
    _, faces = obj_polygons(out / "frame_0000.obj")
    assert np.array_equal(np.array(faces) - 1, Fin)


def test_clean_triangle_mesh_has_no_source(tmp_path):
    import trimesh

    m = trimesh.creation.icosphere(subdivisions=1)
    kf = sio.keyframes_from_arrays([m.vertices, 2 * m.vertices], m.faces)
    assert kf.source is None and kf.n == len(m.vertices)


def test_quad_diagonal_best_over_all_keyframes():
    """A square in keyframe 0 (both diagonals equal) that is concave at vertex 1 in keyframe
    1: there the diagonal 0-2 lies outside the quad (triangle 0-1-2 flips); 1-3 must be
    chosen for every keyframe."""
    V0 = np.array([[0.0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]])
    V1 = V0.copy()
    V1[1] = [0.4, 0.6, 0.0]       # reflex corner at vertex 1
    F, p = triangulate_polygons(np.stack([V0, V1]), [0, 4], [0, 1, 2, 3])
    assert p.tolist() == [0, 0]
    diag = set(map(frozenset, ([F[0][i], F[0][(i + 1) % 3]] for i in range(3)))) & \
        set(map(frozenset, ([F[1][i], F[1][(i + 1) % 3]] for i in range(3))))
    assert diag == {frozenset({1, 3})}
    # the other order of keyframes gives the same triangles (one choice for the set)
    F2, _ = triangulate_polygons(np.stack([V1, V0]), [0, 4], [0, 1, 2, 3])
    assert np.array_equal(F, F2)


def test_ngon_triangulation_covers_the_polygon():
    """A non-convex L-shaped hexagon, tilted in 3-D: n-2 triangles, oriented like the polygon,
    whose areas add up to the polygon's (shoelace formula)."""
    pytest.importorskip("mapbox_earcut")
    xy = np.array([[0.0, 0], [2, 0], [2, 1], [1, 1], [1, 2], [0, 2]])
    R = np.linalg.qr(np.random.default_rng(3).normal(size=(3, 3)))[0]
    X = np.c_[xy, np.zeros(6)] @ R.T
    F, _ = triangulate_polygons(X[None], [0, 6], np.arange(6))
    assert F.shape == (4, 3)
    n = np.cross(X[F[:, 1]] - X[F[:, 0]], X[F[:, 2]] - X[F[:, 0]])
    normal = R[:, 2]
    assert (n @ normal > 0).all()
    shoelace = 0.5 * abs(np.dot(xy[:, 0], np.roll(xy[:, 1], -1))
                         - np.dot(xy[:, 1], np.roll(xy[:, 0], -1)))
    assert np.isclose(0.5 * np.linalg.norm(n, axis=1).sum(), shoelace, rtol=1e-12)


def test_ngon_without_earcut_names_the_extra(monkeypatch):
    import sys

    monkeypatch.setitem(sys.modules, "mapbox_earcut", None)  # import fails
    X = np.array([[np.cos(t), np.sin(t), 0.0] for t in np.linspace(0, 6, 5)])
    raises_mesh_error(lambda: triangulate_polygons(X[None], [0, 5], np.arange(5), "cap.obj"),
                      "cap.obj", "mapbox_earcut", "shellspline[dcc]")
    # quads need nothing
    F, _ = triangulate_polygons(X[None, :4], [0, 4], np.arange(4))
    assert F.shape == (2, 3)


def test_weld_needs_coincidence_in_every_keyframe(tmp_path):
    """Two vertices that coincide in one keyframe only are not welded."""
    V = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0], [1, 0, 0]])
    F = np.array([[0, 1, 2], [4, 3, 2]])     # vertex 4 duplicates vertex 1 in keyframe 0
    V2 = V.copy()
    V2[4] = [1.0, 0, 0.3]
    kf = sio.keyframes_from_arrays([V, V2], F)
    assert kf.source is None
    kf = sio.keyframes_from_arrays([V, V * 2], F)
    assert kf.source.n_welded == 1 and kf.n == 4
    assert kf.F.tolist() == [[0, 1, 2], [1, 3, 2]]


def test_truly_invalid_input_still_refused(tmp_path, tube):
    d = dict(tube)
    paths = write_set(tmp_path, d)
    # index out of range in a polygon
    bad = tmp_path / "bad.obj"
    bad.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nf 1 2 4 9\n")
    raises_mesh_error(lambda: sio.read_keyframes([bad, bad]), "bad.obj",
                      "line 5, face 1 (f 1 2 4 9): vertex 9 does not exist (the file has 4 "
                      "vertices)")
    # NaN
    nan = tmp_path / "nan.obj"
    nan.write_text(paths[1].read_text().replace("v 1 0 0", "v nan 0 0", 1))
    raises_mesh_error(lambda: sio.read_keyframes([paths[0], nan]), "nan.obj", "NaN")
    # different vertex counts
    V = tube["V"][1][:-1]
    o, i = tube["offsets"][:-5], tube["indices"][:tube["offsets"][-5]]
    short = write_dcc_obj(tmp_path / "short.obj", V, o, i)
    raises_mesh_error(lambda: sio.read_keyframes([paths[0], short]), "short.obj", "vertices")
    # a polygon that repeats a vertex
    rep = tmp_path / "rep.obj"
    rep.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nf 1 2 4 2\n")
    raises_mesh_error(lambda: sio.read_keyframes([rep, rep]), "rep.obj",
                      "line 5, face 1 (f 1 2 4 2): repeats vertex 2")
    # no faces at all
    empty = tmp_path / "empty.obj"
    empty.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\n")
    raises_mesh_error(lambda: sio.read_keyframes([empty, empty]), "empty.obj", "no faces")


# ----------------------------------------------------------------------------------------
# hostile files (issue 14)
# ----------------------------------------------------------------------------------------
def test_ply_header_that_lies(tmp_path):
    V = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
    head = ("ply\nformat binary_little_endian 1.0\nelement vertex 5\nproperty double x\n"
            "property double y\nproperty double z\nelement face 1\n"
            "property list uchar int vertex_indices\nend_header\n")
    p = tmp_path / "liar.ply"
    p.write_bytes(head.encode() + V.astype("<f8").tobytes() + bytes([3]) +
                  np.array([0, 1, 2], "<i4").tobytes())
    msg = raises_mesh_error(lambda: sio.read_mesh(p), "liar.ply", "does not match the header",
                            "5 vertices")
    assert "unexpected length" not in msg.split("(", 1)[0]


@pytest.mark.parametrize("extra", [False, True])
def test_binary_ply_with_mixed_polygons(tmp_path, tube, extra):
    """Binary PLY mixing quads, an n-gon and triangles (as Blender writes it; trimesh refuses
    such files as 'unexpected length'), records packed one by one with ``struct``, with and
    without an extra face property after the list."""
    import struct

    V, o, i = tube["V"][1], tube["offsets"], tube["indices"]
    P = len(o) - 1
    head = ("ply\nformat binary_little_endian 1.0\n"
            f"element vertex {len(V)}\nproperty float x\nproperty float y\nproperty float z\n"
            f"element face {P}\nproperty list uchar uint vertex_indices\n"
            + ("property ushort material\n" if extra else "") + "end_header\n")
    body = b"".join(struct.pack("<3f", *v) for v in V)
    for p in range(P):
        c = i[o[p]:o[p + 1]]
        body += struct.pack(f"<B{len(c)}I", len(c), *c) + (struct.pack("<H", p) if extra else b"")
    f = tmp_path / "blender.ply"
    f.write_bytes(head.encode() + body)
    V2, F2 = sio.read_mesh(f)
    assert np.array_equal(V2, V.astype(np.float32).astype(np.float64))
    _, o2, i2, _ = sio.meshes.read_polygons(f)
    assert np.array_equal(o2, o) and np.array_equal(i2, i)
    f.write_bytes(head.encode() + body[:-3])
    raises_mesh_error(lambda: sio.read_mesh(f), "blender.ply", "does not match the header")


def test_coordinates_that_overflow(tmp_path):
    V = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]]) * 1e200
    F = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    raises_mesh_error(lambda: sio.keyframes_from_arrays([V, V * 0.5], F), "keyframe 0",
                      "coordinates overflow")


def test_read_sequence_accepts_a_glb_file(tmp_path):
    pytest.importorskip("pygltflib")
    import trimesh

    m = trimesh.creation.icosphere(subdivisions=1)
    V = np.stack([m.vertices * s for s in (1.0, 1.5, 2.0)])
    out = sio.write_sequence(tmp_path / "out", V, m.faces, {"K": 2}, fmt="glb")
    V2, F2, rep = sio.read_sequence(out / sio.GLB_NAME)
    assert np.allclose(V2, V, atol=1e-6) and np.array_equal(F2, m.faces) and rep == {"K": 2}


# ----------------------------------------------------------------------------------------
# back to the input: expand and write
# ----------------------------------------------------------------------------------------
def _rotation(t):
    return np.array([[np.cos(t), -np.sin(t), 0], [np.sin(t), np.cos(t), 0], [0, 0, 1]])


def test_expand_carries_set_aside_vertices_rigidly(tube):
    """Keyframes related by a rotation: the solve mesh turns by a rotation angle growing
    linearly; the fin vertex and the isolated vertex must turn with it exactly."""
    V0 = tube["V"][0]
    K, frames = 8, np.array([0, 8])
    keys = np.stack([V0, V0 @ _rotation(0.8).T])
    o, i = tube["offsets"], tube["indices"]
    from shellspline.mesh.source_mesh import solve_mesh

    Vs, F, src, _ = solve_mesh(keys, o, i)
    seq = np.stack([Vs[0] @ _rotation(0.1 * k).T for k in range(K + 1)])
    seq[8] = Vs[1]
    out = src.expand(seq, frames, K)
    assert out.shape == (K + 1, V0.shape[0], 3)
    assert np.array_equal(out[0], keys[0]) and np.array_equal(out[8], keys[1])
    for k in range(1, K):
        assert np.allclose(out[k], V0 @ _rotation(0.1 * k).T, atol=1e-12), k


def test_expand_blends_isolated_vertices_linearly(tube):
    """An isolated vertex has no face to ride on: it follows the per-vertex linear blend of its
    keyframe positions (keyframes 0, 10, 20), whatever the solve mesh does."""
    from shellspline.mesh.source_mesh import solve_mesh

    Vs, F, src, _ = solve_mesh(tube["V"], tube["offsets"], tube["indices"])
    frames, K = np.array([0, 10, 20]), 20
    seq = np.repeat(Vs[:1], K + 1, axis=0) * 1.5
    seq[frames] = Vs
    out = src.expand(seq, frames, K)
    X = tube["V"][:, tube["isolated"]]
    for k in range(K + 1):
        j, t = min(k // 10, 1), (k - 10 * min(k // 10, 1)) / 10
        assert np.allclose(out[k, tube["isolated"]], (1 - t) * X[j] + t * X[j + 1],
                           rtol=0, atol=1e-15), k
    assert (src.anchors[src.set_aside == tube["isolated"]] == -1).all()
    assert (src.anchors[src.set_aside == tube["fin_vertex"]] >= 0).all()


def test_write_back_polygons_obj_and_ply(tmp_path, tube):
    kf = sio.read_keyframes(write_set(tmp_path, tube), frames=tube["frames"])
    K = int(kf.frames[-1])
    from shellspline.pipeline.interpolation import linear_blend

    seq = kf.source.expand(linear_blend(kf.V, kf.frames, K), kf.frames, K)
    out = sio.write_sequence(tmp_path / "o", seq, None, fmt="obj", source=kf.source)
    V5, faces = obj_polygons(out / "frame_0005.obj")
    assert [[c - 1 for c in f] for f in faces] == polygon_list(tube)
    assert np.array_equal(V5, seq[5])
    outp = sio.write_sequence(tmp_path / "p", seq, None, fmt="ply", source=kf.source)
    Vr, offr, idxr, _ = sio.meshes.read_polygons(outp / "frame_0010.ply")
    assert np.array_equal(Vr, tube["V"][1])
    assert np.array_equal(offr, tube["offsets"]) and np.array_equal(idxr, tube["indices"])
    # read_sequence triangulates the polygons once for the whole sequence
    Vq, Fq, _ = sio.read_sequence(outp)
    assert np.array_equal(Vq, seq) and Fq.shape == kf.source.triangles.shape
    with pytest.raises(ValueError, match="input's 164 vertices"):
        sio.write_sequence(tmp_path / "x", seq[:, :-1], None, source=kf.source)


@pytest.mark.slow
def test_cli_end_to_end_on_seamed_quad_obj(tmp_path, tube):
    """The seamed quad OBJ through ``shellspline interpolate``: exit 0, the input's polygons
    and vertex count written back, seams not torn, keyframes exact."""
    from shellspline.cli.main import main

    paths = write_set(tmp_path, tube, bom=True, crlf=True)
    out = tmp_path / "out"
    rc = main(["interpolate", *map(str, paths), "--frames", "0,10,20", "-o", str(out), "-q"])
    assert rc == 0
    frames = sorted(out.glob("frame_*.obj"))
    assert len(frames) == 21
    seam = tube["seam"]
    for k, f in enumerate(frames):
        V, faces = obj_polygons(f)
        assert [[c - 1 for c in p] for p in faces] == polygon_list(tube)
        assert V.shape == tube["V"][0].shape
        assert np.array_equal(V[seam[:, 0]], V[seam[:, 1]]), k       # seams not torn
        if k % 10 == 0:
            assert np.array_equal(V, tube["V"][k // 10]), k           # keyframes exact
    # the fin vertex stays near its edge (it is carried, not left behind)
    V10, _ = obj_polygons(frames[5])
    e = [tube["indices"][tube["offsets"][tube["fin"]] + i] for i in range(2)]
    d = np.linalg.norm(V10[tube["fin_vertex"]] - V10[e].mean(0))
    d0 = np.linalg.norm(tube["V"][0, tube["fin_vertex"]] - tube["V"][0, e].mean(0))
    assert abs(d - d0) < 0.2 * d0
    import json

    rep = json.loads((out / "report.json").read_text())
    assert rep["source_mesh"] == {"source_vertices": 164, "polygons": 134,
                                  "non_triangle_polygons": 133, "welded_vertices": 9,
                                  "set_aside_vertices": 2, "fin_polygons": 1,
                                  "reoriented_polygons": 0, "texture_coordinates": 164}
    # texture coordinates carried: the same vt values, every corner naming the input's vt
    _, _, _, (uv_in, cuv_in) = sio.meshes.read_polygons(paths[0])
    _, _, _, (uv_out, cuv_out) = sio.meshes.read_polygons(frames[7])
    assert np.array_equal(uv_out, uv_in) and np.array_equal(cuv_out, cuv_in)


def test_batch_writes_back_the_input_and_maps_pins(tmp_path, tube):
    """A batch job on the seamed quad OBJ: the input's polygons and vertex count written back,
    and a pin given by the files' numbering (a seam copy) reaches its solve vertex."""
    import shellspline as ss

    d = tmp_path / "seqs" / "tube"
    d.mkdir(parents=True)
    paths = write_set(d, tube, bom=True, crlf=True)
    copy = int(tube["seam"][3, 1])
    (tmp_path / "job.toml").write_text(
        '[job]\noutput = "out"\nworkers = 1\n[[sequences]]\nname = "tube"\n'
        f'keyframes = {[str(p) for p in paths]!r}\nframes = [0, 10, 20]\nmethod = "linear"\n'
        f'pinned = [{copy}]\n'.replace("'", '"'))
    summary = ss.run_batch(ss.load_job(tmp_path / "job.toml"))
    assert summary.exit_code == 0
    frame = sorted((tmp_path / "out" / "tube").glob("frame_*.obj"))[5]
    V, faces = obj_polygons(frame)
    assert [[c - 1 for c in f] for f in faces] == polygon_list(tube)
    assert V.shape == tube["V"][0].shape
    seam = tube["seam"]
    assert np.array_equal(V[seam[:, 0]], V[seam[:, 1]])


def test_cli_says_what_reading_changed(tmp_path, tube, capsys):
    from shellspline.cli.main import main

    paths = write_set(tmp_path, tube)
    rc = main(["interpolate", *map(str, paths), "--frames", "0,10,20", "-o",
               str(tmp_path / "o"), "--method", "linear"])
    err = capsys.readouterr().err
    assert rc == 0
    line = next(ln for ln in err.splitlines() if ln.strip().startswith("input:"))
    for says in ("164 vertices, 134 faces", "133 polygons triangulated",
                 "9 seam vertices welded", "1 fin faces set aside", "2 vertices set aside",
                 "164 texture coordinates kept"):
        assert says in line, (says, line)


@pytest.mark.parametrize("fmt", ["obj", "ply", "off"])
def test_data_synth_command_line_writes_the_dcc_set(tmp_path, tube, fmt, capsys):
    from data_synth.__main__ import main as synth_main

    assert synth_main(["dcc_tube", str(tmp_path / "d"), "--format", fmt]) == 0
    paths = sorted((tmp_path / "d").glob(f"pose_*.{fmt}"))
    assert len(paths) == 3
    if fmt == "obj":
        raw = paths[0].read_bytes()
        assert raw.startswith(b"\xef\xbb\xbf") and b"\r\n" in raw
    kf = sio.read_keyframes(paths, frames=tmp_path / "d" / "frames.txt")
    assert kf.frames.tolist() == [0, 10, 20] and kf.source.n_source == tube["V"].shape[1]
    assert np.array_equal(kf.V[:, kf.source.to_solve[0]], tube["V"][:, 0])
    with pytest.raises(SystemExit):
        synth_main(["dcc_tube", str(tmp_path / "e"), "--vertices", "100"])


def test_polygons_written_from_another_corner_are_the_same_faces(tmp_path, tube):
    """One keyframe's exporter starts every polygon at another corner (same orientation): the
    keyframes read exactly as if it had not; a real difference still names the face, with a
    hint about vertex order."""
    polys = polygon_list(tube)
    rng = np.random.default_rng(5)
    turned = [p[k:] + p[:k] for p, k in zip(polys, rng.integers(0, 16, len(polys)) % 3)]
    assert turned != polys
    ref = sio.read_keyframes(write_set(tmp_path, tube))
    paths = write_set(tmp_path, tube)
    lines = paths[1].read_text(encoding="utf-8-sig").splitlines()
    faces = iter(turned)
    lines = ["f " + " ".join(str(i + 1) for i in next(faces)) if ln.startswith("f ") else ln
             for ln in lines]
    paths[1].write_text("\n".join(lines) + "\n")
    got = sio.read_keyframes(paths)
    np.testing.assert_array_equal(got.V, ref.V)
    np.testing.assert_array_equal(got.F, ref.F)
    # reversed orientation is another face list
    lines = ["f " + " ".join(str(i + 1) for i in p[::-1]) for p in polys]
    paths[2].write_text("".join(f"v {x!r} {y!r} {z!r}\n" for x, y, z in tube["V"][2].tolist())
                        + "\n".join(lines) + "\n")
    raises_mesh_error(lambda: sio.read_keyframes(paths), "pose_2.obj: face list differs",
                      "first difference at face 1 on line", "same vertex order")

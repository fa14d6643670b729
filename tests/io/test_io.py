"""Tests for shellspline.io: reading, validation, atomic writing."""
from __future__ import annotations

import json
import multiprocessing as mp
import os
from pathlib import Path

import numpy as np
import pytest
import trimesh

from shellspline import io as sio
from shellspline.errors import MeshError, ShellsplineError
from shellspline.io.sequences import frame_files

from conftest import raises_mesh_error

SHARED_DATA = Path(__file__).resolve().parents[3] / "shared" / "data"


# ----------------------------------------------------------------------------------------
# helpers: meshes built in code, files written by hand (independent of the module)
# ----------------------------------------------------------------------------------------
def sphere():
    m = trimesh.creation.icosphere(subdivisions=1)
    return np.array(m.vertices, dtype=np.float64), np.array(m.faces, dtype=np.int64)


def write_obj(path, V, F, header=""):
    lines = [header] if header else []
    lines += ["v %r %r %r" % tuple(v) for v in V.tolist()]
    lines += ["f %d %d %d" % tuple(f) for f in (np.asarray(F) + 1).tolist()]
    Path(path).write_text("\n".join(lines) + "\n")
    return str(path)


def write_off(path, V, F):
    lines = ["OFF", f"{len(V)} {len(F)} 0"]
    lines += ["%r %r %r" % tuple(v) for v in V.tolist()]
    lines += [" ".join(map(str, [len(f)] + list(f))) for f in F]
    Path(path).write_text("\n".join(lines) + "\n")
    return str(path)


def write_ply_ascii(path, V, F, prop="double"):
    head = ["ply", "format ascii 1.0", f"element vertex {len(V)}",
            f"property {prop} x", f"property {prop} y", f"property {prop} z",
            f"element face {len(F)}", "property list uchar int vertex_indices", "end_header"]
    body = ["%r %r %r" % tuple(v) for v in np.asarray(V).tolist()]
    body += [" ".join(map(str, [len(f)] + list(f))) for f in F]
    Path(path).write_text("\n".join(head + body) + "\n")
    return str(path)


def write_ply_binary(path, V, F, prop="double"):
    head = ("ply\nformat binary_little_endian 1.0\n"
            f"element vertex {len(V)}\nproperty {prop} x\nproperty {prop} y\n"
            f"property {prop} z\nelement face {len(F)}\n"
            "property list uchar int vertex_indices\nend_header\n")
    rec = np.zeros(len(F), dtype=[("c", "u1"), ("i", "<i4", (3,))])
    rec["c"], rec["i"] = 3, F
    dtype = "<f8" if prop == "double" else "<f4"
    Path(path).write_bytes(head.encode() + np.asarray(V, dtype).tobytes() + rec.tobytes())
    return str(path)


def keyframe_files(tmp_path, n_keys=3, ext="obj"):
    V, F = sphere()
    writer = {"obj": write_obj, "off": write_off, "ply": write_ply_ascii}[ext]
    return [writer(tmp_path / f"k{j}.{ext}", V * (1 + 0.25 * j), F) for j in range(n_keys)]


def bits(X):
    return np.ascontiguousarray(X, dtype=np.float64).view(np.int64)


# ----------------------------------------------------------------------------------------
# reading
# ----------------------------------------------------------------------------------------
def test_formats_agree_and_keep_vertex_order(tmp_path):
    V, F = sphere()
    perm = np.random.default_rng(1).permutation(len(V))
    V = V[perm]
    F = np.argsort(perm)[F]  # same surface, permuted vertex numbering
    # a vertex at the same position as vertex 0, used by one face, and an unused vertex
    n = len(V)
    V = np.vstack([V, V[0], [[7.0, 8.0, 9.0]]])
    t = int(np.flatnonzero((F == 0).any(axis=1))[0])
    F[t][F[t] == 0] = n
    paths = [write_obj(tmp_path / "m.obj", V, F), write_off(tmp_path / "m.off", V, F),
             write_ply_ascii(tmp_path / "m.ply", V, F), write_ply_binary(tmp_path / "b.ply", V, F)]
    for p in paths:
        V2, F2 = sio.read_mesh(p)
        assert V2.dtype == np.float64 and F2.dtype == np.int64, p
        assert V2.shape == (n + 2, 3) and F2.shape == F.shape, p
        assert np.array_equal(bits(V2), bits(V)), p
        assert np.array_equal(F2, F), p


def test_float32_ply_converted_exactly(tmp_path):
    V, F = sphere()
    p = write_ply_binary(tmp_path / "f32.ply", V, F, prop="float")
    V2, F2 = sio.read_mesh(p)
    assert V2.dtype == np.float64
    assert np.array_equal(V2, V.astype(np.float32).astype(np.float64))
    assert np.array_equal(F2, F)


def test_ascii_ply_float_is_float32_for_triangles_and_polygons(tmp_path):
    """ASCII "property float" reads as the float32 the header declares, whether the faces
    are triangles (trimesh's reader) or quads (ours): the same mesh reads the same."""
    V = np.array([[0.1, 0.2, 0.3], [1.1, 0.2, 0.3], [1.1, 1.7, 0.3], [0.1, 1.7, 0.3]])
    head = ("ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\n"
            "property float z\nproperty uchar red\nelement face {}\n"
            "property list uchar int vertex_indices\nend_header\n")
    verts = "".join(f"{x} {y} {z} 200\n" for x, y, z in V)
    tri = tmp_path / "tri.ply"
    tri.write_text(head.format(2) + verts + "3 0 1 2\n3 0 2 3\n")
    quad = tmp_path / "quad.ply"
    quad.write_text(head.format(1) + verts + "4 0 1 2 3\n")
    expect = V.astype(np.float32).astype(np.float64)
    for p in (tri, quad):
        V2, F2 = sio.read_mesh(p)
        assert np.array_equal(V2, expect), p
        assert F2.shape == (2, 3)


_PYRAMID = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0.5, 0.5, 1]])
_PYRAMID_POLYS = [[0, 1, 2, 3], [0, 1, 4], [1, 2, 4], [2, 3, 4], [3, 0, 4]]


def _meshlab_ply(path, polys, fmt):
    """A PLY as MeshLab writes it: per-vertex quality, per-face texcoord lists (floats) and
    texnumber, and a TextureFile comment naming an image that is not there."""
    import struct
    e = ">" if "big" in fmt else "<"
    head = (f"ply\nformat {fmt} 1.0\ncomment VCGLIB generated\ncomment TextureFile tex.png\n"
            f"element vertex 5\nproperty float x\nproperty float y\nproperty float z\n"
            f"property float quality\nelement face {len(polys)}\n"
            "property list uchar int vertex_indices\nproperty list uchar float texcoord\n"
            "property int texnumber\nend_header\n").encode()
    if fmt == "ascii":
        body = "".join(f"{x} {y} {z} 0.5\n" for x, y, z in _PYRAMID)
        body += "".join(f"{len(f)} {' '.join(map(str, f))} {2 * len(f)} "
                        f"{' '.join(['0.25'] * 2 * len(f))} 0\n" for f in polys)
        body = body.encode()
    else:
        body = b"".join(struct.pack(e + "4f", *v, 0.5) for v in _PYRAMID)
        body += b"".join(struct.pack(e + "B", len(f)) + struct.pack(e + f"{len(f)}i", *f)
                         + struct.pack(e + "B", 2 * len(f))
                         + struct.pack(e + f"{2 * len(f)}f", *[0.25] * (2 * len(f)))
                         + struct.pack(e + "i", 0) for f in polys)
    path.write_bytes(head + body)
    return path


@pytest.mark.parametrize("fmt", ["ascii", "binary_little_endian", "binary_big_endian"])
@pytest.mark.parametrize("quads", [True, False])
def test_meshlab_ply_with_texcoord_lists(tmp_path, caplog, fmt, quads):
    polys = _PYRAMID_POLYS if quads else [[0, 1, 2], [0, 2, 3]] + _PYRAMID_POLYS[1:]
    p = _meshlab_ply(tmp_path / "m.ply", polys, fmt)
    with caplog.at_level("DEBUG"):
        V, offsets, indices, _ = sio.meshes.read_polygons(p)
    assert np.array_equal(V, _PYRAMID)
    assert [indices[a:b].tolist() for a, b in zip(offsets[:-1], offsets[1:])] == polys
    # trimesh logged "unable to load image!" with a traceback (shown on the terminal)
    assert not [r for r in caplog.records if r.levelno >= 30 or r.exc_info]


@pytest.mark.parametrize("header, phrase", [
    ("element vertex 4\nproperty float128 x\nproperty float y\nproperty float z\n",
     "header line 4: not a PLY property: 'property float128 x' (unknown type 'float128')"),
    ("element vertex -4\nproperty float x\nproperty float y\nproperty float z\n",
     "element 'vertex' needs a non-negative count, got '-4'"),
])
def test_ply_header_errors_in_words(tmp_path, header, phrase):
    p = tmp_path / "h.ply"
    p.write_text("ply\nformat ascii 1.0\n" + header + "element face 1\nproperty list uchar "
                 "int vertex_indices\nend_header\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n4 0 1 2 3\n")
    raises_mesh_error(lambda: sio.read_mesh(p), "h.ply", phrase)
    q = tmp_path / "nolist.ply"
    q.write_text("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
                 "property float z\nelement face 1\nproperty int a\nend_header\n0 0 0\n1 0 0\n"
                 "0 1 0\n4\n")
    raises_mesh_error(lambda: sio.read_mesh(q), "no 'vertex_indices' list property")
    r = tmp_path / "big.obj"
    r.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 99999999999999999999\n")
    raises_mesh_error(lambda: sio.read_mesh(r), "line 4, face 1 (f 1 2 99999999999999999999)",
                      "vertex index '99999999999999999999' is too large")


@pytest.mark.parametrize("name, content, phrase", [
    ("two.off", "OFF\n4 2 0\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n4 0 1 2 3\n2 0 1\n",
     "face 1 has 2 vertices (a face needs at least 3"),
    ("words.off", "OFF\n4 1 0\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n4 0 1 2 x\n",
     "which declares 4 vertices and 1 faces ('x' is not an integer"),
    ("count.off", "OFF\nfour 1 0\n0 0 0\n", "('four' is not an integer"),
    ("noend.ply", "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\n",
     "the PLY header has no end_header"),
    ("noz.ply", "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y"
     "\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n0 0\n1 0\n1 1\n"
     "0 1\n4 0 1 2 3\n", "the vertex element has no 'z' property"),
    ("half.ply", "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y"
     "\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
     "0 0 0\n1 0 0\n1 1 0\n0 1 0\n4 0 1 2.5 3\n", "'2.5' is not an integer"),
])
def test_malformed_ply_and_off_say_why_in_words(tmp_path, name, content, phrase):
    """No Python exception names (IndexError, KeyError, 'invalid literal ...') in the
    message: what is wrong with the file, in words."""
    p = tmp_path / name
    p.write_text(content)
    msg = raises_mesh_error(lambda: sio.read_mesh(p), name, phrase)
    assert "Error" not in msg and "literal" not in msg


def test_obj_dialects(tmp_path):
    text = ("# comment line\r\n"
            "o thing\r\n"
            "v 0 0 0 1.0\r\n"          # optional w ignored
            "  v\t1 0 0\r\n"           # leading whitespace and tab
            "v 0 1 0  # trailing comment\r\n"
            "v 0 0 1\r\n"
            "vt 0 0\r\nvt 1 0\r\nvt 0 1\r\nvn 0 0 1\r\n"
            "usemtl red\r\ng side\r\n"
            "f 1/1/1 3/3/1 2/2/1\r\n"
            "f 1//1 2//1 4//1\r\n"
            "f -4 -1 -2\r\n"            # relative: vertices 1, 4, 3
            "f 2/2 3/3 4/1\r\n")
    p = tmp_path / "dialect.obj"
    p.write_bytes(text.encode())
    V, F = sio.read_mesh(p)
    assert V.tolist() == [[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]]
    assert F.tolist() == [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]


def test_read_shared_sphere_keyframes():
    d = SHARED_DATA / "unit_sphere"
    if not d.is_dir():
        pytest.skip("../shared/data not present (a user's clone has no ../shared)")
    paths = [d / f for f in ("unitSphere1.ply", "unitSphere1_defX.ply", "unitSphere1_defY.ply",
                             "unitSphere1_defZ.ply")]
    kf = sio.read_keyframes(paths, frames=[0, 3, 6, 9])
    assert (kf.J, kf.n, kf.m) == (4, 162, 320)
    assert kf.V.dtype == np.float64 and kf.F.dtype == np.int64
    assert kf.names == [str(p) for p in paths]


# ----------------------------------------------------------------------------------------
# validation: every invalid input raises a one-line MeshError naming the file
# ----------------------------------------------------------------------------------------
def test_missing_file(tmp_path):
    paths = keyframe_files(tmp_path, 2)
    missing = str(tmp_path / "nope.obj")
    raises_mesh_error(lambda: sio.read_keyframes(paths + [missing]), "nope.obj",
                      "no such file")


@pytest.mark.parametrize("ext", ["obj", "ply", "off"])
def test_garbage_content(tmp_path, ext):
    p = tmp_path / f"junk.{ext}"
    p.write_bytes(b"\x00\x01\x02garbage\xff\xfe" * 10)
    good = keyframe_files(tmp_path, 1)
    raises_mesh_error(lambda: sio.read_keyframes(good + [p]), f"junk.{ext}", "cannot read")


def test_unknown_extension(tmp_path):
    p = tmp_path / "mesh.stl"
    p.write_text("solid x\nendsolid x\n")
    raises_mesh_error(lambda: sio.read_mesh(p), "mesh.stl", "unknown extension")


def test_empty_mesh(tmp_path):
    p = tmp_path / "empty.obj"
    p.write_text("# nothing here\n")
    good = keyframe_files(tmp_path, 1)
    raises_mesh_error(lambda: sio.read_keyframes(good + [p]), "empty.obj", "empty mesh")


def test_mismatched_vertex_count(tmp_path):
    V, F = sphere()
    a = write_obj(tmp_path / "a.obj", V, F)
    b = write_obj(tmp_path / "b.obj", np.vstack([V, [[5.0, 5, 5]]]), F)
    raises_mesh_error(lambda: sio.read_keyframes([a, b]), "b.obj has 43 vertices but",
                      "a.obj has 42")


def test_mismatched_faces(tmp_path):
    V, F = sphere()
    F2 = F.copy()
    F2[17] = F2[17][[0, 2, 1]]  # same vertices, other orientation (a turned listing,
    # [1, 2, 0], is the same face: accepted, see test_io_dcc)
    a = write_obj(tmp_path / "a.obj", V, F)
    b = write_obj(tmp_path / "b.obj", V, F2)
    # in the OBJ files' own terms: the 18th face, on line 42 + 18 (1-based vertex indices)
    f17 = " ".join(str(i + 1) for i in F2[17])
    raises_mesh_error(lambda: sio.read_keyframes([a, b]), "b.obj", "face list differs",
                      "a.obj", f"first difference at face 18 on line 60 (f {f17}) vs face 18")
    c = write_obj(tmp_path / "c.obj", V, F[:-1])
    raises_mesh_error(lambda: sio.read_keyframes([a, c]), "c.obj", "face list differs")


@pytest.mark.parametrize("ext", ["obj", "off", "ply"])
def test_quad_face(tmp_path, ext):
    V = np.array([[0.0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [2, 0, 0], [2, 1, 0]])
    F = [[0, 1, 2, 3], [1, 4, 5]]
    p = tmp_path / f"quad.{ext}"
    if ext == "obj":
        p.write_text("".join("v %r %r %r\n" % tuple(v) for v in V.tolist())
                     + "f 1 2 3 4\nf 2 5 6\n")
    elif ext == "off":
        write_off(p, V, F)
    else:
        write_ply_ascii(p, V, F)
    V2, F2 = sio.read_mesh(p)  # polygons are triangulated (they were refused before)
    assert np.array_equal(V2, V)
    # the quad's two triangles first (a diagonal of 0-1-2-3, same orientation), then 1-5-6
    assert F2.shape == (3, 3) and F2[2].tolist() == [1, 4, 5]
    assert sorted(map(sorted, F2[:2].tolist())) in ([[0, 1, 2], [0, 2, 3]], [[0, 1, 3], [1, 2, 3]])
    n = np.cross(V2[F2[:, 1]] - V2[F2[:, 0]], V2[F2[:, 2]] - V2[F2[:, 0]])
    assert (n[:, 2] > 0).all()


def test_non_manifold_edge(tmp_path):
    V = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1]])
    F = np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4]])  # edge (0,1) has three faces
    paths = [write_obj(tmp_path / f"nm{j}.obj", V * (j + 1), F) for j in range(2)]
    kf = sio.read_keyframes(paths)  # the third face is set aside as a fin (refused before)
    assert kf.F.tolist() == [[0, 1, 2], [1, 0, 3]] and kf.n == 4
    assert kf.source.fin_polygons.tolist() == [2] and kf.source.set_aside.tolist() == [4]
    # a face given again (either orientation) is set aside as a fin
    F = np.array([[0, 1, 2], [1, 0, 3], [2, 1, 0], [0, 1, 2]])
    paths = [write_obj(tmp_path / f"nn{j}.obj", V * (j + 1), F) for j in range(2)]
    kf = sio.read_keyframes(paths)
    assert kf.F.tolist() == [[0, 1, 2], [1, 0, 3]] and kf.source.fin_polygons.tolist() == [2, 3]


def test_inconsistent_orientation(tmp_path):
    V = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, -1, 0]])
    F = np.array([[0, 1, 2], [0, 1, 3]])  # both traverse 0 -> 1: fixable, face 1 reversed
    kf = sio.keyframes_from_arrays([V, 2 * V], F)
    assert kf.F.tolist() == [[0, 1, 2], [0, 3, 1]] and kf.source.n_reoriented == 1
    # a Moebius strip cannot be oriented: still refused
    t = np.linspace(0, 2 * np.pi, 9)[:-1]
    ring = [np.c_[(1 + w * np.cos(t / 2)) * np.cos(t), (1 + w * np.cos(t / 2)) * np.sin(t),
                  w * np.sin(t / 2)] for w in (-0.3, 0.3)]
    Vm = np.vstack(ring)                                    # vertex i (w=-), 8 + i (w=+)
    Fm = []
    for i in range(8):
        a, b = i, 8 + i
        c, d = ((i + 1, 9 + i) if i < 7 else (8, 0))        # the half twist swaps the sides
        Fm += [[a, c, b], [b, c, d]]
    raises_mesh_error(lambda: sio.keyframes_from_arrays([Vm, 2 * Vm], Fm), "keyframe 0",
                      "consistently oriented")


@pytest.mark.parametrize("kind", ["coincident", "collinear"])
def test_degenerate_face(tmp_path, kind):
    V, F = sphere()
    a, b, c = F[5]
    W = V.copy()
    W[a] = W[b] if kind == "coincident" else 0.5 * (W[b] + W[c])
    paths = [write_obj(tmp_path / "ok.obj", V, F), write_obj(tmp_path / "flat.obj", W, F)]
    msg = raises_mesh_error(lambda: sio.read_keyframes(paths), "flat.obj", "degenerate")
    assert "face 5" in msg or "degenerate (zero-area) faces" in msg


def test_nan_coordinate(tmp_path):
    V, F = sphere()
    W = V.copy()
    W[3, 1] = np.nan
    paths = [write_obj(tmp_path / "a.obj", V, F), write_obj(tmp_path / "b.obj", W, F)]
    raises_mesh_error(lambda: sio.read_keyframes(paths), "b.obj", "NaN", "vertex 3")
    W[3, 1] = np.inf
    raises_mesh_error(lambda: sio.keyframes_from_arrays([V, W], F), "keyframe 1", "inf")


def test_single_keyframe(tmp_path):
    paths = keyframe_files(tmp_path, 1)
    raises_mesh_error(lambda: sio.read_keyframes(paths), "at least 2 keyframes", "k0.obj")
    raises_mesh_error(lambda: sio.read_keyframes(paths[0]), "at least 2 keyframes")
    V, F = sphere()
    raises_mesh_error(lambda: sio.keyframes_from_arrays(V, F), "at least 2 keyframes")
    raises_mesh_error(lambda: sio.keyframes_from_arrays([V], F), "at least 2 keyframes")


@pytest.mark.parametrize("frames, phrase", [
    ([0, 10], "one entry per keyframe (3)"),
    ([0, 10, 10], "strictly increasing"),
    ([0, 20, 10], "strictly increasing"),
    ([-1, 10, 20], "non-negative"),
    ([0, 2.5, 5], "integers"),
    ("0,a,3", "frames '0,a,3'"),
    ([[0, 1, 2]], "1-D"),
])
def test_bad_frames(tmp_path, frames, phrase):
    paths = keyframe_files(tmp_path, 3)
    raises_mesh_error(lambda: sio.read_keyframes(paths, frames=frames), phrase)
    V, F = sphere()
    raises_mesh_error(lambda: sio.keyframes_from_arrays([V, 2 * V, 3 * V], F, frames=frames),
                      phrase)


def test_good_frames_are_canonical(tmp_path):
    paths = keyframe_files(tmp_path, 3)
    assert sio.read_keyframes(paths).frames is None
    for spec in ([0, 5, 9], np.array([0.0, 5.0, 9.0]), "0, 5,9", (0, 5, 9)):
        fr = sio.read_keyframes(paths, frames=spec).frames
        assert fr.dtype == np.int64 and fr.tolist() == [0, 5, 9]
    kf = sio.read_keyframes(paths)
    kf2 = kf.with_frames([0, 1, 2])
    assert kf2.frames.tolist() == [0, 1, 2] and kf2.topology is kf.topology
    with pytest.raises(MeshError, match="strictly increasing"):
        kf.with_frames([0, 2, 1])


def test_pinned(tmp_path):
    paths = keyframe_files(tmp_path, 2)
    kf = sio.read_keyframes(paths, pinned=[5, 3, 3, 0])
    assert kf.pinned.tolist() == [0, 3, 5] and kf.pinned.dtype == np.int64
    raises_mesh_error(lambda: sio.read_keyframes(paths, pinned=[0, 42]), "[0, 42)", "42")
    raises_mesh_error(lambda: sio.read_keyframes(paths, pinned=[-1]), "[0, 42)")
    mask = np.zeros(42, dtype=bool)
    mask[[1, 4]] = True
    assert sio.read_keyframes(paths, pinned=mask).pinned.tolist() == [1, 4]
    idx_file = tmp_path / "pins.txt"
    idx_file.write_text("# pins\n7,8\n9\n")
    assert sio.read_keyframes(paths, pinned=idx_file).pinned.tolist() == [7, 8, 9]


def test_keyframes_from_arrays_copies_and_caches_topology():
    V, F = sphere()
    Vs = np.stack([V, 1.5 * V])
    kf = sio.keyframes_from_arrays(Vs, F.astype(np.int32), frames=[0, 4])
    assert kf.V.dtype == np.float64 and kf.F.dtype == np.int64
    assert kf.names == ["keyframe 0", "keyframe 1"]
    assert not np.shares_memory(kf.V, Vs)
    assert kf.topology is kf.topology
    assert (kf.J, kf.n, kf.m) == (2, 42, 80)
    raises_mesh_error(lambda: sio.keyframes_from_arrays([V, V[:-1]], F),
                      "keyframe 1 has 41 vertices but keyframe 0 has 42")
    raises_mesh_error(lambda: sio.keyframes_from_arrays([V, V], F + 1), "keyframe 0",
                      "face indices")
    raises_mesh_error(lambda: sio.keyframes_from_arrays([V, V], F, names=["a"]), "names")


# ----------------------------------------------------------------------------------------
# small text inputs
# ----------------------------------------------------------------------------------------
def test_read_indices(tmp_path):
    p = tmp_path / "idx.txt"
    p.write_text("# header\n1 2, 3\n\n4,5 # tail\n6\n")
    out = sio.read_indices(p)
    assert out.dtype == np.int64 and out.tolist() == [1, 2, 3, 4, 5, 6]
    p.write_text("1 2\nx 3\n")
    raises_mesh_error(lambda: sio.read_indices(p), "idx.txt", "line 2", "'x'")
    raises_mesh_error(lambda: sio.read_indices(tmp_path / "none.txt"), "none.txt",
                      "cannot read")


def test_read_indices_shared_cactus_mask():
    p = SHARED_DATA / "cactus" / "cactusBottomMask_indices.txt"
    if not p.is_file():
        pytest.skip("../shared/data not present (a user's clone has no ../shared)")
    idx = sio.read_indices(p)
    assert idx.size == 311 and idx.min() >= 0 and idx.max() < 5261


def test_read_frames(tmp_path):
    assert sio.read_frames("0,10,20").tolist() == [0, 10, 20]
    assert sio.read_frames(" 0 10\t20 ").tolist() == [0, 10, 20]
    p = tmp_path / "frames.txt"
    p.write_text("0\n# middle\n7\n12\n")
    assert sio.read_frames(str(p)).tolist() == [0, 7, 12]
    assert sio.read_frames(p).tolist() == [0, 7, 12]
    assert sio.read_frames([0, 3]).tolist() == [0, 3]
    raises_mesh_error(lambda: sio.read_frames("0,1.5"), "neither")
    raises_mesh_error(lambda: sio.read_frames("0,,x"), "neither")
    raises_mesh_error(lambda: sio.read_frames([0.5, 1]), "integers")


# ----------------------------------------------------------------------------------------
# writing
# ----------------------------------------------------------------------------------------
def awkward_poses(K1=3):
    V, F = sphere()
    rng = np.random.default_rng(0)
    Vs = V[None] + rng.standard_normal((K1, len(V), 3))
    Vs[0, 0] = [0.1, 1.0 / 3.0, -0.0]
    Vs[0, 1] = [5e-324, 1e-300, -1e300]
    Vs[0, 2] = [2.0 ** -60, 123456789.123456789, np.nextafter(1.0, 2.0)]
    return Vs, F


@pytest.mark.parametrize("fmt", ["obj", "ply"])
def test_round_trip_bit_exact(tmp_path, fmt):
    Vs, F = awkward_poses()
    report = {"K": np.int64(2), "res": np.array([1.5, 2.5]), "ok": np.bool_(True),
              "path": tmp_path, "nested": {"t": (1, 2)}}
    out = sio.write_sequence(tmp_path / "out", Vs, F, report, fmt=fmt)
    assert out == (tmp_path / "out").resolve()
    names = sorted(p.name for p in out.iterdir())
    assert names == [f"frame_000{k}.{fmt}" for k in range(3)] + ["report.json"]
    V2, F2, rep = sio.read_sequence(out)
    assert np.array_equal(bits(V2), bits(Vs))
    assert np.array_equal(F2, F)
    assert rep == {"K": 2, "res": [1.5, 2.5], "ok": True, "path": str(tmp_path),
                   "nested": {"t": [1, 2]}}
    assert json.loads((out / "report.json").read_text()) == rep


def test_obj_output_is_plain_and_one_based(tmp_path):
    V = np.array([[[0.0, 0, 0], [1, 0, 0], [0, 1, 0]]])
    out = sio.write_sequence(tmp_path / "o", V, [[0, 1, 2]])
    assert (out / "frame_0000.obj").read_text() == "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"
    assert sio.read_sequence(out)[2] == {}


def test_frame_name_width_grows(tmp_path, monkeypatch):
    written = []
    monkeypatch.setattr(sio.sequences, "write_ply_frame", lambda p, *a: written.append(p.name))
    V = np.zeros((12345, 3, 3))
    sio.write_sequence(tmp_path / "w", V, [[0, 1, 2]], fmt="ply")
    assert written[0] == "frame_00000.ply" and written[-1] == "frame_12344.ply"


def test_failure_midway_leaves_nothing(tmp_path, monkeypatch):
    Vs, F = awkward_poses(5)
    calls = []
    real = sio.sequences.write_obj_frame

    def flaky(path, V, block):
        calls.append(path)
        if len(calls) == 3:
            raise RuntimeError("disk on fire")
        real(path, V, block)

    monkeypatch.setattr(sio.sequences, "write_obj_frame", flaky)
    with pytest.raises(RuntimeError, match="disk on fire"):
        sio.write_sequence(tmp_path / "out", Vs, F)
    assert list(tmp_path.iterdir()) == []  # no out_dir, no temporary directory


def test_unserialisable_report_fails_before_writing(tmp_path):
    Vs, F = awkward_poses(2)
    with pytest.raises(ShellsplineError, match=r"report\['bad'\]"):
        sio.write_sequence(tmp_path / "out", Vs, F, {"bad": object()})
    assert list(tmp_path.iterdir()) == []


def test_existing_output_without_overwrite(tmp_path):
    Vs, F = awkward_poses(2)
    out = tmp_path / "out"
    out.mkdir()
    (out / "keep.txt").write_text("precious")
    with pytest.raises(FileExistsError, match="out"):
        sio.write_sequence(out, Vs, F)
    assert [p.name for p in out.iterdir()] == ["keep.txt"]
    assert (out / "keep.txt").read_text() == "precious"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]
    # overwrite=True still refuses a directory that is not an earlier output
    with pytest.raises(ShellsplineError, match="does not look like an earlier output"):
        sio.write_sequence(out, Vs, F, overwrite=True)
    assert [p.name for p in out.iterdir()] == ["keep.txt"]


def test_overwrite_replaces_earlier_output(tmp_path):
    Vs, F = awkward_poses(3)
    out = sio.write_sequence(tmp_path / "out", Vs, F, {"run": 1})
    sio.write_sequence(tmp_path / "out", 2 * Vs[:2], F, {"run": 2}, overwrite=True)
    V2, _, rep = sio.read_sequence(out)
    assert rep == {"run": 2} and np.array_equal(V2, 2 * Vs[:2])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]  # nothing left aside


def test_protect_inputs(tmp_path):
    (tmp_path / "in").mkdir()
    paths = keyframe_files(tmp_path / "in", 2)
    Vs, F = awkward_poses(2)
    for bad in (tmp_path / "in", tmp_path, Path(paths[0])):
        with pytest.raises((ShellsplineError, FileExistsError)) as info:
            sio.write_sequence(bad, Vs, F, protect=paths, overwrite=True)
        assert isinstance(info.value, ShellsplineError), info.value
        assert "k0.obj" in str(info.value)
    assert sorted(p.name for p in (tmp_path / "in").iterdir()) == ["k0.obj", "k1.obj"]
    out = sio.write_sequence(tmp_path / "out", Vs, F, protect=paths)
    assert out.is_dir()


def test_bad_write_arguments(tmp_path):
    Vs, F = awkward_poses(2)
    with pytest.raises(ShellsplineError, match="fmt"):
        sio.write_sequence(tmp_path / "o", Vs, F, fmt="stl")
    with pytest.raises(ShellsplineError, match=r"\(K\+1,n,3\)"):
        sio.write_sequence(tmp_path / "o", Vs[0], F)
    with pytest.raises(ShellsplineError, match="outside"):
        sio.write_sequence(tmp_path / "o", Vs, F + 1)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.skipif("fork" not in mp.get_all_start_methods(), reason="needs fork")
def test_parallel_writer_matches_serial(tmp_path):
    Vs, F = awkward_poses(5)
    a = sio.write_sequence(tmp_path / "a", Vs, F)
    b = sio.write_sequence(tmp_path / "b", Vs, F, workers=2)
    for k in range(5):
        name = f"frame_{k:04d}.obj"
        assert (a / name).read_bytes() == (b / name).read_bytes()


def test_read_sequence_errors(tmp_path):
    Vs, F = awkward_poses(3)
    out = sio.write_sequence(tmp_path / "out", Vs, F)
    os.remove(out / "frame_0001.obj")
    raises_mesh_error(lambda: sio.read_sequence(out), "missing [1]")
    raises_mesh_error(lambda: sio.read_sequence(tmp_path / "none"), "not a directory")


# ----------------------------------------------------------------------------------------
# frame folders: which run of digits is the frame number
# ----------------------------------------------------------------------------------------
def _frame_folder(d, names):
    V, F = sphere()
    d.mkdir()
    for j, name in enumerate(names):
        write_obj(d / name, V * (1 + 0.1 * j), F)
    return d


def test_frame_number_is_the_run_of_digits_that_varies(tmp_path):
    """A version suffix after the frame number (``frame_0001_v2.obj``, as DCC tools export)
    made every file its own sequence ('frame_0001_v#'): the number that varies is the frame."""
    frames = [10, 2, 1, 3]  # unpadded numbers too: natural order
    d = _frame_folder(tmp_path / "v", [f"frame_{k:04d}_v2.obj" for k in frames])
    assert [f.name for f in frame_files(d)] == \
        [f"frame_{k:04d}_v2.obj" for k in (1, 2, 3, 10)]
    u = _frame_folder(tmp_path / "u", [f"shot3_{k}_v12.ply" for k in frames])
    assert [f.name for f in frame_files(u)] == [f"shot3_{k}_v12.ply" for k in (1, 2, 3, 10)]
    # the frames read are those of the plain-named folder
    p = _frame_folder(tmp_path / "p", [f"frame_{k:04d}.obj" for k in frames])
    Vv = sio.read_keyframes(frame_files(d)).V
    assert np.array_equal(Vv, sio.read_keyframes(frame_files(p)).V)
    # today's refusals stay: a stray mesh, one frame twice (each number run compared by value)
    write_obj(d / "rest.obj", *sphere())
    raises_mesh_error(lambda: frame_files(d), "not one numbered sequence",
                      "4 named like frame_0001_v2.obj, 1 like rest.obj")
    (d / "rest.obj").unlink()
    write_obj(d / "frame_3_v2.obj", *sphere())
    raises_mesh_error(lambda: frame_files(d),
                      "two files of frame 3: frame_0003_v2.obj and frame_3_v2.obj")
    (d / "frame_3_v2.obj").unlink()
    # a frame exported again as another version: one version differs, the frame too
    write_obj(d / "frame_0003_v3.obj", *sphere())
    raises_mesh_error(lambda: frame_files(d), "not one numbered sequence")


def test_two_takes_in_one_folder_are_refused_not_read_as_one(tmp_path):
    """Where several runs of digits vary (take and frame), the last is the frame number and
    the takes are separate sequences: refused, as before, not interleaved into one."""
    names = [f"take{t}_{k:04d}.obj" for t in (1, 2) for k in (1, 2, 3)]
    d = _frame_folder(tmp_path / "t", names)
    raises_mesh_error(lambda: frame_files(d), "not one numbered sequence",
                      "3 named like take1_0001.obj, 3 like take2_0001.obj")
    # one take's frames with the take number constant: one sequence
    one = _frame_folder(tmp_path / "one", names[3:])
    assert [f.name for f in frame_files(one)] == names[3:]
    # a take number that rises with the frame is no frame number either
    s = _frame_folder(tmp_path / "s", ["take1_0001.obj", "take2_0002.obj", "take3_0003.obj"])
    raises_mesh_error(lambda: frame_files(s), "not one numbered sequence")

"""What the input had is written back, and bad input is said in the file's own terms.

Point caches on a polygon mesh (``--topology``) keep the mesh's polygons, numbering, texture
coordinates and material/group lines; a bad ``vt`` reference is an error, faces without one a
note; quad diagonals do not depend on the unit; index and frame files with a byte-order mark;
``--overwrite`` named on the command line; OBJ messages with 1-based indices and line numbers;
a point cache without ``--topology``; ``mtllib/usemtl/o/g/s`` lines written back.
"""
from __future__ import annotations

import json
import os

import numpy as np
import pytest

import shellspline.io as sio
from data_synth.dcc import dcc_tube, write_dcc_obj
from shellspline.cli.main import main
from shellspline.io.pointcache import read_pc2, write_mdd, write_pc2

from conftest import raises_mesh_error


def write_set(d, folder, **kw):
    folder.mkdir(parents=True, exist_ok=True)
    return [write_dcc_obj(folder / f"pose_{j}.obj", X, d["offsets"], d["indices"], d["uv"], **kw)
            for j, X in enumerate(d["V"])]


def obj_file(path):
    """An independent line-by-line OBJ reader: ``v`` rows, ``vt`` rows, the polygons' vertex
    and texture indices (1-based, as written; relative ones resolved) and the sequence of
    ``mtllib/usemtl/o/g/s`` lines and faces (``"f"`` for a face)."""
    V, VT, faces, tex, order = [], [], [], [], []
    for ln in path.read_text(encoding="utf-8-sig").splitlines():
        t = ln.split("#")[0].split()
        if not t:
            continue
        if t[0] == "v":
            V.append([float(x) for x in t[1:4]])
        elif t[0] == "vt":
            VT.append([float(x) for x in t[1:3]])
        elif t[0] == "f":
            c = [x.split("/") for x in t[1:]]
            vi = [int(x[0]) for x in c]
            faces.append([i if i > 0 else len(V) + i + 1 for i in vi])
            ti = [int(x[1]) if len(x) > 1 and x[1] else None for x in c]
            tex.append([None if i is None else i if i > 0 else len(VT) + i + 1 for i in ti])
            order.append("f")
        elif t[0] in ("mtllib", "usemtl", "o", "g", "s"):
            order.append(" ".join(t))
    return np.array(V), np.array(VT), faces, tex, order


def stderr_line(err, start):
    return next(ln for ln in err.splitlines() if ln.strip().startswith(start))


# ----------------------------------------------------------------------------------------
# 1. a point cache on a polygon mesh: the mesh written back as given
# ----------------------------------------------------------------------------------------
def test_point_cache_on_a_polygon_mesh_writes_the_mesh_back(tmp_path, tube, capsys):
    """``keys.pc2 --topology pose_0.obj``: every frame has the mesh's own polygons, numbering,
    texture coordinates and group lines (as OBJ keyframes do), the seam copies coincide, the
    cache's keyframe samples come back exactly; a point-cache output holds the mesh's 164
    vertices (seam copies included) and its mesh.obj the polygons; the summary says what was
    written."""
    paths = write_set(tube, tmp_path / "in")
    V_in, VT_in, faces_in, tex_in, order_in = obj_file(paths[0])
    cache = write_pc2(tmp_path / "keys.pc2", tube["V"])
    out = tmp_path / "out"
    rc = main(["interpolate", str(cache), "--topology", str(paths[0]), "--frames", "0,10,20",
               "--method", "linear", "-o", str(out)])
    err = capsys.readouterr().err
    assert rc == 0
    assert "written back as given" in stderr_line(err, "input:")
    frames = sorted(out.glob("frame_*.obj"))
    assert len(frames) == 21
    keys = read_pc2(cache)[0]
    seam = tube["seam"]
    # the material library named from the output folder (a sibling of in/)
    order_out = ["mtllib ../in/tube.mtl" if o == "mtllib tube.mtl" else o for o in order_in]
    for k, f in enumerate(frames):
        V, VT, faces, tex, order = obj_file(f)
        assert faces == faces_in and tex == tex_in and order == order_out, k
        assert np.array_equal(VT, VT_in)
        assert V.shape == (164, 3) and np.array_equal(V[seam[:, 0]], V[seam[:, 1]])
        if k % 10 == 0:
            assert np.array_equal(V, keys[k // 10]), k
    rep = json.loads((out / "report.json").read_text())
    assert rep["source_mesh"]["polygons"] == 134
    assert rep["source_mesh"]["texture_coordinates"] == 164
    # as a point cache: the mesh's vertex count, mesh.obj with its polygons and vt
    for fmt, write in (("pc2", write_pc2), ("mdd", write_mdd)):
        keys = write(tmp_path / f"keys.{fmt}", tube["V"])
        cached = tmp_path / f"cached_{fmt}"
        rc = main(["interpolate", str(keys), "--topology", str(paths[0]), "--frames",
                   "0,10,20", "--method", "linear", "-o", str(cached), "--format", fmt])
        err = capsys.readouterr().err
        assert rc == 0
        assert "the cache written on its 164 vertices, mesh.obj as given" in err
        Vc, Fc, _ = sio.read_sequence(cached)
        assert Vc.shape == (21, 164, 3)
        V0, VT0, faces0, tex0, order0 = obj_file(cached / "mesh.obj")
        assert faces0 == faces_in and tex0 == tex_in and order0 == order_out
        assert np.array_equal(VT0, VT_in) and V0.shape == (164, 3)
    # formats that cannot hold everything say so instead of "as given"
    rc = main(["interpolate", str(cache), "--topology", str(paths[0]), "--frames", "0,10,20",
               "--method", "linear", "-o", str(tmp_path / "ply"), "--format", "ply"])
    line = stderr_line(capsys.readouterr().err, "input:")
    assert rc == 0 and "as given" not in line
    assert "its 164 texture coordinates are not written (PLY)" in line


def test_keyframes_from_cache_keep_the_source_mesh(tmp_path, tube):
    """The Python side of the same: ``keyframes_from_cache`` maps back to the mesh's polygons
    and texture coordinates, exactly as ``read_keyframes`` on the OBJ keyframes does."""
    from shellspline.io.pointcache import keyframes_from_cache

    f32 = {**tube, "V": tube["V"].astype(np.float32).astype(np.float64)}  # the cache's values
    paths = write_set(f32, tmp_path)
    ref = sio.read_keyframes(paths, frames=[0, 10, 20])
    kf = keyframes_from_cache(write_pc2(tmp_path / "k.pc2", tube["V"]), paths[0],
                              frames=[0, 10, 20])
    a, b = kf.source, ref.source
    assert np.array_equal(a.poly_offsets, b.poly_offsets)
    assert np.array_equal(a.poly_indices, b.poly_indices)
    assert np.array_equal(a.corner_uv, b.corner_uv) and np.array_equal(a.uv, b.uv)
    assert np.array_equal(a.to_solve, b.to_solve) and a.statements == b.statements
    assert np.array_equal(kf.F, ref.F) and kf.n == ref.n


# ----------------------------------------------------------------------------------------
# 2. texture references
# ----------------------------------------------------------------------------------------
TRI = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0.2\nvt 0 0\nvt 1 0\nvt 0 1\nvt 1 1\n"


def test_bad_texture_reference_is_an_error_naming_the_line(tmp_path):
    p = tmp_path / "uv.obj"
    p.write_text(TRI + "f 1/1 2/2 3/3\nf 2/2 4/999 3/3\n")
    raises_mesh_error(lambda: sio.read_keyframes([p, p]), "uv.obj: line 10, face 2 "
                      "(f 2/2 4/999 3/3): texture coordinate 999 does not exist (the file has "
                      "4 vt lines)")
    p.write_text(TRI + "f 1/1 2/2 3/3\nf 2/2 4/-9 3/3\n")
    raises_mesh_error(lambda: sio.read_keyframes([p, p]), "line 10, face 2",
                      "relative texture coordinate index -9")
    p.write_text(TRI + "f 1/1 2/0 3/3\nf 2/2 4/4 3/3\n")
    raises_mesh_error(lambda: sio.read_keyframes([p, p]), "line 9, face 1",
                      "uses texture coordinate index 0 (OBJ indices start at 1)")
    p.write_text(TRI + "f 1/1 2/2 3/3\nf 2/2 4/x 3/3\n")
    raises_mesh_error(lambda: sio.read_keyframes([p, p]), "line 10, face 2",
                      "texture coordinate index 'x' is not an integer")
    p.write_text(TRI.split("vt")[0] + "f 1/1 2/2 3/3\nf 2/2 4/4 3/3\n")   # no vt lines at all
    raises_mesh_error(lambda: sio.read_keyframes([p, p]), "line 5, face 1",
                      "texture coordinate 1 does not exist (the file has 0 vt lines)")
    p.write_text(TRI.replace("vt 1 0", "vt 1 zero") + "f 1/1 2/2 3/3\nf 2/2 4/4 3/3\n")
    raises_mesh_error(lambda: sio.read_keyframes([p, p]), "uv.obj: line 6: texture coordinate 2")


def test_corners_without_texture_coordinates_are_a_note(tmp_path, capsys):
    p, q = tmp_path / "a.obj", tmp_path / "b.obj"
    p.write_text(TRI + "f 1/1 2/2 3/3\nf 2 4/4 3/3\n")
    q.write_text(TRI.replace("0.2", "0.4") + "f 1/1 2/2 3/3\nf 2 4/4 3/3\n")
    with pytest.warns(UserWarning, match=r"a\.obj: 1 of 6 face corners name no texture "
                                         r"coordinate \(the first on line 10, face 2\)"):
        kf = sio.read_keyframes([p, q])
    assert kf.source is None
    rc = main(["interpolate", str(p), str(q), "-o", str(tmp_path / "o"), "--method", "linear"])
    err = capsys.readouterr().err
    assert rc == 0
    notes = [ln for ln in err.splitlines() if ln.strip().startswith("note:")]
    assert len(notes) == 1 and "1 of 6 face corners name no texture coordinate" in notes[0]
    assert "Warning" not in err and "Traceback" not in err


# ----------------------------------------------------------------------------------------
# 3. quad diagonals do not depend on the unit
# ----------------------------------------------------------------------------------------
@pytest.mark.slow
def test_quad_diagonals_and_result_do_not_depend_on_the_unit(tmp_path):
    """The same keyframes in other units give the same triangles (before: 16 of 45 quads of
    this tube took the other diagonal at x3, symmetric quads tied to round-off), and a solve
    whose result depends on the triangles (geodesic) scales with them."""
    import shellspline as ss

    pytest.importorskip("mapbox_earcut")
    d = dcc_tube(around=8, rings=4)
    runs = {}
    for s in (1.0, 3.0, 1e6, 1e-3):
        kf = sio.read_keyframes(write_set({**d, "V": d["V"] * s}, tmp_path / f"s{s:g}"),
                                frames=d["frames"])
        res = ss.interpolate(kf, method="geodesic")
        runs[s] = (kf, res.source.expand(res.V, res.frames, res.K))
    kf1, V1 = runs[1.0]
    for s in (3.0, 1e6, 1e-3):
        kf, V = runs[s]
        assert np.array_equal(kf.source.triangles, kf1.source.triangles), s
        assert np.array_equal(kf.F, kf1.F), s
        assert np.abs(V / s - V1).max() <= 1e-11 * np.abs(V1).max(), s


def test_symmetric_quad_ties_keep_the_first_diagonal():
    """A square (both diagonals equally good) keeps the diagonal ac at every scale and
    placement, in every keyframe."""
    from shellspline.mesh.source_mesh import triangulate_polygons

    sq = np.array([[0.0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]])
    rng = np.random.default_rng(1)
    for s in (1.0, 3.0, 1e-3, 1e6, 0.1, 7.3):
        R = np.linalg.qr(rng.standard_normal((3, 3)))[0]
        V = sq @ R.T * s + rng.standard_normal(3) * s
        F, _ = triangulate_polygons(np.stack([V, V]), [0, 4], [0, 1, 2, 3])
        assert F.tolist() == [[0, 1, 2], [0, 2, 3]], s


# ----------------------------------------------------------------------------------------
# 4. index and frame files with a byte-order mark, or in UTF-16
# ----------------------------------------------------------------------------------------
def test_index_files_with_a_byte_order_mark(tmp_path, capsys):
    fr, pins = tmp_path / "frames.txt", tmp_path / "pins.txt"
    fr.write_bytes(b"\xef\xbb\xbf0\r\n10\r\n")
    pins.write_bytes(b"\xef\xbb\xbf# base\r\n0, 1\r\n")
    assert sio.read_frames(str(fr)).tolist() == [0, 10]
    assert sio.read_indices(pins).tolist() == [0, 1]
    p, q = tmp_path / "a.obj", tmp_path / "b.obj"
    p.write_text(TRI + "f 1 2 3\nf 2 4 3\n")
    q.write_text(TRI.replace("0.2", "0.4") + "f 1 2 3\nf 2 4 3\n")
    rc = main(["interpolate", str(p), str(q), "--frames", str(fr), "--pinned", str(pins),
               "-o", str(tmp_path / "o"), "--method", "linear", "-q"])
    assert rc == 0, capsys.readouterr().err
    assert len(list((tmp_path / "o").glob("frame_*.obj"))) == 11
    u16 = tmp_path / "u16.txt"
    u16.write_text("0\n10\n", encoding="utf-16")
    raises_mesh_error(lambda: sio.read_frames(str(u16)), "u16.txt' is UTF-16 encoded; save it "
                      "as UTF-8")
    rc = main(["interpolate", str(p), str(q), "--pinned", str(u16), "-o",
               str(tmp_path / "o2"), "--method", "linear", "-q"])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and "\n" not in err and "UTF-16 encoded; save it as UTF-8" in err
    u16.write_bytes("0\n10\n".encode("utf-16-le"))   # no byte-order mark: NUL bytes
    raises_mesh_error(lambda: sio.read_indices(u16), "not a text file", "UTF-16")
    obj16 = tmp_path / "u16.obj"
    obj16.write_text(TRI + "f 1 2 3\n", encoding="utf-16")
    raises_mesh_error(lambda: sio.read_mesh(obj16), "u16.obj", "UTF-16 encoded; save it as "
                      "UTF-8")


# ----------------------------------------------------------------------------------------
# 5. an existing output: the command line names --overwrite
# ----------------------------------------------------------------------------------------
def test_existing_output_names_the_option(tmp_path, capsys):
    p, q = tmp_path / "a.obj", tmp_path / "b.obj"
    p.write_text(TRI + "f 1 2 3\nf 2 4 3\n")
    q.write_text(TRI.replace("0.2", "0.4") + "f 1 2 3\nf 2 4 3\n")
    (tmp_path / "o").mkdir()
    rc = main(["interpolate", str(p), str(q), "-o", str(tmp_path / "o"), "-q"])
    err = capsys.readouterr().err
    assert rc == 2 and "use --overwrite to replace it" in err and "overwrite=True" not in err
    with pytest.raises(FileExistsError, match=r"use overwrite=True"):  # the Python API's words
        sio.write_sequence(tmp_path / "o", np.zeros((2, 3, 3)), [[0, 1, 2]])


# ----------------------------------------------------------------------------------------
# 6. OBJ messages in the file's own terms
# ----------------------------------------------------------------------------------------
def test_obj_errors_use_the_files_numbering(tmp_path):
    head = "".join(f"v {i} {i * i % 7} {i % 3}\n" for i in range(8))
    good = ["f 1 2 3", "f 2 3 4", "f 3 4 5", "f 4 5 6", "f 5 6 7 8"]
    p = tmp_path / "m.obj"

    def with_face(k, text):
        faces = list(good)
        faces[k] = text
        p.write_text(head + "\n".join(faces) + "\n")
        return p

    raises_mesh_error(lambda: sio.read_mesh(with_face(2, "f 1 2 999")),
                      "m.obj: line 11, face 3 (f 1 2 999): vertex 999 does not exist (the file "
                      "has 8 vertices)")
    raises_mesh_error(lambda: sio.read_mesh(with_face(4, "f 1 2 2 3")),
                      "line 13, face 5 (f 1 2 2 3): repeats vertex 2")
    raises_mesh_error(lambda: sio.read_mesh(with_face(1, "f 0 1 2")),
                      "line 10, face 2 (f 0 1 2): uses vertex index 0 (OBJ indices start at 1)")
    raises_mesh_error(lambda: sio.read_mesh(with_face(1, "f -1 -2 -9")),
                      "line 10, face 2", "relative vertex index -9 reaches before the first "
                      "one (only 8 vertices are defined above this line)")
    raises_mesh_error(lambda: sio.read_mesh(with_face(3, "f 4 5")),
                      "line 12, face 4 (f 4 5): has 2 vertices (a face needs at least 3)")
    msg = raises_mesh_error(lambda: sio.read_mesh(with_face(0, "f 1 2 9")), "line 9, face 1")
    assert "[0," not in msg and "998" not in msg
    # a face list that differs names the file's fifth face as face 5, with its line
    a = tmp_path / "a.obj"
    a.write_text(head + "\n".join(good) + "\n")
    b = with_face(4, "f 5 6 8 7")
    raises_mesh_error(lambda: sio.read_keyframes([a, b]), "m.obj: face list differs from",
                      "first difference at face 5 on line 13 (f 5 6 8 7) vs face 5 on line 13 "
                      "(f 5 6 7 8)")
    # a degenerate polygon: named as the file names it
    flat = tmp_path / "flat.obj"
    flat.write_text(head.replace("v 5 4 2", "v 5 2 2") + "\n".join(good) + "\n")
    raises_mesh_error(lambda: sio.read_keyframes([a, flat]), "flat.obj",
                      "degenerate (zero-area) faces, first is a triangle of face 4 on line 12 "
                      "(f 4 5 6)")


# ----------------------------------------------------------------------------------------
# 7. a point cache without --topology
# ----------------------------------------------------------------------------------------
def test_point_cache_without_topology_says_what_is_missing(tmp_path, capsys):
    V = np.random.default_rng(0).random((3, 4, 3))
    pc2, mdd = write_pc2(tmp_path / "keys.pc2", V), write_mdd(tmp_path / "keys.mdd", V)
    for argv in ([pc2], [pc2, pc2], [mdd], [pc2, mdd]):
        rc = main(["interpolate", *map(str, argv), "-o", str(tmp_path / "o")])
        err = capsys.readouterr().err.strip()
        assert rc == 2 and "\n" not in err, err
        assert f"'{argv[0]}' is a point cache" in err and "--topology MESH" in err, err
        assert "need at least 2 keyframes" not in err and "unknown extension" not in err
    raises_mesh_error(lambda: sio.read_keyframes([pc2]), "is a point cache",
                      "keyframes_from_cache")


# ----------------------------------------------------------------------------------------
# 8. material and group lines written back
# ----------------------------------------------------------------------------------------
def test_material_and_group_lines_are_written_back(tmp_path, tube, capsys):
    paths = write_set(tube, tmp_path / "in")
    _, _, faces_in, _, order_in = obj_file(paths[0])
    assert "usemtl bark" in order_in and order_in[0] == "mtllib tube.mtl"
    out = tmp_path / "out"
    assert main(["interpolate", *map(str, paths), "--frames", "0,10,20", "--method", "linear",
                 "-o", str(out), "-q"]) == 0
    # the material library is named from the output folder (test below)
    order_out = ["mtllib ../in/tube.mtl" if o == "mtllib tube.mtl" else o for o in order_in]
    for f in sorted(out.glob("frame_*.obj"))[::7]:
        _, _, faces, _, order = obj_file(f)
        assert order == order_out and faces == faces_in
    # mtllib and o stand before the vertices, as in the input
    lines = (out / "frame_0003.obj").read_text().splitlines()
    assert lines[:2] == ["mtllib ../in/tube.mtl", "o Tube"] and lines[2].startswith("v ")
    # a triangle mesh with material lines only: kept too (nothing else to write back)
    tri = "mtllib m.mtl\no Thing\n" + TRI + "usemtl red\ns 1\nf 1 2 3\nusemtl blue\nf 2 4 3\n"
    p, q = tmp_path / "t0.obj", tmp_path / "t1.obj"
    p.write_text(tri)
    q.write_text(tri.replace("0.2", "0.4"))
    kf = sio.read_keyframes([p, q])
    assert kf.source is not None and kf.source.n_welded == 0 and kf.n == 4
    assert main(["interpolate", str(p), str(q), "--method", "linear", "-o",
                 str(tmp_path / "t"), "-q", "--frames", "0,2"]) == 0
    text = (tmp_path / "t" / "frame_0001.obj").read_text()
    assert text.startswith("mtllib ../m.mtl\no Thing\nv ")
    assert text.endswith("usemtl red\ns 1\nf 1 2 3\nusemtl blue\nf 2 4 3\n")


def test_material_libraries_are_named_from_the_output_folder(tmp_path):
    """``mtllib m.mtl`` names a file beside the OBJ; the frames are written elsewhere, and
    their ``mtllib`` lines must name the same files from there (they said ``m.mtl``, which the
    output folder does not have: viewers opened the frames without their materials). Names
    with spaces, several files on one line, ``..`` through a symlinked folder (resolved as the
    file system does), a missing file (where the input would look), a point cache's mesh.obj;
    a path sharing only the root with the output stays absolute; nothing is copied."""
    scene = tmp_path / "scene"
    (scene / "keys").mkdir(parents=True)
    (scene / "mats").mkdir()
    (tmp_path / "link").symlink_to(scene / "keys", target_is_directory=True)
    for f in ("keys/m.mtl", "keys/my mats.mtl", "mats/x.mtl"):
        (scene / f).write_text("newmtl red\nKd 1 0 0\n")
    far = "/nonexistent-shellspline-test/far.mtl"
    text = (f"mtllib m.mtl\nmtllib my mats.mtl\no Thing\n{TRI}usemtl red\nf 1 2 3\n"
            f"mtllib ../mats/x.mtl gone.mtl\nmtllib {far}\nusemtl blue\nf 2 4 3\n")
    (scene / "keys" / "t0.obj").write_text(text)
    (scene / "keys" / "t1.obj").write_text(text.replace("0.2", "0.4"))
    kf = sio.read_keyframes([tmp_path / "link" / "t0.obj", tmp_path / "link" / "t1.obj"])
    want = [scene / "keys" / "m.mtl", scene / "keys" / "my mats.mtl", scene / "mats" / "x.mtl",
            scene / "keys" / "gone.mtl"]
    for fmt, name in (("obj", "frame_0001.obj"), ("pc2", "mesh.obj")):
        out = tmp_path / "renders" / fmt
        sio.write_sequence(out, kf.V, kf.F, source=kf.source, fmt=fmt)
        lines = (out / name).read_text().splitlines()
        libs = [ln[len("mtllib "):] for ln in lines if ln.startswith("mtllib ")]
        assert [(out / x).resolve() for x in libs[:4]] == [w.resolve() for w in want]
        assert libs[0] == "../../scene/keys/m.mtl" and libs[4] == far
        assert [ln for ln in lines if not ln.startswith(("v ", "vt ", "mtllib "))] == \
            ["o Thing", "usemtl red", "f 1 2 3", "usemtl blue", "f 2 4 3"]
        assert not list(out.glob("*.mtl"))


def test_a_symlinked_material_library_is_named_as_the_link(tmp_path):
    """A viewer reads a .mtl's texture maps from the folder it named the .mtl in: the input's
    ``m.mtl`` is a link into a shared store, its ``map_Kd tex.png`` beside the link. The
    frames named the link's target (``../store/m.mtl``), from whose folder the texture is
    missing; they name the link, whose folder has it."""
    keys, store = tmp_path / "keys", tmp_path / "store"
    keys.mkdir()
    store.mkdir()
    (store / "m.mtl").write_text("newmtl red\nmap_Kd tex.png\n")
    (keys / "m.mtl").symlink_to(store / "m.mtl")
    (keys / "tex.png").write_bytes(b"")
    text = f"mtllib m.mtl\no Thing\n{TRI}usemtl red\nf 1 2 3\nf 2 4 3\n"
    (keys / "t0.obj").write_text(text)
    (keys / "t1.obj").write_text(text.replace("0.2", "0.4"))
    kf = sio.read_keyframes([keys / "t0.obj", keys / "t1.obj"])
    out = tmp_path / "renders"
    sio.write_sequence(out, kf.V, kf.F, source=kf.source)
    lib = (out / "frame_0001.obj").read_text().splitlines()[0]
    assert lib == "mtllib ../keys/m.mtl"
    mtl = os.path.normpath(out.resolve() / lib[len("mtllib "):])  # as a viewer joins it
    assert os.path.exists(os.path.join(os.path.dirname(mtl), "tex.png"))

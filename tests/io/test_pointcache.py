"""Point caches (MDD, PC2) and USD: byte layouts checked by readers written here from the format
definitions (struct), by Blender's Mesh Cache modifier and USD importer (bpy) and by pxr."""
import struct

import numpy as np
import pytest

from shellspline.errors import ShellsplineError
from shellspline.io.pointcache import (mdd_bytes, pc2_bytes, read_mdd, read_pc2, read_point_cache,
                                    write_mdd, write_pc2)

TET_F = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])


def _poses(frames=5, n=4, seed=0):
    rng = np.random.default_rng(seed)
    return 10 * rng.standard_normal((frames, n, 3)) + 1e-3 * rng.random((frames, n, 3))


# --- independent readers, written from the format definitions -------------------------
def _struct_mdd(data: bytes):
    frames, n = struct.unpack(">2i", data[:8])
    times = struct.unpack(f">{frames}f", data[8:8 + 4 * frames])
    pts = struct.unpack(f">{3 * n * frames}f", data[8 + 4 * frames:])
    return frames, n, times, np.array(pts).reshape(frames, n, 3)


def _struct_pc2(data: bytes):
    sig, version, n, start, rate, samples = struct.unpack("<12siiffi", data[:32])
    pts = struct.unpack(f"<{3 * n * samples}f", data[32:])
    return sig, version, n, start, rate, samples, np.array(pts).reshape(samples, n, 3)


def test_mdd_layout_matches_the_format_definition():
    V = _poses(6, 5)
    data = mdd_bytes(V, fps=30)
    assert len(data) == 8 + 4 * 6 + 12 * 6 * 5
    frames, n, times, P = _struct_mdd(data)
    assert (frames, n) == (6, 5)
    np.testing.assert_array_equal(times, np.float32(np.arange(6) / 30))
    np.testing.assert_array_equal(P, V.astype(np.float32))
    # big-endian: the first count reads as 6 << 24 the other way round
    assert struct.unpack("<i", data[:4])[0] == 6 << 24


def test_mdd_explicit_times_and_roundtrip_exact_in_float32(tmp_path):
    V = _poses(4, 3)
    times = [0.0, 0.5, 0.5, 2.0]
    p = write_mdd(tmp_path / "a.mdd", V, times=times)
    W, t = read_mdd(p)
    np.testing.assert_array_equal(W, V.astype(np.float32))
    np.testing.assert_array_equal(t, np.float32(times))
    Vr, frames = read_point_cache(p, fps=2)
    np.testing.assert_array_equal(frames, [0, 1, 1, 4])


def test_mdd_with_blenders_rest_block_is_read_without_it(tmp_path):
    V = _poses(3, 4)
    rest = np.full((1, 4, 3), 7.0)
    data = mdd_bytes(V)  # Blender's exporter: header of 3 frames, rest block, then 3 frames
    head = 8 + 4 * 3
    p = tmp_path / "blender.mdd"
    p.write_bytes(data[:head] + rest.astype(">f4").tobytes() + data[head:])
    W, _ = read_mdd(p)
    np.testing.assert_array_equal(W, V.astype(np.float32))


def test_pc2_layout_matches_the_format_definition(tmp_path):
    V = _poses(7, 3)
    data = pc2_bytes(V, start_frame=10, sample_rate=0.5)
    assert len(data) == 32 + 12 * 7 * 3
    sig, version, n, start, rate, samples, P = _struct_pc2(data)
    assert (sig, version, n, start, rate, samples) == (b"POINTCACHE2\0", 1, 3, 10.0, 0.5, 7)
    np.testing.assert_array_equal(P, V.astype(np.float32))
    p = write_pc2(tmp_path / "a.pc2", V, start_frame=10, sample_rate=0.5)
    W, s, r = read_pc2(p)
    np.testing.assert_array_equal(W, V.astype(np.float32))
    assert (s, r) == (10.0, 0.5)
    np.testing.assert_array_equal(read_point_cache(p)[1], 10 + 0.5 * np.arange(7))


@pytest.mark.parametrize("V, kw, match", [
    (np.zeros((0, 3, 3)), {}, "shape"),
    (np.zeros((2, 3)), {}, "shape"),
    (np.full((1, 2, 3), np.nan), {}, "finite"),
    (np.full((1, 2, 3), 1e39), {}, "float32 range"),
    (np.zeros((2, 2, 3)), {"fps": 0}, "fps"),
    (np.zeros((2, 2, 3)), {"times": [1.0, 0.0]}, "non-decreasing"),
    (np.zeros((2, 2, 3)), {"times": [1.0]}, "times"),
])
def test_mdd_rejects_bad_input(V, kw, match):
    with pytest.raises(ShellsplineError, match=match):
        mdd_bytes(V, **kw)


@pytest.mark.parametrize("kw, match", [({"sample_rate": -1}, "sample_rate"),
                                       ({"start_frame": float("inf")}, "start_frame"),
                                       ({"start_frame": "x"}, "start_frame")])
def test_pc2_rejects_bad_input(kw, match):
    with pytest.raises(ShellsplineError, match=match):
        pc2_bytes(np.zeros((2, 2, 3)), **kw)


def test_readers_reject_damaged_files(tmp_path):
    V = _poses(3, 2)
    mdd, pc2 = mdd_bytes(V), pc2_bytes(V)
    cases = {"short.mdd": mdd[:-4], "tiny.mdd": b"\0\0", "neg.mdd": b"\xff" * 8 + mdd[8:],
             "short.pc2": pc2[:-1], "sig.pc2": b"POINTCACHE3\0" + pc2[12:],
             "ver.pc2": pc2[:12] + struct.pack("<i", 2) + pc2[16:],
             "nantime.mdd": mdd[:12] + struct.pack(">f", np.nan) + mdd[16:],
             "nanrate.pc2": pc2[:24] + struct.pack("<f", np.inf) + pc2[28:],
             "head.pc2": pc2[:20]}
    for name, data in cases.items():
        (tmp_path / name).write_bytes(data)
        reader = read_mdd if name.endswith(".mdd") else read_pc2
        with pytest.raises(ShellsplineError, match=name):
            reader(tmp_path / name)
    with pytest.raises(ShellsplineError, match="truncated"):
        read_pc2(tmp_path / "head.pc2")
    with pytest.raises(ShellsplineError, match="missing.pc2"):
        read_pc2(tmp_path / "missing.pc2")
    with pytest.raises(ShellsplineError, match=r"\.mdd or \.pc2"):
        read_point_cache(tmp_path / "x.obj")


# --- Blender's Mesh Cache modifier (bpy) -------------------------------------------------
def _bpy():
    return pytest.importorskip("bpy", reason="Blender as a Python module (pip install "
                                             "'shellspline[blender]') is not installed")


def _blender_tet(bpy, V0):
    bpy.ops.wm.read_factory_settings(use_empty=True)
    me = bpy.data.meshes.new("tet")
    me.from_pydata(V0.tolist(), [], TET_F.tolist())
    ob = bpy.data.objects.new("tet", me)
    bpy.context.scene.collection.objects.link(ob)
    return ob


def _evaluated(bpy, ob, frame):
    bpy.context.scene.frame_set(frame)
    ev = ob.evaluated_get(bpy.context.evaluated_depsgraph_get())
    me = ev.to_mesh()
    co = np.zeros(3 * len(me.vertices))
    me.vertices.foreach_get("co", co)
    ev.to_mesh_clear()
    return co.reshape(-1, 3)


@pytest.mark.parametrize("fmt", ["MDD", "PC2"])
def test_blender_mesh_cache_modifier_plays_our_caches(tmp_path, fmt):
    bpy = _bpy()
    V = _poses(6, 4, seed=3)
    ob = _blender_tet(bpy, np.zeros((4, 3)))
    path = tmp_path / f"a.{fmt.lower()}"
    (write_mdd(path, V, fps=25) if fmt == "MDD" else write_pc2(path, V))
    mod = ob.modifiers.new("cache", "MESH_CACHE")
    mod.cache_format, mod.filepath, mod.frame_start = fmt, str(path), 0
    for k in range(6):  # frame k of the scene shows sample k
        np.testing.assert_array_equal(_evaluated(bpy, ob, k), V[k].astype(np.float32))
    if fmt == "MDD":  # time mode: Blender places the samples by the file's times (seconds)
        bpy.context.scene.render.fps = 25
        mod.time_mode = "TIME"
        for k in (1, 4):
            np.testing.assert_array_equal(_evaluated(bpy, ob, k), V[k].astype(np.float32))
    # (PC2 in time mode is not checked: Blender 4.2 computes the sample as
    # ((seconds / fps) - start) / rate, MOD_meshcache_pc2.cc, which is off by fps**2; in frame
    # mode it ignores the file's start frame and rate.)


# --- USD (pxr) ---------------------------------------------------------------------------
def _pxr():
    return pytest.importorskip("pxr", reason="usd-core (pip install 'shellspline[usd]') is not "
                                             "installed")


@pytest.mark.parametrize("ext", ["usda", "usdc"])
def test_usd_stage_read_with_pxr(tmp_path, ext):
    pxr = _pxr()
    from pxr import Usd, UsdGeom

    from shellspline.io.usd import read_usd, write_usd

    V = _poses(5, 4, seed=5)
    p = write_usd(tmp_path / f"s.{ext}", V, TET_F, fps=30, up_axis="z", start=3)
    stage = Usd.Stage.Open(str(p))
    assert stage.GetTimeCodesPerSecond() == 30 and stage.GetFramesPerSecond() == 30
    assert (stage.GetStartTimeCode(), stage.GetEndTimeCode()) == (3, 7)
    assert UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.z
    mesh = UsdGeom.Mesh(stage.GetDefaultPrim())
    assert mesh and list(mesh.GetFaceVertexCountsAttr().Get()) == [3] * 4
    np.testing.assert_array_equal(np.asarray(mesh.GetFaceVertexIndicesAttr().Get()),
                                  TET_F.ravel())
    pts = mesh.GetPointsAttr()
    assert pts.GetTimeSamples() == [3, 4, 5, 6, 7]
    for k in range(5):
        np.testing.assert_array_equal(np.asarray(pts.Get(3 + k)), V[k].astype(np.float32))
    # between samples USD interpolates linearly (held samples would be wrong here)
    np.testing.assert_allclose(np.asarray(pts.Get(3.5)),
                               (V[0].astype(np.float32) + V[1].astype(np.float32)) / 2,
                               rtol=1e-6, atol=1e-5)
    lo, hi = np.asarray(mesh.GetExtentAttr().Get(5))
    np.testing.assert_array_equal(lo, V[2].astype(np.float32).min(0))
    assert pxr is not None
    W, off, idx, info = read_usd(p)
    np.testing.assert_array_equal(W, V.astype(np.float32))
    assert info["fps"] == 30 and info["up_axis"] == "Z" and info["times"] == [3, 4, 5, 6, 7]


def test_usd_polygons_and_bad_input(tmp_path):
    _pxr()
    from shellspline.io.usd import read_usd, write_usd

    V = np.zeros((2, 5, 3))
    V[:, :, 0] = [0, 1, 1, 0, 2]
    V[:, :, 1] = [0, 0, 1, 1, 0.5]
    off, idx = np.array([0, 4, 7]), np.array([0, 1, 2, 3, 1, 4, 2])
    W, off2, idx2, _ = read_usd(write_usd(tmp_path / "q.usda", V, polygons=(off, idx)))
    np.testing.assert_array_equal(off2, off)
    np.testing.assert_array_equal(idx2, idx)
    for kw, match in [({"up_axis": "x"}, "up_axis"), ({"fps": -1}, "fps"),
                      ({"name": "1bad"}, "identifier")]:
        with pytest.raises(ShellsplineError, match=match):
            write_usd(tmp_path / "e.usda", V, TET_F, **kw)
    with pytest.raises(ShellsplineError, match="outside"):
        write_usd(tmp_path / "e.usda", V[:, :3], TET_F)
    for bad in (np.nan, 1e39):  # 1e39 would be stored as inf in a point3f
        W = V[:, :4].copy()
        W[1, 2, 0] = bad
        with pytest.raises(ShellsplineError, match="frame 1, point 2"):
            write_usd(tmp_path / "e.usda", W, TET_F)
    with pytest.raises(ShellsplineError, match=".usda"):
        write_usd(tmp_path / "e.txt", V, TET_F)
    (tmp_path / "bad.usda").write_text("not usd")
    with pytest.raises(ShellsplineError, match="bad.usda"):
        read_usd(tmp_path / "bad.usda")
    from shellspline.io.usd import conventional_up_axis
    assert conventional_up_axis(tmp_path / "bad.usda") == "y"  # USD's default, no exception
    # foreign stages: a mesh without faces, without points, with faces beyond its points
    mesh = 'def Mesh "m"\n{\n%s}\n'
    pts = "    point3f[] points = [(0,0,0), (1,0,0), (0,1,0)]\n"
    tri = "    int[] faceVertexCounts = [3]\n    int[] faceVertexIndices = [%s]\n"
    for name, body, match in [("nofaces", pts, "has no faces"),
                              ("nopoints", tri % "0, 1, 2", "has no points"),
                              ("beyond", pts + tri % "0, 1, 3", r"inconsistent.*\[0, 3\] for 3")]:
        (tmp_path / f"{name}.usda").write_text("#usda 1.0\n" + mesh % body)
        with pytest.raises(ShellsplineError, match=f"{name}.usda.*{match}"):
            read_usd(tmp_path / f"{name}.usda")
    (tmp_path / "ok.usda").write_text("#usda 1.0\n" + mesh % (pts + tri % "0, 1, 2"))
    W, off, idx, _ = read_usd(tmp_path / "ok.usda")
    assert W.shape == (1, 3, 3) and off.tolist() == [0, 3] and idx.tolist() == [0, 1, 2]


def test_blender_imports_our_usd(tmp_path):
    bpy = _bpy()
    _pxr()
    from shellspline.io.usd import write_usd

    V = _poses(4, 4, seed=6)
    p = write_usd(tmp_path / "s.usdc", V, TET_F, fps=24, up_axis="Z")
    bpy.ops.wm.read_factory_settings(use_empty=True)
    assert bpy.ops.wm.usd_import(filepath=str(p)) == {"FINISHED"}
    ob = next(o for o in bpy.context.scene.objects if o.type == "MESH")
    assert len(ob.data.polygons) == 4
    for k in range(4):
        np.testing.assert_allclose(_evaluated(bpy, ob, k), V[k].astype(np.float32), rtol=0,
                                   atol=0)


# --- sequences and the CLI: --format mdd|pc2|usd, point caches as keyframe input ---------
def _quad_strip_files(d, nx=5):
    """Three poses of a strip of quads (OBJ, y up), rolled up about the z axis."""
    x = np.linspace(0, 2, nx + 1)
    V0 = np.array([[xi, 0.0, z] for z in (0.0, 0.5) for xi in x])
    quads = [(i, i + 1, nx + 2 + i, nx + 1 + i) for i in range(nx)]
    paths = []
    for j, angle in enumerate((0.0, 1.2, 0.4)):
        V = V0.copy()
        if angle:
            r = 2 / angle
            V[:, 0], V[:, 1] = r * np.sin(V0[:, 0] / r), r * (1 - np.cos(V0[:, 0] / r))
        p = d / f"pose_{j}.obj"
        p.write_text("".join(f"v {a!r} {b!r} {c!r}\n" for a, b, c in V.tolist())
                     + "".join("f" + "".join(f" {i + 1}" for i in q) + "\n" for q in quads))
        paths.append(p)
    return paths


@pytest.mark.parametrize("fmt", ["mdd", "pc2", "usd"])
def test_interpolate_writes_and_reads_back_each_format(tmp_path, fmt):
    from shellspline.cli.main import main
    from shellspline.io import read_sequence

    if fmt == "usd":
        _pxr()
    keys = _quad_strip_files(tmp_path)
    ref, out = tmp_path / "ref", tmp_path / fmt
    common = [*map(str, keys), "--frames", "0,4,10", "--method", "linear", "--fps", "30", "-q"]
    assert main(["interpolate", *common, "-o", str(ref), "--format", "ply"]) == 0
    assert main(["interpolate", *common, "-o", str(out), "--format", fmt]) == 0
    V, F, rep = read_sequence(ref)
    W, G, rep2 = read_sequence(out)
    np.testing.assert_array_equal(W, V.astype(np.float32))  # every frame, keyframes included
    np.testing.assert_array_equal(G, F)
    assert rep2["parameters"] == rep["parameters"]
    if fmt == "mdd":
        frames, n, times, P = _struct_mdd((out / "animation.mdd").read_bytes())
        assert (frames, n) == V.shape[:2]
        np.testing.assert_array_equal(times, np.float32(np.arange(11) / 30))
    if fmt in ("mdd", "pc2"):  # the mesh the cache animates keeps the input's quads
        faces = [ln for ln in (out / "mesh.obj").read_text().splitlines() if ln.startswith("f")]
        assert len(faces) == 5 and all(len(f.split()) == 5 for f in faces)
    else:
        from pxr import Usd, UsdGeom

        stage = Usd.Stage.Open(str(out / "animation.usdc"))
        assert UsdGeom.GetStageUpAxis(stage) == "Y"  # OBJ input: y up
        assert stage.GetTimeCodesPerSecond() == 30 and stage.GetEndTimeCode() == 10
        mesh = UsdGeom.Mesh(stage.GetDefaultPrim())
        assert list(mesh.GetFaceVertexCountsAttr().Get()) == [4] * 5


@pytest.mark.parametrize("fmt", ["mdd", "pc2"])
def test_point_cache_and_mesh_as_keyframe_input(tmp_path, fmt):
    from shellspline.cli.main import main
    from shellspline.io import read_sequence

    keys = _quad_strip_files(tmp_path)
    out = tmp_path / "cache"
    assert main(["interpolate", *map(str, keys), "--frames", "0,4,10", "--method", "linear",
                 "-o", str(out), "--format", fmt, "-q"]) == 0
    V = read_sequence(out)[0]
    # the cache's own frames (every sample a keyframe, 0..10) ...
    again = tmp_path / "again"
    assert main(["interpolate", str(out / f"animation.{fmt}"), "--topology",
                 str(out / "mesh.obj"), "--method", "linear", "-o", str(again), "-q"]) == 0
    np.testing.assert_array_equal(read_sequence(again)[0], V.astype(np.float32))
    # ... or placed by --frames
    spread = tmp_path / "spread"
    assert main(["interpolate", str(out / f"animation.{fmt}"), "--topology",
                 str(out / "mesh.obj"), "--frames", ",".join(str(2 * k) for k in range(11)),
                 "--method", "linear", "-o", str(spread), "-q"]) == 0
    W = read_sequence(spread)[0]
    np.testing.assert_array_equal(W[::2], V.astype(np.float32))
    np.testing.assert_allclose(W[1::2], (W[:-1:2] + W[2::2]) / 2, atol=1e-12)
    # two files, or a mesh of another size, are refused
    assert main(["interpolate", str(out / f"animation.{fmt}"), str(keys[0]), "--topology",
                 str(out / "mesh.obj"), "-o", str(tmp_path / "x"), "-q"]) == 2
    (tmp_path / "tri.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    assert main(["interpolate", str(out / f"animation.{fmt}"), "--topology",
                 str(tmp_path / "tri.obj"), "-o", str(tmp_path / "x"), "-q"]) == 2


def test_cache_samples_out_of_order_need_frames(tmp_path):
    from shellspline.io.pointcache import keyframes_from_cache

    (tmp_path / "tet.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\n"
                                      "f 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n")
    V0 = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    write_mdd(tmp_path / "back.mdd", [V0, 2 * V0, 3 * V0], times=[0.0, 1.0, 1.0])
    with pytest.raises(ShellsplineError, match=r"back\.mdd: sample 2 lies at frame 24, not "
                                                r"after sample 1 at 24"):
        keyframes_from_cache(tmp_path / "back.mdd", tmp_path / "tet.obj")
    kf = keyframes_from_cache(tmp_path / "back.mdd", tmp_path / "tet.obj", frames=[0, 5, 9])
    assert kf.frames.tolist() == [0, 5, 9]
    with pytest.raises(ShellsplineError, match=r"back\.mdd holds 3 samples .* 2 keyframe frames"):
        keyframes_from_cache(tmp_path / "back.mdd", tmp_path / "tet.obj", frames=[0, 5])


def test_mdd_frames_must_be_whole_numbers_apart(tmp_path):
    from shellspline.io.pointcache import keyframes_from_cache

    (tmp_path / "tet.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\n"
                                      "f 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n")
    V0 = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    write_mdd(tmp_path / "a.mdd", [V0, 1.5 * V0], times=[0.0, 0.1])
    with pytest.raises(ShellsplineError, match="whole numbers"):
        keyframes_from_cache(tmp_path / "a.mdd", tmp_path / "tet.obj", fps=24)
    kf = keyframes_from_cache(tmp_path / "a.mdd", tmp_path / "tet.obj", fps=30)
    assert kf.frames.tolist() == [0, 3]


@pytest.mark.parametrize("fmt", ["mdd", "pc2"])
def test_blender_opens_our_output_directory(tmp_path, fmt):
    """mesh.obj through Blender's OBJ importer, the cache through its Mesh Cache modifier."""
    bpy = _bpy()
    from shellspline.cli.main import main
    from shellspline.io import read_sequence

    keys = _quad_strip_files(tmp_path)
    out = tmp_path / "o"
    assert main(["interpolate", *map(str, keys), "--frames", "0,4,10", "--method", "linear",
                 "-o", str(out), "--format", fmt, "-q"]) == 0
    V = read_sequence(out)[0]
    bpy.ops.wm.read_factory_settings(use_empty=True)
    # default axes: the importer turns y-up into Blender's z-up by the object's rotation and
    # keeps the file's coordinates in the mesh, which the cache then overwrites one to one
    bpy.ops.wm.obj_import(filepath=str(out / "mesh.obj"))
    ob = bpy.context.selected_objects[0]
    assert not np.allclose(np.array(ob.matrix_world), np.eye(4))
    assert len(ob.data.polygons) == 5 and len(ob.data.vertices) == V.shape[1]
    mod = ob.modifiers.new("cache", "MESH_CACHE")
    mod.cache_format, mod.filepath = fmt.upper(), str(out / f"animation.{fmt}")
    for k in (0, 3, 4, 10):
        np.testing.assert_array_equal(_evaluated(bpy, ob, k), V[k].astype(np.float32))


def test_usd_without_pxr_is_a_one_line_error_before_the_solve(tmp_path, monkeypatch, capsys):
    """Without usd-core, ``--format usd`` stops with exit 2 (a missing extra, not a bug) before
    any computing, and the library raises an ImportError that names the extra."""
    import sys

    from shellspline.cli.main import main
    from shellspline.io.usd import write_usd

    monkeypatch.setitem(sys.modules, "pxr", None)  # import pxr now raises ImportError
    with pytest.raises(ImportError, match=r"shellspline\[usd\]"):
        write_usd(tmp_path / "a.usda", np.zeros((1, 4, 3)), TET_F)
    keys = _quad_strip_files(tmp_path)
    capsys.readouterr()
    assert main(["interpolate", *map(str, keys), "--frames", "0,4,10", "-o",
                 str(tmp_path / "out"), "--format", "usd", "-q"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "usd-core" in err[0] and "internal error" not in err[0]
    assert not (tmp_path / "out").exists()

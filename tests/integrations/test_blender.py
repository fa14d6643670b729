"""The Blender add-on: the installable zip, its engine (no bpy), and the operator run headless in
Blender as a Python module (``pip install 'shellspline[blender]'``; skipped without it)."""
import importlib
import inspect
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest

import shellspline as ss
from shellspline.errors import ShellsplineError
from shellspline.integrations.blender import ADDON_PACKAGE, write_addon_zip
from shellspline.integrations.blender import engine


def _strip(nx=6, ny=2):
    """A flat triangulated strip along x, (n,3) vertices and (m,3) triangles."""
    x, y = np.meshgrid(np.linspace(0, 3, nx + 1), np.linspace(0, 1, ny + 1))
    V = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], axis=1)
    idx = np.arange(x.size).reshape(ny + 1, nx + 1)
    a, b, c, d = idx[:-1, :-1], idx[:-1, 1:], idx[1:, 1:], idx[1:, :-1]
    F = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3),
                        np.stack([a, c, d], -1).reshape(-1, 3)])
    return V, F


def _bent(V, angle):
    """The strip rolled up around the y axis by ``angle`` over its length (isometric)."""
    if angle == 0:
        return V.copy()
    r = 3.0 / angle
    t = V[:, 0] / r
    return np.stack([r * np.sin(t), V[:, 1], r * (1 - np.cos(t))], axis=1)


def test_addon_zip_holds_the_addon_sources(tmp_path):
    p = write_addon_zip(tmp_path / "shellspline_addon.zip")
    with zipfile.ZipFile(p) as zf:
        names = sorted(zf.namelist())
        init = zf.read(f"{ADDON_PACKAGE}/__init__.py").decode()
    assert names == [f"{ADDON_PACKAGE}/__init__.py", f"{ADDON_PACKAGE}/engine.py"]
    assert "bl_info" in init and '"blender": (4, 2, 0)' in init
    assert "from . import engine" in init and "shellspline.integrations" not in init
    with pytest.raises(FileExistsError):
        write_addon_zip(p)
    write_addon_zip(p, overwrite=True)
    with pytest.raises(ShellsplineError, match=r"\.zip"):
        write_addon_zip(tmp_path / "addon.tar")


def test_engine_choices_are_the_librarys():
    """The engine spells the choices out (it must import without shellspline); they must not
    drift from the library's, or the dialog offers what the CLI refuses."""
    from shellspline.pipeline.options import METHODS, RIGID_TRACKS
    from shellspline.timeline import BOUNDARY_CONDITIONS

    assert engine.METHODS == METHODS
    assert engine.BOUNDARY_CONDITIONS == BOUNDARY_CONDITIONS
    assert engine.RIGID_TRACKS == RIGID_TRACKS
    defaults = inspect.signature(ss.interpolate).parameters
    for name in ("method", "bc", "eta", "rigid_track"):
        assert getattr(engine.Options(), name) == defaults[name].default, name


def test_engine_pc2_matches_the_library_writer(tmp_path):
    from shellspline.io.pointcache import pc2_bytes

    V = np.random.default_rng(1).standard_normal((4, 5, 3))
    engine.write_pc2(tmp_path / "e.pc2", V, start_frame=7)
    assert (tmp_path / "e.pc2").read_bytes() == pc2_bytes(V, start_frame=7)
    np.testing.assert_array_equal(engine.read_pc2(tmp_path / "e.pc2"), V.astype(np.float32))


def test_engine_problems_lists_what_the_report_flags():
    rep = {"gauss_newton": {"stalled": [3, 4], "iteration_limit": []},
           "quality": {"keyframes_exact": True, "flipped_faces": 2, "folded_edges": 0,
                       "pop": 3.5, "pop_limit": 2.0, "pop_frame": 9, "worst_frames": [4]},
           "nonlinear": {"success": False, "message": "time limit"}}
    lines = engine.problems(rep)
    assert any("stalled at frames [3, 4]" in s for s in lines)
    assert any("2 new flipped faces" in s for s in lines)
    assert any("pop 3.50 at frame 9" in s for s in lines)
    assert any("nonlinear" in s and "time limit" in s for s in lines)
    assert not any("folded" in s for s in lines)
    assert engine.problems({}) == []
    shifted = engine.problems(rep, start=100)
    assert any("stalled at frames [103, 104]" in s for s in shifted)
    assert any("worst frames [104]" in s for s in shifted)
    assert any("pop 3.50 at frame 109" in s for s in shifted)


@pytest.mark.parametrize("backend", ["library", "cli"])
def test_engine_problems_read_a_real_report(backend):
    """problems() on the report a real run writes (not a hand-made dict): Gauss-Newton cut
    at one iteration is flagged at exactly the in-between frames, through both back ends."""
    V0, F = _strip()
    keys = np.stack([_bent(V0, a) for a in (0.0, 1.5, 0.5)])
    res = engine.interpolate(keys, F, [3, 7, 13], options=engine.Options(method="lta",
                                                                           max_iter=1),
                             backend=backend)
    gn = res.report["gauss_newton"]
    assert gn["iteration_limit"] == [1, 2, 3, 5, 6, 7, 8, 9] and gn["iterations_max"] == 1
    # named as Blender's frames: the first keyframe is frame 3
    assert res.problems == ["Gauss-Newton at the iteration limit at frames "
                            "[4, 5, 6, 8, 9, 10, 11, 12]"]
    ok = engine.interpolate(keys, F, [3, 7, 13], options=engine.Options(method="lta"),
                            backend=backend)
    assert ok.report["gauss_newton"]["converged"] == 8 and ok.problems == []


def test_engine_library_and_cli_back_ends_agree():
    V0, F = _strip()
    keys = np.stack([_bent(V0, a) for a in (0.0, 1.5, 0.5)])
    opts = engine.Options(method="linear")
    lib = engine.interpolate(keys, F, [5, 9, 15], options=opts, backend="library")
    assert lib.start == 5 and lib.V.shape == (11, V0.shape[0], 3)
    ref = ss.interpolate(ss.keyframes_from_arrays(keys, F, frames=[0, 4, 10]), method="linear")
    np.testing.assert_array_equal(lib.V, ref.V)
    cli = engine.interpolate(keys, F, [5, 9, 15], options=opts, backend="cli")
    assert cli.backend == "cli" and cli.start == 5
    np.testing.assert_array_equal(cli.V, ref.V.astype(np.float32))  # exact, through float32
    with pytest.raises(ValueError, match="strictly increasing"):
        engine.interpolate(keys, F, [5, 5, 15], options=opts)
    with pytest.raises(ValueError, match="method"):
        engine.Options(method="cubic")


# --- headless Blender ----------------------------------------------------------------------
@pytest.fixture(scope="module")
def addon(tmp_path_factory):
    bpy = pytest.importorskip("bpy", reason="Blender as a Python module (pip install "
                                            "'shellspline[blender]') is not installed")
    d = tmp_path_factory.mktemp("addon")
    with zipfile.ZipFile(write_addon_zip(d / "shellspline_addon.zip")) as zf:
        zf.extractall(d)  # installed from the zip, as Blender would
    sys.path.insert(0, str(d))
    try:
        mod = importlib.import_module(ADDON_PACKAGE)
        mod.register()
        yield bpy, mod
        mod.unregister()
    finally:
        sys.path.remove(str(d))
        sys.modules.pop(f"{ADDON_PACKAGE}.engine", None)
        sys.modules.pop(ADDON_PACKAGE, None)


def _scene_with_keyed_strip(bpy, pin=False):
    """A strip with shape keys 'a' and 'b' keyed: basis at frame 1, a at 9, b at 21."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    V0, F = _strip()
    me = bpy.data.meshes.new("strip")
    me.from_pydata(V0.tolist(), [], F.tolist())
    ob = bpy.data.objects.new("strip", me)
    bpy.context.scene.collection.objects.link(ob)
    bpy.context.view_layer.objects.active = ob
    ob.shape_key_add(name="Basis")
    keys = {"a": _bent(V0, 1.5), "b": _bent(V0, 0.5)}
    for name, V in keys.items():
        kb = ob.shape_key_add(name=name, from_mix=False)
        kb.data.foreach_set("co", V.ravel())
    kb = ob.data.shape_keys.key_blocks
    for frame, (a, b) in ((1, (0, 0)), (9, (1, 0)), (21, (0, 1))):
        kb["a"].value, kb["b"].value = a, b
        kb["a"].keyframe_insert("value", frame=frame)
        kb["b"].keyframe_insert("value", frame=frame)
    if pin:
        vg = ob.vertex_groups.new(name="base")
        vg.add([0, 7, 14], 1.0, "REPLACE")  # the x = 0 edge
    Vkeys = np.stack([V0, keys["a"], keys["b"]]).astype(np.float32).astype(np.float64)
    return ob, Vkeys, F


def _evaluated(bpy, ob, frame):
    bpy.context.scene.frame_set(frame)
    ev = ob.evaluated_get(bpy.context.evaluated_depsgraph_get())
    me = ev.to_mesh()
    co = np.zeros(3 * len(me.vertices))
    me.vertices.foreach_get("co", co)
    ev.to_mesh_clear()
    return co.reshape(-1, 3)


@pytest.mark.parametrize("output", ["SHAPE_KEYS", "CACHE"])
def test_operator_bakes_the_librarys_result(addon, tmp_path, output):
    bpy, mod = addon
    ob, Vkeys, F = _scene_with_keyed_strip(bpy)
    # the keyframes as Blender shows them (basis + 1.0 * (key - basis) in float32)
    Vkeys = np.stack([_evaluated(bpy, ob, f) for f in (1, 9, 21)])
    ref = ss.interpolate(ss.keyframes_from_arrays(Vkeys, F, frames=[0, 8, 20]), coarse="none")
    kw = {"cache_path": str(tmp_path / "strip.pc2")} if output == "CACHE" else {}
    assert bpy.ops.object.shellspline_interpolate(timing="KEYED", output=output,
                                                  coarse="none", **kw) == {"FINISHED"}
    scale = np.abs(ref.V).max()
    for k in range(21):
        got = _evaluated(bpy, ob, 1 + k)
        if output == "CACHE":  # the cache holds float32(V) and Blender plays it as it is
            np.testing.assert_array_equal(got, ref.V[k].astype(np.float32))
        else:  # basis + 1.0 * (key - basis), in float32
            np.testing.assert_allclose(got, ref.V[k], rtol=0, atol=4e-7 * scale)
    keys = ob.data.shape_keys.key_blocks
    baked = [kb.name for kb in keys if kb.name.startswith(mod.PREFIX)]
    assert len(baked) == (21 if output == "SHAPE_KEYS" else 0)
    assert keys["a"].mute == (output == "SHAPE_KEYS")
    if output == "CACHE":
        assert ob.modifiers[0].name == mod.MODIFIER and ob.modifiers[0].cache_format == "PC2"
        np.testing.assert_array_equal(engine.read_pc2(tmp_path / "strip.pc2"),
                                      ref.V.astype(np.float32))


def test_operator_rerun_replaces_the_bake_and_pins_a_group(addon):
    bpy, mod = addon
    ob, Vkeys, F = _scene_with_keyed_strip(bpy, pin=True)
    bpy.ops.object.shellspline_interpolate(timing="KEYED", method="linear")
    assert bpy.ops.object.shellspline_interpolate(
        timing="EVEN", use_basis=True, frame_start=1, frame_step=4, pin_group="base",
        coarse="none", frame_end=13) == {"FINISHED"}
    keys = ob.data.shape_keys.key_blocks
    assert sum(kb.name.startswith(mod.PREFIX) for kb in keys) == 13  # frames 1..13, not 21+13
    ref = ss.interpolate(ss.keyframes_from_arrays(Vkeys, F, frames=[0, 4, 8],
                                                  pinned=[0, 7, 14]), K=12, coarse="none")
    for k in (2, 6, 12):
        got = _evaluated(bpy, ob, 1 + k)
        np.testing.assert_allclose(got, ref.V[k], rtol=0, atol=1e-6)
        np.testing.assert_allclose(got[[0, 7, 14]], Vkeys[0][[0, 7, 14]], atol=1e-6)


def test_operator_reports_problems_as_errors(addon):
    bpy, _ = addon
    bpy.ops.wm.read_factory_settings(use_empty=True)
    me = bpy.data.meshes.new("plain")
    me.from_pydata([(0, 0, 0), (1, 0, 0), (0, 1, 0)], [], [(0, 1, 2)])
    ob = bpy.data.objects.new("plain", me)
    bpy.context.scene.collection.objects.link(ob)
    bpy.context.view_layer.objects.active = ob
    with pytest.raises(RuntimeError, match="needs shape keys"):
        bpy.ops.object.shellspline_interpolate()
    ob.shape_key_add(name="Basis")
    ob.shape_key_add(name="k1", from_mix=False)
    with pytest.raises(RuntimeError, match="keyed at 0 frame"):
        bpy.ops.object.shellspline_interpolate(timing="KEYED")
    with pytest.raises(RuntimeError, match="vertex group 'nope'"):
        bpy.ops.object.shellspline_interpolate(timing="EVEN", pin_group="nope")


def test_cli_writes_the_addon_zip(tmp_path, capsys):
    from shellspline.cli.main import main

    p = tmp_path / "shellspline_addon.zip"
    assert main(["blender-addon", "-o", str(p), "-q"]) == 0
    assert zipfile.ZipFile(p).read(f"{ADDON_PACKAGE}/engine.py") == \
        (Path(engine.__file__)).read_bytes()
    capsys.readouterr()
    assert main(["blender-addon", "-o", str(p), "-q"]) == 2  # exists: says which option helps
    err = capsys.readouterr().err.strip()
    assert err == f"shellspline: error: '{p}' already exists (--overwrite replaces it)"
    assert main(["blender-addon", "-o", str(p), "--overwrite", "-q"]) == 0
    assert main(["blender-addon", "-o", str(tmp_path / "addon.txt"), "-q"]) == 2
    assert "must end in .zip" in capsys.readouterr().err


_INSTALL_AND_RUN = r"""
import json, sys
import bpy  # first: it puts addon_utils on the path
import addon_utils
import numpy as np
sys.path[:0] = [sys.argv[2], sys.argv[2].rsplit("/", 1)[0]]  # this file, conftest.py
from test_blender import _evaluated, _scene_with_keyed_strip

ob, Vkeys, F = _scene_with_keyed_strip(bpy)  # first: factory settings drop user add-ons
assert bpy.ops.preferences.addon_install(filepath=sys.argv[1]) == {"FINISHED"}
addon_utils.enable("shellspline_addon", default_set=True, handle_error=None)
prefs = bpy.context.preferences.addons["shellspline_addon"].preferences
prefs.backend = "cli"  # the external command, as without shellspline in Blender's Python
keys = [_evaluated(bpy, ob, f).tolist() for f in (1, 9, 21)]
bpy.ops.object.shellspline_interpolate(timing="KEYED", method="linear", output="CACHE",
                                       cache_path=sys.argv[3])
frames = [_evaluated(bpy, ob, 1 + k).tolist() for k in range(21)]
print(json.dumps({"keys": keys, "frames": frames, "modifier": ob.modifiers[0].name}))
"""


def test_addon_installed_from_the_zip_runs_the_external_cli(addon, tmp_path):
    """Blender's own installer (Preferences > Install from Disk) on the zip, the add-on's
    preferences set to the external ``shellspline`` command, the operator baking a PC2 cache;
    in a fresh Blender process with its user folder under tmp_path."""
    import json
    import os
    import subprocess

    zp = write_addon_zip(tmp_path / "shellspline_addon.zip")
    script = tmp_path / "run.py"
    script.write_text(_INSTALL_AND_RUN)
    env = dict(os.environ, HOME=str(tmp_path))  # Blender's user scripts go to $HOME/.config
    proc = subprocess.run([sys.executable, str(script), str(zp), str(Path(__file__).resolve().parent),
                           str(tmp_path / "cache.pc2")], capture_output=True, text=True,
                          env=env, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    got = json.loads(proc.stdout.strip().splitlines()[-1])
    assert (tmp_path / ".config").is_dir() and got["modifier"] == "shellspline"
    Vkeys = np.array(got["keys"])
    ref = ss.interpolate(ss.keyframes_from_arrays(Vkeys, _strip()[1], frames=[0, 8, 20]),
                         method="linear")
    # the keyframes reach the CLI exactly (OBJ with 17 digits); the cache is float32
    np.testing.assert_array_equal(np.array(got["frames"]), ref.V.astype(np.float32))

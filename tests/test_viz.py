"""Previews, off-screen renders, plots (shellspline.viz), headless."""
from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest

import shellspline as ss
from shellspline import viz
from shellspline.errors import ShellsplineError
from shellspline.io.atomic import write_atomically
from shellspline.metrics import lta_energies, shell_energies, speed

from conftest import REPO, icosphere

pv = pytest.importorskip("pyvista", reason="viz tests need the viz extra (pip install '.[test]')")
iio = pytest.importorskip("imageio.v3", reason="viz tests need imageio")
pytest.importorskip("matplotlib", reason="viz tests need matplotlib")

K = 6
KEYFRAMES = [0, 3, 6]
SMALL = (160, 120)


def _sequence():
    """A sphere (162 vertices) that travels along +x and stretches: frames all differ."""
    V0, F = icosphere(2)
    t = np.linspace(0.0, 1.0, K + 1)[:, None, None]
    V = V0[None] * np.array([1.0, 1.0, 1.0]) * (1 + 0.3 * t * np.array([0, 0, 1.0]))
    V = V + t * np.array([4.0, 0.0, 0.0])
    return V, F


@pytest.fixture(scope="module")
def seq():
    return _sequence()


@pytest.fixture(scope="module")
def outdir(tmp_path_factory, seq):
    V, F = seq
    report = {"parameters": {"frames": KEYFRAMES, "bc": "natural", "eta": 1e-3, "mu": 1.0,
                             "lam": 1.0, "method": "lta"}}
    return ss.write_sequence(tmp_path_factory.mktemp("viz") / "out", V, F, report)


@pytest.fixture(scope="module", autouse=True)
def can_render():
    """Skip (with the reason) where VTK cannot create an off-screen render window."""
    V, F = _sequence()
    try:
        img = viz.render_frames((V[:1], F), window_size=(32, 32), annotate=False)
    except Exception as exc:  # pragma: no cover - environment dependent
        pytest.skip(f"off-screen rendering is not available here: {type(exc).__name__}: {exc}")
    if not (img != 255).any():  # pragma: no cover
        pytest.skip("off-screen rendering produced a blank image (no OpenGL?)")


def _mask(img):
    """Pixels that are not the white background."""
    return (img.astype(int) < 245).any(axis=-1)


def _saturation(pixels):
    p = pixels.reshape(-1, 3).astype(float)
    return float((p.max(axis=1) - p.min(axis=1)).mean())


# ----------------------------------------------------------------------------------------
# Off-screen renders
# ----------------------------------------------------------------------------------------
def test_render_shows_the_mesh_where_it_is_and_frames_differ(seq):
    V, F = seq
    imgs = viz.render_frames((V, F, KEYFRAMES), [0, 1, 2, K], window_size=SMALL, view="front",
                             annotate=False)
    assert imgs.shape == (4, SMALL[1], SMALL[0], 3) and imgs.dtype == np.uint8
    masks = [_mask(im) for im in imgs]
    for m in masks:
        assert 0.03 < m.mean() < 0.6  # non-blank, not all mesh
    # front view: +x is to the right; the sphere travels along +x
    cols = [np.nonzero(m)[1].mean() for m in masks]
    assert cols[0] < SMALL[0] / 2 < cols[-1]
    assert cols[0] < cols[1] < cols[2] < cols[3]
    assert (imgs[1] != imgs[2]).any()
    # keyframes gray, in-betweens coloured (orange)
    assert _saturation(imgs[0][masks[0]]) < 10
    inner = imgs[1][masks[1]].reshape(-1, 3).astype(float)
    assert _saturation(inner) > 40 and inner[:, 0].mean() > inner[:, 2].mean() + 40


def test_camera_is_fitted_to_the_whole_sequence(seq):
    V, F = seq
    imgs = viz.render_frames((V, F), window_size=SMALL, view="iso", annotate=False)
    union = np.zeros(imgs.shape[1:3], dtype=bool)
    for im in imgs:
        m = _mask(im)
        # nothing touches the border in any frame: the camera sees every pose
        assert not (m[0].any() or m[-1].any() or m[:, 0].any() or m[:, -1].any())
        union |= m
    rows, cols = np.nonzero(union)
    # and the whole motion fills the window reasonably (fitted, not tiny)
    assert cols.max() - cols.min() > 0.6 * SMALL[0]


def test_render_strip_panels(seq, tmp_path):
    V, F = seq
    w, h, gap = 80, 60, 6
    frames = [0, 1, 3, 5]
    p = viz.render_strip((V, F, KEYFRAMES), tmp_path / "s.png", frames=frames,
                         window_size=(w, h), gap=gap, view="front", annotate=False)
    img = iio.imread(p)[..., :3]
    assert img.shape == (h, 4 * w + 3 * gap, 3)
    for i, f in enumerate(frames):
        panel = img[:, i * (w + gap):i * (w + gap) + w]
        m = _mask(panel)
        assert m.mean() > 0.02, f"panel {i} is blank"
        sat = _saturation(panel[m])
        assert (sat < 10) if f in KEYFRAMES else (sat > 40), (i, sat)
        if i < 3:
            assert not _mask(img[:, i * (w + gap) + w:(i + 1) * (w + gap)]).any()  # white gap
    # same camera: the sphere moves to the right from panel to panel
    centres = [np.nonzero(_mask(img[:, i * (w + gap):i * (w + gap) + w]))[1].mean()
               for i in range(4)]
    assert centres == sorted(centres)
    # two rows
    p2 = viz.render_strip((V, F, KEYFRAMES), tmp_path / "s2.png", frames=frames, columns=2,
                          window_size=(w, h), gap=gap)
    assert iio.imread(p2).shape[:2] == (2 * h + gap, 2 * w + gap)
    assert not list(tmp_path.glob(".*tmp*"))


def test_default_strip_frames():
    assert viz.default_strip_frames(6, KEYFRAMES).tolist() == [0, 1, 3, 4, 6]
    assert viz.default_strip_frames(20, []).tolist() == [0, 5, 10, 15, 20]
    many = np.arange(0, 171, 10)
    assert viz.default_strip_frames(170, many).tolist() == np.round(
        np.linspace(0, 170, 12)).astype(int).tolist()
    assert viz.default_strip_frames(170, many[:7]).tolist() == many[:7].tolist()


def test_render_gif_has_every_frame(outdir, tmp_path):
    p = ss.render_animation(outdir, tmp_path / "a.gif", fps=10, window_size=(64, 48))
    frames = iio.imread(p, index=None)
    assert frames.shape[:3] == (K + 1, 48, 64)
    assert not np.array_equal(frames[0], frames[K])
    meta = iio.immeta(p, index=0)
    assert meta.get("duration") == pytest.approx(100, abs=1)
    sub = ss.render_animation(outdir, tmp_path / "b.gif", frames=[0, 6], window_size=(64, 48))
    assert iio.imread(sub, index=None).shape[0] == 2


def test_render_mp4(outdir, tmp_path):
    pytest.importorskip("imageio_ffmpeg", reason="MP4 output needs imageio-ffmpeg")
    import imageio.v2 as iio2

    p = ss.render_animation(outdir, tmp_path / "a.mp4", fps=12, window_size=(63, 47))
    with iio2.get_reader(p, format="FFMPEG") as r:
        assert r.count_frames() == K + 1
        assert r.get_meta_data()["fps"] == pytest.approx(12)
        assert r.get_data(0).shape == (48, 64, 3)  # rounded up to even sizes


def test_outputs_are_atomic_and_never_replace_inputs(seq, outdir, tmp_path):
    V, F = seq
    frame0 = outdir / "frame_0000.obj"
    before = frame0.read_bytes()
    with pytest.raises(ShellsplineError, match=r"\.gif or \.mp4"):
        ss.render_animation(outdir, tmp_path / "a.avi")
    with pytest.raises(ShellsplineError, match="png"):
        ss.render_strip(outdir, frame0)
    (tmp_path / "d.png").mkdir()
    with pytest.raises(ShellsplineError, match="directory"):
        ss.render_strip(outdir, tmp_path / "d.png")
    assert frame0.read_bytes() == before
    assert sorted(p.name for p in outdir.iterdir())[-1] == "report.json"  # nothing added
    # a GLB output directory: exporting over its own animation.glb is refused
    gout = ss.write_sequence(tmp_path / "g", V, F, {}, fmt="glb")
    glb = (gout / "animation.glb").read_bytes()
    with pytest.raises(ShellsplineError, match="input file"):
        ss.export_glb(gout, gout / "animation.glb", frames=[0, 1])
    assert (gout / "animation.glb").read_bytes() == glb
    assert sorted(p.name for p in gout.iterdir()) == ["animation.glb", "report.json"]
    # a failing writer leaves no temporary file behind
    def boom(tmp):
        tmp.write_bytes(b"partial")
        raise OSError("disk full")
    with pytest.raises(OSError, match="disk full"):
        write_atomically(tmp_path / "x.png", boom)  # the recipe every viz writer uses
    assert not (tmp_path / "x.png").exists() and not list(tmp_path.glob(".*tmp*"))


def test_bad_render_arguments(seq):
    V, F = seq
    with pytest.raises(ShellsplineError, match="outside 0..6"):
        viz.render_frames((V, F), [0, 7])
    with pytest.raises(ShellsplineError, match="WIDTHxHEIGHT"):
        viz.render_frames((V, F), [0], window_size="big")
    with pytest.raises(ShellsplineError, match="view"):
        viz.render_frames((V, F), [0], view="diagonal")
    with pytest.raises(ShellsplineError, match=r"\(K\+1,n,3\)"):
        viz.render_frames((V[0], F))
    with pytest.raises(ShellsplineError, match="source"):
        viz.load_source(42)


# ----------------------------------------------------------------------------------------
# The preview window's logic, driven off-screen
# ----------------------------------------------------------------------------------------
def test_viewer_slider_and_playback_drive_the_mesh(seq):
    V, F = seq
    short = (V[:4], F, [0, 3])  # a second, shorter source
    v = ss.preview((V, F, KEYFRAMES), short, track=[0, 5], off_screen=True, window_size=SMALL,
                   labels=["long", "short"])
    try:
        assert v.K == K and v.k == 0
        np.testing.assert_array_equal(v.meshes[0].points, V[0])
        for value, k in ((2.6, 3), (5.0, 5), (-3, 0), (99, K)):
            assert v.on_slider(value) == k
            np.testing.assert_array_equal(v.meshes[0].points, V[k])
            np.testing.assert_array_equal(v.meshes[1].points, V[min(k, 3)])  # clamped
            np.testing.assert_array_equal(v.markers[0].points, V[k, [0, 5]])
            assert v.slider.GetRepresentation().GetValue() == k
        # gray at keyframes, coloured between
        v.set_frame(3)
        assert v.actors[0].prop.color.hex_rgb == viz.KEYFRAME_COLOR
        v.set_frame(4)
        assert v.actors[0].prop.color.hex_rgb == viz.PALETTE[0]
        assert v.actors[1].prop.color.hex_rgb == viz.KEYFRAME_COLOR  # short: still frame 3
        # playback: loop wraps, no loop stops and pauses
        v.set_frame(K)
        v.play()
        assert v.playing and v.checkbox.GetRepresentation().GetState() == 1
        assert v.tick() == 0
        assert v.step(-1) == K
        v.toggle_loop()
        assert not v.loop and v.tick() == K and not v.playing
        assert v.checkbox.GetRepresentation().GetState() == 0
        assert v.step(5) == K
        # the playback timer advances only while playing
        v.set_frame(2)
        v.on_timer()
        assert v.k == 2
        v.play()
        v.on_timer()
        assert v.k == 3 and v.playing
        np.testing.assert_array_equal(v.meshes[0].points, V[3])
        # views are linked: one camera
        r = v.plotter.renderers
        assert r[0].camera is r[1].camera
        a = v.screenshot()
        v.set_frame(1)
        assert (v.screenshot() != a).any()
    finally:
        v.close()


def test_viewer_key_bindings(seq):
    V, F = seq
    v = ss.preview((V, F, KEYFRAMES), off_screen=True, window_size=SMALL)
    try:
        iren = v.plotter.iren.interactor  # VTK's own key events, as a window sends them

        def press(key):
            iren.SetKeySym(key)
            iren.InvokeEvent("KeyPressEvent")

        press("Right"), press("Right")
        assert v.k == 2
        press("End")
        assert v.k == K
        press("Home")
        assert v.k == 0
        press("Left")
        assert v.k == K  # loop on: wraps
        press("space")
        assert v.playing
        press("l")
        assert not v.loop
    finally:
        v.close()


def test_preview_without_a_display_says_so(seq, monkeypatch):
    V, F = seq
    monkeypatch.setattr(sys, "platform", "linux")
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    with pytest.raises(ShellsplineError, match="needs a display"):
        ss.preview((V, F))


def test_missing_extra_names_it(seq, monkeypatch, tmp_path):
    V, F = seq
    monkeypatch.setitem(sys.modules, "pyvista", None)
    with pytest.raises(ShellsplineError, match=r'pip install "shellspline\[viz\]"'):
        viz.render_frames((V, F))
    monkeypatch.setitem(sys.modules, "matplotlib.figure", None)
    with pytest.raises(ShellsplineError, match=r'pip install "shellspline\[viz\]"'):
        viz.plot_figure((V, F), "speed")


def test_import_stays_light():
    code = ("import sys, shellspline; "
            "print(sorted(m for m in ('pyvista', 'vtk', 'matplotlib', 'imageio', 'dask', "
            "'distributed') "
            "if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         cwd=REPO, env={**os.environ, "PYTHONPATH": str(REPO)}, check=True)
    assert out.stdout.strip() == "[]"


# ----------------------------------------------------------------------------------------
# Plots
# ----------------------------------------------------------------------------------------
def _data_lines(ax):
    return [ln for ln in ax.get_lines() if not ln.get_label().startswith("_")]


def test_plot_figure_energy_speed_track(seq, outdir):
    V, F = seq
    kink = V.copy()
    kink[1:3] = V[0] + (V[3] - V[0]) * np.array([1, 2])[:, None, None] / 3  # linear pieces
    fig = viz.plot_figure([outdir, (kink, F, KEYFRAMES)], ("energy", "speed"), track="0,7",
                          labels="spline,kinked", shell_energy="step")
    axes = fig.axes
    assert len(axes) == 4  # LΘA energy, shell energy, speed, trajectories
    T = ss.topology(F)
    for ax in axes[:3]:
        assert [ln.get_label() for ln in _data_lines(ax)] == ["spline", "kinked"]
        # keyframes drawn as vertical lines at 0, 3, 6
        xs = sorted(ln.get_xdata()[0] for ln in ax.get_lines() if ln.get_label() == "_keyframe")
        assert xs == KEYFRAMES
    np.testing.assert_allclose(_data_lines(axes[0])[0].get_ydata(), lta_energies(V, T))
    np.testing.assert_allclose(_data_lines(axes[1])[1].get_ydata(),
                               shell_energies(kink, T, midpoints=False)[:K])
    np.testing.assert_allclose(_data_lines(axes[1])[1].get_xdata(), np.arange(K) + 0.5)
    np.testing.assert_allclose(_data_lines(axes[2])[0].get_ydata(), speed(V))
    np.testing.assert_allclose(_data_lines(axes[2])[0].get_xdata(), np.arange(K) + 0.5)
    # trajectories: one line per source and tracked vertex
    assert len([ln for ln in axes[3].get_lines() if ln.get_label() != "_keyframe"]) == 4
    # what="speed" alone: one axes
    assert len(viz.plot_figure((V, F), "speed").axes) == 1
    assert len(viz.plot_figure((V, F), "energy", shell_energy="none").axes) == 1


def test_lta_energy_from_report_equals_recomputation(tmp_path):
    V0, F = icosphere(1)
    Vs = np.stack([V0, V0 * np.array([1.4, 1.0, 0.8]), V0])
    res = ss.interpolate((Vs, F), frames=[0, 3, 6], eta=0.1)
    fig = viz.plot_figure(res, "energy", shell_energy="none")
    (line,) = _data_lines(fig.axes[0])
    rep = np.asarray(res.report["energies"]["lta_output_energy_per_frame"])
    np.testing.assert_array_equal(line.get_ydata(), rep)
    np.testing.assert_allclose(rep, lta_energies(res.V, ss.topology(F), eta=0.1), rtol=1e-9,
                               atol=1e-15)


def test_plot_files(seq, outdir, tmp_path):
    V, F = seq
    png = ss.plot(outdir, tmp_path / "p.png", "speed")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 2000
    svg = ss.plot([outdir, (V, F)], tmp_path / "p.svg", ("speed",), labels=["a", "b"])
    text = svg.read_text()
    assert "<svg" in text and text.count("<path") > 4
    with pytest.raises(ShellsplineError, match="png"):
        ss.plot(outdir, tmp_path / "p.txt")
    with pytest.raises(ShellsplineError, match="unknown plot"):
        viz.plot_figure(outdir, "accel")
    with pytest.raises(ShellsplineError, match="labels"):
        viz.plot_figure([outdir, outdir], "speed", labels="one")
    with pytest.raises(ShellsplineError, match="outside"):
        viz.plot_figure(outdir, "speed", track=[10_000])
    assert not list(tmp_path.glob(".*tmp*"))


def test_half_axes_plot(seq, outdir, tmp_path):
    V, F = seq
    from shellspline.metrics import half_axes

    fig = viz.half_axes_figure({"spline": half_axes(V), "dir": outdir})
    lines = _data_lines(fig.axes[0])
    assert [ln.get_label() for ln in lines] == ["spline: x", "spline: y", "spline: z",
                                                "dir: x", "dir: y", "dir: z"]
    np.testing.assert_allclose(lines[2].get_ydata(), half_axes(V)[:, 2])
    keys = sorted(ln.get_xdata()[0] for ln in fig.axes[0].get_lines()
                  if ln.get_label() == "_keyframe")
    assert keys == KEYFRAMES  # taken from the directory's report
    p = ss.plot_half_axes({"a": half_axes(V)}, tmp_path / "h.png")
    assert p.read_bytes()[:4] == b"\x89PNG"
    with pytest.raises(ShellsplineError, match=r"\(K\+1,3\)"):
        viz.half_axes_figure({"bad": np.zeros((4, 2))})


# ----------------------------------------------------------------------------------------
# GLB export from an output directory, CLI
# ----------------------------------------------------------------------------------------
def test_export_glb_from_outdir(seq, outdir, tmp_path):
    from shellspline.io.gltf import read_glb

    V, F = seq
    p = ss.export_glb(outdir, tmp_path / "a.glb", fps=8, frames=[0, 3, 6])
    V2, F2, fps = read_glb(p)
    assert fps == 8.0
    np.testing.assert_array_equal(F2, F)
    np.testing.assert_allclose(V2, V[[0, 3, 6]], atol=1e-6)


def test_cli_render_plot_preview(outdir, tmp_path, capsys):
    from shellspline.cli.main import main

    gif, strip, glb = tmp_path / "a.gif", tmp_path / "s.png", tmp_path / "a.glb"
    assert main(["render", str(outdir), "--gif", str(gif), "--strip", str(strip), "--glb",
                 str(glb), "--size", "64x48", "--frames", "0,2,4,6", "-q"]) == 0
    assert iio.imread(gif, index=None).shape[0] == 4
    assert iio.imread(strip).shape[:2] == (48, 4 * 64 + 3 * 8)
    assert glb.stat().st_size > 1000
    png = tmp_path / "p.png"
    assert main(["plot", str(outdir), str(outdir), "--labels", "x,y", "--speed", "-o",
                 str(png), "-q"]) == 0
    assert png.read_bytes()[:4] == b"\x89PNG"
    capsys.readouterr()
    assert main(["render", str(outdir)]) == 2
    assert "nothing to write" in capsys.readouterr().err
    assert main(["plot", str(outdir), "-o", str(outdir / "frame_0000.obj")]) == 2
    assert main(["render", str(outdir), "--strip", str(outdir / "frame_0001.obj")]) == 2
    assert main(["render", str(outdir), "--gif", str(gif), "--size", "12"]) == 2
    assert main(["plot", str(tmp_path / "missing"), "-o", str(png)]) == 2
    with pytest.raises(SystemExit):
        main(["preview", "--help"])
    helptext = capsys.readouterr().out
    for key in ("space", "left, right", "home, end", "loop", "quit"):
        assert key in helptext


@pytest.mark.parametrize("args, needle", [
    (["--strip", "{t}/s.jpg"], "--strip '"),                      # wrong suffix
    (["--glb", "{t}/a.gltf"], "--glb '"),
    (["--strip", "{t}/blocker/s.png"], "cannot write in"),        # parent is a file
    (["--strip", "{t}/s.png", "--columns", "0"], "--columns"),
    (["--strip", "{t}/s.png", "--size", "garbage"], "'garbage'"),
    (["--strip", "{t}/s.png", "--view", "diagonal"], "view"),
    (["--strip", "{t}/s.png", "--fps", "nan"], "--fps"),
])
def test_cli_render_checks_every_output_before_rendering(outdir, tmp_path, capsys, args,
                                                          needle):
    from shellspline.cli.main import main

    (tmp_path / "blocker").write_text("a file, not a directory")
    gif = tmp_path / "a.gif"
    rc = main(["render", str(outdir), "--gif", str(gif),
               *[a.replace("{t}", str(tmp_path)) for a in args]])
    err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1 and err.startswith("shellspline: error: ")
    assert needle in err
    assert not gif.exists()  # nothing was rendered before the bad option was found
    assert sorted(p.name for p in tmp_path.iterdir()) == ["blocker"]  # no temporary files


def test_unwritable_output_is_one_line_before_any_work(seq, tmp_path, monkeypatch):
    (tmp_path / "blocker").write_text("")
    calls = []
    monkeypatch.setattr(viz, "plot_figure", lambda *a, **k: calls.append(a))
    with pytest.raises(ShellsplineError, match=r"plot '.*x\.png': cannot write in"):
        viz.plot([seq], tmp_path / "blocker" / "x.png")
    assert calls == []  # the energies were not computed for nothing
    with pytest.raises(ShellsplineError, match=r"filmstrip '.*s\.png': cannot write in"):
        viz.render_strip(seq, tmp_path / "blocker" / "s.png")
    with pytest.raises(ShellsplineError, match=r"animation '.*a\.mp4': cannot write in"):
        viz.render_animation(seq, tmp_path / "blocker" / "a.mp4")


# --- the scene's up axis ----------------------------------------------------------------
@pytest.mark.parametrize("up", ["x", "y", "z"])
def test_view_vectors_turn_with_the_up_axis(up):
    e = {"x": np.eye(3)[0], "y": np.eye(3)[1], "z": np.eye(3)[2]}
    for view in ("iso", "front", "side", "top", "xy", "xz", "yz", (1.0, 2.0, 3.0)):
        d, u = viz.view_vectors(view, up)
        assert np.isclose(np.linalg.norm(d), 1) and np.isclose(np.linalg.norm(u), 1)
        assert abs(d @ u) < 1e-12
        if abs(d @ e[up]) < 1 - 1e-9:  # the up axis points up on screen where it can
            assert u @ e[up] > 0.5
    # top looks down the up axis; front and side look horizontally
    np.testing.assert_allclose(viz.view_vectors("top", up)[0], e[up], atol=1e-12)
    for view in ("front", "side"):
        assert abs(viz.view_vectors(view, up)[0] @ e[up]) < 1e-12
    # a proper rotation of the z-up views: the screen's right in the front view is x for a
    # z-up or y-up scene (Blender's front view of the OBJ it exported) and y for x-up
    d, u = viz.view_vectors("front", up)
    right = np.cross(-d, u)
    np.testing.assert_allclose(right, e["y"] if up == "x" else e["x"], atol=1e-12)
    with pytest.raises(ShellsplineError, match="up must be x, y or z"):
        viz.view_vectors("iso", "w")


def test_up_z_keeps_the_former_views():
    for view, (d, u) in {"front": ((0, -1, 0), (0, 0, 1)), "top": ((0, 0, 1), (0, 1, 0)),
                         "side": ((1, 0, 0), (0, 0, 1))}.items():
        got = viz.view_vectors(view)
        np.testing.assert_allclose(got[0], d, atol=1e-12)
        np.testing.assert_allclose(got[1], u, atol=1e-12)


def test_scene_up_axis_from_the_files(seq, tmp_path):
    V, F = seq
    rep = {"mesh": {"names": ["keys/cactus0.ply", "keys/cactus1.ply"]}}
    assert viz.scene_up_axis(ss.write_sequence(tmp_path / "a", V, F, rep)) == "z"
    rep = {"mesh": {"names": ["keys/horse-01.OBJ"]}}
    assert viz.scene_up_axis(ss.write_sequence(tmp_path / "b", V, F, rep, fmt="ply")) == "y"
    # no report: the output's own files
    assert viz.scene_up_axis(ss.write_sequence(tmp_path / "c", V, F)) == "y"
    assert viz.scene_up_axis(ss.write_sequence(tmp_path / "d", V, F, fmt="ply")) == "z"
    assert viz.scene_up_axis(ss.write_sequence(tmp_path / "e", V, F, fmt="glb")) == "y"
    assert viz.scene_up_axis(ss.write_sequence(tmp_path / "f", V, F, fmt="pc2")) == "y"
    assert viz.scene_up_axis((V, F)) == "z"
    pytest.importorskip("pxr", reason="USD metadata needs usd-core")
    out = ss.write_sequence(tmp_path / "g", V, F, fmt="usd", up_axis="z")
    assert viz.scene_up_axis(out) == "z"


def _extent(img):
    rows, cols = np.nonzero(_mask(img))
    return rows.max() - rows.min(), cols.max() - cols.min()


def test_a_y_up_figure_stands_in_the_picture(tmp_path):
    """An ellipsoid long along y, written as OBJ frames (y-up by convention), renders taller
    than wide; forced to z-up it lies on its side."""
    V0, F = icosphere(2)
    V = (V0 * np.array([0.4, 1.5, 0.25]))[None]
    out = ss.write_sequence(tmp_path / "figure", np.concatenate([V, V + 0.01]), F)
    h, w = _extent(viz.render_frames(out, [0], window_size=(200, 200), annotate=False)[0])
    assert h > 2 * w
    h, w = _extent(viz.render_frames(out, [0], window_size=(200, 200), annotate=False,
                                     up="z")[0])
    assert w > 1.5 * h
    for view in ("front", "side"):  # from any side it stands
        h, w = _extent(viz.render_frames(out, [0], window_size=(200, 200), view=view,
                                         annotate=False)[0])
        assert h > 2 * w


def test_cli_up_option(outdir, tmp_path, capsys):
    from shellspline.cli.main import main

    strip = tmp_path / "s.png"
    assert main(["render", str(outdir), "--strip", str(strip), "--up", "x", "--size", "64x64",
                 "-q"]) == 0 and strip.is_file()
    with pytest.raises(SystemExit):  # argparse: not one of x, y, z
        main(["render", str(outdir), "--strip", str(tmp_path / "t.png"), "--up", "w"])
    assert "invalid choice" in capsys.readouterr().err


def test_render_glb_follows_the_up_override(seq, tmp_path):
    """``render --glb`` gives the GLB the up rotation of ``--up`` (as the rendered views use
    it), and of the files' convention without it."""
    from shellspline.cli.main import main
    from shellspline.io.gltf import UP_ROTATIONS, glb_up_axis, read_glb

    V, F = seq
    d = ss.write_sequence(tmp_path / "ply", V, F, fmt="ply")  # PLY frames: z-up by convention
    assert viz.scene_up_axis(d) == "z"
    for up, want in ((None, "z"), ("y", "y"), ("x", "x"), ("z", "z")):
        glb = tmp_path / f"up_{up}.glb"
        assert main(["render", str(d), "--glb", str(glb), "-q"]
                    + ([] if up is None else ["--up", up])) == 0
        assert glb_up_axis(glb) == want
        np.testing.assert_allclose(read_glb(glb)[0], V, atol=1e-6)  # data in the input's axes
    # the rotation itself: the chosen up axis becomes glTF's +y (independent of glb_up_axis)
    import json
    import struct

    raw = (tmp_path / "up_x.glb").read_bytes()
    (jlen,) = struct.unpack_from("<I", raw, 12)
    q = json.loads(raw[20:20 + jlen])["nodes"][0]["rotation"]
    from scipy.spatial.transform import Rotation

    np.testing.assert_allclose(Rotation.from_quat(q).apply([1, 0, 0]), [0, 1, 0], atol=1e-7)
    assert q == list(UP_ROTATIONS["x"])
    with pytest.raises(ss.ShellsplineError, match="up must be"):
        ss.export_glb(d, tmp_path / "bad.glb", up="w")


def test_plot_energies_of_an_output_written_with_a_fin_face(tmp_path):
    """An output written back with its input's polygons keeps the input's fin face (three
    faces on one edge) and UV-seam duplicates; the plot measures it as interpolate solved
    it (fin set aside, seams welded) instead of refusing it as non-manifold, and its
    recomputed energies equal the report's."""
    from data_synth.dcc import write_dcc

    paths = write_dcc("dcc_tube", tmp_path / "in")
    keys = [p for p in paths if p.suffix == ".obj"]
    frames = [int(x) for x in (tmp_path / "in" / "frames.txt").read_text().split()]
    res = ss.interpolate(ss.read_keyframes(keys, frames=frames), eta=0.1)
    out = tmp_path / "out"
    assert res.source is not None and res.source.fin_polygons.size
    ss.write_sequence(out, res.source.expand(res.V, res.frames, res.K, "natural"), res.F,
                      res.report, source=res.source)
    seq = viz.load_source(out)
    with pytest.raises(ShellsplineError, match="non-manifold"):
        ss.topology(seq.F, seq.V.shape[1])          # the written polygons: the fin is there
    seq.report.pop("energies")                       # force the recomputation
    e, how = viz._lta_energy(seq)
    assert how == "recomputed"
    # (read back, the written quads are triangulated on the keyframes, as the solve did)
    np.testing.assert_allclose(e, res.report["energies"]["lta_output_energy_per_frame"],
                               rtol=1e-9, atol=1e-15)
    fig = viz.plot_figure(out, "energy")
    assert len(fig.axes) == 2 and np.all(np.isfinite(_data_lines(fig.axes[1])[0].get_ydata()))

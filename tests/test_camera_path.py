"""``render --camera-path``: cameras that follow a spline through camera poses (viz.CameraPath).

Oracles: the closed-form circle (an SE(3) spline through equally spaced poses of a camera
circling the origin is that circle exactly), scipy's ``CubicSpline`` (the product metric on
rotations about one axis is a cubic in the angle), VTK's own view matrix, and a pinhole
projection of a static asymmetric scene against the rendered pixels.
"""
from __future__ import annotations

import re

import numpy as np
import pytest
from scipy import ndimage
from scipy.interpolate import CubicSpline

import shellspline as ss
from shellspline import viz
from shellspline.cli.main import main
from shellspline.errors import ShellsplineError
from shellspline.groups import se3, so3
from shellspline.io.posefiles import write_poses

from conftest import icosphere

K = 8
SIZE = (160, 120)
RADIUS = 8.0


def circle_poses(deg, radius=RADIUS, height=0.0):
    """OpenCV camera-to-world poses on a circle around the z axis, looking at the axis
    (x right, y down = −z, z towards the axis); 0° is at −y looking along +y."""
    a = np.radians(np.asarray(deg, dtype=np.float64))
    pos = np.c_[radius * np.sin(a), -radius * np.cos(a), np.full(a.size, height)]
    z = np.c_[-np.sin(a), np.cos(a), 0 * a]
    y = np.tile([0.0, 0.0, -1.0], (a.size, 1))
    R = np.stack([np.cross(y, z), y, z], axis=-1)
    return se3.from_rt(R, pos)


def scene():
    """A static sphere at the origin and a small one at +x, a little up: the view tells left
    from right and up from down."""
    V0, F0 = icosphere(2)
    V = np.concatenate([V0, 0.4 * V0 + [2.5, 0.0, 0.6]])
    F = np.concatenate([F0, F0 + len(V0)])
    return np.repeat(V[None], K + 1, axis=0), F


def project(view, p, size=SIZE, angle=30.0):
    """Pixel (column, row from the top) of world point ``p`` in VTK's perspective camera."""
    x, y, z = (view @ np.append(p, 1.0))[:3]
    f = 1.0 / np.tan(np.radians(angle) / 2)
    w, h = size
    return ((f * h / w * x / -z + 1) / 2 * w - 0.5, (1 - f * y / -z) / 2 * h - 0.5)


@pytest.fixture(scope="module", autouse=True)
def can_render():
    pytest.importorskip("pyvista", reason="render tests need the viz extra")
    pytest.importorskip("imageio.v3", reason="render tests need imageio")
    V, F = scene()
    try:
        img = viz.render_frames((V[:1], F), window_size=(32, 32), annotate=False)
    except Exception as exc:  # pragma: no cover - environment dependent
        pytest.skip(f"off-screen rendering is not available here: {type(exc).__name__}: {exc}")
    if not (img != 255).any():  # pragma: no cover
        pytest.skip("off-screen rendering produced a blank image (no OpenGL?)")


@pytest.fixture(scope="module")
def outdir(tmp_path_factory):
    V, F = scene()
    report = {"parameters": {"frames": [0, 4, 8], "method": "lta"}}
    return ss.write_sequence(tmp_path_factory.mktemp("cam") / "out", V, F, report)


# ----------------------------------------------------------------------------------------
# The path: poses at the frames
# ----------------------------------------------------------------------------------------
def test_se3_path_through_a_circle_is_the_circle_at_every_frame():
    cam = viz.CameraPath((np.arange(5.0), circle_poses(np.arange(5) * 90.0)), group="se3")
    k = np.arange(K + 1)
    np.testing.assert_allclose(cam.poses(k, K), circle_poses(k * 45.0), atol=1e-9)
    # keyframes exactly; view matrices = diag(1,-1,-1,1) T^-1 (OpenCV -> VTK axes)
    T = circle_poses(np.arange(5) * 90.0)
    np.testing.assert_allclose(cam.poses([0, 2, 4, 6, 8], K), T, atol=1e-12)
    flip = np.diag([1.0, -1.0, -1.0, 1.0])
    np.testing.assert_allclose(cam.view_matrices([0, 2, 4, 6, 8], K),
                               flip @ np.linalg.inv(T), atol=1e-12)
    gl = viz.CameraPath((np.arange(5.0), T @ flip), group="se3", convention="opengl")
    np.testing.assert_allclose(gl.view_matrices(k, K), cam.view_matrices(k, K), atol=1e-12)


def test_product_metric_path_equals_scipy_cubic_splines_about_one_axis():
    # non-uniform angles and times: rotations about z are a natural cubic in the angle and
    # positions a natural cubic in R^3 (scipy's CubicSpline on both)
    deg = np.array([0.0, 70.0, 160.0, 200.0, 330.0])
    t = np.array([0.0, 0.7, 2.0, 2.5, 4.0])
    T = circle_poses(deg, height=1.0)
    cam = viz.CameraPath((t, T), times="frames", group="so3xr3")
    tq = np.linspace(0, 4, 33)
    got = cam.spline(tq)
    ang = CubicSpline(t, np.radians(deg), bc_type="natural")(tq)
    pos = CubicSpline(t, T[:, :3, 3], bc_type="natural")(tq)
    R = so3.exp(ang[:, None] * [0, 0, 1.0]) @ T[0, :3, :3]
    np.testing.assert_allclose(got[:, :3, :3], R, atol=1e-9)
    np.testing.assert_allclose(got[:, :3, 3], pos, atol=1e-9)
    # frames = times here; "normalized" stretches the same path over 0..K
    np.testing.assert_allclose(cam.poses([0, 1, 2, 3, 4], 4), got[::8], atol=1e-12)
    norm = viz.CameraPath((t, T))
    np.testing.assert_allclose(norm.poses(np.arange(K + 1), K), cam.spline(t[0] + 0.5 *
                               np.arange(K + 1)), atol=1e-12)


def test_time_mappings_and_their_limits():
    t = 10.0 + np.array([0.0, 1.0, 2.0, 3.0])
    T = circle_poses([0, 30, 60, 90])
    sec = viz.CameraPath((t, T), times="seconds", fps=2.0)
    np.testing.assert_allclose(sec.frame_times([0, 1, 6], 6), [10.0, 10.5, 13.0])
    with pytest.raises(ShellsplineError, match=r"camera path: poses cover times 10\.\.13, frame 7"):
        sec.frame_times([7], 7)
    frames = viz.CameraPath((np.arange(4.0), T), times="frames")
    with pytest.raises(ShellsplineError, match=r"frame 4 is at 4"):
        frames.poses([0, 4], 4)
    np.testing.assert_allclose(viz.CameraPath((t, T)).frame_times([0, 3, 6], 6),
                               [10.0, 11.5, 13.0])


def test_camera_positions_look_along_the_pose_and_match_vtk():
    V, F = scene()
    cam = viz.CameraPath((np.arange(5.0), circle_poses(np.arange(5) * 90.0)))
    sv = viz.SequenceViewer((V, F), off_screen=True, window_size=SIZE, widgets=False,
                            annotate=False)
    try:
        for k, view in zip(range(K + 1), cam.camera_positions(range(K + 1), K, np.zeros(3))):
            pos, focal, up = (np.array(v) for v in view)
            T = cam.poses([k], K)[0]
            np.testing.assert_allclose(pos, T[:3, 3], atol=1e-12)
            np.testing.assert_allclose((focal - pos) / np.linalg.norm(focal - pos), T[:3, 2],
                                       atol=1e-12)          # OpenCV: looks along +z
            np.testing.assert_allclose(up, -T[:3, 1], atol=1e-12)   # y is down
            sv.plotter.camera_position = view
            m = sv.plotter.camera.GetModelViewTransformMatrix()
            M = np.array([[m.GetElement(i, j) for j in range(4)] for i in range(4)])
            np.testing.assert_allclose(M, cam.view_matrices([k], K)[0], atol=1e-12)
    finally:
        sv.close()


# ----------------------------------------------------------------------------------------
# Renders
# ----------------------------------------------------------------------------------------
def test_circling_camera_sees_the_small_sphere_where_the_pinhole_model_puts_it():
    V, F = scene()
    cam = viz.CameraPath((np.arange(5.0), circle_poses(np.arange(5) * 90.0)), group="se3")
    imgs = viz.render_frames((V, F), window_size=SIZE, annotate=False, camera_path=cam)
    exact = circle_poses(np.arange(K + 1) * 45.0)           # the true camera of every frame
    flip = np.diag([1.0, -1.0, -1.0, 1.0])
    side = []
    for k, img in enumerate(imgs):
        view = flip @ np.linalg.inv(exact[k])
        big, small = project(view, np.zeros(3)), project(view, np.array([2.5, 0.0, 0.6]))
        mask = (img < 250).any(axis=2)
        labels, n = ndimage.label(mask)
        if k in (2, 6):  # one sphere in front of the other: one blob centred on both
            assert n == 1
            assert abs(ndimage.center_of_mass(mask)[1] - big[0]) < 1.5
            continue
        assert n == 2, f"frame {k}: {n} blobs"
        sizes = ndimage.sum(mask, labels, [1, 2])
        (r, c), (_, cb) = ndimage.center_of_mass(mask, labels, 1 + np.argsort(sizes))
        assert abs(c - small[0]) < 1.5 and abs(r - small[1]) < 1.5, (k, (c, r), small)
        assert r < SIZE[1] / 2 - 5                         # above the middle: z is up
        assert abs(cb - big[0]) < 1.5
        side.append(int(np.sign(c - cb)))
    # in the image: right of the big sphere from the front half of the circle, left from the
    # back half (frames 0, 1, 3, 4, 5, 7, 8)
    assert side == [1, 1, -1, -1, -1, 1, 1]


def test_cli_render_camera_path(outdir, tmp_path, capsys):
    iio = pytest.importorskip("imageio.v3")
    poses = tmp_path / "camera.txt"
    write_poses(poses, 100.0 + np.arange(5.0), circle_poses(np.arange(5) * 90.0), "tum")
    strip = tmp_path / "strip.png"
    assert main(["render", str(outdir), "--strip", str(strip), "--camera-path", str(poses),
                 "--frames", "0,1,4", "--size", "80x60", "--no-labels", "-q"]) == 0
    got = iio.imread(strip)
    want = viz.render_frames(outdir, [0, 1, 4], window_size=(80, 60), annotate=False,
                             camera_path=viz.CameraPath(poses))
    np.testing.assert_array_equal(got[:, :80], want[0])
    np.testing.assert_array_equal(got[:, 2 * 88:], want[2])
    # the same poses read as OpenGL cameras look away from the scene: nothing in view
    gif = tmp_path / "away.gif"
    assert main(["render", str(outdir), "--gif", str(gif), "--camera-path", str(poses),
                 "--camera-convention", "opengl", "--frames", "0,4", "--size", "48x48",
                 "--no-labels", "-q"]) == 0
    assert (iio.imread(gif, index=None)[..., :3] > 250).all()
    capsys.readouterr()


@pytest.mark.parametrize("content,extra,match", [
    (None, [], r"missing\.txt: no such pose file"),
    ("1 0 0 0 0 0 0 1\n2 2 3 4 5 6 7\n", [], r"bad\.txt:2: expected 8 numbers"),
    ("1 0 0 0 0 0 0 1\n", [], r"bad\.txt: a camera path needs at least 2 poses, got 1"),
    ("0 0 0 0 0 0 0 1\n1 1 0 0 0 0 0 1\n", ["--camera-times", "frames"],
     r"bad\.txt: poses cover times 0\.\.1, frame 2 is at 2"),
    ("0 0 0 0 0 0 0 1\n1 1 0 0 0 0 0 1\n2 2 0 0 0 0 0 1\n", ["--camera-bc", "periodic"],
     r"bad\.txt: bc='periodic' needs the last pose equal to the first"),
])
def test_cli_bad_camera_files_fail_in_one_line_naming_the_file(outdir, tmp_path, capsys,
                                                               content, extra, match):
    path = tmp_path / ("missing.txt" if content is None else "bad.txt")
    if content is not None:
        path.write_text(content)
    strip = tmp_path / "s.png"
    rc = main(["render", str(outdir), "--strip", str(strip), "--camera-path", str(path),
               "--frames", "0,2", *extra])
    err = capsys.readouterr().err.strip()
    assert rc == 2
    assert len(err.splitlines()) == 1 and err.startswith("shellspline: error: ")
    assert re.search(match, err), err
    assert not strip.exists()


def test_bad_camera_arguments():
    T = circle_poses([0, 90])
    with pytest.raises(ShellsplineError, match="camera convention must be one of opencv, opengl"):
        viz.CameraPath((np.arange(2.0), T), convention="blender")
    with pytest.raises(ShellsplineError, match="camera times must be one of"):
        viz.CameraPath((np.arange(2.0), T), times="ticks")
    with pytest.raises(ShellsplineError, match=r"poses must be \(n,4,4\) for 3 times"):
        viz.CameraPath((np.arange(3.0), T))
    with pytest.raises(ShellsplineError, match="camera_path must be a pose file"):
        viz.CameraPath([1, 2])

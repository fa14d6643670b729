"""Keyframes of ``shellspline path --keep-every``: where the dropped poses turn past half a
turn from their interval's start, the curve (which turns the short way between keyframes)
would go backwards; more keyframes are added there (``KEY_TURN``), and nowhere else, however
much a jittery track's steps add up to."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.interpolate import CubicSpline
from scipy.spatial.transform import Rotation
from conftest import shared_data

from shellspline.cli.main import main
from shellspline.cli.path import keyframe_indices
from shellspline.groups import se3, so3
from shellspline.io.posefiles import read_poses, write_poses


def spin(deg) -> np.ndarray:
    """Rotations about z by the angles ``deg`` (degrees)."""
    a = np.radians(np.asarray(deg, dtype=np.float64))
    return Rotation.from_rotvec(np.c_[0 * a, 0 * a, a]).as_matrix()


def gap(R, deg) -> np.ndarray:
    """Angles (degrees) between the rotations ``R`` and the spins by ``deg``."""
    return np.degrees(so3.angle(np.swapaxes(R, -1, -2) @ spin(deg)))


def path(tmp_path, capsys, deg, every, group="so3xr3"):
    """``shellspline path`` of poses spinning through ``deg`` (one pose per second, on a
    helix) with ``--keep-every every``: exit code, summary, output poses."""
    a = np.radians(np.asarray(deg, dtype=np.float64))
    T = se3.from_rt(spin(deg), np.c_[np.cos(a), np.sin(a), 0.1 * a])
    write_poses(tmp_path / "spin.txt", np.arange(a.size, dtype=np.float64), T, "tum")
    code = main(["path", str(tmp_path / "spin.txt"), "-o", str(tmp_path / "out.txt"),
                 "--keep-every", str(every), "--group", group, "--overwrite"])
    return code, capsys.readouterr().err, read_poses(tmp_path / "out.txt")


def test_a_spin_the_short_way_would_reverse_gets_keyframes(tmp_path, capsys):
    """Poses at 0, 119, 250, 300 degrees about z, every 2nd kept: each step is less than
    180 degrees, but keyframes 0 and 250 are 110 degrees apart the short way. No pose was
    120 degrees from its interval's start by the principal angle (250 is 110 of it), so
    none was added: the output was 0, -81, -110, -60 degrees (angle errors up to 200),
    exit 0. Measured along the path, pose 2 is 250 degrees from pose 0: pose 1 is added
    and the output passes every pose."""
    deg = [0.0, 119.0, 250.0, 300.0]
    code, err, out = path(tmp_path, capsys, deg, 2)
    assert code == 0 and "4 poses, 4 keyframes (1 added" in err
    assert gap(out.T[:, :3, :3], deg).max() < 1e-9
    np.testing.assert_array_equal(keyframe_indices(4, 2, spin(deg)), [0, 1, 2, 3])
    # the same poses sampled ten times as finely (the angle linear in between): the dropped
    # poses, more than half of them, are passed within rounding too (a spin at a constant
    # rate between the poses; the spline of the angle is exact where it is linear)
    fine = np.interp(np.arange(31) / 10.0, [0, 1, 2, 3], deg)
    keys = keyframe_indices(fine.size, 15, spin(fine))
    assert np.diff(np.unwrap(np.radians(fine))[keys]).max() < np.pi
    code, err, out = path(tmp_path, capsys, fine, 15)
    assert code == 0 and "added" in err
    got = np.degrees(np.unwrap(Rotation.from_matrix(out.T[:, :3, :3]).as_rotvec()[:, 2]))
    oracle = CubicSpline(keys.astype(float), fine[keys], bc_type="natural")(np.arange(31.0))
    assert np.abs(got - oracle).max() < 1e-9
    assert np.all(np.diff(got) > 0)                                      # never backwards


@pytest.mark.parametrize("step,every", [(7.0, 30), (20.0, 10), (45.0, 5), (59.0, 7),
                                        (100.0, 3), (130.0, 2), (150.0, 9), (179.0, 4)])
@pytest.mark.parametrize("group", ["so3xr3", "se3"])
def test_a_steady_spin_is_followed_at_any_speed(tmp_path, capsys, step, every, group):
    """A spin at ``step`` degrees per pose, every ``every``-th pose kept (3.5 to 2.0 turns
    between keyframes): the keyframes are less than 180 degrees apart along the spin, and
    the output is the spin at every pose (closed form: the angle is linear in time, and
    so is its spline through the keyframes)."""
    n = 41
    deg = step * np.arange(n)
    R = spin(deg)
    keys = keyframe_indices(n, every, R)
    assert np.diff(deg[keys]).max() < 180.0
    if step * every < 120.0:  # turned less than KEY_TURN: every every-th pose only
        np.testing.assert_array_equal(keys, keyframe_indices(n, every))
    code, _, out = path(tmp_path, capsys, deg, every, group)
    assert code == 0
    assert gap(out.T[:, :3, :3], deg).max() < 1e-8
    if group == "se3":  # a screw motion at a constant rate: the positions too
        a = np.radians(deg)
        np.testing.assert_allclose(out.T[:, :3, 3], np.c_[np.cos(a), np.sin(a), 0.1 * a],
                                   atol=1e-8)


@pytest.mark.parametrize("seed", range(6))
def test_an_uneven_spin_never_turns_back(tmp_path, capsys, seed):
    """A spin about z at a rate that jumps from pose to pose (10 to 179 degrees per step),
    every 2nd to 6th pose kept. Oracle: the natural cubic spline of the unwrapped angle
    through the keyframes (scipy), which the curve about one axis equals, with keyframes
    less than 180 degrees apart along the spin: the short way between them is the way the
    poses went. With the principal angle measuring the turn, seeds that end an interval
    between 180 and 240 degrees on (e.g. 119 then 131) went backwards."""
    rng = np.random.default_rng(seed)
    n = 50
    deg = np.concatenate([[0.0], np.cumsum(rng.uniform(10.0, 179.0, n - 1))])
    every = 2 + seed % 5
    keys = keyframe_indices(n, every, spin(deg))
    assert np.diff(deg[keys]).max() < 180.0
    code, _, out = path(tmp_path, capsys, deg, every)
    assert code == 0
    oracle = CubicSpline(keys.astype(float), deg[keys], bc_type="natural")(np.arange(n))
    assert gap(out.T[:, :3, :3], oracle).max() < 1e-8
    assert gap(out.T[keys, :3, :3], deg[keys]).max() < 1e-9


def _step_sums(R, every) -> float:
    """The largest sum of the step angles (degrees) over an interval of every-th poses."""
    s = np.degrees(so3.angle(np.swapaxes(R[:-1], -1, -2) @ R[1:]))
    return max(s[i:i + every].sum() for i in range(0, s.size, every))


def test_no_keyframes_are_added_on_a_real_camera_track():
    """The TUM freiburg1_xyz ground truth (3,000 poses at 100 Hz, hand-held, turned at most
    29 degrees from its first pose): kept every 10th to every 3000th pose, no keyframe is
    added, though the steps' angles add up to 240 degrees in 1,000 poses and to 600 over the
    track (a rule on the sum of the steps would split those intervals)."""
    track = read_poses(shared_data("camera", "freiburg1_xyz-groundtruth.txt"))
    R = track.T[:, :3, :3]
    n = R.shape[0]
    for every in (10, 100, 500, 1000, 3000):
        np.testing.assert_array_equal(keyframe_indices(n, every, R), keyframe_indices(n, every))
    assert _step_sums(R, 1000) > 180.0 and _step_sums(R, 3000) > 540.0


def test_no_keyframes_are_added_on_a_jittery_track(tmp_path, capsys):
    """20,000 poses at 1 kHz: a slow 30 degree pan with 1 degree of noise on every pose. The
    steps' angles add up to 2,300 degrees per 1,000 poses; no keyframe is added for any
    --keep-every. The same noise on a spin of 800 degrees (200 per 5,000 poses) gets
    keyframes, less than 180 degrees apart along the spin."""
    rng = np.random.default_rng(0)
    n = 20000
    noise = so3.exp(rng.normal(scale=np.radians(1.0), size=(n, 3)))
    u = np.linspace(0.0, 1.0, n)
    pan = spin(30.0 * u) @ noise
    for every in (10, 100, 1000, 5000, n):
        np.testing.assert_array_equal(keyframe_indices(n, every, pan), keyframe_indices(n, every))
    assert _step_sums(pan, 1000) > 2000.0
    T = se3.from_rt(pan, np.c_[u, 0 * u, 0 * u])
    write_poses(tmp_path / "jitter.txt", u * 20.0, T, "tum")
    code = main(["path", str(tmp_path / "jitter.txt"), "-o", str(tmp_path / "out.txt"),
                 "--keep-every", "1000"])
    err = capsys.readouterr().err
    assert code == 0 and f"{n} poses, 21 keyframes, interp" in err
    # a real spin under the same noise: split, and never more than 180 degrees per interval
    whirl = spin(800.0 * u) @ noise
    keys = keyframe_indices(n, 5000, whirl)
    assert keys.size > 5
    q = so3.quat_continuous(so3.quat_from_matrix(whirl[keys]))
    assert np.degrees(2 * np.arccos(np.clip(np.sum(q[1:] * q[:-1], axis=1), -1, 1))).max() \
        < 180.0
    assert np.all(np.diff(800.0 * u[keys]) < 180.0)

"""Pose files (TUM, KITTI, EuRoC, our CSV/JSON) and the ``shellspline path`` command."""
from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from conftest import shared_data

from shellspline.cli.path import build_curve, keyframe_indices
from shellspline.errors import ShellsplineError
from shellspline.cli.main import main
from shellspline.groups import SE3, se3, so3
from shellspline.io.posefiles import FORMATS, detect_format, read_poses, write_poses

SUFFIX = {"tum": ".txt", "kitti": ".txt", "euroc": ".csv", "csv": ".csv", "json": ".json"}


def _track(n=40, seed=0):
    rng = np.random.default_rng(seed)
    t = 100.0 + np.cumsum(rng.uniform(0.05, 0.15, n))
    T = SE3.exp(np.cumsum(rng.normal(size=(n, 6)) * 0.05, axis=0))
    return t, T


@pytest.mark.parametrize("fmt", FORMATS)
def test_pose_files_round_trip_and_are_detected(tmp_path, fmt):
    t, T = _track()
    path = tmp_path / f"poses{SUFFIX[fmt]}"
    tt = t - t[0] if fmt == "euroc" else t
    write_poses(path, tt, T, fmt, origin_ns=1_403_636_579_758_555_392 if fmt == "euroc" else 0)
    assert detect_format(path) == fmt
    back = read_poses(path)
    assert back.format == fmt
    np.testing.assert_allclose(back.T, T, atol=1e-11)
    expect = np.arange(t.size, dtype=float) if fmt == "kitti" else tt
    np.testing.assert_allclose(back.t, expect, atol=1e-9, rtol=0)
    if fmt == "euroc":
        assert back.origin_ns == 1_403_636_579_758_555_392
        first = path.read_text().splitlines()[1].split(",")[0]
        assert first == "1403636579758555392"  # nanoseconds written back exactly
    assert not list(tmp_path.glob(".*tmp"))  # atomic: no temporary left behind


def test_written_quaternions_are_sign_continuous_and_scalar_last(tmp_path):
    ang = np.linspace(0, 4 * np.pi, 50)
    T = se3.from_rt(so3.exp(ang[:, None] * [0, 0, 1.0]), np.zeros(3))
    write_poses(tmp_path / "p.txt", np.arange(50.0), T, "tum")
    q = np.loadtxt(tmp_path / "p.txt")[:, 4:]
    assert np.all(np.einsum("ni,ni->n", q[1:], q[:-1]) > 0)
    np.testing.assert_allclose(q[0], [0, 0, 0, 1], atol=1e-15)
    write_poses(tmp_path / "p.csv", np.arange(50.0), T, "euroc")
    qe = np.loadtxt(tmp_path / "p.csv", delimiter=",", skiprows=1)[:, 4:8]  # w x y z
    np.testing.assert_allclose(qe, q[:, [3, 0, 1, 2]], atol=1e-12)


@pytest.mark.parametrize("content,name,match", [
    ("1 0 0 0 0 0 0 1\n2 2 3 4 5 6 7\n", "a.txt", r"a\.txt:2: expected 8 numbers"),
    ("1 0 0 0 0 0 0 1\n2 0 0 0 0 0 0 2\n", "a.txt", r"a\.txt:2: quaternion norm 2"),
    ("1 0 0 0 0 0 0 1\n1 5 0 0 0 0 0 1\n", "a.txt", r"a\.txt:2: times must increase"),
    ("# Image list with two lines of data per image:\n1 1 0 0 0 0 0 0 1 a.png\n\n", "images.txt",
     r"images\.txt:1: COLMAP images\.txt is not supported"),
    ("# c\n1 0 0 0 0 0 x 1\n", "a.txt", r"a\.txt:2: not a number: 'x'"),
    ("1 2 3 4 5\n", "a.txt", r"a\.txt:1: cannot tell the pose format: 5 numbers"),
    ("# only comments\n", "a.txt", r"a\.txt: no poses"),
    ("2 0 0 0 0 1 0 0 0 0 1 0\n", "k.txt", r"k\.txt:1: the 3x3 block is not a rotation"),
    ("t,tx,ty,tz,qx,qy,qz,qw\n0,0,0,0,0,0,0,1\n0.5,0,0\n", "c.csv", r"c\.csv:3: expected 8"),
    ("#timestamp [ns],x\n1.5,0,0,0,1,0,0,0\n", "e.csv", r"e\.csv:2: EuRoC timestamps are"),
    ('{"t": [0], "position": [[0, 0]], "quaternion_xyzw": [[0, 0, 0, 1]]}', "j.json",
     r"j\.json: expected t \(n,\), position \(n, 3\)"),
    ('{"t": [0]', "j.json", r"j\.json:1: invalid JSON"),
])
def test_bad_pose_files_give_one_line_errors_naming_file_and_line(tmp_path, content, name,
                                                                  match):
    p = tmp_path / name
    p.write_text(content)
    with pytest.raises(ShellsplineError, match=match) as exc:
        read_poses(p)
    assert "\n" not in str(exc.value)


def _tum_lines(t, T):
    q = Rotation.from_matrix(T[:, :3, :3]).as_quat()
    return [" ".join(repr(float(x)) for x in (ti, *Ti[:3, 3], *qi)) for ti, Ti, qi in
            zip(t, T, q)]


def test_what_real_exporters_add_is_accepted(tmp_path):
    """A BOM, CRLF, a header line without '#', a line repeated verbatim, quaternions
    written with 3 digits (norm off by up to 1e-3 per component) and sign flips: read as
    scipy reads the same numbers."""
    t, T = _track(12)
    lines = _tum_lines(t, T)
    q3 = np.round(Rotation.from_matrix(T[:, :3, :3]).as_quat(), 3)
    q3[1::2] *= -1  # q and -q: the same rotation
    rows = [" ".join(ln.split()[:4]) + " " + " ".join(repr(float(x)) for x in q)
            for ln, q in zip(lines, q3)]
    rows.insert(5, rows[4])  # a logger wrote pose 4 twice
    text = "timestamp tx ty tz qx qy qz qw\r\n" + "\r\n".join(rows) + "\r\n"
    p = tmp_path / "poses.txt"
    p.write_bytes(b"\xef\xbb\xbf" + text.encode())
    assert detect_format(p) == "tum"
    back = read_poses(p)
    np.testing.assert_array_equal(back.t, t)
    np.testing.assert_allclose(back.T[:, :3, 3], T[:, :3, 3], atol=1e-15)
    np.testing.assert_allclose(back.T[:, :3, :3], Rotation.from_quat(q3).as_matrix(),
                               atol=1e-15)
    # the same numbers as CSV without a header: column names skipped too
    c = tmp_path / "poses.csv"
    c.write_text("time,x,y,z,qx,qy,qz,qw\n" + "\n".join(ln.replace(" ", ",")
                                                        for ln in lines) + "\n")
    np.testing.assert_allclose(read_poses(c).T, T, atol=1e-12)
    # KITTI has no times: a repeated pose is a frame of its own, kept
    k = tmp_path / "k.txt"
    k.write_text("\n".join(" ".join(repr(float(x)) for x in Ti[:3].ravel())
                           for Ti in T[[0, 0, 1]]) + "\n")
    assert read_poses(k).t.tolist() == [0.0, 1.0, 2.0]


@pytest.mark.parametrize("kind", ["interp", "bezier", "bspline"])
def test_curve_does_not_depend_on_the_time_unit(kind):
    """ORB-SLAM3 writes TUM files with nanosecond timestamps: the same poses at the same
    instants give the same curve as in seconds (the C² solve once stopped at once there)."""
    t, T = _track(60, seed=4)
    keys = keyframe_indices(t.size, 5)
    ref = build_curve(t[keys], T[keys], kind)(t)
    for scale, shift in ((1e9, 0.0), (1e9, -t[0]), (1e-3, 0.0)):
        tt = (t + shift) * scale
        got = build_curve(tt[keys], T[keys], kind)(tt)
        np.testing.assert_allclose(got, ref, atol=1e-9)


def test_comments_in_a_windows_code_page_and_binary_data(tmp_path):
    t, T = _track(5)
    p = tmp_path / "p.txt"
    p.write_bytes("# Données de la caméra\n".encode("cp1252")
                  + ("\n".join(_tum_lines(t, T)) + "\n").encode())
    np.testing.assert_allclose(read_poses(p).T, T, atol=1e-14)
    b = tmp_path / "b.txt"
    b.write_bytes(b"\x00\x01\x02 1 2 3")
    with pytest.raises(ShellsplineError, match=r"b\.txt: not a text pose file"):
        read_poses(b)


def test_column_names_decide_the_quaternion_order(tmp_path):
    """A header that names the columns is believed over the guess from the data: integer
    nanoseconds with 'qx,qy,qz,qw' are not EuRoC (scalar first) but ours; a TUM-like file
    whose header says 'qw qx qy qz' is refused instead of read with every rotation wrong."""
    t, T = _track(10)
    ns = (np.round(t * 1e9)).astype(np.int64)
    q = Rotation.from_matrix(T[:, :3, :3]).as_quat()  # x y z w
    p = tmp_path / "ns.csv"
    p.write_text("timestamp,tx,ty,tz,qx,qy,qz,qw\n" + "".join(
        f"{n}," + ",".join(repr(float(x)) for x in (*Ti[:3, 3], *qi)) + "\n"
        for n, Ti, qi in zip(ns, T, q)))
    assert detect_format(p) == "csv"
    back = read_poses(p)
    np.testing.assert_allclose(back.T[:, :3, :3], Rotation.from_quat(q).as_matrix(), atol=1e-14)
    np.testing.assert_array_equal(back.t, ns.astype(np.float64))
    w = tmp_path / "wxyz.txt"
    w.write_text("# timestamp x y z qw qx qy qz\n" + "".join(
        " ".join(repr(float(x)) for x in (ti, *Ti[:3, 3], qi[3], *qi[:3])) + "\n"
        for ti, Ti, qi in zip(t, T, q)))
    with pytest.raises(ShellsplineError, match=r"wxyz\.txt:1: the column names put the "
                                               r"quaternion scalar first.*TUM has it last"):
        read_poses(w)
    # the real EuRoC header is still EuRoC
    e = tmp_path / "e.csv"
    write_poses(e, t - t[0], T, "euroc", origin_ns=int(ns[0]))
    assert detect_format(e) == "euroc"


def test_keyframe_indices_keep_first_and_last():
    np.testing.assert_array_equal(keyframe_indices(10, 3), [0, 3, 6, 9])
    np.testing.assert_array_equal(keyframe_indices(11, 3), [0, 3, 6, 9, 10])
    np.testing.assert_array_equal(keyframe_indices(5, 1), np.arange(5))
    np.testing.assert_array_equal(keyframe_indices(5, 100), [0, 4])


@pytest.mark.parametrize("fmt", ["tum", "kitti", "euroc", "csv", "json"])
def test_path_writes_every_input_time_in_the_input_format(tmp_path, fmt, capsys):
    t, T = _track(31)
    src = tmp_path / f"in{SUFFIX[fmt]}"
    write_poses(src, t - t[0] if fmt == "euroc" else t, T, fmt)
    out = tmp_path / f"out{SUFFIX[fmt]}"
    assert main(["path", str(src), "-o", str(out), "--keep-every", "4"]) == 0
    a, b = read_poses(src), read_poses(out)
    assert b.format == fmt
    np.testing.assert_allclose(b.t, a.t, atol=1e-9)
    keys = keyframe_indices(a.t.size, 4)
    np.testing.assert_allclose(b.T[keys], a.T[keys], atol=1e-9)  # keyframes exact
    # in-betweens: the C² spline through the keyframes, evaluated at the input times
    ref = build_curve(a.t[keys], a.T[keys])(a.t)
    np.testing.assert_allclose(b.T, ref, atol=1e-9)
    err = capsys.readouterr().err
    assert "9 keyframes" in err and "in-between" in err  # 0, 4, ..., 28 and 30


def test_path_rate_times_format_kinds_groups(tmp_path):
    t, T = _track(25)
    src = tmp_path / "in.txt"
    write_poses(src, t, T, "tum")
    out = tmp_path / "o.csv"
    assert main(["path", str(src), "-o", str(out), "--rate", "20", "--format", "csv",
                 "--kind", "bezier", "--group", "so3xr3", "-q"]) == 0
    b = read_poses(out)
    assert b.format == "csv"
    np.testing.assert_allclose(np.diff(b.t), 0.05, atol=1e-9)
    assert b.t[0] == pytest.approx(t[0]) and b.t[-1] <= t[-1] + 1e-9
    times = tmp_path / "times.txt"
    times.write_text("# times\n" + "\n".join(str(x) for x in np.linspace(t[0], t[-1], 7)))
    out2 = tmp_path / "o2.json"
    assert main(["path", str(src), "-o", str(out2), "--times", str(times), "--format", "json",
                 "--kind", "bspline", "--keep-every", "3", "-q"]) == 0
    d = json.loads(out2.read_text())
    assert len(d["t"]) == 7
    b2 = read_poses(out2)
    np.testing.assert_allclose(b2.T[[0, -1]], T[[0, -1]], atol=1e-9)  # clamped B-spline ends


def test_path_times_file_in_euroc_nanoseconds(tmp_path):
    t, T = _track(12)
    origin = 1_403_636_579_758_555_392
    src = tmp_path / "in.csv"
    write_poses(src, t - t[0], T, "euroc", origin_ns=origin)
    ns = origin + np.round((t[[2, 5]] - t[0]) * 1e9).astype(np.int64) + 1000
    times = tmp_path / "times.txt"
    times.write_text("\n".join(str(n) for n in ns) + "\n")
    out = tmp_path / "out.csv"
    assert main(["path", str(src), "-o", str(out), "--times", str(times), "-q"]) == 0
    rows = out.read_text().splitlines()[1:]
    assert [int(r.split(",")[0]) for r in rows] == ns.tolist()


def test_times_from_a_pose_file_with_column_names(tmp_path):
    """--times takes the first field of another pose file: EuRoC CSV with its header (integer
    nanoseconds), a TUM-like file with a header line without '#' and a BOM."""
    t, T = _track(12)
    origin = 1_403_636_579_758_555_392
    src = tmp_path / "in.csv"
    write_poses(src, t - t[0], T, "euroc", origin_ns=origin)
    other = tmp_path / "other.csv"
    write_poses(other, t[[1, 4, 6]] - t[0], T[[1, 4, 6]], "euroc", origin_ns=origin)
    out = tmp_path / "out.csv"
    assert main(["path", str(src), "-o", str(out), "--times", str(other), "-q"]) == 0
    np.testing.assert_allclose(read_poses(out).T, T[[1, 4, 6]], atol=1e-9)  # keyframes
    tum = tmp_path / "in.txt"
    write_poses(tum, t, T, "tum")
    times = tmp_path / "times.txt"
    rows = f"{float(t[2])!r},0\n{float(t[3])!r},0\n"
    times.write_bytes(b"\xef\xbb\xbftimestamp,x\n" + rows.encode())
    assert main(["path", str(tum), "-o", str(tmp_path / "o.txt"), "--times", str(times),
                 "-q"]) == 0
    np.testing.assert_array_equal(read_poses(tmp_path / "o.txt").t, t[[2, 3]])


def test_path_periodic_and_clamped(tmp_path):
    ang = np.linspace(0, 2 * np.pi, 13)
    T = se3.from_rt(so3.exp(ang[:, None] * [0, 0, 1.0]),
                    np.stack([np.cos(ang), np.sin(ang), 0 * ang], 1))
    T[-1] = T[0]
    src = tmp_path / "circle.txt"
    write_poses(src, ang, T, "tum")
    out = tmp_path / "o.txt"
    # a body turning once around a circle (always facing along it), keyframes every 30
    # degrees: under the screw metric the keyframes lie on one screw motion, so the periodic
    # spline is that motion (geodesic precision): the path stays on the circle, no drift
    assert main(["path", str(src), "-o", str(out), "--bc", "periodic", "--rate", "50",
                 "--group", "se3", "-q"]) == 0
    b = read_poses(out)
    np.testing.assert_allclose(np.linalg.norm(b.T[:, :2, 3], axis=1), 1, atol=1e-9)
    np.testing.assert_allclose(b.T[:, 2, 3], 0, atol=1e-12)
    # the product metric interpolates the positions as a periodic cubic: close, not exact
    assert main(["path", str(src), "-o", str(out), "--bc", "periodic", "--rate", "50",
                 "-q", "--overwrite"]) == 0
    r = np.linalg.norm(read_poses(out).T[:, :2, 3], axis=1)
    assert 1e-6 < np.abs(r - 1).max() < 1e-2
    assert main(["path", str(src), "-o", str(out), "--bc", "clamped", "--rate", "1000", "-q",
                 "--overwrite"]) == 0
    v = read_poses(out).T[:2, :3, 3]
    assert np.linalg.norm(v[1] - v[0]) < 1e-5  # starts at rest (1 ms step, zero velocity)


def test_path_errors_exit_2_with_one_line(tmp_path, capsys):
    t, T = _track(10)
    src = tmp_path / "in.txt"
    write_poses(src, t, T, "tum")
    out = str(tmp_path / "o.txt")
    cases = [
        (["--bc", "periodic"], "needs the last pose equal to the first"),
        (["--kind", "bezier", "--bc", "clamped"], "applies to --kind interp only"),
        (["--keep-every", "0"], "--keep-every must be >= 1"),
        (["--rate", "-1"], "--rate must be > 0"),
    ]
    for extra, msg in cases:
        assert main(["path", str(src), "-o", out] + extra) == 2
        err = capsys.readouterr().err
        assert msg in err and err.count("\n") == 1
    times = tmp_path / "times.txt"
    times.write_text(f"{t[0] - 1}\n")
    assert main(["path", str(src), "-o", out, "--times", str(times)]) == 2
    assert "times must lie in" in capsys.readouterr().err
    assert main(["path", str(tmp_path / "missing.txt"), "-o", out]) == 2
    assert "no such pose file" in capsys.readouterr().err


def test_path_plot(tmp_path):
    pytest.importorskip("matplotlib")
    t, T = _track(20)
    src = tmp_path / "in.txt"
    write_poses(src, t, T, "tum")
    png = tmp_path / "p.png"
    assert main(["path", str(src), "-o", str(tmp_path / "o.txt"), "--keep-every", "5",
                 "--plot", str(png), "-q"]) == 0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_camera_ground_truth_spline_beats_linear_between_keyframes(tmp_path):
    gt = shared_data("camera", "freiburg1_xyz-groundtruth.txt")
    a = read_poses(gt)
    assert a.t.size == 3000 and a.format == "tum"
    n = 600
    t, T = a.t[:n], a.T[:n]
    keys = keyframe_indices(n, 10)
    rest = np.setdiff1d(np.arange(n), keys)
    ours = build_curve(t[keys], T[keys])(t)
    from shellspline.curves import geodesic_interpolant
    from shellspline.groups import SO3xR3

    lin = geodesic_interpolant(SO3xR3, t[keys], T[keys])(t)
    dp = np.linalg.norm(ours[rest, :3, 3] - T[rest, :3, 3], axis=1)
    dl = np.linalg.norm(lin[rest, :3, 3] - T[rest, :3, 3], axis=1)
    assert np.sqrt(np.mean(dp ** 2)) < 0.7 * np.sqrt(np.mean(dl ** 2))


def test_path_plot_without_matplotlib_fails_before_writing(tmp_path, monkeypatch, capsys):
    import importlib.util

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec",
                        lambda name, *a: None if name == "matplotlib" else real(name, *a))
    t, T = _track(8)
    src = tmp_path / "in.txt"
    write_poses(src, t, T, "tum")
    out = tmp_path / "o.txt"
    assert main(["path", str(src), "-o", str(out), "--plot", str(tmp_path / "p.png")]) == 2
    assert "pip install 'shellspline[viz]'" in capsys.readouterr().err
    assert not out.exists()


@pytest.mark.parametrize("group", ["so3xr3", "se3"])
def test_keyframes_are_added_where_the_dropped_poses_turn_half_a_turn(tmp_path, capsys, group):
    """A camera circling at 20 degrees per pose, every 10th pose kept: 200 degrees between
    keyframes, which the curve took the short way round (-160 degrees: angle errors up to
    180 degrees, exit 0). Keyframes are added where the poses turn 120 degrees or more from
    the interval's start; the spin about one axis at a constant rate is then followed to
    rounding (oracle: the input poses)."""
    n = 61
    a = np.radians(20.0) * np.arange(n)
    R = Rotation.from_rotvec(np.c_[0 * a, 0 * a, a]).as_matrix()
    T = se3.from_rt(R, np.c_[np.cos(a), np.sin(a), 0.1 * a])
    write_poses(tmp_path / "spin.txt", 0.1 * np.arange(n), T, "tum")
    code = main(["path", str(tmp_path / "spin.txt"), "-o", str(tmp_path / "out.txt"),
                 "--keep-every", "10", "--group", group])
    err = capsys.readouterr().err
    assert code == 0 and "added where the poses turn 120° or more between keyframes" in err
    out = read_poses(tmp_path / "out.txt")
    turn = so3.angle(np.swapaxes(out.T[:, :3, :3], -1, -2) @ R)
    assert np.degrees(turn).max() < 1e-9
    keys = keyframe_indices(n, 10, R)
    steps = so3.angle(np.swapaxes(R[keys[:-1]], -1, -2) @ R[keys[1:]])
    assert np.degrees(steps).max() <= 80.0 + 1e-9        # 60 degrees + one step
    # a track that turns less (2 degrees per pose) keeps exactly every 10th pose
    slow = Rotation.from_rotvec(np.c_[0 * a, 0 * a, a / 10]).as_matrix()
    assert np.array_equal(keyframe_indices(n, 10, slow), keyframe_indices(n, 10))


def test_a_rate_that_asks_for_billions_of_poses_is_refused(tmp_path, capsys):
    # --rate 1e12 on 4 s of poses asked numpy for 4e12 poses (a MemoryError, reported as an
    # internal error, or the machine's memory); now one line, exit 2, nothing written
    t, T = _track(40)
    write_poses(tmp_path / "p.txt", t, T, "tum")
    code = main(["path", str(tmp_path / "p.txt"), "-o", str(tmp_path / "o.txt"), "--rate",
                 "1e12"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1
    assert "p.txt gives" in err and "at most 10,000,000" in err
    assert not (tmp_path / "o.txt").exists()


def test_times_outside_the_keyframes_are_named_in_the_files_unit(tmp_path, capsys):
    # Unix-epoch seconds were printed with 9 digits ("[1.30503110e+09, ...]"), EuRoC ones as
    # seconds since the first stamp while the user wrote nanoseconds
    t, T = _track(10)
    t = (t + 1305031000.0).tolist()
    write_poses(tmp_path / "p.txt", t, T, "tum")
    (tmp_path / "times.txt").write_text(f"{t[0] - 0.5!r}\n{t[1]!r}\n")
    code = main(["path", str(tmp_path / "p.txt"), "-o", str(tmp_path / "o.txt"), "--times",
                 str(tmp_path / "times.txt")])
    err = capsys.readouterr().err
    assert code == 2 and f"[{t[0]!r}, {t[-1]!r}]" in err and f"got {t[0] - 0.5!r}.." in err
    origin = 1_403_636_579_758_555_392
    write_poses(tmp_path / "e.csv", np.array(t) - t[0], T, "euroc", origin_ns=origin)
    (tmp_path / "ns.txt").write_text(f"{origin - 1000}\n")
    code = main(["path", str(tmp_path / "e.csv"), "-o", str(tmp_path / "o.csv"), "--times",
                 str(tmp_path / "ns.txt")])
    err = capsys.readouterr().err
    assert code == 2 and f"[{origin}, " in err and f"got {origin - 1000}..{origin - 1000}" in err


def test_path_never_overwrites_its_input_nor_an_output_unasked(tmp_path, capsys):
    """`path` replaced an existing OUT silently, and `-o` naming the input overwrote the
    input itself (the poses were lost). Now: the input is refused as OUT, an existing OUT
    needs --overwrite (as `interpolate` and `motion`), each in one line, exit 2, files
    untouched."""
    t, T = _track(10)
    src = tmp_path / "in.txt"
    write_poses(src, t, T, "tum")
    before = src.read_bytes()
    assert main(["path", str(src), "-o", str(src), "-q", "--overwrite"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "is an input of this command" in err
    assert src.read_bytes() == before
    out = tmp_path / "o.txt"
    out.write_text("keep me\n")
    assert main(["path", str(src), "-o", str(out), "-q"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "exists (use --overwrite" in err and str(out) in err
    assert out.read_text() == "keep me\n"
    assert main(["path", str(src), "-o", str(out), "-q", "--overwrite"]) == 0
    np.testing.assert_allclose(read_poses(out).T, T, atol=1e-9)
    assert main(["path", str(src), "-o", str(tmp_path / "no" / "o.txt"), "-q"]) == 2
    assert "does not exist" in capsys.readouterr().err


def test_path_outputs_are_checked_before_any_work(tmp_path, capsys):
    """`-o X --plot X`: the picture replaced the poses (exit 0); `--plot p.xyz` was an
    internal error (exit 3) after the poses were written; an existing picture is kept."""
    t, T = _track(10)
    src = tmp_path / "in.txt"
    write_poses(src, t, T, "tum")
    same = tmp_path / "same.png"
    assert main(["path", str(src), "-o", str(same), "--plot", str(same), "-q"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "-o" in err and "--plot" in err and "are the same file" in err
    assert not same.exists()
    out = tmp_path / "o.txt"
    assert main(["path", str(src), "-o", str(out), "--plot", str(tmp_path / "p.xyz")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "internal error" not in err
    assert "p.xyz: expected one of .png, .svg, .pdf" in err
    keep = tmp_path / "keep.png"
    keep.write_text("precious\n")
    assert main(["path", str(src), "-o", str(out), "--plot", str(keep)]) == 2
    assert "keep.png exists (use --overwrite" in capsys.readouterr().err
    assert main(["path", str(src), "-o", str(out), "--plot", str(tmp_path / "no" / "p.png")]) == 2
    assert "does not exist" in capsys.readouterr().err
    assert keep.read_text() == "precious\n" and not out.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in.txt", "keep.png"]


def _half_turn_file(tmp_path, name="half.txt"):
    """Poses at t = 1, 2, 3 (lines 2-4) with a half turn about z between the first two."""
    p = tmp_path / name
    p.write_text("# t tx ty tz qx qy qz qw\n1.0 0 0 0 0 0 0 1\n2.0 1 0 0 0 0 1 0\n"
                 "3.0 2 0 0 0 0 1 0\n")
    return p


@pytest.mark.parametrize("kind", ["interp", "bezier", "bspline"])
def test_a_half_turn_between_keyframes_is_refused_naming_file_lines_and_times(tmp_path,
                                                                               capsys, kind):
    """Two keyframes 180 degrees apart: interp and bezier said "X: poses 0 and 1 differ..."
    (X: an internal name), bspline accepted them (the turn's direction is arbitrary)."""
    src = _half_turn_file(tmp_path)
    out = tmp_path / "o.txt"
    for group in ("so3xr3", "se3"):
        assert main(["path", str(src), "-o", str(out), "--kind", kind, "--group", group]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "X:" not in err
        assert (f"{src}: the keyframes at lines 2 and 3 (t = 1.0 and 2.0) differ by a rotation "
                "of 180.0 degrees") in err
    assert not out.exists()
    track = read_poses(src)
    with pytest.raises(ShellsplineError, match="poses 0 and 1 differ by a rotation of 180"):
        build_curve(track.t, track.T, kind)


def test_curve_errors_of_the_keyframes_name_the_file(tmp_path, capsys):
    t, T = _track(10)
    src = tmp_path / "in.txt"
    write_poses(src, t, T, "tum")
    assert main(["path", str(src), "-o", str(tmp_path / "o.txt"), "--bc", "periodic"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"{src}: " in err and "needs the last pose equal" in err


def test_extra_numbers_on_a_pose_line_are_refused_documented_extras_kept(tmp_path):
    """A TUM line with a 9th number was read silently (a missing one was refused); KITTI's
    and ours likewise. EuRoC's further columns (velocities, biases) stay documented and read,
    a trailing comma in a CSV line stays accepted."""
    cases = [("a.txt", "1 0 0 0 0 0 0 1\n2 1 0 0 0 0 0 1 7\n",
              r"a\.txt:2: expected 8 numbers \(t tx ty tz qx qy qz qw\), got 9"),
             ("k.txt", "1 0 0 0 0 1 0 0 0 0 1 0\n1 0 0 1 0 1 0 0 0 0 1 0 9\n",
              r"k\.txt:2: expected 12 numbers \(a 3x4 matrix row by row\), got 13"),
             ("c.csv", "t,tx,ty,tz,qx,qy,qz,qw\n0,0,0,0,0,0,0,1\n1,1,0,0,0,0,0,1,5\n",
              r"c\.csv:3: expected 8 numbers \(t tx ty tz qx qy qz qw\), got 9")]
    for name, text, match in cases:
        (tmp_path / name).write_text(text)
        with pytest.raises(ShellsplineError, match=match) as exc:
            read_poses(tmp_path / name)
        assert "\n" not in str(exc.value)
    ok = tmp_path / "t.csv"
    ok.write_text("t,tx,ty,tz,qx,qy,qz,qw\n0,0,0,0,0,0,0,1,\n1,1,0,0,0,0,0,1,\n")
    assert read_poses(ok).t.tolist() == [0.0, 1.0]
    e = tmp_path / "e.csv"
    e.write_text("#timestamp [ns],p_RS_R_x [m],p_RS_R_y [m],p_RS_R_z [m],q_RS_w [],q_RS_x [],"
                 "q_RS_y [],q_RS_z [],v_RS_R_x [m s^-1],v_RS_R_y [m s^-1],v_RS_R_z [m s^-1]\n"
                 "1403636579758555392,1,2,3,1,0,0,0,0.1,0.2,0.3\n"
                 "1403636579763555584,4,5,6,1,0,0,0,0.1,0.2,0.3\n")
    tr = read_poses(e)
    assert tr.format == "euroc" and tr.T[:, :3, 3].tolist() == [[1, 2, 3], [4, 5, 6]]
    assert tr.lines.tolist() == [2, 3]

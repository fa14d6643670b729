"""``shellspline path`` and the pose files on trajectories as SLAM tools write them, made from
the real TUM RGB-D ground truth (freiburg1_xyz): ORB-SLAM3's nanosecond stamps, CSV headers
that start like EuRoC's, EuRoC rows out of order, and poses the writer must not write."""
from __future__ import annotations

import numpy as np
import pytest
from conftest import shared_data

from shellspline.cli.main import main
from shellspline.curves import BSpline, bezier, bezier_velocity, clamped_knots
from shellspline.errors import ShellsplineError
from shellspline.groups import so3
from shellspline.io.posefiles import read_poses, write_poses


def _tum(n=300):
    a = read_poses(shared_data("camera", "freiburg1_xyz-groundtruth.txt"))
    return a.t[:n], a.T[:n]


def test_orbslam3_nanosecond_stamps_with_a_zero_fraction(tmp_path):
    """ORB-SLAM3 writes EuRoC runs as TUM lines whose stamp is ``1e9 * t`` in fixed notation
    (``1403636580863555584.000000``): they were read as float "seconds" of 1.4e18, so
    ``--rate 200`` asked for 200 poses per nanosecond (refused: billions) and the stamps came
    back as ``1.4036365808635556e+18``. They are integer nanoseconds, kept exact."""
    t, T = _tum()
    ns = [int(1e9 * (x + 98_605_481.0)) for x in t]  # EuRoC-era epochs, as 1e9 * double
    q = so3.quat_from_matrix(T[:, :3, :3])
    q[1::2] *= -1  # both quaternion signs, as the exporters' conversions give them
    src = tmp_path / "f_dataset-MH01_mono.txt"
    src.write_text("".join(f"{n}.000000 " + " ".join(f"{x:.9f}" for x in (*Ti[:3, 3], *qi))
                           + "\n" for n, Ti, qi in zip(ns, T, q)))
    tr = read_poses(src)
    assert (tr.format, tr.time_unit, tr.origin_ns) == ("tum", "ns", ns[0])
    np.testing.assert_allclose(tr.t, (np.array(ns) - ns[0]) * 1e-9, rtol=0, atol=1e-15)
    out = tmp_path / "o.txt"
    assert main(["path", str(src), "-o", str(out), "--rate", "200", "--keep-every", "5",
                 "-q"]) == 0
    stamps = [int(ln.split()[0]) for ln in out.read_text().splitlines()[1:]]
    span = ns[-1] - ns[0]
    assert stamps == [ns[0] + 5_000_000 * k for k in range(span // 5_000_000 + 1)]
    # its own stamps as --times: every pose back, at the same integers (interp reproduces
    # the keyframes, and with every pose kept, every pose)
    assert main(["path", str(src), "-o", str(out), "--times", str(src), "--overwrite",
                 "-q"]) == 0
    back = read_poses(out)
    assert [int(ln.split()[0]) for ln in out.read_text().splitlines()[1:]] == ns
    np.testing.assert_allclose(back.T, tr.T, atol=1e-12)


def test_a_timestamp_header_with_the_quaternion_scalar_last_is_not_euroc(tmp_path):
    """``#timestamp [ns],tx,ty,tz,qx,qy,qz,qw`` starts like EuRoC's header and was read as
    EuRoC (scalar first) without looking at the names: every rotation wrong, no error. The
    names decide, as they do under any other header."""
    t, T = _tum(50)
    ns = 1_403_636_579_758_555_392 + np.round((t - t[0]) * 1e9).astype(np.int64)
    q = so3.quat_from_matrix(T[:, :3, :3])  # x y z w
    body = "".join(f"{n}," + ",".join(repr(float(x)) for x in (*Ti[:3, 3], *qi)) + "\n"
                   for n, Ti, qi in zip(ns.tolist(), T, q))
    for head in ("#timestamp [ns],tx,ty,tz,qx,qy,qz,qw", "#timestamp,x,y,z,q_x,q_y,q_z,q_w"):
        src = tmp_path / "traj.csv"
        src.write_text(head + "\n" + body)
        tr = read_poses(src)
        assert (tr.format, tr.time_unit, tr.origin_ns) == ("csv", "ns", int(ns[0]))
        np.testing.assert_allclose(tr.T, T, atol=1e-14)
    # EuRoC's own header (scalar first, named) is still EuRoC
    src.write_text("#timestamp [ns],p_RS_R_x [m],p_RS_R_y [m],p_RS_R_z [m],q_RS_w [],"
                   "q_RS_x [],q_RS_y [],q_RS_z []\n" + "".join(
                       f"{n}," + ",".join(repr(float(x)) for x in (*Ti[:3, 3], qi[3], *qi[:3]))
                       + "\n" for n, Ti, qi in zip(ns.tolist(), T, q)))
    tr = read_poses(src)
    assert tr.format == "euroc"
    np.testing.assert_allclose(tr.T, T, atol=1e-14)


def test_euroc_rows_out_of_order_are_named_by_their_stamps(tmp_path, capsys):
    """Rows out of order or two poses at one stamp: the message showed seconds since the
    first stamp (``got 0.0399 after 0.0499``), which are nowhere in the file."""
    t, T = _tum(20)
    origin = 1_403_636_579_758_555_392
    src = tmp_path / "data.csv"
    write_poses(src, t - t[0], T, "euroc", origin_ns=origin)
    rows = src.read_text().splitlines()
    a, b = rows[5].split(",")[0], rows[6].split(",")[0]
    rows[5], rows[6] = rows[6], rows[5]
    src.write_text("\n".join(rows) + "\n")
    assert main(["path", str(src), "-o", str(tmp_path / "o.csv")]) == 2
    err = capsys.readouterr().err
    assert f"data.csv:7: times must increase strictly, got {a} after {b}" in err
    assert err.count("\n") == 1


@pytest.mark.parametrize("fmt", ["tum", "kitti", "euroc", "csv", "json"])
def test_poses_the_reader_would_refuse_are_not_written(tmp_path, fmt):
    """A NaN pose (tracking lost), a non-finite time, a rotation block that is not one: they
    were written, into a file the reader then refused (or, for the rotation, read as some
    other rotation's quaternion). Refused before anything is written."""
    t, T = _tum(10)
    cases = []
    bad = T.copy()
    bad[3, 1, 3] = np.nan
    cases.append((t, bad, r"write_poses: non-finite T\[3\]"))
    tt = t.copy()
    tt[4] = np.inf
    cases.append((tt, T, r"write_poses: non-finite t\[4\]"))
    bad = T.copy()
    bad[2, :3, :3] *= 1.1
    cases.append((t, bad, r"write_poses: T\[2\]: the rotation block is not a rotation"))
    bad = T.copy()
    bad[6, :3, 0] *= -1  # a reflection
    cases.append((t, bad, r"write_poses: T\[6\]: the rotation block is not a rotation"))
    out = tmp_path / f"o.{fmt}"
    for times, poses, match in cases:
        with pytest.raises(ShellsplineError, match=match):
            write_poses(out, times, poses, fmt)
        assert not list(tmp_path.iterdir())
    # rounding (KITTI's 7 significant digits) is not refused
    M = np.array([float(f"{x:.6e}") for x in T[:, :3, :3].ravel()]).reshape(-1, 3, 3)
    near = T.copy()
    near[:, :3, :3] = M
    write_poses(out, t, near, fmt)
    np.testing.assert_allclose(read_poses(out).T, T, atol=1e-6)


def test_bezier_and_bspline_refuse_poses_that_are_not_poses():
    """``bezier``/``bezier_velocity``/``BSpline`` (the Python API of ``--kind bspline``) took
    any array: a NaN pose gave NaN poses, a scaled rotation block smooth garbage, silently.
    They are checked as ``cubic_spline`` checks its poses (one line naming the argument)."""
    t, T = _tum(8)
    nan = T.copy()
    nan[3, 0, 0] = np.nan
    scaled = T.copy()
    scaled[3, :3, :3] *= 1.1
    cases = [(nan, "{} contains non-finite values"),
             (scaled, r"{}\[3\]: the rotation block is not a rotation")]
    for G in ("se3", "so3xr3"):
        for X, msg in cases:
            with pytest.raises(ShellsplineError, match=msg.format("control")):
                BSpline(G, X, clamped_knots(t, 3), 3)
            with pytest.raises(ShellsplineError, match=msg.format("P")):
                bezier(G, X[:4], np.linspace(0, 1, 5))
            with pytest.raises(ShellsplineError, match=msg.format("P")):
                bezier_velocity(G, X[:5], 0.5)
    # valid poses still go through
    assert BSpline("se3", T, clamped_knots(t, 3), 3)(t).shape == (8, 4, 4)
    assert bezier("so3xr3", T[:4], np.linspace(0, 1, 5)).shape == (5, 4, 4)

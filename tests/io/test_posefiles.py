"""Pose files written and read back: exact numbers, and absolute times across formats."""
from decimal import Decimal

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from shellspline.groups import se3
from shellspline.io.posefiles import FORMATS, read_poses, write_poses


def _utm_track(n=50, seed=0):
    """A vehicle in UTM coordinates (~5e6 m) moving by millimetres, at TUM-like times."""
    rng = np.random.default_rng(seed)
    R = Rotation.from_rotvec(np.cumsum(rng.normal(size=(n, 3)) * 0.01, axis=0)).as_matrix()
    p = np.array([448262.123456789, 5411932.987654321, 251.25]) + \
        np.cumsum(rng.normal(size=(n, 3)) * 1e-3, axis=0)
    t = 1305031098.6659 + 0.01 * np.arange(n)
    return t, se3.from_rt(R, p)


@pytest.mark.parametrize("fmt", FORMATS)
def test_written_poses_read_back_exactly(tmp_path, fmt):
    # %.12g kept 5 micrometres of a 5.4e6 m coordinate; shortest-repr numbers keep them all
    t, T = _utm_track()
    path = tmp_path / f"poses.{'json' if fmt == 'json' else 'txt'}"
    write_poses(path, t, T, fmt)
    back = read_poses(path, fmt)
    np.testing.assert_array_equal(back.T[:, :3, 3], T[:, :3, 3])
    assert np.abs(back.T[:, :3, :3] - T[:, :3, :3]).max() < 1e-15
    if fmt == "kitti":
        np.testing.assert_array_equal(back.t, np.arange(t.size))
    elif fmt == "euroc":   # nanoseconds: the decimal of each time, exactly
        assert back.origin_ns == 1305031098665900000
        ns = np.array([int(Decimal(repr(x)) * 10 ** 9) for x in t.tolist()])
        np.testing.assert_allclose(back.t, (ns - ns[0]) * 1e-9, rtol=0, atol=1e-15)
    else:
        np.testing.assert_array_equal(back.t, t)
    # a second round trip writes the same file (times and positions; rotations to 1e-15)
    write_poses(tmp_path / "again", back.t, back.T, fmt, origin_ns=back.origin_ns)
    again = read_poses(tmp_path / "again", fmt)
    np.testing.assert_array_equal(again.t, back.t)
    np.testing.assert_array_equal(again.T[:, :3, 3], back.T[:, :3, 3])


def _euroc(path, ns, T):
    from shellspline.groups import so3

    q = so3.quat_from_matrix(T[:, :3, :3])
    rows = ["#timestamp [ns],p_RS_R_x [m],p_RS_R_y [m],p_RS_R_z [m],q_RS_w [],q_RS_x [],"
            "q_RS_y [],q_RS_z []"]
    rows += [f"{n},{p[0]!r},{p[1]!r},{p[2]!r},{qq[3]!r},{qq[0]!r},{qq[1]!r},{qq[2]!r}"
             for n, p, qq in zip(ns, T[:, :3, 3].tolist(), q.tolist())]
    path.write_text("\n".join(rows) + "\n")


@pytest.mark.parametrize("fmt", ["tum", "csv", "json"])
def test_euroc_track_written_in_seconds_keeps_its_absolute_times(tmp_path, fmt):
    # EuRoC times are read as seconds since the first stamp (origin_ns); written as TUM, CSV
    # or JSON they were those relative seconds (0.0, 0.005, ...): the clock was lost
    _, T = _utm_track(20)
    ns = 1403636579758555392 + 5_000_000 * np.arange(20, dtype=np.int64) + \
        np.arange(20) % 3  # a jittery nanosecond clock
    _euroc(tmp_path / "data.csv", ns.tolist(), T)
    tr = read_poses(tmp_path / "data.csv")
    assert tr.format == "euroc" and tr.origin_ns == int(ns[0])
    out = tmp_path / f"out.{'json' if fmt == 'json' else 'txt'}"
    write_poses(out, tr.t, tr.T, fmt, origin_ns=tr.origin_ns)
    back = read_poses(out, fmt)
    exact = np.array([float(Decimal(int(n)) / 10 ** 9) for n in ns])
    np.testing.assert_array_equal(back.t, exact)
    if fmt != "json":
        first = out.read_text().splitlines()[1].replace(",", " ").split()[0]
        assert first == "1403636579.758555392"
    # and back to EuRoC: the same nanoseconds, to the float64 of the seconds (< 256 ns)
    write_poses(tmp_path / "e.csv", back.t, back.T, "euroc")
    e = read_poses(tmp_path / "e.csv", "euroc")
    got = e.origin_ns + np.round(e.t * 1e9).astype(np.int64)
    assert np.abs(got - ns).max() < 256


def test_seconds_to_euroc_nanoseconds_are_the_decimal_ones(tmp_path):
    # t * 1e9 in float64 at 1.3e9 s is 32 ns off (1305031098665900032); the file's decimal
    # 1305031098.6659 is 1305031098665900000 ns
    t = np.array([1305031098.6659, 1305031098.6759, 1305031098.7])
    T = np.broadcast_to(np.eye(4), (3, 4, 4))
    write_poses(tmp_path / "e.csv", t, T, "euroc")
    stamps = [ln.split(",")[0] for ln in (tmp_path / "e.csv").read_text().splitlines()[1:]]
    assert stamps == ["1305031098665900000", "1305031098675900000", "1305031098700000000"]


@pytest.mark.parametrize("sep,fmt", [(",", "csv"), (" ", "tum")])
def test_integer_nanosecond_stamps_are_kept_exact_and_read_as_seconds(tmp_path, sep, fmt):
    # ROS tools write integer nanosecond stamps under t,tx,...,qw names (or TUM-like lines):
    # they were float "seconds" of 1.4e18 (256 ns apart in float64), written back as
    # 1.4036365797585554e+18, and --rate 1000 asked for 1000 poses per nanosecond
    ns = [1403636579758555392 + 5_000_000 * i + i for i in range(5)]
    head = "timestamp,tx,ty,tz,qx,qy,qz,qw" if fmt == "csv" else "# t tx ty tz qx qy qz qw"
    rows = [head] + [sep.join([str(n), repr(0.1 * i), "0", "0", "0", "0", "0", "1"])
                     for i, n in enumerate(ns)]
    src = tmp_path / f"ros.{'csv' if fmt == 'csv' else 'txt'}"
    src.write_text("\n".join(rows) + "\n")
    tr = read_poses(src)
    assert (tr.format, tr.time_unit, tr.origin_ns) == (fmt, "ns", ns[0])
    np.testing.assert_allclose(tr.t, (np.array(ns) - ns[0]) * 1e-9, rtol=0, atol=1e-15)
    write_poses(tmp_path / "back", tr.t, tr.T, fmt, origin_ns=tr.origin_ns,
                time_unit=tr.time_unit)
    lines = (tmp_path / "back").read_text().splitlines()[1:]
    assert [int(ln.replace(",", " ").split()[0]) for ln in lines] == ns
    from shellspline.cli.main import main

    out = tmp_path / f"r.{'csv' if fmt == 'csv' else 'txt'}"
    assert main(["path", str(src), "-o", str(out), "--rate", "1000", "-q"]) == 0
    stamps = [int(ln.replace(",", " ").split()[0]) for ln in out.read_text().splitlines()[1:]]
    assert stamps == [ns[0] + 1_000_000 * k for k in range(21)]   # 20 ms at 1 kHz
    # a later stamp that is not an integer is refused in one line
    bad = tmp_path / "bad.txt"
    bad.write_text(rows[0] + "\n" + rows[1] + "\n" + rows[2].replace(str(ns[1]), "1.5", 1)
                   + "\n")
    from shellspline.errors import ShellsplineError

    with pytest.raises(ShellsplineError, match="bad.txt:3: the first time stamps are integer"):
        read_poses(bad)

"""``shellspline path``: smooth camera / rigid-body paths through keyframe poses.

Reads a pose file (TUM, KITTI, EuRoC, our CSV/JSON), keeps every N-th pose as a keyframe
(first and last always), builds a curve of the chosen kind on SE(3) or SO(3) x R^3 through
(or, for B-splines, controlled by) the keyframes, and writes poses at the input times (or at a
rate, or at times from a file) in the input's format or another one; optionally a plot.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from ..errors import ShellsplineError
from ..io.atomic import write_atomically
from .outputs import PICTURES, Output, check_outputs

EXIT_OK, EXIT_WARN = 0, 1
# Most poses --rate may ask for: 10 million poses are ~1.3 GB of matrices and a 1.5 GB
# text file; a rate given per millisecond or in the wrong unit asked for billions (and the
# machine's memory) before.
MAX_OUTPUT_POSES = 10_000_000

_EPILOG = """examples:
  shellspline path groundtruth.txt -o smooth.txt --keep-every 10
  shellspline path poses.csv -o out.csv --rate 200 --group se3 --plot path.png
  shellspline path kitti_00.txt -o resampled.txt --kind bspline --times times.txt

kinds: interp  C2 cubic spline through the keyframes (--bc natural|clamped|periodic;
               clamped = zero velocity at both ends, periodic needs first == last pose)
       bezier  C1 piecewise-cubic Bezier through the keyframes, Catmull-Rom velocities (local)
       bspline cubic geodesic B-spline with the keyframes as control points (smooths; passes
               through the first and last keyframe only)
groups: so3xr3 (default: rotation and position interpolated separately; on the TUM camera
        ground truth its errors equal or beat scipy's, see benchmarks/README.md) or se3
        (screw motions: the curve does not depend on where the body frame sits)"""


def add_parsers(sub) -> None:
    """Register ``shellspline path`` on the ``shellspline`` subparsers."""
    p = sub.add_parser("path", help="smooth camera/rigid-body paths through keyframe poses",
                       description="Interpolate or smooth a trajectory on SE(3) or SO(3)xR^3 "
                                   "through keyframe poses and resample it.",
                       epilog=_EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("poses", metavar="POSES",
                   help="pose file: TUM (t tx ty tz qx qy qz qw), KITTI (3x4 rows), EuRoC CSV, "
                        "or ours (.csv with header t,tx,ty,tz,qx,qy,qz,qw / .json)")
    p.add_argument("-o", "--out", required=True, metavar="OUT", help="pose file to write")
    p.add_argument("--format", choices=["tum", "kitti", "euroc", "csv", "json"],
                   help="format of OUT (default: the input's)")
    p.add_argument("--keep-every", type=int, default=1, metavar="N",
                   help="keyframes are every N-th input pose, first and last always (default 1)")
    p.add_argument("--kind", choices=["interp", "bezier", "bspline"], default="interp",
                   help="curve kind (default interp)")
    p.add_argument("--group", choices=["se3", "so3xr3"], default="so3xr3",
                   help="metric on poses: so3xr3 (default; rotation and position separately) or "
                        "se3 (screw motions)")
    p.add_argument("--bc", choices=["natural", "clamped", "periodic"], default="natural",
                   help="end conditions of --kind interp (default natural)")
    when = p.add_mutually_exclusive_group()
    when.add_argument("--rate", type=float, metavar="HZ",
                      help="output poses at this rate from the first to the last keyframe time "
                           "(KITTI: poses per index step)")
    when.add_argument("--times", metavar="FILE",
                      help="output poses at these times: the first field of every line "
                           "('#' comments; a TUM or EuRoC file gives its timestamps), in the "
                           "input's unit (seconds; EuRoC and integer stamps of 13 digits or "
                           "more: nanoseconds; KITTI: pose index)")
    p.add_argument("--plot", metavar="PNG",
                   help="plot positions, rotation angles and angular rate (needs matplotlib: "
                        "pip install 'shellspline[viz]')")
    p.add_argument("--overwrite", action="store_true",
                   help="replace OUT (and the --plot picture) when they exist")
    p.add_argument("-q", "--quiet", action="store_true", help="print nothing")
    p.set_defaults(func=_path)


# Keyframe intervals in which a pose is turned this much from the interval's first pose get
# more keyframes: the curve between two keyframes turns the short way (the principal
# logarithm), so where the dropped poses turn 180 degrees or more it went backwards (a
# camera spinning 20 degrees per pose, every 10th kept: angle errors up to 180 degrees,
# exit 0). The angle is measured along the path: the path lifted to unit quaternions
# (sign-continuous from pose to pose) and the angle of a pose's lift from the first one's,
# 0 to 360 degrees, which goes on past 180 where the path does (the principal angle turns
# back: poses at 0, 119, 250 and 300 degrees, every 2nd kept, had no pose 120 degrees from
# its interval's start, 250 being 110 the short way, and came out at 0, -81, -110, -60).
# It is the pose's turn from the start, not the sum of the steps' angles, so the noise of a
# jittery track does not add up to a turn. The extra keyframes are the poses where the
# path's turn since the interval's start (the sum of its steps' angles) passes a multiple
# of KEY_TURN / 2; an interval still turned KEY_TURN or more after that (its last step is
# longer than KEY_TURN / 2) keeps all its poses. Then in every interval that drops poses,
# each pose is less than KEY_TURN from its start along the path, so the path never passes
# 180 degrees from it and the short way between the keyframes is the way the poses went.
KEY_TURN = 2 * np.pi / 3


def keyframe_indices(n: int, every: int, R=None) -> np.ndarray:
    """Every ``every``-th index of ``range(n)``, always with the first and the last.

    With the rotations ``R (n, 3, 3)`` of the poses, an interval between two such indices
    in which a pose is turned by ``KEY_TURN`` or more from its first pose, measured along
    the path (past 180 degrees where the path goes on turning), also gets the poses where
    the turn of the path since its start passes a multiple of ``KEY_TURN / 2``, and all its
    poses if that leaves a part turned ``KEY_TURN`` or more (see ``KEY_TURN``).
    """
    idx = np.arange(0, n, every)
    idx = idx if idx[-1] == n - 1 else np.append(idx, n - 1)
    if R is None or idx.size == n:
        return idx
    from ..groups import so3

    R = np.asarray(R, dtype=np.float64)
    C = np.concatenate([[0.0], np.cumsum(so3.angle(np.swapaxes(R[:-1], -1, -2) @ R[1:]))])
    q = so3.quat_continuous(so3.quat_from_matrix(R))        # the path lifted to S^3

    def turned(keys):
        """Interval of every pose, and per interval the largest angle (0 to 2 pi) of a pose's
        lift from the lift of the interval's first pose, its last pose included."""
        k = np.minimum(np.searchsorted(keys, np.arange(n), side="right") - 1, keys.size - 2)
        far = 2.0 * np.arccos(np.clip(np.einsum("ij,ij->i", q[keys[k]], q), -1.0, 1.0))
        end = 2.0 * np.arccos(np.clip(np.einsum("ij,ij->i", q[keys[:-1]], q[keys[1:]]),
                                      -1.0, 1.0))
        return k, np.maximum(np.maximum.reduceat(far, keys[:-1]), end)

    k, turn = turned(idx)
    level = np.floor((C - C[idx[k]]) / (0.5 * KEY_TURN))
    cross = np.flatnonzero((level[1:] > level[:-1]) & (k[1:] == k[:-1])) + 1
    keys = np.union1d(idx, cross[turn[k[cross]] >= KEY_TURN])
    if np.any(turn >= KEY_TURN):  # a part that still ends with a long step: all its poses
        _, turn = turned(keys)
        bad = np.flatnonzero((turn >= KEY_TURN) & (np.diff(keys) > 1))
        if bad.size:
            keys = np.union1d(keys, np.concatenate([np.arange(keys[b] + 1, keys[b + 1])
                                                    for b in bad]))
    return keys


def _read_times(path, nanoseconds=False):
    """Times from a text file: the first field of every line (``#`` comments; fields split
    at whitespace or commas, so a TUM or EuRoC file gives its timestamps; a first line of
    column names is skipped); with ``nanoseconds`` integers kept exact (EuRoC timestamps
    exceed float64's 16 digits), also written with a fraction of zeros."""
    import re

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such times file")
    vals = []
    for k, raw in enumerate(path.read_text(encoding="utf-8-sig").splitlines(), start=1):
        s = raw.strip()
        if not s or s.startswith("#"):
            continue
        fields = re.split(r"[,\s]+", s)
        tok = fields[0]
        if nanoseconds and re.fullmatch(r"-?\d+\.0*", tok):
            tok = tok.split(".")[0]  # 1403636580863555584.000000 (ORB-SLAM3 writes 1e9 * t)
        try:
            v = int(tok) if nanoseconds else float(tok)
        except ValueError:
            if not vals and not any(_is_number(x) for x in fields):
                continue  # column names
            what = "an integer nanosecond timestamp" if nanoseconds else "a time"
            raise ShellsplineError(f"{path}:{k}: not {what}: {tok!r}") from None
        if not np.isfinite(v):
            raise ShellsplineError(f"{path}:{k}: non-finite time")
        vals.append(v)
    if not vals:
        raise ShellsplineError(f"{path}: no times in the file")
    t = np.array(vals, dtype=np.int64 if nanoseconds else np.float64)
    if np.any(np.diff(t) < 0):
        raise ShellsplineError(f"{path}: times must not decrease")
    return t


def _is_number(x: str) -> bool:
    try:
        float(x)
    except ValueError:
        return False
    return True


def build_curve(t, T, kind="interp", group="so3xr3", bc="natural"):
    """The curve ``shellspline path`` uses through keyframe poses ``T (n, 4, 4)`` at times
    ``t (n,)``; returns an object evaluated as ``curve(times) -> (m, 4, 4)`` with a ``solve``
    record for ``interp``."""
    from ..curves import BSpline, clamped_knots, cubic_spline, hermite_spline
    from ..groups import group as _group

    G = _group(group)
    _check_kind(kind, bc)
    if kind == "interp":
        return cubic_spline(G, t, T, bc)
    if kind == "bezier":
        return hermite_spline(G, t, T)
    turn = half_turn(G, T)  # de Boor's geodesics need them as interp's and bezier's do
    if turn is not None:
        i, deg = turn
        raise ShellsplineError(f"T: poses {i} and {i + 1} differ by a rotation of {deg:.1f} "
                               "degrees; consecutive poses must be less than 180 degrees "
                               "apart (insert intermediate poses)")
    m = min(3, t.size - 1)
    return BSpline(G, T, clamped_knots(t, m), m)


def _check_kind(kind, bc) -> None:
    if kind not in ("interp", "bezier", "bspline"):
        raise ShellsplineError(f"kind must be interp, bezier or bspline, got {kind!r}")
    if kind != "interp" and bc != "natural":
        raise ShellsplineError(f"--bc {bc} applies to --kind interp only")


# Consecutive keyframes turned this close to 180 degrees apart have no shortest geodesic
# between them (the curves' own check, curves.interp, uses the same bound).
HALF_TURN_TOL = 1e-6


def half_turn(G, T):
    """``(i, degrees)`` for the first ``i`` where the poses ``T[i]`` and ``T[i + 1]`` (``(n, 4,
    4)``) are turned 180 degrees apart (to :data:`HALF_TURN_TOL`), or None. ``G`` is the
    curve's group (its rotation angle decides, as in the curves' own check)."""
    from ..groups import group as _group

    G = _group(G)
    T = np.asarray(T, dtype=np.float64)
    if T.shape[0] < 2:
        return None
    ang = G.rotation_angle(G.log(G.compose(G.inverse(T[:-1]), T[1:])))
    bad = np.flatnonzero(ang > np.pi - HALF_TURN_TOL)
    return (int(bad[0]), float(np.degrees(ang[bad[0]]))) if bad.size else None


def _pose_names(track, idx) -> str:
    """The poses ``idx`` of ``track`` as its file shows them: lines, and times in the file's
    unit (``lines 4 and 5 (t = 1.2 and 1.3)``; KITTI: lines only, its time is the index)."""
    idx = [int(i) for i in idx]
    both = " and ".join
    where = (f"lines {both(str(int(track.lines[i])) for i in idx)}"
             if track.lines is not None else f"poses {both(str(i) for i in idx)}")
    if track.format == "kitti":
        return where
    if track.time_unit == "ns":
        times = [str(track.origin_ns + int(round(float(track.t[i]) * 1e9))) for i in idx]
    else:
        times = [repr(float(track.t[i])) for i in idx]
    return f"{where} (t = {both(times)})"


def _check_outputs(args) -> None:
    """Fail before any work on an output that is one of the inputs (never overwritten), that
    is the other output, exists without ``--overwrite``, whose folder is missing, or a
    picture of an unknown type (:func:`shellspline.cli.outputs.check_outputs`)."""
    check_outputs([Output("-o", args.out), Output("--plot", args.plot, PICTURES)],
                  [args.poses, args.times], overwrite=args.overwrite)


def _path(args) -> int:
    from ..groups import so3
    from ..io.posefiles import read_poses, write_poses

    out = sys.stderr
    say = (lambda s: None) if args.quiet else (lambda s: print(s, file=out))
    if args.keep_every < 1:
        raise ShellsplineError(f"--keep-every must be >= 1, got {args.keep_every}")
    if args.rate is not None and not args.rate > 0:
        raise ShellsplineError(f"--rate must be > 0, got {args.rate}")
    _check_kind(args.kind, args.bc)
    _check_outputs(args)
    if args.plot:  # fail before any work when the picture cannot be drawn
        import importlib.util

        if importlib.util.find_spec("matplotlib") is None:
            raise ShellsplineError("--plot needs matplotlib: pip install 'shellspline[viz]'")
    track = read_poses(args.poses)
    n = track.t.size
    if n < 2:
        raise ShellsplineError(f"{args.poses}: a path needs at least 2 poses, got {n}")
    keys = keyframe_indices(n, args.keep_every, track.T[:, :3, :3])
    added = keys.size - keyframe_indices(n, args.keep_every).size
    tk, Tk = track.t[keys], track.T[keys]
    turn = half_turn(args.group, Tk)
    if turn is not None:
        i, deg = turn
        raise ShellsplineError(
            f"{args.poses}: the keyframes at {_pose_names(track, keys[i:i + 2])} differ by a "
            f"rotation of {deg:.1f} degrees; consecutive keyframes must be less than 180 "
            "degrees apart (insert intermediate poses)")
    try:
        curve = build_curve(tk, Tk, args.kind, args.group, args.bc)
    except ShellsplineError as exc:  # what the keyframes cannot give (--bc periodic ...)
        raise ShellsplineError(f"{args.poses}: {exc}") from None
    if args.rate is not None:
        m = np.floor((tk[-1] - tk[0]) * args.rate + 1e-9) + 1
        if not m <= MAX_OUTPUT_POSES:
            raise ShellsplineError(
                f"--rate {args.rate:g} over the span {tk[-1] - tk[0]:.6g} of {args.poses} "
                f"gives {m:.6g} poses; at most {MAX_OUTPUT_POSES:,} (--rate is poses per second;"
                " KITTI: per pose index)")
        tq = tk[0] + np.arange(int(m)) / args.rate
    elif args.times is not None:
        if track.time_unit == "ns":  # the file's unit: integer nanoseconds (EuRoC, ROS)
            tq = (_read_times(args.times, nanoseconds=True) - track.origin_ns) * 1e-9
        else:
            tq = _read_times(args.times)
        lo, hi = tk[0], tk[-1]
        if tq[0] < lo - 1e-9 or tq[-1] > hi + 1e-9:
            def shown(x):  # in the file's unit (1.3e9 s printed as 1.30503110e+09 before)
                if track.time_unit == "ns":
                    return str(track.origin_ns + int(round(float(x) * 1e9)))
                return repr(float(x))
            raise ShellsplineError(f"{args.times}: times must lie in [{shown(lo)}, {shown(hi)}] "
                                   f"(the keyframes), got {shown(tq[0])}..{shown(tq[-1])}")
    else:
        tq = track.t
    Tq = curve(tq)
    fmt = args.format or track.format
    write_poses(args.out, tq, Tq, fmt, origin_ns=track.origin_ns,
                time_unit=track.time_unit if fmt == track.format else "s")
    solve = getattr(curve, "solve", None)
    say(f"  path        {n} poses, {keys.size} keyframes"
        + (f" ({added} added where the poses turn {np.degrees(KEY_TURN):.0f}° or more "
           "between keyframes)" if added else "")
        + f", {args.kind} on {args.group}"
        + (f" ({args.bc})" if args.kind == "interp" else "")
        + (f", {solve.message}" if solve is not None and solve.message else ""))
    if tq is track.t and keys.size < n:
        rest = np.setdiff1d(np.arange(n), keys)
        dp = np.linalg.norm(Tq[rest, :3, 3] - track.T[rest, :3, 3], axis=1)
        da = np.degrees(so3.angle(np.swapaxes(Tq[rest, :3, :3], -1, -2) @ track.T[rest, :3, :3]))
        say(f"  in-between  {rest.size} poses: position rms {np.sqrt(np.mean(dp ** 2)):.3g} "
            f"max {dp.max():.3g}; angle rms {np.sqrt(np.mean(da ** 2)):.3g} max "
            f"{da.max():.3g} deg")
    say(f"  wrote       {args.out} ({tq.size} poses, {fmt})")
    if args.plot:
        _plot(args.plot, curve, tq, Tq, tk, Tk, args.group)
        say(f"  plot        {args.plot}")
    if solve is not None and not solve.success:
        say(f"  warning: {solve.message}")
        return EXIT_WARN
    return EXIT_OK


def _plot(png, curve, tq, Tq, tk, Tk, group):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ..groups import so3

    R0t = Tq[0, :3, :3].T
    rv = so3.log(R0t @ Tq[:, :3, :3])
    rvk = so3.log(R0t @ Tk[:, :3, :3])
    if hasattr(curve, "velocity"):
        rate = np.linalg.norm(curve.velocity(tq)[:, :3], axis=1)
    else:  # B-spline: central differences of the points
        h = 1e-4 * (tq[-1] - tq[0])
        tt = np.clip(tq, tq[0] + h, tq[-1] - h)
        rate = np.linalg.norm(so3.log(np.swapaxes(curve(tt - h)[:, :3, :3], -1, -2)
                                      @ curve(tt + h)[:, :3, :3]), axis=1) / (2 * h)
    fig, ax = plt.subplots(3, 1, figsize=(8, 8), sharex=True)
    t0 = tq[0]
    x, xk = tq - t0, tk - t0
    ms = 4 if len(tk) <= 60 else 2
    for i, c in enumerate("xyz"):
        ax[0].plot(x, Tq[:, i, 3], label=c)
        ax[0].plot(xk, Tk[:, i, 3], "k.", ms=ms)
        ax[1].plot(x, np.degrees(rv[:, i]), label=c)
        ax[1].plot(xk, np.degrees(rvk[:, i]), "k.", ms=ms)
    ax[0].set_ylabel("position")
    ax[1].set_ylabel("rotation from start (deg,\nrotation vector)")
    ax[2].plot(x, np.degrees(rate))
    ax[2].set_ylabel("angular rate (deg/s)")
    ax[2].set_xlabel(f"t - {t0:.6g}")
    ax[0].legend(loc="best", fontsize=8)
    ax[0].set_title(f"{len(tk)} keyframes (dots), {group}")
    fig.tight_layout()
    try:
        write_atomically(png, lambda tmp: fig.savefig(tmp, dpi=100))
    finally:
        plt.close(fig)

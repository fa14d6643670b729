"""Pose files: camera and rigid-body trajectories in the formats users bring.

=========  =====================================================================================
format     content
=========  =====================================================================================
``tum``    ``timestamp tx ty tz qx qy qz qw`` per line (seconds; quaternion scalar last), ``#``
           comments (TUM RGB-D benchmark)
``kitti``  12 numbers per line: the 3x4 matrix ``[R | t]`` row by row; no times (the pose
           index is the time)
``euroc``  CSV ``#timestamp [ns], p_x, p_y, p_z, q_w, q_x, q_y, q_z[, more columns]``
           (nanoseconds; quaternion scalar first; extra columns are ignored)
``csv``    ours: header ``t,tx,ty,tz,qx,qy,qz,qw`` (seconds; quaternion scalar last)
``json``   ours: ``{"format": "shellspline-poses", "version": 1, "t": [...], "position":
           [[x, y, z], ...], "quaternion_xyzw": [[x, y, z, w], ...]}``
=========  =====================================================================================

Poses are ``(n, 4, 4)`` rigid motions body -> world. Reading validates once (finite numbers,
unit quaternions within 1e-2 — then normalised; files written with 2 or 3 digits are not
exactly unit —, rotation blocks within 1e-3 of orthonormal — then projected —, strictly
increasing times, the format's count of numbers on every line: EuRoC's further columns are
ignored, a missing or an extra number elsewhere is refused) and raises a one-line
:class:`~shellspline.errors.ShellsplineError` naming the file and line. What real exporters
add is accepted: a UTF-8 byte-order mark, CRLF, tabs, a header line without ``#`` (a first
data line with no number on it, e.g. ``timestamp tx ty ...``), a trailing comma in a CSV
line, and a line repeated verbatim right after itself (the same time and pose: dropped).
Column names above the data, when they name the quaternion (``qx ... qw``, ``q_RS_w []``),
are checked against the detected format: integer nanoseconds under scalar-last names are
ours (``csv``), not EuRoC, even under a header that starts as EuRoC's (``#timestamp [ns],``);
a scalar-first header over TUM-like data is refused (every quaternion would still be a unit
one, read wrong). Integer time stamps of 13 digits or more (nanoseconds: EuRoC, and TUM or
CSV files from ROS tools; also with a fraction of zeros, as ORB-SLAM3 writes ``1e9 * t``)
are kept exact: ``t`` is seconds since ``origin_ns`` and ``time_unit`` is ``"ns"``, so they
are written back as the same integers. COLMAP ``images.txt`` is recognised and refused with
a message (not supported). Writing is atomic (a temporary file in the target folder, then a
rename), makes quaternion signs continuous, and first refuses what the reader would refuse
(non-finite numbers, rotation blocks that are not rotations).
Layer rule: numpy, :mod:`shellspline.groups`, :mod:`shellspline.errors` and
:mod:`shellspline.io.atomic` only.
"""
from __future__ import annotations

import json
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import ShellsplineError
from ..groups import se3, so3
from .atomic import write_text_atomic

__all__ = ["PoseTrack", "FORMATS", "detect_format", "read_poses", "write_poses",
           "write_text_atomic"]  # write_text_atomic: :mod:`shellspline.io.atomic`'s, re-exported

FORMATS = ("tum", "kitti", "euroc", "csv", "json")
_EUROC_HEADER = ("#timestamp [ns],p_RS_R_x [m],p_RS_R_y [m],p_RS_R_z [m],q_RS_w [],q_RS_x [],"
                 "q_RS_y [],q_RS_z []")


@dataclass
class PoseTrack:
    """A timed sequence of poses read from (or to be written to) a file.

    Attributes
    ----------
    t : (n,) ndarray
        Times in seconds (KITTI: the pose index; with integer nanosecond stamps: seconds
        since ``origin_ns``).
    T : (n, 4, 4) ndarray
        Rigid motions body -> world.
    format : str
        One of :data:`FORMATS`.
    origin_ns : int
        The integer nanosecond timestamp of ``t == 0`` (keeps nanosecond timestamps exact
        through float seconds); 0 when the file's times are seconds.
    time_unit : str
        The unit of the file's time stamps: ``"ns"`` (EuRoC; TUM or CSV files whose stamps
        are integers of 13 digits or more, as ROS tools write them) or ``"s"``.
    lines : (n,) int ndarray or None
        The file line (from 1) of each pose, for messages that name a pose; None when the
        poses were not read from a text file of lines (JSON, or made in memory).
    """

    t: np.ndarray
    T: np.ndarray
    format: str
    origin_ns: int = 0
    time_unit: str = "s"
    lines: np.ndarray | None = field(default=None, repr=False, compare=False)


def _fail(path, line, msg):
    where = f"{path}:{line}" if line else f"{path}"
    raise ShellsplineError(f"{where}: {msg}")


def _text(path) -> str:
    """The file's text: UTF-8 (a byte-order mark skipped), else Windows-1252 (comments with
    accents from older tools); binary data is refused."""
    data = Path(path).read_bytes()
    if b"\0" in data:
        _fail(path, 0, "not a text pose file (binary data)")
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError:
        return data.decode("cp1252", errors="replace")


def _data_lines(text, comment="#"):
    for k, raw in enumerate(text.splitlines(), start=1):
        s = raw.strip()
        if s and not s.startswith(comment):
            yield k, s


def detect_format(path) -> str:
    """The format of a pose file from its name and first data line (see the module table).

    Raises
    ------
    ShellsplineError
        When the content matches none of the formats (names the file and line).
    """
    path = Path(path)
    if path.suffix.lower() == ".json":
        return "json"
    head = [ln.strip() for ln in _text(path).splitlines()[:200]]
    header = None  # the last comment or column-names line before the data
    for k, s in enumerate(head, start=1):
        if not s:
            continue
        low = s.lower()
        if "image list with two lines of data per image" in low:
            _fail(path, k, "COLMAP images.txt is not supported (convert it to TUM: camera "
                           "centre -R^T t and the inverse rotation, with a time per image)")
        if "," in s and (low.startswith("#timestamp") or "p_rs_r" in low):
            return _agree_with_header(path, (k, s), "euroc")  # '#timestamp,...,qx,qy,qz,qw'
        if low.replace(" ", "").startswith("t,tx,ty,tz"):
            return "csv"
        if s.startswith("#") or _is_header(s.replace(",", " ").split()):
            header = (k, s)  # a comment, or column names without '#'
            continue
        if "," in s:
            first = s.split(",")[0].strip()
            fmt = "euroc" if first.isdigit() and len(first) >= 13 else "csv"
        else:
            n = len(s.split())
            if n not in (8, 12):
                _fail(path, k, f"cannot tell the pose format: {n} numbers on a line (TUM has "
                               "8, KITTI 12; EuRoC and ours are CSV)")
            fmt = "tum" if n == 8 else "kitti"
        return _agree_with_header(path, header, fmt)
    _fail(path, 0, "no poses in the file")


def _scalar_first(names) -> bool | None:
    """Whether column names put the quaternion's scalar before its x (``qw qx qy qz``,
    ``q_RS_w []``: True; ``qx qy qz qw``: False), or None when they do not name both."""
    keys = [re.sub(r"\[.*?\]|[^a-z0-9]", "", x.lower()) for x in names]
    w = next((i for i, x in enumerate(keys) if x[:1] == "q" and x[-1:] == "w"), None)
    x = next((i for i, x in enumerate(keys) if x[:1] == "q" and x[-1:] == "x"), None)
    return None if w is None or x is None else w < x


def _agree_with_header(path, header, fmt):
    """The format detected from the data, checked against the column names above it: a
    header that puts the quaternion's scalar elsewhere than the format would be read
    silently wrong (every quaternion is still a unit one)."""
    if header is None or fmt == "kitti":
        return fmt
    k, s = header
    first = _scalar_first(re.split(r"[,\s]+", s.lstrip("#").strip()))
    if first is None or first == (fmt == "euroc"):
        return fmt
    if fmt == "euroc":  # integer nanoseconds, quaternion scalar last: ours, in the file's unit
        return "csv"
    order = "first (w x y z)" if first else "last (x y z w)"
    need = ("TUM has it last (qx qy qz qw)" if fmt == "tum" else
            "ours has it last; EuRoC has it first with integer nanosecond timestamps")
    _fail(path, k, f"the column names put the quaternion scalar {order}; {need}")


def _numbers(path, k, fields, n, what):
    if len(fields) < n:
        _fail(path, k, f"expected {n} numbers ({what}), got {len(fields)}")
    try:
        return [float(x) for x in fields[:n]]
    except ValueError:
        bad = next(x for x in fields[:n] if not _is_float(x))
        _fail(path, k, f"not a number: {bad!r} (expected {what})")


def _is_float(x):
    try:
        float(x)
        return True
    except ValueError:
        return False


def _is_header(fields):
    """A line of column names: no field is a number (``timestamp tx ty ...``)."""
    return bool(fields) and not any(_is_float(x) for x in fields)


def _quats(path, lines, q):
    """Unit quaternions ``(n, 4)`` from file values, normalised; one-line error at the first
    that is not within 1e-2 of unit norm (a quaternion written with 2 digits is within 1e-2;
    a norm farther from 1 means the columns are not what the format says)."""
    nq = np.linalg.norm(q, axis=1)
    bad = np.abs(nq - 1) > 1e-2
    if np.any(bad):
        i = int(np.argmax(bad))
        _fail(path, lines[i], f"quaternion norm {nq[i]:.6g} is not 1 (within 1e-2)")
    return q / nq[:, None]


def _check_times(path, t, lines, tns=None):
    """Strictly increasing times; the error names the line and the two stamps as the file
    has them (``tns``: its integer nanoseconds, else the seconds ``t``)."""
    d = np.diff(t)
    if np.any(d <= 0):
        i = int(np.argmax(d <= 0))
        a, b = (tns[i], tns[i + 1]) if tns else (repr(float(t[i])), repr(float(t[i + 1])))
        _fail(path, lines[i + 1], f"times must increase strictly, got {b} after {a}")


_LAYOUT = {"tum": (8, "t tx ty tz qx qy qz qw"), "kitti": (12, "a 3x4 matrix row by row"),
           "csv": (8, "t tx ty tz qx qy qz qw"), "euroc": (8, "timestamp px py pz qw qx qy qz")}


def read_poses(path, format=None) -> PoseTrack:
    """Read a pose file.

    Parameters
    ----------
    path : str or Path
    format : str, optional
        One of :data:`FORMATS`; default :func:`detect_format`.

    Returns
    -------
    PoseTrack

    Raises
    ------
    ShellsplineError
        One line naming the file and line: wrong count of numbers, a non-number, a quaternion
        or rotation that is not one, times that do not increase, an empty file.
    FileNotFoundError
        When ``path`` does not exist.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such pose file")
    fmt = detect_format(path) if format is None else str(format).lower()
    if fmt not in FORMATS:
        raise ShellsplineError(f"format must be one of {', '.join(FORMATS)}, got {format!r}")
    text = _text(path)
    if fmt == "json":
        t, T, lines = _read_json(path, text)
        _check_times(path, t, lines)
        return PoseTrack(t, T, fmt)
    n, what = _LAYOUT[fmt]
    rows, lines, tns = [], [], []
    for k, s in _data_lines(text):
        if fmt in ("tum", "kitti"):
            f = s.split()
        else:
            f = [x.strip() for x in s.split(",")]
        if not rows and _is_header(f):
            continue  # column names without '#' (ours: t,tx,ty,...)
        if fmt == "euroc":
            if not f[0].lstrip("-").isdigit():
                _fail(path, k, f"EuRoC timestamps are integer nanoseconds, got {f[0]!r}")
            tns.append(int(f[0]))
        elif fmt != "kitti" and (tns or not rows) and _is_nanoseconds(f[0]):
            tns.append(int(f[0].split(".")[0]))  # nanosecond stamps (ROS, ORB-SLAM3): exact
        elif tns:
            _fail(path, k, f"the first time stamps are integer nanoseconds, this one is "
                           f"{f[0]!r}")
        if fmt == "csv":
            while len(f) > n and not f[-1]:
                f = f[:-1]  # a trailing comma: no column
        if len(f) > n and fmt != "euroc":  # (EuRoC's further columns are documented: ignored)
            _fail(path, k, f"expected {n} numbers ({what}), got {len(f)}")
        rows.append(_numbers(path, k, f, n, what))
        lines.append(k)
    if not rows:
        _fail(path, 0, "no poses in the file")
    V = np.array(rows, dtype=np.float64)
    if len(rows) > 1 and fmt != "kitti":  # a line repeated right after itself: dropped
        # (KITTI has no times: a repeated pose is a frame where the camera stood still)
        keep = np.ones(len(rows), dtype=bool)
        keep[1:] = np.any(V[1:] != V[:-1], axis=1)
        if tns:
            keep[1:] |= np.diff(np.array(tns, dtype=np.int64)) != 0
        if not keep.all():
            V, lines = V[keep], [ln for ln, kp in zip(lines, keep) if kp]
            tns = [x for x, kp in zip(tns, keep) if kp]
    finite = np.all(np.isfinite(V), axis=1)
    if not np.all(finite):
        _fail(path, lines[int(np.argmin(finite))], f"non-finite number (expected {what})")
    origin, unit = 0, "s"
    if fmt == "kitti":
        M = V.reshape(-1, 3, 4)
        t = np.arange(len(rows), dtype=np.float64)
        R, p = _rotations(path, lines, M[:, :, :3]), M[:, :, 3]
    else:
        if tns:
            origin, unit = tns[0], "ns"
            t = (np.array(tns, dtype=np.int64) - origin).astype(np.float64) * 1e-9
        else:
            t = V[:, 0]
        q = V[:, [5, 6, 7, 4]] if fmt == "euroc" else V[:, 4:8]
        R, p = so3.matrix_from_quat(_quats(path, lines, q)), V[:, 1:4]
    _check_times(path, t, lines, tns)
    return PoseTrack(t, se3.from_rt(R, p), fmt, origin, unit, np.array(lines, dtype=np.int64))


def _is_nanoseconds(x: str) -> bool:
    """An integer time stamp of 13 digits or more: nanoseconds since an epoch (seconds
    since 1970 have 10 digits; EuRoC's format detection uses the same length), also with a
    fraction of zeros (``1403636580863555584.000000``: ORB-SLAM3 writes ``1e9 * t`` so)."""
    return re.fullmatch(r"-?\d{13,}(\.0*)?", x) is not None


def _rotations(path, lines, M):
    """Rotation blocks ``(n, 3, 3)`` projected onto SO(3) (SVD); one-line error at the first
    that is more than 1e-3 from orthonormal or reflects."""
    err = np.abs(M @ np.swapaxes(M, -1, -2) - np.eye(3)).max(axis=(1, 2))
    det = np.linalg.det(M)
    bad = (err > 1e-3) | (det < 0)
    if np.any(bad):
        i = int(np.argmax(bad))
        _fail(path, lines[i], f"the 3x3 block is not a rotation (|R R^T - I| = {err[i]:.2g}, "
                              f"det = {det[i]:.3g})")
    U, _, Vt = np.linalg.svd(M)
    return U @ Vt


def _read_json(path, text):
    try:
        d = json.loads(text)
    except json.JSONDecodeError as exc:
        _fail(path, exc.lineno, f"invalid JSON: {exc.msg}")
    if isinstance(d, dict) and isinstance(d.get("frames"), list) and \
            any(isinstance(f, dict) and "transform_matrix" in f for f in d["frames"]):
        _fail(path, 0, "a NeRF/instant-ngp transforms.json is not supported (camera-to-world "
                       "OpenGL matrices without times: convert it to TUM or our JSON)")
    if not isinstance(d, dict) or not {"t", "position", "quaternion_xyzw"} <= set(d):
        _fail(path, 0, "JSON poses need the keys t, position, quaternion_xyzw")
    try:
        t = np.asarray(d["t"], dtype=np.float64)
        p = np.asarray(d["position"], dtype=np.float64)
        q = np.asarray(d["quaternion_xyzw"], dtype=np.float64)
    except (TypeError, ValueError):
        _fail(path, 0, "t, position and quaternion_xyzw must be numbers")
    n = t.shape[0] if t.ndim == 1 else -1
    if n < 1 or p.shape != (n, 3) or q.shape != (n, 4):
        _fail(path, 0, f"expected t (n,), position (n, 3), quaternion_xyzw (n, 4), got "
                       f"{t.shape}, {p.shape}, {q.shape}")
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(p)) and np.all(np.isfinite(q))):
        _fail(path, 0, "non-finite numbers")
    lines = [f"pose {i}" for i in range(n)]
    return t, se3.from_rt(so3.matrix_from_quat(_quats(path, lines, q)), p), lines


def _row(xs, sep=" ") -> str:
    """Numbers in their shortest exact form (``repr``): a pose written and read back is the
    same float64 (``%.12g`` kept 10 micrometres of a UTM coordinate of 5e6 m)."""
    return sep.join(map(repr, xs))


def _time_strings(t, origin_ns: int, fmt: str, unit: str = "s") -> list:
    """Time stamps as written: EuRoC integer nanoseconds, otherwise seconds.

    With ``origin_ns`` (a track read from EuRoC, ``t`` seconds since it) the seconds are the
    exact decimal of ``origin_ns + round(t * 1e9)``, so a EuRoC file written as TUM keeps its
    absolute times to the nanosecond. Without it, ``t`` is absolute seconds; EuRoC then gets
    the nanoseconds of each time's shortest decimal (``1305031098.6659`` ->
    ``1305031098665900000``; ``t * 1e9`` in float64 is 32 ns off there).
    """
    if origin_ns:
        ns = origin_ns + np.round(t * 1e9).astype(np.int64)
        if fmt == "euroc" or unit == "ns":
            return [str(int(n)) for n in ns]
        return [_decimal_seconds(int(n)) for n in ns]
    if fmt == "euroc" or unit == "ns":
        from decimal import ROUND_HALF_EVEN, Decimal

        return [str(int((Decimal(repr(x)) * 1_000_000_000).to_integral_value(ROUND_HALF_EVEN)))
                for x in t.tolist()]
    return [repr(x) for x in t.tolist()]


def _decimal_seconds(ns: int) -> str:
    """``1305031098665900032`` -> ``"1305031098.665900032"`` (trailing zeros dropped)."""
    sign, ns = ("-" if ns < 0 else ""), abs(ns)
    frac = f"{ns % 1_000_000_000:09d}".rstrip("0") or "0"
    return f"{sign}{ns // 1_000_000_000}.{frac}"


def _check_writable(t, T) -> None:
    """Refuse what :func:`read_poses` would refuse in the written file, or read as another
    pose: non-finite times or poses, rotation blocks farther than the reader's 1e-3 from
    orthonormal or reflecting (their quaternion is some other rotation's)."""
    bad_t, bad_T = ~np.isfinite(t), ~np.all(np.isfinite(T), axis=(1, 2))
    if np.any(bad_t) or np.any(bad_T):
        i = int(np.argmax(bad_t | bad_T))
        raise ShellsplineError(f"write_poses: non-finite {'t' if bad_t[i] else 'T'}[{i}]")
    R = T[:, :3, :3]
    err = np.abs(R @ np.swapaxes(R, -1, -2) - np.eye(3)).max(axis=(1, 2))
    det = np.linalg.det(R)
    bad = (err > 1e-3) | (det < 0)
    if np.any(bad):
        i = int(np.argmax(bad))
        raise ShellsplineError(f"write_poses: T[{i}]: the rotation block is not a rotation "
                               f"(|R R^T - I| = {err[i]:.2g}, det = {det[i]:.3g})")


def write_poses(path, t, T, format, *, origin_ns: int = 0, time_unit: str = "s") -> None:
    """Write poses in one of :data:`FORMATS` (atomically).

    Parameters
    ----------
    path : str or Path
    t : (n,) array_like
        Times in seconds (ignored by KITTI): since ``origin_ns`` when it is given, else
        absolute. EuRoC writes ``origin_ns + round(t * 1e9)``; the other formats write the
        seconds of that same instant exactly, so a EuRoC track converted keeps its times.
    T : (n, 4, 4) array_like
        Rigid motions body -> world.
    format : str
    origin_ns : int
        The integer nanosecond time of ``t == 0`` (see :class:`PoseTrack`; 0: ``t`` is
        absolute).
    time_unit : {"s", "ns"}
        TUM and CSV: ``"ns"`` writes integer nanosecond stamps ``origin_ns + round(t *
        1e9)`` (a file read with such stamps is written back with them:
        :attr:`PoseTrack.time_unit`). EuRoC always writes nanoseconds, JSON seconds.

    Raises
    ------
    ShellsplineError
        Before anything is written: wrong shapes, non-finite times or poses, a rotation
        block that the reader would refuse (more than 1e-3 from orthonormal, or a
        reflection).

    Notes
    -----
    Numbers are written in their shortest exact form, so reading a written file gives the
    same times and positions bit for bit and rotations to rounding (1e-16).
    """
    fmt = str(format).lower()
    if fmt not in FORMATS:
        raise ShellsplineError(f"format must be one of {', '.join(FORMATS)}, got {format!r}")
    t = np.asarray(t, dtype=np.float64)
    T = np.asarray(T, dtype=np.float64)
    if T.ndim != 3 or T.shape[1:] != (4, 4) or t.shape != (T.shape[0],):
        raise ShellsplineError(f"write_poses: expected t (n,) and T (n, 4, 4), got {t.shape} and "
                               f"{T.shape}")
    _check_writable(t, T)
    p = T[:, :3, 3]
    q = so3.quat_continuous(so3.quat_from_matrix(T[:, :3, :3]))
    if time_unit not in ("s", "ns"):
        raise ShellsplineError(f"time_unit must be 's' or 'ns', got {time_unit!r}")
    stamps = _time_strings(t, int(origin_ns), fmt, time_unit if fmt != "json" else "s")
    P, Q = p.tolist(), q.tolist()
    out = []
    if fmt == "tum":
        out.append("# timestamp tx ty tz qx qy qz qw")
        out += [f"{ti} {_row(pi)} {_row(qi)}" for ti, pi, qi in zip(stamps, P, Q)]
    elif fmt == "kitti":
        out += [_row(Ti) for Ti in T[:, :3].reshape(-1, 12).tolist()]
    elif fmt == "euroc":
        out.append(_EUROC_HEADER)
        out += [f"{n},{_row(pi, ',')},{qi[3]!r},{_row(qi[:3], ',')}"
                for n, pi, qi in zip(stamps, P, Q)]
    elif fmt == "csv":
        out.append("t,tx,ty,tz,qx,qy,qz,qw")
        out += [f"{ti},{_row(pi, ',')},{_row(qi, ',')}" for ti, pi, qi in zip(stamps, P, Q)]
    else:
        doc = {"format": "shellspline-poses", "version": 1,
               "t": [float(x) for x in stamps], "position": P, "quaternion_xyzw": Q}
        write_text_atomic(path, json.dumps(doc) + "\n")
        return
    write_text_atomic(path, "\n".join(out) + "\n")

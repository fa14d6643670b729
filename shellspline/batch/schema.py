"""The job file's schema: allowed keys, defaults, and the check of one parameter value.

Everything here is about the TOML text; :mod:`shellspline.batch.job` assembles a
:class:`~shellspline.batch.job.Job` from it.
"""
from __future__ import annotations

import math
import numbers
import os
import re
import sys
from pathlib import Path

from ..errors import ShellsplineError
from ..pipeline.options import DEFAULT_SPLINE, DEFAULT_TRANSFER
from .outroot import LOCK_NAME, LOG_NAME, SUMMARY_NAME

__all__ = ["JobError", "job_error", "JOB_KEYS", "PARAM_KEYS", "SOURCE_KEYS", "DEFAULTS",
           "INTERPOLATION_KEYS", "RESERVED_NAMES", "is_int", "is_num", "check_param",
           "check_name", "read_toml", "table", "reject_unknown", "resolve"]

JOB_KEYS = {"name", "output", "executor", "scheduler", "workers"}
#: keys allowed in [defaults] and in every [[sequences]] entry (per-sequence overrides)
PARAM_KEYS = {"frames", "K", "bc", "method", "eta", "mu", "lam", "reference", "coarse", "fine",
              "fade_angle", "spline", "transfer",
              "max_iter", "max_time", "pinned", "fix_boundary", "formats", "keyframe_pattern",
              "frames_file", "pinned_file", "render", "plots", "delay"}
SOURCE_KEYS = {"name", "glob", "keyframes", "synth", "vertices", "synth_params"}
DEFAULTS = {"frames": None, "K": None, "bc": "natural", "method": "lta", "eta": 1e-3,
            "mu": 1.0, "lam": 1.0, "reference": "constant", "coarse": "auto", "fine": False,
            "max_iter": None, "max_time": None, "pinned": None, "fix_boundary": False,
            "formats": ["obj"], "keyframe_pattern": "pose_*.obj",
            "frames_file": "frames.txt", "pinned_file": "pinned.txt", "render": [],
            "plots": [], "delay": 0.0, "fade_angle": 0.5, "spline": DEFAULT_SPLINE,
            "transfer": DEFAULT_TRANSFER}
#: the parameters handed to :func:`shellspline.interpolate` (``SequenceSpec.params``)
INTERPOLATION_KEYS = ("method", "bc", "K", "eta", "mu", "lam", "reference", "coarse", "fine",
                      "max_iter", "max_time", "fix_boundary", "fade_angle", "spline",
                      "transfer")
#: names a sequence may not take: the job's own files in the output root
RESERVED_NAMES = {SUMMARY_NAME, LOG_NAME, LOCK_NAME, "half_axes.png"}
_RENDERS = ("strip", "gif")
_PLOTS = ("half_axes",)
_NAME_RE = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9._-]{0,127}$")


class JobError(ShellsplineError):
    """An invalid job file (one line naming the file and the key)."""


def job_error(where: str, msg: str) -> JobError:
    """``JobError("<where>: <msg>")``."""
    return JobError(f"{where}: {msg}")


def is_int(v) -> bool:
    """An integer that is not a bool."""
    return isinstance(v, numbers.Integral) and not isinstance(v, bool)


def is_num(v) -> bool:
    """A finite real number that is not a bool."""
    return isinstance(v, numbers.Real) and not isinstance(v, bool) and math.isfinite(v)


def _check_frames(w, v):
    if isinstance(v, str):
        return v
    if not isinstance(v, list) or not v or not all(is_int(x) and x >= 0 for x in v):
        raise job_error(w, f"must be a list of non-negative integers or a file, got {v!r}")
    if any(b <= a for a, b in zip(v, v[1:])):
        raise job_error(w, f"must be strictly increasing, got {v}")
    if v[0] != 0:
        raise job_error(w, f"must start at 0 (the first keyframe is frame 0), got {v}")
    return [int(x) for x in v]


def _check_choice(w, key, v):
    from ..pipeline.interpolation import BOUNDARY_CONDITIONS, METHODS, SPLINES
    from ..pipeline.options import TRANSFERS

    choices = {"bc": BOUNDARY_CONDITIONS, "method": METHODS, "spline": SPLINES,
               "transfer": TRANSFERS}[key]
    if not isinstance(v, str) or v.strip().lower() not in choices:
        raise job_error(w, f"must be one of {', '.join(choices)}, got {v!r}")
    return v.strip().lower()


def _check_reference(w, v):
    if is_int(v) and v >= 0:
        return int(v)
    if isinstance(v, str) and v.strip().lower() in ("constant", "keyframe", "geodesic"):
        return v.strip().lower()
    raise job_error(w, f"must be 'constant', 'keyframe', 'geodesic' or a keyframe index, got "
                       f"{v!r}")


def _check_coarse(w, v):
    if isinstance(v, str) and v.strip().lower() in ("auto", "none"):
        return v.strip().lower()
    if is_int(v) and v >= 4:
        return int(v)
    if is_num(v) and 0 < v < 1:
        return float(v)
    raise job_error(w, f"must be 'auto', 'none', a vertex count >= 4 or a fraction in (0, 1), "
                       f"got {v!r}")


def _check_pinned(w, v):
    if isinstance(v, str):
        return v
    if not isinstance(v, list) or not all(is_int(x) and x >= 0 for x in v):
        raise job_error(w, f"must be a list of vertex indices or a file, got {v!r}")
    return [int(x) for x in v]


def _check_names(w, key, v):
    from ..io.sequences import SEQUENCE_FORMATS

    choices = {"formats": SEQUENCE_FORMATS, "render": _RENDERS, "plots": _PLOTS}[key]
    if not isinstance(v, list) or not all(isinstance(x, str) for x in v) or \
            len(set(v)) != len(v):
        raise job_error(w, f"must be a list of distinct names from {', '.join(choices)}, "
                           f"got {v!r}")
    bad = [x for x in v if x not in choices]
    if bad:
        raise job_error(w, f"unknown {key[:-1] if key != 'plots' else 'plot'} {bad[0]!r} "
                           f"(choose from {', '.join(choices)})")
    if key == "formats" and not v:
        raise job_error(w, "needs at least one format")
    return list(v)


def _check_file_name(w, key, v):
    if key == "keyframe_pattern":
        if not isinstance(v, str) or not v or "/" in v or os.sep in v:
            raise job_error(w, f"must be a file name pattern such as 'pose_*.obj', got {v!r}")
        return v
    if not isinstance(v, str) or "/" in v or os.sep in v:
        raise job_error(w, f"must be a file name inside the sequence directory ('' for none), "
                           f"got {v!r}")
    return v


def _check_count(w, v):
    if not is_int(v) or v < 1:
        raise job_error(w, f"must be an integer >= 1, got {v!r}")
    return int(v)


def _check_weight(w, v):
    if not is_num(v) or v < 0:
        raise job_error(w, f"must be a finite number >= 0, got {v!r}")
    return float(v)


def _check_bool(w, v):
    if not isinstance(v, bool):
        raise job_error(w, f"must be true or false, got {v!r}")
    return v


def _check_seconds(w, key, v):
    if not is_num(v) or v < 0 or (key == "max_time" and v == 0):
        raise job_error(w, f"must be a number {'> 0' if key == 'max_time' else '>= 0'}, "
                           f"got {v!r}")
    return float(v)


_CHECKS = {
    "frames": lambda w, k, v: _check_frames(w, v),
    "K": lambda w, k, v: _check_count(w, v),
    "max_iter": lambda w, k, v: _check_count(w, v),
    "bc": _check_choice, "method": _check_choice, "spline": _check_choice,
    "transfer": _check_choice,
    "eta": lambda w, k, v: _check_weight(w, v),
    "mu": lambda w, k, v: _check_weight(w, v),
    "lam": lambda w, k, v: _check_weight(w, v),
    "fade_angle": lambda w, k, v: _check_weight(w, v),
    "reference": lambda w, k, v: _check_reference(w, v),
    "coarse": lambda w, k, v: _check_coarse(w, v),
    "fine": lambda w, k, v: _check_bool(w, v),
    "fix_boundary": lambda w, k, v: _check_bool(w, v),
    "max_time": _check_seconds, "delay": _check_seconds,
    "pinned": lambda w, k, v: _check_pinned(w, v),
    "formats": _check_names, "render": _check_names, "plots": _check_names,
    "keyframe_pattern": _check_file_name, "frames_file": _check_file_name,
    "pinned_file": _check_file_name,
}
assert set(_CHECKS) == PARAM_KEYS


def check_param(where: str, key: str, v):
    """Validate one parameter value of ``[defaults]`` or a ``[[sequences]]`` entry.

    Parameters
    ----------
    where : str
        The file and table, for the message.
    key : str
        One of :data:`PARAM_KEYS`.
    v : object
        The TOML value.

    Returns
    -------
    object
        The value canonicalised (lower-case choices, ints, floats, lists).

    Raises
    ------
    JobError
        ``"<where> key '<key>': must be ..., got ..."``.
    """
    return _CHECKS[key](f"{where} key '{key}'", key, v)


def check_name(where: str, n: str, key: str = "name") -> str:
    """``n`` if it is usable as the name of an output directory, else a :class:`JobError`."""
    if not _NAME_RE.match(n) or n in RESERVED_NAMES:
        raise job_error(f"{where} key '{key}'", f"'{n}' is not usable as a directory name "
                                                "(letters, digits, '.', '_', '-'; not starting "
                                                "with '.')")
    return n


def read_toml(path: Path) -> dict:
    """The parsed job file; one-line :class:`ShellsplineError` when unreadable or invalid."""
    if sys.version_info >= (3, 11):
        import tomllib
    else:  # pragma: no cover
        import tomli as tomllib
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise ShellsplineError(f"cannot read job file '{path}': {exc.strerror or exc}") from None
    try:
        return tomllib.loads(data.decode("utf-8"))
    except UnicodeDecodeError:
        raise ShellsplineError(f"{path}: not UTF-8 text") from None
    except tomllib.TOMLDecodeError as exc:
        raise ShellsplineError(f"{path}: invalid TOML: {' '.join(str(exc).split())}") from None


def table(where: str, v) -> dict:
    """``v`` if it is a TOML table, else a :class:`JobError`."""
    if not isinstance(v, dict):
        raise job_error(where, f"must be a table, got {type(v).__name__}")
    return v


def reject_unknown(where: str, tbl: dict, allowed: set) -> None:
    """A :class:`JobError` naming the first key of ``tbl`` not in ``allowed``."""
    for k in tbl:
        if k not in allowed:
            raise job_error(where, f"unknown key '{k}' (allowed: {', '.join(sorted(allowed))})")


def resolve(base: Path, p: str) -> Path:
    """``p`` (``~`` expanded) as an absolute path, relative ones against ``base``."""
    q = Path(os.path.expanduser(p))
    return (q if q.is_absolute() else base / q).resolve()

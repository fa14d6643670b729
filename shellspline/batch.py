"""Batch jobs: many keyframe sequences from one TOML file, run in parallel, nothing lost.

A job file (``pipelines/*.toml``) lists sequences — directories found by a glob, explicit
keyframe files, or synthetic keyframes from :mod:`data_synth` — with defaults and
per-sequence overrides of the interpolation parameters. :func:`load_job` validates the whole
file up front; :func:`run_batch` runs every sequence that is not already up to date, on a
local process pool (one process per sequence) or on a Dask distributed cluster (one task
per sequence), and returns a :class:`BatchSummary`.

Guarantees
----------
* Each sequence's output directory ``OUT/<name>/`` appears atomically (everything is written
  into a hidden staging directory ``OUT/.<name>.stage-<hex>`` that is renamed into place) and
  holds ``manifest.json``: sha256 of every input file (or the synthetic generator and its
  parameters), all parameters, the shellspline version, the time and the size of every
  output file.
* Re-running a job skips the sequences whose manifest matches (same inputs, parameters and
  version, every listed output file present with its size) and redoes the others: after a
  Ctrl-C, a crash or a killed worker the job resumes where it stopped. Leftover staging
  directories of a killed run are removed at the start and end of the next run (an output
  root is locked while a job runs on it, so they cannot belong to a live run).
* One failing sequence never stops the others; its one-line reason appears in the summary.
* A task that runs twice (a Dask worker declared dead while still running) does not
  duplicate or tear an output: the second attempt finds a complete output with a matching
  manifest and leaves it untouched.

Only the public API of :mod:`shellspline` does the numerical work:
:func:`~shellspline.read_keyframes`, :func:`~shellspline.interpolate`,
:func:`~shellspline.write_sequence`.

Paths in a job file are relative to the directory of the job file.
"""
from __future__ import annotations

import contextlib
import dataclasses
import datetime as _dt
import hashlib
import json
import logging
import math
import multiprocessing as mp
import numbers
import os
import re
import secrets
import shutil
import signal
import socket
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

from .errors import ShellsplineError, one_line
from .version import __version__

__all__ = ["Job", "SequenceSpec", "BatchSummary", "load_job", "run_batch", "sequence_metrics",
           "REGRESSION_METRICS"]

MANIFEST_FORMAT = "shellspline-batch-manifest/1"
SUMMARY_NAME, LOG_NAME, LOCK_NAME = "summary.json", "batch.log", ".batch.lock"
_RESERVED = {SUMMARY_NAME, LOG_NAME, LOCK_NAME, "half_axes.png"}
_TEMP_MARKERS = (".stage-", ".tmp-", ".old-")

EXIT_OK, EXIT_FAILED, EXIT_JOB, EXIT_INTERRUPTED = 0, 1, 2, 130

_log = logging.getLogger("shellspline.batch")

# --------------------------------------------------------------------------------------
# Job schema
# --------------------------------------------------------------------------------------
_JOB_KEYS = {"name", "output", "executor", "scheduler", "workers"}
#: keys allowed in [defaults] and in every [[sequences]] entry (per-sequence overrides)
_PARAM_KEYS = {"frames", "K", "bc", "method", "eta", "mu", "lam", "reference", "coarse", "fine",
               "max_iter", "max_time", "pinned", "fix_boundary", "formats", "keyframe_pattern",
               "frames_file", "pinned_file", "render", "plots", "delay"}
_SOURCE_KEYS = {"name", "glob", "keyframes", "synth", "vertices", "synth_params"}
_REGRESSION_KEYS = {"expected", "tolerances"}
_TOLERANCE_KEYS = {"rtol", "atol", "mode"}
_DEFAULTS = {"frames": None, "K": None, "bc": "natural", "method": "lta", "eta": 1e-3,
             "mu": 1.0, "lam": 1.0, "reference": "constant", "coarse": "auto", "fine": False,
             "max_iter": None, "max_time": None, "pinned": None, "fix_boundary": False,
             "formats": ["obj"], "keyframe_pattern": "pose_*.obj",
             "frames_file": "frames.txt", "pinned_file": "pinned.txt", "render": [],
             "plots": [], "delay": 0.0}
_FORMATS = ("obj", "ply", "glb", "mdd", "pc2", "usd")  # io.sequences.SEQUENCE_FORMATS
_RENDERS = ("strip", "gif")
_PLOTS = ("half_axes",)
_NAME_RE = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9._-]{0,127}$")

#: Metrics written to every sequence's ``metrics.json`` and compared by a ``[regression]``.
REGRESSION_METRICS = ("keyframe_error", "keyframe_kinks", "half_axes", "gn_frames",
                      "gn_converged", "gn_iterations_total", "gn_grad_norm_max",
                      "gn_energy_final", "flipped_faces", "degenerate_faces")


@dataclass
class SequenceSpec:
    """One sequence of a job, fully resolved (absolute paths, every parameter set).

    Small and picklable: it is what a worker process or a Dask task receives; the task reads
    (or generates) its own keyframes, so heavy arrays never travel.

    Attributes
    ----------
    name : str
        Also the name of the output directory ``out``.
    out : str
        Absolute output directory of this sequence (inside the job's output root).
    source : {"files", "synth"}
    keyframes : list of str
        Keyframe files (``source="files"``), in time order.
    directory : str or None
        The sequence directory a glob found (for messages).
    frames, pinned : list of int or None
        Explicit keyframe frames / pinned vertices.
    frames_path, pinned_path : str or None
        Files to read them from (a directory's ``frames.txt``/``pinned.txt``, or a path in
        the job file); hashed into the manifest.
    synth : dict or None
        ``{"name", "vertices", "params"}`` for :func:`data_synth.generate`.
    params : dict
        ``method, bc, K, eta, mu, lam, reference, coarse, fine, max_iter, max_time,
        fix_boundary`` for :func:`shellspline.interpolate`.
    formats, render, plots : list of str
    delay : float
        Seconds to sleep between solving and writing (a testing knob; not in the manifest).
    """

    name: str
    out: str
    source: str
    keyframes: list = field(default_factory=list)
    directory: str | None = None
    keyframe_pattern: str | None = None
    frames: list | None = None
    frames_path: str | None = None
    pinned: list | None = None
    pinned_path: str | None = None
    synth: dict | None = None
    params: dict = field(default_factory=dict)
    formats: list = field(default_factory=lambda: ["obj"])
    render: list = field(default_factory=list)
    plots: list = field(default_factory=list)
    delay: float = 0.0

    def key_parameters(self) -> dict:
        """Everything besides the inputs that determines the output (goes into the key)."""
        return {"params": dict(self.params), "frames": self.frames, "pinned": self.pinned,
                "formats": list(self.formats), "render": list(self.render),
                "plots": list(self.plots)}


@dataclass
class Job:
    """A validated batch job (see :func:`load_job`).

    Attributes
    ----------
    path : Path or None
        The job file.
    name : str
    output : Path
        Output root: one directory per sequence, plus ``summary.json`` and ``batch.log``.
    executor : {"local", "dask"}
    scheduler : str or None
        Address of a Dask scheduler (``tcp://HOST:PORT``).
    workers : int
        Local processes, or the workers of a Dask ``LocalCluster``.
    sequences : list of SequenceSpec
    regression : dict or None
        ``{"expected": {sequence: {metric: value}}, "expected_path": Path or None,
        "tolerances": {metric: {"rtol", "atol", "mode"}}}``.
    """

    path: Path | None
    name: str
    output: Path
    executor: str = "local"
    scheduler: str | None = None
    workers: int = 1
    sequences: list = field(default_factory=list)
    regression: dict | None = None

    def with_output(self, output) -> "Job":
        """The same job writing to another output root."""
        output = Path(output).resolve()
        seqs = [dataclasses.replace(s, out=str(output / s.name)) for s in self.sequences
                if s.directory is None or s.keyframes or not _holds(Path(s.directory), output)]
        job = dataclasses.replace(self, output=output, sequences=seqs)
        _check_outputs_do_not_hold_inputs(job)
        return job


class _JobError(ShellsplineError):
    pass


def _err(where: str, msg: str) -> _JobError:
    return _JobError(f"{where}: {msg}")


def _is_int(v) -> bool:
    return isinstance(v, numbers.Integral) and not isinstance(v, bool)


def _is_num(v) -> bool:
    return isinstance(v, numbers.Real) and not isinstance(v, bool) and math.isfinite(v)


def _check_param(where: str, key: str, v):
    """Validate one parameter value; returns it canonicalised."""
    w = f"{where} key '{key}'"
    if key == "frames":
        if isinstance(v, str):
            return v
        if not isinstance(v, list) or not v or not all(_is_int(x) and x >= 0 for x in v):
            raise _err(w, f"must be a list of non-negative integers or a file, got {v!r}")
        if any(b <= a for a, b in zip(v, v[1:])):
            raise _err(w, f"must be strictly increasing, got {v}")
        return [int(x) for x in v]
    if key == "K":
        if not _is_int(v) or v < 1:
            raise _err(w, f"must be an integer >= 1, got {v!r}")
        return int(v)
    if key in ("bc", "method"):
        from .pipeline.interpolation import BOUNDARY_CONDITIONS, METHODS

        choices = BOUNDARY_CONDITIONS if key == "bc" else METHODS
        if not isinstance(v, str) or v.strip().lower() not in choices:
            raise _err(w, f"must be one of {', '.join(choices)}, got {v!r}")
        return v.strip().lower()
    if key in ("eta", "mu", "lam"):
        if not _is_num(v) or v < 0:
            raise _err(w, f"must be a finite number >= 0, got {v!r}")
        return float(v)
    if key == "reference":
        if _is_int(v) and v >= 0:
            return int(v)
        if isinstance(v, str) and v.strip().lower() in ("constant", "keyframe"):
            return v.strip().lower()
        raise _err(w, f"must be 'constant', 'keyframe' or a keyframe index, got {v!r}")
    if key == "coarse":
        if isinstance(v, str) and v.strip().lower() in ("auto", "none"):
            return v.strip().lower()
        if _is_int(v) and v >= 4:
            return int(v)
        if _is_num(v) and 0 < v < 1:
            return float(v)
        raise _err(w, f"must be 'auto', 'none', a vertex count >= 4 or a fraction in (0, 1), "
                      f"got {v!r}")
    if key in ("fine", "fix_boundary"):
        if not isinstance(v, bool):
            raise _err(w, f"must be true or false, got {v!r}")
        return v
    if key == "max_iter":
        if not _is_int(v) or v < 1:
            raise _err(w, f"must be an integer >= 1, got {v!r}")
        return int(v)
    if key in ("max_time", "delay"):
        if not _is_num(v) or v < 0 or (key == "max_time" and v == 0):
            raise _err(w, f"must be a number {'> 0' if key == 'max_time' else '>= 0'}, "
                          f"got {v!r}")
        return float(v)
    if key == "pinned":
        if isinstance(v, str):
            return v
        if not isinstance(v, list) or not all(_is_int(x) and x >= 0 for x in v):
            raise _err(w, f"must be a list of vertex indices or a file, got {v!r}")
        return [int(x) for x in v]
    if key in ("formats", "render", "plots"):
        choices = {"formats": _FORMATS, "render": _RENDERS, "plots": _PLOTS}[key]
        if not isinstance(v, list) or not all(isinstance(x, str) for x in v) or \
                len(set(v)) != len(v):
            raise _err(w, f"must be a list of distinct names from {', '.join(choices)}, "
                          f"got {v!r}")
        bad = [x for x in v if x not in choices]
        if bad:
            raise _err(w, f"unknown {key[:-1] if key != 'plots' else 'plot'} {bad[0]!r} "
                          f"(choose from {', '.join(choices)})")
        if key == "formats" and not v:
            raise _err(w, "needs at least one format")
        return list(v)
    if key == "keyframe_pattern":
        if not isinstance(v, str) or not v or "/" in v or os.sep in v:
            raise _err(w, f"must be a file name pattern such as 'pose_*.obj', got {v!r}")
        return v
    if key in ("frames_file", "pinned_file"):
        if not isinstance(v, str) or "/" in v or os.sep in v:
            raise _err(w, f"must be a file name inside the sequence directory ('' for none), "
                          f"got {v!r}")
        return v
    raise AssertionError(key)  # pragma: no cover


def _read_toml(path: Path) -> dict:
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


def _table(where: str, v) -> dict:
    if not isinstance(v, dict):
        raise _err(where, f"must be a table, got {type(v).__name__}")
    return v


def _unknown(where: str, table: dict, allowed: set) -> None:
    for k in table:
        if k not in allowed:
            raise _err(where, f"unknown key '{k}' (allowed: {', '.join(sorted(allowed))})")


def _holds(d: Path, root: Path) -> bool:
    """Whether directory ``d`` is the output root ``root`` or one of its ancestors: a glob
    such as ``shots/*`` with ``output = "shots/_out"`` must not take the job's own output
    root for a sequence directory on the next run."""
    return d == root or d in root.parents


def _keyframe_files(d: Path, pattern: str) -> list[Path]:
    """The files of directory ``d`` matching ``pattern``, in natural sort order."""
    return sorted((p for p in d.glob(pattern) if p.is_file()), key=_natural_key)


def _natural_key(p: Path):
    return [int(t) if t.isdigit() else t for t in re.split(r"(\d+)", p.name)]


def _resolve(base: Path, p: str) -> Path:
    q = Path(os.path.expanduser(p))
    return (q if q.is_absolute() else base / q).resolve()


def load_job(path) -> Job:
    """Read and validate a TOML batch job.

    Parameters
    ----------
    path : str or path-like
        The job file. Relative paths inside it (``output``, ``glob``, ``keyframes``,
        ``frames``/``pinned`` files, ``regression.expected``) are relative to the directory
        of the job file.

    Returns
    -------
    Job

    Raises
    ------
    ShellsplineError
        One line naming the file and the offending key: invalid TOML, an unknown key, a bad
        value, a glob that matches no directory, two sequences with the same name, an output
        directory that would contain an input.

    Notes
    -----
    Schema (every key of ``[defaults]`` may be overridden in a ``[[sequences]]`` entry)::

        [job]        name, output, executor = "local"|"dask", scheduler, workers
        [defaults]   frames, K, bc, method, eta, mu, lam, reference, coarse, fine, max_iter,
                     max_time, pinned, fix_boundary, formats, keyframe_pattern, frames_file,
                     pinned_file, render, plots, delay
        [[sequences]] one of: glob = "dir/*" (sequence directories) |
                     keyframes = ["a.obj", ...] + name | synth = "ellipsoids" + name
                     (+ vertices, synth_params)
        [regression] expected = "file.json" or an inline table, tolerances.<metric> =
                     {rtol, atol, mode = "close"|"max"|"min"}

    Frames and pinned vertices: a sequence's own ``frames``/``pinned`` win; then the
    source's (``frames.txt``/``pinned.txt`` in a sequence directory, or the synthetic
    generator's); then ``[defaults]``.
    """
    path = Path(path)
    doc = _read_toml(path)
    base = path.resolve().parent
    f = str(path)
    _unknown(f, doc, {"job", "defaults", "sequences", "regression"})
    jt = _table(f"{f}: [job]", doc.get("job", {}))
    _unknown(f"{f}: [job]", jt, _JOB_KEYS)
    name = jt.get("name", path.stem)
    if not isinstance(name, str) or not name.strip():
        raise _err(f"{f}: [job] key 'name'", f"must be a non-empty string, got {name!r}")
    if "output" not in jt:
        raise _err(f"{f}: [job]", "missing key 'output' (the output root directory)")
    if not isinstance(jt["output"], str) or not jt["output"].strip():
        raise _err(f"{f}: [job] key 'output'", f"must be a path, got {jt['output']!r}")
    output = _resolve(base, jt["output"])
    executor = jt.get("executor", "local")
    if executor not in ("local", "dask"):
        raise _err(f"{f}: [job] key 'executor'", f"must be 'local' or 'dask', got {executor!r}")
    scheduler = jt.get("scheduler")
    if scheduler is not None:
        scheduler = check_scheduler_address(scheduler, f"{f}: [job] key 'scheduler'")
    workers = jt.get("workers", 1)
    if not _is_int(workers) or workers < 1:
        raise _err(f"{f}: [job] key 'workers'", f"must be an integer >= 1, got {workers!r}")

    dt = _table(f"{f}: [defaults]", doc.get("defaults", {}))
    _unknown(f"{f}: [defaults]", dt, _PARAM_KEYS | {"vertices"})
    defaults = dict(_DEFAULTS)
    defaults.update({k: _check_param(f"{f}: [defaults]", k, v) for k, v in dt.items()
                     if k != "vertices"})
    if "vertices" in dt:
        v = dt["vertices"]
        if not _is_int(v) or v < 4:
            raise _err(f"{f}: [defaults] key 'vertices'", f"must be an integer >= 4, got {v!r}")
        defaults["vertices"] = int(v)

    entries = doc.get("sequences", [])
    if not isinstance(entries, list) or not entries or \
            not all(isinstance(e, dict) for e in entries):
        raise _err(f, "needs at least one [[sequences]] entry")
    seqs: list[SequenceSpec] = []
    for i, e in enumerate(entries):
        where = f"{f}: [[sequences]] #{i + 1}"
        _unknown(where, e, _PARAM_KEYS | _SOURCE_KEYS)
        kinds = [k for k in ("glob", "keyframes", "synth") if k in e]
        if len(kinds) != 1:
            raise _err(where, "needs exactly one of 'glob', 'keyframes', 'synth', got "
                              f"{kinds or 'none'}")
        own = {k: _check_param(where, k, v) for k, v in e.items() if k in _PARAM_KEYS}
        for k in ("vertices", "synth_params"):
            if k in e and kinds[0] != "synth":
                raise _err(f"{where} key '{k}'", "applies to synthetic sequences only")
        seqs.extend(_expand_entry(where, base, output, kinds[0], e, own, defaults))
    names = set()
    for s in seqs:
        if s.name in names:
            raise _err(f, f"two sequences are named '{s.name}' (names must be unique; set "
                          "'name')")
        names.add(s.name)
    regression = None
    if "regression" in doc:
        regression = _load_regression(f, base, _table(f"{f}: [regression]", doc["regression"]),
                                      names)
    job = Job(path=path.resolve(), name=name.strip(), output=output, executor=executor,
              scheduler=scheduler, workers=int(workers), sequences=seqs, regression=regression)
    _check_outputs_do_not_hold_inputs(job)
    return job


def check_scheduler_address(addr, where: str = "--scheduler") -> str:
    """Return a Dask scheduler address after a syntax check (``tcp://HOST:PORT``)."""
    if not isinstance(addr, str) or not re.fullmatch(
            r"(?:(?:tcp|tls|ws|wss|ucx)://)?(?:\[[0-9a-fA-F:]+\]|[A-Za-z0-9_.-]+):\d{1,5}",
            addr.strip()):
        raise ShellsplineError(f"{where}: expected a scheduler address such as "
                               f"tcp://127.0.0.1:8786, got {addr!r}")
    addr = addr.strip()
    return addr if "://" in addr else "tcp://" + addr


def _expand_entry(where, base, output, kind, e, own, defaults):
    merged = dict(defaults)
    merged.pop("vertices", None)
    merged.update(own)
    params = {k: merged[k] for k in ("method", "bc", "K", "eta", "mu", "lam", "reference",
                                     "coarse", "fine", "max_iter", "max_time",
                                     "fix_boundary")}
    if params["max_time"] is not None and params["method"] != "nonlinear":
        raise _err(f"{where} key 'max_time'", "applies to method = 'nonlinear' only")
    common = dict(params=params, formats=merged["formats"], render=merged["render"],
                  plots=merged["plots"], delay=merged["delay"])
    name = e.get("name")
    if name is not None and (not isinstance(name, str) or not name):
        raise _err(f"{where} key 'name'", f"must be a non-empty string, got {name!r}")

    def check_name(n, key="name"):
        if not _NAME_RE.match(n) or n in _RESERVED:
            raise _err(f"{where} key '{key}'", f"'{n}' is not usable as a directory name "
                                               "(letters, digits, '.', '_', '-'; not starting "
                                               "with '.')")
        return n

    def frames_pinned(src_frames_path, src_pinned_path, src_frames=None, src_pinned=None):
        out = {}
        for key, src_path, src_val in (("frames", src_frames_path, src_frames),
                                       ("pinned", src_pinned_path, src_pinned)):
            if key in own:
                v, origin = own[key], "own"
            elif src_path is not None or src_val is not None:
                v, origin = None, "source"
            else:
                v, origin = defaults[key], "defaults"
            if origin == "source":
                out[key], out[f"{key}_path"] = src_val, src_path
            elif isinstance(v, str):
                if key == "frames" and re.fullmatch(r"[\s,0-9]+", v) and re.search(r"\d", v):
                    out[key], out[f"{key}_path"] = [int(t) for t in
                                                    v.replace(",", " ").split()], None
                else:
                    p = _resolve(base, v)
                    if not p.is_file():
                        w = where if origin == "own" else where.split(": ")[0] + \
                            ": [defaults]"
                        raise _err(f"{w} key '{key}'", f"file '{p}' does not exist")
                    out[key], out[f"{key}_path"] = None, str(p)
            else:
                out[key], out[f"{key}_path"] = v, None
        return out

    if kind == "glob":
        pat = e["glob"]
        if not isinstance(pat, str) or not pat:
            raise _err(f"{where} key 'glob'", f"must be a glob pattern, got {pat!r}")
        gp = Path(os.path.expanduser(pat))
        if gp.is_absolute():
            anchor = Path(gp.anchor)
            rel = str(gp.relative_to(anchor))
        else:
            anchor, rel = base, pat
        kfp = merged["keyframe_pattern"]
        # the output root (or a folder holding it) is no sequence, unless it holds keyframes:
        # then the job is refused (_check_outputs_do_not_hold_inputs)
        dirs = sorted((p.resolve() for p in anchor.glob(rel) if p.is_dir() and not (
            _holds(p.resolve(), output) and not _keyframe_files(p, kfp))), key=_natural_key)
        if not dirs:
            raise _err(f"{where} key 'glob'", f"'{pat}' matches no directory (relative to "
                                              f"{base})")
        template = name if name is not None else "{dir}"
        if "{dir}" not in template and len(dirs) > 1:
            raise _err(f"{where} key 'name'", f"the glob matches {len(dirs)} directories: the "
                                              "name needs '{dir}'")
        out = []
        for d in dirs:
            sname = check_name(template.replace("{dir}", d.name))
            files = _keyframe_files(d, kfp)
            ff = d / merged["frames_file"] if merged["frames_file"] else None
            pf = d / merged["pinned_file"] if merged["pinned_file"] else None
            fp = frames_pinned(str(ff) if ff is not None and ff.is_file() else None,
                               str(pf) if pf is not None and pf.is_file() else None)
            out.append(SequenceSpec(name=sname, out=str(output / sname), source="files",
                                    keyframes=[str(p) for p in files], directory=str(d),
                                    keyframe_pattern=kfp, **fp, **common))
        return out
    if name is None:
        raise _err(where, f"a '{kind}' entry needs a 'name'")
    check_name(name)
    if kind == "keyframes":
        kfs = e["keyframes"]
        if not isinstance(kfs, list) or len(kfs) < 2 or \
                not all(isinstance(p, str) and p for p in kfs):
            raise _err(f"{where} key 'keyframes'", f"must list at least 2 files, got {kfs!r}")
        paths = [str(_resolve(base, p)) for p in kfs]
        missing = [p for p in paths if not Path(p).is_file()]
        if missing:
            raise _err(f"{where} key 'keyframes'", f"file '{missing[0]}' does not exist")
        fp = frames_pinned(None, None)
        return [SequenceSpec(name=name, out=str(output / name), source="files",
                             keyframes=paths, **fp, **common)]
    # synthetic
    import data_synth

    gen = e["synth"]
    if gen not in data_synth.NAMES:
        raise _err(f"{where} key 'synth'", f"must be one of {', '.join(data_synth.NAMES)}, "
                                           f"got {gen!r}")
    vertices = e.get("vertices", defaults.get("vertices"))
    if vertices is not None and (not _is_int(vertices) or vertices < 4):
        raise _err(f"{where} key 'vertices'", f"must be an integer >= 4, got {vertices!r}")
    sp = _table(f"{where} key 'synth_params'", e.get("synth_params", {}))
    try:  # validate the generator parameters here, not in a worker
        data = data_synth.generate(gen, vertices, **_json_roundtrip(sp))
    except (TypeError, ValueError) as exc:
        raise _err(f"{where} key 'synth_params'", " ".join(str(exc).split())) from None
    src_frames = [int(x) for x in data["frames"]]
    src_pinned = None if data.get("pinned") is None else [int(x) for x in data["pinned"]]
    fp = frames_pinned(None, None, src_frames, src_pinned)
    return [SequenceSpec(name=name, out=str(output / name), source="synth",
                         synth={"name": gen, "vertices": vertices, "params": sp}, **fp,
                         **common)]


def _json_roundtrip(obj):
    return json.loads(json.dumps(obj))


def _load_regression(f, base, rt, names):
    where = f"{f}: [regression]"
    _unknown(where, rt, _REGRESSION_KEYS)
    exp = rt.get("expected")
    expected_path = None
    if isinstance(exp, str):
        expected_path = _resolve(base, exp)
        try:
            exp = json.loads(expected_path.read_text(encoding="utf-8"))
        except FileNotFoundError:
            exp = None  # run_batch(write_expected=True) creates it; otherwise an error
        except OSError as exc:
            raise _err(f"{where} key 'expected'", f"cannot read '{expected_path}': "
                                                  f"{exc.strerror or exc}") from None
        except ValueError as exc:
            raise _err(f"{where} key 'expected'", f"'{expected_path}' is not valid JSON: "
                                                  f"{exc}") from None
        if isinstance(exp, dict) and "sequences" in exp:
            exp = exp["sequences"]
    elif exp is None:
        exp = {}
    if exp is None:
        return {"expected": None, "expected_path": expected_path,
                "tolerances": _load_tolerances(where, rt)}
    if not isinstance(exp, dict) or not all(isinstance(v, dict) for v in exp.values()):
        raise _err(f"{where} key 'expected'", "must map sequence names to tables of metric "
                                              "values")
    for sname, metrics in exp.items():
        if sname not in names:
            raise _err(f"{where} key 'expected'", f"names an unknown sequence '{sname}'")
        for m in metrics:
            if m not in REGRESSION_METRICS:
                raise _err(f"{where} key 'expected'", f"sequence '{sname}': unknown metric "
                                                      f"'{m}' (known: "
                                                      f"{', '.join(REGRESSION_METRICS)})")
    return {"expected": exp, "expected_path": expected_path,
            "tolerances": _load_tolerances(where, rt)}


def _load_tolerances(where, rt):
    tols = _table(f"{where} key 'tolerances'", rt.get("tolerances", {}))
    out_tols = {}
    for m, t in tols.items():
        w = f"{where} key 'tolerances.{m}'"
        if m not in REGRESSION_METRICS:
            raise _err(w, f"unknown metric (known: {', '.join(REGRESSION_METRICS)})")
        t = _table(w, t)
        _unknown(w, t, _TOLERANCE_KEYS)
        rtol, atol, mode = t.get("rtol", 0.0), t.get("atol", 0.0), t.get("mode", "close")
        if not (_is_num(rtol) and rtol >= 0 and _is_num(atol) and atol >= 0):
            raise _err(w, f"rtol and atol must be numbers >= 0, got {rtol!r}, {atol!r}")
        if mode not in ("close", "max", "min"):
            raise _err(w, f"mode must be 'close', 'max' or 'min', got {mode!r}")
        out_tols[m] = {"rtol": float(rtol), "atol": float(atol), "mode": mode}
    return out_tols


def _check_outputs_do_not_hold_inputs(job: Job) -> None:
    root = job.output
    where = job.path or "job"
    for s in job.sequences:
        folders = {Path(p).resolve().parent for p in s.keyframes}
        if s.directory:
            folders.add(Path(s.directory).resolve())
        for d in sorted(folders):
            if _holds(d, root):
                raise ShellsplineError(f"{where}: output root '{root}' is "
                                       f"{'the' if d == root else 'inside the'} keyframe "
                                       f"folder '{d}' of sequence '{s.name}' (choose an "
                                       "output outside the input folders)")
        inputs = list(s.keyframes) + [p for p in (s.frames_path, s.pinned_path, s.directory)
                                      if p]
        for p in inputs:
            rp = Path(p).resolve()
            for o in (Path(s.out),):
                if o == rp or o in rp.parents:
                    where = job.path or "job"
                    raise ShellsplineError(f"{where}: output '{o}' would contain the input "
                                           f"'{p}' of sequence '{s.name}'")


# --------------------------------------------------------------------------------------
# Hashing and manifests
# --------------------------------------------------------------------------------------
def _sha256_file(path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def _sha256_json(obj) -> str:
    return hashlib.sha256(json.dumps(obj, sort_keys=True, separators=(",", ":"))
                          .encode()).hexdigest()


def _input_digest(spec: SequenceSpec) -> dict:
    """sha256 of every input (raises OSError when a file cannot be read)."""
    if spec.source == "synth":
        return {"synth": spec.synth, "sha256": _sha256_json(spec.synth)}
    d = {"keyframes": [{"path": p, "sha256": _sha256_file(p)} for p in spec.keyframes]}
    for k in ("frames_path", "pinned_path"):
        p = getattr(spec, k)
        d[k[:-5] + "_file"] = None if p is None else {"path": p, "sha256": _sha256_file(p)}
    return d


def _sequence_key(spec: SequenceSpec, digest: dict) -> str:

    hashes = {"synth": digest.get("sha256")} if spec.source == "synth" else {
        "keyframes": [x["sha256"] for x in digest["keyframes"]],
        **{k: (digest[k] or {}).get("sha256") for k in ("frames_file", "pinned_file")}}
    return _sha256_json({"inputs": hashes, "parameters": spec.key_parameters(),
                         "shellspline_version": __version__})


def _read_manifest(out: Path) -> dict | None:
    try:
        m = json.loads((out / "manifest.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return m if isinstance(m, dict) and m.get("format") == MANIFEST_FORMAT else None


def _manifest_matches(out, key: str) -> dict | None:
    """The manifest of a complete output with this key, else None."""
    out = Path(out)
    m = _read_manifest(out)
    if m is None or m.get("key") != key or not isinstance(m.get("outputs"), dict):
        return None
    for rel, size in m["outputs"].items():
        try:
            if (out / rel).stat().st_size != size:
                return None
        except OSError:
            return None
    return m


def _now() -> str:
    return _dt.datetime.now(_dt.timezone.utc).astimezone().isoformat(timespec="seconds")


def _json_safe(obj):
    """NaN/inf -> None (strict JSON), recursively."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: _json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_json_safe(v) for v in obj]
    return obj


def _write_json_atomic(path: Path, obj) -> None:
    tmp = path.parent / f".{path.name}.tmp-{os.getpid()}-{secrets.token_hex(4)}"
    try:
        tmp.write_text(json.dumps(_json_safe(obj), indent=2, allow_nan=False) + "\n",
                       encoding="utf-8")
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


# --------------------------------------------------------------------------------------
# One sequence (runs in a worker process or a Dask task)
# --------------------------------------------------------------------------------------
def _one_line(exc: BaseException) -> str:
    return one_line(exc, limit=300, bare=(ShellsplineError, OSError))


def sequence_metrics(V, keyframes_V, frames, report) -> dict:
    """The regression metrics of one interpolated sequence.

    Parameters
    ----------
    V : (K+1,n,3) array
        The sequence.
    keyframes_V : (J,n,3) array
        The input keyframes.
    frames : (J,) int array
        Keyframe frames.
    report : dict
        The report of :func:`shellspline.interpolate`.

    Returns
    -------
    dict
        ``keyframe_error`` (max |V[frames[j]] - keyframe j|), ``keyframe_kinks``
        (:func:`shellspline.metrics.keyframe_kinks`), ``half_axes`` ((K+1,3) list,
        :func:`shellspline.metrics.half_axes`), Gauss–Newton ``gn_frames``, ``gn_converged``,
        ``gn_iterations_total``, ``gn_grad_norm_max``, ``gn_energy_final`` (per reconstructed
        frame), and the quality counts ``flipped_faces``, ``degenerate_faces``.
    """
    import numpy as np

    from .metrics import half_axes, keyframe_kinks

    V = np.asarray(V, dtype=np.float64)
    frames = np.asarray(frames, dtype=np.int64)
    err = float(np.abs(V[frames] - np.asarray(keyframes_V)).max())
    recs = report.get("frames") or []
    gn = report.get("gauss_newton") or {}
    q = report.get("quality") or {}

    def finite(x):
        return None if x is None or not math.isfinite(x) else float(x)

    return {
        "keyframe_error": err,
        "keyframe_kinks": [float(x) for x in keyframe_kinks(V, frames)],
        "half_axes": half_axes(V).tolist(),
        "gn_frames": int(gn.get("frames", 0)),
        "gn_converged": int(gn.get("converged", 0)),
        "gn_iterations_total": int(gn.get("iterations_total", 0)),
        "gn_grad_norm_max": finite(max((r.get("grad_norm_final", math.nan) for r in recs),
                                       default=0.0)),
        "gn_energy_final": [finite(r.get("energy_final")) for r in recs],
        "flipped_faces": int(q.get("flipped_faces", 0)),
        "degenerate_faces": int(q.get("degenerate_faces", 0)),
    }


def _quality_warning(report: dict) -> str:
    q = report.get("quality", {})
    gn = report.get("gauss_newton")
    parts = []
    if gn and gn["converged"] != gn["frames"]:
        parts.append(f"Gauss–Newton converged on {gn['converged']}/{gn['frames']} frames")
    if not q.get("keyframes_exact", True):
        parts.append("keyframes not reproduced exactly")
    for key, what in (("flipped_faces", "flipped faces"), ("collapsed_faces", "collapsed faces"),
                      ("folded_edges", "folded edges"), ("degenerate_faces", "degenerate faces")):
        if q.get(key):
            parts.append(f"{q[key]} {what}")
    if q.get("pop", 0.0) > q.get("pop_limit", float("inf")):
        parts.append(f"a pop of {q['pop']:.1f}x the neighbouring steps at frame {q['pop_frame']}")
    for name in ("geodesic", "nonlinear"):
        if name in report and not report[name]["success"]:
            parts.append(f"{name} did not converge")
    return "; ".join(parts)


def _keyframes_of(spec: SequenceSpec):
    """Read or generate the keyframes (public API only) -> (Keyframes, pinned or None)."""
    import numpy as np

    from .io import keyframes_from_arrays, read_frames, read_indices, read_keyframes

    if spec.source == "synth":
        import data_synth

        syn = spec.synth
        data = data_synth.generate(syn["name"], syn["vertices"], **_json_roundtrip(syn["params"]))
        names = [f"{syn['name']}#{j}" for j in range(data["V"].shape[0])]
        kf = keyframes_from_arrays(data["V"], data["F"], frames=spec.frames, names=names)
    else:
        if len(spec.keyframes) < 2:
            where = spec.directory or spec.name
            raise ShellsplineError(f"{where}: {len(spec.keyframes)} file(s) match "
                                   f"'{spec.keyframe_pattern}' (need at least 2 keyframes)")
        frames = spec.frames
        if frames is None and spec.frames_path is not None:
            frames = read_frames(Path(spec.frames_path))
        kf = read_keyframes(spec.keyframes, frames=frames)
    pinned = None
    if spec.pinned is not None:
        pinned = np.asarray(spec.pinned, dtype=np.int64)
    elif spec.pinned_path is not None:
        pinned = read_indices(spec.pinned_path)
    if pinned is not None and kf.source is not None:  # pins number the files' vertices
        pinned = kf.source.solve_vertices(pinned, str(spec.pinned_path or spec.name))
    if spec.params.get("fix_boundary"):
        bv = kf.topology.boundary_vertices
        if bv.size == 0:
            raise ShellsplineError(f"{spec.name}: fix_boundary = true but the mesh has no "
                                   "boundary")
        pinned = bv if pinned is None else np.union1d(pinned, bv)
    if pinned is not None and pinned.size and (pinned.min() < 0 or pinned.max() >= kf.n):
        raise ShellsplineError(f"{spec.pinned_path or spec.name}: pinned vertex indices must "
                               f"lie in [0, {kf.n}), got range [{pinned.min()}, "
                               f"{pinned.max()}]")
    return kf, pinned


def _outputs_of(d: Path) -> dict:
    out = {}
    for p in sorted(d.rglob("*")):
        if p.is_file() and p.name != "manifest.json":
            out[p.relative_to(d).as_posix()] = p.stat().st_size
    return out


def _publish(staging: Path, final: Path, key: str, keep: Callable[[dict], bool]) -> str:
    """Rename a complete staging directory into place; 'published' or 'existing' (a complete
    output with the same key that ``keep(manifest)`` accepts was already there)."""
    try:
        os.rename(staging, final)
        return "published"
    except OSError:
        if not (final.exists() or final.is_symlink()):
            raise
    m = _manifest_matches(final, key)
    if m is not None and keep(m):  # another attempt finished first
        shutil.rmtree(staging, ignore_errors=True)
        return "existing"
    if not final.is_dir() or final.is_symlink() or (
            any(final.iterdir()) and not (final / "manifest.json").is_file()
            and not (final / "report.json").is_file()):
        shutil.rmtree(staging, ignore_errors=True)
        raise ShellsplineError(f"refusing to replace '{final}': it does not look like an "
                               "earlier output (no manifest.json or report.json)")
    from .io.sequences import move_into_place

    move_into_place(staging, final, overwrite=True)  # old output set aside, then removed
    return "published"


def _run_sequence(spec: SequenceSpec, key: str | None, inner_workers: int = 1,
                  emit: Callable[[dict], None] | None = None, run_id: str = "",
                  force: bool = False) -> dict:
    """Interpolate and write one sequence; never raises except KeyboardInterrupt.

    An output that is already complete with a matching manifest is left untouched (unless
    ``force``, in which case only one written by this run, ``run_id``, is kept): a task that
    runs twice neither rewrites nor duplicates it.

    Returns the outcome record (``status`` 'done' or 'failed', ``reason``, ``warning``,
    ``seconds``, ``frames``, ``vertices``, ``metrics``...).
    """
    from .io import write_sequence
    from .pipeline import interpolate

    from .parallel import parent_alive

    t0 = time.perf_counter()
    final = Path(spec.out)
    outcome = {"name": spec.name, "status": "failed", "reason": "", "warning": "",
               "seconds": 0.0, "frames": None, "vertices": None, "out": str(final),
               "worker": f"{socket.gethostname()}:{os.getpid()}"}
    staging = None
    try:
        digest = _input_digest(spec)
        my_key = _sequence_key(spec, digest)  # from the bytes read now (the planner's key
        # differs only if an input changed meanwhile; the manifest records what was read)

        def keep(m):
            return not force or m.get("run") == run_id

        m = _manifest_matches(final, my_key)
        if m is not None and keep(m):  # complete already: never rewritten
            this_run = bool(run_id) and m.get("run") == run_id
            outcome.update(status="done" if this_run else "skipped",
                           reason="completed by an earlier attempt of this run" if this_run
                           else "up to date (manifest matches)",
                           warning=m.get("warning", ""), frames=m.get("frames"),
                           vertices=m.get("vertices"))
            return outcome
        kf, pinned = _keyframes_of(spec)
        p = spec.params
        gn_options = {} if p["max_iter"] is None else {"max_iter": p["max_iter"]}
        solver_options = {}
        if p["method"] == "nonlinear":
            solver_options["max_time_s"] = 600.0 if p["max_time"] is None else p["max_time"]

        def progress(ev):
            if emit is not None and ev.get("kind") in ("stage_end", "message"):
                emit(dict(ev))

        t_read = time.perf_counter() - t0
        res = interpolate(kf, K=p["K"], method=p["method"], bc=p["bc"], eta=p["eta"],
                             mu=p["mu"], lam=p["lam"], reference=p["reference"],
                             pinned=pinned, workers=inner_workers, gn_options=gn_options,
                             solver_options=solver_options, coarse=p["coarse"],
                             fine=p["fine"], progress=progress)
        report = res.report
        report["timings"]["read"] = t_read
        metrics = sequence_metrics(res.V, kf.V, res.frames, report)
        if spec.delay:
            time.sleep(spec.delay)
        t_w = time.perf_counter()
        final.parent.mkdir(parents=True, exist_ok=True)
        staging = final.parent / f".{final.name}.stage-{secrets.token_hex(6)}"
        protect = list(spec.keyframes) + [q for q in (spec.frames_path, spec.pinned_path) if q]
        # the input's polygons and vertex numbering written back (real exports)
        V_out = res.V if res.source is None else res.source.expand(res.V, res.frames, res.K,
                                                                   p["bc"])
        from .io.usd import conventional_up_axis  # the input's convention, for a USD stage

        up = "z" if spec.keyframes and conventional_up_axis(spec.keyframes[0]) == "z" else "y"
        write_sequence(staging, V_out, res.F, report, fmt=spec.formats[0],
                          protect=protect, workers=inner_workers, source=res.source, up_axis=up)
        for fmt in spec.formats[1:]:
            write_sequence(staging / fmt, V_out, res.F, report, fmt=fmt, protect=protect,
                              workers=inner_workers, source=res.source, up_axis=up)
        _write_json_atomic(staging / "metrics.json",
                           {**metrics, "keyframe_frames": [int(f) for f in res.frames]})
        if emit is not None:
            emit({"kind": "stage_end", "stage": "write", "seconds": time.perf_counter() - t_w})
        if spec.render or spec.plots:
            t_r = time.perf_counter()
            _render(spec, staging, res)
            if emit is not None:
                emit({"kind": "stage_end", "stage": "render",
                      "seconds": time.perf_counter() - t_r})
        warning = _quality_warning(report)
        manifest = {
            "format": MANIFEST_FORMAT, "key": my_key, "sequence": spec.name, "run": run_id,
            "shellspline_version": __version__, "created": _now(),
            "inputs": digest, "parameters": spec.key_parameters(),
            "frames": int(res.K + 1), "vertices": int(res.V.shape[1]),
            "warning": warning, "worker": outcome["worker"],
            "seconds": time.perf_counter() - t0, "outputs": _outputs_of(staging),
        }
        _write_json_atomic(staging / "manifest.json", manifest)
        if not parent_alive():  # an orphaned worker: the batch that wanted this is gone
            raise KeyboardInterrupt
        state = _publish(staging, final, my_key, keep)
        staging = None
        outcome.update(status="done", warning=warning, frames=int(res.K + 1),
                       vertices=int(res.V.shape[1]))
        if state == "existing":
            outcome["reason"] = "an identical output appeared meanwhile; kept it"
    except Exception as exc:  # one failing sequence never stops the others
        outcome.update(status="failed", reason=_one_line(exc))
    finally:
        if staging is not None:
            shutil.rmtree(staging, ignore_errors=True)
        outcome["seconds"] = time.perf_counter() - t0
    return outcome


def _render(spec: SequenceSpec, staging: Path, res) -> None:
    try:
        from . import viz
    except ImportError as exc:
        raise ShellsplineError(f"rendering needs the viz module and its extra "
                               f"(pip install \"shellspline[viz]\"): {_one_line(exc)}") from None
    src = (res.V, res.F, res.frames)  # keyframes drawn gray
    if "strip" in spec.render:
        viz.render_strip(src, staging / "strip.png")
    if "gif" in spec.render:
        viz.render_animation(src, staging / "animation.gif")
    if "half_axes" in spec.plots:
        from .metrics import half_axes

        viz.plot_half_axes({spec.name: half_axes(res.V)}, staging / "half_axes.png",
                           frames=res.frames)


# --------------------------------------------------------------------------------------
# Executors
# --------------------------------------------------------------------------------------
def _raise_interrupt(signum, frame):
    raise KeyboardInterrupt


_STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


@contextlib.contextmanager
def _stop_signals_blocked():
    """Hold SIGINT/SIGTERM while a worker is started: it inherits the mask and unblocks them
    once its own handlers are set, and the parent has registered it before a pending
    Ctrl-C interrupts the parent."""
    if not hasattr(signal, "pthread_sigmask"):  # pragma: no cover - not POSIX
        yield
        return
    old = signal.pthread_sigmask(signal.SIG_BLOCK, _STOP_SIGNALS)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)


def _child_main(conn, spec, key, inner_workers, run_id, force, parent_pid, pdeathsig):
    """Entry point of a local worker process: run one sequence, send events and the outcome.

    Ctrl-C is the parent's business (a terminal sends SIGINT to every process of the job):
    the worker ignores SIGINT and unwinds on the parent's SIGTERM, removing its staging
    directory. It receives SIGTERM too when the parent dies, whatever killed it
    (:func:`shellspline.parallel.die_with_parent`), and closes its copy of the inherited
    lock file, so an orphan neither keeps the output root locked nor publishes a sequence.
    """
    from .parallel import die_with_parent

    for fh in list(_HELD_LOCKS):  # forked: the parent's lock stays the parent's
        fh.close()
    _HELD_LOCKS.clear()
    signal.signal(signal.SIGTERM, _raise_interrupt)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    die_with_parent(parent_pid, signal.SIGTERM, pdeathsig)
    if hasattr(signal, "pthread_sigmask"):
        signal.pthread_sigmask(signal.SIG_UNBLOCK, _STOP_SIGNALS)
    try:
        from threadpoolctl import threadpool_limits

        # the process pool is the parallelism: BLAS threads on top only oversubscribe
        threadpool_limits(limits=max(1, inner_workers))
    except ImportError:  # pragma: no cover - a required dependency
        pass
    try:
        outcome = _run_sequence(spec, key, inner_workers,
                                emit=lambda ev: conn.send(("event", spec.name, ev)),
                                run_id=run_id, force=force)
        conn.send(("result", spec.name, outcome))
    except KeyboardInterrupt:
        os._exit(130)
    finally:
        conn.close()


def _inner_workers(n_seq: int, workers: int) -> list[int]:
    """Processes inside each sequence: spare workers go to the first sequences."""
    if n_seq >= workers:
        return [1] * n_seq
    base, extra = divmod(workers, n_seq)
    return [base + (1 if i < extra else 0) for i in range(n_seq)]


def _drain(conn, on_event, outcomes) -> bool:
    """Read every message waiting on a worker's pipe; True once the pipe is closed."""
    try:
        while conn.poll():
            kind, name, payload = conn.recv()
            if kind == "event":
                on_event({"kind": "sequence_event", "name": name, "event": payload})
            else:
                outcomes[name] = payload
                on_event({"kind": "sequence_end", "name": name, "outcome": payload})
    except (EOFError, OSError):
        return True
    return False


def _run_local(todo, workers, on_event, outcomes, run_id, force):
    """One forked (or spawned) process per sequence, at most ``workers`` at a time."""
    from multiprocessing.connection import wait

    import threading

    from .parallel import start_method, stop_processes

    ctx = mp.get_context(start_method())
    # the Linux parent-death signal follows the forking thread: armed only from the main one
    ids = (os.getpid(), threading.current_thread() is threading.main_thread())
    inner = _inner_workers(len(todo), workers)
    queue = list(zip(todo, inner))
    queue.reverse()
    running = {}  # conn -> (proc, spec)
    slots = min(workers, len(todo))
    try:
        while queue or running:
            while queue and len(running) < slots:
                (spec, key), n_inner = queue.pop()
                parent_conn, child_conn = ctx.Pipe(duplex=False)
                proc = ctx.Process(target=_child_main, args=(child_conn, spec, key, n_inner,
                                                                    run_id, force, *ids),
                                   name=f"shellspline-batch-{spec.name}")
                with _stop_signals_blocked():
                    proc.start()
                    running[parent_conn] = (proc, spec)
                child_conn.close()
                on_event({"kind": "sequence_start", "name": spec.name})
            ready = set(wait(list(running) + [r[0].sentinel for r in running.values()],
                             timeout=1.0))
            for conn in list(running):
                proc, spec = running[conn]
                if conn not in ready and proc.sentinel not in ready:
                    continue
                eof = _drain(conn, on_event, outcomes)
                if not eof and proc.is_alive():
                    continue
                proc.join()
                _drain(conn, on_event, outcomes)  # anything sent just before the exit
                conn.close()
                del running[conn]
                if spec.name not in outcomes:  # the process died without an outcome
                    code = proc.exitcode
                    why = (f"worker process killed by signal {-code}" if code and code < 0
                           else f"worker process exited with code {code} without a result")
                    o = {"name": spec.name, "status": "failed", "reason": why,
                         "warning": "", "seconds": 0.0, "frames": None, "vertices": None,
                         "out": spec.out, "worker": f"{socket.gethostname()}:{proc.pid}"}
                    outcomes[spec.name] = o
                    on_event({"kind": "sequence_end", "name": spec.name, "outcome": o})
            on_event({"kind": "tick"})
    except KeyboardInterrupt:
        # SIGTERM: a child unwinds and removes its staging directory; one still busy after
        # the grace time is killed (run_batch then removes what it left)
        stop_processes([proc for proc, spec in running.values()])
        raise


def _import_distributed():
    try:
        import distributed
    except ImportError:
        raise ShellsplineError('the Dask executor needs dask.distributed: pip install '
                               '"shellspline[dask]"') from None
    return distributed


def _dask_task(spec: SequenceSpec, key: str | None, run_id: str, force: bool) -> dict:
    """A Dask task: one whole sequence (the task reads or generates its own inputs)."""
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=1):
        return _run_sequence(spec, key, 1, emit=None, run_id=run_id, force=force)


def _run_dask(todo, workers, address, on_event, outcomes, run_id, force):
    distributed = _import_distributed()
    cluster = None
    try:
        if address is None:
            cluster = distributed.LocalCluster(n_workers=workers, threads_per_worker=1,
                                               processes=True, host="127.0.0.1",
                                               dashboard_address=None)
            client = distributed.Client(cluster)
        else:
            try:
                client = distributed.Client(address, timeout="10s")
            except (OSError, TimeoutError) as exc:
                raise ShellsplineError(f"cannot connect to the Dask scheduler at {address}: "
                                       f"{_one_line(exc)}") from None
    except BaseException:
        if cluster is not None:
            cluster.close()
        raise
    futures = {}
    try:
        for spec, key in todo:
            fut = client.submit(_dask_task, spec, key, run_id, force,
                                key=f"shellspline-{spec.name}-{run_id}", pure=False)
            futures[fut] = spec
            on_event({"kind": "sequence_start", "name": spec.name})
        for fut in distributed.as_completed(list(futures)):
            spec = futures[fut]
            try:
                o = fut.result()
            except Exception as exc:  # KilledWorker after repeated worker deaths, ...
                o = {"name": spec.name, "status": "failed", "reason": _one_line(exc),
                     "warning": "", "seconds": 0.0, "frames": None, "vertices": None,
                     "out": spec.out, "worker": "dask"}
            outcomes[spec.name] = o
            on_event({"kind": "sequence_end", "name": spec.name, "outcome": o})
    except KeyboardInterrupt:
        client.cancel(list(futures))
        raise
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


# --------------------------------------------------------------------------------------
# The batch
# --------------------------------------------------------------------------------------
@dataclass
class BatchSummary:
    """What :func:`run_batch` returns (also written to ``OUT/summary.json``).

    Attributes
    ----------
    job : str
    output : Path
    sequences : list of dict
        One outcome per sequence, in job order: ``name``, ``status`` ('done', 'skipped',
        'failed', 'interrupted'), ``reason`` (one line), ``warning`` (quality or convergence
        problem of a written output), ``seconds``, ``frames``, ``vertices``, ``out``.
    regression : dict or None
        ``{"passed": bool, "checks": [{"sequence", "metric", "ok", "deviation", ...}]}``.
    interrupted : bool
    interrupt_exit : int
        The exit code of an interrupted run: 130 after Ctrl-C/SIGINT, 143 after SIGTERM
        (``128 +`` the signal).
    seconds : float
    executor : str
    workers : int
    errors : list of str
        Job-level problems (a job plot that failed).
    """

    job: str
    output: Path
    sequences: list
    regression: dict | None = None
    interrupted: bool = False
    interrupt_exit: int = EXIT_INTERRUPTED
    seconds: float = 0.0
    executor: str = "local"
    workers: int = 1
    scheduler: str | None = None
    errors: list = field(default_factory=list)

    def count(self, status: str) -> int:
        return sum(o["status"] == status for o in self.sequences)

    @property
    def exit_code(self) -> int:
        """0 all sequences done or up to date (and the regression passed); 1 a sequence
        failed, an output has a quality warning or the regression failed; 130 interrupted
        (143 by SIGTERM)."""
        if self.interrupted:
            return self.interrupt_exit
        bad = any(o["status"] == "failed" or o.get("warning") for o in self.sequences)
        if bad or self.errors or (self.regression is not None and
                                  not self.regression["passed"]):
            return EXIT_FAILED
        return EXIT_OK

    def to_dict(self) -> dict:

        frames = sum(o["frames"] or 0 for o in self.sequences if o["status"] == "done")
        return {
            "job": self.job, "output": str(self.output), "executor": self.executor,
            "workers": self.workers, "scheduler": self.scheduler,
            "shellspline_version": __version__, "finished": _now(),
            "seconds": self.seconds, "interrupted": self.interrupted,
            "counts": {s: self.count(s) for s in ("done", "skipped", "failed",
                                                  "interrupted")},
            "frames_written": frames, "exit_code": self.exit_code,
            "sequences": [{k: v for k, v in o.items() if k != "metrics"}
                          for o in self.sequences],
            "regression": self.regression, "errors": list(self.errors),
        }

    def table(self) -> str:
        """The summary as a fixed-width text table (one line per sequence)."""
        rows = [("sequence", "status", "frames", "seconds", "reason")]
        for o in self.sequences:
            why = o.get("reason") or ""
            if o.get("warning"):
                why = (why + "; " if why else "") + "warning: " + o["warning"]
            rows.append((o["name"], o["status"], "-" if o["frames"] is None else
                         str(o["frames"]), f"{o['seconds']:.2f}", why))
        w = [max(len(r[i]) for r in rows) for i in range(4)]
        lines = ["  ".join([r[0].ljust(w[0]), r[1].ljust(w[1]), r[2].rjust(w[2]),
                            r[3].rjust(w[3]), r[4]]).rstrip() for r in rows]
        lines.insert(1, "  ".join("-" * x for x in w) + "  ------")
        c = {s: self.count(s) for s in ("done", "skipped", "failed", "interrupted")}
        lines.append(f"{c['done']} done, {c['skipped']} skipped (up to date), {c['failed']} "
                     f"failed" + (f", {c['interrupted']} interrupted" if c['interrupted'] else "")
                     + f" in {self.seconds:.1f} s; output {self.output}")
        if self.regression is not None:
            lines.append(regression_table(self.regression))
        for e in self.errors:
            lines.append(f"error: {e}")
        return "\n".join(lines)


def _cleanup_leftovers(root: Path) -> list[str]:
    """Remove staging/temporary entries left in the output root by a killed run."""
    removed = []
    try:
        entries = list(root.iterdir())
    except OSError:
        return removed
    for p in entries:
        n = p.name
        if n.startswith(".") and any(m in n for m in _TEMP_MARKERS):
            if p.is_dir() and not p.is_symlink():
                shutil.rmtree(p, ignore_errors=True)
            else:
                try:
                    p.unlink()
                except OSError:
                    continue
            removed.append(n)
    return removed


_HELD_LOCKS: list = []  # open lock files of this process (a forked worker closes its copies)


class _Lock:
    """An exclusive lock on the output root (so leftovers cannot belong to a live run).

    The lock is an ``flock`` on ``OUT/.batch.lock``; it lasts while any process holds the open
    file, so forked workers close their inherited copy first (:func:`_child_main`): a worker
    orphaned by a killed batch never keeps the root locked.
    """

    def __init__(self, root: Path):
        self.path = root / LOCK_NAME
        self.fh = None

    def __enter__(self):
        self.fh = open(self.path, "a+")
        _HELD_LOCKS.append(self.fh)
        try:
            import fcntl
        except ImportError:  # pragma: no cover - not POSIX: no locking
            return self
        try:
            fcntl.flock(self.fh.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            _HELD_LOCKS.remove(self.fh)
            self.fh.close()
            raise ShellsplineError(f"{self.path.parent}: another shellspline batch is running "
                                   f"on this output root (lock {self.path})") from None
        return self

    def __exit__(self, *exc):
        if self.fh in _HELD_LOCKS:
            _HELD_LOCKS.remove(self.fh)
        self.fh.close()  # closing releases the flock


def _setup_log(root: Path):
    handler = logging.FileHandler(root / LOG_NAME, encoding="utf-8")
    handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(message)s"))
    _log.addHandler(handler)
    _log.setLevel(logging.INFO)
    _log.propagate = False
    return handler


def _log_event(ev: dict) -> None:
    k = ev.get("kind")
    if k == "sequence_start":
        _log.info("%s: started", ev["name"])
    elif k == "sequence_event":
        e = ev["event"]
        if e.get("kind") == "stage_end":
            _log.info("%s: %s %.3f s", ev["name"], e["stage"], e["seconds"])
        elif e.get("kind") == "message":
            _log.info("%s: note: %s", ev["name"], e["text"])
    elif k == "sequence_end":
        o = ev["outcome"]
        msg = f"{o['name']}: {o['status']} in {o['seconds']:.2f} s"
        if o.get("reason"):
            msg += f": {o['reason']}"
        if o.get("warning"):
            msg += f" (warning: {o['warning']})"
        (_log.warning if o["status"] == "failed" else _log.info)("%s", msg)
    elif k == "message":
        _log.info("%s", ev["text"])


def run_batch(job: Job, workers: int | None = None, scheduler: str | None = None, *,
              executor: str | None = None, force: bool = False,
              progress: Callable[[dict], None] | None = None,
              write_expected: bool = False) -> BatchSummary:
    """Run a batch job; never raises for a failing sequence.

    Parameters
    ----------
    job : Job
        From :func:`load_job`.
    workers : int, optional
        Local worker processes (default ``job.workers``). With fewer sequences to run than
        workers, the spare workers reconstruct frames inside the sequences. With the Dask
        executor and no scheduler address: the workers of the ``LocalCluster``.
    scheduler : str, optional
        ``tcp://HOST:PORT`` of a running Dask scheduler; implies the Dask executor.
    executor : {"local", "dask"}, optional
        Default ``job.executor`` ("dask" when a scheduler is given).
    force : bool
        Redo every sequence even when its manifest matches.
    progress : callable(dict), optional
        Receives events: ``batch_start`` (``total``, ``to_run``, ``skipped``),
        ``sequence_start``/``sequence_end`` (``name``, ``outcome``), ``sequence_event``
        (``name``, ``event``: a pipeline stage_end/message event), ``tick``, ``message``.
    write_expected : bool
        With a ``[regression]`` whose ``expected`` is a file: rewrite that file from this
        run's metrics (when every sequence succeeded) instead of comparing.

    Returns
    -------
    BatchSummary
        Also written to ``job.output/summary.json``; ``batch.log`` in the same directory
        logs every run. After Ctrl-C (or SIGTERM through the CLI) the running sequences are
        abandoned (their staging directories removed), the summary is written with
        ``interrupted=True`` and ``exit_code`` 130; completed sequences are kept.

    Raises
    ------
    ShellsplineError
        Before anything runs: the output root is locked by another run, Dask is missing, the
        scheduler cannot be reached.
    """
    t0 = time.perf_counter()
    workers = job.workers if workers is None else int(workers)
    if workers < 1:
        raise ShellsplineError(f"workers must be >= 1, got {workers}")
    if scheduler is not None:
        scheduler = check_scheduler_address(scheduler)
    else:
        scheduler = job.scheduler
    executor = executor or ("dask" if scheduler else job.executor)
    if executor not in ("local", "dask"):
        raise ShellsplineError(f"executor must be 'local' or 'dask', got {executor!r}")
    if executor == "dask":
        _import_distributed()
    _check_viz_available(job)
    if write_expected and (job.regression is None or job.regression["expected_path"] is None):
        raise ShellsplineError(f"{job.path}: --write-expected needs a [regression] section "
                               "whose 'expected' is a JSON file")
    if job.regression is not None and job.regression["expected"] is None and \
            not write_expected:
        raise ShellsplineError(f"{job.path}: [regression] expected values file "
                               f"'{job.regression['expected_path']}' does not exist (create it "
                               "with --write-expected)")
    emit = progress or (lambda ev: None)
    root = job.output
    if root.exists() and not root.is_dir():
        raise ShellsplineError(f"output root '{root}' exists and is not a directory")
    try:
        root.mkdir(parents=True, exist_ok=True)
        (root / LOCK_NAME).touch()
    except OSError as exc:
        raise ShellsplineError(f"output root '{root}': cannot write there: "
                               f"{exc.strerror or exc}") from None
    from .parallel import interrupt_exit_code

    outcomes: dict[str, dict] = {}
    interrupted, interrupt_exit = False, EXIT_INTERRUPTED
    run_id = f"{_dt.datetime.now():%Y%m%dT%H%M%S}-{secrets.token_hex(4)}"
    with _Lock(root):
        handler = _setup_log(root)
        try:
            def on_event(ev):
                _log_event(ev)
                emit(ev)

            removed = _cleanup_leftovers(root)
            _log.info("job %s (%s): %d sequences, executor %s%s, %d workers", job.name,
                      job.path, len(job.sequences), executor,
                      f" at {scheduler}" if scheduler else "", workers)
            if removed:
                on_event({"kind": "message", "text": f"removed {len(removed)} leftover "
                                                     "temporary entries of an interrupted run"})
            todo = []
            for spec in job.sequences:
                try:
                    key = _sequence_key(spec, _input_digest(spec))
                except OSError:
                    key = None  # the task will report the unreadable input
                m = None if force or key is None else _manifest_matches(spec.out, key)
                if m is not None:
                    o = {"name": spec.name, "status": "skipped",
                         "reason": "up to date (manifest matches)",
                         "warning": m.get("warning", ""), "seconds": 0.0,
                         "frames": m.get("frames"), "vertices": m.get("vertices"),
                         "out": spec.out, "worker": ""}
                    outcomes[spec.name] = o
                    _log.info("%s: skipped (manifest matches)", spec.name)
                else:
                    todo.append((spec, key))
            emit({"kind": "batch_start", "total": len(job.sequences), "to_run": len(todo),
                  "skipped": len(job.sequences) - len(todo), "executor": executor,
                  "workers": workers})
            try:
                if todo:
                    if executor == "local":
                        _run_local(todo, workers, on_event, outcomes, run_id, force)
                    else:
                        _run_dask(todo, workers, scheduler, on_event, outcomes, run_id,
                                  force)
            except KeyboardInterrupt as exc:
                interrupted, interrupt_exit = True, interrupt_exit_code(exc)
                _log.warning("interrupted (%s)", str(exc) or "SIGINT")
            _cleanup_leftovers(root)
            seqs = []
            for spec in job.sequences:
                o = outcomes.get(spec.name) or {
                    "name": spec.name, "status": "interrupted",
                    "reason": "not finished: the batch was interrupted", "warning": "",
                    "seconds": 0.0, "frames": None, "vertices": None, "out": spec.out,
                    "worker": ""}
                seqs.append(o)
            summary = BatchSummary(job=job.name, output=root, sequences=seqs,
                                   interrupted=interrupted, interrupt_exit=interrupt_exit,
                                   executor=executor, workers=workers, scheduler=scheduler)
            if job.regression is not None and not interrupted:
                metrics = {o["name"]: _read_metrics(Path(o["out"])) for o in seqs
                           if o["status"] in ("done", "skipped")}
                if write_expected:
                    _write_expected(job, metrics, seqs)
                summary.regression = compare_regression(job.regression, metrics)
            if not interrupted:
                _job_plots(job, seqs, summary)
            summary.seconds = time.perf_counter() - t0
            _write_json_atomic(root / SUMMARY_NAME, summary.to_dict())
            for line in summary.table().splitlines():
                _log.info("%s", line)
            _log.info("exit code %d", summary.exit_code)
            return summary
        finally:
            _log.removeHandler(handler)
            handler.close()


def _check_viz_available(job: Job) -> None:
    """Renders and plots need the viz extra: fail before anything runs, in one line."""
    import importlib.util

    need = set()
    for s in job.sequences:
        if s.render:
            need |= {"pyvista"} | ({"imageio"} if "gif" in s.render else set())
        if s.plots:
            need.add("matplotlib")
    missing = sorted(m for m in need if importlib.util.find_spec(m) is None)
    if missing:
        raise ShellsplineError(f"{job.path}: render/plots need {', '.join(missing)}: pip "
                               'install "shellspline[viz]"')


def _read_metrics(out: Path) -> dict | None:
    try:
        return json.loads((out / "metrics.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None


def _write_expected(job: Job, metrics: dict, seqs: list) -> None:
    bad = [o["name"] for o in seqs if o["status"] not in ("done", "skipped")]
    if bad:
        raise ShellsplineError(f"not writing expected values: sequences {bad} did not finish")
    data = {"job": job.name, "written": _now(),
            "sequences": {name: {k: m[k] for k in REGRESSION_METRICS if k in m}
                          for name, m in metrics.items() if m is not None}}
    path = job.regression["expected_path"]
    _write_json_atomic(path, data)
    job.regression["expected"] = data["sequences"]


_DEFAULT_TOL = {"rtol": 1e-6, "atol": 1e-12, "mode": "close"}


def compare_regression(regression: dict, metrics: dict) -> dict:
    """Compare measured metrics with the expected values.

    Parameters
    ----------
    regression : dict
        ``Job.regression``.
    metrics : dict
        ``{sequence: metrics dict or None}``.

    Returns
    -------
    dict
        ``{"passed": bool, "checks": [...]}``; a check passes when every element satisfies
        ``|actual - expected| <= atol + rtol |expected|`` (mode ``close``),
        ``actual <= expected + atol + rtol |expected|`` (``max``) or
        ``actual >= expected - atol - rtol |expected|`` (``min``).
    """
    import numpy as np

    checks = []
    for sname, exp in regression["expected"].items():
        got = metrics.get(sname)
        for metric, ev in exp.items():
            tol = regression["tolerances"].get(metric, _DEFAULT_TOL)
            c = {"sequence": sname, "metric": metric, "mode": tol["mode"],
                 "rtol": tol["rtol"], "atol": tol["atol"]}
            if got is None or metric not in got:
                c.update(ok=False, deviation=None, note="no result")
                checks.append(c)
                continue
            try:
                e = np.asarray(ev, dtype=np.float64)
                a = np.asarray(got[metric], dtype=np.float64)
            except (TypeError, ValueError):
                c.update(ok=False, deviation=None, note="not numeric")
                checks.append(c)
                continue
            if e.shape != a.shape:
                c.update(ok=False, deviation=None,
                         note=f"shape {list(a.shape)} != expected {list(e.shape)}")
                checks.append(c)
                continue
            bound = tol["atol"] + tol["rtol"] * np.abs(e)
            if tol["mode"] == "close":
                dev = np.abs(a - e)
            elif tol["mode"] == "max":
                dev = a - e
            else:
                dev = e - a
            nan = ~np.isfinite(a) | ~np.isfinite(e)
            excess = np.where(nan, np.inf, dev - bound)
            worst = int(np.argmax(excess)) if excess.size else 0
            ok = bool(np.all(excess <= 0))
            c.update(ok=ok, deviation=float(dev.ravel()[worst]) if dev.size else 0.0,
                     bound=float(bound.ravel()[worst]) if bound.size else 0.0,
                     expected=float(e.ravel()[worst]) if e.size else None,
                     actual=float(a.ravel()[worst]) if a.size else None,
                     note="" if ok else (f"element {np.unravel_index(worst, e.shape)}"
                                         if e.ndim else ""))
            checks.append(c)
    return {"passed": all(c["ok"] for c in checks), "checks": checks}


def regression_table(regression: dict) -> str:
    """Fixed-width table of the regression checks."""
    rows = [("sequence", "metric", "mode", "expected", "actual", "deviation", "bound", "ok")]
    for c in regression["checks"]:
        def g(k):
            v = c.get(k)
            return "-" if v is None else f"{v:.4g}"
        rows.append((c["sequence"], c["metric"], c["mode"], g("expected"), g("actual"),
                     g("deviation"), g("bound"), ("ok" if c["ok"] else "REGRESSION")
                     + (f" ({c['note']})" if c.get("note") else "")))
    w = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    lines = ["  ".join(x.ljust(w[i]) if i < 3 else x.rjust(w[i]) if i < 7 else x
                       for i, x in enumerate(r)).rstrip() for r in rows]
    lines.insert(1, "  ".join("-" * x for x in w))
    n_bad = sum(not c["ok"] for c in regression["checks"])
    lines.append(f"regression: {'passed' if regression['passed'] else 'FAILED'} "
                 f"({len(regression['checks']) - n_bad}/{len(regression['checks'])} checks)")
    return "\n".join(lines)


def _job_plots(job: Job, seqs: list, summary: BatchSummary) -> None:
    names = [s.name for s in job.sequences if "half_axes" in s.plots]
    curves, frames = {}, None
    for o in seqs:
        if o["name"] in names and o["status"] in ("done", "skipped"):
            m = _read_metrics(Path(o["out"]))
            if m is not None:
                curves[o["name"]] = m["half_axes"]
                frames = m.get("keyframe_frames") if frames is None else frames
    if len(curves) < 2:
        return
    path = job.output / "half_axes.png"
    tmp = job.output / f".half_axes.tmp-{os.getpid()}-{secrets.token_hex(4)}.png"
    try:
        import numpy as np

        from . import viz

        viz.plot_half_axes({k: np.asarray(v) for k, v in curves.items()}, tmp, frames=frames)
        os.replace(tmp, path)
    except Exception as exc:
        summary.errors.append(f"job plot {path.name}: {_one_line(exc)}")
    finally:
        if tmp.exists():
            tmp.unlink()

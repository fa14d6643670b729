"""A batch job: the validated job file (:func:`load_job`) and its sequences.

A job file (``pipelines/*.toml``) lists sequences — directories found by a glob, explicit
keyframe files, or synthetic keyframes from :mod:`data_synth` — with defaults and
per-sequence overrides of the interpolation parameters. :func:`load_job` validates the whole
file up front, so that nothing fails for a reason the file could have told.

Paths in a job file are relative to the directory of the job file.
"""
from __future__ import annotations

import dataclasses
import glob
import json
import os
import re
from dataclasses import dataclass, field
from pathlib import Path

from ..errors import ShellsplineError
from .regression import load_regression
from .schema import (DEFAULTS, INTERPOLATION_KEYS, JOB_KEYS, PARAM_KEYS, SOURCE_KEYS,
                     check_name, check_param, is_int, job_error, read_toml, reject_unknown,
                     resolve, table)

__all__ = ["SequenceSpec", "Job", "load_job", "check_scheduler_address", "json_roundtrip"]


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
        fix_boundary, fade_angle, spline, transfer`` for :func:`shellspline.interpolate`.
    formats, render, plots : list of str
    delay : float
        Seconds to sleep between writing the staging directory and publishing it (a testing
        knob: a stop signal then finds a staging directory to remove; not in the manifest).
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
                     pinned_file, render, plots, delay, fade_angle, spline, transfer
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
    doc = read_toml(path)
    base = path.resolve().parent
    f = str(path)
    reject_unknown(f, doc, {"job", "defaults", "sequences", "regression"})
    head = _job_table(f, base, table(f"{f}: [job]", doc.get("job", {})), path.stem)
    defaults = _defaults_table(f, table(f"{f}: [defaults]", doc.get("defaults", {})))
    seqs = _sequences(f, base, head["output"], doc.get("sequences", []), defaults)
    names = {s.name for s in seqs}
    regression = None
    if "regression" in doc:
        regression = load_regression(f, base, table(f"{f}: [regression]", doc["regression"]),
                                     names)
    job = Job(path=path.resolve(), sequences=seqs, regression=regression, **head)
    _check_outputs_do_not_hold_inputs(job)
    return job


def _job_table(f: str, base: Path, jt: dict, stem: str) -> dict:
    """The ``[job]`` table checked: name, output, executor, scheduler, workers."""
    reject_unknown(f"{f}: [job]", jt, JOB_KEYS)
    name = jt.get("name", stem)
    if not isinstance(name, str) or not name.strip():
        raise job_error(f"{f}: [job] key 'name'", f"must be a non-empty string, got {name!r}")
    if "output" not in jt:
        raise job_error(f"{f}: [job]", "missing key 'output' (the output root directory)")
    if not isinstance(jt["output"], str) or not jt["output"].strip():
        raise job_error(f"{f}: [job] key 'output'", f"must be a path, got {jt['output']!r}")
    executor = jt.get("executor", "local")
    if executor not in ("local", "dask"):
        raise job_error(f"{f}: [job] key 'executor'",
                        f"must be 'local' or 'dask', got {executor!r}")
    scheduler = jt.get("scheduler")
    if scheduler is not None:
        scheduler = check_scheduler_address(scheduler, f"{f}: [job] key 'scheduler'")
    workers = jt.get("workers", 1)
    if not is_int(workers) or workers < 1:
        raise job_error(f"{f}: [job] key 'workers'", f"must be an integer >= 1, got {workers!r}")
    return {"name": name.strip(), "output": resolve(base, jt["output"]), "executor": executor,
            "scheduler": scheduler, "workers": int(workers)}


def _defaults_table(f: str, dt: dict) -> dict:
    """``[defaults]`` checked and merged over :data:`~shellspline.batch.schema.DEFAULTS`."""
    reject_unknown(f"{f}: [defaults]", dt, PARAM_KEYS | {"vertices"})
    defaults = dict(DEFAULTS)
    defaults.update({k: check_param(f"{f}: [defaults]", k, v) for k, v in dt.items()
                     if k != "vertices"})
    if "vertices" in dt:
        v = dt["vertices"]
        if not is_int(v) or v < 4:
            raise job_error(f"{f}: [defaults] key 'vertices'",
                            f"must be an integer >= 4, got {v!r}")
        defaults["vertices"] = int(v)
    return defaults


def _sequences(f, base, output, entries, defaults) -> list[SequenceSpec]:
    """Every ``[[sequences]]`` entry expanded into resolved specs with unique names."""
    if not isinstance(entries, list) or not entries or \
            not all(isinstance(e, dict) for e in entries):
        raise job_error(f, "needs at least one [[sequences]] entry")
    seqs: list[SequenceSpec] = []
    for i, e in enumerate(entries):
        where = f"{f}: [[sequences]] #{i + 1}"
        reject_unknown(where, e, PARAM_KEYS | SOURCE_KEYS)
        kinds = [k for k in ("glob", "keyframes", "synth") if k in e]
        if len(kinds) != 1:
            raise job_error(where, "needs exactly one of 'glob', 'keyframes', 'synth', got "
                                   f"{kinds or 'none'}")
        own = {k: check_param(where, k, v) for k, v in e.items() if k in PARAM_KEYS}
        for k in ("vertices", "synth_params"):
            if k in e and kinds[0] != "synth":
                raise job_error(f"{where} key '{k}'", "applies to synthetic sequences only")
        entry = _Entry(where, base, output, e, own, defaults)
        seqs.extend({"glob": entry.from_glob, "keyframes": entry.from_files,
                     "synth": entry.from_synth}[kinds[0]]())
    names = set()
    for s in seqs:
        if s.name in names:
            raise job_error(f, f"two sequences are named '{s.name}' (names must be unique; set "
                               "'name')")
        names.add(s.name)
    return seqs


def check_scheduler_address(addr, where: str = "--scheduler") -> str:
    """Return a Dask scheduler address after a syntax check (``tcp://HOST:PORT``)."""
    if not isinstance(addr, str) or not re.fullmatch(
            r"(?:(?:tcp|tls|ws|wss|ucx)://)?(?:\[[0-9a-fA-F:]+\]|[A-Za-z0-9_.-]+):\d{1,5}",
            addr.strip()):
        raise ShellsplineError(f"{where}: expected a scheduler address such as "
                               f"tcp://127.0.0.1:8786, got {addr!r}")
    addr = addr.strip()
    return addr if "://" in addr else "tcp://" + addr


class _Entry:
    """One ``[[sequences]]`` entry: its own keys over ``[defaults]``, expanded into specs."""

    def __init__(self, where, base, output, e, own, defaults):
        self.where, self.base, self.output, self.e = where, base, output, e
        self.own, self.defaults = own, defaults
        merged = dict(defaults)
        merged.pop("vertices", None)
        merged.update(own)
        self.merged = merged
        params = {k: merged[k] for k in INTERPOLATION_KEYS}
        ref_geodesic = str(params["reference"]).strip().lower() == "geodesic" and \
            params["method"] != "linear"
        if params["max_time"] is not None and params["method"] not in ("nonlinear",
                                                                       "geodesic") \
                and not ref_geodesic:
            # as `shellspline interpolate --max-time`: it also bounds the reference geodesic
            raise job_error(f"{where} key 'max_time'",
                            "applies to method = 'nonlinear' or 'geodesic' and to "
                            "reference = 'geodesic' only")
        _check_own_keys(where, params, own)
        self.common = dict(params=params, formats=merged["formats"], render=merged["render"],
                           plots=merged["plots"], delay=merged["delay"])
        name = e.get("name")
        if name is not None and (not isinstance(name, str) or not name):
            raise job_error(f"{where} key 'name'", f"must be a non-empty string, got {name!r}")
        self.name = name

    def frames_pinned(self, src_frames_path=None, src_pinned_path=None, src_frames=None,
                      src_pinned=None) -> dict:
        """``frames``, ``frames_path``, ``pinned``, ``pinned_path``: the entry's own values
        win, then the source's, then ``[defaults]``."""
        out = {}
        for key, src_path, src_val in (("frames", src_frames_path, src_frames),
                                       ("pinned", src_pinned_path, src_pinned)):
            if key in self.own:
                v, origin = self.own[key], "own"
            elif src_path is not None or src_val is not None:
                out[key], out[f"{key}_path"] = src_val, src_path
                continue
            else:
                v, origin = self.defaults[key], "defaults"
            out[key], out[f"{key}_path"] = self._value_or_file(key, v, origin)
        return out

    def check_frames_fit(self, name: str, fp: dict, n_keyframes: int) -> None:
        """Explicit ``frames`` (not a file) must give one frame per keyframe."""
        frames = fp.get("frames")
        if frames is None or len(frames) == n_keyframes:
            return
        w = self.where if "frames" in self.own else \
            self.where.split(": ")[0] + ": [defaults]"
        raise job_error(f"{w} key 'frames'", f"sequence '{name}': {len(frames)} frames "
                                             f"{list(frames)} for {n_keyframes} keyframes "
                                             "(one frame per keyframe)")

    def _value_or_file(self, key, v, origin):
        if not isinstance(v, str):
            return v, None
        if key == "frames" and re.fullmatch(r"[\s,0-9]+", v) and re.search(r"\d", v):
            w = self.where if origin == "own" else self.where.split(": ")[0] + ": [defaults]"
            return check_param(w, "frames", [int(t) for t in v.replace(",", " ").split()]), None
        p = resolve(self.base, v)
        if not p.is_file():
            w = self.where if origin == "own" else self.where.split(": ")[0] + ": [defaults]"
            raise job_error(f"{w} key '{key}'", f"file '{p}' does not exist")
        return None, str(p)

    def from_glob(self) -> list[SequenceSpec]:
        """One spec per directory the entry's glob matches."""
        where, pat = self.where, self.e["glob"]
        if not isinstance(pat, str) or not pat:
            raise job_error(f"{where} key 'glob'", f"must be a glob pattern, got {pat!r}")
        gp = Path(os.path.expanduser(pat))
        anchor, rel = (Path(gp.anchor), str(gp.relative_to(gp.anchor))) if gp.is_absolute() \
            else (self.base, pat)
        kfp = self.merged["keyframe_pattern"]
        # the output root (or a folder holding it) is no sequence, unless it holds keyframes:
        # then the job is refused (_check_outputs_do_not_hold_inputs)
        dirs = sorted((p.resolve() for p in visible_glob(anchor, rel) if p.is_dir() and not (
            _holds(p.resolve(), self.output) and not keyframe_files(p, kfp))),
            key=_natural_key)
        if not dirs:
            raise job_error(f"{where} key 'glob'", f"'{pat}' matches no directory (relative to "
                                                   f"{self.base})")
        template = self.name if self.name is not None else "{dir}"
        if "{dir}" not in template and len(dirs) > 1:
            raise job_error(f"{where} key 'name'", f"the glob matches {len(dirs)} directories: "
                                                   "the name needs '{dir}'")
        return [self._directory_spec(check_name(where, template.replace("{dir}", d.name)), d,
                                     kfp) for d in dirs]

    def _directory_spec(self, sname, d, kfp) -> SequenceSpec:
        files = keyframe_files(d, kfp)
        ff = d / self.merged["frames_file"] if self.merged["frames_file"] else None
        pf = d / self.merged["pinned_file"] if self.merged["pinned_file"] else None
        fp = self.frames_pinned(str(ff) if ff is not None and ff.is_file() else None,
                                str(pf) if pf is not None and pf.is_file() else None)
        if len(files) >= 2:  # fewer: the sequence fails with its own reason
            self.check_frames_fit(sname, fp, len(files))
        return SequenceSpec(name=sname, out=str(self.output / sname), source="files",
                            keyframes=[str(p) for p in files], directory=str(d),
                            keyframe_pattern=kfp, **fp, **self.common)

    def _named(self, kind) -> str:
        if self.name is None:
            raise job_error(self.where, f"a '{kind}' entry needs a 'name'")
        return check_name(self.where, self.name)

    def from_files(self) -> list[SequenceSpec]:
        """The spec of an explicit list of keyframe files."""
        name, kfs = self._named("keyframes"), self.e["keyframes"]
        if not isinstance(kfs, list) or len(kfs) < 2 or \
                not all(isinstance(p, str) and p for p in kfs):
            raise job_error(f"{self.where} key 'keyframes'",
                            f"must list at least 2 files, got {kfs!r}")
        paths = [str(resolve(self.base, p)) for p in kfs]
        missing = [p for p in paths if not Path(p).is_file()]
        if missing:
            raise job_error(f"{self.where} key 'keyframes'",
                            f"file '{missing[0]}' does not exist")
        fp = self.frames_pinned()
        self.check_frames_fit(name, fp, len(paths))
        return [SequenceSpec(name=name, out=str(self.output / name), source="files",
                             keyframes=paths, **fp, **self.common)]

    def from_synth(self) -> list[SequenceSpec]:
        """The spec of synthetic keyframes (the generator runs here once, to validate)."""
        import data_synth

        where, name, gen = self.where, self._named("synth"), self.e["synth"]
        if gen not in data_synth.NAMES:
            raise job_error(f"{where} key 'synth'", f"must be one of "
                                                    f"{', '.join(data_synth.NAMES)}, got {gen!r}")
        vertices = self.e.get("vertices", self.defaults.get("vertices"))
        if vertices is not None and (not is_int(vertices) or vertices < 4):
            raise job_error(f"{where} key 'vertices'",
                            f"must be an integer >= 4, got {vertices!r}")
        sp = table(f"{where} key 'synth_params'", self.e.get("synth_params", {}))
        try:  # validate the generator parameters here, not in a worker
            data = data_synth.generate(gen, vertices, **json_roundtrip(sp))
        except (TypeError, ValueError) as exc:
            raise job_error(f"{where} key 'synth_params'", " ".join(str(exc).split())) from None
        src_pinned = None if data.get("pinned") is None else [int(x) for x in data["pinned"]]
        fp = self.frames_pinned(src_frames=[int(x) for x in data["frames"]],
                                src_pinned=src_pinned)
        self.check_frames_fit(name, fp, int(data["V"].shape[0]))
        return [SequenceSpec(name=name, out=str(self.output / name), source="synth",
                             synth={"name": gen, "vertices": vertices, "params": sp}, **fp,
                             **self.common)]


#: Job keys that only some runs use, as :func:`shellspline.interpolate` names them.
_CONDITIONAL_KEYS = {"coarse": "coarse", "fine": "fine", "transfer": "transfer",
                     "reference": "reference", "spline": "spline", "fade_angle": "fade_angle",
                     "max_iter": "gn_options"}
_JOB_KEYS = {v: k for k, v in _CONDITIONAL_KEYS.items()}
_NO_VALUE = object()


def _job_spelling(option: str, value=_NO_VALUE) -> str:
    key = _JOB_KEYS.get(option, option)
    if option == "gn_options" and isinstance(value, dict):
        value = value.get("max_iter", _NO_VALUE)
    return f"'{key}'" if value is _NO_VALUE else f"{key} = {value!r}"


def _set_keys(params: dict, keys) -> dict:
    """``{option: value}`` of the :data:`_CONDITIONAL_KEYS` among ``keys`` that ``params``
    sets, as :func:`~shellspline.pipeline.interpolation.inapplicable_options` takes them."""
    return {_CONDITIONAL_KEYS[k]: {"max_iter": params[k]} if k == "max_iter" else params[k]
            for k in keys if k in _CONDITIONAL_KEYS and params[k] is not None
            and not (k == "fine" and not params[k])}


def _check_own_keys(where: str, params: dict, own: dict) -> None:
    """A key of the sequence's own entry that its run cannot use is a :class:`JobError`, as
    the CLI refuses such an option
    (:func:`~shellspline.pipeline.interpolation.inapplicable_options`); one taken from
    ``[defaults]`` is not (:func:`applicable_params`)."""
    from ..pipeline.interpolation import inapplicable_options

    refused, _ = inapplicable_options(_set_keys(params, own), params["method"],
                                      params["coarse"], spell=_job_spelling)
    if refused:
        raise job_error(where, refused[0][1])


def applicable_params(params: dict) -> dict:
    """``params`` (a :attr:`SequenceSpec.params`) for :func:`shellspline.interpolate`: the
    keys the sequence's method cannot use, which it took from ``[defaults]`` (its own ones
    are refused when the job is loaded), at their defaults. One ``[defaults]`` table serves
    every sequence: ``pipelines/regression_ellipsoids.toml`` sets the paper's spline for its
    LΘA sequences beside a ``method = "linear"`` baseline."""
    from ..pipeline.interpolation import inapplicable_options

    out = dict(params)
    set_away = [k for k in params if params[k] != DEFAULTS.get(k)]
    refused, _ = inapplicable_options(_set_keys(params, set_away), params["method"],
                                      params["coarse"])
    for option, _ in refused:
        out[_JOB_KEYS[option]] = DEFAULTS[_JOB_KEYS[option]]
    return out


def json_roundtrip(obj):
    """``obj`` through JSON and back (TOML values as plain lists, dicts and numbers)."""
    return json.loads(json.dumps(obj))


def _holds(d: Path, root: Path) -> bool:
    """Whether directory ``d`` is the output root ``root`` or one of its ancestors: a glob
    such as ``shots/*`` with ``output = "shots/_out"`` must not take the job's own output
    root for a sequence directory on the next run."""
    return d == root or d in root.parents


def keyframe_files(d: Path, pattern: str) -> list[Path]:
    """The files of directory ``d`` matching ``pattern``, in natural sort order.

    Hidden files (a name that starts with ``.``) are left out unless the pattern starts with
    ``.`` (:func:`visible_glob`), as :func:`shellspline.io.sequences.frame_files` leaves them
    out: macOS writes a ``._pose_01.obj`` resource fork (binary) beside every file on a
    FAT/exFAT drive or a network share."""
    return sorted((p for p in visible_glob(d, pattern) if p.is_file()), key=_natural_key)


def visible_glob(anchor: Path, pattern: str) -> list[Path]:
    """The paths matching the glob ``pattern`` (relative to ``anchor``, or absolute), hidden
    entries left out as a shell leaves them out.

    A name that starts with ``.`` is matched only by a pattern component that starts with
    ``.`` too: ``shots/*`` leaves out ``shots/.Trashes`` and ``shots/.git``, ``shots/**``
    every hidden folder below ``shots`` (and what they hold), while ``shots/.cache/*`` and
    ``shots/.*`` name them. :meth:`Path.glob` matched them all. ``**`` matches any number of
    folders, as in :meth:`Path.glob`.
    """
    return [Path(anchor, m) for m in glob.glob(pattern, root_dir=anchor, recursive=True)]


def _natural_key(p: Path):
    return [int(t) if t.isdigit() else t for t in re.split(r"(\d+)", p.name)]


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
        o = Path(s.out)
        for p in inputs:
            rp = Path(p).resolve()
            if o == rp or o in rp.parents:
                raise ShellsplineError(f"{where}: output '{o}' would contain the input "
                                       f"'{p}' of sequence '{s.name}'")

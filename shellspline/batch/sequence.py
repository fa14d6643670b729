"""One sequence of a batch, as a worker process or a Dask task runs it.

:func:`run_sequence` reads (or generates) the keyframes, interpolates them through the public
API (:func:`~shellspline.io.read_keyframes`, :func:`~shellspline.interpolate`,
:func:`~shellspline.io.write_sequence`), writes every output into a hidden staging directory
``OUT/.<name>.stage-<hex>`` with ``metrics.json`` and ``manifest.json``, and renames it into
place (:func:`publish`), so an output directory exists exactly when it is complete.
"""
from __future__ import annotations

import math
import os
import secrets
import shutil
import socket
import time
from pathlib import Path
from typing import Callable

from ..errors import ShellsplineError
from ..version import __version__
from .job import applicable_params, json_roundtrip
from .manifest import (MANIFEST_FORMAT, input_digest, manifest_matches, now, output_sizes,
                       sequence_key, write_json_atomic)
from .summary import reason

__all__ = ["run_sequence", "sequence_metrics", "quality_warning", "read_sequence_inputs",
           "publish", "render_previews"]


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

    from ..metrics import half_axes, keyframe_kinks

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


def quality_warning(report: dict) -> str:
    """One line listing the quality or convergence problems of an interpolation report
    ("" when there are none)."""
    from ..pipeline.report import convergence_problems, seam_defects

    q = report.get("quality", {})
    parts = convergence_problems(report)
    if not q.get("keyframes_exact", True):
        parts.append("keyframes not reproduced exactly")
    for key, what in (("flipped_faces", "flipped faces"), ("collapsed_faces", "collapsed faces"),
                      ("folded_edges", "folded edges"), ("degenerate_faces", "degenerate faces")):
        if q.get(key):
            parts.append(f"{q[key]} {what}")
    at = seam_defects(report)
    n_at = at["flipped"] + at["folded"] + at["collapsed"]
    if n_at:
        fr = at["frames"]
        parts.append(f"{n_at} of these at the seams between two minima (steps into frames "
                     f"{fr[:10]}{' …' if len(fr) > 10 else ''})")
    if q.get("pop", 0.0) > q.get("pop_limit", float("inf")):
        parts.append(f"a pop of {q['pop']:.1f}x the neighbouring steps at frame {q['pop_frame']}")
    return "; ".join(parts)


def read_sequence_inputs(spec):
    """Read or generate the keyframes of a spec (public API only).

    Returns
    -------
    kf : Keyframes
    pinned : (p,) int64 numpy array or None
        The pinned vertices (explicit, from a file, and the boundary with ``fix_boundary``),
        in the keyframes' vertex numbering.
    """
    from ..io import keyframes_from_arrays, read_frames, read_keyframes

    if spec.source == "synth":
        import data_synth

        syn = spec.synth
        data = data_synth.generate(syn["name"], syn["vertices"], **json_roundtrip(syn["params"]))
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
    return kf, _pinned(spec, kf)


def _pinned(spec, kf):
    import numpy as np

    from ..io import read_indices

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
    return pinned


def publish(staging: Path, final: Path, key: str, keep: Callable[[dict], bool]) -> str:
    """Rename a complete staging directory into place.

    Returns
    -------
    {"published", "existing"}
        "existing": a complete output with the same key that ``keep(manifest)`` accepts was
        already there (another attempt finished first); the staging directory is removed.

    Raises
    ------
    ShellsplineError
        When ``final`` does not look like an earlier output (no manifest or report).
    """
    try:
        os.rename(staging, final)
        return "published"
    except OSError:
        if not (final.exists() or final.is_symlink()):
            raise
    m = manifest_matches(final, key)
    if m is not None and keep(m):  # another attempt finished first
        shutil.rmtree(staging, ignore_errors=True)
        return "existing"
    if not final.is_dir() or final.is_symlink() or (
            any(final.iterdir()) and not (final / "manifest.json").is_file()
            and not (final / "report.json").is_file()):
        shutil.rmtree(staging, ignore_errors=True)
        raise ShellsplineError(f"refusing to replace '{final}': it does not look like an "
                               "earlier output (no manifest.json or report.json)")
    from ..io.atomic import move_into_place

    move_into_place(staging, final, overwrite=True)  # old output set aside, then removed
    return "published"


def run_sequence(spec, key: str | None = None, inner_workers: int = 1,
                 emit: Callable[[dict], None] | None = None, run_id: str = "",
                 force: bool = False) -> dict:
    """Interpolate and write one sequence; never raises except KeyboardInterrupt.

    An output that is already complete with a matching manifest is left untouched (unless
    ``force``, in which case only one written by this run, ``run_id``, is kept): a task that
    runs twice neither rewrites nor duplicates it.

    Parameters
    ----------
    spec : SequenceSpec
    key : str or None
        The planner's key (informative: the key is recomputed from the bytes read now, so a
        manifest records what was actually read).
    inner_workers : int
        Processes for the frames of this sequence.
    emit : callable(dict), optional
        Receives the pipeline's ``stage_end``/``message`` events and this function's
        ``write``/``render`` stage ends.
    run_id : str
        The batch run; recorded in the manifest.
    force : bool
        Redo a matching output unless this run wrote it.

    Returns
    -------
    dict
        The outcome record (``status`` 'done', 'skipped' or 'failed', ``reason``,
        ``warning``, ``seconds``, ``frames``, ``vertices``, ``out``, ``worker``).
    """
    t0 = time.perf_counter()
    final = Path(spec.out)
    out = {"name": spec.name, "status": "failed", "reason": "", "warning": "",
           "seconds": 0.0, "frames": None, "vertices": None, "out": str(final),
           "worker": f"{socket.gethostname()}:{os.getpid()}"}
    task = _Task(spec, inner_workers, emit, run_id, force, t0)
    try:
        task.digest = input_digest(spec)
        task.key = sequence_key(spec, task.digest)
        m = manifest_matches(final, task.key)
        if m is not None and task.keep(m):  # complete already: never rewritten
            this_run = bool(run_id) and m.get("run") == run_id
            out.update(status="done" if this_run else "skipped",
                       reason="completed by an earlier attempt of this run" if this_run
                       else "up to date (manifest matches)",
                       warning=m.get("warning", ""), frames=m.get("frames"),
                       vertices=m.get("vertices"))
            return out
        res, metrics = task.solve()
        warning = task.write(res, metrics, out["worker"])
        state = task.publish()
        out.update(status="done", warning=warning, frames=int(res.K + 1),
                   vertices=int(res.V.shape[1]))
        if state == "existing":
            out["reason"] = "an identical output appeared meanwhile; kept it"
    except Exception as exc:  # one failing sequence never stops the others
        out.update(status="failed", reason=reason(exc))
    finally:
        if task.staging is not None:
            shutil.rmtree(task.staging, ignore_errors=True)
        out["seconds"] = time.perf_counter() - t0
    return out


class _Task:
    """The state of :func:`run_sequence` between its stages (solve, write, publish)."""

    def __init__(self, spec, inner_workers, emit, run_id, force, t0):
        self.spec, self.inner, self.emit = spec, inner_workers, emit
        self.run_id, self.force, self.t0 = run_id, force, t0
        self.digest = self.key = self.staging = None

    def keep(self, m: dict) -> bool:
        """Whether an existing complete output with this key is kept."""
        return not self.force or m.get("run") == self.run_id

    def _stage_end(self, stage: str, t: float) -> None:
        if self.emit is not None:
            self.emit({"kind": "stage_end", "stage": stage,
                       "seconds": time.perf_counter() - t})

    def solve(self):
        """(InterpolationResult, metrics) of the spec."""
        from ..pipeline import interpolate

        spec = self.spec
        kf, pinned = read_sequence_inputs(spec)
        p = applicable_params(spec.params)  # [defaults] apply where they can
        gn_options = {} if p["max_iter"] is None else {"max_iter": p["max_iter"]}
        solver_options = {}
        if p["method"] in ("nonlinear", "geodesic"):  # as `shellspline interpolate`
            solver_options["max_time_s"] = 600.0 if p["max_time"] is None else p["max_time"]
        elif p["max_time"] is not None:  # lta: the reference geodesic's own limit
            solver_options["max_time_s"] = p["max_time"]

        def progress(ev):
            if self.emit is not None and ev.get("kind") in ("stage_end", "message"):
                self.emit(dict(ev))

        t_read = time.perf_counter() - self.t0
        res = interpolate(kf, K=p["K"], method=p["method"], bc=p["bc"], eta=p["eta"],
                          mu=p["mu"], lam=p["lam"], reference=p["reference"],
                          pinned=pinned, workers=self.inner, gn_options=gn_options,
                          solver_options=solver_options, coarse=p["coarse"],
                          fine=p["fine"], fade_angle=p["fade_angle"], spline=p["spline"],
                          transfer=p["transfer"], progress=progress)
        res.report["timings"]["read"] = t_read
        return res, sequence_metrics(res.V, kf.V, res.frames, res.report)

    def write(self, res, metrics: dict, worker: str) -> str:
        """Every output and the manifest into a fresh staging directory; the quality
        warning."""
        from ..io import write_sequence
        from ..io.usd import conventional_up_axis  # the input's convention, for a USD stage

        spec, p = self.spec, self.spec.params
        t_w = time.perf_counter()
        final = Path(spec.out)
        final.parent.mkdir(parents=True, exist_ok=True)
        self.staging = staging = final.parent / f".{final.name}.stage-{secrets.token_hex(6)}"
        protect = list(spec.keyframes) + [q for q in (spec.frames_path, spec.pinned_path) if q]
        # the input's polygons and vertex numbering written back (real exports)
        V_out = res.V if res.source is None else res.source.expand(res.V, res.frames, res.K,
                                                                   p["bc"])
        up = "z" if spec.keyframes and conventional_up_axis(spec.keyframes[0]) == "z" else "y"
        for i, fmt in enumerate(spec.formats):
            write_sequence(staging if i == 0 else staging / fmt, V_out, res.F, res.report,
                           fmt=fmt, protect=protect, workers=self.inner, source=res.source,
                           up_axis=up)
        write_json_atomic(staging / "metrics.json",
                          {**metrics, "keyframe_frames": [int(f) for f in res.frames]})
        self._stage_end("write", t_w)
        if spec.render or spec.plots:
            t_r = time.perf_counter()
            render_previews(spec, staging, res)
            self._stage_end("render", t_r)
        warning = quality_warning(res.report)
        write_json_atomic(staging / "manifest.json", {
            "format": MANIFEST_FORMAT, "key": self.key, "sequence": spec.name,
            "run": self.run_id, "shellspline_version": __version__, "created": now(),
            "inputs": self.digest, "parameters": spec.key_parameters(),
            "frames": int(res.K + 1), "vertices": int(res.V.shape[1]),
            "warning": warning, "worker": worker,
            "seconds": time.perf_counter() - self.t0, "outputs": output_sizes(staging)})
        return warning

    def publish(self) -> str:
        """Rename the staging directory into place ('published' or 'existing')."""
        from ..parallel import parent_alive

        if self.spec.delay:  # a testing knob: a stop now finds a staging directory
            time.sleep(self.spec.delay)
        if not parent_alive():  # an orphaned worker: the batch that wanted this is gone
            raise KeyboardInterrupt
        state = publish(self.staging, Path(self.spec.out), self.key, self.keep)
        self.staging = None
        return state


def render_previews(spec, staging: Path, res) -> None:
    """The filmstrip, GIF and half-axes plot a spec asks for, into ``staging``."""
    try:
        from .. import viz
    except ImportError as exc:
        raise ShellsplineError(f"rendering needs the viz module and its extra "
                               f"(pip install \"shellspline[viz]\"): {reason(exc)}") from None
    src = (res.V, res.F, res.frames)  # keyframes drawn gray
    if "strip" in spec.render:
        viz.render_strip(src, staging / "strip.png")
    if "gif" in spec.render:
        viz.render_animation(src, staging / "animation.gif")
    if "half_axes" in spec.plots:
        from ..metrics import half_axes

        viz.plot_half_axes({spec.name: half_axes(res.V)}, staging / "half_axes.png",
                           frames=res.frames)

"""Running a job: plan → execute → collect → regression check → summary.

:func:`run_batch` is the only place that knows this order; each stage is a short function
below.
"""
from __future__ import annotations

import datetime as _dt
import secrets
import time
from pathlib import Path
from typing import Callable

from ..errors import ShellsplineError
from .executors import make_executor
from .job import Job, check_scheduler_address
from .manifest import input_digest, manifest_matches, sequence_key, write_json_atomic
from .outroot import (LOCK_NAME, SUMMARY_NAME, OutputLock, batch_log, cleanup_leftovers, log,
                      log_event)
from .regression import compare_regression, read_metrics, write_expected
from .summary import EXIT_INTERRUPTED, BatchSummary, outcome, reason

__all__ = ["run_batch"]


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
        run's metrics (when every sequence succeeded) instead of comparing; otherwise
        nothing is written, ``summary.errors`` says why and the exit code is 1.

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
        scheduler cannot be reached, renders/plots need the viz extra, ``formats`` holds
        ``"usd"`` and ``pxr`` is missing (a
        :class:`~shellspline.io.usd.UsdUnavailableError`).
    """
    t0 = time.perf_counter()
    ex, scheduler = _checked_options(job, workers, scheduler, executor, write_expected)
    emit = progress or (lambda ev: None)
    root = _prepared_root(job.output)
    run_id = f"{_dt.datetime.now():%Y%m%dT%H%M%S}-{secrets.token_hex(4)}"
    with OutputLock(root), batch_log(root):
        def on_event(ev):
            log_event(ev)
            emit(ev)

        _start_log(job, root, ex, scheduler, on_event)
        outcomes: dict[str, dict] = {}
        todo = _plan(job, force, outcomes)
        emit({"kind": "batch_start", "total": len(job.sequences), "to_run": len(todo),
              "skipped": len(job.sequences) - len(todo), "executor": ex.name,
              "workers": ex.workers})
        stop = _execute(ex, todo, on_event, outcomes, run_id, force)
        cleanup_leftovers(root)
        summary = BatchSummary(job=job.name, output=root,
                               sequences=_collect(job, outcomes, todo, run_id),
                               interrupted=stop is not None,
                               interrupt_exit=stop or EXIT_INTERRUPTED, executor=ex.name,
                               workers=ex.workers, scheduler=scheduler)
        if stop is None:
            summary.regression = _regression(job, summary.sequences, write_expected,
                                             summary.errors)
            _job_plots(job, summary)
        summary.seconds = time.perf_counter() - t0
        _finish(summary, root)
        return summary


def _checked_options(job, workers, scheduler, executor, write_expected):
    """(executor object, scheduler address): the arguments checked before anything runs."""
    workers = job.workers if workers is None else int(workers)
    if workers < 1:
        raise ShellsplineError(f"workers must be >= 1, got {workers}")
    if scheduler is not None:
        scheduler = check_scheduler_address(scheduler)
    else:
        scheduler = job.scheduler
    ex = make_executor(executor or ("dask" if scheduler else job.executor), workers, scheduler)
    _check_viz_available(job)
    _check_usd_available(job)
    if write_expected and (job.regression is None or job.regression["expected_path"] is None):
        raise ShellsplineError(f"{job.path}: --write-expected needs a [regression] section "
                               "whose 'expected' is a JSON file")
    if job.regression is not None and job.regression["expected"] is None and \
            not write_expected:
        raise ShellsplineError(f"{job.path}: [regression] expected values file "
                               f"'{job.regression['expected_path']}' does not exist (create it "
                               "with --write-expected)")
    return ex, scheduler


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


def _check_usd_available(job: Job) -> None:
    """``formats = ["usd"]`` needs the usd extra: fail before anything runs (nothing written),
    in one line, rather than failing every sequence after its solve."""
    wanting = [s.name for s in job.sequences if "usd" in s.formats]
    if not wanting:
        return
    from ..io.usd import UsdUnavailableError, require_usd

    try:
        require_usd()
    except UsdUnavailableError as exc:
        more = f" and {len(wanting) - 1} more" if len(wanting) > 1 else ""
        raise UsdUnavailableError(f"{job.path}: formats \"usd\" (sequence {wanting[0]}{more}) "
                                  f"needs the usd extra: {exc}") from None


def _prepared_root(root: Path) -> Path:
    """The output root, created, with a writable lock file (one-line error otherwise)."""
    if root.exists() and not root.is_dir():
        raise ShellsplineError(f"output root '{root}' exists and is not a directory")
    try:
        root.mkdir(parents=True, exist_ok=True)
        (root / LOCK_NAME).touch()
    except OSError as exc:
        raise ShellsplineError(f"output root '{root}': cannot write there: "
                               f"{exc.strerror or exc}") from None
    return root


def _start_log(job, root, ex, scheduler, on_event) -> None:
    """Remove a killed run's leftovers and log the start of this run."""
    removed = cleanup_leftovers(root)
    log.info("job %s (%s): %d sequences, executor %s%s, %d workers", job.name, job.path,
             len(job.sequences), ex.name, f" at {scheduler}" if scheduler else "", ex.workers)
    if removed:
        on_event({"kind": "message", "text": f"removed {len(removed)} leftover temporary "
                                             "entries of an interrupted run"})


def _plan(job: Job, force: bool, outcomes: dict) -> list:
    """``[(spec, key)]`` of the sequences to run; the up-to-date ones go into ``outcomes``
    as skipped."""
    todo = []
    for spec in job.sequences:
        try:
            key = sequence_key(spec, input_digest(spec))
        except OSError:
            key = None  # the task will report the unreadable input
        m = None if force or key is None else manifest_matches(spec.out, key)
        if m is None:
            todo.append((spec, key))
            continue
        outcomes[spec.name] = outcome(spec, "skipped", "up to date (manifest matches)",
                                      warning=m.get("warning", ""), frames=m.get("frames"),
                                      vertices=m.get("vertices"))
        log.info("%s: skipped (manifest matches)", spec.name)
    return todo


def _execute(ex, todo, on_event, outcomes, run_id, force) -> int | None:
    """Run ``todo`` on the executor; None, or the exit code of a stop signal (130/143)."""
    from ..parallel import interrupt_exit_code

    try:
        if todo:
            ex.run(todo, on_event, outcomes, run_id, force)
    except KeyboardInterrupt as exc:
        log.warning("interrupted (%s)", str(exc) or "SIGINT")
        return interrupt_exit_code(exc)
    return None


def _collect(job: Job, outcomes: dict, todo=(), run_id: str = "") -> list:
    """One outcome per sequence in job order; 'interrupted' for those without one, unless
    this run published its output: a stop signal can arrive after a task moved its complete
    output into place and before its result reached ``outcomes`` (an output exists exactly
    when it is complete, and is then reported done)."""
    keys = {spec.name: key for spec, key in todo}
    out = []
    for spec in job.sequences:
        o = outcomes.get(spec.name)
        key = keys.get(spec.name)
        m = manifest_matches(spec.out, key) if o is None and key is not None else None
        if o is None and m is not None and run_id and m.get("run") == run_id:
            o = outcome(spec, "done", "completed before the interrupt took effect",
                        warning=m.get("warning", ""), frames=m.get("frames"),
                        vertices=m.get("vertices"))
        out.append(o or outcome(spec, "interrupted", "not finished: the batch was interrupted"))
    return out


def _regression(job: Job, seqs: list, write: bool, errors: list) -> dict | None:
    """The regression check (after writing the expected values when ``write``). When a
    sequence did not finish, nothing is written, the check is skipped and ``errors`` says
    so (exit code 1)."""
    if job.regression is None:
        return None
    metrics = {o["name"]: read_metrics(Path(o["out"])) for o in seqs
               if o["status"] in ("done", "skipped")}
    if write:
        why = write_expected(job, metrics, seqs)
        if why is not None:
            errors.append(why)
            log.warning("%s", why)
            return None
    return compare_regression(job.regression, metrics)


def _finish(summary: BatchSummary, root: Path) -> None:
    """``summary.json`` and the summary table in ``batch.log``."""
    write_json_atomic(root / SUMMARY_NAME, summary.to_dict())
    for line in summary.table().splitlines():
        log.info("%s", line)
    log.info("exit code %d", summary.exit_code)


def _job_plots(job: Job, summary: BatchSummary) -> None:
    """``OUT/half_axes.png`` comparing every sequence that asks for the plot (two or more);
    a failure is a job error in the summary."""
    names = [s.name for s in job.sequences if "half_axes" in s.plots]
    curves, frames = {}, None
    for o in summary.sequences:
        if o["name"] in names and o["status"] in ("done", "skipped"):
            m = read_metrics(Path(o["out"]))
            if m is not None:
                curves[o["name"]] = m["half_axes"]
                frames = m.get("keyframe_frames") if frames is None else frames
    if len(curves) < 2:
        return
    path = job.output / "half_axes.png"
    try:
        import numpy as np

        from .. import viz

        viz.plot_half_axes({k: np.asarray(v) for k, v in curves.items()}, path, frames=frames)
    except Exception as exc:  # viz writes atomically: nothing is left behind
        summary.errors.append(f"job plot {path.name}: {reason(exc)}")

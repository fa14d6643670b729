"""CLI subcommand ``batch`` (see :mod:`shellspline.batch`).

``shellspline batch JOB.toml [-o OUT] [--workers N] [--scheduler tcp://HOST:PORT]
[--executor local|dask] [--force] [--write-expected] [-q]``

Exit codes: 0 every sequence done or up to date (and the regression passed), 1 a sequence
failed, has a quality warning, or the regression failed, 2 bad job file or usage, 130
interrupted by Ctrl-C/SIGINT, 143 by SIGTERM (completed sequences are kept; re-run to resume).
"""
from __future__ import annotations

import sys
import time


class _BatchBar:
    """Overall progress (sequences, elapsed, ETA) plus per-sequence stage lines on stderr.

    Same look as the ``interpolate`` bar (:class:`shellspline.cli.main._Bar`): on a terminal the
    overall bar is redrawn in place under the stage lines; elsewhere (logs, pipes) only the
    lines are written.
    """

    def __init__(self, stream=None, quiet: bool = False):
        self.stream = stream or sys.stderr
        self.quiet = quiet
        self.tty = hasattr(self.stream, "isatty") and self.stream.isatty()
        self.total = 0
        self.done = 0
        self.t0 = time.perf_counter()
        self._last = 0.0

    def __call__(self, ev) -> None:
        if self.quiet:
            return
        kind = ev.get("kind")
        if kind == "batch_start":
            self.total = ev["to_run"]
            self.t0 = time.perf_counter()
            where = f"{ev['executor']}, {ev['workers']} worker{'s' if ev['workers'] > 1 else ''}"
            self._line(f"batch: {ev['total']} sequences, {ev['skipped']} up to date, "
                       f"{ev['to_run']} to run ({where})")
        elif kind == "sequence_event":
            e = ev["event"]
            if e.get("kind") == "stage_end":
                self._line(f"  {ev['name']}: {e['stage']:<12s} {e['seconds']:8.3f} s")
            elif e.get("kind") == "message":
                self._line(f"  {ev['name']}: note: {e['text']}")
        elif kind == "sequence_end":
            self.done += 1
            o = ev["outcome"]
            text = f"[{self.done}/{self.total}] {o['name']}: {o['status']} " \
                   f"({o['seconds']:.2f} s)"
            if o.get("reason"):
                text += f": {o['reason']}"
            if o.get("warning"):
                text += f" (warning: {o['warning']})"
            if not self.tty:
                text += f"  eta {self._eta()}"
            self._line(text)
        elif kind == "message":
            self._line(f"note: {ev['text']}")
        elif kind == "tick":
            now = time.perf_counter()
            if self.tty and now - self._last > 0.5:
                self._draw()
                self._last = now

    def _eta(self) -> str:
        el = time.perf_counter() - self.t0
        if not self.done:
            return "-"
        return f"{el / self.done * (self.total - self.done):.1f}s"

    def _line(self, text: str) -> None:
        if self.tty:
            self.stream.write("\r\033[K")
        self.stream.write(text + "\n")
        if self.tty and self.total:
            self._draw()
        self.stream.flush()

    def _draw(self) -> None:
        if not self.tty or not self.total:
            return
        width = 30
        fill = int(width * self.done / max(self.total, 1))
        el = time.perf_counter() - self.t0
        self.stream.write(f"\r  {'sequences':<12s} [{'#' * fill}{'.' * (width - fill)}] "
                          f"{self.done}/{self.total}  {el:5.1f}s  eta {self._eta()}")
        self.stream.flush()

    def close(self) -> None:
        if self.tty and not self.quiet:
            self.stream.write("\r\033[K")
            self.stream.flush()


def _batch(args) -> int:
    from ..batch import load_job, run_batch

    if args.workers is not None and args.workers < 1:
        from ..errors import ShellsplineError

        raise ShellsplineError(f"--workers must be >= 1, got {args.workers}")
    job = load_job(args.job)
    if args.output:
        job = job.with_output(args.output)
    bar = _BatchBar(quiet=args.quiet)
    try:
        summary = run_batch(job, workers=args.workers, scheduler=args.scheduler,
                            executor=args.executor, force=args.force, progress=bar,
                            write_expected=args.write_expected)
    finally:
        bar.close()
    if not args.quiet or summary.exit_code:
        print(summary.table(), file=sys.stderr)
    if args.write_expected and job.regression is not None and not summary.interrupted and \
            summary.regression is not None:   # (not written when a sequence failed)
        print(f"wrote expected values to {job.regression['expected_path']}", file=sys.stderr)
    if summary.interrupted:
        print("shellspline: interrupted; completed sequences are kept (re-run the same command "
              "to resume)", file=sys.stderr)
    return summary.exit_code


def add_parsers(sub) -> None:
    """Register the ``batch`` subcommand on the ``shellspline`` subparsers."""
    q = sub.add_parser(
        "batch", help="run a TOML batch job (many sequences, parallel or on Dask)",
        description="Run every sequence of a TOML job file (see pipelines/). Each sequence is "
                    "written atomically to OUT/<name>/ with manifest.json; re-running skips "
                    "sequences whose manifest matches and redoes the rest. Writes "
                    "OUT/summary.json and OUT/batch.log. Exit codes: 0 all ok, 1 a sequence "
                    "failed or the regression failed, 2 bad job file, 130/143 interrupted "
                    "(SIGINT/SIGTERM).")
    q.add_argument("job", help="job file (TOML); relative paths in it are relative to its "
                               "directory")
    q.add_argument("-o", "--output", help="output root (overrides [job] output)")
    q.add_argument("--workers", type=int, default=None,
                   help="local worker processes, or the workers of a Dask LocalCluster "
                        "(default: [job] workers)")
    q.add_argument("--executor", choices=["local", "dask"], default=None,
                   help="local process pool (default) or Dask (a LocalCluster unless "
                        "--scheduler is given)")
    q.add_argument("--scheduler", help="address of a running Dask scheduler, e.g. "
                                       "tcp://127.0.0.1:8786 (implies --executor dask)")
    q.add_argument("--force", action="store_true",
                   help="redo every sequence, even those whose manifest matches")
    q.add_argument("--write-expected", action="store_true",
                   help="rewrite the [regression] expected-values file from this run")
    q.add_argument("-q", "--quiet", action="store_true",
                   help="no progress output (the summary table is still printed on failure)")
    q.set_defaults(func=_batch)

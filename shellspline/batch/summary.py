"""The outcome of a batch: one record per sequence and the :class:`BatchSummary`."""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from ..errors import ShellsplineError, one_line
from ..version import __version__
from .manifest import now
from .regression import regression_table

__all__ = ["BatchSummary", "outcome", "reason", "EXIT_OK", "EXIT_FAILED", "EXIT_JOB",
           "EXIT_INTERRUPTED", "STATUSES"]

EXIT_OK, EXIT_FAILED, EXIT_JOB, EXIT_INTERRUPTED = 0, 1, 2, 130
#: the statuses of a sequence's outcome
STATUSES = ("done", "skipped", "failed", "interrupted")


def reason(exc: BaseException) -> str:
    """One line (at most 300 characters) saying why a sequence failed; our own errors and
    OS errors without their type name."""
    return one_line(exc, limit=300, bare=(ShellsplineError, OSError))


def outcome(spec, status: str, reason: str = "", *, worker: str = "", **fields) -> dict:
    """The outcome record of one sequence.

    Parameters
    ----------
    spec : SequenceSpec
    status : {"done", "skipped", "failed", "interrupted"}
    reason : str
        One line.
    worker : str
        ``host:pid`` (or ``"dask"``) of the process that ran it.
    **fields
        Overrides of ``warning`` (""), ``seconds`` (0.0), ``frames`` and ``vertices`` (None).

    Returns
    -------
    dict
        ``name, status, reason, warning, seconds, frames, vertices, out, worker``.
    """
    o = {"name": spec.name, "status": status, "reason": reason, "warning": "",
         "seconds": 0.0, "frames": None, "vertices": None, "out": spec.out, "worker": worker}
    o.update(fields)
    return o


@dataclass
class BatchSummary:
    """What :func:`~shellspline.run_batch` returns (also written to ``OUT/summary.json``).

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
        """Number of sequences with this status."""
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
        """The content of ``summary.json``."""
        frames = sum(o["frames"] or 0 for o in self.sequences if o["status"] == "done")
        return {
            "job": self.job, "output": str(self.output), "executor": self.executor,
            "workers": self.workers, "scheduler": self.scheduler,
            "shellspline_version": __version__, "finished": now(),
            "seconds": self.seconds, "interrupted": self.interrupted,
            "counts": {s: self.count(s) for s in STATUSES},
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
        c = {s: self.count(s) for s in STATUSES}
        lines.append(f"{c['done']} done, {c['skipped']} skipped (up to date), {c['failed']} "
                     f"failed" + (f", {c['interrupted']} interrupted" if c['interrupted'] else "")
                     + f" in {self.seconds:.1f} s; output {self.output}")
        if self.regression is not None:
            lines.append(regression_table(self.regression))
        for e in self.errors:
            lines.append(f"error: {e}")
        return "\n".join(lines)

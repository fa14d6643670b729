"""The output root of a job: its lock, its log, and the leftovers of a killed run.

The root holds one directory per sequence plus ``summary.json``, ``batch.log`` and
``.batch.lock``. While a job runs, it holds an exclusive ``flock`` on the lock file, so hidden
staging entries found at the start of a run cannot belong to a live run and are removed.
"""
from __future__ import annotations

import contextlib
import logging
import shutil
from pathlib import Path

from ..errors import ShellsplineError
from ..io.atomic import TEMP_MARKERS as ATOMIC_MARKERS

__all__ = ["SUMMARY_NAME", "LOG_NAME", "LOCK_NAME", "TEMP_MARKERS", "OutputLock", "HELD_LOCKS",
           "cleanup_leftovers", "batch_log", "log", "log_event"]

SUMMARY_NAME, LOG_NAME, LOCK_NAME = "summary.json", "batch.log", ".batch.lock"
#: what the hidden temporary entries of a run carry in their names: a sequence's staging
#: directory (``.<name>.stage-<hex>``) and :mod:`shellspline.io.atomic`'s temporaries
TEMP_MARKERS = (".stage-", *ATOMIC_MARKERS)

log = logging.getLogger("shellspline.batch")

#: open lock files of this process (a forked worker closes its copies first)
HELD_LOCKS: list = []


def cleanup_leftovers(root: Path) -> list[str]:
    """Remove the staging/temporary entries a killed run left in ``root``; their names."""
    removed = []
    try:
        entries = list(root.iterdir())
    except OSError:
        return removed
    for p in entries:
        n = p.name
        if n.startswith(".") and any(m in n for m in TEMP_MARKERS):
            if p.is_dir() and not p.is_symlink():
                shutil.rmtree(p, ignore_errors=True)
            else:
                try:
                    p.unlink()
                except OSError:
                    continue
            removed.append(n)
    return removed


class OutputLock:
    """An exclusive lock on the output root (so leftovers cannot belong to a live run).

    The lock is an ``flock`` on ``OUT/.batch.lock``; it lasts while any process holds the open
    file, so forked workers close their inherited copy first
    (:func:`shellspline.batch.executors.child_main`): a worker orphaned by a killed batch
    never keeps the root locked.

    Raises
    ------
    ShellsplineError
        On entering, when another process holds the lock.
    """

    def __init__(self, root: Path):
        self.path = root / LOCK_NAME
        self.fh = None

    def __enter__(self):
        self.fh = open(self.path, "a+")
        HELD_LOCKS.append(self.fh)
        try:
            import fcntl
        except ImportError:  # pragma: no cover - not POSIX: no locking
            return self
        try:
            fcntl.flock(self.fh.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            HELD_LOCKS.remove(self.fh)
            self.fh.close()
            raise ShellsplineError(f"{self.path.parent}: another shellspline batch is running "
                                   f"on this output root (lock {self.path})") from None
        return self

    def __exit__(self, *exc):
        if self.fh in HELD_LOCKS:
            HELD_LOCKS.remove(self.fh)
        self.fh.close()  # closing releases the flock


@contextlib.contextmanager
def batch_log(root: Path):
    """Inside the block, the ``shellspline.batch`` logger appends to ``root/batch.log``."""
    handler = logging.FileHandler(root / LOG_NAME, encoding="utf-8")
    handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(message)s"))
    log.addHandler(handler)
    log.setLevel(logging.INFO)
    log.propagate = False
    try:
        yield log
    finally:
        log.removeHandler(handler)
        handler.close()


def log_event(ev: dict) -> None:
    """One line of ``batch.log`` for a progress event of :func:`~shellspline.run_batch`."""
    k = ev.get("kind")
    if k == "sequence_start":
        log.info("%s: started", ev["name"])
    elif k == "sequence_event":
        e = ev["event"]
        if e.get("kind") == "stage_end":
            log.info("%s: %s %.3f s", ev["name"], e["stage"], e["seconds"])
        elif e.get("kind") == "message":
            log.info("%s: note: %s", ev["name"], e["text"])
    elif k == "sequence_end":
        o = ev["outcome"]
        msg = f"{o['name']}: {o['status']} in {o['seconds']:.2f} s"
        if o.get("reason"):
            msg += f": {o['reason']}"
        if o.get("warning"):
            msg += f" (warning: {o['warning']})"
        (log.warning if o["status"] == "failed" else log.info)("%s", msg)
    elif k == "message":
        log.info("%s", ev["text"])

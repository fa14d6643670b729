"""The one small reporting helper: stages, progress counts and log lines.

Numerical modules never print. :mod:`shellspline.pipeline` reports through a
:class:`Progress`; the CLI gives it a callback that draws a progress bar, the Python API
defaults to silence (or to :mod:`logging` at DEBUG level).
"""
from __future__ import annotations

import logging
import time
from contextlib import contextmanager
from typing import Callable

__all__ = ["Progress", "ProgressEvent"]

log = logging.getLogger("shellspline")


class ProgressEvent(dict):
    """A progress event: ``kind`` ('stage_start', 'stage_end', 'advance', 'message'),
    ``stage``, ``done``, ``total``, ``seconds``, ``text``."""


class Progress:
    """Collects per-stage wall times and forwards events to an optional callback.

    Parameters
    ----------
    callback : callable(ProgressEvent) -> None, optional

    Attributes
    ----------
    timings : dict of str to float
        Seconds per stage name, summed over the stage's runs.
    within : dict of str to str
        The stages run inside another one (``{"reference geodesic": "describe"}``), with
        the innermost one around them at their first run: their seconds are counted in that
        stage's too.
    """

    def __init__(self, callback: Callable[[ProgressEvent], None] | None = None):
        self.callback = callback
        self.timings: dict[str, float] = {}
        self.within: dict[str, str] = {}
        self._open: list[str] = []  # the stages running, innermost last

    def _emit(self, **kw) -> None:
        ev = ProgressEvent(**kw)
        log.debug("%s", ev)
        if self.callback is not None:
            self.callback(ev)

    @contextmanager
    def stage(self, name: str, total: int | None = None):
        """Time a stage: ``with progress.stage("reconstruct", total=K): ...``."""
        t0 = time.perf_counter()
        if self._open and self._open[-1] != name:
            self.within.setdefault(name, self._open[-1])
        self._emit(kind="stage_start", stage=name, total=total, done=0)
        self._open.append(name)
        try:
            yield self
        finally:
            self._open.pop()
            dt = time.perf_counter() - t0
            self.timings[name] = self.timings.get(name, 0.0) + dt
            self._emit(kind="stage_end", stage=name, seconds=dt, total=total)

    def advance(self, stage: str, done: int, total: int, text: str | None = None) -> None:
        """``done`` of ``total``; ``text`` (optional) describes the state, e.g. an
        optimiser's iteration, energy and gradient (the CLI prints it as a log line when
        stderr is not a terminal)."""
        self._emit(kind="advance", stage=stage, done=done, total=total, text=text)

    def message(self, text: str) -> None:
        self._emit(kind="message", text=text)

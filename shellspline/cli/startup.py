"""Ctrl-C while the ``shellspline`` command starts: one line and exit status 130.

The console script (and ``python -m shellspline``) imports the package before
:func:`shellspline.cli.main.main` runs, and the package face imports nearly all of it (half a
second); a Ctrl-C or SIGINT then raised ``KeyboardInterrupt`` out of an import, printed as a
traceback. The package face calls :func:`guard` before anything else: when this process is
the command line, a SIGINT then ends it at once with the one line ``main`` prints for an
interrupt and exit status 130 (nothing has been read or written yet); ``main`` calls
:func:`release` first, inside its own handling of ``KeyboardInterrupt``, which puts Python's
handler back. ``import shellspline`` in the user's own program changes nothing. Standard
library only: this runs before the rest of the package is imported.
"""
from __future__ import annotations

import os
import signal
import sys
from pathlib import Path

__all__ = ["INTERRUPTED", "EXIT_INTERRUPTED", "is_command_line", "guard", "release",
           "output_written", "interrupted_line", "forget_outputs"]

INTERRUPTED = "shellspline: interrupted; no output was written"
"""The line an interrupt prints (the same in :func:`shellspline.cli.main.main`)."""
EXIT_INTERRUPTED = 130
"""128 + SIGINT."""
_written: list[str] = []  # files a command finished before an interrupt (output_written)
_SCRIPT_NAMES = ("shellspline", "shellspline.exe", "shellspline-script.py")
_OPTIONS_WITH_VALUE = ("-X", "-W", "-Q")


def is_command_line() -> bool:
    """Whether this process is the ``shellspline`` command: its console script, or
    ``python -m shellspline``."""
    if sys.argv and Path(str(sys.argv[0])).name in _SCRIPT_NAMES:
        return True
    args = list(getattr(sys, "orig_argv", ()))[1:]  # the interpreter's own options first
    i = 0
    while i < len(args):
        arg = args[i]
        if arg.startswith("-m"):
            module = arg[2:] or (args[i + 1] if i + 1 < len(args) else "")
            return module == "shellspline"
        if arg == "-c" or not arg.startswith("-"):  # code or a script: not the command
            return False
        i += 2 if arg in _OPTIONS_WITH_VALUE else 1
    return False


def output_written(path) -> None:
    """Record that the running command has finished writing ``path`` (a final output): an
    interrupt then reports it instead of :data:`INTERRUPTED` (:func:`interrupted_line`)."""
    _written.append(str(path))


def forget_outputs() -> None:
    """Forget the outputs recorded by :func:`output_written` (a new command starts)."""
    _written.clear()


def interrupted_line() -> str:
    """The line an interrupt prints: :data:`INTERRUPTED`, or, when the command had already
    written some of its outputs (:func:`output_written`), which ones."""
    if not _written:
        return INTERRUPTED
    return ("shellspline: interrupted; written before the interrupt: " + ", ".join(_written)
            + "; the other outputs were not written")


def _in_worker_process() -> bool:
    """Whether this process is a ``multiprocessing`` child (a spawned pool or Dask worker
    imports the package with the parent's ``sys.argv``): never the command line."""
    if "--multiprocessing-fork" in getattr(sys, "orig_argv", ()):
        return True
    mp = sys.modules.get("multiprocessing")  # imported already in a child; not imported here
    if mp is None:
        return False
    try:
        if mp.parent_process() is not None:
            return True
        return bool(getattr(mp.current_process(), "_inheriting", False))
    except Exception:  # pragma: no cover - defensive
        return False


def _interrupted(signum, frame) -> None:  # pragma: no cover - ends the process
    try:
        sys.stderr.write(INTERRUPTED + "\n")
        sys.stderr.flush()
    finally:
        # not SystemExit: an import that catches every exception, or a __del__ running at
        # that moment, would swallow it; nothing is open that needs closing
        os._exit(EXIT_INTERRUPTED)


def guard() -> None:
    """On the command line, make SIGINT end the start-up with one line and exit 130.

    Only where SIGINT has Python's default handler (a background job that ignores it keeps
    ignoring it) and in the main thread; elsewhere, for any other program, and in a
    ``multiprocessing`` child (a spawned worker of the command: a Dask worker is stopped
    by its parent, and must not print the command's line), nothing."""
    if not is_command_line() or _in_worker_process():
        return
    try:
        if signal.getsignal(signal.SIGINT) is signal.default_int_handler:
            signal.signal(signal.SIGINT, _interrupted)
    except (ValueError, OSError):  # not the main thread
        pass


def release() -> None:
    """Put Python's SIGINT handler back if :func:`guard` installed its own (``main`` then
    handles ``KeyboardInterrupt`` itself)."""
    try:
        if signal.getsignal(signal.SIGINT) is _interrupted:
            signal.signal(signal.SIGINT, signal.default_int_handler)
    except (ValueError, OSError):
        pass

"""Output paths of the file-writing subcommands (``path``, ``motion``), checked before any work.

One check for every output a command will write (``-o``, ``--plot``, ``--render``): a
picture's type is known, no output is one of the command's inputs (an input is never
overwritten, ``--overwrite`` or not), no two outputs are the same file (or one inside the
other), an existing output is replaced only with ``--overwrite``, and the folder exists and
takes a new file. Every refusal is one line naming the path, raised as
:class:`~shellspline.errors.ShellsplineError` (exit status 2) before anything is read or
written.
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import NamedTuple

from ..errors import ShellsplineError
from ..io.atomic import temporary_sibling

__all__ = ["Output", "PICTURES", "ANIMATIONS", "check_outputs"]

PICTURES = (".png", ".svg", ".pdf")
"""Picture types matplotlib writes (``--plot``, a ``--render`` strip)."""
ANIMATIONS = PICTURES + (".gif",)
"""``--render``: a strip or an animated GIF."""


class Output(NamedTuple):
    """One output of a command: ``option`` names it in messages (``-o``, ``--plot``); ``path``
    None (the option not given) is skipped; ``suffixes`` the file types its writer knows
    (lower case, with the dot; None: any); ``folder`` a folder is written (a mesh sequence)
    rather than a file."""

    option: str
    path: object
    suffixes: tuple | None = None
    folder: bool = False


class _Named(NamedTuple):
    out: Output
    shown: str
    target: Path


def _same_file(a: Path, b: Path) -> bool:
    """Whether two existing paths are one file (hard links, case-insensitive names)."""
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


def _inside(inner: Path, outer: Path) -> bool:
    return outer in inner.parents


def check_outputs(outputs, inputs=(), *, overwrite: bool = False) -> None:
    """Refuse, in one line and before any work, outputs that cannot or must not be written.

    Parameters
    ----------
    outputs : iterable of Output
    inputs : iterable of str or path-like
        The files and folders the command reads (None entries are skipped).
    overwrite : bool
        Existing outputs may be replaced (never an input).

    Raises
    ------
    ShellsplineError
        An unknown picture type; an output that is an input, contains one (a folder) or is
        inside an output folder; two outputs that are one file; an output that exists
        without ``overwrite``, a folder where a file is written (or the other way round);
        a missing or unwritable folder.
    """
    named = [_Named(o, str(o.path), Path(o.path).resolve()) for o in outputs
             if o.path is not None and str(o.path) != ""]
    for n in named:  # what the writer can make of the name comes first: no file system
        o = n.out
        if o.suffixes and Path(n.shown).suffix.lower() not in o.suffixes:
            raise ShellsplineError(f"{o.option} {n.shown}: expected one of "
                                   f"{', '.join(o.suffixes)}")
    ins = [(str(p), Path(p).resolve()) for p in inputs if p is not None and str(p) != ""]
    for n in named:
        for shown_in, rp in ins:
            if rp == n.target or _same_file(rp, n.target):
                raise ShellsplineError(f"{n.shown} is an input of this command: write to "
                                       "another file")
            if _inside(rp, n.target):
                raise ShellsplineError(f"{n.shown} contains the input {shown_in}: write "
                                       "elsewhere")
    for i, n in enumerate(named):
        for m in named[i + 1:]:
            if n.target == m.target or _same_file(n.target, m.target):
                raise ShellsplineError(f"{n.out.option} {n.shown} and {m.out.option} "
                                       f"{m.shown} are the same file: give each output its "
                                       "own name")
            for inner, outer in ((n, m), (m, n)):
                if _inside(inner.target, outer.target):
                    raise ShellsplineError(f"{inner.out.option} {inner.shown} is inside "
                                           f"{outer.out.option} {outer.shown}: give each "
                                           "output its own place")
    for n in named:
        p, o = Path(n.shown), n.out
        if p.is_dir() and not o.folder:
            raise ShellsplineError(f"{n.shown} is a folder, expected a file")
        if o.folder and p.exists() and not p.is_dir():
            raise ShellsplineError(f"{n.shown} is a file, expected a folder")
        if (p.exists() or p.is_symlink()) and not overwrite:
            raise ShellsplineError(f"{n.shown} exists (use --overwrite to replace it)")
        folder = n.target.parent
        if not folder.is_dir():
            raise ShellsplineError(f"{n.shown}: the folder {p.parent} does not exist")
        probe = temporary_sibling(n.target)
        try:  # a file made and removed: os.access does not know read-only mounts
            probe.touch(exist_ok=False)
            probe.unlink()
        except OSError as exc:
            raise ShellsplineError(f"{n.shown}: cannot write in the folder {p.parent} "
                                   f"({exc.strerror or exc})") from None

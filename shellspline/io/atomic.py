"""Atomic writes: every output file or directory of the package appears whole or not at all.

One recipe, used by every writer (sequences, BVH, pose files, pictures, manifests, the
Blender add-on zip): write into a hidden temporary sibling of the target, then rename it into
place (``os.replace`` for a file, :func:`move_into_place` for a directory). The temporary
is removed on any failure, and an ``OSError`` is raised again with a message that names the
user's path, never the temporary one.

Policy
------
* Names: ``.<name>.tmp-<pid>-<hex><suffix>`` (files: the target's suffix is kept, so writers
  that pick a format by extension still do) and ``.<name>.old-<pid>-<hex>`` (an output set
  aside while its replacement moves in). Both carry a marker of :data:`TEMP_MARKERS`, which
  :func:`shellspline.batch.outroot.cleanup_leftovers` removes after a killed run.
* Permissions: the temporary is created by an ordinary ``open`` (``0o666`` minus the umask),
  so outputs get the same mode as any file the user creates; never ``mkstemp``'s ``0o600``.
* No ``fsync``: the rename protects readers from half-written files and a killed process
  from leaving one, not a power cut from losing the last seconds of writes; every output
  here can be made again, so the cost of syncing each file is not paid.
"""
from __future__ import annotations

import os
import secrets
import shutil
from pathlib import Path
from typing import Callable

__all__ = ["TMP_MARKER", "OLD_MARKER", "TEMP_MARKERS", "temporary_sibling",
           "temporary_directory", "write_atomically", "write_bytes_atomic", "write_text_atomic",
           "move_into_place", "on_user_path"]

TMP_MARKER = ".tmp-"
"""In the name of a temporary file or directory being written (``.<name>.tmp-<pid>-<hex>``)."""
OLD_MARKER = ".old-"
"""In the name of an output set aside while its replacement is renamed into place."""
TEMP_MARKERS = (TMP_MARKER, OLD_MARKER)
"""The markers of this module's hidden temporary names."""


def temporary_sibling(target, suffix: str | None = None) -> Path:
    """A fresh hidden name beside ``target``: ``.<name>.tmp-<pid>-<hex><suffix>``.

    Parameters
    ----------
    target : str or path-like
    suffix : str, optional
        Appended to the name (default: ``target``'s suffix in lower case, so that
        ``savefig`` or ``imageio`` infer the same format from the temporary's name).

    Returns
    -------
    pathlib.Path
        Nothing is created.

    Examples
    --------
    >>> p = temporary_sibling("out/strip.PNG")
    >>> p.parent.as_posix(), p.name.startswith(".strip.PNG.tmp-"), p.suffix
    ('out', True, '.png')
    """
    t = Path(target)
    if suffix is None:
        suffix = t.suffix.lower()
    return t.parent / f".{t.name}{TMP_MARKER}{os.getpid()}-{secrets.token_hex(4)}{suffix}"


def temporary_directory(target) -> Path:
    """Create and return a fresh empty hidden directory beside ``target`` (see
    :func:`temporary_sibling`); rename it into place with :func:`move_into_place`.

    Raises
    ------
    OSError
        If the parent of ``target`` does not exist or cannot be written.
    """
    while True:
        p = temporary_sibling(target, suffix="")
        try:
            p.mkdir()
            return p
        except FileExistsError:  # pragma: no cover - 32 random bits
            continue


def on_user_path(exc: OSError, path, doing: str = "writing", tmp=None) -> OSError:
    """``exc`` again (same errno, hence same subclass) with a message naming the user's path.

    Parameters
    ----------
    exc : OSError
    path : str or path-like
        The path the user gave (an output file or directory).
    doing : str
        The verb of the message (``"writing"``, ``"creating"``).
    tmp : path-like, optional
        A temporary directory that stands for ``path``: a file inside it that ``exc`` names
        is named by where it would have landed in ``path``.

    Returns
    -------
    OSError
        ``No space left on device`` becomes ``no space left on device writing 'PATH'``.

    Examples
    --------
    >>> import errno
    >>> e = on_user_path(OSError(errno.ENOSPC, "No space left on device", "/x/.tmp-1/f.obj"),
    ...                  "out", tmp="/x/.tmp-1")
    >>> type(e).__name__, str(e)
    ('OSError', "[Errno 28] no space left on device writing 'out/f.obj'")
    """
    where = Path(path)
    for name in (exc.filename, exc.filename2):
        if name is None or tmp is None:
            continue
        try:
            where = Path(path) / Path(os.fsdecode(name)).relative_to(tmp)
            break
        except ValueError:
            continue
    what = exc.strerror or str(exc) or type(exc).__name__
    return OSError(exc.errno, f"{what[:1].lower()}{what[1:]} {doing} '{where}'")


def write_atomically(path, write: Callable[[Path], object], *, shown=None) -> Path:
    """Call ``write(tmp)`` for a temporary sibling of ``path``, then rename it over ``path``.

    Parameters
    ----------
    path : str or path-like
        The file to write; its folder must exist.
    write : callable
        ``write(tmp)`` creates the file ``tmp`` (a :class:`pathlib.Path` with ``path``'s
        suffix) and writes all of it.
    shown : str or path-like, optional
        The name an ``OSError`` message uses (default ``path``): the name the user gave.

    Returns
    -------
    pathlib.Path
        ``path``.

    Raises
    ------
    OSError
        With the message naming ``shown`` (errno kept); the temporary is removed. Any other
        exception from ``write`` propagates unchanged, after the temporary is removed.

    Examples
    --------
    >>> import os, tempfile
    >>> d = tempfile.mkdtemp()
    >>> p = write_atomically(os.path.join(d, "a.txt"), lambda tmp: tmp.write_text("hi"))
    >>> p.read_text(), os.listdir(d)
    ('hi', ['a.txt'])
    """
    target = Path(path)
    tmp = temporary_sibling(target)
    try:
        write(tmp)
        os.replace(tmp, target)
    except BaseException as exc:
        try:
            tmp.unlink()
        except FileNotFoundError:
            pass
        if isinstance(exc, OSError) and exc.errno is not None:
            raise on_user_path(exc, path if shown is None else shown) from None
        raise
    return target


def write_bytes_atomic(path, data: bytes, *, shown=None) -> Path:
    """Write ``data`` to ``path`` atomically (:func:`write_atomically`)."""
    return write_atomically(path, lambda tmp: tmp.write_bytes(data), shown=shown)


def write_text_atomic(path, text: str, *, shown=None) -> Path:
    """Write ``text`` (UTF-8, newlines as given) to ``path`` atomically
    (:func:`write_atomically`): readers never see a half-written file."""
    return write_atomically(path, lambda tmp: tmp.write_bytes(text.encode("utf-8")),
                            shown=shown)


def move_into_place(tmp, target, overwrite: bool) -> None:
    """Rename the finished directory (or file) ``tmp`` to ``target``.

    An existing ``target`` is replaced only with ``overwrite``: it is renamed aside
    (``.<name>.old-<pid>-<hex>``), ``tmp`` takes its place, then the old one is deleted; if
    the second rename fails the old output is put back.

    Raises
    ------
    FileExistsError
        ``target`` exists and ``overwrite`` is false (it appeared while ``tmp`` was written);
        the message names ``target``, ``errno`` is None.
    OSError
        From the renames.
    """
    tmp, target = Path(tmp), Path(target)
    if target.exists() or target.is_symlink():
        if not overwrite:
            raise FileExistsError(f"output directory '{target}' already exists")
        aside = target.parent / (f".{target.name}{OLD_MARKER}{os.getpid()}-"
                                 f"{secrets.token_hex(4)}")
        os.rename(target, aside)
        try:
            os.rename(tmp, target)
        except BaseException:
            os.rename(aside, target)
            raise
        if aside.is_dir() and not aside.is_symlink():
            shutil.rmtree(aside, ignore_errors=True)
        else:
            aside.unlink(missing_ok=True)
    else:
        os.rename(tmp, target)

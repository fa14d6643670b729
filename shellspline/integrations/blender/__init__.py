"""The Blender add-on: its sources and the zip that Blender installs (:func:`write_addon_zip`,
``shellspline blender-addon -o FILE.zip``).

The zip holds one package ``shellspline_addon``: ``__init__.py`` is :file:`addon.py` (the
operator, panel and preferences; imports ``bpy``, so only Blender imports it) and
``engine.py`` is :mod:`.engine` (no ``bpy``: keyframe arrays in, frames out, through the
library or an external ``shellspline`` command), importable and tested without Blender.

The add-on interpolates a mesh's shape keys (keyed on the timeline or evenly spaced) and
bakes the in-betweens back as keyed shape keys or as a PC2 point cache with a Mesh Cache
modifier. It finds shellspline either in Blender's own Python (installed there with Blender's
pip) or as an external ``shellspline`` command; see the README, section "Blender add-on".
"""
from __future__ import annotations

import zipfile
from pathlib import Path

from ...errors import ShellsplineError
from ...io.atomic import write_atomically

__all__ = ["ADDON_PACKAGE", "write_addon_zip", "addon_files"]

ADDON_PACKAGE = "shellspline_addon"
"""Name of the add-on's package inside Blender (the folder in the zip)."""

_SOURCES = {"__init__.py": "addon.py", "engine.py": "engine.py"}  # name in the zip: source


def addon_files() -> dict:
    """The add-on's files: ``{name in the zip: bytes}``."""
    here = Path(__file__).parent
    return {f"{ADDON_PACKAGE}/{name}": (here / src).read_bytes() for name, src in _SOURCES.items()}


def write_addon_zip(path, *, overwrite: bool = False) -> Path:
    """Write the installable add-on zip (Blender > Preferences > Add-ons > Install from Disk).

    Parameters
    ----------
    path : str or path-like
        The ``.zip`` file to write (atomically: a temporary sibling renamed into place).
    overwrite : bool
        Replace an existing file.

    Returns
    -------
    pathlib.Path
        ``path``.

    Raises
    ------
    FileExistsError
        If ``path`` exists and ``overwrite`` is false.
    ShellsplineError
        If ``path`` does not end in ``.zip``.

    Examples
    --------
    >>> import tempfile, os, zipfile
    >>> p = write_addon_zip(os.path.join(tempfile.mkdtemp(), "shellspline_addon.zip"))
    >>> sorted(zipfile.ZipFile(p).namelist())
    ['shellspline_addon/__init__.py', 'shellspline_addon/engine.py']
    """
    p = Path(path)
    if p.suffix.lower() != ".zip":
        raise ShellsplineError(f"the add-on file must end in .zip, got '{path}'")
    if (p.exists() or p.is_symlink()) and not overwrite:
        raise FileExistsError(f"'{path}' already exists (use overwrite to replace it)")
    files = addon_files()
    p.parent.mkdir(parents=True, exist_ok=True)

    def write(tmp):
        with zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as zf:
            for name, data in files.items():
                zf.writestr(name, data)

    write_atomically(p, write, shown=path)
    return p

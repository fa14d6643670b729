"""Synthetic keyframe meshes for shellspline (ellipsoids, cactus, folded hexagon, bumpy).

Every generator returns the keyframe poses of one mesh with shared connectivity as a
dictionary::

    V       (J,n,3) float64   vertex positions of the J keyframes
    F       (m,3)   int64     faces: consistently oriented, edge-manifold, no degenerate
                              face; outward normals for closed surfaces
    frames  (J,)    int64     suggested frame index of every keyframe
    pinned  (p,)    int64     vertices that are identical in all poses, or None

plus generator-specific entries (``rest``, ``axes``, ...).

Data sets (name: keyframes; default ``n_vertices``; default frames):

* ``ellipsoids``: geodesic sphere scaled to half-axes (2,1,1), (1,1,1), (1,2,1); 500; 0 6 12
* ``cactus``: ribbed capped trunk bent towards +x, straight, bent towards +y, base
  pinned; 5000; 0 10 20
* ``hexagon``: flat regular hexagon folded along its 3 long diagonals (crease, exact
  isometry); 1000; 0 4 8 (periodic, K = 12)
* ``bumpy``: the ellipsoid keyframes with high-frequency radial bumps; 2500; 0 6 12

Command line: ``python -m data_synth NAME OUT [--vertices N] [--format obj|ply|off]
[--count C]`` (``--count``: ``C`` varied sequences in ``OUT/NAME_00/ ...``, see
:func:`write_batch`).
"""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from .cactus import cactus, cactus_rest
from .hexagon import hexagon, hexagon_sheet
from .io import FORMATS, pose_filenames, write_mesh
from .sphere import DEFAULT_ELLIPSOID_AXES, bumpy, ellipsoids, geodesic_sphere

__all__ = ["NAMES", "FORMATS", "generate", "write", "write_keyframes", "ellipsoids", "cactus",
           "hexagon", "bumpy", "geodesic_sphere", "cactus_rest", "hexagon_sheet", "write_mesh",
           "pose_filenames", "DEFAULT_ELLIPSOID_AXES", "variants", "write_batch"]

_GENERATORS = {
    "ellipsoids": ellipsoids,
    "cactus": cactus,
    "hexagon": hexagon,
    "bumpy": bumpy,
}

#: Names accepted by :func:`generate`, :func:`write` and the command line.
NAMES = tuple(_GENERATORS)

_POSE_FILE = re.compile(r"pose_\d+\.(obj|ply|off)")


def generate(name: str, n_vertices: int | None = None, **params) -> dict:
    """Generate the keyframes of a named synthetic data set.

    Parameters
    ----------
    name : str
        One of :data:`NAMES`.
    n_vertices : int, optional
        Approximate vertex count; default: the generator's own default.
    **params
        Further keyword arguments of the generator (e.g. ``bend_angle`` for ``cactus``).

    Returns
    -------
    dict
        ``V`` (J,n,3) float64, ``F`` (m,3) int64, ``frames`` (J,) int64, ``pinned``
        (p,) int64 or ``None``, plus generator-specific entries.

    Raises
    ------
    ValueError
        If ``name`` is unknown or a parameter is invalid.
    """
    if name not in _GENERATORS:
        raise ValueError(f"name must be one of {NAMES}, got {name!r}")
    if n_vertices is not None:
        params["n_vertices"] = n_vertices
    return _GENERATORS[name](**params)


def write_keyframes(data: dict, out_dir, fmt: str = "obj") -> list[Path]:
    """Write generated keyframes to a directory.

    Writes ``pose_00.<fmt>, pose_01.<fmt>, ...`` (lexicographic order = keyframe order),
    ``frames.txt`` (one integer per line) and, when ``data["pinned"]`` is not ``None``,
    ``pinned.txt`` (0-based vertex indices, one per line).  Stale files of this layout
    (``pose_<digits>.obj|ply|off`` not written by this call, and ``pinned.txt`` when
    nothing is pinned) are removed so that the directory describes exactly one data set;
    other files are left alone.

    Parameters
    ----------
    data : dict
        Output of a generator: ``V`` (J,n,3), ``F`` (m,3), ``frames`` (J,), ``pinned``.
    out_dir : str or path-like
        Output directory, created if missing.
    fmt : {"obj", "ply", "off"}
        Mesh file format.

    Returns
    -------
    list of Path
        The pose files, in keyframe order.
    """
    if fmt not in FORMATS:
        raise ValueError(f"fmt must be one of {FORMATS}, got {fmt!r}")
    Vs = np.asarray(data["V"])
    if Vs.ndim != 3 or Vs.shape[2] != 3:
        raise ValueError(f"data['V'] must be a (J,n,3) array, got shape {Vs.shape}")
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    names = pose_filenames(Vs.shape[0], fmt)
    for old in out_dir.glob("pose_*.*"):
        if _POSE_FILE.fullmatch(old.name) and old.name not in names and old.is_file():
            old.unlink()
    paths = [write_mesh(out_dir / fname, V, data["F"], fmt) for fname, V in zip(names, Vs)]
    np.savetxt(out_dir / "frames.txt", np.asarray(data["frames"], dtype=np.int64), fmt="%d")
    pinned_path = out_dir / "pinned.txt"
    if data.get("pinned") is not None:
        np.savetxt(pinned_path, np.asarray(data["pinned"], dtype=np.int64), fmt="%d")
    elif pinned_path.is_file():
        pinned_path.unlink()
    return paths


def write(name: str, out_dir, n_vertices: int | None = None, fmt: str = "obj",
          **params) -> list[Path]:
    """Generate a named data set and write it to a directory (see :func:`write_keyframes`).

    Parameters
    ----------
    name : str
        One of :data:`NAMES`.
    out_dir : str or path-like
        Output directory, created if missing.
    n_vertices : int, optional
        Approximate vertex count; default: the generator's default.
    fmt : {"obj", "ply", "off"}
        Mesh file format.
    **params
        Further keyword arguments of the generator.

    Returns
    -------
    list of Path
        The pose files ``out_dir/pose_00.<fmt>, ...``, in keyframe order.
    """
    if fmt not in FORMATS:
        raise ValueError(f"fmt must be one of {FORMATS}, got {fmt!r}")
    return write_keyframes(generate(name, n_vertices, **params), out_dir, fmt)


def variants(name: str, count: int, seed: int = 0) -> list[dict]:
    """Generator parameters of ``count`` distinct, deterministic variants of a data set.

    Ellipsoids and bumpy ellipsoids vary their stretched half-axes, the cactus its bend
    angle, the hexagon its fold angle (each within a range where the data set stays valid).

    Parameters
    ----------
    name : str
        One of :data:`NAMES`.
    count : int
        Number of variants (>= 1).
    seed : int
        Seed of the random variation.

    Returns
    -------
    list of dict
        Keyword arguments for :func:`generate`, one per variant.
    """
    from ._common import positive_int

    count = positive_int(count, "count")
    if name not in _GENERATORS:
        raise ValueError(f"name must be one of {NAMES}, got {name!r}")
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(count):
        if name in ("ellipsoids", "bumpy"):
            a, b = rng.uniform(1.3, 2.2, size=2)
            out.append({"axes": [[float(a), 1.0, 1.0], [1.0, 1.0, 1.0], [1.0, float(b), 1.0]]})
        elif name == "cactus":
            out.append({"bend_angle": float(rng.uniform(0.2, 0.9))})
        else:
            out.append({"fold_angle": float(rng.uniform(0.8, 1.8))})
    return out


def write_batch(name: str, out_root, count: int, n_vertices: int | None = None,
                fmt: str = "obj", seed: int = 0) -> list[Path]:
    """Write ``count`` varied sequences of a data set as ``out_root/<name>_00/``, ... .

    Each directory is laid out as by :func:`write_keyframes` (``pose_*.<fmt>``,
    ``frames.txt``, ``pinned.txt``), ready for a batch job's ``glob``.

    Parameters
    ----------
    name : str
        One of :data:`NAMES`.
    out_root : str or path-like
        Parent directory, created if missing.
    count : int
        Number of sequences.
    n_vertices : int, optional
        Approximate vertex count.
    fmt : {"obj", "ply", "off"}
    seed : int
        Seed of :func:`variants`.

    Returns
    -------
    list of Path
        The sequence directories.
    """
    if fmt not in FORMATS:
        raise ValueError(f"fmt must be one of {FORMATS}, got {fmt!r}")
    params = variants(name, count, seed)
    width = max(2, len(str(count - 1)))
    dirs = []
    for i, p in enumerate(params):
        d = Path(out_root) / f"{name}_{i:0{width}d}"
        write_keyframes(generate(name, n_vertices, **p), d, fmt)
        dirs.append(d)
    return dirs

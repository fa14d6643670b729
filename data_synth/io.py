"""Writers for keyframe meshes (OBJ, PLY, OFF) that keep vertex order and full precision."""
from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["FORMATS", "write_mesh", "pose_filenames"]

FORMATS = ("obj", "ply", "off")
_FLOAT = "%.17g"


def _check_mesh(V, F):
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F)
    if V.ndim != 2 or V.shape[1] != 3:
        raise ValueError(f"V must be an (n,3) array, got shape {V.shape}")
    if F.ndim != 2 or F.shape[1] != 3 or not np.issubdtype(F.dtype, np.integer):
        raise ValueError(f"F must be an (m,3) integer array, got shape {F.shape}, "
                         f"dtype {F.dtype}")
    if F.size and (F.min() < 0 or F.max() >= V.shape[0]):
        raise ValueError(f"F indexes vertices outside [0, {V.shape[0]})")
    return V, F.astype(np.int64)


def _rows(fmt: str, A: np.ndarray) -> str:
    """Format every row of ``A`` with ``fmt`` (one line each) in a single ``%`` operation."""
    if A.shape[0] == 0:
        return ""
    return ((fmt + "\n") * A.shape[0]) % tuple(A.ravel().tolist())


def write_mesh(path, V, F, fmt: str | None = None) -> Path:
    """Write one triangle mesh as ASCII OBJ, PLY or OFF.

    Coordinates are written with ``%.17g`` (round-trip exact) and vertices in the given
    order; OBJ faces are 1-based, PLY and OFF faces 0-based.

    Parameters
    ----------
    path : str or path-like
        Output file.
    V : (n,3) float array
        Vertices.
    F : (m,3) int array
        Faces.
    fmt : {"obj", "ply", "off"}, optional
        File format; default taken from the file suffix.

    Returns
    -------
    Path
        The written file.
    """
    path = Path(path)
    if fmt is None:
        fmt = path.suffix.lstrip(".").lower()
    if fmt not in FORMATS:
        raise ValueError(f"fmt must be one of {FORMATS}, got {fmt!r}")
    V, F = _check_mesh(V, F)
    n, m = V.shape[0], F.shape[0]
    with open(path, "w", encoding="ascii", newline="\n") as fh:
        if fmt == "obj":
            fh.write(f"# {n} vertices, {m} faces (data_synth)\n")
            fh.write(_rows("v " + " ".join([_FLOAT] * 3), V))
            fh.write(_rows("f %d %d %d", F + 1))
        elif fmt == "ply":
            fh.write("ply\nformat ascii 1.0\ncomment data_synth\n"
                     f"element vertex {n}\nproperty double x\nproperty double y\n"
                     f"property double z\nelement face {m}\n"
                     "property list uchar int vertex_indices\nend_header\n")
            fh.write(_rows(" ".join([_FLOAT] * 3), V))
            fh.write(_rows("3 %d %d %d", F))
        else:
            fh.write(f"OFF\n{n} {m} 0\n")
            fh.write(_rows(" ".join([_FLOAT] * 3), V))
            fh.write(_rows("3 %d %d %d", F))
    return path


def pose_filenames(n_poses: int, fmt: str = "obj") -> list[str]:
    """File names ``pose_00.obj, pose_01.obj, ...`` whose lexicographic order is pose order.

    Parameters
    ----------
    n_poses : int
        Number of poses ``J``.
    fmt : str
        File suffix without the dot.

    Returns
    -------
    list of str
        Zero-padded to at least two digits (more when ``J > 100``).
    """
    width = max(2, len(str(max(n_poses - 1, 0))))
    return [f"pose_{j:0{width}d}.{fmt}" for j in range(n_poses)]

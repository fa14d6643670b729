"""A flat regular hexagon sheet and isometric folds of it (paper Fig. 10, inputs D, E, F).

The sheet is the part of a regular triangular lattice inside a regular hexagon of
circumradius 1 centred at the origin in the ``z = 0`` plane; with ``k`` lattice steps per
side it has ``3k^2 + 3k + 1`` vertices and ``6k^2`` equilateral faces.  Its three long
diagonals are lattice lines, so a fold along one of them is a crease on mesh edges.

The keyframes fold the sheet along the long diagonals at ``0``, ``120`` and ``240``
degrees with both wings lifted symmetrically (a "V"), so pose ``j+1`` is pose ``j``
rotated by 120 degrees about ``z``: the periodic sequence D -> E -> F -> D is symmetric.
"""
from __future__ import annotations

import math

import numpy as np

from ._common import frames_array, keyframes, positive_float, positive_int

__all__ = ["hexagon_steps", "hexagon_sheet", "folded", "hexagon"]

_FOLD_MODES = ("crease", "roll")


def hexagon_steps(n_vertices: int) -> int:
    """Lattice steps per side ``k`` whose hexagon has about ``n_vertices`` vertices.

    Parameters
    ----------
    n_vertices : int
        Requested vertex count (``>= 7``).

    Returns
    -------
    int
        ``k >= 1`` minimising ``|3k^2 + 3k + 1 - n_vertices|``.
    """
    n_vertices = positive_int(n_vertices, "n_vertices", minimum=7)
    k = max(1, int(round((-3.0 + math.sqrt(9.0 + 12.0 * (n_vertices - 1))) / 6.0)))
    cand = np.array([max(1, k - 1), k, k + 1])
    return int(cand[np.argmin(np.abs(3 * cand**2 + 3 * cand + 1 - n_vertices))])


def hexagon_sheet(k: int, circumradius: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Flat regular hexagon triangulated by a regular triangular lattice.

    Parameters
    ----------
    k : int
        Lattice steps per hexagon side (``>= 1``).
    circumradius : float
        Distance from the centre to a corner; corners lie at angles ``0, 60, ..., 300``
        degrees.

    Returns
    -------
    V : (3k^2+3k+1, 3) float64 array
        Vertices in the ``z = 0`` plane, sorted by lattice row (``y``) then ``x``.
    F : (6k^2, 3) int64 array
        Faces, counter-clockwise seen from ``+z`` (normals ``+z``).
    """
    k = positive_int(k, "k")
    circumradius = positive_float(circumradius, "circumradius")
    r, q = np.meshgrid(np.arange(-k, k + 1), np.arange(-k, k + 1), indexing="ij")
    inside = np.abs(q + r) <= k
    q, r = q[inside], r[inside]  # row-major: r (row) slow, q fast
    n = q.shape[0]
    index = np.full((2 * k + 3, 2 * k + 3), -1, dtype=np.int64)
    index[q + k + 1, r + k + 1] = np.arange(n)

    def at(dq, dr):
        qq, rr = q + dq, r + dr
        ok = (np.abs(qq) <= k) & (np.abs(rr) <= k) & (np.abs(qq + rr) <= k)
        return np.where(ok, index[qq + k + 1, rr + k + 1], -1)

    base = np.arange(n)
    up = np.stack([base, at(1, 0), at(0, 1)], axis=1)
    down = np.stack([base, at(0, 1), at(-1, 1)], axis=1)
    tri = np.concatenate([up, down])
    F = tri[(tri >= 0).all(axis=1)]
    s = circumradius / k
    V = np.zeros((n, 3))
    V[:, 0] = s * (q + 0.5 * r)
    V[:, 1] = s * (0.5 * math.sqrt(3.0)) * r
    return V, F.astype(np.int64)


def folded(V, angle_of_line: float, fold_angle: float, mode: str = "crease",
           half_width: float | None = None) -> np.ndarray:
    """Fold a flat sheet in the ``z = 0`` plane along a line through the origin.

    Both sides of the line are lifted symmetrically towards ``+z``.

    Parameters
    ----------
    V : (n,3) float array
        Flat sheet (``z`` is ignored).
    angle_of_line : float
        Direction of the fold line, radians from the ``+x`` axis.
    fold_angle : float
        Angle (radians) between the two sides' normals far from the line, in ``[0, pi)``.
    mode : {"crease", "roll"}
        ``"crease"``: each side is rotated rigidly by ``fold_angle/2`` about the line (a sharp
        fold; exactly isometric for any mesh, and a crease along mesh edges when the line
        lies on edges).  ``"roll"``: the sheet is rolled onto a circular cylinder whose
        axis is parallel to the line, turning by ``fold_angle/2`` at distance
        ``half_width``; isometric as a surface, edge lengths change by ``O(h^2 kappa^2)``.
    half_width : float, optional
        For ``"roll"``: largest distance of the sheet from the line (default: the largest
        ``|distance|`` over ``V``).

    Returns
    -------
    (n,3) float64 array
        Folded vertex positions.
    """
    if mode not in _FOLD_MODES:
        raise ValueError(f"mode must be one of {_FOLD_MODES}, got {mode!r}")
    if not np.isfinite(fold_angle) or not 0 <= fold_angle < math.pi:
        raise ValueError(f"fold_angle must lie in [0, pi), got {fold_angle!r}")
    V = np.asarray(V, dtype=np.float64)
    d = np.array([math.cos(angle_of_line), math.sin(angle_of_line)])
    nrm = np.array([-d[1], d[0]])
    u = V[:, :2] @ d
    v = V[:, :2] @ nrm
    scale = max(float(np.abs(V[:, :2]).max()), 1e-300)
    v[np.abs(v) < 1e-12 * scale] = 0.0  # vertices on the fold line stay exactly on it
    half = 0.5 * fold_angle
    out = np.empty_like(V)
    if mode == "crease":
        across = v * math.cos(half)
        lift = np.abs(v) * math.sin(half)
    else:
        w = float(np.abs(v).max()) if half_width is None else positive_float(half_width,
                                                                             "half_width")
        if half == 0 or w == 0:
            across, lift = v, np.zeros_like(v)
        else:
            Rc = w / half
            across = Rc * np.sin(v / Rc)
            lift = Rc * (1.0 - np.cos(v / Rc))
    out[:, :2] = u[:, None] * d[None, :] + across[:, None] * nrm[None, :]
    out[:, 2] = lift
    return out


def hexagon(n_vertices: int = 1000, *, fold_angle: float = math.pi / 2, mode: str = "crease",
            frames=(0, 4, 8)) -> dict:
    """Three isometric folds D, E, F of a flat regular hexagon (paper Fig. 10).

    Parameters
    ----------
    n_vertices : int
        Approximate vertex count (``3k^2 + 3k + 1`` for the closest ``k``; 1000 gives 1027).
    fold_angle : float
        Angle between the two wings' normals, in ``[0, pi)``; default ``pi/2``.
    mode : {"crease", "roll"}
        Sharp crease along a long diagonal (exact discrete isometry, default) or a smooth
        cylindrical roll about it; see :func:`folded`.
    frames : (3,) int array_like
        Suggested keyframe frames, default ``(0, 4, 8)`` (use periodically with ``K = 12``).

    Returns
    -------
    dict
        ``V`` (3,n,3) float64, ``F`` (m,3) int64 (normals ``+z`` in the flat sheet),
        ``frames`` (3,) int64, ``pinned`` ``None``, ``rest`` (n,3) float64 (the flat
        hexagon ``H``), ``periodic`` ``True``.
    """
    k = hexagon_steps(n_vertices)
    fr = frames_array(frames, 3)
    H, F = hexagon_sheet(k)
    poses = [folded(H, 2.0 * math.pi * j / 3.0, fold_angle, mode) for j in range(3)]
    return keyframes(np.stack(poses), F, fr, None, rest=H, periodic=True)

"""A ribbed, capped cactus trunk bent in two orthogonal directions (paper Fig. 4).

The surface is a surface of revolution with a flat bottom disk, a vertical trunk and a
hemispherical dome, optionally with vertical ribs.  It is meshed as a ring grid: a bottom
pole, ``rings`` rings of ``segments`` vertices each, and a top pole, so the vertex count
is ``segments * rings + 2``.

The bent poses roll the trunk above the base onto a circular arc: every horizontal cross
section stays rigid and follows the arc, perpendicular to it.  The centre line keeps its
length, and a point at signed distance ``u`` from it (towards the bend) is
stretched by the factor ``1 - u * curvature``, so the deformation is isometric up to a
relative strain of at most ``max_radius * bend_angle / bend_length`` (about 6 % with the
defaults).  Everything at or below ``base_height`` stays fixed.
"""
from __future__ import annotations

import math

import numpy as np

from ._common import frames_array, keyframes, positive_float, positive_int

__all__ = ["cactus", "cactus_rest", "bent"]


def _ring_counts(n_vertices: int, height: float, radius: float, multiple: int):
    """Segments per ring and ring counts of disk, side and dome for about ``n_vertices``."""
    circumference = 2.0 * math.pi * radius
    dome = 0.5 * math.pi * radius
    profile = radius + height + dome

    def counts(h):
        S = max(multiple, multiple * int(round(circumference / h / multiple)))
        nd = max(1, int(round(radius / h)))
        ns = max(1, int(round(height / h)))
        nt = max(2, int(round(dome / h)))
        return S, nd, ns, nt, 2 + S * (nd + ns + nt - 1)

    h = math.sqrt(circumference * profile / max(n_vertices - 2, 1))
    S, nd, ns, nt, n = counts(h)
    # one correction step for rounding (helps at low resolutions)
    S, nd, ns, nt, n2 = counts(h * math.sqrt(n / n_vertices))
    if abs(n2 - n_vertices) > abs(n - n_vertices):
        S, nd, ns, nt, n2 = counts(h)
    return S, nd, ns, nt


def cactus_rest(n_vertices: int = 5000, *, height: float = 1.0, radius: float = 0.08,
                n_ribs: int = 8, rib_depth: float = 0.08) -> tuple[np.ndarray, np.ndarray]:
    """Straight (rest) cactus trunk: a closed, ribbed, capped tube standing on ``z = 0``.

    Parameters
    ----------
    n_vertices : int
        Approximate vertex count (``>= 20``).
    height : float
        Height of the cylindrical part; the dome adds ``radius`` on top.
    radius : float
        Mean trunk radius.
    n_ribs : int
        Number of vertical ribs (``0`` for a round trunk).
    rib_depth : float
        Relative radial rib amplitude, ``0 <= rib_depth < 1``: the cross section radius is
        ``radius * (1 + rib_depth * cos(n_ribs * phi))``.

    Returns
    -------
    V : (n,3) float64 array
        Vertices: index 0 is the bottom pole, then the rings from bottom to top (each
        counter-clockwise seen from ``+z``, starting on the ``+x`` axis), last the top pole.
    F : (m,3) int64 array
        Faces with outward normals.
    """
    n_vertices = positive_int(n_vertices, "n_vertices", minimum=20)
    height = positive_float(height, "height")
    radius = positive_float(radius, "radius")
    n_ribs = positive_int(n_ribs, "n_ribs", minimum=0)
    rib_depth = positive_float(rib_depth, "rib_depth", allow_zero=True)
    if rib_depth >= 1:
        raise ValueError(f"rib_depth must be < 1, got {rib_depth}")
    multiple = math.lcm(4, n_ribs) if n_ribs else 4
    S, nd, ns, nt = _ring_counts(n_vertices, height, radius, multiple)

    # Profile (rho, z) of the rings, bottom pole and top pole excluded.
    rho_disk = radius * np.arange(1, nd + 1) / nd
    z_disk = np.zeros(nd)
    z_side = height * np.arange(1, ns + 1) / ns
    rho_side = np.full(ns, radius)
    psi = 0.5 * math.pi * np.arange(1, nt) / nt
    rho_dome = radius * np.cos(psi)
    z_dome = height + radius * np.sin(psi)
    rho = np.concatenate([rho_disk, rho_side, rho_dome])
    z = np.concatenate([z_disk, z_side, z_dome])
    R = rho.shape[0]

    phi = 2.0 * math.pi * np.arange(S) / S
    shape = 1.0 + rib_depth * np.cos(n_ribs * phi) if n_ribs else np.ones(S)
    ring_xy = np.stack([np.cos(phi) * shape, np.sin(phi) * shape], axis=1)  # (S,2)
    V = np.empty((R * S + 2, 3))
    V[0] = (0.0, 0.0, 0.0)
    V[1:-1, :2] = (rho[:, None, None] * ring_xy[None, :, :]).reshape(-1, 2)
    V[1:-1, 2] = np.repeat(z, S)
    V[-1] = (0.0, 0.0, height + radius)

    j = np.arange(S)
    j1 = (j + 1) % S
    top = R * S + 1
    bottom_fan = np.stack([np.zeros(S, np.int64), 1 + j1, 1 + j], axis=1)
    lo = 1 + (np.arange(R - 1)[:, None] * S)  # first vertex of the lower ring of each band
    L0, L1 = lo + j, lo + j1
    U0, U1 = L0 + S, L1 + S
    quads_a = np.stack([L0, L1, U1], axis=-1).reshape(-1, 3)
    quads_b = np.stack([L0, U1, U0], axis=-1).reshape(-1, 3)
    last = 1 + (R - 1) * S
    top_fan = np.stack([last + j, last + j1, np.full(S, top)], axis=1)
    F = np.concatenate([bottom_fan, quads_a, quads_b, top_fan]).astype(np.int64)
    return V, F


def bent(V, direction, bend_angle: float, base_height: float, length: float) -> np.ndarray:
    """Bend a vertical trunk onto a circular arc above ``z = base_height``.

    Each horizontal slice at height ``z > base_height`` is moved rigidly to arc length
    ``s = z - base_height`` along an arc of curvature ``bend_angle / length`` that starts
    vertically at ``(0, 0, base_height)``, and is rotated to stay perpendicular to the arc.
    Points at or below ``base_height`` are returned unchanged (bit for bit).

    Parameters
    ----------
    V : (n,3) float array
        Straight trunk, axis along ``z`` through the origin.
    direction : (2,) float array_like
        Horizontal direction ``(d_x, d_y)`` towards which the trunk bends (normalised here).
    bend_angle : float
        Angle (radians) between the trunk's axis at the base and at arc length ``length``.
    base_height : float
        Height of the fixed base.
    length : float
        Arc length over which the tangent turns by ``bend_angle``.

    Returns
    -------
    (n,3) float64 array
        Bent vertex positions.
    """
    V = np.asarray(V, dtype=np.float64)
    d = np.asarray(direction, dtype=np.float64)
    if d.shape != (2,) or not np.all(np.isfinite(d)) or np.linalg.norm(d) == 0:
        raise ValueError(f"direction must be a nonzero (2,) vector, got {direction!r}")
    d = d / np.linalg.norm(d)
    length = positive_float(length, "length")
    out = V.copy()
    if bend_angle == 0:
        return out
    kappa = float(bend_angle) / length
    Rc = 1.0 / kappa
    moving = V[:, 2] > base_height
    P = V[moving]
    u = P[:, :2] @ d  # component towards the bend
    w = P[:, :2] - u[:, None] * d[None, :]  # horizontal component across the bend
    theta = kappa * (P[:, 2] - base_height)
    arm = Rc - u
    u_new = Rc - arm * np.cos(theta)
    out[moving, :2] = w + u_new[:, None] * d[None, :]
    out[moving, 2] = base_height + arm * np.sin(theta)
    return out


def cactus(n_vertices: int = 5000, *, height: float = 1.0, radius: float = 0.08,
           n_ribs: int = 8, rib_depth: float = 0.08, bend_angle: float = math.pi / 4,
           base_height: float = 0.05, frames=(0, 10, 20)) -> dict:
    """Three cactus keyframes: bent towards ``+x``, straight, bent towards ``+y`` (Fig. 4).

    Parameters
    ----------
    n_vertices : int
        Approximate vertex count (5000 gives about the paper's 5261-vertex cactus).
    height, radius, n_ribs, rib_depth
        Shape of the straight trunk, see :func:`cactus_rest`.
    bend_angle : float
        Angle (radians) by which the trunk's tip direction turns in the bent poses; the
        curvature is constant from the base to the tip.  Default ``pi/4``.
    base_height : float
        Vertices with ``z <= base_height`` (bottom disk and lowest rings) are identical in
        all poses and returned as ``pinned``; ``0 <= base_height < height``.
    frames : (3,) int array_like
        Suggested keyframe frames, default ``(0, 10, 20)``.

    Returns
    -------
    dict
        ``V`` (3,n,3) float64, ``F`` (m,3) int64 (outward), ``frames`` (3,) int64,
        ``pinned`` (p,) int64 (base vertices), ``rest`` (n,3) float64 (= ``V[1]``),
        ``curvature`` float (of the bent trunk's centre line).
    """
    V0, F = cactus_rest(n_vertices, height=height, radius=radius, n_ribs=n_ribs,
                        rib_depth=rib_depth)
    if isinstance(bend_angle, bool) or not np.isfinite(bend_angle) \
            or not 0 <= float(bend_angle) <= math.pi:
        raise ValueError(f"bend_angle must lie in [0, pi], got {bend_angle!r}")
    base_height = positive_float(base_height, "base_height", allow_zero=True)
    if base_height >= height:
        raise ValueError(f"base_height must be < height ({height}), got {base_height}")
    fr = frames_array(frames, 3)
    length = height + radius - base_height
    Vx = bent(V0, (1.0, 0.0), bend_angle, base_height, length)
    Vy = bent(V0, (0.0, 1.0), bend_angle, base_height, length)
    pinned = np.flatnonzero(V0[:, 2] <= base_height)
    return keyframes(np.stack([Vx, V0, Vy]), F, fr, pinned, rest=V0,
                     curvature=float(bend_angle) / length)

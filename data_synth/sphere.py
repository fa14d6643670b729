"""Geodesic (subdivided icosahedron) spheres, ellipsoid keyframes and bumpy spheres.

The sphere is a class-I geodesic polyhedron: each icosahedron face is cut into
``nu**2`` triangles by a regular barycentric grid and the grid points are projected onto
the unit sphere.  It has ``10 nu**2 + 2`` vertices, any ``nu >= 1`` is allowed, so a
requested vertex count is met closely, and its triangles are nearly equilateral.
"""
from __future__ import annotations

import numpy as np

from ._common import frames_array, keyframes, positive_float, positive_int

__all__ = ["sphere_frequency", "geodesic_sphere", "ellipsoids", "bumpy",
           "DEFAULT_ELLIPSOID_AXES"]

#: Default half-axes ``(a_x, a_y, a_z)`` of the three ellipsoid keyframes: stretched along
#: ``x``, the unit sphere, stretched along ``y``.  In the ``(a_x, a_y)`` half-axis plane the
#: keyframes form an "L" with its corner at the middle keyframe, so a piecewise geodesic
#: interpolation has a kink there while a spline passes it smoothly (paper Fig. 3).
DEFAULT_ELLIPSOID_AXES = ((2.0, 1.0, 1.0), (1.0, 1.0, 1.0), (1.0, 2.0, 1.0))

_PHI = (1.0 + 5.0 ** 0.5) / 2.0
_ICO_V = np.array([
    [-1, _PHI, 0], [1, _PHI, 0], [-1, -_PHI, 0], [1, -_PHI, 0],
    [0, -1, _PHI], [0, 1, _PHI], [0, -1, -_PHI], [0, 1, -_PHI],
    [_PHI, 0, -1], [_PHI, 0, 1], [-_PHI, 0, -1], [-_PHI, 0, 1],
], dtype=np.float64)
_ICO_F = np.array([
    [0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11],
    [1, 5, 9], [5, 11, 4], [11, 10, 2], [10, 7, 6], [7, 1, 8],
    [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8], [3, 8, 9],
    [4, 9, 5], [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1],
], dtype=np.int64)


def _outward_icosahedron() -> tuple[np.ndarray, np.ndarray]:
    """Icosahedron with every face oriented so that its normal points away from the centre."""
    V = _ICO_V / np.linalg.norm(_ICO_V, axis=1, keepdims=True)
    F = _ICO_F.copy()
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    inward = np.einsum("ij,ij->i", np.cross(b - a, c - a), a + b + c) < 0
    F[inward] = F[inward][:, [0, 2, 1]]
    return V, F


def sphere_frequency(n_vertices: int) -> int:
    """Subdivision frequency ``nu`` whose geodesic sphere has about ``n_vertices`` vertices.

    Parameters
    ----------
    n_vertices : int
        Requested vertex count (``>= 12``).

    Returns
    -------
    int
        ``nu >= 1`` minimising ``|10 nu**2 + 2 - n_vertices|``.
    """
    n_vertices = positive_int(n_vertices, "n_vertices", minimum=12)
    nu = max(1, int(round(np.sqrt((n_vertices - 2) / 10.0))))
    candidates = np.array([max(1, nu - 1), nu, nu + 1])
    return int(candidates[np.argmin(np.abs(10 * candidates**2 + 2 - n_vertices))])


def geodesic_sphere(nu: int) -> tuple[np.ndarray, np.ndarray]:
    """Unit geodesic sphere obtained by ``nu``-fold subdivision of an icosahedron.

    Parameters
    ----------
    nu : int
        Subdivision frequency (``>= 1``); every icosahedron edge is cut into ``nu`` pieces.

    Returns
    -------
    V : (10 nu**2 + 2, 3) float64 array
        Vertices on the unit sphere.
    F : (20 nu**2, 3) int64 array
        Faces, consistently oriented with outward normals.
    """
    nu = positive_int(nu, "nu")
    V0, F0 = _outward_icosahedron()
    # Local barycentric grid of one face: point (i, j) has weights (nu-i-j, i, j) on (A, B, C).
    i, j = np.meshgrid(np.arange(nu + 1), np.arange(nu + 1), indexing="ij")
    keep = i + j <= nu
    i, j = i[keep], j[keep]
    P = i.shape[0]
    local = np.full((nu + 2, nu + 2), -1, dtype=np.int64)
    local[i, j] = np.arange(P)
    up = (i + j) <= nu - 1
    iu, ju = i[up], j[up]
    tri_up = np.stack([local[iu, ju], local[iu + 1, ju], local[iu, ju + 1]], axis=1)
    dn = (i + j) <= nu - 2
    idn, jdn = i[dn], j[dn]
    tri_dn = np.stack([local[idn + 1, jdn], local[idn + 1, jdn + 1], local[idn, jdn + 1]], axis=1)
    tri = np.concatenate([tri_up, tri_dn])

    # Integer weights on the 12 icosahedron vertices identify shared points exactly.
    nf = F0.shape[0]
    W = np.zeros((nf, P, 12), dtype=np.int32)
    rows = np.arange(P)
    for c, w in enumerate((nu - i - j, i, j)):
        # one assignment per corner; corners of a face are distinct vertices
        W[np.arange(nf)[:, None], rows[None, :], F0[:, c][:, None]] = w[None, :]
    W = W.reshape(nf * P, 12)
    _, first, inverse = np.unique(W, axis=0, return_index=True, return_inverse=True)
    inverse = inverse.reshape(-1)
    # number vertices by first occurrence (keeps neighbouring vertices close in memory)
    order = np.argsort(first, kind="stable")
    rank = np.empty_like(order)
    rank[order] = np.arange(order.shape[0])
    glob = rank[inverse]
    Wu = W[first[order]].astype(np.float64)
    V = Wu @ V0
    V /= np.linalg.norm(V, axis=1, keepdims=True)
    F = glob.reshape(nf, P)[np.arange(nf)[:, None, None], tri[None, :, :]].reshape(-1, 3)
    return V, F.astype(np.int64)


def _axes_array(axes, name: str = "axes") -> np.ndarray:
    A = np.asarray(axes, dtype=np.float64)
    if A.ndim != 2 or A.shape[1] != 3 or A.shape[0] < 1:
        raise ValueError(f"{name} must be a (J,3) array of half-axes, got shape {A.shape}")
    if not np.all(np.isfinite(A)) or np.any(A <= 0):
        raise ValueError(f"{name} must be finite and positive, got {A.tolist()}")
    return A


def _default_frames(J: int, spacing: int) -> np.ndarray:
    return np.arange(J, dtype=np.int64) * spacing


def ellipsoids(n_vertices: int = 500, *, axes=DEFAULT_ELLIPSOID_AXES, frames=None) -> dict:
    """Keyframe poses of ellipsoids with varying half-axes (paper Fig. 3).

    Every pose is the same geodesic sphere scaled by its half-axes, so vertex ``i`` keeps
    its position on the unit sphere and the connectivity is shared.

    Parameters
    ----------
    n_vertices : int
        Approximate vertex count; the mesh has ``10 nu**2 + 2`` vertices for the closest
        ``nu`` (500 gives 492).
    axes : (J,3) float array_like
        Half-axes ``(a_x, a_y, a_z)`` of each pose.  Default
        ``((2,1,1), (1,1,1), (1,2,1))``: stretched along ``x``, sphere, stretched along ``y``.
    frames : (J,) int array_like, optional
        Suggested keyframe frames; default ``0, 6, 12, ...`` (``K = 6 (J-1)``).

    Returns
    -------
    dict
        ``V`` (J,n,3) float64, ``F`` (m,3) int64 (outward), ``frames`` (J,) int64,
        ``pinned`` ``None``, ``axes`` (J,3) float64.
    """
    nu = sphere_frequency(n_vertices)
    A = _axes_array(axes)
    S, F = geodesic_sphere(nu)
    Vs = S[None, :, :] * A[:, None, :]
    fr = _default_frames(A.shape[0], 6) if frames is None else frames_array(frames, A.shape[0])
    return keyframes(Vs, F, fr, None, axes=A)


def bumpy(n_vertices: int = 2500, *, axes=DEFAULT_ELLIPSOID_AXES, frequency: int = 6,
          amplitude: float = 0.03, frames=None) -> dict:
    """Ellipsoid keyframes carrying high-frequency radial bumps (for multiresolution tests).

    The unit sphere is displaced radially by ``1 + amplitude * sin(f x) sin(f y) sin(f z)``
    (``f = frequency * pi``) and then scaled by each pose's half-axes; the bumps therefore
    ride along with the coarse ellipsoid deformation.

    Parameters
    ----------
    n_vertices : int
        Approximate vertex count (geodesic sphere, ``10 nu**2 + 2`` vertices).
    axes : (J,3) float array_like
        Half-axes of each pose; same default as :func:`ellipsoids`.
    frequency : int
        Number of bump periods across the unit sphere's diameter per axis.
    amplitude : float
        Relative radial bump height, ``0 <= amplitude < 1``.
    frames : (J,) int array_like, optional
        Suggested keyframe frames; default ``0, 6, 12, ...``.

    Returns
    -------
    dict
        ``V`` (J,n,3) float64, ``F`` (m,3) int64 (outward), ``frames`` (J,) int64,
        ``pinned`` ``None``, ``axes`` (J,3) float64.
    """
    nu = sphere_frequency(n_vertices)
    A = _axes_array(axes)
    frequency = positive_int(frequency, "frequency")
    amplitude = positive_float(amplitude, "amplitude", allow_zero=True)
    if amplitude >= 1:
        raise ValueError(f"amplitude must be < 1, got {amplitude}")
    S, F = geodesic_sphere(nu)
    f = frequency * np.pi
    r = 1.0 + amplitude * np.sin(f * S[:, 0]) * np.sin(f * S[:, 1]) * np.sin(f * S[:, 2])
    B = S * r[:, None]
    Vs = B[None, :, :] * A[:, None, :]
    fr = _default_frames(A.shape[0], 6) if frames is None else frames_array(frames, A.shape[0])
    return keyframes(Vs, F, fr, None, axes=A)

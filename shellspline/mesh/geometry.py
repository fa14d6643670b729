"""Vectorised geometry of triangle meshes: cross and dot products over the last axis, face
normals and areas, area-weighted vertex normals, all batched over leading pose axes.

The mesh layer and everything above it take these from here (one implementation of each).
"""
from __future__ import annotations

import numpy as np

from ..errors import tol

__all__ = ["cross", "dot", "norms", "normalized", "coordinate_rows", "cross_rows", "dot_rows",
           "face_normals", "face_areas",
           "vertex_face_incidence", "vertex_normals", "flap_angles"]


def cross(a, b) -> np.ndarray:
    """Cross product over the last axis (broadcasting), written out.

    Several times faster than ``np.cross`` on large batched arrays and bit-identical to it
    (the same products and differences).

    Parameters
    ----------
    a, b : (..., 3) float arrays

    Returns
    -------
    (..., 3) float64 array

    Examples
    --------
    >>> cross([1.0, 0, 0], [0, 1.0, 0]).tolist()
    [0.0, 0.0, 1.0]
    """
    a, b = np.asarray(a), np.asarray(b)
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)


def dot(a, b) -> np.ndarray:
    """Dot product over the last axis: ``(..., d), (..., d) -> (...)``."""
    return np.einsum("...i,...i->...", a, b)


def norms(a) -> np.ndarray:
    """Euclidean lengths over the last axis: ``(..., d) -> (...)``."""
    return np.sqrt(np.einsum("...i,...i->...", a, a))


def normalized(a) -> np.ndarray:
    """``a`` divided by its length over the last axis (a zero vector stays zero).

    The length is floored at :data:`shellspline.errors.tol.zero`, so nothing is divided by 0.

    Examples
    --------
    >>> normalized([[3.0, 4.0, 0.0], [0.0, 0.0, 0.0]]).tolist()
    [[0.6, 0.8, 0.0], [0.0, 0.0, 0.0]]
    """
    a = np.asarray(a, dtype=np.float64)
    return a / np.maximum(norms(a), tol.zero)[..., None]


def coordinate_rows(V) -> np.ndarray:
    """The coordinates of ``V`` as three contiguous rows: ``(..., 3) -> (3, ...)``.

    The layout of :func:`cross_rows` and :func:`dot_rows`: gathering element corners with
    ``np.take(X, idx, axis=-1)`` then gives three contiguous component arrays, and every
    product below runs on contiguous memory instead of stride-3 views.
    """
    return np.ascontiguousarray(np.moveaxis(np.asarray(V), -1, 0))


def cross_rows(a, b) -> tuple:
    """:func:`cross` of vectors given as coordinate rows ``a = (a0, a1, a2)``.

    Parameters
    ----------
    a, b : sequences of three (...) arrays, or (3, ...) arrays
        Components (e.g. from :func:`coordinate_rows`); real or complex.

    Returns
    -------
    tuple of three (...) arrays
        The components of ``a × b``: the same products and differences as :func:`cross`
        (bit-identical).

    Examples
    --------
    >>> [float(c) for c in cross_rows([1.0, 0, 0], [0, 1.0, 0])]
    [0.0, 0.0, 1.0]
    """
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def dot_rows(a, b):
    """:func:`dot` of 3-vectors given as coordinate rows: ``(a0 b0 + a2 b2) + a1 b1``.

    The sum is taken in the order numpy's ``einsum`` takes it over a last axis of length 3
    on x86-64 (two SIMD lanes: components 0 and 2 first), so for real input the result
    equals :func:`dot` bit for bit there; the Gauss–Newton iterates of
    :mod:`shellspline.shells.reconstruct` did not change when its element gradients moved
    to this layout.

    Parameters
    ----------
    a, b : sequences of three (...) arrays, or (3, ...) arrays

    Returns
    -------
    (...) array

    Examples
    --------
    >>> float(dot_rows([1.0, 2.0, 3.0], [4.0, 5.0, 6.0]))
    32.0
    """
    return (a[0] * b[0] + a[2] * b[2]) + a[1] * b[1]


def face_normals(V, F, *, unit: bool = False) -> np.ndarray:
    """Face normals ``(v1 − v0) × (v2 − v0)`` (length twice the area) or unit normals.

    Parameters
    ----------
    V : (..., n, 3) float array
        One pose or a batch of poses.
    F : (m,3) int array
    unit : bool
        Normalise to unit length (a degenerate face gets the zero vector).

    Returns
    -------
    N : (..., m, 3) float64 array

    Examples
    --------
    >>> V = [[0.0, 0, 0], [2.0, 0, 0], [0, 1.0, 0]]
    >>> face_normals(V, [[0, 1, 2]]).tolist(), face_areas(V, [[0, 1, 2]]).tolist()
    ([[0.0, 0.0, 2.0]], [1.0])
    """
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F)
    # np.take along the vertex axis: ~2x faster than V[..., idx, :] on batched poses
    v0, v1, v2 = (np.take(V, F[:, i], axis=-2) for i in range(3))
    N = cross(v1 - v0, v2 - v0)
    if unit:
        nn = norms(N)[..., None]
        N = np.divide(N, nn, out=np.zeros_like(N), where=nn > 0)
    return N


def face_areas(V, F) -> np.ndarray:
    """Triangle areas: ``(..., n, 3)`` poses, ``(m,3)`` faces ``-> (..., m)``."""
    return 0.5 * norms(face_normals(V, F))


def vertex_face_incidence(F, n: int):
    """The sparse ``(n, m)`` matrix with a 1 where vertex ``i`` is a corner of face ``t``.

    ``vertex_face_incidence(F, n) @ X`` sums per-face rows ``X (m, ...)`` onto the vertices.
    """
    import scipy.sparse as sp

    F = np.asarray(F, dtype=np.int64)
    m = F.shape[0]
    return sp.csr_matrix((np.ones(3 * m), (F.T.ravel(), np.tile(np.arange(m), 3))),
                         shape=(n, m))


def vertex_normals(V, F, incidence=None) -> np.ndarray:
    """Area-weighted unit vertex normals of one or several poses.

    Parameters
    ----------
    V : (..., n, 3) float array
    F : (m,3) int array
    incidence : scipy.sparse matrix, optional
        :func:`vertex_face_incidence` of ``F`` (pass it to reuse it across calls).

    Returns
    -------
    (..., n, 3) float64 array
        Unit normals (zero for vertices no face uses, or whose face normals cancel).

    Examples
    --------
    >>> V = [[0.0, 0, 0], [1.0, 0, 0], [0, 1.0, 0], [5.0, 5.0, 5.0]]
    >>> vertex_normals(V, [[0, 1, 2]]).tolist()
    [[0.0, 0.0, 1.0], [0.0, 0.0, 1.0], [0.0, 0.0, 1.0], [0.0, 0.0, 0.0]]
    """
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    n, m = V.shape[-2], F.shape[0]
    inc = vertex_face_incidence(F, n) if incidence is None else incidence
    fn = face_normals(V, F)  # twice the area times the unit normal, (..., m, 3)
    batch = fn.shape[:-2]
    cols = np.moveaxis(fn, -2, 0).reshape(m, -1)  # (m, batch*3)
    N = np.moveaxis(np.asarray(inc @ cols).reshape((n,) + batch + (3,)), 0, -2)
    nn = norms(N)[..., None]
    return np.divide(N, nn, out=np.zeros_like(N), where=nn > 0)


def flap_angles(V, N, T) -> np.ndarray:
    """Signed dihedral angles of the interior edges from the face normals ``N`` of ``V``.

    ``atan2((n1 × n2) · e, (n1 · n2) |e|)`` with ``n1, n2`` the normals of the edge's two
    faces (first the face holding the flap's third vertex) and ``e`` the edge vector: the
    angle of :func:`shellspline.shells.descriptors.dihedral_angles` to round-off, for
    callers that already have the normals (the defect checks: one cross product per face
    instead of two per edge).

    Parameters
    ----------
    V : (..., n, 3) float64 array
    N : (..., m, 3) float64 array
        Face normals of ``V`` (any positive length per face, e.g. :func:`face_normals`).
    T : Topology

    Returns
    -------
    (..., i) float64 array in (-π, π]

    Examples
    --------
    >>> from shellspline.mesh.topology import topology
    >>> F = np.array([[0, 1, 2], [1, 0, 3]])
    >>> V = np.array([[0., 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, -1]])
    >>> np.degrees(flap_angles(V, face_normals(V, F), topology(F))).round(6).tolist()
    [90.0]
    """
    ef = T.edge_faces[T.interior]
    n1, n2 = N[..., ef[:, 0], :], N[..., ef[:, 1], :]
    e = V[..., T.flaps[:, 1], :] - V[..., T.flaps[:, 0], :]
    # both arguments scaled by |n1| |n2| |e| > 0: the angle of the unit vectors
    return np.arctan2(dot(cross(n1, n2), e), dot(n1, n2) * norms(e))

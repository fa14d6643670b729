"""Rigid motions of a mesh: the kernel of every shell energy (dimension 6).

Rigid motions must be fixed before any Cholesky of a shell Hessian (ARCHITECTURE, math notes).
"""
from __future__ import annotations

import numpy as np

from ..errors import tol

__all__ = ["rigid_modes", "best_rotations"]


def rigid_modes(V, free, pinned_dofs):
    """Orthonormal basis ``(len(free), r)`` of the infinitesimal rigid motions of ``V (n,3)``
    that leave the pinned DOFs fixed, restricted to the free DOFs (``r <= 6``). The pinned rows
    are examined first, so three non-collinear pins (``r = 0``) cost no full-size basis."""
    c = V - V.mean(axis=0)

    def basis(cc):  # (m,3) centred points -> (3m, 6): translations, e_a × c
        B = np.zeros((len(cc), 3, 6))
        B[:, [0, 1, 2], [0, 1, 2]] = 1.0
        B[:, 1, 3], B[:, 2, 3] = -cc[:, 2], cc[:, 1]
        B[:, 0, 4], B[:, 2, 4] = cc[:, 2], -cc[:, 0]
        B[:, 0, 5], B[:, 1, 5] = -cc[:, 1], cc[:, 0]
        return B.reshape(-1, 6)

    C = None
    if len(pinned_dofs):
        pv = np.unique(pinned_dofs // 3)
        rows = 3 * np.searchsorted(pv, pinned_dofs // 3) + pinned_dofs % 3
        Bp = basis(c[pv])[rows]
        if len(Bp) < 6:  # one pin: pad with zero rows so that Vh is (6,6) (same row space)
            Bp = np.vstack([Bp, np.zeros((6 - len(Bp), 6))])
        _, s, Vh = np.linalg.svd(Bp, full_matrices=False)
        rank = int(np.sum(s > 1e-10 * max(s[0], tol.zero)))
        C = Vh[rank:].T
        if C.shape[1] == 0:
            return np.zeros((len(free), 0))
    B = basis(c)
    if C is not None:
        B = B @ C
    Q, _ = np.linalg.qr(B[free])
    return Q


def best_rotations(X, Y) -> np.ndarray:
    """Rotations ``R`` (det +1) that best map centred points ``X`` onto centred points ``Y``
    (Kabsch): ``R`` minimises ``Σ_i |R x_i − y_i|²``, batched over leading axes.

    Parameters
    ----------
    X, Y : (..., n, 3) float arrays
        Point sets with their centroids removed (broadcast against each other).

    Returns
    -------
    R : (..., 3, 3) float64 array
        ``y_i ≈ R x_i``; a reflection is never returned (the last singular direction is
        flipped instead).

    Examples
    --------
    >>> X = np.array([[1.0, 0, 0], [-1.0, 0, 0], [0, 2.0, 0], [0, -2.0, 0]])
    >>> Rz = np.array([[0.0, -1, 0], [1.0, 0, 0], [0, 0, 1.0]])
    >>> bool(np.allclose(best_rotations(X, X @ Rz.T), Rz))
    True
    """
    H = np.einsum("...ni,...nk->...ik", X, Y)                 # cross-covariances
    U, _, Wt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(np.einsum("...ki,...lk->...il", Wt, U)))
    D = np.zeros(H.shape)
    D[..., 0, 0] = D[..., 1, 1] = 1.0
    D[..., 2, 2] = np.where(d == 0, 1.0, d)
    return np.einsum("...ki,...kl,...ml->...im", Wt, D, U)

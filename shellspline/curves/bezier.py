"""Bézier curves on a Lie group by geodesic de Casteljau, with exact velocities.

Control points are arrays ``P (..., n + 1, *G.shape)`` (leading axes: many curves), times
``s (T,)`` in ``[0, 1]`` (values outside extrapolate smoothly); results are
``(..., T, *G.shape)``. Velocities are left-trivialised (body frame): ``xi = g^{-1} dg/ds``,
``(..., T, G.dim)``.
"""
from __future__ import annotations

import numpy as np

from ..errors import ShellsplineError
from ..groups.lie import group

__all__ = ["geodesic", "de_casteljau", "bezier", "bezier_velocity", "bezier_ckl"]


def _times(s, name="s"):
    s = np.asarray(s, dtype=np.float64)
    if s.ndim > 1 or not np.all(np.isfinite(s)):
        raise ShellsplineError(f"{name} must be a finite scalar or 1-D array, got shape "
                               f"{s.shape}")
    return np.atleast_1d(s), s.ndim == 0


def _expand(G, P, s):
    """``(..., T, n+1, *shape)`` copies of the control points and ``s`` broadcastable to
    ``(..., T, n)``."""
    k = len(G.shape)
    P = np.asarray(P, dtype=np.float64)
    if P.ndim < k + 1 or P.shape[P.ndim - k:] != tuple(G.shape):
        raise ShellsplineError(f"control points must have shape (..., n+1, "
                               f"{', '.join(map(str, G.shape))}), got {P.shape}")
    P = G.check(P, "P")  # finite, rotations that are rotations (a NaN pose went through)
    lead = P.shape[:P.ndim - k - 1]
    b = np.broadcast_to(np.expand_dims(P, P.ndim - k - 1), lead + (s.size,) + P.shape[-k - 1:])
    return b, k


def geodesic(G, a, b, s):
    """The geodesic interpolant ``a exp(s log(a^{-1} b))`` at times ``s``.

    Parameters
    ----------
    G : LieGroup or str
    a, b : (..., *G.shape) array_like
    s : (T,) array_like or float

    Returns
    -------
    (..., T, *G.shape) ndarray, or ``(..., *G.shape)`` for a scalar ``s``.

    Examples
    --------
    >>> import numpy as np
    >>> from shellspline.groups import so3
    >>> R = geodesic("so3", np.eye(3), so3.exp([0, 0, 1.0]), 0.25)
    >>> float(np.round(so3.log(R)[2], 12))
    0.25
    """
    G = group(G)
    a, b = np.broadcast_arrays(np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64))
    return bezier(G, np.stack([a, b], axis=a.ndim - len(G.shape)), s)


def de_casteljau(G, P, s, velocity=False):
    """The geodesic de Casteljau algorithm with one parameter per curve.

    Parameters
    ----------
    G : LieGroup
    P : (..., n + 1, *G.shape) ndarray
        Control points of independent curves.
    s : array_like, broadcastable to ``P.shape[:-len(G.shape)-1]``
        One parameter per curve.
    velocity : bool
        Also return the exact body velocity ``g^{-1} dg/ds``.

    Returns
    -------
    g : (..., *G.shape) ndarray
    xi : (..., G.dim) ndarray, only with ``velocity``

    Notes
    -----
    ``b_{i,0} = g_i``, ``b_{i,j} = interp_s(b_{i,j-1}, b_{i+1,j-1})``, ``g = b_{0,n}`` (seed 002
    algorithm 4.1.2, eq. 4.2). The velocity is forward-mode differentiation through each
    interpolation ``c = a exp(s W)``, ``W = log(a^{-1} b)``, ``E = a^{-1} b``:
    ``xi_E = -Ad_{E^{-1}} xi_a + xi_b``, ``W' = J_r(W)^{-1} xi_E``,
    ``xi_c = Ad_{exp(-s W)} xi_a + J_r(s W) (W + s W')``.
    """
    k = len(G.shape)
    b = np.asarray(P, dtype=np.float64)
    ax = b.ndim - k - 1  # the control-point axis
    s = np.asarray(s, dtype=np.float64)
    sv = s[..., None]  # broadcast over the control-point axis
    sw = sv[..., None]
    xi = np.zeros(b.shape[:ax + 1] + (G.dim,)) if velocity else None
    while b.shape[ax] > 1:
        m = b.shape[ax] - 1
        lo, hi = np.take(b, range(m), axis=ax), np.take(b, range(1, m + 1), axis=ax)
        if not velocity:
            b = G.interp(lo, hi, sv)
            continue
        xlo, xhi = xi[..., :m, :], xi[..., 1:, :]
        E = G.compose(G.inverse(lo), hi)
        W = G.log(E)
        dW = G.jac_right_inv(W, xhi - G.adjoint(G.inverse(E), xlo))
        sW = sw * W
        step = G.exp(sW)
        b = G.compose(lo, step)
        xi = G.adjoint(G.inverse(step), xlo) + G.jac_right(sW, W + sw * dW)
    g = np.take(b, 0, axis=ax)
    return (g, xi[..., 0, :]) if velocity else g


def bezier(G, P, s):
    """Bézier curve on a Lie group by the geodesic de Casteljau algorithm.

    Parameters
    ----------
    G : LieGroup or str
        The group (its metric decides the geodesics).
    P : (..., n + 1, *G.shape) array_like
        Control points; consecutive ones must be within the injectivity radius (angle < pi)
        for the curve to be defined (seed 002 algorithm 4.1.2, proposition 4.1.3).
    s : (T,) array_like or float
        Parameters in ``[0, 1]`` (``s = (t - r) / (s - r)`` for a curve on ``[r, s]``).

    Returns
    -------
    (..., T, *G.shape) ndarray (``T`` axis dropped for scalar ``s``)

    Notes
    -----
    See :func:`de_casteljau`. Equal to the Crouch–Kun–Leite product form :func:`bezier_ckl`
    (seed corollary 4.2.11).
    """
    G = group(G)
    s, scalar = _times(s)
    b, k = _expand(G, P, s)
    out = de_casteljau(G, b, s)
    return np.take(out, 0, axis=out.ndim - k - 1) if scalar else out


def bezier_velocity(G, P, s):
    """Points and exact body-frame velocities ``g^{-1} dg/ds`` of a de Casteljau Bézier curve.

    Parameters
    ----------
    G : LieGroup or str
    P : (..., n + 1, *G.shape) array_like
    s : (T,) array_like or float

    Returns
    -------
    g : (..., T, *G.shape) ndarray
    xi : (..., T, G.dim) ndarray
        Derivative with respect to ``s`` (divide by ``s - r`` for a curve on ``[r, s]``). At
        ``s = 0`` it is the seed's end velocity ``n V_0^1`` (proposition 4.2.8).

    Notes
    -----
    For accelerations (and space-frame vectors) use the curve as a one-segment
    :class:`~shellspline.curves.PiecewiseBezier`:
    ``PiecewiseBezier(G, [r, s], np.expand_dims(P, -len(G.shape) - 2)).acceleration(t)``.
    """
    G = group(G)
    s, scalar = _times(s)
    b, k = _expand(G, P, s)
    g, xi = de_casteljau(G, b, s, velocity=True)
    if scalar:
        return np.take(g, 0, axis=g.ndim - k - 1), xi[..., 0, :]
    return g, xi


def bezier_ckl(G, P, s):
    """Bézier curve in the Crouch–Kun–Leite product form (seed 002 section 4.2, eq. 4.5).

    ``p_n(s) = g_0 exp(s V_0^1) exp(s V_0^2(s)) ... exp(s V_0^n(s))`` with
    ``V_k^1 = log(g_k^{-1} g_{k+1})`` and
    ``exp(V_k^j(s)) = exp((1-s) V_k^{j-1}(s)) exp(s V_{k+1}^{j-1}(s))``.
    An independent construction used as the oracle of :func:`bezier` (corollary 4.2.11);
    same parameters and result shapes.
    """
    G = group(G)
    s, scalar = _times(s)
    b, k = _expand(G, P, s)
    ax = b.ndim - k - 1
    n = b.shape[ax] - 1
    V = G.between(np.take(b, range(n), axis=ax), np.take(b, range(1, n + 1), axis=ax))
    sw = s.reshape((-1, 1, 1))
    p = G.compose(np.take(b, 0, axis=ax), G.exp(sw[..., 0, :] * V[..., 0, :]))
    for _ in range(2, n + 1):
        V = G.log(G.compose(G.exp((1 - sw) * V[..., :-1, :]), G.exp(sw * V[..., 1:, :])))
        p = G.compose(p, G.exp(sw[..., 0, :] * V[..., 0, :]))
    return np.take(p, 0, axis=ax - 1) if scalar else p

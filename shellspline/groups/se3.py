"""The rigid motions SE(3): closed-form exp/log, adjoint and Jacobians.

Rigid motions are homogeneous ``(..., 4, 4)`` matrices ``[[R, p], [0, 1]]`` (a pose maps
body coordinates to world coordinates: ``x_world = R x_body + p``). Twists are ``(..., 6)``
vectors ``(w, v)``, rotation part first as in seed 002 section 5.2, with
``hat((w, v)) = [[hat(w), v], [0, 0]]``.

The exponential is the matrix exponential: its one-parameter subgroups are screw motions,
the geodesics of the Ad-invariant (pseudo-Riemannian) metric of seed 002 section 5.2.1.
"""
from __future__ import annotations

import numpy as np

from . import so3

__all__ = ["hat", "vee", "exp", "log", "inverse", "adjoint", "jac_right", "jac_right_inv",
           "from_rt", "to_rt"]

_SMALL = 1e-3


def from_rt(R, p):
    """Homogeneous ``(..., 4, 4)`` matrices from rotations ``(..., 3, 3)`` and translations
    ``(..., 3)`` (broadcast against each other)."""
    R = np.asarray(R, dtype=np.float64)
    p = np.asarray(p, dtype=np.float64)
    lead = np.broadcast_shapes(R.shape[:-2], p.shape[:-1])
    T = np.zeros(lead + (4, 4))
    T[..., :3, :3] = R
    T[..., :3, 3] = p
    T[..., 3, 3] = 1.0
    return T


def to_rt(T):
    """Rotations ``(..., 3, 3)`` and translations ``(..., 3)`` of ``(..., 4, 4)`` motions."""
    T = np.asarray(T, dtype=np.float64)
    return T[..., :3, :3], T[..., :3, 3]


def hat(xi):
    """``(..., 4, 4)`` Lie-algebra matrices of twists ``(..., 6)`` ``(w, v)``."""
    xi = np.asarray(xi, dtype=np.float64)
    X = np.zeros(xi.shape[:-1] + (4, 4))
    X[..., :3, :3] = so3.hat(xi[..., :3])
    X[..., :3, 3] = xi[..., 3:]
    return X


def vee(X):
    """Twists ``(..., 6)`` of ``(..., 4, 4)`` Lie-algebra matrices (inverse of :func:`hat`)."""
    X = np.asarray(X, dtype=np.float64)
    return np.concatenate([so3.vee(X[..., :3, :3]), X[..., :3, 3]], axis=-1)


def _lmat(w):
    """The seed's ``A(w) = J_l(w)`` as ``(..., 3, 3)`` matrices."""
    th = np.sqrt(np.einsum("...i,...i->...", w, w))
    _, b, c = so3.exp_coefficients(th)
    W = so3.hat(w)
    return np.eye(3) + b[..., None, None] * W + c[..., None, None] * (W @ W)


def exp(xi):
    """Rigid motions of twists: the matrix exponential in closed form.

    Parameters
    ----------
    xi : (..., 6) array_like
        Twists ``(w, v)``.

    Returns
    -------
    T : (..., 4, 4) ndarray
        ``[[exp(w), A(w) v], [0, 1]]`` with ``A(w) = I + (1-cos t)/t^2 W + (t-sin t)/t^3 W^2``
        (seed 002 section 5.2.3).
    """
    xi = np.asarray(xi, dtype=np.float64)
    w, v = xi[..., :3], xi[..., 3:]
    return from_rt(so3.exp(w), np.einsum("...ij,...j->...i", _lmat(w), v))


def log(T):
    """Twists of rigid motions: the principal matrix logarithm in closed form.

    Parameters
    ----------
    T : (..., 4, 4) array_like

    Returns
    -------
    xi : (..., 6) ndarray
        ``w = so3.log(R)`` (``|w| <= pi``; at exactly pi the representative documented in
        :func:`shellspline.groups.so3.log`) and ``v = A(w)^{-1} p`` with
        ``A^{-1} = I - W/2 + (1/t^2 - cot(t/2)/(2t)) W^2`` (finite through pi).
    """
    T = np.asarray(T, dtype=np.float64)
    w = so3.log(T[..., :3, :3])
    p = T[..., :3, 3]
    # A(w)^{-1} p = J_l^{-1}(w) p = J_r^{-1}(-w) p
    v = so3.jac_right_inv(-w, p)
    return np.concatenate([w, v], axis=-1)


def inverse(T):
    """Inverses ``[[R^T, -R^T p], [0, 1]]`` of ``(..., 4, 4)`` rigid motions."""
    T = np.asarray(T, dtype=np.float64)
    Rt = np.swapaxes(T[..., :3, :3], -1, -2)
    return from_rt(Rt, -np.einsum("...ij,...j->...i", Rt, T[..., :3, 3]))


def adjoint(T, xi):
    """``Ad_T xi`` for twists ``(w, v)``: ``(R w, R v + p x R w)`` (``hat(Ad_T xi) = T hat(xi)
    T^{-1}``)."""
    T = np.asarray(T, dtype=np.float64)
    xi = np.asarray(xi, dtype=np.float64)
    R, p = T[..., :3, :3], T[..., :3, 3]
    Rw = np.einsum("...ij,...j->...i", R, xi[..., :3])
    Rv = np.einsum("...ij,...j->...i", R, xi[..., 3:])
    return np.concatenate([Rw, Rv + np.cross(p, Rw)], axis=-1)


def _q_coeffs(th):
    small = th < _SMALL
    ts = np.where(small, 1.0, th)
    t2 = th * th
    sn, cs = np.sin(ts), np.cos(ts)
    c1 = np.where(small, 1 / 6 - t2 / 120, (ts - sn) / ts ** 3)
    c2 = np.where(small, 1 / 24 - t2 / 720, (ts * ts + 2 * cs - 2) / (2 * ts ** 4))
    c3 = np.where(small, 1 / 120 - t2 / 2520, (2 * ts - 3 * sn + ts * cs) / (2 * ts ** 5))
    return c1, c2, c3


def _qapply(w, v, a):
    """``Q(w, v) a`` with Barfoot's ``Q`` (the lower-left block of the left Jacobian of SE(3)),
    by cross products: ``W a = w x a``, ``P a = v x a``."""
    th = np.sqrt(np.einsum("...i,...i->...", w, w))
    c1, c2, c3 = (c[..., None] for c in _q_coeffs(th))
    cross = so3.cross
    Wa = cross(w, a)
    Pa = cross(v, a)
    WPa = cross(w, Pa)
    PWa = cross(v, Wa)
    WPWa = cross(w, PWa)
    WWPa = cross(w, WPa)
    PWWa = cross(v, cross(w, Wa))
    WPWWa = cross(w, PWWa)
    WWPWa = cross(w, WPWa)
    return (0.5 * Pa + c1 * (WPa + PWa + WPWa) + c2 * (WWPa + PWWa - 3 * WPWa)
            + c3 * (WPWWa + WWPWa))


def jac_right(xi, x):
    """Right Jacobian of the SE(3) exponential applied to twists: ``J_r(xi) x``.

    ``J_l((w, v)) = [[J_l(w), 0], [Q(w, v), J_l(w)]]`` (Barfoot's Q, rotation first) and
    ``J_r(xi) = J_l(-xi)``.
    """
    xi = np.asarray(xi, dtype=np.float64)
    x = np.asarray(x, dtype=np.float64)
    w, v = -xi[..., :3], -xi[..., 3:]
    xw, xv = x[..., :3], x[..., 3:]
    Jw = so3.jac_right(-w, xw)  # J_l(w) xw
    out_v = so3.jac_right(-w, xv) + _qapply(w, v, xw)
    return np.concatenate([Jw, out_v], axis=-1)


def jac_right_inv(xi, x):
    """``J_r(xi)^{-1} x`` for twists: ``J_l^{-1} = [[J^{-1}, 0], [-J^{-1} Q J^{-1}, J^{-1}]]``
    evaluated at ``-xi``."""
    xi = np.asarray(xi, dtype=np.float64)
    x = np.asarray(x, dtype=np.float64)
    w, v = -xi[..., :3], -xi[..., 3:]
    a = so3.jac_right_inv(-w, x[..., :3])  # J_l(w)^{-1} xw
    b = x[..., 3:] - _qapply(np.broadcast_to(w, a.shape), np.broadcast_to(v, a.shape), a)
    return np.concatenate([a, so3.jac_right_inv(-w, b)], axis=-1)

"""Component-first ("structure of arrays") kernels of the groups, for fast evaluation.

A kernel stores elements as ``(k, ...)`` arrays whose first axis holds the components (unit
quaternions for rotations: ``k = 4`` for SO(3), ``7`` for SE(3) and SO(3) x R^3, ``4 d + 3``
for SO(3)^d x R^3) and tangent vectors as ``(dim, ...)``. Every operation is a short sequence
of elementwise numpy operations on contiguous rows; batched 3x3 / 4x4 matrix products on many
small matrices are about ten times slower (measured: benchmarks/README.md, ``bench_curves.py``).
The curve evaluators use it when the group has one (``G.kernel() is not None``); results equal
the matrix formulas to rounding.

Quaternion logarithms take the representative with non-negative scalar part, so ``log`` of a
relative rotation returns the angle in ``[0, pi]`` (the geodesic), as :func:`so3.log` does.
"""
from __future__ import annotations

import numpy as np

from ..errors import tol
from . import so3

__all__ = ["SO3Kernel", "SE3Kernel", "SO3xR3Kernel", "SO3dR3Kernel"]

_SMALL = 1e-3


def _qmul(a, b):
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return np.stack([aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx,
                     aw * bz + ax * by - ay * bx + az * bw,
                     aw * bw - ax * bx - ay * by - az * bz])


def _qconj(a):
    return np.concatenate([-a[:3], a[3:4]])


def _cross(a, b):
    return np.stack([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2],
                     a[0] * b[1] - a[1] * b[0]])


def _qrot(q, p):
    """Rotate vectors ``p (3, ...)`` by quaternions ``q (4, ...)``."""
    v, w = q[:3], q[3]
    t = 2 * _cross(v, p)
    return p + w * t + _cross(v, t)


def _qexp(w):
    """Quaternions of rotation vectors ``(3, ...)``; also the angle ``t``, ``sin(t/2)`` and
    ``cos(t/2)``."""
    th = np.sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2])
    h = 0.5 * th
    s, c = np.sin(h), np.cos(h)
    small = th < _SMALL
    f = np.where(small, 0.5 - th * th / 48, s / np.where(small, 1.0, th))
    return np.concatenate([f * w, c[None]]), th, s, c


def _qlog(q):
    """Rotation vectors of quaternions (scalar part made non-negative); also the angle and
    ``cot(t/2)`` pieces ``(n, w)`` with ``n = |vector part|``."""
    v, w = q[:3], q[3]
    sg = np.where(w < 0, -1.0, 1.0)
    w = w * sg
    n = np.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
    small = n < _SMALL * w
    th = 2 * np.arctan2(n, w)
    f = np.where(small, 2 / w * (1 - n * n / (3 * w * w)), th / np.where(small, 1.0, n))
    return (f * sg) * v, th, n, w


class _Kernel:
    """Geodesic interpolation from the primitives; subclasses may override with closed forms.
    ``prepare(a, b)`` holds what does not depend on ``s`` (reused for many ``s``)."""

    def prepare(self, a, b):
        return a, self.log(self.compose(self.inverse(a), b))

    def interp_prepared(self, prep, s):
        a, V = prep
        return self.compose(a, self.exp(s * V))

    def interp(self, a, b, s):
        """``a exp(s log(a^{-1} b))`` for ``a, b (k, ...)`` and ``s`` broadcastable."""
        return self.interp_prepared(self.prepare(a, b), s)


def _slerp_prepare(qa, qb):
    d = qa[0] * qb[0] + qa[1] * qb[1] + qa[2] * qb[2] + qa[3] * qb[3]
    sg = np.where(d < 0, -1.0, 1.0)
    qb = qb * sg
    d = np.abs(d)
    # half the rotation angle, accurate for all d: atan2(|qb - d qa|, d); sin = |qb - d qa| / r
    dx = qb - d * qa
    n = np.sqrt(dx[0] ** 2 + dx[1] ** 2 + dx[2] ** 2 + dx[3] ** 2)
    th = np.arctan2(n, d)
    zero = n < 1e-150  # equal rotations: linear weights (the limit)
    inv = np.sqrt(n * n + d * d) / np.where(zero, 1.0, n)
    return qa, qb, th, inv, (zero if np.any(zero) else None)


def _slerp(prep, s, weights=False):
    """``sin((1-s) t)/sin t qa + sin(s t)/sin t qb`` (exact for small t > 0 too); with
    ``weights`` also the weight of ``qb``."""
    qa, qb, th, inv, zero = prep
    wa = np.sin((1 - s) * th)
    wa *= inv
    wb = np.sin(s * th)
    wb *= inv
    if zero is not None:
        wa = np.where(zero, 1 - s, wa)
        wb = np.where(zero, s, wb)
    out = qa * wa
    out += qb * wb
    return (out, wb) if weights else out


class SO3Kernel(_Kernel):
    """SO(3) as unit quaternions ``(4, ...)`` ``[x, y, z, w]``; geodesics by slerp."""

    k, dim = 4, 3

    def prepare(self, a, b):
        return _slerp_prepare(a, b)

    def interp_prepared(self, prep, s):
        return _slerp(prep, s)

    def pack(self, R):
        return np.moveaxis(so3.quat_from_matrix(R), -1, 0)

    def unpack(self, q):
        return so3.matrix_from_quat(np.moveaxis(q, 0, -1))

    def compose(self, a, b):
        return _qmul(a, b)

    def inverse(self, a):
        return _qconj(a)

    def exp(self, w):
        return _qexp(w)[0]

    def log(self, q):
        return _qlog(q)[0]


class SE3Kernel(_Kernel):
    """SE(3) (screw metric) as ``(7, ...)``: quaternion then translation."""

    k, dim = 7, 6

    def pack(self, T):
        T = np.asarray(T, dtype=np.float64)
        return np.concatenate([SO3Kernel.pack(self, T[..., :3, :3]),
                               np.moveaxis(T[..., :3, 3], -1, 0)])

    def unpack(self, x):
        from .se3 import from_rt

        return from_rt(so3.matrix_from_quat(np.moveaxis(x[:4], 0, -1)), np.moveaxis(x[4:], 0, -1))

    def compose(self, a, b):
        return np.concatenate([_qmul(a[:4], b[:4]), _qrot(a[:4], b[4:]) + a[4:]])

    def inverse(self, a):
        qi = _qconj(a[:4])
        return np.concatenate([qi, -_qrot(qi, a[4:])])

    def exp(self, xi):
        w, v = xi[:3], xi[3:]
        q, th, s, c = _qexp(w)
        small = th < _SMALL
        ts = np.where(small, 1.0, th)
        t2 = th * th
        sin_t, cos_t = 2 * s * c, 1 - 2 * s * s
        b = np.where(small, 0.5 - t2 / 24, (1 - cos_t) / ts ** 2)
        cc = np.where(small, 1 / 6 - t2 / 120, (ts - sin_t) / ts ** 3)
        wv = _cross(w, v)
        return np.concatenate([q, v + b * wv + cc * _cross(w, wv)])

    def prepare(self, a, b):
        """Screw interpolation (ScLERP): the rotation by slerp; the translation, in world
        coordinates, ``p_a + s d_par + sin(s t)/sin(t) Rot_n((s-1) t) d_perp`` with ``t`` half
        the relative angle, ``n`` the world axis of ``R_b R_a^T`` and ``d = p_b - p_a`` split
        along/across ``n`` (the closed form of ``a exp(s log(a^{-1} b))``)."""
        qa = a[:4]
        sp = _slerp_prepare(qa, b[:4])
        v = _qmul(sp[1], _qconj(qa))[:3]  # world-frame relative rotation, scalar part >= 0
        n = np.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
        ax = v / np.where(n > tol.zero, n, 1.0)
        d = b[4:] - a[4:]
        dpar = (ax[0] * d[0] + ax[1] * d[1] + ax[2] * d[2]) * ax
        return sp, a[4:], dpar, d - dpar, _cross(ax, d)

    def interp_prepared(self, prep, s):
        sp, pa, dpar, dperp, axd = prep
        q, wb = _slerp(sp, s, weights=True)
        beta = (s - 1) * sp[2]
        u = s * dpar + wb * (np.cos(beta) * dperp + np.sin(beta) * axd)
        return np.concatenate([q, pa + u])

    def log(self, x):
        w, th, n, cw = _qlog(x[:4])
        p = x[4:]
        small = th < _SMALL
        ts = np.where(small, 1.0, th)
        # 1/t^2 - cot(t/2) / (2 t), cot(t/2) = cw / n
        d = np.where(small, 1 / 12 + th * th / 720,
                     1 / ts ** 2 - cw / (2 * ts * np.where(small, 1.0, n)))
        wp = _cross(w, p)
        return np.concatenate([w, p - 0.5 * wp + d * _cross(w, wp)])


class SO3xR3Kernel(SE3Kernel):
    """SO(3) x R^3 (product metric, direct-product composition) as ``(7, ...)``."""

    def compose(self, a, b):
        return np.concatenate([_qmul(a[:4], b[:4]), a[4:] + b[4:]])

    def inverse(self, a):
        return np.concatenate([_qconj(a[:4]), -a[4:]])

    def prepare(self, a, b):
        return _slerp_prepare(a[:4], b[:4]), a[4:], b[4:] - a[4:]

    def interp_prepared(self, prep, s):
        q, p, dp = prep
        return np.concatenate([_slerp(q, s), p + s * dp])

    def exp(self, xi):
        return np.concatenate([_qexp(xi[:3])[0], xi[3:]])

    def log(self, x):
        return np.concatenate([_qlog(x[:4])[0], x[4:]])


class SO3dR3Kernel(_Kernel):
    """SO(3)^d x R^3 as ``(4 d + 3, ...)``: d quaternions then the position."""

    def __init__(self, G):
        self.G, self.d = G, G.d
        self.k, self.dim = 4 * G.d + 3, G.dim

    def pack(self, g):
        R, p = self.G.unpack(g)
        q = np.moveaxis(so3.quat_from_matrix(R), (-2, -1), (1, 0))  # (4, d, ...)
        return np.concatenate([q.reshape((4 * self.d,) + q.shape[2:]), np.moveaxis(p, -1, 0)])

    def unpack(self, x):
        q = x[:4 * self.d].reshape((4, self.d) + x.shape[1:])
        R = so3.matrix_from_quat(np.moveaxis(q, (0, 1), (-1, -2)))
        return self.G.pack(R, np.moveaxis(x[4 * self.d:], 0, -1))

    def _q(self, x):
        return x[:4 * self.d].reshape((4, self.d) + x.shape[1:])

    def _w(self, xi):
        return xi[:3 * self.d].reshape((self.d, 3) + xi.shape[1:]).swapaxes(0, 1)

    def _flatq(self, q):
        return q.reshape((4 * self.d,) + q.shape[2:])

    def _flatw(self, w):
        return w.swapaxes(0, 1).reshape((3 * self.d,) + w.shape[2:])

    def compose(self, a, b):
        return np.concatenate([self._flatq(_qmul(self._q(a), self._q(b))),
                               a[4 * self.d:] + b[4 * self.d:]])

    def inverse(self, a):
        return np.concatenate([self._flatq(_qconj(self._q(a))), -a[4 * self.d:]])

    def exp(self, xi):
        return np.concatenate([self._flatq(_qexp(self._w(xi))[0]), xi[3 * self.d:]])

    def prepare(self, a, b):
        p = a[4 * self.d:]
        return _slerp_prepare(self._q(a), self._q(b)), p, b[4 * self.d:] - p

    def interp_prepared(self, prep, s):
        q, p, dp = prep
        return np.concatenate([self._flatq(_slerp(q, s)), p + s * dp])

    def log(self, x):
        return np.concatenate([self._flatw(_qlog(self._q(x))[0]), x[4 * self.d:]])

"""The rotation group SO(3): closed-form exp/log, Jacobians and conversions.

Rotations are ``(..., 3, 3)`` matrices, rotation vectors ``(..., 3)`` (axis times angle in
radians), unit quaternions scalar-last ``(..., 4)`` ``[x, y, z, w]`` (files only). All
functions are vectorised over the leading axes and use only numpy.

The metric is the bi-invariant ``<X, Y> = -1/2 tr(X^T Y)`` of seed 002 eq. (3.7), under which
the geodesic distance of ``R1`` and ``R2`` is the angle of ``R1^T R2`` and the injectivity
radius is pi.
"""
from __future__ import annotations

import numpy as np

from ..errors import tol
from ..mesh.geometry import cross

__all__ = ["hat", "vee", "exp", "log", "angle", "jac_right", "jac_right_inv",
           "quat_from_matrix", "matrix_from_quat", "quat_continuous"]

# Below this angle (rad) the closed forms are replaced by 3-term Taylor series (truncation
# ~theta^6/5040 < 1e-21 at 1e-3, below the cancellation error of the closed forms).
_SMALL = 1e-3
# Above this angle (rad) the log takes its axis from the symmetric part of R, where the skew
# part 2 sin(theta) a has lost its relative accuracy.
_NEAR_PI = 2.5


def hat(w):
    """Skew-symmetric matrices of vectors.

    Parameters
    ----------
    w : (..., 3) array_like

    Returns
    -------
    W : (..., 3, 3) ndarray
        ``W @ x == cross(w, x)``.
    """
    w = np.asarray(w, dtype=np.float64)
    W = np.zeros(w.shape[:-1] + (3, 3))
    W[..., 0, 1], W[..., 0, 2] = -w[..., 2], w[..., 1]
    W[..., 1, 0], W[..., 1, 2] = w[..., 2], -w[..., 0]
    W[..., 2, 0], W[..., 2, 1] = -w[..., 1], w[..., 0]
    return W


def vee(W):
    """Vectors of (the skew part of) ``(..., 3, 3)`` matrices: the inverse of :func:`hat`."""
    W = np.asarray(W, dtype=np.float64)
    return 0.5 * np.stack([W[..., 2, 1] - W[..., 1, 2], W[..., 0, 2] - W[..., 2, 0],
                           W[..., 1, 0] - W[..., 0, 1]], axis=-1)


def _sq(w):
    return np.einsum("...i,...i->...", w, w)


def exp_coefficients(th):
    """``sin(t)/t``, ``(1-cos t)/t^2`` and ``(t - sin t)/t^3``, series near 0."""
    small = th < _SMALL
    ts = np.where(small, 1.0, th)
    t2 = th * th
    a = np.where(small, 1 - t2 / 6 + t2 * t2 / 120, np.sin(ts) / ts)
    b = np.where(small, 0.5 - t2 / 24 + t2 * t2 / 720, (1 - np.cos(ts)) / ts ** 2)
    c = np.where(small, 1 / 6 - t2 / 120 + t2 * t2 / 5040, (ts - np.sin(ts)) / ts ** 3)
    return a, b, c


def exp(w):
    """Rotation matrices of rotation vectors (Rodrigues' formula).

    Parameters
    ----------
    w : (..., 3) array_like
        Rotation vectors (axis times angle, radians); any length.

    Returns
    -------
    R : (..., 3, 3) ndarray
        ``R = I + sin(t)/t W + (1 - cos t)/t^2 W^2`` with ``W = hat(w)``, ``t = |w|``.

    Examples
    --------
    >>> import numpy as np
    >>> R = exp([0, 0, np.pi / 2])
    >>> np.round(R @ [1, 0, 0], 12) + 0.0
    array([0., 1., 0.])
    """
    w = np.asarray(w, dtype=np.float64)
    th = np.sqrt(_sq(w))
    a, b, _ = exp_coefficients(th)
    W = hat(w)
    return np.eye(3) + a[..., None, None] * W + b[..., None, None] * (W @ W)


def angle(R):
    """Rotation angles in ``[0, pi]`` of ``(..., 3, 3)`` rotations (atan2 form: accurate at
    every angle, unlike arccos of the trace near 0 and pi)."""
    R = np.asarray(R, dtype=np.float64)
    s = np.sqrt(_sq(vee(R)))
    c = 0.5 * (np.trace(R, axis1=-2, axis2=-1) - 1.0)
    return np.arctan2(s, c)


def log(R):
    """Rotation vectors of rotation matrices: the principal logarithm.

    Parameters
    ----------
    R : (..., 3, 3) array_like
        Rotation matrices (orthonormal, det +1; not checked here).

    Returns
    -------
    w : (..., 3) ndarray
        Rotation vectors with ``|w| <= pi`` and ``exp(w) == R``.

    Notes
    -----
    The angle is ``atan2(|vee(R - R^T)|/2, (tr R - 1)/2)`` (never arcsin, which is wrong beyond
    90 degrees, nor a bare arccos, which loses half the digits near 0 and pi). Below 2.5 rad the
    axis comes from the skew part ``(R - R^T)/2 = sin(t) hat(a)``; above, from the largest column
    of the symmetric part ``(R + R^T)/2 - cos(t) I = (1 - cos t) a a^T``, signed by the skew part.

    **At angle exactly pi** the logarithm is not unique (``w`` and ``-w`` both map to ``R``).
    We return the axis whose component of largest magnitude is positive; ties between equal
    magnitudes go to the first such component (x before y before z). Anywhere else the result
    is the unique vector of norm ``< pi``.

    Examples
    --------
    >>> import numpy as np
    >>> w = np.array([0.3, -2.0, 1.1])
    >>> bool(np.allclose(log(exp(w)), w))
    True
    >>> log(np.diag([-1.0, -1.0, 1.0]))  # angle pi about z: the +z representative
    array([0.        , 0.        , 3.14159265])
    """
    R = np.asarray(R, dtype=np.float64)
    v = vee(R)  # sin(t) a
    s = np.sqrt(_sq(v))
    c = 0.5 * (np.trace(R, axis1=-2, axis2=-1) - 1.0)
    th = np.arctan2(s, c)
    # generic and small angles: w = t / sin(t) * v
    small = th < _SMALL
    ts = np.where(small, 1.0, th)
    big = th > _NEAR_PI
    f = np.where(small, 1 + th * th / 6 + 7 * th ** 4 / 360,
                 ts / np.where(small | big, 1.0, np.sin(ts)))
    w = f[..., None] * v
    if np.any(big):
        Rb, cb, vb, tb = R[big], c[big], v[big], th[big]
        S = 0.5 * (Rb + np.swapaxes(Rb, -1, -2)) - cb[:, None, None] * np.eye(3)
        d = np.diagonal(S, axis1=-2, axis2=-1)
        k = np.argmax(d, axis=-1)
        col = np.take_along_axis(S, k[:, None, None], axis=-1)[..., 0]
        a = col / np.sqrt(_sq(col))[:, None]
        sgn = np.einsum("ni,ni->n", a, vb)
        # exactly pi (no skew part left): largest-magnitude component positive
        m = np.take_along_axis(a, np.argmax(np.abs(a), axis=-1)[:, None], axis=-1)[:, 0]
        sgn = np.where(np.abs(sgn) > tol.zero, sgn, m)
        a = np.where(sgn[:, None] < 0, -a, a)
        w[big] = tb[:, None] * a
    return w


def jac_right(w, x):
    """Right Jacobian of exp applied to vectors: ``J_r(w) x``.

    ``exp(w)^T d/dt exp(w(t)) = hat(J_r(w) w')`` and ``J_r(w) = J_l(-w)``, with
    ``J_l(w) = I + (1-cos t)/t^2 W + (t - sin t)/t^3 W^2`` (the seed's ``A(w)``).

    Parameters
    ----------
    w, x : (..., 3) array_like

    Returns
    -------
    (..., 3) ndarray
    """
    w = np.asarray(w, dtype=np.float64)
    x = np.asarray(x, dtype=np.float64)
    th = np.sqrt(_sq(w))
    _, b, c = exp_coefficients(th)
    wx = cross(w, x)
    return x - b[..., None] * wx + c[..., None] * cross(w, wx)


def jac_right_inv(w, x):
    """Inverse right Jacobian applied to vectors: ``J_r(w)^{-1} x`` (``|w| < 2 pi``).

    ``J_r^{-1}(w) = I + W/2 + (1/t^2 - cot(t/2)/(2t)) W^2``; the cotangent form stays finite
    through ``t = pi``.
    """
    w = np.asarray(w, dtype=np.float64)
    x = np.asarray(x, dtype=np.float64)
    th = np.sqrt(_sq(w))
    small = th < _SMALL
    ts = np.where(small, 1.0, th)
    d = np.where(small, 1 / 12 + th * th / 720 + th ** 4 / 30240,
                 1 / ts ** 2 - 1 / (2 * ts * np.tan(0.5 * ts)))
    wx = cross(w, x)
    return x + 0.5 * wx + d[..., None] * cross(w, wx)


def quat_from_matrix(R):
    """Unit quaternions, scalar-last ``[x, y, z, w]`` with ``w >= 0``, of rotation matrices.

    Parameters
    ----------
    R : (..., 3, 3) array_like

    Returns
    -------
    q : (..., 4) ndarray
        Shepperd's method: the largest of ``w, x, y, z`` is computed from the diagonal, the
        others from off-diagonal sums, so no branch loses accuracy.
    """
    R = np.asarray(R, dtype=np.float64)
    tr = np.trace(R, axis1=-2, axis2=-1)
    d = np.stack([R[..., 0, 0], R[..., 1, 1], R[..., 2, 2], tr], axis=-1)
    k = np.argmax(d, axis=-1)
    q = np.zeros(R.shape[:-2] + (4,))
    # case w largest
    s = k == 3
    if np.any(s):
        r = R[s]
        t = 1 + np.trace(r, axis1=-2, axis2=-1)
        q[s] = np.stack([r[:, 2, 1] - r[:, 1, 2], r[:, 0, 2] - r[:, 2, 0],
                         r[:, 1, 0] - r[:, 0, 1], t], axis=-1)
    for i in range(3):
        s = k == i
        if not np.any(s):
            continue
        j, l = (i + 1) % 3, (i + 2) % 3
        r = R[s]
        t = 1 + r[:, i, i] - r[:, j, j] - r[:, l, l]
        qq = np.zeros((r.shape[0], 4))
        qq[:, i] = t
        qq[:, j] = r[:, j, i] + r[:, i, j]
        qq[:, l] = r[:, l, i] + r[:, i, l]
        qq[:, 3] = r[:, l, j] - r[:, j, l]
        q[s] = qq
    q /= np.sqrt(_sq(q))[..., None]
    return np.where(q[..., 3:4] < 0, -q, q)


def matrix_from_quat(q):
    """Rotation matrices of quaternions ``[x, y, z, w]`` (normalised here; any sign)."""
    q = np.asarray(q, dtype=np.float64)
    q = q / np.sqrt(_sq(q))[..., None]
    x, y, z, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    R = np.empty(q.shape[:-1] + (3, 3))
    R[..., 0, 0] = 1 - 2 * (y * y + z * z)
    R[..., 0, 1] = 2 * (x * y - z * w)
    R[..., 0, 2] = 2 * (x * z + y * w)
    R[..., 1, 0] = 2 * (x * y + z * w)
    R[..., 1, 1] = 1 - 2 * (x * x + z * z)
    R[..., 1, 2] = 2 * (y * z - x * w)
    R[..., 2, 0] = 2 * (x * z - y * w)
    R[..., 2, 1] = 2 * (y * z + x * w)
    R[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return R


def quat_continuous(q, axis=-2):
    """Flip quaternion signs so that consecutive ones along ``axis`` have ``q_i . q_{i-1} >= 0``.

    Parameters
    ----------
    q : (..., n, 4) array_like
        A sequence of unit quaternions along ``axis`` (default: the axis before the last).

    Returns
    -------
    (..., n, 4) ndarray
        The same rotations; the first keeps its sign, each later one the sign that is closest
        to its predecessor (the file convention of TUM/EuRoC trajectories).
    """
    q = np.moveaxis(np.array(q, dtype=np.float64), axis, 0)
    if q.shape[0] > 1:
        d = np.einsum("n...i,n...i->n...", q[1:], q[:-1])
        flips = np.cumprod(np.where(d < 0, -1.0, 1.0), axis=0)
        q[1:] *= flips[..., None]
    return np.moveaxis(q, 0, axis)

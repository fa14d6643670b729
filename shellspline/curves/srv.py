"""Square-root-velocity transform (SRVT) of sampled curves in SO(3)^d x R^m (seed 000).

A :class:`ProductCurve` is ``N`` samples of a curve in the product group ``SO(3)^d x R^m``:
``d >= 0`` rotations (the joints of a skeleton) and ``m >= 0`` Euclidean components (a root
position, or the LTheta A descriptors of a mesh animation with ``d = 0``). Between samples the
curve is the right-trivialised geodesic ``c(t) = exp((t - t_i) eta_i) c_i`` (seed 000 eq. 19),
so its right logarithmic derivative ``c' c^{-1}`` is the piecewise constant

    ``eta_i = log(c_{i+1} c_i^{-1}) / (t_{i+1} - t_i)``   (per rotation; ``dX / dt`` for R^m),

and its SRVT (seed 000 eq. 3) is ``q_i = eta_i / sqrt(|eta_i|)``, one vector of ``R^(3d+m)`` per
interval, ``|.|`` the Euclidean norm of all ``3d + m`` components together (rotations in
radians, the bi-invariant metric ``-1/2 tr(X^T Y)`` of :mod:`shellspline.groups.so3`).

Everything here is exact for such piecewise-geodesic curves: :func:`srv_inverse` undoes
:func:`srv` to rounding, a piecewise-linear reparametrisation has exactly the SRV
``sqrt(phi') q(phi)`` (seed 000 Lemma 3.6), and :func:`srv_distance` integrates the piecewise
constant ``|q0 - q1|^2`` exactly.

Units: the Euclidean components enter the norm as they are; scale them (e.g. a root position
in metres rather than centimetres) so that they weigh what they should against radians.

Layer rule: imports only numpy, :mod:`shellspline.groups` and :mod:`shellspline.errors`.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import ShellsplineError
from ..groups import so3

__all__ = ["ProductCurve", "srv", "srv_inverse", "srv_distance", "reparametrize", "blend",
           "warp_grid", "normalized_times", "cumulative_product"]

# Consecutive samples must rotate every joint by less than this (rad): the principal log, and
# so the piecewise geodesic between them, is unique only below pi.
_MAX_STEP_ANGLE = np.pi - 1e-6


@dataclass(frozen=True, eq=False)
class ProductCurve:
    """``N`` samples of a curve in ``SO(3)^d x R^m``.

    Parameters
    ----------
    R : (N,d,3,3) array_like, optional
        Rotations (``d = 0`` when omitted).
    X : (N,m) array_like, optional
        Euclidean components (``m = 0`` when omitted).
    t : (N,) array_like, optional
        Strictly increasing sample times (default ``linspace(0, 1, N)``).

    Attributes
    ----------
    R : (N,d,3,3) float64 ndarray
    X : (N,m) float64 ndarray
    t : (N,) float64 ndarray

    Raises
    ------
    ShellsplineError
        On inconsistent shapes, non-finite values, times that do not increase, matrices that
        are not rotations, or consecutive rotations ``pi`` or more apart.

    Examples
    --------
    >>> import numpy as np
    >>> c = ProductCurve(X=np.c_[np.linspace(0, 1, 5), np.zeros(5)])
    >>> c.n_frames, c.d, c.m, c.dim
    (5, 0, 2, 2)
    """

    R: np.ndarray = None
    X: np.ndarray = None
    t: np.ndarray = None

    def __post_init__(self):
        R, X, t = self.R, self.X, self.t
        if R is None and X is None:
            raise ShellsplineError("ProductCurve: give rotations R (N,d,3,3) and/or a "
                                   "Euclidean part X (N,m)")
        if R is not None:
            R = np.asarray(R, dtype=np.float64)
            if R.ndim != 4 or R.shape[2:] != (3, 3):
                raise ShellsplineError(f"ProductCurve: R must have shape (N,d,3,3), got "
                                       f"{R.shape}")
        if X is not None:
            X = np.asarray(X, dtype=np.float64)
            if X.ndim == 1:
                X = X[:, None]
            if X.ndim != 2:
                raise ShellsplineError(f"ProductCurve: X must have shape (N,m), got {X.shape}")
        N = R.shape[0] if R is not None else X.shape[0]
        if R is None:
            R = np.zeros((N, 0, 3, 3))
        if X is None:
            X = np.zeros((N, 0))
        if X.shape[0] != N:
            raise ShellsplineError(f"ProductCurve: R has {N} samples but X has {X.shape[0]}")
        if N < 2:
            raise ShellsplineError(f"ProductCurve: need at least 2 samples, got {N}")
        t = np.linspace(0.0, 1.0, N) if t is None else np.asarray(t, dtype=np.float64)
        if t.shape != (N,):
            raise ShellsplineError(f"ProductCurve: t must have shape ({N},), got {t.shape}")
        if not (np.all(np.isfinite(R)) and np.all(np.isfinite(X)) and np.all(np.isfinite(t))):
            raise ShellsplineError("ProductCurve: R, X and t must be finite")
        if np.any(np.diff(t) <= 0):
            i = int(np.argmax(np.diff(t) <= 0))
            raise ShellsplineError(f"ProductCurve: t must be strictly increasing, got "
                                   f"t[{i}] = {t[i]!r}, t[{i + 1}] = {t[i + 1]!r}")
        if R.shape[1]:
            err = np.abs(R @ np.swapaxes(R, -1, -2) - np.eye(3)).max(axis=(-1, -2))
            bad = (err > 1e-6) | (np.linalg.det(R) < 0)
            if np.any(bad):
                n, j = map(int, np.argwhere(bad)[0])
                raise ShellsplineError(f"ProductCurve: R[{n}, {j}] is not a rotation "
                                       f"(|R R^T - I| = {err[n, j]:.2g})")
            ang = so3.angle(R[1:] @ np.swapaxes(R[:-1], -1, -2))
            if np.any(ang > _MAX_STEP_ANGLE):
                n, j = map(int, np.argwhere(ang > _MAX_STEP_ANGLE)[0])
                raise ShellsplineError(f"ProductCurve: rotation {j} turns by {ang[n, j]:.4f} rad "
                                       f"between samples {n} and {n + 1}; consecutive samples "
                                       "must be less than pi apart")
        object.__setattr__(self, "R", R)
        object.__setattr__(self, "X", X)
        object.__setattr__(self, "t", t)

    @property
    def n_frames(self) -> int:
        """Number of samples ``N``."""
        return self.t.shape[0]

    @property
    def d(self) -> int:
        """Number of rotations."""
        return self.R.shape[1]

    @property
    def m(self) -> int:
        """Number of Euclidean components."""
        return self.X.shape[1]

    @property
    def dim(self) -> int:
        """Dimension ``3 d + m`` of the Lie algebra (of one SRV vector)."""
        return 3 * self.d + self.m

    def with_times(self, t) -> "ProductCurve":
        """The same samples at other times ``t (N,)`` (only ``t`` is checked: the samples
        were, and checking N x d rotations again took 0.04 s per call on 4,801 frames)."""
        t = np.asarray(t, dtype=np.float64)
        N = self.n_frames
        if t.shape != (N,) or not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0):
            return ProductCurve(self.R, self.X, t)  # raises the full message
        out = object.__new__(ProductCurve)
        for name, value in (("R", self.R), ("X", self.X), ("t", t)):
            object.__setattr__(out, name, value)
        return out

    def right_translated(self, R=None, x=None) -> "ProductCurve":
        """``c(t) g`` for ``g = (R (d,3,3), x (m,))``: rotations multiplied on the right, ``x``
        added (the translation under which the SRVT is invariant, seed 000 Lemma 3.6)."""
        Rn = self.R if R is None else self.R @ np.asarray(R, dtype=np.float64)
        Xn = self.X if x is None else self.X + np.asarray(x, dtype=np.float64)
        return ProductCurve(Rn, Xn, self.t)


def normalized_times(t) -> np.ndarray:
    """Times mapped affinely onto ``[0, 1]``: ``(t - t[0]) / (t[-1] - t[0])``, ``(N,)``."""
    t = np.asarray(t, dtype=np.float64)
    return (t - t[0]) / (t[-1] - t[0])


def _increments(curve: ProductCurve) -> np.ndarray:
    """``log(c_{i+1} c_i^{-1})`` per interval: ``(N-1, 3d+m)`` (rotation vectors, then dX)."""
    R, X = curve.R, curve.X
    N, d = R.shape[0], R.shape[1]
    w = so3.log(R[1:] @ np.swapaxes(R[:-1], -1, -2)).reshape(N - 1, 3 * d)
    return np.concatenate([w, np.diff(X, axis=0)], axis=1)


def srv(curve: ProductCurve) -> np.ndarray:
    """Right-trivialised SRVT of a sampled curve (seed 000 eq. 3 and section 5.1).

    Parameters
    ----------
    curve : ProductCurve
        ``N`` samples, ``d`` rotations, ``m`` Euclidean components.

    Returns
    -------
    Q : (N-1, 3d+m) ndarray
        ``q_i = eta_i / sqrt(|eta_i|)`` with ``eta_i = log(c_{i+1} c_i^{-1}) / dt_i``
        (rotation vectors of joint 0, 1, ..., then ``dX / dt``); ``q_i = 0`` where the curve
        does not move.

    Notes
    -----
    Right translation invariant, ``srv(c g) == srv(c)``, and reparametrisation equivariant:
    a curve re-sampled at times ``u_i = phi(t_i)`` of its own samples has the SRV
    ``q_i sqrt(du_i / dt_i)`` (seed 000 Lemma 3.6, exact in the discrete setting).

    Examples
    --------
    >>> import numpy as np
    >>> c = ProductCurve(X=np.array([[0.0], [4.0]]))   # speed 4 on [0, 1]
    >>> srv(c)
    array([[2.]])
    """
    eta = _increments(curve) / np.diff(curve.t)[:, None]
    return _scale_sqrt(eta)


def _scale_sqrt(eta):
    n = np.sqrt(np.einsum("ij,ij->i", eta, eta))
    f = np.where(n > 0, 1.0 / np.sqrt(np.where(n > 0, n, 1.0)), 0.0)
    return eta * f[:, None]


def cumulative_product(E, R0) -> np.ndarray:
    """Rotations ``R_0, E_0 R_0, E_1 E_0 R_0, ...`` of a batch of increments.

    Parameters
    ----------
    E : (N-1, d, 3, 3) array_like
        Left factors ``R_{i+1} = E_i R_i``.
    R0 : (d, 3, 3) array_like

    Returns
    -------
    (N, d, 3, 3) ndarray

    Notes
    -----
    A parallel prefix (Hillis-Steele) scan: ``ceil(log2 N)`` batched matrix products over all
    frames and joints at once instead of a Python loop over frames.
    """
    S = np.array(E, dtype=np.float64)
    k = 1
    while k < S.shape[0]:
        S[k:] = S[k:] @ S[:-k]
        k *= 2
    R0 = np.asarray(R0, dtype=np.float64)
    return np.concatenate([R0[None], S @ R0[None]], axis=0)


def srv_inverse(Q, t, *, R0=None, X0=None, d=None) -> ProductCurve:
    """Inverse SRVT: the piecewise-geodesic curve with SRV ``Q`` starting at ``(R0, X0)``.

    Parameters
    ----------
    Q : (N-1, 3d+m) array_like
        SRV vectors per interval.
    t : (N,) array_like
        Strictly increasing sample times.
    R0 : (d,3,3) array_like, optional
        Start rotations (default identities; then ``d`` must be given).
    X0 : (m,) array_like, optional
        Start of the Euclidean part (default zeros).
    d : int, optional
        Number of rotations when ``R0`` is omitted (default 0).

    Returns
    -------
    ProductCurve
        ``c_{i+1} = exp(dt_i |q_i| q_i) c_i`` per rotation (the discrete inverse of seed 000
        section 5.1 *with* the time step ``dt_i``, which the printed formula drops), and
        ``X_{i+1} = X_i + dt_i |q_i| q_i`` for the Euclidean part.

    Raises
    ------
    ShellsplineError
        On bad shapes, or when a joint would turn by ``pi`` or more in one step
        (``dt_i |q_i|^2``, its rotation part): the samples ``exp(...)`` would still be right,
        but the piecewise geodesic between them (the principal logarithm) would turn the other
        way round, so the result would not have the SRV ``Q``. Sample ``t`` more finely.

    Examples
    --------
    >>> import numpy as np
    >>> c = ProductCurve(R=np.eye(3)[None, None].repeat(3, 0), X=[[0.0], [1.0], [3.0]])
    >>> c2 = srv_inverse(srv(c), c.t, R0=c.R[0], X0=c.X[0])
    >>> bool(np.allclose(c2.X, c.X) and np.allclose(c2.R, c.R))
    True
    """
    return _srv_inverse(Q, t, R0, X0, d, "srv_inverse", "sample t more finely")


def _srv_inverse(Q, t, R0, X0, d, where, hint) -> ProductCurve:
    """:func:`srv_inverse`, its step-angle error naming ``where`` and advising ``hint``."""
    Q = np.asarray(Q, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64)
    if Q.ndim != 2 or t.shape != (Q.shape[0] + 1,):
        raise ShellsplineError(f"srv_inverse: Q must be (N-1, dim) and t (N,), got {Q.shape} "
                               f"and {t.shape}")
    if R0 is not None:
        R0 = np.asarray(R0, dtype=np.float64)
        if R0.ndim != 3 or R0.shape[1:] != (3, 3):
            raise ShellsplineError(f"srv_inverse: R0 must be (d,3,3), got {R0.shape}")
        d = R0.shape[0]
    d = 0 if d is None else int(d)
    m = Q.shape[1] - 3 * d
    if m < 0:
        raise ShellsplineError(f"srv_inverse: Q has {Q.shape[1]} columns, fewer than 3 d = "
                               f"{3 * d}")
    R0 = np.broadcast_to(np.eye(3), (d, 3, 3)) if R0 is None else R0
    X0 = np.zeros(m) if X0 is None else np.asarray(X0, dtype=np.float64).reshape(-1)
    if X0.shape != (m,):
        raise ShellsplineError(f"srv_inverse: X0 must have {m} components, got {X0.shape}")
    N = t.shape[0]
    n = np.sqrt(np.einsum("ij,ij->i", Q, Q))
    inc = Q * (n * np.diff(t))[:, None]           # dt |q| q = log(c_{i+1} c_i^{-1})
    w = inc[:, :3 * d].reshape(N - 1, d, 3)
    ang = np.sqrt(np.einsum("ijk,ijk->ij", w, w))
    if np.any(ang > _MAX_STEP_ANGLE):  # exp would wrap: right samples, wrong way between them
        i, j = map(int, np.argwhere(ang > _MAX_STEP_ANGLE)[0])
        raise ShellsplineError(f"{where}: joint {j} would turn by {ang[i, j]:.4f} rad between "
                               f"samples {i} and {i + 1} (dt |q|^2); a piecewise geodesic turns "
                               f"less than pi per step: {hint}")
    E = so3.exp(w)
    R = cumulative_product(E, R0)
    X = X0 + np.concatenate([np.zeros((1, m)), np.cumsum(inc[:, 3 * d:], axis=0)], axis=0)
    return ProductCurve(R, X, t)


def srv_distance(curve0: ProductCurve, curve1: ProductCurve) -> float:
    """``||q0 - q1||_{L2[0,1]}``: the SRV distance of two curves on the same time grid (seed
    000 eq. 7, the geodesic distance of the elastic metric for ``3d + m > 2``).

    Parameters
    ----------
    curve0, curve1 : ProductCurve
        Same ``N``, ``d``, ``m`` and the same normalised times (reparametrise one of them
        with :func:`reparametrize` first otherwise).

    Returns
    -------
    float
        ``sqrt(sum_i dt_i |q0_i - q1_i|^2)`` with both SRVs taken over the normalised times
        ``[0, 1]`` (exact for the piecewise constant SRVs; independent of the time unit).
    """
    _check_same_grid(curve0, curve1, "srv_distance")
    t = normalized_times(curve0.t)
    c0, c1 = curve0.with_times(t), curve1.with_times(t)
    D = srv(c0) - srv(c1)
    return float(np.sqrt(np.sum(np.diff(t) * np.einsum("ij,ij->i", D, D))))


def _check_same_grid(c0, c1, where):
    if (c0.n_frames, c0.d, c0.m) != (c1.n_frames, c1.d, c1.m):
        raise ShellsplineError(f"{where}: curves must have the same samples and components, "
                               f"got (N, d, m) = {(c0.n_frames, c0.d, c0.m)} and "
                               f"{(c1.n_frames, c1.d, c1.m)}")
    if not np.allclose(normalized_times(c0.t), normalized_times(c1.t), rtol=0, atol=1e-9):
        raise ShellsplineError(f"{where}: curves must share their (normalised) time grid; "
                               "reparametrize one onto the other first")


def reparametrize(curve: ProductCurve, phi, t=None, *, periodic: bool = False) -> ProductCurve:
    """``c o phi``: the curve sampled at the times ``phi`` by geodesic interpolation.

    Parameters
    ----------
    curve : ProductCurve
    phi : (K,) array_like
        Non-decreasing times in ``curve.t``'s units, within ``[t[0], t[-1]]`` (any real
        time when ``periodic``).
    t : (K,) array_like, optional
        Times of the new samples (default ``curve.t``, which needs ``K == N``).
    periodic : bool
        The curve is closed (``c[-1] == c[0]``): ``phi`` is taken modulo the period
        ``t[-1] - t[0]``.

    Returns
    -------
    ProductCurve
        Samples ``c(phi_k)`` at times ``t``: between samples ``j`` and ``j+1``,
        ``exp(s log(c_{j+1} c_j^{-1})) c_j`` with ``s = (phi - t_j) / dt_j`` (the
        right-trivialised geodesic of the curve itself, so that the SRV of the result is
        exactly ``sqrt(phi') q(phi)`` for piecewise-linear ``phi``; seed 000 section 5.1 prints
        the product on the wrong side).
    """
    phi = np.asarray(phi, dtype=np.float64).reshape(-1)
    T = curve.t
    t = T if t is None else np.asarray(t, dtype=np.float64)
    if t.shape != phi.shape:
        raise ShellsplineError(f"reparametrize: phi has {phi.shape[0]} values but the new "
                               f"times t have shape {t.shape}")
    if not np.all(np.isfinite(phi)):
        raise ShellsplineError("reparametrize: phi must be finite")
    span = T[-1] - T[0]
    if periodic:
        phi = T[0] + np.mod(phi - T[0], span)
    elif phi.min() < T[0] - 1e-9 * span or phi.max() > T[-1] + 1e-9 * span:
        raise ShellsplineError(f"reparametrize: phi must lie in [{T[0]!r}, {T[-1]!r}], got "
                               f"[{phi.min()!r}, {phi.max()!r}]")
    j = np.clip(np.searchsorted(T, phi, side="right") - 1, 0, T.shape[0] - 2)
    s = np.clip((phi - T[j]) / (T[j + 1] - T[j]), 0.0, 1.0)
    inc = _increments(curve)                     # (N-1, 3d+m)
    d = curve.d
    w = inc[j, :3 * d].reshape(j.shape[0], d, 3) * s[:, None, None]
    R = so3.exp(w) @ curve.R[j]
    X = curve.X[j] + s[:, None] * inc[j, 3 * d:]
    return ProductCurve(R, X, t)


def blend(curve0: ProductCurve, curve1: ProductCurve, s, warp=None, *,
          periodic: bool = False) -> ProductCurve:
    """Geodesic of the SRV metric between two curves: ``R^{-1}((1-s) q0 + s q1)`` (seed 000
    eq. 20), started at the geodesic blend of the start points.

    Parameters
    ----------
    curve0, curve1 : ProductCurve
        Same ``d`` and ``m``; any numbers of samples.
    s : float
        Blend weight: ``0`` gives ``curve0``, ``1`` gives ``curve1`` (reparametrised by
        ``warp``); values outside ``[0, 1]`` extrapolate.
    warp : (N0,) array_like, optional
        ``phi`` on ``curve0``'s times with values in ``curve1``'s times (e.g.
        :attr:`AlignResult.phi`): ``curve1`` is blended as ``curve1 o phi``. Default: the
        affine map of ``curve0.t`` onto ``curve1.t``.
    periodic : bool
        ``curve1`` is closed and ``warp`` is taken modulo its period (the warp of
        ``align(..., closed=True)``, which runs from its ``shift`` over one period).

    Returns
    -------
    ProductCurve
        On ``curve0.t``: ``curve1 o warp`` is sampled there, so ``s = 1`` gives ``curve1``
        only where those samples keep ``curve1``'s own; sample ``curve0`` on
        :func:`warp_grid` for the exact blend of the two piecewise-geodesic curves. Start
        point ``c0(0) exp(s log(c0(0)^{-1} c1(0)))`` per rotation, ``(1-s) X0(0) + s X1(0)``; then ``c(t) = R^{-1}(q)(t) c(0)`` (right translation, under
        which the SRVT is invariant). ``q1`` is the SRV of ``curve1 o warp`` on ``curve0.t``
        with each joint's increment on the branch of the logarithm that ``curve1``'s path
        takes (a fast joint that turns ``pi`` or more between two samples of ``curve0`` keeps
        turning forwards, where the principal logarithm would turn it back).

    Raises
    ------
    ShellsplineError
        For different components or a bad ``warp``, or when a joint of the blend would turn
        by ``pi`` or more between two samples of ``curve0`` (no piecewise geodesic on that
        grid does; resample ``curve0`` more finely).
    """
    if (curve0.d, curve0.m) != (curve1.d, curve1.m):
        raise ShellsplineError(f"blend: curves must have the same components, got (d, m) = "
                               f"{(curve0.d, curve0.m)} and {(curve1.d, curve1.m)}")
    s = float(s)
    t0 = curve0.t
    if warp is None:
        warp = curve1.t[0] + normalized_times(t0) * (curve1.t[-1] - curve1.t[0])
    elif np.shape(warp) != t0.shape:
        raise ShellsplineError(f"blend: warp must have one value per sample of curve0 "
                               f"({t0.shape[0]}), got shape {np.shape(warp)}")
    c1 = reparametrize(curve1, warp, t0, periodic=periodic)
    # the increments of curve1 o warp between curve0's samples, on the branch of the logarithm
    # that curve1's own path takes: where warp skips several samples of a fast joint, the
    # step may exceed pi and the principal logarithm of c1's samples would turn it backwards
    d = curve1.d
    inc = _increments(c1)
    path = _path_increments(curve1, np.asarray(warp, dtype=np.float64), periodic)
    if d:
        inc[:, :3 * d] = _unwrapped(inc[:, :3 * d].reshape(-1, d, 3),
                                    path[:, :3 * d].reshape(-1, d, 3)).reshape(-1, 3 * d)
    Q = (1 - s) * srv(curve0) + s * _scale_sqrt(inc / np.diff(t0)[:, None])
    w = so3.log(np.swapaxes(curve0.R[0], -1, -2) @ c1.R[0])
    R0 = curve0.R[0] @ so3.exp(s * w)
    X0 = (1 - s) * curve0.X[0] + s * c1.X[0]
    return _srv_inverse(Q, t0, R0, X0, None, "blend", "resample curve0 on a finer grid "
                        "(reparametrize) so that curve1 o warp turns less than pi per step")


def warp_grid(t0, warp_t, warp, t1, *, tol: float = 1e-13) -> tuple[np.ndarray, np.ndarray]:
    """The grid on which :func:`blend` is the exact SRV geodesic of two piecewise-geodesic
    curves, and the warp on it.

    :func:`blend` works on ``curve0``'s samples: ``curve1 o warp`` is sampled there and
    joined by geodesics, so where a sample of ``curve1`` falls between two of them it is cut
    off (``s = 1`` is then not ``curve1``). On the union of ``t0`` (``curve0``'s samples),
    ``warp_t`` (the warp's breakpoints) and the times where the warp passes a sample of
    ``curve1`` (``warp^{-1}(t1)``), both curves are single geodesics between consecutive
    times, so their SRVs are constant there and the blend of the sampled curves is the blend
    of the curves themselves, for every ``s``: ``s = 0`` gives ``curve0`` at ``t0`` and
    ``s = 1`` gives ``curve1`` at the times where the warp meets ``t1``.

    Parameters
    ----------
    t0 : (N0,) array_like
        Strictly increasing times of ``curve0``.
    warp_t, warp : (K,) array_like
        The warp, piecewise linear: ``warp(warp_t[k]) = warp[k]`` (values in ``curve1``'s
        times), ``warp_t`` strictly increasing from ``t0[0]`` to ``t0[-1]``; any direction
        (a warp that turns back passes a sample of ``curve1`` more than once).
    t1 : (N1,) array_like
        Strictly increasing times of ``curve1``.
    tol : float
        Added times closer than ``tol`` times the span to a kept one are dropped (``t0`` is
        kept whole), so that no interval is shorter than rounding.

    Returns
    -------
    t : (N,) float64 numpy array
        Contains ``t0`` exactly.
    phi : (N,) float64 numpy array
        The warp at ``t`` (the ``warp=`` of :func:`blend` for ``curve0`` reparametrised onto
        ``t``).

    Examples
    --------
    >>> t, phi = warp_grid([0.0, 0.5, 1.0], [0.0, 1.0], [0.0, 1.0], [0.0, 0.25, 1.0])
    >>> t.tolist(), phi.tolist()
    ([0.0, 0.25, 0.5, 1.0], [0.0, 0.25, 0.5, 1.0])
    """
    t0, tw, p, t1 = (np.asarray(x, dtype=np.float64).reshape(-1) for x in (t0, warp_t, warp, t1))
    if tw.shape != p.shape or tw.size < 2 or np.any(np.diff(tw) <= 0):
        raise ShellsplineError(f"warp_grid: warp_t must be >= 2 strictly increasing times "
                               f"with one warp value each, got {tw.size} and {p.size}")
    if not (np.all(np.isfinite(p)) and np.all(np.isfinite(t0)) and np.all(np.isfinite(t1))):
        raise ShellsplineError("warp_grid: times and warp must be finite")
    lo, hi = np.minimum(p[:-1], p[1:]), np.maximum(p[:-1], p[1:])
    k0 = np.searchsorted(t1, lo, side="right")   # samples of curve1 strictly inside each
    cnt = np.maximum(np.searchsorted(t1, hi, side="left") - k0, 0)    # interval of the warp
    i = np.repeat(np.arange(lo.size), cnt)
    k = np.arange(int(cnt.sum())) - np.repeat(np.cumsum(cnt) - cnt, cnt) + np.repeat(k0, cnt)
    x = tw[i] + (t1[k] - p[i]) / (p[i + 1] - p[i]) * (tw[i + 1] - tw[i])
    x = np.clip(x, tw[i], tw[i + 1])
    span = max(t0[-1] - t0[0], 0.0)
    extra = np.unique(np.concatenate([tw, x]))
    extra = extra[(extra > t0[0]) & (extra < t0[-1])]
    if extra.size:  # drop the added times within tol of t0 or of the previous added one
        j = np.clip(np.searchsorted(t0, extra), 1, t0.size - 1)
        near = np.minimum(extra - t0[j - 1], t0[j] - extra) <= tol * span
        extra = extra[~near]
    if extra.size > 1:
        extra = extra[np.concatenate([[True], np.diff(extra) > tol * span])]
    t = np.union1d(t0, extra)
    return t, np.interp(t, tw, p)


def _path_increments(curve: ProductCurve, phi, periodic: bool) -> np.ndarray:
    """``(K-1, 3d+m)``: the integral of the curve's piecewise constant ``eta`` over
    ``[phi_k, phi_{k+1}]`` (rotation vectors summed along the path: exact for a joint turning
    about a fixed axis, and a guide to the branch of the logarithm otherwise). ``phi`` is taken
    unwrapped when ``periodic`` (one more period adds the whole curve's integral)."""
    T = curve.t
    inc = _increments(curve)
    A = np.concatenate([np.zeros((1, inc.shape[1])), np.cumsum(inc, axis=0)], axis=0)
    laps = np.zeros_like(phi)
    if periodic:
        span = T[-1] - T[0]
        laps = np.floor((phi - T[0]) / span)
        phi = phi - laps * span
    j = np.clip(np.searchsorted(T, phi, side="right") - 1, 0, T.shape[0] - 2)
    u = np.clip((phi - T[j]) / (T[j + 1] - T[j]), 0.0, 1.0)
    at = A[j] + u[:, None] * inc[j] + laps[:, None] * A[-1]
    return np.diff(at, axis=0)


def _unwrapped(w, ref) -> np.ndarray:
    """The logarithm of ``exp(w)`` (``w (..., 3)`` principal) nearest ``ref (..., 3)``: one of
    ``w + 2 pi n w / |w|``, ``n`` an integer (along ``ref`` where ``w`` is zero)."""
    th = np.sqrt(np.einsum("...k,...k->...", w, w))
    r = np.sqrt(np.einsum("...k,...k->...", ref, ref))
    axis = np.where((th > 1e-12)[..., None], w / np.maximum(th, 1e-300)[..., None],
                    ref / np.maximum(r, 1e-300)[..., None])
    n = np.rint((np.einsum("...k,...k->...", ref, axis) - th) / (2 * np.pi))
    return w + (2 * np.pi * n)[..., None] * axis

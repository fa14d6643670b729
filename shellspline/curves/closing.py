"""Make a sampled curve in ``SO(3)^d x R^m`` cyclic by changing its SRV (seed 000 section 4).

Seed 000 closes a curve ``c = R^{-1}(q) c(0)`` by a gradient flow on the seam gap

    ``Phi(q) = 1/2 |log(c(1) c(0)^{-1})|^2``    (eq. 11; the plain difference for ``R^m``),

whose L2 gradient is ``|q| alpha + <alpha, q/|q|> q`` with ``alpha(t) = Ad*_{c(t)^{-1}} log r``
(Corollary 4.8). Here the same derivative is taken of the *discrete* curve
``c_{i+1} = exp(dt_i |q_i| q_i) c_i``:

    ``d log(r) / d q_i = J_l(log r)^{-1} Ad_{c_end c_{i+1}^{-1}} dt_i J_l(dt_i eta_i) M_i``,
    ``M_i = |q_i| I + q_i q_i^T / |q_i|``

(per rotation; ``dt_i M_i`` for ``R^m``), and used two ways:

* ``method="gradient"``: the seed's steepest descent, with the Polyak step
  ``Phi / |grad Phi|^2`` and backtracking (linear convergence);
* ``method="gauss-newton"`` (default): the smallest change of ``q`` (in the L2 metric, or a
  smoother one) that closes the linearised gap, ``dq = W^{-1} J^T (J W^{-1} J^T)^{-1} (-gap)``
  with backtracking: the projection onto the closed curves, quadratically convergent.

Beyond the seed, ``c1=True`` also removes the velocity jump at the seam: once ``c(1) = c(0)``
the right-trivialised velocities ``c' c^{-1}`` at both ends are comparable, and the extra
constraint is that the SRV extrapolated to the seam from either side is the same,
``q_0 - r_0 (q_1 - q_0) = q_end + r_e (q_end - q_{end-1})`` (:func:`seam_weights`). The
samples ``q_i`` are the velocities of the intervals, half an interval away from the seam on
each side: the plain ``q_end = q_0`` is violated by ``h q'`` on a clip that already loops
smoothly, and closing such a 20 s walk at 120 Hz moved its joints by up to 41 degrees.
Its update would be a spike at both ends in the L2 metric, so the changes are measured in the periodic H1-type metric
``sum dt |dq|^2 + kappa sum |dq_{i+1} - dq_i|^2 / dt`` (wrapping round the seam), which spreads
them over a time of about ``sqrt(kappa)``.

The result has ``c[-1] == c[0]`` (to the tolerance): when looping, play samples ``0..N-2``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import ShellsplineError
from ..errors import tol as tolerances  # here `tol` names the solvers' stopping argument
from ..groups import so3
from ..numerics.result import SolverResult
from .srv import ProductCurve, normalized_times, srv, srv_inverse

__all__ = ["CloseResult", "close", "seam_gap", "seam_weights"]

# Default smoothing length^2 (normalised time) of the H1 metric used for c1 closure: the
# changes spread over ~sqrt(0.01) = 10 % of the clip on both sides of the seam.
_KAPPA_C1 = 0.01


@dataclass(kw_only=True)
class CloseResult(SolverResult):
    """Result of :func:`close` (a :class:`~shellspline.numerics.result.SolverResult`: its
    ``energies`` are the closing energy ½ seam_gap² before each iteration and after the last).

    Attributes
    ----------
    curve : ProductCurve
        The closed curve (same times and start point as the input; ``c[-1] ~ c[0]``).
    seam_gap : (k+1,) ndarray
        ``|log(c(1) c(0)^{-1})|`` (rotation vectors in radians and the ``R^m`` difference,
        in one Euclidean norm) before each iteration and after the last.
    velocity_jump : (k+1,) ndarray
        ``|eta_e - eta_s|``, the jump of the right-trivialised velocity across the seam (per
        unit of the curve's time), at the same moments: ``eta = q |q|`` of the SRV
        extrapolated to the seam from the two intervals on each side (:func:`seam_weights`).
    change : float
        SRV distance between the input and the closed curve (normalised time).
    iterations : int
    status : str
        ``"converged"`` (gap below ``tol``), ``"limit"`` (``iterations`` reached) or
        ``"stalled"`` (no step lowered the gap).
    message : str
    """

    curve: ProductCurve = None
    seam_gap: np.ndarray = None
    velocity_jump: np.ndarray = None
    change: float = float("nan")


def _jl_matrix(w):
    """``J_l(w)`` as ``(..., 3, 3)`` matrices (``J_l(w) = J_r(-w)``)."""
    w = np.asarray(w, dtype=np.float64)
    return np.swapaxes(so3.jac_right(-w[..., None, :], np.eye(3)), -1, -2)


def _jl_inv_matrix(w):
    w = np.asarray(w, dtype=np.float64)
    return np.swapaxes(so3.jac_right_inv(-w[..., None, :], np.eye(3)), -1, -2)


def _forward(q, h, R0, X0, d):
    """Curve samples and gap ``log(c_end c_0^{-1})`` of an SRV (normalised times ``h``)."""
    c = srv_inverse(q, np.concatenate([[0.0], np.cumsum(h)]), R0=R0, X0=X0, d=d)
    gR = so3.log(c.R[-1] @ np.swapaxes(c.R[0], -1, -2)).reshape(-1)
    return c, np.concatenate([gR, c.X[-1] - c.X[0]])


def seam_gap(curve: ProductCurve) -> float:
    """``|log(c(1) c(0)^{-1})|``: the jump when the curve is looped (rotation vectors and the
    ``R^m`` difference in one Euclidean norm)."""
    g = np.concatenate([so3.log(curve.R[-1] @ np.swapaxes(curve.R[0], -1, -2)).reshape(-1),
                        curve.X[-1] - curve.X[0]])
    return float(np.linalg.norm(g))


def seam_weights(h) -> np.ndarray:
    """Weights ``w (n,)`` of the C1 seam condition ``sum_i w_i q_i = 0`` on interval samples.

    Parameters
    ----------
    h : (n,) float64 numpy array
        Interval lengths (``n >= 2``).

    Returns
    -------
    (n,) float64 numpy array
        ``sum_i w_i q_i`` is the value at the end of the curve extrapolated linearly from the
        last two interval midpoints minus the value at the start extrapolated from the first
        two: zero when the samples come from a function that is smooth across the seam, to
        second order (the plain ``q_end - q_0`` is first order: ``h q'``).

    Examples
    --------
    >>> seam_weights(np.full(4, 0.25)).tolist()
    [-1.5, 0.5, -0.5, 1.5]
    >>> q = np.sin(2 * np.pi * (np.arange(100) + 0.5) / 100)   # periodic, at the midpoints
    >>> round(float(q[-1] - q[0]), 4), round(float(seam_weights(np.full(100, 0.01)) @ q), 6)
    (-0.0628, -0.000124)
    """
    h = np.asarray(h, dtype=np.float64)
    w = np.zeros(h.shape[0])
    r0 = h[0] / (h[0] + h[1])          # start: q_0 - r0 (q_1 - q_0)
    re = h[-1] / (h[-1] + h[-2])       # end:   q_end + re (q_end - q_end-1)
    w[-1] += 1.0 + re
    w[-2] -= re
    w[0] -= 1.0 + r0
    w[1] += r0
    return w


class _Constraints:
    """The linearised closure constraints at ``q`` as an operator, never as a dense matrix.

    Rows: the gap ``log(c_end c_0^{-1})`` (``D``), with ``c1`` also ``sum_i w_i q_i`` (``D``;
    ``w`` = :func:`seam_weights`).
    The gap's derivative w.r.t. ``q_i`` is ``|q_i| A_i + (A_i q_i) q_i^T / |q_i|`` with
    ``A_i`` block diagonal (``J_l(gap)^{-1} Ad dt J_l(dt eta)`` per rotation, ``dt`` for
    ``R^m``), so ``J^T y`` and ``J z`` cost ``O(n D)`` per column: memory and time stay
    linear in the number of frames (a dense ``(n, 2D, D)`` Jacobian took 1 GB and a minute for
    1,600 frames of 93 dimensions).
    """

    def __init__(self, q, h, c, gap, d, c1):
        n, D = q.shape
        self.n, self.D, self.d, self.c1 = n, D, d, c1
        self.K = 2 * D if c1 else D
        self.w = seam_weights(h) if c1 else None
        nq = np.sqrt(np.einsum("ij,ij->i", q, q))
        self.nq = nq
        self.v = q * np.where(nq > 0, 1.0 / np.where(nq > 0, nq, 1.0), 0.0)[:, None]
        self.h = h
        if d:
            eta = q[:, :3 * d] * nq[:, None]
            B = _jl_inv_matrix(gap[:3 * d].reshape(d, 3))                  # (d,3,3)
            P = c.R[-1][None] @ np.swapaxes(c.R[1:], -1, -2)                # (n,d,3,3)
            Jl = _jl_matrix(h[:, None, None] * eta.reshape(n, d, 3))
            self.blocks = B[None] @ P @ (h[:, None, None, None] * Jl)      # (n,d,3,3)
        else:
            self.blocks = np.zeros((n, 0, 3, 3))
        self.u = self._A(q[:, :, None])[:, :, 0]                            # A_i q_i

    def _A(self, Z):
        """``A_i Z_i`` for ``Z (n, D, k)``."""
        n, d, k = self.n, self.d, Z.shape[2]
        rot = self.blocks @ Z[:, :3 * d].reshape(n, d, 3, k)
        return np.concatenate([rot.reshape(n, 3 * d, k),
                               self.h[:, None, None] * Z[:, 3 * d:]], axis=1)

    def JT(self, Y):
        """``J^T Y``: ``Y (K, k)`` -> ``(n, D, k)``."""
        n, d, D = self.n, self.d, self.D
        y = Y[:D]
        k = Y.shape[1]
        ATy = np.concatenate([
            (np.swapaxes(self.blocks, -1, -2) @ y[:3 * d].reshape(d, 3, k)).reshape(n, 3 * d, k),
            self.h[:, None, None] * y[3 * d:][None]], axis=1)
        out = self.nq[:, None, None] * ATy + self.v[:, :, None] * \
            np.einsum("na,ak->nk", self.u, y)[:, None, :]
        if self.c1:
            out += self.w[:, None, None] * Y[D:][None]
        return out

    def weighted_sum(self, w):
        """``sum_i w_i d gap / d q_i``: ``(D, D)``."""
        d, D = self.d, self.D
        out = np.einsum("n,na,nb->ab", w, self.u, self.v)
        wq = w * self.nq
        rot = np.einsum("n,njab->jab", wq, self.blocks)                    # (d,3,3)
        jj = np.arange(d)
        blk = np.zeros((d, 3, d, 3))
        blk[jj, :, jj, :] = rot
        out[:3 * d, :3 * d] += blk.reshape(3 * d, 3 * d)
        idx = np.arange(3 * d, D)
        out[idx, idx] += np.sum(wq * self.h)
        return out

    def J(self, Z):
        """``J Z``: ``Z (n, D, k)`` -> ``(K, k)``."""
        AZ = self._A(Z)
        g = np.einsum("n,nak->ak", self.nq, AZ) + \
            np.einsum("na,nk->ak", self.u, np.einsum("na,nak->nk", self.v, Z))
        if self.c1:
            g = np.concatenate([g, np.einsum("n,nak->ak", self.w, Z)], axis=0)
        return g


# Constraint columns per block when the Schur complement J W^-1 J^T is assembled (bounds the
# temporary (n, D, block) arrays).
_COLUMN_BLOCK = 32


def _metric_solver(h, kappa):
    """``W^{-1}`` of the metric ``sum h |x|^2 + kappa sum |x_{i+1} - x_i|^2 / h_mid`` (periodic:
    the difference across the seam counts too), applied along axis 0 of ``(n, k)`` arrays.

    ``W`` is tridiagonal plus the two corner entries of the wrap: a banded Cholesky factor of
    the tridiagonal part and the Woodbury identity for the rank-2 corner correction.
    """
    if not kappa:
        return lambda F: F / h[:, None]
    from scipy.linalg import cho_solve_banded, cholesky_banded

    n = h.shape[0]
    hm = 0.5 * (h + np.roll(h, -1))                     # between interval i and i+1 (cyclic)
    k = kappa / hm
    main = h + k + np.roll(k, 1)
    ab = np.zeros((2, n))
    ab[0, 1:] = -k[:-1]
    ab[1] = main
    cb = cholesky_banded(ab)
    kw = k[-1]                                          # the wrap: W[0, n-1] = W[n-1, 0] = -kw
    U = np.zeros((n, 2))
    U[0, 0] = U[n - 1, 1] = 1.0
    TU = cho_solve_banded((cb, False), U)
    Cinv = np.array([[0.0, -1.0 / kw], [-1.0 / kw, 0.0]])
    small = np.linalg.inv(Cinv + U.T @ TU)              # 2 x 2

    def solve(F):
        TF = cho_solve_banded((cb, False), F)
        TF -= TU @ (small @ TF[[0, n - 1]])
        return TF
    return solve


def close(curve: ProductCurve, *, iterations: int = 10, c1: bool = False,
          method: str = "gauss-newton", kappa: float | None = None,
          tol: float = 1e-10) -> CloseResult:
    """Close a curve: change its SRV until ``c(1) = c(0)`` (and, with ``c1``, until the
    velocity has no jump at the seam).

    Parameters
    ----------
    curve : ProductCurve
        ``N >= 3`` samples in ``SO(3)^d x R^m``. Put in ``X`` only what should loop (e.g. a
        root height, not the forward travel of a walk).
    iterations : int
        Maximal number of iterations (each: one linearisation and a backtracking step).
    c1 : bool
        Also make the right-trivialised velocity continuous across the seam.
    method : {"gauss-newton", "gradient"}
        ``"gradient"``: seed 000's gradient flow on ``Phi`` (with ``c1``, on
        ``Phi + 1/2 |q_end - q_0|^2``), Polyak step and backtracking.
    kappa : float, optional
        Smoothing (normalised time squared) of the metric in which the change is smallest:
        ``0`` is the L2 metric of the SRVs (the seed's); default 0, or 0.01 with ``c1``.
    tol : float
        Stop when the seam gap (and, with ``c1``, the SRV jump) is below ``tol``.

    Returns
    -------
    CloseResult

    Raises
    ------
    ShellsplineError
        On bad options or a curve with fewer than 3 samples.

    Examples
    --------
    >>> import numpy as np
    >>> t = np.linspace(0, 1, 50)
    >>> c = ProductCurve(X=np.c_[np.cos(5 * t), np.sin(5 * t)])      # 5 of 2 pi radians
    >>> r = close(c)
    >>> r.status, bool(r.seam_gap[-1] < 1e-10)
    ('converged', True)
    """
    if not isinstance(curve, ProductCurve):
        raise ShellsplineError(f"close: curve must be a ProductCurve, got "
                               f"{type(curve).__name__}")
    if curve.n_frames < 3:
        raise ShellsplineError(f"close: need at least 3 samples, got {curve.n_frames}")
    if method not in ("gauss-newton", "gradient"):
        raise ShellsplineError(f"close: method must be 'gauss-newton' or 'gradient', got "
                               f"{method!r}")
    iterations = int(iterations)
    if iterations < 0:
        raise ShellsplineError(f"close: iterations must be >= 0, got {iterations}")
    kappa = (_KAPPA_C1 if c1 else 0.0) if kappa is None else float(kappa)
    if not kappa >= 0:
        raise ShellsplineError(f"close: kappa must be >= 0, got {kappa!r}")
    d, T = curve.d, curve.t[-1] - curve.t[0]
    tn = normalized_times(curve.t)
    h = np.diff(tn)
    q0 = srv(curve.with_times(tn))
    q = q0.copy()
    R0, X0 = curve.R[0], curve.X[0]
    solve = _metric_solver(h, kappa)

    ends = seam_weights(h)

    def residual(qq):
        c, gap = _forward(qq, h, R0, X0, d)
        res = np.concatenate([gap, ends @ qq]) if c1 else gap
        return c, gap, res

    r0, re = h[0] / (h[0] + h[1]), h[-1] / (h[-1] + h[-2])

    def jump(qq):  # the velocities of the SRVs extrapolated to the seam from both sides
        qs, qe = (1 + r0) * qq[0] - r0 * qq[1], (1 + re) * qq[-1] - re * qq[-2]
        return float(np.linalg.norm(qe * np.linalg.norm(qe) - qs * np.linalg.norm(qs))) / T

    w_c1 = solve(ends[:, None])[:, 0]                            # W^-1 J_c1^T (per dim)
    c, gap, res = residual(q)
    gaps, jumps = [np.linalg.norm(gap)], [jump(q)]
    status, msg, it = "limit", f"{iterations} iterations", 0
    for it in range(1, iterations + 1):
        if np.linalg.norm(res) <= tol:
            status, msg, it = "converged", "seam closed to the tolerance", it - 1
            break
        op = _Constraints(q, h, c, gap, d, c1)
        n, D, K = op.n, op.D, op.K

        def winv_jt(Y):                                          # W^-1 J^T Y: (n, D, k)
            k = Y.shape[1]
            return solve(op.JT(Y).reshape(n, D * k)).reshape(n, D, k)

        if method == "gauss-newton":
            S = np.zeros((K, K))                                 # J W^-1 J^T
            for k0 in range(0, D, _COLUMN_BLOCK):                # the gap columns
                E = np.eye(K)[:, k0:min(D, k0 + _COLUMN_BLOCK)]
                S[:D, k0:k0 + E.shape[1]] = op.J(winv_jt(E))[:D]
            if c1:
                # the C1 rows sum_i w_i q_i have J^T = w x I, so W^-1 J^T is (W^-1 w) x I:
                # their blocks of S in closed form
                S[:D, D:] = op.weighted_sum(w_c1)
                S[D:, :D] = S[:D, D:].T
                S[D:, D:] = float(ends @ w_c1) * np.eye(D)
            S[:D, :D] = 0.5 * (S[:D, :D] + S[:D, :D].T)
            try:
                y = np.linalg.solve(S, -res)
            except np.linalg.LinAlgError:                        # dependent constraints
                y = np.linalg.lstsq(S, -res, rcond=None)[0]
            yg = np.concatenate([y[:D], np.zeros(K - D)])
            dq = winv_jt(yg[:, None])[:, :, 0]
            if c1:
                dq += w_c1[:, None] * y[D:][None, :]
        else:
            grad = -winv_jt(res[:, None])[:, :, 0]               # -W^{-1} J^T res
            g2 = -float(res @ op.J(grad[:, :, None])[:, 0])      # |grad|_W^2
            dq = grad * (0.5 * float(res @ res) / max(g2, tolerances.zero))
        merit = float(res @ res)
        step, accepted = 1.0, False
        for _ in range(30):
            qn = q + step * dq
            try:
                cn, gapn, resn = residual(qn)
            except ShellsplineError:  # a joint would turn by pi or more in one step: the
                step *= 0.5           # trial left the piecewise geodesics, so it is shorter
                continue
            if float(resn @ resn) < merit:
                accepted = True
                break
            step *= 0.5
        if not accepted:
            status, msg, it = "stalled", "no step lowered the seam gap", it - 1
            break
        q, c, gap, res = qn, cn, gapn, resn
        gaps.append(np.linalg.norm(gap))
        jumps.append(jump(q))
    else:
        if np.linalg.norm(res) <= tol:
            status, msg = "converged", "seam closed to the tolerance"
    D = q - q0
    change = float(np.sqrt(np.sum(h * np.einsum("ij,ij->i", D, D))))
    out = ProductCurve(c.R, c.X, curve.t)
    gaps = np.array(gaps)
    return CloseResult(curve=out, seam_gap=gaps, velocity_jump=np.array(jumps), change=change,
                       iterations=it, status=status, message=msg, energies=0.5 * gaps ** 2)

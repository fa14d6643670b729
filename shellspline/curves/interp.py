"""Piecewise Bézier curves on a Lie group and splines through given poses at given times.

* :class:`PiecewiseBezier` — evaluation (points, body/space velocities and accelerations) of
  curves made of Bézier segments on consecutive time intervals, vectorised over many curves
  and many times.
* :func:`cubic_spline` — the C² interpolating cubic (seed 002 section 7.4.2) with natural,
  clamped or periodic ends, by a global Newton solve (default) or by the seed's marching
  construction with blow-up detection.
* :func:`quadratic_spline` — the C¹ interpolating quadratic by the seed's marching (7.4.1).
* :func:`hermite_spline` — C¹ cubic segments with Catmull–Rom (finite-difference) velocities:
  local, no solve.
* :func:`geodesic_interpolant` — piecewise geodesic (degree 1; scipy's ``Slerp`` on SO(3)).

Velocities are left-trivialised (body frame) ``g^{-1} dg/dt`` in ``R^G.dim``; the space-frame
vector is ``Ad_g`` of it.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import ShellsplineError
from ..groups.lie import group
from ..numerics.result import SolverResult
from .bezier import de_casteljau

__all__ = ["PiecewiseBezier", "SplineSolve", "cubic_spline", "quadratic_spline",
           "hermite_spline", "geodesic_interpolant"]

# Relative step of the acceleration's central difference of the exact velocity: truncation
# ~h^2 |xi'''| / 6 ~ 1e-9, round-off ~eps / h ~ 1e-12 (tests/curves/test_curves.py checks 1e-7).
_ACC_STEP = 3e-5
# Times evaluated per block by the kernel path: 4096 measured ~1.9x faster than one block of
# 100,000 (fresh large temporaries) and ~1.1x faster than 1024 (call overhead); see
# benchmarks/README.md (bench_curves.py).
_CHUNK = 4096


@dataclass(kw_only=True)
class SplineSolve(SolverResult):
    """Record of an interpolating-spline construction (a
    :class:`~shellspline.numerics.result.SolverResult`).

    Attributes
    ----------
    status : str
        ``"converged"`` (the C² conditions hold to the tolerance, or a direct construction:
        marching, Hermite, geodesic — ``iterations == 0`` and the message says which) or
        ``"limit"`` (Newton iteration limit: the curve is C¹ but not C²).
    iterations : int
    grad_norms : (it+1,) float64 array
        Max-norm of the C² residual (angular/linear acceleration jumps) per iteration (empty
        for a direct construction); also readable as :attr:`residuals`.
    message : str
    """

    status: str = "converged"
    message: str = "direct construction (no iteration)"

    @property
    def residuals(self) -> list:
        """The C² residual history (:attr:`grad_norms`) as a list."""
        return self.grad_norms.tolist()


class PiecewiseBezier:
    """A curve on a Lie group made of Bézier segments on consecutive time intervals.

    Parameters
    ----------
    G : LieGroup or str
    t : (N + 1,) array_like
        Strictly increasing breakpoints.
    control : (..., N, n + 1, *G.shape) array_like
        Control points of each segment (segment ``i`` lives on ``[t_i, t_{i+1}]``); leading axes
        are independent curves.
    solve : SplineSolve, optional
        How the control points were found.

    Notes
    -----
    Times outside ``[t_0, t_N]`` extrapolate the first/last segment.
    """

    def __init__(self, G, t, control, solve=None):
        self.G = G = group(G)
        self.t = _check_times(t, "t")
        self.control = np.asarray(control, dtype=np.float64)
        k = len(G.shape)
        nseg = self.control.shape[self.control.ndim - k - 2] if self.control.ndim >= k + 2 else -1
        if nseg != self.t.size - 1:
            raise ShellsplineError(f"control must have shape (..., {self.t.size - 1}, n+1, "
                                   f"*{G.shape}), got {self.control.shape}")
        self.solve = solve or SplineSolve()
        self._ax = self.control.ndim - k - 2  # segment axis

    @property
    def degree(self) -> int:
        return self.control.shape[self._ax + 1] - 1

    @property
    def knots(self):
        """The breakpoints ``t``."""
        return self.t

    def _locate(self, t):
        t = np.asarray(t, dtype=np.float64)
        scalar = t.ndim == 0
        t = np.atleast_1d(t)
        if t.ndim != 1 or not np.all(np.isfinite(t)):
            raise ShellsplineError(f"evaluation times must be finite and 1-D, got shape {t.shape}")
        i = np.clip(np.searchsorted(self.t, t, side="right") - 1, 0, self.t.size - 2)
        h = self.t[i + 1] - self.t[i]
        return (t - self.t[i]) / h, i, h, scalar

    def _segments(self, i):
        # (..., T, n+1, *shape) control points of the segment of each time
        return np.take(self.control, i, axis=self._ax)

    def _eval_segments(self, P, s):
        return de_casteljau(self.G, P, s)

    def __call__(self, t):
        """Points at times ``t (T,)`` (or a float): ``(..., T, *G.shape)``."""
        s, i, _, scalar = self._locate(t)
        K = self.G.kernel()
        if K is None:
            out = self._eval_segments(self._segments(i), s)
        else:
            out = self._eval_kernel(K, i, s)
        return np.take(out, 0, axis=self._ax) if scalar else out

    def _eval_kernel(self, K, i, s):
        """de Casteljau on the group's component-first kernel (contiguous rows: control index
        before time); the first level's ``s``-independent parts are computed once per curve."""
        if getattr(self, "_kcache", None) is None:
            Pk = np.moveaxis(K.pack(self.control), -2, -1)  # (k, ..., n+1, N)
            self._kcache = _Rows(K.prepare(Pk[..., :-1, :], Pk[..., 1:, :]))
        # chunks of times: temporaries stay small and in cache (fresh large arrays cost page
        # faults that dominate elementwise numpy work); measured in benchmarks/bench_curves.py
        lead = self.control.shape[:self._ax]
        out = np.zeros(lead + s.shape + tuple(self.G.shape))
        for c in range(0, s.size, _CHUNK):
            sl = slice(c, c + _CHUNK)
            ss = s[sl]
            b = K.interp_prepared(self._kcache.take(i[sl]), ss)  # (k, ..., n, T)
            while b.shape[-2] > 1:
                b = K.interp(b[..., :-1, :], b[..., 1:, :], ss)
            out[(Ellipsis, sl) + (slice(None),) * len(self.G.shape)] = K.unpack(b[..., 0, :])
        return out

    def _velocity_s(self, P, s):
        # exact body velocity d/ds, each time on its own segment (extended past its ends)
        return de_casteljau(self.G, P, s, velocity=True)

    def velocity(self, t, frame="body"):
        """Velocities at times ``t``: ``(..., T, G.dim)``.

        Parameters
        ----------
        t : (T,) array_like or float
        frame : {"body", "space"}
            ``g^{-1} dg/dt`` (body) or ``Ad_g`` of it (space: for SO(3) the angular velocity in
            world coordinates; for SE(3) the spatial twist; for the product groups the world
            angular velocity and ``dp/dt``).

        Notes
        -----
        Exact (forward-mode through de Casteljau, see :func:`bezier_velocity`). At a knot the
        right segment is used.
        """
        s, i, h, scalar = self._locate(t)
        g, xi = self._velocity_s(self._segments(i), s)
        xi = xi / h[:, None]
        if _frame(frame) == "space":
            xi = self.G.adjoint(g, xi)
        return xi[..., 0, :] if scalar else xi

    def acceleration(self, t, frame="body"):
        """Accelerations ``d/dt`` of the body velocity (``frame="body"``) or of the space
        velocity (``"space"``, equal to ``Ad_g`` of the body one): ``(..., T, G.dim)``.

        Notes
        -----
        A central difference of the exact velocity within each time's own segment (extended
        smoothly past its ends), step ``3e-5`` of the segment: relative accuracy ~1e-9. At a
        knot the right segment is used.
        """
        s, i, h, scalar = self._locate(t)
        P = self._segments(i)
        d = _ACC_STEP
        _, xp = self._velocity_s(P, s + d)
        _, xm = self._velocity_s(P, s - d)
        acc = (xp - xm) / (2 * d * h[:, None] ** 2)
        if _frame(frame) == "space":
            acc = self.G.adjoint(self._eval_segments(P, s), acc)
        return acc[..., 0, :] if scalar else acc


class _Rows:
    """A tuple of per-segment arrays ``(..., N)`` (or None) stored as one ``(F, N)`` table, so
    that gathering the segments of many times is one ``np.take`` into contiguous rows."""

    def __init__(self, tree):
        self.leaves, self.spec = [], []
        self._flatten(tree)
        N = self.leaves[0].shape[-1]
        self.table = np.ascontiguousarray(np.concatenate([x.reshape(-1, N) for x in self.leaves]))

    def _flatten(self, x):
        if isinstance(x, tuple):
            self.spec.append(("(", len(x)))
            for y in x:
                self._flatten(y)
        elif x is None:
            self.spec.append(("none", None))
        else:
            self.spec.append(("leaf", x.shape[:-1]))
            self.leaves.append(x)

    def take(self, i):
        g = np.take(self.table, i, axis=1)  # (F, T): np.take is ~5x faster than [:, i] here
        it = iter(self.spec)
        pos = [0]

        def build():
            kind, info = next(it)
            if kind == "(":
                return tuple(build() for _ in range(info))
            if kind == "none":
                return None
            size = int(np.prod(info))
            out = g[pos[0]:pos[0] + size].reshape(info + (g.shape[1],))
            pos[0] += size
            return out

        return build()


def _frame(frame):
    if frame not in ("body", "space"):
        raise ShellsplineError(f"frame must be 'body' or 'space', got {frame!r}")
    return frame


def _check_times(t, name):
    t = np.asarray(t, dtype=np.float64)
    if t.ndim != 1 or t.size < 2:
        raise ShellsplineError(f"{name} must be a 1-D array of at least 2 times, got shape "
                               f"{t.shape}")
    if not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0):
        raise ShellsplineError(f"{name} must be finite and strictly increasing")
    return t


def _check_poses(G, t, X, name="X"):
    t = _check_times(t, "t")
    X = G.check(X, name)
    k = len(G.shape)
    if X.ndim < k + 1 or X.shape[X.ndim - k - 1] != t.size:
        raise ShellsplineError(f"{name} must have shape (..., {t.size}, "
                               f"{', '.join(map(str, G.shape))}) to match t, got {X.shape}")
    return t, X, X.ndim - k - 1


def _too_far(G, D, name):
    """Raise when consecutive poses are pi or more apart in rotation (no unique geodesic)."""
    w = G.log(D)
    ang = G.rotation_angle(w)
    bad = ang > np.pi - 1e-6
    if np.any(bad):
        i = int(np.argwhere(bad)[0][-1])
        raise ShellsplineError(f"{name}: poses {i} and {i + 1} differ by a rotation of "
                               f"{np.degrees(ang[bad].max()):.1f} degrees; consecutive poses "
                               "must be less than 180 degrees apart (insert intermediate poses)")
    return w


def geodesic_interpolant(G, t, X):
    """Piecewise-geodesic curve through ``X (..., N+1, *G.shape)`` at times ``t (N+1,)``
    (on SO(3) this is scipy's ``Slerp``). Returns a degree-1 :class:`PiecewiseBezier`."""
    G = group(G)
    t, X, ax = _check_poses(G, t, X)
    n = t.size - 1
    lo, hi = np.take(X, range(n), axis=ax), np.take(X, range(1, n + 1), axis=ax)
    _too_far(G, G.compose(G.inverse(lo), hi), "X")
    return PiecewiseBezier(G, t, np.stack([lo, hi], axis=ax + 1))


def _hermite_control(G, X, ax, h, Om):
    """Cubic Bézier control points from knot poses and body velocities ``Om (..., N+1, dim)``:
    ``a_i = x_i exp(h_i w_i / 3)``, ``b_i = x_{i+1} exp(-h_i w_{i+1} / 3)`` (C¹ by
    construction)."""
    n = h.size
    lo, hi = np.take(X, range(n), axis=ax), np.take(X, range(1, n + 1), axis=ax)
    hh = h[:, None]
    a = G.compose(lo, G.exp(hh * Om[..., :-1, :] / 3))
    b = G.compose(hi, G.exp(-hh * Om[..., 1:, :] / 3))
    return np.stack([lo, a, b, hi], axis=ax + 1)


def hermite_spline(G, t, X, velocities=None):
    """C¹ piecewise-cubic Bézier curve through poses with given (or Catmull–Rom) velocities.

    Parameters
    ----------
    G : LieGroup or str
    t : (N + 1,) array_like
    X : (..., N + 1, *G.shape) array_like
    velocities : (..., N + 1, G.dim) array_like, optional
        Body velocities at the poses. Default: the average of the two neighbouring chord
        velocities ``log(x_i^{-1} x_{i+1}) / h_i`` weighted like a non-uniform finite difference
        (one-sided at the ends): the Catmull–Rom choice. Local: moving a pose changes the curve
        only on the (at most four) intervals within two poses of it.

    Returns
    -------
    PiecewiseBezier
    """
    G = group(G)
    t, X, ax = _check_poses(G, t, X)
    h = np.diff(t)
    n = h.size
    lo, hi = np.take(X, range(n), axis=ax), np.take(X, range(1, n + 1), axis=ax)
    delta = _too_far(G, G.compose(G.inverse(lo), hi), "X") / h[:, None]
    if velocities is None:
        Om = np.concatenate([delta[..., :1, :], delta[..., -1:, :]], axis=-2)
        if n > 1:
            w0, w1 = h[1:, None], h[:-1, None]
            mid = (w0 * delta[..., :-1, :] + w1 * delta[..., 1:, :]) / (w0 + w1)
            Om = np.concatenate([delta[..., :1, :], mid, delta[..., -1:, :]], axis=-2)
    else:
        Om = np.asarray(velocities, dtype=np.float64)
        if Om.shape != delta.shape[:-2] + (n + 1, G.dim):
            raise ShellsplineError(f"velocities must have shape {delta.shape[:-2] + (n + 1, G.dim)}"
                                   f", got {Om.shape}")
    return PiecewiseBezier(G, t, _hermite_control(G, X, ax, h, Om))


# --- the C² cubic ------------------------------------------------------------------------

def _canonical_bc(bc, G, lead):
    """``"periodic"`` or a pair of ends, each ``("natural", None)`` or ``("velocity", v)``."""
    if isinstance(bc, str):
        if bc == "periodic":
            return "periodic"
        bc = (bc, bc)
    if not isinstance(bc, (tuple, list)) or len(bc) != 2:
        raise ShellsplineError(f"bc must be 'natural', 'clamped', 'periodic' or a pair (start, "
                               f"end), got {bc!r}")
    ends = []
    for e in bc:
        if isinstance(e, str):
            if e == "natural":
                ends.append(("natural", None))
            elif e == "clamped":
                ends.append(("velocity", np.zeros(lead + (G.dim,))))
            else:
                raise ShellsplineError(f"bc ends must be 'natural', 'clamped' or a velocity, got "
                                       f"{e!r}")
        else:
            v = np.asarray(e, dtype=np.float64)
            try:
                v = np.broadcast_to(v, lead + (G.dim,))
            except ValueError:
                raise ShellsplineError(f"an end velocity must have shape (..., {G.dim}) "
                                       f"(body frame), got {v.shape}") from None
            ends.append(("velocity", v))
    return tuple(ends)


class _C2System:
    """Residual of the C² conditions in the unknown knot velocities ``Om (..., N+1, dim)``.

    For segment ``i`` with ``V0 = h w_i / 3``, ``V2 = h w_{i+1} / 3`` and
    ``V1 = log(exp(-V0) x_i^{-1} x_{i+1} exp(-V2))``, the body accelerations at its ends are

        alpha_start = 6 / h^2 J_r(V0)^{-1} (V1 - V0)
        alpha_end   = 6 / h^2 J_r(-V2)^{-1} (V2 - V1)

    (forward-mode through de Casteljau; the seed's proposition 4.2.9). C²: ``alpha_end_{i-1}
    = alpha_start_i`` at interior knots.
    """

    def __init__(self, G, D, h, ends):
        self.G, self.D, self.h, self.ends = G, D, h, ends

    def accelerations(self, Om):
        G, h = self.G, self.h[:, None]
        V0 = h * Om[..., :-1, :] / 3
        V2 = h * Om[..., 1:, :] / 3
        V1 = G.log(G.compose(G.compose(G.exp(-V0), self.D), G.exp(-V2)))
        a0 = 6 / h ** 2 * G.jac_right_inv(V0, V1 - V0)
        a1 = 6 / h ** 2 * G.jac_right_inv(-V2, V2 - V1)
        return a0, a1

    def residual(self, Om):
        a0, a1 = self.accelerations(Om)
        mid = a1[..., :-1, :] - a0[..., 1:, :]
        if self.ends == "periodic":
            return np.concatenate([(a1[..., -1, :] - a0[..., 0, :])[..., None, :], mid], axis=-2)
        (k0, v0), (k1, v1) = self.ends
        first = a0[..., 0, :] if k0 == "natural" else (Om[..., 0, :] - v0) * self._scale
        last = a1[..., -1, :] if k1 == "natural" else (Om[..., -1, :] - v1) * self._scale
        return np.concatenate([first[..., None, :], mid, last[..., None, :]], axis=-2)

    @property
    def _scale(self):
        return 1.0 / np.mean(self.h)


def _flat_jacobian(h, ends, n_unknown, periodic):
    """The C² residual's Jacobian in a flat (commutative) group, per component: a scalar
    tridiagonal (cyclic when periodic) matrix, factorised once."""
    import scipy.sparse as sp
    from scipy.sparse.linalg import splu

    n = n_unknown
    N = h.size
    i = np.arange(1, N)  # interior knots: alpha_end_{i-1} - alpha_start_i
    rows = [i % n, i % n, i % n]
    cols = [(i - 1) % n, i % n, (i + 1) % n]
    vals = [2 / h[:-1], 4 / h[:-1] + 4 / h[1:], 2 / h[1:]]
    if periodic:  # row 0: alpha_end_{N-1} - alpha_start_0 (unknown N is unknown 0)
        rows += [[0], [0], [0]]
        cols += [[N - 1], [0], [1 % n]]
        vals += [[2 / h[N - 1]], [4 / h[N - 1] + 4 / h[0]], [2 / h[0]]]
    else:
        (k0, _), (k1, _) = ends
        sc = 1.0 / np.mean(h)
        if k0 == "natural":
            rows, cols, vals = rows + [[0, 0]], cols + [[0, 1]], vals + [[-4 / h[0], -2 / h[0]]]
        else:
            rows, cols, vals = rows + [[0]], cols + [[0]], vals + [[sc]]
        if k1 == "natural":
            rows += [[N, N]]
            cols += [[N - 1, N]]
            vals += [[2 / h[N - 1], 4 / h[N - 1]]]
        else:
            rows, cols, vals = rows + [[N]], cols + [[N]], vals + [[sc]]
    A = sp.coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                      shape=(n, n))
    return splu(A.tocsc())


def _newton(system, Om, tol, max_iter, periodic):
    """Solve the C² conditions: a chord iteration with the flat-space Jacobian (exact when
    the rotations commute; it contracts the faster, the smaller the rotation per interval),
    then full Newton with a coloured finite-difference banded Jacobian if the chord iteration
    contracts by less than 1/2 per step. (Anderson acceleration of the chord iteration was
    measured and dropped: 10 -> 8-9 steps on the benchmark, slower on large rotations.)"""
    def F(Om_):
        if periodic:
            return system.residual(np.concatenate([Om_, Om_[..., :1, :]], axis=-2))
        return system.residual(Om_)

    lead, n, dim = Om.shape[:-2], Om.shape[-2], Om.shape[-1]
    lu = _flat_jacobian(system.h, system.ends, n, periodic)
    r = F(Om)
    res = [float(np.abs(r).max())]
    # the residuals are accelerations (1/time^2): the floor of the tolerance is one in units
    # of the mean interval, so the result does not depend on the time unit (nanosecond
    # timestamps once stopped at 0 steps, the curve C1 only: 24 % farther from the truth)
    scale = max(1.0 / float(np.mean(system.h)) ** 2, res[0])
    it = 0
    while it < max_iter and res[-1] > tol * scale:
        rr = np.moveaxis(r, -2, 0).reshape(n, -1)
        step = np.moveaxis(lu.solve(rr).reshape((n,) + lead + (dim,)), 0, -2)
        cand = Om - step
        rc = F(cand)
        it += 1
        if not np.abs(rc).max() < 0.5 * res[-1]:
            break  # too slow (or diverging): Newton from the better of the two
        Om, r = cand, rc
        res.append(float(np.abs(r).max()))
    if res[-1] <= tol * scale:
        return Om, SplineSolve(status="converged", iterations=it, grad_norms=res,
                                 message=f"C² residual {res[-1]:.2e} (chord iteration, "
                                         f"{it} steps)")
    Om, rec = _newton_fd(F, Om, r, res, scale, tol, max_iter - it, periodic)
    rec.message += f" (chord iteration, {it} steps, then Newton, {rec.iterations} steps)"
    rec.iterations += it
    return Om, rec


def _newton_fd(F, Om, r, res, scale, tol, max_iter, periodic):
    """Newton with a banded (cyclic: sparse) Jacobian by coloured central differences and
    backtracking on the residual's max-norm."""
    from scipy.linalg import solve_banded

    lead, n, dim = Om.shape[:-2], Om.shape[-2], Om.shape[-1]
    B = int(np.prod(lead))
    idx = np.arange(n)
    # colours: row i depends on unknowns i-1, i, i+1 (cyclically when periodic), which must
    # get different colours; the last n % 3 unknowns of a cycle get colours of their own
    colour = idx % 3
    if periodic and n % 3:
        colour[n - n % 3:] = 3 + np.arange(n % 3)
    offsets = (0, 1) if periodic and n == 2 else (0, 1, 2)
    done = 0
    for done in range(max_iter):
        if res[-1] <= tol * scale:
            break
        eps = 1e-6 * (1.0 + np.abs(Om).max())
        # blocks[b, i, d, a, k] = dF_i[a] / dOm_{i+d-1}[k] for d = 0,1,2 (cyclic when periodic)
        blocks = np.zeros((B, n, 3, dim, dim))
        for c in np.unique(colour):
            sel = colour == c
            for kk in range(dim):
                P = Om.copy()
                P[..., sel, kk] += eps
                M = Om.copy()
                M[..., sel, kk] -= eps
                dF = ((F(P) - F(M)) / (2 * eps)).reshape(B, n, dim)
                for d in offsets:
                    j = idx + d - 1
                    inside = (j >= 0) & (j < n)
                    ok = (colour[j % n] == c) & (True if periodic else inside)
                    view = blocks[:, :, d, :, kk]
                    view[:, ok, :] = dF[:, ok, :]
        step = _solve_blocks(blocks, -r.reshape(B, n * dim), periodic, solve_banded)
        step = step.reshape(Om.shape)
        lam = 1.0
        while True:
            cand = Om + lam * step
            rc = F(cand)
            if np.abs(rc).max() < res[-1] or lam < 1e-3:
                break
            lam *= 0.5
        Om, r = cand, rc
        res.append(float(np.abs(r).max()))
    else:
        done = max_iter
    if res[-1] <= tol * scale:
        return Om, SplineSolve(status="converged", iterations=done, grad_norms=res,
                                 message=f"C² residual {res[-1]:.2e}")
    return Om, SplineSolve(status="limit", iterations=done, grad_norms=res,
                             message=f"C² residual {res[-1]:.2e} at the iteration limit: "
                                     "the curve is C¹ but not C²")


def _solve_blocks(blocks, rhs, periodic, solve_banded):
    B, n, _, dim, _ = blocks.shape
    N = n * dim
    if periodic and n > 2:
        import scipy.sparse as sp
        from scipy.sparse.linalg import spsolve

        out = np.zeros_like(rhs)
        i = np.arange(n)
        rows, cols = [], []
        for d in range(3):
            j = (i + d - 1) % n
            a, k = np.meshgrid(np.arange(dim), np.arange(dim), indexing="ij")
            rows.append((i[:, None, None] * dim + a).ravel())
            cols.append((j[:, None, None] * dim + k).ravel())
        rows, cols = np.concatenate(rows), np.concatenate(cols)
        for b in range(B):
            vals = np.concatenate([blocks[b, :, d].ravel() for d in range(3)])
            A = sp.csc_matrix((vals, (rows, cols)), shape=(N, N))
            out[b] = spsolve(A, rhs[b])
        return out
    if periodic:  # n <= 2: dense
        A = np.zeros((B, N, N))
        for ii in range(n):
            for d in range(3):
                j = (ii + d - 1) % n
                A[:, ii * dim:(ii + 1) * dim, j * dim:(j + 1) * dim] += blocks[:, ii, d]
        return np.linalg.solve(A, rhs[..., None])[..., 0]
    # banded: curves stacked one after the other (no coupling between them)
    w = 2 * dim - 1
    ab = np.zeros((2 * w + 1, B * N))
    ii, d, a, k = np.meshgrid(np.arange(n), np.arange(3), np.arange(dim), np.arange(dim),
                              indexing="ij")
    j = ii + d - 1
    ok = (j >= 0) & (j < n)
    row, col = (ii * dim + a)[ok], (j * dim + k)[ok]
    vals = blocks.transpose(0, 1, 2, 3, 4)[:, ii[ok], d[ok], a[ok], k[ok]]  # (B, nnz)
    cols = (np.arange(B)[:, None] * N + col[None, :])
    ab[np.broadcast_to(w + row - col, cols.shape), cols] = vals
    return solve_banded((w, w), ab, rhs.reshape(-1)).reshape(B, N)


def cubic_spline(G, t, X, bc="natural", *, method="newton", tol=1e-10, max_iter=50,
                 start_acceleration=None):
    """C² cubic spline on a Lie group through poses at given times.

    Parameters
    ----------
    G : LieGroup or str
        ``"so3"``, ``"se3"`` (screw metric), ``"so3xr3"`` (product metric) or a group object.
    t : (N + 1,) array_like
        Strictly increasing times (non-uniform allowed).
    X : (..., N + 1, *G.shape) array_like
        Poses; leading axes are independent curves solved together. Consecutive poses must
        differ by less than 180 degrees of rotation.
    bc : str or (start, end)
        ``"natural"`` (zero body acceleration at both ends), ``"clamped"`` (zero velocity at
        both ends, as scipy's ``CubicSpline``), ``"periodic"`` (requires ``X[..., 0] ==
        X[..., N]``; velocity and acceleration match across the seam), or a pair whose items are
        ``"natural"``, ``"clamped"`` or a body-frame velocity ``(..., G.dim)``.
    method : {"newton", "march"}
        ``"newton"``: solve all C² conditions at once (Newton, banded Jacobian by coloured
        central differences, started from the chord-velocity average). ``"march"``: the seed's
        algorithm 7.4.1 — start velocity from ``bc[0]`` (a velocity is required) and
        ``start_acceleration`` (default zero), then each segment follows from the previous one;
        the end condition is not met and errors grow like ``(2 + sqrt 3)^i``: a
        :class:`ShellsplineError` is raised when consecutive control points drift beyond
        half a turn (the blow-up the seed warns about).
    tol : float
        Newton stops when the max C² residual is below ``tol`` times the initial one (or 1).
    max_iter : int
    start_acceleration : (..., G.dim) array_like, optional
        Only for ``method="march"``.

    Returns
    -------
    PiecewiseBezier
        Cubic segments; ``.solve`` records status, iterations and residuals. A Newton run that
        stops at ``max_iter`` has ``solve.status == "limit"`` (never reported as converged).

    Notes
    -----
    Each segment is a de Casteljau cubic with control points ``x_i, x_i exp(h_i w_i / 3),
    x_{i+1} exp(-h_i w_{i+1} / 3), x_{i+1}`` (C¹ by construction, seed proposition 4.2.8); the
    unknowns are the knot velocities ``w_i``; the C² conditions are in :class:`_C2System`. In
    a flat group this is the classical cubic spline (tested against
    ``scipy.interpolate.CubicSpline``).

    Examples
    --------
    >>> import numpy as np
    >>> from shellspline.groups import so3
    >>> X = so3.exp([[0, 0, 0], [0.3, 0, 0], [0.3, 0.4, 0], [0, 0.4, 0.2]])
    >>> S = cubic_spline("so3", [0, 1, 2.5, 3], X)
    >>> S.solve.status, bool(np.allclose(S([0, 1, 2.5, 3]), X))
    ('converged', True)
    """
    G = group(G)
    t, X, ax = _check_poses(G, t, X)
    h = np.diff(t)
    n = h.size
    lead = X.shape[:ax]
    lo, hi = np.take(X, range(n), axis=ax), np.take(X, range(1, n + 1), axis=ax)
    D = G.compose(G.inverse(lo), hi)
    delta = _too_far(G, D, "X") / h[:, None]
    ends = _canonical_bc(bc, G, lead)
    if method == "march":
        return _march_cubic(G, t, X, ax, h, ends, start_acceleration)
    if method != "newton":
        raise ShellsplineError(f"method must be 'newton' or 'march', got {method!r}")
    periodic = ends == "periodic"
    if periodic:
        gap = G.distance(np.take(X, 0, axis=ax), np.take(X, n, axis=ax))
        if np.max(gap) > 1e-8:
            raise ShellsplineError(f"bc='periodic' needs the last pose equal to the first, they "
                                   f"differ by {np.max(gap):.3g}")
        if n < 2:
            raise ShellsplineError("bc='periodic' needs at least 3 poses (2 intervals)")
    # start: chord-velocity averages (the geodesic's body velocity is constant along it)
    Om = np.zeros(lead + (n + 1, G.dim))
    Om[..., 0, :], Om[..., n, :] = delta[..., 0, :], delta[..., n - 1, :]
    if n > 1:
        w0, w1 = h[1:, None], h[:-1, None]
        Om[..., 1:n, :] = (w0 * delta[..., :-1, :] + w1 * delta[..., 1:, :]) / (w0 + w1)
    if periodic:
        Om[..., 0, :] = Om[..., n, :] = (delta[..., 0, :] * h[-1] + delta[..., -1, :] * h[0]) / (
            h[0] + h[-1])
    else:
        for e, (kind, v) in enumerate(ends):
            if kind == "velocity":
                Om[..., 0 if e == 0 else n, :] = v
    system = _C2System(G, D, h, ends)
    if periodic:
        Om_, rec = _newton(system, Om[..., :n, :], tol, max_iter, True)
        Om = np.concatenate([Om_, Om_[..., :1, :]], axis=-2)
    else:
        Om, rec = _newton(system, Om, tol, max_iter, False)
    return PiecewiseBezier(G, t, _hermite_control(G, X, ax, h, Om), rec)


def _march_cubic(G, t, X, ax, h, ends, start_acc):
    if ends == "periodic" or ends[0][0] != "velocity":
        raise ShellsplineError("method='march' needs a start velocity: bc=('clamped', ...) or "
                               "(velocity, ...)")
    w = np.array(ends[0][1], dtype=np.float64)
    lead = w.shape[:-1]
    alpha = np.zeros(lead + (G.dim,)) if start_acc is None else np.broadcast_to(
        np.asarray(start_acc, dtype=np.float64), lead + (G.dim,))
    n = h.size
    ctrl = []
    for i in range(n):
        xi, x1 = np.take(X, i, axis=ax), np.take(X, i + 1, axis=ax)
        V0 = h[i] * w / 3
        # alpha_start = 6/h^2 J_r(V0)^{-1} (V1 - V0)  =>  V1 = V0 + h^2/6 J_r(V0) alpha
        V1 = V0 + h[i] ** 2 / 6 * G.jac_right(V0, alpha)
        a = G.compose(xi, G.exp(V0))
        b = G.compose(a, G.exp(V1))
        V2 = G.between(b, x1)
        for V in (V1, V2):
            ang = G.rotation_angle(V)
            if np.any(ang > np.pi / 2) or not np.all(np.isfinite(V)):
                raise ShellsplineError(f"marching cubic spline blew up on interval {i} "
                                       f"(t = {t[i]:g}..{t[i + 1]:g}): a control-polygon step "
                                       f"of {np.degrees(np.max(ang)):.0f} degrees (limit 90); "
                                       "use method='newton'")
        ctrl.append(np.stack([xi, a, b, x1], axis=ax))
        w = 3 * V2 / h[i]
        alpha = 6 / h[i] ** 2 * G.jac_right_inv(-V2, V2 - V1)
    return PiecewiseBezier(G, t, np.stack(ctrl, axis=ax), SplineSolve(
        message="marching construction (seed algorithm 7.4.1): direct, no iteration"))


def quadratic_spline(G, t, X, start_velocity=None):
    """C¹ quadratic spline through poses by the seed's marching construction (7.4.1).

    Parameters
    ----------
    G : LieGroup or str
    t : (N + 1,) array_like
    X : (..., N + 1, *G.shape) array_like
    start_velocity : (..., G.dim) array_like, optional
        Body velocity at ``X[0]``; default the first chord velocity (first segment a geodesic).

    Returns
    -------
    PiecewiseBezier
        Quadratic segments ``(x_i, x_i exp(h_i w_i / 2), x_{i+1})``; the next velocity is
        ``w_{i+1} = 2 log(c_i^{-1} x_{i+1}) / h_i`` (the extrapolation ``b_{2i+3} =
        interp_L(b_{2i+1}, b_{2i+2})``, ``L = 1 + h_{i+1}/h_i``). Raises
        :class:`ShellsplineError` when a middle control point ends up more than 90 degrees
        from its pose (the construction oscillates with growing amplitude on uneven data).
    """
    G = group(G)
    t, X, ax = _check_poses(G, t, X)
    h = np.diff(t)
    n = h.size
    D = G.compose(G.inverse(np.take(X, range(n), axis=ax)), np.take(X, range(1, n + 1), axis=ax))
    delta = _too_far(G, D, "X") / h[:, None]
    w = delta[..., 0, :] if start_velocity is None else np.broadcast_to(
        np.asarray(start_velocity, dtype=np.float64), delta[..., 0, :].shape)
    ctrl = []
    for i in range(n):
        xi, x1 = np.take(X, i, axis=ax), np.take(X, i + 1, axis=ax)
        V0 = h[i] * w / 2
        c = G.compose(xi, G.exp(V0))
        V1 = G.between(c, x1)
        ang = np.maximum(G.rotation_angle(V0), G.rotation_angle(V1))
        if np.any(ang > np.pi / 2):
            raise ShellsplineError(f"marching quadratic spline blew up on interval {i} "
                                   f"(t = {t[i]:g}..{t[i + 1]:g}): a control point "
                                   f"{np.degrees(np.max(ang)):.0f} degrees from its pose")
        ctrl.append(np.stack([xi, c, x1], axis=ax))
        w = 2 * V1 / h[i]
    return PiecewiseBezier(G, t, np.stack(ctrl, axis=ax), SplineSolve(
        message="marching construction (seed section 7.4.1): direct, no iteration"))

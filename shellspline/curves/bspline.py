"""B-splines of degree m on a Lie group by geodesic de Boor, and knot insertion.

A spline has control points ``d (..., n, *G.shape)`` and a non-decreasing knot vector
``u (n + m + 1,)``; it is defined on ``[u[m], u[n]]``. Knots may be non-uniform and repeated
(multiplicity <= m inside, m + 1 at clamped ends).
"""
from __future__ import annotations

import numpy as np

from ..errors import ShellsplineError
from ..groups.lie import group

__all__ = ["BSpline", "clamped_knots"]


def clamped_knots(t, m):
    """Clamped knot vector whose control points sit at the parameters ``t`` in the
    averaging sense (knot averaging, de Boor's choice for interpolation).

    Parameters
    ----------
    t : (n,) array_like
        Strictly increasing parameters, one per control point (``n > m``).
    m : int
        Degree.

    Returns
    -------
    u : (n + m + 1,) ndarray
        ``m + 1`` copies of ``t[0]``, interior knots ``mean(t[j+1 : j+m+1])``, ``m + 1`` copies
        of ``t[-1]``; its Greville abscissae are close to ``t``.
    """
    t = np.asarray(t, dtype=np.float64)
    n = t.size
    if n <= m:
        raise ShellsplineError(f"a degree-{m} B-spline needs more than {m} control points, got "
                               f"{n}")
    inner = [t[j + 1:j + m + 1].mean() for j in range(n - m - 1)] if m > 0 else list(t[1:-1])
    return np.concatenate([[t[0]] * (m + 1), inner, [t[-1]] * (m + 1)])


class BSpline:
    """A B-spline on a Lie group, evaluated by the geodesic de Boor algorithm.

    Parameters
    ----------
    G : LieGroup or str
    control : (..., n, *G.shape) array_like
        Control points (leading axes: independent curves sharing the knots). Consecutive
        control points must be closer than the injectivity radius.
    knots : (n + m + 1,) array_like
        Non-decreasing knots.
    degree : int
        ``m >= 1``.

    Notes
    -----
    For ``t`` in ``[u_k, u_{k+1})`` start from ``d_j = control[k - m + j]`` (``j = 0..m``;
    seed 002 algorithm 4.3.3 with its erratum ``d_{i,0} := d_{i-1}``: the printed
    ``d_i - 1`` is an index shift) and for ``r = 1..m``, ``j = m..r``::

        a = (t - u[j+k-m]) / (u[j+1+k-r] - u[j+k-m]),   d_j = interp_a(d_{j-1}, d_j)

    The result is ``d_m``. In a flat group this is the classical de Boor algorithm.

    Examples
    --------
    >>> import numpy as np
    >>> from shellspline.groups import so3
    >>> d = so3.exp(np.array([[0, 0, 0], [0, 0, 0.5], [0, 0, 1.0], [0, 0, 1.5]]))
    >>> S = BSpline("so3", d, clamped_knots([0, 1, 2, 3], 2), 2)
    >>> float(np.round(so3.log(S(3.0))[2], 12))  # clamped ends interpolate
    1.5
    """

    def __init__(self, G, control, knots, degree):
        self.G = G = group(G)
        k = len(G.shape)
        d = np.asarray(control, dtype=np.float64)
        u = np.asarray(knots, dtype=np.float64)
        m = int(degree)
        if d.ndim < k + 1 or d.shape[d.ndim - k:] != tuple(G.shape):
            raise ShellsplineError(f"control must have shape (..., n, "
                                   f"{', '.join(map(str, G.shape))}), got {d.shape}")
        d = G.check(d, "control")  # finite, rotations that are rotations
        n = d.shape[d.ndim - k - 1]
        if m < 1 or n <= m:
            raise ShellsplineError(f"degree must be >= 1 and below the number of control points "
                                   f"({n}), got {degree}")
        if u.shape != (n + m + 1,) or np.any(np.diff(u) < 0) or not np.all(np.isfinite(u)):
            raise ShellsplineError(f"knots must be {n + m + 1} non-decreasing numbers for {n} "
                                   f"control points of degree {m}, got shape {u.shape}")
        if not u[n] > u[m]:
            raise ShellsplineError("knots: the domain [u[m], u[n]] is empty")
        self.control, self.knots, self.degree, self.n = d, u, m, n
        self._ax = d.ndim - k - 1

    @property
    def domain(self):
        """``(u[m], u[n])``."""
        return float(self.knots[self.degree]), float(self.knots[self.n])

    def _span(self, t):
        m, n, u = self.degree, self.n, self.knots
        k = np.searchsorted(u, t, side="right") - 1
        return np.clip(k, m, n - 1)

    def __call__(self, t):
        """Points at parameters ``t (T,)`` (or a float): ``(..., T, *G.shape)``."""
        G, m, u = self.G, self.degree, self.knots
        t = np.asarray(t, dtype=np.float64)
        scalar = t.ndim == 0
        t = np.atleast_1d(t)
        k = self._span(t)
        ax = self._ax
        # d[j] for j = 0..m: (..., T, *shape)
        d = [np.take(self.control, k - m + j, axis=ax) for j in range(m + 1)]
        for r in range(1, m + 1):
            for j in range(m, r - 1, -1):
                lo, hi = u[j + k - m], u[j + 1 + k - r]
                a = (t - lo) / np.where(hi > lo, hi - lo, 1.0)
                d[j] = G.interp(d[j - 1], d[j], a)
        out = d[m]
        return np.take(out, 0, axis=ax) if scalar else out

    def insert_knot(self, x):
        """The spline with the knot ``x`` inserted once (Boehm's algorithm, geodesic).

        Returns
        -------
        BSpline
            ``n + 1`` control points: for ``i = k-m+1..k`` (``u_k <= x < u_{k+1}``)
            ``d'_i = interp_a(d_{i-1}, d_i)``, ``a = (x - u_i) / (u_{i+m} - u_i)``; the rest are
            kept. In a flat group the curve is unchanged and insertions commute; on a curved
            group neither holds exactly (seed 002 chapter 6: SO(3) is not a "Menelaus space"),
            which ``benchmarks/bench_curves.py`` measures.
        """
        G, m, u, ax = self.G, self.degree, self.knots, self._ax
        x = float(x)
        lo, hi = self.domain
        if not lo <= x <= hi:
            raise ShellsplineError(f"insert_knot: {x} is outside the domain [{lo}, {hi}]")
        k = int(self._span(np.array([x]))[0])
        d = self.control
        new = [np.take(d, i, axis=ax) for i in range(k - m + 1)]
        for i in range(k - m + 1, k + 1):
            a = (x - u[i]) / (u[i + m] - u[i])
            new.append(G.interp(np.take(d, i - 1, axis=ax), np.take(d, i, axis=ax), a))
        new += [np.take(d, i, axis=ax) for i in range(k, self.n)]
        return BSpline(G, np.stack(new, axis=ax), np.insert(u, k + 1, x), m)

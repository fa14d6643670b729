"""Elastic (SRV) time alignment of two sampled curves, with feature points (seeds 000, 003).

Given SRVs ``q0`` and ``q1`` of two curves (any dimension: curves in ``R^m`` or, through
:func:`~shellspline.curves.srv.srv`, in ``SO(3)^d x R^m``) we look for the warp ``phi`` of
``[0, 1]`` minimising (seed 003 eq. 21, seed 000 eq. 10)

    ``E(phi) = int_0^1 |q0(t) - sqrt(phi'(t)) q1(phi(t))|^2 dt + lam sum_i (phi(a_i) - b_i)^2``

(times normalised to ``[0, 1]``; ``a_i``, ``b_i`` feature times of curve 0 and curve 1),
optionally with the symmetric term ``lam sum_i (phi^{-1}(b_i) - a_i)^2`` (seed 003 sect. 2.4)
and hard bounds ``|phi(a_i) - b_i| <= bound_i``.

Both curves are piecewise geodesic between their samples, so their SRVs are piecewise
constant and, for a piecewise-linear ``phi``, the elastic term has the closed form

    ``|q0|^2 + |q1|^2 - 2 sum_n sqrt(h0 / dphi_n) <q0_n, Q1(phi_{n+1}) - Q1(phi_n)>``

with ``Q1`` the (piecewise-linear) integral of ``q1``. The dynamic programme (seed 003 sect.
3.2) evaluates exactly this energy on every lattice segment, so the energy it reports *is* the
energy of the warp it returns; a quasi-Newton refinement (seed 003 sect. 3.1, in the
``log dphi`` variables, which keep ``phi`` increasing) then moves the vertices off the lattice.

The DP is vectorised over one grid axis: segment costs are built for blocks of rows at once
from the Gram matrix ``<q0_n, q1_p>`` (one shifted add per non-zero overlap of a step), and
the recursion over a row takes the minimum over all predecessor steps in one gather.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from math import gcd

import numpy as np

from ..errors import ShellsplineError
from ..errors import tol as tolerances  # here `tol` names the solvers' stopping argument
from .srv import ProductCurve, normalized_times, srv

__all__ = ["AlignResult", "align", "align_srv", "warp_energy", "warp_energy_grad",
           "shape_distance", "project_closed", "neighborhood", "dtw"]

# Rows of the DP cost computed at once: large enough to amortise numpy's per-call overhead,
# small enough that 23 cost blocks of 1,600 columns stay in cache-friendly ~10 MB
# (benchmarks/bench_motion.py, bench_dp).
_ROW_BLOCK = 48
# Row blocks per strip of the Gram matrix (one BLAS call each).
_STRIP_BLOCKS = 8
# DTW cost of a cell outside the band: finite, so that running sums never meet inf - inf.
_FAR = 1e150
# Refinement stops as converged when the last _WINDOW iterations lowered the energy by less
# than h^2 of it (h: the finer sample spacing, normalised), the order of the discretisation
# error of the energy itself: a piecewise-constant SRV loses |q - Pq|^2 = O(h^2) of |q|^2
# (scipy's ftol criterion, over a window because kinks make single steps tiny). The energy
# is only piecewise smooth (a kink wherever a vertex crosses a sample of curve 1), so the
# gradient does not vanish at its minima and a fixed 1e-9 was never met on real mocap: the
# refinement crawled along kinks for thousands of iterations at ~1e-6 per 10 (walk_normal vs
# walk_tired, 247 frames: 32.47 after 492 iterations, 32.35 after 3,100; the warp within 0.33
# frames of the latter). A window of 20, not 10: short plateaus of the crawl end runs from
# rounding-level different starts 1 % apart in energy with 10.
_WINDOW = 20
#: ... and never asks for less than this relative decrease over the window (the distance, the
#: energy's square root, then moves by less than 5e-7 of itself): at 4,801 frames ``h²`` is
#: 4e-8, and the iterations it took past 200 (20.8 s against 8.2 s for the whole distance)
#: left the distance unchanged to 7 digits.
FTOL_FLOOR = 1e-6
# Log-slopes of the refined warp are clipped to [-_ZMAX, _ZMAX] around their mean.
_ZMAX = 20.0


def neighborhood(size: int = 6) -> np.ndarray:
    """DP steps ``(a, b)``: all coprime pairs with ``1 <= a, b <= size``, ``(S, 2)`` int64.

    ``size = 6`` gives the 23 steps of fdasrsf (slopes from 1/6 to 6).
    """
    size = int(size)
    if size < 1:
        raise ShellsplineError(f"neighborhood: size must be >= 1, got {size}")
    return np.array([(a, b) for a in range(1, size + 1) for b in range(1, size + 1)
                     if gcd(a, b) == 1], dtype=np.int64)


@dataclass
class AlignResult:
    """Result of :func:`align` / :func:`align_srv`.

    Attributes
    ----------
    phi : (N0,) ndarray
        The warp on curve 0's times, with values in curve 1's times (``curve1 o phi`` is
        aligned to ``curve0``). For closed curves the values run from ``shift`` to
        ``shift + period`` (take them modulo the period).
    t : (N0,) ndarray
        Curve 0's times.
    energy : float
        Final energy ``E(phi)`` (elastic + feature terms), normalised time.
    energy_dp : float
        Energy of the DP warp (before refinement).
    energy_identity : float
        Energy of the identity (affine) warp, for comparison.
    elastic : float
        The elastic part of ``energy``; ``distance = sqrt(elastic)``.
    distance : float
        SRV distance of ``curve0`` and ``curve1 o phi``.
    iterations : int
        Refinement iterations (0 without refinement).
    status : str
        ``"dp"`` (DP only: optimal among warps on the lattice), ``"converged"`` (the
        refinement met its tolerance, or the DP warp already has zero energy; when the
        refined warp is not below the DP energy the DP warp is kept), ``"stalled"`` (the
        refinement stopped without meeting its tolerance: a line search failed, or its warp
        left the hard feature bounds; the DP warp is kept when it is lower) or ``"limit"``
        (the refinement stopped at ``max_iter`` iterations).
    message : str
    shift : float
        Closed curves: the time of curve 1 matched to curve 0's start (else ``t1[0]``).
    path : (K,2) ndarray
        Lattice vertices ``(i, j)`` of the DP warp (sample indices of curve 0 and curve 1).
    """

    phi: np.ndarray
    t: np.ndarray
    energy: float
    energy_dp: float
    energy_identity: float
    elastic: float
    distance: float
    iterations: int
    status: str
    message: str
    shift: float = 0.0
    path: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), dtype=np.int64))

    @property
    def success(self) -> bool:
        """True when the solve reached what it set out to do: ``status`` is ``"converged"``,
        or ``"dp"`` (no refinement asked for: the DP warp is exact on its lattice)."""
        return self.status in ("converged", "dp")


# --------------------------------------------------------------------------------------------
# features


@dataclass(frozen=True)
class _Features:
    """Feature times in normalised units: ``a`` (curve 0), ``b`` (curve 1), soft weight,
    symmetric flag, hard bounds (inf = none)."""

    a: np.ndarray
    b: np.ndarray
    lam: float
    symmetric: bool
    bound: np.ndarray

    @property
    def n(self):
        return self.a.shape[0]


def _canonical_features(features, lam, symmetric, bounds, t0, t1, N0, N1):
    if features is None:
        if bounds is not None:
            raise ShellsplineError("align: bounds given without features")
        return None
    try:
        a, b = features
        a = np.asarray(a, dtype=np.float64).reshape(-1)
        b = np.asarray(b, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise ShellsplineError("align: features must be a pair (times in curve 0, times in "
                               f"curve 1), got {features!r}") from None
    if a.shape != b.shape:
        raise ShellsplineError(f"align: features need as many times in curve 0 as in curve 1, "
                               f"got {a.shape[0]} and {b.shape[0]}")
    for name, x, t in (("curve 0", a, t0), ("curve 1", b, t1)):
        if not np.all(np.isfinite(x)) or x.size and (x.min() < t[0] or x.max() > t[-1]):
            raise ShellsplineError(f"align: feature times of {name} must lie in "
                                   f"[{t[0]!r}, {t[-1]!r}], got {x.tolist()}")
    lam = float(lam)
    if not lam >= 0:
        raise ShellsplineError(f"align: lam must be >= 0, got {lam!r}")
    an, bn = (a - t0[0]) / (t0[-1] - t0[0]), (b - t1[0]) / (t1[-1] - t1[0])
    if bounds is None:
        bound = np.full(a.shape, np.inf)
    else:
        bound = np.broadcast_to(np.asarray(bounds, dtype=np.float64), a.shape).copy()
        if np.any(~(bound >= 0)):
            raise ShellsplineError(f"align: bounds must be >= 0, got {np.asarray(bounds)}")
        bound = bound / (t1[-1] - t1[0])
        # a zero bound is a passage point: snap both times to the nearest samples
        z = bound == 0
        an[z] = np.round(an[z] * (N0 - 1)) / (N0 - 1)
        bn[z] = np.round(bn[z] * (N1 - 1)) / (N1 - 1)
        bound[z] = 1e-9
    return _Features(an, bn, lam, bool(symmetric), bound)


# --------------------------------------------------------------------------------------------
# exact energy of a piecewise-linear warp


def _cumulative(q1):
    """``Q1`` at the samples of curve 1: ``(N1, D)``."""
    return np.concatenate([np.zeros((1, q1.shape[1])), np.cumsum(q1, axis=0) / q1.shape[0]])


def _Q1(q1, u, cum):
    """``p`` (interval index) and ``Q1(u) = int_0^u q1`` for ``u`` in ``[0, 1]``."""
    n1 = q1.shape[0]
    h1 = 1.0 / n1
    p = np.clip(np.floor(u * n1).astype(np.int64), 0, n1 - 1)
    return p, cum[p] + (u - p * h1)[:, None] * q1[p]


def _feature_terms(phi, feats, with_grad):
    """Feature energy and its gradient w.r.t. the vertex values ``phi (N0,)``."""
    N0 = phi.shape[0]
    h0 = 1.0 / (N0 - 1)
    g = np.zeros(N0)
    if feats is None or feats.n == 0 or feats.lam == 0:
        return 0.0, g
    x = feats.a / h0
    n = np.clip(np.floor(x).astype(np.int64), 0, N0 - 2)
    f = x - n
    val = phi[n] + f * (phi[n + 1] - phi[n])
    r = val - feats.b
    E = feats.lam * float(np.sum(r * r))
    if with_grad:
        np.add.at(g, n, 2 * feats.lam * r * (1 - f))
        np.add.at(g, n + 1, 2 * feats.lam * r * f)
    if feats.symmetric:
        y = feats.b
        k = np.clip(np.searchsorted(phi, y, side="right") - 1, 0, N0 - 2)
        D = phi[k + 1] - phi[k]
        rr = (y - phi[k]) / D
        inv = (k + rr) * h0
        s = inv - feats.a
        E += feats.lam * float(np.sum(s * s))
        if with_grad:
            np.add.at(g, k, 2 * feats.lam * s * h0 * (rr - 1) / D)
            np.add.at(g, k + 1, 2 * feats.lam * s * h0 * (-rr) / D)
    return E, g


def _public_features(q0, q1, features, lam, symmetric):
    if features is None:
        return None
    N0, N1 = q0.shape[0] + 1, q1.shape[0] + 1
    return _canonical_features(features, lam, symmetric, None, np.linspace(0, 1, N0),
                               np.linspace(0, 1, N1), N0, N1)


def warp_energy(q0, q1, phi, *, features=None, lam=0.0, symmetric=False):
    """Exact energy of a piecewise-linear warp (normalised time, uniform grids).

    Parameters
    ----------
    q0 : (N0-1, D) array_like
        SRV of curve 0 on ``N0 - 1`` equal intervals of ``[0, 1]``.
    q1 : (N1-1, D) array_like
        SRV of curve 1.
    phi : (N0,) array_like
        Increasing warp values at curve 0's vertices, ``phi[0] = 0``, ``phi[-1] = 1``.
    features, lam, symmetric
        Soft feature term as in :func:`align` (feature times in ``[0, 1]``).

    Returns
    -------
    total, elastic : float
        ``elastic = int |q0 - sqrt(phi') q1(phi)|^2``, ``total = elastic + feature terms``.
    """
    q0, q1 = np.asarray(q0, float), np.asarray(q1, float)
    feats = _public_features(q0, q1, features, lam, symmetric)
    E, _ = _energy(q0, q1, np.asarray(phi, float), feats, False)
    return E


def warp_energy_grad(q0, q1, phi, *, features=None, lam=0.0, symmetric=False):
    """Total energy of :func:`warp_energy` and its gradient w.r.t. ``phi``, ``(N0,)``
    (zero at both ends, which are fixed; right derivatives where a vertex sits on a sample of
    curve 1)."""
    q0, q1 = np.asarray(q0, float), np.asarray(q1, float)
    feats = _public_features(q0, q1, features, lam, symmetric)
    (E, _), g = _energy(q0, q1, np.asarray(phi, float), feats, True)
    return E, g


def _energy(q0, q1, phi, feats, with_grad, cum=None):
    N0 = phi.shape[0]
    h0 = 1.0 / (N0 - 1)
    h1 = 1.0 / q1.shape[0]
    n0sq = h0 * float(np.einsum("ij,ij->", q0, q0))
    n1sq = h1 * float(np.einsum("ij,ij->", q1, q1))
    dphi = np.diff(phi)
    # Q1 is continuous; its derivative q1 is taken from the right at samples of curve 1 (so
    # the gradient is the right derivative at the kinks there)
    cum = _cumulative(q1) if cum is None else cum
    p_all, Q_all = _Q1(q1, phi, cum)  # once at every vertex: both ends of the segments
    C = np.einsum("ij,ij->i", q0, Q_all[1:] - Q_all[:-1])
    pos = dphi > 0
    sq = np.sqrt(h0 / np.where(pos, dphi, 1.0))
    cross = np.where(pos, sq * C, 0.0)
    elastic = n0sq + n1sq - 2.0 * float(np.sum(cross))
    Ef, gf = _feature_terms(phi, feats, with_grad)
    if not with_grad:
        return (elastic + Ef, elastic), None
    q1p = q1[p_all]
    a_hi = np.einsum("ij,ij->i", q0, q1p[1:])
    a_lo = np.einsum("ij,ij->i", q0, q1p[:-1])
    dC = np.where(pos, 0.5 * sq / np.where(pos, dphi, 1.0) * C, 0.0)
    g = np.zeros(N0)
    g[1:] += -2.0 * (np.where(pos, sq * a_hi, 0.0) - dC)
    g[:-1] += -2.0 * (-np.where(pos, sq * a_lo, 0.0) + dC)
    g += gf
    g[0] = g[-1] = 0.0
    return (elastic + Ef, elastic), g


# --------------------------------------------------------------------------------------------
# dynamic programming


def _overlaps(a, b):
    """Non-zero overlaps of curve-0 interval ``n`` (mapped to ``[n b/a, (n+1) b/a]``) with
    curve-1 interval ``[p, p+1]``: arrays ``n, p, w`` (index units)."""
    n = np.arange(a)[:, None]
    p = np.arange(b)[None, :]
    w = np.minimum((n + 1) * b / a, p + 1) - np.maximum(n * b / a, p)
    n, p = np.nonzero(w > 1e-12)
    return n, p, w[n, p]


def _dp(q0, q1, steps, window, feats):
    """Lattice DP; returns (energy, path (K,2)).

    Memory ``O(N0 N1)`` bytes for the back pointers only: the Gram matrix is built per block
    of rows within the window, and the values are kept for the last ``P + 1`` rows (a ring;
    no step reaches further back). Two 40 s clips at 120 Hz (4,801 frames): 581 -> 180 MB
    (benchmarks/bench_motion.py, bench_long_distance)."""
    N0, N1 = q0.shape[0] + 1, q1.shape[0] + 1
    h0, h1 = 1.0 / (N0 - 1), 1.0 / (N1 - 1)
    S = steps.shape[0]
    P = int(steps.max())
    if N1 - 1 > P * (N0 - 1) or N0 - 1 > P * (N1 - 1):
        raise ShellsplineError(f"align: no admissible warp: the curves have {N0 - 1} and "
                               f"{N1 - 1} intervals, and the DP's slopes lie in [1/{P}, {P}] "
                               "(resample one curve, or a larger neighborhood_size)")
    A0 = np.concatenate([np.zeros(P + 1), np.cumsum(h0 * np.einsum("ij,ij->i", q0, q0))])
    A1 = np.concatenate([np.zeros(P + 1), np.cumsum(h1 * np.einsum("ij,ij->i", q1, q1))])
    # A0[P + i] = int_0^{t_i} |q0|^2
    ovl = [_overlaps(int(a), int(b)) for a, b in steps]
    coef = np.array([2.0 * h1 / np.sqrt(b * h1 / (a * h0)) for a, b in steps])
    W = N1 + P
    ring = P + 1                                   # lattice row i is Hp[(P + i) % ring]
    Hp = np.full((ring, W), np.inf)
    Hp[P % ring, P] = 0.0
    back = np.zeros((N0, N1), dtype=np.int8)
    flatH = Hp.reshape(-1)
    w = 1.0 if window is None else float(window)
    ii = np.arange(N0) * h0
    sr1 = 0
    for r0 in range(1, N0, _ROW_BLOCK):
        r1 = min(N0, r0 + _ROW_BLOCK)
        jlo = max(1, int(np.floor((ii[r0] - w) / h1)) - 1)
        jhi = min(N1, int(np.ceil((ii[r1 - 1] + w) / h1)) + 2)
        rows = np.arange(r0, r1)
        cols = np.arange(jlo, jhi)
        nr, nc = rows.size, cols.size
        inwin = np.abs(rows[:, None] * h0 - cols[None, :] * h1) <= w + 1e-12
        if r1 > sr1:
            # the Gram matrix <q0_x, q1_y> on a strip of rows x in [sr0 - P, sr1 - 1) and the
            # window's columns y in [sj0 - P, sj1 - 1) (zero at negative indices): O(strip)
            # memory, not O(N0 N1), in few BLAS calls (per block they cost 3x on 2 threads)
            sr0, sr1 = r0, min(N0, r0 + _STRIP_BLOCKS * _ROW_BLOCK)
            sj0, sj1 = jlo, min(N1, int(np.ceil((ii[sr1 - 1] + w) / h1)) + 2)
            Gs = np.zeros((sr1 - sr0 + P - 1, sj1 - sj0 + P - 1))
            x0, y0 = max(sr0 - P, 0), max(sj0 - P, 0)
            Gs[x0 - (sr0 - P):, y0 - (sj0 - P):] = q0[x0:sr1 - 1] @ q1[y0:sj1 - 1].T
        G = Gs[r0 - sr0:r0 - sr0 + nr + P - 1, jlo - sj0:jlo - sj0 + nc + P - 1]
        C = np.empty((S, nr, nc))
        outwin = ~inwin
        # preallocated: a temporary of a block (~1 MB) is an mmap and its page faults
        cross, tmp = np.empty((nr, nc)), np.empty((nr, nc))
        for s, (a, b) in enumerate(steps):
            a, b = int(a), int(b)
            cross.fill(0.0)
            for n, p, wt in zip(*ovl[s]):
                np.multiply(G[P - a + n:P - a + n + nr, P - b + p:P - b + p + nc], wt, out=tmp)
                cross += tmp
            Cs = C[s]
            np.multiply(cross, coef[s], out=tmp)
            np.subtract((A0[P + rows] - A0[P + rows - a])[:, None], tmp, out=Cs)
            Cs += (A1[P + cols] - A1[P + cols - b])[None, :]
            np.copyto(Cs, np.inf, where=outwin)
            Cs[:max(a - r0, 0)] = np.inf                       # rows < a
            Cs[:, :max(b - jlo, 0)] = np.inf                   # cols < b
            if feats is not None and feats.n:
                _add_features(Cs, feats, a, b, rows, cols, h0, h1)
        colidx = (P + cols)[None, :] - steps[:, 1][:, None]
        for k, i in enumerate(rows):
            cand = np.take(flatH, ((P + i - steps[:, 0]) % ring * W)[:, None] + colidx)
            cand += C[:, k, :]
            best = cand.min(axis=0)
            row = Hp[(P + i) % ring]
            row.fill(np.inf)
            row[P + jlo:P + jhi] = best
            # the first step reaching the minimum (argmin's choice); argmin along axis 0 of
            # a (steps, columns) block is 12x slower than min: 125 against 10 us per row
            back[i, jlo:jhi] = (cand == best).argmax(axis=0)
    E = Hp[(P + N0 - 1) % ring, P + N1 - 1]
    if not np.isfinite(E):
        raise ShellsplineError("align: no admissible warp: the feature bounds, the window and "
                               "the slope limits cannot all be met")
    path = [(N0 - 1, N1 - 1)]
    i, j = N0 - 1, N1 - 1
    while i > 0 or j > 0:
        a, b = steps[back[i, j]]
        i, j = i - int(a), j - int(b)
        path.append((i, j))
    return float(E), np.array(path[::-1], dtype=np.int64)


def _add_features(Cs, feats, a, b, rows, cols, h0, h1):
    """Add the feature terms of step ``(a, b)`` to the cost block ``Cs`` (rows x cols)."""
    N0m1 = round(1.0 / h0)
    r0, r1 = rows[0], rows[-1] + 1
    x = feats.a / h0
    nidx = np.minimum(np.floor(x).astype(np.int64), N0m1 - 1)
    for m in np.nonzero((nidx + a >= r0) & (nidx + 1 < r1))[0]:
        lo, hi = max(r0, nidx[m] + 1), min(r1, nidx[m] + a + 1)
        if lo >= hi:
            continue
        ri = np.arange(lo, hi)
        frac = (x[m] - (ri - a)) / a                              # position in the segment
        phi = (cols[None, :] - b + b * frac[:, None]) * h1
        r = phi - feats.b[m]
        blk = Cs[lo - r0:hi - r0]
        blk += feats.lam * r * r
        blk[np.abs(r) > feats.bound[m]] = np.inf
    if feats.symmetric:
        N1m1 = round(1.0 / h1)
        y = feats.b / h1
        pidx = np.minimum(np.floor(y).astype(np.int64), N1m1 - 1)
        c0, c1 = cols[0], cols[-1] + 1
        for m in np.nonzero((pidx + b >= c0) & (pidx + 1 < c1))[0]:
            lo, hi = max(c0, pidx[m] + 1), min(c1, pidx[m] + b + 1)
            if lo >= hi:
                continue
            cj = np.arange(lo, hi)
            frac = (y[m] - (cj - b)) / b
            inv = (rows[:, None] - a + a * frac[None, :]) * h0
            r = inv - feats.a[m]
            Cs[:, lo - c0:hi - c0] += feats.lam * r * r


# --------------------------------------------------------------------------------------------
# refinement


def _lbfgs(fun, x, max_iter, gtol, ftol, memory=8):
    """Limited-memory BFGS with Armijo backtracking (the two-loop recursion).

    The energy is only piecewise smooth (kinks where a warp vertex crosses a sample of curve
    1): when a line search fails the memory is dropped and a steepest-descent step is tried;
    the iteration stops when that fails too ("stalled"), when ``|grad|_inf <= gtol``
    or the energy fell by less than ``ftol`` (relative) over ``_WINDOW`` iterations
    ("converged"), or after ``max_iter`` iterations ("limit"). A hand-written loop: scipy's
    L-BFGS-B spends milliseconds per iteration in its Fortran driver at these sizes, 10x the
    energy evaluation. Returns ``(x, f, iterations, converged, message)``.
    """
    f, g = fun(x)
    S, Y = [], []
    hist = [f]
    for it in range(1, max_iter + 1):
        if np.max(np.abs(g)) <= gtol:
            return x, f, it - 1, True, "gradient below tolerance"
        if len(hist) > _WINDOW and \
                hist[-1 - _WINDOW] - f <= ftol * max(abs(f), tolerances.zero):
            return x, f, it - 1, True, (f"relative energy decrease over {_WINDOW} iterations "
                                        f"below {ftol:.2g} (h^2 of the sample grid)")
        q = g.copy()
        coef = []
        for s, y in zip(reversed(S), reversed(Y)):
            rho = 1.0 / (y @ s)
            a = rho * (s @ q)
            q -= a * y
            coef.append((rho, a))
        if S:
            q *= (S[-1] @ Y[-1]) / (Y[-1] @ Y[-1])
        else:
            q *= 1.0 / max(np.max(np.abs(g)), 1.0)
        for (s, y), (rho, a) in zip(zip(S, Y), reversed(coef)):
            q += s * (a - rho * (y @ q))
        d = -q
        slope = g @ d
        if not slope < 0:
            S, Y = [], []
            d = -g / max(np.max(np.abs(g)), 1.0)
            slope = g @ d
        step = 1.0
        for _ in range(40):
            xn = x + step * d
            fn, gn = fun(xn)
            if fn <= f + 1e-4 * step * slope:
                break
            step *= 0.5
        else:
            if S:
                S, Y = [], []
                continue
            return x, f, it - 1, False, "line search failed (a kink of the energy)"
        s, y = xn - x, gn - g
        if s @ y > 1e-12 * np.sqrt((s @ s) * (y @ y)):
            S.append(s)
            Y.append(y)
            if len(S) > memory:
                S.pop(0)
                Y.pop(0)
        x, f, g = xn, fn, gn
        hist.append(f)
    return x, f, max_iter, False, f"iteration limit ({max_iter})"


def _refine(q0, q1, phi, feats, max_iter, tol, smooth=True):
    """L-BFGS on ``z = log dphi`` (``dphi = softmax(z)`` keeps ``phi`` increasing with fixed
    ends) from the DP warp ``phi``, smoothed first (``smooth``) or only moved off the kinks;
    returns ``(phi, energy, iterations, status, message)``, ``status`` one of
    ``"converged"``, ``"limit"``, ``"stalled"``."""
    def unpack(z):
        # slopes stay within e^{+-40} of each other (no under/overflow in sqrt(h0 / dphi))
        z = np.clip(z, -_ZMAX, _ZMAX)
        e = np.exp(z - z.max())
        dphi = e / e.sum()
        return np.concatenate([[0.0], np.cumsum(dphi)[:-1], [1.0]]), dphi

    cum = _cumulative(q1)

    def fun(z):
        ph, dphi = unpack(z)
        (E, _), g = _energy(q0, q1, ph, feats, True, cum)
        gd = np.cumsum(g[::-1])[::-1][1:]                # dE/d dphi_n = sum_{i > n} dE/dphi_i
        gz = dphi * (gd - np.dot(dphi, gd))
        return E, np.where(np.abs(z) < _ZMAX, gz, 0.0)

    # start off the lattice: at the DP's vertices (sample nodes of both curves) the energy
    # has kinks on which the line search stalls at once; one [1/4, 1/2, 1/4] pass moves them
    # inside their segments
    # inside their segments (without it: only off the kinks, at nearly the DP energy, where
    # the iteration may need a few hundred steps to leave the lattice's kinks)
    phi = phi.copy()
    if smooth:
        phi[1:-1] = 0.25 * phi[:-2] + 0.5 * phi[1:-1] + 0.25 * phi[2:]
    # and off the samples of curve 1 (a shift by 0.1 (1e-4) of its step; the DP's slopes are
    # at least 1/6 of a step per interval, so phi stays increasing)
    h1 = 1.0 / q1.shape[0]
    phi[1:-1] += (0.1 if smooth else 1e-4) * h1 * np.minimum(1.0, np.diff(phi)[-1] / h1)
    z = np.log(np.maximum(np.diff(phi), 1e-12))
    z = np.clip(z - z.mean(), -_ZMAX, _ZMAX)
    ftol = max((1.0 / max(q0.shape[0], q1.shape[0])) ** 2, FTOL_FLOOR)
    z, E, nit, ok, msg = _lbfgs(fun, z, int(max_iter), tol, ftol)
    ph, _ = unpack(z)
    status = "converged" if ok else ("limit" if nit >= max_iter else "stalled")
    return ph, E, nit, status, msg


# --------------------------------------------------------------------------------------------
# public entry points


def align_srv(q0, q1, *, features=None, lam=0.0, symmetric=False, bounds=None,
              window=0.25, neighborhood_size=6, refine=True, max_iter=None,
              tol=1e-8) -> AlignResult:
    """Align two SRVs given on equal intervals of ``[0, 1]`` (see :func:`align`).

    Parameters
    ----------
    q0 : (N0-1, D) array_like
    q1 : (N1-1, D) array_like
    features, lam, symmetric, bounds, window, neighborhood_size, refine, max_iter, tol
        As in :func:`align`; feature times in ``[0, 1]``.

    Returns
    -------
    AlignResult
        With ``phi`` and ``t`` in ``[0, 1]``.
    """
    q0 = np.asarray(q0, dtype=np.float64)
    q1 = np.asarray(q1, dtype=np.float64)
    if q0.ndim != 2 or q1.ndim != 2 or q0.shape[1] != q1.shape[1]:
        raise ShellsplineError(f"align: q0 and q1 must be (N0-1, D) and (N1-1, D) arrays, got "
                               f"{q0.shape} and {q1.shape}")
    if q0.shape[0] < 1 or q1.shape[0] < 1:
        raise ShellsplineError("align: curves need at least 2 samples")
    if not (np.all(np.isfinite(q0)) and np.all(np.isfinite(q1))):
        raise ShellsplineError("align: q0 and q1 must be finite")
    N0, N1 = q0.shape[0] + 1, q1.shape[0] + 1
    t0, t1 = np.linspace(0, 1, N0), np.linspace(0, 1, N1)
    feats = _canonical_features(features, lam, symmetric, bounds, t0, t1, N0, N1)
    if window is not None and not window > 0:
        raise ShellsplineError(f"align: window must be > 0 (a fraction of the duration) or "
                               f"None, got {window!r}")
    steps = neighborhood(neighborhood_size)
    return _align_normalised(q0, q1, feats, steps, window, refine, max_iter, tol)


def _align_normalised(q0, q1, feats, steps, window, refine, max_iter, tol):
    N0, N1 = q0.shape[0] + 1, q1.shape[0] + 1
    max_iter = _iteration_limit(max_iter, max(N0, N1))
    t0 = np.linspace(0, 1, N0)
    E_id, _ = _energy(q0, q1, t0, feats, False)[0]
    E_dp, path = _dp(q0, q1, steps, window, feats)
    phi = np.interp(np.arange(N0), path[:, 0], path[:, 1] / (N1 - 1))
    (E, el), _ = _energy(q0, q1, phi, feats, False)
    status, msg, nit = "dp", "dynamic programming on the sample lattice", 0
    scale = (np.sum(q0 * q0) / (N0 - 1) + np.sum(q1 * q1) / (N1 - 1))
    if refine and E <= 1e-14 * scale:
        status, msg = "converged", "the DP warp matches exactly (zero energy)"
    elif refine and N0 > 2:
        def within(ph):
            return feats is None or bool(np.all(
                np.abs(_feature_values(ph, feats) - feats.b) <= feats.bound))
        ph, E_r, nit, status, msg_r = _refine(q0, q1, phi, feats, max_iter, tol)
        if not (E_r < E and within(ph)) and nit < max_iter:
            # the smoothed start (above the DP energy) ended no lower than the DP warp: refine
            # from the DP warp itself, with the iterations left
            ph2, E2, nit2, status2, msg2 = _refine(q0, q1, phi, feats, max_iter - nit, tol,
                                                   smooth=False)
            nit += nit2
            if within(ph2) and (E2 < E_r or not within(ph)):
                ph, E_r, status, msg_r = ph2, E2, status2, msg2
        if E_r < E and within(ph):
            phi, E = ph, E_r
            (_, el), _ = _energy(q0, q1, phi, feats, False)
            msg = f"refined from the DP warp: {msg_r}"
        elif not within(ph):
            status = "stalled"
            msg = "refinement left the hard feature bounds; DP warp kept"
        else:
            msg = f"refinement did not lower the DP energy ({msg_r}); DP warp kept"
    return AlignResult(phi=phi, t=t0, energy=float(E), energy_dp=float(E_dp),
                       energy_identity=float(E_id), elastic=float(el),
                       distance=float(np.sqrt(max(el, 0.0))), iterations=nit, status=status,
                       message=msg, shift=0.0, path=path)


def _iteration_limit(max_iter, n):
    """``max_iter`` checked, or its default for curves of ``n`` samples."""
    if max_iter is None:
        return max(5000, 4 * n)
    if isinstance(max_iter, (bool, np.bool_)) or not isinstance(max_iter, (int, np.integer)) \
            or max_iter < 1:
        raise ShellsplineError(f"align: max_iter must be an integer >= 1 or None, got "
                               f"{max_iter!r}")
    return int(max_iter)


def _feature_values(phi, feats):
    N0 = phi.shape[0]
    x = feats.a * (N0 - 1)
    n = np.clip(np.floor(x).astype(np.int64), 0, N0 - 2)
    f = x - n
    return phi[n] + f * (phi[n + 1] - phi[n])


def _as_curve(c, name):
    if isinstance(c, ProductCurve):
        return c
    try:
        return ProductCurve(X=np.asarray(c, dtype=np.float64))
    except ShellsplineError as e:
        raise ShellsplineError(f"align: {name}: {e}") from None


def align(curve0, curve1, *, features=None, lam=0.0, symmetric=False, bounds=None,
          window=0.25, closed=False, n_starts=4, neighborhood_size=6, refine=True,
          max_iter=None, tol=1e-8) -> AlignResult:
    """Optimal time warp ``phi`` aligning ``curve1 o phi`` to ``curve0`` for the SRV metric.

    Parameters
    ----------
    curve0, curve1 : ProductCurve or (N,m) array_like
        Curves in ``SO(3)^d x R^m`` (same ``d`` and ``m``; any numbers of samples; plain
        arrays are curves in ``R^m`` on ``linspace(0, 1, N)``). Uniform sample times are
        assumed for the DP lattice (times are normalised to ``[0, 1]``).
    features : pair of (F,) array_like, optional
        Feature times ``(a, b)``: ``a_i`` in curve 0's times should map to ``b_i`` in curve
        1's times.
    lam : float
        Weight of the soft feature term ``lam sum (phi(a_i) - b_i)^2`` (normalised times).
    symmetric : bool
        Add the symmetric term ``lam sum (phi^{-1}(b_i) - a_i)^2`` (seed 003 sect. 2.4).
    bounds : float or (F,) array_like, optional
        Hard bounds ``|phi(a_i) - b_i| <= bound_i`` (curve 1's time units). ``0`` makes the
        pair a passage point (both times snapped to the nearest samples).
    window : float or None
        Admissible band ``|t - phi(t)| <= window`` (normalised times); ``None``: no band.
    closed : bool
        Closed curves (``c[-1] == c[0]``): also optimise the start point of curve 1 (the
        ``n_starts`` best cyclic shifts by FFT correlation are aligned by DP; the best is
        kept).
    n_starts : int
        Candidate start points for closed curves.
    neighborhood_size : int
        DP steps ``(a, b)`` coprime with ``a, b <= neighborhood_size`` (slopes 1/size..size).
    refine : bool
        Refine the DP warp by L-BFGS on the exact energy.
    max_iter : int, optional
        Refinement iteration limit (default ``max(5000, 4 N)`` for ``N`` samples of the
        longer curve: real walks of 200 to 2,000 frames converge in a few hundred to about
        2,100). Stopping there gives ``status == "limit"``.
    tol : float
        Refinement gradient tolerance. The refinement also converges when the last 20
        iterations lowered the energy by less than ``h^2`` of it (``h = 1 / (N - 1)``: the
        order of the discretisation error of the energy; its kinks keep the gradient from
        vanishing).

    Returns
    -------
    AlignResult

    Raises
    ------
    ShellsplineError
        On bad curves or options, or when no warp meets the hard bounds.

    Notes
    -----
    Energy (seed 003 eq. 20/21, seed 000 eq. 10 for the Lie group SRVT):
    ``int_0^1 |q0 - sqrt(phi') q1 o phi|^2 + lam sum (phi(a_i) - b_i)^2``.

    Examples
    --------
    >>> import numpy as np
    >>> t = np.linspace(0, 1, 101)
    >>> c1 = np.c_[np.cos(3 * t), np.sin(5 * t)]
    >>> c0 = np.c_[np.cos(3 * t ** 2), np.sin(5 * t ** 2)]      # c0 = c1 o t^2
    >>> r = align(c0, c1)
    >>> bool(np.abs(r.phi - t ** 2).max() < 0.01)
    True
    """
    c0, c1 = _as_curve(curve0, "curve0"), _as_curve(curve1, "curve1")
    if (c0.d, c0.m) != (c1.d, c1.m):
        raise ShellsplineError(f"align: curves must have the same components, got (d, m) = "
                               f"{(c0.d, c0.m)} and {(c1.d, c1.m)}")
    for name, c in (("curve0", c0), ("curve1", c1)):
        dt = np.diff(c.t)
        if np.ptp(dt) > 1e-6 * dt.mean():
            raise ShellsplineError(f"align: {name} must have uniform sample times (resample it "
                                   "with reparametrize first)")
    t0, t1 = c0.t, c1.t
    N0, N1 = t0.size, t1.size
    feats = _canonical_features(features, lam, symmetric, bounds, t0, t1, N0, N1)
    if window is not None and not window > 0:
        raise ShellsplineError(f"align: window must be > 0 (a fraction of the duration) or "
                               f"None, got {window!r}")
    steps = neighborhood(neighborhood_size)
    _iteration_limit(max_iter, 2)  # checked before any DP
    q0 = srv(c0.with_times(normalized_times(t0)))
    q1 = srv(c1.with_times(normalized_times(t1)))
    T1 = t1[-1] - t1[0]
    if not closed:
        r = _align_normalised(q0, q1, feats, steps, window, refine, max_iter, tol)
        r.phi = t1[0] + r.phi * T1
        r.t = t0.copy()
        r.shift = float(t1[0])
        return r
    # every candidate start by DP, the best one refined
    best = None
    for s in _start_candidates(q0, q1, int(n_starts)):
        fs = feats
        if feats is not None:
            fs = _Features(feats.a, np.mod(feats.b - s / (N1 - 1), 1.0), feats.lam,
                           feats.symmetric, feats.bound)
        try:
            E_dp, _ = _dp(q0, np.roll(q1, -s, axis=0), steps, window, fs)
        except ShellsplineError:
            continue
        if best is None or E_dp < best[0]:
            best = (E_dp, s, fs)
    if best is None:
        raise ShellsplineError("align: no admissible warp for any start point: the feature "
                               "bounds, the window and the slope limits cannot all be met")
    _, s, fs = best
    r = _align_normalised(q0, np.roll(q1, -s, axis=0), fs, steps, window, refine, max_iter,
                          tol)
    r.shift = float(t1[0] + s * T1 / (N1 - 1))
    r.phi = r.shift + r.phi * T1
    r.t = t0.copy()
    return r


def _start_candidates(q0, q1, k):
    """Cyclic shifts ``s`` of ``q1`` (in intervals) with the largest correlation
    ``sum_n <q0_n, q1_{n+s}>`` (``q1`` resampled to ``q0``'s intervals by nearest index)."""
    n0, n1 = q0.shape[0], q1.shape[0]
    idx = np.minimum((np.arange(n0) * n1) // n0, n1 - 1)
    qr = q1[idx]
    corr = np.fft.irfft(np.sum(np.conj(np.fft.rfft(q0, axis=0)) * np.fft.rfft(qr, axis=0),
                               axis=1), n=n0)
    order = np.argsort(-corr)[:max(1, k)]
    return sorted({int(round(s * n1 / n0)) % n1 for s in order})


def shape_distance(curve0, curve1, **options) -> float:
    """Symmetric elastic shape distance ``inf_phi |q0 - sqrt(phi') q1 o phi|`` (seed 000 eq.
    10), estimated both ways.

    Both :func:`align` (curve 1 onto curve 0) and the reverse give upper bounds of the
    infimum (a discrete optimum); the smaller one is returned, which is symmetric in the two
    curves. ``options`` go to :func:`align` (without feature points: this is the distance of
    the unparametrised curves).

    Returns
    -------
    float
    """
    if "features" in options:
        raise ShellsplineError("shape_distance: feature points do not define a distance; use "
                               "align")
    r01 = align(curve0, curve1, **options)
    r10 = align(curve1, curve0, **options)
    return float(min(r01.distance, r10.distance))


def project_closed(Q, t=None, *, tol=1e-12, max_iter=50) -> np.ndarray:
    """Project the SRV of an open curve in ``R^m`` onto the SRVs of closed curves (seed 003
    Theorem 2): the nearest ``q`` (Newton along the normal basis ``U_i``) with
    ``int |q| q dt = 0``.

    Parameters
    ----------
    Q : (N-1, m) array_like
        Piecewise constant SRV.
    t : (N,) array_like, optional
        Sample times (default ``linspace(0, 1, N)``).
    tol : float
        Stop when ``|int |q| q| <= tol * int |q|^2`` (the closure gap relative to the length).
    max_iter : int

    Returns
    -------
    (N-1, m) ndarray

    Raises
    ------
    ShellsplineError
        When the iteration does not close the curve in ``max_iter`` steps.

    Notes
    -----
    The constraint ``G(q) = int |q| q`` has the derivative
    ``U_i(q) = (q_i q + |q|^2 e_i) / |q|`` (seed 003 eq. 11); each step solves
    ``G(q) - sum_j beta_j <U_i, U_j> = 0`` and sets ``q <- q - sum_j beta_j U_j``.
    """
    Q = np.array(Q, dtype=np.float64)
    if Q.ndim != 2:
        raise ShellsplineError(f"project_closed: Q must be (N-1, m), got {Q.shape}")
    n, m = Q.shape
    t = np.linspace(0, 1, n + 1) if t is None else np.asarray(t, dtype=np.float64)
    if t.shape != (n + 1,):
        raise ShellsplineError(f"project_closed: t must have shape ({n + 1},), got {t.shape}")
    dt = np.diff(t)
    length = float(np.sum(dt * np.einsum("ij,ij->i", Q, Q)))
    for _ in range(max_iter):
        nq = np.sqrt(np.einsum("ij,ij->i", Q, Q))
        Gv = (dt * nq) @ Q
        if np.linalg.norm(Gv) <= tol * max(length, tolerances.zero):
            return Q
        safe = np.where(nq > 0, nq, 1.0)
        # U[k, i, :] = (q_i q + |q|^2 e_i) / |q| on interval k
        U = (Q[:, :, None] * Q[:, None, :] + (nq ** 2)[:, None, None] * np.eye(m)) \
            / safe[:, None, None]
        M = np.einsum("k,kia,kja->ij", dt, U, U)
        beta = np.linalg.solve(M, Gv)
        Q = Q - np.einsum("j,kja->ka", beta, U)
    raise ShellsplineError(f"project_closed: the curve did not close in {max_iter} steps "
                           f"(gap {np.linalg.norm(Gv):.2g})")


def dtw(x0, x1, *, window=None) -> tuple[float, np.ndarray]:
    """Dynamic time warping of two sampled curves (a baseline for :func:`align`).

    Parameters
    ----------
    x0 : (N0, D) array_like
    x1 : (N1, D) array_like
    window : float, optional
        Sakoe-Chiba band ``|i/N0 - j/N1| <= window``.

    Returns
    -------
    cost : float
        Sum of Euclidean distances along the optimal path (steps (1,0), (0,1), (1,1)).
    path : (K,2) int64 ndarray
    """
    x0 = np.asarray(x0, dtype=np.float64)
    x1 = np.asarray(x1, dtype=np.float64)
    if x0.ndim == 1:
        x0 = x0[:, None]
    if x1.ndim == 1:
        x1 = x1[:, None]
    N0, N1 = x0.shape[0], x1.shape[0]
    d2 = (np.einsum("ij,ij->i", x0, x0)[:, None] + np.einsum("ij,ij->i", x1, x1)[None, :]
          - 2 * x0 @ x1.T)
    Dm = np.sqrt(np.maximum(d2, 0))
    if window is not None:
        i = np.arange(N0)[:, None] / max(N0 - 1, 1)
        j = np.arange(N1)[None, :] / max(N1 - 1, 1)
        Dm[np.abs(i - j) > window] = _FAR
    H = np.full((N0, N1), np.inf)
    H[0] = np.cumsum(Dm[0])
    back = np.zeros((N0, N1), dtype=np.int8)
    for i in range(1, N0):
        diag = np.concatenate([[np.inf], H[i - 1, :-1]])
        up = H[i - 1]
        best = np.minimum(diag, up)
        src = np.where(diag <= up, 0, 1)
        # left moves within the row: H[i, j] = min(best[j], H[i, j-1]) + D[i, j], a running
        # minimum of (best - cumsum D) shifted by cumsum D
        cs = np.cumsum(Dm[i])
        v = best - np.concatenate([[0.0], cs[:-1]])
        run = np.minimum.accumulate(v)
        H[i] = run + cs
        back[i] = np.where(v <= run, src, 2)
    path = [(N0 - 1, N1 - 1)]
    i, j = N0 - 1, N1 - 1
    while i > 0 or j > 0:
        k = back[i, j] if i > 0 else 2
        i, j = (i - 1, j - 1) if k == 0 else (i - 1, j) if k == 1 else (i, j - 1)
        path.append((i, j))
    cost = float(H[-1, -1])
    return (cost if cost < _FAR else np.inf), np.array(path[::-1], dtype=np.int64)

"""Time-discrete LΘA splines, solved for all descriptors at once.

Every column of a descriptor matrix ``Z (K+1,d)`` (an edge length, a dihedral angle or a
triangle area along the ``K+1`` frames) is an independent quadratic minimisation: the
time-discrete spline energy of Heeren et al. 2016 (eqs. 7 and 11) with the keyframe values as
hard constraints. The normal equations are small pentadiagonal systems, one per column.

* With a constant reference (``weights=None``, or weights constant in time) every column has
  the same matrix: it is factored once and the spline is one matrix product
  ``Z = P @ Z_key`` with an interpolation matrix ``P (K+1,J)``.
* With weights that vary in time each column has its own matrix. They are factored by a
  banded ``L D Lᵀ`` elimination that loops over the (few) frames and is vectorised over the
  (many) descriptor columns.

:class:`LTASpline` is the precompute object (factor once, :meth:`LTASpline.solve` many
times); :func:`lta_spline` is the one-shot wrapper. ``spline='continuous'`` replaces the
discrete spline by the C² cubic spline in continuous time that it approximates
(:func:`continuous_spline_matrix`; with weights that vary in time, the continuous limit of the
weighted energy: a banded system in the frames' values and fluxes ``w z'``, vectorised over the
columns like the discrete one). :func:`lta_energy_per_frame` and
:func:`spline_energy` evaluate the energy of a given descriptor path.
"""
from __future__ import annotations

import warnings

import numpy as np
import scipy.sparse

from ..errors import ShellsplineError
from ..timeline import canonical_bc, checked_frames, checked_K

__all__ = ["LTASpline", "lta_spline", "lta_energy_per_frame", "spline_energy",
           "continuous_spline_matrix", "canonical_spline", "SPLINES"]

#: Time splines of the descriptors: the paper's time-discrete spline, or the C² cubic spline
#: in continuous time that it approximates (see :func:`continuous_spline_matrix`). This
#: module's functions default to the paper's spline; :func:`shellspline.interpolate` defaults
#: to the continuous one (:data:`shellspline.pipeline.options.DEFAULT_SPLINE`: no velocity
#: kink at the keyframes).
SPLINES = ("discrete", "continuous")

#: Weights below this fraction of their column's maximum are raised to it.
_WEIGHT_FLOOR = 1e-12
#: A pivot of the banded L D Lᵀ below this fraction of its diagonal entry marks the column's
#: matrix as singular to working precision (it then falls back to the constant reference).
_PIVOT_FLOOR = 1e-15
#: Number of float64 entries of one chunk's band matrix ``(p+1, n, chunk)``; bounds the
#: working memory of the batched path.
CHUNK_ELEMS = 1 << 20

# The nine ordered slot pairs (x, y) of a three-point residual r = g0 z_{k-1} + g1 z_k + g2 z_{k+1},
# and which of the six distinct products cw g_x g_y each one is (see ``_term_values``).
_PAIRS = tuple((x, y) for x in range(3) for y in range(3))
_VALUE_TYPE = np.array([[0, 3, 5], [3, 1, 4], [5, 4, 2]])


# --------------------------------------------------------------------------------------
# Validation and canonicalisation
# --------------------------------------------------------------------------------------
def _checked_weights(weights, K: int):
    """Validate ``weights`` and return ``(W, d)``.

    ``W`` is ``None`` (constant reference), or a float64 array of shape ``(K+1, 1)`` (the
    same weights for all columns) or ``(K+1, d)``; ``d`` is the number of columns the weights
    fix, or ``None`` when they fit any ``d``. Weights of shape ``(d,)`` are constant in time
    and give the same spline as ``None`` (returned as ``W=None`` with ``d`` set).
    """
    if weights is None:
        return None, None
    try:
        W = np.asarray(weights, dtype=np.float64)
    except (TypeError, ValueError):
        raise ShellsplineError(f"`weights` must be a float array, got {type(weights).__name__}") from None
    if W.ndim == 1:
        return None, int(W.shape[0])
    if W.ndim != 2 or W.shape[0] != K + 1:
        raise ShellsplineError(
            f"`weights` must have shape (K+1, d) = ({K + 1}, d), (K+1, 1) or (d,), got {W.shape}"
        )
    return W, (int(W.shape[1]) if W.shape[1] != 1 else None)


def _sanitized_weights(W: np.ndarray) -> np.ndarray:
    """Return positive finite weights: bad entries -> floor, all-bad columns -> ones.

    Entries that are not finite and positive count as zero; every entry is raised to
    ``_WEIGHT_FLOOR`` times its column's maximum; a column without any positive finite
    weight becomes all ones.
    """
    colmax = W.max(axis=0)
    if np.all(np.isfinite(colmax)) and np.all(W.min(axis=0) >= _WEIGHT_FLOOR * colmax) \
            and np.all(colmax > 0):
        return W  # already sane (the usual case): no copy
    W = np.where(np.isfinite(W) & (W > 0), W, 0.0)
    colmax = W.max(axis=0)
    dead = colmax <= 0
    if np.any(dead):
        W[:, dead] = 1.0
        colmax = np.where(dead, 1.0, colmax)
    return np.maximum(W, _WEIGHT_FLOOR * colmax)


def _checked_Z(Z, name: str) -> np.ndarray:
    try:
        A = np.asarray(Z, dtype=np.float64)
    except (TypeError, ValueError):
        raise ShellsplineError(f"`{name}` must be a float array, got {type(Z).__name__}") from None
    if A.ndim not in (1, 2):
        raise ShellsplineError(f"`{name}` must have shape (n,) or (n, d), got {A.shape}")
    if not np.all(np.isfinite(A)):
        bad = np.argwhere(~np.isfinite(A))[0].tolist()
        raise ShellsplineError(f"`{name}` must be finite, got a non-finite value at index {bad}")
    return A


# --------------------------------------------------------------------------------------
# Structure of the normal equations (independent of the values)
# --------------------------------------------------------------------------------------
class _Structure:
    """Index tables of the energy terms, the unknowns and their band ordering.

    Nodes are the frames that carry a value: ``0..K`` (natural, hermite) or ``0..K-1``
    (periodic, frame ``K`` is frame ``0``). Term ``t`` is the residual
    ``r_t = z_k - a z_{k-1} - b z_{k+1}`` with node triple ``nodes3[t] = (k-1, k, k+1)``
    (cyclic for periodic); its weight rows are ``(k-1, k)``. The free nodes are ordered for a
    small bandwidth: in time order (bandwidth 2) or, for periodic, folded
    ``0, K-1, 1, K-2, ...`` (bandwidth <= 4).
    """

    def __init__(self, frames: np.ndarray, K: int, bc: str):
        self.K, self.bc, self.frames = K, bc, frames
        if bc == "periodic":
            n_nodes = K
            k = np.arange(K)
            nodes3 = np.stack([(k - 1) % K, k, (k + 1) % K], axis=1)
            fold = np.zeros(K, dtype=np.int64)
            lo = np.arange((K + 1) // 2)
            hi = K - 1 - np.arange(K // 2)
            fold[0::2], fold[1::2] = lo, hi
            order = fold
        else:
            n_nodes = K + 1
            k = np.arange(1, K)
            nodes3 = np.stack([k - 1, k, k + 1], axis=1).reshape(-1, 3)
            order = np.arange(n_nodes)
        self.n_nodes = n_nodes
        self.nodes3 = nodes3.astype(np.int64)
        self.T = self.nodes3.shape[0]

        key_of = np.full(n_nodes, -1, dtype=np.int64)
        key_of[frames] = np.arange(frames.shape[0])
        self.key_of = key_of
        free_in_order = order[key_of[order] < 0]
        self.free_nodes = free_in_order  # node of each unknown position
        self.n = int(free_in_order.shape[0])
        # every unknown is a frame value (see _HermiteStructure, whose unknowns are not)
        self.z_pos, self.z_nodes = np.arange(self.n), free_in_order
        pos_of = np.full(n_nodes, -1, dtype=np.int64)
        pos_of[free_in_order] = np.arange(self.n)
        self.pos_of = pos_of

        # Every ordered slot pair (x, y) of every term contributes ``cw g_x g_y`` (one of six
        # value types, see ``_term_values``) either to the band (both slots free, taken once
        # as the lower entry) or to a coupling of an unknown to a keyframe (y fixed).
        pos3 = pos_of[self.nodes3]
        key3 = key_of[self.nodes3]
        both = [(pos3[:, x] >= 0) & (pos3[:, y] >= 0) & (pos3[:, x] >= pos3[:, y])
                for x, y in _PAIRS]
        self.p = p = max([int((pos3[b, x] - pos3[b, y]).max()) for (x, y), b in zip(_PAIRS, both)
                          if b.any()], default=0)
        n, T = self.n, self.T
        rows, cols = [], []
        q_rows: dict[tuple[int, int], int] = {}
        for (x, y), b in zip(_PAIRS, both):
            t = np.flatnonzero(b)
            rows.append((pos3[t, x] - pos3[t, y]) * n + pos3[t, y])
            cols.append(_VALUE_TYPE[x, y] * T + t)
            t = np.flatnonzero((pos3[:, x] >= 0) & (key3[:, y] >= 0))
            q = [q_rows.setdefault((int(pos3[i, x]), int(key3[i, y])), len(q_rows)) for i in t]
            rows.append((p + 1) * n + np.array(q, dtype=np.int64))
            cols.append(_VALUE_TYPE[x, y] * T + t)
        rows, cols = np.concatenate(rows), np.concatenate(cols)
        # Coupling q of unknown ``cq_pos[q]`` to keyframe ``cq_key[q]``: rhs -= C_q Z_key[key].
        keys = sorted(q_rows, key=q_rows.get)
        self.cq_pos = np.array([r[0] for r in keys], dtype=np.int64)
        self.cq_key = np.array([r[1] for r in keys], dtype=np.int64)
        # Sparse 0/1 assembly operator: [S.ravel(); C] = M @ values (duplicates add up).
        self.assembly = scipy.sparse.csr_array(
            (np.ones(rows.shape[0]), (rows, cols)),
            shape=((p + 1) * n + len(keys), 6 * T),
        )

    def values(self, W: np.ndarray) -> np.ndarray:
        return _term_values(self, W)


def _band_assembly(pos_t: np.ndarray, key_t: np.ndarray, types: np.ndarray, n: int):
    """The band layout of ``Σ_t x_tᵀ H_t x_t`` over local slot vectors ``x_t``.

    ``pos_t (T,s)``: unknown position of each local slot (-1: a keyframe value), ``key_t
    (T,s)``: its keyframe index (-1: unknown), ``types (s,s)``: which of the six value types
    ``H_t[x, y]`` is. Returns ``(p, assembly, cq_pos, cq_key)`` as in :class:`_Structure`.
    """
    T, ns = pos_t.shape
    pairs = [(x, y) for x in range(ns) for y in range(ns)]
    both = [(pos_t[:, x] >= 0) & (pos_t[:, y] >= 0) & (pos_t[:, x] >= pos_t[:, y])
            for x, y in pairs]
    p = max([int((pos_t[b, x] - pos_t[b, y]).max()) for (x, y), b in zip(pairs, both)
             if b.any()], default=0)
    rows, cols = [], []
    q_rows: dict[tuple[int, int], int] = {}
    for (x, y), b in zip(pairs, both):
        t = np.flatnonzero(b)
        rows.append((pos_t[t, x] - pos_t[t, y]) * n + pos_t[t, y])
        cols.append(types[x, y] * T + t)
        t = np.flatnonzero((pos_t[:, x] >= 0) & (key_t[:, y] >= 0))
        q = [q_rows.setdefault((int(pos_t[i, x]), int(key_t[i, y])), len(q_rows)) for i in t]
        rows.append((p + 1) * n + np.array(q, dtype=np.int64))
        cols.append(types[x, y] * T + t)
    rows, cols = np.concatenate(rows), np.concatenate(cols)
    keys = sorted(q_rows, key=q_rows.get)
    assembly = scipy.sparse.csr_array((np.ones(rows.shape[0]), (rows, cols)),
                                      shape=((p + 1) * n + len(keys), 6 * T))
    return (p, assembly, np.array([r[0] for r in keys], dtype=np.int64),
            np.array([r[1] for r in keys], dtype=np.int64))


class _HermiteStructure:
    """The continuous-time spline with weights that vary in time, as a banded system.

    The limit of the discrete energy as the time step goes to 0, with ``w_k`` the weight of
    the unit segment ``[k, k+1]`` (as the discrete energy reads it), is ``Σ_k w_k ∫_k^{k+1}
    z''² dt`` over curves whose flux ``w z'`` is continuous: its minimiser is a cubic on every
    segment. The unknowns are each frame's value ``z_k`` (unless a keyframe) and flux ``u_k``;
    on segment ``[a, b]`` with ``Δ = z_b - z_a`` and end slopes ``u_a/w``, ``u_b/w`` the
    cubic's energy is ``12 w Δ² - 12 (u_a + u_b) Δ + (4/w)(u_a² + u_a u_b + u_b²)``. Nodes
    are ordered as in :class:`_Structure`, each node's ``z`` before its ``u``.
    """

    # local slots (z_a, u_a, z_b, u_b); value types 12w, -12w, 6, -6, 4/w, 2/w
    _TYPES = np.array([[0, 2, 1, 2], [2, 4, 3, 5], [1, 3, 0, 3], [2, 5, 3, 4]])

    def __init__(self, frames: np.ndarray, K: int, bc: str):
        base = _Structure(frames, K, bc)  # node order and keyframe lookup
        self.K, self.bc, self.frames = K, bc, frames
        n_nodes = base.n_nodes
        if bc == "periodic":  # the folded order of _Structure, keyframes included
            fold = np.zeros(K, dtype=np.int64)
            fold[0::2], fold[1::2] = np.arange((K + 1) // 2), K - 1 - np.arange(K // 2)
            order = fold
        else:
            order = np.arange(n_nodes)
        is_free = base.key_of[order] < 0
        n_per = 1 + is_free  # unknowns per node in that order
        start = np.concatenate([[0], np.cumsum(n_per)[:-1]])
        pos_z = np.full(n_nodes, -1, dtype=np.int64)
        pos_u = np.empty(n_nodes, dtype=np.int64)
        pos_z[order[is_free]] = start[is_free]
        pos_u[order] = start + is_free
        self.n = int(n_per.sum())
        t = np.arange(K)
        a, b = t, (t + 1) % n_nodes
        self.seg = a  # the weight row of each segment
        pos_t = np.stack([pos_z[a], pos_u[a], pos_z[b], pos_u[b]], axis=1)
        minus = np.full(K, -1, dtype=np.int64)
        key_t = np.stack([base.key_of[a], minus, base.key_of[b], minus], axis=1)
        self.T = K
        self.p, self.assembly, self.cq_pos, self.cq_key = _band_assembly(
            pos_t, key_t, self._TYPES, self.n)
        self.z_nodes = np.flatnonzero(pos_z >= 0)
        self.z_pos = pos_z[self.z_nodes]

    def values(self, W: np.ndarray) -> np.ndarray:
        w = W[self.seg]
        V = np.empty((6, self.T, W.shape[1]))
        np.multiply(w, 12.0, out=V[0])
        np.negative(V[0], out=V[1])
        V[2], V[3] = 6.0, -6.0
        np.divide(4.0, w, out=V[4])
        np.multiply(V[4], 0.5, out=V[5])
        return V


def _term_values(st: _Structure, W: np.ndarray) -> np.ndarray:
    """Return the six products ``cw g_x g_y`` of every term, ``(6,T,c)``, for ``W (K+1,c)``.

    ``r_t = g0 z_{k-1} + g1 z_k + g2 z_{k+1}`` with ``g = (-a, 1, -b)``,
    ``a = w_{k-1}/(w_{k-1}+w_k)``, ``b = w_k/(w_{k-1}+w_k)``, and term weight ``cw = w_k``.
    The value types are ``cw a², cw, cw b², -cw a, -cw b, cw a b`` (slot pairs 00, 11, 22,
    01, 12, 02).
    """
    if st.bc == "periodic":
        wm, wk = W[st.nodes3[:, 0]], W[st.nodes3[:, 1]]
    else:
        wm, wk = W[: st.T], W[1 : st.T + 1]
    V = np.zeros((6, st.T, W.shape[1]))
    a, b = V[3], V[4]
    np.add(wm, wk, out=V[1])                    # w_{k-1} + w_k (scratch)
    np.divide(wm, V[1], out=a)                  # a
    np.divide(wk, V[1], out=b)                  # b
    np.multiply(a, b, out=V[5])
    V[5] *= wk                                  # cw a b
    np.multiply(a, a, out=V[0])
    V[0] *= wk                                  # cw a²
    V[1] = wk                                   # cw
    np.multiply(b, b, out=V[2])
    V[2] *= wk                                  # cw b²
    a *= wk
    np.negative(a, out=a)                       # -cw a
    b *= wk
    np.negative(b, out=b)                       # -cw b
    return V


def _assembled(st: _Structure, W: np.ndarray):
    """Assemble the free-free band ``S (p+1,n,c)`` and couplings ``C (Q,c)`` for ``W (K+1,c)``.

    ``S[m, j] = A[j+m, j]`` (lower band, the layout of ``scipy.linalg.solveh_banded``) of the
    normal matrix ``A = Σ_t cw_t g_t g_tᵀ`` restricted to the unknowns; the right-hand side of
    the normal equations is ``rhs[cq_pos[q]] = -Σ_q C[q] Z_key[cq_key[q]]``.
    """
    c = W.shape[1]
    R = st.assembly @ st.values(W).reshape(6 * st.T, c)
    nb = (st.p + 1) * st.n
    return R[:nb].reshape(st.p + 1, st.n, c), R[nb:]


def _ldl_banded_inplace(S: np.ndarray) -> np.ndarray:
    """Factor ``A = L D Lᵀ`` in place for a batch of banded SPD matrices.

    ``S (p+1,n,c)`` holds ``S[m, j] = A[j+m, j]`` per column ``c``; on return ``S[0]`` is
    ``D`` and ``S[m, j] = L[j+m, j]``. The loop runs over the ``n`` rows and the band; every
    operation is a vector operation over the ``c`` columns. Returns the ``(c,)`` mask of
    columns whose matrix is singular to working precision (a pivot below
    ``_PIVOT_FLOOR`` times its diagonal entry); their factors are meaningless.
    """
    p, n = S.shape[0] - 1, S.shape[1]
    singular = np.zeros(S.shape[2:], dtype=bool)
    U = np.zeros((p + 1,) + S.shape[2:])  # U[i-k] = L[i,k] D[k] of the current row i
    tmp = np.zeros(S.shape[2:])
    for i in range(n):
        j0 = max(0, i - p)
        diag = S[0, i].copy()
        for j in range(j0, i):
            v = S[i - j, j].copy()  # A[i, j]
            for k in range(j0, j):
                np.multiply(U[i - k], S[j - k, k], out=tmp)
                v -= tmp
            U[i - j] = v
            np.divide(v, S[0, j], out=S[i - j, j])  # L[i, j]
            np.multiply(v, S[i - j, j], out=tmp)
            diag -= tmp
        ok = diag > _PIVOT_FLOOR * np.abs(S[0, i])  # False for NaN as well
        singular |= ~ok
        S[0, i] = np.where(ok, diag, 1.0)
    return singular


def _ldl_solved(S: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """Solve ``L D Lᵀ x = rhs`` in place for factors from :func:`_ldl_banded_inplace`."""
    p, n = S.shape[0] - 1, S.shape[1]
    y = rhs
    for i in range(1, n):
        for m in range(1, min(p, i) + 1):
            y[i] -= S[m, i - m] * y[i - m]
    y /= S[0]
    for i in range(n - 2, -1, -1):
        for m in range(1, min(p, n - 1 - i) + 1):
            y[i] -= S[m, i] * y[i + m]
    return y


def _coupled_rhs(st: _Structure, C: np.ndarray, Zk: np.ndarray) -> np.ndarray:
    """Right-hand side ``(n,c)`` of the normal equations from couplings ``C (Q,c)``."""
    rhs = np.zeros((st.n, Zk.shape[1]))
    for q in range(st.cq_pos.shape[0]):
        rhs[st.cq_pos[q]] -= C[q] * Zk[st.cq_key[q]]
    return rhs


def _warn_fallback(which: str, stacklevel: int = 4) -> None:
    warnings.warn(
        f"lta_spline: the weighted normal equations of {which} are numerically singular "
        "(extreme or zero `weights`); the constant-reference spline is used there instead",
        RuntimeWarning,
        stacklevel=stacklevel,
    )


def _chunks(st: _Structure, d: int):
    size = max(1, CHUNK_ELEMS // max(1, (st.p + 1) * max(st.n, 1)))
    return [(a, min(d, a + size)) for a in range(0, d, size)]


# --------------------------------------------------------------------------------------
# The continuous-time spline
# --------------------------------------------------------------------------------------
def canonical_spline(spline) -> str:
    """Return ``spline`` as one of :data:`SPLINES` (case and surrounding blanks ignored).

    Raises
    ------
    ValueError
        (a :class:`~shellspline.errors.ShellsplineError`) naming the choices and what was got.
    """
    key = spline.strip().lower() if isinstance(spline, str) else None
    if key not in SPLINES:
        raise ShellsplineError(f"`spline` must be one of {', '.join(map(repr, SPLINES))} "
                               f"(case-insensitive), got {spline!r}")
    return key


def _second_derivative_map(x: np.ndarray, periodic: bool) -> np.ndarray:
    """``G (J,J)`` with ``M = G @ y``: the knot second derivatives of the C² cubic spline
    through values ``y`` at the knots ``x`` (natural: ``M`` = 0 at both ends; periodic: ``x``
    holds the ``J`` knots of one period and ``x[J]``, the first knot one period later)."""
    J = x.shape[0] - (1 if periodic else 0)
    h = np.diff(x)
    A = np.zeros((J, J))
    R = np.zeros((J, J))
    # equation i: h_{i-1} M_{i-1} + 2 (h_{i-1} + h_i) M_i + h_i M_{i+1}
    #             = 6 ((y_{i+1} - y_i) / h_i - (y_i - y_{i-1}) / h_{i-1})
    i = np.arange(J) if periodic else np.arange(1, J - 1)
    hm, hp = h[i - 1], h[i % h.shape[0]]
    im, ip = (i - 1) % J, (i + 1) % J
    for M, rows, cols, vals in ((A, i, im, hm), (A, i, i, 2.0 * (hm + hp)), (A, i, ip, hp),
                                (R, i, ip, 6.0 / hp), (R, i, i, -6.0 / hp - 6.0 / hm),
                                (R, i, im, 6.0 / hm)):
        np.add.at(M, (rows, cols), vals)  # adds up where im == ip (periodic, J = 2)
    if not periodic:
        A[0, 0] = A[J - 1, J - 1] = 1.0  # natural ends: M_0 = M_{J-1} = 0 (rows of R are 0)
    return np.linalg.solve(A, R)


def continuous_spline_matrix(frames, K, bc="natural") -> np.ndarray:
    """Return ``P (K+1,J)``: the C² cubic spline through keyframe values, sampled at the frames.

    ``P @ Z_key`` is, column by column, the cubic spline ``s(t)`` with ``s(frames[j]) =
    Z_key[j]`` evaluated at ``t = 0..K``: the continuous-time spline that the time-discrete
    LΘA spline (:func:`lta_spline` with a constant reference) approximates to ``O(1/K²)``,
    without its velocity kink at the keyframes.

    Parameters
    ----------
    frames : (J,) int array_like
        Keyframe frames, validated as in :class:`LTASpline`.
    K : int
        Index of the last frame (``K >= 1``).
    bc : {'natural', 'periodic', 'hermite'}, optional
        ``'natural'``: zero second derivative at the first and last keyframe, and frames
        after the last keyframe continue its tangent line (as the discrete spline's do).
        ``'periodic'``: period ``K`` (frame ``K`` is frame 0). ``'hermite'``: the natural
        spline through the keyframes at ``0, 1, …, K-1, K``; the poses at frames 1 and ``K-1``
        fix the end velocities, as in the discrete spline (whose hermite system is its
        natural one with those keyframes).

    Returns
    -------
    P : (K+1,J) float64 numpy array
        Rows at keyframes are exactly the unit vectors (keyframes exact); row ``K`` equals row
        0 for periodic.

    Raises
    ------
    ValueError
        (a :class:`~shellspline.errors.ShellsplineError`) on invalid ``frames``, ``K`` or ``bc``.

    Notes
    -----
    The knot second derivatives ``M`` solve the classic tridiagonal (cyclic for periodic)
    system ``h_{i-1} M_{i-1} + 2(h_{i-1}+h_i) M_i + h_i M_{i+1} = 6 (Δ_i - Δ_{i-1})`` with
    ``Δ_i = (y_{i+1}-y_i)/h_i``, solved once for ``y = I_J`` (``J`` is the number of
    keyframes, small); between knots ``s = a y_i + b y_{i+1} + ((a³-a) M_i + (b³-b) M_{i+1})
    h_i²/6`` with ``b = (t - x_i)/h_i = 1 - a``. The same spline as
    ``scipy.interpolate.CubicSpline(frames, Z_key, bc_type='natural' | 'periodic')`` inside
    the keyframe range (its oracle in the tests). Evaluated at every frame at once: no loop
    over frames or descriptors.

    Examples
    --------
    >>> P = continuous_spline_matrix([0, 2, 4], K=4)
    >>> (P @ [0.0, 1.0, 0.0]).round(4).tolist()
    [0.0, 0.6875, 1.0, 0.6875, 0.0]
    >>> (continuous_spline_matrix([0, 2], K=4, bc="periodic") @ [0.0, 1.0]).round(4).tolist()
    [0.0, 0.5, 1.0, 0.5, 0.0]
    """
    bc = canonical_bc(bc)
    K = checked_K(K)
    fr = checked_frames(frames, K, bc)
    J, periodic = fr.shape[0], bc == "periodic"
    x = np.append(fr, K).astype(np.float64) if periodic else fr.astype(np.float64)
    G = _second_derivative_map(x, periodic)  # (J, J)
    t = np.arange(K + 1, dtype=np.float64)
    n_int = x.shape[0] - 1
    i = np.clip(np.searchsorted(x, t, side="right") - 1, 0, n_int - 1)
    h = x[i + 1] - x[i]
    b = np.clip((t - x[i]) / h, 0.0, 1.0)  # frames after the last keyframe: see below
    a = 1.0 - b
    ip = (i + 1) % J
    Y = np.eye(J)
    P = a[:, None] * Y[i] + b[:, None] * Y[ip] \
        + (h * h / 6.0)[:, None] * (((a**3 - a)[:, None]) * G[i] + ((b**3 - b)[:, None]) * G[ip])
    if not periodic and K > fr[-1]:
        # beyond the last keyframe: its tangent line (M = 0 there, so this is still C²)
        last = fr[-1]
        hl = x[-1] - x[-2]
        slope = (Y[-1] - Y[-2]) / hl + hl * (G[-2] + 2.0 * G[-1]) / 6.0
        after = t > last
        P[after] = Y[-1] + (t[after] - last)[:, None] * slope
    P[fr] = Y
    if periodic:
        P[K] = P[0]
    return P


# --------------------------------------------------------------------------------------
# Public API
# --------------------------------------------------------------------------------------
class LTASpline:
    """Precomputed time-discrete LΘA spline: factor once, solve for many keyframe values.

    Parameters
    ----------
    frames : (J,) int array_like
        Strictly increasing frame indices of the keyframes, ``frames[0] == 0``,
        ``frames[-1] <= K`` (``< K`` for ``bc='periodic'``). Integer-valued floats are accepted.
    K : int
        Index of the last frame; the path has ``K+1`` frames ``0..K``. ``K >= 1``.
    bc : {'natural', 'periodic', 'hermite'}, optional
        Boundary condition (case-insensitive). ``'hermite'`` needs keyframes at frames
        ``0, 1, K-1, K`` (the end velocities are given by those poses, paper §8).
    weights : None or (K+1,d) or (K+1,1) or (d,) float array_like, optional
        Positive weights ``w_k`` of each descriptor at the reference mesh of frame ``k``.
        ``None`` (constant reference) and weights constant in time give the same spline.
        Entries that are not finite and positive count as zero and, like every tiny weight,
        are raised to ``1e-12`` times their column's maximum; an all-zero column uses unit
        weights. For ``bc='periodic'`` row ``K`` is not used (frame ``K`` is frame ``0``).
        Only ratios within a column matter: scaling a column's weights leaves its spline
        unchanged.
    spline : {'discrete', 'continuous'}, optional
        ``'discrete'`` (default here; :func:`shellspline.interpolate` defaults to
        ``'continuous'``): the paper's time-discrete spline. ``'continuous'``: the C²
        cubic spline in continuous time through the keyframe values
        (:func:`continuous_spline_matrix`), the limit of the discrete one as the time step
        goes to 0. With weights that vary in time, the limit of the weighted discrete energy
        (see :func:`lta_spline`, Notes): a cubic on every frame interval with the flux
        ``w z'`` and ``z''`` continuous, solved as a banded system in the values and fluxes
        of the frames (half bandwidth <= 3, 5 for periodic).

    Attributes
    ----------
    frames : (J,) int64 numpy array
    K : int
    bc : str
        The canonical boundary condition.
    n_free : int
        Number of unknown frames per descriptor.
    bandwidth : int
        Half bandwidth of the (reordered) normal matrix: at most 2 (4 for periodic); for
        ``spline='continuous'`` with weights that vary in time, at most 3 (5 for periodic).
    batched : bool
        ``True`` when every column has its own matrix (weights vary in time and across
        columns); ``False`` when one factorization serves all columns.
    n_columns : int or None
        Number of descriptor columns fixed by ``weights`` (``None``: any).
    spline : str
        The canonical time spline.

    Raises
    ------
    ValueError
        (a :class:`~shellspline.errors.ShellsplineError`) on invalid ``frames``, ``K``,
        ``bc``, ``weights`` or ``spline``; the message names the argument and shows what was
        got.

    Warns
    -----
    RuntimeWarning
        When the weights make a column's normal matrix singular to working precision (a
        pivot below ``1e-15`` times its diagonal, e.g. weights that alternate between 1 and
        1e-8, or a result that overflows); that column falls back to the constant-reference
        spline. Never raised for weights whose ratios stay moderate.

    See Also
    --------
    lta_spline : one-shot wrapper.

    Notes
    -----
    The time-discrete elastic energy (paper eqs. 7 and 11) per descriptor column is

    .. math:: F = 4K^3 \\sum_k c_k (z_k - \\tilde z_k)^2, \\quad
              \\tilde z_k = \\frac{w_{k-1} z_{k-1} + w_k z_{k+1}}{w_{k-1} + w_k}, \\quad c_k = w_k,

    where ``z̃_k`` is the midpoint of the LΘA geodesic between ``z_{k-1}`` and ``z_{k+1}``
    (the minimiser of ``w_{k-1}(z-z_{k-1})² + w_k(z-z_{k+1})²``). The sum runs over
    ``k = 1..K-1`` (natural, hermite) or cyclically over ``k = 0..K-1`` (periodic, frames
    identified mod ``K``, paper §8). Hermite conditions fix the poses at frames 0, 1, K-1, K.
    Keyframe values are hard constraints. Writing ``r = G z`` for the residuals, the normal
    equations are ``(Gᵀ C G)_{ff} z_f = -(Gᵀ C G)_{fk} z_key`` on the free frames ``f``; the
    matrix is pentadiagonal. For a constant reference it is ``¼ DᵀD`` with ``D`` the
    second-difference operator; the rows of ``DᵀD`` for natural conditions are::

        [ 1 -2  1          ]
        [-2  5 -4  1       ]     (the paper prints 3 instead of 5 in row 2)
        [ 1 -4  6 -4  1    ]
        [    1 -4  6 -4  1 ] ...

    With a constant reference the discrete spline converges to the cubic spline
    (``scipy.interpolate.CubicSpline``) with the same boundary conditions as ``O(1/K²)``.
    For periodic conditions the unknowns are ordered ``0, K-1, 1, K-2, ...`` so that the
    cyclic matrix becomes banded (half bandwidth <= 4). Time-varying weights are factored by
    a banded ``L D Lᵀ`` vectorised over columns, in chunks of columns to bound memory; the
    factors take ``O(d · n_free · bandwidth)`` memory.

    Examples
    --------
    >>> import numpy as np
    >>> spl = LTASpline([0, 2, 4], K=4)
    >>> spl.solve(np.array([[0.0], [1.0], [0.0]])).ravel().round(4).tolist()
    [0.0, 0.6667, 1.0, 0.6667, 0.0]
    >>> spl.solve(np.array([[0.0], [2.0], [4.0]])).ravel().round(12).tolist()
    [0.0, 1.0, 2.0, 3.0, 4.0]
    """

    def __init__(self, frames, K, bc="natural", weights=None, spline="discrete"):
        self._setup(frames, K, bc, weights, spline)
        if self.batched:
            self._factors = [
                self._factored_chunk(a, b) for a, b in _chunks(self._st, self._W.shape[1])
            ]
        else:
            self._P = self._interpolation_matrix(self._W)

    def chunks(self, d: int) -> list:
        """Column ranges ``[(a, b), ...]`` in which ``d`` descriptor columns are factored and
        solved (each chunk's band matrix holds at most :data:`CHUNK_ELEMS` numbers)."""
        return list(_chunks(self._st, int(d)))

    # -- construction helpers ----------------------------------------------------------

    def _setup(self, frames, K, bc, weights, spline="discrete") -> None:
        self.spline = canonical_spline(spline)
        self.bc = canonical_bc(bc)
        self.K = checked_K(K)
        self.frames = checked_frames(frames, self.K, self.bc)
        W, self.n_columns = _checked_weights(weights, self.K)
        self._st = st = _Structure(self.frames, self.K, self.bc)
        self.n_free, self.bandwidth = st.n, st.p
        self.batched = False
        if W is not None:
            W = _sanitized_weights(W)
            used = W[: st.n_nodes]
            if np.all(used == used[:1]):  # constant in time: the constant reference
                W = None
            elif W.shape[1] > 1 and np.all(used == used[:, :1]):  # one column for all
                W = W[:, :1].copy()
            else:
                self.batched = W.shape[1] > 1
        self._W = W
        if self.spline == "continuous" and W is not None:  # weights that vary in time
            self._st = st = _HermiteStructure(self.frames, self.K, self.bc)
            self.n_free, self.bandwidth = int(st.z_nodes.shape[0]), st.p

    def _interpolation_matrix(self, W) -> np.ndarray:
        """``P (K+1,J)`` with ``Z = P @ Z_key`` for one matrix shared by all columns."""
        if self.spline == "continuous" and W is None:
            return continuous_spline_matrix(self.frames, self.K, self.bc)
        st, J = self._st, self.frames.shape[0]
        W1 = np.ones((self.K + 1, 1)) if W is None else W
        P = np.zeros((self.K + 1, J))
        if st.n:
            S, C = _assembled(st, W1)
            B = np.zeros((st.n, J))
            np.add.at(B, (st.cq_pos, st.cq_key), -C[:, 0])
            with np.errstate(all="ignore"):
                singular = _ldl_banded_inplace(S)[0]
                P[st.z_nodes] = _ldl_solved(S, B)[st.z_pos]
            if W is not None and (singular or not np.all(np.isfinite(P))):
                _warn_fallback("all descriptor columns (weights shared by all columns)")
                return self._interpolation_matrix(None)
        P[self.frames, np.arange(J)] = 1.0
        if self.bc == "periodic":
            P[self.K] = P[0]
        return P

    def _unit_interpolation_matrix(self) -> np.ndarray:
        if getattr(self, "_P_unit", None) is None:
            self._P_unit = self._interpolation_matrix(None)
        return self._P_unit

    def _with_fallback_columns(self, Z, Zk, singular, stacklevel):
        """Replace columns with singular matrices by the constant-reference spline."""
        bad = singular | ~np.all(np.isfinite(Z), axis=0)
        if np.any(bad):
            _warn_fallback(f"{int(bad.sum())} of {Z.shape[1]} descriptor column(s)", stacklevel)
            Z[:, bad] = self._unit_interpolation_matrix() @ Zk[:, bad]
        return Z

    def _factored_chunk(self, a: int, b: int):
        S, C = _assembled(self._st, self._W[:, a:b])
        with np.errstate(all="ignore"):
            singular = _ldl_banded_inplace(S)
        return a, b, S, C, singular

    def _checked_key_values(self, Z_key) -> tuple[np.ndarray, bool]:
        Zk = _checked_Z(Z_key, "Z_key")
        J = self.frames.shape[0]
        if Zk.shape[0] != J:
            raise ShellsplineError(
                f"`Z_key` must have one row per keyframe (len(frames) = {J}), got shape {Zk.shape}"
            )
        flat = Zk.ndim == 1
        Zk = Zk.reshape(J, -1)
        if self.n_columns is not None and Zk.shape[1] != self.n_columns:
            raise ShellsplineError(
                f"`Z_key` must have d = {self.n_columns} columns to match `weights`, "
                f"got shape {Zk.shape if not flat else (J,)}"
            )
        return Zk, flat

    # -- solving -------------------------------------------------------------------------
    def solve(self, Z_key) -> np.ndarray:
        """Return the spline through the keyframe values ``Z_key``.

        Parameters
        ----------
        Z_key : (J,d) or (J,) float array_like
            Finite descriptor values at the keyframes, one row per keyframe.

        Returns
        -------
        Z : (K+1,d) or (K+1,) float64 numpy array
            The spline; ``Z[frames] == Z_key`` exactly, and for periodic ``Z[K] == Z[0]``.

        Raises
        ------
        ValueError
            If ``Z_key`` has the wrong shape (or a ``d`` other than the weights') or is not
            finite.

        Warns
        -----
        RuntimeWarning
            For columns with numerically singular weighted matrices (see the class).
        """
        Zk, flat = self._checked_key_values(Z_key)
        if self.batched:
            Z = np.zeros((self.K + 1, Zk.shape[1]))
            st = self._st
            singular = np.zeros(Zk.shape[1], dtype=bool)
            with np.errstate(all="ignore"):
                for a, b, S, C, sing in self._factors:
                    Z[st.z_nodes, a:b] = _ldl_solved(S, _coupled_rhs(st, C, Zk[:, a:b]))[st.z_pos]
                    singular[a:b] = sing
            Z = self._with_fallback_columns(Z, Zk, singular, stacklevel=4)
        else:
            Z = self._P @ Zk
        return self._finished(Z, Zk, flat)

    def _finished(self, Z, Zk, flat):
        Z[self.frames] = Zk
        if self.bc == "periodic":
            Z[self.K] = Zk[0]
        return Z.ravel() if flat else Z

    def _solved_streaming(self, Z_key) -> np.ndarray:
        """Like :meth:`solve` for a batched spline built without stored factors."""
        Zk, flat = self._checked_key_values(Z_key)
        st = self._st
        Z = np.zeros((self.K + 1, Zk.shape[1]))
        singular = np.zeros(Zk.shape[1], dtype=bool)
        for a, b in _chunks(st, Zk.shape[1]):
            _, _, S, C, singular[a:b] = self._factored_chunk(a, b)
            with np.errstate(all="ignore"):
                Z[st.z_nodes, a:b] = _ldl_solved(S, _coupled_rhs(st, C, Zk[:, a:b]))[st.z_pos]
        return self._finished(self._with_fallback_columns(Z, Zk, singular, 5), Zk, flat)


def lta_spline(Z_key, frames, K, bc="natural", weights=None, spline="discrete") -> np.ndarray:
    """Return the time-discrete LΘA spline through keyframe descriptor values.

    Parameters
    ----------
    Z_key : (J,d) or (J,) float array_like
        Descriptor values at the ``J`` keyframes; each column is an independent scalar
        descriptor (an edge length, a dihedral angle or a triangle area).
    frames : (J,) int array_like
        Strictly increasing frame indices of the keyframes, ``frames[0] == 0``,
        ``frames[-1] <= K`` (``< K`` for periodic). Frames after the last keyframe are
        extrapolated (linearly for a constant reference).
    K : int
        Index of the last frame (``K >= 1``); the result has ``K+1`` rows.
    bc : {'natural', 'periodic', 'hermite'}, optional
        Boundary condition, case-insensitive. ``'periodic'`` identifies frame ``K`` with
        frame 0; ``'hermite'`` needs keyframes at frames ``0, 1, K-1, K``.
    weights : None or (K+1,d) or (K+1,1) or (d,) float array_like, optional
        Reference-mesh weights ``w_k`` per frame and descriptor; see :class:`LTASpline`.
    spline : {'discrete', 'continuous'}, optional
        The paper's time-discrete spline (default here; :func:`shellspline.interpolate`
        defaults to ``'continuous'``), or the C² cubic spline in continuous time
        through the keyframe values (:func:`continuous_spline_matrix`), or, with weights that
        vary in time, the continuous limit of the weighted discrete spline; see Notes.

    Returns
    -------
    Z : (K+1,d) or (K+1,) float64 numpy array
        The minimiser of the spline energy with ``Z[frames] == Z_key`` exactly (and
        ``Z[K] == Z[0]`` for periodic).

    Raises
    ------
    ValueError
        (a :class:`~shellspline.errors.ShellsplineError`) on any invalid argument; the
        message names the argument and shows what was got.

    Warns
    -----
    RuntimeWarning
        For columns whose weights make the normal matrix singular to working precision;
        they fall back to the constant-reference spline (see :class:`LTASpline`).

    See Also
    --------
    LTASpline : the precompute/solve split, to reuse the factorization.
    lta_energy_per_frame, spline_energy : the energy that is minimised.

    Notes
    -----
    Minimises, independently per column, ``F = 4K³ Σ_k w_k (z_k − z̃_k)²`` with the LΘA
    geodesic midpoint ``z̃_k = (w_{k−1} z_{k−1} + w_k z_{k+1}) / (w_{k−1} + w_k)`` (paper
    eqs. 7, 11; boundary conditions as in §8). With weights that vary in time and across
    columns the banded systems are factored in chunks of columns and discarded, so the
    working memory stays bounded; use :class:`LTASpline` to keep the factors.

    ``spline='continuous'`` minimises the limit of ``F`` as the time step goes to 0,
    ``∫ z''(t)² dt``, with the same keyframe constraints: the C² cubic spline. The discrete
    minimiser is a cubic on each keyframe gap too, but its velocity jumps at every interior
    keyframe by ``O(1/K)`` (the kink costs 0.1–3.5 % of the error against the true frames of
    a skinned animation, ``benchmarks/bench_real.py``, row ``cubic-discrete``). With weights
    that vary in time the residual is ``z_k - z̃_k = -(w_k z'_+ - w_{k-1} z'_-)/(w_{k-1} +
    w_k) / K + …``, with ``w_k`` the weight of the frame interval ``[k, k+1]``: a jump of the
    flux ``w z'`` costs ``O(K)``, so the limit is ``Σ_k w_k ∫_k^{k+1} z''² dt`` over curves
    with a continuous flux (``∫ ((w z')')²/w dt`` for smooth weights). Its minimiser is a
    cubic on every frame interval, with ``z``, ``w z'`` and ``z''`` continuous: where the
    weights jump (``reference='keyframe'`` between two keyframes' references) the velocity
    jumps in their ratio, as the discrete spline's does. The discrete spline on a grid ``m``
    times finer (each interval's weight repeated) converges to it as ``O(1/m)``.

    Examples
    --------
    >>> import numpy as np
    >>> Z = lta_spline(np.array([[0.0, 1.0], [1.0, 1.0], [0.0, 1.0]]), [0, 2, 4], K=4)
    >>> Z.shape
    (5, 2)
    >>> Z[:, 0].round(4).tolist(), Z[:, 1].round(12).tolist()
    ([0.0, 0.6667, 1.0, 0.6667, 0.0], [1.0, 1.0, 1.0, 1.0, 1.0])
    >>> Zp = lta_spline(np.array([0.0, 1.0]), [0, 2], K=4, bc="periodic")
    >>> Zp.round(4).tolist()
    [0.0, 0.5, 1.0, 0.5, 0.0]
    """
    spl = LTASpline.__new__(LTASpline)
    spl._setup(frames, K, bc, weights, spline)
    if spl.batched:
        return spl._solved_streaming(Z_key)
    spl._P = spl._interpolation_matrix(spl._W)
    return spl.solve(Z_key)


def _energy_terms(Z, bc, weights) -> tuple[np.ndarray, int]:
    bc = canonical_bc(bc)
    Z = _checked_Z(Z, "Z")
    if Z.shape[0] < 2:
        raise ShellsplineError(f"`Z` must have K+1 >= 2 rows, got shape {Z.shape}")
    Z2 = Z.reshape(Z.shape[0], -1)
    K = Z2.shape[0] - 1
    W, d = _checked_weights(weights, K)
    if d is not None and d != Z2.shape[1]:
        raise ShellsplineError(
            f"`weights` must match the {Z2.shape[1]} columns of `Z`, got shape {np.shape(weights)}"
        )
    if weights is None:
        W = np.ones((K + 1, 1))
    elif W is None:  # (d,): constant in time, scaled per column
        W = np.broadcast_to(_sanitized_weights(np.asarray(weights, float)[None, :]), (K + 1, d))
    else:
        W = _sanitized_weights(W)
    if bc == "periodic":
        k = np.arange(K)
        km, kp = (k - 1) % K, (k + 1) % K
    else:
        k = np.arange(1, K)
        km, kp = k - 1, k + 1
    # One frame at a time: vectorised over the descriptors, without (K+1, d) temporaries
    # (at 150k vertices d ≈ 1M, and the stacked form allocated several GB).
    out = np.zeros(K + 1)
    for i, a, b in zip(k.tolist(), km.tolist(), kp.tolist()):
        wa, wi = W[a], W[i]
        r = Z2[i] - (wa * Z2[a] + wi * Z2[b]) / (wa + wi)
        out[i] = np.sum(wi * r * r)
    return out, K


def lta_energy_per_frame(Z, bc="natural", weights=None) -> np.ndarray:
    """Return the per-frame terms ``c_k (z_k − z̃_k)²`` of the spline energy, summed over descriptors.

    Parameters
    ----------
    Z : (K+1,d) or (K+1,) float array_like
        A descriptor path (for periodic, row ``K`` is frame 0 again and is not used).
    bc : {'natural', 'periodic', 'hermite'}, optional
        Boundary condition (case-insensitive); it decides which terms exist.
    weights : None or (K+1,d) or (K+1,1) or (d,) float array_like, optional
        Reference-mesh weights as in :class:`LTASpline` (sanitised the same way); ``None``
        means unit weights, i.e. ``z̃_k = (z_{k−1} + z_{k+1})/2``.

    Returns
    -------
    E : (K+1,) float64 numpy array
        ``E[k] = Σ_descriptors w_k (z_k − z̃_k)²`` for ``k = 1..K−1`` (natural, hermite) or
        ``k = 0..K−1`` (periodic); zero where a term is not defined. Multiply the sum by
        ``4K³`` for the energy (see :func:`spline_energy`).

    Raises
    ------
    ValueError
        On a bad ``bc``, non-finite ``Z``, or ``weights`` of the wrong shape.

    Notes
    -----
    These are the summands of paper eq. 11 (the curves in Figs. 11 and 12), with the LΘA
    geodesic midpoint ``z̃_k = (w_{k−1} z_{k−1} + w_k z_{k+1}) / (w_{k−1} + w_k)``.

    Examples
    --------
    >>> import numpy as np
    >>> lta_energy_per_frame(np.array([0.0, 0.0, 1.0, 0.0, 0.0])).tolist()
    [0.0, 0.25, 1.0, 0.25, 0.0]
    """
    return _energy_terms(Z, bc, weights)[0]


def spline_energy(Z, bc="natural", weights=None) -> float:
    """Return the time-discrete spline energy ``F = 4K³ Σ_k c_k (z_k − z̃_k)²`` of a path.

    Parameters
    ----------
    Z : (K+1,d) or (K+1,) float array_like
        A descriptor path.
    bc : {'natural', 'periodic', 'hermite'}, optional
        Boundary condition (case-insensitive).
    weights : None or (K+1,d) or (K+1,1) or (d,) float array_like, optional
        Reference-mesh weights as in :class:`LTASpline`.

    Returns
    -------
    F : float
        ``4 K³`` times the sum of :func:`lta_energy_per_frame`.

    Raises
    ------
    ValueError
        As :func:`lta_energy_per_frame`.

    Notes
    -----
    Paper eqs. 7 and 11. For a constant reference and a smooth curve sampled at ``k/K`` it
    approximates ``∫₀¹ |z''(t)|² dt``.

    Examples
    --------
    >>> import numpy as np
    >>> t = np.linspace(0.0, 1.0, 101)
    >>> round(spline_energy(t**2), 6)  # ≈ ∫ 2² dt = 4; the sum skips k = 0 and K
    3.96
    """
    E, K = _energy_terms(Z, bc, weights)
    return float(4.0 * K**3 * E.sum())

"""Simultaneous decimation of all keyframe poses (paper §8, "Multiresolution optimization").

Every pose of a keyframe set shares one connectivity. :func:`decimate` removes vertices by
*halfedge collapses* ``u -> v`` (``u`` disappears, ``v`` keeps its position in every pose),
performed on all poses at once, so that

* the coarse poses share one coarse connectivity ``Decimation.F``;
* coarse vertices are a subset of the fine vertices and the coarse keyframes are exact
  restrictions ``Vs[:, kept]`` (no position optimisation, nothing to prolong at the kept
  vertices).

Collapses are prioritised by the *sum over poses* of Garland–Heckbert quadric errors
[GH97], as in [KMP07] and the paper: with ``Q_u^j`` the accumulated, area-weighted plane
quadric of vertex ``u`` in pose ``j``, the cost of ``u -> v`` is
``Σ_j v_jᵀ (Q_u^j + Q_v^j) v_j`` (the total quadric error of the merged vertex).

The collapses are not performed one by one from a priority queue (a Python loop per
collapse would take minutes on a 100k-vertex mesh). Instead every *round* evaluates all
candidate halfedges with numpy, keeps the valid cheapest ones and accepts a set of
collapses whose closed one-rings are pairwise disjoint (a greedy-by-cost independent set,
computed by Luby-style local-minimum sweeps on the vertex graph), so that the collapses of a
round commute and every validity check made before the round stays true after it.

:func:`decimate_replay` is the baseline the issue asks for (pose-0 simplification replayed
on the other poses with the optional ``fast-simplification`` package), and
:func:`hausdorff_fine_to_coarse` measures both.
"""
from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

from ..errors import ShellsplineError, tol
from .geometry import cross, dot, norms, normalized, vertex_face_incidence
from .pinned import pinned_mask
from .topology import Topology, topology

__all__ = ["Decimation", "decimate", "decimate_replay", "hausdorff_fine_to_coarse",
           "canonical_target"]


@dataclass(frozen=True)
class Decimation:
    """Result of :func:`decimate`: a coarse keyframe set embedded in the fine one.

    Attributes
    ----------
    kept : (nc,) int64 numpy array
        Fine indices of the coarse vertices, sorted increasingly. Coarse vertex ``c`` *is*
        fine vertex ``kept[c]``.
    F : (mc,3) int64 numpy array
        Coarse faces in coarse indexing, oriented like the fine faces.
    V : (J,nc,3) float64 numpy array
        Coarse poses, exactly ``Vs[:, kept]``.
    collapse_map : (n,) int64 numpy array
        For every fine vertex, the coarse vertex (coarse index) it was finally merged into;
        ``collapse_map[kept] == arange(nc)``.
    n_fine : int
        Number of fine vertices ``n``.
    pinned : (pc,) int64 numpy array or None
        Coarse indices of the coarse vertices that are pinned (``None`` when no ``pinned``
        was given).
    stats : dict
        ``rounds``, ``collapses``, ``seconds``, ``reached`` (target reached), ``target``,
        ``n_vertices`` (coarse count), ``n_faces``.
    """

    kept: np.ndarray
    F: np.ndarray
    V: np.ndarray
    collapse_map: np.ndarray
    n_fine: int
    pinned: np.ndarray | None = None
    stats: dict = field(default_factory=dict, compare=False)

    @property
    def n_vertices(self) -> int:
        """Number of coarse vertices ``nc``."""
        return int(self.kept.shape[0])

    def restrict(self, Vs) -> np.ndarray:
        """Coarse version of fine poses: ``Vs[..., kept, :]``.

        Parameters
        ----------
        Vs : (..., n, 3) float array_like

        Returns
        -------
        (..., nc, 3) float64 numpy array
        """
        Vs = np.asarray(Vs, dtype=np.float64)
        if Vs.ndim < 2 or Vs.shape[-2:] != (self.n_fine, 3):
            raise ShellsplineError(f"`Vs` must have shape (..., {self.n_fine}, 3), got {Vs.shape}")
        return Vs[..., self.kept, :]


# -- input canonicalisation --------------------------------------------------------------------

def canonical_target(target, n: int) -> int:
    """Number of coarse vertices asked for by ``target``.

    Parameters
    ----------
    target : int or float
        An ``int >= 4``: a vertex count; a ``float`` in ``(0, 1]``: the fraction ``γ`` of the
        ``n`` fine vertices that remains (rounded up, at least 4).
    n : int
        Number of fine vertices.

    Returns
    -------
    int
        ``min(n, count)``.

    Raises
    ------
    ValueError
        If ``target`` is a bool, not a number, a count below 4 or a fraction outside (0, 1].
    """
    if isinstance(target, (bool, np.bool_)):
        raise ShellsplineError(f"`target` must be a vertex count (int) or a fraction (float), got "
                               f"{target!r}")
    if isinstance(target, (int, np.integer)):
        if target < 4:
            raise ShellsplineError(f"`target` as a vertex count must be >= 4, got {target}")
        return int(min(int(target), n))
    if isinstance(target, (float, np.floating)):
        if not (0.0 < float(target) <= 1.0) or not math.isfinite(float(target)):
            raise ShellsplineError(f"`target` as a fraction must lie in (0, 1], got {target}")
        return int(min(n, max(4, math.ceil(float(target) * n))))
    raise ShellsplineError(f"`target` must be a vertex count (int) or a fraction (float), got "
                           f"{type(target).__name__} {target!r}")


def _canonical_poses(Vs, F, name_V="Vs", name_F="F"):
    Vs = np.asarray(Vs, dtype=np.float64)
    if Vs.ndim == 2:
        Vs = Vs[None]
    if Vs.ndim != 3 or Vs.shape[2] != 3 or Vs.shape[0] < 1:
        raise ShellsplineError(f"`{name_V}` must be a (J,n,3) (or (n,3)) array of poses, got shape "
                               f"{np.shape(Vs)}")
    if not np.isfinite(Vs).all():
        raise ShellsplineError(f"`{name_V}` contains non-finite coordinates")
    if isinstance(F, Topology):
        if F.n_vertices != Vs.shape[1]:
            raise ShellsplineError(f"`{name_F}` is a Topology of {F.n_vertices} vertices, "
                                   f"`{name_V}` has {Vs.shape[1]}")
        return Vs, F
    T = topology(F, Vs.shape[1], name=f"`{name_F}`")
    return Vs, T


# -- quadrics ----------------------------------------------------------------------------------
# A symmetric 4x4 quadric is stored by its 10 upper coefficients
# [aa, ab, ac, ad, bb, bc, bd, cc, cd, dd] for the plane (a, b, c, d).

def _plane_quadrics(a, b, c, d, w):
    """(k,10) quadric coefficients of the planes ``a x + b y + c z + d = 0`` (unit normals)
    with weights ``w``; all arguments (k,)."""
    out = np.zeros((a.shape[0], 10))
    for i, (p, q) in enumerate(((a, a), (a, b), (a, c), (a, d), (b, b), (b, c), (b, d),
                                (c, c), (c, d), (d, d))):
        np.multiply(p * q, w, out=out[:, i])
    return out


def _setup_pose(x, F, bnd_edges, bnd_faces, boundary_weight, inc, incb):
    """Quadrics (n,10), unnormalised vertex normals (n,3) and the mean face area of one pose
    ``x (n,3)``.

    Face planes are weighted by the face area; boundary edges add a plane through the edge
    perpendicular to its face, weighted by ``boundary_weight * |e|²`` (GH97 §6), so that the
    boundary keeps its shape.
    """
    p0 = x[F[:, 0]]
    N = cross(x[F[:, 1]] - p0, x[F[:, 2]] - p0)
    nn = norms(N)
    unit = N / np.maximum(nn, tol.zero)[:, None]
    u0, u1, u2 = unit[:, 0], unit[:, 1], unit[:, 2]
    d = -(u0 * p0[:, 0] + u1 * p0[:, 1] + u2 * p0[:, 2])
    Q = inc @ _plane_quadrics(u0, u1, u2, d, 0.5 * nn)
    if incb is not None:
        a = x[bnd_edges[:, 0]]
        e = x[bnd_edges[:, 1]] - a
        pn = normalized(cross(e, unit[bnd_faces]))
        db = -dot(pn, a)
        Q += incb @ _plane_quadrics(pn[:, 0], pn[:, 1], pn[:, 2], db,
                                    boundary_weight * dot(e, e))
    return Q, inc @ N, 0.5 * float(nn.mean())


def _length_quadrics(x, w):
    """(..., 10) coefficients of the quadric ``w |y − x|²`` (centred at points ``x``)."""
    out = np.zeros(x.shape[:-1] + (10,))
    out[..., 0] = out[..., 4] = out[..., 7] = w
    out[..., 3], out[..., 6], out[..., 8] = -w * x[..., 0], -w * x[..., 1], -w * x[..., 2]
    out[..., 9] = w * dot(x, x)
    return out


def _point_moments(x):
    """(..., 10) coefficients of ``x̂ x̂ᵀ`` (``x̂ = (x, 1)``) such that the quadric error of
    coefficient rows ``q`` at ``x`` is ``(q * m).sum(-1)``."""
    X, Y, Z = x[..., 0], x[..., 1], x[..., 2]
    out = np.zeros(x.shape[:-1] + (10,))
    out[..., 0], out[..., 1], out[..., 2], out[..., 3] = X * X, 2 * X * Y, 2 * X * Z, 2 * X
    out[..., 4], out[..., 5], out[..., 6] = Y * Y, 2 * Y * Z, 2 * Y
    out[..., 7], out[..., 8], out[..., 9] = Z * Z, 2 * Z, 1.0
    return out


def _quadric_errors(Q, M, iq, im, chunk: int = 8192):
    """``Σ_j Q[iq, j] · M[im, j]`` for quadric rows ``Q (n,J,10)`` and point moments
    ``M (n,J,10)`` (coefficients of ``x̂ x̂ᵀ``): the quadric errors summed over the poses in
    pose order (so J equal poses give exactly J times one pose). Chunked: no temporaries of
    the size of all halfedges times ``10 J``."""
    n, J, _ = Q.shape
    Q2, M2 = Q.reshape(n, 10 * J), M.reshape(n, 10 * J)
    out = np.zeros(iq.shape[0])
    for s in range(0, iq.shape[0], chunk):
        q = np.take(Q2, iq[s:s + chunk], axis=0)
        q *= np.take(M2, im[s:s + chunk], axis=0)
        out[s:s + chunk] = q.reshape(-1, J, 10).sum(axis=2).sum(axis=1)
    return out


# -- graph helpers -----------------------------------------------------------------------------

class _Graph:
    """Vertex adjacency of the current mesh as CSR arrays (sorted rows)."""

    def __init__(self, src, dst, n):
        self.n = n
        self.src, self.dst = src, dst              # sorted by (src, dst)
        self.indptr = np.zeros(n + 1, dtype=np.int64)
        np.cumsum(np.bincount(src, minlength=n), out=self.indptr[1:])

    def neighbours(self, ys):
        """Concatenated neighbour lists of the vertices ``ys``: ``(nb, starts, nonempty)``,
        where row ``i`` is ``nb[starts[i]:starts[i] + deg(ys[i])]``."""
        lo, hi = self.indptr[ys], self.indptr[ys + 1]
        deg = hi - lo
        starts = np.cumsum(deg) - deg
        nb = self.dst[np.repeat(lo - starts, deg) + np.arange(int(deg.sum()))]
        return nb, starts, deg > 0

    def closed_min_at(self, x, ys, rows=None):
        """``min(x[y], min of x over the neighbours of y)`` for each ``y`` in ``ys``
        (``rows``: ``self.neighbours(ys)`` when already computed)."""
        nb, starts, nz = self.neighbours(ys) if rows is None else rows
        out = x[ys]
        if nb.size:
            out[nz] = np.minimum(out[nz], np.minimum.reduceat(x[nb], starts[nz]))
        return out

    def closed_mark(self, ys):
        """(n,) bool mask of the closed one-rings ``N[y]`` of the vertices ``ys``."""
        mask = np.zeros(self.n, dtype=bool)
        mask[ys] = True
        mask[self.neighbours(ys)[0]] = True
        return mask


def _conflict_free_winners(g: _Graph, us, vs, key, big):
    """Positions of the collapses ``us -> vs`` (distinct ``us``) whose key is the smallest
    among all collapses they conflict with (see :func:`_select_collapses`)."""
    umin = np.full(g.n, big, dtype=np.int64)
    umin[us] = key
    vmin = np.full(g.n, big, dtype=np.int64)
    np.minimum.at(vmin, vs, key)
    rows_u = g.neighbours(us)
    win = (g.closed_min_at(umin, us, rows_u) == key) & (g.closed_min_at(vmin, us, rows_u) == key)
    w = np.flatnonzero(win)
    w = w[g.closed_min_at(umin, vs[w]) == key[w]]
    return w


_N_BINS = 1 << 40
_SLACK = 2.0      # competitors per round: the _SLACK * budget cheapest u
_MAX_SWEEPS = 64
_TAIL = 32        # an excess this small is removed in one round (cheapest independent set)


def _select_collapses(g: _Graph, ckey, on_boundary, iu, iv, cost, budget, face_ok, rng,
                      max_alternatives):
    """One round's set of simultaneous collapses: valid, conflict-free, cheap first.

    Parameters
    ----------
    g : _Graph
        Vertex adjacency of the current mesh.
    ckey : (h,) int64 array
        Sorted directed-edge keys ``src * n + dst`` of ``g``.
    on_boundary, iu, iv, cost : (c,) arrays
        The candidate halfedges ``iu -> iv`` (sorted by ``iu``), whether each lies on the
        boundary, and their costs.
    budget : int
        At most this many collapses.
    face_ok : callable(us, vs) -> (k,) bool array
        The geometric checks (flips, slivers in every pose).
    rng : numpy Generator
    max_alternatives : int
        Targets tried per ``u`` (cheapest first) when the cheaper ones fail the checks.

    Returns
    -------
    us, vs : (k,) int64 arrays, ``k <= budget``

    Notes
    -----
    Two collapses ``i, j`` conflict when ``u_i ∈ N[u_j]``, ``v_i ∈ N[u_j]`` or
    ``v_j ∈ N[u_i]`` (``N[x]``: closed one-ring). A conflict-free set touches no face twice
    and changes neither the one-rings of any ``u_i, v_i`` nor the faces around any ``u_i``,
    so all checks made on the current mesh hold for the simultaneous collapse (a halfedge
    collapse moves no vertex). The set is built by Luby-style sweeps: a candidate is a
    tentative winner when its priority (rank of its cost, ties at random) is the smallest among the
    active candidates it conflicts with; tentative winners are checked (link condition, then
    ``face_ok``); valid ones are accepted and deactivate their conflicts, invalid ones move
    on to their next cheapest target. Only the ``_SLACK * budget`` ``u`` with the cheapest
    best target compete, so that no expensive collapse is made while cheap ones wait.
    """
    brk = np.r_[True, iu[1:] != iu[:-1]]
    gstart = np.flatnonzero(brk)
    gid = np.cumsum(brk) - 1
    work = cost.copy()
    gmin = np.minimum.reduceat(work, gstart)
    # the first halfedge of each group attaining its minimum
    im = np.flatnonzero(work == gmin[gid])[::-1]
    first_min = np.full(gstart.shape[0], -1, dtype=np.int64)  # every group gets its own
    first_min[gid[im]] = im
    order = np.argsort(gmin, kind="stable")
    lim = int(math.ceil(_SLACK * budget))
    while True:
        us, vs = _sweeps(g, ckey, on_boundary, iu, iv, work, gstart, gmin, first_min,
                         order[:lim], budget, face_ok, rng, max_alternatives)
        if us.shape[0] or lim >= order.shape[0]:
            return us, vs
        lim *= 4          # every competitor failed: let more compete


def _sweeps(g, ckey, on_boundary, iu, iv, work, gstart, gmin, first_min, comp, budget,
            face_ok, rng, max_alternatives):
    """Luby-style sweeps of :func:`_select_collapses` among the competing groups ``comp``."""
    big = np.iinfo(np.int64).max
    gend = np.r_[gstart[1:], iu.shape[0]]
    U = comp.shape[0]
    cur = first_min[comp]
    sorted_best = gmin[comp]                               # increasing
    # priority: rank of the collapse's cost among the competitors (ties at random)
    tie = rng.permutation(U)
    nb = max(1, min(_N_BINS, U))
    prio = (np.arange(U) * nb // U) * U + tie
    tries = np.ones(U, dtype=np.int64)
    active = np.ones(U, dtype=bool)
    accepted = []
    blocked_u = np.zeros(g.n, dtype=bool)     # closed one-rings of accepted u's
    for _ in range(_MAX_SWEEPS):
        ai = np.flatnonzero(active)
        if ai.size == 0:
            break
        w = ai[_conflict_free_winners(g, iu[cur[ai]], iv[cur[ai]], prio[ai], big)]
        if w.size == 0:
            break
        ci = cur[w]
        us, vs = iu[ci], iv[ci]
        good = _link_ok(g, ckey, us, vs, on_boundary[ci])
        if good.any():        # a sweep whose winners all fail the link condition checks no face
            good[good] = face_ok(us[good], vs[good])
        ok_w, bad_w = w[good], w[~good]
        if ok_w.size:
            accepted.append(ok_w)
            active[ok_w] = False
            ru, rv = g.closed_mark(iu[cur[ok_w]]), g.closed_mark(iv[cur[ok_w]])
            blocked_u |= ru
            ai = np.flatnonzero(active)
            ca, cb = iu[cur[ai]], iv[cur[ai]]
            active[ai[ru[ca] | rv[ca] | ru[cb]]] = False
        if bad_w.size:
            work[cur[bad_w]] = np.inf
            retry = active[bad_w] & (tries[bad_w] < max_alternatives)
            active[bad_w[~retry]] = False
            bad_w = bad_w[retry]
        if bad_w.size:
            # next cheapest target of each failed u
            grp = comp[bad_w]
            lo, hi = gstart[grp], gend[grp]
            h = _ranges(lo, hi)
            who = np.repeat(np.arange(bad_w.shape[0]), hi - lo)
            wv = work[h]
            m = np.minimum.reduceat(wv, np.r_[0, np.cumsum(hi - lo)][:-1])
            isn = np.flatnonzero(wv == m[who])[::-1]
            nxt = np.full(bad_w.shape[0], -1, dtype=np.int64)
            nxt[who[isn]] = h[isn]
            fin = np.isfinite(m)
            active[bad_w[~fin]] = False
            bw = bad_w[fin]
            cur[bw] = nxt[fin]
            tries[bw] += 1
            # the new target must not touch an accepted collapse's one-ring
            active[bw] &= ~blocked_u[iv[cur[bw]]]
            rank = np.clip(np.searchsorted(sorted_best, m[fin], side="right") - 1, 0, U - 1)
            prio[bw] = (rank * nb // U) * U + tie[bw]
    if not accepted:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    acc = np.concatenate(accepted)
    acc = acc[np.argsort(work[cur[acc]], kind="stable")][:budget]
    return iu[cur[acc]], iv[cur[acc]]


def _ranges(lo, hi):
    """Concatenation of ``arange(lo[i], hi[i])``."""
    ln = hi - lo
    return np.repeat(lo - np.r_[0, np.cumsum(ln)][:-1], ln) + np.arange(int(ln.sum()))


# -- the decimation ----------------------------------------------------------------------------

def _row_positions(ptr, owners):
    """Positions ``ptr[o]:ptr[o+1]`` of the CSR rows ``o in owners``, concatenated, with the
    position (into ``owners``) each entry belongs to."""
    lo = ptr[owners]
    deg = ptr[owners + 1] - lo
    who = np.repeat(np.arange(owners.shape[0]), deg)
    return np.repeat(lo - (np.cumsum(deg) - deg), deg) + np.arange(who.shape[0]), who


def _expand(ptr, items, owners):
    """Concatenated CSR rows ``items[ptr[o]:ptr[o+1]]`` for ``o in owners``, with the
    position (into ``owners``) each entry belongs to."""
    pos, who = _row_positions(ptr, owners)
    return items[pos], who


def _link_ok(g: _Graph, ckey, us, vs, on_boundary):
    """Link condition: ``|N(u) ∩ N(v)|`` is 2 for an interior edge and 1 for a boundary edge."""
    w, who = _expand(g.indptr, g.dst, us)
    k = vs[who] * g.n + w
    p = np.minimum(np.searchsorted(ckey, k), ckey.shape[0] - 1)
    common = np.bincount(who, weights=(ckey[p] == k), minlength=us.shape[0])
    return common == np.where(on_boundary, 1, 2)


def _face_checks(X, gid, vnormals, folded, fold_area2, hs, us, vs, min_cos, min_quality):
    """Validity of the collapses ``us -> vs`` w.r.t. the faces around ``u``, in every pose.

    A collapse is rejected when, in any pose, a face around ``u`` that survives it turns its
    normal by more than ``arccos(min_cos)`` (this includes flips), makes an angle of more than
    ``arccos(min_cos)`` with the fine surface's normal at one of its corners (so that faces
    cannot drift away from the surface over many collapses), or becomes a sliver (quality
    ``4√3 a / Σ l²`` below ``min_quality`` and below its quality before). With ``folded``
    given, the corner-normal test is waived at a corner that is folded in that pose (its own
    fine faces fail it) when the new face's doubled area is below ``fold_area2`` in every
    pose.

    ``hs`` is the round's :class:`_Halfedges`; ``X`` and ``vnormals`` are (n,J,3) arrays and
    ``folded`` an (n,J) bool array or None, indexed by fine vertex (``gid`` maps current to
    fine indices); ``fold_area2`` is (J,).
    """
    # the faces around u are those of the halfedges u -> a (face (u, a, b))
    h, owner = _row_positions(hs.g.indptr, us)
    a, b = hs.g.dst[h], hs.opp[h]
    v = vs[owner]
    survives = (b >= 0) & (a != v) & (b != v)
    owner, a, b, v = owner[survives], a[survives], b[survives], v[survives]
    k, J = owner.shape[0], X.shape[1]
    if k == 0:                 # no collapse has a surviving face (ears, or no collapse at all)
        return np.ones(us.shape[0], dtype=bool)
    gv, ga, gb = gid[v], gid[a], gid[b]
    P = X[np.concatenate([gid[us[owner]], gv, ga, gb])].reshape(4, k, J, 3)    # u, v, a, b
    # edge vectors a-u, b-u (old face), a-v, b-v (new face), b-a (shared), all poses at once
    D = P[[2, 3, 2, 3, 3]] - P[[0, 0, 1, 1, 2]]                                # (5,k,J,3)
    L = dot(D, D)
    N = cross(D[[0, 2]], D[[1, 3]])                    # old and new face normal
    nn = norms(N)
    ok = dot(N[0], N[1]) > min_cos * nn[0] * nn[1]
    corners = np.concatenate([gv, ga, gb])
    vn = vnormals[corners].reshape(3, k, J, 3)
    along = np.einsum("sxji,xji->sxj", vn, N[1]) > min_cos * nn[1]             # (3,k,J)
    if folded is not None:
        small = (nn[1] < fold_area2).all(axis=1)                                # (k,)
        along |= folded[corners].reshape(3, k, J) & small[None, :, None]
    ok &= along.all(axis=0)
    c = 2.0 * math.sqrt(3.0)
    q0 = c * nn[0] / np.maximum(L[0] + L[1] + L[4], tol.zero)
    q1 = c * nn[1] / np.maximum(L[2] + L[3] + L[4], tol.zero)
    ok &= (q1 >= min_quality) | (q1 >= q0)
    ok = ok.all(axis=1)
    bad = np.zeros(us.shape[0], dtype=bool)
    bad[owner[~ok]] = True
    return ~bad


class _Halfedges:
    """Directed edges of the current mesh, sorted by ``(src, dst)``, with the boundary ones'
    reverses added (so both collapse directions of a boundary edge are candidates).

    Attributes: ``key`` (h,) ``src * n + dst``; ``g`` the :class:`_Graph`; ``bnd`` (h,) bool
    (on a boundary edge); ``opp`` (h,) the third vertex of the halfedge's face (``-1`` for an
    added boundary reverse, which has no face).
    """

    def __init__(self, F, n, is_bnd):
        src = F.ravel()
        dst = F[:, [1, 2, 0]].ravel()
        opp = F[:, [2, 0, 1]].ravel()
        key = src * n + dst
        o = np.argsort(key)
        key, src, dst, opp = key[o], src[o], dst[o], opp[o]
        # a boundary edge joins two boundary vertices: only those halfedges look for a twin
        bnd = is_bnd[src] & is_bnd[dst]
        cand = np.flatnonzero(bnd)
        if cand.size:
            rkey = dst[cand] * n + src[cand]
            p = np.minimum(np.searchsorted(key, rkey), key.shape[0] - 1)
            bnd[cand] = key[p] != rkey
            rkey = rkey[bnd[cand]]
        if bnd.any():
            rl = np.sort(rkey)
            pos = np.searchsorted(key, rl)
            key = np.insert(key, pos, rl)
            bnd = np.insert(bnd, pos, True)
            opp = np.insert(opp, pos, -1)
            src, dst = key // n, key % n
        self.key, self.bnd, self.opp = key, bnd, opp
        self.g = _Graph(src, dst, n)


def decimate(Vs, F, target, *, pinned=None, boundary_weight: float = 1.0,
             length_weight: float = 1e-3, min_normal_cos: float = 0.2,
             min_quality: float = 0.05, fold_area: float = 0.0,
             round_fraction: float = 0.25, max_alternatives: int = 3, seed: int = 0,
             max_rounds: int = 10_000) -> Decimation:
    """Decimate all poses of a keyframe set simultaneously by halfedge collapses.

    Parameters
    ----------
    Vs : (J,n,3) float array_like
        Poses of one mesh (a single ``(n,3)`` pose is accepted).
    F : (m,3) int array_like or Topology
        Shared faces: consistently oriented, edge-manifold (a prebuilt
        :class:`~shellspline.mesh.topology.Topology` of them skips rebuilding it).
    target : int or float
        Number of coarse vertices (``int >= 4``) or the remaining fraction ``γ`` of the
        vertices (``float`` in ``(0, 1]``, as in the paper's Table 2); see
        :func:`canonical_target`.
    pinned : (p,) int array_like or (n,) bool array_like, optional
        Vertices that are fixed (identical in all poses). A pinned vertex is only ever
        collapsed into another pinned vertex, so the coarse pinned set is ``pinned ∩ kept``,
        it still covers the pinned region, and every coarse vertex whose fine region contains
        an unpinned vertex is unpinned.
    boundary_weight : float
        Weight of the boundary-preserving plane quadrics (perpendicular to the surface through
        each boundary edge, weighted by ``|e|²``); 0 disables them.
    length_weight : float
        Weight of a small edge-length term ``length_weight * ā * Σ_j |v_j − u_j|²`` (``ā``:
        mean face area) added to the cost, which keeps flat regions (quadric error 0)
        uniformly sampled instead of collapsing in arbitrary order.
    min_normal_cos : float
        A collapse is rejected when, in any pose, a surviving face around ``u`` turns its
        normal by more than ``arccos(min_normal_cos)`` (``0.2``: about 78°; every flip).
    min_quality : float
        A collapse is rejected when, in any pose, it creates a face with quality
        ``4√3 a / Σ l²`` (1 for equilateral) below ``min_quality`` and below that face's
        quality before the collapse.
    fold_area : float
        Where the fine surface itself folds over in a pose (a vertex whose own fine faces make
        more than ``arccos(min_normal_cos)`` with its vertex normal: skin folding at a joint),
        waive the corner-normal rule for new faces smaller, in every pose, than ``fold_area``
        times the mean face area at the target resolution, so that such folds are coarsened
        to about that resolution instead of keeping their fine faces. Default 0: never (see
        the Notes for why it is off).
    round_fraction : float
        At most this fraction of the remaining excess ``n_current − target`` is collapsed per
        round (smaller: closer to the sequential greedy order, more rounds); the last
        ``_TAIL`` (32) excess vertices go in one round.
    max_rounds : int
        Safety limit on the number of rounds.

    Returns
    -------
    Decimation
        ``stats["reached"]`` is ``False`` when no further valid collapse existed before the
        target (a ``RuntimeWarning`` is issued); with ``fold_area`` > 0,
        ``stats["folded_corners"]`` counts the fine vertices where some pose folds over.

    Raises
    ------
    ValueError
        On invalid arguments (the message names the argument); ``MeshError`` (a
        ``ValueError``) when ``F`` is not an oriented manifold triangle mesh.

    Notes
    -----
    Collapse rules, checked in every pose:

    * cost ``Σ_j v_jᵀ (Q_u^j + Q_v^j) v_j`` with accumulated area-weighted plane quadrics
      (``Q_v += Q_u`` after the collapse), plus the small length term;
    * link condition (``N(u) ∩ N(v)`` are exactly the opposite vertices of the edge's faces),
      so the surface stays an oriented 2-manifold with the same Euler characteristic;
    * boundary vertices stay on the boundary: a boundary ``u`` only collapses along a
      boundary edge into its boundary neighbour (the boundary polygon loses a vertex),
      interior vertices may collapse onto boundary vertices;
    * no face around ``u`` flips, turns by more than ``arccos(min_normal_cos)``, deviates by
      more than that from the fine vertex normals at its corners, or becomes a sliver, in any
      pose.

    Where a keyframe folds over, its own fine faces fail the corner-normal rule, so no face
    touching such a corner can be replaced and the fold's neighbourhood keeps its fine
    faces. On a dense mesh these are tiny: the horse Loop-subdivided twice (134 782
    vertices to 1000) keeps 112 fine faces, down to 10⁻⁴ of the median coarse face area and
    squeezed 140:1 between poses, and its coarse Gauss–Newton (alone) takes a median 20
    iterations with 3 of 38 frames unconverged; ``fold_area=0.5`` coarsens the folds (7
    fine faces left, every face's area ratio between poses above 0.06) and the coarse solve
    takes 5, 38 of 38 converged. It stays off because the prolongation needs the folds
    resolved: with ``fold_area`` 0.125 or 0.5 the 150° joint of
    ``tests/shells/test_prolong.py`` prolongs with 31–105 fine faces flipped against the
    exact motion instead of at most 12 (the frozen joint held 125–130 of the 144 coarse
    vertices, 51–68 with the waiver), and
    the subdivided horse's full path (multiresolution, otherwise default) ends with 39
    instead of 21 folded edges (mean of 900, 1000 and 1100 coarse vertices).

    A round accepts collapses whose closed one-rings are pairwise disjoint, chosen greedily
    by cost, at most ``round_fraction`` of the remaining excess. Such collapses commute, and
    since a halfedge collapse moves no vertex, the checks made before the round hold after
    it. Candidates compete by the rank of their cost (ties broken at random by ``seed``).
    Every round works on the current mesh only (removed vertices are compacted away), pair
    costs are reused unless their ``u`` absorbed a quadric, and the conflict tests touch only
    the one-rings of the competing collapses, so the work per round is a few sorts over the
    current mesh; the number of rounds grows like ``log(n / target)``.

    Examples
    --------
    >>> import data_synth
    >>> d = data_synth.generate("ellipsoids", n_vertices=500)
    >>> dec = decimate(d["V"], d["F"], 100)
    >>> dec.n_vertices, dec.V.shape[0], bool((dec.V == d["V"][:, dec.kept]).all())
    (100, 3, True)
    """
    t0 = time.perf_counter()
    Vs, T = _canonical_poses(Vs, F)
    n = Vs.shape[1]
    nt = canonical_target(target, n)
    pin = pinned_mask(pinned, n)
    _check_options(boundary_weight, length_weight, min_normal_cos, min_quality, round_fraction,
                   fold_area)
    st = _CollapseState(Vs, T, pin, float(boundary_weight), float(length_weight),
                        float(min_normal_cos), float(fold_area) * n / nt)
    rng = np.random.default_rng(seed)
    while st.n_cur > nt and st.rounds < max_rounds:
        if not _collapse_round(st, nt, float(round_fraction), float(min_normal_cos),
                               float(min_quality), int(max_alternatives), rng):
            break
    if st.n_cur > nt:
        warnings.warn(f"decimate: stopped at {st.n_cur} vertices, target {nt} (no further "
                      "valid collapse)", RuntimeWarning, stacklevel=2)
    return _decimation(st, Vs, pin if pinned is not None else None, nt, t0)


def _check_options(boundary_weight, length_weight, min_normal_cos, min_quality,
                   round_fraction, fold_area) -> None:
    """The scalar options of :func:`decimate` (one-line errors naming the argument)."""
    for name, val, lo in (("boundary_weight", boundary_weight, 0.0),
                          ("length_weight", length_weight, 0.0),
                          ("min_quality", min_quality, 0.0),
                          ("fold_area", fold_area, 0.0)):
        if not (math.isfinite(float(val)) and float(val) >= lo):
            raise ShellsplineError(f"`{name}` must be a finite number >= {lo}, got {val!r}")
    if not -1.0 <= float(min_normal_cos) < 1.0:
        raise ShellsplineError(f"`min_normal_cos` must lie in [-1, 1), got {min_normal_cos!r}")
    if not 0.0 < float(round_fraction) <= 1.0:
        raise ShellsplineError(f"`round_fraction` must lie in (0, 1], got {round_fraction!r}")


class _CollapseState:
    """The quadrics of the fine poses and the current (partly collapsed) mesh.

    Fine-indexed, ``(n, J, ·)``: centred poses ``Xn``, accumulated quadrics ``Q``, pair-term
    quadrics ``Qp = Q + length term``, point moments ``M``, vertex terms ``evert``, fine vertex
    normals ``vnormals``, ``folded`` (n,J) (see :func:`_folded_corners`), ``parent`` (the
    vertex each one collapsed into); ``fold_area2`` (J,): twice the largest face area per
    pose that the fold waiver allows (``fold_scale`` times the mean fine face area, per
    pose); ``folded`` and ``fold_area2`` are None without the waiver. The current mesh in
    compact indexing: current vertex ``c`` is fine vertex ``gid[c]``, faces ``Fc``, pinned
    and boundary flags ``pin_c``, ``bnd_c``; ``n_cur`` counts its vertices (unreferenced ones
    count but are never removed). ``prev_key``/``prev_pair``/``dirty`` reuse last round's
    pair costs.
    """

    def __init__(self, Vs, T, pin, boundary_weight, length_weight, min_cos, fold_scale):
        J, n, _ = Vs.shape
        X = Vs - Vs.mean(axis=1, keepdims=True)          # centred: better conditioned quadrics
        self.Xn = np.ascontiguousarray(X.transpose(1, 0, 2))  # (n,J,3): one row per vertex
        self.Q, self.vnormals, area = _fine_quadrics(X, T, boundary_weight)
        self.folded = self.fold_area2 = None
        if fold_scale > 0:
            self.folded = _folded_corners(X, T.F, self.vnormals, min_cos)
            p0 = X[:, T.F[:, 0]]
            self.fold_area2 = fold_scale * norms(cross(X[:, T.F[:, 1]] - p0,
                                                       X[:, T.F[:, 2]] - p0)).mean(axis=1)
        is_bnd = np.zeros(n, dtype=bool)
        is_bnd[T.boundary_vertices] = True
        self.lw = length_weight * area
        # Cost of u -> v: Σ_j [(Q_u^j + lw L_u^j) + Q_v^j] : m(x_v^j), where m(x) holds the
        # coefficients of x̂ x̂ᵀ (x̂ = (x, 1)) so that a quadric error is a row dot product,
        # and L_u = |x − x_u|² is the length term as a quadric. Split as pair(u, v) +
        # vertex(v): the pair term only changes when u absorbs a quadric, the vertex term is
        # one value per vertex.
        self.M = _point_moments(self.Xn)                   # (n,J,10)
        self.Qp = _length_quadrics(self.Xn, self.lw)       # quadric of the pair term
        self.Qp += self.Q
        self.evert = _quadric_errors(self.Q, self.M, np.arange(n), np.arange(n))  # (n,)
        self.n = n
        self.parent = np.arange(n, dtype=np.int64)
        self.gid = np.arange(n, dtype=np.int64)
        self.Fc = T.F.copy()
        self.pin_c, self.bnd_c = pin.copy(), is_bnd
        self.n_cur = n
        self.rounds = self.collapses = 0
        self.prev_key = self.prev_pair = None
        self.dirty = np.zeros(n, dtype=bool)


def _fine_quadrics(X, T, boundary_weight):
    """Accumulated quadrics ``(n,J,10)``, unit fine vertex normals ``(n,J,3)`` and the mean
    face area (averaged over the poses) of the centred poses ``X (J,n,3)``."""
    J, n, _ = X.shape
    bnd_e = T.edge_faces[:, 1] < 0
    E_b, F_b = T.E[bnd_e], T.edge_faces[bnd_e, 0]
    inc = vertex_face_incidence(T.F, n)
    incb = None
    if E_b.shape[0] and boundary_weight > 0:
        nb = E_b.shape[0]
        incb = sp.csr_matrix((np.ones(2 * nb), (E_b.T.ravel(), np.tile(np.arange(nb), 2))),
                             shape=(n, nb))
    Q = np.zeros((n, J, 10))                          # accumulated quadrics
    vnormals = np.zeros((n, J, 3))                    # fine vertex normals
    area = 0.0
    for j in range(J):
        Q[:, j], vnormals[:, j], a_j = _setup_pose(X[j], T.F, E_b, F_b, boundary_weight, inc,
                                                    incb)
        area += a_j / J
    vnormals = normalized(vnormals)
    return Q, vnormals, area


def _folded_corners(X, F, vnormals, min_cos):
    """(n,J) bool: vertex ``i`` is *folded* in pose ``j`` when one of its own fine faces
    makes an angle of more than ``arccos(min_cos)`` with its vertex normal there (the fine
    surface folds over at ``i``: skin folding at a joint, a crease pinched shut), i.e. the
    fine mesh itself fails the corner-normal test of :func:`_face_checks` at ``i``.

    ``X (J,n,3)`` poses, ``F (m,3)`` faces, ``vnormals (n,J,3)`` unit vertex normals."""
    J, n, _ = X.shape
    folded = np.zeros((n, J), dtype=bool)
    for j in range(J):
        p0 = X[j, F[:, 0]]
        N = cross(X[j, F[:, 1]] - p0, X[j, F[:, 2]] - p0)
        nn = norms(N)
        for c in range(3):
            bad = dot(vnormals[F[:, c], j], N) <= min_cos * nn
            folded[F[bad, c], j] = True
    return folded


def _candidates(st: _CollapseState, hs: "_Halfedges"):
    """Halfedges of the current mesh that pass the cheap rules (pinned only into pinned, a
    boundary ``u`` only along a boundary edge) and their costs; None when there are none.

    Returns ``(idx_ok, iu, iv, cost)``: indices into the halfedges, their current end
    vertices, ``pair + vertex`` cost. Pair terms are reused from the last round unless ``u``
    absorbed a quadric (new halfedges always touch such a vertex or are new keys).
    """
    cu, cv = hs.g.src, hs.g.dst
    okc = ~(st.pin_c[cu] & ~st.pin_c[cv]) & (~st.bnd_c[cu] | (st.bnd_c[cv] & hs.bnd))
    idx_ok = np.flatnonzero(okc)
    if idx_ok.shape[0] == 0:
        return None
    iu, iv = cu[idx_ok], cv[idx_ok]
    gu, gv = st.gid[iu], st.gid[iv]
    gkey = gu * st.n + gv                            # increasing: gid is increasing
    if st.prev_key is None:
        pair = _quadric_errors(st.Qp, st.M, gu, gv)
    else:
        pair = np.zeros(iu.shape[0])
        p = np.minimum(np.searchsorted(st.prev_key, gkey), st.prev_key.shape[0] - 1)
        hit = (st.prev_key[p] == gkey) & ~st.dirty[gu]
        pair[hit] = st.prev_pair[p[hit]]
        redo = np.flatnonzero(~hit)
        pair[redo] = _quadric_errors(st.Qp, st.M, gu[redo], gv[redo])
    st.prev_key, st.prev_pair = gkey, pair
    return idx_ok, iu, iv, pair + st.evert[gv]


def _collapse_round(st: _CollapseState, nt, round_fraction, min_cos, min_q,
                    max_alternatives, rng) -> bool:
    """One round: evaluate every candidate, accept an independent set of valid collapses
    (at most ``round_fraction`` of the excess), apply it. False when nothing was collapsed."""
    nl = st.gid.shape[0]
    hs = _Halfedges(st.Fc, nl, st.bnd_c)
    cand = _candidates(st, hs)
    if cand is None:
        return False
    idx_ok, iu, iv, cost = cand
    excess = st.n_cur - nt
    budget = excess if excess <= _TAIL else max(1, int(math.ceil(round_fraction * excess)))
    us, vs = _select_collapses(hs.g, hs.key, hs.bnd[idx_ok], iu, iv, cost, budget,
                               lambda u, v: _face_checks(st.Xn, st.gid, st.vnormals, st.folded,
                                                         st.fold_area2, hs, u, v, min_cos,
                                                         min_q),
                               rng, max_alternatives)
    if us.shape[0] == 0:
        return False
    _apply_collapses(st, us, vs)
    return True


def _apply_collapses(st: _CollapseState, us, vs) -> None:
    """``u -> v`` for every pair (current indices): u disappears, its faces move to v, the
    two (one) faces of uv vanish, v absorbs u's quadric; the removed vertices are compacted
    away."""
    nl = st.gid.shape[0]
    to = np.arange(nl, dtype=np.int64)
    to[us] = vs
    Fn = to[st.Fc]
    alive_f = (Fn[:, 0] != Fn[:, 1]) & (Fn[:, 1] != Fn[:, 2]) & (Fn[:, 2] != Fn[:, 0])
    gus, gvs = st.gid[us], st.gid[vs]
    st.Q[gvs] += st.Q[gus]
    st.Qp[gvs] = st.Q[gvs] + _length_quadrics(st.Xn[gvs], st.lw)
    st.evert[gvs] = _quadric_errors(st.Q, st.M, gvs, gvs)
    st.dirty[:] = False
    st.dirty[gvs] = True
    st.parent[gus] = gvs
    keep = np.ones(nl, dtype=bool)
    keep[us] = False
    new = np.cumsum(keep) - 1
    st.Fc = new[Fn[alive_f]]
    st.gid, st.pin_c, st.bnd_c = st.gid[keep], st.pin_c[keep], st.bnd_c[keep]
    st.n_cur -= us.shape[0]
    st.collapses += us.shape[0]
    st.rounds += 1


def _decimation(st: _CollapseState, Vs, pin, nt, t0) -> Decimation:
    """The :class:`Decimation` of the final state (``pin``: the fine pinned mask, or None)."""
    n = st.n
    kept = np.flatnonzero(st.parent == np.arange(n)).astype(np.int64)
    root = st.parent
    while True:
        nxt = root[root]
        if np.array_equal(nxt, root):
            break
        root = nxt
    cidx = np.full(n, -1, dtype=np.int64)
    cidx[kept] = np.arange(kept.shape[0])
    F_coarse = cidx[st.gid[st.Fc]]
    pin_c = np.flatnonzero(pin[kept]).astype(np.int64) if pin is not None else None
    stats = {"rounds": st.rounds, "collapses": st.collapses,
             "seconds": time.perf_counter() - t0, "reached": bool(st.n_cur <= nt),
             "target": nt, "n_vertices": int(kept.shape[0]), "n_faces": int(F_coarse.shape[0])}
    if st.folded is not None:  # fine vertices where some keyframe folds over (fold_area > 0)
        stats["folded_corners"] = int(st.folded.any(axis=1).sum())
    return Decimation(kept=kept, F=F_coarse, V=Vs[:, kept], collapse_map=cidx[root],
                      n_fine=n, pinned=pin_c, stats=stats)


# -- baseline and error measure ----------------------------------------------------------------

def decimate_replay(Vs, F, target):
    """Baseline: simplify pose 0 alone with ``fast-simplification`` and replay on the others.

    Parameters
    ----------
    Vs : (J,n,3) float array_like
    F : (m,3) int array_like
    target : int or float
        As in :func:`decimate` (converted to a face count ``≈ 2 * vertices`` for the
        library's face target).

    Returns
    -------
    Vc : (J,nc,3) float64 numpy array
        Coarse poses. Pose 0 carries the library's optimised vertex positions, the other
        poses the positions its replay computes.
    Fc : (mc,3) int64 numpy array
        Coarse faces (the replayed connectivity of pose 0).

    Raises
    ------
    ImportError
        When ``fast-simplification`` is not installed (``pip install fast-simplification``).

    Notes
    -----
    This is the "decimate one pose, transfer the collapse sequence" approach; its collapse
    order knows nothing about the other poses, unlike :func:`decimate`.
    """
    try:
        import fast_simplification as fs
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise ImportError("decimate_replay needs the optional package fast-simplification: "
                          "pip install fast-simplification") from exc
    Vs, T = _canonical_poses(Vs, F)
    J, n, _ = Vs.shape
    nt = canonical_target(target, n)
    m = T.F.shape[0]
    target_faces = int(min(m - 1, max(4, round(m * nt / n))))
    _, _, coll = fs.simplify(Vs[0], T.F.astype(np.int32), target_count=target_faces,
                             return_collapses=True)
    out, Fc = [], None
    for j in range(J):
        pts, tri, _ = fs.replay_simplification(np.ascontiguousarray(Vs[j]),
                                               T.F.astype(np.int32), coll)
        if Fc is None:
            Fc = np.asarray(tri, dtype=np.int64)
        out.append(np.asarray(pts, dtype=np.float64))
    return np.stack(out), Fc


def hausdorff_fine_to_coarse(Vs, Vc, Fc, *, k: int = 16, chunk: int = 20_000) -> np.ndarray:
    """One-sided Hausdorff distance from each fine pose's vertices to its coarse surface.

    Parameters
    ----------
    Vs : (J,n,3) float array_like
        Fine poses (only the vertices are measured).
    Vc : (J,nc,3) float array_like
        Coarse poses.
    Fc : (mc,3) int array_like
        Coarse faces.
    k : int
        Candidate coarse triangles per fine vertex (nearest centroids); the exact point–
        triangle distance is taken to each candidate.
    chunk : int
        Fine vertices processed together (bounds the memory).

    Returns
    -------
    (J,) float64 numpy array
        ``max_i dist(Vs[j,i], coarse surface j)`` per pose; take ``.max()`` for the worst pose.

    Notes
    -----
    The nearest-centroid candidates make this an upper bound of the exact one-sided
    distance; with ``k = 16`` it is exact in practice on meshes of bounded triangle aspect.
    """
    from scipy.spatial import cKDTree
    from trimesh.triangles import closest_point

    Vs = np.asarray(Vs, dtype=np.float64)
    Vc = np.asarray(Vc, dtype=np.float64)
    Fc = np.asarray(Fc, dtype=np.int64)
    if Vs.ndim == 2:
        Vs, Vc = Vs[None], Vc[None]
    if Vs.shape[0] != Vc.shape[0]:
        raise ShellsplineError(f"`Vs` and `Vc` must hold the same number of poses, got "
                               f"{Vs.shape[0]} and {Vc.shape[0]}")
    kk = int(min(k, Fc.shape[0]))
    out = np.zeros(Vs.shape[0])
    step = max(1, int(chunk))
    for j in range(Vs.shape[0]):
        tri = Vc[j][Fc]
        tree = cKDTree(tri.mean(axis=1))
        for s in range(0, Vs.shape[1], step):
            P = Vs[j, s:s + step]
            _, cand = tree.query(P, k=kk)
            cand = cand.reshape(P.shape[0], kk)
            pts = np.repeat(P, kk, axis=0)
            cp = closest_point(tri[cand.ravel()], pts)
            dist = np.sqrt(((cp - pts) ** 2).sum(1)).reshape(-1, kk).min(axis=1)
            out[j] = max(out[j], float(dist.max()))
    return out

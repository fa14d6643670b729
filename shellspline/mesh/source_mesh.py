"""Real exports: from the polygons and vertices of the input files to the solve mesh and back.

Meshes exported by DCC tools (Blender, Maya, 3ds Max) are rarely the clean, edge-manifold
triangle meshes the shell model needs. :func:`solve_mesh` turns the keyframes' polygons into
one triangle mesh for the solve, and a :class:`SourceMesh` maps its results back:

* **Polygons** (quads, n-gons) are triangulated **once for the whole keyframe set**, so every
  keyframe has the same triangles: a quad takes the diagonal whose worst triangle, over all
  keyframes, has the best quality; an n-gon (5 or more corners) is cut by ``mapbox_earcut``
  (the ear-clipping library trimesh uses; optional extra ``dcc``) in its plane in every
  keyframe, and the candidate whose worst triangle over all keyframes is best is kept; when
  every candidate folds a triangle over the polygon in some keyframe, the best of all the
  polygon's triangulations (:func:`_maxmin_triangulation`) is taken instead.
* **Seams**: vertices that are coincident in **every** keyframe (to round-off: the same cell of
  a grid of ``1e-10 x`` the bounding-box diagonal) are welded into one solve vertex, so a mesh
  split at UV or normal seams cannot tear.
* **Orientation**: where two faces traverse a shared edge the same way, the minority
  orientation of each connected component is reversed for the solve (the output keeps the
  polygons as written); a non-orientable component is refused.
* **Fins**: a face repeating an earlier face's vertices is set aside; where an edge has more
  than two faces, the faces are grouped into *sheets* (faces connected through edges with
  exactly two faces); on each such edge the sheets are kept largest first while the edge
  keeps at most two faces, and the others are set aside.
* **Set-aside vertices** are not solved. One that a fin face uses (a fin's tip) is attached to
  the solve face of its nearest solve vertex (in keyframe 0) and moves with that face's
  frame, its coordinates in the frame blended linearly between keyframes; an isolated vertex
  (no face uses it, so nothing ties it to the surface) follows the per-vertex linear blend of
  its keyframe positions (:meth:`SourceMesh.expand`).
* **Texture coordinates** (OBJ ``vt``, when every corner names one) and OBJ material and group
  lines (``mtllib/usemtl/o/g/s``) are carried to the output.

Examples
--------
Two quads whose shared edge is split at a seam (vertices 4 and 5 repeat 1 and 2), in two
poses:

>>> import numpy as np
>>> V = np.array([[0., 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [1, 0, 0], [1, 1, 0],
...               [2, 0, 0], [2, 1, 0]])
>>> Vs = np.stack([V, V * [1, 1, 2]])
>>> V2, F, src, _ = solve_mesh(Vs, np.array([0, 4, 8]), np.array([0, 1, 2, 3, 4, 6, 7, 5]))
>>> V2.shape[1], F.shape[0], src.n_welded, src.to_solve.tolist()
(6, 4, 2, [0, 1, 2, 3, 1, 2, 4, 5])
>>> seq = np.stack([V2[0], (V2[0] + V2[1]) / 2, V2[1]])      # a solve-mesh sequence
>>> out = src.expand(seq, frames=[0, 2])                      # back to the 8 input vertices
>>> out.shape, bool((out[:, 4] == out[:, 1]).all()), bool((out[2] == Vs[1]).all())
((3, 8, 3), True, True)
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import MeshError
from .geometry import cross, normalized

__all__ = ["SourceMesh", "solve_mesh", "triangulate_polygons", "face_frames",
           "WELD_TOLERANCE"]

#: Vertices whose positions agree in every keyframe to this fraction of the bounding-box
#: diagonal of keyframe 0 are welded (a grid cell: round-off of exported text is ~1e-16).
WELD_TOLERANCE = 1e-10
_SQRT3x4 = 4.0 * np.sqrt(3.0)
_CHUNK = 100_000  # polygons x keyframes per vectorised block of the quad triangulation


@dataclass(frozen=True, eq=False)
class SourceMesh:
    """The map between the input files' mesh (the *source*) and the solve mesh.

    Attributes
    ----------
    n_source : int
        Number of vertices in the input files.
    poly_offsets : (P+1,) int64 numpy array
        Polygon ``p`` of the input is ``poly_indices[poly_offsets[p]:poly_offsets[p+1]]``.
    poly_indices : (N,) int64 numpy array
        Corner vertices of all input polygons, source indexing, in file order.
    triangles : (t,3) int64 numpy array
        The triangulation of every input polygon (fins included), source indexing.
    to_solve : (n_source,) int64 numpy array
        Solve vertex of every source vertex; ``-1`` for a vertex set aside.
    set_aside : (s,) int64 numpy array
        Source indices of the vertices set aside (isolated or used by fin faces only).
    anchors : (s,3) int64 numpy array
        Solve face (three solve vertices) that carries each set-aside vertex of a fin face;
        ``-1`` rows for isolated vertices (linear blend).
    exact : (e,) int64 numpy array
        Source vertices whose keyframe coordinates are restored bit for bit at keyframes
        (set-aside vertices and welded duplicates).
    exact_V : (J,e,3) float64 numpy array
        Their keyframe coordinates.
    fin_polygons : (q,) int64 numpy array
        Input polygons set aside as fins.
    n_welded : int
        Source vertices merged into another one.
    n_reoriented : int
        Input polygons whose orientation the solve mesh reverses (the minority of their
        connected component); the output keeps them as written.
    uv : (t,2) float64 numpy array or None
        Texture coordinates of the input (OBJ ``vt``), written back with the polygons.
    corner_uv : (N,) int64 numpy array or None
        Texture coordinate of every polygon corner (aligned with ``poly_indices``).
    statements : tuple or None
        The input's OBJ material and group lines (``mtllib/usemtl/o/g/s``) as
        ``(head, body)``: ``head`` the lines before the vertices, ``body`` ``(p, line)``
        pairs, each line written before polygon ``p``
        (:func:`shellspline.io.meshes.obj_statements`); ``None`` if it had none.
    """

    n_source: int
    poly_offsets: np.ndarray
    poly_indices: np.ndarray
    triangles: np.ndarray
    to_solve: np.ndarray
    set_aside: np.ndarray
    anchors: np.ndarray
    exact: np.ndarray
    exact_V: np.ndarray
    fin_polygons: np.ndarray
    n_welded: int
    n_reoriented: int = 0
    uv: np.ndarray | None = None
    corner_uv: np.ndarray | None = None
    statements: tuple | None = None

    @property
    def n_solve(self) -> int:
        """Number of solve vertices."""
        return int(self.to_solve.max()) + 1

    @property
    def n_polygons(self) -> int:
        """Number of input polygons."""
        return int(self.poly_offsets.shape[0] - 1)

    def summary(self) -> dict:
        """Counts for reports: polygons, triangles, welded, set-aside vertices, fin polygons."""
        sizes = np.diff(self.poly_offsets)
        return {"source_vertices": self.n_source, "polygons": self.n_polygons,
                "non_triangle_polygons": int((sizes != 3).sum()),
                "welded_vertices": int(self.n_welded),
                "set_aside_vertices": int(self.set_aside.size),
                "fin_polygons": int(self.fin_polygons.size),
                "reoriented_polygons": int(self.n_reoriented),
                "texture_coordinates": 0 if self.uv is None else int(self.uv.shape[0])}

    def solve_vertices(self, idx, what: str = "pinned") -> np.ndarray:
        """Solve-mesh indices of source vertices ``idx`` (sorted, unique).

        Raises
        ------
        MeshError
            If an index is out of range or names a vertex set aside for the solve.
        """
        idx = np.asarray(idx, dtype=np.int64).ravel()
        out = (idx < 0) | (idx >= self.n_source)
        if out.any():
            raise MeshError(f"{what} vertex indices must lie in [0, {self.n_source}), got "
                            f"{int(idx[out][0])} ({int(out.sum())} out of range)")
        to = self.to_solve[idx]
        if (to < 0).any():
            raise MeshError(f"{what} vertex {int(idx[to < 0][0])} is set aside for the solve "
                            f"(isolated, or used by fin faces only; {int((to < 0).sum())} such)")
        return np.unique(to)

    def expand(self, V, frames, K: int | None = None, bc: str = "natural") -> np.ndarray:
        """Poses of the solve mesh → poses of the input's vertices.

        Parameters
        ----------
        V : (K+1,n,3) float array
            A sequence on the solve mesh whose frames ``frames[j]`` are the keyframes.
        frames : (J,) int array
            Keyframe frames (as for :func:`shellspline.interpolate`).
        K : int, optional
            Last frame; default ``V.shape[0] - 1`` (given, it must agree).
        bc : {"natural", "periodic", "hermite"}
            ``"periodic"``: frames after the last keyframe blend back into keyframe 0.

        Returns
        -------
        (K+1,n_source,3) float64 numpy array
            Welded vertices take their solve vertex's position; a fin's set-aside vertex moves
            with the orthonormal frame of its anchor face, its coordinates in that frame
            blended linearly between the keyframes around each frame; an isolated vertex is
            blended linearly between its keyframe positions. At keyframes every source vertex
            has its input coordinates bit for bit.

        Raises
        ------
        MeshError
            If ``V`` does not have the solve mesh's vertex count or ``frames``/``K`` do not
            fit it.
        """
        V = np.asarray(V, dtype=np.float64)
        if V.ndim != 3 or V.shape[1:] != (self.n_solve, 3):
            raise MeshError(f"V must be a (K+1,{self.n_solve},3) sequence on the solve mesh, "
                            f"got shape {V.shape}")
        frames = np.asarray(frames, dtype=np.int64).ravel()
        if K is None:
            K = V.shape[0] - 1
        if int(K) != V.shape[0] - 1 or frames.size != self.exact_V.shape[0] or \
                frames.min() < 0 or frames.max() > K:
            raise MeshError(f"frames {frames.tolist()} and K={K} do not fit a sequence of "
                            f"{V.shape[0]} frames with {self.exact_V.shape[0]} keyframes")
        from scipy.interpolate import make_interp_spline

        periodic = str(bc).lower() == "periodic"
        out = np.zeros((V.shape[0], self.n_source, 3))
        kept = self.to_solve >= 0
        out[:, kept] = V[:, self.to_solve[kept]]
        if self.set_aside.size:
            X = self.exact_V[:, np.searchsorted(self.exact, self.set_aside)]   # (J,s,3)
            fin = self.anchors[:, 0] >= 0
            local = X.copy()                                     # isolated: world coordinates
            if fin.any():
                origin, R = face_frames(V, self.anchors[fin])   # (K+1,f,3), (K+1,f,3,3)
                local[:, fin] = np.einsum("jsba,jsb->jsa", R[frames], X[:, fin] - origin[frames])
            # piecewise linear in time through the keyframes; periodic: back to keyframe 0 at
            # frame K; frames after the last keyframe hold it
            t, Y = frames.astype(np.float64), local
            if periodic:
                t, Y = np.append(t, float(K)), np.concatenate([local, local[:1]])
            k = np.clip(np.arange(K + 1, dtype=np.float64), t[0], t[-1])
            loc = make_interp_spline(t, Y, k=1, axis=0)(k)
            if fin.any():
                loc[:, fin] = origin + np.einsum("ksab,ksb->ksa", R, loc[:, fin])
            out[:, self.set_aside] = loc
        for j, f in enumerate(frames):
            out[f, self.exact] = self.exact_V[j]
        if periodic and self.exact.size:
            out[K, self.exact] = self.exact_V[0]
        return out


def face_frames(V: np.ndarray, tri: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Origin and orthonormal frame of triangles in every pose (the frame a fin's set-aside
    vertex moves with: :meth:`SourceMesh.expand`, :func:`shellspline.animation.mesh_on_source`).

    Parameters
    ----------
    V : (K,n,3) float64 numpy array
        Poses.
    tri : (f,3) int numpy array
        Triangles ``(a, b, c)``.

    Returns
    -------
    origin : (K,f,3) float64 numpy array
        Their corner ``a``.
    frame : (K,f,3,3) float64 numpy array
        ``[e1 e2 n]`` as columns: ``e1`` along ``ab``, ``n`` the unit normal, ``e2 = n x e1``.
    """
    a, b, c = V[:, tri[:, 0]], V[:, tri[:, 1]], V[:, tri[:, 2]]
    e1 = b - a
    n = normalized(cross(e1, c - a))
    e1 = normalized(e1)
    e2 = cross(n, e1)
    return a, np.stack([e1, e2, n], axis=-1)


# ----------------------------------------------------------------------------------------
# Triangulation
# ----------------------------------------------------------------------------------------
def triangulate_polygons(Vs, offsets, indices, name: str = "mesh"):
    """Triangulate polygons once for a whole set of poses.

    Parameters
    ----------
    Vs : (J,n,3) float array
        The poses (keyframes).
    offsets : (P+1,) int array
        Polygon ``p`` is ``indices[offsets[p]:offsets[p+1]]`` (at least 3 corners).
    indices : (N,) int array
        Corner vertex indices.
    name : str
        Used in error messages.

    Returns
    -------
    F : (t,3) int64 numpy array
        Triangles, oriented like their polygon, polygons in order.
    polygon : (t,) int64 numpy array
        The polygon each triangle comes from.

    Raises
    ------
    MeshError
        If an n-gon cannot be triangulated, or n-gons are present and ``mapbox_earcut`` is
        not installed.

    Notes
    -----
    A triangle's quality is ``4 sqrt(3) A / (l1² + l2² + l3²)`` (1 for an equilateral
    triangle), with the area ``A`` signed against the polygon's Newell normal in that pose, so
    a triangle that folds over its polygon scores below zero. Among the candidates of a
    polygon the one whose worst triangle over all poses scores highest is kept; ties (scores
    within :data:`QUALITY_TIE`, 1e-6, of the best) keep the first candidate (for a quad
    ``abcd``: the diagonal ``ac``). The quality is unit-free and computed on each polygon
    moved to its centre and divided by its size, so the choice does not depend on the unit
    or the placement of the poses (round-off cannot break a tie).

    Examples
    --------
    >>> import numpy as np
    >>> V = np.array([[0., 0, 0], [4, 0, 0], [4, 1, 0], [0, 1, 0]])  # a long thin quad
    >>> V2 = V.copy(); V2[2, 2] = 1.0                                    # ... bent in pose 2
    >>> F, p = triangulate_polygons(np.stack([V, V2]), [0, 4], [0, 1, 2, 3])
    >>> F.tolist(), p.tolist()
    ([[1, 2, 3], [1, 3, 0]], [0, 0])
    """
    Vs = np.asarray(Vs, dtype=np.float64)
    offsets = np.asarray(offsets, dtype=np.int64)
    indices = np.asarray(indices, dtype=np.int64)
    sizes = np.diff(offsets)
    P = sizes.size
    tris: list[np.ndarray] = []
    owner: list[np.ndarray] = []
    for s in np.unique(sizes):
        polys = np.flatnonzero(sizes == s)
        C = indices[offsets[polys][:, None] + np.arange(s)]     # (p,s)
        if s == 3:
            T = C[:, None, :]
        elif s == 4:
            cand = np.stack([C[:, [0, 1, 2, 0, 2, 3]], C[:, [1, 2, 3, 1, 3, 0]]], axis=1)
            cand = cand.reshape(len(polys), 2, 2, 3)
            step = max(1, _CHUNK // Vs.shape[0])  # bounded memory: (J, step, 2, 2, 3) arrays
            T = np.concatenate([_best_candidate(Vs, C[a:a + step], cand[a:a + step])
                                for a in range(0, len(polys), step)])
        else:
            T = _earcut_polygons(Vs, C, polys, name)
        tris.append(T.reshape(-1, 3))
        owner.append(np.repeat(polys, T.shape[1]))
    F = np.concatenate(tris) if tris else np.zeros((0, 3), dtype=np.int64)
    own = np.concatenate(owner) if owner else np.zeros(0, dtype=np.int64)
    order = np.argsort(own, kind="stable")
    assert P == 0 or own.max() < P
    return F[order].astype(np.int64), own[order].astype(np.int64)


def _newell_normals(Vs: np.ndarray, C: np.ndarray) -> np.ndarray:
    """Newell normals (J,p,3) of polygons ``C`` (p,s) in every pose (unnormalised)."""
    P0 = Vs[:, C]                        # (J,p,s,3)
    P1 = np.roll(P0, -1, axis=2)
    return cross(P0, P1).sum(axis=2) * 0.5


#: Candidate triangulations whose worst quality (a unit-free number in [-1, 1]) is within
#: this of the best are tied, and the first of them is kept: round-off must not decide
#: between the two diagonals of a symmetric quad, or the choice would depend on the unit of
#: the coordinates (float64 round-off, ~1e-16) or on their precision (float32 point caches,
#: ~1e-7, against the float64 OBJ of the same poses).
QUALITY_TIE = 1e-6


def _best_candidate(Vs: np.ndarray, C: np.ndarray, cand: np.ndarray) -> np.ndarray:
    """Per polygon, the candidate triangulation (c of cand (p,c,t,3)) with the best worst
    signed quality over all poses; returns (p,t,3). The quality is unit-free (each pose is
    divided by its polygon's size first), and candidates within :data:`QUALITY_TIE` of the
    best count as tied: the first of them is kept, whatever the scale of the poses."""
    best = _first_best(_candidate_scores(Vs, C, cand))           # (p,)
    return cand[np.arange(cand.shape[0]), best]


def _first_best(score: np.ndarray) -> np.ndarray:
    """Per row of ``score`` (p,c), the first candidate within :data:`QUALITY_TIE` of the best."""
    tied = score >= score.max(axis=1, keepdims=True) - QUALITY_TIE
    return np.argmax(tied, axis=1)


def _candidate_scores(Vs: np.ndarray, C: np.ndarray, cand: np.ndarray) -> np.ndarray:
    """Worst signed quality (p,c) over all poses and triangles of each candidate triangulation
    ``cand`` (p,c,t,3) of polygons ``C`` (p,s) (see :func:`_best_candidate`)."""
    P = Vs[:, C]                                                  # (J,p,s,3)
    centre = P.mean(axis=2)
    size = np.sqrt(((P - centre[:, :, None]) ** 2).sum(axis=(2, 3)))   # (J,p)
    size = np.where(size > 0, size, 1.0)
    N = normalized(_newell_normals(Vs, C))                       # (J,p,3)

    def corner(i):  # (J,p,c,t,3), unit-free: relative to the polygon's centre and size
        return (Vs[:, cand[..., i]] - centre[:, :, None, None]) / size[:, :, None, None, None]

    A, B, Cc = corner(0), corner(1), corner(2)
    area2 = np.einsum("jpctx,jpx->jpct", cross(B - A, Cc - A), N)
    l2 = (((B - A) ** 2).sum(-1) + ((Cc - B) ** 2).sum(-1) + ((A - Cc) ** 2).sum(-1))
    with np.errstate(invalid="ignore", divide="ignore"):
        q = np.where(l2 > 0, 0.5 * _SQRT3x4 * area2 / np.where(l2 > 0, l2, 1.0), -2.0)
    return q.min(axis=(0, 3))                                     # (p,c)


#: Polygons of up to this many corners that ear clipping cannot triangulate without a
#: triangle folding over the polygon in some pose are triangulated by
#: :func:`_maxmin_triangulation` (O(s³) work and memory per polygon; the triangles are
#: scored in blocks of :data:`_CHUNK` triangles x keyframes: a 64-gon over 50 keyframes
#: took 350 MB at once, 1.4 GB over 200).
MAXMIN_CORNERS = 64


def _maxmin_triangulation(Vs: np.ndarray, C: np.ndarray) -> tuple[np.ndarray, float]:
    """Among all triangulations of the polygon ``C`` (s,) by its diagonals, the one whose worst
    signed quality over all poses and triangles is best (``(s-2,3)`` corners, oriented like
    the polygon), and that quality: dynamic programming over the corner intervals.

    A triangulation whose triangles all have positive area against the polygon's normal in a
    pose covers the polygon exactly once there, so a positive score means valid in every
    pose; ear clipping, run on each pose alone, can miss such a triangulation."""
    s = C.size
    i, k, j = (a.ravel() for a in np.meshgrid(*(np.arange(s),) * 3, indexing="ij"))
    keep = (i < k) & (k < j)
    i, k, j = i[keep], k[keep], j[keep]
    score = np.full((s, s, s), -np.inf)
    tri = C[np.stack([i, k, j], axis=1)]            # every triangle of corners, in order
    step = max(1, _CHUNK // Vs.shape[0])             # bounded memory: (J, step, 3) arrays
    for a in range(0, tri.shape[0], step):
        b = slice(a, a + step)
        score[i[b], k[b], j[b]] = _candidate_scores(Vs, C[None], tri[None, b, None])[0]
    best = np.full((s, s), np.inf)                   # best[a, b]: the chain a..b closed by ab
    split = np.zeros((s, s), dtype=np.int64)
    for length in range(2, s):
        for a in range(s - length):
            b = a + length
            mid = np.arange(a + 1, b)
            val = np.minimum(np.minimum(best[a, mid], best[mid, b]), score[a, mid, b])
            m = int(np.argmax(val))                  # the first of equals: deterministic
            best[a, b], split[a, b] = val[m], mid[m]
    tris, stack = [], [(0, s - 1)]
    while stack:
        a, b = stack.pop()
        m = int(split[a, b])
        tris.append([a, m, b])
        stack += [(x, y) for x, y in ((a, m), (m, b)) if y - x >= 2]
    tris.sort()
    return C[np.array(tris, dtype=np.int64)], float(best[0, s - 1])


def _earcut_polygons(Vs: np.ndarray, C: np.ndarray, polys: np.ndarray, name: str) -> np.ndarray:
    """Triangulations (p,s-2,3) of s-gons by ear clipping in their plane, best over poses;
    where every ear-clipping candidate folds in some pose, the best triangulation of all
    (:func:`_maxmin_triangulation`, up to :data:`MAXMIN_CORNERS` corners)."""
    try:
        import mapbox_earcut
    except ImportError:
        raise MeshError(f"{name}: {len(polys)} polygons with {C.shape[1]} corners need the "
                        "optional package mapbox_earcut (pip install 'shellspline[dcc]')"
                        ) from None
    J, (p, s) = Vs.shape[0], C.shape
    N = _newell_normals(Vs, C)
    rings = np.array([s], dtype=np.uint32)
    out = np.zeros((p, s - 2, 3), dtype=np.int64)
    found = []                                                     # per polygon: (c,s-2,3)
    for i in range(p):
        cands = []
        for j in range(J):
            n = N[j, i]
            nn = np.linalg.norm(n)
            if nn == 0:
                continue
            n = n / nn
            u = np.cross(n, [1.0, 0, 0] if abs(n[0]) < 0.9 else [0, 1.0, 0])
            u /= np.linalg.norm(u)
            w = np.cross(n, u)
            X = Vs[j, C[i]]
            xy = np.stack([X @ u, X @ w], axis=1)
            t = np.asarray(mapbox_earcut.triangulate_float64(xy, rings), dtype=np.int64)
            if t.size != 3 * (s - 2):
                continue
            t = t.reshape(-1, 3)
            d = xy[t]
            cross = ((d[:, 1, 0] - d[:, 0, 0]) * (d[:, 2, 1] - d[:, 0, 1])
                     - (d[:, 1, 1] - d[:, 0, 1]) * (d[:, 2, 0] - d[:, 0, 0]))
            t[cross < 0] = t[cross < 0][:, [0, 2, 1]]
            t = t[np.lexsort(t.T[::-1])]
            if not any(np.array_equal(t, c) for c in cands):
                cands.append(t)
        found.append(C[i][np.stack(cands)] if cands else None)
    # the candidates scored together, polygons with as many candidates in one block each
    worst = np.zeros(p)
    counts = np.array([0 if f is None else f.shape[0] for f in found])
    for c in np.unique(counts[counts > 0]):
        rows = np.flatnonzero(counts == c)
        step = max(1, _CHUNK // (J * c * (s - 2)))  # bounded memory: (J,step,c,s-2,3) arrays
        for a in range(0, rows.size, step):
            r = rows[a:a + step]
            cand = np.stack([found[i] for i in r])                 # (r,c,s-2,3)
            score = _candidate_scores(Vs, C[r], cand)              # (r,c)
            best = _first_best(score)
            out[r], worst[r] = cand[np.arange(r.size), best], score[np.arange(r.size), best]
    for i in np.flatnonzero(worst <= 0):  # folds (or none) in some pose: try them all
        ok = found[i] is not None
        if s <= MAXMIN_CORNERS:
            T, score = _maxmin_triangulation(Vs, C[i])
            if score > worst[i] if ok else score > 0:
                out[i], worst[i], ok = T, score, True
        if not ok:
            raise MeshError(f"{name}: polygon {int(polys[i])} with {s} corners cannot be "
                            "triangulated (degenerate or self-intersecting in every keyframe)")
    return out


# ----------------------------------------------------------------------------------------
# Welding, fins, set-aside vertices
# ----------------------------------------------------------------------------------------
def _weld_map(Vs: np.ndarray) -> np.ndarray:
    """Representative (lowest index) of every vertex among those coincident in all poses."""
    J, n = Vs.shape[:2]
    rep = np.arange(n)
    lo, hi = Vs[0].min(axis=0), Vs[0].max(axis=0)
    diag = float(np.linalg.norm(hi - lo))
    if not np.isfinite(diag) or diag == 0 or n < 2:
        return rep
    cell = WELD_TOLERANCE * diag
    Q0 = np.round((Vs[0] - lo) / cell).astype(np.int64)
    # candidates: one hashed key per vertex (a collision only adds a candidate; the grouping
    # below compares the full keys of every keyframe)
    h = Q0[:, 0] * np.int64(1000003) ^ Q0[:, 1] * np.int64(998244353) ^ Q0[:, 2]
    _, inv0, counts0 = np.unique(h, return_inverse=True, return_counts=True)
    cand = np.flatnonzero(counts0[inv0.ravel()] > 1)
    if cand.size == 0:
        return rep
    Q = np.round((Vs[:, cand] - lo) / cell).astype(np.int64)        # (J,c,3)
    key = Q.transpose(1, 0, 2).reshape(cand.size, -1)
    _, inv = np.unique(key, axis=0, return_inverse=True)
    inv = inv.ravel()
    first = np.full(inv.max() + 1, n, dtype=np.int64)
    np.minimum.at(first, inv, cand)
    rep[cand] = first[inv]
    return rep


def _fin_faces(F: np.ndarray, n: int) -> np.ndarray:
    """Mask of faces set aside so that no edge keeps more than two faces (see module doc)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    m = F.shape[0]
    # a face repeating an earlier one (same three vertices, either orientation) is a fin
    S = np.sort(F, axis=1)
    if n < 1 << 21:  # one int64 key per face
        order = np.argsort((S[:, 0] << 42) | (S[:, 1] << 21) | S[:, 2], kind="stable")
    else:
        order = np.lexsort((S[:, 2], S[:, 1], S[:, 0]))
    Ss = S[order]
    fins = np.zeros(m, dtype=bool)
    fins[order[1:][(Ss[1:] == Ss[:-1]).all(axis=1)]] = True
    if fins.any():
        rest = np.flatnonzero(~fins)
        fins[rest[_fin_faces(F[rest], n)]] = True
        return fins
    src, dst = F[:, [1, 2, 0]].ravel(), F[:, [2, 0, 1]].ravel()
    key = np.minimum(src, dst) * np.int64(n) + np.maximum(src, dst)
    face = np.repeat(np.arange(m), 3)
    _, inv, counts = np.unique(key, return_inverse=True, return_counts=True)
    if (counts <= 2).all():
        return fins
    # sheets: faces connected through edges with exactly two faces
    two = counts[inv] == 2
    order = np.argsort(inv[two], kind="stable")
    pairs = face[two][order].reshape(-1, 2)
    adj = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(m, m))
    _, sheet = connected_components(adj, directed=False)
    size = np.bincount(sheet)
    by_edge = np.argsort(inv, kind="stable")                      # halfedges grouped by edge
    first = np.concatenate([[0], np.cumsum(counts)])
    for _ in range(m):  # each round sets aside at least one sheet, or stops
        live = ~fins[face]
        c = np.bincount(inv[live], minlength=counts.size)
        bad = np.flatnonzero(c > 2)
        if bad.size == 0:
            break
        drop = set()
        for e in bad:
            fs = face[by_edge[first[e]:first[e + 1]]]
            fs = fs[~fins[fs]]
            sh, nf = np.unique(sheet[fs], return_counts=True)
            rank = np.lexsort((sh, -size[sh]))
            kept = 0
            for r in rank:
                if r == rank[0] or kept + nf[r] <= 2:
                    kept += nf[r]
                else:
                    drop.add(int(sh[r]))
        if not drop:
            break  # a sheet meets itself on an edge: left for topology() to report
        fins |= np.isin(sheet, list(drop))
    return fins


def _reoriented(F: np.ndarray, n: int) -> np.ndarray:
    """Faces to reverse so that every edge with two faces is traversed both ways: in each
    connected component (through such edges) the minority orientation is reversed. A
    non-orientable component (a Moebius strip) is left alone, for topology() to report."""
    m = F.shape[0]
    flip = np.zeros(m, dtype=bool)
    src, dst = F[:, [1, 2, 0]].ravel(), F[:, [2, 0, 1]].ravel()
    key = np.minimum(src, dst) * np.int64(n) + np.maximum(src, dst)
    order = np.argsort(key, kind="stable")
    pair = key[order][1:] == key[order][:-1]
    i, j = order[:-1][pair], order[1:][pair]
    same = src[i] == src[j]                     # same direction: the two faces disagree
    if not same.any():
        return flip
    fa, fb = i // 3, j // 3
    a, b, d = np.r_[fa, fb], np.r_[fb, fa], np.r_[same, same]
    by = np.argsort(a, kind="stable")
    nbr, disagree = b[by].tolist(), d[by].tolist()
    ptr = np.searchsorted(a[by], np.arange(m + 1)).tolist()
    parity = [-1] * m
    for root in range(m):
        if parity[root] >= 0:
            continue
        parity[root] = 0
        stack, comp = [root], [root]
        while stack:
            f = stack.pop()
            for e in range(ptr[f], ptr[f + 1]):
                g, want = nbr[e], parity[f] ^ disagree[e]
                if parity[g] < 0:
                    parity[g] = want
                    stack.append(g)
                    comp.append(g)
                elif parity[g] != want:
                    return np.zeros(m, dtype=bool)  # not orientable: left to topology()
        ones = sum(parity[f] for f in comp)
        if 2 * ones > len(comp):
            for f in comp:
                parity[f] ^= 1
    return np.array(parity, dtype=bool)


def solve_mesh(Vs, offsets, indices, name: str = "mesh", uv=None, *, statements=None):
    """Split an input mesh into the solve mesh and its :class:`SourceMesh` map.

    Parameters
    ----------
    Vs : (J,n,3) float64 numpy array
        Keyframe poses of the input vertices (finite).
    offsets : (P+1,) int64 numpy array
        Polygon offsets (see :class:`SourceMesh`).
    indices : (N,) int64 numpy array
        Polygon corners, in ``[0, n)``.
    name : str
        Used in error messages.
    uv : tuple ``(uv (t,2), corner_uv (N,))`` or None
        Texture coordinates to carry back to the output (they make ``source`` not ``None``).
    statements : tuple or None
        OBJ material and group lines to carry back (:attr:`SourceMesh.statements`; they
        make ``source`` not ``None``).

    Returns
    -------
    V : (J,n_solve,3) float64 numpy array
        Solve-mesh poses.
    F : (m,3) int64 numpy array
        Solve-mesh triangles.
    source : SourceMesh or None
        ``None`` when the input is already a triangle mesh without texture coordinates or
        material and group lines, and with nothing welded or set aside (then ``V`` and ``F``
        are the inputs).
    tri_polygon : (m,) int64 numpy array
        Input polygon of every solve triangle (for messages).
    """
    J, n = Vs.shape[:2]
    sizes = np.diff(offsets)
    if (sizes == 3).all():
        tris, tri_poly = indices.reshape(-1, 3), np.arange(sizes.size, dtype=np.int64)
    else:
        tris, tri_poly = triangulate_polygons(Vs, offsets, indices, name)
    rep = _weld_map(Vs)
    F = rep[tris]
    fins = _fin_faces(F, n)
    flip = np.zeros(F.shape[0], dtype=bool)
    flip[~fins] = _reoriented(F[~fins], n)
    used = np.zeros(n, dtype=bool)
    used[F[~fins].ravel()] = True
    welded = rep != np.arange(n)
    if (sizes == 3).all() and not welded.any() and not fins.any() and used.all() and \
            uv is None and statements is None and not flip.any():
        return Vs, tris, None, tri_poly
    F = np.where(flip[:, None], F[:, [0, 2, 1]], F)
    keep_v = np.flatnonzero(used & ~welded)     # representatives used by kept faces
    solve_of = np.full(n, -1, dtype=np.int64)
    solve_of[keep_v] = np.arange(keep_v.size)
    to_solve = solve_of[rep]
    Fs = to_solve[F[~fins]]
    set_aside = np.flatnonzero(to_solve < 0)
    anchors = np.full((set_aside.size, 3), -1, dtype=np.int64)
    on_fin = np.isin(rep[set_aside], F[fins])
    if on_fin.any():
        from scipy.spatial import cKDTree

        _, near = cKDTree(Vs[0, keep_v]).query(Vs[0, set_aside[on_fin]])
        first_face = np.full(keep_v.size, -1, dtype=np.int64)
        first_face[Fs[::-1].ravel()] = np.repeat(np.arange(Fs.shape[0])[::-1], 3)
        anchors[on_fin] = Fs[first_face[near]]
    exact = np.flatnonzero((to_solve < 0) | welded)
    src = SourceMesh(n_source=n, poly_offsets=offsets, poly_indices=indices, triangles=tris,
                     to_solve=to_solve, set_aside=set_aside, anchors=anchors, exact=exact,
                     exact_V=np.ascontiguousarray(Vs[:, exact]),
                     fin_polygons=np.unique(tri_poly[fins]), n_welded=int(welded.sum()),
                     n_reoriented=int(np.unique(tri_poly[flip]).size),
                     uv=None if uv is None else uv[0], corner_uv=None if uv is None else uv[1],
                     statements=statements)
    return np.ascontiguousarray(Vs[:, keep_v]), Fs, src, tri_poly[~fins]

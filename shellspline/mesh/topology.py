"""Connectivity tables of a triangle mesh, built once and shared by every stage.

All tables are plain numpy arrays computed with vectorised sorting (no Python loop over
faces or edges).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import MeshError

__all__ = ["Topology", "topology"]


@dataclass(frozen=True)
class Topology:
    """Connectivity of a consistently oriented, edge-manifold triangle mesh.

    Attributes
    ----------
    F : (m,3) int64 numpy array
        Faces.
    n_vertices : int
        Number of vertices ``n``.
    E : (e,2) int64 numpy array
        Unique undirected edges, ``E[:,0] < E[:,1]``.
    edge_faces : (e,2) int64 numpy array
        The (up to two) faces of each edge; ``-1`` where an edge has a single face.
        ``edge_faces[:,0]`` is the face in which the edge runs ``E[:,0] -> E[:,1]`` when it
        exists, otherwise the only face.
    face_edges : (m,3) int64 numpy array
        ``face_edges[t,c]`` is the edge opposite corner ``c`` of face ``t``.
    interior : (i,) int64 numpy array
        Indices into ``E`` of the interior edges (two faces).
    flaps : (i,4) int64 numpy array
        For each interior edge the stencil ``(v0, v1, v2, v3)``: the edge runs ``v0 -> v1`` in
        face ``(v0, v1, v2)`` and ``v1 -> v0`` in face ``(v1, v0, v3)``.
    boundary_vertices : (b,) int64 numpy array
        Vertices on a boundary edge, sorted.
    """

    F: np.ndarray
    n_vertices: int
    E: np.ndarray
    edge_faces: np.ndarray
    face_edges: np.ndarray
    interior: np.ndarray
    flaps: np.ndarray
    boundary_vertices: np.ndarray
    _cache: dict = field(default_factory=dict, repr=False, compare=False)

    @property
    def n_edges(self) -> int:
        return int(self.E.shape[0])

    @property
    def n_faces(self) -> int:
        return int(self.F.shape[0])

    @property
    def n_interior(self) -> int:
        return int(self.interior.shape[0])

    @property
    def n_descriptors(self) -> int:
        """Length of the LΘA vector ``z = (L, Θ, A)``: ``e + i + m``."""
        return self.n_edges + self.n_interior + self.n_faces

    @property
    def n_components(self) -> int:
        """Number of edge-connected components of the faces (vertices in no face do not
        count); computed once."""
        if "n_components" not in self._cache:
            from scipy.sparse import coo_matrix
            from scipy.sparse.csgraph import connected_components

            n = self.n_vertices
            A = coo_matrix((np.ones(len(self.E)), (self.E[:, 0], self.E[:, 1])), shape=(n, n))
            _, label = connected_components(A, directed=False)
            self._cache["n_components"] = int(np.unique(label[np.unique(self.F)]).size) \
                if self.F.size else 0
        return self._cache["n_components"]

    def descriptor_slices(self) -> tuple[slice, slice, slice]:
        """Slices of ``L``, ``Θ`` and ``A`` inside a descriptor vector ``z``."""
        e, i = self.n_edges, self.n_interior
        return slice(0, e), slice(e, e + i), slice(e + i, e + i + self.n_faces)


def topology(F, n_vertices: int | None = None, *, name: str = "mesh") -> Topology:
    """Build the connectivity tables of a triangle mesh and check it is usable.

    Parameters
    ----------
    F : (m,3) int array
        Triangle faces, zero-based vertex indices.
    n_vertices : int, optional
        Number of vertices; default ``F.max() + 1``.
    name : str
        Name used in error messages (typically the file name).

    Returns
    -------
    Topology

    Raises
    ------
    MeshError
        If ``F`` is not an ``(m,3)`` integer array, indexes vertices out of range, has a face
        with a repeated vertex, an edge shared by more than two faces, or two faces that
        traverse a shared edge in the same direction (inconsistent orientation).

    Examples
    --------
    >>> import numpy as np
    >>> T = topology(np.array([[0, 1, 2], [2, 1, 3]]))
    >>> T.E.tolist(), T.flaps.tolist()
    ([[0, 1], [0, 2], [1, 2], [1, 3], [2, 3]], [[1, 2, 0, 3]])
    """
    F = np.asarray(F)
    if F.ndim != 2 or F.shape[1] != 3:
        raise MeshError(f"{name}: faces must be an (m,3) array of triangles, got shape {F.shape}")
    if F.shape[0] == 0:
        raise MeshError(f"{name}: the mesh has no faces")
    if not np.issubdtype(F.dtype, np.integer):
        raise MeshError(f"{name}: face indices must be integers, got dtype {F.dtype}")
    F = F.astype(np.int64, copy=False)
    if n_vertices is None:
        n_vertices = int(F.max()) + 1
    if F.min() < 0 or F.max() >= n_vertices:
        raise MeshError(f"{name}: face indices must lie in [0, {n_vertices}), got range "
                        f"[{F.min()}, {F.max()}]")
    bad = (F[:, 0] == F[:, 1]) | (F[:, 1] == F[:, 2]) | (F[:, 2] == F[:, 0])
    if bad.any():
        t = int(np.flatnonzero(bad)[0])
        raise MeshError(f"{name}: face {t} {F[t].tolist()} repeats a vertex "
                        f"({int(bad.sum())} such faces)")
    m = F.shape[0]
    # Halfedge c of face t runs F[t,c+1] -> F[t,c+2] (opposite corner c).
    src = F[:, [1, 2, 0]].ravel()
    dst = F[:, [2, 0, 1]].ravel()
    lo, hi = np.minimum(src, dst), np.maximum(src, dst)
    key = lo * np.int64(n_vertices) + hi
    uniq, inv, counts = np.unique(key, return_inverse=True, return_counts=True)
    if (counts > 2).any():
        u = int(np.flatnonzero(counts > 2)[0])
        a, b = divmod(int(uniq[u]), n_vertices)
        raise MeshError(f"{name}: non-manifold edge ({a}, {b}) is shared by {int(counts[u])} "
                        f"faces ({int((counts > 2).sum())} such edges)")
    dkey = src * np.int64(n_vertices) + dst
    ds = np.sort(dkey)
    dup = ds[1:] == ds[:-1]
    if dup.any():
        a, b = divmod(int(ds[1:][dup][0]), n_vertices)
        raise MeshError(f"{name}: faces are not consistently oriented: two faces traverse edge "
                        f"({a}, {b}) in the same direction ({int(dup.sum())} such edges)")
    e = uniq.shape[0]
    E = np.stack([uniq // n_vertices, uniq % n_vertices], axis=1)
    face_of_he = np.repeat(np.arange(m, dtype=np.int64), 3)
    face_edges = inv.reshape(m, 3).astype(np.int64)
    forward = src < dst  # halfedge runs E[:,0] -> E[:,1]
    edge_faces = np.full((e, 2), -1, dtype=np.int64)
    # forward halfedges go to slot 0, backward to slot 1, then compact single-face edges
    edge_faces[inv[forward], 0] = face_of_he[forward]
    edge_faces[inv[~forward], 1] = face_of_he[~forward]
    only_back = edge_faces[:, 0] < 0
    edge_faces[only_back, 0] = edge_faces[only_back, 1]
    edge_faces[only_back, 1] = -1
    interior = np.flatnonzero(edge_faces[:, 1] >= 0).astype(np.int64)
    # flap stencil: v0 = E0, v1 = E1, v2 = corner opposite in forward face, v3 in backward face
    corner = np.tile(np.arange(3), m)
    opp_vertex = F[face_of_he, corner]
    v2 = np.full(e, -1, dtype=np.int64)
    v3 = np.full(e, -1, dtype=np.int64)
    v2[inv[forward]] = opp_vertex[forward]
    v3[inv[~forward]] = opp_vertex[~forward]
    flaps = np.stack([E[interior, 0], E[interior, 1], v2[interior], v3[interior]], axis=1)
    bnd = edge_faces[:, 1] < 0
    boundary_vertices = np.unique(E[bnd].ravel())
    return Topology(F=F, n_vertices=int(n_vertices), E=E, edge_faces=edge_faces,
                    face_edges=face_edges, interior=interior, flaps=flaps,
                    boundary_vertices=boundary_vertices)

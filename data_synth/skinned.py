"""A body mesh skinned to a BVH skeleton: mesh animations with known in-betweens.

:func:`skinned_sequence` builds one closed, consistently oriented triangle mesh around the
bones of a skeleton and poses it at every frame of a BVH clip by *linear blend skinning*
(LBS), the way game engines and rigs produce mesh animations. Every frame is known, so a
subset can serve as keyframes and the rest as ground truth for in-betweens. The sequences
have what real rigs have: knees and elbows flexing (skin folding and the LBS volume loss at
joints), a body that travels and turns (root motion), several bones per vertex.

Construction (deterministic, no dependency beyond numpy/scipy and shellspline):

1. Forward kinematics of the clip (:mod:`shellspline.io.bvh`). Bones are the segments from a
   joint to each child joint (and to non-zero ``End Site`` offsets); a bone moves rigidly
   with its *parent* joint. Zero-length bones are dropped, and so is the segment from a root
   to a child whose position channels move (a ground-reference root such as the Bandai
   Namco ``joint_Root``: that segment is not part of the body).
2. Bind pose: the clip frame where non-neighbouring bones (three or more bones apart) are
   farthest apart relative to their radii, so that arms and legs are as free as the clip
   allows. Radii grow with the number of joints below a bone (torso thicker than limbs):
   ``r = radius * H * (1 + subtree)**(1/3)`` with ``H`` the skeleton's extent in that pose;
   leaf joints get a ball (head, hands, toes).
3. Surface: the zero set of a smooth union (log-sum-exp) of capsule distances, sampled on a
   regular grid and extracted by *marching tetrahedra* (six Kuhn tetrahedra per cube: the
   zero set of the piecewise-linear interpolant is a closed 2-manifold, oriented by the
   side of the inside nodes), then decimated to ``n_vertices`` by
   :func:`shellspline.mesh.decimate` (which removes the slivers marching tetrahedra leaves).
4. Weights: per vertex, inverse distance to the bones of each joint, ``((d_min + s) / (d_j
   + s))**4``, the ``max_influences`` largest kept and normalised.
5. Pose: ``v(t) = Σ_j w_j (R_j(t) R_j(b)ᵀ (v − p_j(b)) + p_j(t))`` with ``b`` the bind frame.
"""
from __future__ import annotations

import numpy as np

__all__ = ["skinned_sequence", "skinned_body", "linear_blend_skinning", "skeleton_bones",
           "marching_tetrahedra"]

# Kuhn subdivision of the unit cube into 6 tetrahedra around the diagonal 0 -> 7 (corner
# index = 4x + 2y + z): consistent across neighbouring cubes, so the surface is watertight.
_CORNERS = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)])
_KUHN = np.array([[0, 4, 6, 7], [0, 4, 5, 7], [0, 2, 6, 7], [0, 2, 3, 7], [0, 1, 5, 7],
                  [0, 1, 3, 7]])


def skeleton_bones(motion, P, R):
    """Bone segments of a skeleton at every frame.

    Parameters
    ----------
    motion : shellspline.io.bvh.Motion
    P : (T,J,3) float array
        Joint positions (from :func:`shellspline.io.bvh.forward_kinematics`).
    R : (T,J,3,3) float array
        Joint rotations.

    Returns
    -------
    A : (T,B,3) float64 numpy array
        Bone start points (the driving joint's origin).
    Bend : (T,B,3) float64 numpy array
        Bone end points (child joint or End Site).
    driver : (B,) int64 numpy array
        Joint that moves each bone rigidly (the parent joint of the segment).
    subtree : (B,) int64 numpy array
        Number of joints at and below the bone's end (1 for End Sites).
    leaf : (B,) bool numpy array
        Whether the bone's end is a leaf of the body (no further bone starts there).
    """
    J = motion.n_joints
    vals = motion.values
    H = np.ptp(P.reshape(-1, 3), axis=0).max() if P.size else 1.0
    size = np.ones(J, dtype=np.int64)
    for j in range(J - 1, -1, -1):
        if motion.parents[j] >= 0:
            size[motion.parents[j]] += size[j]
    starts, ends, driver, subtree = [], [], [], []
    for c in range(J):
        p = motion.parents[c]
        if p < 0:
            continue
        if motion.parents[p] < 0:
            cols = [col for col, name in zip(motion.channel_columns(c), motion.channels[c])
                    if name.endswith("position")]
            if cols and np.ptp(vals[:, cols], axis=0).max(initial=0.0) > 1e-6 * H:
                continue  # a ground-reference root: not a body segment
        starts.append(P[:, p])
        ends.append(P[:, c])
        driver.append(p)
        subtree.append(size[c])
    for p, off in motion.end_sites:
        starts.append(P[:, p])
        ends.append(P[:, p] + R[:, p] @ off)
        driver.append(p)
        subtree.append(1)
    if not starts:
        from shellspline.errors import ShellsplineError

        raise ShellsplineError(f"skeleton_bones: the skeleton ({', '.join(motion.names)}) has "
                               "no bone to build a body around")
    A = np.stack(starts, axis=1)
    Bend = np.stack(ends, axis=1)
    length = np.linalg.norm(Bend[0] - A[0], axis=1)
    keep = length > 1e-6 * H
    A, Bend = A[:, keep], Bend[:, keep]
    driver = np.asarray(driver, dtype=np.int64)[keep]
    subtree = np.asarray(subtree, dtype=np.int64)[keep]
    # a bone's end is a leaf when no kept bone starts at the same point
    d = np.linalg.norm(Bend[0][:, None] - A[0][None], axis=2)
    leaf = ~np.any(d < 1e-6 * H, axis=1)
    return A, Bend, driver, subtree, leaf


def _segment_distances(X, A, B):
    """Distances (n,B) from points X (n,3) to segments A[b]-B[b] (B,3)."""
    AB = B - A
    L2 = np.maximum(np.einsum("bi,bi->b", AB, AB), 1e-300)
    XA = X[:, None, :] - A[None]
    t = np.clip(np.einsum("nbi,bi->nb", XA, AB) / L2, 0.0, 1.0)
    return np.linalg.norm(XA - t[..., None] * AB[None], axis=2)


def _smooth_union(A, B, r, lo, h, shape, k):
    """Grid samples of ``-k log Σ_b exp(-(dist(x, A_b B_b) - r_b) / k)`` (a smooth minimum
    of capsule distances), each capsule evaluated only inside its box widened by ``20 k``
    (beyond, its term is below ``exp(-20)`` of the nearest capsule's near the surface)."""
    S = np.zeros(shape)
    pad = r + 20.0 * k
    for a, b, rb, pb in zip(A, B, r, pad):
        i0 = np.maximum(np.floor((np.minimum(a, b) - pb - lo) / h).astype(int), 0)
        i1 = np.minimum(np.ceil((np.maximum(a, b) + pb - lo) / h).astype(int) + 1, shape)
        axes = [lo[d] + h * np.arange(i0[d], i1[d]) for d in range(3)]
        X = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1)
        d = _segment_distances(X.reshape(-1, 3), a[None], b[None])[:, 0] - rb
        S[i0[0]:i1[0], i0[1]:i1[1], i0[2]:i1[2]] += np.exp(-d / k).reshape(X.shape[:3])
    return -k * np.log(np.maximum(S, np.exp(-60.0)))


def _union_value_grad(X, A, B, r, k):
    """The smooth union ``phi`` of :func:`_smooth_union` and its gradient at points X (n,3)."""
    AB = B - A
    L2 = np.maximum(np.einsum("bi,bi->b", AB, AB), 1e-300)
    XA = X[:, None, :] - A[None]
    t = np.clip(np.einsum("nbi,bi->nb", XA, AB) / L2, 0.0, 1.0)
    diff = XA - t[..., None] * AB[None]  # (n,B,3) from the closest point of each axis
    dist = np.maximum(np.linalg.norm(diff, axis=2), 1e-300)
    d = dist - r
    dmin = d.min(axis=1, keepdims=True)
    e = np.exp(-(d - dmin) / k)
    S = e.sum(axis=1, keepdims=True)
    phi = dmin[:, 0] - k * np.log(S[:, 0])
    grad = np.einsum("nb,nbi->ni", e / S, diff / dist[..., None])
    return phi, grad


def _relax(V, F, A, B, r, k, iterations: int = 6):
    """Tangential Laplacian smoothing, each step followed by a projection onto the zero set
    of the capsule union: smooth, well-shaped triangles on the smooth surface (marching
    tetrahedra leaves a faceted, stair-stepped surface and slivers)."""
    import scipy.sparse as sp

    n = V.shape[0]
    i = np.concatenate([F[:, 0], F[:, 1], F[:, 2]])
    j = np.concatenate([F[:, 1], F[:, 2], F[:, 0]])
    adj = sp.csr_matrix((np.ones(i.size), (i, j)), shape=(n, n))
    adj = ((adj + adj.T) > 0).astype(np.float64)
    deg = np.asarray(adj.sum(axis=1)).ravel()
    V = V.copy()
    for _ in range(iterations):
        V_old = V.copy()
        was_inverted = _inverted(V, F, A, B, r, k)
        phi, g = _union_value_grad(V, A, B, r, k)
        nrm = g / np.maximum(np.linalg.norm(g, axis=1, keepdims=True), 1e-300)
        step = adj @ V / deg[:, None] - V
        V += 0.5 * (step - np.einsum("ni,ni->n", step, nrm)[:, None] * nrm)
        for _ in range(2):  # Newton steps onto phi = 0
            phi, g = _union_value_grad(V, A, B, r, k)
            V -= (phi / np.maximum(np.einsum("ni,ni->n", g, g), 1e-300))[:, None] * g
        for _ in range(10):  # undo the moves around a triangle this step turned inside out
            bad = np.unique(F[_inverted(V, F, A, B, r, k) & ~was_inverted])
            if bad.size == 0:
                break
            V[bad] = V_old[bad]
    return V


def _bone_graph_far(driver, A0, B0, H):
    """(B,B) mask of bone pairs at least three bones apart in the skeleton graph."""
    nb = len(driver)
    pts = np.concatenate([A0, B0])
    # identify bone endpoints (joints) by position
    key = np.round(pts / (1e-6 * H)).astype(np.int64)
    _, node = np.unique(key, axis=0, return_inverse=True)
    node = node.reshape(-1)
    ends = np.stack([node[:nb], node[nb:]], axis=1)
    adj = np.zeros((nb, nb), dtype=bool)
    for a in range(2):
        for b in range(2):
            adj |= ends[:, a][:, None] == ends[:, b][None, :]
    reach = (adj | np.eye(nb, dtype=bool)).astype(np.int64)
    return (reach @ reach) == 0  # not within two bones of each other


def _far_pair_distances(A, B, far):
    """Distances (T,p) between the far bone pairs ``(i, j)`` (p,) at every frame (closest
    of 6 sample points per bone)."""
    s = np.linspace(0.0, 1.0, 6)
    pts = A[:, :, None] + s[None, None, :, None] * (B - A)[:, :, None]  # (T,B,6,3)
    i, j = np.nonzero(np.triu(far))
    D = np.empty((A.shape[0], i.size))  # every column is filled below
    for c in range(0, i.size, 64):  # bounded memory: 64 pairs x 36 sample distances x T
        d = pts[:, i[c:c + 64], :, None] - pts[:, j[c:c + 64], None, :]
        D[:, c:c + 64] = np.sqrt(np.einsum("tpabx,tpabx->tpab", d, d)).min(axis=(2, 3))
    return D, i, j


def _bind_and_radii(A, B, radii, reach, far, gap_of_h):
    """Bind frame and capped radii.

    Only pairs of far bones that move relative to each other over the clip count (thighs,
    arm and torso; not neck and shoulders, whose overlap is part of the body): the bind
    frame maximises their smallest clearance ``distance − reach_i − reach_j``, and in that
    frame the radii of a pair are scaled down (at most to half) until their clearance is at
    least ``gap_of_h(radii)``, so that no two body parts are nearly touching: the grid would
    bridge them with a thin web of folded triangles.
    """
    D, i, j = _far_pair_distances(A, B, far)
    moving = np.ptp(D, axis=0) > 0.1 * (reach[i] + reach[j]) if D.size else np.zeros(0, bool)
    if not moving.any():
        return 0, radii
    i, j, D = i[moving], j[moving], D[:, moving]
    clearance = D - reach[i] - reach[j]
    bind = int(np.argmax(clearance.min(axis=1)))
    gap = gap_of_h(radii)
    scale = np.ones_like(radii)
    need = np.clip((D[bind] - gap) / (reach[i] + reach[j]), 0.5, 1.0)
    np.minimum.at(scale, i, need)
    np.minimum.at(scale, j, need)
    return bind, radii * scale


def marching_tetrahedra(phi, origin, h, clamp: float = 0.05):
    """Triangle mesh of the zero set of a grid function (inside: ``phi < 0``).

    Parameters
    ----------
    phi : (nx,ny,nz) float array
        Samples at ``origin + h * (i, j, k)``; must be positive on the grid's boundary for a
        closed surface.
    origin : (3,) float array
    h : float
        Grid spacing.
    clamp : float
        Crossing parameters along tetrahedron edges are clamped to ``[clamp, 1 - clamp]``, so
        no two surface vertices coincide and no triangle is degenerate.

    Returns
    -------
    V : (n,3) float64 numpy array
    F : (m,3) int64 numpy array
        Oriented with normals pointing to ``phi > 0``.
    """
    phi = np.where(phi == 0.0, 1e-12, phi)
    nx, ny, nz = phi.shape
    inside = phi < 0
    flat = phi.ravel()
    cube = np.stack(np.meshgrid(np.arange(nx - 1), np.arange(ny - 1), np.arange(nz - 1),
                                indexing="ij"), axis=-1).reshape(-1, 3)
    strides = np.array([ny * nz, nz, 1])
    corner_id = (cube @ strides)[:, None] + _CORNERS @ strides  # (c,8)
    cin = inside.ravel()[corner_id]
    mixed = cin.any(axis=1) & ~cin.all(axis=1)
    tets = corner_id[mixed][:, _KUHN].reshape(-1, 4)  # (t,4) node ids
    tin = inside.ravel()[tets]
    n_in = tin.sum(axis=1)
    edges_b, out_node = [], []  # (t,3,2) node pairs of each triangle, a node outside
    for case in (1, 3):  # one triangle around the lone vertex (inside for 1, outside for 3)
        sel, s_in = tets[n_in == case], tin[n_in == case]
        lone = s_in if case == 1 else ~s_in
        q = np.take_along_axis(sel, np.argsort(~lone, axis=1, kind="stable"), axis=1)
        edges_b.append(np.stack([np.stack([q[:, 0], q[:, k]], axis=1) for k in (1, 2, 3)],
                                axis=1))
        out_node.append(q[:, 0] if case == 3 else q[:, 1])
    sel = tets[n_in == 2]
    s_in = tin[n_in == 2]
    order = np.argsort(~s_in, axis=1, kind="stable")  # inside a, b first; outside c, d
    q = np.take_along_axis(sel, order, axis=1)
    a, b, c, d = q.T
    quad = [np.stack([a, c], 1), np.stack([a, d], 1), np.stack([b, d], 1), np.stack([b, c], 1)]
    edges_b.append(np.stack([quad[0], quad[1], quad[2]], axis=1))
    out_node.append(c)
    edges_b.append(np.stack([quad[0], quad[2], quad[3]], axis=1))
    out_node.append(c)
    tri_edges = np.concatenate(edges_b)  # (m,3,2) node pairs
    outside = np.concatenate(out_node)
    pairs = np.sort(tri_edges.reshape(-1, 2), axis=1)
    uniq, inv = np.unique(pairs, axis=0, return_inverse=True)
    F = inv.reshape(-1, 3).astype(np.int64)
    pa, pb = flat[uniq[:, 0]], flat[uniq[:, 1]]
    t = np.clip(pa / (pa - pb), clamp, 1.0 - clamp)

    def pos(ids):
        i = ids // (ny * nz)
        j = (ids // nz) % ny
        k = ids % nz
        return np.asarray(origin) + h * np.stack([i, j, k], axis=1).astype(np.float64)

    V = (1 - t)[:, None] * pos(uniq[:, 0]) + t[:, None] * pos(uniq[:, 1])
    n = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    flip = np.einsum("ij,ij->i", n, pos(outside) - V[F[:, 0]]) < 0
    F[flip] = F[flip][:, ::-1]
    return V, F


def _largest_component(V, F):
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components

    n = V.shape[0]
    g = sp.coo_matrix((np.ones(F.size), (F.ravel(), np.roll(F, 1, axis=1).ravel())),
                      shape=(n, n))
    _, lab = connected_components(g, directed=False)
    big = np.bincount(lab[F[:, 0]]).argmax()
    Fk = F[lab[F[:, 0]] == big]
    used = np.unique(Fk)
    remap = np.full(n, -1, dtype=np.int64)
    remap[used] = np.arange(used.size)
    return V[used], remap[Fk]


def skinned_body(motion, *, n_vertices: int = 5000, radius: float = 0.03,
                 max_influences: int = 3, oversample: float = 3.0,
                 bind_frame: int | None = None):
    """Body mesh, skinning weights and bind pose for a skeleton.

    Parameters
    ----------
    motion : shellspline.io.bvh.Motion
        The clip (the bind pose is chosen among its frames).
    n_vertices : int
        Vertex count after decimation (the marching-tetrahedra surface is decimated to it).
    radius : float
        Base bone radius as a fraction of the skeleton's extent (limbs ``≈ 1.3-1.6x``,
        torso ``≈ 2.3x`` that).
    max_influences : int
        Joints per vertex.
    oversample : float
        The marching-tetrahedra surface has about ``oversample * n_vertices`` vertices
        before decimation (finer: closer to the capsule union; coarser: faster).
    bind_frame : int, optional
        Frame of ``motion`` used as bind pose; default: the frame of largest clearance
        between non-neighbouring bones.

    Returns
    -------
    dict
        ``V`` (n,3) bind-pose vertices, ``F`` (m,3) faces (outward normals), ``W`` (n,J)
        weights (rows sum to 1, at most ``max_influences`` non-zeros), ``bind_frame`` int,
        ``P`` (T,J,3) and ``R`` (T,J,3,3) the forward kinematics of ``motion``.
    """
    from shellspline.io.bvh import forward_kinematics
    from shellspline.mesh.decimate import decimate

    P, R = forward_kinematics(motion)
    A, B, driver, subtree, leaf = skeleton_bones(motion, P, R)
    H = np.ptp(np.concatenate([A[0], B[0]]), axis=0).max()
    radii = radius * H * (1.0 + subtree) ** (1.0 / 3.0)
    ball = 1.4  # radius of the balls at the leaves (head, hands, toes) / their bone's
    reach = np.where(leaf, ball, 1.0)

    def grid_step(radii):
        # marching tetrahedra gives about 4.5 A / h² vertices (A: surface area, estimated by
        # the capsules' sides and balls); aim at `oversample` x n_vertices before decimating,
        # never coarser than 1/1.5 of the thinnest radius
        L = np.linalg.norm(B[0] - A[0], axis=1)
        area = np.sum(2 * np.pi * radii * L) + 4 * np.pi * np.sum((ball * radii[leaf]) ** 2)
        return min(np.sqrt(4.5 * 0.8 * area / (oversample * n_vertices)), radii.min() / 1.5,
                   H / 40.0)

    far = _bone_graph_far(driver, A[0], B[0], H)
    bind, radii = _bind_and_radii(A, B, radii, reach * radii, far,
                                  lambda r: 2.5 * grid_step(r))
    bind_frame = bind if bind_frame is None else int(bind_frame)
    A0, B0 = A[bind_frame], B[bind_frame]
    Ac = np.concatenate([A0, B0[leaf]])  # balls as zero-length capsules
    Bc = np.concatenate([B0, B0[leaf]])
    rc = np.concatenate([radii, ball * radii[leaf]])
    lo = np.minimum(Ac, Bc).min(0) - rc.max() - 0.1 * H
    hi = np.maximum(Ac, Bc).max(0) + rc.max() + 0.1 * H
    h = max(grid_step(radii), (hi - lo).max() / 300.0)
    shape = np.ceil((hi - lo) / h).astype(int) + 1
    k = 0.25 * radius * H  # smoothing length of the union (fillets at the joints)
    phi = _smooth_union(Ac, Bc, rc, lo, h, shape, k)
    Vf, Ff = marching_tetrahedra(phi.reshape(shape), lo, h)
    Vf, Ff = _largest_component(Vf, Ff)
    if Vf.shape[0] > n_vertices:
        dec = decimate(Vf[None], Ff, int(n_vertices))
        V, F = dec.V[0], dec.F
    else:
        V, F = Vf, Ff
    Vr = _relax(V, F, Ac, Bc, rc, k)
    if _inverted(Vr, F, Ac, Bc, rc, k).sum() <= _inverted(V, F, Ac, Bc, rc, k).sum():
        V = Vr  # (kept unrelaxed if relaxing left more triangles facing inwards)
    W = _skin_weights(V, A0, B0, driver, motion.n_joints, max_influences, radius * H)
    return {"V": V, "F": F, "W": W, "bind_frame": int(bind_frame), "P": P, "R": R}


def _normals(V, F):
    return np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])


def _inverted(V, F, A, B, r, k):
    """Faces (m,) bool whose normal points into the capsule union (against its gradient)."""
    _, g = _union_value_grad(V[F].mean(axis=1), A, B, r, k)
    return np.einsum("mi,mi->m", _normals(V, F), g) <= 0


def _skin_weights(V, A0, B0, driver, J, max_influences, s):
    d_bone = _segment_distances(V, A0, B0)
    d = np.full((V.shape[0], J), np.inf)
    for b, j in enumerate(driver):
        d[:, j] = np.minimum(d[:, j], d_bone[:, b])
    dmin = d.min(axis=1, keepdims=True)
    w = ((dmin + s) / (d + s)) ** 4
    if max_influences < J:
        drop = np.argsort(-w, axis=1, kind="stable")[:, max_influences:]
        np.put_along_axis(w, drop, 0.0, axis=1)
    w[w < 0.02] = 0.0
    return w / w.sum(axis=1, keepdims=True)


def linear_blend_skinning(V, W, P_bind, R_bind, P, R):
    """Pose a mesh by linear blend skinning.

    Parameters
    ----------
    V : (n,3) float array
        Bind-pose vertices.
    W : (n,J) float array
        Weights (rows sum to 1).
    P_bind, R_bind : (J,3), (J,3,3) float arrays
        Joint positions and rotations in the bind pose.
    P, R : (T,J,3), (T,J,3,3) float arrays
        Joint positions and rotations of the frames to pose.

    Returns
    -------
    (T,n,3) float64 numpy array
        ``Σ_j W[:, j] (M_j(t) v + b_j(t))``, ``M_j = R_j(t) R_j(bind)ᵀ``,
        ``b_j = P_j(t) − M_j P_j(bind)``.
    """
    M = R @ np.swapaxes(R_bind, -1, -2)[None]  # (T,J,3,3)
    b = P - np.einsum("tjab,jb->tja", M, P_bind)
    T, J = M.shape[:2]
    Mv = (W @ M.reshape(T, J, 9).transpose(1, 0, 2).reshape(J, -1)).reshape(-1, T, 3, 3)
    out = np.einsum("ntab,nb->tna", Mv, V)
    out += np.einsum("nj,tja->tna", W, b)
    return out


def skinned_sequence(bvh_path, *, start: int = 0, stop: int | None = None, step: int = 1,
                     n_vertices: int = 5000, **body_options):
    """A body mesh skinned to a BVH clip and posed at every frame of a window.

    Parameters
    ----------
    bvh_path : str or path-like
        BVH file (any skeleton, see :mod:`shellspline.io.bvh`).
    start, stop, step : int
        Window of frames ``start:stop:step`` of the clip.
    n_vertices : int
        Approximate vertex count of the body.
    **body_options
        Further options of :func:`skinned_body` (``radius``, ``max_influences``, ``oversample``,
        ``bind_frame``). The body and its bind pose are built from the whole clip, so
        every window of one clip poses the same mesh.

    Returns
    -------
    Vs : (T,n,3) float64 numpy array
        The posed body at every frame of the window.
    F : (m,3) int64 numpy array
        Faces: one closed, consistently oriented, manifold surface.
    fps : float
        Frame rate of the window (the clip's rate divided by ``step``).

    Examples
    --------
    >>> Vs, F, fps = skinned_sequence("../shared/data/motion/sinusoidal.bvh",
    ...                               n_vertices=800)  # doctest: +SKIP
    """
    from shellspline.errors import ShellsplineError
    from shellspline.io.bvh import read_bvh

    if not (isinstance(step, (int, np.integer)) and step >= 1):
        raise ShellsplineError(f"step must be a positive integer, got {step!r}")
    motion = read_bvh(bvh_path)
    window = np.arange(motion.n_frames)[start:stop:step]
    if window.size == 0:
        raise ShellsplineError(f"{bvh_path}: the window {start}:{stop}:{step} of its "
                               f"{motion.n_frames} frames is empty")
    body = skinned_body(motion, n_vertices=n_vertices, **body_options)  # bind: whole clip
    b = body["bind_frame"]
    Vs = linear_blend_skinning(body["V"], body["W"], body["P"][b], body["R"][b],
                               body["P"][window], body["R"][window])
    return Vs, body["F"], motion.fps / step


def main(argv=None) -> int:
    """``python -m data_synth skinned BVH OUT [--start S] [--stop E] [--step D]
    [--vertices N]``: write every posed frame as ``OUT/frame_0000.obj ...`` and
    ``report.json`` (source, window, fps)."""
    import argparse

    from shellspline.io import write_sequence

    parser = argparse.ArgumentParser(
        prog="python -m data_synth skinned",
        description="Skin a body mesh to a BVH clip (linear blend skinning) and write every "
                    "frame of a window: OUT/frame_0000.obj, ... and OUT/report.json.")
    parser.add_argument("bvh", help="BVH file")
    parser.add_argument("out", help="output directory (replaced if it holds an earlier output)")
    parser.add_argument("--start", type=int, default=0, help="first frame (default 0)")
    parser.add_argument("--stop", type=int, default=None, help="frame after the last")
    parser.add_argument("--step", type=int, default=1, help="frame step (default 1)")
    parser.add_argument("--vertices", type=int, default=5000, metavar="N",
                        help="vertex count of the body (default 5000)")
    args = parser.parse_args(argv)
    try:
        Vs, F, fps = skinned_sequence(args.bvh, start=args.start, stop=args.stop,
                                      step=args.step, n_vertices=args.vertices)
        out = write_sequence(args.out, Vs, F, {"source": str(args.bvh), "start": args.start,
                                               "stop": args.stop, "step": args.step,
                                               "fps": fps}, overwrite=True, fps=fps)
    except (ValueError, OSError) as exc:
        parser.error(str(exc))  # exits with status 2
    print(f"skinned: wrote {Vs.shape[0]} frames ({Vs.shape[1]} vertices, {F.shape[0]} faces, "
          f"{fps:g} fps) to {out}")
    return 0

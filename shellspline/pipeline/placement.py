"""The place stage: where the in-between frames sit rigidly.

Shell energies ignore rigid motions (paper 001 §8): every reconstructed frame is moved
rigidly onto a track through the keyframes (:func:`placement_track`: a per-vertex cubic, an
SE(3) screw spline through the keyframes' rigid poses, or the linear blend), each connected
component on its own, and the keyframes are restored bit for bit (:func:`place`).
"""
from __future__ import annotations

import numpy as np

from ..errors import ShellsplineError
from ..mesh.rigid import best_rotations
from ..shells.reconstruct import rigid_placement
from ..timeline import linear_blend
from .options import RIGID_TRACKS

__all__ = ["place", "placement_track", "pinned_parts", "RIGID_TRACKS"]


def placement_track(Vkey, frames, K, bc: str = "natural", kind: str = "fit", subset=None):
    """Where the frames of a sequence are placed rigidly: a per-vertex C² cubic spline through
    the keyframes (natural, or periodic through frame K), held at the last keyframe after it.

    Shell energies ignore rigid motions (paper §8), so every reconstructed frame is moved
    rigidly onto this track. A per-vertex *linear* blend gave the body of a skinned walk the
    piecewise-linear travel and turn of linear blending: on `benchmarks/bench_real.py` the
    LΘA in-betweens were 1.02–1.96 × the per-vertex cubic's error, all of it in the rigid
    part; placed on the cubic they are 0.91–1.05 × (issue 13).

    Parameters
    ----------
    Vkey : (J,n,3) float64 array
    frames : (J,) int array
    K : int
    bc : {"natural", "periodic", "hermite"}
    kind : {"fit", "spline", "linear"}
        ``"fit"``: the per-vertex cubic above. ``"spline"``: a rigid track: each keyframe's
        rigid pose (Kabsch against the first keyframe, about the vertex centroid) follows a C²
        SE(3) spline with the screw (Ad-invariant) metric (:func:`shellspline.curves.cubic_spline`),
        and the keyframe shapes, brought back by their poses, are blended linearly: a body
        that turns while it travels follows a screw motion (a circle exactly), where the
        per-vertex cubic cuts the corner; falls back to ``"fit"`` when consecutive keyframes
        turn by half a turn or more. ``"linear"``: the per-vertex linear blend.
    subset : (s,) int array, optional
        ``kind="spline"``: the vertices whose Kabsch fit is each keyframe's rigid pose (e.g.
        the torso, so that a swinging limb does not drag the pose); default all.

    Returns
    -------
    (K+1,n,3) float64 array
        Equal to the keyframes at their frames (to round-off; the pipeline restores them bit
        for bit after placing).
    """
    from scipy.interpolate import CubicSpline

    Vkey = np.asarray(Vkey, dtype=np.float64)
    if kind == "linear":
        return linear_blend(Vkey, frames, K, bc)
    if kind == "spline":
        track = _screw_track(Vkey, frames, K, bc, subset)
        if track is not None:
            return track
    frames = np.asarray(frames)
    J = Vkey.shape[0]
    periodic = bc == "periodic"
    if J < 3 and not periodic:
        return linear_blend(Vkey, frames, K, bc)
    if periodic:
        t = np.concatenate([frames, [K]]).astype(np.float64)
        Y = np.concatenate([Vkey, Vkey[:1]])
        if J < 2:
            return linear_blend(Vkey, frames, K, bc)
        cs = CubicSpline(t, Y.reshape(J + 1, -1), bc_type="periodic")
    else:
        cs = CubicSpline(frames.astype(np.float64), Vkey.reshape(J, -1), bc_type="natural")
    k = np.arange(K + 1, dtype=np.float64)
    if not periodic:
        k = np.minimum(k, frames[-1])
    return cs(k).reshape(K + 1, *Vkey.shape[1:])


def _screw_track(Vkey, frames, K, bc, subset=None):
    """The ``kind="spline"`` track of :func:`placement_track`, or None where the SE(3) spline
    is not defined (consecutive keyframe poses half a turn or more apart)."""
    from ..curves import cubic_spline

    J = Vkey.shape[0]
    periodic = bc == "periodic"
    Vs = Vkey if subset is None else Vkey[:, subset]         # the vertices that carry the pose
    c = Vs.mean(axis=1)                                      # (J,3)
    X0 = Vs[0] - c[0]
    R = best_rotations(X0, Vs - c[:, None])                  # Vkey[j] - c[j] ≈ R_j X0
    G = np.zeros((J, 4, 4))
    G[:, :3, :3], G[:, :3, 3], G[:, 3, 3] = R, c, 1.0
    t = np.asarray(frames, dtype=np.float64)
    if periodic:
        G, t = np.concatenate([G, G[:1]]), np.concatenate([t, [K]])
    try:
        s = cubic_spline("se3", t, G, bc="periodic" if periodic else "natural")
    except ShellsplineError:
        return None
    if s.solve is not None and s.solve.status != "converged":
        return None
    k = np.arange(K + 1, dtype=np.float64)
    if not periodic:
        k = np.minimum(k, t[-1])
    Gk = s(k)                                                # (K+1,4,4)
    shapes = np.einsum("jnk,jki->jni", Vkey - c[:, None], R)  # R_jᵀ (V - c): keyframes at rest
    rest = linear_blend(shapes, frames, K, bc)
    return np.einsum("kni,kji->knj", rest, Gk[:, :3, :3]) + Gk[:, None, :3, 3]


def place(V, frames, K, bc, pinned, Vkey, F, rigid_track="fit", subset=None):
    """Rigidly place the in-between frames onto :func:`placement_track` (with pins: only by the
    rigid motions that keep them fixed) and restore the keyframes bit for bit. Each connected
    component of the mesh is placed on its own: shell energies do not see how separate pieces
    sit relative to each other, so a reconstruction leaves that free.

    Parameters
    ----------
    V : (K+1,n,3) float64 array
        Reconstructed frames (their rigid position is arbitrary).
    frames : (J,) int array
    K : int
    bc : str
    pinned : (p,) int array or None
    Vkey : (J,n,3) float64 array
    F : (m,3) int array
    rigid_track : {"fit", "spline", "linear"}
        See :func:`placement_track`.
    subset : (s,) int array, optional
        Vertices that carry the rigid pose (e.g. the torso): the keyframe poses of the
        ``"spline"`` track are fitted on them, and each frame is placed by the Kabsch fit of
        these vertices onto the track (a component without any of them: by all its vertices),
        so the rest of the body follows the shape spline.

    Returns
    -------
    (K+1,n,3) float64 array
    """
    V = np.array(V, dtype=np.float64, copy=True)
    periodic = bc == "periodic"
    track = placement_track(Vkey, frames, K, bc, kind=rigid_track, subset=subset)
    is_key = np.zeros(K + 1, dtype=bool)
    is_key[frames] = True
    is_key[K] |= periodic
    parts = pinned_parts(F, Vkey.shape[1], pinned)
    weights = [_subset_weights(idx, Vkey.shape[1], subset) for idx, _ in parts]
    for k in np.flatnonzero(~is_key):
        # with pins only the motions they leave free (none for 3+ non-collinear pins)
        for (idx, fixed), w in zip(parts, weights):
            V[k, idx] = rigid_placement(V[k, idx], track[k, idx], weights=w, fixed=fixed)
    for j, f in enumerate(frames):
        V[f] = Vkey[j]
    if periodic:
        V[K] = Vkey[0]
    return V


def pinned_parts(F, n, pinned):
    """The connected parts of a mesh and the pins of each.

    Parameters
    ----------
    F : (m,3) int array
    n : int
        Vertex count.
    pinned : (p,) int array or None

    Returns
    -------
    list of (index, pins)
        One entry per connected component: its vertices (``slice(None)`` for a connected
        mesh, else an int array) and the pins among them as indices into those vertices
        (None where it has none; for a connected mesh ``pinned`` as given).
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    E = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    A = coo_matrix((np.ones(len(E)), (E[:, 0], E[:, 1])), shape=(n, n))
    m, label = connected_components(A, directed=False)
    if m == 1:
        return [(slice(None), pinned)]
    out = []
    for c in range(m):
        idx = np.flatnonzero(label == c)
        fixed = None
        if pinned is not None and len(pinned):
            local = np.flatnonzero(np.isin(idx, pinned))
            fixed = local if local.size else None
        out.append((idx, fixed))
    return out


def _subset_weights(idx, n, subset):
    """Kabsch weights of a component's vertices ``idx``: 1 on the subset, 0 elsewhere; None
    (all equal) without a subset or when the component holds none of it."""
    if subset is None:
        return None
    w = np.zeros(n)
    w[subset] = 1.0
    w = w[idx]
    return w if w.any() else None

"""Stress cases of real production meshes, one difficulty each (issue 13).

* :func:`joint` — a tube whose joint flexes by up to 150°: the inner side compresses and its
  skin folds (dihedral angles that turn by nearly π between keyframes, triangles that the
  keyframe blend collapses).
* :func:`fold_over` — a strip whose end flap folds over onto itself: a crease whose dihedral
  angle goes from flat to within a few degrees of ±π.
* :func:`slivers` — the joint tube with every odd ring moved next to the following one, so
  half of its triangles are slivers (1 % of the median area).
* :func:`dense_slivers` — :func:`slivers` on a longer, finer tube, midpoint-subdivided: a mesh
  above the multiresolution threshold (24 192 vertices by default) whose coarse mesh is 24
  times coarser, slivers everywhere (the detail carried over long distances from the base).
* :func:`squeezed_face` — a sphere one of whose triangles is squeezed to 2 % of its height at
  an early keyframe and grows back: the extrapolated start of the frames after it pushes the
  triangle past its hinge.

Each returns the dictionary of :func:`data_synth.generate` (``V (J,n,3)``, ``F (m,3)``,
``frames (J,)``, ``pinned``), deterministic.
"""
from __future__ import annotations

import numpy as np

__all__ = ["joint", "fold_over", "slivers", "dense_slivers", "squeezed_face", "tube", "z_fold"]


def tube(rings: int = 24, segments: int = 16, length: float = 2.0, radius: float = 0.2,
         squeeze: float = 0.0):
    """An open cylinder along x: ``rings`` rings of ``segments`` vertices.

    Parameters
    ----------
    rings, segments : int
    length, radius : float
    squeeze : float
        Every odd ring moves this fraction of the ring spacing toward the next ring, so the
        triangles between them are slivers (height ``1 − squeeze`` of the spacing).

    Returns
    -------
    V : (rings*segments, 3) float64 array
    F : (m, 3) int64 array
        Outward oriented.
    """
    h = length / (rings - 1)
    x = np.arange(rings) * h
    x[1:-1:2] += squeeze * h
    phi = 2 * np.pi * np.arange(segments) / segments
    V = np.stack([np.repeat(x[:, None], segments, 1),
                  radius * np.cos(phi)[None, :].repeat(rings, 0),
                  radius * np.sin(phi)[None, :].repeat(rings, 0)], axis=-1).reshape(-1, 3)
    i = np.arange(rings - 1)[:, None]
    j = np.arange(segments)[None, :]
    a, b = i * segments + j, i * segments + (j + 1) % segments
    c, d = a + segments, b + segments
    F = np.concatenate([np.stack([a, b, d], -1).reshape(-1, 3),
                        np.stack([a, d, c], -1).reshape(-1, 3)])
    return V, F.astype(np.int64)


def _flexed(V, angle, at: float = 1.0, width: float = 0.25):
    """Bend the tube about the z axis through ``(at, 0, 0)``: vertices beyond the joint turn by
    ``angle``, blended over ``[at − width, at + width]`` (a skinned elbow)."""
    s = np.clip((V[:, 0] - (at - width)) / (2 * width), 0.0, 1.0)
    s = s * s * (3 - 2 * s)
    th = angle * s
    p = V - np.array([at, 0.0, 0.0])
    c, sn = np.cos(th), np.sin(th)
    out = np.stack([c * p[:, 0] - sn * p[:, 1], sn * p[:, 0] + c * p[:, 1], p[:, 2]], -1)
    return out + np.array([at, 0.0, 0.0])


def joint(angles=(0.0, 150.0, 30.0), frames=(0, 10, 20), rings: int = 24,
          segments: int = 16, squeeze: float = 0.0) -> dict:
    """A tube flexing at a joint by ``angles`` (degrees) at ``frames``; the first ring pinned.

    Examples
    --------
    >>> d = joint()
    >>> d["V"].shape, d["frames"].tolist()
    ((3, 384, 3), [0, 10, 20])
    """
    V0, F = tube(rings, segments, squeeze=squeeze)
    V = np.stack([_flexed(V0, np.radians(a)) for a in angles])
    return {"V": V, "F": F, "frames": np.asarray(frames, dtype=np.int64),
            "pinned": np.arange(segments, dtype=np.int64)}


def slivers(rings: int = 24, segments: int = 16, squeeze: float = 0.99) -> dict:
    """:func:`joint` on a tube whose odd rings sit next to the following ring: half of the
    triangles are slivers (``1 − squeeze`` of the ring spacing high: 1 % of the median
    area by default).

    Examples
    --------
    >>> import numpy as np, shellspline as ss
    >>> d = slivers()
    >>> a = ss.face_areas(d["V"][0], ss.topology(d["F"]))
    >>> bool(a.min() < 0.01 * np.median(a))
    True
    """
    return joint(rings=rings, segments=segments, squeeze=squeeze)


def dense_slivers(rings: int = 48, segments: int = 32, subdivisions: int = 2,
                  squeeze: float = 0.99) -> dict:
    """:func:`slivers` with ``rings × segments`` vertices, every triangle then split into four
    ``subdivisions`` times (midpoints, the same in every keyframe): slivers stay slivers
    (1 % of the median area), and the default run decimates it to 1000 vertices (the first
    ring of the tube, x = 0, pinned).

    Examples
    --------
    >>> d = dense_slivers(rings=12, segments=8, subdivisions=1)
    >>> d["V"].shape, d["F"].shape, d["pinned"].tolist()
    ((3, 368, 3), (704, 3), [0, 1, 2, 3, 4, 5, 6, 7, 96, 97, 98, 99, 100, 101, 102, 103])
    """
    from trimesh.remesh import subdivide

    d = joint(rings=rings, segments=segments, squeeze=squeeze)
    V, F = list(d["V"]), d["F"]
    for _ in range(int(subdivisions)):
        out = [subdivide(v, F) for v in V]
        V, F = [v for v, _ in out], out[0][1]
    V = np.stack(V)
    rest, _ = tube(rings, segments, squeeze=squeeze)
    pinned = np.flatnonzero(np.abs(V[0, :, 0] - rest[0, 0]) < 1e-12).astype(np.int64)
    return {"V": V, "F": np.asarray(F, dtype=np.int64), "frames": d["frames"],
            "pinned": pinned}


def fold_over(n: int = 12, angles=(0.0, 150.0, 176.0), frames=(0, 10, 20)) -> dict:
    """A flat ``2 × 1`` strip (``2n × n`` grid, split into triangles) whose half ``x > 1``
    folds about the line ``x = 1`` by ``angles`` (degrees): at 176° the flap lies nearly on
    the other half, its crease within 4° of ±π. The half ``x <= 1`` is pinned.

    Examples
    --------
    >>> d = fold_over()
    >>> d["V"].shape
    (3, 325, 3)
    """
    xs = np.linspace(0.0, 2.0, 2 * n + 1)
    ys = np.linspace(0.0, 1.0, n + 1)
    X, Y = np.meshgrid(xs, ys, indexing="ij")
    V0 = np.stack([X.ravel(), Y.ravel(), np.zeros(X.size)], -1)
    ny = n + 1
    i = np.arange(2 * n)[:, None]
    j = np.arange(n)[None, :]
    a = i * ny + j
    b, c, d = a + ny, a + ny + 1, a + 1
    F = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3),
                        np.stack([a, c, d], -1).reshape(-1, 3)]).astype(np.int64)
    Vs = []
    for deg in angles:
        th = np.radians(deg)
        V = V0.copy()
        m = V0[:, 0] > 1.0
        dx = V0[m, 0] - 1.0
        V[m, 0] = 1.0 + dx * np.cos(th)
        V[m, 2] = dx * np.sin(th)
        Vs.append(V)
    return {"V": np.stack(Vs), "F": F, "frames": np.asarray(frames, dtype=np.int64),
            "pinned": np.flatnonzero(V0[:, 0] <= 1.0 + 1e-12).astype(np.int64)}


def squeezed_face(height: float = 0.02, frames=(0, 2, 12), subdivisions: int = 2) -> dict:
    """An icosphere whose face 0 has its first corner moved to ``height`` of the way from the
    midpoint of the opposite edge at the middle keyframe (a sliver ``height`` of its height
    high), round again at the last: a keyframe with a nearly degenerate triangle next to a
    short gap and a long one. Nothing pinned.

    Examples
    --------
    >>> d = squeezed_face()
    >>> d["V"].shape, d["frames"].tolist()
    ((3, 162, 3), [0, 2, 12])
    """
    import trimesh

    m = trimesh.creation.icosphere(subdivisions=subdivisions)
    V = np.asarray(m.vertices, dtype=np.float64)
    F = np.asarray(m.faces, dtype=np.int64)
    a, b, c = F[0]
    Vmid = V.copy()
    Vmid[a] = (1.0 - height) * (0.5 * (V[b] + V[c])) + height * V[a]
    return {"V": np.stack([V, Vmid, V]), "F": F, "frames": np.asarray(frames, dtype=np.int64),
            "pinned": np.zeros(0, dtype=np.int64)}


def z_fold(nx: int = 151, ny: int = 36, length: float = 3.0, width: float = 0.7,
           x0: float = 1.2, lam: float = 0.6, lift: float = 0.002, reach: float = 1.5,
           frames=(0, 10)) -> dict:
    """A dense flat strip (``nx × ny`` grid) and the same strip with a skin fold: over
    ``[x0, x0 + lam]`` the strip is pushed together into a Z (``x → x − reach/k sin θ``,
    ``z = lift (1 − cos θ)``, ``θ = k (x − x0)``, ``k = 2π/lam``), so it runs back, forward
    and back again, the three layers ``lift`` apart: the fine faces fold over at the two
    creases and the two turns, and are squeezed next to the turns (a keyframe folding over
    where the other does not, as skin at a joint; see ``decimate``'s ``fold_area``). With
    three ``frames`` the third pose is flat again. Nothing pinned.

    Examples
    --------
    >>> d = z_fold(nx=31, ny=8)
    >>> d["V"].shape, d["F"].shape
    ((2, 248, 3), (420, 3))
    """
    xs, ys = np.linspace(0.0, length, nx), np.linspace(0.0, width, ny)
    X, Y = np.meshgrid(xs, ys, indexing="ij")
    V0 = np.stack([X.ravel(), Y.ravel(), np.zeros(X.size)], -1)
    a = np.arange(nx - 1)[:, None] * ny + np.arange(ny - 1)[None, :]
    F = np.concatenate([np.stack([a, a + ny, a + ny + 1], -1).reshape(-1, 3),
                        np.stack([a, a + ny + 1, a + 1], -1).reshape(-1, 3)])
    k = 2.0 * np.pi / lam
    th = np.clip(k * (V0[:, 0] - x0), 0.0, 2.0 * np.pi)
    V1 = V0.copy()
    V1[:, 0] -= reach / k * np.sin(th)
    V1[:, 2] = lift * (1.0 - np.cos(th))
    poses = [V0, V1, V0][:len(frames)]
    return {"V": np.stack(poses), "F": F, "frames": np.asarray(frames, dtype=np.int64),
            "pinned": np.zeros(0, dtype=np.int64)}

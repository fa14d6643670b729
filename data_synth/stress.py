"""Stress cases of real production meshes, one difficulty each (issue 13).

* :func:`joint` — a tube whose joint flexes by up to 150°: the inner side compresses and its
  skin folds (dihedral angles that turn by nearly π between keyframes, triangles that the
  keyframe blend collapses).
* :func:`fold_over` — a strip whose end flap folds over onto itself: a crease whose dihedral
  angle goes from flat to within a few degrees of ±π.
* :func:`slivers` — the joint tube with every ring shifted by a random fraction of a segment
  and split by the long diagonal, so a third of its triangles are slivers (down to ~0.5 % of
  the median area).

Each returns the dictionary of :func:`data_synth.generate` (``V (J,n,3)``, ``F (m,3)``,
``frames (J,)``, ``pinned``), deterministic.
"""
from __future__ import annotations

import numpy as np

__all__ = ["joint", "fold_over", "slivers", "tube"]


def tube(rings: int = 24, segments: int = 16, length: float = 2.0, radius: float = 0.2,
         jitter: float = 0.0, seed: int = 0):
    """An open cylinder along x: ``rings`` rings of ``segments`` vertices.

    Parameters
    ----------
    rings, segments : int
    length, radius : float
    jitter : float
        Each ring is turned by a random fraction (up to ``jitter``) of a segment, and the
        quads are split so that a share of the triangles become slivers.
    seed : int

    Returns
    -------
    V : (rings*segments, 3) float64 array
    F : (m, 3) int64 array
        Outward oriented.
    """
    rng = np.random.default_rng(seed)
    x = np.linspace(0.0, length, rings)
    turn = np.zeros(rings) if jitter == 0 else rng.uniform(0, jitter, rings)
    phi = 2 * np.pi * (np.arange(segments)[None, :] + turn[:, None]) / segments
    V = np.stack([np.repeat(x[:, None], segments, 1), radius * np.cos(phi),
                  radius * np.sin(phi)], axis=-1).reshape(-1, 3)
    i = np.arange(rings - 1)[:, None]
    j = np.arange(segments)[None, :]
    a, b = i * segments + j, i * segments + (j + 1) % segments
    c, d = a + segments, b + segments
    if jitter == 0:
        F = np.concatenate([np.stack([a, b, d], -1).reshape(-1, 3),
                            np.stack([a, d, c], -1).reshape(-1, 3)])
    else:  # split along the other diagonal on every other ring: slivers where rings turned
        alt = (i % 2 == 1) & np.ones_like(j, dtype=bool)
        t1 = np.where(alt[..., None], np.stack([a, b, c], -1), np.stack([a, b, d], -1))
        t2 = np.where(alt[..., None], np.stack([b, d, c], -1), np.stack([a, d, c], -1))
        F = np.concatenate([t1.reshape(-1, 3), t2.reshape(-1, 3)])
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
          segments: int = 16, jitter: float = 0.0, seed: int = 0) -> dict:
    """A tube flexing at a joint by ``angles`` (degrees) at ``frames``; the first ring pinned.

    Examples
    --------
    >>> d = joint()
    >>> d["V"].shape, d["frames"].tolist()
    ((3, 384, 3), [0, 10, 20])
    """
    V0, F = tube(rings, segments, jitter=jitter, seed=seed)
    V = np.stack([_flexed(V0, np.radians(a)) for a in angles])
    return {"V": V, "F": F, "frames": np.asarray(frames, dtype=np.int64),
            "pinned": np.arange(segments, dtype=np.int64)}


def slivers(rings: int = 24, segments: int = 16, seed: int = 0) -> dict:
    """:func:`joint` on a tube whose rings are turned at random, split into slivers."""
    return joint(rings=rings, segments=segments, jitter=0.95, seed=seed)


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

"""The defect rules of a sequence, element by element (one implementation).

A sequence ``V (K+1,n,3)`` with keyframes at ``frames`` has three kinds of element defect
that its keyframes do not have themselves (issue 13):

- **flipped**: step ``k → k+1`` reverses face ``t``'s normal (``n_{k+1} · n_k < 0``) although
  the face's normals at the two keyframes around the step do not point against each other;
- **folded**: step ``k → k+1`` takes interior edge ``e``'s signed dihedral angle through ±π
  (``|θ_{k+1} − θ_k| > π``), unless the keyframes around the step hold it within
  :data:`~shellspline.shells.descriptors.FOLD_BAND` of ±π at one end and the shorter way
  between them crosses ±π, or the step starts or ends at a keyframe that holds it within that
  band;
- **collapsed**: in-between frame ``k`` has face ``t`` below :data:`COLLAPSE_RATIO` of its
  smallest keyframe area.

:class:`DefectRules` holds what the keyframes decide (computed once) and
:meth:`DefectRules.scan` lists the defects of any steps of a sequence;
:func:`shellspline.metrics.sequence_defects` counts them, the multiresolution guard
(:func:`~shellspline.shells.prolong.fade_new_defects`) fades them and re-scans only the
steps it changed.

Cost. A fold needs ``|θ| > π/2`` at one end of the step, that is ``n1 · n2 < 0`` for the
edge's two face normals in one of the two frames; the dihedral angles (a cross product and an
``atan2`` per edge) are computed only for those edges, from the face normals the flip and
collapse rules need anyway, a few frames at a time (bounded temporaries). The angles of an
edge are computed by the same expressions as
:func:`~shellspline.mesh.geometry.flap_angles`, so the decisions are those of evaluating every
angle (tests compare with a dense evaluation).
"""
from __future__ import annotations

import numpy as np

from ..mesh.geometry import cross, dot, face_normals, flap_angles, norms
from ..mesh.topology import Topology

__all__ = ["COLLAPSE_RATIO", "DefectRules", "step_defects"]

#: A face is *collapsed* in a frame when its area is below this fraction of its smallest
#: keyframe area (issue 13: the horse's LΘA output had 36 such faces, linear blending none).
COLLAPSE_RATIO = 1e-3


class DefectRules:
    """What the keyframes of a sequence decide in the defect rules, computed once.

    Parameters
    ----------
    Vkey : (J,n,3) float array_like
        The keyframes (``V[frames]`` of the sequences scanned).
    T : Topology
    frames : (J,) int array_like
        Keyframe frames, strictly increasing.
    K : int
        Last frame of the sequences scanned.
    bc : {"natural", "hermite", "periodic"}
        ``"periodic"``: the steps after the last keyframe lead back to keyframe 0.

    Attributes
    ----------
    akey : (m,) float64 numpy array
        Smallest keyframe area of every face.
    is_key : (K+1,) bool numpy array
        Keyframe frames (frame ``K`` too when periodic).

    Examples
    --------
    >>> from shellspline.mesh.topology import topology
    >>> F = np.array([[0, 1, 2], [1, 0, 3]])
    >>> V0 = np.array([[0., 0, 0], [1, 0, 0], [0, 1, 0], [0, -1, 0]])
    >>> V = np.stack([V0, V0 * [1, 1, 0], V0 * [1, -1, 1], V0])
    >>> DefectRules(V[[0, 3]], topology(F), [0, 3], 3).scan(V)["flipped"].tolist()
    [[1, 0], [1, 1], [2, 0], [2, 1]]
    """

    def __init__(self, Vkey, T: Topology, frames, K: int, bc: str = "natural"):
        from .descriptors import FOLD_BAND
        from ..timeline import keyframe_gap

        Vkey = np.asarray(Vkey, dtype=np.float64)
        self.T = T
        self.frames = np.asarray(frames, dtype=np.int64)
        self.K = int(K)
        periodic = str(bc).lower() == "periodic"
        self.band = np.pi - FOLD_BAND
        self.is_key = np.zeros(self.K + 1, dtype=bool)
        self.is_key[self.frames] = True
        self.is_key[self.K] |= periodic
        self._ef = np.ascontiguousarray(T.edge_faces[T.interior])
        self._fl = np.ascontiguousarray(T.flaps[:, :2])
        Nkey = face_normals(Vkey, T.F)                                 # (J, m, 3)
        self.akey = 0.5 * norms(Nkey).min(axis=0)
        Tkey = flap_angles(Vkey, Nkey, T)                              # (J, i)
        if self.K == 0:
            self._gap = np.zeros(0, dtype=np.int64)
            self._key_flip = np.zeros((0, T.F.shape[0]), dtype=bool)
            self._key_fold = np.zeros((0, T.n_interior), dtype=bool)
            return
        g0, g1 = keyframe_gap(self.frames, self.K, periodic)          # per step
        pairs, self._gap = np.unique(np.stack([g0, g1], axis=1), axis=0, return_inverse=True)
        self._gap = self._gap.ravel()
        a, b = pairs[:, 0], pairs[:, 1]
        self._key_flip = dot(Nkey[a], Nkey[b]) < 0                    # (G, m)
        # a crossing the keyframes hold themselves: one end near ±π, the short way through it
        Ta, Tb = Tkey[a], Tkey[b]
        self._key_fold = ((np.abs(Ta) > self.band) | (np.abs(Tb) > self.band)) & \
            (np.abs(Tb - Ta) > np.pi)                                  # (G, i)

    def _frame_data(self, Vf):
        """Face normals, twice the face areas, and which interior edges have ``n1 · n2 > 0``
        (dihedral angle below π/2: cannot take part in a fold), of one frame ``Vf (n,3)``."""
        N = face_normals(Vf, self.T.F)
        n1 = np.take(N, self._ef[:, 0], axis=0)
        n2 = np.take(N, self._ef[:, 1], axis=0)
        return N, norms(N), dot(n1, n2) > 0

    def _angles(self, Vf, N, idx):
        """Dihedral angles of interior edges ``idx`` in one frame ``Vf (n,3)`` with face
        normals ``N (m,3)``: the expressions of
        :func:`~shellspline.mesh.geometry.flap_angles`."""
        n1, n2 = N[self._ef[idx, 0]], N[self._ef[idx, 1]]
        e = Vf[self._fl[idx, 1]] - Vf[self._fl[idx, 0]]
        return np.arctan2(dot(cross(n1, n2), e), dot(n1, n2) * norms(e))

    def scan(self, V, steps=None) -> dict:
        """The defects of steps of a sequence, as lists of ``(step or frame, element)``.

        One frame at a time (its normals are used by the two steps next to it): the
        temporaries are a few arrays of one frame's faces and edges.

        Parameters
        ----------
        V : (K+1,n,3) float array_like
            The sequence (its keyframes those given to the constructor).
        steps : (s,) int array_like, optional
            Steps ``k → k+1`` to scan (``0 <= k < K``); default all. Collapsed faces are
            listed for the in-between frames these steps touch.

        Returns
        -------
        dict
            ``flipped`` (f,2) int64: ``(k, t)`` step ``k`` flips face ``t``; ``folded``
            (g,2) int64: ``(k, e)`` step ``k`` folds interior edge ``e``; ``collapsed``
            (c,2) int64: ``(k, t)`` face ``t`` is collapsed in frame ``k``; ``steps`` (s,)
            and ``frames`` (f,) int64: the steps and frames looked at. Rows sorted by step /
            frame.
        """
        V = np.asarray(V, dtype=np.float64)
        K = self.K
        ks = np.arange(K) if steps is None else np.unique(np.asarray(steps, dtype=np.int64))
        is_step = np.zeros(K + 1, dtype=bool)
        is_step[ks] = True
        fs = np.union1d(ks, ks + 1) if ks.size else ks
        flips, folds, colls = [], [], []
        band, is_key = self.band, self.is_key
        prev = None  # (N, cpos) of frame f - 1 when it was computed
        for f in fs.tolist():
            N, nrm, cpos = self._frame_data(V[f])
            if not is_key[f]:
                t = np.flatnonzero(nrm * 0.5 < COLLAPSE_RATIO * self.akey)
                colls.append(np.stack([np.full(t.size, f), t], axis=1))
            k = f - 1
            if prev is not None and is_step[k]:
                Na, ca = prev
                g = self._gap[k]
                t = np.flatnonzero((dot(N, Na) < 0) & ~self._key_flip[g])
                flips.append(np.stack([np.full(t.size, k), t], axis=1))
                # the few edges with n1 · n2 <= 0 at one end of the step
                e = np.flatnonzero(~(ca & cpos))
                if e.size:
                    ta = self._angles(V[k], Na, e)
                    tb = self._angles(V[f], N, e)
                    held = (is_key[k] & (np.abs(ta) > band)) | (is_key[f] & (np.abs(tb) > band))
                    e = e[(np.abs(tb - ta) > np.pi) & ~self._key_fold[g, e] & ~held]
                    folds.append(np.stack([np.full(e.size, k), e], axis=1))
            prev = (N, cpos) if f < K and is_step[f] else None

        def rows(parts):
            return np.concatenate(parts).astype(np.int64) if parts else \
                np.zeros((0, 2), dtype=np.int64)

        return {"flipped": rows(flips), "folded": rows(folds), "collapsed": rows(colls),
                "steps": ks, "frames": fs}


def step_defects(V, T: Topology, frames, *, bc: str = "natural") -> dict:
    """Which element has which defect in which step of a sequence, as dense masks (the rules
    of :class:`DefectRules`, counted by :func:`shellspline.metrics.sequence_defects`).

    Parameters
    ----------
    V : (K+1,n,3) float array_like
    T : Topology
    frames : (J,) int array_like
        Keyframe frames.
    bc : {"natural", "hermite", "periodic"}

    Returns
    -------
    dict
        ``flipped`` (K,m) bool, ``folded`` (K,i) bool (per step ``k → k+1``),
        ``collapsed`` (K+1,m) bool (per frame).

    Examples
    --------
    >>> from shellspline.mesh.topology import topology
    >>> F = np.array([[0, 1, 2], [1, 0, 3]])
    >>> V0 = np.array([[0., 0, 0], [1, 0, 0], [0, 1, 0], [0, -1, 0]])
    >>> V = np.stack([V0, V0 * [1, 1, 0] + [0, 0, 0], V0 * [1, -1, 1], V0])
    >>> step_defects(V, topology(F), [0, 3])["flipped"].sum(axis=1).tolist()
    [0, 2, 2]
    """
    V = np.asarray(V, dtype=np.float64)
    fr = np.asarray(frames, dtype=np.int64)
    K = V.shape[0] - 1
    d = DefectRules(V[fr], T, fr, K, bc).scan(V)
    out = {"flipped": np.zeros((K, T.F.shape[0]), dtype=bool),
           "folded": np.zeros((K, T.n_interior), dtype=bool),
           "collapsed": np.zeros((K + 1, T.F.shape[0]), dtype=bool)}
    for key, mask in out.items():
        mask[d[key][:, 0], d[key][:, 1]] = True
    return out

"""The time grid of a sequence: frames ``k = 0..K``, keyframes at integer ``frames[j]``.

Every stage that asks "which keyframes bracket frame k" asks :func:`keyframe_bracket`.
"""
from __future__ import annotations

import numpy as np

__all__ = ["keyframe_bracket", "keyframe_gap"]


def keyframe_bracket(frames, K: int, periodic: bool = False):
    """Keyframes around every frame and the blend parameter between them.

    Parameters
    ----------
    frames : (J,) int array
        Keyframe frames, strictly increasing, ``frames[0] == 0``.
    K : int
        Last frame.
    periodic : bool
        Frame ``K`` is frame ``0`` again: frames after the last keyframe blend back into
        keyframe 0.

    Returns
    -------
    j0, j1 : (K+1,) int arrays
        Keyframe indices before and after frame ``k`` (frames after the last keyframe of a
        non-periodic sequence belong to the last gap, with ``t = 1``).
    t : (K+1,) float array
        Blend parameter in ``[0, 1]``: ``0`` at keyframe ``j0``, ``1`` at ``j1``.

    Examples
    --------
    >>> j0, j1, t = keyframe_bracket([0, 2, 4], 4)
    >>> j0.tolist(), j1.tolist(), t.tolist()
    ([0, 0, 1, 1, 1], [1, 1, 2, 2, 2], [0.0, 0.5, 0.0, 0.5, 1.0])
    """
    frames = np.asarray(frames)
    k = np.arange(K + 1)
    fr = frames.astype(np.float64)
    J = len(frames)
    if periodic:
        fr_ext = np.concatenate([fr, [K]])
        j_ext = np.concatenate([np.arange(J), [0]])
        pos = np.clip(np.searchsorted(fr_ext, k, side="right") - 1, 0, J - 1)
        j0, j1 = j_ext[pos], j_ext[pos + 1]
        t = (k - fr_ext[pos]) / (fr_ext[pos + 1] - fr_ext[pos])
    else:
        pos = np.clip(np.searchsorted(fr, k, side="right") - 1, 0, max(J - 2, 0))
        j0, j1 = pos, np.minimum(pos + 1, J - 1)
        t = np.clip((k - fr[pos]) / np.maximum(fr[j1] - fr[j0], 1.0), 0.0, 1.0)
    return j0, j1, t


def keyframe_gap(frames, K: int, periodic: bool = False):
    """Keyframes around every *step* ``k → k+1`` (``k = 0..K−1``).

    Returns
    -------
    j0, j1 : (K,) int arrays
        The keyframes bounding the gap that contains the step (steps after the last keyframe
        of a non-periodic sequence count in the last gap).
    """
    j0, j1, _ = keyframe_bracket(frames, K, periodic)
    return j0[:-1], j1[:-1]

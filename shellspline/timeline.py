"""The time grid of a sequence: frames ``k = 0..K``, keyframes at integer ``frames[j]``.

Every stage that asks "which keyframes bracket frame k" asks :func:`keyframe_bracket`.
"""
from __future__ import annotations

import numbers

import numpy as np

from .errors import ShellsplineError

__all__ = ["keyframe_bracket", "keyframe_gap", "canonical_bc", "checked_K", "checked_frames",
           "canonical_frames", "linear_blend", "linear_time_weights", "BOUNDARY_CONDITIONS",
           "DEFAULT_STEP",
           "MAX_FRAMES"]

BOUNDARY_CONDITIONS = ("natural", "periodic", "hermite")
"""Time boundary conditions of every spline over frames (paper 001 §4, §8)."""
DEFAULT_STEP = 10
"""Frames between keyframes when neither ``frames`` nor ``K`` is given."""
MAX_FRAMES = 1_000_000
"""Largest ``K`` accepted (a bound on memory, not on the mathematics)."""


_NOT_GIVEN = object()


def api_spelling(option: str, value=_NOT_GIVEN) -> str:
    """How :func:`shellspline.interpolate`'s messages name an option (a backquoted
    ``transfer``) or a setting (``method='linear'``): the default ``spell`` of the messages
    that name options (:func:`canonical_frames`,
    :func:`shellspline.pipeline.options.coarse_target`,
    :func:`shellspline.pipeline.interpolation.inapplicable_options`), which the CLI and job
    files replace by their own spelling (``--K``, ``'coarse'``)."""
    return f"`{option}`" if value is _NOT_GIVEN else f"{option}={value!r}"


def canonical_bc(bc) -> str:
    """Return ``bc`` as one of ``'natural'``, ``'periodic'``, ``'hermite'``."""
    if isinstance(bc, str):
        key = bc.strip().lower()
        if key in BOUNDARY_CONDITIONS:
            return key
    raise ShellsplineError(
        f"`bc` must be one of {', '.join(repr(b) for b in BOUNDARY_CONDITIONS)} (case-insensitive), got {bc!r}"
    )


def checked_K(K) -> int:
    """``K`` (the last frame) as a Python int >= 1; integral floats are accepted."""
    if isinstance(K, (bool, np.bool_)) or not isinstance(K, (numbers.Integral, numbers.Real)):
        raise ShellsplineError(f"`K` must be an integer >= 1, got {K!r}")
    if isinstance(K, numbers.Integral):
        Ki = int(K)
    else:
        if not np.isfinite(K) or float(K) != int(K):
            raise ShellsplineError(f"`K` must be an integer >= 1, got {K!r}")
        Ki = int(K)
    if Ki < 1:
        raise ShellsplineError(f"`K` must be an integer >= 1, got {K!r}")
    return Ki


def checked_frames(frames, K: int, bc: str) -> np.ndarray:
    """Validate keyframe indices against ``K`` and the boundary condition; return int64."""
    f = np.asarray(frames)
    shown = np.array2string(f.ravel()[:20], separator=", ") if f.size else "[]"
    if f.ndim != 1:
        raise ShellsplineError(f"`frames` must be a 1-D array of frame indices, got shape {f.shape}")
    if f.dtype == bool or not (np.issubdtype(f.dtype, np.integer) or np.issubdtype(f.dtype, np.floating)):
        raise ShellsplineError(f"`frames` must hold integer frame indices, got dtype {f.dtype}")
    if f.shape[0] < 2:
        raise ShellsplineError(f"`frames` must hold at least 2 keyframes, got {shown}")
    if np.issubdtype(f.dtype, np.floating):
        if not np.all(np.isfinite(f)) or np.any(f != np.round(f)):
            raise ShellsplineError(f"`frames` must be integer-valued, got {shown}")
    fi = f.astype(np.int64)
    if np.any(np.diff(fi) <= 0):
        raise ShellsplineError(f"`frames` must be strictly increasing, got {shown}")
    if fi[0] < 0 or fi[-1] > K:
        raise ShellsplineError(f"`frames` must lie in [0, K] = [0, {K}], got {shown}")
    if fi[0] != 0:
        raise ShellsplineError(
            f"`frames` must start with frame 0 (the first keyframe sits at the start of the "
            f"path), got {shown}"
        )
    if bc == "periodic" and fi[-1] >= K:
        raise ShellsplineError(
            f"`frames` must end before K = {K} for bc='periodic' (frame K is frame 0), got {shown}"
        )
    if bc == "hermite":
        missing = [k for k in (1, K - 1, K) if k not in set(fi.tolist())]
        if missing:
            raise ShellsplineError(
                f"`frames` must contain frames 0, 1, K-1 and K (= 0, 1, {K - 1}, {K}) for "
                f"bc='hermite' (the end velocities are fixed by the poses at 0, 1 and K-1, K); "
                f"missing {missing}, got {shown}"
            )
    return fi


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
        t = np.clip((k - fr_ext[pos]) / (fr_ext[pos + 1] - fr_ext[pos]), 0.0, 1.0)
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


def canonical_frames(J: int, frames=None, K=None, bc: str = "natural", *, spell=None):
    """Canonical keyframe frames and last frame index ``K`` of a sequence of ``J`` keyframes.

    Parameters
    ----------
    J : int
        Number of keyframes.
    frames : (J,) int array, optional
        Keyframe frames; default: evenly spaced over ``[0, K]`` (``[0, K)`` when periodic),
        or every :data:`DEFAULT_STEP` frames when ``K`` is not given either.
    K : int, optional
        Last frame; default: the last keyframe's frame (periodic: one keyframe gap later).
    bc : {"natural", "periodic", "hermite"}
        Canonical boundary condition (:func:`canonical_bc`). ``"hermite"`` needs keyframes at
        frames 0, 1, K-1 and K (the poses at 1 and K-1 fix the end velocities).
    spell : callable(option, value=...) -> str, optional
        How messages name an option or a setting (the CLI's flags); default
        :func:`api_spelling` (:func:`shellspline.interpolate`'s keywords).

    Returns
    -------
    frames : (J,) int64 array
    K : int

    Raises
    ------
    ShellsplineError
        Frames not integers, not strictly increasing, not starting at 0, beyond ``K``;
        ``K`` out of ``[1, MAX_FRAMES]`` or too small for ``J`` keyframes; a periodic
        keyframe at ``K``; hermite frames missing.

    Examples
    --------
    >>> canonical_frames(3)
    (array([ 0, 10, 20]), 20)
    >>> canonical_frames(3, K=12, bc="periodic")
    (array([0, 4, 8]), 12)
    """
    o = spell or api_spelling
    periodic = bc == "periodic"
    if frames is None:
        if bc == "hermite":
            raise ShellsplineError(f"{o('bc', 'hermite')} needs explicit {o('frames')}: the "
                                   "poses at frames 1 and K-1 fix the end velocities")
        if K is None:
            frames = DEFAULT_STEP * np.arange(J)
            K = int(frames[-1] + (DEFAULT_STEP if periodic else 0))
        else:
            K = _bounded_K(K, o)
            if periodic:
                frames = np.round(np.arange(J) * K / J).astype(np.int64)
            else:
                frames = np.round(np.linspace(0, K, J)).astype(np.int64)
            if len(np.unique(frames)) != J:
                raise ShellsplineError(f"{o('K', K)} is too small for {J} keyframes")
    try:
        frames = np.asarray(frames)
    except (TypeError, ValueError):
        raise ShellsplineError(f"{o('frames')} must be integer frame indices, got "
                               f"{frames!r}") from None
    if frames.dtype == bool or not (np.issubdtype(frames.dtype, np.integer)
                                    or np.issubdtype(frames.dtype, np.floating)):
        raise ShellsplineError(f"{o('frames')} must be integer frame indices, got "
                               f"{frames.ravel()[:20].tolist()} (dtype {frames.dtype})")
    if frames.ndim != 1 or len(frames) != J:
        raise ShellsplineError(f"{o('frames')} must have one entry per keyframe ({J}), got "
                               f"{frames.tolist()}")
    if not np.all(np.isfinite(frames)) or not np.all(frames == np.round(frames)):
        raise ShellsplineError(f"{o('frames')} must be integers, got {frames.tolist()}")
    frames = frames.astype(np.int64)
    if np.any(np.diff(frames) <= 0):
        raise ShellsplineError(f"{o('frames')} must be strictly increasing, got "
                               f"{frames.tolist()}")
    if frames[0] != 0:
        raise ShellsplineError(f"{o('frames')} must start at 0, got {frames.tolist()}")
    if K is None:
        K = int(frames[-1] + ((frames[-1] - frames[-2]) if periodic else 0))
    K = _bounded_K(K, o)
    if periodic and frames[-1] >= K:
        raise ShellsplineError(f"with {o('bc', 'periodic')} the keyframes must lie before "
                               f"{o('K', K)} (frame K is frame 0 again), got frames "
                               f"{frames.tolist()}")
    if frames[-1] > K:
        raise ShellsplineError(f"{o('K', K)} is smaller than the last keyframe frame "
                               f"{int(frames[-1])}")
    if bc == "hermite" and (len(frames) < 4 or frames[1] != 1 or frames[-2] != K - 1
                            or frames[-1] != K):
        raise ShellsplineError(f"{o('bc', 'hermite')} needs keyframes at frames 0, 1, K-1 and "
                               "K (the poses at 1 and K-1 fix the end velocities); got frames "
                               f"{frames.tolist()} with K={K}")
    return frames, K


def _bounded_K(K, spell=api_spelling) -> int:
    if isinstance(K, (bool, np.bool_)) or not isinstance(K, numbers.Real) or \
            not np.isfinite(K) or float(K) != int(K):
        raise ShellsplineError(f"{spell('K')} must be an integer (the last frame), got {K!r}")
    K = int(K)
    if K < 1 or K > MAX_FRAMES:
        raise ShellsplineError(f"{spell('K')} must lie in [1, {MAX_FRAMES}], got {K}")
    return K


def linear_time_weights(frames, K: int, bc: str = "natural") -> np.ndarray:
    """Piecewise-linear interpolation weights of the keyframes, frame by frame: row ``k`` of
    the result blends the keyframes as :func:`linear_blend` does at frame ``k``.

    Parameters
    ----------
    frames : (J,) int array
        Strictly increasing keyframe frames in ``[0, K]``.
    K : int
    bc : {"natural", "periodic", "hermite"}
        ``"periodic"`` blends the last keyframe back into the first at frame ``K``; otherwise
        frames after the last keyframe (and before the first) hold that keyframe.

    Returns
    -------
    W : (K+1,J) float64 array
        Rows sum to 1; ``W[frames[j]] = e_j`` exactly.

    Examples
    --------
    >>> linear_time_weights([0, 4], 4)[:, 1].tolist()
    [0.0, 0.25, 0.5, 0.75, 1.0]
    """
    frames = np.asarray(frames, dtype=np.int64)
    J = len(frames)
    j0, j1, t = keyframe_bracket(frames, K, str(bc).lower() == "periodic")
    W = np.zeros((K + 1, J))
    rows = np.arange(K + 1)
    np.add.at(W, (rows, j0), 1.0 - t)
    np.add.at(W, (rows, j1), t)
    W[frames] = np.eye(J)
    return W


def linear_blend(Vkey, frames, K: int, bc: str = "natural"):
    """Per-vertex linear blending of keyframes: the naive baseline and the initial guess.

    Parameters
    ----------
    Vkey : (J,n,3) float64 array
        Keyframe poses (any trailing shape works: ``(J, ...)``).
    frames : (J,) int array
        Canonical keyframe frames (:func:`canonical_frames`).
    K : int
    bc : {"natural", "periodic", "hermite"}
        ``"periodic"`` blends the last keyframe back into the first at frame ``K``.

    Returns
    -------
    (K+1,n,3) float64 array
        Keyframes are reproduced exactly, and so is any coordinate that is equal in the two
        bracketing keyframes. Frames after the last keyframe (non-periodic) hold the last
        keyframe.

    Examples
    --------
    >>> linear_blend([[0.0], [1.0]], [0, 4], 4)[:, 0].tolist()
    [0.0, 0.25, 0.5, 0.75, 1.0]
    """
    bc = canonical_bc(bc)
    try:
        Vkey = np.asarray(Vkey, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ShellsplineError(f"`Vkey` must be a numeric (J, ...) array of keyframe poses: "
                               f"{str(exc).splitlines()[0] if str(exc) else exc!r}") from None
    if Vkey.ndim < 1 or Vkey.shape[0] < 2:
        raise ShellsplineError(f"`Vkey` must hold at least 2 keyframes along its first axis, got "
                               f"shape {Vkey.shape}")
    frames, K = canonical_frames(Vkey.shape[0], frames, K, bc)
    j0, j1, t = keyframe_bracket(frames, K, bc == "periodic")
    A, B = Vkey[j0], Vkey[j1]
    t = t.reshape((-1,) + (1,) * (Vkey.ndim - 1))
    out = (1.0 - t) * A + t * B
    out = np.where(A == B, A, out)  # a vertex that does not move stays bit-identical
    out[frames] = Vkey
    if bc == "periodic":
        out[K] = Vkey[0]
    return out

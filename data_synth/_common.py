"""Argument validation and small helpers shared by the generators."""
from __future__ import annotations

import numbers

import numpy as np


def positive_int(value, name: str, minimum: int = 1) -> int:
    """Return ``value`` as an ``int`` after checking it is an integer ``>= minimum``.

    Parameters
    ----------
    value : int
        The value to check (``bool`` is rejected).
    name : str
        Argument name used in the error message.
    minimum : int
        Smallest accepted value.

    Returns
    -------
    int

    Raises
    ------
    ValueError
        If ``value`` is not an integer or is below ``minimum``.
    """
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise ValueError(f"{name} must be an integer, got {value!r}")
    if value < minimum:
        raise ValueError(f"{name} must be >= {minimum}, got {value}")
    return int(value)


def positive_float(value, name: str, *, allow_zero: bool = False) -> float:
    """Return ``value`` as a finite ``float`` that is ``> 0`` (or ``>= 0``).

    Parameters
    ----------
    value : float
        The value to check.
    name : str
        Argument name used in the error message.
    allow_zero : bool
        Accept ``0``.

    Returns
    -------
    float

    Raises
    ------
    ValueError
        If ``value`` is not a finite real number of the required sign.
    """
    if isinstance(value, bool) or not isinstance(value, numbers.Real) or not np.isfinite(value):
        raise ValueError(f"{name} must be a finite real number, got {value!r}")
    value = float(value)
    if value < 0 or (value == 0 and not allow_zero):
        bound = ">= 0" if allow_zero else "> 0"
        raise ValueError(f"{name} must be {bound}, got {value}")
    return value


def frames_array(frames, n_poses: int, name: str = "frames") -> np.ndarray:
    """Check suggested keyframe frames: ``n_poses`` strictly increasing integers ``>= 0``.

    Parameters
    ----------
    frames : (J,) int array_like
        Frame index of every keyframe.
    n_poses : int
        Number of keyframe poses ``J``.
    name : str
        Argument name used in the error message.

    Returns
    -------
    frames : (J,) int64 array

    Raises
    ------
    ValueError
        If the length, type or ordering is wrong.
    """
    arr = np.asarray(frames)
    if arr.ndim != 1 or arr.shape[0] != n_poses:
        raise ValueError(f"{name} must have {n_poses} entries (one per pose), "
                         f"got shape {arr.shape}")
    if arr.size and not np.issubdtype(arr.dtype, np.integer):
        raise ValueError(f"{name} must be integers, got dtype {arr.dtype}")
    arr = arr.astype(np.int64)
    if arr.size and (arr[0] < 0 or np.any(np.diff(arr) <= 0)):
        raise ValueError(f"{name} must be non-negative and strictly increasing, "
                         f"got {arr.tolist()}")
    return arr


def keyframes(Vs, F, frames, pinned=None, **extra) -> dict:
    """Bundle a generator's output into the dictionary every generator returns.

    Parameters
    ----------
    Vs : (J,n,3) float array_like
        Vertex positions of the ``J`` keyframe poses.
    F : (m,3) int array_like
        Shared faces.
    frames : (J,) int array_like
        Suggested frame index of every keyframe.
    pinned : (p,) int array_like or None
        Vertices that should stay fixed (same position in every pose).
    **extra
        Further entries (e.g. ``rest``), stored as given.

    Returns
    -------
    dict
        ``V`` (J,n,3) float64, ``F`` (m,3) int64, ``frames`` (J,) int64, ``pinned``
        (p,) int64 or ``None``, plus ``extra``.
    """
    Vs = np.ascontiguousarray(Vs, dtype=np.float64)
    F = np.ascontiguousarray(F, dtype=np.int64)
    out = {
        "V": Vs,
        "F": F,
        "frames": frames_array(frames, Vs.shape[0]),
        "pinned": None if pinned is None else np.ascontiguousarray(pinned, dtype=np.int64),
    }
    out.update(extra)
    return out

"""Pinned (fixed) vertices: validated once into canonical forms."""
from __future__ import annotations

import numpy as np

from ..errors import ShellsplineError

__all__ = ["canonical_pinned", "pinned_mask"]


def canonical_pinned(pinned, n: int) -> np.ndarray | None:
    """Pinned vertices as sorted unique int64 indices, or ``None`` when there are none."""
    if pinned is None:
        return None
    p = np.asarray(pinned)
    if p.size == 0:
        return None
    if p.ndim != 1 or not np.issubdtype(p.dtype, np.integer):
        raise ShellsplineError(f"`pinned` must be a 1-D array of vertex indices, got {p!r}")
    if p.min() < 0 or p.max() >= n:
        raise ShellsplineError(f"`pinned` must index vertices in [0, {n}), got range "
                               f"[{p.min()}, {p.max()}]")
    return np.unique(p.astype(np.int64))


def pinned_mask(pinned, n: int) -> np.ndarray:
    """Pinned vertices as a boolean mask ``(n,)`` (from ``None``, a mask or indices)."""
    if pinned is None:
        return np.zeros(n, dtype=bool)
    p = np.asarray(pinned)
    if p.dtype == bool:
        if p.shape != (n,):
            raise ShellsplineError(f"`pinned` as a mask must have shape ({n},), got {p.shape}")
        return p.copy()
    if p.size and not np.issubdtype(p.dtype, np.integer):
        raise ShellsplineError(f"`pinned` must hold vertex indices (integers), got dtype {p.dtype}")
    p = p.astype(np.int64).ravel()
    if p.size and (p.min() < 0 or p.max() >= n):
        raise ShellsplineError(f"`pinned` indices must lie in [0, {n}), got range [{p.min()}, "
                               f"{p.max()}]")
    mask = np.zeros(n, dtype=bool)
    mask[p] = True
    return mask

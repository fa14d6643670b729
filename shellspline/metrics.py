"""Small, dependency-free measurements of a sequence, shared by tests, benchmarks, plots and
the regression pipeline.

All functions take poses with frames on axis 0 (``V (K+1,n,3)``) and are vectorised over
frames.
"""
from __future__ import annotations

import numpy as np

from .descriptors import edge_lengths
from .topology import Topology

__all__ = ["half_axes", "keyframe_kinks", "edge_strain", "speed"]


def half_axes(V) -> np.ndarray:
    """Half-extents along x, y, z about the centroid (paper Fig. 3 plots these for ellipsoids).

    Parameters
    ----------
    V : (..., n, 3) array

    Returns
    -------
    (..., 3) array
        ``max_i |V_i - c|`` per coordinate, ``c`` the vertex centroid of each pose.
    """
    V = np.asarray(V, dtype=np.float64)
    C = V - V.mean(axis=-2, keepdims=True)
    return np.abs(C).max(axis=-2)


def keyframe_kinks(V, frames) -> np.ndarray:
    """Relative second difference at each interior keyframe.

    ``|V[f+1] - 2 V[f] + V[f-1]| / |V[f+1] - V[f-1]|``: O(1/K) where the curve is C¹ (a spline),
    O(1) at a velocity kink (piecewise geodesic or linear blending).

    Parameters
    ----------
    V : (K+1, n, 3) array
    frames : (J,) int array
        Keyframe frames; only those with a neighbour on both sides are measured.

    Returns
    -------
    (J_interior,) array
    """
    V = np.asarray(V, dtype=np.float64)
    f = np.asarray([k for k in np.asarray(frames).tolist() if 0 < k < V.shape[0] - 1], dtype=int)
    if f.size == 0:
        return np.zeros(0)
    num = np.linalg.norm((V[f + 1] - 2 * V[f] + V[f - 1]).reshape(f.size, -1), axis=1)
    den = np.linalg.norm((V[f + 1] - V[f - 1]).reshape(f.size, -1), axis=1)
    return num / np.maximum(den, np.finfo(float).tiny)


def edge_strain(V, V_ref, T: Topology) -> np.ndarray:
    """Maximum relative edge-length change of every pose against a reference pose.

    Parameters
    ----------
    V : (K+1, n, 3) or (n, 3) array
    V_ref : (n, 3) array
    T : Topology

    Returns
    -------
    (K+1,) array (or a scalar for one pose)
        ``max_e |l_e(V) / l_e(V_ref) - 1|`` (paper Fig. 10: near-isometric motion keeps it small).
    """
    l0 = edge_lengths(np.asarray(V_ref, dtype=np.float64), T)
    lk = edge_lengths(np.asarray(V, dtype=np.float64), T)
    return np.abs(lk / l0 - 1.0).max(axis=-1)


def speed(V) -> np.ndarray:
    """Per-step speed ``K |V[k+1] - V[k]|`` (Frobenius over vertices, divided by sqrt(n)).

    Returns
    -------
    (K,) array
        Root-mean-square vertex speed in units of length per unit time (the curve runs over
        t in [0, 1]).
    """
    V = np.asarray(V, dtype=np.float64)
    K = V.shape[0] - 1
    d = (V[1:] - V[:-1]).reshape(K, -1)
    return K * np.linalg.norm(d, axis=1) / np.sqrt(V.shape[1])

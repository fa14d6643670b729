"""Small, dependency-free measurements of a sequence, shared by tests, benchmarks, plots and
the regression pipeline.

All functions take poses with frames on axis 0 (``V (K+1,n,3)``) and are vectorised over
frames.
"""
from __future__ import annotations

import numpy as np

from .descriptors import edge_lengths
from .topology import Topology

__all__ = ["half_axes", "keyframe_kinks", "edge_strain", "speed", "lta_energies",
           "shell_energies"]


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


def lta_energies(V, T: Topology, *, bc: str = "natural", mu: float = 1.0, lam: float = 1.0,
                 eta: float = 1e-3, reference=None, chunk: int = 8) -> np.ndarray:
    """LΘA-space energy ``Ŵ[z_k, z̃_k]`` of every frame of a sequence (paper Figs. 11–12).

    The descriptors of every pose are computed (a few frames at a time), the dihedral angles
    unwrapped across frames, and the per-frame terms of the spline energy (eq. 11) evaluated
    with the LΘA weights of one reference pose, as ``interpolate`` records them in
    ``report["energies"]["lta_output_energy_per_frame"]`` for a constant reference.

    Parameters
    ----------
    V : (K+1, n, 3) array
    T : Topology
    bc : {"natural", "periodic", "hermite"}
        Decides which frames have a term (see :func:`~shellspline.lta_spline.lta_energy_per_frame`).
    mu, lam, eta : float
        LΘA weights (membrane lengths, areas, bending).
    reference : (n, 3) array, optional
        Pose that defines the weights; default ``V[0]``.
    chunk : int
        Frames per descriptor batch (bounds memory on large meshes).

    Returns
    -------
    (K+1,) array
        Zero where no term is defined (the end frames for natural/hermite).
    """
    from .descriptors import lta_descriptors, lta_weights, unwrap_angles
    from .lta_spline import lta_energy_per_frame

    V = np.asarray(V, dtype=np.float64)
    ref = V[0] if reference is None else np.asarray(reference, dtype=np.float64)
    sT = T.descriptor_slices()[1]
    Z = np.concatenate([lta_descriptors(V[i:i + chunk], T) for i in range(0, V.shape[0], chunk)])
    Z[:, sT] = unwrap_angles(Z[:, sT])
    W = lta_weights(ref, T, mu=mu, lam=lam, eta=eta)
    return lta_energy_per_frame(Z, bc=bc, weights=W)


def shell_energies(V, T: Topology, *, bc: str = "natural", mu: float = 1.0, lam: float = 1.0,
                   eta: float = 1e-3, midpoints: bool = True, tol: float = 1e-8) -> np.ndarray:
    """Nonlinear Discrete Shells energy along a sequence (paper Figs. 11–12, second row).

    Parameters
    ----------
    V : (K+1, n, 3) array
    T : Topology
    bc : {"natural", "periodic", "hermite"}
        Which frames carry a term: ``1..K−1`` (natural, hermite) or ``0..K−1`` cyclically
        (periodic; frame ``K`` is frame ``0``).
    mu, lam, eta : float
        Discrete Shells weights (paper eq. 9).
    midpoints : bool
        ``True``: the paper's quantity ``W[s_k, s̃_k]`` with ``s̃_k`` the discrete geodesic
        midpoint of ``s_{k−1}`` and ``s_{k+1}`` (eq. 8), one small Newton solve per frame
        (warm-started at ``s_k``; seconds for a few thousand vertices). ``False``: the cheap
        step energy ``W[s_k, s_{k+1}]`` (the discrete path energy density, eq. 3) of every
        frame ``k = 0..K−1``.
    tol : float
        Relative gradient tolerance of the midpoint solves.

    Returns
    -------
    (K+1,) array
        Zero where no term is defined.
    """
    from .geodesic import PathSolver
    from .lta_spline import _canonical_bc
    from .shell_energy import DiscreteShells

    V = np.asarray(V, dtype=np.float64)
    K = V.shape[0] - 1
    bc = _canonical_bc(bc)
    W = DiscreteShells(T, mu=mu, lam=lam, eta=eta)
    out = np.zeros(K + 1)
    if not midpoints:
        for k in range(K):
            out[k] = W.energy(V[k], V[k + 1])
        return out
    if K < 2:
        return out
    ks = range(K) if bc == "periodic" else range(1, K)
    solver = PathSolver(W, 1)
    for k in ks:
        a, b = (k - 1) % K, k + 1  # periodic: frame K is frame 0
        m = solver.solve(V[a], V[b], V[k][None], tol=tol).V[1]
        out[k] = W.energy(V[k], m)
    return out

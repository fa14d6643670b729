"""Small, dependency-free measurements of a sequence, shared by tests, benchmarks, plots and
the regression pipeline.

All functions take poses with frames on axis 0 (``V (K+1,n,3)``) and are vectorised over
frames.
"""
from __future__ import annotations

import numpy as np

from .mesh.geometry import face_normals, norms
from .mesh.topology import Topology
from .shells.defects import COLLAPSE_RATIO, DefectRules
from .shells.descriptors import edge_lengths

__all__ = ["length_scale", "half_axes", "keyframe_kinks", "edge_strain", "speed", "lta_energies", "sequence_defects",
           "shell_energies", "COLLAPSE_RATIO"]


def length_scale(V, F) -> float:
    """The length the keyframes are measured in: ``D = sqrt(surface area)`` of the pose ``V``.

    Shell energies mix lengths (membrane) with angles weighted by ``η`` (bending, a length²):
    :func:`~shellspline.pipeline.interpolate` divides the keyframes by ``D`` before any stage
    and multiplies the result back, so that an interpolation does not depend on the unit
    (millimetres or kilometres give the same shape), and ``η`` is relative:
    ``η = (thickness / D)²``; :func:`lta_energies` and :func:`shell_energies` measure a
    sequence the same way (``D`` of its first pose), so their values are unit-free and equal
    the energies in ``report.json``. The area is used rather than a bounding box
    because it does not change when the input is rotated (a bounding-box diagonal does, so a
    turned input would get another ``η``), nor with the sampling of the surface, so the coarse
    meshes of a multiresolution run and the full mesh share it; unused vertices do not count.

    Parameters
    ----------
    V : (n,3) float64 array
    F : (m,3) int array

    Returns
    -------
    float
        ``D > 0`` (1.0 for a mesh without area).

    Examples
    --------
    >>> length_scale(np.array([[0., 0, 0], [2, 0, 0], [0, 2, 0], [2, 2, 0]]), [[0, 1, 3], [0, 3, 2]])
    2.0
    """
    N = face_normals(np.asarray(V, dtype=np.float64), np.asarray(F))
    D = float(np.sqrt(0.5 * norms(N).sum()))
    return D if np.isfinite(D) and D > 0 else 1.0


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
        Decides which frames have a term (see :func:`~shellspline.shells.lta_spline.lta_energy_per_frame`).
    mu, lam, eta : float
        LΘA weights (membrane lengths, areas, bending); ``η`` relative to the size of the
        first pose, as in :func:`~shellspline.pipeline.interpolate`: the sequence is measured
        divided by :func:`length_scale` of ``V[0]``.
    reference : (n, 3) array, optional
        Pose that defines the weights; default ``V[0]``.
    chunk : int
        Frames per descriptor batch (bounds memory on large meshes).

    Returns
    -------
    (K+1,) array
        Zero where no term is defined (the end frames for natural/hermite).
    """
    from .shells.descriptors import lta_descriptors, lta_weights, unwrap_angles
    from .shells.lta_spline import lta_energy_per_frame

    V = np.asarray(V, dtype=np.float64)
    ref = V[0] if reference is None else np.asarray(reference, dtype=np.float64)
    D = length_scale(V[0], T.F)
    V, ref = V / D, ref / D
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
        Discrete Shells weights (paper eq. 9); ``η`` relative to the size of the first pose,
        as in :func:`~shellspline.pipeline.interpolate`: the sequence is measured divided by
        :func:`length_scale` of ``V[0]``.
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
    from .shells.geodesic import PathSolver
    from .timeline import canonical_bc
    from .shells.energy import DiscreteShells

    V = np.asarray(V, dtype=np.float64)
    V = V / length_scale(V[0], T.F)
    K = V.shape[0] - 1
    bc = canonical_bc(bc)
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


def sequence_defects(V, T: Topology, frames, *, bc: str = "natural",
                     chunk: int = 8) -> dict:
    """Defects of a sequence that its keyframes do not have themselves.

    Three kinds of element defect and one of motion, each counted per frame (the element
    rules are those of :class:`~shellspline.shells.defects.DefectRules`, which the
    multiresolution guard uses too):

    - **flipped faces**: step ``k−1 → k`` reverses a face's normal (``n_k · n_{k−1} < 0``)
      although the face's normals at the two keyframes around the step do not point against
      each other (a face whose keyframes are flipped must flip somewhere in between);
    - **collapsed faces**: a face's area in an in-between frame is below
      :data:`COLLAPSE_RATIO` of its smallest keyframe area;
    - **folded edges**: step ``k−1 → k`` takes an interior edge's signed dihedral angle
      through ±π (its two triangles pass through each other), unless the keyframes around the
      step hold it within :data:`~shellspline.shells.descriptors.FOLD_BAND` of ±π at one end and the
      shorter way between them crosses ±π (a fold the keyframes themselves hold a little past
      the touching point: skin folding at a joint), or the step starts or ends at a keyframe
      that holds it within that band (the sign of an angle at ±π is round-off); an edge that
      turns by more than π between keyframes away from ±π is expected to turn the direct way,
      through 0 (see :func:`~shellspline.shells.descriptors.consistent_angles`);
    - **pop**: the largest vertex displacement of a step over the typical one around it,
      ``max_i |V[k+1,i] − V[k,i]|`` divided by the mean of the same quantity over the up to
      four neighbouring steps (``k−2..k+2`` without ``k``; not wrapped around a periodic
      sequence), that mean raised to at least a quarter of the sequence's median step; a step
      below that quarter counts 1. A smooth sequence stays near 1 (also where it slows down
      to turn back: the mean, unlike the median, is not fooled by two near-zero steps at a
      turning point); a velocity kink between keyframe gaps of different speed gives at
      most about 2; a frame that jumps gives much more.

    Parameters
    ----------
    V : (K+1, n, 3) float64 array
    T : Topology
    frames : (J,) int array
        Keyframe frames (the keyframes are ``V[frames]``).
    bc : {"natural", "periodic", "hermite"}
        ``"periodic"``: the steps after the last keyframe lead back to keyframe 0.
    chunk : int
        Steps per batch of the vertex displacements (bounds memory on large meshes).

    Returns
    -------
    dict
        ``flipped_faces``, ``collapsed_faces``, ``folded_edges`` (ints, summed over frames),
        ``pop`` (float), ``pop_frame`` (the step ``k → k+1`` with the largest pop, as ``k+1``),
        ``per_frame`` (``flipped``, ``collapsed``, ``folded``: (K+1,) lists, frame ``k``
        holding the count of step ``k−1 → k`` or of frame ``k``; ``pop``: (K+1,) list,
        frame ``k+1`` holding step ``k → k+1``'s ratio, 0 at frame 0) and ``worst_frames``
        (up to five frames with the most defects, worst first).

    Examples
    --------
    >>> import numpy as np
    >>> from shellspline.mesh.topology import topology
    >>> F = np.array([[0, 1, 2], [1, 0, 3]])
    >>> V0 = np.array([[0., 0, 0], [1, 0, 0], [0, 1, 0], [0, -1, 0]])
    >>> Vs = np.stack([V0 + 0.1 * k * np.array([0, 0, 1.0]) for k in range(5)])
    >>> d = sequence_defects(Vs, topology(F), [0, 4])
    >>> d["flipped_faces"], d["collapsed_faces"], d["folded_edges"], round(d["pop"], 6)
    (0, 0, 0, 1.0)
    """
    V = np.asarray(V, dtype=np.float64)
    frames = np.asarray(frames, dtype=np.int64)
    K = V.shape[0] - 1
    # the element defects: the rules of shells.defects (one implementation)
    d = DefectRules(V[frames], T, frames, K, bc).scan(V)
    flipped = np.bincount(d["flipped"][:, 0] + 1, minlength=K + 1)
    folded = np.bincount(d["folded"][:, 0] + 1, minlength=K + 1)
    collapsed = np.bincount(d["collapsed"][:, 0], minlength=K + 1)
    steps = np.zeros(K)
    for i in range(0, K, chunk):  # largest vertex displacement of every step
        j = min(i + chunk, K)
        dV = V[i + 1:j + 1] - V[i:j]
        steps[i:j] = np.sqrt(np.einsum("kni,kni->kn", dV, dV).max(axis=1))
    pop = np.zeros(K + 1)
    if K >= 2:
        # steps at round-off level (static frames) are not motion
        diag = float(np.linalg.norm(np.ptp(V[frames].reshape(-1, 3), axis=0)))
        # ... and neither are steps far below the sequence's own speed (a motion that slows
        # down to a stop and starts again is not a pop: compare with a quarter of the median)
        floor = max(1e-12 * float(steps.max()), 1e-10 * diag, np.finfo(float).tiny,
                    0.25 * float(np.median(steps)))
        for k in range(K):  # K scalars: the neighbourhood means
            nb = np.concatenate([steps[max(k - 2, 0):k], steps[k + 1:k + 3]])
            pop[k + 1] = steps[k] / max(float(np.mean(nb)), floor) if steps[k] > floor \
                else 1.0
    elif K == 1:
        pop[1] = 1.0
    score = flipped + collapsed + folded + (pop > 1.5)
    order = [int(k) for k in np.argsort(-score, kind="stable")[:5] if score[k] > 0]
    kpop = int(np.argmax(pop))
    return {
        "flipped_faces": int(flipped.sum()),
        "collapsed_faces": int(collapsed.sum()),
        "folded_edges": int(folded.sum()),
        "pop": float(pop.max()) if K else 1.0,
        "pop_frame": kpop,
        "per_frame": {"flipped": flipped.tolist(), "collapsed": collapsed.tolist(),
                      "folded": folded.tolist(), "pop": pop.tolist()},
        "worst_frames": order,
    }

"""The describe and solve stages: LΘA descriptors of the keyframes on consistent angle
branches, the weights of the chosen reference, and the time spline of the targets (paper 001
§4, §7: the time-discrete spline; ``spline="continuous"``: the C² cubic it approximates).
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable

import numpy as np

from ..shells.descriptors import consistent_angles, lta_descriptors, lta_weights
from ..shells.lta_spline import lta_spline
from ..timeline import keyframe_bracket

__all__ = ["describe_and_solve", "SplineTargets", "keyframe_angles", "AngleBand", "SplineRows",
           "geodesic_weights", "ANGLE_MARGIN", "bending_fade", "flap_strain", "FADE_ANGLE", "FADE_FLOOR",
           "HINGE_STRAIN", "POSITIVE_FLOOR", "tube_weights"]

#: Default ``fade_angle`` (radians): an edge whose dihedral angle turns by more than this
#: between the two keyframes of a gap has its bending weight faded in that gap (see
#: :func:`bending_fade`).
FADE_ANGLE = 0.5
#: Factor of a fully faded bending weight.
FADE_FLOOR = 0.01


#: Flap strain (relative change of the edge's length or of either triangle's area between
#: the gap's keyframes) below which an edge is an isometric hinge and keeps its weight, and
#: above which the fade applies in full (smoothstep in between).
HINGE_STRAIN = (0.02, 0.1)


def flap_strain(Zkey, T, periodic: bool = False) -> np.ndarray:
    """Largest relative change of an interior edge's length and of its two triangles' areas
    between the two keyframes of each gap, ``(gaps, i)``: 0 for a flap that turns as a rigid
    hinge, large where the skin around a fold stretches or compresses."""
    sL, _, sA = T.descriptor_slices()
    Z = np.asarray(Zkey, dtype=np.float64)
    if periodic:
        Z = np.vstack([Z, Z[:1]])
    L = Z[:, sL][:, T.interior]
    A = Z[:, sA]
    ef = T.edge_faces[T.interior]

    def rel(X):
        return np.abs(np.diff(X, axis=0)) / np.maximum(np.abs(X[:-1]), np.finfo(float).tiny)
    return np.maximum.reduce([rel(L), rel(A[:, ef[:, 0]]), rel(A[:, ef[:, 1]])])


def bending_fade(Theta_key, periodic: bool = False, angle: float = FADE_ANGLE,
                 floor: float = FADE_FLOOR, strain=None) -> np.ndarray:
    """Factors of the bending weights in the middle of each keyframe gap: ``floor ** s(Δθ)``.

    ``Δθ`` is the turn of an edge's dihedral angle between the two keyframes of the gap (on
    the paths of :func:`keyframe_angles`) and ``s`` a smoothstep from 0 at ``Δθ = angle/2``
    to 1 at ``Δθ = angle``: edges that turn little keep the paper's weight, edges that turn a
    lot (skin folding or unfolding at a joint) keep ``floor`` of it, and nothing jumps in
    between.

    Why: the spline moves such an angle steadily from one keyframe value to the other, but
    a fold in real skin forms by buckling, and the steady target is incompatible with the
    length targets around it. With the paper's weight these few edges (horse-reference →
    horse-03: 318 of 25,255) outvote their neighbours, and the reconstruction has two
    families of local minima in the gap (fold formed / not formed); the run from each
    keyframe stays in its own, so the sequence jumps between them (pop 7.9, 4 flipped faces
    on the horse pair). Faded, their angle follows from the lengths and the unchanged angles
    around them, and the jump goes (pop 1.1). Keyframes stay exact (a keyframe's descriptors
    have zero residual whatever the weights).

    Parameters
    ----------
    Theta_key : (J, i) float64 array
        Keyframe dihedral angles on consistent paths.
    periodic : bool
        Add the gap from the last keyframe back to the first.
    angle : float
        ``0`` (or less) disables the fade: all factors 1.
    floor : float
        In ``(0, 1]``.
    strain : (gaps, i) float64 array, optional
        :func:`flap_strain`; the exponent is multiplied by a smoothstep of it over
        :data:`HINGE_STRAIN`, so an edge that folds as an isometric hinge (the paper's folded
        hexagon, a folding flap) keeps the paper's weight: nothing competes with its angle
        target there, and fading only changed its path (hexagon: 2 % of the diagonal). The
        edges faded on the horse, the stress joint and the sliver tube all have a strain of
        0.18 or more (10th percentile); the hexagon's and the flap's are 0.

    Returns
    -------
    (gaps, i) float64 array

    Examples
    --------
    >>> import numpy as np
    >>> Th = np.array([[0.0, 0.0, 0.0], [0.1, 0.375, 2.0]])
    >>> bending_fade(Th, angle=0.5).round(4).tolist()
    [[1.0, 0.1, 0.01]]
    """
    Th = np.asarray(Theta_key, dtype=np.float64)
    if periodic:
        Th = np.vstack([Th, Th[:1]])
    turn = np.abs(np.diff(Th, axis=0))
    if not angle > 0:
        return np.ones_like(turn)
    s = np.clip((turn - 0.5 * angle) / (0.5 * angle), 0.0, 1.0)
    s = s * s * (3.0 - 2.0 * s)
    if strain is not None:
        lo, hi = HINGE_STRAIN
        g = np.clip((np.asarray(strain, dtype=np.float64) - lo) / (hi - lo), 0.0, 1.0)
        s = s * g * g * (3.0 - 2.0 * g)
    return float(floor) ** s


def keyframe_angles(Theta, periodic):
    """Keyframe angles on the paths of :func:`~shellspline.shells.descriptors.consistent_angles`; for
    a periodic sequence an edge whose paths wind once around the circle over the loop (frame
    K must equal frame 0) takes the direct path in every gap instead."""
    out = consistent_angles(Theta, periodic=periodic)
    if not periodic:
        return out
    wound = np.abs(out[-1] - out[0]) > np.pi
    out = out[:-1]
    out[:, wound] = Theta[:, wound]
    return out


#: Lowest length or area target between two keyframes, as a fraction of the smaller of the
#: two keyframe values (see :class:`AngleBand`).
POSITIVE_FLOOR = 0.5


class AngleBand:
    """Keeps the spline's dihedral-angle targets off ±π between keyframes that are not there,
    and (with ``Zkey``) its length and area targets above :data:`POSITIVE_FLOOR` of the
    smaller of the gap's two keyframe values.

    A cubic through a triangle that shrinks hard at a joint overshoots below its smallest
    keyframe area, to zero and below (horse 0/02/04/06/08 at frames 0, 12, 24, 36, 48: a face
    at −0.017 of the median area at frame 41). A non-positive target gets no weight, so the
    face collapsed freely, its flaps' angle gradients grew like one over its height, and
    Gauss–Newton stalled there (|g| 15 times its start after 26 iterations).

    A spline through angles near ±π overshoots between its keyframes; a target beyond ±π asks
    the reconstruction to pass the edge's triangles through each other (a fold the keyframes
    do not have). In every keyframe gap each angle is clipped to ``[−π + m, π − m]`` widened
    to the two keyframe values themselves (so keyframes held past ±π, see
    :func:`~shellspline.shells.descriptors.consistent_angles`, and the path between them stay as they
    are), with the margin ``m`` = :data:`ANGLE_MARGIN`. Edges away from ±π are untouched.
    """

    def __init__(self, Tkey, sT, frames, K, periodic, Zkey=None, slices=None):
        Tkey = np.asarray(Tkey, dtype=np.float64)
        ext = np.concatenate([Tkey, Tkey[:1]]) if periodic else Tkey
        j0, _, _ = keyframe_bracket(frames, K, periodic)
        self.sT = sT
        self.lo = np.minimum(np.minimum(ext[:-1], ext[1:]), -np.pi + ANGLE_MARGIN)  # per gap
        self.hi = np.maximum(np.maximum(ext[:-1], ext[1:]), np.pi - ANGLE_MARGIN)
        self.gap = np.minimum(j0, len(ext) - 2)
        self.cols = self.floor = None
        if Zkey is not None:
            sL, _, sA = slices
            Zk = np.asarray(Zkey, dtype=np.float64)
            Zk = np.concatenate([Zk, Zk[:1]]) if periodic else Zk
            self.cols = np.r_[np.arange(sL.start, sL.stop), np.arange(sA.start, sA.stop)]
            P = Zk[:, self.cols]
            self.floor = POSITIVE_FLOOR * np.maximum(np.minimum(P[:-1], P[1:]), 0.0)

    def __call__(self, Z, k=None):
        """Clip the angle part of targets ``Z`` ((K+1, d), or rows ``k`` of them)."""
        Z = np.array(Z, dtype=np.float64, copy=True)
        g = self.gap if k is None else self.gap[k]
        Z[..., self.sT] = np.clip(Z[..., self.sT], self.lo[g], self.hi[g])
        if self.floor is not None:
            Z[..., self.cols] = np.maximum(Z[..., self.cols], self.floor[g])
        return Z


#: Margin (radians) between a clipped angle target and ±π (see :class:`AngleBand`).
ANGLE_MARGIN = 0.02


class SplineRows:
    """Rows of ``Z = S @ Zkey`` computed on demand (``S (K+1, J)`` the spline's linear map of
    the keyframe values, ``Zkey (J, d)``, clipped by ``clamp``): ``Z[k]`` for an int, an index
    array or a slice, so the (K+1, d) array need not exist while the reconstruction runs."""

    def __init__(self, S, Zkey, clamp=None):
        self.S, self.Zkey = np.asarray(S, dtype=np.float64), np.asarray(Zkey, dtype=np.float64)
        self.shape = (self.S.shape[0], self.Zkey.shape[1])
        self.clamp = clamp

    def __len__(self):
        return self.shape[0]

    def __getitem__(self, k):
        Z = self.S[k] @ self.Zkey
        if self.clamp is None:
            return Z
        return self.clamp(Z, np.arange(self.shape[0])[k])


def geodesic_weights(Vkey, T, pinned, frames, K, bc, mu, lam, eta, prog, stage_prefix="",
                     max_time_s=None):
    """LΘA weights ``(K+1, d)`` at the piecewise discrete geodesic through the keyframes, and
    the geodesic solve's record (``report["reference_geodesic"]``: an unconverged solve gives
    weights from its last iterates, and the run is not a success).

    ``max_time_s`` (seconds, or None for no limit) bounds this solve on its own, from its
    start (:func:`~shellspline.shells.geodesic.geodesic_interpolation`): a solve it stops
    keeps the paths reached so far, and the record says ``status`` ``"limit"``,
    ``time_limit_reached`` true and "time limit reached" in its ``message``. The record also
    has the solve's ``nit``, initial and final path energy and gradient max-norm
    (:meth:`~shellspline.numerics.result.SolverResult.summary`), ``seconds`` and
    ``max_time_s``."""
    from ..shells.geodesic import geodesic_interpolation

    n_seg = len(frames) - (0 if bc == "periodic" else 1)
    stage = stage_prefix + "reference geodesic"
    t0 = time.perf_counter()
    with prog.stage(stage, total=n_seg):
        import warnings

        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            # one line per Newton step in logs, as for method="geodesic"
            g = geodesic_interpolation(
                Vkey, frames, K, T, mu=mu, lam=lam, eta=eta, pinned=pinned, bc=bc,
                max_time_s=max_time_s, callback=lambda s, r: prog.advance(stage, s + 1, n_seg),
                progress=lambda s, it, e, gn: prog.advance(
                    stage, s, n_seg, text=f"segment {s + 1}/{n_seg}  it {it:3d}  E {e:.6g}  "
                                          f"|g| {gn:.2e}"))
        if not g.success:
            prog.message(f"reference geodesic: {g.message} (weights from the current iterates)")
    record = {**g.summary(), "resolution": stage_prefix.strip() or "full",
              "time_limit_reached": bool(g.time_limit_reached), "max_time_s": max_time_s,
              "seconds": time.perf_counter() - t0, "factorizations": int(g.factorizations)}
    return lta_weights(g.V, T, mu=mu, lam=lam, eta=eta), record


@dataclass
class SplineTargets:
    """What the describe and solve stages give the reconstruction.

    Attributes
    ----------
    Zkey : (J,d) float64 array
        Keyframe descriptors, angles on consistent branches.
    clamp : AngleBand
        Keeps angle targets off ±π (re-used by the fixpoint iterations).
    Z : (K+1,d) float64 array or SplineRows
        Targets of every frame (rows on demand with a constant reference).
    W_of : callable(int) -> (d,) float64 array
        Weights of frame ``k``.
    W_spline : (K+1,d) float64 array or None
        Per-frame weights of the spline (None: constant, ``W_report``).
    W_report : (d,) or (K+1,d) float64 array
        The weights the report's energies use (the paper's, without the fade).
    faded_edges : int
        Interior edges whose bending weight :func:`bending_fade` lowers in some gap.
    tube_of : callable(int) -> (i,) float64 array, or None
        Tube weights of frame ``k``'s dihedral angles (:func:`tube_weights`); None without a
        fade.
    reference : dict or None
        With ``reference="geodesic"``: the record of its geodesic solve
        (:func:`geodesic_weights`).
    """

    Zkey: np.ndarray
    clamp: AngleBand
    Z: object
    W_of: Callable
    W_spline: np.ndarray | None
    W_report: np.ndarray
    faded_edges: int = 0
    tube_of: Callable | None = None
    reference: dict | None = None


def describe_and_solve(Vkey, T, pinned, prob, opts, prog, stage_prefix="") -> SplineTargets:
    """Describe the keyframes, choose the weights of ``opts.reference`` and solve the LΘA
    spline of the targets.

    Parameters
    ----------
    Vkey : (J,n,3) float64 array
    T : Topology
    pinned : (p,) int array or None
    prob : InterpolationProblem
        Frames, ``K`` (the mesh of ``prob`` may be a finer resolution than ``Vkey``).
    opts : InterpolationOptions
    prog : Progress
    stage_prefix : str

    Returns
    -------
    SplineTargets
    """
    frames, K, bc, periodic = prob.frames, prob.K, opts.bc, opts.periodic
    par = dict(mu=opts.mu, lam=opts.lam, eta=opts.eta)
    with prog.stage(stage_prefix + "describe"):
        Zkey = lta_descriptors(Vkey, T)
        sT = T.descriptor_slices()[1]
        Zkey[:, sT] = keyframe_angles(Zkey[:, sT], periodic)
        clamp = AngleBand(Zkey[:, sT], sT, frames, K, periodic, Zkey=Zkey,
                          slices=T.descriptor_slices())
        ref = opts.reference
        ref_record = None
        if not isinstance(ref, str) or ref == "constant":
            w_const = lta_weights(Vkey[0 if isinstance(ref, str) else ref], T, **par)
            W_spline, W_report = None, w_const

            def W_of(k):
                return w_const
        elif ref == "geodesic":
            # the solver stages' time limit bounds this solve too, on its own clock
            W_spline, ref_record = geodesic_weights(
                Vkey, T, pinned, frames, K, bc, prog=prog, stage_prefix=stage_prefix,
                max_time_s=opts.solver_options.get("max_time_s"), **par)
            W_report = W_spline

            def W_of(k):
                return W_spline[k]
        else:
            Wkey = lta_weights(Vkey, T, **par)
            j0, j1, t = keyframe_bracket(frames, K, periodic)
            nearest = np.where(t <= 0.5, j0, j1)
            W_spline = W_report = Wkey[nearest]

            def W_of(k):
                return Wkey[nearest[k]]
        fade = bending_fade(Zkey[:, sT], periodic, opts.fade_angle,
                            strain=flap_strain(Zkey, T, periodic))
        faded = int((fade < 1.0).any(axis=0).sum())
        tube_of = None
        if faded:
            j0, _, t = keyframe_bracket(frames, K, periodic)
            gap = np.minimum(j0, len(fade) - 1)
            depth = np.sin(np.pi * np.clip(t, 0.0, 1.0))
            tube_of = tube_weights(W_of, fade, gap, depth, sT)
            W_of = _faded(W_of, fade, gap, depth, sT)
    with prog.stage(stage_prefix + "solve"):
        if W_spline is None:
            # constant weights: the spline is one linear map of the keyframes, Z = S Zkey;
            # the reconstruction takes its rows on demand and the (K+1, d) array is formed
            # afterwards (0.5 GB at 150k vertices, K = 50, not held while the workers run)
            Z = SplineRows(lta_spline(np.eye(len(frames)), frames, K, bc=bc, spline=opts.spline),
                           Zkey, clamp)
        else:
            Z = clamp(lta_spline(Zkey, frames, K, bc=bc, weights=W_spline, spline=opts.spline))
    return SplineTargets(Zkey=Zkey, clamp=clamp, Z=Z, W_of=W_of, W_spline=W_spline,
                         W_report=W_report, faded_edges=faded, tube_of=tube_of,
                         reference=ref_record)


def _faded(W_of, fade, gap, depth, sT):
    """``W_of`` with the bending weights of frame ``k`` multiplied by its gap's fade raised to
    ``depth[k]`` (``sin(π t)``, ``t`` the frame's place in its gap): the full fade in the middle
    of the gap, none at its keyframes, so that the frames next to a keyframe approach it with
    the paper's weights (measured on data_synth.stress.joint: the constant fade let 2–3
    edges that fold completely at the 150° keyframe snap through in a single step; faded
    this way none does, and the horse pair keeps its gain, pop 7.9 → 1.4)."""
    def faded_W_of(k):
        w = np.array(W_of(k), dtype=np.float64, copy=True)
        w[sT] *= fade[gap[k]] ** depth[k]
        return w
    return faded_W_of


def tube_weights(W_of, fade, gap, depth, sT):
    """The tube weights that go with the faded bending weights of :func:`_faded`: what the
    fade took away, ``w (1 − fade ** depth)`` per dihedral angle of frame ``k``.

    The reconstruction (:meth:`~shellspline.shells.reconstruct.GaussNewton.merit`) lets an
    angle leave its spline target by up to
    :data:`~shellspline.shells.reconstruct.ANGLE_TUBE` at its faded weight and charges the
    paper's weight again on the distance beyond. Why: a faded angle is free, and a flap whose
    lengths and areas are its only targets is bistable (it can buckle either way, and a
    skin fold can be formed or not): on the horse (``horse-reference, horse-03, horse-07`` at
    frames 0, 20, 40) faded edges stayed at their keyframe's value for half a gap and then
    snapped through ±π in one step (edge 16743: keyframes −0.43, 2.44, −0.13; frames 4–8 of
    the run from keyframe 0: −0.44, −0.52, −0.76, −2.79, 3.08), and the two runs of a gap met
    with a fold formed in one and not in the other (edge 1364: keyframes 0.00, 0.93, −0.14;
    2.54 at frame 31, −1.41 at frame 32).
    A band between the two keyframe values did not help (both states are inside it: 5 flips
    and 7 folds instead of 4 and 6); the full weight back everywhere (``fade_angle=0``)
    crumpled the seam (38 flipped faces). With the tube, no edge folds on four horse pose
    sets (2026-11-25, ``coarse="none"``; new flipped / folded, before → after):
    reference/03/07 4/6 → 6/0, reference/05/09 1/1 → 2/0, 01/04/08 6/8 → 9/0, the five
    poses reference/02/04/06/08 1/6 → 1/0, pops within ±0.03. Narrower tubes hold harder and
    crumple more (0.75: 8 and 10 flips on the first and third; 0.4: 13 on the first), wider
    ones fold more on the sliver tube of ``data_synth.stress`` (1.25: 3 folded edges, 1.0:
    1, none: 9).

    Parameters
    ----------
    W_of : callable(int) -> (d,) float64 array
        The unfaded weights of frame ``k``.
    fade : (gaps, i) float64 array
        :func:`bending_fade`.
    gap : (K+1,) int array
        Keyframe gap of every frame.
    depth : (K+1,) float64 array
        Exponent of the fade at every frame (see :func:`_faded`).
    sT : slice
        The dihedral angles in the descriptor vector.

    Returns
    -------
    callable(int) -> (i,) float64 array
    """
    def tube_of(k):
        w = np.asarray(W_of(k), dtype=np.float64)[sT]
        return w * (1.0 - fade[gap[k]] ** depth[k])
    return tube_of

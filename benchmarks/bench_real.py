"""Real data: in-betweens against ground truth (skinned BVH bodies) and the horse (issue 13).

What is measured
----------------
**Ground truth** (``--no-gt`` skips it). For every BVH clip in ``../shared/data/motion``
(skipped with a message when absent), :mod:`data_synth.skinned` builds a closed body mesh
around the clip's skeleton and poses it at every frame by linear blend skinning, as games and
rigs do: the true frames of a window of ``K + 1`` consecutive frames (the middle of the clip,
``K`` a multiple of 6). Every 3rd and every 6th frame is kept as a keyframe, and the frames in
between are rebuilt by

* ``lta``: ``shellspline.interpolate`` (LΘA, default options: ``spline="continuous"``, the C²
  cubic spline in time through the keyframe descriptors; the body is below the automatic
  multiresolution threshold, so this is full resolution);
* ``lta-keyref``: the same with ``reference="keyframe"`` (the LΘA weights of each frame's
  nearest keyframe instead of the first keyframe's; the skin at the joints changes its
  triangles between keyframes, and the first keyframe's weights misjudge them later on; with
  the continuous spline, the continuous limit of the spline weighted by the nearest keyframe);
* ``lta-discrete``: the same as ``lta`` with ``spline="discrete"`` (the paper's time-discrete
  spline, the default before, whose velocity kinks at the keyframes ``cubic-discrete`` below
  measures);
* ``lta-disc-keyref``: ``spline="discrete", reference="keyframe"``;
* ``lta-c1000``: the same as ``lta`` with ``coarse=1000`` (full mode only);
* ``linear``: ``shellspline.linear_blend`` (per-vertex linear blending);
* ``cubic``: ``scipy.interpolate.CubicSpline`` through the keyframes, per vertex coordinate,
  natural end conditions;
* ``lta-cold`` (``--cold``, a diagnostic): LΘA with ``warm_start=False``;
* ``lta@cubic`` (a diagnostic, no solve): every LΘA frame moved rigidly (Kabsch) onto the
  cubic's frame (``interpolate`` already places its frames on the cubic track, so this equals
  ``lta`` up to round-off: a check that the rigid parts compare alike);
* ``lta@wfit`` (a diagnostic, no solve): the same with a weighted Kabsch fit, each vertex
  weighted by ``1 / (0.3 median(q) + q)``, ``q`` the cubic's squared third-derivative jumps
  at the interior keyframes (:func:`spline_error_weights`): a placement that trusts the
  vertices whose track the keyframes resolve; what a weighted placement would gain or cost;
* ``cubic-discrete`` (a diagnostic, fairness of the comparison): the paper's time-discrete
  spline (``shellspline.shells.lta_spline``, constant reference, natural ends: the spline LΘA
  runs on its descriptors) applied per vertex coordinate. Its ratio to ``cubic`` is what the
  time discretisation alone costs (a discrete spline is piecewise cubic with a velocity kink
  at the keyframes: 0.1–0.5 % with every 6th frame kept, 1.6–3.5 % with every 3rd);
* ``rig`` (a diagnostic, no mesh solve): the truth's own rig interpolated: each joint's local
  rotation by a natural C² cubic spline on SO(3) (:func:`shellspline.curves.cubic_spline`),
  its local translation by a natural cubic, forward kinematics, and the same skinning. LΘA
  interpolates intrinsic quantities (lengths, dihedral angles) and so behaves like a joint-space
  interpolant; where ``rig`` also loses to the cubic in ``shape``, interpolating the joints is
  worse than interpolating world positions for that motion (a planted foot is static in world
  space, not in joint space) and the loss is not the reconstruction's.

Error of a frame: rms vertex distance to the true frame over the body's size (the mean over
the window of each true frame's bounding-box diagonal: the body travels meters, its diagonal
stays ≈ its height); reported as the rms over the in-between frames (``err``), the worst
in-between frame (``max``), and the same after a per-frame rigid (Procrustes) alignment to the
truth (``shape``: the part that no rigid placement can explain; ``rigid`` =
``sqrt(err² − shape²)``, the rms rigid misplacement of the frames). Quality:
``shellspline.metrics.sequence_defects`` (new flipped / collapsed faces, folded edges, pop),
Gauss–Newton frames converged / stalled and iterations. Ratios ``lta/linear`` and
``lta/cubic`` (issue 13's goal: both ≤ 1, column ``goal``) and ``shape/cubic`` (the ``shape``
parts; the ``rigid`` parts are equal by construction), for the diagnostics too. Where LΘA
loses, the JSON says where: the worst frames (error, flips, Gauss–Newton status) and the
joints whose vertices carry most of the excess ``shape`` error over the cubic spline. A third
table splits the rigid misplacement of ``lta`` and ``cubic`` (rms centroid offset, per axis,
and best-fit rotation angle: an aliased vertical bounce shows as one large axis) and gives
their error over the two end gaps and over the interior gaps relative to the cubic's (where
the natural end conditions act, and where they do not). ``--descriptors`` (a diagnostic, a
minute per clip) rebuilds LΘA's in-betweens from the natural cubic spline of the keyframe
descriptors with one group taken from the truth (lengths, dihedral angles, areas;
:func:`descriptor_swaps`): the group whose true values remove the ``shape`` loss is the one
whose time interpolation costs it.

**Horse** (``--no-horse`` skips it): ``../shared/data/horse`` keyframes ``horse-reference,
horse-03, horse-07`` at frames 0, 20, 40 (K = 40): full resolution (``coarse="none"``),
``coarse=1000`` and ``coarse=1000, fine=True``, and linear blending: wall time, Gauss–Newton
frames converged / stalled, iterations median / max, new defects, pop, ``strain99``
(:func:`length_strain`), keyframes exact.
``--subdivided`` adds the same keyframes midpoint-subdivided twice (134 782 vertices) through
the default options (above 20 000 vertices: multiresolution with 1000 coarse vertices), the
same with the paper's detail transfer (``transfer="displacement"``), and their linear
blending. Midpoint subdivision leaves every original triangle flat, which no scan or sculpt
has (the decimation of it stops at 1 297 vertices: its flat patches cannot lose more vertices
without turning faces over in some pose), so ``--subdivided`` also runs the keyframes
Loop-subdivided once (33 705 vertices, the size of the camel, flamingo or elephant of the
deformation-transfer meshes) and twice (134 782), smooth everywhere, through the default
options: production-size meshes as the default path meets them.
``--nonlinear`` adds five horse poses (reference, 02, 04, 06, 08) at frames 0, 12, 24, 36,
48 with ``method="nonlinear"``, ``coarse=1000``, ``solver_options={"max_time_s": 120}``.

Run
---
::

    PYTHONPATH=. python3 benchmarks/bench_real.py --quick      # smaller windows, coarse horse
    PYTHONPATH=. python3 benchmarks/bench_real.py              # full (~8-15 minutes)
    PYTHONPATH=. python3 benchmarks/bench_real.py --no-horse --clips walk_normal
    PYTHONPATH=. python3 benchmarks/bench_real.py --no-horse --clips run_normal --start 0
    PYTHONPATH=. python3 benchmarks/bench_real.py --no-horse --clips run_normal --descriptors

``--start`` moves the window (default: the middle of the clip), so that the keyframes fall on
other phases of the motion: one window is one sample of where the keyframes happen to land.

The tables go to stdout, everything to ``benchmarks/results/bench_real.json`` (``--json``).
A benchmark, not a test: nothing is asserted.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from _common import _timed, format_table  # noqa: E402  (benchmarks/ is on sys.path)

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
MOTION_DIR = REPO.parent / "shared" / "data" / "motion"
HORSE_DIR = REPO.parent / "shared" / "data" / "horse"
DEFAULT_OUT = REPO / "benchmarks" / "results" / "bench_real.json"
HORSE_KEYS = ("horse-reference", "horse-03", "horse-07")
HORSE_FRAMES = (0, 20, 40)
HORSE_NONLINEAR_KEYS = ("horse-reference", "horse-02", "horse-04", "horse-06", "horse-08")
HORSE_NONLINEAR_FRAMES = (0, 12, 24, 36, 48)


# ----------------------------------------------------------------------------------------
# measurements shared by both parts
# ----------------------------------------------------------------------------------------
def gn_summary(report: dict) -> dict:
    """Gauss–Newton frames converged / stalled, iterations (median, max) and the seams (first
    frame after a jump between the two runs of a keyframe gap, and the jump over the typical
    step: ``shellspline.pipeline.reconstruction.seam_records``) of a report."""
    recs = report.get("frames") or []
    nit = [r["nit"] for r in recs]
    statuses = {}
    for r in recs:
        statuses[r.get("status", "?")] = statuses.get(r.get("status", "?"), 0) + 1
    return {"frames": len(recs), "statuses": statuses,
            "converged": int(sum(bool(r["success"]) for r in recs)),
            "stalled": int(sum(r.get("status") == "stalled" for r in recs)),
            "it_median": float(np.median(nit)) if nit else None,
            "it_max": int(max(nit)) if nit else None,
            "seams": [[int(r["frame"]), round(float(r["seam_jump"]), 2)] for r in recs
                      if "seam_jump" in r]}


def defects(V, T, frames) -> dict:
    from shellspline.metrics import sequence_defects

    d = sequence_defects(V, T, frames)
    return {"flipped": d["flipped_faces"], "collapsed": d["collapsed_faces"],
            "folded": d["folded_edges"], "pop": d["pop"], "per_frame": d["per_frame"]}


# ----------------------------------------------------------------------------------------
# ground truth
# ----------------------------------------------------------------------------------------
def _rigidly_onto(X, Y):
    """Every frame of X (T,n,3) moved by its best rotation + translation onto Y (T,n,3)
    (Kabsch)."""
    from shellspline.mesh.rigid import best_rotations

    Xm, Ym = X.mean(axis=1, keepdims=True), Y.mean(axis=1, keepdims=True)
    R = best_rotations(X - Xm, Y - Ym)  # maps X onto Y: y = R x
    return np.einsum("tij,tnj->tni", R, X - Xm) + Ym


def procrustes_residual(X, Y):
    """Per-frame rms of X (T,n,3) after the best rotation + translation onto Y (T,n,3)."""
    return np.sqrt(((_rigidly_onto(X, Y) - Y) ** 2).sum(-1).mean(-1))


def rigid_offsets(X, Y):
    """The rigid misplacement of every frame of X (T,n,3) against Y (T,n,3): the offset of
    the vertex centroids ``(T,3)`` and the angle in degrees ``(T,)`` of the best rotation
    (Kabsch) of X onto Y about them."""
    from shellspline.mesh.rigid import best_rotations

    Xm, Ym = X.mean(axis=1, keepdims=True), Y.mean(axis=1, keepdims=True)
    R = best_rotations(X - Xm, Y - Ym)
    cos = np.clip((np.trace(R, axis1=-2, axis2=-1) - 1.0) / 2.0, -1.0, 1.0)
    return (Xm - Ym)[:, 0], np.degrees(np.arccos(cos))


def ground_truth_errors(X, truth, inner, size, frames=None) -> dict:
    """Errors of poses ``X (T,n,3)`` against ``truth`` on the in-between frames ``inner``,
    relative to ``size``: rms ``err``, worst frame ``max``, the ``shape`` part (after a
    per-frame rigid fit) and the ``rigid`` rest (``err² = shape² + rigid²``); the rigid
    misplacement itself: rms centroid offset (``translation``, and per axis
    ``translation_axes``) and best-fit rotation angle (``rotation_deg``); with the keyframes
    ``frames``, ``err`` over the two end gaps and over the interior gaps (``gaps``: where a
    spline's end conditions act, and where they do not)."""
    e = np.sqrt(((X - truth) ** 2).sum(-1).mean(-1)) / size
    s = procrustes_residual(X[inner], truth[inner]) / size
    err, shape = float(np.sqrt(np.mean(e[inner] ** 2))), float(np.sqrt(np.mean(s ** 2)))
    dc, angle = rigid_offsets(X[inner], truth[inner])
    # err² = shape² + rigid²: the rigid part is the rms of the per-frame rigid misplacement
    out = {"err": err, "max": float(e[inner].max()), "shape": shape,
           "rigid": float(np.sqrt(max(err ** 2 - shape ** 2, 0.0))),
           "translation": float(np.sqrt(np.mean((dc ** 2).sum(-1)))) / size,
           "translation_axes": (np.sqrt(np.mean(dc ** 2, axis=0)) / size).tolist(),
           "rotation_deg": float(np.sqrt(np.mean(angle ** 2))),
           "err_per_frame": e.tolist()}
    if frames is not None and len(frames) > 2:
        f = np.asarray(frames)
        end = (inner < f[1]) | (inner > f[-2])
        out["gaps"] = {name: float(np.sqrt(np.mean(e[inner[m]] ** 2))) if m.any() else None
                       for name, m in (("end", end), ("interior", ~end))}
    return out


def spline_error_weights(Vkey, frames, floor: float = 0.3):
    """Per-vertex weights ``1 / (floor · median(q) + q)`` from the natural per-vertex cubic
    spline through the keyframes ``Vkey (J,n,3)`` at ``frames``: ``q`` is the mean over the
    interior keyframes of the squared jump of the spline's third derivative, its local error
    indicator (the error of a cubic interpolant grows with the fourth derivative, which the
    jumps over the spacing estimate). None (equal weights) with fewer than 3 keyframes or
    where every ``q`` is 0."""
    from scipy.interpolate import CubicSpline

    if len(frames) < 3:
        return None
    t = np.asarray(frames, dtype=np.float64)
    cs = CubicSpline(t, Vkey, axis=0, bc_type="natural")
    q = ((6.0 * np.diff(cs.c[0], axis=0)) ** 2).sum(-1).mean(0)  # (n,)
    scale = np.median(q) if np.median(q) > 0 else np.mean(q)
    # jumps at round-off level (every track a line): no preference
    if not scale > 1e-24 * (np.ptp(Vkey, axis=0).max() / np.diff(t).min() ** 3) ** 2:
        return None
    return 1.0 / (floor * scale + q)


def placed_on(V, track, frames, weights=None):
    """Every in-between frame of ``V (K+1,n,3)`` (not in ``frames``) moved rigidly onto the
    same frame of ``track`` by a Kabsch fit with per-vertex ``weights``; keyframes kept."""
    from shellspline.shells.reconstruct import rigid_placement

    out = np.array(V, dtype=np.float64, copy=True)
    for k in np.setdiff1d(np.arange(V.shape[0]), frames):
        out[k] = rigid_placement(V[k], track[k], weights=weights)
    return out


def descriptor_swaps(truth, F, frames, V_init, size) -> dict:
    """Which descriptor's time spline costs the shape: every in-between frame rebuilt
    (one Gauss–Newton solve from ``V_init``, LΘA weights of the first keyframe, the
    keyframes scaled by :func:`shellspline.metrics.length_scale` as ``interpolate`` does)
    from the natural C² cubic spline of the keyframe descriptors (lengths, dihedral angles on
    their :func:`~shellspline.shells.descriptors.consistent_angles` paths, areas), and from
    the same with one group replaced by the truth's (``true_L``, ``true_theta``, ``true_A``).

    Returns
    -------
    dict
        ``shape`` error (rms over the in-between frames, after each frame's rigid fit to the
        truth, relative to ``size``) per variant (``spline``, ``true_L``, ``true_theta``,
        ``true_A``), and the Gauss–Newton frames that did not converge (``unconverged``).
    """
    from scipy.interpolate import CubicSpline

    from shellspline.metrics import length_scale
    from shellspline.shells.descriptors import (consistent_angles, dihedral_angles,
                                                edge_lengths, face_areas, lta_weights,
                                                wrap_angle)
    from shellspline.shells.reconstruct import reconstruct
    from shellspline.mesh.topology import topology

    T = topology(F)
    frames = np.asarray(frames)
    K = truth.shape[0] - 1
    inner = np.setdiff1d(np.arange(K + 1), frames)
    D = length_scale(truth[frames[0]], F)
    X = truth / D
    L, Th, A = edge_lengths(X, T), dihedral_angles(X, T), face_areas(X, T)
    key = np.concatenate([L[frames], consistent_angles(Th[frames]), A[frames]], axis=1)
    Zs = CubicSpline(frames.astype(np.float64), key, axis=0, bc_type="natural")(inner)
    e, i = L.shape[1], Th.shape[1]
    th_true = Zs[:, e:e + i] + wrap_angle(Th[inner] - Zs[:, e:e + i])  # on the spline's branch
    Zt = np.concatenate([L[inner], th_true, A[inner]], axis=1)
    w = lta_weights(X[frames[0]], T)
    groups = {"true_L": slice(0, e), "true_theta": slice(e, e + i), "true_A": slice(e + i, None)}
    out, unconverged = {}, 0
    for name in ("spline", *groups):
        Z = Zs.copy()
        if name in groups:
            Z[:, groups[name]] = Zt[:, groups[name]]
        Vr = np.empty((len(inner),) + truth.shape[1:])
        for r, k in enumerate(inner):
            res = reconstruct(Z[r], w, V_init[k] / D, T)
            Vr[r] = res.V * D
            unconverged += not res.success
        s = procrustes_residual(Vr, truth[inner]) / size
        out[name] = float(np.sqrt(np.mean(s ** 2)))
    out["unconverged"] = int(unconverged)
    return out


def gt_case(path: Path, window: int, n_vertices: int, steps, workers: int,
            coarse: bool, cold: bool = False, start: int | None = None,
            descriptors: bool = False) -> dict:
    """All methods on one clip: the true window (from frame ``start``, default the middle of
    the clip), keyframes every ``step`` frames; ``descriptors``: also
    :func:`descriptor_swaps` from the LΘA frames."""
    import shellspline
    from scipy.interpolate import CubicSpline

    from data_synth.skinned import linear_blend_skinning, skinned_body
    from shellspline.io.bvh import read_bvh
    from shellspline.shells.lta_spline import lta_spline

    motion = read_bvh(path)
    K = (min(window, motion.n_frames - 1) // 6) * 6
    if start is None:
        start = (motion.n_frames - (K + 1)) // 2
    elif not 0 <= start <= motion.n_frames - (K + 1):
        raise SystemExit(f"--start {start}: {path.name} has {motion.n_frames} frames, a window "
                         f"of {K + 1} starts at 0 .. {motion.n_frames - (K + 1)}")
    win = np.arange(start, start + K + 1)
    body, t_body = _timed(skinned_body, motion, n_vertices=n_vertices)
    b = body["bind_frame"]
    truth = linear_blend_skinning(body["V"], body["W"], body["P"][b], body["R"][b],
                                  body["P"][win], body["R"][win])
    F = body["F"]
    T = shellspline.topology(F)
    size = float(np.mean(np.linalg.norm(np.ptp(truth, axis=1), axis=1)))
    owner = body["W"].argmax(axis=1)
    out = {"clip": path.stem, "vertices": int(truth.shape[1]), "faces": int(F.shape[0]),
           "K": int(K), "start": int(start), "fps": motion.fps, "body_seconds": t_body,
           "body_size": size, "travel": float(np.linalg.norm(truth[-1].mean(0)
                                                             - truth[0].mean(0))),
           "steps": {}}
    for step in steps:
        frames = np.arange(0, K + 1, step)
        inner = np.setdiff1d(np.arange(K + 1), frames)
        kf = shellspline.keyframes_from_arrays(truth[frames], F, frames=frames)
        runs = {}
        res, t = _timed(shellspline.interpolate, kf, workers=workers)
        runs["lta"] = (res.V, t, gn_summary(res.report))
        res_k, t = _timed(shellspline.interpolate, kf, workers=workers, reference="keyframe")
        runs["lta-keyref"] = (res_k.V, t, gn_summary(res_k.report))
        res_s, t = _timed(shellspline.interpolate, kf, workers=workers, spline="discrete")
        runs["lta-discrete"] = (res_s.V, t, gn_summary(res_s.report))
        res_s, t = _timed(shellspline.interpolate, kf, workers=workers, spline="discrete",
                          reference="keyframe")
        runs["lta-disc-keyref"] = (res_s.V, t, gn_summary(res_s.report))
        if coarse:
            res_c, t = _timed(shellspline.interpolate, kf, workers=workers, coarse=1000)
            runs["lta-c1000"] = (res_c.V, t, gn_summary(res_c.report))
        if cold:
            res_w, t = _timed(shellspline.interpolate, kf, workers=workers, warm_start=False)
            runs["lta-cold"] = (res_w.V, t, gn_summary(res_w.report))
        Vl, t = _timed(shellspline.linear_blend, truth[frames], frames, K)
        runs["linear"] = (Vl, t, None)
        Vc, t = _timed(lambda: CubicSpline(frames, truth[frames], axis=0,
                                           bc_type="natural")(np.arange(K + 1)))
        runs["cubic"] = (Vc, t, None)
        # diagnostic: LΘA's shapes moved rigidly onto the cubic instead of the linear blend
        # (what the rigid placement alone costs or gains)
        runs["lta@cubic"] = (_rigidly_onto(res.V, Vc), 0.0, None)
        # diagnostic: LΘA's frames placed on the cubic by a fit weighted by the cubic's own
        # error indicator (trusting the vertices whose track the keyframes resolve)
        runs["lta@wfit"] = (placed_on(res.V, Vc, frames,
                                      spline_error_weights(truth[frames], frames)), 0.0, None)
        Vd, t = _timed(lambda: np.einsum("kj,jnx->knx", lta_spline(np.eye(len(frames)), frames, K),
                                         truth[frames]))
        runs["cubic-discrete"] = (Vd, t, None)
        rig = rig_interpolation(motion, win, frames)
        if rig is not None:
            Vr, t = _timed(linear_blend_skinning, body["V"], body["W"], body["P"][b],
                           body["R"][b], *rig)
            runs["rig"] = (Vr, t, None)
        rec = {"keyframes": frames.tolist(), "truth_defects": _strip(defects(truth, T, frames)),
               "methods": {}}
        for name, (X, t, gn) in runs.items():
            rec["methods"][name] = {"seconds": t, "gn": gn,
                                    **ground_truth_errors(X, truth, inner, size, frames),
                                    **defects(X, T, frames)}
        rec["where"] = {name: _where(name, runs, truth, inner, size, owner, motion.names, rec)
                        for name in runs if name.startswith("lta") and "@" not in name}
        if descriptors:
            rec["descriptors"] = descriptor_swaps(truth, F, frames, res.V, size)
        out["steps"][str(step)] = rec
    return out


def rig_interpolation(motion, win, frames):
    """The joints of a clip's window interpolated through its keyframes, in joint space.

    Parameters
    ----------
    motion : shellspline.io.bvh.Motion
    win : (K+1,) int array
        Clip frames of the window.
    frames : (J,) int array
        Keyframes, as indices into the window (increasing, ``frames[0] = 0``).

    Returns
    -------
    (P, R) : (K+1,J,3), (K+1,J,3,3) float64 arrays, or None
        World joint positions and rotations of every window frame by forward kinematics of
        the interpolated local transforms: each local rotation follows a natural C² cubic
        spline on SO(3), each local translation a natural cubic (scipy); equal to the clip's
        at the keyframes. None when the SO(3) spline is not defined (a joint turning by half
        a turn or more between keyframes) or its solve does not converge.
    """
    from scipy.interpolate import CubicSpline

    from shellspline.curves import cubic_spline
    from shellspline.errors import ShellsplineError

    R_loc, t_loc = motion.frames(int(win[0]), int(win[-1]) + 1).local_transforms()
    t = np.asarray(frames, dtype=np.float64)
    k = np.arange(len(win), dtype=np.float64)
    try:
        s = cubic_spline("so3", t, np.swapaxes(R_loc[frames], 0, 1))  # (J, keys, 3, 3)
    except ShellsplineError:
        return None
    if s.solve is not None and s.solve.status != "converged":
        return None
    R_loc = np.swapaxes(s(k), 0, 1)
    t_loc = CubicSpline(t, t_loc[frames], axis=0, bc_type="natural")(k)
    P, R = np.empty_like(t_loc), np.empty_like(R_loc)
    for j, p in enumerate(motion.parents):  # parents first (BVH order)
        if p < 0:
            P[:, j], R[:, j] = t_loc[:, j], R_loc[:, j]
        else:
            P[:, j] = P[:, p] + np.einsum("fab,fb->fa", R[:, p], t_loc[:, j])
            R[:, j] = R[:, p] @ R_loc[:, j]
    return P, R


def _strip(d: dict) -> dict:
    return {k: v for k, v in d.items() if k != "per_frame"}


def _where(name, runs, truth, inner, size, owner, names, rec) -> dict:
    """Where an LΘA run's error comes from: its worst in-between frames, and the joints whose
    vertices (by strongest skinning weight) carry most of its excess over the cubic in the
    ``shape`` part (share of the summed excess of the joints where it is worse; LΘA may be
    better overall)."""
    lta, cub = rec["methods"][name], rec["methods"]["cubic"]
    e = np.asarray(lta["err_per_frame"])
    worst = inner[np.argsort(-e[inner])[:3]]
    frames_out = [{"frame": int(k), "lta": float(e[k]), "cubic": cub["err_per_frame"][k],
                   "linear": rec["methods"]["linear"]["err_per_frame"][k],
                   "flipped": lta["per_frame"]["flipped"][k]} for k in worst]
    # per-vertex errors after each frame's rigid fit to the truth: the shape part, where the
    # excess lives (the rigid parts are equal: both are placed on the same travel)
    d_l = ((_rigidly_onto(runs[name][0][inner], truth[inner]) - truth[inner]) ** 2
           ).sum(-1).mean(0)  # (n,)
    d_c = ((_rigidly_onto(runs["cubic"][0][inner], truth[inner]) - truth[inner]) ** 2
           ).sum(-1).mean(0)
    J = owner.max() + 1
    excess = np.bincount(owner, d_l - d_c, minlength=J)
    total = max(float(np.sum(np.maximum(excess, 0.0))), 1e-300)  # joints where LΘA is worse
    joints = []
    for j in [j for j in np.argsort(-excess) if np.any(owner == j)][:3]:  # joints with skin
        m = owner == j
        joints.append({"joint": names[j], "vertices": int(m.sum()),
                       "share_of_excess": float(excess[j] / total),
                       "lta": float(np.sqrt(d_l[m].mean()) / size),
                       "cubic": float(np.sqrt(d_c[m].mean()) / size)})
    # error of the frames next to a keyframe vs the others (mid-gap)
    step = int(np.diff(rec["keyframes"][:2])[0]) if len(rec["keyframes"]) > 1 else 1
    off = np.minimum(inner % step, step - inner % step)
    near = [float(np.sqrt(np.mean(e[inner[off == o]] ** 2))) for o in np.unique(off)]
    return {"worst_frames": frames_out, "joints": joints, "by_distance_to_keyframe": near}


def gt_tables(cases) -> str:
    rows, ratio_rows = [], []
    for c in cases:
        for step, rec in c["steps"].items():
            m = rec["methods"]
            for name, r in m.items():
                gn = r["gn"] or {}
                rows.append([f"{c['clip']} /{step}", name, 1e3 * r["err"], 1e3 * r["max"],
                             1e3 * r["shape"], 1e3 * r["rigid"], r["flipped"], r["collapsed"],
                             r["folded"],
                             r["pop"], f"{gn['converged']}/{gn['stalled']}/{gn['frames']}"
                             if gn else "-",
                             f"{gn['it_median']:g}/{gn['it_max']}" if gn else "-",
                             r["seconds"]])
            for name in [n for n in m if n not in ("linear", "cubic", "lta@cubic")]:
                r_lin = m[name]["err"] / m["linear"]["err"]
                r_cub = m[name]["err"] / m["cubic"]["err"]
                lta = name.startswith("lta") and "@" not in name  # lta@...: diagnostics
                ratio_rows.append([f"{c['clip']} /{step}", name, f"{r_lin:.3f}", f"{r_cub:.3f}",
                                   f"{m[name]['shape'] / max(m['cubic']['shape'], 1e-300):.3f}",
                                   ("yes" if max(r_lin, r_cub) <= 1 else "NO") if lta
                                   else "(diagnostic)",
                                   ", ".join(f"{j['joint']} {100 * j['share_of_excess']:.0f}%"
                                             for j in rec["where"].get(name, {"joints": []})
                                             ["joints"]
                                             if j["share_of_excess"] > 0.1) or "-"])
    t1 = format_table(["clip /step", "method", "err‰", "max‰", "shape‰", "rigid‰", "flip",
                       "coll", "fold", "pop", "GN conv/stall/n", "it med/max", "s"], rows)
    t2 = format_table(["clip /step", "method", "err/linear", "err/cubic", "shape/cubic",
                       "goal (both <= 1)", "excess over cubic (joints)"], ratio_rows)
    return t1 + "\n\n" + t2 + "\n\n" + placement_table(cases) + descriptor_table(cases)


def placement_table(cases) -> str:
    """Where LΘA and the cubic lose: the rigid misplacement (centroid offset per axis, rotation)
    and the error over the end gaps and the interior gaps, LΘA over the cubic."""
    rows = []
    for c in cases:
        for step, rec in c["steps"].items():
            for name in ("lta", "cubic"):
                r, cub = rec["methods"][name], rec["methods"]["cubic"]
                g, gc = r.get("gaps") or {}, cub.get("gaps") or {}
                rows.append([f"{c['clip']} /{step}", name, 1e3 * r["translation"],
                             " ".join(f"{1e3 * a:.2f}" for a in r["translation_axes"]),
                             r["rotation_deg"],
                             *(f"{g[k] / gc[k]:.3f}" if g.get(k) and gc.get(k) else "-"
                               for k in ("end", "interior"))])
    return format_table(["clip /step", "method", "centroid‰", "per axis x y z ‰", "rot °",
                         "end gaps / cubic", "interior / cubic"], rows)


def descriptor_table(cases) -> str:
    """``--descriptors``: the shape error of in-betweens rebuilt from the descriptor spline
    with one descriptor group taken from the truth (:func:`descriptor_swaps`)."""
    rows = []
    for c in cases:
        for step, rec in c["steps"].items():
            d = rec.get("descriptors")
            if d:
                m = rec["methods"]
                rows.append([f"{c['clip']} /{step}", 1e3 * m["lta"]["shape"],
                             1e3 * m["cubic"]["shape"], 1e3 * d["spline"], 1e3 * d["true_L"],
                             1e3 * d["true_theta"], 1e3 * d["true_A"], d["unconverged"]])
    if not rows:
        return ""
    return "\n\nShape ‰ of in-betweens rebuilt from the descriptor spline, one group true\n" + \
        format_table(["clip /step", "lta", "cubic", "spline", "true L", "true Θ", "true A",
                      "GN unconverged"], rows)


# ----------------------------------------------------------------------------------------
# horse
# ----------------------------------------------------------------------------------------
def subdivided(kf, times: int = 2):
    """The keyframes ``kf`` midpoint-subdivided ``times`` times (each face into four, the
    same connectivity in every pose: ``trimesh.remesh.subdivide``): the horse at 134 782
    vertices, a production-size mesh that takes the default multiresolution path."""
    from trimesh.remesh import subdivide

    Vs, F = [], None
    for V in kf.V:
        Fi = kf.F
        for _ in range(times):
            V, Fi = subdivide(V, Fi)
        Vs.append(V)
        F = Fi
    return np.stack(Vs), np.asarray(F, dtype=np.int64)


def loop_subdivided(kf, times: int = 1):
    """The keyframes ``kf`` Loop-subdivided ``times`` times (``trimesh.remesh.subdivide_loop``:
    linear in the vertex positions, so every pose gets the same connectivity): a smooth
    surface, as scanned or sculpted production meshes are, unlike :func:`subdivided`'s flat
    patches. The horse: 33 705 vertices once, 134 782 twice."""
    from trimesh.remesh import subdivide_loop

    Vs, F = [], None
    for V in kf.V:
        V, F = subdivide_loop(V, kf.F, iterations=times)
        Vs.append(V)
    return np.stack(Vs), np.asarray(F, dtype=np.int64)


def horse_runs(workers: int, quick: bool, nonlinear: bool, subdiv: bool = False) -> list[dict]:
    import shellspline

    kf = shellspline.read_keyframes([HORSE_DIR / f"{k}.obj" for k in HORSE_KEYS],
                                    frames=list(HORSE_FRAMES))
    T = kf.topology
    configs = [("coarse=1000", {"coarse": 1000})] if quick else [
        ("full", {"coarse": "none"}), ("coarse=1000", {"coarse": 1000}),
        ("coarse=1000 fine", {"coarse": 1000, "fine": True})]
    out = []
    for label, opts in configs:
        res, t = _timed(shellspline.interpolate, kf, workers=workers, **opts)
        out.append(_horse_record(label, res.V, kf, T, t, gn_summary(res.report)))
    Vl, t = _timed(shellspline.linear_blend, kf.V, kf.frames, int(kf.frames[-1]))
    out.append(_horse_record("linear", Vl, kf, T, t, None))
    if subdiv:
        Vs, Fs = subdivided(kf)
        res, t = _timed(shellspline.interpolate, (Vs, Fs), frames=list(HORSE_FRAMES),
                        workers=workers)
        sub = SimpleNamespace(V=Vs, frames=kf.frames)
        Ts = shellspline.topology(Fs)
        rec = _horse_record("subdivided x2 (auto)", res.V, sub, Ts, t, gn_summary(res.report))
        rec["guard"] = (res.report.get("multires") or {}).get("guard")
        out.append(rec)
        # the paper's detail transfer on the same path, for the ratio in one run
        res, t = _timed(shellspline.interpolate, (Vs, Fs), frames=list(HORSE_FRAMES),
                        workers=workers, transfer="displacement")
        rec = _horse_record("subdivided x2 displacement", res.V, sub, Ts, t,
                            gn_summary(res.report))
        rec["guard"] = (res.report.get("multires") or {}).get("guard")
        out.append(rec)
        Vl, t = _timed(shellspline.linear_blend, Vs, kf.frames, int(kf.frames[-1]))
        out.append(_horse_record("subdivided x2 linear", Vl, sub, Ts, t, None))
        for times in (1, 2):  # smooth production-size meshes through the default path
            Vs, Fs = loop_subdivided(kf, times)
            res, t = _timed(shellspline.interpolate, (Vs, Fs), frames=list(HORSE_FRAMES),
                            workers=workers)
            sub = SimpleNamespace(V=Vs, frames=kf.frames)
            rec = _horse_record(f"loop x{times} (auto)", res.V, sub, shellspline.topology(Fs),
                                t, gn_summary(res.report))
            rec["guard"] = (res.report.get("multires") or {}).get("guard")
            rec["coarse_vertices"] = (res.report.get("multires") or {}).get("coarse_vertices")
            out.append(rec)
    if nonlinear:
        kn = shellspline.read_keyframes([HORSE_DIR / f"{k}.obj" for k in HORSE_NONLINEAR_KEYS],
                                        frames=list(HORSE_NONLINEAR_FRAMES))
        res, t = _timed(shellspline.interpolate, kn, method="nonlinear", coarse=1000,
                        workers=workers, solver_options={"max_time_s": 120})
        rec = _horse_record("nonlinear 5 poses c1000", res.V, kn, kn.topology, t,
                            gn_summary(res.report))
        rec["nonlinear"] = {k: v for k, v in (res.report.get("nonlinear") or {}).items()
                            if isinstance(v, (int, float, str, bool))}
        out.append(rec)
    return out


def _horse_record(label, V, kf, T, seconds, gn) -> dict:
    d = defects(V, T, kf.frames)
    exact = all(np.array_equal(V[f], kf.V[j]) for j, f in enumerate(kf.frames))
    return {"run": label, "vertices": int(V.shape[1]), "K": int(V.shape[0] - 1),
            "seconds": seconds, "gn": gn, "keyframes_exact": bool(exact),
            "strain_p99": length_strain(V, kf.V, kf.frames, T), **_strip(d)}


def length_strain(V, Vkey, frames, T) -> float:
    """99th percentile over edges and frames of ``|l / l̄ − 1|``, ``l̄`` the keyframes' edge
    lengths blended linearly in time: how far the in-betweens stretch or squeeze the mesh at
    its own scale (a prolongation that fades fine detail onto a smooth surface stretches
    slivers' short edges many times over while flipping nothing)."""
    from shellspline.timeline import linear_time_weights

    E = T.E

    def lengths(X):
        return np.linalg.norm(X[..., E[:, 1], :] - X[..., E[:, 0], :], axis=-1)

    K = V.shape[0] - 1
    blended = linear_time_weights(np.asarray(frames), K, "natural") @ lengths(np.asarray(Vkey))
    strain = np.abs(lengths(V) / np.maximum(blended, 1e-300) - 1.0)
    return float(np.quantile(strain, 0.99))


def horse_table(runs) -> str:
    rows = []
    for r in runs:
        gn = r["gn"] or {}
        rows.append([r["run"], r["K"], r["seconds"],
                     f"{gn['converged']}/{gn['stalled']}/{gn['frames']}" if gn else "-",
                     f"{gn['it_median']:g}/{gn['it_max']}" if gn else "-",
                     r["flipped"], r["collapsed"], r["folded"], r["pop"], r["strain_p99"],
                     " ".join(f"{k}:{j:g}" for k, j in gn.get("seams", [])) or "-",
                     r["keyframes_exact"]])
    return format_table(["horse", "K", "s", "GN conv/stall/n", "it med/max", "flip", "coll",
                         "fold", "pop", "strain99", "seams", "keys exact"], rows)


# ----------------------------------------------------------------------------------------
def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true",
                    help="ground truth: 30-frame windows, 2000-vertex bodies; horse: "
                         "coarse=1000 only")
    ap.add_argument("--json", default=str(DEFAULT_OUT), metavar="PATH",
                    help=f"where to write the results (default {DEFAULT_OUT})")
    ap.add_argument("--no-horse", action="store_true", help="skip the horse runs")
    ap.add_argument("--no-gt", action="store_true", help="skip the ground-truth runs")
    ap.add_argument("--subdivided", action="store_true",
                    help="also the horse subdivided twice (134 782 vertices) through the "
                         "default path (multiresolution, 1000 coarse vertices), and with "
                         "transfer=\"displacement\"; and Loop-subdivided once and twice "
                         "(33 705 and 134 782 vertices, smooth) through the default path, "
                         "~4 min")
    ap.add_argument("--nonlinear", action="store_true",
                    help="also the nonlinear spline on five horse poses (minutes)")
    ap.add_argument("--cold", action="store_true",
                    help="ground truth: also LΘA with warm_start=False (diagnostic: each frame "
                         "starts from the keyframe blend)")
    ap.add_argument("--descriptors", action="store_true",
                    help="ground truth: also rebuild the LΘA in-betweens from the descriptor "
                         "spline with the lengths, angles or areas of the truth (diagnostic: "
                         "which descriptor's interpolation costs the shape; a minute per clip)")
    ap.add_argument("--clips", nargs="+", metavar="NAME",
                    help="only the BVH clips whose file name contains one of these")
    ap.add_argument("--start", type=int, default=None, metavar="FRAME",
                    help="ground truth: first clip frame of the window (default: the window "
                         "in the middle of the clip); other starts sample other phases of "
                         "the motion against the keyframes")
    ap.add_argument("--window", type=int, default=None,
                    help="frames per ground-truth window (default 60, --quick 30)")
    ap.add_argument("--vertices", type=int, default=None,
                    help="vertices of the skinned body (default 3000, --quick 2000)")
    ap.add_argument("--workers", type=int, default=1, help="interpolate workers (default 1)")
    args = ap.parse_args(argv)
    window = args.window or (30 if args.quick else 60)
    n_vertices = args.vertices or (2000 if args.quick else 3000)
    result = {"started": time.strftime("%Y-%m-%dT%H:%M:%S"), "argv": sys.argv[1:],
              "platform": {"python": platform.python_version(), "cpus": os.cpu_count(),
                           "load": os.getloadavg()},
              "ground_truth": [], "horse": []}
    if not args.no_gt:
        clips = sorted(MOTION_DIR.glob("*.bvh")) if MOTION_DIR.is_dir() else []
        if args.clips:
            clips = [c for c in clips if any(s in c.name for s in args.clips)]
        if not clips:
            print(f"ground truth skipped: no BVH clips in {MOTION_DIR}")
        for c in clips:
            print(f"... {c.name}", flush=True)
            result["ground_truth"].append(gt_case(c, window, n_vertices, (3, 6), args.workers,
                                                  coarse=not args.quick, cold=args.cold,
                                                  start=args.start,
                                                  descriptors=args.descriptors))
        if result["ground_truth"]:
            print("\nGround truth (errors in ‰ of the body size; flip/coll/fold: new defects)")
            print(gt_tables(result["ground_truth"]))
    if not args.no_horse:
        if not HORSE_DIR.is_dir():
            print(f"horse skipped: {HORSE_DIR} not present")
        else:
            print("... horse", flush=True)
            result["horse"] = horse_runs(args.workers, args.quick, args.nonlinear,
                                       args.subdivided)
            print("\n" + horse_table(result["horse"]))
    result["load_after"] = os.getloadavg()
    out = Path(args.json)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=1, default=float))
    print(f"\nwritten {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

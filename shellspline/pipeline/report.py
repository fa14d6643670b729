"""The report of an interpolation: parameters, solver records, energies and quality.

:func:`start_report` records what was asked, the stages add their sections,
:func:`energies_record` measures the energies (in the stages' scale-free units) and
:func:`finish_report` adds per-frame Gauss–Newton records, quality checks and timings;
``report.json`` is that dict (strict JSON).
"""
from __future__ import annotations

import os
import platform
import time

import numpy as np

from ..errors import tol
from ..mesh.geometry import face_normals, norms
from ..metrics import sequence_defects
from ..shells.descriptors import lta_descriptors, lta_weights, unwrap_angles
from ..shells.lta_spline import lta_energy_per_frame
from ..shells.reconstruct import LARGE_MESH
from ..mesh.topology import Topology
from ..version import __version__

__all__ = ["start_report", "energies_record", "finish_report", "sequence_quality", "quality_record", "quality_ok",
           "seam_defects",
           "sequence_energies", "gauss_newton_summary", "nonlinear_record", "fixpoint_change",
           "convergence_problems", "start_frames_note", "POP_LIMIT", "ENERGY_TERMS"]


def sequence_quality(V, T: Topology, frames) -> dict:
    """Quality checks of a sequence: degenerate and flipped triangles.

    A triangle is *flipped* in frame ``k`` when its normal points against its normal in frame
    ``k-1`` (dot product < 0; counted whether or not the keyframes force it, see
    :func:`shellspline.metrics.sequence_defects` for the defects the keyframes do not have);
    *degenerate* when its area is below 1e-6 of its mean area over the keyframes.
    """
    V = np.asarray(V)
    F = T.F

    def normals(Vs):
        return face_normals(Vs, F)

    a_ref = (0.5 * norms(normals(V[np.asarray(frames)]))).mean(axis=0)
    a_ref = np.maximum(a_ref, tol.zero)
    rmin, rmax, n_degen, n_flip, prev = np.inf, 0.0, 0, 0, None
    for i in range(0, V.shape[0], 8):  # a few frames at a time: bounded memory
        N = normals(V[i:i + 8])
        ratio = 0.5 * norms(N) / a_ref
        rmin, rmax = min(rmin, float(ratio.min())), max(rmax, float(ratio.max()))
        n_degen += int((ratio < 1e-6).sum())
        NN = N if prev is None else np.concatenate([prev[None], N])
        n_flip += int((np.einsum("kij,kij->ki", NN[1:], NN[:-1]) < 0).sum())
        prev = N[-1]
    return {
        "min_area_ratio": rmin,
        "degenerate_faces": n_degen,
        "flipped_faces": n_flip,
        "max_area_ratio": rmax,
    }


#: A step whose largest vertex displacement exceeds this multiple of its neighbours' is a pop
#: (:func:`shellspline.metrics.sequence_defects`); a velocity kink between keyframe gaps of
#: different speed (linear blending) stays below 2.
POP_LIMIT = 2.0


def quality_record(V, T: Topology, frames, bc, Vkey) -> dict:
    """The report's quality record: new defects (flipped and collapsed faces, folded edges,
    pops; :func:`shellspline.metrics.sequence_defects`), with a per-frame record and the
    worst frames, the older counts of :func:`sequence_quality`, and keyframe exactness."""
    old = sequence_quality(V, T, frames)
    d = sequence_defects(V, T, frames, bc=bc)
    per = d.pop("per_frame")
    return {
        "keyframes_exact": bool(all(np.array_equal(V[f], Vkey[j]) for j, f in enumerate(frames))),
        "flipped_faces": d["flipped_faces"], "collapsed_faces": d["collapsed_faces"],
        "folded_edges": d["folded_edges"], "pop": d["pop"], "pop_frame": d["pop_frame"],
        "pop_limit": POP_LIMIT, "worst_frames": d["worst_frames"],
        "degenerate_faces": old["degenerate_faces"],
        "flipped_faces_all": old["flipped_faces"],
        "min_area_ratio": old["min_area_ratio"], "max_area_ratio": old["max_area_ratio"],
        "per_frame": per,
    }


def quality_ok(quality: dict) -> bool:
    """Whether a quality record (``report["quality"]``) shows no defect: keyframes exact, no new
    flipped or collapsed face, no folded edge, no degenerate face, no pop."""
    return bool(quality["keyframes_exact"] and not quality["flipped_faces"]
                and not quality.get("collapsed_faces", 0) and not quality.get("folded_edges", 0)
                and not quality["degenerate_faces"]
                and quality.get("pop", 0.0) <= quality.get("pop_limit", POP_LIMIT))


def seam_defects(report: dict) -> dict:
    """The new defects of a report (``quality.per_frame``) that sit at its seams.

    A seam is where the two runs of a keyframe gap meet in different local minima of the
    reconstruction (``seam_jump`` in a frame record; a multiresolution run's are in
    ``multires.coarse_frames``, whose frames are the output's). The switch between the two
    minima happens in the step into the seam's frame, or, where a bridge was kept, in one of
    the steps of its window (``bridge.frames``) or the step out of it. On the horse every new
    flipped face of the full-resolution run is there (benchmarks/README.md, "The seam
    snaps"): telling them apart from the others says whether a defect is this bistability or
    something else.

    Returns
    -------
    dict
        ``flipped``, ``folded``, ``collapsed`` (ints) and ``frames`` (the frames counted,
        sorted: frame ``k`` holds step ``k − 1 → k``).

    Examples
    --------
    >>> rep = {"quality": {"per_frame": {"flipped": [0, 0, 2, 0, 1], "folded": [0] * 5,
    ...                                  "collapsed": [0] * 5}},
    ...        "frames": [{"frame": 2, "seam_jump": 3.1}]}
    >>> seam_defects(rep)
    {'flipped': 2, 'folded': 0, 'collapsed': 0, 'frames': [2]}
    """
    per = (report.get("quality") or {}).get("per_frame") or {}
    out = {"flipped": 0, "folded": 0, "collapsed": 0, "frames": []}
    if not per.get("flipped"):
        return out
    K = len(per["flipped"]) - 1
    records = list(report.get("frames") or []) + \
        list((report.get("multires") or {}).get("coarse_frames") or [])
    at = set()
    for rec in records:
        if "seam_jump" not in rec:
            continue
        br = rec.get("bridge") or {}
        if br.get("kept") and br.get("frames"):
            at.update(range(int(min(br["frames"])), int(max(br["frames"])) + 2))
        else:
            at.add(int(rec["frame"]))
    out["frames"] = sorted(k for k in at if 0 < k <= K)
    for key in ("flipped", "folded", "collapsed"):
        counts = per.get(key) or [0] * (K + 1)
        out[key] = int(sum(counts[k] for k in out["frames"]))
    return out


def convergence_problems(report: dict) -> list[str]:
    """The solver failures that decide whether an interpolation succeeded (``[]``: none).

    The solver whose result is the output decides: the nonlinear stage for
    ``method="nonlinear"`` (its Gauss–Newton frames are only its starting path, see
    :func:`start_frames_note`), else the Gauss–Newton frames and the geodesic solve. An
    unconverged reference geodesic (``reference="geodesic"``, e.g. stopped by
    ``max_time_s``) always counts: the weights are not the ones asked for.

    Parameters
    ----------
    report : dict
        An interpolation report (``report.json``).

    Returns
    -------
    list of str
        One short phrase per failure, e.g. ``"nonlinear did not converge"``.

    Examples
    --------
    >>> gn = {"frames": 4, "converged": 3, "stalled": [], "iteration_limit": [2]}
    >>> convergence_problems({"gauss_newton": gn})
    ['Gauss–Newton converged on 3/4 frames']
    >>> convergence_problems({"gauss_newton": gn, "nonlinear": {"success": True}})
    []
    >>> convergence_problems({"nonlinear": {"success": True, "start_returned": True}})
    ['nonlinear result refused (more defects than its LΘA start, which was written)']
    >>> convergence_problems({"reference_geodesic": {"success": False, "status": "limit",
    ...                                              "time_limit_reached": True}})
    ['reference geodesic did not converge (time limit reached; weights from its last iterate)']
    """
    out = []
    gn = report.get("gauss_newton")
    if gn and gn["converged"] != gn["frames"] and "nonlinear" not in report:
        out.append(f"Gauss–Newton converged on {gn['converged']}/{gn['frames']} frames")
    for name in ("geodesic", "nonlinear"):
        if name in report and not report[name]["success"]:
            out.append(f"{name} did not converge")
    ref = report.get("reference_geodesic")
    if ref and not ref["success"]:
        # the weights came from an unconverged path: not the reference that was asked for
        why = "time limit reached; " if ref.get("time_limit_reached") else ""
        out.append(f"reference geodesic did not converge ({why}weights from its last "
                   "iterate)")
    if report.get("nonlinear", {}).get("start_returned"):
        # the output is not what was asked for: not a success, whatever the solve reached
        out.append("nonlinear result refused (more defects than its LΘA start, which was "
                   "written)")
    return out


def start_frames_note(report: dict) -> str:
    """For a nonlinear report whose starting frames (the LΘA Gauss–Newton solves) did not all
    converge, what happened to them, e.g. ``"start frames: 2 at the iteration limit"``; ``""``
    otherwise (they do not decide success: :func:`convergence_problems`).

    Examples
    --------
    >>> start_frames_note({"gauss_newton": {"frames": 4, "converged": 2, "stalled": [3],
    ...                                     "iteration_limit": [1]}, "nonlinear": {}})
    'start frames: 1 at the iteration limit, 1 stalled'
    """
    gn = report.get("gauss_newton")
    if "nonlinear" not in report or not gn or gn["converged"] == gn["frames"]:
        return ""
    limit, stalled = len(gn.get("iteration_limit", [])), len(gn.get("stalled", []))
    other = gn["frames"] - gn["converged"] - limit - stalled
    parts = [f"{limit} at the iteration limit" if limit else "",
             f"{stalled} stalled" if stalled else "", f"{other} failed" if other > 0 else ""]
    return "start frames: " + ", ".join(x for x in parts if x)


def sequence_energies(V, Z, T: Topology, bc: str, W, chunk: int | None = None) -> dict:
    """Per-frame LΘA energies (paper Figs. 11–12) of the output and, when given, of the spline
    targets ``Z``, plus the reconstruction misfit of every frame; ``W`` is (d,) or (K+1,d).
    Descriptors are computed a few frames at a time to bound memory on large meshes (one
    frame at a time above :data:`~shellspline.shells.reconstruct.LARGE_MESH` vertices, where
    stacked frames fall out of cache: measured 1.7x slower per frame at 150k)."""
    sT = T.descriptor_slices()[1]
    K1 = V.shape[0]
    if chunk is None:
        chunk = 1 if V.shape[1] > LARGE_MESH else 8
    with np.errstate(divide="ignore", invalid="ignore"):
        Zout = np.concatenate([lta_descriptors(V[i:i + chunk], T) for i in range(0, K1, chunk)])
    bad = np.flatnonzero(~np.isfinite(Zout).all(axis=1))
    if bad.size:
        # a triangle collapsed to a segment or point has no dihedral angle: the energies of
        # the sequence are undefined (a linear blend through a half-turn; the quality check
        # reports the collapsed faces)
        return {"error": f"degenerate triangles (no dihedral angle) at frames "
                         f"{bad[:10].tolist()}{' …' if bad.size > 10 else ''}: the LΘA "
                         f"energies are undefined"}
    Zout[:, sT] = unwrap_angles(Zout[:, sT])
    out = {"lta_output_energy_per_frame": lta_energy_per_frame(Zout, bc=bc, weights=W).tolist()}
    if Z is not None:
        Wk = np.broadcast_to(W, Z.shape)
        Zout -= Z
        Zout[:, sT] = (Zout[:, sT] + np.pi) % (2 * np.pi) - np.pi
        out["lta_spline_energy_per_frame"] = lta_energy_per_frame(Z, bc=bc, weights=W).tolist()
        out["reconstruction_energy_per_frame"] = np.einsum("kd,kd->k", Wk, Zout * Zout).tolist()
    return out


def fixpoint_change(V, Vnew, Z, Znew, T, Vkey) -> dict:
    """Change of one fixpoint iteration: vertices (absolute and relative to the keyframes'
    bounding-box diagonal) and spline descriptors (lengths and areas relative to their
    magnitude, angles in radians)."""
    diag = float(np.linalg.norm(Vkey.reshape(-1, 3).max(0) - Vkey.reshape(-1, 3).min(0)))
    dv = float(np.abs(Vnew - V).max())
    sL, sT, sA = T.descriptor_slices()
    out = {"max_vertex_change": dv, "rel_vertex_change": dv / max(diag, tol.zero)}
    for name, sl, rel in (("lengths", sL, True), ("angles", sT, False), ("areas", sA, True)):
        d = np.abs(Znew[:, sl] - Z[:, sl])
        if d.size == 0:
            continue
        out[f"max_{name}_change"] = float(d.max() / (np.abs(Z[:, sl]).max() if rel else 1.0))
    return out


def start_report(opts, prob) -> dict:
    """The report's ``parameters`` and ``mesh`` sections (what was asked, on what)."""
    kf, T = prob.keyframes, prob.T
    J, n = prob.Vkey.shape[:2]
    return {
        "shellspline_version": __version__,
        "parameters": {
            "method": opts.method, "bc": opts.bc, "K": int(prob.K),
            "frames": prob.frames.tolist(), "eta": opts.eta, "mu": opts.mu, "lam": opts.lam,
            "reference": opts.reference, "workers": opts.workers,
            "warm_start": opts.warm_start,
            "pinned_vertices": 0 if prob.pinned is None else int(prob.pinned.size),
            "gn_options": dict(opts.gn_options), "solver_options": dict(opts.solver_options),
            "coarse": opts.coarse, "fine": opts.fine, "fixpoint": opts.fixpoint,
            "rigid_track": opts.rigid_track, "fade_angle": opts.fade_angle,
            "spline": opts.spline, "transfer": opts.transfer,
            "rigid_subset_vertices": 0 if prob.rigid_subset is None else
            int(prob.rigid_subset.size),
        },
        "mesh": {"vertices": int(n), "faces": int(T.n_faces), "edges": int(T.n_edges),
                 "keyframes": int(J), "names": list(kf.names)},
    }


#: ``report["energies"]["per_frame_terms"]``: what the per-frame LΘA energies are, for each
#: time spline of the targets (``None``: a method without targets; see :func:`energies_record`).
ENERGY_TERMS = {
    None: "paper eq. 11 terms w_k (z_k - z~_k)^2",  # no spline targets (linear, geodesic)
    "discrete": "paper eq. 11 terms w_k (z_k - z~_k)^2; the spline targets minimise their sum",
    "continuous": "paper eq. 11 terms w_k (z_k - z~_k)^2; the continuous spline minimises "
                  "the integral of w z''^2 instead, and on its targets these terms are "
                  "w z''(k)^2 / 4 (frame units; exact between keyframes for a constant "
                  "reference)",
}


def energies_record(seq, prob, opts, prog) -> dict:
    """``report["energies"]`` of the method stage's result ``seq`` (a
    :class:`~shellspline.pipeline.stages.StageResult`), in the stages' units (lengths in
    units of ``prob.scale``: the energies do not depend on the input's unit).

    The per-frame energies of the output and of the spline targets are the same measure,
    the terms of the paper's time-discrete energy (eq. 11, paper Figs. 11–12), whichever
    time spline made the targets, so the two stay comparable. The discrete spline's targets
    minimise their sum; the continuous spline (``opts.spline="continuous"``) minimises
    ``∫ w z''² dt`` instead, whose density these terms sample: on its targets a term is
    ``w z''(k)² / 4`` in frame units, exactly at frames between keyframes for a constant
    reference. ``per_frame_terms`` says which (:data:`ENERGY_TERMS`)."""
    with prog.stage("energies"):
        if seq.energy_source is not None:
            Ve, Ze, Te, We, resolution = (*seq.energy_source, "coarse")
        else:
            Ve, Ze, Te, We, resolution = seq.V, seq.Z, prob.T, seq.W, "full"
            if We is None:
                We = lta_weights(prob.Vkey[0], prob.T, mu=opts.mu, lam=opts.lam, eta=opts.eta)
        if np.all(np.isfinite(Ve)):
            out = sequence_energies(Ve, Ze, Te, opts.bc, We)
        else:  # a failed frame: keep the report (the quality check flags the sequence)
            out = {"error": "the sequence has non-finite coordinates"}
        out["resolution"] = resolution
        out["per_frame_terms"] = ENERGY_TERMS[opts.spline if Ze is not None else None]
    return out


def finish_report(report: dict, V, frame_records, prob, opts, prog, t_start: float,
                  gn_work=None) -> dict:
    """Add frame records, quality of the final sequence ``V`` (K+1,n,3) in the input's
    units, the Gauss–Newton summary (with ``gn_work``, the record of all the solves,
    :func:`~.reconstruction.work_record`), timings and the platform to ``report`` (in place)
    and return it."""
    report["parameters"]["length_scale"] = float(prob.scale)
    for rec in report.get("fixpoint", []):
        rec["max_vertex_change"] *= prob.scale
    report["frames"] = frame_records
    with prog.stage("quality"):
        report["quality"] = quality_record(V, prob.T, prob.frames, opts.bc, prob.keyframes.V)
    if frame_records:
        report["gauss_newton"] = gauss_newton_summary(frame_records, gn_work)
        failed = [r["frame"] for r in frame_records if not r["success"]]
        if failed:
            start = "start frames of the nonlinear stage: " if opts.method == "nonlinear" \
                else ""
            prog.message(f"{start}Gauss–Newton did not converge on frames {failed[:10]}"
                         f"{' …' if len(failed) > 10 else ''}")
    report["timings"] = dict(prog.timings)
    report["timings"]["total"] = time.perf_counter() - t_start
    # stages timed inside another (the reference geodesic inside describe): part of its time
    report["timings_within"] = dict(prog.within)
    report["platform"] = {"python": platform.python_version(), "cpus": os.cpu_count()}
    return report


def gauss_newton_summary(records: list, work: dict | None = None) -> dict:
    """Totals of the per-frame Gauss–Newton records (``report["gauss_newton"]``): the solves
    the frames keep. ``work``: all the solves, kept or not
    (:func:`~.reconstruction.work_record`), added as ``"work"``."""
    nits = [r["nit"] for r in records]
    out = {
        "frames": len(records),
        "converged": int(sum(r["success"] for r in records)),
        "stalled": [int(r["frame"]) for r in records if r.get("status") == "stalled"],
        "iteration_limit": [int(r["frame"]) for r in records if r.get("status") == "limit"],
        # frames given more iterations after the passes (still converging at their limit)
        "resumed": [int(r["frame"]) for r in records if r.get("resumed")],
        "iterations_median": float(np.median(nits)),
        "iterations_total": int(sum(nits)),
        "iterations_max": int(max(nits)),
        "cg_iterations_total": int(sum(r["cg_iterations"] for r in records)),
        "factorizations_total": int(sum(r["factorizations"] for r in records)),
    }
    if work is not None:
        out["work"] = work
    return out


def nonlinear_record(nl, n_vertices: int) -> dict:
    """``report["nonlinear"]`` from a :func:`~shellspline.shells.nonlinear.nonlinear_spline`
    result (``energy_initial`` etc. None when the time limit ran out before the first
    evaluation finished). ``status`` is the solver's (``"converged"``, ``"stalled"``,
    ``"limit"``, ``"failed"``) and ``time_limit_reached`` says whether ``max_time_s`` stopped
    it, as in ``report["reference_geodesic"]`` and ``report["geodesic"]``."""
    return {"success": bool(nl.success), "status": str(nl.status),
            "time_limit_reached": nl.status == "limit", "nit": int(nl.nit), "nfev": int(nl.nfev),
            "message": nl.message, "optimizer": nl.optimizer,
            "energy_initial": _at(nl.energies, 0), "energy_final": _at(nl.energies, -1),
            "grad_norm_initial": _at(nl.grad_norms, 0),
            "grad_norm_final": _at(nl.grad_norms, -1), "seconds": float(nl.time_s),
            "cg_iterations": [int(c) for c in nl.cg_iterations],
            "midpoint_newton_iterations": int(nl.midpoint_newton_iterations),
            "vertices": int(n_vertices),
            "energy_history": [float(e) for e in nl.energies],
            "grad_norm_history": [float(g) for g in nl.grad_norms],
            "time_history": [float(t) for t in nl.times],
            "step_lengths": [float(a) for a in nl.step_lengths],
            "hessian": [str(h) for h in nl.hessian]}


def _at(history, i):
    return float(history[i]) if len(history) else None

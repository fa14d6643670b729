"""One stage function per method (linear, geodesic, LΘA, nonlinear) and the multiresolution
path; each returns a :class:`StageResult`. Which stage runs in which order is decided here
and in :func:`~shellspline.pipeline.interpolate` only.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import numpy as np

from ..errors import tol
from ..mesh.topology import topology
from ..metrics import sequence_defects
from ..shells.descriptors import lta_weights
from ..shells.lta_spline import lta_spline
from ..timeline import linear_blend
from .describe import SplineRows, describe_and_solve
from .placement import place
from .reconstruction import (POP_DEFECTS, RESUME_ITER, SEAM_POP, GaussNewtonWork,
                             parallel_decode, reconstruct_frames, resume_steady,
                             run_reconstruction, safe_init)
from .report import fixpoint_change, nonlinear_record

__all__ = ["StageResult", "run_method", "aligned_keyframes", "in_input_units", "linear_stage",
           "geodesic_stage", "lta_stage",
           "lta_sequence", "given_starts", "fixpoint_iterations", "multires_sequence",
           "decimated", "prolonged", "nonlinear_solve", "worse_than_start"]


@dataclass
class StageResult:
    """What a method stage returns.

    Attributes
    ----------
    V : (K+1,n,3) float64 array
        The placed sequence, keyframes exact.
    Z : (K+1,d) float64 array or None
        Spline targets (LΘA at full resolution).
    W : (d,) or (K+1,d) float64 array or None
        Weights of the report's energies (None: the first keyframe's).
    frame_records : list of dict
        Per-frame Gauss–Newton records.
    energy_source : tuple or None
        ``(V, Z, T, W)`` where the spline was solved when that is not the output (a coarse
        mesh); None: the output itself.
    report : dict
        Sections the stage adds to the report (``geodesic``, ``multires``, ``nonlinear``,
        ``fixpoint``).
    gn_work : dict
        All the Gauss–Newton solves of the frames, kept or not, per resolution:
        ``{"full": GaussNewtonWork}``, or ``"coarse"`` and ``"fine"``
        (:class:`~.reconstruction.GaussNewtonWork`; ``frame_records`` count the kept solves).
    """

    V: np.ndarray
    Z: np.ndarray | None = None
    W: np.ndarray | None = None
    frame_records: list = field(default_factory=list)
    energy_source: tuple | None = None
    report: dict = field(default_factory=dict)
    gn_work: dict = field(default_factory=dict)


def run_method(prob, opts, prog) -> StageResult:
    """The stage of ``opts.method`` on ``prob``: a shell method on the keyframes aligned
    rigidly (:func:`aligned_keyframes`), its frames then placed on the track through the
    keyframes as given."""
    if opts.method == "linear":
        return linear_stage(prob, opts, prog)
    stage = geodesic_stage if opts.method == "geodesic" else lta_stage
    if prob.pinned is not None and len(prob.pinned):
        return stage(prob, opts, prog)  # pins hold the keyframes where they are
    Vkey, shift = aligned_keyframes(prob.Vkey, prob.T.F, periodic=opts.periodic)
    seq = stage(replace(prob, Vkey=Vkey), opts, prog)
    seq.V = _placed(seq.V, prob.Vkey, prob.T, None, prob, opts)
    seq.report["keyframe_alignment"] = {"max_shift": shift}
    return seq


def aligned_keyframes(Vkey, F=None, periodic: bool = False):
    """The keyframes moved rigidly, each onto the one before it as aligned (Kabsch; each
    connected component of the faces ``F`` on its own, as :func:`~.placement.place` places
    them), and the largest vertex shift that took over the bounding-box diagonal. With
    ``periodic`` each onto the first instead: a loop also blends its last keyframe with its
    first, and the small turns a chain of fits picks up from swinging limbs (the horse's
    poses: 5–47° against the reference) would add up between those two.

    Shell energies ignore rigid motions, but the start of every frame does not: it comes
    from the keyframe blend, and the blend of two poses a quarter turn apart is a shrunken,
    folded shape. Before, the horse pair ``reference → 03`` with ``horse-03`` turned by 90°
    and moved by 54 (``--frames 0,4``) ended in another minimum (energy 0.0044 against
    0.0010 in place, 2 flips against 1), and through ``--coarse 1000`` (0, 6, 12) frames
    differed by up to 0.12 of the diagonal, 41 flips against 25. Aligned, the shapes do not
    depend on where the keyframes sit; the frames are then placed on the track through the
    keyframes as given (:func:`~.placement.place`), which restores them bit for bit. The
    horse in place gains too: ``horse-03`` and ``07`` sit 0.4 of the diagonal away from the
    reference, and at ``--coarse 1000`` with frames 0, 6, 12 the flipped faces went from 25
    to 7 and the folded edges from 8 to 2 (frames 0, 20, 40: the same defects). Pieces are
    aligned one by one: aligned as one mesh, a piece moving against another was turned in
    the blend and came out of its solve off its own rigid track.
    """
    from ..shells.reconstruct import rigid_placement
    from .placement import pinned_parts

    Vkey = np.asarray(Vkey, dtype=np.float64)
    out = Vkey.copy()
    parts = [slice(None)] if F is None else \
        [idx for idx, _ in pinned_parts(np.asarray(F), Vkey.shape[1], None)]
    diag = float(np.linalg.norm(Vkey[0].max(axis=0) - Vkey[0].min(axis=0))) or 1.0
    for j in range(1, len(Vkey)):
        for idx in parts:
            moved = rigid_placement(Vkey[j, idx], out[0 if periodic else j - 1, idx])
            # a keyframe already in place stays bit for bit (a held pose stays one shape)
            if np.abs(moved - Vkey[j, idx]).max() > 1e-12 * diag:
                out[j, idx] = moved
    shift = float(np.sqrt(np.einsum("jnc,jnc->jn", out - Vkey, out - Vkey).max())) / diag
    return out, shift


def in_input_units(seq, prob, opts):
    """The stage result ``seq`` back in the keyframes' units (the stages work on keyframes
    divided by ``prob.scale``, see :func:`~shellspline.pipeline.options.length_scale`).

    Returns
    -------
    V : (K+1,n,3) float64 array
        ``seq.V`` times the scale (in place), keyframes restored bit for bit and pinned
        vertices at their blended position (as at unit scale).
    Z : (K+1,d) float64 array or None
        Targets with lengths times the scale and areas times its square.
    """
    D, V, Z = prob.scale, seq.V, seq.Z
    if opts.method == "linear":  # blended in the input's units: bit for bit what it promises
        return linear_blend(prob.keyframes.V, prob.frames, prob.K, opts.bc), None
    if D == 1.0:
        return V, Z
    V *= D
    Vkey = prob.keyframes.V
    V[prob.frames] = Vkey
    if opts.periodic:
        V[prob.K] = Vkey[0]
    if prob.pinned is not None:
        V[:, prob.pinned] = linear_blend(Vkey[:, prob.pinned], prob.frames, prob.K, opts.bc)
    if Z is not None:
        sL, _, sA = prob.T.descriptor_slices()
        Z = np.array(Z, dtype=np.float64, copy=True)
        Z[:, sL] *= D
        Z[:, sA] *= D * D
    return V, Z


def _placed(V, Vkey, T, pinned, prob, opts):
    # the rigid subset numbers the full mesh's vertices: coarse meshes are placed by all theirs
    return place(V, prob.frames, prob.K, opts.bc, pinned, Vkey, T.F, opts.rigid_track,
                 subset=prob.rigid_subset if T is prob.T else None)


def linear_stage(prob, opts, prog) -> StageResult:
    """Per-vertex linear blending of the keyframes (the baseline)."""
    return StageResult(V=linear_blend(prob.Vkey, prob.frames, prob.K, opts.bc))


def geodesic_stage(prob, opts, prog) -> StageResult:
    """Piecewise discrete geodesics in shell space between consecutive keyframes (paper §3),
    at full resolution or, with ``prob.n_coarse``, on the decimated keyframes and prolonged
    by detail transfer like the LΘA spline (:func:`multires_sequence`).

    Each segment is one Newton solve on all its inner shells at once (``3 n (K_j − 1)``
    unknowns): on the 8.4k-vertex horse, 20 frames apart, that is 480k unknowns, 30 s of
    symbolic analysis and more than four minutes and 4 GB for the first Newton step, so
    ``coarse="auto"`` decimates above :data:`~.options.AUTO_NONLINEAR_ABOVE` vertices as for
    the nonlinear spline."""
    from ..shells.geodesic import geodesic_interpolation

    frames = prob.frames
    n_seg = len(frames) - (0 if opts.periodic else 1)
    if prob.n_coarse is None:
        Vkey, T, pinned, dec, multires = prob.Vkey, prob.T, prob.pinned, None, None
    else:
        dec, Tc, multires = decimated(prob, prog)
        Vkey, T, pinned = dec.V, Tc, dec.pinned
    prefix = "coarse " if dec is not None else ""
    stage = prefix + "geodesic"
    # each segment starts from the LΘA spline (near-isometric shells): from the keyframe
    # blend the coarse horse's first Newton step needed a damping shift of 0.3 × the
    # Hessian's largest entry (a gradient step) and 17 factorizations to find it
    start = lta_sequence(Vkey, T, pinned, prob, opts, prog, stage_prefix=prefix + "start ")

    def progress(s, it, e, g):
        prog.advance(stage, s, n_seg, text=f"segment {s + 1}/{n_seg}  it {it:3d}  "
                                            f"E {e:.6g}  |g| {g:.2e}")

    with prog.stage(stage, total=n_seg):
        g = geodesic_interpolation(Vkey, frames, prob.K, T, mu=opts.mu, lam=opts.lam,
                                   eta=opts.eta, pinned=pinned, bc=opts.bc,
                                   callback=lambda s, r: prog.advance(stage, s + 1, n_seg),
                                   progress=progress, init=start.V, **opts.solver_options)
    if not g.success:  # worded as the solver's warning, which the CLI then prints once
        prog.message(f"geodesic interpolation: {g.message}")
    last = int(frames[-1])
    if not opts.periodic and prob.K > last:
        # geodesics join keyframes only: the frames after the last one (which
        # geodesic_interpolation holds there) are the LΘA start's extrapolation, as announced
        g.V[last + 1:] = start.V[last + 1:]
    rec = {"success": bool(g.success), "status": str(g.status),
           "time_limit_reached": bool(g.time_limit_reached), "nit": int(g.nit),
           "message": g.message,
           "segment_energies": [float(e) for e in g.segment_energies], "start": "lta",
           "factorizations": int(g.factorizations),
           "start_frames": start.frame_records}
    out = StageResult(V=g.V, report={"geodesic": rec})
    if dec is not None:
        rec["resolution"] = "coarse"
        out.V = prolonged(prob, opts, prog, dec, g.V, multires)
        out.report["multires"] = multires
    out.V = _placed(out.V, prob.Vkey, prob.T, prob.pinned, prob, opts)
    return out


def lta_stage(prob, opts, prog) -> StageResult:
    """The LΘA spline (single or multiresolution) and, for ``method="nonlinear"``, the
    nonlinear spline started from it."""
    log: list = []
    if prob.n_coarse is None:
        seq = lta_sequence(prob.Vkey, prob.T, prob.pinned, prob, opts, prog, fixpoint_log=log)
    else:
        seq = multires_sequence(prob, opts, prog, fixpoint_log=log)
    if opts.fixpoint:
        seq.report["fixpoint"] = log
    if seq.W is None:
        seq.W = lta_weights(prob.Vkey[0], prob.T, mu=opts.mu, lam=opts.lam, eta=opts.eta)
    if opts.method == "nonlinear" and "nonlinear" not in seq.report:
        Vn, seq.report["nonlinear"] = nonlinear_solve(prob.Vkey, prob.T, prob.pinned, seq.V,
                                                      prob, opts, prog)
        seq.V = _placed(Vn, prob.Vkey, prob.T, prob.pinned, prob, opts)
        seq.energy_source = None  # energies of the final (full-resolution) sequence
    return seq


def _in_betweens(prob, opts):
    is_key = np.zeros(prob.K + 1, dtype=bool)
    is_key[prob.frames] = True
    is_key[prob.K] |= opts.periodic
    return np.flatnonzero(~is_key)


def lta_sequence(Vkey, T, pinned, prob, opts, prog, *, Vinit=None, stage_prefix="",
                 fixpoint_log=None, start_log=None) -> StageResult:
    """The LΘA stages on one resolution: describe, solve, reconstruct, place, and the
    ``opts.fixpoint`` iterations (their records appended to ``fixpoint_log``).

    ``Vinit`` (K+1,n,3): a given initial sequence (the prolonged coarse result of
    ``fine=True``): the first frame of each run starts from it or from the keyframe blend,
    whichever has the lower energy (:func:`given_starts`, its record put into the dict
    ``start_log``). Default: the keyframe blend
    (frames where it collapses triangles start from the nearer keyframe). Warm starts
    extrapolate the solutions in both cases: following the prolonged sequence's change from
    frame to frame instead (``warm="delta"``) took more Gauss–Newton iterations (horse
    0/03/07 at 1000 coarse vertices: 661 against 550, 228 s against 195 s;
    ``data_synth.stress.slivers`` at 1/4: 597 against 304).
    """
    frames, K, bc = prob.frames, prob.K, opts.bc
    tg = describe_and_solve(Vkey, T, pinned, prob, opts, prog, stage_prefix)
    ks = _in_betweens(prob, opts)
    warm = "extrapolate" if opts.warm_start else False
    refine = Vinit is not None  # (a bool: Vinit itself is freed below)
    work = GaussNewtonWork()
    if Vinit is None:
        Vinit = safe_init(linear_blend(Vkey, frames, K, bc), Vkey, frames, K, bc, T)
    else:
        Vinit, starts = given_starts(np.asarray(Vinit, dtype=np.float64), Vkey, T, ks, tg,
                                     pinned, prob, opts, work)
        if start_log is not None:
            start_log.update(starts)
    # a refinement (given starts: the guarded prolonged sequence) promises no defect that
    # the coarse frames lack, and its guard fades new ones back to those starts: its bridges
    # do not trade folds for a pop (with the coarse weight, a sliver tube's fine bridges
    # added 4 folded edges that the guard could not fade out)
    results = reconstruct_frames(T, ks, tg.Z, tg.W_of, Vinit, pinned, frames=frames, K=K,
                                 periodic=opts.periodic, gn_options=opts.gn_options,
                                 workers=opts.workers, warm=warm, prog=prog,
                                 stage_prefix=stage_prefix,
                                 pop_defects=1 if refine else POP_DEFECTS,
                                 tube_of=tg.tube_of,
                                 resume=_resume_budget(opts), work=work)
    del Vinit
    Z = tg.Z[:] if isinstance(tg.Z, SplineRows) else tg.Z
    with prog.stage(stage_prefix + "place"):
        V = linear_blend(Vkey, frames, K, bc)  # (K+1, n, 3): not held during reconstruction
        for k in ks:
            V[k] = results[k][0]
        V = _placed(V, Vkey, T, pinned, prob, opts)
    seq = StageResult(V=V, Z=Z, W=tg.W_report, frame_records=[results[k][1] for k in ks],
                      gn_work={stage_prefix.strip() or "full": work})
    seq.report["bending_fade"] = {"fade_angle": opts.fade_angle, "faded_edges": tg.faded_edges,
                                  "interior_edges": int(T.n_interior)}
    if tg.reference is not None:
        seq.report["reference_geodesic"] = tg.reference
    if opts.fixpoint:
        fixpoint_iterations(seq, tg, Vkey, T, pinned, prob, opts, prog, stage_prefix,
                            fixpoint_log, work=work)
    return seq


def given_starts(Vinit, Vkey, T, ks, tg, pinned, prob, opts, work=None):
    """Where a given initial sequence (the prolonged coarse result of ``fine=True``) starts
    the reconstruction: the first frame of each run from a keyframe
    (:func:`~.reconstruction.reconstruction_runs`; later frames extrapolate their solved
    predecessors) starts from the given frame or from the keyframe blend, whichever has the
    lower reconstruction energy.

    A prolonged frame is the better start where the coarse solution is close to the fine
    one (horse 0/03/07 at 1000 coarse vertices: frames 1, 19, 21 at energies 0.0075,
    0.0097, 0.0088 against 0.023, 0.060, 0.051 from the blend, 9, 5, 6 Gauss–Newton
    iterations against 12, 10, 13) and a worse one where it is not: frame 39 started at
    0.42 from the prolonged frame (0.11 from the blend), ended in another minimum at 0.045
    (0.0015) after the iteration limit, and the run it started carried that minimum to
    frame 35 (225 iterations for frames 35–39 against 56, two frames at the iteration
    limit, 18 new flipped faces).

    Returns
    -------
    V : (K+1,n,3) float64 array
        ``Vinit`` with the frames where the blend is better replaced by the blend's.
    record : dict
        ``prolonged`` and ``blend``: the run-starting frames that start from each.

    ``work`` (a :class:`~.reconstruction.GaussNewtonWork`) counts the solves from both starts
    as ``"trial_start"`` (the one kept) and ``"trial_start_discarded"``.
    """
    from ..shells.descriptors import lta_descriptors
    from ..shells.reconstruct import GaussNewton
    from .reconstruction import reconstruction_runs

    frames, K, bc = prob.frames, prob.K, opts.bc
    runs = reconstruction_runs(ks, frames, K, opts.periodic)
    first = sorted({int(r[0]) for r, _ in runs if len(r)})
    blend = dict(zip(first, safe_init(linear_blend(Vkey, frames, K, bc), Vkey, frames, K, bc,
                                      T)[first]))
    gn = GaussNewton(T, pinned=pinned, **opts.gn_options)
    sL, _, sA = T.descriptor_slices()
    rec = {"prolonged": [], "blend": []}
    V = Vinit
    for k in first:
        z = np.asarray(tg.Z[k], dtype=np.float64)
        w = np.array(tg.W_of(k), dtype=np.float64, copy=True)
        w[sL][z[sL] <= 0] = 0.0  # as Gauss–Newton weighs them
        w[sA][z[sA] <= 0] = 0.0
        tube = None if tg.tube_of is None else tg.tube_of(k)
        f_given, f_blend = (gn.merit(lta_descriptors(X, T), z, w, tube)[0]
                            for X in (Vinit[k], blend[k]))
        take_blend = f_blend < f_given or not np.isfinite(f_given)
        if np.isfinite(f_given) and np.isfinite(f_blend) and \
                max(f_given, f_blend) < START_AMBIGUITY * min(f_given, f_blend):
            # starts this close say little about where they end: solve from both and start
            # the run at the better minimum (solved: its first solve stops at once)
            gn.reset()
            r_given = gn.solve(z, tg.W_of(k), Vinit[k], tube)
            gn.reset()
            r_blend = gn.solve(z, tg.W_of(k), blend[k], tube)
            take_blend = r_blend.energy < r_given.energy
            if work is not None:
                kept, other = (r_blend, r_given) if take_blend else (r_given, r_blend)
                work.add("trial_start", kept.summary())
                work.add("trial_start_discarded", other.summary())
            rec.setdefault("solved_both", []).append(
                {"frame": k, "prolonged": float(r_given.energy), "blend": float(r_blend.energy)})
            if V is Vinit:
                V = Vinit.copy()
            V[k] = (r_blend if take_blend else r_given).V
        elif take_blend:
            if V is Vinit:
                V = Vinit.copy()
            V[k] = blend[k]
        rec["blend" if take_blend else "prolonged"].append(k)
    return V, rec


#: Where the prolonged and the blended start of a run's first frame are within this factor
#: of each other in energy, :func:`given_starts` solves from both and keeps the lower minimum
#: (horse 0/03/07 at 1000 coarse vertices, keyframes aligned: frame 39 started at 0.121 from
#: the prolonged frame and 0.153 from the blend; the lower start ended in another minimum,
#: at the iteration limit, 0.006 against 0.0015, and carried it to frame 36: 214 iterations
#: for frames 36–39, pop 1.52). Farther apart (frames 1, 19, 21 there: 2.3–5x) the lower start
#: is kept without solving.
START_AMBIGUITY = 2.0


def _resume_budget(opts) -> int:
    """Iterations :func:`~.reconstruction.resume_steady` may add: none where the user (or
    the coarse mesh's own :data:`COARSE_MAX_ITER`) set the limit, which then holds."""
    return 0 if "max_iter" in opts.gn_options else RESUME_ITER


def fixpoint_iterations(seq, tg, Vkey, T, pinned, prob, opts, prog, stage_prefix="",
                        log=None, work=None) -> StageResult:
    """The fixpoint iterations of the LΘA model (paper §9, Fig. 9), on ``seq`` in place:
    reference meshes ← the current result, re-solve the spline, reconstruct from the current
    result, place; the change of each iteration is appended to ``log``, its solves counted
    in ``work`` (a :class:`~.reconstruction.GaussNewtonWork`) as ``"fixpoint"`` and
    ``"resumed"``."""
    frames, K, bc = prob.frames, prob.K, opts.bc
    ks = _in_betweens(prob, opts)
    for it in range(opts.fixpoint):
        t0 = time.perf_counter()
        with prog.stage(stage_prefix + f"fixpoint {it + 1} solve"):
            W_spline = lta_weights(seq.V, T, mu=opts.mu, lam=opts.lam, eta=opts.eta)
            Znew = tg.clamp(lta_spline(tg.Zkey, frames, K, bc=bc, weights=W_spline,
                                       spline=opts.spline))
        stage = stage_prefix + f"fixpoint {it + 1} reconstruct"
        with prog.stage(stage, total=len(ks)):
            results = run_reconstruction(T, ks, Znew, lambda k: W_spline[k], seq.V, pinned,
                                         opts.gn_options, opts.workers, prog, False,
                                         stage=stage, work=work, kind="fixpoint")
        resume_steady(T, results, Znew, lambda k: W_spline[k], pinned, opts.gn_options,
                      opts.workers, prog, stage_prefix + f"fixpoint {it + 1} ",
                      budget=_resume_budget(opts), work=work)
        Vnew = linear_blend(Vkey, frames, K, bc)
        for k in ks:
            Vnew[k] = results[k][0]
        Vnew = _placed(Vnew, Vkey, T, pinned, prob, opts)
        if log is not None:
            log.append(dict(fixpoint_change(seq.V, Vnew, seq.Z, Znew, T, Vkey),
                            iteration=it + 1, resolution=stage_prefix.strip() or "full",
                            seconds=time.perf_counter() - t0))
        seq.V, seq.Z, seq.W = Vnew, Znew, W_spline
        seq.frame_records = [results[k][1] for k in ks]
    return seq


#: Gauss–Newton iteration limit per frame on the coarse mesh of a multiresolution run (the
#: solver's default, 60, elsewhere; ``gn_options={"max_iter": ...}`` / ``--max-iter`` set
#: both). The coarse mesh of the horse subdivided twice (1174 vertices, slivers the
#: decimation could not remove) has frames whose line search cuts most steps to a tenth: their
#: energy still fell steadily at 60 iterations (|g|/|g0| = 0.31, exit 1) and they converge
#: in 76–129.
COARSE_MAX_ITER = 200


def multires_sequence(prob, opts, prog, fixpoint_log=None) -> StageResult:
    """Multiresolution (paper §8): decimate all keyframes at once, run the LΘA spline (and,
    for ``method="nonlinear"`` without ``fine``, the nonlinear spline) on the coarse meshes,
    prolong by detail transfer, optionally refine at full resolution (``fine``), place."""
    from ..shells.prolong import fade_new_defects

    Vkey, T, pinned, frames, K, bc = prob.Vkey, prob.T, prob.pinned, prob.frames, prob.K, opts.bc
    dec, Tc, multires = decimated(prob, prog)
    # iterations on the coarse mesh are cheap (a few ms): its slow frames get more of them
    copts = replace(opts, gn_options={"max_iter": COARSE_MAX_ITER, **opts.gn_options})
    coarse = lta_sequence(dec.V, Tc, dec.pinned, prob, copts, prog, stage_prefix="coarse ",
                          fixpoint_log=fixpoint_log)
    discarded = None
    before = _unconverged(coarse.frame_records)
    if before and opts.method == "lta":
        # frames that did not converge on the coarse mesh: where a keyframe folds over, the
        # decimation may have left the fold's tiny fine faces (see decimate's fold_area);
        # with the fold coarsened, the run is kept if fewer frames fail
        again = decimated(prob, prog, fold_area=REFOLD_AREA)
        if again is not None:
            dec2, Tc2, multires2 = again
            log2 = None if fixpoint_log is None else []  # the kept run's fixpoint records
            coarse2 = lta_sequence(dec2.V, Tc2, dec2.pinned, prob, copts, prog,
                                   stage_prefix="coarse ", fixpoint_log=log2)
            after = _unconverged(coarse2.frame_records)
            multires2["refolded"] = {"fold_area": REFOLD_AREA, "unconverged_before": before,
                                     "unconverged_after": after, "kept": after < before}
            prog.message(f"coarse mesh: {before} frame(s) did not converge; decimated again "
                         f"with the folds of the keyframes coarsened (fold_area "
                         f"{REFOLD_AREA:g}): {after} did not converge, "
                         f"{'kept' if after < before else 'not kept'}")
            if after < before:
                if fixpoint_log is not None:
                    fixpoint_log[:] = log2
                discarded, coarse = coarse, coarse2
                dec, Tc, multires2["first_decimation"] = dec2, Tc2, multires["decimation"]
                multires = multires2
            else:
                discarded = coarse2
                multires["refolded"] = multires2["refolded"]
    out = StageResult(V=coarse.V, report={"multires": multires},
                      gn_work=dict(coarse.gn_work))
    if discarded is not None:
        out.gn_work["coarse (discarded)"] = discarded.gn_work["coarse"].discarded()
    if "bending_fade" in coarse.report:
        multires["bending_fade"] = coarse.report["bending_fade"]
    if "reference_geodesic" in coarse.report:
        out.report["reference_geodesic"] = coarse.report["reference_geodesic"]
    if opts.method == "nonlinear" and not opts.fine:
        # the nonlinear spline on the coarse meshes (started from their LΘA spline),
        # prolonged like the LΘA result
        coarse.V, out.report["nonlinear"] = nonlinear_solve(dec.V, Tc, dec.pinned, coarse.V,
                                                            prob, opts, prog, "coarse ")
        out.report["nonlinear"]["resolution"] = "coarse"
        coarse.Z = None
    V = prolonged(prob, opts, prog, dec, coarse.V, multires)
    multires["coarse_frames"] = coarse.frame_records
    if opts.fine:
        multires["fine_starts"] = {}
        fine = lta_sequence(Vkey, T, pinned, prob, opts, prog, Vinit=V, stage_prefix="fine ",
                            fixpoint_log=fixpoint_log, start_log=multires["fine_starts"])
        # nor does the refinement: where it adds a defect, it fades back to its start
        fine.V, multires["fine_guard"] = fade_new_defects(
            fine.V, coarse.V, T, Tc, dec.collapse_map, frames,
            _placed(V, Vkey, T, pinned, prob, opts), bc=bc)
        out.V, out.Z, out.W, out.frame_records = fine.V, fine.Z, fine.W, fine.frame_records
        out.gn_work.update(fine.gn_work)
        out.report["bending_fade"] = fine.report.get("bending_fade")
        if "reference_geodesic" in fine.report and \
                out.report.get("reference_geodesic", {}).get("success", True):
            out.report["reference_geodesic"] = fine.report["reference_geodesic"]
    else:
        out.frame_records = coarse.frame_records
        # energies where the spline was solved (full-resolution descriptors of every frame
        # would cost more than the whole coarse run)
        out.energy_source = (coarse.V, coarse.Z, Tc, coarse.W)
        out.V = V
    out.V = _placed(out.V, Vkey, T, pinned, prob, opts)
    return out


#: ``fold_area`` of the second decimation of a multiresolution run whose coarse frames did
#: not all converge (:func:`multires_sequence`; see
#: :func:`~shellspline.mesh.decimate.decimate`). Not the first choice: the detail transfer
#: loses folds coarsened this way (a 150° joint, ``tests/shells/test_prolong.py``: 31–105
#: flipped fine faces instead of at most 12), but a coarse mesh that keeps a fold's tiny fine
#: faces can stop its Gauss–Newton frames short: the horse Loop-subdivided twice (134 782
#: vertices, 1000 coarse) had 33 of 38 coarse frames converged (median 21 iterations), with
#: the fold coarsened 38 of 38 (median 5), 77 / 0 / 33 new flipped / collapsed / folded
#: against 108 / 0 / 42.
REFOLD_AREA = 0.5


def _unconverged(records) -> int:
    return sum(1 for r in records if r.get("status") != "converged")


def decimated(prob, prog, fold_area: float = 0.0):
    """All keyframes decimated at once to ``prob.n_coarse`` vertices (paper §8): the
    :class:`~shellspline.mesh.decimate.Decimation`, the coarse topology and the start of the
    report's ``multires`` section. With ``fold_area`` > 0 (see
    :func:`~shellspline.mesh.decimate.decimate`): None where no keyframe folds over (the
    decimation would be the same)."""
    from ..mesh.decimate import decimate

    with prog.stage("decimate"):
        dec = decimate(prob.Vkey, prob.T, prob.n_coarse, pinned=prob.pinned,
                       fold_area=fold_area)
        if fold_area > 0 and not dec.stats.get("folded_corners"):
            return None
        Tc = topology(dec.F, dec.V.shape[1], name="coarse mesh")
    multires = {"coarse_vertices": int(dec.V.shape[1]), "coarse_faces": int(dec.F.shape[0]),
                "decimation": {k: v for k, v in dec.stats.items()
                               if isinstance(v, (int, float, str, bool))}}
    return dec, Tc, multires


def prolonged(prob, opts, prog, dec, Vc, multires):
    """The coarse sequence ``Vc (K+1,nc,3)`` prolonged to the full mesh by detail transfer
    (paper §8), with no defect that the coarse frames do not have (the guard's record goes
    into ``multires["guard"]``); pins that move between keyframes follow their blend."""
    from ..shells.prolong import Prolongation

    Vkey, T, pinned, frames, K, bc = prob.Vkey, prob.T, prob.pinned, prob.frames, prob.K, opts.bc
    with prog.stage("prolong"):
        moving = pinned is not None and bool(np.any(Vkey[:, pinned] != Vkey[0, pinned]))
        P = Prolongation.encode(Vkey, T, dec, frames, pinned=None if moving else pinned,
                                transfer=opts.transfer)
        V = parallel_decode(P, Vc, frames, K, bc, opts.workers)
        # no defect that the coarse frames do not have: the detail fades where it adds one
        V, multires["guard"] = P.guard(V, Vc, K, bc=bc)
        del P  # its factorization is not needed any more (memory of a fine run)
        if moving:  # same semantics as full resolution: pins follow the blend
            V[:, pinned] = linear_blend(Vkey[:, pinned], frames, K, bc)
    return V


def nonlinear_solve(Vkey, T, pinned, Vinit, prob, opts, prog, stage_prefix=""):
    """The nonlinear spline (paper eqs. 7–8) started from ``Vinit``; returns
    ``(V (K+1,n,3), report record)``, ``V`` the start itself (keyframes exact) when the
    spline's result has defects the start does not (:func:`worse_than_start`; the record says
    so in ``start_returned`` and its message)."""
    from ..shells.nonlinear import nonlinear_spline

    kw = dict(opts.solver_options)
    max_iter = int(kw.pop("max_iter", 500))
    stage = stage_prefix + "nonlinear"
    gtol = float(kw.get("gtol", 1e-6))
    first = {}

    def report(it, e, g):
        # the bar fills with the gradient reduction on a log scale, 1000 = gtol reached
        g0 = first.setdefault("g", g)
        red = g / g0 if g0 > 0 else 0.0
        frac = np.log(1.0 / max(red, tol.zero)) / np.log(1.0 / gtol) if 0 < gtol < 1 else 0.0
        prog.advance(stage, int(1000 * min(max(frac, 0.0), 1.0)), 1000,
                     text=f"it {it:3d}  F {e:.7g}  |g|/|g0| {red:.1e}")

    with prog.stage(stage, total=1000):
        # iteration 0 is reported after the first evaluation, one geodesic midpoint solve per
        # energy term: minutes on the coarse horse (K = 40), so say what is happening
        n_terms = prob.K if opts.periodic else prob.K - 1
        prog.advance(stage, 0, 1000, text=f"evaluating the start path ({n_terms} geodesic "
                                          "midpoints)")
        nl = nonlinear_spline(Vkey, prob.frames, prob.K, T, bc=opts.bc, mu=opts.mu,
                              lam=opts.lam, eta=opts.eta, pinned=pinned, init=Vinit,
                              max_iter=max_iter, callback=report, **kw)
    if not nl.success:
        prog.message(f"nonlinear spline: {nl.message}")
    rec = nonlinear_record(nl, Vkey.shape[1])
    start = np.array(Vinit, dtype=np.float64)
    start[prob.frames] = Vkey
    if opts.periodic:
        start[prob.K] = Vkey[0]
    worse = worse_than_start(nl.V, start, T, prob.frames, opts.bc)
    rec["start_returned"] = bool(worse)
    if not worse:
        return nl.V, rec
    # the guarantee: the nonlinear spline starts from the LΘA result and must not make
    # it worse (on the coarse horse, 5 poses, 300 s: F 3.4e5 -> 1.8e5 but 3 folded edges
    # against the start's 1)
    rec["message"] += f"; the result has more defects than its LΘA start ({worse}): " \
                      "the start is returned"
    prog.message(f"nonlinear spline: result has more defects than its LΘA start ({worse}); "
                 "returning the start")
    return start, rec


def worse_than_start(V, start, T, frames, bc) -> str:
    """Which defects (:func:`shellspline.metrics.sequence_defects`) the sequence ``V
    (K+1,n,3)`` has more of than ``start``: more flipped or collapsed faces or folded edges,
    or a pop above both :data:`POP_MARGIN` times the start's and
    :data:`~.reconstruction.SEAM_POP`; ``""`` if none (the nonlinear spline's result is kept
    only then)."""
    got = sequence_defects(V, T, frames, bc=bc)
    ref = sequence_defects(start, T, frames, bc=bc)
    out = [f"{k.replace('_', ' ')} {got[k]} > {ref[k]}"
           for k in ("flipped_faces", "collapsed_faces", "folded_edges") if got[k] > ref[k]]
    bound = max(POP_MARGIN * ref["pop"], SEAM_POP)
    if got["pop"] > bound:
        out.append(f"pop {got['pop']:.2f} > {bound:.2f}")
    return ", ".join(out)


#: :func:`worse_than_start` calls a pop worse only beyond this factor of the start's: the
#: pop is a ratio of steps that any change of the path moves a little (a converged nonlinear
#: spline of the ellipsoids, started from poorly solved LΘA frames: 1.83 against 1.79).
POP_MARGIN = 1.1

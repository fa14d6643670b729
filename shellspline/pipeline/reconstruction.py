"""The reconstruction stage: Gauss–Newton per frame, in runs from the keyframes, serially or
on a process pool, and the parallel prolongation decode.

Frames are solved in runs that start next to a keyframe (:func:`reconstruction_runs`), warm
started along the run (:func:`solve_run`); a second pass continues the better run of each
keyframe gap into the other half (:func:`continued_runs`); where the two runs of a gap still
meet in different local minima, the frames around the seam are re-solved together
(:func:`bridge_seams`, :mod:`shellspline.pipeline.bridge`). :func:`reconstruct_frames` is
the whole stage.

On a process pool each gap goes through these steps as soon as the one before is done for
that gap, while the other workers still solve other gaps (:class:`GapContinuations`): its
continuation once its two runs are solved, its seam's bridge once its continuation is. A
seam bridged after the pool (the last one, or where nothing else was left to overlap) shares
its window's frames with a forked worker instead (:meth:`~.bridge.SeamBridge.solve`).
"""
from __future__ import annotations

import mmap
import time

import numpy as np

from ..shells.descriptors import face_normals
from ..shells.reconstruct import LARGE_MESH, GaussNewton, rigid_placement
from ..timeline import keyframe_bracket

__all__ = ["reconstruct_frames", "run_reconstruction", "reconstruction_runs", "continued_runs",
           "GapContinuations", "GaussNewtonWork", "work_record", "WORK_KINDS", "DISCARDED_KINDS",
           "solve_run", "parallel_decode", "safe_init", "single_blas_thread", "seam_jump",
           "seam_records", "bridge_seams", "bridge_kept", "SERIAL_RECONSTRUCT_WORK",
           "SERIAL_DECODE_WORK", "SPLIT_BRIDGE_WORK", "CONTINUE_MARGIN", "SEAM_POP", "SEAM_DETECT",
           "SEAM_ROUNDOFF",
           "POP_DEFECTS"]

#: Below this many vertex-frames the Gauss–Newton reconstruction runs in this process even
#: with ``workers > 1``: starting a pool costs more than the work (cactus γ = 0.05, K = 20:
#: 263 coarse vertices × 18 frames, 0.11 s in-process against 0.19 s with two workers).
SERIAL_RECONSTRUCT_WORK = 20_000
#: Below this many vertex-frames in its window a bridge run in this process (one seam, or a
#: large mesh) keeps all its frames here instead of sharing them with a forked worker
#: (:meth:`~shellspline.pipeline.bridge.SeamBridge.solve`): the same bound as the frames'.
SPLIT_BRIDGE_WORK = 20_000
#: The same for the prolongation decode (cheaper per vertex-frame): the 5.2k-vertex cactus,
#: K = 20, decodes in 0.08 s in-process and 0.10 s with two workers.
SERIAL_DECODE_WORK = 250_000

#: A window step ratio above :data:`SEAM_POP` counts as this many element defects in
#: :func:`bridge_kept`: a pop moves the whole mesh at once, a folded edge two triangles.
#: Bridges that removed a pop added 1–3 folded edges on the horse (0/02/04/06/08 coarse:
#: 1; at full resolution: 2 at each of two seams; the pair 03 → 09: 3); counted as one
#: defect, all of these were refused and the pops (up to 3.5) stayed.
POP_DEFECTS = 3

_WORKER: dict = {}

#: The kinds of Gauss–Newton solve that :class:`GaussNewtonWork` counts, in report order.
WORK_KINDS = ("first_pass", "continued", "resumed", "fixpoint", "bridge", "trial_start",
              "replaced", "continuation_discarded", "speculative_discarded", "bridge_discarded",
              "trial_start_discarded", "redecimated_discarded")
#: The kinds whose result was thrown away: no output frame comes from it, directly or as the
#: start of another solve.
DISCARDED_KINDS = ("replaced", "continuation_discarded", "speculative_discarded",
                   "bridge_discarded", "trial_start_discarded", "redecimated_discarded")
_WORK_FIELDS = ("solves", "iterations", "cg_iterations", "factorizations")


class GaussNewtonWork:
    """All the Gauss–Newton work of a reconstruction, by kind of solve: every per-frame solve
    and every seam bridge's joint solve, whether its result was kept or not (the frame
    records count only the solve each frame keeps).

    Kinds (:data:`WORK_KINDS`):

    * ``first_pass``, ``continued``: the solve of a frame of a first-pass run, of a
      continuation run (:func:`continued_runs`), that the frame keeps;
    * ``resumed``: the rounds of :func:`resume_steady` (added to their frame's record);
    * ``fixpoint``: the frames of the ``fixpoint`` iterations
      (:func:`~.stages.fixpoint_iterations`);
    * ``bridge``: a kept bridge's joint solve (:func:`bridge_seams`; the bridged frames'
      records still count their own solve);
    * ``trial_start``: of :func:`~.stages.given_starts`' two solves of a run's first frame,
      the one the run starts from;
    * and the discarded ones (:data:`DISCARDED_KINDS`): ``replaced`` (a first-pass frame a
      continuation replaced), ``continuation_discarded`` (the frame at which a continuation
      stopped, not lower than the first pass), ``speculative_discarded`` (frames of a
      speculative continuation that the continuation given its energies from the start does
      not solve, :meth:`GapContinuations.speculate`: only on a process pool),
      ``bridge_discarded`` (a bridge not kept), ``trial_start_discarded`` (the other start),
      ``redecimated_discarded`` (every solve of a coarse run given up for another decimation,
      :func:`~.stages.multires_sequence`).

    Plain counts: a pool worker returns its own, which the parent adds (:meth:`merge`), so
    one worker and several count the same solves the same, but for the speculative ones.

    Examples
    --------
    >>> w = GaussNewtonWork()
    >>> w.add("first_pass", {"nit": 7, "cg_iterations": 30, "factorizations": 2})
    >>> w.add("first_pass", {"nit": 4, "cg_iterations": 12, "factorizations": 1})
    >>> w.move({"nit": 4, "cg_iterations": 12, "factorizations": 1}, "first_pass", "replaced")
    >>> r = w.record()
    >>> r["iterations"], r["discarded_solves"], r["by_kind"]["replaced"]["iterations"]
    (11, 1, 4)
    """

    def __init__(self):
        self.counts: dict = {}   # kind -> [solves, iterations, cg_iterations, factorizations]

    def add(self, kind: str, rec, solves: int = 1) -> None:
        """Count ``solves`` solves of ``kind`` whose work is ``rec``: a frame record
        (``nit``, ``cg_iterations``, ``factorizations``) or a
        :class:`~.bridge.BridgeResult`'s summary (``iterations`` for ``nit``)."""
        assert kind in WORK_KINDS, kind
        row = self.counts.setdefault(kind, [0, 0, 0, 0])
        for i, v in enumerate((solves, *_work_of(rec))):
            row[i] += int(v)

    def move(self, rec, src: str, dst: str) -> None:
        """Count a solve already counted as ``src`` (its work ``rec``) as ``dst`` instead."""
        nit, cg, facts = _work_of(rec)
        self.add(src, {"nit": -nit, "cg_iterations": -cg, "factorizations": -facts},
                 solves=-1)
        self.add(dst, rec)

    def merge(self, other: "GaussNewtonWork") -> "GaussNewtonWork":
        """Add ``other``'s counts (a worker's) to these; returns self."""
        for kind, row in other.counts.items():
            mine = self.counts.setdefault(kind, [0, 0, 0, 0])
            for i, v in enumerate(row):
                mine[i] += v
        return self

    def discarded(self, kind: str = "redecimated_discarded") -> "GaussNewtonWork":
        """All of these counts as one discarded ``kind`` (a new accumulator)."""
        out = GaussNewtonWork()
        t = self.totals()
        out.add(kind, {"nit": t["iterations"], "cg_iterations": t["cg_iterations"],
                       "factorizations": t["factorizations"]}, solves=t["solves"])
        return out

    def totals(self, kinds=WORK_KINDS) -> dict:
        """``{"solves", "iterations", "cg_iterations", "factorizations"}`` over ``kinds``."""
        rows = [self.counts[k] for k in kinds if k in self.counts]
        return {f: int(sum(r[i] for r in rows)) for i, f in enumerate(_WORK_FIELDS)}

    def record(self) -> dict:
        """The report's record: :meth:`totals`, ``discarded_solves`` and ``by_kind`` (the
        totals of each kind that has solves, in :data:`WORK_KINDS` order)."""
        return {**self.totals(),
                "discarded_solves": self.totals(DISCARDED_KINDS)["solves"],
                "by_kind": {k: self.totals((k,)) for k in WORK_KINDS
                            if self.counts.get(k, [0])[0]}}


def _work_of(rec) -> tuple:
    """``(iterations, CG iterations, factorizations)`` of a frame record or a bridge's
    summary."""
    return (rec["nit"] if "nit" in rec else rec["iterations"], rec.get("cg_iterations", 0),
            rec.get("factorizations", 0))


def work_record(levels: dict) -> dict:
    """``report["gauss_newton"]["work"]``: the :meth:`GaussNewtonWork.record` of all the
    resolutions' work ``levels`` (``{"full": work}``, or ``{"coarse": .., "fine": ..}``)
    together, with ``by_resolution`` (each one's totals) where there are several."""
    total = GaussNewtonWork()
    for w in levels.values():
        total.merge(w)
    out = total.record()
    if len(levels) > 1:
        out["by_resolution"] = {name: {**w.totals(), "discarded_solves":
                                       w.totals(DISCARDED_KINDS)["solves"]}
                                for name, w in levels.items()}
    return out


def single_blas_thread():
    """Limit BLAS thread pools to one thread in this process (our parallelism is the process
    pool; BLAS threads on level-1/2 work only oversubscribe the cores). Returns the limiter
    (keep a reference) or None when threadpoolctl is unavailable."""
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:  # pragma: no cover - threadpoolctl is a required dependency
        return None
    return threadpool_limits(limits=1)


def _worker_init(F, n, pinned, gn_options):
    from ..mesh.topology import topology

    _WORKER["blas"] = single_blas_thread()
    if "gn" not in _WORKER:  # forked workers inherit the parent's prepared solver
        _WORKER["gn"] = GaussNewton(topology(F, n), pinned=pinned, **gn_options)


def solve_run(gn: GaussNewton, ks, Zs, Ws, Vinit, Vanchor, warm, on_frame=None,
               worse_than=None, tubes=None, gate=None, work=None, kind="first_pass"):
    """Reconstruct a run of consecutive frames, in the run's order (see :func:`reconstruction_runs`).

    ``Vanchor`` is the keyframe next to the run's first frame, or a pair of solved frames
    ``(V[k∓2], V[k∓1])`` that the run continues. With ``warm`` each frame starts from its
    solved predecessor in the run, moved by the initial sequence's change (``warm="delta"``,
    for a given good sequence such as a prolonged coarse result) or, with
    ``warm="extrapolate"``, the second and later frames from the linear extrapolation
    ``2 V[k∓1] − V[k∓2]`` of the last two solutions (the keyframe counting as the first of
    them), the first from the keyframe moved by the initial sequence's change
    ``Vinit[k] − Vanchor``. Extrapolating the solutions carries the motion of the spline
    itself; moving by the keyframe blend's change instead carries the blend's flaps that turn
    over between keyframes (measured on the horse: the blend passes 43 edges through ±π).

    ``worse_than`` (energies, one per frame of the run): the run stops at the first frame
    whose energy is not below it, and that frame is not returned (see :func:`continued_runs`).

    ``tubes`` (one ``(i,)`` array or None per frame): the frames' tube weights
    (:meth:`~shellspline.shells.reconstruct.GaussNewton.solve`).

    ``gate`` (a speculative continuation, see :class:`GapContinuations`): called before each
    frame, returns ``(state, energies)``: :data:`GATE_WAIT` (energies not known yet: go on),
    :data:`GATE_ABORT` (stop), or :data:`GATE_GO` with the energies to beat, which then act as
    ``worse_than`` from the first frame on (frames already solved that do not beat theirs
    are dropped with all after them): the frames returned are those of the same run given
    ``worse_than`` from the start.

    ``work`` (a :class:`GaussNewtonWork`): every solve is counted there, those of the frames
    returned as ``kind``; the frame at which ``worse_than`` stops the run as
    ``"continuation_discarded"``, and frames a gate drops after it as
    ``"speculative_discarded"``.
    """
    out = []
    work = GaussNewtonWork() if work is None else work
    gn.reset()  # a run's result does not depend on which runs this solver did before, so
    # one worker and several give the same sequence
    if isinstance(Vanchor, tuple):
        prev2, prev = Vanchor
        prev_init = prev
    else:
        prev2, prev, prev_init = None, Vanchor, Vanchor
    for i, (k, z, w, v) in enumerate(zip(ks, Zs, Ws, Vinit)):
        if gate is not None:
            state, energies = gate()
            if state == GATE_ABORT:
                break
            if state == GATE_GO:
                worse_than, gate = energies, None
                cut = beaten_prefix(out, worse_than)
                if cut < len(out):
                    # the run given worse_than from the start solves frame `cut` and stops
                    work.move(out[cut][2], kind, "continuation_discarded")
                    for _, _, rec in out[cut + 1:]:
                        work.move(rec, kind, "speculative_discarded")
                    del out[cut:]
                    break
        t0 = time.perf_counter()
        v0 = v
        tube = None if tubes is None else tubes[i]
        if warm and prev is not None:
            v = warm_start(gn, z, w, tube, v, prev, prev2, prev_init, warm)
        r = gn.solve(z, w, v, tube)
        rec = r.summary()
        if worse_than is not None and not r.energy < (1.0 - CONTINUE_MARGIN) * worse_than[i]:
            work.add("continuation_discarded", rec)
            break
        work.add(kind, rec)
        prev2, prev, prev_init = prev, r.V, v0
        if r.status == "limit":   # for resume_steady
            rec["to_go"] = iterations_to_go(r.energies, gn.dtol)
        rec["frame"] = int(k)
        rec["seconds"] = time.perf_counter() - t0
        out.append((int(k), r.V, rec))
        if on_frame is not None:
            on_frame(i + 1, rec)
    return out


#: States of a speculative continuation's gate (see :func:`solve_run`): the energies to beat
#: are not known yet; known (go on while beating them); the other run of the gap won (stop).
GATE_WAIT, GATE_GO, GATE_ABORT = 0, 1, 2


def beaten_prefix(solved, worse_than) -> int:
    """How many of the solved frames ``[(k, V, record), ...]`` of a continuation beat the
    energies ``worse_than`` of the first pass, in order (the frames a run given
    ``worse_than`` keeps: it stops at the first that does not)."""
    for i, (_, _, rec) in enumerate(solved):
        if not rec["energy_final"] < (1.0 - CONTINUE_MARGIN) * worse_than[i]:
            return i
    return len(solved)


#: Gauss–Newton iterations a frame stopped at its limit while still converging steadily may
#: be given after the reconstruction passes (see :func:`resume_steady`) ...
RESUME_ITER = 40
#: ... in rounds of this many, each granted only while the frame's tail still projects to
#: convergence within what is left.
RESUME_ROUND = 10


def iterations_to_go(energies, dtol: float, window: int = 10) -> float:
    """How many more Gauss–Newton iterations a frame whose energies were ``energies`` needs
    to meet the decrement criterion, projected from its tail: its last ``window`` energy
    decreases (≈ the Gauss–Newton decrements) must all be positive and shrink, and at their
    geometric rate the decrease falls below ``dtol`` times the energy after the returned
    number of iterations (0 where it already has; ``inf`` for a tail that is not steady).

    >>> e = 1.0 + 0.5 ** np.arange(25)          # halves the gap every iteration
    >>> round(iterations_to_go(e, 1e-12), 2)     # log2(0.5 ** 24 / 1e-12)
    15.86
    >>> iterations_to_go(1.0 + 1e-3 * np.arange(30, 0, -1), 1e-12)   # a constant pace
    inf
    """
    e = np.asarray(energies, dtype=np.float64)
    if e.size < window + 1 or not np.all(np.isfinite(e[-window - 1:])):
        return np.inf
    d = -np.diff(e[-window - 1:])
    if not np.all(d > 0) or not d[-1] < d[0]:
        return np.inf
    goal = dtol * e[-1]
    if d[-1] <= goal:
        return 0.0
    rate = (d[-1] / d[0]) ** (1.0 / (window - 1))
    return float(np.log(goal / d[-1]) / np.log(rate))


def steady_tail(energies, dtol: float, budget: int = RESUME_ITER, window: int = 10) -> bool:
    """Whether a frame stopped at its limit projects to convergence within ``budget`` more
    iterations (:func:`iterations_to_go`).

    >>> e = 1.0 + 0.5 ** np.arange(40)
    >>> steady_tail(e, 2e-6), steady_tail(1.0 + 0.99 ** np.arange(40), 2e-6)
    (True, False)
    """
    return budget > 0 and iterations_to_go(energies, dtol, window) <= budget


class _FrameStarts:
    """``Vinit``-like view of solved frames ``{k: (n,3) array}`` (for :func:`resume_steady`)."""

    def __init__(self, V):
        self.V = V

    def __getitem__(self, k):
        if np.ndim(k) == 0:
            return self.V[int(k)]
        return np.stack([self.V[int(i)] for i in k])


def resume_steady(T, results, Z, W_of, pinned, gn_options, workers, prog, stage_prefix="",
                  tube_of=None, budget: int = RESUME_ITER, work=None):
    """Give the frames that stopped at their iteration limit while still converging steadily
    up to ``budget`` more Gauss–Newton iterations, each from where it stopped, after every
    run has been solved: in rounds of :data:`RESUME_ROUND`, a frame taking part in a round
    only while its tail (the first round: ``record["to_go"]``, set by :func:`solve_run`;
    later: the last round's) projects to convergence within the iterations left
    (:func:`iterations_to_go`).

    Why after, not in place: slow tails on real meshes are motion, not round-off (horse,
    eleven poses every 10th frame: three frames stopped at 60 iterations with vertices still
    up to 0.8 edge lengths from their minimum; resumed, they converge within 11 more).
    Granting the iterations inside the runs changes the warm start of every later frame of
    the run, and on a sliver tube whose chain of warm starts is chaotic that sent frames
    14–17 of ``data_synth.stress.dense_slivers`` (decimated) into basins 10–50× higher.
    Resumed here, no other frame's start changes. Why in rounds: a tail's rate can slow
    down; on the 6k-vertex sliver tube (``dense_slivers(subdivisions=1)``) six frames
    projected within 40 and none converged in 40 more (+40 s of 650). A flat higher limit
    spends the most there (~270 → 495 s for 5 instead of 3 converged frames of 18).

    Updates ``results`` in place; a resumed frame's record says ``"resumed": true`` and
    counts the iterations, CG iterations, factorizations and seconds of all its solves.
    Returns the frames resumed. ``work``: a :class:`GaussNewtonWork` counting the rounds'
    solves as ``"resumed"``.
    """
    left = int(budget)
    todo = sorted(int(k) for k, (_, rec) in results.items()
                  if rec.pop("to_go", np.inf) <= left)
    resumed = []
    stage = stage_prefix + "reconstruct (resume steady frames)"
    while todo and left > 0:
        step = min(RESUME_ROUND, left)
        left -= step
        resumed += [k for k in todo if k not in resumed]
        starts = _FrameStarts({k: results[k][0] for k in todo})
        with prog.stage(stage, total=len(todo)):
            more = run_reconstruction(T, np.array(todo), Z, W_of, starts, pinned,
                                      {**gn_options, "max_iter": step}, workers, prog,
                                      False, stage=stage,
                                      runs=[(np.array([k]), k) for k in todo],
                                      tube_of=tube_of, work=work, kind="resumed")
        todo = []
        for k, (Vk, rec) in more.items():
            old = results[k][1]
            new = {**old, **{key: rec[key] for key in ("success", "status", "message",
                                                      "energy_final", "grad_norm_final")}}
            for key in ("nit", "cg_iterations", "factorizations", "seconds"):
                if key in old or key in rec:
                    new[key] = old.get(key, 0) + rec.get(key, 0)
            new["resumed"] = True
            if new.get("status") == "limit":
                # the tail this round saw (its energies start where the last round stopped)
                new["message"] = rec["message"].replace(
                    f"({step})", f"({new['nit']}, resumed)")
                if rec.pop("to_go", np.inf) <= left:
                    todo.append(int(k))
            rec.pop("to_go", None)
            new.pop("to_go", None)
            results[k] = (Vk, new)
        todo.sort()
    return sorted(resumed)


def warm_start(gn: GaussNewton, z, w, tube, v, prev, prev2, prev_init, warm):
    """The start of a frame in a run: the usual candidate (the first below), or another one
    whose reconstruction energy
    (:meth:`~shellspline.shells.reconstruct.GaussNewton.start_energy`) is below
    :data:`START_PREFERENCE` times the best so far (the initial sequence's frame ``v`` when no
    candidate leaves every triangle above the collapse floor).

    Candidates: with ``warm="extrapolate"`` and two solved frames, the linear extrapolation
    ``2 prev − prev2``; the solved predecessor moved by the initial sequence's change
    ``prev + (v − prev_init)``; and, after two solved frames of a connected mesh, the
    predecessor itself. The
    extrapolation is the usual winner (it carries the spline's motion), but next to a
    keyframe with a nearly degenerate triangle it can push that triangle past its hinge: an
    icosphere face squeezed to 2 % of its height at a keyframe had the extrapolated start of
    the frame after next at energy 10.4 against 0.05 at its predecessor, and Gauss–Newton
    crept back over 121 iterations (60 is the limit; the frame was reported unconverged).
    Each candidate costs one descriptor evaluation.
    """
    cands = []
    if prev2 is not None and warm == "extrapolate":
        cands.append(2.0 * prev - prev2)
    cands.append(prev + (v - prev_init))
    if prev2 is not None and gn.T.n_components == 1:
        # (not next to the keyframe: it sits closer to the first frame's targets than any
        # start that moves, but starting there cost the cactus iterations; and not for pieces
        # of a mesh, placed relative to each other only by the other two starts: the energy
        # does not see it, and a frame that kept its predecessor's placement of the pieces
        # would jump against the other run of its gap)
        cands.append(prev)
    best, best_f = v, np.inf
    for i, c in enumerate(cands):
        if not np.all(np.isfinite(c)):
            continue
        f = gn.start_energy(c, z, w, tube)
        # the usual start (the first) unless another is clearly better: starts of equal
        # energy reach the same minimum by different paths, and frames of smooth sequences
        # would move within the solver's tolerance for nothing
        if f < (START_PREFERENCE if i and np.isfinite(best_f) else 1.0) * best_f:
            best, best_f = c, f
    return best


#: A start other than the usual one (see :func:`warm_start`) is taken only when its energy is
#: below this fraction of the usual start's.
START_PREFERENCE = 0.1


def _frame_text(rec) -> str:
    """One progress line for a reconstructed frame (logs get one per frame)."""
    return (f"frame {rec['frame']:4d}: {rec['status']:<9s} {rec['nit']:3d} it  "
            f"E {rec['energy_final']:.3g}")


#: A continued run replaces a first-pass frame only when its energy is lower by this fraction
#: (equal minima differ at solver tolerance; without a margin the choice was decided by
#: round-off and differed between one and two workers).
CONTINUE_MARGIN = 1e-3


def continued_runs(runs, results, Vinit):
    """Second pass over each keyframe gap solved from both ends (see :func:`reconstruction_runs`).

    The runs from the two keyframes of a gap can settle into different local minima of the
    reconstruction (the horse: frame 10 at energy 0.075 from keyframe 0, frame 11 at 0.011
    from keyframe 20; a jump where they meet). The run whose frame at the meeting point has
    the lower energy is continued into the other half, frame by frame, for as long as it
    finds lower energies there than the first pass did.

    Returns the continuation runs ``(frames, (V[k∓2], V[k∓1]), energies to beat)`` for
    :func:`run_reconstruction`. The jump that remains is measured by :func:`seam_records`.
    """
    tasks = []
    # pair each forward run (anchor before its frames) with the backward run of its gap
    fwd = {int(r[-1]): (r, a) for r, a in runs if len(r) and r[0] > a}
    for r, a in runs:
        if not len(r) or r[0] > a:
            continue
        m = int(r[-1]) - 1                                   # last frame of the forward half
        if m not in fwd:
            continue
        rf, af = fwd[m]
        ef = results[m][1]["energy_final"]
        eb = results[int(r[-1])][1]["energy_final"]
        frames_, anchor_ = continuation(((rf, af), (r, a)), ef <= eb, results, Vinit)
        tasks.append((frames_, anchor_,
                      np.array([results[int(k)][1]["energy_final"] for k in frames_])))
    return tasks


def continuation(gap, forward: bool, results, Vinit):
    """The frames and anchor of the run continuing one run of a keyframe ``gap`` (its
    forward and backward runs) into the other half: the forward run's (``forward``) or the
    backward run's, solved in ``results``. Returns ``(frames, (V[k∓2], V[k∓1]))``."""
    (rf, af), (rb, ab) = gap
    if forward:    # continue the forward run into the backward half
        frames_, seq, anchor_ = rb[::-1], rf, af
    else:          # continue the backward run into the forward half
        frames_, seq, anchor_ = rf[::-1], rb, ab
    V1 = results[int(seq[-1])][0]
    V2 = results[int(seq[-2])][0] if len(seq) >= 2 else Vinit[anchor_]
    return frames_, (V2, V1)


class GapContinuations:
    """The continuation runs of :func:`continued_runs`, gap by gap, as soon as both runs of a
    keyframe gap are solved: on a process pool they fill the time the other workers still
    need for the first pass (:func:`run_reconstruction`'s ``follow``) instead of waiting for
    all of it. A gap's continuation depends on that gap's two runs only, and every run starts
    its solver afresh (:func:`solve_run`), so the frames are the same as from the separate
    pass. Horse (``horse-reference, 03, 07`` at 0, 20, 40, two workers): the first pass's
    runs took about 12, 6, 8.5 and 13 s, so one worker idled for 10 s at its end, and the
    continuation of the first gap (frames 7–10, 5 s) now runs there.

    Parameters
    ----------
    runs : list of ((r,) int array, int)
        The first pass's runs (:func:`reconstruction_runs`).
    Vinit : (K+1,n,3) float64 array
        Initial sequence (keyframes at their frames).
    stage : str
        Progress stage name of the continuation frames.
    """

    def __init__(self, runs, Vinit, stage: str, bridge=None):
        self.Vinit, self.stage = Vinit, stage
        fwd = {int(r[-1]): (r, a) for r, a in runs if len(r) and r[0] > a}
        # the two runs of each gap: the forward run ending just before the backward one
        self.gaps = [[fwd[int(r[-1]) - 1], (r, a)] for r, a in runs
                     if len(r) and r[0] < a and int(r[-1]) - 1 in fwd]
        self._started = set()
        self.submitted = set()  # frames (as tuples) of the runs handed out
        self.results = {}
        self._done = self._total = 0
        self._gap_of = {}       # frames (as tuples) of a continuation run -> its gap
        self._running = {}      # gap -> its continuation runs still on the pool
        self._finished = []     # gaps whose continuation is solved, not yet looked at
        self.bridge = bridge    # (K, half, gn_options): bridge finished gaps on the pool
        self.bridged = {}       # seam frame -> (s, a, b, BridgeResult, before, after)
        self.gate = None        # (state (g,), energies (g, L)) shared with the workers
        self._spec = {}         # gap -> its speculative continuation (see speculate)

    def ready(self, results) -> list:
        """The continuation runs of the gaps whose runs are all in ``results`` (each gap
        once), as :func:`run_reconstruction` takes runs. A gap whose continuation is
        already being solved speculatively in the same direction gets none: its gate is
        opened with the energies to beat instead (see :meth:`speculate`)."""
        out = []
        for i, gap in enumerate(self.gaps):
            if i in self._started or not all(int(k) in results for r, _ in gap for k in r):
                continue
            self._started.add(i)
            for task in continued_runs(gap, results, self.Vinit):
                key = tuple(int(k) for k in task[0])
                self.submitted.add(key)
                self._gap_of[key] = i
                self._running[i] = self._running.get(i, 0) + 1
                self._total += len(task[0])
                spec = self._spec.get(i)
                if spec is not None and spec["key"] == key:
                    state, energies = self.gate
                    energies[i, :len(key)] = task[2]
                    state[i] = GATE_GO  # after the energies: the worker reads them next
                    spec["worse_than"] = task[2]
                else:
                    if spec is not None:
                        self.gate[0][i] = GATE_ABORT
                    out.append(task)
        return out

    def speculate(self, results, slots: int) -> list:
        """Speculative continuations for up to ``slots`` idle workers: a gap with one run
        solved and the other still going is continued from the solved run into the other
        half at once, before it is known which of the two runs is better (the run at the
        gap's middle with the lower energy, :func:`continued_runs`) or which energies its
        frames must beat. The worker reads both, once known, through the shared ``gate``
        between frames (:func:`solve_run`): the same direction keeps the frames a
        continuation given the energies from the start keeps, the other direction stops
        it. Horse, three keyframes: the second gap's continuation (frame 31, 29 iterations)
        ran 5 s after its runs, with one worker idle for those 5 s before."""
        out = []
        if self.gate is None or slots <= 0:
            return out
        for i, gap in enumerate(self.gaps):
            if len(out) >= slots:
                break
            if i in self._started or i in self._spec:
                continue
            done = [all(int(k) in results for k in r) for r, _ in gap]
            if done[0] == done[1]:
                continue
            frames_, anchor = continuation(gap, done[0], results, self.Vinit)
            self._spec[i] = {"key": tuple(int(k) for k in frames_), "out": None}
            out.append(("speculate", i, frames_, anchor))
        return out

    def speculated(self, i, solved) -> None:
        """Keep the frames a speculative continuation of gap ``i`` returned."""
        self._spec[i]["out"] = solved

    def settle(self, progress) -> None:
        """Record the speculative continuations that are back and whose direction won, cut
        to the frames that beat the first pass (:func:`beaten_prefix`)."""
        for i, spec in self._spec.items():
            if spec["out"] is not None and "worse_than" in spec and not spec.get("done"):
                spec["done"] = True
                solved = spec["out"]
                self.record(solved[:beaten_prefix(solved, spec["worse_than"])], progress,
                            spec["key"])

    def count_speculation(self, work) -> None:
        """Count the frames of the speculative continuations that no frame keeps, once they
        are all back (their solves were counted as ``"continued"`` by their workers): where
        the other direction won, all of them (``"speculative_discarded"``); where theirs did,
        those after the frames that beat the first pass (:meth:`settle`), the first of
        which the continuation given the energies from the start solves too
        (``"continuation_discarded"``)."""
        for spec in self._spec.values():
            solved = spec["out"] or []
            cut = beaten_prefix(solved, spec["worse_than"]) if "worse_than" in spec else 0
            for j, (_, _, rec) in enumerate(solved[cut:]):
                work.move(rec, "continued", "continuation_discarded"
                          if j == 0 and "worse_than" in spec else "speculative_discarded")

    def record(self, solved, progress, key=None) -> None:
        """Keep the frames ``[(k, V, record), ...]`` of a continuation run (``key``: the
        frames it was given, as a tuple)."""
        for kk, Vk, rec in solved:
            self.results[kk] = (Vk, rec)
            self._done += 1
            progress.advance(self.stage, self._done, self._total, text=_frame_text(rec))
        i = self._gap_of.get(key)
        if i is not None:
            self._running[i] -= 1
            if not self._running[i]:
                self._finished.append(i)

    def bridges_ready(self, results, pinned) -> list:
        """Bridge tasks (:func:`_worker_bridge`) for the gaps whose continuation just
        finished, where the gap has a seam and no frame that :func:`resume_steady` will
        change (a frame stopped at its limit): the bridge then sees what it would see after
        all the passes, and runs while the other workers still solve other gaps (the horse's
        gaps finish 10 s apart). Empty without ``bridge``."""
        out = []
        gaps, self._finished = self._finished, []
        if self.bridge is None:
            return out
        K, half, gn_options = self.bridge
        for i in gaps:
            view = _merged_gap(self.gaps[i], results, self.results)
            if any("to_go" in rec for _, rec in view.values()):
                continue
            for seam in seam_records(self.gaps[i], view, self.Vinit, pinned):
                s = seam["frame"]
                (rf, a), (rb, b) = self.gaps[i]
                lo, hi = max(a, s - half - 2), min(b, s + half + 1)
                # the bridge's context and the window check's frames and keyframes
                frames = {k: (self.Vinit[k] if k in (a, b) else view[k][0])
                          for k in [a, b, *range(lo, hi + 1)]}
                out.append(("bridge", s, a, b, K, half, gn_options, frames))
        return out

    def record_bridge(self, out) -> None:
        """Keep a bridge solved on the pool: ``(s, a, b, BridgeResult, before, after)``."""
        self.bridged[out[0]] = out


def _merged_gap(gap, results, continued) -> dict:
    """``{k: (V, record)}`` of a gap's frames as the passes leave them: the first pass's,
    replaced by the continuation's (records copied, marked ``"continued"``)."""
    view = {}
    for r, _ in gap:
        for k in r:
            k = int(k)
            if k in continued:
                Vk, rec = continued[k]
                view[k] = (Vk, {**rec, "continued": True})
            else:
                view[k] = results[k]
    return view


def reconstruction_runs(ks, frames, K, periodic):
    """The frames to reconstruct as runs that start next to a keyframe.

    Each keyframe gap is solved from both ends toward its middle (frames ``a+1 … m`` forward
    from keyframe ``a``, ``b−1 … m+1`` backward from keyframe ``b``), so every frame next to a
    keyframe starts from that keyframe and no chain of warm starts ends at a keyframe it never
    saw (a run ``21 … 39`` drifted away from keyframe 40: a pop into the last keyframe,
    issue 13). Frames after the last keyframe of a non-periodic sequence run forward from it.

    Returns
    -------
    list of ((r,) int array, int)
        The run's frames in solving order and the frame of its anchor keyframe.
    """
    todo = set(int(k) for k in ks)
    bounds = [int(f) for f in frames] + ([K] if periodic else [])
    out = []
    for a, b in zip(bounds[:-1], bounds[1:]):
        m = (a + b) // 2
        fwd = [k for k in range(a + 1, m + 1) if k in todo]
        bwd = [k for k in range(b - 1, m, -1) if k in todo]
        out += [(np.array(fwd), a)] if fwd else []
        out += [(np.array(bwd), b)] if bwd else []
    tail = [k for k in range(bounds[-1] + 1, K + 1) if k in todo]
    if tail:
        out.append((np.array(tail), bounds[-1]))
    assert sum(len(r) for r, _ in out) == len(todo)
    return out


def _worker_solve(kind, task):
    """A run on a pool worker (:func:`solve_run`, its solves counted as ``kind``): ``(frames,
    GaussNewtonWork)``."""
    work = GaussNewtonWork()
    if isinstance(task, tuple) and len(task) == 4 and task[0] == "inherited":
        # forked worker: the frame data are the parent's arrays, inherited (no copies)
        _, ks, anchor, worse = task
        Z, W_of, Vinit, warm, tube_of = _WORKER["frame_data"]
        return solve_run(_WORKER["gn"], ks, [Z[k] for k in ks], [W_of(k) for k in ks],
                         [Vinit[k] for k in ks], _anchor(anchor, Vinit), warm,
                         worse_than=worse, tubes=_tubes(tube_of, ks), work=work,
                         kind=kind), work
    return solve_run(_WORKER["gn"], *task, work=work, kind=kind), work


def _worker_speculate(task):
    """A speculative continuation on a forked worker (:meth:`GapContinuations.speculate`):
    the run's frames, read from the shared gate of its gap between frames, and its
    :class:`GaussNewtonWork` (the frames counted as ``"continued"``)."""
    _, i, ks, anchor = task
    Z, W_of, Vinit, warm, tube_of = _WORKER["frame_data"]
    state, energies = _WORKER["gate"]

    def gate():
        st = int(state[i])
        return st, (energies[i, :len(ks)].copy() if st == GATE_GO else None)

    work = GaussNewtonWork()
    return solve_run(_WORKER["gn"], ks, [Z[k] for k in ks], [W_of(k) for k in ks],
                     [Vinit[k] for k in ks], anchor, warm, tubes=_tubes(tube_of, ks),
                     gate=gate, work=work, kind="continued"), work


def _worker_bridge(task):
    """A seam bridged on a forked reconstruction worker (see
    :meth:`GapContinuations.bridges_ready`): ``(s, a, b, BridgeResult, before, after)``."""
    _, s, a, b, K, half, gn_options, frames = task
    gn0 = _WORKER["gn"]
    Z, W_of, _, _, tube_of = _WORKER["frame_data"]
    pinned = gn0.pinned if gn0.pinned.size else None
    out = _bridge_seam_checked(GaussNewton(gn0.T, pinned=pinned, **gn_options),
                               frames.__getitem__, K, s, a, b, Z, W_of, half, tube_of, False)
    return (s, a, b) + out


def _tubes(tube_of, ks):
    """The tube weights of frames ``ks`` (None without ``tube_of``)."""
    return None if tube_of is None else [tube_of(int(k)) for k in ks]


def _anchor(anchor, Vinit):
    """A run's anchor: the frame index of its keyframe, or a pair of solved frames."""
    return anchor if isinstance(anchor, tuple) else Vinit[anchor]


def _decode_worker(task):
    Vc, frames, K, bc, ks = task
    return ks, _WORKER["prolong"].decode(Vc, frames, K, time_weights="linear", bc=bc,
                                         only=ks)[ks]


def parallel_decode(P, Vc, frames, K, bc, workers):
    """Prolongation of every frame; frames split over ``workers`` forked processes (they share
    the parent's factorization; without fork, or with one worker, it runs here)."""
    from ..parallel import process_pool, start_method

    if workers <= 1 or start_method() != "fork" or P.n_vertices * (K + 1) < SERIAL_DECODE_WORK:
        return P.decode(Vc, frames, K, time_weights="linear", bc=bc)
    _WORKER["prolong"] = P
    try:
        out = np.zeros((K + 1, P.n_vertices, 3))
        chunks = _chunks(np.arange(K + 1), workers)
        with process_pool(workers, method="fork") as ex:
            for ks, Vk in ex.map(_decode_worker, [(Vc, frames, K, bc, c) for c in chunks]):
                out[ks] = Vk
        return out
    finally:
        _WORKER.pop("prolong", None)


def _chunks(idx, n_chunks):
    n_chunks = max(1, min(n_chunks, len(idx)))
    return [c for c in np.array_split(np.asarray(idx), n_chunks) if len(c)]


def run_reconstruction(T, ks, Z, W_of, Vinit, pinned, gn_options, workers, progress, warm,
                        stage="reconstruct", runs=None, tube_of=None, follow=None, work=None,
                        kind="first_pass"):
    """Reconstruct frames ``ks`` (in ``runs``, see :func:`reconstruction_runs`; default one run per frame
    anchored at its predecessor) serially or on ``workers`` processes; ``tube_of(k)``: the
    tube weights of frame ``k`` (see :func:`solve_run`).

    ``follow`` (a :class:`GapContinuations`, process pool only): after each run, the runs it
    returns for the results so far are solved on the same pool, in the time the other
    workers still need for their runs; their results are ``follow.results``.

    ``work`` (a :class:`GaussNewtonWork`): counts every solve, the workers' included, the
    frames returned as ``kind`` (:func:`solve_run`; ``follow``'s as ``"continued"``).
    """
    work = GaussNewtonWork() if work is None else work
    results = {}
    total = len(ks)
    if runs is None:
        runs = [(np.array([k]), max(int(k) - 1, 0)) for k in ks]
    runs = [r if len(r) == 3 else (*r, None) for r in runs]
    if total == 0:
        return results
    if workers <= 1 or total == 1 or T.n_vertices * total < SERIAL_RECONSTRUCT_WORK:
        limiter = single_blas_thread()
        try:
            gn = GaussNewton(T, pinned=pinned, **gn_options)
            for run, anchor, worse in runs:
                done = len(results)
                for kk, Vk, rec in solve_run(gn, run, Z[run], [W_of(k) for k in run],
                                              Vinit[run], _anchor(anchor, Vinit), warm,
                                              lambda i, rec: progress.advance(
                                                  stage, done + i, total,
                                                  text=_frame_text(rec)), worse,
                                              _tubes(tube_of, run), work=work, kind=kind):
                    results[kk] = (Vk, rec)
        finally:
            if limiter is not None:
                limiter.restore_original_limits()
        return results
    # runs of neighbouring (similar) frames on one worker keep its cached preconditioner and
    # warm starts good
    from concurrent.futures import FIRST_COMPLETED, wait

    from ..parallel import process_pool, start_method

    method = start_method()
    if method == "fork":
        # build the assembly pattern once here; the forked workers inherit it, and the frame
        # data (targets, weights, initial guesses): tasks then carry only frame indices, so
        # no chunk is copied, pickled and unpickled (at 150k vertices and K=50 that saved
        # ~3 GB across the parent and two workers)
        gn = GaussNewton(T, pinned=pinned, **gn_options)
        gn.prepare(Vinit[ks[0]])  # and the fill-reducing order (large meshes), also inherited
        _WORKER["gn"] = gn
        _WORKER["frame_data"] = (Z, W_of, Vinit, warm, tube_of)
        if follow is not None and follow.gaps:
            # the gates of speculative continuations: memory shared with the forked workers
            ng, longest = len(follow.gaps), max(len(r) for r, *_ in runs)
            buf = mmap.mmap(-1, 8 * ng * (1 + longest))
            follow.gate = _WORKER["gate"] = (
                np.frombuffer(buf, dtype=np.int64, count=ng),
                np.frombuffer(buf, dtype=np.float64, count=ng * longest, offset=8 * ng)
                .reshape(ng, longest))
    done = 0

    def submit(ex, c, a, w, kind=kind):
        return ex.submit(_worker_solve, kind, ("inherited", c, a, w) if method == "fork" else
                         (c, Z[c], np.stack([W_of(k) for k in c]), Vinit[c],
                          _anchor(a, Vinit), warm, None, w, _tubes(tube_of, c)))

    extra = {}  # follow-up futures -> ("continue", frames) or ("bridge", seam)

    try:
        with process_pool(workers, _worker_init, (T.F, T.n_vertices, pinned, gn_options),
                          method) as ex:
            # one task per run (runs start next to a keyframe; the pool balances them)
            firsts = {submit(ex, c, a, w) for c, a, w in runs}
            pending = set(firsts)
            while pending:
                finished, pending = wait(pending, return_when=FIRST_COMPLETED)
                for fut in finished:
                    out = fut.result()
                    task = extra.pop(fut, None)
                    if task is not None and task[0] == "bridge":
                        follow.record_bridge(out)
                        continue
                    out, w = out  # a run and the work its worker counted
                    work.merge(w)
                    if task is not None:  # a follow-up run
                        if task[0] == "speculate":
                            follow.speculated(task[1], out)
                        else:
                            follow.record(out, progress, task[1])
                        continue
                    for kk, Vk, rec in out:
                        results[kk] = (Vk, rec)
                        done += 1
                        progress.advance(stage, done, total, text=_frame_text(rec))
                if follow is not None:
                    for r in follow.ready(results):
                        fut = submit(ex, *r, kind="continued")
                        extra[fut] = ("continue", tuple(int(k) for k in r[0]))
                        pending.add(fut)
                    follow.settle(progress)
                    # an idle worker starts a gap's continuation before the gap's other
                    # run is done
                    for task in follow.speculate(results, workers - len(pending)):
                        fut = ex.submit(_worker_speculate, task)
                        extra[fut] = ("speculate", task[1])
                        pending.add(fut)
                    # a finished gap's bridge while other work is still on the pool (the
                    # last gap's is bridged after it, split over the workers)
                    if method == "fork" and pending:
                        for task in follow.bridges_ready(results, pinned):
                            fut = ex.submit(_worker_bridge, task)
                            extra[fut] = ("bridge", task[1])
                            pending.add(fut)
        if follow is not None:
            follow.count_speculation(work)
    finally:
        _WORKER.pop("gn", None)
        _WORKER.pop("frame_data", None)
        _WORKER.pop("gate", None)
        if follow is not None:
            follow.gate = None
    return results


def safe_init(blend, Vkey, frames, K, bc, T, min_ratio=1e-3):
    """The keyframe blend as initial guess, except for frames where the blend collapses
    triangles (e.g. a half-turn between keyframes): those start from the nearer keyframe."""
    F = T.F

    def areas(Vs):
        return 0.5 * np.linalg.norm(face_normals(Vs, F), axis=-1)

    a_key = areas(Vkey).mean(axis=0)
    out = blend
    j0, j1, t = keyframe_bracket(np.asarray(frames), K, bc == "periodic")
    for i in range(0, K + 1, 8):
        bad = (areas(blend[i:i + 8]) < min_ratio * a_key).any(axis=1)
        for k in np.flatnonzero(bad) + i:
            if out is blend:
                out = blend.copy()
            out[k] = Vkey[j0[k] if t[k] <= 0.5 else j1[k]]
    return out


def reconstruct_frames(T, ks, Z, W_of, Vinit, pinned, *, frames, K, periodic, gn_options,
                       workers, warm, prog, stage_prefix="", bridge=True,
                       pop_defects=POP_DEFECTS, tube_of=None, resume: int = RESUME_ITER,
                       work=None):
    """The reconstruction stage: frames ``ks`` in runs from the keyframes
    (:func:`reconstruction_runs`), then, with ``warm="extrapolate"``, the continuation pass
    of :func:`continued_runs`, then :func:`resume_steady` (``resume`` more iterations for
    frames stopped at their limit while still converging steadily; 0: none).

    Parameters
    ----------
    T : Topology
    ks : (r,) int array
        The frames to reconstruct (the in-betweens).
    Z : (K+1,d) float64 array, or anything whose rows ``Z[idx]`` are the targets
        Target descriptors.
    W_of : callable(int) -> (d,) float64 array
        Weights of frame ``k``.
    Vinit : (K+1,n,3) float64 array
        Initial sequence (keyframes at their frames).
    pinned : (p,) int array or None
    frames : (J,) int array
    K : int
    periodic : bool
    gn_options : dict
        Options of :class:`~shellspline.shells.reconstruct.GaussNewton`.
    workers : int
    warm : {"extrapolate", "delta", False}
        See :func:`solve_run`.
    prog : Progress
    stage_prefix : str
        Prefix of the progress stage names (``"coarse "``, ``"fine "``).
    bridge : bool
        Re-solve the frames around each seam jointly (:func:`bridge_seams`).
    pop_defects : int
        What a pop counts in the bridges' keep rule (:func:`bridge_kept`).
    tube_of : callable(int) -> (i,) float64 array, optional
        Tube weights of frame ``k``'s dihedral angles
        (:func:`~shellspline.pipeline.describe.tube_weights`).
    resume : int
        Budget of :func:`resume_steady`.
    work : GaussNewtonWork, optional
        Counts all the stage's Gauss–Newton solves, kept or not, by kind (the records count
        each frame's kept solve only).

    Returns
    -------
    dict
        ``{k: (V (n,3) float64 array, record dict)}``; frames replaced by the continuation
        have ``record["continued"] = True``, resumed frames ``record["resumed"] = True``; the first frame after a jump between the two runs
        of a gap (:func:`seam_records`) has ``record["seam_jump"]``, the step there over the
        typical step next to it.
    """
    work = GaussNewtonWork() if work is None else work
    runs = reconstruction_runs(ks, frames, K, periodic)
    stage = stage_prefix + "reconstruct"
    # the continuation of a gap starts on the pool as soon as its two runs are solved
    from .bridge import BRIDGE_HALF

    # seams bridged on the pool as their gaps finish (not above LARGE_MESH: a bridge's
    # factors there are too large to hold next to another worker's)
    early = (K, BRIDGE_HALF, gn_options) if bridge and T.n_vertices <= LARGE_MESH else None
    follow = GapContinuations(runs, Vinit, stage_prefix + "reconstruct (continue)",
                              bridge=early) if warm == "extrapolate" else None
    with prog.stage(stage, total=len(ks)):
        results = run_reconstruction(T, ks, Z, W_of, Vinit, pinned, gn_options, workers, prog,
                                     warm, stage=stage, runs=runs, tube_of=tube_of,
                                     follow=follow, work=work)
    if warm != "extrapolate":
        resume_steady(T, results, Z, W_of, pinned, gn_options, workers, prog, stage_prefix,
                      tube_of, resume, work=work)
        return results
    again = [t for t in continued_runs(runs, results, Vinit)
             if tuple(int(k) for k in t[0]) not in follow.submitted]
    stage = stage_prefix + "reconstruct (continue)"
    with prog.stage(stage, total=sum(len(r) for r, _, _ in again)):
        better = run_reconstruction(T, np.concatenate([r for r, _, _ in again]) if again
                                    else np.zeros(0, int), Z, W_of, Vinit, pinned, gn_options,
                                    workers, prog, warm, stage=stage, runs=again,
                                    tube_of=tube_of, work=work, kind="continued")
    better = {**follow.results, **better}
    for kk, (Vk, rec) in better.items():
        work.move(results[kk][1], "first_pass", "replaced")
        rec["continued"] = True
        results[kk] = (Vk, rec)
    resume_steady(T, results, Z, W_of, pinned, gn_options, workers, prog, stage_prefix, tube_of,
                  resume, work=work)
    seams = seam_records(runs, results, Vinit, pinned)
    for seam in seams:
        results[seam["frame"]][1]["seam_jump"] = seam["jump"]
    taken = set()
    if bridge and seams:
        taken = bridge_seams(T, seams, results, Z, W_of, Vinit, pinned, gn_options, K, prog,
                             stage_prefix, workers, pop_defects, tube_of, early=follow.bridged,
                             work=work)
    for s, done in follow.bridged.items():
        if s not in taken and done[3] is not None:  # bridged on the pool, then not used
            work.add("bridge_discarded", done[3].summary())
    return results


def bridge_seams(T, seams, results, Z, W_of, Vinit, pinned, gn_options, K, prog,
                 stage_prefix="", workers=1, pop_defects=POP_DEFECTS, tube_of=None,
                 early=None, work=None) -> set:
    """Re-solve the frames around each seam jointly (:func:`~.bridge.bridge_seam`) and
    replace them in ``results`` (in place) where that removes the jump without a new defect.

    A bridge is kept when the window's largest step over its mean step drops and the window
    has no more defects (flipped faces, folded edges and collapsed faces together) than before
    (:class:`~shellspline.shells.defects.DefectRules`, with the gap's keyframes). Kept, the
    bridged frames' records get ``"bridged"`` (the seam's frame) and the joint solve's status,
    message and their own energies. The seam's frame record gets ``"bridge"``: the joint
    solve's summary, ``"kept"``, the window's step ratio and defect counts before and after
    (its ``"seam_jump"`` is the jump before bridging). Seams are bridged on ``workers`` forked
    processes when there are several. Above
    :data:`~shellspline.shells.reconstruct.LARGE_MESH` vertices a bridge holds one sparse
    factor per window frame (about 1.6 GB each at 155k vertices), so large meshes bridge one
    frame on each side of the seam, one seam at a time (horse, 1 instead of 2 frames a side:
    pop 1.35 instead of 1.14). ``early``: ``{s: (s, a, b, BridgeResult, before, after)}``,
    seams already bridged on the reconstruction's pool (:class:`GapContinuations`), taken
    as they are where the seam and its gap are the same. ``work``: a
    :class:`GaussNewtonWork` counting each joint solve as ``"bridge"`` or
    ``"bridge_discarded"`` (not kept). Returns the seam frames of the ``early`` bridges
    taken.
    """
    work = GaussNewtonWork() if work is None else work
    from ..parallel import process_pool, start_method
    from .bridge import BRIDGE_HALF

    def frame_of(k):
        return results[k][0] if k in results else Vinit[k]

    tasks = []
    for seam in seams:
        s = seam["frame"]
        a = s - 1
        while a in results:
            a -= 1
        b = s
        while b in results:
            b += 1
        tasks.append((s, a, b))
    stage = stage_prefix + "bridge seams"
    large = T.n_vertices > LARGE_MESH
    half = 1 if large else BRIDGE_HALF
    # a bridge run here (one seam, or a large mesh) shares its window's frames with a forked
    # worker where the frames are worth it
    split = workers > 1 and 2 * half * T.n_vertices >= SPLIT_BRIDGE_WORK
    workers = 1 if large else workers
    _WORKER["bridge"] = (T, frame_of, K, Z, W_of, pinned, gn_options, half, tube_of)
    try:
        with prog.stage(stage, total=len(tasks)):
            early = {t[0]: early[t[0]] for t in tasks
                     if early and t[0] in early and early[t[0]][:3] == t}
            todo = [t for t in tasks if t[0] not in early]
            if workers > 1 and len(todo) > 1 and start_method() == "fork":
                with process_pool(min(workers, len(todo)), _blas_worker_init,
                                  method="fork") as ex:
                    done = list(ex.map(_bridge_one, [t + (False,) for t in todo]))
            else:
                limiter = single_blas_thread()
                try:
                    done = [_bridge_one(t + (split,)) for t in todo]
                finally:
                    if limiter is not None:
                        limiter.restore_original_limits()
            done = sorted(done + list(early.values()), key=lambda d: d[0])
            for i, (s, _, _, br, before, after) in enumerate(done):
                if br is None:
                    continue
                keep = bridge_kept(br, before, after, pop_defects)
                work.add("bridge" if keep else "bridge_discarded", br.summary())
                if keep:
                    for k, Vk, e in zip(br.frames, br.V, br.energies):
                        rec = dict(results[int(k)][1])
                        rec.update(status=br.status, success=br.status == "converged",
                                   energy_final=float(e), bridged=int(s),
                                   message=f"bridged: {br.message}")
                        results[int(k)] = (Vk, rec)
                results[s][1]["bridge"] = dict(
                    br.summary(), kept=bool(keep), step_ratio_before=before[0],
                    step_ratio_after=after[0],
                    defects_before=dict(zip(("flipped", "folded", "collapsed"),
                                            before[1].tolist())),
                    defects_after=dict(zip(("flipped", "folded", "collapsed"),
                                           after[1].tolist())))
                prog.advance(stage, i + 1, len(tasks),
                             text=f"seam at frame {s}: {br.status}, {br.iterations} it, "
                                  f"step ratio {before[0]:.2f} -> {after[0]:.2f}"
                                  f"{'' if keep else ' (not kept)'}")
    finally:
        _WORKER.pop("bridge", None)
    return set(early)


def bridge_kept(br, before, after, pop_defects: int = POP_DEFECTS) -> bool:
    """Whether a bridge replaces its window's frames: it did not fail, the window's largest
    step over its mean step dropped, and the window's defects did not grow: its flipped,
    folded and collapsed elements, and ``pop_defects`` (:data:`POP_DEFECTS`) more where that
    step ratio is above :data:`SEAM_POP`.

    ``before``/``after``: ``(step ratio, (3,) defect counts)`` of the window
    (:func:`_window_check`)."""
    def count(check):
        return int(check[1].sum()) + pop_defects * int(check[0] > SEAM_POP)
    return br.status != "failed" and after[0] < before[0] and count(after) <= count(before)


def _blas_worker_init():
    _WORKER["blas"] = single_blas_thread()


def _bridge_one(task):
    """Bridge one seam ``(s, a, b, split)`` (the data in ``_WORKER["bridge"]``; ``split``:
    see :meth:`~.bridge.SeamBridge.solve`): ``(s, a, b, BridgeResult or None, before,
    after)`` (:func:`_bridge_seam_checked`)."""
    s, a, b, split = task
    T, frame_of, K, Z, W_of, pinned, gn_options, half, tube_of = _WORKER["bridge"]
    gn = GaussNewton(T, pinned=pinned, **gn_options)
    return (s, a, b) + _bridge_seam_checked(gn, frame_of, K, s, a, b, Z, W_of, half, tube_of,
                                            split)


def _bridge_seam_checked(gn, frame_of, K, s, a, b, Z, W_of, half, tube_of, split):
    """Bridge the seam at ``s`` of the gap ``(a, b)`` and measure its window before and
    after (:func:`_window_check`): ``(BridgeResult or None, before, after)``."""
    from .bridge import BRIDGE_MAX_ITER, bridge_seam

    T = gn.T
    pinned = gn.pinned if gn.pinned.size else None
    # a lower limit on the frames (the user's --max-iter) holds for their bridge too
    br = bridge_seam(gn, frame_of, K, s, a, b, Z, W_of, half=half, tube_of=tube_of,
                     max_iter=min(BRIDGE_MAX_ITER, gn.max_iter), split=split)
    if br is None:
        return None, None, None
    new = dict(zip(br.frames.tolist(), br.V))

    def bridged(k):
        return new[k] if k in new else frame_of(k)

    win = list(range(max(a, int(br.frames[0]) - 2), min(b, int(br.frames[-1]) + 2) + 1))
    return (br, _window_check(T, win, a, b, frame_of, pinned),
            _window_check(T, win, a, b, bridged, pinned))


def _window_check(T, win, a, b, frame_of, pinned):
    """The largest step of the frames ``win`` (consecutive, inside the gap ``[a, b]``) over
    their mean step (each pair placed rigidly, see :func:`seam_jump`), and the flipped,
    folded and collapsed counts of those steps (3,) by the gap's keyframe rules."""
    from ..shells.defects import DefectRules

    Vs = np.stack([frame_of(k) for k in win])
    pin = pinned is not None and len(pinned)

    def step(A, B):
        A = A if pin else rigid_placement(A, B)
        return float(np.sqrt(np.einsum("ij,ij->i", A - B, A - B).max()))

    steps = np.array([step(Vs[i + 1], Vs[i]) for i in range(len(win) - 1)])
    ratio = float(steps.max() / steps.mean()) if steps.mean() > 0 else 1.0
    # the gap's keyframes first and last, the window between (its steps only are scanned)
    seq = np.concatenate([frame_of(a)[None], Vs, frame_of(b)[None]])
    keys = [0, len(seq) - 1]
    rules = DefectRules(seq[keys], T, keys, len(seq) - 1)
    d = rules.scan(seq, np.arange(1, len(win)))
    return ratio, np.array([len(d["flipped"]), len(d["folded"]), len(d["collapsed"])])


#: A seam between the two runs of a keyframe gap whose step is more than this many times the
#: typical step next to it is a switch between two local minima of the reconstruction (see
#: :func:`seam_records`); the same bound as the pop target of issue 13.
SEAM_POP = 1.5

#: :func:`seam_records` records (and :func:`bridge_seams` bridges) a seam whose step is above
#: this many times the typical step next to it. Lower than :data:`SEAM_POP`: the pop of the
#: quality check compares a step with the sequence's median step, a seam's jump with the
#: steps right next to it, which are often larger near a keyframe (horse-reference → 05 → 09
#: at frames 0, 20, 40: a jump of 1.49 by this measure was a pop of 1.72 in the output, and
#: was not bridged).
SEAM_DETECT = 1.25


#: A step across a seam below this fraction of the frame's bounding-box diagonal is
#: round-off, not a jump (:func:`seam_jump`): identical keyframes aligned rigidly differ by
#: ~1e-16, and the ratio of such steps bridged a "seam" whose joint solve could only reach
#: its iteration limit (frames reported unconverged, exit 1).
SEAM_ROUNDOFF = 1e-10


def seam_jump(V_before2, V_before, V_after, V_after2, pinned=None) -> float:
    """The step across a seam over the typical step next to it.

    Parameters
    ----------
    V_before2, V_before : (n,3) float64 arrays
        The two frames before the seam, on the run that ends there.
    V_after, V_after2 : (n,3) float64 arrays
        The two frames after it, on the run that starts there.
    pinned : (p,) int array, optional
        Pinned vertices (then no frame is moved rigidly before comparing).

    Returns
    -------
    float
        ``max_i |V_after,i − V_before,i|`` over the mean of the same quantity for the steps
        ``V_before2 → V_before`` and ``V_after → V_after2``, each frame first placed rigidly
        onto the one it is compared with (the reconstruction leaves rigid motions free); 1 for
        a seam as smooth as its neighbours.
    """
    def step(A, B):
        if pinned is None or not len(pinned):
            A = rigid_placement(A, B)
        return float(np.sqrt(np.einsum("ij,ij->i", A - B, A - B).max()))

    typical = 0.5 * (step(V_before2, V_before) + step(V_after2, V_after))
    jump = step(V_after, V_before)
    # steps at round-off (one shape held: keyframes equal up to a rigid motion) are no seam
    size = float(np.linalg.norm(np.ptp(np.asarray(V_before, dtype=np.float64), axis=0)))
    if jump <= SEAM_ROUNDOFF * size:
        return 1.0
    return jump / typical if typical > 0 else np.inf


def seam_records(runs, results, Vinit, pinned=None) -> list:
    """Where the two runs of a keyframe gap meet in different local minima.

    The reconstruction of one frame has several local minima on real meshes, and the run
    from each keyframe of a gap can follow its own family of them all the way across. On
    the horse (8.4k vertices, keyframes horse-reference and horse-03 at frames 0 and 20) the
    run from frame 0 keeps the hind leg's skin fold unformed and reaches frame 19 at energy
    0.10 (0.0002 from frame 20); the run from frame 20 keeps it folded and reaches frame 1
    at 0.061 (0.0004 from frame 0); the two differ by 17–35 % of the bounding-box diagonal
    in every frame, and the energy of each grows like the square of the distance to its
    keyframe. Neither a stiffer bending weight (10x, 100x, or a homotopy 1000x → 1x), nor a
    start from the keyframe blend, nor following the descriptor path between the two runs'
    own shapes from one end joins them: every sequence of minimisers jumps somewhere
    between the keyframes, and :func:`continued_runs` puts the jump where the two energies
    cross. A cross-fade of the two runs over a few frames removes the jump (horse pair: pop
    7.9 → 1.1, flipped faces 4 → 0) but passes skin folds through each other (folded edges
    0 → 6; the flexing joint of ``data_synth.stress``: 0 → 10, the same with a rotation-aware
    blend); it is not done. :func:`bridge_seams` re-solves the frames around the seam
    jointly instead, with a small acceleration penalty.

    Parameters
    ----------
    runs : list
        The first-pass runs (:func:`reconstruction_runs`).
    results : dict
        ``{k: (V, record)}`` after the continuation pass.
    Vinit : (K+1,n,3) float64 array
        Initial sequence (the keyframes at their frames).
    pinned : (p,) int array, optional

    Returns
    -------
    list of dict
        One ``{"frame": s, "jump": ratio}`` per keyframe gap whose runs meet with a step
        ``V[s−1] → V[s]`` above :data:`SEAM_DETECT` times the typical step next to it
        (:func:`seam_jump`); ``s`` is the first frame of the gap taken from the backward run.
    """
    fwd_of = {int(r[-1]): (r, a) for r, a in runs if len(r) and r[0] > a}
    out = []
    for rb, b in runs:
        if not len(rb) or rb[0] > b or int(rb[-1]) - 1 not in fwd_of:
            continue
        rf, a = fwd_of[int(rb[-1]) - 1]
        # the sequence takes the forward run up to the seam and the backward run from it
        # on; a continued run moved the seam into the other half
        back = [k for k in range(a + 1, b)
                if (results[k][1].get("continued") and k in rf) or
                (not results[k][1].get("continued") and k in rb)]
        if not back or back[0] == a + 1:
            continue
        s = back[0]

        def at(k):
            return Vinit[k] if k in (a, b) else results[k][0]

        ratio = seam_jump(at(max(s - 2, a)), at(s - 1), at(s), at(min(s + 1, b)), pinned)
        if ratio > SEAM_DETECT:
            out.append({"frame": int(s), "jump": float(ratio)})
    return out

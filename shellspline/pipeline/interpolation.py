"""The interpolation pipeline: the only place that knows the order of the stages.

``describe → solve → reconstruct → place`` for ``method="lta"`` (paper §7), or per-vertex
linear blending for ``method="linear"`` (the naive baseline). See ``ARCHITECTURE.md``.
"""
from __future__ import annotations

import os
import platform
import time
from dataclasses import dataclass, field

import numpy as np

from ..version import __version__
from ..errors import ShellsplineError
from ..progress import Progress
from ..shells.descriptors import consistent_angles, lta_descriptors, lta_weights, unwrap_angles
from ..io.keyframes import Keyframes, keyframes_from_arrays, read_keyframes
from ..shells.lta_spline import lta_energy_per_frame, lta_spline
from ..shells.reconstruct import GaussNewton, rigid_placement
from ..timeline import keyframe_bracket
from ..mesh.topology import Topology, topology

__all__ = ["interpolate", "InterpolationResult", "METHODS", "BOUNDARY_CONDITIONS", "REFERENCES",
           "canonical_frames", "linear_blend", "placement_track", "sequence_quality",
           "quality_ok", "POP_LIMIT", "RIGID_TRACKS"]

#: Below this many vertex-frames the Gauss–Newton reconstruction runs in this process even
#: with ``workers > 1``: starting a pool costs more than the work (cactus γ = 0.05, K = 20:
#: 263 coarse vertices × 18 frames, 0.11 s in-process against 0.19 s with two workers).
SERIAL_RECONSTRUCT_WORK = 20_000
#: The same for the prolongation decode (cheaper per vertex-frame): the 5.2k-vertex cactus,
#: K = 20, decodes in 0.08 s in-process and 0.10 s with two workers.
SERIAL_DECODE_WORK = 250_000

METHODS = ("lta", "linear", "geodesic", "nonlinear")
BOUNDARY_CONDITIONS = ("natural", "periodic", "hermite")
REFERENCES = ("constant", "keyframe", "geodesic")
DEFAULT_STEP = 10
MAX_FRAMES = 1_000_000
FULL_RESOLUTION_WARN = 50_000


@dataclass
class InterpolationResult:
    """What :func:`interpolate` returns.

    Attributes
    ----------
    V : (K+1,n,3) float64 array
        The sequence; ``V[frames[j]]`` is keyframe ``j`` bit for bit.
    F : (m,3) int64 array
    frames : (J,) int64 array
        Keyframe frames.
    report : dict
        JSON-friendly record: parameters, per-stage wall times, per-frame Gauss–Newton records,
        energies and quality checks.
    Z : (K+1,d) float64 array or None
        Target LΘA descriptors of every frame (``method="lta"``).
    source : SourceMesh or None
        The keyframes' :attr:`~shellspline.io.Keyframes.source`: how ``V`` and ``F`` (the
        solve mesh) map back to the input's vertices and polygons
        (``source.expand(V, frames, K, bc)``); ``None`` for a clean triangle mesh.
    """

    V: np.ndarray
    F: np.ndarray
    frames: np.ndarray
    report: dict = field(default_factory=dict)
    Z: np.ndarray | None = None
    source: object | None = None

    @property
    def K(self) -> int:
        return int(self.V.shape[0] - 1)


def _canonical_choice(value, name, choices):
    v = str(value).strip().lower()
    if v not in choices:
        raise ShellsplineError(f"`{name}` must be one of {', '.join(map(repr, choices))}, "
                               f"got {value!r}")
    return v


def canonical_frames(J: int, frames=None, K=None, bc: str = "natural"):
    """Canonical keyframe frames and last frame index ``K``.

    Parameters
    ----------
    J : int
        Number of keyframes.
    frames : (J,) int array, optional
        Keyframe frames; default: evenly spaced over ``[0, K]`` (``[0, K)`` when periodic),
        or every ``10`` frames when ``K`` is not given either.
    K : int, optional
        Last frame; default: the last keyframe's frame (periodic: one keyframe gap later).
    bc : str

    Returns
    -------
    frames : (J,) int64 array
    K : int

    Examples
    --------
    >>> canonical_frames(3)
    (array([ 0, 10, 20]), 20)
    >>> canonical_frames(3, K=12, bc="periodic")
    (array([0, 4, 8]), 12)
    """
    periodic = bc == "periodic"
    if frames is None:
        if bc == "hermite":
            raise ShellsplineError("bc='hermite' needs explicit `frames`: the poses at frames 1 "
                                   "and K-1 fix the end velocities")
        if K is None:
            frames = DEFAULT_STEP * np.arange(J)
            K = int(frames[-1] + (DEFAULT_STEP if periodic else 0))
        else:
            K = int(K)
            if K < 1 or K > MAX_FRAMES:
                raise ShellsplineError(f"`K` must lie in [1, {MAX_FRAMES}], got {K}")
            if periodic:
                frames = np.round(np.arange(J) * K / J).astype(np.int64)
            else:
                frames = np.round(np.linspace(0, K, J)).astype(np.int64)
            if len(np.unique(frames)) != J:
                raise ShellsplineError(f"`K`={K} is too small for {J} keyframes")
    frames = np.asarray(frames)
    if frames.ndim != 1 or len(frames) != J:
        raise ShellsplineError(f"`frames` must have one entry per keyframe ({J}), got "
                               f"{frames.tolist()}")
    if not np.all(np.isfinite(frames)) or not np.all(frames == np.round(frames)):
        raise ShellsplineError(f"`frames` must be integers, got {frames.tolist()}")
    frames = frames.astype(np.int64)
    if np.any(np.diff(frames) <= 0):
        raise ShellsplineError(f"`frames` must be strictly increasing, got {frames.tolist()}")
    if frames[0] != 0:
        raise ShellsplineError(f"`frames` must start at 0, got {frames.tolist()}")
    if K is None:
        K = int(frames[-1] + ((frames[-1] - frames[-2]) if periodic else 0))
    K = int(K)
    if K < 1 or K > MAX_FRAMES:
        raise ShellsplineError(f"`K` must lie in [1, {MAX_FRAMES}], got {K}")
    if periodic and frames[-1] >= K:
        raise ShellsplineError(f"with bc='periodic' the keyframes must lie before `K`={K} (frame K "
                               f"is frame 0 again), got frames {frames.tolist()}")
    if frames[-1] > K:
        raise ShellsplineError(f"`K`={K} is smaller than the last keyframe frame {int(frames[-1])}")
    return frames, K


def linear_blend(Vkey, frames, K, bc: str = "natural"):
    """Per-vertex linear blending of keyframes: the naive baseline.

    Parameters
    ----------
    Vkey : (J,n,3) float64 array
    frames : (J,) int array
    K : int
    bc : str
        ``"periodic"`` blends the last keyframe back into the first at frame ``K``.

    Returns
    -------
    (K+1,n,3) float64 array; keyframes are reproduced exactly, and so is any coordinate that is
    equal in the two bracketing keyframes. Frames after the last keyframe (non-periodic) hold
    the last keyframe.
    """
    Vkey = np.asarray(Vkey, dtype=np.float64)
    j0, j1, t = keyframe_bracket(np.asarray(frames), K, bc == "periodic")
    A, B = Vkey[j0], Vkey[j1]
    out = (1.0 - t)[:, None, None] * A + t[:, None, None] * B
    out = np.where(A == B, A, out)  # a vertex that does not move stays bit-identical
    for j, f in enumerate(frames):
        out[f] = Vkey[j]
    if bc == "periodic":
        out[K] = Vkey[0]
    return out


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
        return _tri_normals(Vs, F)

    def norms(N):
        return np.sqrt(np.einsum("kmi,kmi->km", N, N))

    a_ref = (0.5 * norms(normals(V[np.asarray(frames)]))).mean(axis=0)
    a_ref = np.maximum(a_ref, 1e-300)
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


def _quality(V, T: Topology, frames, bc, Vkey) -> dict:
    """The report's quality record: new defects (flipped and collapsed faces, folded edges,
    pops; :func:`shellspline.metrics.sequence_defects`), with a per-frame record and the
    worst frames, the older counts of :func:`sequence_quality`, and keyframe exactness."""
    from ..metrics import sequence_defects

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


# -- parallel reconstruction -----------------------------------------------------------------
_WORKER: dict = {}


def _single_blas_thread():
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

    _WORKER["blas"] = _single_blas_thread()
    if "gn" not in _WORKER:  # forked workers inherit the parent's prepared solver
        _WORKER["gn"] = GaussNewton(topology(F, n), pinned=pinned, **gn_options)


def _solve_run(gn: GaussNewton, ks, Zs, Ws, Vinit, Vanchor, warm, on_frame=None,
               worse_than=None):
    """Reconstruct a run of consecutive frames, in the run's order (see :func:`_runs`).

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
    whose energy is not below it, and that frame is not returned (see :func:`_continued`).
    """
    out = []
    gn.reset()  # a run's result does not depend on which runs this solver did before, so
    # one worker and several give the same sequence
    if isinstance(Vanchor, tuple):
        prev2, prev = Vanchor
        prev_init = prev
    else:
        prev2, prev, prev_init = None, Vanchor, Vanchor
    for i, (k, z, w, v) in enumerate(zip(ks, Zs, Ws, Vinit)):
        t0 = time.perf_counter()
        v0 = v
        if warm and prev is not None:
            vw = 2.0 * prev - prev2 if prev2 is not None and warm == "extrapolate" else \
                prev + (v - prev_init)
            # a start must leave every triangle above the line search's floor
            if np.all(np.isfinite(vw)) and np.all(
                    0.5 * np.linalg.norm(_tri_normals(vw, gn.T.F), axis=-1)
                    > 1e-6 * np.maximum(z[gn.T.descriptor_slices()[2]], 0.0)):
                v = vw
        r = gn.solve(z, w, v)
        if worse_than is not None and not r.energy < (1.0 - CONTINUE_MARGIN) * worse_than[i]:
            break
        prev2, prev, prev_init = prev, r.V, v0
        rec = r.summary()
        rec["frame"] = int(k)
        rec["seconds"] = time.perf_counter() - t0
        out.append((int(k), r.V, rec))
        if on_frame is not None:
            on_frame(i + 1, rec)
    return out


def _frame_text(rec) -> str:
    """One progress line for a reconstructed frame (logs get one per frame)."""
    return (f"frame {rec['frame']:4d}: {rec['status']:<9s} {rec['nit']:3d} it  "
            f"E {rec['energy_final']:.3g}")


#: A continued run replaces a first-pass frame only when its energy is lower by this fraction
#: (equal minima differ at solver tolerance; without a margin the choice was decided by
#: round-off and differed between one and two workers).
CONTINUE_MARGIN = 1e-3


def _continued(runs, results, Vinit):
    """Second pass over each keyframe gap solved from both ends (see :func:`_runs`).

    The runs from the two keyframes of a gap can settle into different local minima of the
    reconstruction (the horse: frame 10 at energy 0.075 from keyframe 0, frame 11 at 0.011
    from keyframe 20; a jump where they meet). The run whose frame at the meeting point has
    the lower energy is continued into the other half, frame by frame, for as long as it
    finds lower energies there than the first pass did.

    Returns the continuation runs ``(frames, (V[k∓2], V[k∓1]), energies to beat)`` for
    :func:`_run_reconstruction`.
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
        if ef <= eb:   # continue the forward run into the backward half
            frames_, seq, anchor_ = r[::-1], rf, af
        else:          # continue the backward run into the forward half
            frames_, seq, anchor_ = rf[::-1], r, a
        V1 = results[int(seq[-1])][0]
        V2 = results[int(seq[-2])][0] if len(seq) >= 2 else Vinit[anchor_]
        tasks.append((frames_, (V2, V1),
                      np.array([results[int(k)][1]["energy_final"] for k in frames_])))
    return tasks


def _runs(ks, frames, K, periodic):
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


def _worker_solve(task):
    if isinstance(task, tuple) and len(task) == 4 and task[0] == "inherited":
        # forked worker: the frame data are the parent's arrays, inherited (no copies)
        _, ks, anchor, worse = task
        Z, W_of, Vinit, warm = _WORKER["frame_data"]
        return _solve_run(_WORKER["gn"], ks, [Z[k] for k in ks], [W_of(k) for k in ks],
                          [Vinit[k] for k in ks], _anchor(anchor, Vinit), warm,
                          worse_than=worse)
    return _solve_run(_WORKER["gn"], *task)


def _anchor(anchor, Vinit):
    """A run's anchor: the frame index of its keyframe, or a pair of solved frames."""
    return anchor if isinstance(anchor, tuple) else Vinit[anchor]


def _decode_worker(task):
    Vc, frames, K, bc, ks = task
    return ks, _WORKER["prolong"].decode(Vc, frames, K, time_weights="linear", bc=bc,
                                         only=ks)[ks]


def _parallel_decode(P, Vc, frames, K, bc, workers):
    """Prolongation of every frame; frames split over ``workers`` forked processes (they share
    the parent's factorization; without fork, or with one worker, it runs here)."""
    from concurrent.futures import as_completed

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


def _keyframe_angles(Theta, periodic):
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


class _AngleBand:
    """Keeps the spline's dihedral-angle targets off ±π between keyframes that are not there.

    A spline through angles near ±π overshoots between its keyframes; a target beyond ±π asks
    the reconstruction to pass the edge's triangles through each other (a fold the keyframes
    do not have). In every keyframe gap each angle is clipped to ``[−π + m, π − m]`` widened
    to the two keyframe values themselves (so keyframes held past ±π, see
    :func:`~shellspline.shells.descriptors.consistent_angles`, and the path between them stay as they
    are), with the margin ``m`` = :data:`ANGLE_MARGIN`. Edges away from ±π are untouched.
    """

    def __init__(self, Tkey, sT, frames, K, periodic):
        Tkey = np.asarray(Tkey, dtype=np.float64)
        ext = np.concatenate([Tkey, Tkey[:1]]) if periodic else Tkey
        j0, _, _ = keyframe_bracket(frames, K, periodic)
        self.sT = sT
        self.lo = np.minimum(np.minimum(ext[:-1], ext[1:]), -np.pi + ANGLE_MARGIN)  # per gap
        self.hi = np.maximum(np.maximum(ext[:-1], ext[1:]), np.pi - ANGLE_MARGIN)
        self.gap = np.minimum(j0, len(ext) - 2)

    def __call__(self, Z, k=None):
        """Clip the angle part of targets ``Z`` ((K+1, d), or rows ``k`` of them)."""
        Z = np.array(Z, dtype=np.float64, copy=True)
        g = self.gap if k is None else self.gap[k]
        Z[..., self.sT] = np.clip(Z[..., self.sT], self.lo[g], self.hi[g])
        return Z


#: Margin (radians) between a clipped angle target and ±π (see :class:`_AngleBand`).
ANGLE_MARGIN = 0.02


class _SplineRows:
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


def _chunks(idx, n_chunks):
    n_chunks = max(1, min(n_chunks, len(idx)))
    return [c for c in np.array_split(np.asarray(idx), n_chunks) if len(c)]


def _run_reconstruction(T, ks, Z, W_of, Vinit, pinned, gn_options, workers, progress, warm,
                        stage="reconstruct", runs=None):
    """Reconstruct frames ``ks`` (in ``runs``, see :func:`_runs`; default one run per frame
    anchored at its predecessor) serially or on ``workers`` processes."""
    results = {}
    total = len(ks)
    if runs is None:
        runs = [(np.array([k]), max(int(k) - 1, 0)) for k in ks]
    runs = [r if len(r) == 3 else (*r, None) for r in runs]
    if total == 0:
        return results
    if workers <= 1 or total == 1 or T.n_vertices * total < SERIAL_RECONSTRUCT_WORK:
        limiter = _single_blas_thread()
        try:
            gn = GaussNewton(T, pinned=pinned, **gn_options)
            for run, anchor, worse in runs:
                done = len(results)
                for kk, Vk, rec in _solve_run(gn, run, Z[run], [W_of(k) for k in run],
                                              Vinit[run], _anchor(anchor, Vinit), warm,
                                              lambda i, rec: progress.advance(
                                                  stage, done + i, total,
                                                  text=_frame_text(rec)), worse):
                    results[kk] = (Vk, rec)
        finally:
            if limiter is not None:
                limiter.restore_original_limits()
        return results
    # runs of neighbouring (similar) frames on one worker keep its cached preconditioner and
    # warm starts good
    from concurrent.futures import as_completed

    from ..parallel import process_pool, start_method

    method = start_method()
    if method == "fork":
        # build the assembly pattern once here; the forked workers inherit it, and the frame
        # data (targets, weights, initial guesses): tasks then carry only frame indices, so
        # no chunk is copied, pickled and unpickled (at 150k vertices and K=50 that saved
        # ~3 GB across the parent and two workers)
        gn = GaussNewton(T, pinned=pinned, **gn_options)
        gn._assembler()
        gn._dof_order(Vinit[ks[0]])  # fill-reducing order (large meshes), also inherited
        _WORKER["gn"] = gn
        _WORKER["frame_data"] = (Z, W_of, Vinit, warm)
    done = 0
    try:
        with process_pool(workers, _worker_init, (T.F, T.n_vertices, pinned, gn_options),
                          method) as ex:
            # one task per run (runs start next to a keyframe; the pool balances them)
            futs = [ex.submit(_worker_solve, ("inherited", c, a, w) if method == "fork" else
                              (c, Z[c], np.stack([W_of(k) for k in c]), Vinit[c],
                               _anchor(a, Vinit), warm, None, w))
                    for c, a, w in runs]
            for fut in as_completed(futs):
                for kk, Vk, rec in fut.result():
                    results[kk] = (Vk, rec)
                    done += 1
                    progress.advance(stage, done, total, text=_frame_text(rec))
    finally:
        _WORKER.pop("gn", None)
        _WORKER.pop("frame_data", None)
    return results


def interpolate(keyframes, K=None, method: str = "lta", bc: str = "natural", eta: float = 1e-3,
                mu: float = 1.0, lam: float = 1.0, reference="constant", *, frames=None,
                pinned=None, workers: int = 1, gn_options: dict | None = None,
                warm_start: bool = True, solver_options: dict | None = None,
                coarse="auto", fine: bool = False, fixpoint: int = 0,
                rigid_track: str = "fit", progress=None) -> InterpolationResult:
    """Interpolate keyframe poses of one triangle mesh by a spline in shell space.

    Parameters
    ----------
    keyframes : Keyframes, sequence of paths, or (J,n,3) array with ``F`` via ``(V, F)`` tuple
        The keyframe poses (see :func:`shellspline.read_keyframes`).
    K : int, optional
        Last frame index; the result has ``K+1`` frames. Default from the keyframe frames.
    method : {"lta", "linear", "geodesic", "nonlinear"}
        ``"lta"``: LΘA spline (paper §7): descriptors, time-discrete spline, Gauss–Newton
        reconstruction. ``"linear"``: per-vertex linear blending (baseline). ``"geodesic"``:
        piecewise discrete geodesics in shell space (paper §3, the paper's baseline).
        ``"nonlinear"``: the nonlinear spline on the Discrete Shells energy (paper eqs. 7–8,
        adjoint gradient), started from the LΘA spline; slow on large meshes.
    bc : {"natural", "periodic", "hermite"}
        Time boundary conditions (paper §8). ``"hermite"`` needs keyframes at frames 1 and
        ``K-1`` (they fix the end velocities).
    eta, mu, lam : float
        Bending (``η = thickness²``), length and area weights (paper eq. 9–10).
    reference : {"constant", "keyframe", "geodesic"} or int
        Reference meshes for the LΘA weights: one keyframe for all frames (``"constant"`` = the
        first keyframe, or an int keyframe index), the nearest keyframe per frame
        (``"keyframe"``), or the piecewise discrete geodesic between the keyframes evaluated at
        every frame (``"geodesic"``, paper §7/§9: physically closer to the undeformed shell of
        each energy term; costs one geodesic solve per keyframe gap, on the coarse mesh under
        multiresolution).
    fixpoint : int
        Fixpoint iterations of the LΘA model (paper §9, Fig. 9): after the LΘA sequence, set
        the reference meshes to the current result, re-solve the spline and reconstruct
        (started from the current result); repeat ``fixpoint`` times. ``report["fixpoint"]``
        records the change per iteration. Paper: converges, with minor corrections.
    frames : (J,) int array, optional
        Keyframe frames (overrides ``keyframes.frames``).
    pinned : (p,) int array, optional
        Vertices fixed at their (common) keyframe position; else the frames are placed rigidly.
    workers : int
        Processes for the per-frame reconstructions.
    gn_options : dict, optional
        Options of :class:`shellspline.shells.reconstruct.GaussNewton`.
    coarse : "auto", "none", int or float
        Multiresolution (paper §8): decimate all keyframes simultaneously to this many
        vertices (int) or this fraction of them (float in (0,1)), run the LΘA spline and the
        reconstruction on the coarse meshes and prolong the result by detail transfer.
        ``"auto"`` (default) decimates to 1000 vertices above 20 000 vertices (above 2000 with
        ``method="nonlinear"``, :data:`AUTO_NONLINEAR_ABOVE`); ``"none"`` runs at full
        resolution. Applies to ``method="lta"`` and ``"nonlinear"`` (the nonlinear spline then
        runs on the coarse meshes, started from their LΘA spline, and is prolonged).
    fine : bool
        After the coarse run, run the LΘA spline and Gauss–Newton at full resolution,
        initialised from the prolonged sequence (paper Table 2, last column).
    solver_options : dict, optional
        Extra options of :func:`shellspline.shells.geodesic.geodesic_interpolation` (``tol``,
        ``max_iter``) or :func:`shellspline.shells.nonlinear.nonlinear_spline` (``max_iter``,
        ``gtol``, ``max_time_s``, ...).
    warm_start : bool
        Start frame k's Gauss–Newton from frame k-1's solution moved by the change of the
        keyframe blend (frames are solved in time order within each worker's run); otherwise
        from the blend.
    rigid_track : {"fit", "spline", "linear"}
        Where in-between frames are placed rigidly (shell energies do not see rigid motions):
        onto the per-vertex C² cubic through the keyframes (``"fit"``), along a C² SE(3)
        spline through the keyframes' rigid poses (``"spline"``), or onto the per-vertex
        linear blend (``"linear"``); see :func:`placement_track`.
    progress : callable(ProgressEvent), optional
        Receives stage/progress events (the CLI draws a bar with it).

    Returns
    -------
    InterpolationResult

    Examples
    --------
    >>> import numpy as np, trimesh
    >>> m = trimesh.creation.icosphere(subdivisions=1)
    >>> Vs = np.stack([m.vertices, m.vertices * [1.5, 1, 1], m.vertices * [1, 1.5, 1]])
    >>> res = interpolate((Vs, m.faces), K=8)
    >>> res.V.shape, bool((res.V[[0, 4, 8]] == Vs).all())
    ((9, 42, 3), True)
    """
    t_start = time.perf_counter()
    prog = Progress(progress)
    method = _canonical_choice(method, "method", METHODS)
    rigid_track = _canonical_choice(rigid_track, "rigid_track", RIGID_TRACKS)
    bc = _canonical_choice(bc, "bc", BOUNDARY_CONDITIONS)
    for name, val in (("eta", eta), ("mu", mu), ("lam", lam)):
        if not np.isfinite(val) or val < 0:
            raise ShellsplineError(f"`{name}` must be a finite non-negative number, got {val!r}")
    if mu == 0 and lam == 0:
        raise ShellsplineError("`mu` and `lam` cannot both be zero (the membrane energy would "
                               "vanish)")
    workers = 1 if workers is None else int(workers)
    if workers < 1:
        raise ShellsplineError(f"`workers` must be >= 1, got {workers}")

    if isinstance(keyframes, Keyframes):
        kf = keyframes
    elif isinstance(keyframes, tuple) and len(keyframes) == 2 and \
            not isinstance(keyframes[0], (str, os.PathLike)):
        with prog.stage("validate"):
            kf = keyframes_from_arrays(keyframes[0], keyframes[1])
    else:
        with prog.stage("read"):
            kf = read_keyframes(keyframes)
    T = kf.topology
    if pinned is None:
        pinned = kf.pinned
    if pinned is not None:
        pinned = np.asarray(pinned, dtype=np.int64).ravel()
        if pinned.size and (pinned.min() < 0 or pinned.max() >= kf.V.shape[1]):
            raise ShellsplineError(f"`pinned` indices must lie in [0, {kf.V.shape[1]}), got range "
                                   f"[{pinned.min()}, {pinned.max()}]")
        if pinned.size == 0:
            pinned = None
    frames, K = canonical_frames(kf.V.shape[0], kf.frames if frames is None else frames, K, bc)
    if bc == "hermite" and (len(frames) < 4 or frames[1] != 1 or frames[-2] != K - 1
                            or frames[-1] != K):
        raise ShellsplineError("bc='hermite' needs keyframes at frames 0, 1, K-1 and K (the poses "
                               f"at 1 and K-1 fix the end velocities); got frames "
                               f"{frames.tolist()} with K={K}")
    Vkey = kf.V
    J, n = Vkey.shape[:2]
    if bc != "periodic" and K > frames[-1] and method != "linear":
        prog.message(f"frames {int(frames[-1]) + 1}..{K} lie after the last keyframe: the "
                     "spline extrapolates them (linearly in its variables)")
    if pinned is not None:
        spread = np.abs(Vkey[:, pinned] - Vkey[0, pinned]).max()
        if spread > 0:
            prog.message(f"pinned vertices move between keyframes (max {spread:.3g}); "
                         "each frame pins them at their blended position")
    report = {
        "shellspline_version": __version__,
        "parameters": {
            "method": method, "bc": bc, "K": int(K), "frames": frames.tolist(), "eta": eta,
            "mu": mu, "lam": lam, "reference": reference, "workers": workers, "warm_start": bool(warm_start),
            "pinned_vertices": 0 if pinned is None else int(pinned.size),
            "gn_options": dict(gn_options or {}),
            "solver_options": dict(solver_options or {}), "coarse": coarse, "fine": bool(fine),
            "fixpoint": int(fixpoint), "rigid_track": rigid_track,
        },
        "mesh": {"vertices": int(n), "faces": int(T.n_faces), "edges": int(T.n_edges),
                 "keyframes": int(J), "names": list(kf.names)},
    }
    periodic = bc == "periodic"
    blend = linear_blend(Vkey, frames, K, bc)
    Z = None
    frame_records = []
    energy_source = None
    if method == "linear":
        V = blend
    elif method == "geodesic":
        from ..shells.geodesic import geodesic_interpolation

        with prog.stage("geodesic", total=len(frames) - (0 if periodic else 1)):
            g = geodesic_interpolation(Vkey, frames, K, T, mu=mu, lam=lam, eta=eta,
                                       pinned=pinned, bc=bc,
                                       callback=lambda s, r: prog.advance("geodesic", s + 1,
                                                                          len(frames)),
                                       **dict(solver_options or {}))
        V = _placed(g.V, frames, K, bc, pinned, Vkey, T.F, rigid_track)
        report["geodesic"] = {"success": bool(g.success), "nit": int(g.nit),
                              "message": g.message,
                              "segment_energies": [float(e) for e in g.segment_energies]}
        if not g.success:
            prog.message(f"geodesic: {g.message}")
    else:
        fixpoint = int(fixpoint)
        if fixpoint < 0:
            raise ShellsplineError(f"`fixpoint` must be a non-negative number of iterations, got "
                                   f"{fixpoint}")
        fixpoint_log: list = []
        lta_args = dict(frames=frames, K=K, bc=bc, mu=mu, lam=lam, eta=eta, reference=reference,
                        workers=workers, gn_options=dict(gn_options or {}),
                        warm_start=warm_start, prog=prog, fixpoint=fixpoint,
                        fixpoint_log=fixpoint_log, rigid_track=rigid_track)
        n_coarse = _coarse_target(coarse, n, method)
        if method == "nonlinear" and not fine:
            if n_coarse is not None and _coarse_target(coarse, n) is None:
                prog.message(f"nonlinear: solving on {n_coarse} coarse vertices and prolonging "
                             f"to {n} (--coarse none: all {n}, far slower)")
            elif n_coarse is None and n > AUTO_NONLINEAR_ABOVE:
                prog.message(f"nonlinear spline on all {n} vertices: expect far more than the "
                             f"~4 min it takes at {AUTO_COARSE_VERTICES} (--coarse "
                             f"{AUTO_COARSE_VERTICES} solves there and prolongs)")
        if fine and n_coarse is None:
            raise ShellsplineError("`fine=True` refines a multiresolution run: it needs `coarse` "
                                   f"(a vertex count or fraction below the {n} vertices), got "
                                   f"coarse={coarse!r}")
        if (n_coarse is None or fine) and n > FULL_RESOLUTION_WARN:
            prog.message(f"Gauss–Newton at full resolution on {n} vertices takes minutes and "
                         "gigabytes (measured: 154k vertices, K = 50, --fine from 1000 coarse "
                         "vertices, 2 workers: 7.1 min, 6.8 GiB)" +
                         ("" if fine else "; here frames start from the keyframe blend, "
                          "not from a prolonged coarse result; the multiresolution path "
                          "(--coarse, default above 20 000 vertices) takes seconds"))
        if n_coarse is None:
            V, Z, W_report, frame_records = _lta_sequence(Vkey, T, pinned, **lta_args)
        else:
            from ..mesh.decimate import decimate
            from ..shells.prolong import Prolongation

            with prog.stage("decimate"):
                dec = decimate(Vkey, T, n_coarse, pinned=pinned)
                Tc = topology(dec.F, dec.V.shape[1], name="coarse mesh")
            report["multires"] = {"coarse_vertices": int(dec.V.shape[1]),
                                  "coarse_faces": int(dec.F.shape[0]),
                                  "decimation": {k: v for k, v in dec.stats.items()
                                                 if isinstance(v, (int, float, str, bool))}}
            Vc, Zc, Wc, coarse_records = _lta_sequence(
                dec.V, Tc, dec.pinned, stage_prefix="coarse ", **lta_args)
            if method == "nonlinear" and not fine:
                # the nonlinear spline on the coarse meshes (started from their LΘA spline),
                # prolonged like the LΘA result
                Vc, report["nonlinear"] = _nonlinear_stage(
                    dec.V, Tc, dec.pinned, Vc, frames, K, bc, mu, lam, eta, solver_options,
                    prog, "coarse ")
                report["nonlinear"]["resolution"] = "coarse"
                Zc = None
            with prog.stage("prolong"):
                moving = pinned is not None and bool(np.any(Vkey[:, pinned] != Vkey[0, pinned]))
                P = Prolongation.encode(Vkey, T, dec, frames,
                                        pinned=None if moving else pinned)
                V = _parallel_decode(P, Vc, frames, K, bc, workers)
                del P  # its factorization is not needed any more (memory of a --fine run)
                if moving:  # same semantics as full resolution: pins follow the blend
                    V[:, pinned] = blend[:, pinned]
            report["multires"]["coarse_frames"] = coarse_records
            Z, W_report = None, None
            if fine:
                del blend  # (K+1, n, 3): not held while the workers run
                V, Z, W_report, frame_records = _lta_sequence(Vkey, T, pinned, Vinit=V,
                                                              stage_prefix="fine ", **lta_args)
            else:
                frame_records = coarse_records
                # energies where the spline was solved (full-resolution descriptors of every
                # frame would cost more than the whole coarse run)
                energy_source = (Vc, Zc, Tc, Wc)
            V = _placed(V, frames, K, bc, pinned, Vkey, T.F, rigid_track)
        if fixpoint:
            report["fixpoint"] = fixpoint_log
        if W_report is None:
            W_report = lta_weights(Vkey[0], T, mu=mu, lam=lam, eta=eta)
        if method == "nonlinear" and "nonlinear" not in report:
            Vn, report["nonlinear"] = _nonlinear_stage(Vkey, T, pinned, V, frames, K, bc, mu,
                                                       lam, eta, solver_options, prog)
            V = _placed(Vn, frames, K, bc, pinned, Vkey, T.F, rigid_track)
            energy_source = None  # energies of the final (full-resolution) sequence
    with prog.stage("energies"):
        if energy_source is not None:
            Ve, Ze, Te, We, resolution = (*energy_source, "coarse")
        else:
            We = W_report if method in ("lta", "nonlinear") else \
                lta_weights(Vkey[0], T, mu=mu, lam=lam, eta=eta)
            Ve, Ze, Te, resolution = V, Z, T, "full"
        if np.all(np.isfinite(Ve)):
            report["energies"] = _energies(Ve, Ze, Te, bc, We)
        else:  # a failed frame: keep the report (the quality check flags the sequence)
            report["energies"] = {"error": "the sequence has non-finite coordinates"}
        report["energies"]["resolution"] = resolution
    report["frames"] = frame_records
    with prog.stage("quality"):
        report["quality"] = _quality(V, T, frames, bc, Vkey)
    if frame_records:
        nits = [r["nit"] for r in frame_records]
        report["gauss_newton"] = {
            "frames": len(frame_records),
            "converged": int(sum(r["success"] for r in frame_records)),
            "stalled": [int(r["frame"]) for r in frame_records
                        if r.get("status") == "stalled"],
            "iteration_limit": [int(r["frame"]) for r in frame_records
                                if r.get("status") == "limit"],
            "iterations_median": float(np.median(nits)),
            "iterations_total": int(sum(nits)),
            "iterations_max": int(max(nits)),
            "cg_iterations_total": int(sum(r["cg_iterations"] for r in frame_records)),
            "factorizations_total": int(sum(r["factorizations"] for r in frame_records)),
        }
        failed = [r["frame"] for r in frame_records if not r["success"]]
        if failed:
            prog.message(f"Gauss–Newton did not converge on frames {failed[:10]}"
                         f"{' …' if len(failed) > 10 else ''}")
    report["timings"] = dict(prog.timings)
    report["timings"]["total"] = time.perf_counter() - t_start
    report["platform"] = {"python": platform.python_version(), "cpus": os.cpu_count()}
    return InterpolationResult(V=V, F=T.F, frames=frames, report=_jsonable(report), Z=Z,
                               source=kf.source)


AUTO_COARSE_ABOVE = 20_000
AUTO_COARSE_VERTICES = 1000
#: ``coarse="auto"`` with ``method="nonlinear"`` decimates above this many vertices (to
#: :data:`AUTO_COARSE_VERTICES`): the nonlinear spline takes ~4 min at 1000 vertices (cactus,
#: K = 20) and its cost grows faster than the vertex count.
AUTO_NONLINEAR_ABOVE = 2000


def _coarse_target(coarse, n, method: str = "lta"):
    """Canonical coarse vertex count, or None for a single-resolution run."""
    if coarse is None or (isinstance(coarse, str) and coarse.strip().lower() == "auto"):
        above = AUTO_NONLINEAR_ABOVE if method == "nonlinear" else AUTO_COARSE_ABOVE
        return AUTO_COARSE_VERTICES if n > above else None
    if isinstance(coarse, str):
        c = coarse.strip().lower()
        if c in ("none", "off", "no"):
            return None
        try:
            coarse = float(c) if any(ch in c for ch in ".e") else int(c)
        except ValueError:
            raise ShellsplineError(f"`coarse` must be 'auto', 'none', a vertex count or a fraction "
                                   f"in (0, 1), got {coarse!r}") from None
    if isinstance(coarse, bool):
        raise ShellsplineError(f"`coarse` must be 'auto', 'none', a vertex count or a fraction, "
                               f"got {coarse!r}")
    if isinstance(coarse, (float, np.floating)) and 0 < coarse < 1:
        target = int(round(coarse * n))
    elif float(coarse) == int(coarse) and int(coarse) >= 4:
        target = int(coarse)
    else:
        raise ShellsplineError(f"`coarse` must be a vertex count >= 4 or a fraction in (0, 1), got "
                               f"{coarse!r}")
    return None if target >= n else max(target, 4)


def _lta_sequence(Vkey, T, pinned, *, frames, K, bc, mu, lam, eta, reference, workers,
                  gn_options, warm_start, prog, Vinit=None, stage_prefix="", fixpoint=0,
                  fixpoint_log=None, rigid_track="fit"):
    """The LΘA stages on one resolution: describe, solve, reconstruct, place (and the
    optional fixpoint iterations, appending their records to ``fixpoint_log``).

    Returns ``(V (K+1,n,3), Z (K+1,d), W (d,) or (K+1,d), frame_records)``.
    """
    J = Vkey.shape[0]
    periodic = bc == "periodic"
    with prog.stage(stage_prefix + "describe"):
        Zkey = lta_descriptors(Vkey, T)
        sT = T.descriptor_slices()[1]
        Zkey[:, sT] = _keyframe_angles(Zkey[:, sT], periodic)
        clamp = _AngleBand(Zkey[:, sT], sT, frames, K, periodic)
        if isinstance(reference, (int, np.integer)) and not isinstance(reference, bool):
            ref_idx, ref_kind = int(reference), "constant"
            if not 0 <= ref_idx < J:
                raise ShellsplineError(f"`reference` keyframe index must lie in [0, {J}), got "
                                       f"{reference}")
        else:
            ref_kind = _canonical_choice(reference, "reference", REFERENCES)
            ref_idx = 0
        if ref_kind == "constant":
            w_const = lta_weights(Vkey[ref_idx], T, mu=mu, lam=lam, eta=eta)
            W_spline, W_report = None, w_const

            def W_of(k):
                return w_const
        elif ref_kind == "geodesic":
            W_spline = W_report = _geodesic_weights(Vkey, T, pinned, frames, K, bc, mu, lam, eta,
                                                    prog, stage_prefix)

            def W_of(k):
                return W_spline[k]
        else:
            Wkey = lta_weights(Vkey, T, mu=mu, lam=lam, eta=eta)
            j0, j1, t = keyframe_bracket(frames, K, periodic)
            nearest = np.where(t <= 0.5, j0, j1)
            W_spline = W_report = Wkey[nearest]

            def W_of(k):
                return Wkey[nearest[k]]
    with prog.stage(stage_prefix + "solve"):
        if W_spline is None:
            # constant weights: the spline is one linear map of the keyframes, Z = S Zkey;
            # the reconstruction takes its rows on demand and the (K+1, d) array is formed
            # afterwards (0.5 GB at 150k vertices, K = 50, not held while the workers run)
            Z = _SplineRows(lta_spline(np.eye(J), frames, K, bc=bc), Zkey, clamp)
        else:
            Z = clamp(lta_spline(Zkey, frames, K, bc=bc, weights=W_spline))
    is_key = np.zeros(K + 1, dtype=bool)
    is_key[frames] = True
    is_key[K] |= periodic
    ks = np.flatnonzero(~is_key)
    # with a given initial sequence (the prolonged coarse result of ``fine=True``) a warm
    # start moves frame k-1's solution by the change of that sequence: it cancels most of
    # the prolongation's misfit and keeps the cached preconditioner good from frame to frame
    # (a given sequence is followed by its change; the keyframe blend only for the first
    # frame of a run, then the solutions are extrapolated, see _solve_run)
    warm = ("delta" if Vinit is not None else "extrapolate") if warm_start else False
    Vinit = _safe_init(linear_blend(Vkey, frames, K, bc), Vkey, frames, K, bc, T) \
        if Vinit is None else np.asarray(Vinit, dtype=np.float64)
    runs = _runs(ks, frames, K, periodic)
    with prog.stage(stage_prefix + "reconstruct", total=len(ks)):
        results = _run_reconstruction(T, ks, Z, W_of, Vinit, pinned, gn_options, workers, prog,
                                      warm, stage=stage_prefix + "reconstruct", runs=runs)
    if warm == "extrapolate":
        again = _continued(runs, results, Vinit)
        n_again = sum(len(r) for r, _, _ in again)
        stage = stage_prefix + "reconstruct (continue)"
        with prog.stage(stage, total=n_again):
            better = _run_reconstruction(T, np.concatenate([r for r, _, _ in again]) if again
                                         else np.zeros(0, int), Z, W_of, Vinit, pinned,
                                         gn_options, workers, prog, warm, stage=stage,
                                         runs=again)
        for kk, (Vk, rec) in better.items():
            rec["continued"] = True
            results[kk] = (Vk, rec)
    if isinstance(Z, _SplineRows):
        Z = Z[:]
    with prog.stage(stage_prefix + "place"):
        blend = linear_blend(Vkey, frames, K, bc)  # (K+1, n, 3): not held during reconstruction
        V = blend.copy()
        for k in ks:
            V[k] = results[k][0]
        V = _placed(V, frames, K, bc, pinned, Vkey, T.F, rigid_track)
    records = [results[k][1] for k in ks]
    for it in range(int(fixpoint)):
        t0 = time.perf_counter()
        with prog.stage(stage_prefix + f"fixpoint {it + 1} solve"):
            W_spline = lta_weights(V, T, mu=mu, lam=lam, eta=eta)
            Znew = clamp(lta_spline(Zkey, frames, K, bc=bc, weights=W_spline))
        stage = stage_prefix + f"fixpoint {it + 1} reconstruct"
        with prog.stage(stage, total=len(ks)):
            results = _run_reconstruction(T, ks, Znew, lambda k: W_spline[k], V, pinned,
                                          gn_options, workers, prog, False, stage=stage)
        Vnew = blend.copy()
        for k in ks:
            Vnew[k] = results[k][0]
        Vnew = _placed(Vnew, frames, K, bc, pinned, Vkey, T.F, rigid_track)
        if fixpoint_log is not None:
            fixpoint_log.append(dict(_fixpoint_change(V, Vnew, Z, Znew, T, Vkey),
                                     iteration=it + 1, resolution=stage_prefix.strip() or "full",
                                     seconds=time.perf_counter() - t0))
        V, Z, W_report, records = Vnew, Znew, W_spline, [results[k][1] for k in ks]
    return V, Z, W_report, records


def _nonlinear_stage(Vkey, T, pinned, Vinit, frames, K, bc, mu, lam, eta, solver_options,
                     prog, stage_prefix=""):
    """The nonlinear spline started from ``Vinit``; returns ``(V, report record)``."""
    from ..shells.nonlinear import nonlinear_spline

    opts = dict(solver_options or {})
    max_iter = int(opts.pop("max_iter", 500))
    stage = stage_prefix + "nonlinear"
    gtol = float(opts.get("gtol", 1e-6))
    first = {}

    def report(it, e, g):
        # the bar fills with the gradient reduction on a log scale, 1000 = gtol reached
        g0 = first.setdefault("g", g)
        red = g / g0 if g0 > 0 else 0.0
        frac = np.log(1.0 / max(red, 1e-300)) / np.log(1.0 / gtol) if 0 < gtol < 1 else 0.0
        prog.advance(stage, int(1000 * min(max(frac, 0.0), 1.0)), 1000,
                     text=f"it {it:3d}  F {e:.7g}  |g|/|g0| {red:.1e}")

    with prog.stage(stage, total=1000):
        # iteration 0 is reported after the first evaluation, one geodesic midpoint solve per
        # energy term: minutes on the coarse horse (K = 40), so say what is happening
        n_terms = K if bc == "periodic" else K - 1
        prog.advance(stage, 0, 1000, text=f"evaluating the start path ({n_terms} geodesic "
                                          "midpoints)")
        nl = nonlinear_spline(Vkey, frames, K, T, bc=bc, mu=mu, lam=lam, eta=eta,
                              pinned=pinned, init=Vinit, max_iter=max_iter, callback=report,
                              **opts)
    rec = {"success": bool(nl.success), "nit": int(nl.nit), "nfev": int(nl.nfev),
           "message": nl.message, "optimizer": nl.optimizer,
           # None: the time limit ran out before the first evaluation finished
           "energy_initial": _at(nl.energies, 0), "energy_final": _at(nl.energies, -1),
           "grad_norm_initial": _at(nl.grad_norms, 0),
           "grad_norm_final": _at(nl.grad_norms, -1), "seconds": float(nl.time_s),
           "cg_iterations": [int(c) for c in nl.cg_iterations],
           "midpoint_newton_iterations": int(nl.midpoint_newton_iterations),
           "vertices": int(Vkey.shape[1]),
           "energy_history": [float(e) for e in nl.energies],
           "grad_norm_history": [float(g) for g in nl.grad_norms],
           "time_history": [float(t) for t in nl.times],
           "step_lengths": [float(a) for a in nl.step_lengths],
           "hessian": [str(h) for h in nl.hessian]}
    if not nl.success:
        prog.message(f"nonlinear spline: {nl.message}")
    return nl.V, rec


def _at(history, i):
    return float(history[i]) if len(history) else None


def _geodesic_weights(Vkey, T, pinned, frames, K, bc, mu, lam, eta, prog, stage_prefix=""):
    """LΘA weights ``(K+1, d)`` at the piecewise discrete geodesic through the keyframes."""
    from ..shells.geodesic import geodesic_interpolation

    n_seg = len(frames) - (0 if bc == "periodic" else 1)
    stage = stage_prefix + "reference geodesic"
    with prog.stage(stage, total=n_seg):
        import warnings

        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            g = geodesic_interpolation(Vkey, frames, K, T, mu=mu, lam=lam, eta=eta,
                                       pinned=pinned, bc=bc,
                                       callback=lambda s, r: prog.advance(stage, s + 1, n_seg))
        if not g.success:
            prog.message(f"reference geodesic: {g.message} (weights from the current iterates)")
    return lta_weights(g.V, T, mu=mu, lam=lam, eta=eta)


def _fixpoint_change(V, Vnew, Z, Znew, T, Vkey) -> dict:
    """Change of one fixpoint iteration: vertices (absolute and relative to the keyframes'
    bounding-box diagonal) and spline descriptors (lengths and areas relative to their
    magnitude, angles in radians)."""
    diag = float(np.linalg.norm(Vkey.reshape(-1, 3).max(0) - Vkey.reshape(-1, 3).min(0)))
    dv = float(np.abs(Vnew - V).max())
    sL, sT, sA = T.descriptor_slices()
    out = {"max_vertex_change": dv, "rel_vertex_change": dv / max(diag, 1e-300)}
    for name, sl, rel in (("lengths", sL, True), ("angles", sT, False), ("areas", sA, True)):
        d = np.abs(Znew[:, sl] - Z[:, sl])
        if d.size == 0:
            continue
        out[f"max_{name}_change"] = float(d.max() / (np.abs(Z[:, sl]).max() if rel else 1.0))
    return out


def _safe_init(blend, Vkey, frames, K, bc, T, min_ratio=1e-3):
    """The keyframe blend as initial guess, except for frames where the blend collapses
    triangles (e.g. a half-turn between keyframes): those start from the nearer keyframe."""
    F = T.F

    def areas(Vs):
        return 0.5 * np.linalg.norm(_tri_normals(Vs, F), axis=-1)

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


def _tri_normals(Vs, F):
    """Unnormalised face normals ``(..., m, 3)`` of poses ``Vs (..., n, 3)``: frame by frame on
    coordinate rows (measured 3-5x faster than one batched gather over a few frames of a
    5k-vertex mesh; same values as ``descriptors._cross``)."""
    Vs = np.asarray(Vs, dtype=np.float64)
    flat = Vs.reshape(-1, *Vs.shape[-2:])
    out = np.zeros((flat.shape[0], F.shape[0], 3))
    for i in range(flat.shape[0]):
        x = np.ascontiguousarray(flat[i].T)                       # (3,n)
        p0 = x[:, F[:, 0]]
        a, b = x[:, F[:, 1]] - p0, x[:, F[:, 2]] - p0
        out[i, :, 0] = a[1] * b[2] - a[2] * b[1]
        out[i, :, 1] = a[2] * b[0] - a[0] * b[2]
        out[i, :, 2] = a[0] * b[1] - a[1] * b[0]
    return out.reshape(*Vs.shape[:-2], F.shape[0], 3)


def _jsonable(obj):
    """The report with numpy scalars/arrays as Python values and non-finite floats as None
    (strict JSON)."""
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _jsonable(obj.tolist())
    if isinstance(obj, (np.bool_, bool)):
        return bool(obj)
    if isinstance(obj, (np.integer, int)):
        return int(obj)
    if isinstance(obj, (np.floating, float)):
        return float(obj) if np.isfinite(obj) else None
    return obj


#: Where in-between frames are placed rigidly (:func:`placement_track`).
RIGID_TRACKS = ("fit", "spline", "linear")


def placement_track(Vkey, frames, K, bc: str = "natural", kind: str = "fit"):
    """Where the frames of a sequence are placed rigidly: a per-vertex C² cubic spline through
    the keyframes (natural, or periodic through frame K), held at the last keyframe after it.

    Shell energies ignore rigid motions (paper §8), so every reconstructed frame is moved
    rigidly onto this track. A per-vertex *linear* blend gave the body of a skinned walk the
    piecewise-linear travel and turn of linear blending: on `benchmarks/bench_real.py` the
    LΘA in-betweens were 1.02–1.96 × the per-vertex cubic's error, all of it in the rigid
    part; placed on the cubic they are 0.91–1.05 × (issue 13).

    Parameters
    ----------
    Vkey : (J,n,3) float64 array
    frames : (J,) int array
    K : int
    bc : {"natural", "periodic", "hermite"}
    kind : {"fit", "spline", "linear"}
        ``"fit"``: the per-vertex cubic above. ``"spline"``: a rigid track: each keyframe's
        rigid pose (Kabsch against the first keyframe, about the vertex centroid) follows a C²
        SE(3) spline with the screw (Ad-invariant) metric (:func:`shellspline.curves.cubic_spline`),
        and the keyframe shapes, brought back by their poses, are blended linearly: a body
        that turns while it travels follows a screw motion (a circle exactly), where the
        per-vertex cubic cuts the corner; falls back to ``"fit"`` when consecutive keyframes
        turn by half a turn or more. ``"linear"``: the per-vertex linear blend.

    Returns
    -------
    (K+1,n,3) float64 array
        Equal to the keyframes at their frames (to round-off; the pipeline restores them bit
        for bit after placing).
    """
    from scipy.interpolate import CubicSpline

    Vkey = np.asarray(Vkey, dtype=np.float64)
    if kind == "linear":
        return linear_blend(Vkey, frames, K, bc)
    if kind == "spline":
        track = _screw_track(Vkey, frames, K, bc)
        if track is not None:
            return track
    frames = np.asarray(frames)
    J = Vkey.shape[0]
    periodic = bc == "periodic"
    if J < 3 and not periodic:
        return linear_blend(Vkey, frames, K, bc)
    if periodic:
        t = np.concatenate([frames, [K]]).astype(np.float64)
        Y = np.concatenate([Vkey, Vkey[:1]])
        if J < 2:
            return linear_blend(Vkey, frames, K, bc)
        cs = CubicSpline(t, Y.reshape(J + 1, -1), bc_type="periodic")
    else:
        cs = CubicSpline(frames.astype(np.float64), Vkey.reshape(J, -1), bc_type="natural")
    k = np.arange(K + 1, dtype=np.float64)
    if not periodic:
        k = np.minimum(k, frames[-1])
    return cs(k).reshape(K + 1, *Vkey.shape[1:])


def _screw_track(Vkey, frames, K, bc):
    """The ``kind="spline"`` track of :func:`placement_track`, or None where the SE(3) spline
    is not defined (consecutive keyframe poses half a turn or more apart)."""
    from ..errors import ShellsplineError
    from ..curves import cubic_spline

    J = Vkey.shape[0]
    periodic = bc == "periodic"
    c = Vkey.mean(axis=1)                                    # (J,3)
    X0 = Vkey[0] - c[0]
    H = np.einsum("ni,jnk->jik", X0, Vkey - c[:, None])      # (J,3,3) cross-covariances
    U, _, Wt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(np.einsum("jki,jlk->jil", Wt, U)))
    D = np.zeros((J, 3, 3))
    D[:, 0, 0] = D[:, 1, 1] = 1.0
    D[:, 2, 2] = np.where(d == 0, 1.0, d)
    R = np.einsum("jki,jkl,jml->jim", Wt, D, U)              # Vkey[j] - c[j] ≈ R_j X0
    G = np.zeros((J, 4, 4))
    G[:, :3, :3], G[:, :3, 3], G[:, 3, 3] = R, c, 1.0
    t = np.asarray(frames, dtype=np.float64)
    if periodic:
        G, t = np.concatenate([G, G[:1]]), np.concatenate([t, [K]])
    try:
        s = cubic_spline("se3", t, G, bc="periodic" if periodic else "natural")
    except ShellsplineError:
        return None
    if s.solve is not None and s.solve.status != "converged":
        return None
    k = np.arange(K + 1, dtype=np.float64)
    if not periodic:
        k = np.minimum(k, t[-1])
    Gk = s(k)                                                # (K+1,4,4)
    shapes = np.einsum("jnk,jki->jni", Vkey - c[:, None], R)  # R_jᵀ (V - c): keyframes at rest
    rest = linear_blend(shapes, frames, K, bc)
    return np.einsum("kni,kji->knj", rest, Gk[:, :3, :3]) + Gk[:, None, :3, 3]


def _placed(V, frames, K, bc, pinned, Vkey, F, rigid_track="fit"):
    """Rigidly place the in-between frames onto :func:`placement_track` (with pins: only by the
    rigid motions that keep them fixed) and restore the keyframes bit for bit. Each connected
    component of the mesh is placed on its own: shell energies do not see how separate pieces
    sit relative to each other, so a reconstruction leaves that free."""
    V = np.array(V, dtype=np.float64, copy=True)
    periodic = bc == "periodic"
    track = placement_track(Vkey, frames, K, bc, kind=rigid_track)
    is_key = np.zeros(K + 1, dtype=bool)
    is_key[frames] = True
    is_key[K] |= periodic
    parts = _components(F, Vkey.shape[1], pinned)
    for k in np.flatnonzero(~is_key):
        # with pins only the motions they leave free (none for 3+ non-collinear pins)
        for idx, fixed in parts:
            V[k, idx] = rigid_placement(V[k, idx], track[k, idx], fixed=fixed)
    for j, f in enumerate(frames):
        V[f] = Vkey[j]
    if periodic:
        V[K] = Vkey[0]
    return V


def _components(F, n, pinned):
    """``[(vertex indices, pins among them as local indices or None), ...]`` of the connected
    components of the mesh ``F`` with ``n`` vertices (one entry for a connected mesh)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    E = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    A = coo_matrix((np.ones(len(E)), (E[:, 0], E[:, 1])), shape=(n, n))
    m, label = connected_components(A, directed=False)
    if m == 1:
        return [(slice(None), pinned)]
    out = []
    for c in range(m):
        idx = np.flatnonzero(label == c)
        fixed = None
        if pinned is not None and len(pinned):
            local = np.flatnonzero(np.isin(idx, pinned))
            fixed = local if local.size else None
        out.append((idx, fixed))
    return out


def _energies(V, Z, T: Topology, bc: str, W, chunk: int | None = None) -> dict:
    """Per-frame LΘA energies (paper Figs. 11–12) of the output and, when given, of the spline
    targets ``Z``, plus the reconstruction misfit of every frame; ``W`` is (d,) or (K+1,d).
    Descriptors are computed a few frames at a time to bound memory on large meshes (one
    frame at a time above 20 000 vertices, where stacked frames fall out of cache: measured
    1.7x slower per frame at 150k)."""
    sT = T.descriptor_slices()[1]
    K1 = V.shape[0]
    if chunk is None:
        chunk = 1 if V.shape[1] > 20_000 else 8
    Zout = np.concatenate([lta_descriptors(V[i:i + chunk], T) for i in range(0, K1, chunk)])
    Zout[:, sT] = unwrap_angles(Zout[:, sT])
    out = {"lta_output_energy_per_frame": lta_energy_per_frame(Zout, bc=bc, weights=W).tolist()}
    if Z is not None:
        Wk = np.broadcast_to(W, Z.shape)
        Zout -= Z
        Zout[:, sT] = (Zout[:, sT] + np.pi) % (2 * np.pi) - np.pi
        out["lta_spline_energy_per_frame"] = lta_energy_per_frame(Z, bc=bc, weights=W).tolist()
        out["reconstruction_energy_per_frame"] = np.einsum("kd,kd->k", Wk, Zout * Zout).tolist()
    return out

"""Benchmark of the shape analysis of motions (issue 17): DP alignment, seed 003's sizes,
closing.

What is measured (functions ``bench_dp``, ``bench_table1``, ``bench_close``)
---------------------------------------------------------------------------
1. **DP alignment of skeletal motions** (targets: 400 frames <= 0.3 s, 1,600 frames <= 3 s,
   31 joints = 93 dimensions). The real walks of ``../shared/data/motion`` have 22 joints; to
   reach the issue's size, joints 0-7 are appended once more (30 rotations) and the root
   position (metres) added: ``3 x 30 + 3 = 93`` dimensions. ``walk_normal`` is aligned to
   ``walk_tired`` after resampling both (geodesically) to 400 and 1,600 frames. Rows: our DP
   alone, DP + refinement, a vectorised DTW on the same SRVs (same band), and fdasrsf's
   ``optimum_reparam_curve`` (its DP; when fdasrsf is importable here or an interpreter that
   has it is given with ``--fdasrsf-python``), with the energy each warp reaches under our
   exact energy. Plus accuracy: ``walk_normal`` against itself re-timed by ``t^1.5``.
2. **Seed 003 Table 1 sizes** (their Python: 17 / 32 / 67 s elastic; targets 0.1 / 0.2 /
   0.5 s): closed planar curves of 100 / 200 / 400 points (a five-lobed "hand" and a
   deformed, re-timed, re-started copy; their hand outlines are not available), aligned as
   closed curves (start-point search and DP; then also the refinement): elastic only, 3
   correct and 3 wrong feature points.
3. **Closing** ``walk_normal`` (joint rotations + root height): seam gap per iteration of the
   Gauss-Newton projection, seed 000's gradient flow and the C1 closure.
4. **End to end** (``bench_motion_ops``, :mod:`shellspline.animation`): reading and the exact
   curve round trip of the real clips, distances (none / DP / DP with foot contacts),
   alignment and blending of walk pairs (and a 120 Hz copy against a 30 Hz clip), foot skate
   of the blends.
5. **Closing the walks** at the motion level (root travel kept as root motion, feet planted
   afterwards): seam gap, joint jump, foot skate of input / closed / output.
6. **Mesh animation** (``bench_mesh_animation``): a body skinned to one gait cycle of the walk,
   closed in LΘA space and reconstructed by Gauss-Newton; aligned and blended with another
   window of the clip. Plus the closing alone on a 125-vertex body: ``close_euclidean``
   against the generic ``curves.closing.close`` (why mesh animations use the former).
7. **Long clips** (``bench_long_distance``, ``--long-only``): ``shellspline motion distance``
   on ``walk_normal`` and ``walk_tired`` resampled to 120 Hz and repeated to 40 s (4,801
   frames), wall time and peak memory of the command, for this tree and for the package at
   ``--before`` (default ``fd9258c``, before the DP kept only a strip of its Gram matrix and
   a ring of its rows).

Run
---
::

    cd /work/main
    PYTHONPATH=. python3 benchmarks/bench_motion.py                 # ~1 minute
    PYTHONPATH=. python3 benchmarks/bench_motion.py --fdasrsf-python /tmp/fdvenv/bin/python

Tables to stdout, everything to ``benchmarks/results/bench_motion.json``. Times are the
fastest of ``--repeat`` runs (the machine is shared: compare rows of one run).
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import format_table  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
MOTION = REPO.parent / "shared" / "data" / "motion"


def _best(fn, repeat):
    times, out = [], None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return out, min(times), times


def skeleton_curve(name, n_frames, extra_joints=8):
    """A real walk as a curve in SO(3)^(22+extra) x R^3, resampled to ``n_frames``."""
    from shellspline.curves.srv import ProductCurve, reparametrize
    from shellspline.io.bvh import read_bvh

    m = read_bvh(MOTION / f"{name}.bvh")
    R, t = m.local_transforms()
    R = np.concatenate([R, R[:, :extra_joints]], axis=1)
    c = ProductCurve(R, t[:, 0] * 0.01, np.linspace(0, 1, m.n_frames))
    u = np.linspace(0, 1, n_frames)
    return reparametrize(c, u, u)


# --------------------------------------------------------------------------------------------
# fdasrsf (optional baseline)

_FDA_SNIPPET = r"""
import sys, time, json, numpy as np
import fdasrsf.curve_functions as cf
q0, q1 = np.load(sys.argv[1]), np.load(sys.argv[2])
t0 = time.perf_counter()
g = cf.optimum_reparam_curve(np.ascontiguousarray(q0.T), np.ascontiguousarray(q1.T))
dt = time.perf_counter() - t0
import fdasrsf
print(json.dumps({"seconds": dt, "gamma": np.asarray(g).tolist(),
                  "version": getattr(fdasrsf, "__version__", "?")}))
"""


def fdasrsf_dp(q0, q1, python=None, timeout=600):
    """fdasrsf's curve DP on our SRVs (``(N-1, D)``, transposed for it): ``(seconds, gamma,
    version)`` or None when fdasrsf is not available."""
    if python is None:
        try:
            import fdasrsf  # noqa: F401
            python = sys.executable
        except ImportError:
            return None
    with tempfile.TemporaryDirectory() as d:
        a, b = Path(d) / "q0.npy", Path(d) / "q1.npy"
        np.save(a, q0)
        np.save(b, q1)
        try:
            out = subprocess.run([python, "-c", _FDA_SNIPPET, str(a), str(b)],
                                 capture_output=True, text=True, timeout=timeout, check=True)
        except (subprocess.SubprocessError, OSError) as e:
            print(f"   fdasrsf failed: {e}", file=sys.stderr)
            return None
    r = json.loads(out.stdout.strip().splitlines()[-1])
    return r["seconds"], np.asarray(r["gamma"]), r["version"]


# --------------------------------------------------------------------------------------------
# 1. DP alignment of skeletal motions


def bench_dp(sizes=(400, 1600), repeat=3, fdasrsf_python=None, fdasrsf_max=400):
    """Timings and energies of the DP alignment, DTW and fdasrsf on 93-dimensional walks."""
    from shellspline.curves.align import align, dtw, warp_energy
    from shellspline.curves.srv import normalized_times, reparametrize, srv

    res, rows = {"sizes": {}}, []
    for N in sizes:
        c0 = skeleton_curve("dataset-1_walk_normal_001", N)
        c1 = skeleton_curve("dataset-1_walk_tired_001", N)
        q0 = srv(c0.with_times(normalized_times(c0.t)))
        q1 = srv(c1.with_times(normalized_times(c1.t)))
        r_dp, t_dp, all_dp = _best(lambda: align(c0, c1, refine=False), repeat)
        r_rf, t_rf, all_rf = _best(lambda: align(c0, c1), repeat)
        (_, path), t_dtw, all_dtw = _best(lambda: dtw(q0, q1, window=0.25), repeat)
        # the DTW path as a warp: its energy under the same elastic model
        phi_dtw = np.interp(np.arange(N), *_monotone(path)) / (N - 1)
        E_dtw = warp_energy(q0, q1, phi_dtw)[0]
        entry = {"frames": N, "dims": int(q0.shape[1]),
                 "dp_seconds": t_dp, "dp_runs": all_dp, "dp_energy": r_dp.energy,
                 "refined_seconds": t_rf, "refined_runs": all_rf,
                 "refined_energy": r_rf.energy, "refined_status": r_rf.status,
                 "refined_iterations": r_rf.iterations,
                 "identity_energy": r_dp.energy_identity,
                 "dtw_seconds": t_dtw, "dtw_energy": E_dtw}
        rows += [[f"{N} ours: DP", t_dp, r_dp.energy, r_dp.energy_identity, "dp"],
                 [f"{N} ours: DP + refine", t_rf, r_rf.energy, r_rf.energy_identity,
                  f"{r_rf.status} ({r_rf.iterations} it)"],
                 [f"{N} DTW (same SRVs, band 0.25)", t_dtw, E_dtw, r_dp.energy_identity,
                  "-"]]
        if N <= fdasrsf_max:
            fd = fdasrsf_dp(q0, q1, fdasrsf_python)
            if fd is not None:
                sec, gamma, ver = fd
                phi = np.interp(np.linspace(0, 1, N), np.linspace(0, 1, gamma.size), gamma)
                phi = np.maximum.accumulate(np.clip(phi, 0, 1))
                phi[0], phi[-1] = 0.0, 1.0
                E_fd = warp_energy(q0, q1, phi)[0]
                entry.update(fdasrsf_seconds=sec, fdasrsf_energy=E_fd, fdasrsf_version=ver)
                rows.append([f"{N} fdasrsf {ver} optimum_reparam_curve", sec, E_fd,
                             r_dp.energy_identity, "-"])
            else:
                entry["fdasrsf_seconds"] = None
        res["sizes"][str(N)] = entry
    # accuracy: a known warp
    N = 400
    c = skeleton_curve("dataset-1_walk_normal_001", N)
    u = np.linspace(0, 1, N)
    warped = reparametrize(c, u ** 1.5, u)
    r0 = align(warped, c, refine=False)
    r1 = align(warped, c)
    res["known_warp"] = {"frames": N, "warp": "t^1.5",
                         "dp_sup_error": float(np.abs(r0.phi - u ** 1.5).max()),
                         "refined_sup_error": float(np.abs(r1.phi - u ** 1.5).max()),
                         "refined_status": r1.status}
    return res, rows


def _monotone(path):
    """DTW paths repeat indices; keep the last ``j`` of every ``i`` (a function of ``i``)."""
    i, j = path[:, 0], path[:, 1]
    keep = np.r_[i[1:] != i[:-1], True]
    return i[keep], j[keep]


# --------------------------------------------------------------------------------------------
# 2. seed 003 Table 1 sizes


def hand(u, lobes=5, depth=0.35):
    """A closed planar "hand": a circle with ``lobes`` finger-like bulges, ``(n, 2)``."""
    r = 1 + depth * np.maximum(0, np.cos(lobes * 2 * np.pi * u)) ** 3
    return np.c_[r * np.cos(2 * np.pi * u), r * np.sin(2 * np.pi * u)]


def bench_table1(sizes=(100, 200, 400), repeat=3):
    """Closed-curve alignment with and without feature points at seed 003's sizes."""
    from shellspline.curves.align import align

    res, rows = {}, []
    paper = {100: (17, 11, 22), 200: (32, 22, 50), 400: (67, 48, 95)}
    for n in sizes:
        u = np.linspace(0, 1, n)
        c0 = hand(u)
        # the other hand: fingers of other lengths, re-timed and started 0.2 later
        warp = u + 0.04 * np.sin(2 * np.pi * u)
        c1 = hand(warp + 0.2, depth=0.45) * [1.0, 0.9]
        # fingertips of c0 are at u = k/5; in c1 at the u with warp(u) + 0.2 = k/5 (mod 1)
        tips0 = np.array([0.2, 0.4, 0.6])
        tips1 = np.interp(np.mod(tips0 - 0.2, 1.0), warp, u)
        wrong1 = np.mod(tips1 + 0.1, 1.0)                      # between the fingers
        cases = [("elastic", {}),
                 ("correct features", {"features": (tips0, tips1), "lam": 1.0}),
                 ("incorrect features", {"features": (tips0, wrong1), "lam": 1.0})]
        res[str(n)] = {}
        for name, kw in cases:
            d, sec_d, runs_d = _best(lambda: align(c0, c1, closed=True, refine=False, **kw),
                                     repeat)
            r, sec, runs = _best(lambda: align(c0, c1, closed=True, **kw), repeat)
            res[str(n)][name] = {"dp_seconds": sec_d, "dp_runs": runs_d, "dp_energy": d.energy,
                                 "seconds": sec, "runs": runs, "energy": r.energy,
                                 "elastic": r.elastic, "status": r.status,
                                 "iterations": r.iterations, "shift": r.shift}
            k = ["elastic", "correct features", "incorrect features"].index(name)
            rows.append([f"{n} {name}", paper[n][k], sec_d, d.energy, sec, r.energy,
                         f"{r.status} ({r.iterations} it)"])
    return res, rows


# --------------------------------------------------------------------------------------------
# 3. closing


def bench_close(repeat=3):
    """Seam gap per iteration when closing the normal walk."""
    from shellspline.curves.closing import close
    from shellspline.curves.srv import ProductCurve
    from shellspline.io.bvh import read_bvh

    m = read_bvh(MOTION / "dataset-1_walk_normal_001.bvh")
    R, t = m.local_transforms()
    c = ProductCurve(R, t[:, 0, 1:2] * 0.01, np.arange(m.n_frames) * m.frame_time)
    res, rows = {"frames": m.n_frames, "joints": m.n_joints}, []
    for name, kw in (("gauss-newton", {}), ("gradient (seed 000)", {"method": "gradient"}),
                     ("gauss-newton, C1", {"c1": True})):
        r, sec, _ = _best(lambda: close(c, **kw), repeat)
        res[name] = {"seconds": sec, "seam_gap": r.seam_gap.tolist(),
                     "velocity_jump": r.velocity_jump.tolist(), "change": r.change,
                     "status": r.status, "iterations": r.iterations}
        rows.append([name, sec, r.iterations, r.seam_gap[0], r.seam_gap[-1],
                     f"{r.seam_gap[0] / max(r.seam_gap[-1], 1e-300):.3g}", r.velocity_jump[-1],
                     r.change])
    return res, rows


# ----------------------------------------------------------------------------------------
# End to end on the real clips (shellspline.animation): read, align, blend, close, meshes
# ----------------------------------------------------------------------------------------
WALKS = ("dataset-1_walk_normal_001.bvh", "dataset-1_walk_tired_001.bvh",
         "dataset-1_walk_happy_001.bvh")


def bench_motion_ops(repeat=3):
    """Read (+ curve round trip), distance, align, blend and close of the real clips through
    :mod:`shellspline.animation`, with foot skate and seam gaps; a 120 Hz copy of a walk
    against a 30 Hz clip."""
    from shellspline import animation as A
    from shellspline.io.bvh import read_bvh

    res, rows = {}, []
    clips = {}
    for name in WALKS + ("dataset-1_run_normal_001.bvh",):
        m, sec, _ = _best(lambda: read_bvh(MOTION / name), repeat)
        c, sec_c, _ = _best(lambda: A.motion_curve(m).to_motion(), repeat)
        err = float(np.abs(c.values - m.values).max())
        fc = A.foot_contacts(m)
        clips[name] = m
        short = name.replace("dataset-1_", "").replace("_001.bvh", "")
        res[short] = {"frames": m.n_frames, "read_s": sec, "round_trip_s": sec_c,
                      "round_trip_max_deg": err, "touchdowns": [int(fc.onsets(i).size)
                                                                for i in range(len(fc.feet))]}
        rows.append([f"read {short}", sec + sec_c, m.n_frames, f"{err:.1e} deg",
                     f"touch-downs {res[short]['touchdowns']}"])
    a, b, h = (clips[n] for n in WALKS)
    hi = A.resample(a, frame_time=a.frame_time / 4)  # a 120 Hz copy
    for label, x, y in (("normal/tired", a, b), ("normal/happy", a, h),
                        ("normal 120 Hz/tired 30 Hz", hi, b)):
        for how, kw in (("none", {"align": "none"}), ("dp", {}),
                        ("dp + contacts", {"features": "contacts"})):
            d, sec, _ = _best(lambda: A.distance(x, y, **kw), repeat)
            res[f"distance {label} {how}"] = {"seconds": sec, "distance": d}
            rows.append([f"distance {label}, {how}", sec, x.n_frames, f"{d:.4g}", ""])
        rep, sec, _ = _best(lambda: A.align(x, y), repeat)
        res[f"align {label}"] = {"seconds": sec, "before": rep.distance_before,
                                 "after": rep.distance_after, "status": rep.result.status}
        rows.append([f"align {label}", sec, rep.t.size,
                     f"{rep.distance_before:.4g} -> {rep.distance_after:.4g}",
                     rep.result.status])
        for plant in (False, True):
            (m, _), sec, _ = _best(lambda: A.blend(x, y, 0.5, plant=plant), repeat)
            sk = A.foot_skate(m)
            key = f"blend {label}{' planted' if plant else ''}"
            res[key] = {"seconds": sec, "frames": m.n_frames, "skate_speed": sk["speed"],
                        "skate_per_leg": sk["speed_per_leg"]}
            rows.append([f"blend {label} (s=0.5, dp{', plant' if plant else ''})", sec,
                         m.n_frames, f"skate {sk['speed']:.3g} u/s",
                         f"{sk['speed_per_leg']:.3g} leg/s"])
    from shellspline.io.bvh import forward_kinematics

    def pose_change(src, out):
        """Mean displacement of the joints relative to the body's centroid (file units)."""
        P0, P1 = forward_kinematics(src)[0][:, 1:], forward_kinematics(out)[0][:, 1:]
        rel = lambda P: P - P.mean(axis=1, keepdims=True)  # noqa: E731
        return float(np.linalg.norm(rel(P0) - rel(P1), axis=2).mean())

    close_rows = []
    for name in WALKS:
        short = name.replace("dataset-1_", "").replace("_001.bvh", "")
        for c1, trim in ((False, False), (True, False), (False, True)):
            (m, r), sec, _ = _best(lambda: A.close(clips[name], iterations=10, c1=c1,
                                                   trim=trim), repeat)
            red = r.history[0] / max(r.history[-1], 1e-300)
            label = f"{short}{', C1' if c1 else ''}{', trim' if trim else ''}"
            change = pose_change(clips[name].frames(r.frames[0], r.frames[1] + 1), m)
            res[f"close {label}"] = {
                "seconds": sec, "iterations": r.iterations, "status": r.status,
                "frames": list(r.frames), "pose_change": change,
                "history": r.history.tolist(), "gap_before": r.gap_before,
                "gap_after": r.gap_after, "skate_before": r.skate_before,
                "skate_closed": r.skate_closed, "skate_after": r.skate_after}
            close_rows.append([label, sec, r.iterations, f"{change:.3g}",
                               f"{red:.2g}x", f"{r.gap_before['rotation_max']:.3g} -> "
                               f"{r.gap_after['rotation_max']:.2g}",
                               f"{r.gap_before['position_max']:.3g} -> "
                               f"{r.gap_after['position_max']:.2g}",
                               f"{r.skate_before['speed']:.3g} / {r.skate_closed['speed']:.3g}"
                               f" / {r.skate_after['speed']:.3g}"])
    return res, rows, close_rows


def bench_mesh_animation(n_vertices=1000, repeat=1):
    """A body skinned to one gait cycle of the real walk (frames 10..43): closing the loop in
    LΘA space, aligning and blending with another window, Gauss–Newton reconstruction."""
    from data_synth.skinned import skinned_sequence
    from shellspline import animation as A
    from shellspline.shells.reconstruct import rigid_placement

    clip = MOTION / "dataset-1_walk_normal_001.bvh"
    Vs, F, _ = skinned_sequence(clip, start=10, stop=44, n_vertices=n_vertices)
    Vs2, _, _ = skinned_sequence(clip, start=60, stop=100, n_vertices=n_vertices)
    res, rows = {"vertices": int(Vs.shape[1]), "frames": int(Vs.shape[0])}, []
    gap = lambda V: float(np.abs(rigid_placement(V[-1], V[0]) - V[0]).max())  # noqa: E731
    (out, rep), sec, _ = _best(lambda: A.mesh_close(Vs, F), repeat)
    res["close"] = {"seconds": sec, "converged": rep.converged, "frames": rep.frames,
                    "history": rep.history.tolist(), "vertex_gap_before": gap(Vs),
                    "vertex_gap_after": gap(out), "descriptor_error": rep.descriptor_error}
    rows.append(["close (one gait cycle)", sec, f"{rep.converged}/{rep.frames}",
                 f"vertex seam {gap(Vs):.3g} -> {gap(out):.2g}", rep.descriptor_error])
    r, sec, _ = _best(lambda: A.mesh_align(Vs, Vs2, F), repeat)
    res["align"] = {"seconds": sec, "energy_identity": r.energy_identity, "energy": r.energy}
    rows.append(["align (40-frame window)", sec, r.status,
                 f"energy {r.energy_identity:.4g} -> {r.energy:.4g}", ""])
    (out, rep), sec, _ = _best(lambda: A.mesh_blend(Vs, Vs2, F, 0.5), repeat)
    res["blend"] = {"seconds": sec, "converged": rep.converged, "frames": rep.frames,
                    "descriptor_error": rep.descriptor_error}
    rows.append(["blend s=0.5 (dp)", sec, f"{rep.converged}/{rep.frames}", "",
                 rep.descriptor_error])
    # why mesh_close has its own closing: close_euclidean (frame-space Woodbury) against the
    # generic curves.closing.close (a (D,D) constraint-space system) on a 125-vertex body
    # (D ~ 1,000; at 1,000 vertices, D = 7,984, the generic one took 494 s and 1.5 GB)
    from shellspline.curves.closing import close as close_curve

    Vsmall, Fsmall, _ = skinned_sequence(clip, start=10, stop=44, n_vertices=125)
    mc = A.mesh_curve(Vsmall, Fsmall)
    X = mc.Z * mc.sqrt_w
    (Xe, he), sec_e, _ = _best(lambda: A.close_euclidean(X), repeat)
    rg, sec_g, _ = _best(lambda: close_curve(mc.product_curve()), repeat)
    diff = float(np.abs(Xe - rg.curve.X).max())
    res["closing_solvers"] = {"dims": int(X.shape[1]), "close_euclidean_seconds": sec_e,
                              "generic_seconds": sec_g, "max_difference": diff}
    rows.append([f"closing only, D = {X.shape[1]}: close_euclidean", sec_e, "",
                 f"gap {he[0]:.3g} -> {he[-1]:.2g}", ""])
    rows.append([f"closing only, D = {X.shape[1]}: curves.closing", sec_g, "",
                 f"max |difference| {diff:.1g}", ""])
    return res, rows


_LONG_CHILD = """
import json, resource, sys, time
sys.path.insert(0, sys.argv[1])
from shellspline.cli.main import main
t = time.perf_counter()
code = main(["motion", "distance", sys.argv[2], sys.argv[3], "-q"])
print(json.dumps({"seconds": time.perf_counter() - t, "code": code,
                  "peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))
"""


def long_clips(folder, seconds=40.0, fps=120.0):
    """Two long clips (``walk_normal`` and ``walk_tired`` resampled to ``fps`` and repeated
    to ``seconds``) written to ``folder``: the paths."""
    from shellspline.animation import resample
    from shellspline.io.bvh import Motion, read_bvh, write_bvh

    out = []
    for name in ("walk_normal", "walk_tired"):
        m = resample(read_bvh(MOTION / f"dataset-1_{name}_001.bvh"), frame_time=1.0 / fps)
        n = int(round(seconds * fps)) + 1
        v = np.concatenate([m.values] * int(np.ceil(n / m.n_frames)))[:n]
        out.append(write_bvh(Motion(m.names, m.parents, m.offsets, m.channels,
                                    m.frame_time, v, m.end_sites),
                             Path(folder) / f"long_{name}.bvh"))
    return out


def bench_long_distance(before="fd9258c", repeat=1, seconds=40.0):
    """``shellspline motion distance`` on two 40 s clips at 120 Hz (4,801 frames, 22 joints),
    in a child process per run (wall seconds of the command, peak resident memory), for the
    package at git revision ``before`` (extracted with ``git archive``) and for this tree."""
    rows, out = [], {"seconds_of_clip": seconds, "before": before}
    with tempfile.TemporaryDirectory() as tmp:
        a, b = long_clips(tmp, seconds)
        trees = [("this tree", str(REPO))]
        if before:
            old = Path(tmp) / "before"
            old.mkdir()
            arch = subprocess.run(["git", "-C", str(REPO), "archive", before, "shellspline"],
                                  capture_output=True, check=True).stdout
            subprocess.run(["tar", "-x", "-C", str(old)], input=arch, check=True)
            trees.insert(0, (f"before ({before})", str(old)))
        for label, root in trees:
            runs = []
            for _ in range(repeat):
                p = subprocess.run([sys.executable, "-c", _LONG_CHILD, root, str(a), str(b)],
                                   capture_output=True, text=True, timeout=900)
                lines = p.stdout.strip().splitlines()
                runs.append({"distance": float(lines[0]), **json.loads(lines[-1])})
            best = min(runs, key=lambda r: r["seconds"])
            out[label] = best
            rows.append([label, best["seconds"], best["peak_mb"], f"{best['distance']:.6f}"])
    return out, rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--fdasrsf-python", default=os.environ.get("FDASRSF_PYTHON"),
                    help="an interpreter with fdasrsf installed (default: this one, if it has "
                         "fdasrsf)")
    ap.add_argument("--fdasrsf-max", type=int, default=400,
                    help="largest size given to fdasrsf (1,600 frames take minutes)")
    ap.add_argument("--out", default=str(REPO / "benchmarks" / "results" / "bench_motion.json"))
    ap.add_argument("--long-only", action="store_true",
                    help="only section 7 (distance of two 40 s clips at 120 Hz)")
    ap.add_argument("--before", default="fd9258c",
                    help="git revision whose package section 7 also times (empty: none)")
    a = ap.parse_args(argv)
    if not MOTION.exists():
        print(f"{MOTION} not present: the walk clips live in ../shared/data")
        return 1
    res = {"machine": {"python": platform.python_version(), "numpy": np.__version__,
                       "cpus": os.cpu_count(), "load_before": os.getloadavg()}}
    if a.long_only:
        return _long_section(a, res)
    dp, rows = bench_dp(repeat=a.repeat, fdasrsf_python=a.fdasrsf_python,
                        fdasrsf_max=a.fdasrsf_max)
    res["dp"] = dp
    print(f"1. DP alignment, walk_normal -> walk_tired, {dp['sizes']['400']['dims']} dims "
          f"(fastest of {a.repeat}; energies: our exact elastic energy of each warp)")
    print(format_table(["frames / method", "seconds", "energy", "identity", "status"], rows))
    kw = dp["known_warp"]
    print(f"   known warp t^1.5, {kw['frames']} frames: sup error DP {kw['dp_sup_error']:.4f}, "
          f"refined {kw['refined_sup_error']:.4f}")
    t1, rows = bench_table1(repeat=a.repeat)
    res["table1"] = t1
    print("\n2. Seed 003 Table 1 sizes: closed curves (start-point search + DP, then + "
          "refinement)")
    print(format_table(["points / case", "paper s", "DP s", "DP energy", "refined s",
                        "refined energy", "refinement"], rows))
    cl, rows = bench_close(repeat=a.repeat)
    res["close"] = cl
    print(f"\n3. Closing walk_normal ({cl['frames']} frames, {cl['joints']} joints + root "
          "height)")
    print(format_table(["method", "seconds", "iterations", "gap before", "gap after",
                        "reduction", "velocity jump", "SRV change"], rows))
    ops, rows, close_rows = bench_motion_ops(repeat=a.repeat)
    res["motion_ops"] = ops
    print("\n4. End to end on the real clips (shellspline.animation; seconds: fastest of "
          f"{a.repeat})")
    print(format_table(["operation", "seconds", "frames", "result", ""], rows))
    print("\n5. Closing the walks (motion level: root travel kept, feet planted after)")
    print(format_table(["clip", "seconds", "iterations", "pose change", "seam gap",
                        "rotation gap deg", "joint jump units", "skate u/s in/closed/out"],
                       close_rows))
    mesh, rows = bench_mesh_animation()
    res["mesh_animation"] = mesh
    print(f"\n6. Mesh animation: body skinned to the walk ({mesh['vertices']} vertices, "
          f"{mesh['frames']} frames)")
    print(format_table(["operation", "seconds", "frames", "result", "descriptor error"],
                       rows))
    return _long_section(a, res)


def _long_section(a, res):
    long, rows = bench_long_distance(a.before, repeat=a.repeat)
    res["long_distance"] = long
    print("\n7. motion distance, two 40 s clips at 120 Hz (4,801 frames, 22 joints; a child "
          f"process per run, fastest of {a.repeat})")
    print(format_table(["package", "seconds", "peak MB", "distance"], rows))
    res["machine"]["load_after"] = os.getloadavg()
    out = Path(a.out)
    if a.long_only:  # leave the full run's file alone
        out = out.with_name(out.stem + "_long.json")
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(res, indent=1, default=float))
    print(f"\nwrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

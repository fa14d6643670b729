"""Benchmark of the multiresolution stages: simultaneous decimation and prolongation.

What is measured
----------------
Every case runs in a fresh Python process (its peak memory is its own):

* decimation of all keyframe poses to the target with

  - ``summed``: :func:`shellspline.decimate.decimate` (summed per-pose quadrics, the method),
  - ``pose0``: the same decimation run on pose 0 alone, then restricted to every pose,
  - ``replay``: ``fast-simplification`` on pose 0, collapse sequence replayed on the other
    poses (:func:`shellspline.decimate.decimate_replay`; skipped when not installed);

  each with its wall time and the worst (over poses) one-sided Hausdorff distance from the
  fine vertices to the coarse surface (:func:`~shellspline.decimate.hausdorff_fine_to_coarse`),
  also relative to the bounding-box diagonal;
* prolongation: :meth:`Prolongation.encode` time and :meth:`Prolongation.decode` time per
  in-between frame for a linearly blended coarse path, plus the quality of the prolonged
  sequence (flipped / degenerate faces by :func:`shellspline.pipeline.sequence_quality`);
* peak resident memory (``ru_maxrss``) of the case process, and its value after loading the
  keyframes (so the increment is the stages' own).

Cases
-----
``cactus-real``  ``../shared/data/cactus``: 19 poses, 5261 vertices, γ = 0.05 (paper Table 2);
                 prolongation with keyframes every 10 frames (K = 180)
``synth-150k``   ``data_synth.generate("cactus", n_vertices=150_000)``: 3 poses, base pinned,
                 decimated to 1000 vertices; prolongation with frames 0, 10, 20

Run
---
::

    cd /work/main
    PYTHONPATH=. python3 benchmarks/bench_multires.py             # both cases (~1-2 min)
    PYTHONPATH=. python3 benchmarks/bench_multires.py --cases cactus-real

The table goes to stdout, everything to ``benchmarks/results/bench_multires.json``. The
machine is shared: the load average is recorded with every case. Nothing is asserted.
"""
from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
import platform
import resource
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

CASES = ("cactus-real", "synth-150k")


def _load(case):
    import data_synth
    from shellspline import read_keyframes

    if case == "cactus-real":
        d = REPO.parent / "shared" / "data" / "cactus"
        paths = [d / f"cactus{i}.ply" for i in range(19)]
        kf = read_keyframes(paths)
        Vs, F = np.asarray(kf.V), np.asarray(kf.F)
        pin = d / "cactusBottomMask_indices.txt"
        pinned = np.loadtxt(pin, dtype=np.int64) if pin.exists() else None
        return Vs, F, pinned, 0.05, np.arange(Vs.shape[0]) * 10
    if case == "synth-150k":
        g = data_synth.generate("cactus", n_vertices=150_000)
        return g["V"], g["F"], g["pinned"], 1000, np.asarray(g["frames"])
    raise ValueError(f"unknown case {case!r}")


def _rss_mb():
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _run_case(case, q):
    from shellspline.decimate import decimate, decimate_replay, hausdorff_fine_to_coarse
    from shellspline.pipeline import linear_blend, sequence_quality
    from shellspline.prolong import Prolongation
    from shellspline.topology import topology

    res = {"case": case, "loadavg_before": os.getloadavg()}
    Vs, F, pinned, target, frames = _load(case)
    J, n, _ = Vs.shape
    diag = float(np.linalg.norm(Vs.max(axis=(0, 1)) - Vs.min(axis=(0, 1))))
    res.update(n=n, m=int(F.shape[0]), J=J, target=target, diag=diag,
               rss_after_load_mb=_rss_mb())

    t = time.perf_counter()
    dec = decimate(Vs, F, target, pinned=pinned)
    res["summed"] = {"seconds": time.perf_counter() - t, "nc": dec.n_vertices,
                     "rounds": dec.stats["rounds"]}
    res["rss_after_decimate_mb"] = _rss_mb()
    h = hausdorff_fine_to_coarse(Vs, dec.V, dec.F)
    res["summed"].update(hausdorff=float(h.max()), hausdorff_per_pose=h.tolist())

    t = time.perf_counter()
    d0 = decimate(Vs[0], F, target, pinned=pinned)
    res["pose0"] = {"seconds": time.perf_counter() - t, "nc": d0.n_vertices}
    res["pose0"]["hausdorff"] = float(hausdorff_fine_to_coarse(Vs, Vs[:, d0.kept], d0.F).max())

    try:
        t = time.perf_counter()
        Vr, Fr = decimate_replay(Vs, F, target)
        res["replay"] = {"seconds": time.perf_counter() - t, "nc": int(Vr.shape[1])}
        res["replay"]["hausdorff"] = float(hausdorff_fine_to_coarse(Vs, Vr, Fr).max())
    except ImportError:
        res["replay"] = None

    # prolongation of a linearly blended coarse path
    K = int(frames[-1])
    t = time.perf_counter()
    P = Prolongation.encode(Vs, F, dec, frames, pinned=pinned)
    res["encode_s"] = time.perf_counter() - t
    Vc = linear_blend(dec.V, frames, K)
    t = time.perf_counter()
    V = P.decode(Vc)
    n_between = K + 1 - J
    res["decode_s"] = time.perf_counter() - t
    res["decode_ms_per_frame"] = 1e3 * res["decode_s"] / max(n_between, 1)
    res["K"] = K
    res["rss_peak_mb"] = _rss_mb()
    T = topology(F, n)
    res["quality"] = sequence_quality(V, T, frames)
    res["keyframes_exact"] = bool(all(np.array_equal(V[f], Vs[j]) for j, f in enumerate(frames)))
    res["loadavg_after"] = os.getloadavg()
    q.put(res)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--cases", nargs="+", choices=CASES, default=list(CASES))
    ap.add_argument("--out", default=str(REPO / "benchmarks" / "results" / "bench_multires.json"))
    args = ap.parse_args(argv)
    ctx = mp.get_context("spawn")
    results = []
    for case in args.cases:
        q = ctx.Queue()
        p = ctx.Process(target=_run_case, args=(case, q))
        p.start()
        results.append(q.get())
        p.join()

    hdr = (f"{'case':<12} {'n':>7} {'J':>3} {'nc':>5} | {'summed s':>8} {'H_sum':>9} "
           f"{'H/diag':>8} | {'pose0 s':>7} {'H_pose0':>9} | {'replay s':>8} {'H_replay':>9} | "
           f"{'enc s':>6} {'dec ms/fr':>9} {'flip':>4} | {'RSS MB':>7}")
    print(hdr)
    print("-" * len(hdr))
    for r in results:
        rp = r["replay"]
        rep = (f"{rp['seconds']:8.2f} {rp['hausdorff']:9.2e}" if rp else f"{'-':>8} {'-':>9}")
        print(f"{r['case']:<12} {r['n']:>7} {r['J']:>3} {r['summed']['nc']:>5} | "
              f"{r['summed']['seconds']:8.2f} {r['summed']['hausdorff']:9.2e} "
              f"{r['summed']['hausdorff'] / r['diag']:8.2e} | "
              f"{r['pose0']['seconds']:7.2f} {r['pose0']['hausdorff']:9.2e} | {rep} | "
              f"{r['encode_s']:6.2f} {r['decode_ms_per_frame']:9.1f} "
              f"{r['quality']['flipped_faces']:>4} | {r['rss_peak_mb']:7.0f}")
    print("H: worst over poses of the one-sided Hausdorff distance fine vertices -> coarse "
          "surface; flip: flipped faces in the prolonged linear-path sequence; RSS: peak of "
          "the case process (after loading: " + ", ".join(
              f"{r['case']} {r['rss_after_load_mb']:.0f} MB" for r in results) + ")")
    print("load average per case: " + ", ".join(
        f"{r['case']} {r['loadavg_before'][0]:.1f}->{r['loadavg_after'][0]:.1f}"
        for r in results))
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    info = {"python": sys.version.split()[0], "numpy": np.__version__,
            "platform": platform.platform(), "cpus": os.cpu_count()}
    out.write_text(json.dumps({"machine": info, "results": results}, indent=2))
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

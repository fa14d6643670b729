"""Benchmark of the nonlinear model (paper Fig. 3): piecewise geodesic vs nonlinear spline vs LΘA.

Three ellipsoids (data_synth, N≈500, K=12, η=0.1): half-axes (max |x|, max |y|) per frame for
the three methods, the max difference nonlinear−LΘA vs spline−geodesic (paper: ~10× smaller),
the time of the nonlinear spline to a gradient-norm reduction of 1e-6 (or the reduction reached
within the time limit), iterations, time per iteration, and a pyinstrument summary of where
the time goes. Also ../shared/data/unit_sphere (frames 0, 3, 6, η=0.01) when present.

Usage: ``python benchmarks/bench_nonlinear.py [--vertices 500] [--time-limit 120]``.
Prints a table and writes ``benchmarks/results/bench_nonlinear.json``.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
import warnings
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

import data_synth  # noqa: E402
import shellspline as ss  # noqa: E402
from shellspline.geodesic import geodesic_interpolation  # noqa: E402
from shellspline.nonlinear_spline import nonlinear_spline  # noqa: E402

SHARED = REPO.parent / "shared" / "data" / "unit_sphere"


def half_axes(V):
    return np.abs(V[..., 0]).max(axis=-1), np.abs(V[..., 1]).max(axis=-1)


def run_case(name, Vkey, F, frames, K, eta, time_limit, profile=False):
    T = ss.topology(F)
    out = {"name": name, "n_vertices": int(Vkey.shape[1]), "K": int(K), "eta": eta,
           "frames": [int(f) for f in frames]}
    t = time.perf_counter()
    geo = geodesic_interpolation(Vkey, frames, K, T, eta=eta)
    out["geodesic"] = {"time_s": time.perf_counter() - t, "success": geo.success,
                       "newton_iterations": geo.nit,
                       "segment_energies": geo.segment_energies}
    t = time.perf_counter()
    lta = ss.interpolate((Vkey, F), frames=frames, K=K, eta=eta)
    out["lta"] = {"time_s": time.perf_counter() - t}
    trace = []
    t = time.perf_counter()
    kwargs = dict(eta=eta, init=lta.V, gtol=1e-6, max_iter=100000, max_time_s=time_limit,
                  callback=lambda i, F_, g: trace.append((time.perf_counter() - t, F_, g)))
    profiler = None
    if profile:
        try:
            from pyinstrument import Profiler
            profiler = Profiler()
            profiler.start()
        except ImportError:  # pragma: no cover
            profiler = None
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        spl = nonlinear_spline(Vkey, frames, K, T, **kwargs)
    wall = time.perf_counter() - t
    if profiler is not None:
        profiler.stop()
        out["profile_text"] = profiler.output_text(unicode=False, color=False, show_all=False)
    red = spl.grad_norms[-1] / spl.grad_norms[0]
    out["nonlinear"] = {"time_s": wall, "success": spl.success, "message": spl.message,
                        "nit": spl.nit, "nfev": spl.nfev,
                        "time_per_iteration_s": wall / max(spl.nit, 1),
                        "grad_reduction": red, "energy_initial": spl.energies[0],
                        "energy_final": spl.energies[-1],
                        "trace": [[a, b, c] for a, b, c in trace]}
    for tag, V in (("geodesic", geo.V), ("lta", lta.V), ("nonlinear", spl.V)):
        ax, ay = half_axes(V)
        out[tag]["half_axes_x"], out[tag]["half_axes_y"] = ax.tolist(), ay.tolist()

    def dist(A, B):  # max over frames of the half-axis difference
        (ax, ay), (bx, by) = half_axes(A), half_axes(B)
        return float(max(np.abs(ax - bx).max(), np.abs(ay - by).max()))

    out["max_diff_nonlinear_lta"] = dist(spl.V, lta.V)
    out["max_diff_nonlinear_geodesic"] = dist(spl.V, geo.V)
    out["max_vertex_diff_nonlinear_lta"] = float(np.abs(spl.V - lta.V).max())
    out["max_vertex_diff_nonlinear_geodesic"] = float(np.abs(spl.V - geo.V).max())
    return out


def summarise_profile(text, n=25):
    lines = [ln for ln in text.splitlines() if ln.strip()]
    return "\n".join(lines[:n])


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--vertices", type=int, default=500)
    ap.add_argument("--time-limit", type=float, default=120.0)
    ap.add_argument("--no-profile", action="store_true")
    args = ap.parse_args(argv)
    results = []
    d = data_synth.generate("ellipsoids", n_vertices=args.vertices)
    results.append(run_case("ellipsoids", d["V"], d["F"], d["frames"], 12, 0.1, args.time_limit,
                            profile=not args.no_profile))
    if all((SHARED / f).exists() for f in ("unitSphere1.ply", "unitSphere1_defX.ply",
                                           "unitSphere1_defY.ply")):
        meshes = [ss.read_mesh(SHARED / f) for f in ("unitSphere1.ply", "unitSphere1_defX.ply",
                                                     "unitSphere1_defY.ply")]
        Vkey = np.stack([m[0] for m in meshes])
        results.append(run_case("unit_sphere", Vkey, meshes[0][1], np.array([0, 3, 6]), 6, 0.01,
                                args.time_limit))
    else:
        print(f"skipping unit_sphere: {SHARED} not present")
    hdr = (f"{'case':12s} {'N':>5s} {'K':>3s} {'geo s':>7s} {'lta s':>6s} {'nl s':>7s} "
           f"{'nit':>5s} {'s/it':>6s} {'|g|/|g0|':>9s} {'F0':>10s} {'F':>10s} "
           f"{'ax nl-lta':>9s} {'ax nl-geo':>9s} {'ratio':>6s}")
    print(hdr)
    print("-" * len(hdr))
    for r in results:
        nl = r["nonlinear"]
        ratio = r["max_diff_nonlinear_geodesic"] / max(r["max_diff_nonlinear_lta"], 1e-300)
        print(f"{r['name']:12s} {r['n_vertices']:5d} {r['K']:3d} {r['geodesic']['time_s']:7.2f} "
              f"{r['lta']['time_s']:6.2f} {nl['time_s']:7.2f} {nl['nit']:5d} "
              f"{nl['time_per_iteration_s']:6.2f} {nl['grad_reduction']:9.2e} "
              f"{nl['energy_initial']:10.4f} {nl['energy_final']:10.4f} "
              f"{r['max_diff_nonlinear_lta']:9.2e} {r['max_diff_nonlinear_geodesic']:9.2e} "
              f"{ratio:6.1f}")
    r0 = results[0]
    print("\nhalf axes (x, y) per frame, ellipsoids:")
    print(f"{'k':>3s} {'geo x':>7s} {'geo y':>7s} {'nl x':>7s} {'nl y':>7s} {'lta x':>7s} "
          f"{'lta y':>7s}")
    for k in range(r0["K"] + 1):
        print(f"{k:3d} {r0['geodesic']['half_axes_x'][k]:7.4f} "
              f"{r0['geodesic']['half_axes_y'][k]:7.4f} {r0['nonlinear']['half_axes_x'][k]:7.4f} "
              f"{r0['nonlinear']['half_axes_y'][k]:7.4f} {r0['lta']['half_axes_x'][k]:7.4f} "
              f"{r0['lta']['half_axes_y'][k]:7.4f}")
    if "profile_text" in r0:
        print("\nprofile (pyinstrument, ellipsoids nonlinear spline):")
        print(summarise_profile(r0["profile_text"]))
    outdir = REPO / "benchmarks" / "results"
    outdir.mkdir(parents=True, exist_ok=True)
    path = outdir / "bench_nonlinear.json"
    path.write_text(json.dumps(results, indent=1, default=float))
    print(f"\nwrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""Benchmark of the nonlinear model (paper Figs. 3 and 10): piecewise geodesic vs nonlinear
spline vs LΘA.

* Fig. 3, three ellipsoids (data_synth, N≈500, K=12, η=0.1): half-axes (max |x|, max |y|) per
  frame for the three methods, the max difference nonlinear−LΘA vs spline−geodesic (paper:
  ~10× smaller), the time of the nonlinear spline to a gradient-norm reduction of 1e-6 (or the
  reduction reached within the time limit), outer iterations, CG iterations, time per outer
  iteration, and a pyinstrument summary of where the time goes. ``--lbfgs`` also runs the
  L-BFGS optimiser on the same problem (same time limit) for the ratio.
* ../shared/data/unit_sphere (sphere → stretched X → stretched Y at frames 0, 3, 6, η=0.01)
  when present.
* Fig. 10, hexagon folds (data_synth "hexagon", periodic, K=12): η = 1e-4 on the unit hexagon
  (circumradius R = 1) vs η = 10 on the hexagon scaled to R = 30, the max edge strain against
  the flat rest hexagon along the curve for the three methods (small η: near-isometric).
  Only η/R² matters (membrane terms scale with R², W_Θ is scale-invariant), so the second case
  is η ≈ 0.011 on the unit hexagon. η = 10 on the unit hexagon has no minimiser: the path
  energy keeps falling as intermediate shells collapse their crease edges (their bending
  weight l_e²/d_e as the undeformed shell goes to 0; edges at 2e-4 of their length after 60
  Newton steps, membrane cost < 1 % of the energy), so neither the geodesic nor the spline
  can converge there (``--hexagon-unit-eta10`` runs it to show this).
* ``--cactus``: ../shared/data/cactus (poses 0/5/13 at frames 0/10/20, base pinned),
  ``interpolate(method="nonlinear", coarse=1000, K=20, η=1e-3)`` (issue target ≤ 5 min);
  minutes, not run by default.

Usage: ``python benchmarks/bench_nonlinear.py [--vertices 500] [--time-limit 120] [--lbfgs]
[--cactus] [--plots DIR | --no-plots]``.
Prints tables and writes ``benchmarks/results/bench_nonlinear.json``; with the viz extra also
the reproduction figures (PNG, default in ``benchmarks/results``): ``fig3_ellipsoids.png``
(half-axes per frame of the three methods, and the nonlinear−LΘA against nonlinear−geodesic
half-axis differences), ``unit_sphere.png`` (the same), ``fig10_hexagon_strain.png`` (max edge
strain per frame, both η) and ``fig10_hexagon_strip.png`` (filmstrips of the two nonlinear
splines, off-screen rendering).
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
from shellspline import metrics  # noqa: E402
from shellspline.shells.descriptors import edge_lengths  # noqa: E402
from shellspline.shells.geodesic import geodesic_interpolation  # noqa: E402
from shellspline.shells.nonlinear import FTOL_WINDOW, nonlinear_spline  # noqa: E402

SHARED = REPO.parent / "shared" / "data" / "unit_sphere"


def half_axes(V):
    ha = metrics.half_axes(V)
    return ha[..., 0], ha[..., 1]


def run_case(name, Vkey, F, frames, K, eta, time_limit, profile=False, bc="natural",
             lbfgs=False):
    T = ss.topology(F)
    out = {"name": name, "n_vertices": int(Vkey.shape[1]), "K": int(K), "eta": eta, "bc": bc,
           "frames": [int(f) for f in frames]}
    t = time.perf_counter()
    geo = geodesic_interpolation(Vkey, frames, K, T, eta=eta, bc=bc)
    out["geodesic"] = {"time_s": time.perf_counter() - t, "success": geo.success,
                       "newton_iterations": geo.nit,
                       "segment_energies": geo.segment_energies}
    t = time.perf_counter()
    # interpolate's η is relative to sqrt(area) of keyframe 0; the solvers here take it absolute
    lta = ss.interpolate((Vkey, F), frames=frames, K=K, bc=bc,
                         eta=eta / ss.metrics.length_scale(Vkey[0], F) ** 2)
    out["lta"] = {"time_s": time.perf_counter() - t}
    trace = []
    t = time.perf_counter()
    kwargs = dict(eta=eta, init=lta.V, gtol=1e-6, max_iter=100000, max_time_s=time_limit, bc=bc,
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
    out["nonlinear"] = {"time_s": wall, "success": spl.success, "status": spl.status,
                        "message": spl.message,
                        "optimizer": spl.optimizer, "nit": spl.nit, "nfev": spl.nfev,
                        "cg_iterations": spl.cg_iterations, "step_lengths": spl.step_lengths,
                        "midpoint_newton_iterations": spl.midpoint_newton_iterations,
                        "time_per_iteration_s": wall / max(spl.nit, 1),
                        "grad_reduction": red, "energy_initial": spl.energies[0],
                        "energy_final": spl.energies[-1],
                        "trace": [[a, b, c] for a, b, c in trace]}
    if lbfgs:
        t = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            lb = nonlinear_spline(Vkey, frames, K, T, eta=eta, init=lta.V, gtol=1e-6, bc=bc,
                                  max_iter=100000, max_time_s=time_limit, optimizer="lbfgs",
                                  precondition=False)
        wall = time.perf_counter() - t
        out["lbfgs"] = {"time_s": wall, "success": lb.success, "status": lb.status,
                        "nit": lb.nit, "nfev": lb.nfev,
                        "grad_reduction": lb.grad_norms[-1] / lb.grad_norms[0],
                        "energy_final": lb.energies[-1]}
    for tag, V in (("geodesic", geo.V), ("lta", lta.V), ("nonlinear", spl.V)):
        ax, ay = half_axes(V)
        out[tag]["half_axes_x"], out[tag]["half_axes_y"] = ax.tolist(), ay.tolist()
        out[tag]["keyframe_kinks"] = metrics.keyframe_kinks(V, frames).tolist()
    out["_V"] = {"geodesic": geo.V, "lta": lta.V, "nonlinear": spl.V}

    def dist(A, B):  # max over frames of the half-axis difference
        (ax, ay), (bx, by) = half_axes(A), half_axes(B)
        return float(max(np.abs(ax - bx).max(), np.abs(ay - by).max()))

    out["max_diff_nonlinear_lta"] = dist(spl.V, lta.V)
    out["max_diff_nonlinear_geodesic"] = dist(spl.V, geo.V)
    out["max_vertex_diff_nonlinear_lta"] = float(np.abs(spl.V - lta.V).max())
    out["max_vertex_diff_nonlinear_geodesic"] = float(np.abs(spl.V - geo.V).max())
    return out


CACTUS = REPO.parent / "shared" / "data" / "cactus"


def run_cactus(time_limit):
    """Nonlinear spline through the shared cactus (issue target: ≤ 5 min at 1000 coarse
    vertices, K = 20) through the public pipeline; prints and returns its record."""
    files = [CACTUS / f for f in ("cactus0.ply", "cactus5.ply", "cactus13.ply")]
    if not all(f.exists() for f in files):
        print(f"skipping cactus: {CACTUS} not present")
        return {"name": "cactus", "skipped": True}
    pinned = ss.read_indices(CACTUS / "cactusBottomMask_indices.txt")
    kf = ss.read_keyframes(files, frames=[0, 10, 20], pinned=pinned)
    t = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        # η = 1e-3 in the cactus' units, as measured before η became relative to
        # sqrt(area) of keyframe 0 (D² = 0.45 here)
        r = ss.interpolate(kf, K=20, method="nonlinear", coarse=1000,
                           eta=1e-3 / ss.metrics.length_scale(kf.V[0], kf.topology.F) ** 2,
                           solver_options={"max_time_s": max(time_limit, 300.0)})
    wall = time.perf_counter() - t
    nl = r.report["nonlinear"]
    rec = {"name": "cactus", "n_vertices": int(kf.V.shape[1]), "K": 20, "eta": 1e-3,
           "total_s": wall, **{k: nl[k] for k in (
               "vertices", "success", "message", "nit", "nfev", "seconds", "energy_initial",
               "energy_final", "grad_norm_initial", "grad_norm_final", "cg_iterations",
               "midpoint_newton_iterations", "energy_history", "grad_norm_history",
               "time_history", "step_lengths", "hessian")}}
    rec["grad_reduction"] = rec["grad_norm_final"] / rec["grad_norm_initial"]
    # when `ftol` (energy fell by <= ftol·F over FTOL_WINDOW iterations) would have stopped
    E, tt = np.asarray(rec["energy_history"]), rec["time_history"]
    rec["ftol_stop"] = {}
    for ftol in (1e-5, 1e-6, 1e-7):
        hit = [i for i in range(FTOL_WINDOW, len(E)) if E[i - FTOL_WINDOW] - E[i] <= ftol * E[i]]
        rec["ftol_stop"][f"{ftol:g}"] = None if not hit else {
            "iteration": hit[0], "seconds": tt[hit[0]], "energy": float(E[hit[0]]),
            "energy_rel_to_final": float((E[hit[0]] - E[-1]) / E[-1]),
            "grad_reduction": rec["grad_norm_history"][hit[0]] / rec["grad_norm_initial"]}
    print(f"\ncactus ({rec['n_vertices']} vertices, nonlinear at {rec['vertices']} coarse, K=20, "
          f"η=1e-3): total {wall:.0f} s, optimiser {rec['seconds']:.0f} s, {rec['nit']} outer "
          f"iterations ({rec['seconds'] / max(rec['nit'], 1):.1f} s each), F "
          f"{rec['energy_initial']:.4g} -> {rec['energy_final']:.4g}, |g|/|g0| = "
          f"{rec['grad_reduction']:.1e}; {rec['message']}")
    print("  per outer iteration: F " + " ".join(f"{e:.5g}" for e in rec["energy_history"])
          + "\n  |g|/|g0| " + " ".join(f"{g / rec['grad_norm_initial']:.1e}"
                                       for g in rec["grad_norm_history"])
          + "\n  seconds " + " ".join(f"{t:.0f}" for t in rec["time_history"]))
    for key, hit in rec["ftol_stop"].items():
        print(f"  ftol={key}: " + ("not reached" if hit is None else
              f"stops at iteration {hit['iteration']} ({hit['seconds']:.0f} s), F "
              f"{hit['energy']:.7g} ({hit['energy_rel_to_final']:.1e} above the last), "
              f"|g|/|g0| {hit['grad_reduction']:.1e}"))
    return rec


METHODS = (("geodesic", "piecewise geodesic"), ("nonlinear", "nonlinear spline"),
           ("lta", "LΘA spline"))
COLORS = {"geodesic": "#59a14f", "nonlinear": "#f28e2b", "lta": "#4e79a7"}


def half_axes_figure(r):
    """Paper Fig. 3 for one case record of :func:`run_case`: half-axes (x solid, y dashed)
    per frame of the three methods (left); |nonlinear − LΘA| and |nonlinear − geodesic|,
    the larger of the x and y half-axis differences, per frame (right)."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(10.0, 3.8), layout="constrained")
    left, right = fig.subplots(1, 2, width_ratios=(3, 2))
    k = np.arange(r["K"] + 1)
    for tag, label in METHODS:
        for axis, ls in (("x", "-"), ("y", "--")):
            left.plot(k, r[tag][f"half_axes_{axis}"], color=COLORS[tag], ls=ls, lw=1.8,
                      label=f"{label} {axis}")
    _frame_axes(left, r["frames"], "half-axis",
                f"{r['name']}: half-axes along the curve (N={r['n_vertices']}, K={r['K']}, "
                f"η={r['eta']:g})", ncol=3)
    for other, label in (("lta", "nonlinear − LΘA"), ("geodesic", "nonlinear − geodesic")):
        d = half_axis_difference(r, other)
        right.plot(k, d, color=COLORS[other], lw=1.8, marker="o", ms=3,
                   label=f"|{label}| (max {d.max():.2e})")
    _frame_axes(right, (), "half-axis difference", "difference to the nonlinear spline")
    return fig


def _frame_axes(ax, frames, ylabel, title, ncol=1):
    """Keyframes as dotted gray lines, labels, title, legend and grid of a per-frame plot."""
    for f in frames:
        ax.axvline(f, color="#a6a6a6", lw=1.0, ls=":", zorder=0)
    ax.set_xlabel("frame k")
    ax.set_ylabel(ylabel)
    ax.set_title(title, fontsize=10)
    ax.legend(fontsize=7, ncol=ncol)
    ax.grid(alpha=0.3)


def half_axis_difference(r, other):
    """Per frame, max over x and y of |half-axis(nonlinear) − half-axis(other)|."""
    nl, ot = r["nonlinear"], r[other]
    return np.maximum(np.abs(np.subtract(nl["half_axes_x"], ot["half_axes_x"])),
                      np.abs(np.subtract(nl["half_axes_y"], ot["half_axes_y"])))


def strain_figure(hexagon):
    """Paper Fig. 10: max edge strain against the flat hexagon per frame, one panel per
    (R, η) case, the three methods in each."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(5.0 * len(hexagon), 3.6), layout="constrained")
    axes = np.atleast_1d(fig.subplots(1, len(hexagon)))
    for ax, r in zip(axes, hexagon):
        k = np.arange(r["K"] + 1)
        for tag, label in METHODS:
            ax.plot(k, r[tag]["edge_strain_per_frame"], color=COLORS[tag], lw=1.8,
                    label=f"{label} (max {r[tag]['max_edge_strain']:.1e})")
        _frame_axes(ax, r["frames"], "max edge strain",
                    f"hexagon fold, R = {r['radius']:g}, η = {r['eta']:g} "
                    f"(η/R² = {r['eta_unit']:.1e})")
    return fig


def write_plots(results, hexagon, hex_F, outdir):
    """Save the reproduction figures (atomically) and return their paths; ``[]`` with a note
    when the viz extra is missing."""
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        print('no plots: they need the viz extra (pip install "shellspline[viz]")')
        return []
    outdir = Path(outdir)
    outdir.mkdir(parents=True, exist_ok=True)

    def save(fig, name):
        path = outdir / name
        tmp = path.with_name(path.stem + ".tmp.png")
        fig.savefig(tmp, dpi=120)
        tmp.replace(path)
        return path

    written = []
    for r in results:
        if r["name"] in ("ellipsoids", "unit_sphere"):
            name = "fig3_ellipsoids.png" if r["name"] == "ellipsoids" else "unit_sphere.png"
            written.append(save(half_axes_figure(r), name))
    if hexagon:
        written.append(save(strain_figure(hexagon), "fig10_hexagon_strain.png"))
        try:
            from shellspline import viz

            for r in hexagon:
                tag = f"R{r['radius']:g}_eta{r['eta']:g}"
                # periodic: frame K is frame 0 again, so drawn as a keyframe too
                key = list(r["frames"]) + ([r["K"]] if r.get("bc") == "periodic" else [])
                written.append(viz.render_strip((r["_V"]["nonlinear"], hex_F, key),
                                                outdir / f"fig10_hexagon_strip_{tag}.png",
                                                frames=range(0, r["K"] + 1, 2), view="iso"))
        except Exception as exc:  # no off-screen OpenGL here: the strain plot stands alone
            print(f"no hexagon filmstrips: {exc}")
    return written


def summarise_profile(text, n=25):
    lines = [ln for ln in text.splitlines() if ln.strip()]
    return "\n".join(lines[:n])


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--vertices", type=int, default=500)
    ap.add_argument("--time-limit", type=float, default=120.0)
    ap.add_argument("--no-profile", action="store_true")
    ap.add_argument("--lbfgs", action="store_true",
                    help="also run the L-BFGS optimiser on the ellipsoids (same time limit)")
    ap.add_argument("--hexagon-vertices", type=int, default=300,
                    help="vertices of the Fig. 10 hexagon (0 skips it)")
    ap.add_argument("--hexagon-unit-eta10", action="store_true",
                    help="also run η=10 on the unit hexagon (degenerate: does not converge)")
    ap.add_argument("--cactus", action="store_true",
                    help="nonlinear spline on the shared cactus at 1000 coarse vertices, K=20")
    ap.add_argument("--plots", default=str(REPO / "benchmarks" / "results"),
                    help="folder of the reproduction figures (PNG; needs the viz extra)")
    ap.add_argument("--no-plots", action="store_true", help="write no figures")
    args = ap.parse_args(argv)
    hex_F = None
    results = []
    d = data_synth.generate("ellipsoids", n_vertices=args.vertices)
    results.append(run_case("ellipsoids", d["V"], d["F"], d["frames"], 12, 0.1, args.time_limit,
                            profile=not args.no_profile, lbfgs=args.lbfgs))
    if all((SHARED / f).exists() for f in ("unitSphere1.ply", "unitSphere1_defX.ply",
                                           "unitSphere1_defY.ply")):
        meshes = [ss.read_mesh(SHARED / f) for f in ("unitSphere1.ply", "unitSphere1_defX.ply",
                                                     "unitSphere1_defY.ply")]
        Vkey = np.stack([m[0] for m in meshes])
        results.append(run_case("unit_sphere", Vkey, meshes[0][1], np.array([0, 3, 6]), 6, 0.01,
                                args.time_limit))
    else:
        print(f"skipping unit_sphere: {SHARED} not present")
    hexagon = []
    if args.hexagon_vertices:
        h = data_synth.generate("hexagon", n_vertices=args.hexagon_vertices)
        T = ss.topology(h["F"])
        hex_F = h["F"]
        bc = "periodic" if h.get("periodic") else "natural"
        cases = [(1.0, 1e-4), (30.0, 10.0)] + ([(1.0, 10.0)] if args.hexagon_unit_eta10 else [])
        for R, eta in cases:
            r = run_case(f"hex R={R:g} η={eta:g}", R * h["V"], h["F"], h["frames"], 12, eta,
                         args.time_limit, bc=bc)
            r["radius"], r["eta_unit"] = R, eta / R ** 2
            for tag in ("geodesic", "lta", "nonlinear"):
                strain = metrics.edge_strain(r["_V"][tag], R * h["rest"], T)
                r[tag]["max_edge_strain"] = float(strain.max())
                r[tag]["edge_strain_per_frame"] = strain.tolist()
            r["keyframe_max_edge_strain"] = float(metrics.edge_strain(h["V"], h["rest"],
                                                                      T).max())
            Vg = r["_V"]["geodesic"]
            r["geodesic"]["min_edge_ratio"] = float(min(
                (edge_lengths(V, T) / edge_lengths(
                    R * h["rest"], T)).min() for V in Vg))
            results.append(r)
            hexagon.append(r)
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
    if hexagon:
        print("\nFig. 10, hexagon folds: max edge strain against the flat hexagon along the "
              "curve")
        print(f"{'R':>4s} {'eta':>8s} {'eta/R²':>8s} {'keyframes':>9s} {'geodesic':>9s} "
              f"{'lta':>9s} {'nonlinear':>9s} {'geo ok':>6s} {'nl ok':>5s} {'nl nit':>6s} "
              f"{'min edge':>8s}")
        for r in hexagon:
            print(f"{r['radius']:4g} {r['eta']:8.0e} {r['eta_unit']:8.1e} "
                  f"{r['keyframe_max_edge_strain']:9.2e} "
                  f"{r['geodesic']['max_edge_strain']:9.2e} {r['lta']['max_edge_strain']:9.2e} "
                  f"{r['nonlinear']['max_edge_strain']:9.2e} {str(r['geodesic']['success']):>6s} "
                  f"{str(r['nonlinear']['success']):>5s} {r['nonlinear']['nit']:6d} "
                  f"{r['geodesic']['min_edge_ratio']:8.1e}")
    if "lbfgs" in r0:
        lb, nl = r0["lbfgs"], r0["nonlinear"]
        print(f"\nellipsoids, same problem and time limit: gauss-newton {nl['time_s']:.1f} s, "
              f"{nl['nit']} iterations, |g|/|g0| = {nl['grad_reduction']:.1e}; lbfgs "
              f"{lb['time_s']:.1f} s, {lb['nit']} iterations, |g|/|g0| = "
              f"{lb['grad_reduction']:.1e}")
    print(f"\nellipsoids CG iterations per outer iteration: {r0['nonlinear']['cg_iterations']}")
    if "profile_text" in r0:
        print("\nprofile (pyinstrument, ellipsoids nonlinear spline):")
        print(summarise_profile(r0["profile_text"]))
    if not args.no_plots:
        for path in write_plots(results, hexagon, hex_F, args.plots):
            print(f"wrote {path}")
    if args.cactus:
        results.append(run_cactus(args.time_limit))
    outdir = REPO / "benchmarks" / "results"
    outdir.mkdir(parents=True, exist_ok=True)
    path = outdir / "bench_nonlinear.json"
    for r in results:
        r.pop("_V", None)
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(results, indent=1, default=float))
    tmp.replace(path)
    print(f"\nwrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

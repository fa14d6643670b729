"""End-to-end benchmark of LΘA keyframe interpolation (``shellspline.interpolate``).

What is measured
----------------
Every case runs in a fresh Python process (so that its peak memory is its own and no cache
or warm CHOLMOD analysis leaks from one case into the next) and measures, in that one
process, one after the other:

* the keyframe input: reading the PLY files (synthetic data are generated, written as PLY into
  a temporary directory and read back, so both cases read the same way);
* ``interpolate(method="lta")``: the stage times of ``report["timings"]`` (describe, spline
  solve, Gauss–Newton reconstruct, place, energies, quality, total), the Gauss–Newton counts
  (frames converged, iterations total/max, CG iterations, factorizations) and the output
  quality (flipped/degenerate faces, keyframes reproduced exactly);
* ``interpolate(method="linear")`` on the same keyframes: per-vertex blending, the baseline;
* ``write_sequence`` of the LΘA result as OBJ and as PLY into a temporary directory: the
  "floor" that any method producing this output must pay;
* peak resident memory (``ru_maxrss``) of the case process and of its worker processes, read
  right after the LΘA run.

Derived numbers: ms per Gauss–Newton iteration as ``reconstruct × workers / iterations``
(CPU-ms, comparable across worker counts when the workers scale), ``reconstruct /
iterations`` (wall) and ``Σ frame seconds / iterations`` (time a worker really spent per
iteration, which exposes contention); and the ratios ``lta_total / linear_total`` and
``lta_total / write_time``. Ratios taken inside one run are what matter: the machine is
shared and noisy, so the script also records the load average around every case and, right
before every parallel case, a quick probe of how well the worker processes can scale on it.

The paper's numbers (Heeren et al. 2016, Tables 1–2, one core of an i7-2600) and the project
targets are printed alongside.

Cases
-----
``cactus-K20``   real cactus (``../shared/data/cactus``), keyframes cactus0/5/13 at 0,10,20
``cactus-K170``  the same keyframes at 0,85,170 (paper Table 2 setting)
``synth-150k``   ``data_synth.generate("cactus")`` with >= 150 000 vertices, keyframes at
                 0, K//2, K (K=20 unless ``--synth-K``). Above 20 000 vertices
                 ``interpolate`` takes its multiresolution path by default (decimate, LΘA and
                 Gauss–Newton on the coarse mesh, prolong), which is what is timed; the
                 Gauss–Newton numbers of this case are those of the coarse mesh.

Run
---
::

    cd /work/main
    PYTHONPATH=. python3 benchmarks/bench_lta.py            # full (a few minutes)
    PYTHONPATH=. python3 benchmarks/bench_lta.py --quick    # cactus K=20 only (< 1 minute)
    PYTHONPATH=. python3 benchmarks/bench_lta.py --cases cactus-K20 synth-150k --workers 2

The table goes to stdout and everything (plus machine/version information) to
``benchmarks/results/bench_lta.json``. This is a benchmark, not a test: nothing is asserted.
"""
from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
import platform
import signal
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass
from pathlib import Path

from _common import _fmt, _peak_rss_mb, _timed, format_table  # noqa: E402  (benchmarks/ is on sys.path)

REPO = Path(__file__).resolve().parents[1]
CACTUS_DIR = REPO.parent / "shared" / "data" / "cactus"
CACTUS_FILES = ("cactus0.ply", "cactus5.ply", "cactus13.ply")
CACTUS_PINNED = "cactusBottomMask_indices.txt"
SYNTH_MIN_VERTICES = 150_000
DEFAULT_OUT = REPO / "benchmarks" / "results" / "bench_lta.json"
THREAD_VARS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")

#: Heeren et al. 2016, Tables 1–2 (single core, Intel i7-2600), full-resolution cactus.
PAPER = {
    "vertices": 5200,
    "ms_per_gn_iteration": 500.0,
    "cactus_K20_total_s": 83.0,
    "cactus_K170_total_s": 762.0,
}
#: Project targets (5.2k-vertex cactus).
TARGETS = {"ms_per_gn_iteration": 25.0, "cactus_K20_total_s": 5.0}


@dataclass(frozen=True)
class Case:
    """One benchmark case: which keyframes, how many frames, how many workers."""

    name: str
    source: str  # "cactus" (files) or "synth" (data_synth)
    frames: tuple
    K: int
    workers: int
    note: str = ""

    @property
    def label(self) -> str:
        return f"{self.name} w{self.workers}"


# --------------------------------------------------------------------------------------
# case selection
# --------------------------------------------------------------------------------------
CASE_NAMES = ("cactus-K20", "cactus-K170", "synth-150k")


def selected_cases(names, quick: bool, workers: int, synth_K: int) -> list[Case]:
    """The cases to run, in order.

    ``--quick``: cactus K=20 only. Full: every case in :data:`CASE_NAMES`. The cactus
    cases run with 1 and with ``workers`` workers, the synthetic one with ``workers``.
    """
    names = names or (("cactus-K20",) if quick else CASE_NAMES)
    counts = (1, workers) if workers != 1 else (1,)
    cases = []
    for name in names:
        if name == "cactus-K20":
            cases += [Case(name, "cactus", (0, 10, 20), 20, w) for w in counts]
        elif name == "cactus-K170":
            cases += [Case(name, "cactus", (0, 85, 170), 170, w) for w in counts]
        elif name == "synth-150k":
            note = "" if synth_K == 20 else f"K={synth_K} instead of 20"
            cases.append(Case(name, "synth", (0, synth_K // 2, synth_K), synth_K, workers,
                              note))
        else:
            raise ValueError(f"unknown case {name!r}; choose from {CASE_NAMES}")
    return cases


# --------------------------------------------------------------------------------------
# inside the case process
# --------------------------------------------------------------------------------------
def _keyframes(case: Case, tmp: Path):
    """Read the case's keyframes; returns (Keyframes, input-timing dict)."""
    import shellspline as ss

    timing = {}
    if case.source == "cactus":
        paths = [CACTUS_DIR / f for f in CACTUS_FILES]
        pinned_path = CACTUS_DIR / CACTUS_PINNED
    else:
        import data_synth

        data, timing["generate"] = _timed(_synthetic_cactus, SYNTH_MIN_VERTICES)
        data["frames"] = list(case.frames)
        paths, timing["write_keyframes"] = _timed(data_synth.write_keyframes, data,
                                                  tmp / "keyframes", fmt="ply")
        pinned_path = tmp / "keyframes" / "pinned.txt"
    pinned = ss.read_indices(pinned_path) if pinned_path.exists() else None
    kf, timing["read"] = _timed(ss.read_keyframes, paths, frames=list(case.frames),
                                pinned=pinned)
    return kf, timing


def _synthetic_cactus(min_vertices: int) -> dict:
    """``data_synth`` cactus with at least ``min_vertices`` vertices (the count is approximate)."""
    import data_synth

    request = min_vertices
    while True:
        data = data_synth.generate("cactus", n_vertices=request)
        if data["V"].shape[1] >= min_vertices:
            return data
        request = int(request * 1.02) + 1


#: Columns of the stage table. ``interpolate`` prefixes the LΘA stages with ``"coarse "`` /
#: ``"fine "`` on its multiresolution path; those are summed into the plain stage.
STAGES = ("describe", "solve", "reconstruct", "place", "multires", "energies", "quality",
          "other")
_MULTIRES_STAGES = ("decimate", "prolong")


def stage_seconds(timings: dict) -> dict:
    """``report["timings"]`` grouped into :data:`STAGES` (seconds; ``total`` kept apart)."""
    out = dict.fromkeys(STAGES, 0.0)
    for key, sec in timings.items():
        if key in ("total", "read"):
            continue
        name = key.removeprefix("coarse ").removeprefix("fine ")
        name = "multires" if name in _MULTIRES_STAGES else name
        out[name if name in out else "other"] += sec
    return out


def _gn_per_iteration(report: dict, workers: int) -> dict:
    gn = report.get("gauss_newton") or {}
    it = gn.get("iterations_total", 0)
    rec = stage_seconds(report["timings"])["reconstruct"]
    busy = sum(r.get("seconds", 0.0) for r in report.get("frames", []))
    if not it:
        return {}
    return {"ms_per_it_cpu": 1e3 * rec * workers / it,
            "ms_per_it_wall": 1e3 * rec / it,
            "ms_per_it_busy": 1e3 * busy / it}


def _multires_summary(report: dict) -> dict | None:
    m = report.get("multires")
    if not m:
        return None
    return {"coarse_vertices": m.get("coarse_vertices"), "coarse_faces": m.get("coarse_faces")}


def measure_case(case: Case) -> dict:
    """Run one case in this process and return its measurements (JSON-friendly)."""
    import shellspline as ss

    with tempfile.TemporaryDirectory(prefix="bench_lta_") as tmpdir:
        tmp = Path(tmpdir)
        kf, input_timing = _keyframes(case, tmp)
        lta, lta_wall = _timed(ss.interpolate, kf, K=case.K, method="lta",
                               workers=case.workers)
        peak = _peak_rss_mb()
        lin, lin_wall = _timed(ss.interpolate, kf, K=case.K, method="linear")
        _, write_obj = _timed(ss.write_sequence, tmp / "out_obj", lta.V, lta.F, lta.report,
                              overwrite=True, fmt="obj")
        _, write_ply = _timed(ss.write_sequence, tmp / "out_ply", lta.V, lta.F, lta.report,
                              overwrite=True, fmt="ply")
    rep = lta.report
    lta_total = rep["timings"]["total"]
    lin_total = lin.report["timings"]["total"]
    return {
        "vertices": int(kf.V.shape[1]),
        "faces": int(len(kf.F)),
        "input": input_timing,
        "lta": {"timings": rep["timings"], "stages": stage_seconds(rep["timings"]),
                "wall": lta_wall, "multires": _multires_summary(rep),
                "gauss_newton": rep.get("gauss_newton", {}),
                "per_iteration": _gn_per_iteration(rep, case.workers),
                "quality": rep["quality"],
                "frames": [{k: r.get(k) for k in ("frame", "nit", "seconds", "success",
                                                  "cg_iterations", "factorizations")}
                           for r in rep.get("frames", [])]},
        "linear": {"total": lin_total, "wall": lin_wall, "timings": lin.report["timings"]},
        "write": {"obj": write_obj, "ply": write_ply},
        "ratios": {"lta_over_linear": lta_total / lin_total,
                   "lta_over_write_obj": lta_total / write_obj,
                   "lta_over_write_ply": lta_total / write_ply},
        "peak_rss_mb": peak,
    }


def _case_process_main(spec_path: str, result_path: str) -> int:
    spec = json.loads(Path(spec_path).read_text())
    case = Case(**{**spec, "frames": tuple(spec["frames"])})
    result = measure_case(case)
    Path(result_path).write_text(json.dumps(result, indent=1))
    return 0


# --------------------------------------------------------------------------------------
# driver side
# --------------------------------------------------------------------------------------
def run_isolated(case: Case, timeout: float, threads: int | None) -> dict:
    """Run ``measure_case(case)`` in a fresh interpreter; a status dict on failure/timeout."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(REPO), env.get("PYTHONPATH")) if p)
    if threads:
        env.update({v: str(threads) for v in THREAD_VARS})
    with tempfile.TemporaryDirectory(prefix="bench_lta_case_") as tmpdir:
        spec, out = Path(tmpdir) / "case.json", Path(tmpdir) / "result.json"
        spec.write_text(json.dumps(asdict(case)))
        cmd = [sys.executable, str(Path(__file__).resolve()), "--run-case", str(spec),
               "--result", str(out)]
        load0 = os.getloadavg()[0]
        t0 = time.perf_counter()
        proc = subprocess.Popen(cmd, env=env, cwd=REPO, stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True, start_new_session=True)
        try:
            _, err = proc.communicate(timeout=timeout)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)  # the case process and its pool workers
            proc.communicate()
            return {"status": f"timeout after {timeout:.0f} s"}
        meta = {"process_seconds": time.perf_counter() - t0,
                "loadavg_1min": [load0, os.getloadavg()[0]]}
        if proc.returncode != 0 or not out.exists():
            tail = err.strip().splitlines()[-1:] or ["(no stderr)"]
            return {"status": f"error (exit {proc.returncode}): {tail[0]}",
                    "stderr_tail": err[-4000:], **meta}
        return {"status": "ok", **json.loads(out.read_text()), **meta}


def _probe_work(_=None) -> float:
    """A fixed single-threaded pure-Python workload (~0.15 s); returns its wall time."""
    t0 = time.perf_counter()
    acc = 0
    for i in range(3_000_000):
        acc += i * i
    return time.perf_counter() - t0


def parallel_probe(workers: int) -> dict:
    """How well ``workers`` processes scale on this machine right now.

    ``efficiency = t(1 task alone) / t(workers tasks at once)``: 1.0 is perfect scaling,
    ``1/workers`` is none (e.g. other processes busy on the shared machine). Run right
    before each parallel case: the load on the development machine changes by the minute.
    """
    ctx = mp.get_context("spawn")
    with ProcessPoolExecutor(max_workers=workers, mp_context=ctx) as ex:
        list(ex.map(_probe_work, [None] * workers))  # start + warm up every worker
        alone = ex.submit(_probe_work).result()
        together = list(ex.map(_probe_work, [None] * workers))
    return {"workers": workers, "alone_s": alone, "together_s": max(together),
            "efficiency": alone / max(together)}


def _git_state() -> dict:
    def git(*args):
        try:
            return subprocess.run(["git", *args], cwd=REPO, capture_output=True, text=True,
                                  timeout=10).stdout.strip()
        except (OSError, subprocess.SubprocessError):
            return ""
    return {"commit": git("rev-parse", "--short", "HEAD"),
            "dirty_files": git("status", "--porcelain", "--", "shellspline").splitlines()}


def _versions() -> dict:
    import numpy
    import scipy

    import shellspline
    out = {"python": platform.python_version(), "numpy": numpy.__version__,
           "scipy": scipy.__version__, "shellspline": shellspline.__version__}
    try:
        from shellspline import _linalg
        out["sparse_backends"] = _linalg.available_backends()
    except (ImportError, AttributeError):
        pass
    return out


def machine_info() -> dict:
    return {"platform": platform.platform(), "processor": platform.processor(),
            "cpus": os.cpu_count(), "threads_env": {v: os.environ.get(v) for v in THREAD_VARS},
            **_versions(), "git": _git_state()}


# --------------------------------------------------------------------------------------
# printing
# --------------------------------------------------------------------------------------


def timing_rows(results) -> list:
    rows = []
    for case, r in results:
        if r.get("status") != "ok":
            continue
        st = r["lta"]["stages"]
        rows.append([case.label, r["vertices"], case.K, r["input"]["read"],
                     *(st[k] for k in STAGES), r["lta"]["timings"]["total"],
                     r["linear"]["total"], r["write"]["obj"], r["write"]["ply"],
                     r["ratios"]["lta_over_linear"], r["ratios"]["lta_over_write_obj"],
                     r["ratios"]["lta_over_write_ply"]])
    return rows


TIMING_HEADERS = ["case", "n", "K", "read", "describe", "solve", "reconstr", "place",
                  "multires", "energies", "quality", "other", "LTA total", "linear",
                  "write obj", "write ply", "LTA/lin", "LTA/obj", "LTA/ply"]


def gn_rows(results) -> list:
    rows = []
    for case, r in results:
        if r.get("status") != "ok":
            continue
        gn, per = r["lta"]["gauss_newton"], r["lta"]["per_iteration"]
        q = r["lta"]["quality"]
        peak = r["peak_rss_mb"]
        gn_n = (r["lta"]["multires"] or {}).get("coarse_vertices", r["vertices"])
        rows.append([case.label, gn_n, f"{gn.get('converged', 0)}/{gn.get('frames', 0)}",
                     gn.get("iterations_total"), gn.get("iterations_max"),
                     per.get("ms_per_it_cpu"), per.get("ms_per_it_wall"),
                     per.get("ms_per_it_busy"), gn.get("cg_iterations_total"),
                     gn.get("factorizations_total"), round(peak["self"]),
                     round(peak["children"]) if case.workers > 1 else "-",
                     q.get("flipped_faces"), q.get("degenerate_faces"),
                     q.get("min_area_ratio"), q.get("keyframes_exact"),
                     _fmt(r["loadavg_1min"][0], 1) + "→" + _fmt(r["loadavg_1min"][1], 1),
                     r["probe"]["efficiency"] if r.get("probe") else "-"])
    return rows


GN_HEADERS = ["case", "GN n", "GN conv", "it", "it max", "ms/it cpu", "ms/it wall", "ms/it busy",
              "CG it", "factor", "RSS MB", "wkr MB", "flipped", "degen", "min A/A0",
              "kf exact", "load 1m", "probe"]


def reference_lines(results) -> list:
    """Paper numbers and targets, with this run's matching numbers beside them."""
    lines = [f"paper (i7-2600, 1 core): {PAPER['ms_per_gn_iteration']:.0f} ms per GN iteration "
             f"at {PAPER['vertices']} vertices; cactus K=20 {PAPER['cactus_K20_total_s']:.0f} s,"
             f" K=170 {PAPER['cactus_K170_total_s']:.0f} s (full resolution)",
             f"targets: <= {TARGETS['ms_per_gn_iteration']:.0f} ms per GN iteration at 5.2k; "
             f"<= {TARGETS['cactus_K20_total_s']:.0f} s cactus K=20 end to end"]
    for case, r in results:
        if r.get("status") != "ok" or case.source != "cactus":
            continue
        total = r["input"]["read"] + r["lta"]["timings"]["total"]
        paper_total = PAPER[f"cactus_K{case.K}_total_s"]
        ms = r["lta"]["per_iteration"].get("ms_per_it_cpu")
        line = (f"  {case.label}: read+LTA {total:.2f} s (paper {paper_total:.0f} s, "
                f"x{paper_total / total:.0f} faster")
        if case.K == 20:
            line += f"; target {TARGETS['cactus_K20_total_s']:.0f} s: " + \
                ("met" if total <= TARGETS["cactus_K20_total_s"] else "MISSED")
        if ms is not None:
            line += (f"), {ms:.0f} ms/GN it cpu (paper {PAPER['ms_per_gn_iteration']:.0f}, "
                     f"target {TARGETS['ms_per_gn_iteration']:.0f}: "
                     + ("met" if ms <= TARGETS["ms_per_gn_iteration"] else "MISSED") + ")")
        else:
            line += ")"
        lines.append(line)
    return lines


def report_text(results, skipped, git: dict) -> str:
    state = f"commit {git.get('commit') or '?'}" + (" + local changes in shellspline/"
                                                     if git.get("dirty_files") else "")
    parts = [f"LΘA interpolation benchmark, {state}, {time.strftime('%Y-%m-%d %H:%M')} "
             "(seconds unless noted; one fresh process per case)", ""]
    parts += [f"skipped: {s}" for s in skipped]
    parts += [f"{case.label}: {r['status']}" for case, r in results if r.get("status") != "ok"]
    parts += [f"note {case.label}: {case.note}" for case, _ in results if case.note]
    parts += [f"note {case.label}: interpolate() took its multiresolution path: Gauss–Newton "
              f"on a {r['lta']['multires']['coarse_vertices']}-vertex decimation, then "
              "detail-transfer prolongation (stage 'multires' = decimate + prolong)"
              for case, r in results if r.get("status") == "ok" and r["lta"]["multires"]]
    parts.append(f"machine: {os.cpu_count()} cpus, shared. 'probe' = how well the worker "
                 "processes could scale just before the case (1.0 = perfect, 1/workers = "
                 "not at all); 'load 1m' = load average before→after")
    if not any(r.get("status") == "ok" for _, r in results):
        return "\n".join(parts + ["", "no case ran"])
    parts += ["", "stage times", format_table(TIMING_HEADERS, timing_rows(results)), "",
              "Gauss–Newton, memory, quality (ms/it cpu = reconstruct×workers/it; wall = "
              "reconstruct/it; busy = Σ frame seconds/it)",
              format_table(GN_HEADERS, gn_rows(results)), "", *reference_lines(results)]
    return "\n".join(parts)


# --------------------------------------------------------------------------------------
# entry point
# --------------------------------------------------------------------------------------
def _build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--quick", action="store_true",
                   help="real cactus K=20 only (under a minute)")
    p.add_argument("--out", type=Path, default=DEFAULT_OUT, help="JSON results file")
    p.add_argument("--workers", type=int, default=2,
                   help="worker count of the parallel runs (default 2)")
    p.add_argument("--cases", nargs="+", choices=CASE_NAMES, help="cases to run")
    p.add_argument("--synth-K", type=int, default=20,
                   help="K of the synthetic 150k case (keyframes at 0, K//2, K; default 20)")
    p.add_argument("--threads", type=int, default=None,
                   help="set OMP/OPENBLAS/MKL_NUM_THREADS in the case processes")
    p.add_argument("--case-timeout", type=float, default=900.0,
                   help="seconds before a case process is killed (default 900)")
    p.add_argument("--run-case", help=argparse.SUPPRESS)  # internal: case process
    p.add_argument("--result", help=argparse.SUPPRESS)
    return p


def main(argv=None) -> int:
    args = _build_parser().parse_args(argv)
    if args.run_case:
        return _case_process_main(args.run_case, args.result)
    if args.workers < 1:
        print(f"--workers must be >= 1, got {args.workers}", file=sys.stderr)
        return 2
    if args.synth_K < 4:
        print(f"--synth-K must be >= 4 (keyframes at 0, K//2, K), got {args.synth_K}",
              file=sys.stderr)
        return 2
    cases = selected_cases(args.cases, args.quick, args.workers, args.synth_K)
    skipped = []
    if not CACTUS_DIR.is_dir():
        skipped.append("../shared/data/cactus not present")
        cases = [c for c in cases if c.source != "cactus"]
    for line in skipped:
        print(f"skipped: {line}", flush=True)
    results = []
    for case in cases:
        print(f"running {case.label} (K={case.K}) ...", flush=True)
        probe = parallel_probe(case.workers) if case.workers > 1 else None
        r = {**run_isolated(case, args.case_timeout, args.threads), "probe": probe}
        print(f"  {r['status']}" + (f", {r['process_seconds']:.1f} s" if "process_seconds" in r
                                   else ""), flush=True)
        results.append((case, r))
    args.out.parent.mkdir(parents=True, exist_ok=True)
    machine = machine_info()
    payload = {"argv": sys.argv[1:] if argv is None else list(argv), "quick": args.quick,
               "time": time.strftime("%Y-%m-%dT%H:%M:%S%z"), "machine": machine,
               "paper": PAPER, "targets": TARGETS, "skipped": skipped,
               "cases": [{"case": asdict(c), **r} for c, r in results]}
    args.out.write_text(json.dumps(payload, indent=1))
    print()
    print(report_text(results, skipped, machine["git"]))
    print(f"\nwrote {args.out}")
    return 0 if all(r.get("status") == "ok" for _, r in results) else 1


if __name__ == "__main__":
    sys.exit(main())

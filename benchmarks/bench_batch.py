"""Throughput of ``shellspline batch``: one job of synthetic sequences, three executors.

What is measured
----------------
One job of ``--sequences`` (default 24) synthetic ellipsoid sequences (varied half-axes,
``data_synth.variants``; ``--vertices`` about 500, K = 12, LΘA at full resolution) is run
through :func:`shellspline.run_batch` with ``force=True`` (every sequence recomputed and
written) on

* ``local-1``: the local executor with 1 worker process,
* ``local-2``: the local executor with 2 worker processes,
* ``dask-2``: a Dask ``LocalCluster`` (2 worker processes, 1 thread each, loopback) started by
  the script; the cluster start is timed separately and not part of the batch time.

For each: wall time of the batch, sequences per minute, frames per second (all frames
written, keyframes included), the summed per-sequence seconds (CPU-ish work), and the ratios
against ``local-1`` measured in the same run. The load average is recorded before and after
every case: the machine is shared, so only the ratios within one run mean something.

Run
---
::

    cd /work/main
    PYTHONPATH=. python3 benchmarks/bench_batch.py               # ~1-2 minutes
    PYTHONPATH=. python3 benchmarks/bench_batch.py --sequences 20 --vertices 300

The table goes to stdout and everything to ``benchmarks/results/bench_batch.json``. This is
a benchmark, not a test: nothing is asserted.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from _common import format_table  # noqa: E402

DEFAULT_OUT = REPO / "benchmarks" / "results" / "bench_batch.json"


def write_job(dir_: Path, n: int, vertices: int) -> Path:
    import data_synth

    lines = ['[job]', 'name = "bench_batch"', 'output = "out"', 'workers = 1', '',
             '[defaults]', f'vertices = {vertices}', 'coarse = "none"', '']
    for i, p in enumerate(data_synth.variants("ellipsoids", n, seed=1)):
        axes = ", ".join("[" + ", ".join(f"{x:.6f}" for x in a) + "]" for a in p["axes"])
        lines += ['[[sequences]]', f'name = "ell_{i:03d}"', 'synth = "ellipsoids"',
                  f'synth_params = {{axes = [{axes}]}}', '']
    path = dir_ / "bench_batch.toml"
    path.write_text("\n".join(lines))
    return path


def run_case(name, job, out, **kw):
    import shellspline as ss

    load0 = os.getloadavg()[0]
    t0 = time.perf_counter()
    s = ss.run_batch(job.with_output(out), force=True, **kw)
    wall = time.perf_counter() - t0
    if s.exit_code != 0:
        raise SystemExit(f"{name}: batch failed:\n{s.table()}")
    frames = sum(o["frames"] for o in s.sequences)
    return {"case": name, "sequences": len(s.sequences), "frames": frames, "wall_s": wall,
            "sequences_per_min": 60 * len(s.sequences) / wall, "frames_per_s": frames / wall,
            "sum_sequence_s": sum(o["seconds"] for o in s.sequences),
            "load_before": load0, "load_after": os.getloadavg()[0]}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sequences", type=int, default=24)
    ap.add_argument("--vertices", type=int, default=500)
    ap.add_argument("--no-dask", action="store_true", help="skip the LocalCluster case")
    ap.add_argument("--out", default=str(DEFAULT_OUT))
    args = ap.parse_args(argv)

    import shellspline as ss

    tmp = Path(tempfile.mkdtemp(prefix="bench_batch_"))
    job = ss.load_job(write_job(tmp, args.sequences, args.vertices))
    rows = [run_case("local-1", job, tmp / "l1", workers=1),
            run_case("local-2", job, tmp / "l2", workers=2)]
    cluster_start = None
    if not args.no_dask:
        from distributed import LocalCluster

        t0 = time.perf_counter()
        cluster = LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                               host="127.0.0.1", dashboard_address=None)
        cluster_start = time.perf_counter() - t0
        try:
            rows.append(run_case("dask-2", job, tmp / "d2",
                                 scheduler=cluster.scheduler_address))
        finally:
            cluster.close()
    base = rows[0]["wall_s"]
    for r in rows:
        r["speedup_vs_local_1"] = base / r["wall_s"]
    print(f"shellspline batch throughput: {args.sequences} ellipsoid sequences, ~{args.vertices} "
          f"vertices, K = 12 (13 frames each), {os.cpu_count()} CPUs, load "
          f"{os.getloadavg()[0]:.2f}")
    print(format_table(
        ["case", "wall s", "seq/min", "frames/s", "Σ seq s", "speedup", "load before/after"],
        [[r["case"], r["wall_s"], r["sequences_per_min"], r["frames_per_s"], r["sum_sequence_s"],
          r["speedup_vs_local_1"], f"{r['load_before']:.2f}/{r['load_after']:.2f}"]
         for r in rows]))
    if cluster_start is not None:
        print(f"LocalCluster start (not in dask-2's wall time): {cluster_start:.2f} s")
    result = {"benchmark": "bench_batch", "sequences": args.sequences,
              "vertices": args.vertices, "cases": rows, "cluster_start_s": cluster_start,
              "shellspline_version": ss.__version__, "python": platform.python_version(),
              "cpus": os.cpu_count(), "time": time.strftime("%Y-%m-%dT%H:%M:%S")}
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=1))
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Speed of the Gauss–Newton reconstruction on real keyframes (issue 13: targets speed,
iterations).

Runs ``interpolate(coarse="none")`` on the same keyframes in fresh processes, alternating
between configurations (``--repeat`` rounds, so all see the same machine load): this tree
with subspace steps (the default) and, with ``--gauss-newton``, without them
(``GaussNewton(subspace=False)``); with ``--variant dtol=2e-5`` (repeatable; options of
:class:`~shellspline.shells.reconstruct.GaussNewton`, comma-separated), this tree with those
options, e.g. a stopping tolerance against the default in the same run; with ``--baseline DIR``, the same run on another checkout
of the package (e.g. ``git worktree add /tmp/old <rev>``: the old code in the same run).
Prints wall time, CPU time (this process and its workers) and CPU milliseconds per
Gauss–Newton iteration (the whole run's CPU time over its iterations: the per-iteration cost,
less sensitive to the machine's load than wall time; compare configurations whose iteration
counts agree, ``--workers 1`` to make them deterministic), the
time of the reconstruction stages (first pass, continuation pass and seam bridges),
Gauss–Newton iterations (total, median, max), CG iterations, factorizations, frames
converged and the defects of :func:`shellspline.metrics.sequence_defects`; writes every run
to ``benchmarks/results/bench_gn.json`` (``--json``).

From the repository root::

    PYTHONPATH=. python3 benchmarks/bench_gn.py                        # horse pair, ~40 s
    PYTHONPATH=. python3 benchmarks/bench_gn.py --poses horse-reference,horse-03,horse-07 \\
        --frames 0,20,40
    PYTHONPATH=. python3 benchmarks/bench_gn.py --baseline /tmp/old --repeat 2
    PYTHONPATH=. python3 benchmarks/bench_gn.py --variant dtol=2e-5 --variant dtol=5e-5
    PYTHONPATH=. python3 benchmarks/bench_gn.py --data ../shared/data/cactus \\
        --poses cactus0.ply,cactus5.ply,cactus13.ply --frames 0,10,20 \\
        --pinned ../shared/data/cactus/cactusBottomMask_indices.txt
"""
from __future__ import annotations

import argparse
import ast
import json
import os
import resource
import subprocess
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from _common import format_table  # noqa: E402

COLUMNS = ["wall", "cpu", "ms/it", "reconstruct", "continue", "bridges", "iterations", "median",
           "max",
           "cg", "factorizations", "converged", "frames", "flipped", "collapsed", "folded", "pop"]


def gn_variant(text: str) -> dict:
    """``"dtol=2e-5,cg_tol=1e-3"`` -> ``{"dtol": 2e-05, "cg_tol": 0.001}`` (values as Python
    literals)."""
    out = {}
    for item in filter(None, text.split(",")):
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise SystemExit(f"--variant: expected KEY=VALUE, got {item!r}")
        try:
            out[key.strip()] = ast.literal_eval(value.strip())
        except (ValueError, SyntaxError):
            raise SystemExit(f"--variant: {key.strip()} needs a Python literal, got {value!r}")
    return out


def measure(args, subspace: bool) -> dict:
    """One ``interpolate`` run in this process; the record of one table row."""
    import shellspline
    from shellspline.metrics import sequence_defects

    paths = [os.path.join(args.data, p if os.path.splitext(p)[1] else p + ".obj")
             for p in args.poses.split(",")]
    frames = [int(f) for f in args.frames.split(",")]
    kf = shellspline.read_keyframes(paths, frames=frames)
    pinned = np.loadtxt(args.pinned, dtype=np.int64) if args.pinned else None
    t0, c0 = time.perf_counter(), _cpu_seconds()
    res = shellspline.interpolate(kf, coarse="none", workers=args.workers, pinned=pinned,
                                  gn_options={"subspace": subspace,
                                              **gn_variant(args.variant_options or "")})
    wall, cpu = time.perf_counter() - t0, _cpu_seconds() - c0
    gn = res.report["gauss_newton"]
    stages = res.report.get("timings") or res.report.get("stages") or {}
    d = sequence_defects(res.V, shellspline.topology(res.F), res.frames)
    return {"package": os.path.dirname(os.path.abspath(shellspline.__file__)),
            "vertices": int(kf.n), "wall": wall, "cpu": cpu,
            "ms/it": 1e3 * cpu / max(gn["iterations_total"], 1),
            "reconstruct": stages.get("reconstruct"),
            "continue": stages.get("reconstruct (continue)"),
            "bridges": stages.get("bridge seams"),
            "iterations": gn["iterations_total"], "median": gn["iterations_median"],
            "max": gn["iterations_max"], "cg": gn["cg_iterations_total"],
            "factorizations": gn["factorizations_total"], "converged": gn["converged"],
            "frames": gn["frames"], "flipped": d["flipped_faces"],
            "collapsed": d["collapsed_faces"], "folded": d["folded_edges"], "pop": d["pop"]}


def _cpu_seconds() -> float:
    """User + system CPU time of this process and of its finished children (the workers of
    ``interpolate`` are joined before it returns)."""
    return sum(r.ru_utime + r.ru_stime for r in (resource.getrusage(resource.RUSAGE_SELF),
                                                 resource.getrusage(resource.RUSAGE_CHILDREN)))


def _child_argv(args, subspace: bool, options: str = "") -> list:
    argv = [sys.executable, os.path.abspath(__file__), "--child", "--data", args.data,
            "--poses", args.poses, "--frames", args.frames, "--workers", str(args.workers)]
    if args.pinned:
        argv += ["--pinned", args.pinned]
    if options:
        argv += ["--variant-options", options]
    return argv + ([] if subspace else ["--gauss-newton"])


def run_config(args, label: str, root: str, subspace: bool, options: str = "") -> dict:
    """``measure`` in a fresh process whose ``shellspline`` is the one under ``root``."""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(
        [root] + [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p]))
    out = subprocess.run(_child_argv(args, subspace, options), env=env, capture_output=True, text=True,
                         check=False)
    if out.returncode != 0:
        raise SystemExit(f"{label}: the run failed:\n{out.stderr[-2000:]}")
    rec = json.loads(out.stdout.strip().splitlines()[-1])
    rec["config"] = label
    return rec


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default="../shared/data/horse")
    ap.add_argument("--poses", default="horse-reference,horse-03",
                    help="comma-separated file names in --data (.obj added when missing)")
    ap.add_argument("--frames", default="0,20")
    ap.add_argument("--pinned", default=None, help="file of pinned vertex indices")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--baseline", default=None,
                    help="directory holding another checkout's `shellspline` package")
    ap.add_argument("--gauss-newton", action="store_true",
                    help="also run without subspace steps (child: only without them)")
    ap.add_argument("--variant", action="append", default=[], metavar="KEY=VALUE[,...]",
                    help="also run this tree with these GaussNewton options (repeatable)")
    ap.add_argument("--json", default=os.path.join(HERE, "results", "bench_gn.json"))
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--variant-options", default=None, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)

    if not os.path.isdir(args.data):
        print(f"skipped: {args.data} not found (shared data)")
        return 0
    if args.child:
        print(json.dumps(measure(args, subspace=not args.gauss_newton)))
        return 0
    for v in args.variant:
        gn_variant(v)  # refused here, before any run
    this = os.path.dirname(HERE)
    configs = [("subspace", this, True, "")]
    if args.gauss_newton:
        configs.append(("gauss-newton", this, False, ""))
    configs += [(v, this, True, v) for v in args.variant]
    if args.baseline:
        configs.append(("baseline", os.path.abspath(args.baseline), True, ""))
    runs = []
    for _ in range(args.repeat):
        for label, root, subspace, options in configs:
            runs.append(run_config(args, label, root, subspace, options))
    rows = [[r["config"]] + [r[c] for c in COLUMNS] for r in runs]
    print(f"{args.poses} at {args.frames}, workers={args.workers}, {runs[0]['vertices']} "
          f"vertices")
    print(format_table(["config"] + COLUMNS, rows))
    os.makedirs(os.path.dirname(os.path.abspath(args.json)), exist_ok=True)
    with open(args.json, "w") as fh:
        json.dump({"data": args.data, "poses": args.poses, "frames": args.frames,
                   "workers": args.workers, "runs": runs}, fh, indent=1)
    print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""Gauss–Newton steps against subspace steps (``GaussNewton(subspace=...)``) on real keyframes.

Runs ``interpolate(coarse="none")`` on the same keyframes with ``subspace=False`` and
``subspace=True`` (alternating, ``--repeat`` times, so both see the same machine load) and
prints wall time, iterations (total, median, max), CG iterations, factorizations, frames
converged and the defects of :func:`shellspline.metrics.sequence_defects`.

From the repository root::

    PYTHONPATH=. python3 benchmarks/bench_gn.py                        # horse pair, ~40 s
    PYTHONPATH=. python3 benchmarks/bench_gn.py --poses horse-reference,horse-03,horse-07 \\
        --frames 0,20,40
    PYTHONPATH=. python3 benchmarks/bench_gn.py --data ../shared/data/cactus \\
        --poses cactus0.ply,cactus5.ply,cactus13.ply --frames 0,10,20 \\
        --pinned ../shared/data/cactus/cactusBottomMask_indices.txt
"""
from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _common import format_table  # noqa: E402


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default="../shared/data/horse")
    ap.add_argument("--poses", default="horse-reference,horse-03",
                    help="comma-separated file names in --data (.obj added when missing)")
    ap.add_argument("--frames", default="0,20")
    ap.add_argument("--pinned", default=None, help="file of pinned vertex indices")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--repeat", type=int, default=1)
    args = ap.parse_args(argv)

    import shellspline
    from shellspline.metrics import sequence_defects

    if not os.path.isdir(args.data):
        print(f"skipped: {args.data} not found (shared data)")
        return 0
    paths = [os.path.join(args.data, p if os.path.splitext(p)[1] else p + ".obj")
             for p in args.poses.split(",")]
    frames = [int(f) for f in args.frames.split(",")]
    kf = shellspline.read_keyframes(paths, frames=frames)
    pinned = np.loadtxt(args.pinned, dtype=np.int64) if args.pinned else None
    rows = []
    for _ in range(args.repeat):
        for subspace in (False, True):
            t0 = time.perf_counter()
            res = shellspline.interpolate(kf, coarse="none", workers=args.workers,
                                          pinned=pinned, gn_options={"subspace": subspace})
            wall = time.perf_counter() - t0
            gn = res.report["gauss_newton"]
            d = sequence_defects(res.V, shellspline.topology(res.F), res.frames)
            rows.append(["subspace" if subspace else "gauss-newton", wall,
                         gn["iterations_total"], gn["iterations_median"], gn["iterations_max"],
                         gn["cg_iterations_total"], gn["factorizations_total"],
                         f"{gn['converged']}/{gn['frames']}", d["flipped_faces"],
                         d["collapsed_faces"], d["folded_edges"], d["pop"]])
    print(f"{', '.join(os.path.basename(p) for p in paths)} at {frames}, "
          f"workers={args.workers}, {kf.n} vertices")
    print(format_table(["steps", "wall s", "iters", "median", "max", "CG", "facts",
                        "converged", "flipped", "collapsed", "folded", "pop"], rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""Benchmark of the Lie-group curves (``shellspline.curves``) against scipy.

What is measured
----------------
1. **Speed** (issue 16 target): C² interpolation of 1,000 keyframe rotations at non-uniform
   times, built and evaluated at 100,000 times, against ``scipy.spatial.transform.
   RotationSpline`` on the same data in the same process; the same for SE(3) (screw metric)
   and SO(3) x R^3 poses. Each variant runs ``--repeat`` times, interleaved with scipy; the
   table shows the fastest run (the machine is shared: ratios inside one run are what count)
   and the JSON keeps every run. Targets: SO(3) no slower than RotationSpline
   (build + evaluate), SE(3) within 2x.
2. **Camera ground truth** (``../shared/data/camera/freiburg1_xyz-groundtruth.txt``, TUM
   RGB-D, 3,000 poses at ~100 Hz): every 10th pose kept as a keyframe, the curve evaluated
   at the other 2,699 input times, position and angle errors against the dropped poses for
   our C² spline (SE(3) and SO(3) x R^3, natural ends), our C¹ Catmull–Rom Bézier, scipy
   ``RotationSpline`` + ``CubicSpline`` of the position, and ``Slerp`` + linear position.
   Target: errors no larger than scipy's.
3. **Knot insertion order** (seed 002 chapter 6): on SO(3), inserting knots ``a`` then ``b``
   into a cubic B-spline vs ``b`` then ``a``; the control points differ (SO(3) is not a
   "Menelaus space") by an amount that falls with the control polygon's spread ``r`` like
   ``r^p``; one insertion also moves the curve. Both measured for ``r`` = 0.8 ... 0.05 rad.
4. **Marching blow-up** (seed 002 algorithm 7.4.1): the cubic built by marching from the
   exact start velocity and acceleration of the global spline, its distance to the global
   spline per interval (errors grow ~(2 + sqrt 3) per interval from the ~1e-9 start).

Run
---
::

    cd /work/main
    PYTHONPATH=. python3 benchmarks/bench_curves.py              # ~1 minute
    PYTHONPATH=. python3 benchmarks/bench_curves.py --repeat 3 --quick

The tables go to stdout, everything to ``benchmarks/results/bench_curves.json``. Nothing is
asserted: this is a benchmark, not a test.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import format_table  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
CAMERA = REPO.parent / "shared" / "data" / "camera" / "freiburg1_xyz-groundtruth.txt"


def _walk(rng, n, dim, step):
    return np.cumsum(rng.normal(size=(n, dim)) * step, axis=0)


def speed(n_key=1000, n_eval=100_000, repeat=5, seed=0):
    from scipy.spatial.transform import Rotation, RotationSpline

    from shellspline.curves import cubic_spline
    from shellspline.groups import SE3, SO3, SO3xR3, se3, so3

    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.uniform(0.5, 1.5, n_key))
    R = so3.exp(_walk(rng, n_key, 3, 0.15))  # ~15 degrees between keyframes
    P = _walk(rng, n_key, 3, 0.3)
    T = se3.from_rt(R, P)
    tq = np.linspace(t[0], t[-1], n_eval)
    runs = {"scipy RotationSpline": [], "ours SO3": [], "ours SE3": [], "ours SO3xR3": []}
    iters = {}

    def clock(fn):
        t0 = time.perf_counter()
        out = fn()
        return out, time.perf_counter() - t0

    rot = Rotation.from_matrix(R)
    for _ in range(repeat):
        s, b = clock(lambda: RotationSpline(t, rot))
        _, e = clock(lambda: s(tq).as_matrix())
        runs["scipy RotationSpline"].append((b, e))
        for name, G, X in (("ours SO3", SO3, R), ("ours SE3", SE3, T),
                           ("ours SO3xR3", SO3xR3, T)):
            c, b = clock(lambda: cubic_spline(G, t, X))
            _, e = clock(lambda: c(tq))
            runs[name].append((b, e))
            iters[name] = c.solve.message
    best = {k: min(v, key=sum) for k, v in runs.items()}
    ref = sum(best["scipy RotationSpline"])
    rows = [[k, 1e3 * b, 1e3 * e, 1e3 * (b + e), (b + e) / ref, iters.get(k, "")]
            for k, (b, e) in best.items()]
    return {"n_keyframes": n_key, "n_eval": n_eval, "repeat": repeat,
            "runs_s": {k: v for k, v in runs.items()}, "best_s": best,
            "ratio_to_scipy": {k: sum(v) / ref for k, v in best.items()},
            "solver": iters}, rows


def camera(every=10):
    from scipy.interpolate import CubicSpline
    from scipy.spatial.transform import Rotation, RotationSpline, Slerp

    from shellspline.curves import cubic_spline, hermite_spline
    from shellspline.groups import SE3, SO3xR3, so3
    from shellspline.io.posefiles import read_poses

    if not CAMERA.exists():
        print(f"  (skipped: {CAMERA} not present)")
        return None, []
    tr = read_poses(CAMERA)
    t, T = tr.t - tr.t[0], tr.T
    n = t.size
    keys = np.unique(np.r_[np.arange(0, n, every), n - 1])
    rest = np.setdiff1d(np.arange(n), keys)
    tk, Tk = t[keys], T[keys]
    rot = Rotation.from_matrix(Tk[:, :3, :3])
    R_rs = RotationSpline(tk, rot)(t).as_matrix()
    R_sl = Slerp(tk, rot)(t).as_matrix()
    p_cs = CubicSpline(tk, Tk[:, :3, 3], bc_type="natural")(t)
    p_cs_nak = CubicSpline(tk, Tk[:, :3, 3])(t)
    p_lin = np.stack([np.interp(t, tk, Tk[:, i, 3]) for i in range(3)], axis=1)
    cands = {
        "ours C2 SE3 (natural)": cubic_spline(SE3, tk, Tk)(t),
        "ours C2 SO3xR3 (natural)": cubic_spline(SO3xR3, tk, Tk)(t),
        "ours C1 Bezier (Catmull-Rom) SE3": hermite_spline(SE3, tk, Tk)(t),
        "scipy RotationSpline + CubicSpline natural": (R_rs, p_cs),
        "scipy RotationSpline + CubicSpline not-a-knot": (R_rs, p_cs_nak),
        "scipy Slerp + linear position": (R_sl, p_lin),
    }
    out, rows = {}, []
    for name, v in cands.items():
        Rm, p = (v[:, :3, :3], v[:, :3, 3]) if isinstance(v, np.ndarray) else v
        dp = 1e3 * np.linalg.norm(p[rest] - T[rest, :3, 3], axis=1)  # mm
        da = np.degrees(so3.angle(np.swapaxes(Rm[rest], -1, -2) @ T[rest, :3, :3]))
        rec = {"pos_rms_mm": float(np.sqrt(np.mean(dp ** 2))), "pos_max_mm": float(dp.max()),
               "ang_rms_deg": float(np.sqrt(np.mean(da ** 2))), "ang_max_deg": float(da.max())}
        out[name] = rec
        rows.append([name] + [f"{rec[k]:.4f}" for k in ("pos_rms_mm", "pos_max_mm",
                                                         "ang_rms_deg", "ang_max_deg")])
    return {"file": str(CAMERA), "poses": int(n), "keyframes": int(keys.size),
            "every": every, "errors": out}, rows


def knot_order(seed=3):
    from shellspline.curves import BSpline
    from shellspline.groups import SO3

    n, m = 8, 3
    u = np.r_[[0.0] * 3, np.linspace(0, 5, n - m + 1), [5.0] * 3]
    tq = np.linspace(0, 5, 201)
    a, b = 1.3, 1.7
    out, rows = [], []
    for r in (0.8, 0.4, 0.2, 0.1, 0.05):
        diffs, moves = [], []
        for k in range(5):
            rng = np.random.default_rng(seed + k)
            S = BSpline(SO3, SO3.exp(_walk(rng, n, 3, r)), u, m)
            ab, ba = S.insert_knot(a).insert_knot(b), S.insert_knot(b).insert_knot(a)
            diffs.append(SO3.distance(ab.control, ba.control).max())
            moves.append(SO3.distance(S.insert_knot(a)(tq), S(tq)).max())
        out.append({"spread_rad": r, "order_dependence_rad": float(np.median(diffs)),
                    "curve_moved_by_one_insertion_rad": float(np.median(moves))})
        rows.append([r, float(np.median(diffs)), float(np.median(moves))])
    x = np.log([o["spread_rad"] for o in out])
    p_order = float(np.polyfit(x, np.log([o["order_dependence_rad"] for o in out]), 1)[0])
    p_move = float(np.polyfit(x, np.log([o["curve_moved_by_one_insertion_rad"] for o in out]),
                              1)[0])
    return {"cases": out, "exponent_order": p_order, "exponent_move": p_move}, rows


def marching(n_key=30, seed=5):
    from shellspline.curves import cubic_spline
    from shellspline.groups import SO3

    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.uniform(0.5, 1.5, n_key))
    X = SO3.exp(_walk(rng, n_key, 3, 0.3))
    S = cubic_spline(SO3, t, X)
    rows, errs = [], []
    last = n_key - 1
    for upto in range(2, n_key):
        try:
            M = cubic_spline(SO3, t[:upto + 1], X[:upto + 1], (S.velocity(t[0]), "natural"),
                             method="march", start_acceleration=S.acceleration(t[0]))
        except ValueError as exc:
            last = upto
            msg = str(exc)
            break
        tm = np.linspace(t[upto - 1], t[upto], 21)
        errs.append(float(SO3.distance(M(tm), S(tm)).max()))
    else:
        msg = "no blow-up"
    for i, e in enumerate(errs, start=2):
        if i in (2, 3, 4, 6, 8, 10, 12, 14) or i == len(errs) + 1:
            rows.append([i, e])
    growth = float(np.exp(np.polyfit(np.arange(len(errs)), np.log(np.maximum(errs, 1e-300)),
                                     1)[0]))
    return {"intervals": n_key - 1, "error_per_interval_rad": errs, "growth_per_interval":
            growth, "blew_up_at_interval": last, "message": msg}, rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--quick", action="store_true", help="10,000 evaluation times")
    ap.add_argument("--out", default=str(REPO / "benchmarks" / "results" / "bench_curves.json"))
    a = ap.parse_args(argv)
    res = {"machine": {"python": platform.python_version(), "numpy": np.__version__,
                       "cpus": os.cpu_count(), "load_before": os.getloadavg()}}
    import scipy

    res["machine"]["scipy"] = scipy.__version__
    sp, rows = speed(n_eval=10_000 if a.quick else 100_000, repeat=a.repeat)
    res["speed"] = sp
    print(f"1. C² interpolation: {sp['n_keyframes']} keyframes, build + evaluate at "
          f"{sp['n_eval']} times (fastest of {sp['repeat']})")
    print(format_table(["variant", "build ms", "eval ms", "total ms", "x scipy", "solver"],
                       rows))
    cam, rows = camera()
    res["camera"] = cam
    if cam:
        print(f"\n2. Camera ground truth: {cam['poses']} poses, every {cam['every']}th kept "
              f"({cam['keyframes']} keyframes), errors at the other poses")
        print(format_table(["method", "pos rms mm", "pos max mm", "ang rms deg",
                            "ang max deg"], rows))
    ko, rows = knot_order()
    res["knot_insertion"] = ko
    print("\n3. Knot insertion on SO(3): order dependence and curve change vs spread "
          "(median of 5)")
    print(format_table(["spread rad", "|ab - ba| rad", "curve moved rad"], rows))
    print(f"   slopes: order dependence ~ r^{ko['exponent_order']:.2f}, curve change ~ "
          f"r^{ko['exponent_move']:.2f}")
    mr, rows = marching()
    res["marching"] = mr
    print(f"\n4. Marching cubic (seed alg. 7.4.1) vs the global spline, {mr['intervals']} "
          f"intervals: growth x{mr['growth_per_interval']:.2f} per interval; "
          f"{mr['message']}")
    print(format_table(["interval", "max distance rad"], rows))
    res["machine"]["load_after"] = os.getloadavg()
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    Path(a.out).write_text(json.dumps(res, indent=1, default=float))
    print(f"\nwrote {a.out}")


if __name__ == "__main__":
    main()

"""The measurements of benchmarks/bench_real.py (ground-truth errors and their rigid/shape
split) against independent computations."""
from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from conftest import shared_data

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def bench():
    sys.path.insert(0, str(REPO / "benchmarks"))
    try:
        spec = importlib.util.spec_from_file_location("bench_real",
                                                      REPO / "benchmarks" / "bench_real.py")
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
    finally:
        sys.path.remove(str(REPO / "benchmarks"))
    return mod


def test_procrustes_residual_matches_scipy(bench):
    rng = np.random.default_rng(1)
    Y = rng.normal(size=(4, 30, 3))
    R = Rotation.random(4, random_state=2)
    X = np.stack([R[t].apply(Y[t]) + rng.normal(size=3) for t in range(4)])
    np.testing.assert_allclose(bench.procrustes_residual(X, Y), 0, atol=1e-12)
    Xn = X + 0.05 * rng.normal(size=X.shape)
    res = bench.procrustes_residual(Xn, Y)
    for t in range(4):
        a, b = Xn[t] - Xn[t].mean(0), Y[t] - Y[t].mean(0)
        rot, _ = Rotation.align_vectors(b, a)
        assert res[t] == pytest.approx(np.sqrt(((rot.apply(a) - b) ** 2).sum(1).mean()),
                                       rel=1e-9)


def test_error_split_into_shape_and_rigid(bench):
    rng = np.random.default_rng(0)
    truth = rng.normal(size=(7, 40, 3))
    inner = np.array([1, 2, 4, 5])
    moved = truth + np.array([0.3, 0, 0])  # a rigid misplacement only
    e = bench.ground_truth_errors(moved, truth, inner, 2.0)
    assert e["shape"] == pytest.approx(0, abs=1e-12)
    assert e["rigid"] == pytest.approx(e["err"]) == pytest.approx(0.15)
    noisy = moved + 0.1 * rng.normal(size=truth.shape)
    e = bench.ground_truth_errors(noisy, truth, inner, 2.0)
    assert e["err"] ** 2 == pytest.approx(e["shape"] ** 2 + e["rigid"] ** 2)
    assert 0 < e["shape"] < e["err"] and e["max"] >= e["err"]


def test_gt_case_small_clip(bench):
    c = bench.gt_case(shared_data("motion", "sinusoidal.bvh"), 12, 400, (6,), 1, False)
    assert c["K"] == 12 and c["vertices"] == 400
    rec = c["steps"]["6"]
    assert rec["keyframes"] == [0, 6, 12]
    for name in ("lta", "linear", "cubic"):
        m = rec["methods"][name]
        at_keys = [m["err_per_frame"][k] for k in (0, 6, 12)]
        if name == "cubic":  # the spline's evaluation at its knots: round-off
            assert max(at_keys) < 1e-12
        else:  # keyframes bit-exact
            assert at_keys == [0, 0, 0]
        assert m["err"] > 0
    assert set(rec["where"]) == {"lta"}
    # lta@cubic: the same shapes, moved rigidly: identical shape error
    assert rec["methods"]["lta@cubic"]["shape"] == pytest.approx(rec["methods"]["lta"]["shape"],
                                                                rel=1e-9)
    # linear blending of a rotating chain is worse than the cubic through 3 keyframes
    assert rec["methods"]["cubic"]["err"] < rec["methods"]["linear"]["err"]

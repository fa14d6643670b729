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
    for name in ("lta", "lta-keyref", "lta-discrete", "lta-disc-keyref", "linear", "cubic"):
        m = rec["methods"][name]
        at_keys = [m["err_per_frame"][k] for k in (0, 6, 12)]
        if name == "cubic":  # the spline's evaluation at its knots: round-off
            assert max(at_keys) < 1e-12
        else:  # keyframes bit-exact
            assert at_keys == [0, 0, 0]
        assert m["err"] > 0
    for name in ("cubic-discrete", "rig"):  # diagnostics: through the keyframes
        assert max(rec["methods"][name]["err_per_frame"][k] for k in (0, 6, 12)) < 1e-9
    # the paper's time-discrete spline per vertex is a spline too: near the cubic
    assert rec["methods"]["cubic-discrete"]["err"] == pytest.approx(
        rec["methods"]["cubic"]["err"], rel=0.1)
    assert set(rec["where"]) == {"lta", "lta-keyref", "lta-discrete", "lta-disc-keyref"}
    # the joints named as carrying LΘA's excess have skin (child3, the chain's end, owns none)
    joints = rec["where"]["lta"]["joints"]
    assert joints and all(j["vertices"] > 0 and np.isfinite(j["lta"]) for j in joints)
    # lta@cubic: the same shapes, moved rigidly: identical shape error
    assert rec["methods"]["lta@cubic"]["shape"] == pytest.approx(rec["methods"]["lta"]["shape"],
                                                                rel=1e-9)
    # linear blending of a rotating chain is worse than the cubic through 3 keyframes
    assert rec["methods"]["cubic"]["err"] < rec["methods"]["linear"]["err"]


def _chain_motion(values):
    """A 3-joint chain: root (position + Z rotation), two children rotating about X."""
    from shellspline.io.bvh import Motion

    return Motion(("root", "a", "b"), [-1, 0, 1], [[0, 0, 0], [0, 1, 0], [0, 1.5, 0]],
                  (("Xposition", "Yposition", "Zposition", "Zrotation"), ("Xrotation",),
                   ("Xrotation",)), 1 / 30, values)


def test_rig_interpolation_exact_on_constant_joint_velocities(bench):
    # every local rotation at a constant angular velocity about a fixed axis and the root
    # travelling at constant speed: the natural SO(3) and R^3 splines are exact, so the
    # interpolated rig is the clip's forward kinematics at every frame (independent oracle:
    # io.bvh.forward_kinematics of the clip itself)
    from shellspline.io.bvh import forward_kinematics

    t = np.arange(25.0)[:, None]
    vals = np.hstack([0.5 * t, 0.1 * t, -0.2 * t + 3, 4.0 * t, 7.0 * t - 30, -5.0 * t + 10])
    motion = _chain_motion(vals)
    win = np.arange(3, 22)
    P, R = bench.rig_interpolation(motion, win, np.arange(0, 19, 6))
    P0, R0 = forward_kinematics(motion)
    np.testing.assert_allclose(P, P0[win], atol=1e-9)
    np.testing.assert_allclose(R, R0[win], atol=1e-9)


def test_rig_interpolation_through_keyframes_not_exact_between(bench):
    from shellspline.io.bvh import forward_kinematics

    t = np.arange(19.0)[:, None]
    vals = np.hstack([np.sin(t / 3), 0 * t, 0 * t, 40 * np.sin(t / 4), 60 * np.cos(t / 5),
                      30 * np.sin(t / 2)])
    motion = _chain_motion(vals)
    frames = np.arange(0, 19, 6)
    P, R = bench.rig_interpolation(motion, np.arange(19), frames)
    P0, R0 = forward_kinematics(motion)
    np.testing.assert_allclose(P[frames], P0[frames], atol=1e-9)
    np.testing.assert_allclose(R[frames], R0[frames], atol=1e-9)
    assert np.abs(P - P0).max() > 1e-3  # a spline, not a copy of the clip
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-9)  # rotations, not blends
    # a joint turning by half a turn between keyframes: no SO(3) spline, no rig row
    fast = vals.copy()
    fast[:, 3] = 30.0 * np.arange(19)
    assert bench.rig_interpolation(_chain_motion(fast), np.arange(19), frames) is None


def test_gt_case_start_out_of_the_clip_refused(bench):
    path = shared_data("motion", "sinusoidal.bvh")
    with pytest.raises(SystemExit, match="--start 100000: sinusoidal.bvh has"):
        bench.gt_case(path, 12, 400, (6,), 1, False, start=100000)

"""The diagnostics of benchmarks/bench_real.py that say where LΘA loses against the per-vertex
cubic (issue 13, item 6): the rigid misplacement split into centroid offset and rotation, the
end-gap / interior-gap split, and the descriptor swaps, each against an independent oracle
(scipy rotations, constructed offsets, true descriptors)."""
from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def bench():
    sys.path.insert(0, str(REPO / "benchmarks"))
    try:
        spec = importlib.util.spec_from_file_location("bench_real_diag",
                                                      REPO / "benchmarks" / "bench_real.py")
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
    finally:
        sys.path.remove(str(REPO / "benchmarks"))
    return mod


def test_rigid_offsets_match_scipy(bench):
    rng = np.random.default_rng(3)
    Y = rng.normal(size=(5, 40, 3))
    rots = Rotation.random(5, random_state=4)
    shift = rng.normal(size=(5, 3))
    X = np.stack([rots[t].apply(Y[t] - Y[t].mean(0)) + Y[t].mean(0) + shift[t]
                  for t in range(5)])
    X += 0.01 * rng.normal(size=X.shape)                     # not exactly rigid
    dc, angle = bench.rigid_offsets(X, Y)
    np.testing.assert_allclose(dc, X.mean(1) - Y.mean(1), atol=1e-12)
    for t in range(5):
        a, b = X[t] - X[t].mean(0), Y[t] - Y[t].mean(0)
        rot, _ = Rotation.align_vectors(b, a)                # X onto Y: the inverse turn
        assert angle[t] == pytest.approx(np.degrees(rot.magnitude()), abs=1e-6)
        assert angle[t] == pytest.approx(np.degrees(rots[t].magnitude()), abs=1.0)


def test_errors_split_into_translation_rotation_and_gaps(bench):
    rng = np.random.default_rng(5)
    truth = rng.normal(size=(13, 60, 3))
    frames = np.arange(0, 13, 3)
    inner = np.setdiff1d(np.arange(13), frames)
    # a constant offset: all of it translation, per axis, no rotation, no shape
    e = bench.ground_truth_errors(truth + [0.3, -0.4, 0.0], truth, inner, 2.0, frames)
    assert e["translation"] == pytest.approx(0.25) == pytest.approx(e["err"])
    np.testing.assert_allclose(e["translation_axes"], [0.15, 0.2, 0.0], atol=1e-12)
    assert e["rotation_deg"] == pytest.approx(0, abs=1e-6) and e["shape"] < 1e-12
    # each in-between frame turned by 10° about its centroid: rotation only
    R = Rotation.from_euler("z", 10, degrees=True)
    c = truth.mean(1, keepdims=True)
    turned = np.stack([R.apply(truth[t] - c[t, 0]) for t in range(13)]) + c
    e = bench.ground_truth_errors(turned, truth, inner, 2.0, frames)
    assert e["rotation_deg"] == pytest.approx(10.0) and e["translation"] < 1e-12
    # wrong only in the two end gaps (frames 1, 2 and 10, 11): interior 0
    X = truth.copy()
    X[[1, 2, 10, 11]] += 0.2 * rng.normal(size=(4, 60, 3))
    e = bench.ground_truth_errors(X, truth, inner, 2.0, frames)
    assert e["gaps"]["interior"] == 0.0 < e["gaps"]["end"]
    per = np.asarray(e["err_per_frame"])
    assert e["gaps"]["end"] == pytest.approx(np.sqrt(np.mean(per[[1, 2, 10, 11]] ** 2)))
    assert "gaps" not in bench.ground_truth_errors(X, truth, inner, 2.0)


def test_descriptor_swaps_of_a_rigid_motion_are_exact(bench):
    # a plate folded at 40° that only travels and turns: its descriptors are constant, so
    # the spline of them is exact and every variant rebuilds the true shape (invariance oracle)
    V, F = _hinged_plate([40.0] * 13)
    R = Rotation.from_euler("y", np.linspace(0, 60, 13)[:, None], degrees=True)
    truth = np.stack([R[t].apply(V[t]) + [0.5 * t, 0.1 * t ** 2, 0] for t in range(13)])
    start = truth + 0.01 * np.random.default_rng(0).normal(size=truth.shape)
    d = bench.descriptor_swaps(truth, F, np.arange(0, 13, 6), start, 1.0)
    assert d["unconverged"] == 0
    for name in ("spline", "true_L", "true_theta", "true_A"):
        assert d[name] < 1e-5


def _hinged_plate(angles, n: int = 9):
    """A flat square plate (x, z in [-1, 1], a regular n x n grid) folded about the line x = 0
    by ``angles`` (degrees, one per frame): an isometry, so only the dihedral angles of the
    hinge edges change, lengths and areas stay those of the flat plate."""
    g = np.linspace(-1.0, 1.0, n)
    X, Z = np.meshgrid(g, g, indexing="ij")
    P = np.stack([X.ravel(), np.zeros(n * n), Z.ravel()], axis=1)
    i, j = np.meshgrid(np.arange(n - 1), np.arange(n - 1), indexing="ij")
    a, b = (i * n + j).ravel(), ((i + 1) * n + j).ravel()
    F = np.concatenate([np.stack([a, b, b + 1], 1), np.stack([a, b + 1, a + 1], 1)])
    out = []
    for ang in np.radians(angles):
        Q = P.copy()
        right = P[:, 0] > 0
        Q[right, 0], Q[right, 1] = P[right, 0] * np.cos(ang), P[right, 0] * np.sin(ang)
        out.append(Q)
    return np.stack(out), F


def test_descriptor_swaps_find_the_angles_of_a_fast_fold(bench):
    # a hinge that folds to ~100° and back between keyframes 0, 6, 12 (at 0°, 15°, 30°): the
    # spline of the keyframe angles misses the fold; the motion is isometric, so the true
    # angles give the true in-betweens back, and the true lengths or areas are the spline's
    # (constant) and change nothing
    t = np.arange(13)
    truth, F = _hinged_plate(100.0 * np.sin(np.pi * t / 6) ** 2 + 2.5 * t)
    import shellspline

    frames = np.arange(0, 13, 6)
    start = shellspline.linear_blend(truth[frames], frames, 12)
    d = bench.descriptor_swaps(truth, F, frames, start, 1.0)
    assert d["spline"] > 0.05                                # the fold is missed
    assert d["true_theta"] < 1e-5
    assert d["true_L"] == pytest.approx(d["spline"], rel=1e-6)
    assert d["true_A"] == pytest.approx(d["spline"], rel=1e-6)
    assert d["unconverged"] == 0


def test_spline_error_weights_from_third_derivative_jumps(bench):
    from scipy.interpolate import CubicSpline

    rng = np.random.default_rng(7)
    frames = np.array([0, 4, 8, 12, 16])
    t = frames[:, None, None].astype(float)
    # vertex 0 moves at a constant velocity (the natural spline reproduces it: no jump),
    # vertex 1 on a sine, the others at random
    Vkey = rng.normal(size=(5, 6, 3))
    Vkey[:, 0] = (0.5 + 0.2 * t)[:, 0] * [1.0, 2.0, -1.0]
    Vkey[:, 1] = np.sin(t[:, 0] / 2.0) * [1.0, 0.0, 0.0]
    w = bench.spline_error_weights(Vkey, frames)
    # oracle: the jumps of scipy's third derivative, evaluated left and right of each knot
    d3 = CubicSpline(frames, Vkey, axis=0, bc_type="natural").derivative(3)
    jumps = np.stack([d3(f + 1e-9) - d3(f - 1e-9) for f in frames[1:-1]])
    q = (jumps ** 2).sum(-1).mean(0)
    np.testing.assert_allclose(w, 1.0 / (0.3 * np.median(q) + q), rtol=1e-6)
    assert q[0] < 1e-12 and w[0] == w.max()        # the exact track is trusted most
    assert bench.spline_error_weights(Vkey[:2], frames[:2]) is None
    # constant velocities everywhere: no jump, no preference
    lin = np.stack([Vkey[0] + f * Vkey[1] for f in frames])
    assert bench.spline_error_weights(lin, frames) is None


def test_placed_on_moves_rigidly_and_keeps_keyframes(bench):
    rng = np.random.default_rng(8)
    track = rng.normal(size=(7, 20, 3))
    R = Rotation.random(7, random_state=9)
    V = np.stack([R[k].apply(track[k]) + rng.normal(size=3) for k in range(7)])
    frames = np.array([0, 3, 6])
    out = bench.placed_on(V, track, frames, rng.uniform(0.5, 2.0, size=20))
    inner = [1, 2, 4, 5]
    np.testing.assert_allclose(out[inner], track[inner], atol=1e-9)   # rigid copies land
    assert np.array_equal(out[frames], V[frames])

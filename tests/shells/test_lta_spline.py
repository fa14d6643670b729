"""Tests of the time-discrete LΘA spline (shellspline.shells.lta_spline).

Oracles: scipy.interpolate.CubicSpline (convergence as K grows), and a dense per-column
solve of the normal equations whose matrix is read off a plain-loop evaluation of the energy.
"""
from __future__ import annotations

import importlib

import numpy as np
import pytest
from scipy.interpolate import CubicSpline

from shellspline.shells.lta_spline import LTASpline, lta_energy_per_frame, lta_spline, spline_energy

# the module itself (the package re-exports the function under the same name)
lta = importlib.import_module("shellspline.shells.lta_spline")

BCS = ("natural", "periodic", "hermite")


# --------------------------------------------------------------------------------------
# Oracle: the energy written as a loop, its Hessian, and a dense constrained solve
# --------------------------------------------------------------------------------------
def _energy_loop(z, w, bc):
    """Σ_k w_k (z_k − (w_{k−1} z_{k−1} + w_k z_{k+1})/(w_{k−1}+w_k))², term by term."""
    K = len(z) - 1
    total = 0.0
    for k in (range(K) if bc == "periodic" else range(1, K)):
        km, kp = ((k - 1) % K, (k + 1) % K) if bc == "periodic" else (k - 1, k + 1)
        mid = (w[km] * z[km] + w[k] * z[kp]) / (w[km] + w[k])
        total += w[k] * (z[k] - mid) ** 2
    return total


def _hessian_half(w, bc):
    """A with E(z) = zᵀ A z, from E(e_i + e_j) − E(e_i) − E(e_j) = 2 A_ij (E is quadratic)."""
    n = len(w)
    e = np.eye(n)
    Ei = np.array([_energy_loop(e[i], w, bc) for i in range(n)])
    A = np.empty((n, n))
    for i in range(n):
        for j in range(n):
            A[i, j] = 0.5 * (_energy_loop(e[i] + e[j], w, bc) - Ei[i] - Ei[j])
    return A


def _dense_oracle(zkey, frames, K, w, bc, return_cond=False):
    """Minimise the loop energy of one column with the keyframes fixed (np.linalg.solve)."""
    A = _hessian_half(w, bc)
    fixed = list(frames) + ([K] if bc == "periodic" else [])  # periodic: frame K is not a variable
    vals = list(zkey) + ([zkey[0]] if bc == "periodic" else [])
    free = np.setdiff1d(np.arange(K + 1), fixed)
    z = np.zeros(K + 1)
    z[fixed] = vals
    Aff = A[np.ix_(free, free)]
    z[free] = np.linalg.solve(Aff, -A[np.ix_(free, fixed)] @ np.array(vals))
    return (z, np.linalg.cond(Aff)) if return_cond else z


def _frames_for(bc, K=12):
    return {"natural": np.array([0, 3, 7, 10]),  # frames 11, 12 extrapolate
            "periodic": np.array([0, 4, 5, 9]),
            "hermite": np.array([0, 1, 6, K - 1, K])}[bc]


# --------------------------------------------------------------------------------------
# 1. Convergence to scipy's CubicSpline with a constant reference
# --------------------------------------------------------------------------------------
def _f(t):
    return np.sin(2.5 * t) + 0.3 * t**3


def _df(t):
    return 2.5 * np.cos(2.5 * t) + 0.9 * t**2


def _fp(t):  # 1-periodic
    return np.sin(2 * np.pi * t) + 0.5 * np.cos(4 * np.pi * t + 0.3)


def _errors_against_cubic_spline(bc, Ks=(20, 40, 80, 160)):
    errs = []
    for K in Ks:
        if bc == "natural":
            tj = np.array([0.0, 0.3, 0.55, 1.0])
            cs = CubicSpline(tj, _f(tj), bc_type="natural")
            frames, zkey = np.round(K * tj).astype(int), _f(tj)
        elif bc == "periodic":
            tj = np.array([0.0, 0.3, 0.55, 0.8])
            x = np.r_[tj, 1.0]
            y = _fp(x)
            y[-1] = y[0]
            cs = CubicSpline(x, y, bc_type="periodic")
            frames, zkey = np.round(K * tj).astype(int), _fp(tj)
        else:  # hermite <-> clamped spline with the true end slopes; frames 1, K-1 taken from it
            tj = np.array([0.0, 0.3, 0.55, 1.0])
            cs = CubicSpline(tj, _f(tj), bc_type=((1, _df(0.0)), (1, _df(1.0))))
            frames = np.r_[0, 1, np.round(K * tj[1:3]).astype(int), K - 1, K]
            zkey = cs(frames / K)
        assert set(np.round(K * tj).astype(int) / K) <= set(frames / K)  # keyframe times fixed
        assert np.allclose(np.round(K * tj) / K, tj, rtol=0, atol=1e-15)
        Z = lta_spline(zkey[:, None], frames, K, bc=bc)[:, 0]
        errs.append(np.max(np.abs(Z - cs(np.arange(K + 1) / K))))
    return np.array(errs)


@pytest.mark.parametrize("bc", BCS)
def test_constant_reference_converges_to_cubic_spline_second_order(bc):
    errs = _errors_against_cubic_spline(bc)
    orders = np.log2(errs[:-1] / errs[1:])
    # observed: natural 1.98-2.00, periodic 1.94-2.00, hermite 1.91-1.99
    assert np.all(orders >= 1.8), (bc, errs, orders)
    assert errs[-1] < 3e-4


# --------------------------------------------------------------------------------------
# 2./5. Keyframes, linear and constant data, periodic closure
# --------------------------------------------------------------------------------------
@pytest.mark.parametrize("bc", BCS)
@pytest.mark.parametrize("weighted", [False, True])
def test_keyframes_reproduced_bit_for_bit(bc, weighted):
    rng = np.random.default_rng(1)
    K, frames = 12, _frames_for(bc)
    Zk = rng.normal(size=(len(frames), 7)) * 10.0 ** rng.integers(-8, 8, size=7)
    W = rng.uniform(0.1, 3.0, size=(K + 1, 7)) if weighted else None
    Z = lta_spline(Zk, frames, K, bc=bc, weights=W)
    assert Z.shape == (K + 1, 7) and Z.dtype == np.float64
    assert np.array_equal(Z[frames], Zk)
    if bc == "periodic":
        assert np.array_equal(Z[K], Z[0])


def test_linear_data_stays_linear_and_constants_stay_constant():
    K, frames = 30, np.array([0, 3, 10, 11, 21])
    t = np.arange(K + 1, dtype=float)
    line = 2.0 - 0.37 * t
    Z = lta_spline(line[frames], frames, K)
    np.testing.assert_allclose(Z, line, rtol=0, atol=1e-11)  # round-off only; linear past the end too
    for bc in BCS:
        fr = _frames_for(bc)
        Zc = lta_spline(np.full((len(fr), 3), 4.5), fr, 12, bc=bc)
        np.testing.assert_allclose(Zc, 4.5, rtol=1e-13)
        rng = np.random.default_rng(2)
        Zw = lta_spline(np.full((len(fr), 3), 4.5), fr, 12, bc=bc,
                        weights=rng.uniform(0.5, 2.0, (13, 3)))
        np.testing.assert_allclose(Zw, 4.5, rtol=1e-13)


def test_periodic_row_K_equals_row_0_and_is_shift_invariant():
    K, frames = 16, np.array([0, 5, 9])
    v = np.array([1.0, -2.0, 0.5])
    Z = lta_spline(v, frames, K, bc="PERIODIC")
    assert Z.shape == (K + 1,)
    assert Z[K] == Z[0] == 1.0
    # shift time by 7 frames: keyframe 9 lands on 16 = 0 -> frames (0, 7, 12), values rotated
    Zs = lta_spline(v[[2, 0, 1]], [0, 7, 12], K, bc="periodic")
    np.testing.assert_allclose(Zs[:K], np.roll(Z[:K], 7), rtol=1e-12, atol=1e-12)
    rng = np.random.default_rng(13)
    W = rng.uniform(0.5, 2.0, size=(K + 1, 1))
    W[K] = W[0]
    Zw = lta_spline(v, frames, K, bc="periodic", weights=W)
    Zws = lta_spline(v[[2, 0, 1]], [0, 7, 12], K, bc="periodic",
                     weights=np.r_[np.roll(W[:K], 7, axis=0), W[K - 7:K - 6]])
    np.testing.assert_allclose(Zws[:K], np.roll(Zw[:K], 7), rtol=1e-12, atol=1e-12)


def test_hermite_differs_from_natural_only_through_the_extra_constraints():
    K = 10
    fr = np.array([0, 1, 5, 9, 10])
    Zk = np.array([0.0, 0.4, 1.0, 0.3, 0.0])
    Zh = lta_spline(Zk, fr, K, bc="hermite")
    Zn = lta_spline(Zk, fr, K, bc="natural")
    np.testing.assert_allclose(Zh, Zn, rtol=0, atol=1e-14)  # same energy, same constraints
    Zn3 = lta_spline(Zk[[0, 2, 4]], fr[[0, 2, 4]], K)
    assert not np.allclose(Zh, Zn3)


# --------------------------------------------------------------------------------------
# 3. Euler-Lagrange equations and the dense oracle
# --------------------------------------------------------------------------------------
@pytest.mark.parametrize("bc", BCS)
@pytest.mark.parametrize("kind", ["batched", "shared", "none", "wide"])
def test_matches_dense_oracle_per_column(bc, kind):
    rng = np.random.default_rng(3)
    K, frames, d = 12, _frames_for(bc), 5
    Zk = rng.normal(size=(len(frames), d))
    if kind == "batched":
        W = rng.uniform(0.05, 5.0, size=(K + 1, d))
    elif kind == "shared":
        W = np.broadcast_to(rng.uniform(0.05, 5.0, size=(K + 1, 1)), (K + 1, d)).copy()
    elif kind == "wide":  # weights over six decades, and an isolated zero weight
        W = rng.uniform(0.05, 5.0, size=(K + 1, d))
        W[:, 0] = 10.0 ** (3 * np.sin(np.linspace(0.0, 5.0, K + 1)))
        W[6, 1] = 0.0
        W[2, 2] = 1e-9
    else:
        W = None
    Z = lta_spline(Zk, frames, K, bc=bc, weights=W)
    for c in range(d):
        w = np.ones(K + 1) if W is None else np.maximum(W[:, c], 1e-12 * W[:, c].max())
        oracle, cond = _dense_oracle(Zk[:, c], frames, K, w, bc, return_cond=True)
        # both solves are backward stable: they agree to ~cond·eps (1e-10 for sane weights;
        # the "wide" columns reach cond ~ 1e11, where 1e-5 is all that float64 can promise)
        tol = max(1e-10, 1e-15 * cond)
        np.testing.assert_allclose(Z[:, c], oracle, rtol=tol, atol=tol * np.abs(oracle).max())
        if kind != "wide":
            assert tol == 1e-10


@pytest.mark.parametrize("bc", BCS)
def test_euler_lagrange_gradient_vanishes_at_free_frames(bc):
    rng = np.random.default_rng(4)
    K, frames = 12, _frames_for(bc)
    Zk = rng.normal(size=len(frames))
    w = rng.uniform(0.2, 4.0, size=K + 1)
    Z = lta_spline(Zk, frames, K, bc=bc, weights=w[:, None])
    free = np.setdiff1d(np.arange(K if bc == "periodic" else K + 1), frames)
    h = 1e-3
    e = np.eye(K + 1)

    def grad(z):
        return np.array([(_energy_loop(z + h * e[i], w, bc) - _energy_loop(z - h * e[i], w, bc))
                         / (2 * h) for i in free])

    g = grad(Z)
    g_ref = grad(Z + rng.normal(scale=0.1, size=K + 1))  # gradient of a non-minimiser
    assert np.abs(g).max() < 1e-9 * np.abs(g_ref).max()
    # and the minimum: the energy only grows under free perturbations
    E0 = spline_energy(Z, bc=bc, weights=w[:, None])
    for _ in range(5):
        dz = np.zeros(K + 1)
        dz[free] = rng.normal(scale=1e-2, size=len(free))
        assert spline_energy(Z + dz, bc=bc, weights=w[:, None]) > E0


@pytest.mark.parametrize("bc, K, frames", [
    ("periodic", 3, [0, 1]), ("periodic", 4, [0, 2]), ("periodic", 5, [0, 3]),
    ("natural", 2, [0, 2]), ("natural", 3, [0, 1]), ("hermite", 4, [0, 1, 3, 4]),
])
def test_short_paths_match_oracle(bc, K, frames):
    """Tiny K, where cyclic neighbours coincide or wrap onto each other."""
    rng = np.random.default_rng(14)
    Zk = rng.normal(size=(len(frames), 3))
    W = rng.uniform(0.3, 3.0, size=(K + 1, 3))
    for weights in (None, W):
        Z = lta_spline(Zk, frames, K, bc=bc, weights=weights)
        for c in range(3):
            w = np.ones(K + 1) if weights is None else W[:, c]
            np.testing.assert_allclose(Z[:, c], _dense_oracle(Zk[:, c], frames, K, w, bc),
                                       rtol=1e-12, atol=1e-12)


def test_nonuniform_keyframe_spacing_matches_oracle():
    rng = np.random.default_rng(5)
    K, frames = 30, np.array([0, 3, 10, 11, 30])
    Zk = rng.normal(size=(5, 4))
    W = rng.uniform(0.3, 3.0, size=(K + 1, 4))
    for weights in (None, W):
        Z = lta_spline(Zk, frames, K, weights=weights)
        assert np.array_equal(Z[frames], Zk)
        for c in range(4):
            w = np.ones(K + 1) if weights is None else W[:, c]
            np.testing.assert_allclose(Z[:, c], _dense_oracle(Zk[:, c], frames, K, w, "natural"),
                                       rtol=1e-10, atol=1e-10)


# --------------------------------------------------------------------------------------
# 4. Column independence, weight conventions, precompute/solve split
# --------------------------------------------------------------------------------------
@pytest.mark.parametrize("bc", BCS)
def test_columns_are_independent(bc, monkeypatch):
    rng = np.random.default_rng(6)
    K, frames, d = 12, _frames_for(bc), 40
    Zk = rng.normal(size=(len(frames), d))
    W = rng.uniform(0.1, 2.0, size=(K + 1, d))
    Z = lta_spline(Zk, frames, K, bc=bc, weights=W)
    Z0 = lta_spline(Zk, frames, K, bc=bc)
    for c in (0, 17, d - 1):
        Zc = lta_spline(Zk[:, c:c + 1], frames, K, bc=bc, weights=W[:, c:c + 1])
        np.testing.assert_allclose(Zc[:, 0], Z[:, c], rtol=1e-13, atol=1e-13)
        np.testing.assert_allclose(lta_spline(Zk[:, c], frames, K, bc=bc), Z0[:, c],
                                   rtol=1e-13, atol=1e-13)
    # several small chunks of columns give the same result as one chunk
    monkeypatch.setattr(lta, "CHUNK_ELEMS", 3 * 13 * 3)
    assert len(LTASpline(frames, K, bc, W).chunks(d)) > 3
    np.testing.assert_array_equal(lta_spline(Zk, frames, K, bc=bc, weights=W), Z)


@pytest.mark.parametrize("bc", BCS)
def test_weight_conventions(bc):
    rng = np.random.default_rng(7)
    K, frames, d = 12, _frames_for(bc), 6
    Zk = rng.normal(size=(len(frames), d))
    Z = lta_spline(Zk, frames, K, bc=bc)
    np.testing.assert_array_equal(lta_spline(Zk, frames, K, bc=bc, weights=np.ones((K + 1, d))), Z)
    # constant in time (per column), any positive constant: the same spline
    Wc = np.tile(rng.uniform(0.1, 9.0, size=d), (K + 1, 1))
    np.testing.assert_array_equal(lta_spline(Zk, frames, K, bc=bc, weights=Wc), Z)
    np.testing.assert_array_equal(lta_spline(Zk, frames, K, bc=bc, weights=Wc[0]), Z)
    # (K+1, 1) broadcasts to every column; the batched path agrees with the shared one
    w1 = rng.uniform(0.1, 2.0, size=(K + 1, 1))
    Zs = lta_spline(Zk, frames, K, bc=bc, weights=w1)
    np.testing.assert_array_equal(lta_spline(Zk, frames, K, bc=bc, weights=np.tile(w1, (1, d))), Zs)
    W = np.tile(w1, (1, d))
    W[:, 0] *= np.linspace(1, 2, K + 1)  # column 0 differs -> the batched path
    Zb = lta_spline(Zk, frames, K, bc=bc, weights=W)
    assert LTASpline(frames, K, bc, W).batched and not LTASpline(frames, K, bc, w1).batched
    np.testing.assert_allclose(Zb[:, 1:], Zs[:, 1:], rtol=1e-12, atol=1e-12)
    # the spline is invariant under scaling each column's weights
    np.testing.assert_allclose(lta_spline(Zk, frames, K, bc=bc, weights=W * np.arange(1, d + 1)),
                               Zb, rtol=1e-12, atol=1e-12)


def test_bad_weights_do_not_produce_nan():
    rng = np.random.default_rng(8)
    K, frames, d = 12, np.array([0, 5, 12]), 5
    Zk = rng.normal(size=(3, d))
    W = rng.uniform(0.5, 2.0, size=(K + 1, d))
    W[:, 0] = 0.0               # all zero -> unit weights
    W[3, 1] = np.nan            # non-finite -> tiny
    W[4, 2] = np.inf
    W[5, 3] = 0.0               # zero -> tiny
    W[6, 4] = -1.0              # negative -> tiny
    Z = lta_spline(Zk, frames, K, weights=W)
    assert np.all(np.isfinite(Z))
    np.testing.assert_allclose(Z[:, 0], lta_spline(Zk[:, 0], frames, K), rtol=1e-12, atol=1e-12)
    assert np.all(np.isfinite(lta_energy_per_frame(Z, weights=W)))


@pytest.mark.parametrize("bc", BCS)
def test_singular_weights_fall_back_to_constant_reference_with_a_warning(bc):
    K, frames = 30, {"natural": [0, 10, 30], "periodic": [0, 10, 20],
                     "hermite": [0, 1, 10, 29, 30]}[bc]
    rng = np.random.default_rng(12)
    Zk = rng.normal(size=(len(frames), 3))
    W = rng.uniform(0.5, 2.0, size=(K + 1, 3))
    W[::2, 1] = 1e-8  # pairs of frames decouple: singular to working precision
    with pytest.warns(RuntimeWarning, match="1 of 3 descriptor column"):
        Z = lta_spline(Zk, frames, K, bc=bc, weights=W)
    with pytest.warns(RuntimeWarning, match="1 of 3 descriptor column"):
        np.testing.assert_array_equal(LTASpline(frames, K, bc, W).solve(Zk), Z)
    np.testing.assert_allclose(Z[:, 1], lta_spline(Zk[:, 1], frames, K, bc=bc), rtol=1e-13, atol=1e-13)
    np.testing.assert_allclose(Z[:, [0, 2]], lta_spline(Zk[:, [0, 2]], frames, K, bc=bc,
                                                        weights=W[:, [0, 2]]), rtol=1e-13, atol=1e-13)
    with pytest.warns(RuntimeWarning, match="all descriptor columns"):
        Z1 = lta_spline(Zk, frames, K, bc=bc, weights=W[:, 1:2])
    np.testing.assert_allclose(Z1, lta_spline(Zk, frames, K, bc=bc), rtol=1e-13, atol=1e-13)


def test_precompute_object_reuses_its_factorization():
    rng = np.random.default_rng(9)
    K, frames, d = 20, np.array([0, 4, 13, 20]), 9
    for W in (None, rng.uniform(0.2, 2.0, size=(K + 1, d))):
        for bc in ("natural", "hermite") if W is None else ("natural",):
            fr = np.array([0, 1, 10, 19, 20]) if bc == "hermite" else frames
            spl = LTASpline(fr, K, bc=bc, weights=W)
            assert spl.n_free == K + 1 - len(fr) and spl.bandwidth == 2
            for _ in range(2):
                Zk = rng.normal(size=(len(fr), d))
                np.testing.assert_array_equal(spl.solve(Zk), lta_spline(Zk, fr, K, bc, W))
    spl = LTASpline([0, 4, 9], 16, "periodic", rng.uniform(0.2, 2.0, size=(17, 3)))
    assert spl.bc == "periodic" and spl.n_free == 13 and spl.bandwidth <= 4
    with pytest.raises(ValueError, match="Z_key"):
        spl.solve(np.zeros((3, 4)))  # weights fix d = 3


# --------------------------------------------------------------------------------------
# Energy
# --------------------------------------------------------------------------------------
@pytest.mark.parametrize("bc", BCS)
def test_energy_per_frame_matches_loop_and_is_minimal_at_the_spline(bc):
    rng = np.random.default_rng(10)
    K, frames, d = 12, _frames_for(bc), 3
    W = rng.uniform(0.2, 3.0, size=(K + 1, d))
    Z = lta_spline(rng.normal(size=(len(frames), d)), frames, K, bc=bc, weights=W)
    Ek = lta_energy_per_frame(Z, bc=bc, weights=W)
    assert Ek.shape == (K + 1,) and Ek[K] == 0.0 and (bc == "periodic" or Ek[0] == 0.0)
    total = sum(_energy_loop(Z[:, c], W[:, c], bc) for c in range(d))
    np.testing.assert_allclose(Ek.sum(), total, rtol=1e-12)
    np.testing.assert_allclose(spline_energy(Z, bc, W), 4 * K**3 * total, rtol=1e-12)


def test_spline_energy_approximates_integral_of_squared_second_derivative():
    K = 400
    t = np.arange(K + 1) / K
    z = np.sin(3 * t)  # ∫ (9 sin 3t)² dt
    exact = 81 * (0.5 - np.sin(6.0) / 12)
    assert abs(spline_energy(z) - exact) < 0.01 * exact


# --------------------------------------------------------------------------------------
# 7. Invalid input
# --------------------------------------------------------------------------------------
@pytest.mark.parametrize("kwargs, name", [
    (dict(frames=[0, 5, 5, 10]), "frames"),                 # not strictly increasing
    (dict(frames=[0, 7, 3, 10]), "frames"),
    (dict(frames=[0, 5, 11]), "frames"),                    # beyond K
    (dict(frames=[-1, 5, 10]), "frames"),
    (dict(frames=[2, 5, 10]), "frames"),                    # natural must start at 0
    (dict(frames=[0, 2.5, 10]), "frames"),                  # not integer-valued
    (dict(frames=[[0, 5, 10]]), "frames"),                  # wrong shape
    (dict(frames=[0], Z_key=np.zeros((1, 2))), "frames"),   # J < 2
    (dict(Z_key=np.zeros((2, 2))), "Z_key"),                # rows != J
    (dict(Z_key=np.zeros((3, 2, 2))), "Z_key"),
    (dict(Z_key=np.array([[0.0], [np.nan], [1.0]])), "Z_key"),
    (dict(Z_key=np.array([[0.0], [np.inf], [1.0]])), "Z_key"),
    (dict(K=0, frames=[0, 1]), "K"),
    (dict(K=2.5), "K"),
    (dict(bc="clamped"), "bc"),
    (dict(bc=None), "bc"),
    (dict(bc="periodic"), "frames"),                        # frames[-1] == K
    (dict(bc="hermite"), "frames"),                         # no frames 1 and K-1
    (dict(bc="hermite", frames=[0, 1, 5, 10], Z_key=np.zeros((4, 2))), "frames"),
    (dict(weights=np.ones((10, 2))), "weights"),            # K rows instead of K+1
    (dict(weights=np.ones((11, 3))), "Z_key"),              # d mismatch
    (dict(weights=np.ones(3)), "Z_key"),
    (dict(weights=np.ones((11, 2, 1))), "weights"),
])
def test_invalid_input_raises_naming_the_argument(kwargs, name):
    args = dict(Z_key=np.zeros((3, 2)), frames=[0, 5, 10], K=10)
    args.update(kwargs)
    with pytest.raises(ValueError, match=f"`{name}`"):
        lta_spline(**args)


def test_error_messages_show_what_was_got():
    with pytest.raises(ValueError, match=r"strictly increasing, got \[0, 5, 5\]"):
        lta_spline(np.zeros(3), [0, 5, 5], 10)
    with pytest.raises(ValueError, match=r"'natural', 'periodic', 'hermite'.*'spline'"):
        lta_spline(np.zeros(3), [0, 5, 10], 10, bc="spline")
    with pytest.raises(ValueError, match=r"missing \[1, 9\]"):
        lta_spline(np.zeros(3), [0, 5, 10], 10, bc="hermite")
    with pytest.raises(ValueError, match="`bc`"):
        lta_energy_per_frame(np.zeros(5), bc="cyclic")
    with pytest.raises(ValueError, match="`weights`"):
        lta_energy_per_frame(np.zeros((5, 2)), weights=np.ones((4, 2)))


def test_accepted_spellings():
    Zk = np.array([0.0, 1.0, 0.0])
    Z = lta_spline(Zk, [0, 5, 10], 10)
    np.testing.assert_array_equal(lta_spline(Zk, np.array([0.0, 5.0, 10.0]), 10.0, " Natural "), Z)
    np.testing.assert_array_equal(lta_spline(Zk, np.array([0, 5, 10], dtype=np.int32),
                                             np.int64(10)), Z)
    # minimal cases: nothing free
    np.testing.assert_array_equal(lta_spline(np.array([1.0, 2.0]), [0, 1], 1), [1.0, 2.0])
    np.testing.assert_array_equal(lta_spline(np.array([1.0, 2.0]), [0, 1], 1, "hermite"), [1.0, 2.0])
    np.testing.assert_array_equal(lta_spline(np.array([1.0, 2.0]), [0, 1], 2, "periodic"),
                                  [1.0, 2.0, 1.0])


# --------------------------------------------------------------------------------------
# 8. Many columns (the real workload): vectorised over descriptors
# --------------------------------------------------------------------------------------
def test_many_columns_weighted_natural_completes():
    rng = np.random.default_rng(11)
    K, d = 170, 200_000
    frames = np.array([0, 40, 85, 130, 170])
    Zk = rng.normal(size=(len(frames), d))
    W = rng.uniform(0.5, 2.0, size=(K + 1, d))
    Z = lta_spline(Zk, frames, K, weights=W)
    assert Z.shape == (K + 1, d) and np.all(np.isfinite(Z))
    assert np.array_equal(Z[frames], Zk)
    cols = [0, 123_457, d - 1]
    for c in cols:  # spot-check against the per-column shared-matrix solve
        np.testing.assert_allclose(Z[:, c], lta_spline(Zk[:, c], frames, K, weights=W[:, c:c + 1]),
                                   rtol=1e-10, atol=1e-10)


# --------------------------------------------------------------------------------------
# 9. The continuous-time spline (spline="continuous")
# --------------------------------------------------------------------------------------
CONT_CASES = [("natural", [0, 3, 7, 10], 10), ("natural", [0, 2, 3, 9, 17], 17),
              ("natural", [0, 5], 5), ("periodic", [0, 4, 5, 9], 12),
              ("periodic", [0, 2], 4), ("periodic", [0, 1, 6, 7, 8], 11)]


@pytest.mark.parametrize("bc, frames, K", CONT_CASES)
def test_continuous_equals_scipy_cubic_spline(bc, frames, K):
    """Per column, P @ Z_key is scipy's CubicSpline through the keyframes (natural or
    periodic) at every frame, to round-off; keyframe rows are exactly the unit vectors."""
    rng = np.random.default_rng(len(frames) + K)
    fr = np.array(frames)
    Zk = rng.normal(size=(len(fr), 7)) * [1, 10, 0.1, 1, 1, 3, 1e3]
    P = lta.continuous_spline_matrix(fr, K, bc)
    if bc == "periodic":
        cs = CubicSpline(np.append(fr, K), np.vstack([Zk, Zk[:1]]), bc_type="periodic")
    else:
        cs = CubicSpline(fr, Zk, bc_type="natural")
    Z = lta_spline(Zk, fr, K, bc=bc, spline="continuous")
    ref = cs(np.arange(K + 1))
    assert np.abs(Z - ref).max() <= 1e-12 * np.abs(Zk).max()
    assert np.array_equal(Z[fr], Zk)  # keyframes exact
    assert np.array_equal(P[fr], np.eye(len(fr)))
    if bc == "periodic":
        assert np.array_equal(Z[K], Zk[0])


def test_continuous_extrapolates_along_the_end_tangent():
    """Frames after the last keyframe continue the natural spline's tangent line (as the
    discrete spline extrapolates linearly): value and slope from scipy at the last knot."""
    fr, K = np.array([0, 3, 7, 10]), 14
    Zk = np.array([[0.0], [2.0], [-1.0], [0.5]])
    cs = CubicSpline(fr, Zk[:, 0], bc_type="natural")
    Z = lta_spline(Zk, fr, K, spline="continuous")[:, 0]
    t = np.arange(11, 15)
    assert np.allclose(Z[t], cs(10) + cs(10, 1) * (t - 10), atol=1e-13)
    assert np.allclose(Z[:11], cs(np.arange(11)), atol=1e-13)


def test_continuous_hermite_is_the_natural_spline_through_its_keyframes():
    """Hermite ends: the poses at 1 and K-1 fix the end velocities; the discrete hermite
    spline is its natural one with those keyframes, and so is the continuous one."""
    fr, K = np.array([0, 1, 6, 11, 12]), 12
    Zk = np.array([0.0, 0.3, 2.0, -0.2, 0.1])
    Zh = lta_spline(Zk, fr, K, bc="hermite", spline="continuous")
    assert np.allclose(Zh, CubicSpline(fr, Zk, bc_type="natural")(np.arange(K + 1)), atol=1e-13)
    assert np.array_equal(lta_spline(Zk, fr, K, bc="hermite"), lta_spline(Zk, fr, K))


@pytest.mark.parametrize("bc, frames, K", [("natural", [0, 3, 7, 10], 10),
                                           ("periodic", [0, 4, 5, 9], 12)])
def test_discrete_spline_converges_to_the_continuous_one(bc, frames, K):
    """The discrete spline on an m times finer time grid (keyframes at the same times) tends
    to the continuous one at second order: the error falls ~4x per halving of the step."""
    fr = np.array(frames)
    Zk = np.array([[0.0, 1.0], [2.0, -1.0], [-1.0, 0.5], [0.5, 2.0]])
    Zc = lta_spline(Zk, fr, K, bc=bc, spline="continuous")
    err = []
    for m in (2, 4, 8, 16):
        err.append(np.abs(lta_spline(Zk, fr * m, K * m, bc=bc)[::m] - Zc).max())
    ratios = np.array(err[:-1]) / np.array(err[1:])
    assert err[0] > 1e-3  # the discrete spline differs
    assert np.all((ratios > 3.5) & (ratios < 4.5)), ratios


def test_continuous_with_weights_constant_in_time_is_the_cubic():
    """Weights constant in time (None, (d,), equal rows) give the C² cubic spline; a bad
    `spline` is a one-line error naming it."""
    fr, K = np.array([0, 4, 8]), 8
    Zk = np.array([[0.0, 1.0], [1.0, 3.0], [0.0, 2.0]])
    ref = lta.continuous_spline_matrix(fr, K) @ Zk
    for w in (None, np.array([1.0, 5.0]), np.tile([2.0, 7.0], (K + 1, 1))):
        assert np.allclose(lta_spline(Zk, fr, K, weights=w, spline="continuous"), ref,
                           atol=1e-14)
        assert np.allclose(LTASpline(fr, K, weights=w, spline="Continuous ").solve(Zk), ref,
                           atol=1e-14)
    with pytest.raises(ValueError, match=r"`spline` must be one of 'discrete', 'continuous'"
                                         r".*got 'cubic'") as e:
        LTASpline(fr, K, spline="cubic")
    assert "\n" not in str(e.value)
    with pytest.raises(ValueError, match="`spline`"):
        lta.canonical_spline(None)


def _weighted_cubic_oracle(zkey, frames, K, w, periodic):
    """Minimise Σ_k w_k ∫_k^{k+1} z''² over piecewise cubics (coefficients per frame interval)
    with z and the flux w z' continuous at every frame and z = zkey at the keyframes: a dense
    KKT solve (np.linalg.solve), independent of the banded value/flux formulation."""
    nseg = K
    H = np.zeros((4 * nseg, 4 * nseg))
    for k in range(nseg):  # ∫0^1 (2 c2 + 6 c3 s)² ds = 4 c2² + 12 c2 c3 + 12 c3²
        i = 4 * k
        H[i + 2, i + 2] += 4 * w[k]
        H[i + 2, i + 3] += 6 * w[k]
        H[i + 3, i + 2] += 6 * w[k]
        H[i + 3, i + 3] += 12 * w[k]
    rows, rhs = [], []
    val1, der1 = np.array([1.0, 1, 1, 1]), np.array([0.0, 1, 2, 3])  # z(1), z'(1)
    for k in range(nseg if periodic else nseg - 1):
        m = (k + 1) % nseg
        r = np.zeros(4 * nseg)
        r[4 * k:4 * k + 4] = val1
        r[4 * m] -= 1.0                        # z_k(1) = z_m(0)
        rows.append(r), rhs.append(0.0)
        r = np.zeros(4 * nseg)
        r[4 * k:4 * k + 4] = w[k] * der1
        r[4 * m + 1] -= w[m]                   # w_k z_k'(1) = w_m z_m'(0)
        rows.append(r), rhs.append(0.0)
    for f, v in zip(frames, zkey):
        r = np.zeros(4 * nseg)
        if f < nseg:
            r[4 * f] = 1.0
        else:                                  # the end of the last interval
            r[4 * (nseg - 1):] = val1
        rows.append(r), rhs.append(v)
    A = np.array(rows)
    kkt = np.block([[2 * H, A.T], [A, np.zeros((len(rows), len(rows)))]])
    c = np.linalg.solve(kkt, np.concatenate([np.zeros(4 * nseg), rhs]))[:4 * nseg]
    z = np.append(c[0::4], c[4 * (nseg - 1):4 * nseg].sum())
    return z


@pytest.mark.parametrize("bc, frames, K", [("natural", [0, 3, 7, 10], 12),
                                           ("natural", [0, 5], 9),
                                           ("periodic", [0, 4, 5, 9], 12),
                                           ("periodic", [0, 3], 6)])
def test_continuous_with_weights_that_vary_in_time(bc, frames, K):
    """The continuous spline with per-frame weights is the minimiser of Σ w_k ∫ z''² with a
    continuous flux w z' (dense KKT oracle), the limit of the discrete spline on finer time
    grids (O(1/m)), keyframes exact, and unchanged by scaling a column's weights."""
    rng = np.random.default_rng(K + len(frames))
    fr = np.array(frames)
    d = 3
    Zk = rng.normal(size=(len(fr), d))
    W = rng.uniform(0.3, 3.0, size=(K + 1, d))
    Z = lta_spline(Zk, fr, K, bc=bc, weights=W, spline="continuous")
    periodic = bc == "periodic"
    for c in range(d):
        ref = _weighted_cubic_oracle(Zk[:, c], fr, K, W[:, c], periodic)
        assert np.abs(Z[:, c] - ref).max() <= 1e-10 * np.abs(Zk[:, c]).max()
    assert np.array_equal(Z[fr], Zk)
    # the same spline as one precomputed object, with scaled columns, and column by column
    spl = LTASpline(fr, K, bc=bc, weights=W * [1.0, 1e3, 1e-3], spline="continuous")
    assert spl.batched and spl.bandwidth <= (5 if periodic else 3)
    assert np.allclose(spl.solve(Zk), Z, rtol=0, atol=1e-10)
    assert np.allclose(lta_spline(Zk[:, 1], fr, K, bc=bc, weights=W[:, 1:2],
                                  spline="continuous"), Z[:, 1], atol=1e-12)
    # the discrete spline on an m times finer grid (interval k's weight on its m sub-steps)
    err = []
    for m in (8, 16, 32):
        i = np.arange(m * K + 1)
        Zm = lta_spline(Zk, fr * m, m * K, bc=bc, weights=W[np.minimum(i // m, K)])
        err.append(np.abs(Zm[::m] - Z).max())
    if bc == "natural" and len(fr) == 2:  # zero energy (w z' constant) on both grids
        assert max(err) < 1e-6
    else:
        assert err[0] > 1e-4 and 1.7 < err[0] / err[1] < 2.3 and 1.7 < err[1] / err[2] < 2.3, err


def test_discrete_is_the_default_and_unchanged():
    """spline='discrete' is the default and is the dense oracle's minimiser (the paper's
    spline); the continuous one differs from it between keyframes."""
    fr, K = np.array([0, 3, 7, 10]), 12
    Zk = np.array([0.0, 2.0, -1.0, 0.5])
    Zd = lta_spline(Zk, fr, K)
    assert np.array_equal(Zd, lta_spline(Zk, fr, K, spline="discrete"))
    assert np.allclose(Zd, _dense_oracle(Zk, fr, K, np.ones(K + 1), "natural"), atol=1e-12)
    assert np.abs(lta_spline(Zk, fr, K, spline="continuous") - Zd).max() > 1e-2

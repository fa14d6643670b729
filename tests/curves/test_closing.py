"""Closing curves (shellspline.curves.closing): seed 000's gradient flow and the
Gauss-Newton projection close a real walk clip >= 100x in <= 10 iterations; C1 closure removes
the seam velocity jump; quadratic convergence checks the Jacobian without finite differences."""
from __future__ import annotations

import numpy as np
import pytest

from conftest import shared_data
from shellspline.curves.closing import close, seam_gap
from shellspline.curves.srv import ProductCurve, srv
from shellspline.errors import ShellsplineError
from shellspline.groups import so3


def synthetic_open_curve(N=80, d=3, m=2):
    t = np.linspace(0, 1, N)[:, None]
    W = np.stack([np.c_[np.sin(2 * np.pi * t + j) + 0.3 * t, np.cos(2 * np.pi * t) * 0.5,
                        0.8 * t * j] for j in range(d)], axis=1)
    R = so3.exp(W)
    X = np.c_[np.cos(2 * np.pi * t) + 0.2 * t, np.sin(2 * np.pi * t)][:, :m]
    return ProductCurve(R, X, t[:, 0] * 3.0)


@pytest.fixture(scope="module")
def walk():
    from shellspline.io.bvh import read_bvh

    m = read_bvh(shared_data("motion", "dataset-1_walk_normal_001.bvh"))
    R, t = m.local_transforms()
    # joint rotations and the root height (metres): what should repeat in a walk loop
    return ProductCurve(R, t[:, 0, 1:2] * 0.01, np.arange(m.n_frames) * m.frame_time)


@pytest.mark.parametrize("method", ["gauss-newton", "gradient"])
def test_walk_clip_seam_gap_reduced_100x_in_10_iterations(walk, method):
    g0 = seam_gap(walk)
    assert g0 > 0.1                                   # the clip is not a loop
    r = close(walk, iterations=10, method=method)
    assert r.iterations <= 10
    assert r.seam_gap[0] == pytest.approx(g0)
    assert r.seam_gap[-1] <= g0 / 100
    assert seam_gap(r.curve) == pytest.approx(r.seam_gap[-1], abs=1e-12)
    assert len(r.seam_gap) == r.iterations + 1
    assert np.all(np.diff(r.seam_gap) < 0)           # every accepted step lowers the gap
    # the motion is kept: the SRV changes by a few per cent of its norm
    q = srv(walk.with_times(np.linspace(0, 1, walk.n_frames)))
    assert r.change < 0.03 * np.sqrt(np.mean(np.sum(q * q, axis=1)))
    np.testing.assert_allclose(r.curve.R[0], walk.R[0], atol=1e-12)
    np.testing.assert_allclose(r.curve.t, walk.t)


def test_walk_clip_c1_removes_the_velocity_jump(walk):
    r = close(walk, c1=True)
    assert r.status == "converged"
    assert r.seam_gap[-1] < 1e-9
    assert r.velocity_jump[-1] < 1e-6 * r.velocity_jump[0]
    c0 = close(walk)
    assert c0.velocity_jump[-1] > 0.5 * c0.velocity_jump[0]   # C0 closing leaves the jump


def test_gauss_newton_converges_quadratically():
    c = synthetic_open_curve()
    r = close(c, iterations=6, tol=0)
    g = r.seam_gap
    assert g[0] > 0.3
    # quadratic: e_{k+1} <= C e_k^2 until rounding (a wrong Jacobian gives linear at best)
    k = np.nonzero(g > 1e-12)[0]
    ratios = g[k[1:]] / g[k[:-1]] ** 2
    assert np.all(ratios[1:] < 10.0)
    assert g[3] < 1e-9


def test_gradient_flow_decreases_linearly():
    r = close(synthetic_open_curve(), iterations=10, method="gradient")
    assert r.status in ("limit", "converged")
    assert np.all(np.diff(r.seam_gap) < 0)
    assert r.seam_gap[-1] < r.seam_gap[0] / 100


def test_closed_curve_is_left_alone_and_closed_result_loops():
    t = np.linspace(0, 1, 60)
    loop = ProductCurve(so3.exp(np.c_[np.sin(2 * np.pi * t), np.cos(2 * np.pi * t) - 1,
                                      0 * t])[:, None], np.c_[np.sin(2 * np.pi * t)], t)
    r = close(loop, tol=1e-9)
    assert r.status == "converged" and r.iterations == 0 and r.change == 0
    c = close(synthetic_open_curve())
    np.testing.assert_allclose(c.curve.R[-1], c.curve.R[0], atol=1e-9)
    np.testing.assert_allclose(c.curve.X[-1], c.curve.X[0], atol=1e-9)


def test_euclidean_only_and_rotation_only():
    t = np.linspace(0, 1, 50)
    arc = ProductCurve(X=np.c_[np.cos(5 * t), np.sin(5 * t), t], t=t)
    r = close(arc)
    assert r.status == "converged" and np.linalg.norm(r.curve.X[-1] - r.curve.X[0]) < 1e-10
    rot = ProductCurve(synthetic_open_curve().R, None)
    assert close(rot).seam_gap[-1] < 1e-10


def test_invalid_inputs_raise():
    c = synthetic_open_curve()
    with pytest.raises(ShellsplineError, match="method"):
        close(c, method="newton")
    with pytest.raises(ShellsplineError, match="iterations"):
        close(c, iterations=-1)
    with pytest.raises(ShellsplineError, match="kappa"):
        close(c, kappa=-1.0)
    with pytest.raises(ShellsplineError, match="ProductCurve"):
        close(np.zeros((10, 3)))
    with pytest.raises(ShellsplineError, match="3 samples"):
        close(ProductCurve(X=np.zeros((2, 1))))


def test_c1_metric_solver_is_the_inverse_of_the_periodic_h1_metric():
    """The banded Cholesky + Woodbury solve against the dense matrix of the metric built from
    its definition: sum h |x|^2 + kappa sum_i |x_{i+1} - x_i|^2 / hm_i over all n cyclic edges
    (hm_i the mean of the two intervals' lengths). A wrong corner term would still close the
    curve (any SPD metric does), so only this pins the metric down."""
    from shellspline.curves.closing import _metric_solver

    rng = np.random.default_rng(5)
    n, kappa = 40, 0.01
    h = rng.uniform(0.5, 1.5, n)
    h /= h.sum()
    W = np.diag(h)
    for i in range(n):
        j = (i + 1) % n
        w = kappa / (0.5 * (h[i] + h[j]))
        W[[i, j], [i, j]] += w
        W[i, j] -= w
        W[j, i] -= w
    F = rng.normal(size=(n, 3))
    np.testing.assert_allclose(_metric_solver(h, kappa)(F), np.linalg.solve(W, F),
                               rtol=1e-10, atol=1e-12 * np.abs(np.linalg.solve(W, F)).max())
    np.testing.assert_allclose(_metric_solver(h, 0.0)(F), F / h[:, None], rtol=1e-15)


@pytest.mark.parametrize("c1", [False, True])
def test_constraint_jacobian_against_central_differences(c1):
    """J z and J^T y of the linearised closure constraints against central differences of the
    discrete seam gap (and q_end - q_0), and J^T as the adjoint of J."""
    from shellspline.curves.closing import _Constraints, _forward, seam_weights

    c = synthetic_open_curve(N=30, d=2, m=2)
    h = np.diff(np.linspace(0, 1, c.n_frames))
    q = srv(c.with_times(np.linspace(0, 1, c.n_frames)))
    d = c.d

    def residual(qq):
        _, gap = _forward(qq, h, c.R[0], c.X[0], d)
        return np.concatenate([gap, seam_weights(h) @ qq]) if c1 else gap

    cc, gap = _forward(q, h, c.R[0], c.X[0], d)
    op = _Constraints(q, h, cc, gap, d, c1)
    rng = np.random.default_rng(1)
    Z = rng.normal(size=q.shape)
    eps = 1e-6
    fd = (residual(q + eps * Z) - residual(q - eps * Z)) / (2 * eps)
    np.testing.assert_allclose(op.J(Z[:, :, None])[:, 0], fd, rtol=1e-6, atol=1e-8)
    Y = rng.normal(size=(op.K, 1))
    assert float(np.sum(op.JT(Y)[:, :, 0] * Z)) == pytest.approx(
        float(Y[:, 0] @ op.J(Z[:, :, None])[:, 0]), rel=1e-12)


@pytest.mark.parametrize("seconds", [2.0, 20.0])
def test_c1_leaves_a_clip_that_already_loops_smoothly_as_it_is(seconds):
    """A smooth periodic motion sampled with its last sample equal to the first is closed and
    C1 already. Its first and last interval velocities are half an interval either side of
    the seam (they differ by h q'): the plain condition q_end = q_0 treated that as a jump and
    its fix, spread over 10 % of the clip, turned the joints by up to 41 degrees (20 s at
    120 Hz); the condition on the velocities extrapolated to the seam leaves them."""
    N = int(seconds * 120) + 1
    t = np.linspace(0.0, seconds, N)
    ph = 2 * np.pi * t                                   # one cycle per second
    W = np.stack([np.c_[0.6 * np.sin(ph + j), 0.3 * np.cos(2 * ph), 0.2 * np.sin(ph) * j]
                  for j in range(3)], axis=1)
    c = ProductCurve(so3.exp(W), np.c_[np.cos(ph), 0.5 * np.sin(ph)], t)
    assert seam_gap(c) < 1e-12
    r = close(c, c1=True)
    assert r.status == "converged"
    turn = so3.angle(np.swapaxes(c.R, -1, -2) @ r.curve.R)
    assert turn.max() < 1e-4                             # radians (was 0.08 - 0.7)
    assert np.abs(r.curve.X - c.X).max() < 1e-4
    from shellspline.curves.closing import seam_weights

    tn = np.linspace(0.0, 1.0, N)
    q = srv(c.with_times(tn))
    extrapolated = np.linalg.norm(seam_weights(np.diff(tn)) @ q)
    assert extrapolated < 0.05 * np.linalg.norm(q[-1] - q[0])

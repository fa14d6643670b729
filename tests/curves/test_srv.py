"""SRVT of curves in SO(3)^d x R^m (shellspline.curves.srv): round trip, closed forms, the
invariances of seed 000 Lemma 3.6, distances and blends."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp

from shellspline.curves.srv import (ProductCurve, blend, cumulative_product, reparametrize,
                                    srv, srv_distance, srv_inverse, warp_grid)
from shellspline.errors import ShellsplineError
from shellspline.groups import so3


def random_curve(N=60, d=3, m=2, seed=0, uniform=False, scale=0.15):
    rng = np.random.default_rng(seed)
    W = np.cumsum(rng.normal(size=(N, d, 3)) * scale, axis=0)
    R = so3.exp(W)
    X = np.cumsum(rng.normal(size=(N, m)) * 0.1, axis=0)
    t = np.linspace(0, 2, N) if uniform else np.cumsum(rng.uniform(0.5, 1.5, N))
    return ProductCurve(R, X, t)


def smooth_curve(u, d=2):
    """c(u) = exp(a(u)) exp(b(u)) per joint, X = (cos 2u, u^2): analytic, never at rest."""
    u = np.asarray(u)[:, None]
    R = np.stack([so3.exp(np.c_[np.sin(2 * u + j), u + 0.3 * j, 0.5 * np.cos(u)])
                  @ so3.exp(np.c_[0.2 * u, 0.1 + 0 * u, np.sin(3 * u)]) for j in range(d)], 1)
    X = np.c_[np.cos(2 * u), u ** 2]
    return R, X


def test_round_trip_nonuniform_times():
    c = random_curve()
    Q = srv(c)
    assert Q.shape == (c.n_frames - 1, 3 * c.d + c.m)
    c2 = srv_inverse(Q, c.t, R0=c.R[0], X0=c.X[0])
    np.testing.assert_allclose(c2.R, c.R, atol=1e-12)
    np.testing.assert_allclose(c2.X, c.X, atol=1e-12)


def test_round_trip_needs_the_dt_factor():
    # the inverse printed in seed 000 (without dt) would miss the samples unless dt == 1
    c = random_curve(uniform=True)
    Q = srv(c)
    n = np.linalg.norm(Q, axis=1)
    R_wrong = cumulative_product(so3.exp((Q * n[:, None])[:, :3 * c.d].reshape(-1, c.d, 3)),
                                 c.R[0])
    assert np.abs(R_wrong - c.R).max() > 0.1
    assert np.abs(srv_inverse(Q, c.t, R0=c.R[0], X0=c.X[0]).R - c.R).max() < 1e-12


def test_one_parameter_subgroup_has_constant_srv():
    # c(t) = exp(t xi) c0, X = X0 + t v: eta = (xi, v) on every interval, q = eta / sqrt|eta|
    xi = np.array([[0.3, -1.2, 0.5], [2.0, 0.1, -0.4]])
    v = np.array([0.7, -0.2, 0.1])
    t = np.sort(np.random.default_rng(1).uniform(0, 1.3, 25))
    R0 = so3.exp(np.array([[0.1, 0.2, 0.3], [-1, 0.5, 2.0]]))
    c = ProductCurve(so3.exp(t[:, None, None] * xi) @ R0, t[:, None] * v + 1.0, t)
    eta = np.concatenate([xi.ravel(), v])
    np.testing.assert_allclose(srv(c), np.broadcast_to(eta / np.sqrt(np.linalg.norm(eta)),
                                                       (24, 9)), atol=1e-12)


def test_large_rotations_beyond_90_degrees_per_step():
    # 2.5 rad per interval: an arcsin logarithm (seed 000 sect. 5.1) would fold this back
    t = np.linspace(0, 1, 5)
    xi = np.array([[0.0, 0.0, 10.0]])                     # 2.5 rad per step of 0.25
    c = ProductCurve(so3.exp(t[:, None, None] * xi), None, t)
    np.testing.assert_allclose(srv(c), np.tile([[0, 0, np.sqrt(10.0)]], (4, 1)), atol=1e-9)


def test_right_translation_invariance_and_left_is_not():
    c = random_curve()
    rng = np.random.default_rng(5)
    G = so3.exp(rng.normal(size=(c.d, 3)))
    x = rng.normal(size=c.m)
    np.testing.assert_allclose(srv(c.right_translated(G, x)), srv(c), atol=1e-12)
    left = ProductCurve(G[None] @ c.R, c.X, c.t)
    assert np.abs(srv(left) - srv(c)).max() > 1e-2        # the test can fail


def test_reparametrization_equivariance_exact_on_samples():
    # samples kept, times changed: u_i -> t_i; q~_i = q_i sqrt(du_i / dt_i) (Lemma 3.6.1)
    c = random_curve()
    t_new = np.cumsum(np.random.default_rng(9).uniform(0.1, 3.0, c.n_frames))
    q_new = srv(c.with_times(t_new))
    np.testing.assert_allclose(q_new, srv(c) * np.sqrt(np.diff(c.t) / np.diff(t_new))[:, None],
                               atol=1e-12)


@pytest.mark.parametrize("N", [500, 2000])
def test_reparametrization_equivariance_smooth(N):
    # R(c o g) = sqrt(g') R(c) o g for a smooth warp g, up to the O(h) sampling error
    g = lambda s: s + 0.3 * np.sin(np.pi * s) / np.pi       # noqa: E731, increasing on [0, 1]
    dg = lambda s: 1 + 0.3 * np.cos(np.pi * s)              # noqa: E731
    t = np.linspace(0, 1, N)
    tm = 0.5 * (t[1:] + t[:-1])
    q_warped = srv(ProductCurve(*smooth_curve(g(t)), t))
    fine = np.linspace(0, 1, 40 * N)
    qf = srv(ProductCurve(*smooth_curve(fine), fine))
    k = np.minimum((g(tm) * (40 * N - 1)).astype(int), 40 * N - 2)
    expected = qf[k] * np.sqrt(dg(tm))[:, None]
    err = np.abs(q_warped - expected).max()
    assert err < 0.5 / N          # measured 0.08 / N; without sqrt(g') it is ~300 / N


def test_distance_zero_symmetric_closed_form_and_unit_free():
    c0, c1 = random_curve(seed=1, uniform=True), random_curve(seed=2, uniform=True)
    assert srv_distance(c0, c0) == 0.0
    d01 = srv_distance(c0, c1)
    assert d01 == pytest.approx(srv_distance(c1, c0), rel=1e-14)
    assert d01 > 0.1
    # time unit does not matter
    assert srv_distance(c0.with_times(7 * c0.t), c1.with_times(7 * c1.t)) == pytest.approx(d01)
    # straight lines: constant q, d = |v0/sqrt|v0| - v1/sqrt|v1||
    t = np.linspace(0, 1, 11)
    v0, v1 = np.array([3.0, 0, 1]), np.array([-1.0, 2, 0.5])
    l0, l1 = ProductCurve(X=t[:, None] * v0), ProductCurve(X=t[:, None] * v1)
    expect = np.linalg.norm(v0 / np.sqrt(np.linalg.norm(v0)) - v1 / np.sqrt(np.linalg.norm(v1)))
    assert srv_distance(l0, l1) == pytest.approx(expect, rel=1e-13)


def test_blend_endpoints_self_and_geodesic():
    c0, c1 = random_curve(seed=3, uniform=True), random_curve(seed=4, uniform=True)
    for s in (0.3, 0.8):
        b = blend(c0, c0, s)
        np.testing.assert_allclose(b.R, c0.R, atol=1e-12)
        np.testing.assert_allclose(b.X, c0.X, atol=1e-12)
    b0, b1 = blend(c0, c1, 0.0), blend(c0, c1, 1.0)
    np.testing.assert_allclose(b0.R, c0.R, atol=1e-12)
    np.testing.assert_allclose(b1.R, c1.R, atol=1e-11)
    np.testing.assert_allclose(b1.X, c1.X, atol=1e-11)
    # along the geodesic the distance grows linearly (the SRV of the blend is (1-s)q0 + s q1)
    d = srv_distance(c0, c1)
    for s in (0.25, 0.6):
        assert srv_distance(c0, blend(c0, c1, s)) == pytest.approx(s * d, rel=1e-10)
    # the start point is the geodesic midpoint of the start points
    b = blend(c0, c1, 0.5)
    mid = c0.R[0] @ so3.exp(0.5 * so3.log(np.swapaxes(c0.R[0], -1, -2) @ c1.R[0]))
    np.testing.assert_allclose(b.R[0], mid, atol=1e-12)


def test_blend_with_warp_uses_curve1_o_phi():
    c0, c1 = random_curve(seed=3, uniform=True), random_curve(N=40, seed=4, uniform=True)
    phi = c1.t[0] + (c1.t[-1] - c1.t[0]) * ((c0.t - c0.t[0]) / (c0.t[-1] - c0.t[0])) ** 1.3
    b = blend(c0, c1, 1.0, warp=phi)
    r = reparametrize(c1, phi, c0.t)
    np.testing.assert_allclose(b.R, r.R, atol=1e-11)


def test_warp_grid_blends_the_curves_not_their_samples():
    """On warp_grid (curve0's times, the warp's breakpoints, the times where the warp meets a
    sample of curve1) both curves are single geodesics between samples, so the blend is the
    SRV geodesic of the piecewise-geodesic curves: s = 0 is curve0 at its samples, s = 1 is
    curve1 at all of its samples, and any s gives the same curve on any finer grid (oracle:
    the blend on the grid plus 200 random times). On curve0's grid alone the steep end of
    the warp skips samples of curve1 (control)."""
    c0, c1 = random_curve(N=30, seed=3), random_curve(N=47, seed=4)
    tw = np.linspace(c0.t[0], c0.t[-1], 9)        # breakpoints that are not curve0's times
    pw = c1.t[0] + (c1.t[-1] - c1.t[0]) * ((tw - tw[0]) / (tw[-1] - tw[0])) ** 2.5
    t, phi = warp_grid(c0.t, tw, pw, c1.t)
    assert np.isin(c0.t, t).all() and np.isin(tw, t).all()
    span = c1.t[-1] - c1.t[0]
    hit = np.abs(phi[:, None] - c1.t[None, :]).argmin(axis=0)   # where the warp meets c1
    assert np.abs(phi[hit] - c1.t).max() <= 1e-12 * span
    extra = np.random.default_rng(5).uniform(c0.t[0], c0.t[-1], 200)
    fine = np.union1d(t, extra)
    on_t = np.searchsorted(fine, t)
    assert np.array_equal(fine[on_t], t)

    def on(grid, s):
        return blend(reparametrize(c0, grid, grid), c1, s, warp=np.interp(grid, tw, pw))
    for s in (0.0, 0.3, 0.7, 1.0):
        b, bf = on(t, s), on(fine, s)
        np.testing.assert_allclose(bf.R[on_t], b.R, atol=1e-11)
        np.testing.assert_allclose(bf.X[on_t], b.X, atol=1e-11)
    b0, b1 = on(t, 0.0), on(t, 1.0)
    at0 = np.searchsorted(t, c0.t)
    np.testing.assert_allclose(b0.R[at0], c0.R, atol=1e-12)
    np.testing.assert_allclose(b0.X[at0], c0.X, atol=1e-12)
    np.testing.assert_allclose(b1.R[hit], c1.R, atol=1e-11)
    np.testing.assert_allclose(b1.X[hit], c1.X, atol=1e-11)
    # control: sampled on curve0's times only, b o phi cuts the corners of curve1
    coarse = blend(c0, c1, 1.0, warp=np.interp(c0.t, tw, pw))
    assert np.abs(reparametrize(coarse, t, t).X - b1.X).max() > 1e-3
    # the warp met more than once when it turns back; a bad warp is refused
    t2, phi2 = warp_grid([0.0, 1.0], [0.0, 0.5, 1.0], [0.0, 1.0, 0.5], [0.0, 0.25, 0.75, 1.0])
    assert t2.tolist() == [0.0, 0.125, 0.375, 0.5, 0.75, 1.0]
    assert phi2.tolist() == [0.0, 0.25, 0.75, 1.0, 0.75, 0.5]
    with pytest.raises(ShellsplineError, match="warp_t"):
        warp_grid(c0.t, [0.0, 0.0], [0.0, 1.0], c1.t)


def test_reparametrize_matches_slerp_and_identity():
    c = random_curve(d=1, m=1, seed=6)
    same = reparametrize(c, c.t)
    np.testing.assert_allclose(same.R, c.R, atol=1e-12)
    u = np.sort(np.random.default_rng(7).uniform(c.t[0], c.t[-1], 50))
    r = reparametrize(c, u, np.linspace(0, 1, 50))
    sl = Slerp(c.t, Rotation.from_matrix(c.R[:, 0]))(u).as_matrix()
    np.testing.assert_allclose(r.R[:, 0], sl, atol=1e-10)
    np.testing.assert_allclose(r.X[:, 0], np.interp(u, c.t, c.X[:, 0]), atol=1e-12)


def test_reparametrize_periodic_wraps():
    t = np.linspace(0, 1, 21)
    c = ProductCurve(X=np.c_[np.cos(2 * np.pi * t), np.sin(2 * np.pi * t)], t=t)
    a = reparametrize(c, t + 0.25, periodic=True)
    b = reparametrize(c, np.mod(t + 0.25, 1.0))
    np.testing.assert_allclose(a.X, b.X, atol=1e-12)
    with pytest.raises(ShellsplineError, match="phi must lie"):
        reparametrize(c, t + 0.25)


def test_cumulative_product_matches_loop():
    rng = np.random.default_rng(8)
    E = so3.exp(rng.normal(size=(37, 4, 3)))
    R0 = so3.exp(rng.normal(size=(4, 3)))
    R = cumulative_product(E, R0)
    ref = [R0]
    for e in E:
        ref.append(e @ ref[-1])
    np.testing.assert_allclose(R, np.array(ref), atol=1e-12)


def test_invalid_inputs_raise():
    I = np.broadcast_to(np.eye(3), (4, 2, 3, 3))
    with pytest.raises(ShellsplineError, match="strictly increasing"):
        ProductCurve(I, None, [0, 1, 1, 2])
    with pytest.raises(ShellsplineError, match="not a rotation"):
        ProductCurve(I * 2, None)
    with pytest.raises(ShellsplineError, match="less than pi"):
        ProductCurve(so3.exp(np.array([[[0, 0, 0.0]], [[0, 0, np.pi]]])), None)
    with pytest.raises(ShellsplineError, match="and/or"):
        ProductCurve()
    with pytest.raises(ShellsplineError, match="samples"):
        ProductCurve(I, np.zeros((3, 1)))
    with pytest.raises(ShellsplineError, match="same samples"):
        srv_distance(ProductCurve(X=np.zeros((4, 2))), ProductCurve(X=np.zeros((5, 2))))
    with pytest.raises(ShellsplineError, match="same components"):
        blend(ProductCurve(X=np.zeros((4, 2))), ProductCurve(X=np.zeros((4, 3))), 0.5)
    with pytest.raises(ShellsplineError, match="columns"):
        srv_inverse(np.zeros((3, 4)), np.arange(4.0), d=2)


def test_blend_takes_the_warp_of_a_closed_alignment():
    from shellspline.curves.align import align

    u = np.linspace(0, 1, 121)
    loop = lambda x: np.c_[np.cos(2 * np.pi * x) * (1 + 0.3 * np.cos(6 * np.pi * x)),  # noqa
                           np.sin(2 * np.pi * x), 0.2 * np.sin(4 * np.pi * x)]
    c0, c1 = ProductCurve(X=loop(u + 0.25), t=u), ProductCurve(X=loop(u), t=u)
    r = align(c0, c1, closed=True)
    assert r.phi.max() > 1.0                      # runs from the shift over one period
    with pytest.raises(ShellsplineError, match="phi must lie in"):
        blend(c0, c1, 0.5, warp=r.phi)
    b1 = blend(c0, c1, 1.0, warp=r.phi, periodic=True)
    np.testing.assert_allclose(b1.X, c0.X, atol=1e-12)  # c1 o phi is c0 again (a shift)
    b0 = blend(c0, c1, 0.0, warp=r.phi, periodic=True)
    np.testing.assert_allclose(b0.X, c0.X, atol=1e-12)


def _spin(t, rate):
    """(N,1,3,3): one joint turning about z at ``rate`` rad per unit time (scipy's rotations)."""
    return Rotation.from_rotvec(np.outer(rate * np.asarray(t), [0.0, 0.0, 1.0])).as_matrix()[:, None]


def test_blend_keeps_a_fast_joint_turning_the_right_way():
    """A joint spinning 0.3 pi per sample of curve1 turns 1.2 pi per sample of the coarser
    curve0: on curve0's grid its increments must not wrap onto the principal branch (-0.8 pi,
    turning backwards). Oracle: the same blend on a fine resampling of curve0 (scipy Slerp),
    read at curve0's times, and the closed form (q = s q1: the joint turns at s^2 omega)."""
    omega = 4.8 * np.pi
    t0, t1, tf = np.linspace(0, 1, 5), np.linspace(0, 1, 17), np.linspace(0, 1, 65)
    c1 = ProductCurve(_spin(t1, omega), None, t1)
    c0 = ProductCurve(np.broadcast_to(np.eye(3), (5, 1, 3, 3)), None, t0)  # at rest
    c0f = ProductCurve(Slerp(t0, Rotation.from_matrix(c0.R[:, 0]))(tf).as_matrix()[:, None],
                       None, tf)
    for s in (0.25, 0.5, 0.75):
        coarse, fine = blend(c0, c1, s), blend(c0f, c1, s)
        np.testing.assert_allclose(coarse.R, fine.R[::16], atol=1e-10)
        np.testing.assert_allclose(coarse.R, _spin(t0, s ** 2 * omega), atol=1e-10)
    # at s = 1 the blend would turn 1.2 pi between curve0's samples: no piecewise geodesic on
    # that grid does, so it is refused rather than wrapped; the fine grid carries it
    with pytest.raises(ShellsplineError, match=r"joint 0 .* between samples 0 and 1"):
        blend(c0, c1, 1.0)
    np.testing.assert_allclose(blend(c0f, c1, 1.0).R, _spin(tf, omega), atol=1e-10)


def test_blend_unwraps_a_closed_warp_across_the_period():
    """A closed spin (four full turns over the period, 0.1 pi per sample) read through a
    periodic warp that crosses the period's end, on a grid where it turns 4/3 pi per step:
    the increments follow the path across the seam (closed form: the joint turns at
    s^2 omega from the geodesic midpoint of the start points)."""
    omega = 8 * np.pi
    t1, t0 = np.linspace(0, 1, 81), np.linspace(0, 1, 7)
    c1 = ProductCurve(_spin(t1, omega), None, t1)
    c0 = ProductCurve(np.broadcast_to(np.eye(3), (7, 1, 3, 3)), None, t0)
    b = blend(c0, c1, 0.5, warp=0.35 + t0, periodic=True)
    w0 = Rotation.from_matrix(_spin([0.35], omega)[0, 0]).as_rotvec()  # principal, as blend
    expect = _spin(t0, 0.25 * omega)[:, 0] @ Rotation.from_rotvec(0.5 * w0).as_matrix()
    np.testing.assert_allclose(b.R[:, 0], expect, atol=1e-10)


def test_srv_inverse_refuses_a_step_it_cannot_represent():
    """dt |q|^2 >= pi for a joint: the samples exp(...) would be right, but the piecewise
    geodesic between them would turn the other way (-(2 pi - angle)): refused in one line."""
    t = np.linspace(0, 1, 5)
    for turn, ok in ((0.9 * np.pi, True), (1.2 * np.pi, False)):
        eta = np.array([0.0, 0.0, turn / 0.25])            # rad per unit time
        Q = np.tile(eta / np.sqrt(np.linalg.norm(eta)), (4, 1))
        if ok:
            c = srv_inverse(Q, t, d=1)
            np.testing.assert_allclose(c.R, _spin(t, turn / 0.25), atol=1e-10)
            np.testing.assert_allclose(srv(c), Q, atol=1e-10)  # its own geodesics agree
        else:
            with pytest.raises(ShellsplineError, match=r"joint 0 would turn by 3\.7699 rad "
                                                       r"between samples 0 and 1") as info:
                srv_inverse(Q, t, d=1)
            assert "\n" not in str(info.value)

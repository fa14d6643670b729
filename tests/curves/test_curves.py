"""Curves on Lie groups: de Casteljau against the Crouch–Kun–Leite form, the seed's
propositions, scipy oracles (Slerp, RotationSpline, CubicSpline, BSpline), C² continuity,
boundary conditions, the marching constructions and their blow-up, knot insertion."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.interpolate import BSpline as ScipyBSpline
from scipy.interpolate import CubicSpline
from scipy.spatial.transform import Rotation, RotationSpline, Slerp

from shellspline.errors import ShellsplineError
from shellspline.curves import (BSpline, PiecewiseBezier, bezier, bezier_ckl, bezier_velocity,
                                clamped_knots, cubic_spline, geodesic, geodesic_interpolant,
                                hermite_spline, quadratic_spline)
from shellspline.groups import SE3, SO3, SO3dR3, SO3xR3, se3, so3

GROUPS = [SO3, SE3, SO3xR3, SO3dR3(2)]


def _random_walk(G, rng, n, step=0.4, lead=()):
    return G.exp(np.cumsum(rng.normal(size=lead + (n, G.dim)) * step, axis=-2))


def _times(rng, n):
    return np.cumsum(rng.uniform(0.4, 1.6, n))


def _translations(P):
    """Poses with identity rotation: the flat group R^3 inside SO3xR3 / SE3."""
    return se3.from_rt(np.eye(3), P)


def _fd_body_velocity(G, f, t, h=1e-6):
    return G.between(f(t - h), f(t + h)) / (2 * h)


# --- Bézier curves ------------------------------------------------------------------------

@pytest.mark.parametrize("G", GROUPS, ids=str)
@pytest.mark.parametrize("n", [1, 2, 3, 5])
def test_de_casteljau_equals_crouch_kun_leite(G, n):
    rng = np.random.default_rng(n)
    P = _random_walk(G, rng, n + 1, 0.6, lead=(3,))
    s = np.linspace(0, 1, 11)
    np.testing.assert_allclose(bezier(G, P, s), bezier_ckl(G, P, s), atol=1e-12)


@pytest.mark.parametrize("G", GROUPS, ids=str)
def test_bezier_endpoints_and_end_velocities(G):
    # seed proposition 4.2.8: velocity n g0 V_0^1 at s = 0 and n g_n V_{n-1}^1 at s = 1
    rng = np.random.default_rng(11)
    n = 4
    P = _random_walk(G, rng, n + 1, 0.5)
    g, xi = bezier_velocity(G, P, np.array([0.0, 1.0]))
    np.testing.assert_allclose(g, P[[0, n]], atol=1e-13)
    np.testing.assert_allclose(xi[0], n * G.between(P[0], P[1]), atol=1e-12)
    np.testing.assert_allclose(xi[1], n * G.between(P[n - 1], P[n]), atol=1e-12)


@pytest.mark.parametrize("G", [SO3, SE3], ids=str)
@pytest.mark.parametrize("n", [2, 3, 5])
def test_bezier_end_accelerations(G, n):
    # seed proposition 4.2.9 in the body frame: d xi/ds(0) = n(n-1) J_r(V0)^{-1} (V1 - V0) and
    # d xi/ds(1) = n(n-1) J_r(-V_{n-1})^{-1} (V_{n-1} - V_{n-2}), J_r(V) = int_0^1 exp(-u ad V)
    # (the printed "inverse of int exp(u ad V0)" is this with the opposite sign of ad)
    rng = np.random.default_rng(n)
    P = _random_walk(G, rng, n + 1, 0.6)
    C = PiecewiseBezier(G, [0.0, 1.0], P[None])
    V = G.between(P[:-1], P[1:])
    a0 = n * (n - 1) * G.jac_right_inv(V[0], V[1] - V[0])
    a1 = n * (n - 1) * G.jac_right_inv(-V[-1], V[-1] - V[-2])
    np.testing.assert_allclose(C.acceleration(0.0), a0, atol=1e-6 * np.abs(a0).max())
    np.testing.assert_allclose(C.acceleration(1.0 - 1e-13), a1, atol=1e-6 * np.abs(a1).max())
    assert np.abs(n * (n - 1) * G.jac_right_inv(-V[0], V[1] - V[0]) - a0).max() > 1e-2


@pytest.mark.parametrize("G", GROUPS, ids=str)
def test_bezier_velocity_is_the_derivative(G):
    rng = np.random.default_rng(12)
    P = _random_walk(G, rng, 4, 0.7)
    s = np.linspace(0.05, 0.95, 9)
    g, xi = bezier_velocity(G, P, s)
    np.testing.assert_allclose(g, bezier(G, P, s), atol=1e-14)
    np.testing.assert_allclose(xi, _fd_body_velocity(G, lambda u: bezier(G, P, u), s),
                               atol=1e-8)


@pytest.mark.parametrize("G", [SO3, SE3, SO3xR3], ids=str)
def test_left_invariance(G):
    # proposition 4.2.1; for the pose groups the world-frame change is SE(3) multiplication
    rng = np.random.default_rng(13)
    P = _random_walk(G, rng, 4, 0.6)
    h = SE3.exp(rng.normal(size=6)) if G is not SO3 else SO3.exp(rng.normal(size=3))
    act = SE3.compose if G is not SO3 else SO3.compose
    s = np.linspace(0, 1, 7)
    np.testing.assert_allclose(bezier(G, act(h, P), s), act(h, bezier(G, P, s)), atol=1e-12)


def test_right_invariance_holds_for_the_screw_metric_and_fails_for_the_product_metric():
    # corollary 4.2.7 (Ad-invariant metric) and its failure for the "double geodesic"
    rng = np.random.default_rng(14)
    P = _random_walk(SE3, rng, 4, 0.6)
    h = SE3.exp([0.4, -0.7, 0.2, 1.0, 2.0, -0.5])
    s = np.linspace(0, 1, 7)
    moved = bezier(SE3, SE3.compose(P, h), s)
    np.testing.assert_allclose(moved, SE3.compose(bezier(SE3, P, s), h), atol=1e-12)
    moved = bezier(SO3xR3, SE3.compose(P, h), s)
    err = np.abs(moved - SE3.compose(bezier(SO3xR3, P, s), h)).max()
    assert err > 1e-2  # the body-frame offset changes the product-metric curve
    # ...its rotations alone are still right-invariant (SO(3) is bi-invariant)
    np.testing.assert_allclose(moved[..., :3, :3],
                               SE3.compose(bezier(SO3xR3, P, s), h)[..., :3, :3], atol=1e-12)


@pytest.mark.parametrize("G", GROUPS, ids=str)
def test_reversal_symmetry(G):
    # proposition 4.2.3
    rng = np.random.default_rng(15)
    P = _random_walk(G, rng, 5, 0.5)
    s = np.linspace(0, 1, 9)
    np.testing.assert_allclose(bezier(G, P[::-1], s), bezier(G, P, 1 - s), atol=1e-12)


@pytest.mark.parametrize("G", [SO3, SE3, SO3xR3], ids=str)
def test_geodesic_precision(G):
    # proposition 4.2.4: control points along one geodesic give a curve on it
    rng = np.random.default_rng(16)
    g0, V = G.exp(rng.normal(size=G.dim)), rng.normal(size=G.dim)
    V *= 0.8 / np.linalg.norm(V[:3])
    u = np.array([0.0, 0.1, 0.45, 0.6, 1.0])
    P = G.compose(g0, G.exp(u[:, None] * V))
    c = bezier(G, P, np.linspace(0, 1, 13))
    W = G.between(g0, c)
    para = W - (W @ V)[:, None] * V / (V @ V)
    np.testing.assert_allclose(para, 0, atol=1e-13)


def test_geodesic_matches_scipy_slerp():
    rng = np.random.default_rng(17)
    R = so3.exp(rng.normal(size=(2, 3)))
    s = np.linspace(0, 1, 21)
    ref = Slerp([0, 1], Rotation.from_matrix(R))(s).as_matrix()
    np.testing.assert_allclose(geodesic(SO3, R[0], R[1], s), ref, atol=1e-14)


# --- piecewise curves and interpolating splines -------------------------------------------

def test_geodesic_interpolant_matches_slerp_at_nonuniform_times():
    rng = np.random.default_rng(18)
    t = _times(rng, 9)
    R = _random_walk(SO3, rng, 9, 0.6)
    tq = np.linspace(t[0], t[-1], 200)
    ref = Slerp(t, Rotation.from_matrix(R))(tq).as_matrix()
    np.testing.assert_allclose(geodesic_interpolant(SO3, t, R)(tq), ref, atol=1e-13)


@pytest.mark.parametrize("bc", ["natural", "clamped", "periodic", "mixed"])
def test_cubic_spline_in_a_flat_group_is_scipy_cubic_spline(bc):
    rng = np.random.default_rng(19)
    t = _times(rng, 9)
    P = rng.normal(size=(9, 3))
    if bc == "periodic":
        P[-1] = P[0]
    v = np.array([0.5, -1.0, 0.2])
    ours = {"mixed": ("natural", np.r_[0, 0, 0, v])}.get(bc, bc)
    ref = {"mixed": ((2, [0, 0, 0]), (1, v)), "clamped": "clamped"}.get(bc, bc)
    S = cubic_spline(SO3xR3, t, _translations(P), ours)
    tq = np.linspace(t[0], t[-1], 301)
    cs = CubicSpline(t, P, bc_type=ref)
    np.testing.assert_allclose(S(tq)[:, :3, 3], cs(tq), atol=1e-11)
    np.testing.assert_allclose(S.velocity(tq)[:, 3:], cs(tq, 1), atol=1e-9)
    np.testing.assert_allclose(S.acceleration(tq)[:, 3:], cs(tq, 2), atol=1e-6)
    assert S.solve.status == "converged"


def test_cubic_spline_about_one_axis_equals_scipy_rotation_spline():
    # RotationSpline fixes its end rates to the first/last chord rates; about one axis the two
    # constructions are the same cubic in the angle
    rng = np.random.default_rng(20)
    t = _times(rng, 10)
    ang = np.cumsum(rng.normal(size=10) * 0.7)
    axis = np.array([1.0, 2.0, -2.0]) / 3
    R = so3.exp(ang[:, None] * axis)
    chord = np.diff(ang) / np.diff(t)
    S = cubic_spline(SO3, t, R, (chord[0] * axis, chord[-1] * axis))
    tq = np.linspace(t[0], t[-1], 400)
    rs = RotationSpline(t, Rotation.from_matrix(R))
    np.testing.assert_allclose(S(tq), rs(tq).as_matrix(), atol=1e-12)
    np.testing.assert_allclose(S.velocity(tq, "space"), rs(tq, 1), atol=1e-9)
    np.testing.assert_allclose(S.acceleration(tq, "space"), rs(tq, 2), atol=1e-5)


@pytest.mark.parametrize("G", GROUPS, ids=str)
@pytest.mark.parametrize("bc", ["natural", "clamped", "periodic"])
def test_cubic_spline_interpolates_is_c2_and_meets_its_ends(G, bc):
    rng = np.random.default_rng(21)
    n = 10
    t = _times(rng, n)
    X = _random_walk(G, rng, n, 0.35)
    if bc == "periodic":
        X[-1] = X[0]
    S = cubic_spline(G, t, X, bc)
    assert S.solve.status == "converged" and S.solve.success
    np.testing.assert_allclose(S(t), X, atol=1e-12)
    kn = t[1:-1]
    # angular (and linear) acceleration across each knot by one-sided finite differences of
    # the *points* (independent of the spline's own derivatives)
    h = 1e-3

    def acc_fd(tt, side):
        g0, g1, g2 = S(tt), S(tt + side * h), S(tt + 2 * side * h)
        a, b = G.between(g0, g1) / h, G.between(g1, g2) / h
        return (b - a) / h  # O(h) estimate of the body acceleration (either side)

    jump = np.abs(acc_fd(kn, 1) - acc_fd(kn, -1)).max()
    scale = np.abs(acc_fd(kn, 1)).max()
    assert jump < 2e-2 * scale  # O(h) of the one-sided estimates; a C¹ spline fails this
    # the spline's own acceleration (central difference of the exact velocity) jumps ~1e-8
    left, right = S.acceleration(kn - 1e-10), S.acceleration(kn)
    assert np.abs(left - right).max() < 1e-6 * max(1.0, np.abs(right).max())
    vl, vr = S.velocity(kn - 1e-12), S.velocity(kn)
    np.testing.assert_allclose(vl, vr, atol=1e-9)
    if bc == "natural":
        np.testing.assert_allclose(S.acceleration(t[[0, -1]]), 0, atol=1e-7)
    elif bc == "clamped":
        np.testing.assert_allclose(S.velocity(t[[0, -1]]), 0, atol=1e-12)
    else:
        np.testing.assert_allclose(S.velocity(t[0]), S.velocity(t[-1]), atol=1e-9)
        np.testing.assert_allclose(S.acceleration(t[0]), S.acceleration(t[-1]), atol=1e-6)


def test_hermite_catmull_rom_is_only_c1():
    # the check above must be able to fail: the local C¹ spline has acceleration jumps
    rng = np.random.default_rng(22)
    t = _times(rng, 8)
    X = _random_walk(SE3, rng, 8, 0.4)
    S = hermite_spline(SE3, t, X)
    np.testing.assert_allclose(S(t), X, atol=1e-12)
    kn = t[1:-1]
    np.testing.assert_allclose(S.velocity(kn - 1e-12), S.velocity(kn), atol=1e-9)
    assert np.abs(S.acceleration(kn - 1e-10) - S.acceleration(kn)).max() > 1e-2
    # local: moving pose 4 changes the curve on [t_2, t_6] only
    X2 = X.copy()
    X2[4] = SE3.compose(X[4], SE3.exp([0.1, 0, 0, 0, 0.2, 0]))
    S2 = hermite_spline(SE3, t, X2)
    out = np.r_[np.linspace(t[0], t[2], 9), np.linspace(t[6], t[-1], 9)]
    inside = np.linspace(t[2], t[6], 9)[1:-1]
    np.testing.assert_allclose(S2(out), S(out), atol=1e-14)
    assert SE3.distance(S2(inside), S(inside)).min() > 1e-6


@pytest.mark.parametrize("G", [SO3, SE3, SO3xR3], ids=str)
def test_spline_velocities_are_derivatives_in_body_and_space_frames(G):
    rng = np.random.default_rng(23)
    t = _times(rng, 6)
    S = cubic_spline(G, t, _random_walk(G, rng, 6, 0.5))
    tq = np.linspace(t[0] + 0.01, t[-1] - 0.01, 17)
    np.testing.assert_allclose(S.velocity(tq), _fd_body_velocity(G, S, tq), atol=1e-7)
    h = 1e-6
    sp = G.between(S(tq - h), S(tq + h)) / (2 * h)
    np.testing.assert_allclose(S.velocity(tq, "space"), G.adjoint(S(tq), sp), atol=1e-7)
    acc = (S.velocity(tq + 1e-5) - S.velocity(tq - 1e-5)) / 2e-5
    np.testing.assert_allclose(S.acceleration(tq), acc, atol=1e-5)
    acc = (S.velocity(tq + 1e-5, "space") - S.velocity(tq - 1e-5, "space")) / 2e-5
    np.testing.assert_allclose(S.acceleration(tq, "space"), acc, atol=1e-5)


@pytest.mark.parametrize("G", [SO3, SE3, SO3xR3], ids=str)
def test_spline_invariances(G):
    rng = np.random.default_rng(24)
    t = _times(rng, 7)
    X = _random_walk(G, rng, 7, 0.4)
    tq = np.linspace(t[0], t[-1], 41)
    S = cubic_spline(G, t, X)
    # affine reparametrisation (proposition 4.2.2 for the whole spline)
    S2 = cubic_spline(G, 3.0 * t - 5.0, X)
    np.testing.assert_allclose(S2(3.0 * tq - 5.0), S(tq), atol=1e-10)
    # reversal (natural ends are symmetric)
    Sr = cubic_spline(G, -t[::-1], X[::-1])
    np.testing.assert_allclose(Sr(-tq), S(tq), atol=1e-10)
    # left invariance (world-frame change)
    act = SO3.compose if G is SO3 else SE3.compose
    h = G.exp(rng.normal(size=G.dim)) if G is SO3 else SE3.exp(rng.normal(size=6))
    np.testing.assert_allclose(cubic_spline(G, t, act(h, X))(tq), act(h, S(tq)), atol=1e-10)


def test_many_curves_at_once_equal_one_at_a_time():
    rng = np.random.default_rng(25)
    t = _times(rng, 8)
    X = _random_walk(SE3, rng, 8, 0.4, lead=(2, 3))
    tq = np.linspace(t[0], t[-1], 33)
    S = cubic_spline(SE3, t, X, "clamped")
    out = S(tq)
    assert out.shape == (2, 3, 33, 4, 4)
    for i in range(2):
        for j in range(3):
            np.testing.assert_allclose(out[i, j], cubic_spline(SE3, t, X[i, j], "clamped")(tq),
                                       atol=1e-11)
    assert S.velocity(tq).shape == (2, 3, 33, 6)


def test_newton_takes_over_from_a_slow_chord_iteration_and_converges_quadratically():
    rng = np.random.default_rng(0)
    X = SO3.exp(np.cumsum(rng.normal(size=(8, 3)) * 1.2, axis=0))  # ~2 rad per interval
    X[-1] = X[0]
    S = cubic_spline(SO3, np.arange(8.0), X, "periodic")
    assert S.solve.status == "converged" and "then Newton" in S.solve.message
    r = S.solve.residuals
    assert r[-1] < 1e-12 and r[-2] < 1e-6 and r[-1] < 10 * r[-2] ** 1.5  # quadratic tail
    np.testing.assert_allclose(S.acceleration(0.0), S.acceleration(7.0), atol=1e-6)


def test_newton_fallback_and_iteration_limit_are_reported():
    rng = np.random.default_rng(26)
    t = _times(rng, 12)
    X = _random_walk(SO3, rng, 12, 1.0)  # big turns: the chord iteration is slow
    S = cubic_spline(SO3, t, X)
    assert S.solve.status == "converged" and S.solve.residuals[-1] < 1e-9 * max(
        1.0, S.solve.residuals[0])
    S1 = cubic_spline(SO3, t, X, max_iter=1)
    assert S1.solve.status == "limit" and not S1.solve.success
    np.testing.assert_allclose(S1(t), X, atol=1e-12)  # still interpolates (C¹)


def test_marching_cubic_reproduces_the_global_spline_then_blows_up():
    rng = np.random.default_rng(27)
    t = _times(rng, 5)
    X = _random_walk(SO3, rng, 5, 0.3)
    S = cubic_spline(SO3, t, X, "natural")
    v0 = S.velocity(t[0])
    M = cubic_spline(SO3, t, X, (v0, "natural"), method="march",
                     start_acceleration=S.acceleration(t[0]))
    tq = np.linspace(t[0], t[-1], 50)
    # the marching error grows by ~(2 + sqrt 3) per interval from ~1e-9 (FD start acceleration)
    np.testing.assert_allclose(M(tq), S(tq), atol=1e-5)
    np.testing.assert_allclose(M(t), X, atol=1e-12)
    # many intervals: the seed's construction diverges and says so
    t = _times(rng, 40)
    X = _random_walk(SO3, rng, 40, 0.3)
    with pytest.raises(ShellsplineError, match="marching cubic spline blew up on interval"):
        cubic_spline(SO3, t, X, (np.zeros(3), "natural"), method="march")
    with pytest.raises(ShellsplineError, match="needs a start velocity"):
        cubic_spline(SO3, t, X, "natural", method="march")


def test_quadratic_marching_spline_is_c1_and_detects_blow_up():
    rng = np.random.default_rng(28)
    t = _times(rng, 8)
    X = _random_walk(SE3, rng, 8, 0.25)
    S = quadratic_spline(SE3, t, X)
    assert S.degree == 2
    np.testing.assert_allclose(S(t), X, atol=1e-12)
    kn = t[1:-1]
    np.testing.assert_allclose(S.velocity(kn - 1e-12), S.velocity(kn), atol=1e-8)
    # very uneven steps: the oscillation grows until a control point is > 90 degrees away
    t = np.cumsum([1, 0.05, 1, 0.05, 1, 0.05, 1, 0.05, 1])
    X = _random_walk(SO3, rng, t.size, 0.6)
    with pytest.raises(ShellsplineError, match="marching quadratic spline blew up"):
        quadratic_spline(SO3, t, X)


# --- B-splines ----------------------------------------------------------------------------

@pytest.mark.parametrize("m", [1, 2, 3, 4])
def test_de_boor_in_a_flat_group_is_scipy_bspline(m):
    rng = np.random.default_rng(29)
    n = 9
    u = np.sort(rng.uniform(0, 5, n + m + 1))
    u[3:5] = u[3]  # a double knot
    u = np.sort(u)
    P = rng.normal(size=(n, 3))
    S = BSpline(SO3xR3, _translations(P), u, m)
    tq = np.linspace(*S.domain, 57)
    np.testing.assert_allclose(S(tq)[:, :3, 3], ScipyBSpline(u, P, m)(tq), atol=1e-12)


def test_de_boor_with_bezier_knots_is_de_casteljau():
    rng = np.random.default_rng(30)
    P = _random_walk(SE3, rng, 4, 0.6)
    S = BSpline(SE3, P, [2, 2, 2, 2, 5, 5, 5, 5], 3)
    s = np.linspace(0, 1, 11)
    np.testing.assert_allclose(S(2 + 3 * s), bezier(SE3, P, s), atol=1e-12)


def test_clamped_bspline_interpolates_its_ends():
    rng = np.random.default_rng(31)
    t = _times(rng, 7)
    d = _random_walk(SO3, rng, 7, 0.5)
    S = BSpline(SO3, d, clamped_knots(t, 3), 3)
    np.testing.assert_allclose(S(np.array([t[0], t[-1]])), d[[0, -1]], atol=1e-12)


def test_knot_insertion_flat_exact_curved_order_dependent():
    rng = np.random.default_rng(32)
    n, m = 8, 3
    u = np.r_[[0.0] * 3, np.linspace(0, 5, n - m + 1), [5.0] * 3]
    tq = np.linspace(0, 5, 41)
    # flat: the curve is unchanged and two insertions commute (Menelaus)
    F = BSpline(SO3xR3, _translations(rng.normal(size=(n, 3))), u, m)
    a, b = 1.3, 1.7
    Fab, Fba = F.insert_knot(a).insert_knot(b), F.insert_knot(b).insert_knot(a)
    np.testing.assert_allclose(Fab(tq), F(tq), atol=1e-12)
    np.testing.assert_allclose(Fab.control, Fba.control, atol=1e-12)
    # SO(3): neither holds exactly, and the order dependence shrinks fast with the spread
    errs = []
    for scale in (0.8, 0.4, 0.2):
        S = BSpline(SO3, _random_walk(SO3, np.random.default_rng(33), n, scale), u, m)
        ab, ba = S.insert_knot(a).insert_knot(b), S.insert_knot(b).insert_knot(a)
        errs.append(SO3.distance(ab.control, ba.control).max())
        assert SO3.distance(S.insert_knot(a)(tq), S(tq)).max() > 1e-9
    assert errs[0] > 1e-6
    assert errs[1] < errs[0] / 4 and errs[2] < errs[1] / 4


# --- validation ---------------------------------------------------------------------------

def test_invalid_inputs_raise():
    X = so3.exp(np.array([[0, 0, 0], [0, 0, 1.0], [0, 0, 2.0]]))
    with pytest.raises(ShellsplineError, match="strictly increasing"):
        cubic_spline(SO3, [0, 2, 1], X)
    with pytest.raises(ShellsplineError, match="to match t"):
        cubic_spline(SO3, [0, 1], X)
    with pytest.raises(ShellsplineError, match="180 degrees"):
        cubic_spline(SO3, [0, 1, 2], so3.exp(np.array([[0, 0, 0], [0, 0, np.pi], [0, 0, 0]])))
    with pytest.raises(ShellsplineError, match="periodic"):
        cubic_spline(SO3, [0, 1, 2], X, "periodic")
    with pytest.raises(ShellsplineError, match="bc ends"):
        cubic_spline(SO3, [0, 1, 2], X, ("natural", "free"))
    with pytest.raises(ShellsplineError, match="end velocity"):
        cubic_spline(SO3, [0, 1, 2], X, ("natural", [1.0, 2.0]))
    with pytest.raises(ShellsplineError, match="method"):
        cubic_spline(SO3, [0, 1, 2], X, method="secant")
    with pytest.raises(ShellsplineError, match="frame"):
        cubic_spline(SO3, [0, 1, 2], X).velocity(0.5, frame="world")
    with pytest.raises(ShellsplineError, match="knots"):
        BSpline(SO3, X, [0, 0, 1, 1], 1)
    with pytest.raises(ShellsplineError, match="outside the domain"):
        BSpline(SO3, X, [0, 0, 1, 2, 2], 1).insert_knot(3.0)
    with pytest.raises(ShellsplineError, match="not a rotation"):
        cubic_spline(SO3, [0, 1, 2], X * 1.1)
    with pytest.raises(ShellsplineError, match="control"):
        PiecewiseBezier(SO3, [0, 1, 2], X)


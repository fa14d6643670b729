"""Elastic alignment (shellspline.curves.align): DP recovers known warps in R^m and on
SO(3)^d x R^m, its energy is the exact energy of its warp, feature points pull the
alignment (seed 003 Fig. 3 analogue), gradients against finite differences, closed curves."""
from __future__ import annotations

import numpy as np
import pytest

from shellspline.curves.align import (align, align_srv, dtw, neighborhood, project_closed,
                                      shape_distance, warp_energy, warp_energy_grad)
from shellspline.curves.srv import ProductCurve, reparametrize, srv, srv_inverse
from shellspline.errors import ShellsplineError
from shellspline.groups import so3


def space_curve(u):
    u = np.asarray(u)
    return np.c_[np.cos(3 * u) + u, np.sin(5 * u), u ** 2]


def group_curve(N):
    """A curve in SO(3)^2 x R^1 on linspace(0, 1, N)."""
    u = np.linspace(0, 1, N)[:, None]
    R = np.stack([so3.exp(np.c_[np.sin(3 * u), 2 * u, np.cos(4 * u)]),
                  so3.exp(np.c_[u ** 2, np.sin(6 * u), 0.3 + 0 * u])], axis=1)
    return ProductCurve(R, np.sin(5 * u), u[:, 0])


def test_neighborhood_is_fdasrsf_set():
    S = neighborhood(6)
    assert len(S) == 23
    assert {(1, 1), (1, 6), (6, 5), (5, 6)} <= set(map(tuple, S))
    assert (2, 4) not in set(map(tuple, S))


@pytest.mark.parametrize("refine", [False, True])
def test_dp_recovers_known_warp_in_R3(refine):
    N = 400
    t = np.linspace(0, 1, N)
    r = align(space_curve(t ** 1.5), space_curve(t), refine=refine)
    assert np.abs(r.phi - t ** 1.5).max() <= 0.005
    assert r.phi[0] == 0 and r.phi[-1] == 1 and np.all(np.diff(r.phi) > 0)
    assert r.energy <= r.energy_dp + 1e-12 < 0.01 * r.energy_identity


def test_dp_recovers_known_warp_on_the_group():
    N = 300
    c1 = group_curve(N)
    t = c1.t
    c0 = reparametrize(c1, t ** 1.5)                 # c0 = c1 o t^1.5 (geodesic interpolation)
    r = align(c0, c1)
    assert np.abs(r.phi - t ** 1.5).max() <= 0.005
    assert r.distance < 0.05 * np.sqrt(r.energy_identity)


def test_different_lengths_and_time_units():
    # curve 0 has 250 samples over 10 s, curve 1 has 180 over [2, 5]: phi maps into [2, 5]
    t0 = np.linspace(0, 1, 250)
    t1 = np.linspace(0, 1, 180)
    c0 = ProductCurve(X=space_curve(t0 ** 1.5), t=10 * t0)
    c1 = ProductCurve(X=space_curve(t1), t=2 + 3 * t1)
    r = align(c0, c1)
    np.testing.assert_allclose(r.t, c0.t)
    assert r.phi[0] == pytest.approx(2) and r.phi[-1] == pytest.approx(5)
    assert np.abs((r.phi - 2) / 3 - t0 ** 1.5).max() < 0.006


def test_dp_energy_is_the_exact_energy_of_its_warp():
    N = 120
    t = np.linspace(0, 1, N)
    q0 = srv(ProductCurve(X=space_curve(t ** 2)))
    q1 = srv(ProductCurve(X=space_curve(np.sqrt(t))[::-1][::-1]))
    r = align_srv(q0, q1, refine=False)
    assert warp_energy(q0, q1, r.phi)[0] == pytest.approx(r.energy_dp, rel=1e-10)
    # (that it is the lattice optimum: test_dp_equals_a_brute_force_lattice_search)


def _segment_cost(q0, q1, i0, j0, i1, j1):
    """Exact int_{t_i0}^{t_i1} |q0 - sqrt(s) q1(phi)|^2 for the linear phi from (i0, j0) to
    (i1, j1): the integrand is constant between the merged breakpoints of both grids."""
    h0, h1 = 1.0 / q0.shape[0], 1.0 / q1.shape[0]
    s = (j1 - j0) * h1 / ((i1 - i0) * h0)
    ta, tb = i0 * h0, i1 * h0
    cuts = np.r_[np.arange(i0, i1 + 1) * h0, ta + (np.arange(j0, j1 + 1) * h1 - j0 * h1) / s]
    cuts = np.unique(np.clip(cuts, ta, tb))
    mid = 0.5 * (cuts[1:] + cuts[:-1])
    n = np.minimum((mid / h0).astype(int), q0.shape[0] - 1)
    p = np.minimum(((j0 * h1 + s * (mid - ta)) / h1).astype(int), q1.shape[0] - 1)
    r = q0[n] - np.sqrt(s) * q1[p]
    return float(np.sum(np.diff(cuts) * np.einsum("ij,ij->i", r, r)))


@pytest.mark.parametrize("symmetric", [False, True])
def test_dp_equals_a_brute_force_lattice_search(symmetric):
    """The vectorised DP against a plain dynamic programme over the same lattice and the same
    23 steps, with segment costs integrated exactly on merged breakpoints and the feature term
    evaluated on the segment that contains the feature time."""
    rng = np.random.default_rng(7)
    N0, N1 = 11, 14
    q0, q1 = rng.normal(size=(N0 - 1, 3)), rng.normal(size=(N1 - 1, 3))
    a, b, lam = 0.37, 0.61, 3.0                     # on neither grid: one segment holds each
    h0, h1 = 1.0 / (N0 - 1), 1.0 / (N1 - 1)
    steps = [(i, j) for i in range(1, 7) for j in range(1, 7) if np.gcd(i, j) == 1]
    H = np.full((N0, N1), np.inf)
    H[0, 0] = 0.0
    for i in range(1, N0):
        for j in range(1, N1):
            for di, dj in steps:
                i0, j0 = i - di, j - dj
                if i0 < 0 or j0 < 0 or not np.isfinite(H[i0, j0]):
                    continue
                c = _segment_cost(q0, q1, i0, j0, i, j)
                if i0 * h0 < a <= i * h0:           # phi(a) on this segment
                    c += lam * (j0 * h1 + (a - i0 * h0) * dj * h1 / (di * h0) - b) ** 2
                if symmetric and j0 * h1 < b <= j * h1:
                    c += lam * (i0 * h0 + (b - j0 * h1) * di * h0 / (dj * h1) - a) ** 2
                H[i, j] = min(H[i, j], H[i0, j0] + c)
    r = align_srv(q0, q1, features=([a], [b]), lam=lam, symmetric=symmetric, window=None,
                  refine=False)
    assert r.energy_dp == pytest.approx(H[-1, -1], rel=1e-12)
    # and the energy of the warp it returns is that optimum (exact energy of a lattice warp)
    total = warp_energy(q0, q1, r.phi, features=([a], [b]), lam=lam, symmetric=symmetric)[0]
    assert total == pytest.approx(H[-1, -1], rel=1e-10)
    # the optimum is not a trivial one: the identity warp is worse
    assert H[-1, -1] < r.energy_identity - 0.1


def test_energy_closed_form_against_quadrature():
    # E(phi) = int |q0 - sqrt(phi') q1(phi)|^2 by brute-force midpoint quadrature
    rng = np.random.default_rng(3)
    q0, q1 = rng.normal(size=(30, 4)), rng.normal(size=(45, 4))
    phi = np.r_[0, np.sort(rng.uniform(0, 1, 29)), 1]
    tt = (np.arange(300000) + 0.5) / 300000
    n = np.minimum((tt * 30).astype(int), 29)
    dphi = np.diff(phi) * 30
    u = phi[n] + (tt * 30 - n) * np.diff(phi)[n]
    p = np.minimum((u * 45).astype(int), 44)
    ref = np.mean(np.sum((q0[n] - np.sqrt(dphi[n])[:, None] * q1[p]) ** 2, axis=1))
    assert warp_energy(q0, q1, phi)[1] == pytest.approx(ref, rel=2e-4)


@pytest.mark.parametrize("symmetric", [False, True])
def test_energy_gradient_against_finite_differences(symmetric):
    rng = np.random.default_rng(4)
    N0, N1 = 40, 55
    q0, q1 = rng.normal(size=(N0 - 1, 3)), rng.normal(size=(N1 - 1, 3))
    feats = dict(features=([0.31, 0.77], [0.4, 0.7]), lam=2.0, symmetric=symmetric)
    phi = np.r_[0, np.sort(rng.uniform(0, 1, N0 - 2)), 1]
    E, g = warp_energy_grad(q0, q1, phi, **feats)
    for k in rng.choice(np.arange(1, N0 - 1), 8, replace=False):
        e = np.zeros(N0)
        e[k] = 1e-7
        fd = (warp_energy(q0, q1, phi + e, **feats)[0]
              - warp_energy(q0, q1, phi - e, **feats)[0]) / 2e-7
        assert g[k] == pytest.approx(fd, rel=1e-5, abs=1e-6)
    assert g[0] == 0 and g[-1] == 0


def bumps(N):
    t = np.linspace(0, 1, N)
    b = lambda c, h: h * np.exp(-((t - c) / 0.06) ** 2)      # noqa: E731
    c1 = np.c_[t, b(0.35, 1.0) + b(0.7, 0.9)]               # two bumps
    c0 = np.c_[t, b(0.5, 1.0)]                               # one bump
    return t, c0, c1


def test_features_pull_the_alignment_to_the_other_bump():
    t, c0, c1 = bumps(200)
    free = align(c0, c1, window=None)
    assert abs(np.interp(0.5, t, free.phi) - 0.35) < 0.01     # the more similar bump
    pulled = align(c0, c1, window=None, features=([0.5], [0.7]), lam=10.0)
    assert abs(np.interp(0.5, t, pulled.phi) - 0.7) < 0.01    # the bump the user marked
    assert pulled.elastic > free.elastic                       # paid for in elastic energy
    weak = align(c0, c1, window=None, features=([0.5], [0.7]), lam=0.1)
    assert abs(np.interp(0.5, t, weak.phi) - 0.35) < 0.01     # a weak pull loses


def test_symmetric_and_hard_feature_terms():
    t, c0, c1 = bumps(200)
    r = align(c0, c1, window=None, features=([0.5], [0.7]), lam=10.0, symmetric=True)
    assert abs(np.interp(0.7, r.phi, t) - 0.5) < 0.01          # phi^{-1}(b) = a
    hard = align(c0, c1, window=None, features=([0.5], [0.7]), bounds=0.0)
    a, b = np.round(0.5 * 199) / 199, np.round(0.7 * 199) / 199  # passage point on samples
    assert np.interp(a, t, hard.phi) == pytest.approx(b, abs=1e-12)
    band = align(c0, c1, window=None, features=([0.5], [0.7]), bounds=0.01)
    assert abs(np.interp(0.5, t, band.phi) - 0.7) <= 0.01 + 1e-12
    with pytest.raises(ShellsplineError, match="no admissible warp"):
        align(c0, c1, window=0.05, features=([0.5], [0.7]), bounds=0.0)


def test_features_on_the_group():
    # the same pull with the Lie-group SRVT: a joint that swings twice vs once
    N = 200
    t = np.linspace(0, 1, N)
    b = lambda c, h: h * np.exp(-((t - c) / 0.06) ** 2)      # noqa: E731
    R1 = so3.exp(np.c_[b(0.35, 1.0) + b(0.7, 0.9), t, 0 * t])[:, None]
    R0 = so3.exp(np.c_[b(0.5, 1.0), t, 0 * t])[:, None]
    c0, c1 = ProductCurve(R0, None, t), ProductCurve(R1, None, t)
    free = align(c0, c1, window=None)
    pulled = align(c0, c1, window=None, features=([0.5], [0.7]), lam=10.0)
    assert abs(np.interp(0.5, t, free.phi) - 0.35) < 0.01
    assert abs(np.interp(0.5, t, pulled.phi) - 0.7) < 0.01


def test_closed_curves_find_the_start_point():
    N = 201
    s = np.linspace(0, 1, N)
    shape = lambda u: np.c_[np.cos(2 * np.pi * u) * (1 + 0.3 * np.cos(6 * np.pi * u)),  # noqa
                            np.sin(2 * np.pi * u) * (1 + 0.2 * np.sin(4 * np.pi * u))]
    c1 = shape(s)
    c0 = shape(s + 0.3)                                       # same loop, started later
    r = align(c0, c1, closed=True)
    assert abs(r.shift - 0.3) <= 1.5 / (N - 1)
    assert r.distance < 1e-6                                  # an exact cyclic shift
    assert align(c0, c1, refine=False).distance > 0.5         # open: no start search
    assert np.abs(np.mod(r.phi, 1.0) - np.mod(s + 0.3, 1.0)).max() < 0.01


def test_project_closed_really_closes():
    t = np.linspace(0, 1, 300)
    arc = np.c_[np.cos(5.2 * t), np.sin(5.2 * t), 0.3 * t]     # open: 300 degrees and a rise
    c = ProductCurve(X=arc, t=t)
    Q = srv(c)
    Qc = project_closed(Q, t)
    closed = srv_inverse(Qc, t, X0=arc[0])
    assert np.linalg.norm(arc[-1] - arc[0]) > 0.5
    assert np.linalg.norm(closed.X[-1] - closed.X[0]) < 1e-10
    # a small change: the projection is far closer than the curve's own size
    change = np.sqrt(np.sum(np.diff(t)[:, None] * (Qc - Q) ** 2))
    assert change < 0.5 * np.sqrt(np.sum(np.diff(t)[:, None] * Q ** 2))
    # an already closed curve is left alone
    circ = ProductCurve(X=np.c_[np.cos(2 * np.pi * t), np.sin(2 * np.pi * t)], t=t)
    np.testing.assert_allclose(project_closed(srv(circ), t, tol=1e-9), srv(circ), atol=1e-9)


def test_shape_distance_symmetric_and_invariant():
    t = np.linspace(0, 1, 150)
    a, b = space_curve(t), space_curve(t ** 1.7)
    c = np.c_[np.sin(4 * t), t, np.cos(t)]
    assert shape_distance(a, c) == shape_distance(c, a)
    assert shape_distance(a, b) < 0.05 * shape_distance(a, c)     # b is a re-timed a
    from shellspline.curves.srv import srv_distance
    assert srv_distance(ProductCurve(X=a), ProductCurve(X=b)) > 10 * shape_distance(a, b)


def test_dtw_matches_brute_force():
    rng = np.random.default_rng(2)
    x0, x1 = rng.normal(size=(15, 2)), rng.normal(size=(12, 2))
    Dm = np.linalg.norm(x0[:, None] - x1[None], axis=2)
    H = np.full((16, 13), np.inf)
    H[0, 0] = 0
    for i in range(1, 16):
        for j in range(1, 13):
            H[i, j] = Dm[i - 1, j - 1] + min(H[i - 1, j - 1], H[i - 1, j], H[i, j - 1])
    cost, path = dtw(x0, x1)
    assert cost == pytest.approx(H[-1, -1], rel=1e-12)
    assert tuple(path[0]) == (0, 0) and tuple(path[-1]) == (14, 11)
    assert cost == pytest.approx(Dm[path[:, 0], path[:, 1]].sum(), rel=1e-12)


def test_invalid_inputs_raise():
    t = np.linspace(0, 1, 30)
    a = space_curve(t)
    with pytest.raises(ShellsplineError, match="same components"):
        align(a, a[:, :2])
    with pytest.raises(ShellsplineError, match="window"):
        align(a, a, window=0)
    with pytest.raises(ShellsplineError, match="must lie in"):
        align(a, a, features=([1.5], [0.5]), lam=1)
    with pytest.raises(ShellsplineError, match="as many"):
        align(a, a, features=([0.5, 0.6], [0.5]), lam=1)
    with pytest.raises(ShellsplineError, match="uniform"):
        align(ProductCurve(X=a, t=t ** 2 + t), a)
    with pytest.raises(ShellsplineError, match="lam"):
        align(a, a, features=([0.5], [0.5]), lam=-1)
    with pytest.raises(ShellsplineError, match="distance"):
        shape_distance(a, a, features=([0.5], [0.5]))
    with pytest.raises(ShellsplineError, match=r"29 and 5 intervals.*\[1/4, 4\]"):
        align(a, space_curve(np.linspace(0, 1, 6)), neighborhood_size=4)
    assert align(a, space_curve(np.linspace(0, 1, 6)), refine=False).status == "dp"  # 29 <= 6*5

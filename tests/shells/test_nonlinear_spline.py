"""Nonlinear spline: adjoint gradient, Euclidean oracle, C¹ at keyframes, monotone descent."""
from __future__ import annotations

import numpy as np
import pytest
from conftest import icosphere

from shellspline.shells.geodesic import geodesic_interpolation
from shellspline.shells.lta_spline import lta_spline
from shellspline.numerics.krylov import KrylovResult, pcg, steihaug
from shellspline.shells.nonlinear import (GaussNewtonModel, LTARetraction, ModelPreconditioner,
                                          NonlinearSplineProblem, SpaceTimePreconditioner,
                                          TrustRegionNewton, nonlinear_spline)
from shellspline.shells.nonlinear.models import project_rigid
from shellspline.timeline import linear_blend
from shellspline.shells.energy import DiscreteShells, EuclideanEnergy
from shellspline.mesh.topology import topology


def _kink(V, f):
    """Relative second difference at frame f (as in tests/pipeline/test_pipeline.py)."""
    return np.linalg.norm(V[f + 1] - 2 * V[f] + V[f - 1]) / np.linalg.norm(V[f + 1] - V[f - 1])


def _off_rigid(prob, S, rng):
    """A random direction off each free shell's rigid motions (F is invariant along them)."""
    v = rng.standard_normal((len(prob.free_nodes), len(prob.free_dofs)))
    for i, q in enumerate(prob.rigid_bases(S)):
        v[i] -= q @ (q.T @ v[i])
    return v.ravel()


def _fd_hessian_product(prob, S, v, h=1e-5):
    """Central difference of the adjoint gradient of F^K along v (midpoints re-solved)."""
    x = prob.x_of(S)
    gp = prob.x_of(prob.evaluate(prob.nodes_of(x + h * v, S))[1])
    gm = prob.x_of(prob.evaluate(prob.nodes_of(x - h * v, S))[1])
    return (gp - gm) / (2 * h)


@pytest.fixture(scope="module")
def tiny():
    V, F = icosphere(1)
    T = topology(F)
    Vkey = np.stack([V * [1.4, 1, 1], V, V * [1, 1.4, 1]])
    return Vkey, T


def test_adjoint_gradient_matches_central_differences(tiny):
    Vkey, T = tiny
    prob = NonlinearSplineProblem(DiscreteShells(T, eta=0.1), [0, 2, 4], 4, midpoint_tol=1e-14)
    S = linear_blend(Vkey, prob.frames, 4)
    rng = np.random.default_rng(1)
    S[prob.free_nodes] += 0.02 * rng.standard_normal(S[prob.free_nodes].shape)
    F0, G = prob.evaluate(S)
    assert np.all(G[prob.frames] == 0)
    x, g = prob.x_of(S), prob.x_of(G)
    h = 1e-6
    for _ in range(2):  # random directions: F(x ± h d) with every midpoint re-solved
        d = rng.standard_normal(x.size)
        fp = prob.evaluate(prob.nodes_of(x + h * d, S), gradient=False)
        fm = prob.evaluate(prob.nodes_of(x - h * d, S), gradient=False)
        assert abs((fp - fm) / (2 * h) - g @ d) <= 1e-6 * abs(g @ d)


def test_euclidean_energy_gives_the_euclidean_cubic_spline():
    rng = np.random.default_rng(0)
    Vkey = rng.standard_normal((3, 6, 3))
    frames, K = [0, 3, 6], 6
    for bc, fr, KK in (("natural", frames, K), ("periodic", [0, 2, 4], 6)):
        res = nonlinear_spline(Vkey, fr, KK, energy=EuclideanEnergy(6), bc=bc, gtol=1e-10)
        assert res.success
        ref = lta_spline(Vkey.reshape(3, -1), fr, KK, bc=bc).reshape(KK + 1, 6, 3)
        assert np.abs(res.V - ref).max() < 1e-6 * np.abs(ref).max()


def test_smooth_at_the_middle_keyframe_and_monotone(tiny):
    Vkey, T = tiny
    frames, K = [0, 2, 4], 4
    energies = []
    spl = nonlinear_spline(Vkey, frames, K, T, eta=0.1, gtol=1e-4, max_iter=200,
                           callback=lambda i, F, g: energies.append(F))
    assert spl.success, spl.message
    assert np.array_equal(energies, spl.energies)
    assert np.all(np.diff(spl.energies) <= 1e-12 * spl.energies[0])
    assert spl.grad_norms[-1] <= 1e-4 * spl.grad_norms[0]
    for j, f in enumerate(frames):
        assert np.array_equal(spl.V[f], Vkey[j])
    geo = geodesic_interpolation(Vkey, frames, K, T, eta=0.1)
    assert geo.success
    assert _kink(geo.V, 2) > 0.5
    # K = 4 keeps the test fast; the relative second difference of a smooth but strongly bent
    # path stays O(1) at such coarse K (0.71 vs 1.03 here; 0.52 vs 1.05 at K = 6)
    assert _kink(spl.V, 2) < 0.75 * _kink(geo.V, 2)


def test_hermite_and_validation(tiny):
    Vkey, T = tiny
    V4 = np.stack([Vkey[0], 0.9 * Vkey[0] + 0.1 * Vkey[1], 0.1 * Vkey[1] + 0.9 * Vkey[2], Vkey[2]])
    res = nonlinear_spline(V4, [0, 1, 3, 4], 4, T, bc="hermite", eta=0.1, gtol=1e-4)
    assert res.success and np.array_equal(res.V[1], V4[1])
    with pytest.raises(ValueError, match="`frames`"):
        nonlinear_spline(Vkey, [0, 2, 4], 4, T, bc="hermite")
    with pytest.raises(ValueError, match="`init`"):
        nonlinear_spline(Vkey, [0, 2, 4], 4, T, init=Vkey)
    with pytest.raises(ValueError, match="`Vkey`"):
        nonlinear_spline(Vkey[:, :-1], [0, 2, 4], 4, T)
    with pytest.raises(ValueError, match="`bc`"):
        nonlinear_spline(Vkey, [0, 2, 4], 4, T, bc="clamped")


def test_gauss_newton_reaches_the_lbfgs_minimiser_in_fewer_iterations(tiny):
    Vkey, T = tiny
    kw = dict(eta=0.1, gtol=1e-6, max_iter=2000)
    gn = nonlinear_spline(Vkey, [0, 2, 4], 4, T, optimizer="gauss-newton", **kw)
    lb = nonlinear_spline(Vkey, [0, 2, 4], 4, T, optimizer="lbfgs", precondition=False, **kw)
    assert gn.success and lb.success, (gn.message, lb.message)
    assert gn.optimizer == "gauss-newton" and len(gn.cg_iterations) == gn.nit
    assert np.all(np.diff(gn.energies) <= 1e-12 * gn.energies[0])
    assert abs(gn.energy - lb.energy) <= 1e-8 * lb.energy
    scale = np.abs(Vkey).max()
    assert np.abs(gn.V - lb.V).max() <= 1e-4 * scale
    assert 3 * gn.nit < lb.nit, (gn.nit, lb.nit)


def test_gauss_newton_model_is_the_exact_hessian_for_the_euclidean_energy():
    rng = np.random.default_rng(3)
    Vkey = rng.standard_normal((3, 5, 3))
    prob = NonlinearSplineProblem(EuclideanEnergy(5), [0, 3, 6], 6)
    S = linear_blend(Vkey, prob.frames, 6) + 0.1 * rng.standard_normal((7, 5, 3))
    prob.evaluate(S, keep=True)
    model = GaussNewtonModel(prob)
    x, v = prob.x_of(S), rng.standard_normal(prob.n_variables)
    h = 1e-4  # F is quadratic: central differences of the gradient are exact up to round-off
    gp = prob.x_of(prob.evaluate(prob.nodes_of(x + h * v, S))[1])
    gm = prob.x_of(prob.evaluate(prob.nodes_of(x - h * v, S))[1])
    Hv = model.matvec(v)
    assert np.abs(Hv - (gp - gm) / (2 * h)).max() <= 1e-7 * np.abs(Hv).max()


def test_gauss_newton_model_matches_finite_differences_near_the_solution(tiny):
    """For Discrete Shells the model drops the adjoint-weighted third derivatives, which are
    small when the midpoints are close to the shells: check it against central differences of
    the exact (adjoint) gradient on a fine time grid."""
    Vkey, T = tiny
    spl = nonlinear_spline(Vkey, [0, 3, 6], 6, T, eta=0.1, gtol=1e-4)
    prob = NonlinearSplineProblem(DiscreteShells(T, eta=0.1), [0, 3, 6], 6, midpoint_tol=1e-13)
    S = spl.V
    prob.evaluate(S, keep=True)
    model = GaussNewtonModel(prob)
    rng = np.random.default_rng(4)
    v = _off_rigid(prob, S, rng)
    fd = _fd_hessian_product(prob, S, v)
    Hv = model.matvec(v)
    assert np.linalg.norm(Hv - fd) <= 0.1 * np.linalg.norm(fd)
    assert v @ Hv > 0


def test_preconditioner_cuts_cg_iterations(tiny):
    Vkey, T = tiny
    prob = NonlinearSplineProblem(DiscreteShells(T, eta=0.1), [0, 3, 6], 6)
    S = linear_blend(Vkey, prob.frames, 6)
    F, G = prob.evaluate(S, keep=True)
    model = GaussNewtonModel(prob)
    Q = prob.rigid_bases(S)
    P = ModelPreconditioner(prob, S)
    f = len(prob.free_nodes)
    g = prob.x_of(G)
    def proj(v):
        return project_rigid(v.reshape(f, -1), Q).ravel()

    rp = pcg(model.matvec, -g, precond=lambda v: P.apply(v, Q=Q), project=proj, rtol=1e-6,
             max_iter=500)
    ri = pcg(model.matvec, -g, precond=lambda v: proj(v.copy()), project=proj, rtol=1e-6,
             max_iter=500)
    assert rp.status == "converged" and ri.status == "converged", (rp.message, ri.message)
    assert 2 * rp.iterations < ri.iterations, (rp.iterations, ri.iterations)
    # both solve the same projected system
    assert np.linalg.norm(rp.x - ri.x) <= 1e-4 * np.linalg.norm(ri.x)


def test_folded_hexagon_large_eta_converges_and_leaves_the_isometries():
    # paper Fig. 10, bending-dominated: three isometric folds of a flat hexagon of circumradius
    # 30 with η = 10 (W = R² (W_mem + η/R² W_Θ), so this is η ≈ 0.011 on the unit hexagon;
    # on the unit hexagon η = 10 has no minimiser: crease edges collapse). The Gauss–Newton
    # model underestimates the curvature ~30x here (30 iterations: gradient reduced 3e-3
    # only); with the exact Hessian products of hessian="auto" it converges in ~7.
    import data_synth
    from shellspline import interpolate
    from shellspline.shells.descriptors import edge_lengths

    h = data_synth.generate("hexagon", n_vertices=61, frames=(0, 2, 4))
    T = topology(h["F"])
    R, K = 30.0, 6
    Vkey = R * h["V"]
    init = interpolate((Vkey, h["F"]), frames=h["frames"], K=K, eta=10.0, bc="periodic").V
    res = nonlinear_spline(Vkey, h["frames"], K, T, bc="periodic", eta=10.0, init=init,
                           max_iter=12)
    assert res.success, res.message
    assert "exact" in res.hessian
    assert np.all(np.diff(res.energies) <= 1e-12 * res.energies[0])
    L0 = edge_lengths(R * h["rest"], T)
    strain = max(np.abs(edge_lengths(V, T) / L0 - 1).max() for V in res.V)
    assert strain > 0.1  # leaves the isometric deformations of the flat hexagon
    assert np.allclose(res.V[h["frames"]], Vkey)


def test_exact_hessian_products_match_finite_differences_far_from_the_solution(tiny):
    """``exact_matvec`` (third derivatives by forward differences of the Lagrangian gradient)
    equals central differences of the adjoint gradient of F^K, also at a point far from the
    minimiser (the blend, large eta) where the Gauss-Newton model is off."""
    Vkey, T = tiny
    prob = NonlinearSplineProblem(DiscreteShells(T, eta=0.5), [0, 3, 6], 6, midpoint_tol=1e-13)
    S = linear_blend(Vkey, [0, 3, 6], 6)
    S[1:3] += 0.02 * np.random.default_rng(7).standard_normal(S[1:3].shape)
    prob.evaluate(S, keep=True)
    model = GaussNewtonModel(prob)
    rng = np.random.default_rng(5)
    errs, acc_errs, gn_errs = [], [], []
    for _ in range(2):
        v = _off_rigid(prob, S, rng)
        fd = _fd_hessian_product(prob, S, v)
        errs.append(np.linalg.norm(model.exact_matvec(v) - fd) / np.linalg.norm(fd))
        acc_errs.append(np.linalg.norm(model.accurate_matvec(v) - fd) / np.linalg.norm(fd))
        gn_errs.append(np.linalg.norm(model.matvec(v) - fd) / np.linalg.norm(fd))
    assert max(errs) < 1e-4, errs
    assert max(acc_errs) < 1e-4, acc_errs
    assert min(gn_errs) > 100 * max(errs), gn_errs  # the case does exercise the third derivatives


def test_trust_region_and_line_search_reach_the_same_minimiser(tiny):
    Vkey, T = tiny
    kw = dict(eta=0.1, gtol=1e-7)
    tr = nonlinear_spline(Vkey, [0, 3, 6], 6, T, **kw)
    ls = nonlinear_spline(Vkey, [0, 3, 6], 6, T, globalization="line-search", **kw)
    lin = nonlinear_spline(Vkey, [0, 3, 6], 6, T, retract=False, **kw)
    assert tr.success and ls.success and lin.success
    assert np.all(np.diff(tr.energies) <= 1e-12 * tr.energies[0])  # monotone
    scale = np.abs(Vkey).max()
    for other in (ls, lin):
        assert abs(tr.energy - other.energy) <= 1e-8 * tr.energy
        assert np.abs(tr.V - other.V).max() <= 1e-4 * scale
    with pytest.raises(ValueError, match="globalization"):
        nonlinear_spline(Vkey, [0, 3, 6], 6, T, globalization="dogleg")
    with pytest.raises(ValueError, match="retract"):
        nonlinear_spline(Vkey, [0, 3, 6], 6, energy=EuclideanEnergy(42), retract=True)


def test_retraction_is_first_order_and_keeps_pins(tiny):
    """R(s, εd) = s + εd + O(ε²) (a valid curve for the trust-region test), R(s, 0) = s, and
    pinned vertices stay where they are."""
    Vkey, T = tiny
    pinned = np.array([0, 1, 2])
    prob = NonlinearSplineProblem(DiscreteShells(T, eta=0.1), [0, 3, 6], 6, pinned=pinned)
    S = linear_blend(Vkey, [0, 3, 6], 6)
    R = LTARetraction(prob, S)
    D = np.zeros_like(S)
    D[prob.free_nodes] = np.random.default_rng(2).standard_normal(D[prob.free_nodes].shape)
    D[:, pinned] = 0.0
    assert np.abs(R(S, 0 * D) - S).max() < 1e-10
    errs = [np.abs(R(S, e * D) - (S + e * D)).max() for e in (1e-2, 5e-3)]
    assert errs[1] < 0.3 * errs[0]  # quadratic: halving ε quarters the deviation
    assert errs[0] < 1e-2 * 1e-2 * 100  # and small against the step itself
    assert np.array_equal(R(S, 1e-2 * D)[:, pinned], S[:, pinned])


def test_steihaug_solves_stops_on_the_boundary_and_truncates():
    """Steihaug-Toint CG against dense linear algebra: interior solution = H^-1 b, the
    boundary step has P-norm = radius (norm tracked by recurrences, checked with P itself),
    negative curvature goes to the boundary, and the Nash-Sofer truncation stops earlier
    with most of the model decrease."""
    rng = np.random.default_rng(0)
    n = 60
    A = rng.standard_normal((n, n))
    H = A @ A.T / n + np.diag(np.logspace(-3, 1, n))
    Pd = np.diag(H) * rng.uniform(0.5, 2.0, n)  # a diagonal preconditioner, not exact
    b = rng.standard_normal(n)

    def run(radius, truncate=0.0, Hm=H, rtol=1e-10):
        r = steihaug(lambda v: Hm @ v, b, radius, precond=lambda v: v / Pd, rtol=rtol,
                     max_iter=500, truncate=truncate)
        return r.x, r.iterations, r.message, r.model_decrease, r.step_norm

    d, it, status, dec, dn = run(np.inf)
    x = np.linalg.solve(H, b)
    assert status == "converged" and np.abs(d - x).max() < 1e-8 * np.abs(x).max()
    assert np.isclose(dec, 0.5 * b @ x, rtol=1e-10)
    assert np.isclose(dn, np.sqrt(x @ (Pd * x)), rtol=1e-8)
    r = 0.3 * dn
    d, it, status, dec, dn = run(r)
    assert status == "boundary" and np.isclose(np.sqrt(d @ (Pd * d)), r, rtol=1e-10)
    assert np.isclose(dec, b @ d - 0.5 * d @ H @ d, rtol=1e-10) and dec > 0
    Hneg = H - 0.5 * np.eye(n)  # indefinite
    d, it, status, dec, dn = run(1e6, Hm=Hneg)
    assert status == "negative curvature" and np.isclose(np.sqrt(d @ (Pd * d)), 1e6)
    assert np.isclose(dec, b @ d - 0.5 * d @ Hneg @ d, rtol=1e-8) and dec > 0
    full = run(np.inf)
    cut = run(np.inf, truncate=0.25)
    assert cut[1] < full[1] and cut[3] > 0.9 * full[3]


def test_ftol_stops_at_the_first_stalled_window(tiny):
    from shellspline.shells.nonlinear import FTOL_WINDOW

    Vkey, T = tiny
    kw = dict(eta=0.1, gtol=1e-12, max_iter=200)
    full = nonlinear_spline(Vkey, [0, 2, 4], 4, T, **kw)
    E = np.asarray(full.energies)
    # relative decrease over each window of FTOL_WINDOW iterations along the full run
    drops = (E[:-FTOL_WINDOW] - E[FTOL_WINDOW:]) / np.abs(E[FTOL_WINDOW:])
    ftol = 1e-9
    first = int(np.argmax(drops <= ftol)) + FTOL_WINDOW  # iteration where the window stalls
    assert drops.min() <= ftol < drops[0]
    with pytest.warns(RuntimeWarning, match="ftol"):
        res = nonlinear_spline(Vkey, [0, 2, 4], 4, T, ftol=ftol, **kw)
    # the energy settled before the gradient criterion held: honestly "stalled"
    assert res.status == "stalled" and not res.success and "ftol" in res.message, res.message
    # deterministic: the same iterates as the full run, stopped at the first stalled window
    assert res.nit == first < full.nit
    assert np.allclose(res.energies, E[:first + 1], rtol=0, atol=0)
    assert res.grad_norms[-1] > 1e-12 * res.grad_norms[0]  # stopped by ftol, not gtol
    with pytest.raises(ValueError, match="`ftol`"):
        nonlinear_spline(Vkey, [0, 2, 4], 4, T, ftol=-1e-3)


def test_accurate_products_are_symmetric_in_soft_directions(tiny):
    """``accurate_matvec`` differences analytic products once: ``xᵀHy = yᵀHx`` also for
    preconditioned (soft) vectors, and the product does not depend on the difference step."""
    Vkey, T = tiny
    prob = NonlinearSplineProblem(DiscreteShells(T, eta=0.01), [0, 3, 6], 6, pinned=[0, 5, 9],
                                  midpoint_tol=1e-13)
    S = linear_blend(Vkey, [0, 3, 6], 6)
    S[1:3] += 0.02 * np.random.default_rng(7).standard_normal(S[1:3].shape)
    S[:, [0, 5, 9]] = Vkey[0, [0, 5, 9]]
    prob.evaluate(S, keep=True)
    model = GaussNewtonModel(prob)
    P = SpaceTimePreconditioner(prob, S)
    rng = np.random.default_rng(3)
    x, y = (P.apply(rng.standard_normal(prob.n_variables)) for _ in range(2))
    Hx, Hy = model.accurate_matvec(x), model.accurate_matvec(y)
    assert abs(x @ Hy - y @ Hx) <= 1e-6 * np.sqrt(abs(x @ Hx) * abs(y @ Hy))
    h0 = model.h
    model.h = 10 * h0  # drops the products cached at the model point
    assert np.linalg.norm(model.accurate_matvec(x) - Hx) <= 1e-5 * np.linalg.norm(Hx)
    model.h = h0


def test_space_time_preconditioner_inverts_the_lta_spline_hessian(tiny):
    """P is the Hessian of E(s) = 4K³ Σ_t ‖z(s_k) − ½(z(s_a) + z(s_b))‖²_w (LΘA weights at
    s_k, held fixed) where the residuals vanish: with u = P⁻¹ v, second differences of E
    along u give uᵀv. E is evaluated from the descriptors alone (no Jacobians)."""
    from shellspline.shells.descriptors import lta_descriptors, lta_weights, wrap_angle
    Vkey, T = tiny
    W = DiscreteShells(T, eta=0.05)
    for bc, frames, K in (("natural", [0, 3, 6], 6), ("periodic", [0, 3], 6)):
        prob = NonlinearSplineProblem(W, frames, K, bc, pinned=[0, 5, 9])
        S = np.repeat(Vkey[1][None], prob.n_nodes, axis=0)  # equal shells: zero residuals
        P = SpaceTimePreconditioner(prob, S)
        w = {k: lta_weights(S[k], T, mu=1.0, lam=1.0, eta=0.05) for _, k, _ in prob.terms}
        sT = T.descriptor_slices()[1]

        def E(x):
            Z = [lta_descriptors(s, T) for s in prob.nodes_of(x, S)]
            tot = 0.0
            for a, k, b in prob.terms:
                r = Z[k] - 0.5 * (Z[a] + Z[b])
                r[sT] = wrap_angle(Z[k][sT] - 0.5 * (Z[a][sT] + Z[b][sT]))
                tot += np.sum(w[k] * r * r)
            return prob.scale4 * tot

        x0 = prob.x_of(S)
        rng = np.random.default_rng(0)
        for _ in range(2):
            v = rng.standard_normal(prob.n_variables)
            u = P.apply(v)
            h = 1e-4 / np.abs(u).max()
            quad = (E(x0 + h * u) - 2 * E(x0) + E(x0 - h * u)) / h ** 2
            assert abs(quad - u @ v) <= 1e-4 * abs(u @ v), (bc, quad, u @ v)
            # the P-norm of the trust region's radius carry-over: ‖u‖_P² = uᵀPu = uᵀv
            assert abs(P.norm(u) ** 2 - u @ v) <= 1e-9 * abs(u @ v)


@pytest.mark.parametrize("hessian,gtol", [("auto", 1e-6), ("exact", 1e-4)])
def test_cg_is_not_solved_beyond_what_meets_gtol(tiny, hessian, gtol):
    """The forcing term is floored at ``gtol_margin · gtol · ‖∇F₀‖ / ‖∇F‖``: the last Newton
    system is solved only as far as the next gradient must drop, which saves CG iterations and
    still meets ``gtol`` (with Gauss–Newton products, and in the final Newton phase with
    accurate exact ones)."""
    from shellspline.shells.nonlinear.optimizers import GTOL_MARGIN

    Vkey, T = tiny
    runs = {}
    for margin in (GTOL_MARGIN, 0.0):
        calls = []

        def recording(matvec, b, radius, *, rtol, **kw):
            calls.append((rtol, float(np.linalg.norm(b))))
            return steihaug(matvec, b, radius, rtol=rtol, **kw)

        opt = TrustRegionNewton(hessian=hessian, gtol_margin=margin, inner=recording)
        res = nonlinear_spline(Vkey, [0, 2, 4], 4, T, eta=0.1, gtol=gtol, optimizer=opt)
        assert res.success and res.grad_norms[-1] <= gtol * res.grad_norms[0]
        g0 = res.grad_norms[0]
        floors = [min(margin * gtol * g0 / bn, 0.5) for _, bn in calls]
        assert all(rtol >= fl * (1 - 1e-12) for (rtol, _), fl in zip(calls, floors))
        runs[margin] = (res, calls, floors)
    res, calls, floors = runs[GTOL_MARGIN]
    if hessian == "exact":  # the floored solve is one of the final phase's
        assert res.final_phase_iteration is not None and \
            res.final_phase_iteration < len(res.cg_iterations)
    # the floor decided the last solve: looser than the Eisenstat–Walker forcing there
    assert calls[-1][0] == pytest.approx(floors[-1], rel=1e-12)
    assert calls[-1][0] > 2 * runs[0.0][1][-1][0]
    assert sum(res.cg_iterations) < sum(runs[0.0][0].cg_iterations)


@pytest.mark.parametrize("optimizer", ["trust-region", "line-search"])
def test_a_solver_that_cannot_decrease_f_returns_its_start_unchanged(tiny, optimizer):
    """Issue 13 item 4: the nonlinear spline starts from a given sequence (the LΘA result)
    and must never return something worse. Here every inner solve proposes an ascent step
    (as on a start whose folded elements make the model useless), so no trial decreases F:
    the result is the start itself (up to the rigid placement, which it already has), with
    its own energy, and an honest 'stalled' status."""
    from shellspline.shells.nonlinear import LineSearchNewton

    Vkey, T = tiny
    frames, K = [0, 3, 6], 6
    init = linear_blend(Vkey, frames, K)
    init[1:3] *= 1.05                          # a start that is not the minimiser

    def ascent(matvec, b, *args, **kw):
        d = -np.asarray(b, dtype=float)         # b = -g: the step +g increases F
        return KrylovResult(x=d, status="converged", iterations=1, model_decrease=1.0,
                            step_norm=float(np.linalg.norm(d)))

    opt = TrustRegionNewton(inner=ascent) if optimizer == "trust-region" else \
        LineSearchNewton(inner=ascent)
    with pytest.warns(RuntimeWarning, match="not converged"):
        res = nonlinear_spline(Vkey, frames, K, T, eta=0.1, init=init, optimizer=opt,
                               max_iter=5)
    # the trust region rejects every trial (stalled); the line search falls back to the
    # preconditioned gradient, which descends, and runs into max_iter (limit)
    assert not res.success
    assert res.status == ("stalled" if optimizer == "trust-region" else "limit")
    assert res.nit == (0 if optimizer == "trust-region" else 5)
    assert res.message.startswith("not converged")
    assert np.all(np.diff(res.energies) <= 0) and res.energy <= res.energies[0]
    if optimizer == "trust-region":   # every trial rejected: nothing accepted at all
        assert res.energy == res.energies[0] and len(res.energies) == 1
        assert np.abs(res.V - init).max() <= 1e-12 * np.abs(init).max()


def test_trust_region_rules():
    """The forcing term (Eisenstat–Walker, capped by cg_tol, floored by gtol_margin), the
    ratio test and the radius update, on numbers worked out by hand."""
    tr = TrustRegionNewton(cg_tol=0.5)
    assert tr.forcing(1.0, 1.0, 1e-6, False) == 0.5                  # cg_tol caps √1
    assert tr.forcing(1e-2, 1.0, 1e-6, False) == pytest.approx(0.1)   # √(1e-2)
    assert tr.forcing(1e-2, 1.0, 1e-6, True) == 0.05                  # FINAL_CG_TOL
    assert tr.forcing(1e-8, 1.0, 1e-6, False) == 0.5                  # floor 0.5·1e-6/1e-8, capped
    assert tr.forcing(1e-10, 1.0, 1e-12, False) == pytest.approx(5e-3)  # floor 0.5·1e-12/1e-10
    assert TrustRegionNewton(gtol_margin=0.0).forcing(1e-10, 1.0, 1e-12, False) == 1e-3
    assert tr.ratio(10.0, 9.0, 2.0) == 0.5
    assert tr.ratio(10.0, np.inf, 2.0) == -np.inf and tr.ratio(10.0, 11.0, 0.0) == -np.inf
    assert tr.ratio(10.0, 10.0 - 1e-14, 1e-13) == 1.0                 # below the last digits
    assert tr.updated_radius(1.0, 0.1, 0.5) == 0.125                  # a quarter of the step
    assert tr.updated_radius(1.0, 0.9, 1.0) == 2.0                    # boundary step, good
    assert tr.updated_radius(1.0, 0.9, 0.5) == 1.0                    # interior step
    assert tr.updated_radius(1.0, 0.5, 1.0) == 1.0
    with pytest.raises(ValueError, match="hessian"):
        TrustRegionNewton(hessian="newton")
    with pytest.raises(ValueError, match="retract"):
        TrustRegionNewton(retract="yes")


def test_unconverged_midpoints_are_not_moved_by_an_unguarded_newton_step(tiny):
    """F is evaluated at the midpoints the Newton solves returned when they did not converge
    (an extra full step from a non-stationary midpoint is no refinement and can jump far); a
    converged solve still gets its one refinement step (at round-off level)."""
    Vkey, T = tiny
    W = DiscreteShells(T, eta=0.1)
    prob = NonlinearSplineProblem(W, [0, 2, 4], 4, midpoint_tol=1e-12)
    S = linear_blend(Vkey, prob.frames, 4)
    rng = np.random.default_rng(3)
    S[prob.free_nodes] += 0.05 * rng.standard_normal(S[prob.free_nodes].shape)
    warm = 0.5 * (S[prob.terms[:, 0]] + S[prob.terms[:, 2]])
    # no Newton step allowed: every solve returns its start, unconverged
    own = [prob.solver.solve(S[a], S[b], warm[t][None], tol=1e-12, max_iter=0)
           for t, (a, _, b) in enumerate(prob.terms)]
    assert not any(r.success for r in own)
    assert all(np.array_equal(r.V[1], w) for r, w in zip(own, warm))
    F = prob.evaluate(S, gradient=False, warm=warm, max_newton=0)
    assert np.array_equal(prob.midpoints, warm)
    expect = prob.scale4 * sum(W.energy(S[k], w) for (_, k, _), w in zip(prob.terms, warm))
    assert F == pytest.approx(expect, rel=1e-12)
    # converged solves: the refinement step moves the midpoints by round-off only
    prob.evaluate(S, gradient=False, warm=warm)
    conv = np.stack([prob.solver.solve(S[a], S[b], warm[t][None], tol=1e-12).V[1]
                     for t, (a, _, b) in enumerate(prob.terms)])
    assert np.abs(prob.midpoints - conv).max() < 1e-9 * np.abs(conv).max()


def test_full_evaluations_allow_more_newton_steps_than_trials(tiny):
    """Full evaluations give every midpoint solve MIDPOINT_MAX_NEWTON Newton steps (the
    coarse horse's midpoints next to snapping flaps need 61-78), trial points 10."""
    from shellspline.shells.nonlinear import NonlinearSplineSolver
    from shellspline.shells.nonlinear.problem import MIDPOINT_MAX_NEWTON

    Vkey, T = tiny
    prob = NonlinearSplineProblem(DiscreteShells(T, eta=0.1), [0, 2, 4], 4)
    limits = []
    solve = prob.solver.solve

    def spy(*args, max_iter=50, **kw):
        limits.append(max_iter)
        return solve(*args, max_iter=max_iter, **kw)

    prob.solver.solve = spy
    solver = NonlinearSplineSolver(prob)
    solver.S0 = linear_blend(Vkey, prob.frames, 4)
    x = prob.x_of(solver.S0)
    solver.evaluate(x)
    assert limits == [MIDPOINT_MAX_NEWTON] * len(prob.terms) and MIDPOINT_MAX_NEWTON >= 100
    limits.clear()
    solver.evaluate(x, trial=True)
    assert limits == [10] * len(prob.terms)

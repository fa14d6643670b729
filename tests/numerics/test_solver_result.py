"""One SolverResult shape for every iterative solver: same fields, honest statuses.

Every solver is run three ways where it can be: to convergence, into a forced iteration
limit, and into a forced stall; each result must say which, with ``success`` true only for
``"converged"`` and histories of one entry per accepted iterate plus the start.
"""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from conftest import icosphere

from shellspline import GaussNewton, topology
from shellspline.numerics.krylov import KrylovResult, pcg, steihaug
from shellspline.numerics.linesearch import backtracking
from shellspline.numerics.result import STATUSES, SolverResult
from shellspline.shells.descriptors import lta_descriptors, lta_weights
from shellspline.shells.energy import DiscreteShells, EuclideanEnergy
from shellspline.shells.geodesic import discrete_geodesic, geodesic_interpolation
from shellspline.shells.nonlinear import (NonlinearSplineProblem, NonlinearSplineSolver,
                                          StopPolicy, TrustRegionNewton, nonlinear_spline)

COMMON = {"status", "iterations", "energies", "grad_norms", "message"}


def _check_shape(res, *, histories=True):
    """The common fields, their types, and the derived ones."""
    assert isinstance(res, SolverResult)
    names = {f.name for f in dataclasses.fields(res)}
    assert COMMON <= names
    assert res.status in STATUSES
    assert res.success == (res.status == "converged")
    assert res.nit == res.iterations and isinstance(res.iterations, int)
    for h in (res.energies, res.grad_norms):
        assert isinstance(h, np.ndarray) and h.dtype == np.float64 and h.ndim == 1
    assert isinstance(res.message, str) and res.message and "\n" not in res.message
    if histories:
        assert len(res.energies) == len(res.grad_norms) == res.iterations + 1
        assert res.energy == res.energies[-1]
    summary = res.summary()
    assert summary["status"] == res.status and summary["nit"] == res.iterations


@pytest.fixture(scope="module")
def sphere():
    V, F = icosphere(1)
    return V, topology(F)


# -- the base type -------------------------------------------------------------------------

def test_success_is_derived_from_status_and_cannot_be_set():
    r = SolverResult(status="limit", iterations=1, energies=[2.0, 1.0], grad_norms=[1, 0.5],
                     message="limit")
    assert not r.success and r.energy == 1.0 and r.grad_reduction == 0.5
    with pytest.raises(AttributeError):
        r.success = True
    r.record(0.5, 0.25)
    assert r.energies.tolist() == [2.0, 1.0, 0.5] and r.grad_norms[-1] == 0.25
    r.stop("converged", "done")
    assert r.success
    with pytest.raises(ValueError, match="status"):
        r.stop("ok", "?")
    with pytest.raises(ValueError, match="status"):
        SolverResult(status="success")
    empty = SolverResult(status="limit", message="time limit before the first evaluation")
    assert np.isnan(empty.energy) and np.isnan(empty.grad_reduction)
    assert empty.summary()["energy_final"] is None


# -- Gauss–Newton reconstruction -----------------------------------------------------------

def _reconstruction_problem(sphere):
    V, T = sphere
    target = V * [1.3, 1.0, 0.8]
    z, w = lta_descriptors(target, T), lta_weights(target, T, eta=1e-2)
    return T, z, w, V


def test_reconstruction_converged_limit_stalled(sphere):
    T, z, w, V0 = _reconstruction_problem(sphere)
    ok = GaussNewton(T, gtol=1e-8, ftol=1e-14).solve(z, w, V0)
    _check_shape(ok)
    assert ok.status == "converged" and ok.grad_norms[-1] <= 1e-8 * ok.grad_norms[0] or \
        "decrement" in ok.message
    limit = GaussNewton(T, max_iter=1, gtol=1e-12, dtol=0.0).solve(z, w, V0)
    _check_shape(limit)
    assert limit.status == "limit" and not limit.success and limit.iterations == 1
    # an inconsistent target (noisy descriptors): the energy settles at a positive minimum
    # long before an unreachable gtol -> stalled, not converged
    zn = z * (1 + 0.05 * np.random.default_rng(0).standard_normal(z.shape))
    stalled = GaussNewton(T, ftol=1e-3, gtol=1e-14, dtol=0.0).solve(zn, w, V0)
    _check_shape(stalled)
    assert stalled.status == "stalled" and not stalled.success, stalled.message
    assert stalled.grad_norms[-1] > 1e-14 * stalled.grad_norms[0]


# -- discrete geodesics --------------------------------------------------------------------

class _WrongGradient:
    """A Euclidean energy whose gradient points uphill: no Newton or gradient step can
    decrease it, so the line search must fail (a forced stall)."""

    def __init__(self, n):
        self._W = EuclideanEnergy(n)

    def __getattr__(self, name):
        return getattr(self._W, name)

    def gradient(self, X, Y, wrt):
        return -self._W.gradient(X, Y, wrt)


def test_geodesic_converged_limit_stalled(sphere):
    V, T = sphere
    ok = discrete_geodesic(V, 1.2 * V, 4, T, eta=0.1)
    _check_shape(ok)
    assert ok.status == "converged" and np.all(np.diff(ok.energies) <= 0)
    limit = discrete_geodesic(V * [1.5, 1, 1], V * [1, 1, 1.5], 4, T, eta=0.1, max_iter=1,
                              tol=1e-14)
    _check_shape(limit)
    assert limit.status == "limit" and limit.iterations == 1
    rng = np.random.default_rng(0)
    A, B = rng.standard_normal((2, 5, 3))
    init = np.stack([(2 * A + B) / 3, (A + 2 * B) / 3]) + 0.1 * rng.standard_normal((2, 5, 3))
    stalled = discrete_geodesic(A, B, 3, energy=_WrongGradient(5), init=init)
    _check_shape(stalled)
    assert stalled.status == "stalled" and "line search" in stalled.message


def test_geodesic_interpolation_aggregates_segment_statuses(sphere):
    V, T = sphere
    Vkey = np.stack([V * [1.4, 1, 1], V, V * [1, 1.4, 1]])
    ok = geodesic_interpolation(Vkey, [0, 2, 4], 4, T, eta=0.1)
    _check_shape(ok, histories=False)
    assert ok.status == "converged" and ok.iterations == sum(s.nit for s in ok.segments)
    assert ok.energy == pytest.approx(sum(ok.segment_energies))
    with pytest.warns(RuntimeWarning, match="not converged"):
        lim = geodesic_interpolation(Vkey, [0, 2, 4], 4, T, eta=0.1, max_iter=1, tol=1e-14)
    _check_shape(lim, histories=False)
    assert lim.status == "limit" and all(s.status == "limit" for s in lim.segments)


# -- the nonlinear spline ------------------------------------------------------------------

def test_nonlinear_spline_converged_limit_stalled(sphere):
    V, T = sphere
    Vkey = np.stack([V * [1.4, 1, 1], V, V * [1, 1.4, 1]])
    ok = nonlinear_spline(Vkey, [0, 2, 4], 4, T, eta=0.1, gtol=1e-5)
    _check_shape(ok)
    assert ok.status == "converged" and ok.grad_norms[-1] <= 1e-5 * ok.grad_norms[0]
    with pytest.warns(RuntimeWarning, match="maximum number of iterations"):
        limit = nonlinear_spline(Vkey, [0, 2, 4], 4, T, eta=0.1, gtol=1e-9, max_iter=1)
    _check_shape(limit)
    assert limit.status == "limit" and limit.iterations == 1
    # ftol: the energy settled but the gradient did not drop by gtol -> stalled, not converged
    with pytest.warns(RuntimeWarning, match="ftol"):
        stalled = nonlinear_spline(Vkey, [0, 2, 4], 4, T, eta=0.1, gtol=1e-12, ftol=0.5)
    _check_shape(stalled)
    assert stalled.status == "stalled" and stalled.grad_norms[-1] > 1e-12 * stalled.grad_norms[0]
    with pytest.warns(RuntimeWarning, match="time limit"):
        late = nonlinear_spline(Vkey, [0, 2, 4], 4, T, eta=0.1, max_time_s=1e-9)
    _check_shape(late, histories=False)
    assert late.status == "limit" and late.energies.size == 0 and np.isnan(late.energy)
    assert np.array_equal(late.V[[0, 2, 4]], Vkey)


def test_solver_object_with_a_stop_policy_equals_the_convenience_function(sphere):
    """The object API (problem + optimiser + stop policy) is what nonlinear_spline runs."""
    V, T = sphere
    Vkey = np.stack([V * [1.4, 1, 1], V, V * [1, 1.4, 1]])
    prob = NonlinearSplineProblem(DiscreteShells(T, eta=0.1), [0, 2, 4], 4)
    seen = []
    res = NonlinearSplineSolver(prob, TrustRegionNewton(), StopPolicy(gtol=1e-5),
                                callback=lambda i, F, g: seen.append((i, F, g))).solve(Vkey)
    ref = nonlinear_spline(Vkey, [0, 2, 4], 4, T, eta=0.1, gtol=1e-5)
    assert res.status == ref.status == "converged"
    assert np.array_equal(res.energies, ref.energies) and np.array_equal(res.V, ref.V)
    assert [s[0] for s in seen] == list(range(res.iterations + 1))
    assert np.array_equal([s[1] for s in seen], res.energies)
    again = NonlinearSplineSolver(prob, TrustRegionNewton(), StopPolicy(gtol=1e-5)).solve(Vkey)
    assert np.array_equal(again.energies, res.energies) and again.nfev == res.nfev  # fresh run
    for bad in (dict(gtol=0.0), dict(gtol=1.5), dict(ftol=-1.0), dict(max_time_s=0),
                dict(max_iter=-1)):
        with pytest.raises(ValueError, match=next(iter(bad))):
            StopPolicy(**bad)


# -- Krylov solvers and the line search ----------------------------------------------------

def test_krylov_results_converged_and_limit():
    rng = np.random.default_rng(0)
    A = rng.standard_normal((40, 40))
    H = A @ A.T + 0.1 * np.eye(40)
    b = rng.standard_normal(40)
    x = np.linalg.solve(H, b)
    ok = pcg(lambda v: H @ v, b, rtol=1e-10, max_iter=500)
    _check_shape(ok)
    assert isinstance(ok, KrylovResult) and ok.status == "converged"
    assert np.abs(ok.x - x).max() <= 1e-6 * np.abs(x).max()
    # energies: the quadratic model ½xᵀHx − bᵀx at the iterates, decreasing (CG minimises it)
    q = 0.5 * ok.x @ H @ ok.x - b @ ok.x
    assert ok.energies[-1] == pytest.approx(q, rel=1e-8) and np.all(np.diff(ok.energies) <= 1e-12)
    assert ok.grad_norms[-1] <= 1e-10 * ok.grad_norms[0]
    lim = pcg(lambda v: H @ v, b, rtol=1e-12, max_iter=3)
    _check_shape(lim)
    assert lim.status == "limit" and lim.iterations == 3
    tr = steihaug(lambda v: H @ v, b, 1e-3, rtol=1e-10)
    _check_shape(tr)
    assert tr.status == "converged" and tr.message == "boundary"
    assert tr.model_decrease == pytest.approx(-tr.energies[-1])
    neg = pcg(lambda v: -v, b)
    _check_shape(neg)
    assert neg.status == "stalled" and neg.message == "negative curvature"


def test_backtracking_armijo_and_infeasible_trials():
    # φ(α) = (α − 0.3)², φ(0) = 0.09, φ'(0) = −0.6: α = 1 fails, α = 0.5 passes
    r = backtracking(lambda a: ((a - 0.3) ** 2, a), 0.09, -0.6)
    assert r.accepted and r.alpha == 0.5 and r.payload == 0.5 and r.evaluations == 2
    # infeasible above α = 0.1 (inf), e.g. a collapsed triangle: never accepted there
    r = backtracking(lambda a: (np.inf if a > 0.1 else (a - 0.3) ** 2, None), 0.09, -0.6)
    assert r.accepted and r.alpha <= 0.1
    # interpolation: the quadratic's minimiser 0.3 (safeguarded to [0.1, 0.5] α)
    r = backtracking(lambda a: ((a - 0.3) ** 2, None), 0.09, -0.6, interpolate=True)
    assert r.accepted and r.alpha == pytest.approx(0.3) and r.evaluations == 2
    # an ascent direction: nothing accepted within max_steps
    r = backtracking(lambda a: (0.09 + a, None), 0.09, -0.6, max_steps=5)
    assert not r.accepted and r.evaluations == 5


def test_curve_solvers_return_solver_results():
    """The interpolating splines on groups and the closing of curves report like every other
    solver: a direct construction is 'converged' with iterations == 0, a Newton construction
    has its C² residual history, the closing its energy ½ gap² per iteration."""
    from shellspline.curves import cubic_spline, quadratic_spline
    from shellspline.curves.closing import close
    from shellspline.curves.srv import ProductCurve
    from shellspline.groups import so3

    X = so3.exp([[0, 0, 0], [0.3, 0, 0], [0.3, 0.4, 0], [0, 0.4, 0.2]])
    newton = cubic_spline("so3", [0, 1, 2.5, 3], X).solve
    marching = quadratic_spline("so3", [0, 1, 2.5, 3], X).solve
    for r in (newton, marching):
        assert isinstance(r, SolverResult) and r.status == "converged" and r.success
    assert newton.iterations >= 1 and newton.grad_norms.size == len(newton.residuals) >= 2
    assert marching.iterations == 0 and marching.grad_norms.size == 0
    assert "direct" in marching.message

    t = np.linspace(0, 1, 30)
    R = so3.exp(np.outer(np.sin(2 * np.pi * t) + 0.3 * t, [0.2, 0.5, 0.1]))[:, None]
    res = close(ProductCurve(R, np.c_[np.cos(2 * np.pi * t), t], t))
    assert isinstance(res, SolverResult)
    np.testing.assert_allclose(res.energies, 0.5 * res.seam_gap ** 2)
    assert res.iterations == len(res.seam_gap) - 1 and res.status == "converged"

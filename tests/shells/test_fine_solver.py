"""Large-mesh Gauss–Newton paths: nested-dissection ordering, rotations fitted once per frame,
spline rows on demand (the pieces that make ``fine=True`` at 150k vertices fit in time and
memory); each against the plain path as the oracle."""
import numpy as np
import pytest
import scipy.sparse as sp

from shellspline import GaussNewton, topology
from shellspline.numerics.linalg import SparseCholesky, available_backends, nested_dissection
from conftest import cactus_sequence_problem, grid_sheet, icosphere

needs_cholmod = pytest.mark.skipif("cholmod" not in available_backends(),
                                   reason="cvxopt (CHOLMOD) not installed")


def _grid_graph(nx, ny):
    """Grid with one diagonal per cell (a triangulated sheet), positions and edge lists."""
    V, F = grid_sheet(nx, ny)
    T = topology(F)
    return V, T.E[:, 0], T.E[:, 1]


def _factor_nnz(n, I, J, order):
    """Nonzeros of the Cholesky factor of a diagonally dominant matrix on the graph, with
    the elimination order ``order`` (CHOLMOD, simplicial: exact count)."""
    import cvxopt
    import cvxopt.cholmod

    A = sp.coo_matrix((-np.ones(len(I)), (I, J)), shape=(n, n))
    A = (A + A.T).tocsr()
    A = A + sp.diags(1.0 + np.asarray(abs(A).sum(axis=1)).ravel())
    L = sp.tril(A, format="coo")
    M = cvxopt.spmatrix(L.data.tolist(), L.row.tolist(), L.col.tolist(), size=(n, n))
    opts = dict(cvxopt.cholmod.options)
    try:
        cvxopt.cholmod.options["supernodal"] = 0
        cvxopt.cholmod.options["nmethods"] = 1  # the given order only (default: best of it, AMD)
        S = cvxopt.cholmod.symbolic(M, p=cvxopt.matrix(np.asarray(order, dtype=np.int64)),
                                    uplo="L")
        cvxopt.cholmod.numeric(M, S)
        return len(cvxopt.cholmod.getfactor(S))
    finally:
        cvxopt.cholmod.options.clear()
        cvxopt.cholmod.options.update(opts)


def test_nested_dissection_is_a_permutation_in_awkward_cases():
    rng = np.random.default_rng(0)
    X, I, J = _grid_graph(30, 20)
    n = len(X)
    for Xc, Ic, Jc, leaf in [
        (X, I, J, 8),
        (X, np.r_[I, J], np.r_[J, I], 8),             # edges given twice
        (np.zeros_like(X), I, J, 8),                  # all positions equal
        (X, I[:0], J[:0], 8),                         # no edges at all
        (X, I, J, 10 * n),                            # one leaf
        (X[:, [0, 0, 2]], np.r_[I, np.arange(n)], np.r_[J, np.arange(n)], 5),  # self-loops
        (rng.standard_normal((n, 3)), I, J, 16),     # positions unrelated to the graph
    ]:
        order = nested_dissection(Xc, Ic, Jc, leaf=leaf)
        assert order.dtype == np.int64
        assert np.array_equal(np.sort(order), np.arange(n))


@needs_cholmod
def test_nested_dissection_reduces_fill_on_a_grid():
    # row-major (natural) order of a 100x100 grid: a band of width 100, fill ~ n*100; nested
    # dissection: O(n log n); AMD (CHOLMOD's default) as the practical reference: on plain
    # grids it wins below ~90k nodes (measured 1.15x less fill here, 1.04x at 40k, and 0.97x
    # at 90k); on the Gauss–Newton graph of the 154k-vertex cactus nested dissection fills 15 %
    # less. (CHOLMOD itself analyses a given order and AMD and keeps the better one.)
    import cvxopt
    import cvxopt.amd

    X, I, J = _grid_graph(100, 100)
    n = len(X)
    natural = _factor_nnz(n, I, J, np.arange(n))
    nd = _factor_nnz(n, I, J, nested_dissection(X, I, J))
    assert nd < 0.4 * natural
    A = sp.tril(sp.coo_matrix((np.ones(len(I)), (J, I)), shape=(n, n)) + sp.eye(n), format="coo")
    amd = np.array(cvxopt.amd.order(cvxopt.spmatrix(A.data.tolist(), A.row.tolist(),
                                                    A.col.tolist(), size=(n, n)))).ravel()
    assert nd <= 1.25 * _factor_nnz(n, I, J, amd)


@needs_cholmod
def test_cholesky_with_a_given_order_solves():
    X, I, J = _grid_graph(12, 9)
    n = len(X)
    A = sp.coo_matrix((-np.ones(len(I)), (I, J)), shape=(n, n))
    A = (A + A.T).tocsc()
    A = (A + sp.diags(1.5 + np.asarray(abs(A).sum(axis=1)).ravel() + np.arange(n) % 3)).tocsc()
    L = sp.tril(A, format="csc")
    L.sort_indices()
    b = np.random.default_rng(2).standard_normal(n)
    ref = sp.linalg.spsolve(A, b)
    C = SparseCholesky.from_lower_pattern(L.indptr, L.indices, n, L.data, backend="cholmod",
                                          perm=nested_dissection(X, I, J, leaf=4))
    assert np.allclose(C.solve(b), ref, rtol=1e-12, atol=1e-12)
    C.refactor_lower(2.0 * L.data)  # the kept pattern and order serve new values
    assert np.allclose(C.solve(b), 0.5 * ref, rtol=1e-12, atol=1e-12)
    with pytest.raises(ValueError, match="permutation"):
        SparseCholesky.from_lower_pattern(L.indptr, L.indices, n, L.data, backend="cholmod",
                                          perm=np.zeros(n, dtype=int))


@needs_cholmod
def test_nested_dissection_solver_finds_the_amd_minimiser():
    # the large-mesh configuration (nd ordering, rotated factor reused over a run of frames)
    # against the small-mesh one (AMD, fresh factor at every step, no rotation)
    Vs, T, pinned, Z, w, frames = cactus_sequence_problem(900)
    opts = dict(gtol=1e-9, ftol=1e-13)
    nd = GaussNewton(T, pinned=pinned, ordering="nd", rotate_preconditioner=True,
                     amortize_refresh=True, **opts)
    amd = GaussNewton(T, pinned=pinned, ordering="amd", refresh_cg=0,
                      rotate_preconditioner=False, **opts)
    v = Vs[0]
    scale = np.abs(Vs[0]).max()
    for k in range(1, frames[1]):
        a, b = nd.solve(Z[k], w, v), amd.solve(Z[k], w, v)
        assert a.success and b.success, (a.message, b.message)
        assert np.abs(a.V - b.V).max() < 1e-6 * scale
        assert abs(a.energy - b.energy) <= 1e-6 * b.energies[0]
        v = a.V
    assert nd._perm is not None and amd._perm is None
    assert np.array_equal(np.sort(nd._perm), np.arange(3 * T.n_vertices))
    assert nd._perm.reshape(-1, 3).tolist() == \
        (3 * (nd._perm[::3] // 3)[:, None] + np.arange(3)).tolist()  # a vertex's DOFs together
    with pytest.raises(ValueError, match="ordering"):
        GaussNewton(T, ordering="metis")


def test_small_meshes_keep_the_small_mesh_path():
    V, F = icosphere(1)
    gn = GaussNewton(topology(F))
    assert gn.ordering == "amd" and not gn.amortize_refresh and not gn.rotate_preconditioner


@needs_cholmod
def test_amortized_refresh_refactors_when_a_frame_costs_more_than_the_average():
    from shellspline.shells.descriptors import lta_descriptors, lta_weights

    V, F = icosphere(3)
    T = topology(F)
    z, w = lta_descriptors(V * [1.0, 1.1, 0.95], T), lta_weights(V, T, eta=1e-2)
    for amortize in (True, False):
        gn = GaussNewton(T, amortize_refresh=amortize, refresh_cg=10, gtol=1e-8, ftol=1e-14)
        first = gn.solve(z, w, V)
        assert first.success and first.factorizations == 1  # at its first step
        # bookkeeping of the factor's cycle: cost 10 (the factorization) + its CG iterations
        assert gn._cycle == [10.0 + first.cg_iterations, 1]
        for last_cg, cycle, expect in ((6, [10.0, 2], 1), (4, [10.0, 2], 0)):
            gn._last_cg, gn._cycle = last_cg, list(cycle)
            # near the solution: a step or two, none needing the old rule (CG > refresh_cg)
            res = gn.solve(z, w, first.V + 1e-5 * np.sin(np.arange(first.V.size)).reshape(-1, 3))
            assert res.success
            assert res.factorizations == (expect if amortize else 0), (last_cg, cycle)



def test_rotations_fitted_once_per_frame_unless_the_pose_moves(monkeypatch):
    # small Gauss–Newton corrections inside a frame: the rotations from the frame's start are
    # kept (refitting them to such corrections made CG slower at 150k vertices); a large
    # move (here: a start far from the solution) refits them
    from shellspline.shells.descriptors import lta_descriptors, lta_weights
    import importlib

    rc = importlib.import_module("shellspline.shells.reconstruct")

    calls = []
    orig = rc.GaussNewton._rotations

    def counting(self, x):
        calls.append(x.copy())
        return orig(self, x)

    monkeypatch.setattr(rc.GaussNewton, "_rotations", counting)
    V, F = icosphere(3)
    T = topology(F)
    V1 = V * [1.0, 1.2, 0.9]
    z, w = lta_descriptors(V1, T), lta_weights(V, T, eta=1e-2)
    gn = GaussNewton(T, rotate_preconditioner=True, gtol=1e-10, ftol=1e-14)
    first = gn.solve(z, w, V)              # factor at V, then steps of size ~ the stretch
    assert first.success and first.factorizations >= 1
    calls.clear()
    th = 0.02
    Q = np.array([[np.cos(th), -np.sin(th), 0], [np.sin(th), np.cos(th), 0], [0, 0, 1]])
    # a rotated, slightly perturbed solution: small corrections only
    second = gn.solve(z, w, first.V @ Q.T + 1e-5 * np.cos(np.arange(first.V.size)).reshape(-1, 3))
    assert second.success and second.nit >= 2 and second.factorizations == 0
    assert len(calls) == 1                  # one fit for the whole frame
    # the refit threshold: a quarter of the mean edge length of the factored pose
    h = np.mean(np.linalg.norm(gn._x_fact.reshape(-1, 3)[T.E[:, 1]] -
                               gn._x_fact.reshape(-1, 3)[T.E[:, 0]], axis=1))
    x = second.V.ravel().copy()
    for frac, moved in ((0.2, False), (0.3, True)):
        y = x.copy()
        y[3 * 17 + 1] += frac * h  # one vertex
        assert gn._moved(y, x) is moved
    assert not GaussNewton(T, rotate_preconditioner=False)._moved(x + 1.0, x)


def test_spline_rows_equal_the_spline():
    from shellspline.shells.lta_spline import lta_spline
    from shellspline.pipeline.describe import SplineRows as _SplineRows

    Zk = np.random.default_rng(3).standard_normal((3, 50))
    for bc, frames, K in (("natural", [0, 4, 9], 11), ("periodic", [0, 3, 7], 10)):
        Z = lta_spline(Zk, frames, K, bc=bc)
        rows = _SplineRows(lta_spline(np.eye(3), frames, K, bc=bc), Zk)
        assert rows.shape == Z.shape and len(rows) == K + 1
        assert np.allclose(rows[:], Z, rtol=0, atol=1e-13 * np.abs(Z).max())
        assert np.allclose(rows[5], Z[5], rtol=0, atol=1e-13 * np.abs(Z).max())
        assert np.allclose(rows[np.array([1, 2])], Z[[1, 2]], rtol=0,
                           atol=1e-13 * np.abs(Z).max())
        assert np.array_equal(rows[np.array(frames)], Zk)  # keyframes exact


@needs_cholmod
def test_analysis_survives_a_matrix_that_is_not_positive_definite():
    """``numeric=False`` analyses the pattern only; a shift that is not positive definite
    raises in :meth:`refactor_lower` and the next shift reuses the same analysis (the
    geodesic's damping search repeated the analysis on every failed try: 17 analyses in
    the coarse horse's first Newton step)."""
    rng = np.random.default_rng(3)
    n = 40
    B = sp.random(n, n, density=0.1, random_state=4) + sp.eye(n)
    A = (B + B.T).tocsc()                                  # symmetric, indefinite
    L = sp.tril(A, format="csc")
    L.sort_indices()
    diag = np.flatnonzero(L.indices == np.repeat(np.arange(n), np.diff(L.indptr)))
    C = SparseCholesky.from_lower_pattern(L.indptr, L.indices, n, L.data, backend="cholmod",
                                          numeric=False)
    sym = C._symbolic
    assert C.n_factorizations == 0 and sym is not None
    with pytest.raises(ArithmeticError):
        C.refactor_lower(L.data)
    shift = 1.0 + float(np.abs(np.linalg.eigvalsh(A.toarray())).max())
    data = L.data.copy()
    data[diag] += shift
    C.refactor_lower(data)
    assert C._symbolic is sym and C.n_factorizations == 1
    b = rng.standard_normal(n)
    assert np.allclose(C.solve(b), np.linalg.solve(A.toarray() + shift * np.eye(n), b),
                       rtol=1e-10, atol=1e-12)

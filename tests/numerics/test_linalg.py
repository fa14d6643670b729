"""shellspline.numerics.linalg.SparseCholesky against scipy's sparse LU."""
from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from shellspline.numerics.linalg import SparseCholesky, available_backends


def _spd(n=60, seed=0):
    rng = np.random.default_rng(seed)
    B = sp.random(n, n, density=0.08, random_state=seed) + sp.eye(n)
    A = (B.T @ B + sp.eye(n)).tocoo()
    # the same matrix with every entry split in two COO duplicates and explicit zeros added
    # at (i + 7, i) and (i, i + 7)
    k, z = len(A.data), np.arange(5)
    half = A.data * rng.uniform(0.2, 0.8, k)
    dup = sp.coo_matrix((np.r_[half, A.data - half, np.zeros(10)],
                         (np.r_[A.row, A.row, z + 7, z], np.r_[A.col, A.col, z, z + 7])),
                        shape=A.shape)
    return A.tocsc(), dup, rng


@pytest.mark.parametrize("backend", available_backends())
def test_factor_and_refactor_solve_like_splu(backend):
    A, dup, rng = _spd()
    b = rng.standard_normal((A.shape[0], 2))
    C = SparseCholesky(dup, backend=backend)  # duplicates summed, zeros kept in the pattern
    np.testing.assert_allclose(C.solve(b), spla.splu(A).solve(b), rtol=1e-10, atol=1e-12)
    # new values on the same pattern (the explicit zeros of the first matrix now nonzero)
    A2 = (A + sp.coo_matrix((np.full(5, 0.3), (np.arange(5), np.arange(5) + 7)), shape=A.shape)
          + sp.coo_matrix((np.full(5, 0.3), (np.arange(5) + 7, np.arange(5))), shape=A.shape)
          + 2.0 * sp.eye(A.shape[0])).tocsc()
    C.refactor(A2)
    assert C.n_factorizations == 2
    np.testing.assert_allclose(C.solve(b[:, 0]), spla.splu(A2).solve(b[:, 0]), rtol=1e-10,
                               atol=1e-12)

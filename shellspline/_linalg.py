"""Sparse symmetric positive-definite factorization with reusable symbolic analysis.

Backends, picked in this order when ``backend="auto"``:

- ``cholmod``: CHOLMOD through ``cvxopt.cholmod`` (optional extra ``shellspline[fast]``),
  symbolic analysis once, numeric refactorization per call to :meth:`refactor`;
- ``splu``: scipy's SuperLU with the ``MMD_AT_PLUS_A`` ordering and symmetric mode (always
  available; the column ordering is recomputed on each factorization).
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

__all__ = ["SparseCholesky", "available_backends"]


def _has_cholmod() -> bool:
    try:
        import cvxopt  # noqa: F401
        import cvxopt.cholmod  # noqa: F401
    except Exception:  # pragma: no cover - depends on the environment
        return False
    return True


def available_backends() -> list[str]:
    """Factorization backends usable in this environment, fastest first."""
    return (["cholmod"] if _has_cholmod() else []) + ["splu"]


class SparseCholesky:
    """Factor ``A`` (sparse SPD) and solve ``A x = b``; refactor with the same pattern cheaply.

    Parameters
    ----------
    A : (N,N) scipy.sparse matrix
        Symmetric positive definite. Only its sparsity pattern is analysed once.
    backend : {"auto", "cholmod", "splu"}

    Examples
    --------
    >>> import scipy.sparse as sp, numpy as np
    >>> A = sp.diags([[-1.0] * 4, [4.0] * 5, [-1.0] * 4], [-1, 0, 1]).tocsc()
    >>> C = SparseCholesky(A)
    >>> bool(np.allclose(A @ C.solve(np.ones(5)), 1.0))
    True
    """

    def __init__(self, A, backend: str = "auto"):
        backend = str(backend).lower()
        if backend == "auto":
            backend = available_backends()[0]
        if backend not in ("cholmod", "splu"):
            raise ValueError(f"`backend` must be 'auto', 'cholmod' or 'splu', got {backend!r}")
        if backend == "cholmod" and not _has_cholmod():
            raise ImportError("backend='cholmod' needs cvxopt: pip install 'shellspline[fast]'")
        self.backend = backend
        self.n_factorizations = 0
        self._symbolic = None
        self.refactor(A)

    def _scatter(self, A) -> np.ndarray:
        """Values of ``A``'s lower triangle laid out on the pattern analysed at construction."""
        Al = sp.tril(A, format="coo")
        Al.sum_duplicates()
        keys = Al.col.astype(np.int64) * A.shape[0] + Al.row
        pos = np.searchsorted(self._keys, keys)
        pos = np.minimum(pos, len(self._keys) - 1)
        if not np.array_equal(self._keys[pos], keys):
            raise ValueError("the matrix has entries outside the sparsity pattern analysed at "
                             "construction (build it on a fixed structural pattern)")
        data = np.zeros(len(self._keys))
        np.add.at(data, pos, Al.data)
        return data

    def refactor(self, A) -> None:
        """Numeric factorization of ``A``.

        ``A``'s nonzeros must lie within the pattern of the matrix given at construction
        (explicit zeros there count as part of the pattern); the symbolic analysis is reused.
        """
        A = sp.csc_matrix(A)
        if self.backend == "cholmod":
            import cvxopt
            import cvxopt.cholmod

            if self._symbolic is None:
                Al = sp.tril(A, format="csc")
                Al.sort_indices()
                cols = np.repeat(np.arange(A.shape[1]), np.diff(Al.indptr))
                self._keys = cols.astype(np.int64) * A.shape[0] + Al.indices
                order = np.argsort(self._keys)
                self._keys = self._keys[order]
                self._I = cvxopt.matrix((self._keys % A.shape[0]).astype(np.int64))
                self._J = cvxopt.matrix((self._keys // A.shape[0]).astype(np.int64))
            data = self._scatter(A)
            M = cvxopt.spmatrix(cvxopt.matrix(data), self._I, self._J, size=A.shape)
            cvxopt.cholmod.options["supernodal"] = 2
            if self._symbolic is None:
                self._symbolic = cvxopt.cholmod.symbolic(M, uplo="L")
            cvxopt.cholmod.numeric(M, self._symbolic)
        else:
            self._lu = spla.splu(A, permc_spec="MMD_AT_PLUS_A",
                                 options={"SymmetricMode": True}, diag_pivot_thresh=0.0)
        self.n_factorizations += 1

    @classmethod
    def from_lower_pattern(cls, indptr, indices, n: int, data, backend: str = "auto"):
        """Factor a matrix given by its lower triangle in CSC form on a fixed pattern.

        Later calls to :meth:`refactor_lower` pass new values for the same pattern (explicit
        zeros included), so no pattern lookup is needed at all.
        """
        indptr, indices = np.asarray(indptr), np.asarray(indices)
        backend = str(backend).lower()
        if backend == "auto":
            backend = available_backends()[0]
        obj = cls.__new__(cls)
        obj.backend, obj.n_factorizations, obj._symbolic = backend, 0, None
        obj._lower = (indptr, indices, n)
        if backend == "cholmod":
            import cvxopt

            cols = np.repeat(np.arange(n, dtype=np.int64), np.diff(indptr))
            obj._I = cvxopt.matrix(indices.astype(np.int64))
            obj._J = cvxopt.matrix(cols)
        elif backend != "splu":
            raise ValueError(f"`backend` must be 'auto', 'cholmod' or 'splu', got {backend!r}")
        obj.refactor_lower(data)
        return obj

    def refactor_lower(self, data) -> None:
        """Numeric refactorization from lower-triangle values on the pattern of
        :meth:`from_lower_pattern` (same order)."""
        indptr, indices, n = self._lower
        data = np.asarray(data, dtype=np.float64)
        if self.backend == "cholmod":
            import cvxopt
            import cvxopt.cholmod

            # the pattern's CSC order equals the sorted key order used at construction, so
            # later refactorizations only swap the values (building from triplets sorts)
            M = getattr(self, "_M", None)
            if M is None:
                M = self._M = cvxopt.spmatrix(cvxopt.matrix(data), self._I, self._J,
                                              size=(n, n))
            else:
                M.V = cvxopt.matrix(data)
            if self._symbolic is None:
                cvxopt.cholmod.options["supernodal"] = 2
                self._symbolic = cvxopt.cholmod.symbolic(M, uplo="L")
            cvxopt.cholmod.numeric(M, self._symbolic)
            self.n_factorizations += 1
        else:
            L = sp.csc_matrix((data, indices, indptr), shape=(n, n))
            self.refactor(L + sp.tril(L, -1).T)

    def solve(self, b: np.ndarray) -> np.ndarray:
        """Solve ``A x = b`` for a vector or a column block ``b``."""
        if self.backend == "cholmod":
            import cvxopt
            import cvxopt.cholmod

            B = cvxopt.matrix(np.array(b, dtype=np.float64, order="F", copy=True))
            cvxopt.cholmod.solve(self._symbolic, B)
            return np.array(B).reshape(np.shape(b))
        return self._lu.solve(np.asarray(b, dtype=np.float64))

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

from ..errors import ShellsplineError

__all__ = ["SparseCholesky", "available_backends", "nested_dissection"]


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
            raise ShellsplineError(f"`backend` must be 'auto', 'cholmod' or 'splu', got "
                                   f"{backend!r}")
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
                # canonical CSC (rows sorted in each column, no duplicates): the keys
                # col*N + row ascend, and the values are already laid out on the pattern
                Al = sp.tril(A, format="csc")
                Al.sum_duplicates()
                cols = np.repeat(np.arange(A.shape[1]), np.diff(Al.indptr))
                self._keys = cols.astype(np.int64) * A.shape[0] + Al.indices
                self._I = cvxopt.matrix(Al.indices.astype(np.int64))
                self._J = cvxopt.matrix(cols.astype(np.int64))
                data = np.asarray(Al.data, dtype=np.float64)
            else:
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
    def from_lower_pattern(cls, indptr, indices, n: int, data, backend: str = "auto",
                           perm=None, numeric: bool = True):
        """Factor a matrix given by its lower triangle in CSC form on a fixed pattern.

        Later calls to :meth:`refactor_lower` pass new values for the same pattern (explicit
        zeros included), so no pattern lookup is needed at all. ``perm`` ((n,) int array,
        optional): fill-reducing elimination order for the ``cholmod`` backend (e.g. from
        :func:`nested_dissection`); CHOLMOD compares it with its AMD order and keeps the one
        with less fill (default: AMD only). The ``splu`` backend ignores it.
        ``numeric=False`` only analyses the pattern (``cholmod``): the first
        :meth:`refactor_lower` factors, and a matrix that turns out not to be positive
        definite there does not cost the analysis (a damping search tries several shifts).
        """
        indptr, indices = np.asarray(indptr), np.asarray(indices)
        backend = str(backend).lower()
        if backend == "auto":
            backend = available_backends()[0]
        obj = cls.__new__(cls)
        obj.backend, obj.n_factorizations, obj._symbolic = backend, 0, None
        obj._lower = (indptr, indices, n)
        obj._perm = None if perm is None else np.asarray(perm, dtype=np.int64)
        if obj._perm is not None and not np.array_equal(np.sort(obj._perm), np.arange(n)):
            raise ValueError(f"`perm` must be a permutation of 0..{n - 1}")
        if backend == "cholmod":
            import cvxopt

            cols = np.repeat(np.arange(n, dtype=np.int64), np.diff(indptr))
            obj._I = cvxopt.matrix(indices.astype(np.int64))
            obj._J = cvxopt.matrix(cols)
        elif backend != "splu":
            raise ShellsplineError(f"`backend` must be 'auto', 'cholmod' or 'splu', got "
                                   f"{backend!r}")
        if numeric or backend != "cholmod":
            obj.refactor_lower(data)
        else:
            obj._analyse(np.asarray(data, dtype=np.float64))
        return obj

    def refactor_lower(self, data) -> None:
        """Numeric refactorization from lower-triangle values on the pattern of
        :meth:`from_lower_pattern` (same order)."""
        indptr, indices, n = self._lower
        data = np.asarray(data, dtype=np.float64)
        if self.backend == "cholmod":
            import cvxopt
            import cvxopt.cholmod

            M = self._analyse(data)
            cvxopt.cholmod.numeric(M, self._symbolic)
            self.n_factorizations += 1
        else:
            L = sp.csc_matrix((data, indices, indptr), shape=(n, n))
            self.refactor(L + sp.tril(L, -1).T)

    def _analyse(self, data):
        """The CHOLMOD matrix of the lower pattern holding ``data``, and the symbolic
        analysis of its pattern (once)."""
        import cvxopt
        import cvxopt.cholmod

        n = self._lower[2]
        # the pattern's CSC order equals the sorted key order used at construction, so
        # later refactorizations only swap the values (building from triplets sorts)
        M = getattr(self, "_M", None)
        if M is None:
            M = self._M = cvxopt.spmatrix(cvxopt.matrix(data), self._I, self._J, size=(n, n))
            # M holds its own copy of the pattern: the triplet indices (int64, 16 bytes
            # per entry, ~150 MB at 150k vertices) are not needed any more
            self._I = self._J = None
        else:
            M.V = cvxopt.matrix(data)
        if self._symbolic is None:
            cvxopt.cholmod.options["supernodal"] = 2
            perm = getattr(self, "_perm", None)
            self._symbolic = cvxopt.cholmod.symbolic(M, uplo="L") if perm is None else \
                cvxopt.cholmod.symbolic(M, p=cvxopt.matrix(perm), uplo="L")
        return M

    def solve(self, b: np.ndarray) -> np.ndarray:
        """Solve ``A x = b`` for a vector or a column block ``b``."""
        if self.backend == "cholmod":
            import cvxopt
            import cvxopt.cholmod

            B = cvxopt.matrix(np.array(b, dtype=np.float64, order="F", copy=True))
            cvxopt.cholmod.solve(self._symbolic, B)
            return np.array(B).reshape(np.shape(b))
        return self._lu.solve(np.asarray(b, dtype=np.float64))


#: Unit split directions tried by :func:`nested_dissection` in every subdomain (besides its
#: two principal axes): the coordinate axes and the four body diagonals.
_ND_DIRECTIONS = np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1], [1, 1, -1], [1, -1, 1],
                           [-1, 1, 1]], dtype=np.float64)
_ND_DIRECTIONS /= np.linalg.norm(_ND_DIRECTIONS, axis=1, keepdims=True)


def nested_dissection(X, I, J, leaf: int = 64) -> np.ndarray:
    """Geometric nested-dissection elimination order of a graph whose nodes have positions.

    Every subdomain with more than ``leaf`` nodes is split at the median of its nodes along
    the direction (coordinate axes, body diagonals, its two principal axes) that gives the
    smallest separator; the separator is the smaller of the two one-sided boundaries of the
    cut (the endpoints of the cut edges on one side). All subdomains of one level are split
    together (vectorised, about 15 levels at 150 000 nodes). Order: the leaves, then the
    separators from the deepest level up, so every separator comes after both of its halves.

    On large mesh graphs this fills less than minimum degree: the 154k-vertex synthetic
    cactus (graph of ``Jᵀ W J``, 463 878 DOFs) factors with 208M nonzeros in ``L`` against
    246M with CHOLMOD's AMD, numerically 1.5x faster, triangular solves 13 % faster (METIS,
    not a dependency, would give 169M). On small ones AMD wins (a 100x100 grid: 1.15x less
    fill than this); CHOLMOD, given an order, also analyses its own AMD order and keeps the
    one with less fill, so passing this order never makes a factor larger.

    Parameters
    ----------
    X : (n,3) float array
        Node positions (only used to pick the cuts).
    I, J : (k,) int arrays
        Edges of the (symmetric) graph, each given once or twice; self-loops are ignored.
    leaf : int
        Subdomain size at which the dissection stops.

    Returns
    -------
    (n,) int64 array
        Elimination order (``order[i]`` is the node eliminated ``i``-th).
    """
    X = np.asarray(X, dtype=np.float64)
    n = len(X)
    I, J = np.asarray(I, dtype=np.int64), np.asarray(J, dtype=np.int64)
    keep = I != J
    ei, ej = I[keep], J[keep]
    part = np.zeros(n, dtype=np.int64)  # subdomain of every node at the current level
    active = np.ones(n, dtype=bool)     # not yet in a separator or a finished leaf
    level = np.full(n, np.iinfo(np.int64).max)  # separator depth; leaves keep the maximum
    depth, ndom = 0, 1
    while True:
        ids = np.flatnonzero(active)
        if not len(ids):
            break
        dom = part[ids]
        counts = np.bincount(dom, minlength=ndom)
        big = counts > leaf
        active[ids[~big[dom]]] = False  # finished leaves
        if not big.any():
            break
        start = np.concatenate([[0], np.cumsum(counts)])
        inner = active[ei] & active[ej] & (part[ei] == part[ej]) & big[part[ei]]
        a, b = ei[inner], ej[inner]
        # candidate directions per subdomain: fixed ones and the two principal axes
        Xi = X[ids]
        cnt = np.maximum(counts, 1)[:, None]
        mean = np.stack([np.bincount(dom, Xi[:, c], minlength=ndom) for c in range(3)], 1) / cnt
        Y = Xi - mean[dom]
        C = np.stack([np.bincount(dom, Y[:, r] * Y[:, c], minlength=ndom)
                      for r in range(3) for c in range(3)], 1).reshape(-1, 3, 3)
        _, axes = np.linalg.eigh(C)
        directions = [np.broadcast_to(d, (ndom, 3)) for d in _ND_DIRECTIONS] + \
            [axes[:, :, 2], axes[:, :, 1]]
        best_cost = np.full(ndom, np.inf)
        best_side = np.zeros(n, dtype=bool)
        best_sep = np.zeros(n, dtype=bool)
        for D in directions:
            coord = np.einsum("ij,ij->i", Xi, D[dom])
            o = np.lexsort((coord, dom))
            rank = np.empty(len(ids), dtype=np.int64)
            rank[o] = np.arange(len(ids)) - start[dom[o]]
            side = np.zeros(n, dtype=bool)
            side[ids] = rank >= counts[dom] // 2
            cut = side[a] != side[b]
            ca, cb = a[cut], b[cut]
            s1 = np.zeros(n, dtype=bool)
            s1[np.where(side[ca], ca, cb)] = True
            s0 = np.zeros(n, dtype=bool)
            s0[np.where(side[ca], cb, ca)] = True
            c1 = np.bincount(part[s1], minlength=ndom)
            c0 = np.bincount(part[s0], minlength=ndom)
            sep = np.where((c0 < c1)[part], s0, s1)
            cost = np.minimum(c0, c1)
            better = (cost < best_cost)[part]
            best_side = np.where(better, side, best_side)
            best_sep = np.where(better, sep, best_sep)
            best_cost = np.minimum(cost, best_cost)
        sep = np.flatnonzero(best_sep & active)
        level[sep] = depth
        active[sep] = False
        part = 2 * part + best_side
        ndom *= 2
        depth += 1
    # leaves (maximal level) first, grouped by subdomain, then separators deepest first
    return np.lexsort((part, -level)).astype(np.int64)

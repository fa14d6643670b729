"""Lie groups as small objects that curve algorithms use generically.

A group object knows the trailing ``shape`` of its elements, the dimension ``dim`` of its
tangent vectors (left-trivialised: a velocity at ``g`` is ``g^{-1} dg/dt``, a vector in
``R^dim``) and five operations: ``compose``, ``inverse``, ``exp``, ``log`` and, for
derivatives, ``adjoint`` and the right Jacobian of ``exp``. Curves built from
``interp(a, b, s) = a exp(s log(a^{-1} b))`` are the geodesics of the group's metric.

=================  =====================  =====================================================
group              elements               metric / geodesics
=================  =====================  =====================================================
``SO3``            ``(..., 3, 3)``        bi-invariant; great circles
``SE3``            ``(..., 4, 4)``        Ad-invariant ("screw"); screw motions; bi-invariant
                                          curves (seed 002 section 5.2.1, corollary 4.2.7)
``SO3xR3``         ``(..., 4, 4)``        product ("double geodesic"): rotation and position
                                          interpolated separately (section 5.2.2). Curves are
                                          invariant under a change of world frame, not under a
                                          change of body frame.
``SO3dR3(d)``      ``(..., 9 d + 3)``     product SO(3)^d x R^3 (skeletons: d joint rotations
                                          and a root position); :meth:`SO3dR3.pack`.
=================  =====================  =====================================================

``SO3xR3`` composes as the direct product ``(R1 R2, p1 + p2)``: that is the group in which its
curves are left-invariant geodesic constructions. Its elements are ordinary poses, so
``SE3.compose`` is the operation to use when moving a curve of either group in space.
"""
from __future__ import annotations

from abc import ABC, abstractmethod

import numpy as np

from ..errors import ShellsplineError
from . import kernel as _kernel
from . import se3, so3

__all__ = ["LieGroup", "SO3", "SE3", "SO3xR3", "SO3dR3", "group", "karcher_mean"]


class LieGroup(ABC):
    """Base class: the generic operations built from the group's primitives (the abstract
    methods, which every concrete group implements)."""

    name = "group"
    shape: tuple = ()
    dim = 0

    # --- primitives (subclasses) ---------------------------------------------------------
    @abstractmethod
    def compose(self, a, b):  # pragma: no cover - abstract
        ...

    @abstractmethod
    def inverse(self, a):  # pragma: no cover - abstract
        ...

    @abstractmethod
    def exp(self, xi):  # pragma: no cover - abstract
        ...

    @abstractmethod
    def log(self, g):  # pragma: no cover - abstract
        ...

    @abstractmethod
    def adjoint(self, g, xi):  # pragma: no cover - abstract
        """``Ad_g xi``: the space-frame vector of the body-frame velocity ``xi`` at ``g``."""
        ...

    @abstractmethod
    def jac_right(self, xi, x):  # pragma: no cover - abstract
        """``J_r(xi) x`` with ``exp(xi)^{-1} d/dt exp(xi(t)) = J_r(xi) xi'``."""
        ...

    @abstractmethod
    def jac_right_inv(self, xi, x):  # pragma: no cover - abstract
        ...

    def kernel(self):
        """The component-first fast kernel of this group (see :mod:`shellspline.groups.kernel`),
        or None (evaluators then use the matrix operations)."""
        return None

    def rotation_angle(self, xi):
        """The largest rotation angle (radians) in tangent vectors ``xi (..., dim)``: ``(...)``.
        Geodesic constructions need it below pi between consecutive points."""
        xi = np.asarray(xi, dtype=np.float64)
        w = xi[..., :3 * self.n_rotations].reshape(xi.shape[:-1] + (self.n_rotations, 3))
        return np.sqrt(np.einsum("...i,...i->...", w, w)).max(axis=-1)

    n_rotations = 1

    def identity(self, lead=()):
        """Identity elements of shape ``lead + shape``."""
        return self.exp(np.zeros(tuple(lead) + (self.dim,)))

    # --- derived -------------------------------------------------------------------------
    def between(self, a, b):
        """``log(a^{-1} b)``: the tangent vector at ``a`` of the geodesic from ``a`` to ``b``."""
        return self.log(self.compose(self.inverse(a), b))

    def interp(self, a, b, s):
        """Geodesic interpolant ``a exp(s log(a^{-1} b))`` (seed 002 definition 4.1.1).

        Parameters
        ----------
        a, b : (..., *shape) array_like
        s : (...) array_like
            Fractions; ``s`` outside ``[0, 1]`` extrapolates along the geodesic.
        """
        s = np.asarray(s, dtype=np.float64)
        return self.compose(a, self.exp(s[..., None] * self.between(a, b)))

    def distance(self, a, b):
        """Norm of ``log(a^{-1} b)`` (for the product groups, rotations in radians and
        translations in length units added in quadrature)."""
        v = self.between(a, b)
        return np.sqrt(np.einsum("...i,...i->...", v, v))

    def check(self, g, name="g", atol=1e-6):
        """Validate an array of elements; returns it as float64 or raises
        :class:`ShellsplineError` naming ``name`` and what was wrong."""
        g = np.asarray(g, dtype=np.float64)
        k = len(self.shape)
        if g.ndim < k or g.shape[g.ndim - k:] != tuple(self.shape):
            dims = ", ".join(map(str, self.shape))
            raise ShellsplineError(f"{name} must have shape (..., {dims}) for {self.name}, got "
                                   f"{g.shape}")
        if not np.all(np.isfinite(g)):
            raise ShellsplineError(f"{name} contains non-finite values")
        for R, what in self._rotations(g):
            err = np.abs(R @ np.swapaxes(R, -1, -2) - np.eye(3)).max(axis=(-1, -2))
            det = np.linalg.det(R)
            bad = (err > atol) | (det < 0)
            if np.any(bad):
                i = np.argwhere(bad)[0]
                raise ShellsplineError(f"{name}{list(map(int, i))}: {what} is not a rotation "
                                       f"(|R R^T - I| = {err[tuple(i)]:.2g}, det = "
                                       f"{det[tuple(i)]:.3g})")
        return g

    def _rotations(self, g):
        return []

    def __repr__(self):
        return self.name


class _SO3(LieGroup):
    name, shape, dim = "SO3", (3, 3), 3

    def compose(self, a, b):
        return np.matmul(a, b)

    def inverse(self, a):
        return np.swapaxes(np.asarray(a, dtype=np.float64), -1, -2)

    def exp(self, xi):
        return so3.exp(xi)

    def log(self, g):
        return so3.log(g)

    def adjoint(self, g, xi):
        return np.einsum("...ij,...j->...i", g, xi)

    def jac_right(self, xi, x):
        return so3.jac_right(xi, x)

    def jac_right_inv(self, xi, x):
        return so3.jac_right_inv(xi, x)

    def _rotations(self, g):
        return [(g, "the matrix")]

    def kernel(self):
        return _kernel.SO3Kernel()


class _SE3(LieGroup):
    name, shape, dim = "SE3", (4, 4), 6

    def compose(self, a, b):
        return np.matmul(a, b)

    def inverse(self, a):
        return se3.inverse(a)

    def exp(self, xi):
        return se3.exp(xi)

    def log(self, g):
        return se3.log(g)

    def adjoint(self, g, xi):
        return se3.adjoint(g, xi)

    def jac_right(self, xi, x):
        return se3.jac_right(xi, x)

    def jac_right_inv(self, xi, x):
        return se3.jac_right_inv(xi, x)

    def check(self, g, name="g", atol=1e-6):
        g = super().check(g, name, atol)
        bottom = np.abs(g[..., 3, :] - [0, 0, 0, 1]).max(axis=-1)
        if np.any(bottom > atol):
            i = np.argwhere(bottom > atol)[0]
            raise ShellsplineError(f"{name}{list(map(int, i))}: the last row of a rigid motion "
                                   f"must be [0, 0, 0, 1], got {g[tuple(i)][3].tolist()}")
        return g

    def _rotations(self, g):
        return [(g[..., :3, :3], "the rotation block")]

    def kernel(self):
        return _kernel.SE3Kernel()


class _SO3xR3(_SE3):
    name, shape, dim = "SO3xR3", (4, 4), 6

    def compose(self, a, b):
        a = np.asarray(a, dtype=np.float64)
        b = np.asarray(b, dtype=np.float64)
        return se3.from_rt(a[..., :3, :3] @ b[..., :3, :3], a[..., :3, 3] + b[..., :3, 3])

    def inverse(self, a):
        a = np.asarray(a, dtype=np.float64)
        return se3.from_rt(np.swapaxes(a[..., :3, :3], -1, -2), -a[..., :3, 3])

    def exp(self, xi):
        xi = np.asarray(xi, dtype=np.float64)
        return se3.from_rt(so3.exp(xi[..., :3]), xi[..., 3:])

    def log(self, g):
        g = np.asarray(g, dtype=np.float64)
        return np.concatenate([so3.log(g[..., :3, :3]), g[..., :3, 3]], axis=-1)

    def adjoint(self, g, xi):
        xi = np.asarray(xi, dtype=np.float64)
        Rw = np.einsum("...ij,...j->...i", np.asarray(g)[..., :3, :3], xi[..., :3])
        return np.concatenate([Rw, np.broadcast_to(xi[..., 3:], Rw.shape)], axis=-1)

    def jac_right(self, xi, x):
        x = np.asarray(x, dtype=np.float64)
        r = so3.jac_right(np.asarray(xi)[..., :3], x[..., :3])
        return np.concatenate([r, np.broadcast_to(x[..., 3:], r.shape)], axis=-1)

    def jac_right_inv(self, xi, x):
        x = np.asarray(x, dtype=np.float64)
        r = so3.jac_right_inv(np.asarray(xi)[..., :3], x[..., :3])
        return np.concatenate([r, np.broadcast_to(x[..., 3:], r.shape)], axis=-1)

    def kernel(self):
        return _kernel.SO3xR3Kernel()


class SO3dR3(LieGroup):
    """The product group SO(3)^d x R^3 (a skeleton: ``d`` joint rotations and a root
    position), elements packed as flat ``(..., 9 d + 3)`` arrays.

    Parameters
    ----------
    d : int
        Number of rotations (>= 1).

    Examples
    --------
    >>> import numpy as np
    >>> G = SO3dR3(2)
    >>> g = G.pack(np.stack([np.eye(3)] * 2), [1.0, 2.0, 3.0])
    >>> g.shape, G.dim
    ((21,), 9)
    """

    def __init__(self, d: int):
        d = int(d)
        if d < 1:
            raise ShellsplineError(f"SO3dR3: d must be >= 1, got {d}")
        self.d = d
        self.name = f"SO3^{d}xR3"
        self.shape = (9 * d + 3,)
        self.dim = 3 * d + 3
        self.n_rotations = d

    def pack(self, R, p):
        """Elements ``(..., 9 d + 3)`` from rotations ``(..., d, 3, 3)`` and positions
        ``(..., 3)``."""
        R = np.asarray(R, dtype=np.float64)
        p = np.asarray(p, dtype=np.float64)
        if R.shape[-3:] != (self.d, 3, 3) or p.shape[-1:] != (3,):
            raise ShellsplineError(f"{self.name}.pack: R must be (..., {self.d}, 3, 3) and p "
                                   f"(..., 3), got {R.shape} and {p.shape}")
        lead = np.broadcast_shapes(R.shape[:-3], p.shape[:-1])
        R = np.broadcast_to(R, lead + R.shape[-3:])
        p = np.broadcast_to(p, lead + (3,))
        return np.concatenate([R.reshape(lead + (9 * self.d,)), p], axis=-1)

    def unpack(self, g):
        """Rotations ``(..., d, 3, 3)`` and positions ``(..., 3)`` of packed elements."""
        g = np.asarray(g, dtype=np.float64)
        return g[..., :9 * self.d].reshape(g.shape[:-1] + (self.d, 3, 3)), g[..., 9 * self.d:]

    def _split(self, x):
        x = np.asarray(x, dtype=np.float64)
        return x[..., :3 * self.d].reshape(x.shape[:-1] + (self.d, 3)), x[..., 3 * self.d:]

    def _join(self, w, v):
        return np.concatenate([w.reshape(w.shape[:-2] + (3 * self.d,)), v], axis=-1)

    def compose(self, a, b):
        Ra, pa = self.unpack(a)
        Rb, pb = self.unpack(b)
        return self.pack(Ra @ Rb, pa + pb)

    def inverse(self, a):
        R, p = self.unpack(a)
        return self.pack(np.swapaxes(R, -1, -2), -p)

    def exp(self, xi):
        w, v = self._split(xi)
        return self.pack(so3.exp(w), v)

    def log(self, g):
        R, p = self.unpack(g)
        return self._join(so3.log(R), p)

    def adjoint(self, g, xi):
        R, _ = self.unpack(g)
        w, v = self._split(xi)
        return self._join(np.einsum("...ij,...j->...i", R, w), v)

    def jac_right(self, xi, x):
        w, _ = self._split(xi)
        xw, xv = self._split(x)
        return self._join(so3.jac_right(w, xw), xv)

    def jac_right_inv(self, xi, x):
        w, _ = self._split(xi)
        xw, xv = self._split(x)
        return self._join(so3.jac_right_inv(w, xw), xv)

    def _rotations(self, g):
        return [(self.unpack(g)[0], "a rotation block")]

    def kernel(self):
        return _kernel.SO3dR3Kernel(self)


SO3 = _SO3()
SE3 = _SE3()
SO3xR3 = _SO3xR3()


def group(name) -> LieGroup:
    """The group object for a name (``"so3"``, ``"se3"``, ``"so3xr3"``, case-insensitive) or a
    :class:`LieGroup` itself."""
    if isinstance(name, LieGroup):
        return name
    table = {"so3": SO3, "se3": SE3, "so3xr3": SO3xR3}
    key = str(name).lower().replace("(", "").replace(")", "").replace("×", "x")
    if key not in table:
        raise ShellsplineError(f"group must be one of so3, se3, so3xr3 (or a LieGroup), got "
                               f"{name!r}")
    return table[key]


def karcher_mean(G, g, weights=None, *, tol=1e-13, max_iter=100, init=None):
    """Fréchet (Karcher) mean of group elements: ``m`` with ``sum_i w_i log(m^{-1} g_i) = 0``.

    Parameters
    ----------
    G : LieGroup or str
    g : (..., n, *G.shape) array_like
        ``n`` elements per mean; leading axes are independent problems.
    weights : (n,) array_like, optional
        Non-negative weights (normalised here); default uniform.
    tol : float
        Stop when the update's norm is below ``tol``.
    max_iter : int
    init : (..., *G.shape) array_like, optional
        Start (default: the first element).

    Returns
    -------
    m : (..., *G.shape) ndarray

    Raises
    ------
    ShellsplineError
        On bad weights, or when the iteration has not converged after ``max_iter`` steps
        (points spread beyond the injectivity radius have no unique mean).

    Notes
    -----
    The fixed-point iteration ``m <- m exp(sum_i w_i log(m^{-1} g_i))`` (the exponential
    barycentre; for ``SO3`` and the product groups the Riemannian centre of mass, for ``SE3``
    the bi-invariant mean of its Ad-invariant metric). It converges linearly for data within a
    ball of radius pi/2.
    """
    G = group(G)
    g = np.asarray(g, dtype=np.float64)
    k = len(G.shape)
    n = g.shape[g.ndim - k - 1]
    if weights is None:
        w = np.full(n, 1.0 / n)
    else:
        w = np.asarray(weights, dtype=np.float64)
        if w.shape != (n,) or np.any(w < 0) or not w.sum() > 0:
            raise ShellsplineError(f"weights must be {n} non-negative numbers with a positive "
                                   f"sum, got {np.asarray(weights).tolist()}")
        w = w / w.sum()
    m = np.take(g, 0, axis=g.ndim - k - 1) if init is None else np.asarray(init, float)
    for _ in range(max_iter):
        d = G.between(np.expand_dims(m, -k - 1), g)
        step = np.einsum("i,...ij->...j", w, d)
        m = G.compose(m, G.exp(step))
        if np.max(np.linalg.norm(step, axis=-1)) < tol:
            return m
    raise ShellsplineError(f"karcher_mean: no convergence in {max_iter} iterations (last "
                           f"update {np.max(np.linalg.norm(step, axis=-1)):.2g}); are the "
                           "points within pi/2 of each other?")

"""LΘA descriptors: edge lengths L, signed dihedral angles Θ, triangle areas A.

A descriptor vector is ``z = (L, Θ, A)`` of length ``e + i + m`` (all edges, interior edges,
faces; see :meth:`Topology.descriptor_slices`). Everything here is vectorised over elements and
batched over poses where it matters (a leading ``...`` axis on ``V``).

Functions come in pairs: a value function (``edge_lengths``, ``dihedral_angles``,
``face_areas``, ``lta_descriptors``) and the sparse Jacobian of the whole vector
(:func:`lta_jacobian`), plus the reference-mesh weights of paper §7 (:func:`lta_weights`).
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from ..mesh import geometry
from ..mesh.topology import Topology

__all__ = [
    "edge_lengths",
    "face_areas",
    "face_normals",
    "dihedral_angles",
    "lta_descriptors",
    "lta_jacobian",
    "lta_weights",
    "unwrap_angles",
    "consistent_angles",
    "wrap_angle",
]

_TWO_PI = 2.0 * np.pi


def edge_lengths(V, T: Topology) -> np.ndarray:
    """Edge lengths ``l_e``.

    Parameters
    ----------
    V : (..., n, 3) float64 array
        Vertex positions (one or a batch of poses).
    T : Topology

    Returns
    -------
    L : (..., e) float64 array
    """
    V = np.asarray(V, dtype=np.float64)
    d = np.take(V, T.E[:, 1], axis=-2) - np.take(V, T.E[:, 0], axis=-2)
    return np.sqrt(np.einsum("...i,...i->...", d, d))


def face_normals(V, F, *, unit: bool = False) -> np.ndarray:
    """Face normals ``(v1 − v0) × (v2 − v0)`` (length twice the area) or unit normals.

    Parameters
    ----------
    V : (..., n, 3) float64 array
        One pose or a batch of poses.
    F : (m,3) int array or Topology
    unit : bool
        Normalise to unit length (a degenerate face gets the zero vector).

    Returns
    -------
    N : (..., m, 3) float64 array
    """
    return geometry.face_normals(V, F.F if isinstance(F, Topology) else F, unit=unit)


def face_areas(V, T: Topology) -> np.ndarray:
    """Triangle areas ``a_t``.

    Parameters
    ----------
    V : (..., n, 3) float64 array
    T : Topology

    Returns
    -------
    A : (..., m) float64 array
    """
    return geometry.face_areas(V, T.F)


def _flap_geometry(X, flaps):
    """Flap corners and the two face normals from coordinate rows ``X (3, ..., n)``
    (:func:`~shellspline.mesh.geometry.coordinate_rows`); every result is a ``(3, ..., i)``
    array or a tuple of three ``(..., i)`` components."""
    v0, v1, v2, v3 = (np.take(X, flaps[:, k], axis=-1) for k in range(4))
    e = v1 - v0
    n1 = geometry.cross_rows(e, v2 - v0)          # normal of face (v0, v1, v2)
    n2 = geometry.cross_rows(v0 - v1, v3 - v1)    # normal of face (v1, v0, v3)
    return v0, v1, v2, v3, e, n1, n2


def dihedral_angles(V, T: Topology) -> np.ndarray:
    """Signed dihedral angles of the interior edges.

    ``θ_e = atan2(((n1 × n2) · ê), n1 · n2)`` for the flap ``(v0, v1, v2, v3)`` of edge ``e``
    (see :class:`Topology`), so θ = 0 on a flat configuration, θ > 0 on a convex edge of an
    outward-oriented surface, and θ is smooth through flat configurations (the unsigned
    ``arccos`` form is not).

    Parameters
    ----------
    V : (..., n, 3) float64 array
    T : Topology

    Returns
    -------
    Theta : (..., i) float64 array in (-π, π]

    Examples
    --------
    Two faces folded to a right angle along the shared edge:

    >>> import numpy as np
    >>> from shellspline.mesh.topology import topology
    >>> F = np.array([[0, 1, 2], [1, 0, 3]])
    >>> V = np.array([[0., 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, -1]])
    >>> np.degrees(dihedral_angles(V, topology(F))).round(6).tolist()
    [90.0]
    """
    X = geometry.coordinate_rows(np.asarray(V, dtype=np.float64))
    _, _, _, _, e, n1, n2 = _flap_geometry(X, T.flaps)
    el = np.sqrt(geometry.dot_rows(e, e))
    y = geometry.dot_rows(geometry.cross_rows(n1, n2), e) / el
    x = geometry.dot_rows(n1, n2)
    return np.arctan2(y, x)


def lta_descriptors(V, T: Topology) -> np.ndarray:
    """The LΘA vector ``z = (L, Θ, A)`` (paper §7).

    Parameters
    ----------
    V : (..., n, 3) float64 array
    T : Topology

    Returns
    -------
    Z : (..., e + i + m) float64 array
    """
    return np.concatenate([edge_lengths(V, T), dihedral_angles(V, T), face_areas(V, T)], axis=-1)


def wrap_angle(x):
    """Map angles (differences) to ``[-π, π)``.

    ``(x + π) mod 2π − π``; where ``x + π`` lies in ``[−2π, 2π)`` (every residual of the
    reconstruction's merit) the modulo is one comparison and at most one addition, the same
    value as numpy's ``%`` bit for bit and 5x faster (``%`` costs ~9 ns per element).

    Examples
    --------
    >>> wrap_angle(np.array([0.5, 4.0, -4.0, 10.0])).round(4).tolist()
    [0.5, -2.2832, 2.2832, -2.5664]
    """
    y = np.asarray(x) + np.pi
    if y.ndim == 0:
        return y % _TWO_PI - np.pi
    out = np.where(y < 0, y + _TWO_PI, y)
    far = ~((y >= -_TWO_PI) & (y < _TWO_PI))  # also NaN and ±inf
    if far.any():
        out[far] = y[far] % _TWO_PI
    return out - np.pi


def unwrap_angles(Theta) -> np.ndarray:
    """Unwrap dihedral angles across poses (axis 0) per edge.

    Each pose's angle is moved by a multiple of 2π to the branch closest to the previous
    pose's (already unwrapped) value, so a part that twists past ±π keeps a continuous
    trajectory instead of jumping by 2π.

    Parameters
    ----------
    Theta : (J, i) float64 array

    Returns
    -------
    (J, i) float64 array
    """
    Theta = np.array(Theta, dtype=np.float64, copy=True)
    for j in range(1, Theta.shape[0]):  # loop over keyframes only (J is small)
        Theta[j] = Theta[j - 1] + wrap_angle(Theta[j] - Theta[j - 1])
    return Theta


#: A keyframe angle within this many radians of ±π is a fold whose sign is not to be trusted
#: (real keyframes hold creases a little past the touching point: skin folding at a joint,
#: neighbouring edges of one crease at +2.9 and −2.6): the path to it may cross ±π.
FOLD_BAND = 0.5


def consistent_angles(Theta, periodic: bool = False) -> np.ndarray:
    """Dihedral angles of keyframes on paths that do not pass through ±π.

    A signed dihedral angle of ±π means the edge's two triangles lie on top of each other;
    passing through it means they pass through each other. Between two keyframes whose angles
    lie in ``(−π, π]`` the physical path is therefore the *direct* one, even when it is longer
    than π (an edge that turns from 20° convex to 150° concave unfolds through flat), not the
    shorter one through ±π that an angle unwrap takes. The exception is a keyframe angle
    within :data:`FOLD_BAND` of ±π: a fold the keyframes hold a little past the touching
    point, whose sign says little (neighbouring edges of one crease of the horse sit at +2.91
    and −2.65); the path to or from it takes the shorter way, through ±π when that is
    shorter (−1.46 → 2.91 becomes −1.46 → −3.37: a concave fold that ends 13° past flat).

    Parameters
    ----------
    Theta : (J, i) float64 array
        Keyframe angles in ``(−π, π]`` (from :func:`dihedral_angles`).
    periodic : bool
        Also apply the rule between the last and the first keyframe, and return a row
        ``J`` for the first keyframe at the end of the loop.

    Returns
    -------
    (J, i) or (J+1, i) float64 array
        Angles along the chosen paths: each row differs from its predecessor by the chosen
        change (``θ_b − θ_a``, or the change through ±π), so rows may leave ``(−π, π]``.

    Examples
    --------
    >>> import numpy as np
    >>> consistent_angles(np.array([[0.35], [-2.3]]))[:, 0].round(2).tolist()
    [0.35, -2.3]
    >>> consistent_angles(np.array([[-1.46], [2.91]]))[:, 0].round(2).tolist()
    [-1.46, -3.37]
    >>> consistent_angles(np.array([[3.09], [-3.10]]))[:, 0].round(2).tolist()
    [3.09, 3.18]
    """
    Theta = np.asarray(Theta, dtype=np.float64)
    rows = np.concatenate([Theta, Theta[:1]]) if periodic else Theta
    out = rows.copy()
    near = np.abs(rows) > np.pi - FOLD_BAND
    for j in range(1, rows.shape[0]):  # loop over keyframes only (J is small)
        d = rows[j] - rows[j - 1]
        cross = (near[j] | near[j - 1]) & (np.abs(d) > np.pi)
        d = np.where(cross, wrap_angle(d), d)
        out[j] = out[j - 1] + d
    return out


class _JacobianPattern:
    """CSR structure of ``∂z/∂V``; only the data array changes between evaluations."""

    def __init__(self, T: Topology):
        e, i, m = T.n_edges, T.n_interior, T.n_faces
        xyz = np.arange(3)
        colsL = (3 * T.E[:, :, None] + xyz).reshape(e, 6)
        colsT = (3 * T.flaps[:, :, None] + xyz).reshape(i, 12)
        colsA = (3 * T.F[:, :, None] + xyz).reshape(m, 9)
        self.indices = np.concatenate([colsL.ravel(), colsT.ravel(), colsA.ravel()]).astype(np.int32)
        nnz_row = np.concatenate([np.full(e, 6), np.full(i, 12), np.full(m, 9)])
        self.indptr = np.concatenate([[0], np.cumsum(nnz_row)]).astype(np.int32)
        self.shape = (e + i + m, 3 * T.n_vertices)


def pattern(T: Topology) -> _JacobianPattern:
    p = T._cache.get("jacobian_pattern")
    if p is None:
        p = T._cache["jacobian_pattern"] = _JacobianPattern(T)
    return p


def lta_jacobian(V, T: Topology, *, return_values: bool = False):
    """Sparse Jacobian ``J = ∂z/∂V`` of the LΘA vector w.r.t. the flattened vertex positions.

    Closed-form per-element gradients (vectorised):

    - length: ``∂l/∂v1 = -∂l/∂v0 = (v1 - v0)/l``;
    - area: ``∂a/∂v0 = ½ ν × (v2 - v1)`` and cyclically, ``ν`` the unit normal;
    - dihedral angle (flap ``v0 v1 | v2, v3``, ``q_f = |e| n_f / |n_f|²``,
      ``t_f`` the edge parameter of the foot point of the flap vertex):
      ``∂θ/∂v2 = -q_1``, ``∂θ/∂v3 = -q_2``, ``∂θ/∂v0 = (1-t_1) q_1 + (1-t_2) q_2``,
      ``∂θ/∂v1 = t_1 q_1 + t_2 q_2``.

    Parameters
    ----------
    V : (n,3) float64 array
    T : Topology
    return_values : bool
        Also return the descriptor vector ``z`` computed on the way.

    Returns
    -------
    J : (e+i+m, 3n) scipy.sparse.csr_matrix
    z : (e+i+m,) float64 array, only if ``return_values``
    """
    V = np.asarray(V, dtype=np.float64)
    P = pattern(T)
    gL, gT, gA, (L, y, x, nn) = element_gradients(V, T)
    data = np.concatenate([gL.ravel(), gT.ravel(), gA.ravel()])
    J = sp.csr_matrix((data, P.indices, P.indptr), shape=P.shape)
    if return_values:
        return J, np.concatenate([L, np.arctan2(y, x), 0.5 * nn])
    return J


def element_gradients(V, T: Topology):
    """Per-element descriptor gradients of pose ``V``: lengths ``(e,6)``, angles ``(i,12)``,
    areas ``(m,9)`` (the data of :func:`lta_jacobian`), and ``(L, y, x, |n|)`` (lengths, the
    angle's ``atan2`` arguments, twice the face areas).

    Only analytic operations (no conjugation, no ``abs``): for complex positions
    ``V + i h v`` the imaginary parts divided by ``h`` are the element Hessians times ``v``
    to round-off (complex-step differentiation), which
    :meth:`shellspline.shells.energy.DiscreteShells.hessian_product` uses.
    """
    # every element quantity as three contiguous coordinate rows (about 1.5x faster than
    # (k, 3) arrays and their stride-3 components; the same operations, bit-identical)
    X = geometry.coordinate_rows(V)
    dot, cross = geometry.dot_rows, geometry.cross_rows
    # lengths
    d = np.take(X, T.E[:, 1], axis=1) - np.take(X, T.E[:, 0], axis=1)
    L = np.sqrt(dot(d, d))
    u = d / L
    gL = np.stack([-u[0], -u[1], -u[2], u[0], u[1], u[2]], axis=1)
    # dihedral angles
    v0, v1, v2, v3, e, n1, n2 = _flap_geometry(X, T.flaps)
    ee = dot(e, e)
    el = np.sqrt(ee)
    s1, s2 = el / dot(n1, n1), el / dot(n2, n2)
    q1, q2 = [c * s1 for c in n1], [c * s2 for c in n2]
    t1 = dot(v2 - v0, e) / ee
    t2 = dot(v3 - v0, e) / ee
    o1, o2 = 1 - t1, 1 - t2
    gT = np.stack([o1 * q1[c] + o2 * q2[c] for c in range(3)] +
                  [t1 * q1[c] + t2 * q2[c] for c in range(3)] +
                  [-c for c in q1] + [-c for c in q2], axis=1)
    y = dot(cross(n1, n2), e) / el
    x = dot(n1, n2)
    # areas
    w0, w1, w2 = (np.take(X, T.F[:, c], axis=1) for c in range(3))
    N = cross(w1 - w0, w2 - w0)
    nn = np.sqrt(dot(N, N))
    nu = [c / nn for c in N]
    gA = np.stack([0.5 * c for c in cross(nu, w2 - w1) + cross(nu, w0 - w2) + cross(nu, w1 - w0)],
                  axis=1)
    return gL, gT, gA, (L, y, x, nn)


#: Bending weights ``l_e²/d_e`` are capped at this multiple of their value on two equilateral
#: triangles (``6/√3``): a sliver flap (``d_e → 0``) has an ill-conditioned dihedral angle and
#: an unbounded paper weight. The cap binds only below ~1/10 of the equilateral flap area for
#: the edge's length; on a sliver-strewn tube (`data_synth.stress.slivers`, slivers of 1 % of
#: the median area) it took Gauss–Newton from 16/18 to 18/18 converged frames and from 350 to
#: 209 iterations; meshes without slivers are unchanged.
SLIVER_CAP = 10.0


def lta_weights(V_ref, T: Topology, *, mu: float = 1.0, lam: float = 1.0, eta: float = 1e-3,
                sliver_cap: float | None = SLIVER_CAP):
    """Weights of the quadratic LΘA energy at a reference mesh (paper eq. 10).

    ``Ŵ(z, z̃) = Σ_i w_i (z_i - z̃_i)²`` with, at the reference mesh ŝ,
    lengths ``w = μ d_e / l_e²``, angles ``w = η l_e² / d_e``, areas ``w = λ / a_t``, where
    ``d_e = (a_t1 + a_t2)/3`` (one third of the single face's area on a boundary edge).

    Parameters
    ----------
    V_ref : (..., n, 3) float64 array
        Reference pose(s).
    T : Topology
    mu, lam, eta : float
        Membrane (length, area) and bending weights; ``eta = thickness²``.
    sliver_cap : float or None
        Cap of the bending weights relative to an equilateral flap (:data:`SLIVER_CAP`);
        ``None``: the paper's weights unchanged.

    Returns
    -------
    w : (..., e+i+m) float64 array
    """
    V_ref = np.asarray(V_ref, dtype=np.float64)
    L = edge_lengths(V_ref, T)
    A = face_areas(V_ref, T)
    ef = T.edge_faces
    aef = np.where(ef >= 0, A[..., np.maximum(ef, 0)], 0.0)
    de = aef.sum(axis=-1) / 3.0
    wL = mu * de / L**2
    wT = eta * L[..., T.interior] ** 2 / de[..., T.interior]
    if sliver_cap is not None:
        wT = np.minimum(wT, eta * sliver_cap * 6.0 / np.sqrt(3.0))
    wA = lam / A
    return np.concatenate([wL, wT, wA], axis=-1)

"""Prolongation of a coarse sequence to the fine mesh by detail transfer (paper §8).

The coarse mesh of :func:`~shellspline.mesh.decimate.decimate` is a subset of the fine vertices.
Given a coarse pose ``Vc``, the *base surface* ``S(Vc)`` on the fine connectivity is the
fairest surface through the coarse vertices: the kept fine vertices sit exactly at ``Vc``
and the others minimise the bi-Laplacian energy ``‖L S‖²``,

    S_free = −(B_ff)⁻¹ B_fc Vc,    B = Lᵀ L,   L = D − A (graph Laplacian),

with edge weights ``A_uv = 1 / l̄_uv`` (``l̄``: the edge's mean keyframe length, see
:func:`_edge_weights`), so that the base follows the fine surface closely on irregular
meshes and the details stay short: a linear map whose sparse factorization is computed once and reused for every pose
(precompute/solve split). At every fine vertex ``i`` the base carries an orthonormal frame
``R_i(S) = [t_i, b_i, n_i]``: ``n_i`` the area-weighted vertex normal of ``S``, ``t_i`` the
edge to a fixed neighbour projected onto the tangent plane, ``b_i = n_i × t_i``.

Two ways to carry the fine detail on these frames (``transfer``); both interpolate the
keyframes' local coordinates in time with weights ``W[k,j]`` (piecewise linear by default,
or the spline's own), return the input keyframes bit for bit at keyframe frames, and put
the kept vertices exactly at the coarse solution.

*Displacement* (the paper's, ``transfer="displacement"``). Encode (once per keyframe
``j``): ``c_i^j = R_i(S_j)ᵀ (x_i^j − S_i(Vc_j))``, each vertex's offset from the base in its
own frame. Decode (frame ``k``): ``x_i(k) = S_i(Vc_k) + R_i(S(Vc_k)) Σ_j W[k,j] c_i^j``.
Where the frames of neighbouring vertices turn differently, long offsets (a fine mesh far
finer than its coarse mesh, creases, slivers) move small faces over each other.

*Gradient* (default, ``transfer="gradient"``, :class:`_GradientTransfer`). Encode: every
fine edge vector ``x_b^j − x_a^j`` in the frames of both its vertices. Decode: rotate the
time-interpolated coordinates back with the frames of frame ``k``, and solve for the fine
positions that fit these edge vectors best (weighted least squares with the coarse vertices
anchored, one Laplacian factorization for all frames), then spread the misfit left at the
coarse vertices by the same bi-Laplacian as the base. A face keeps its shape up to the turn
of its own vertices' frames, however long the offsets from the base are. Measured on the same
coarse solutions, new flipped faces / folded edges before the guard below: the horse
subdivided twice (134 782 vertices, 1174 coarse) 312 / 216 → 32 / 42,
``data_synth.stress.dense_slivers`` (6 080 vertices, 250 coarse) 4 711 / 1 614 → 7 / 3. Cost
per frame: a Laplacian and a second bi-Laplacian solve, and the edge assembly (the horse
subdivided twice, 41 frames, one core: 10.6 s against 5.9 s).

*The rule: the prolongation adds no defect that the coarse frames do not have.* Detail
carried on frames of the base surface is safe where the coarse in-between moves the base
nearly rigidly at the scale of the detail; on real meshes it is not everywhere: skin creases
that a keyframe holds folded by up to 2.7 rad against the smooth base pass through each
other, and slivers (1 % of an edge high) turn over at the slightest non-rigid motion of the
base under them. Measured with :class:`~shellspline.shells.defects.DefectRules` (the rules
that :func:`shellspline.metrics.sequence_defects` counts, element by element), a fine defect
in a step is *inherited* when one of its vertices was merged into a coarse vertex within one
coarse ring of a coarse element with a defect in the same step; :meth:`Prolongation.guard`
fades the detail of the vertices of every other defect to zero (the vertex then lies on the
base), spread over two graph rings and two frames, keyframes untouched, and repeats (scanning
again only the steps next to the frames it changed) until none is left; where the base
surface itself has a defect (a fair surface through the coarse vertices can fold a fine
crease on its own) the round with the fewest new defects is returned and the rest reported.
With displacements, ``data_synth.stress.slivers`` at a quarter of its vertices: 184 new
flipped faces and 76 folded edges → 0 and at most 1 (the gradient transfer has none to fade
there). Fading onto the base gives up the fine mesh's own edge lengths: on the dense slivers
above it faded 68 % of the vertex-frames of the displacement transfer and left edges 100
times their keyframe length.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from ..errors import ShellsplineError, tol
from ..numerics.linalg import SparseCholesky
from ..mesh.decimate import Decimation
from ..mesh.geometry import cross, dot, normalized, norms, vertex_face_incidence
from ..mesh.pinned import pinned_mask
from ..mesh.topology import Topology, topology
from ..timeline import linear_time_weights as timeline_linear_time_weights
from .defects import DefectRules, step_defects

__all__ = ["Prolongation", "linear_time_weights", "spline_time_weights", "prolong",
           "step_defects", "fade_new_defects", "TRANSFERS", "DEFAULT_TRANSFER", "ANCHOR"]

#: The detail transfers of :meth:`Prolongation.encode` (the module docstring says how they
#: differ) and the default (``interpolate``, the CLI's ``--transfer``, the batch key).
TRANSFERS = ("gradient", "displacement")
DEFAULT_TRANSFER = "gradient"


def linear_time_weights(frames, K: int, bc: str = "natural") -> np.ndarray:
    """Piecewise-linear interpolation weights of the keyframes, frame by frame.

    Parameters
    ----------
    frames : (J,) int array_like
        Strictly increasing keyframe frames in ``[0, K]`` (``< K`` for periodic).
    K : int
        Last frame index.
    bc : {"natural", "hermite", "periodic"}
        ``"periodic"`` blends the last keyframe back into the first at frame ``K``; otherwise
        frames before the first / after the last keyframe hold that keyframe.

    Returns
    -------
    W : (K+1,J) float64 numpy array
        Rows sum to 1; ``W[frames[j]] = e_j`` exactly.
    """
    fr, K = _checked_frames(frames, K)
    return timeline_linear_time_weights(fr, K, bc)


def spline_time_weights(frames, K: int, bc: str = "natural") -> np.ndarray:
    """Weights of the time-discrete cubic spline (constant reference) through the keyframes.

    Row ``k`` holds the coefficients with which frame ``k`` of
    :func:`~shellspline.shells.lta_spline.lta_spline` combines the keyframe values, obtained by
    running the spline on the identity ``Z_key = I_J``.

    Parameters
    ----------
    frames : (J,) int array_like
    K : int
    bc : {"natural", "periodic", "hermite"}

    Returns
    -------
    W : (K+1,J) float64 numpy array
    """
    from .lta_spline import lta_spline

    fr, K = _checked_frames(frames, K)
    W = np.asarray(lta_spline(np.eye(fr.shape[0]), fr, K, bc=bc), dtype=np.float64)
    W[fr] = np.eye(fr.shape[0])
    return W


def _checked_frames(frames, K):
    fr = np.asarray(frames)
    if fr.ndim != 1 or fr.size == 0 or not np.issubdtype(fr.dtype, np.integer):
        raise ShellsplineError(f"`frames` must be a non-empty 1-D integer array, got {frames!r}")
    if isinstance(K, (bool, np.bool_)) or not isinstance(K, (int, np.integer)) or K < 1:
        raise ShellsplineError(f"`K` must be an integer >= 1, got {K!r}")
    fr = fr.astype(np.int64)
    if (np.diff(fr) <= 0).any() or fr[0] < 0 or fr[-1] > K:
        raise ShellsplineError(f"`frames` must be strictly increasing in [0, K={K}], got "
                               f"{fr.tolist()}")
    return fr, int(K)


class Prolongation:
    """Detail transfer from a coarse mesh to the fine mesh it was decimated from.

    Build it with :meth:`encode`; then :meth:`decode` prolongs any coarse sequence. The
    bi-Laplacian factorization is computed once in :meth:`encode` and reused by every
    :meth:`base` / :meth:`decode` call.

    Attributes
    ----------
    F : (m,3) int64 numpy array
        Fine faces.
    kept : (nc,) int64 numpy array
        Fine indices of the coarse vertices.
    frames : (J,) int64 numpy array
        Keyframe frames.
    keyframes : (J,n,3) float64 numpy array
        The fine keyframes (returned verbatim at keyframe frames).
    coeffs : (J,n,3) float64 numpy array
        Detail coordinates ``(t, b, n)`` of every fine vertex in every keyframe (the
        displacement transfer's).
    pinned : (p,) int64 numpy array
        Fine vertices held at their keyframe position in every frame.
    transfer : {"gradient", "displacement"}
        How :meth:`decode` carries the detail (see the module docstring).

    Examples
    --------
    >>> import numpy as np, data_synth
    >>> from shellspline.mesh.decimate import decimate
    >>> d = data_synth.generate("bumpy", n_vertices=600)
    >>> dec = decimate(d["V"], d["F"], 150)
    >>> P = Prolongation.encode(d["V"], d["F"], dec, [0, 2, 4])
    >>> Vc = np.repeat(dec.V, 2, axis=0)[:5]
    >>> Vc[1], Vc[3] = (dec.V[0] + dec.V[1]) / 2, (dec.V[1] + dec.V[2]) / 2
    >>> V = P.decode(Vc)            # (K+1, n, 3); keyframes exact
    >>> V.shape, bool((V[4] == d["V"][2]).all())
    ((5, 642, 3), True)
    """

    def __init__(self, F, n, kept, frames, keyframes, coeffs, pinned, solver, B_fc, free,
                 ref_nbr, coarse_F=None, collapse_map=None):
        self.transfer = "displacement"
        self._grad = None
        self.F = F
        self.coarse_F = coarse_F
        self.collapse_map = collapse_map
        self.n_vertices = n
        self.kept = kept
        self.frames = frames
        self.keyframes = keyframes
        self.coeffs = coeffs
        self.pinned = pinned
        self._solver = solver
        self._B_fc = B_fc
        self._free = free
        self._ref_nbr = ref_nbr

    # -- construction ----------------------------------------------------------------------
    @classmethod
    def encode(cls, Vs_fine, F_fine, dec: Decimation, frames=None, *, pinned=None,
               backend: str = "auto", transfer: str = DEFAULT_TRANSFER) -> "Prolongation":
        """Precompute the base-surface solver and encode the keyframes' fine detail.

        Parameters
        ----------
        Vs_fine : (J,n,3) float array_like
            Fine keyframes.
        F_fine : (m,3) int array_like or Topology
            Fine faces (those given to :func:`~shellspline.mesh.decimate.decimate`), or their
            prebuilt :class:`~shellspline.mesh.topology.Topology`.
        dec : Decimation
            The decimation of these keyframes.
        frames : (J,) int array_like, optional
            Keyframe frames; default ``0, 1, ..., J-1``.
        pinned : (p,) int array_like or (n,) bool array_like, optional
            Fine vertices returned at their (identical) keyframe position in every frame.
        backend : {"auto", "cholmod", "splu"}
            Sparse factorization backend (see :class:`~shellspline.numerics.linalg.SparseCholesky`).
        transfer : {"gradient", "displacement"}
            How the fine detail is carried (see the module docstring): ``"gradient"`` (default)
            carries every fine edge vector on the base frames of its two vertices and solves
            for the positions that fit them best; ``"displacement"`` is the paper's per-vertex
            offset from the base surface.

        Returns
        -------
        Prolongation

        Raises
        ------
        ValueError
            If shapes disagree with ``dec``, ``frames`` is not strictly increasing, or a
            ``pinned`` vertex moves between keyframes.
        """
        Vs = np.asarray(Vs_fine, dtype=np.float64)
        if Vs.ndim == 2:
            Vs = Vs[None]
        if not isinstance(dec, Decimation):
            raise ShellsplineError(f"`dec` must be a Decimation, got {type(dec).__name__}")
        if Vs.ndim != 3 or Vs.shape[1:] != (dec.n_fine, 3):
            raise ShellsplineError(f"`Vs_fine` must have shape (J, {dec.n_fine}, 3), got "
                                   f"{Vs.shape}")
        J, n, _ = Vs.shape
        if isinstance(F_fine, Topology):
            if F_fine.n_vertices != n:
                raise ShellsplineError(f"`F_fine` is a Topology of {F_fine.n_vertices} vertices, "
                                       f"expected {n}")
            T = F_fine
        else:
            T = topology(F_fine, n, name="`F_fine`")
        if frames is None:
            frames = np.arange(J)
        fr = np.asarray(frames)
        if fr.shape != (J,) or not np.issubdtype(fr.dtype, np.integer) or \
                (np.diff(fr) <= 0).any():
            raise ShellsplineError(f"`frames` must be {J} strictly increasing integers, got "
                                   f"{np.asarray(frames).tolist()}")
        tr = str(transfer).strip().lower()
        if tr not in TRANSFERS:
            raise ShellsplineError(f"`transfer` must be one of {', '.join(map(repr, TRANSFERS))}"
                                   f", got {transfer!r}")
        pin = pinned_mask(pinned, n)
        if pin.any() and not (Vs[:, pin] == Vs[:1, pin]).all():
            raise ShellsplineError("`pinned` vertices must be identical in all keyframes")
        # edge-length-weighted graph Laplacian and the bi-Laplacian split free/kept
        E = T.E
        w = _edge_weights(Vs, E)
        A = sp.coo_matrix((np.r_[w, w], (np.r_[E[:, 0], E[:, 1]], np.r_[E[:, 1], E[:, 0]])),
                          shape=(n, n))
        A = A.tocsr()
        deg = np.asarray(A.sum(axis=1)).ravel()
        L = (sp.diags(deg) - A).tocsr()
        B = (L.T @ L).tocsr()
        is_kept = np.zeros(n, dtype=bool)
        is_kept[dec.kept] = True
        free = np.flatnonzero(~is_kept)
        B_ff = B[free][:, free].tocsc()
        B_fc = B[free][:, dec.kept].tocsr()
        solver = SparseCholesky(B_ff, backend=backend) if free.size else None
        # a fixed neighbour per vertex for the tangent direction
        ref_nbr = np.full(n, -1, dtype=np.int64)
        ref_nbr[E[::-1, 0]] = E[::-1, 1]
        ref_nbr[E[::-1, 1]] = E[::-1, 0]
        lonely = ref_nbr < 0
        ref_nbr[lonely] = np.flatnonzero(lonely)        # unreferenced vertex: no frame needed
        obj = cls(T.F, n, dec.kept, fr.astype(np.int64), Vs.copy(), None,
                  np.flatnonzero(pin).astype(np.int64), solver, B_fc, free, ref_nbr,
                  dec.F, dec.collapse_map)
        S = obj.base(Vs[:, dec.kept])
        D = Vs - S
        R = obj._frame_vectors(S)
        obj.coeffs = np.stack([np.einsum("jni,jni->jn", a, D) for a in R], axis=-1)
        if tr == "gradient":
            obj._grad = _GradientTransfer(Vs, R, E, w, L, is_kept, pin, B,
                                          (free, solver, B_fc), backend)
        obj.transfer = tr
        return obj

    # -- evaluation ----------------------------------------------------------------------------
    def base(self, Vc) -> np.ndarray:
        """The fair base surface through coarse poses, on the fine connectivity.

        Parameters
        ----------
        Vc : (nc,3) or (B,nc,3) float array_like
            Coarse poses.

        Returns
        -------
        S : (n,3) or (B,n,3) float64 numpy array
            ``S[..., kept, :] == Vc``; the other vertices minimise ``‖L S‖²``.
        """
        Vc = np.asarray(Vc, dtype=np.float64)
        single = Vc.ndim == 2
        Vb = Vc[None] if single else Vc
        if Vb.ndim != 3 or Vb.shape[1:] != (self.kept.shape[0], 3):
            raise ShellsplineError(f"`Vc` must have shape (..., {self.kept.shape[0]}, 3), got "
                                   f"{Vc.shape}")
        S = self._base_vm(Vb).transpose(1, 0, 2)
        return S[0] if single else np.ascontiguousarray(S)

    def _base_vm(self, Vb):
        """:meth:`base` of coarse poses ``Vb (B,nc,3)`` in vertex-major layout ``(n,B,3)``."""
        nb = Vb.shape[0]
        St = np.zeros((self.n_vertices, nb, 3))
        Vt = Vb.transpose(1, 0, 2)
        St[self.kept] = Vt
        if self._free.size:
            rhs = -(self._B_fc @ Vt.reshape(self.kept.shape[0], 3 * nb))
            St[self._free] = self._solver.solve(rhs).reshape(self._free.shape[0], nb, 3)
        return St

    def frames_of(self, S) -> np.ndarray:
        """Orthonormal frames ``[t, b, n]`` (as columns) of base surfaces.

        Parameters
        ----------
        S : (..., n, 3) float array_like

        Returns
        -------
        R : (..., n, 3, 3) float64 numpy array
            ``R[..., i, :, 0] = t_i``, ``R[..., i, :, 1] = b_i``, ``R[..., i, :, 2] = n_i``.
        """
        return np.stack(self._frame_vectors(np.asarray(S, dtype=np.float64)), axis=-1)

    def _frame_vectors(self, S):
        """The columns ``t, b, n`` (each shaped like ``S (..., n, 3)``) of :meth:`frames_of`."""
        n = self.n_vertices
        St = np.ascontiguousarray(np.moveaxis(S.reshape(-1, n, 3), 1, 0))
        return tuple(np.moveaxis(a, 0, 1).reshape(S.shape) for a in self._frames_vm(St))

    def _frames_vm(self, St):
        """Frame columns ``t, b, n`` of base surfaces in vertex-major layout ``St (n,B,3)``
        (each ``(n,B,3)``): one sparse product for the vertex normals of the whole batch."""
        n, nb, _ = St.shape
        F = self.F
        if getattr(self, "_inc", None) is None:
            self._inc = vertex_face_incidence(F, n)
        p0 = St[F[:, 0]]
        d1 = St[F[:, 1]]
        d1 -= p0
        d2 = St[F[:, 2]]
        d2 -= p0
        N = _cross(d1, d2)                                            # (m,B,3)
        del p0, d1, d2
        nrm = (self._inc @ N.reshape(F.shape[0], 3 * nb)).reshape(n, nb, 3)
        nrm = normalized(nrm)
        e = St[self._ref_nbr] - St
        t = e - dot(e, nrm)[..., None] * nrm
        tl, el = norms(t)[..., None], norms(e)[..., None]
        bad = ~(tl > 1e-12 * np.maximum(el, tol.zero))
        t /= np.maximum(tl, tol.zero)
        if bad.any():
            # fallback for a reference edge along the normal: any direction orthogonal to n
            alt = cross(nrm, np.where(np.abs(nrm[..., :1]) < 0.9, [1.0, 0, 0], [0, 1.0, 0]))
            alt = normalized(alt)
            t = np.where(bad, alt, t)
        return t, _cross(nrm, t), nrm

    def decode(self, Vc, frames=None, K=None, *, time_weights="linear", bc: str = "natural",
               chunk: int = 4, only=None) -> np.ndarray:
        """Prolong a coarse sequence to the fine mesh.

        Parameters
        ----------
        Vc : (K+1,nc,3) float array_like
            Coarse frames ``k = 0..K`` (e.g. the coarse spline).
        frames : (J,) int array_like, optional
            Keyframe frames; default: those given to :meth:`encode`. Must equal them.
        K : int, optional
            Last frame; default ``Vc.shape[0] - 1``.
        time_weights : "linear", "spline" or (K+1,J) float array_like
            How the detail coefficients are interpolated in time: piecewise linear
            (:func:`linear_time_weights`), the constant-reference spline
            (:func:`spline_time_weights`), or explicit weights.
        bc : {"natural", "periodic", "hermite"}
            Boundary condition used by the ``"linear"``/``"spline"`` weights.
        chunk : int
            Frames solved together (memory ``~ chunk * n * 3`` doubles; the gradient transfer
            ``~ chunk * 12 * edges`` more). Small batches stay in cache: the horse subdivided
            twice (134 782 vertices, 41 frames, one core) decodes in 10.6 s at 4 against
            13.4 s at 16 (the displacement transfer 5.9 s against 7.2 s), peak 324 MB
            against 917 MB.
        only : (r,) int array_like, optional
            Decode only these frames (the other rows of the result are zero); lets callers
            split the frames over processes.

        Returns
        -------
        V : (K+1,n,3) float64 numpy array
            ``V[frames[j]]`` is the fine keyframe ``j`` bit for bit; pinned vertices keep
            their keyframe position in every frame.
        """
        Vc = np.asarray(Vc, dtype=np.float64)
        if Vc.ndim != 3 or Vc.shape[1:] != (self.kept.shape[0], 3):
            raise ShellsplineError(f"`Vc` must have shape (K+1, {self.kept.shape[0]}, 3), got "
                                   f"{Vc.shape}")
        if K is None:
            K = Vc.shape[0] - 1
        if Vc.shape[0] != K + 1:
            raise ShellsplineError(f"`Vc` must hold K+1 = {K + 1} frames, got {Vc.shape[0]}")
        fr = self.frames if frames is None else np.asarray(frames)
        if fr.shape != self.frames.shape or not (fr == self.frames).all():
            raise ShellsplineError(f"`frames` must equal the keyframe frames given to encode "
                                   f"{self.frames.tolist()}, got {np.asarray(frames).tolist()}")
        if self.frames[-1] > K:
            raise ShellsplineError(f"`K` = {K} is before the last keyframe frame {self.frames[-1]}")
        J = self.frames.shape[0]
        W = self._time_weights(K, time_weights, bc)
        out = np.zeros((K + 1, self.n_vertices, 3))
        key_of = np.full(K + 1, -1, dtype=np.int64)
        key_of[self.frames] = np.arange(J)
        if str(bc).lower() == "periodic" and self.frames[0] == 0:
            key_of[K] = 0
        todo = np.flatnonzero(key_of < 0)
        if only is not None:
            todo = np.intersect1d(todo, np.asarray(only, dtype=np.int64))
        self._decode_into(out, Vc, W, todo, chunk)
        if self.pinned.size:  # only the rows decoded here (the others stay zero)
            rows = todo if only is None else np.union1d(
                todo, np.intersect1d(np.flatnonzero(key_of >= 0), np.asarray(only)))
            out[rows[:, None], self.pinned] = self.keyframes[0, self.pinned]
        done = np.flatnonzero(key_of >= 0)
        if only is not None:
            done = np.intersect1d(done, np.asarray(only, dtype=np.int64))
        out[done] = self.keyframes[key_of[done]]
        return out


    def _time_weights(self, K, time_weights, bc):
        """The ``(K+1,J)`` detail weights that :meth:`decode`'s ``time_weights`` names."""
        J = self.frames.shape[0]
        if isinstance(time_weights, str):
            tw = time_weights.lower()
            if tw == "linear":
                return linear_time_weights(self.frames, K, bc)
            if tw == "spline":
                return spline_time_weights(self.frames, K, bc)
            raise ShellsplineError(f"`time_weights` must be 'linear', 'spline' or a (K+1,J) "
                                   f"array, got {time_weights!r}")
        W = np.asarray(time_weights, dtype=np.float64)
        if W.shape != (K + 1, J) or not np.isfinite(W).all():
            raise ShellsplineError(f"`time_weights` must be a finite ({K + 1},{J}) array, got "
                                   f"shape {W.shape}")
        return W

    def _decode_into(self, out, Vc, W, todo, chunk):
        """The decoded frames ``todo`` into ``out``, ``chunk`` at a time: ``S(Vc[k]) + R(S) c(k)``
        (displacement) or :meth:`_GradientTransfer.solve` on the frames of ``S(Vc[k])``."""
        step = max(1, int(chunk))
        for s in range(0, todo.shape[0], step):
            ks = todo[s:s + step]
            St = self._base_vm(Vc[ks])                          # (n,B,3)
            t, b, nrm = self._frames_vm(St)
            if self._grad is not None:
                out[ks] = self._grad.solve((t, b, nrm), W[ks], Vc[ks],
                                           self.keyframes[0]).transpose(1, 0, 2)
                continue
            c = np.einsum("kj,jna->nka", W[ks], self.coeffs)
            St += t * c[..., :1]
            St += b * c[..., 1:2]
            St += nrm * c[..., 2:]
            out[ks] = St.transpose(1, 0, 2)

    def guard(self, V, Vc, K=None, *, bc: str = "natural", rings: int = 2, taper: int = 2,
              max_rounds: int = 20, fallback=None):
        """Take back the detail where it adds a defect that the coarse frames do not have.

        The prolongation of a coarse solution carries each keyframe's fine detail (skin
        creases folded up to ±π against the smooth base, slivers 1 % of an edge high) on
        frames that rotate with the base surface. Where the coarse in-between deforms the base
        non-rigidly at the scale of such a detail, the detail turns faces over, passes creases
        through each other or collapses slivers, although the coarse frames (and the base
        through them) do not (horse, keyframes 0/03/07, 1000 coarse vertices: 14 flipped coarse
        faces and no folded coarse edge became 31 flipped fine faces and 13 folded edges;
        ``data_synth.stress.slivers``: 3 → 220 flipped, 0 → 236 folded).

        This pass finds, step by step, the fine defects (:class:`~.defects.DefectRules`) not
        *inherited* (no vertex of the fine face, flap or collapsed face is merged into a
        coarse vertex within one coarse ring of a coarse element with a defect in the same
        step), and fades the detail of their vertices to zero: the vertex then lies on
        the base. The fade is spread over ``rings`` graph rings (linearly) and ``taper``
        frames on either side (within the keyframe gap; keyframes keep their detail, so they
        stay exact), and repeated until no new defect is left or ``max_rounds`` rounds.

        Parameters
        ----------
        V : (K+1,n,3) float64 array
            :meth:`decode`'s result for ``Vc``.
        Vc : (K+1,nc,3) float array_like
            The coarse frames.
        K : int, optional
            Default ``V.shape[0] - 1``.
        bc : {"natural", "hermite", "periodic"}
            As given to :meth:`decode`.
        rings, taper : int
            Spatial and temporal width of the fade.
        max_rounds : int
            At most this many rounds; fewer when :data:`GUARD_PATIENCE` rounds in a row do
            not improve on the best.
        fallback : (K+1,n,3) float array_like, optional
            Positions to fade towards instead of the base surface, in the same placement as
            ``V`` (e.g. the prolonged sequence that a full-resolution refinement started
            from): ``V0 + f (fallback − V0)`` for the fade ``f`` of each vertex-frame.

        Returns
        -------
        V : (K+1,n,3) float64 numpy array
            A new array; keyframes and pinned vertices unchanged.
        record : dict
            ``new_defects_before`` / ``new_defects_after`` (``flipped``, ``folded``,
            ``collapsed``: counts not inherited from the coarse frames), ``rounds``, ``faded``
            (vertex-frames whose detail was reduced).
        """
        V = np.asarray(V, dtype=np.float64)
        Vc = np.asarray(Vc, dtype=np.float64)
        K = V.shape[0] - 1 if K is None else int(K)
        if V.shape != (K + 1, self.n_vertices, 3) or Vc.shape != (K + 1, self.kept.shape[0], 3):
            raise ShellsplineError(f"`V` and `Vc` must have shapes ({K + 1}, {self.n_vertices}, 3)"
                                   f" and ({K + 1}, {self.kept.shape[0]}, 3), got {V.shape} and "
                                   f"{Vc.shape}")
        if self.coarse_F is None:
            raise ShellsplineError("guard needs the coarse faces (encode from a Decimation)")
        if fallback is None:  # the base surface, only of the frames that fade, each once
            cache = {}

            def fallback(ks):
                need = [int(k) for k in ks if int(k) not in cache]
                if need:
                    cache.update(zip(need, self.base(Vc[need])))
                return np.stack([cache[int(k)] for k in ks])
        return fade_new_defects(V, Vc, topology(self.F, self.n_vertices),
                                topology(self.coarse_F, self.kept.shape[0]), self.collapse_map,
                                self.frames, fallback, bc=bc, rings=rings, taper=taper,
                                max_rounds=max_rounds, pinned=self.pinned,
                                pinned_at=self.keyframes[0, self.pinned])


#: The gradient transfer's anchor weight of a coarse vertex, relative to the mean diagonal of
#: the edge Laplacian (see :class:`_GradientTransfer`).
ANCHOR = 1e-3


class _GradientTransfer:
    """The gradient-domain decode of :class:`Prolongation` (``transfer="gradient"``).

    Every fine edge ``e = (a, b)`` keeps its keyframe vector ``g_e^j = x_b^j − x_a^j`` in the
    base frames of both its vertices, ``α_e^j = R_a(S_j)ᵀ g_e^j`` and ``β_e^j = R_b(S_j)ᵀ g_e^j``.
    A frame ``k`` rotates the time-interpolated coordinates back,
    ``h_e(k) = ½ (R_a(S_k) α_e(k) + R_b(S_k) β_e(k))``, and fits the positions to these edge
    vectors in two steps:

    1. ``x̃ = argmin Σ_e w_e ‖x_b − x_a − h_e‖² + ε Σ_kept ‖x_c − Vc_c‖²`` (pinned vertices
       held), ``w`` the base's edge weights (:func:`_edge_weights`), ``ε`` = :data:`ANCHOR`
       times the mean diagonal of ``L = Dᵀ W D``: ``(L + ε P) x̃ = Dᵀ W h + ε P Vc``, one
       factorization for all frames;
    2. ``x = x̃ + c``, the misfit at the coarse vertices ``Vc − x̃_kept`` spread by the same
       bi-Laplacian interpolation as the base surface (coarse and pinned vertices exact).

    Why not hold the coarse vertices in step 1: a point constraint in a Laplacian fit pulls a
    spike (the misfit concentrates in the vertex's first rings): on
    ``data_synth.stress.dense_slivers`` (24 192 vertices, 1000 coarse) 69 % of the new
    flipped faces had a coarse vertex (12 % of all faces do), and fading them onto the base
    surface could not remove them. At a keyframe ``h = g``: the keyframe is the exact
    solution of both steps.
    """

    def __init__(self, Vs, R, E, w, L, is_kept, pin, B, base, backend):
        n, ne = is_kept.shape[0], E.shape[0]
        self.n, self.E = n, E
        held = pin & ~is_kept
        self.pinned = np.flatnonzero(held)
        self.kept = np.flatnonzero(is_kept)
        self.free = np.flatnonzero(~held)                   # the coarse vertices are anchored
        rows = np.r_[np.arange(ne), np.arange(ne)]
        D = sp.csr_matrix((np.r_[-np.ones(ne), np.ones(ne)], (rows, np.r_[E[:, 0], E[:, 1]])),
                          shape=(ne, n))
        DtW = (D.T @ sp.diags(w)).tocsr()                   # (n, ne); DtW @ D is the base's L
        eps = ANCHOR * float(L.diagonal().mean()) if n else 0.0
        anchor = np.zeros(n)
        anchor[is_kept] = eps
        Lf = (L + sp.diags(anchor)).tocsr()[self.free]
        self.DtW_f = DtW[self.free]
        self.anchor_f = anchor[self.free]
        self.L_fp = Lf[:, self.pinned].tocsr()
        self.solver = SparseCholesky(Lf[:, self.free].tocsc(), backend=backend) \
            if self.free.size else None
        # the bi-Laplacian spread of the misfit: the base surface's own solver, unless
        # pinned vertices that are not coarse vertices must stay too
        if self.pinned.size:
            rest = np.flatnonzero(~(is_kept | pin))
            Br = B[rest]
            self.spread = (rest, SparseCholesky(Br[:, rest].tocsc(), backend=backend)
                           if rest.size else None, Br[:, self.kept].tocsr())
        else:
            self.spread = base
        g = Vs[:, E[:, 1]] - Vs[:, E[:, 0]]                              # (J, ne, 3)
        self.alpha = np.stack([np.einsum("jei,jei->je", a[:, E[:, 0]], g) for a in R], axis=-1)
        self.beta = np.stack([np.einsum("jei,jei->je", a[:, E[:, 1]], g) for a in R], axis=-1)

    def solve(self, frame_vectors, Wk, Vc, rest_pose):
        """Positions ``(n,B,3)`` of ``B`` frames: ``frame_vectors`` the base frames ``t, b, n``
        (each ``(n,B,3)``), ``Wk (B,J)`` their time weights, ``Vc (B,nc,3)`` the coarse
        poses, ``rest_pose (n,3)`` a keyframe (for pinned vertices)."""
        E, kept = self.E, self.kept
        nb = Wk.shape[0]
        h = np.zeros((E.shape[0], nb, 3))
        for end, coef in ((E[:, 0], self.alpha), (E[:, 1], self.beta)):
            c = np.einsum("kj,jea->eka", Wk, coef)                       # (ne, B, 3)
            for axis, a in enumerate(frame_vectors):
                h += a[end] * c[..., axis:axis + 1]
        h *= 0.5
        Vt = Vc.transpose(1, 0, 2)                                        # (nc, B, 3)
        x = np.zeros((self.n, nb, 3))
        x[kept] = Vt
        if self.pinned.size:
            x[self.pinned] = rest_pose[self.pinned, None]
        if self.free.size:
            rhs = self.DtW_f @ h.reshape(E.shape[0], 3 * nb)
            rhs += self.anchor_f[:, None] * x[self.free].reshape(self.free.shape[0], 3 * nb)
            if self.pinned.size:
                rhs -= self.L_fp @ x[self.pinned].reshape(self.pinned.shape[0], 3 * nb)
            x[self.free] = self.solver.solve(rhs).reshape(self.free.shape[0], nb, 3)
        r = (Vt - x[kept]).reshape(kept.shape[0], 3 * nb)
        x[kept] = Vt
        rest, solver, B_rk = self.spread
        if rest.size:
            x[rest] -= solver.solve(B_rk @ r).reshape(rest.shape[0], nb, 3)
        return x


#: The guard stops after this many rounds in a row without fewer new defects than its best
#: round (which it returns). Where the fallback has defects of its own everywhere, fading only
#: adds them: the horse subdivided twice (135k vertices, 1174 coarse) went 528 → 10 383 new
#: defects over five rounds and 4 811 after ten, 66 s of guard for the unchanged input.
GUARD_PATIENCE = 3


def fade_new_defects(V, Vc, T: Topology, Tc: Topology, collapse_map, frames, fallback, *,
                     bc: str = "natural", rings: int = 2, taper: int = 2, max_rounds: int = 20,
                     pinned=None, pinned_at=None):
    """Fade a fine sequence towards ``fallback`` where it has a defect that the coarse
    sequence it came from does not have (the loop of :meth:`Prolongation.guard`).

    Parameters
    ----------
    V : (K+1,n,3) float array_like
        Fine sequence (keyframes at ``frames``).
    Vc : (K+1,nc,3) float array_like
        The coarse sequence.
    T, Tc : Topology
        Fine and coarse connectivity.
    collapse_map : (n,) int array_like
        Coarse vertex of every fine vertex (:attr:`~shellspline.mesh.decimate.Decimation.collapse_map`).
    frames : (J,) int array_like
    fallback : (K+1,n,3) float array_like, or callable
        What a faded vertex moves towards, in the placement of ``V``: ``V + f (fallback − V)``;
        a callable ``fallback(ks)`` returns the ``(len(ks),n,3)`` positions of frames ``ks``
        (computed only for frames that need them).
    bc, rings, taper, max_rounds
        See :meth:`Prolongation.guard`.
    pinned : (p,) int array_like, optional
        Vertices reset to ``pinned_at`` ((p,3)) after every round.

    Returns
    -------
    V : (K+1,n,3) float64 numpy array
    record : dict
        As :meth:`Prolongation.guard`.
    """
    V = np.array(V, dtype=np.float64)
    Vc = np.asarray(Vc, dtype=np.float64)
    K = V.shape[0] - 1
    if V.ndim != 3 or V.shape[1:] != (T.n_vertices, 3) or \
            Vc.shape != (K + 1, Tc.n_vertices, 3):
        raise ShellsplineError(f"`V` and `Vc` must have shapes ({K + 1}, {T.n_vertices}, 3) and "
                               f"({K + 1}, {Tc.n_vertices}, 3), got {V.shape} and {Vc.shape}")
    if not callable(fallback):
        fallback = np.asarray(fallback, dtype=np.float64)
        if fallback.shape != V.shape:
            raise ShellsplineError(f"`fallback` must have the shape of `V` {V.shape}, got "
                                   f"{fallback.shape}")
    frames = np.asarray(frames, dtype=np.int64)
    pinned = np.zeros(0, dtype=np.int64) if pinned is None else np.asarray(pinned, np.int64)
    V0 = None  # the input, copied when the first vertex fades
    periodic = str(bc).lower() == "periodic"
    n, nc = T.n_vertices, Tc.n_vertices
    # coarse vertices near a coarse defect of each step (one coarse ring of slack)
    cbad = _defect_vertices(DefectRules(Vc[frames], Tc, frames, K, bc).scan(Vc), Tc, K)
    cbad = np.asarray((_adjacency(Tc.E, nc) @ cbad.T.astype(np.float64)) > 0).T  # (K, nc)
    allowed = cbad[:, np.asarray(collapse_map, dtype=np.int64)]                  # (K, n)
    is_key = np.zeros(K + 1, dtype=bool)
    is_key[frames] = True
    is_key[K] |= periodic
    gap = np.cumsum(is_key)                                           # gap id per frame
    A = _adjacency(T.E, n)
    fade = np.zeros((K + 1, n))
    before = best = None
    rules = DefectRules(V[frames], T, frames, K, bc)  # keyframes never fade
    found = rules.scan(V)
    for rounds in range(max_rounds + 1):
        new, bad = _new_defects(found, T, allowed)
        total = sum(new.values())
        if before is None:
            before = new
        if best is None or total < best[0]:
            # fading can move a vertex onto a fallback (the base surface) that has a defect of
            # its own: the sequence with the fewest new defects is returned
            best = (total, V.copy() if rounds < max_rounds and bad.any() else V, new,
                    int((fade > 0).sum()), rounds)
        bad[is_key] = False
        if rounds == max_rounds or not bad.any() or rounds - best[4] >= GUARD_PATIENCE:
            break
        # spread over rings (linear) and frames (linear, same gap)
        level, reach = bad.astype(np.float64), bad
        for r in range(1, rings + 1):
            reach = np.asarray((A @ reach.T.astype(np.float64)) > 0).T
            level = np.maximum(level, reach * (1.0 - r / (rings + 1)))
        spread = level.copy()
        for dk in range(1, taper + 1):
            w = 1.0 - dk / (taper + 1)
            same = gap[dk:] == gap[:-dk]
            spread[dk:] = np.maximum(spread[dk:], w * level[:-dk] * same[:, None])
            spread[:-dk] = np.maximum(spread[:-dk], w * level[dk:] * same[:, None])
        spread[is_key] = 0.0
        grown = spread > fade
        if not grown.any():
            break
        fade = np.maximum(fade, spread)
        todo = np.flatnonzero(grown.any(axis=1))
        target = fallback(todo) if callable(fallback) else fallback[todo]
        if V0 is None:
            V0 = V.copy()
        V[todo] = V0[todo] + fade[todo, :, None] * (target - V0[todo])
        if pinned.size:
            V[:, pinned] = pinned_at
        # only the steps next to a changed frame can change: scan those again
        steps = np.union1d(todo - 1, todo)
        found = _rescanned(found, rules.scan(V, steps[(steps >= 0) & (steps < K)]))
    _, V, after, faded, kept_round = best
    return V, {"new_defects_before": before, "new_defects_after": after,
               "rounds": int(kept_round), "faded": faded}


def _cross(a, b):
    """:func:`~shellspline.mesh.geometry.cross` of two equally shaped ``(..., 3)`` arrays, the
    same products and differences written into one output (no per-component temporaries and
    no stacking: the decode's two cross products per batch of frames take half the time)."""
    out = np.empty(a.shape)
    tmp = np.empty(a.shape[:-1])
    for i, j, k in ((0, 1, 2), (1, 2, 0), (2, 0, 1)):
        o = out[..., i]
        np.multiply(a[..., j], b[..., k], out=o)
        np.multiply(a[..., k], b[..., j], out=tmp)
        np.subtract(o, tmp, out=o)
    return out


def _adjacency(E, n):
    """Sparse ``(n, n)`` vertex adjacency of the edges ``E`` with the identity."""
    return (sp.coo_matrix((np.ones(2 * E.shape[0]), (np.r_[E[:, 0], E[:, 1]],
                                                     np.r_[E[:, 1], E[:, 0]])), shape=(n, n))
            + sp.identity(n)).tocsr()


def _defect_vertices(d, T, K):
    """(K, n) bool: vertices of an element with any defect of a
    :meth:`~shellspline.shells.defects.DefectRules.scan` ``d`` in step ``k`` (a collapsed
    face counts in both steps next to its frame)."""
    out = np.zeros((K, T.n_vertices), dtype=bool)
    k, t = d["flipped"].T
    out[k[:, None], T.F[t]] = True
    k, e = d["folded"].T
    out[k[:, None], T.flaps[e]] = True
    k, t = d["collapsed"].T
    out[np.maximum(k - 1, 0)[:, None], T.F[t]] = True
    inside = k < K
    out[k[inside, None], T.F[t[inside]]] = True
    return out


def _new_defects(d, T, allowed):
    """Defects of a :meth:`~shellspline.shells.defects.DefectRules.scan` ``d`` with no vertex
    in ``allowed`` ((K, n) bool, per step): counts and the (K+1, n) bool mask of their
    vertices in the frames involved."""
    K = allowed.shape[0]
    bad = np.zeros((K + 1, T.n_vertices), dtype=bool)
    at_frame = np.zeros((K + 1, T.n_vertices), dtype=bool)
    at_frame[:-1] |= allowed
    at_frame[1:] |= allowed
    count = {}
    for key, verts, ok, span in (("flipped", T.F, allowed, 2), ("folded", T.flaps, allowed, 2),
                                 ("collapsed", T.F, at_frame, 1)):
        k, x = d[key].T
        vx = verts[x]                                           # (r, 3 or 4)
        new = ~ok[k[:, None], vx].any(axis=1)
        k, vx = k[new, None], vx[new]
        for dk in range(span):
            bad[k + dk, vx] = True
        count[key] = int(new.sum())
    return count, bad


def _rescanned(found, part):
    """The defect lists ``found`` with the steps and frames that ``part`` (a scan of some
    steps) looked at replaced by ``part``'s."""
    out = {}
    for key in ("flipped", "folded", "collapsed"):
        rows = found[key]
        # flips and folds are listed by step, collapsed faces by frame
        seen = np.isin(rows[:, 0], part["frames"] if key == "collapsed" else part["steps"])
        out[key] = np.concatenate([rows[~seen], part[key]])
    return out


def _edge_weights(Vs, E):
    """Laplacian weights ``1 / l̄_e`` of the edges ``E (e,2)``, ``l̄_e`` the edge's length
    averaged over the keyframes ``Vs (J,n,3)`` (floored at 1e-3 of the mean length), scaled
    to mean 1.

    With uniform weights the fair base surface of an irregular mesh drifts tangentially from
    the fine surface: on the horse (8.4k vertices, 1000 coarse) the encoded details reach
    2.7 mean edge lengths (0.42 on average), and small rotations of the local frames move
    such long detail vectors across their neighbours (167 flipped faces and 89 folded edges
    after prolonging a coarse result with 39 flipped coarse faces). Weights ``1 / l`` halve
    the details (max 1.3, mean 0.23) and give 119 flipped faces and 18 folded edges; uniform,
    cotangent, ``1 / l²`` and ``1 / √l`` weights were measured and are worse.
    """
    d = Vs[:, E[:, 1]] - Vs[:, E[:, 0]]
    ln = np.sqrt(np.einsum("jei,jei->je", d, d)).mean(axis=0)
    if ln.size == 0:
        return ln
    mean = float(ln.mean())
    if not mean > 0:
        return np.ones_like(ln)
    w = 1.0 / np.maximum(ln, 1e-3 * mean)
    return w / w.mean()


def prolong(Vc, Vs_fine, F_fine, dec: Decimation, frames=None, *, pinned=None,
            time_weights="linear", bc: str = "natural",
            transfer: str = DEFAULT_TRANSFER) -> np.ndarray:
    """One-call detail transfer: :meth:`Prolongation.encode` then :meth:`~Prolongation.decode`.

    Parameters
    ----------
    Vc : (K+1,nc,3) float array_like
        Coarse sequence.
    Vs_fine : (J,n,3) float array_like
        Fine keyframes.
    F_fine : (m,3) int array_like
    dec : Decimation
    frames : (J,) int array_like, optional
    pinned : optional
    time_weights, bc
        See :meth:`Prolongation.decode`.
    transfer : {"gradient", "displacement"}
        See :meth:`Prolongation.encode`.

    Returns
    -------
    (K+1,n,3) float64 numpy array
    """
    P = Prolongation.encode(Vs_fine, F_fine, dec, frames, pinned=pinned, transfer=transfer)
    return P.decode(Vc, time_weights=time_weights, bc=bc)

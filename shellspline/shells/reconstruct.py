"""Gauss–Newton reconstruction of vertex positions from LΘA descriptors (paper eq. 12).

For a target ``z* = (L*, Θ*, A*)`` and weights ``w`` we minimise

    f(s) = Σ_i w_i r_i(s)²,   r = z[s] - z*   (Θ residuals wrapped to [-π, π)),

by Gauss–Newton: each step solves ``(Jᵀ W J + δ I) p = -Jᵀ W r`` with preconditioned conjugate
gradients, where the preconditioner is a sparse Cholesky factorization of the Gauss–Newton
matrix at some earlier iterate. The pattern of ``Jᵀ W J`` is the same for every iteration and
frame, so one factorization (and one symbolic analysis) serves many steps and frames; it is
refreshed only when CG stops converging quickly. A backtracking line search on ``f`` makes
every accepted step decrease the energy and rejects steps that collapse a triangle.

A factorization costs about as much as 12–17 CG iterations (8.4k vertices), so a cached one
that has not converged after ``2 refresh_cg`` iterations is refreshed at once and the solve
repeated (one iteration with a fresh factor) rather than run to ``cg_max_iter``; and where
the cached factor failed at a frame's start or after a large step (``f`` down by more than
:data:`STALE_DECREASE`) the last time, it is refreshed there without a try. On the horse
such iterates are common (the first two steps of every warm-started frame move the pose so
far that 40 CG iterations did not reach ``cg_tol``). Horse pair, first pass, one worker:
2347 → 940 CG iterations, 80 → 75 factorizations, 40 → 25 s of CPU (with the rate test of
:data:`SUBSPACE_RATE`: 203 → 169 iterations); the cactus keeps its 58 iterations and 20
factorizations (452 → 352 CG iterations). Both passes, one worker: the pair 220 → 170
iterations (median 10 → 7), 37.2 → 27.5 s of CPU; the three keyframes 411 → 359 (median
10 → 8), 4152 → 2137 CG iterations, 142 → 152 factorizations, 84.9 → 65.7 s; the same
defects.

On real meshes the keyframe descriptors are far from integrable: the residual at the minimum
is large, and the term ``Σ w ρ ∇²ρ`` of the Hessian that Gauss–Newton drops is comparable to
``Jᵀ W J`` (on the horse, 8.4k vertices, the Hessian's eigenvalues relative to ``Jᵀ W J``
spread over [0.4, 1.7] at a solved frame), so Gauss–Newton converges only linearly there, by
a factor of ~0.4 per iteration. Where the last step's secant curvature shows this, the step
is replaced by the minimiser of the second-order model on the plane of the Gauss–Newton step
and the last step (:meth:`GaussNewton.subspace_step`: one extra gradient evaluation; the
search of nonlinear CG preconditioned by ``Jᵀ W J``), in a frame's tail only (see
:data:`SUBSPACE_TAIL`). Horse (``benchmarks/bench_gn.py``, workers 2):
keyframes ``horse-reference, horse-03`` at frames 0, 20, 193 instead of 270 iterations
(median 10 instead of 12, at most 23 instead of 29), every frame converged (18 of 19 before);
with ``horse-07`` at 40, 419 instead of 618 (median 10 instead of 13, at most 24 instead of
52), 38 of 38 frames converged (35 before), 38 s instead of 43 s; the same defects. Full Newton steps
do not pay: the Hessian is indefinite along a mode spread over hundreds of vertices until
close to the solution on most horse frames.

The factorization is *rotated* to the current pose: the descriptors are invariant under
rotations, so if the pose moved from ``s_a`` (where ``H_a = J_aᵀ W J_a`` was factored) to
``s_b`` by local rotations ``R_v`` (one per vertex, fitted to its edges by polar
decomposition), then ``J_b ≈ J_a Rᵀ`` and ``H_b ≈ R H_a Rᵀ`` with ``R = blockdiag(R_v)``; the
preconditioner applies ``R H_a⁻¹ Rᵀ``. For a thin shell (membrane much stiffer than bending)
an unrotated factor from a pose a few degrees away is a poor preconditioner (its stiff
membrane directions point the wrong way: CG hits its limit and the factor must be rebuilt);
rotated, it stays good across Gauss–Newton iterations and neighbouring frames, so large
meshes rarely refactor. The rotations are fitted once per frame (at its initial guess) and
kept for its Gauss–Newton steps unless a vertex moves by more than a quarter of the mean edge
length: the steps inside a warm-started frame are small non-rigid corrections, and rotations
fitted to them made CG slower (154k vertices: 24 CG iterations instead of 13 for the second
step of a frame).

Rigid motions are in the kernel of ``f``: they are removed by pinned vertices when given, and
otherwise by the small Levenberg–Marquardt term ``δ I`` (steps never move along the kernel
because the gradient is orthogonal to it); :func:`rigid_placement` then places each frame.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from ..errors import ShellsplineError, tol
from ..mesh.rigid import rigid_modes
from ..mesh.topology import Topology
from ..numerics.krylov import pcg
from ..numerics.linalg import SparseCholesky, available_backends, nested_dissection
from ..numerics.linesearch import backtracking
from ..numerics.result import SolverResult
from .descriptors import lta_descriptors, lta_jacobian, wrap_angle

__all__ = ["GaussNewton", "ReconstructionResult", "reconstruct", "rigid_placement", "rigid_complement",
           "ANGLE_TUBE"]

#: Vertex count above which :class:`GaussNewton` rotates its cached preconditioner and refreshes
#: it less eagerly (both pay off only when a factorization costs many solves).
LARGE_MESH = 20_000

#: Half-width (radians) of the tube around a dihedral-angle target outside which an angle
#: with a tube weight (``solve(..., tube=)``) pays that weight on its distance to the tube:
#: see :meth:`GaussNewton.merit`.
ANGLE_TUBE = 1.0

#: :class:`GaussNewton` with ``subspace=True`` replaces a step by
#: :meth:`GaussNewton.subspace_step` only where the previous step's secant curvature differs
#: from its Gauss–Newton curvature by more than this fraction (a large-residual frame). At
#: 0.05 the steps of the ellipsoids of paper Fig. 3 (periodic) changed too and their half-axes
#: moved by 1.6e-4 (the regression pipeline allows 1.3e-4); at 0.2 they are bit-identical
#: while the horse keeps its gain.
SUBSPACE_GATE = 0.2

#: ... and only in a frame's tail: once the last step decreased ``f`` by less than this fraction.
#: Earlier, while the iterate still moves between basins, the previous step's momentum can
#: carry it into a worse local minimum (a 100-vertex skinned walk closed with C¹: the last
#: frame, which Gauss–Newton solves exactly, stopped at energy 0.21 without this test).
SUBSPACE_TAIL = 0.01

#: ... and also where the last two decreases of ``f`` shrank by less than this factor (a slow
#: linear tail whose curvature the secant test finds well modelled: on the horse, frames
#: next to a keyframe decrease by a steady ~0.55 per step there). Horse pair, first pass:
#: 169 instead of 182 iterations (median 7 instead of 8); ``data_synth.stress.slivers`` 14
#: instead of 19; the ellipsoids of the regression pipeline are bit-identical (their steps
#: never reach a slow tail), the cactus unchanged.
SUBSPACE_RATE = 0.25

#: A Gauss–Newton step that decreased ``f`` by more than this fraction is a large step: it
#: can move the pose so far that the cached factorization no longer preconditions CG (horse,
#: 8.4k vertices: the next solve did not reach ``cg_tol`` in 40 iterations after a 37 %
#: decrease, and needed 4–8 after 0.3–4 %). Where that happened after the last large step
#: (or at the last frame's start), :class:`GaussNewton` refactors without trying the old
#: factor (unrotated factors only).
STALE_DECREASE = 0.1


@dataclass(kw_only=True)
class ReconstructionResult(SolverResult):
    """Outcome of one Gauss–Newton reconstruction (a :class:`~shellspline.numerics.result.
    SolverResult`).

    Attributes
    ----------
    V : (n,3) float64 array
        Reconstructed vertex positions.
    status : {"converged", "stalled", "limit", "failed"}
        ``"converged"``: ``|g| <= gtol |g_0|`` (or the gradient is at the energy's round-off
        level); ``"stalled"``: the line search failed or the energy stopped decreasing before
        that; ``"limit"``: the iteration limit; ``"failed"``: a degenerate initial guess.
        ``success`` is ``status == "converged"``.
    iterations : int
        Gauss–Newton iterations performed (also ``nit``).
    message : str
        Which test stopped the iteration.
    energies : (it+1,) float64 array
        ``f`` at the initial guess and after each iteration.
    grad_norms : (it+1,) float64 array
        ``|Jᵀ W r|`` at the same points.
    cg_iterations : int
        Total preconditioned-CG iterations.
    factorizations : int
        Numeric factorizations done during this reconstruction.
    """

    V: np.ndarray
    cg_iterations: int = 0
    factorizations: int = 0

    def summary(self) -> dict:
        """JSON-friendly record (no arrays)."""
        return {**super().summary(), "cg_iterations": int(self.cg_iterations),
                "factorizations": int(self.factorizations)}


class GaussNewton:
    """Precomputed Gauss–Newton solver for one connectivity (STYLE rule 6: precompute + solve).

    Parameters
    ----------
    T : Topology
    pinned : (p,) int array, optional
        Vertices held at their initial positions (e.g. the cactus base).
    backend : {"auto", "cholmod", "splu"}
        Sparse Cholesky backend for the preconditioner (see :mod:`shellspline.numerics.linalg`).
    max_iter : int
        Gauss–Newton iteration limit per frame.
    ftol : float
        Stalled (not converged) when the relative energy decrease stays below ``ftol`` for
        three iterations while neither gradient criterion holds.
    gtol : float
        Converged when ``|g| <= gtol * |g_0|``.
    dtol : float
        Converged when the Gauss–Newton decrement is below ``dtol`` times the energy:
        ``−gᵀp <= dtol f`` for the (inexact) Gauss–Newton step ``p`` and ``g = JᵀWρ`` (half the
        gradient of ``f = Σ w ρ²``), i.e. the quadratic model predicts no relative decrease
        above ``dtol`` (``λ²/2`` of Newton's method, a
        gradient norm in the metric of the Gauss–Newton matrix; scale-free, and independent of
        how good the initial guess was, unlike ``gtol``).
    damping : float
        Levenberg–Marquardt term relative to the mean diagonal of ``Jᵀ W J``.
    cg_tol : float
        Relative residual of the inner CG solves (inexact Gauss–Newton); with ``forcing``
        the floor of the forcing term.
    forcing : float
        Forcing term of the inexact Gauss–Newton steps (Eisenstat and Walker's choice 2,
        SIAM J. Sci. Comput. 17, 1996): after a frame's first step CG stops at the relative
        residual ``max(cg_tol, min(cg_tol_max, forcing (‖g_k‖/‖g_{k−1}‖)²))``: looser where
        Gauss–Newton converges only linearly (a tighter inner solve buys no outer
        progress there), ``cg_tol`` where it converges fast; 0 keeps ``cg_tol`` throughout.
        Default 0.9. Where the decrement test passes on a loose solve, the solve is continued
        to ``cg_tol`` first (a truncated CG underestimates ``-g·p``), so frames are judged as
        before. Measured with ``refresh_cg`` 6 (``benchmarks/bench_gn.py``, workers 2, two
        rounds, 2026-11-29): the horse (``horse-reference, 03, 07`` at 0, 20, 40, full
        resolution) 2335 → 1909 CG iterations, 382 → 388 Gauss–Newton iterations (median 8),
        CPU 64.6 → 59.8 s, wall 41.7 → 37.9 s, the same defects; at ``coarse=1000``
        (one worker) 22 % and 25 % fewer CG iterations, CPU 5.4 → 4.4 s (three poses) and
        6.0 → 5.9 s (five); the cactus keeps its 59 iterations (the forcing term alone
        changes nothing there: its gradients drop fast, the floor holds; ``refresh_cg`` 6:
        316 instead of 362 CG iterations, 24 instead of 20 factorizations), the skinned
        bodies of ``bench_real.py`` their errors (to 1e-5).
    cg_tol_max : float
        Ceiling of the forcing term. 0.1 saved 4 % more of the horse's CPU time, but on
        ``data_synth.stress.slivers`` took 245 Gauss–Newton iterations against 222 (0.05:
        227), where the warm-start chain is chaotic and a start of lower energy no longer
        led to fewer iterations (``tests/shells/test_prolong.py``); 0.2 added Gauss–Newton
        iterations on the horse.
    cg_max_iter : int
        CG iteration limit; hitting it marks the preconditioner as stale.
    refresh_cg : int, optional
        A CG solve that needs more iterations than this marks the preconditioner as stale:
        the next Gauss–Newton step refactors at its iterate (numeric factorization only; the
        symbolic analysis is done once). Default: ``8 √(n / 20 000)`` rounded, at least 6
        (6 up to 11 000 vertices, 8 at 20 000, 22 at 150 000), because a factorization costs
        more solves the larger the mesh (measured: about 15 solves at 20k vertices, 40 at
        150k). 8 was the floor before the ``forcing`` term; with it, 6 saved a further 5 %
        of the horse's CPU time (the looser solves hide less of a stale factor's need for a
        refresh) and changed nothing on the cactus.
    ordering : {"auto", "amd", "nd"}
        Fill-reducing order of the factorization (``cholmod`` backend): ``"amd"`` CHOLMOD's
        approximate minimum degree, ``"nd"`` geometric nested dissection of the vertex graph
        (:func:`shellspline.numerics.linalg.nested_dissection`, computed once per solver at the
        first factored pose; CHOLMOD keeps it only where it fills less than its AMD).
        Default: ``"nd"`` above 20 000 vertices (154k-vertex synthetic cactus: 15 % fewer
        nonzeros in the factor, 1.6 GB instead of 2.0 GB, numeric factorization 1.5x and
        triangular solves 13 % faster; the ordering itself takes ~2.5 s), ``"amd"`` below.
    amortize_refresh : bool, optional
        Also refactor at the start of a frame when the previous frame needed more CG
        iterations than this factor's average per frame, the factorization counted as
        ``refresh_cg`` iterations: the per-frame cost grows as warm-started frames move away
        from the factored pose, and refactoring when it passes the running average keeps the
        average smallest. Default: on above 20 000 vertices (154k-vertex synthetic cactus,
        ``fine=True``: a refactorization every 3–5 frames instead of every 10–12, 25 % fewer
        CG iterations in all).
    rotate_preconditioner : bool, optional
        Apply the cached factorization rotated by the per-vertex rotations from the pose it
        was computed at to the current pose (see the module notes); ``False`` applies it
        as is. Default: on above 20 000 vertices (measured on the 154k-vertex synthetic
        cactus, K = 50, ``fine=True``: 10–26 s per frame and one frame in five refactoring,
        against ~80 s and two factorizations per frame before; on the 5.2k cactus the
        rotations cost more than the CG iterations they save).
    subspace : bool
        Take the minimiser of the second-order model of ``f`` (with the term Gauss–Newton
        drops) on the plane of the Gauss–Newton step and the previous step instead of the
        Gauss–Newton step itself (see :meth:`subspace_step`). Default on.
    """

    def __init__(self, T: Topology, *, pinned=None, backend: str = "auto", max_iter: int = 60,
                 ftol: float = 1e-6, gtol: float = 1e-5, damping: float = 1e-8,
                 cg_tol: float = 1e-2, cg_max_iter: int = 40, refresh_cg: int | None = None,
                 dtol: float = 2e-6, forcing: float = 0.9, cg_tol_max: float = 0.05,
                 rotate_preconditioner: bool | None = None, ordering: str = "auto",
                 amortize_refresh: bool | None = None, subspace: bool = True):
        self.T = T
        self.subspace = bool(subspace)
        self.backend = backend
        self.max_iter = int(max_iter)
        self.ftol, self.gtol, self.dtol = float(ftol), float(gtol), float(dtol)
        self.damping = float(damping)
        self.cg_tol, self.cg_max_iter = float(cg_tol), int(cg_max_iter)
        self.forcing, self.cg_tol_max = float(forcing), float(cg_tol_max)
        self.refresh_cg = int(refresh_cg) if refresh_cg is not None else \
            max(6, int(round(8 * np.sqrt(T.n_vertices / LARGE_MESH))))
        self.rotate_preconditioner = T.n_vertices > LARGE_MESH if rotate_preconditioner is None \
            else bool(rotate_preconditioner)
        self.amortize_refresh = T.n_vertices > LARGE_MESH if amortize_refresh is None \
            else bool(amortize_refresh)
        self._cycle, self._last_cg = None, 0
        self._stale_at = {}  # kinds of iterate where the cached factor failed (see solve)
        ordering = str(ordering).lower()
        if ordering not in ("auto", "amd", "nd"):
            raise ShellsplineError(f"`ordering` must be 'auto', 'amd' or 'nd', got {ordering!r}")
        if ordering == "auto":
            ordering = "nd" if T.n_vertices > LARGE_MESH else "amd"
        self.ordering = ordering
        self._perm = None  # DOF elimination order (ordering="nd"), see _dof_order
        self._x_fact = None  # pose (3n,) at which the cached factorization was computed
        self._h = None  # mean edge length there (scale of "moved" for the rotations)
        self._incidence = None
        N = 3 * T.n_vertices
        self.pinned = np.unique(np.asarray(pinned, dtype=np.int64)) if pinned is not None \
            and len(pinned) else np.zeros(0, dtype=np.int64)
        self._dof_pinned = np.zeros(N, dtype=bool)
        self._dof_pinned[(3 * self.pinned[:, None] + np.arange(3)).ravel()] = True
        self._free = ~self._dof_pinned
        self._chol: SparseCholesky | None = None
        self._asm = None
        self._stale = True
        sl = T.descriptor_slices()
        self._sL, self._sT, self._sA = sl

    def reset(self) -> None:
        """Refactor at the next iterate: the next :meth:`solve` no longer depends on the frames
        this solver solved before (the cached preconditioner only changes the inexact steps,
        but those reach the converged frame by different paths)."""
        self._stale = True
        self._last_cg = 0
        self._stale_at = {}

    def prepare(self, V) -> None:
        """Build what every later :meth:`solve` reuses, now: the assembly pattern and the DOF
        elimination order (computed from the pose ``V (n,3)``). Call it before forking worker
        processes so that they inherit both instead of each building them."""
        self._assembler()
        self._dof_order(np.asarray(V, dtype=np.float64).ravel())

    # -- pieces -------------------------------------------------------------------------
    def merit(self, z, z_target, w, tube=None):
        """The reconstruction energy and its Gauss–Newton form at descriptors ``z``.

        Parameters
        ----------
        z, z_target : (e+i+m,) float64 arrays
            Descriptors of the iterate and the target.
        w : (e+i+m,) float64 array
            Weights.
        tube : (i,) float64 array, optional
            Tube weights of the dihedral angles (0: none; see the notes).

        Returns
        -------
        f : float
            ``Σ w ρ²`` (plus the tube terms).
        r_eff, w_eff : (e+i+m,) float64 arrays
            ``Jᵀ (w_eff r_eff)`` is half the gradient of ``f`` and ``Jᵀ W_eff J`` its
            Gauss–Newton matrix (``J`` the descriptor Jacobian).

        Notes
        -----
        ``ρ = z − z*`` (paper eq. 12) except:

        - angle residuals are wrapped to ``[−π, π)`` (the spline's targets keep off ±π, see
          :func:`shellspline.shells.descriptors.consistent_angles`; following each angle continuously
          instead was measured on the horse and gave 5x more flipped triangles: it holds flaps
          that the initial guess has on the wrong side of ±π there);
        - a triangle compressed below its target (``a < a*``) has ``ρ = (a − a*) √(a*/a)``:
          equal value and slope at ``a = a*``, unchanged for ``a ≥ a*``, and a barrier that
          grows like ``1/a`` as the triangle collapses. Without it the line search stalled
          against its no-collapse guard on the horse (gradients up to 3e4 at "converged"
          frames, 29 collapsed triangles); starting the barrier only at a quarter of the
          target area stalled on 23 of 38 horse frames (the full form conditions the
          Gauss–Newton matrix of compressed triangles). It moves the ellipsoids of paper
          Fig. 3 by at most 6e-4 of a half-axis.

        An angle with a tube weight ``w_t > 0`` also pays ``w_t d²``, ``d`` its distance to the
        tube ``[θ* − τ, θ* + τ]`` (``τ`` = :data:`ANGLE_TUBE`, the angle on the branch nearest
        its target): free to leave its target inside the tube at its own (faded) weight, held
        beyond it (see :func:`shellspline.pipeline.describe.tube_weights` for why). The term
        is C¹ and its Gauss–Newton model exact: ``w_eff = w + w_t`` and
        ``r_eff = (w ρ + w_t d) / w_eff`` outside the tube.
        """
        r = z - z_target
        r[self._sT] = wrap_angle(r[self._sT])
        sA = self._sA
        a, at = z[sA], z_target[sA]
        comp = (a < at) & (a > 0)
        w_eff = w
        f_r = r
        if comp.any():
            idx = sA.start + np.flatnonzero(comp)
            g = np.sqrt(at[comp] / a[comp])
            slope = g * (a[comp] + at[comp]) / (2.0 * a[comp])   # dρ/da
            rho = r[idx] * g
            f_r = r.copy()
            f_r[idx] = rho
            w_eff = w.copy()
            w_eff[idx] *= slope * slope
            r = r.copy()
            r[idx] = rho / slope
        f = float(w @ (f_r * f_r))
        if tube is not None:
            sT = self._sT
            e = np.flatnonzero(tube > 0)
            re = r[sT][e]                        # wrapped: the branch nearest the target
            d = re - np.clip(re, -ANGLE_TUBE, ANGLE_TUBE)
            out = d != 0
            if out.any():
                i = sT.start + e[out]
                d, wt = d[out], tube[e[out]]
                f += float(wt @ (d * d))
                w_eff = w_eff.copy() if w_eff is w else w_eff
                wi = w_eff[i]
                r[i] = (wi * r[i] + wt * d) / (wi + wt)
                w_eff[i] = wi + wt
        return f, r, w_eff

    def start_energy(self, V, z_target, weights, tube=None) -> float:
        """The energy :meth:`solve` would start from at pose ``V (n,3)``: ``inf`` where a
        triangle is at or below the line search's collapse floor or the energy is not finite
        (a start to avoid). One descriptor evaluation; used to choose among candidate starts
        (see :func:`shellspline.pipeline.reconstruction.warm_start`)."""
        z_target = np.asarray(z_target, dtype=np.float64)
        w = self.active_weights(z_target, weights)
        with np.errstate(divide="ignore", invalid="ignore"):
            z = lta_descriptors(np.asarray(V, dtype=np.float64), self.T)
        if not np.all(z[self._sA] > self.area_floor(z_target)):
            return np.inf
        f = self.merit(z, z_target, w, tube)[0]
        return f if np.isfinite(f) else np.inf

    def active_weights(self, z_target, weights):
        """A copy of ``weights`` with no weight on non-positive target lengths and areas
        (paper §7)."""
        w = np.array(weights, dtype=np.float64, copy=True)
        w[self._sL][z_target[self._sL] <= 0] = 0.0
        w[self._sA][z_target[self._sA] <= 0] = 0.0
        return w

    def area_floor(self, z_target):
        """The areas no iterate may reach: ``1e-6`` of the target areas."""
        return 1e-6 * np.maximum(z_target[self._sA], 0.0)

    def _assembler(self):
        if self._asm is None:
            self._asm = _LowerAssembler(self.T)
        return self._asm

    def _refresh(self, J, w, x):
        """Factor ``Jᵀ W J + D`` at the current iterate ``x`` (the CG preconditioner)."""
        asm = self._assembler()
        data, diag = asm.values(J.data, w)
        scale = diag[self._free].mean() if self._free.any() else 1.0
        self._delta = self.damping * scale
        data[asm.diag_pos] += np.where(self._dof_pinned, max(scale, 1.0), self._delta)
        if self._chol is None:
            self._chol = SparseCholesky.from_lower_pattern(asm.indptr, asm.indices, asm.N, data,
                                                           backend=self.backend,
                                                           perm=self._dof_order(x))
        else:
            self._chol.refactor_lower(data)
        self._x_fact = np.array(x, dtype=np.float64, copy=True)
        self._stale = False
        # cost of this factor's cycle in CG iterations, the factorization counted as
        # ``refresh_cg`` of them, and the frames it served (see ``solve``)
        self._cycle = [float(self.refresh_cg), 0]

    def _dof_order(self, x):
        """DOF elimination order for the factorization, computed once from the pose ``x``
        (3n,) (None: the backend's own ordering). The vertex graph of ``Jᵀ W J`` is the
        edges plus the two opposite vertices of every flap; each vertex's three DOFs stay
        together."""
        backend = available_backends()[0] if self.backend == "auto" else self.backend
        if self.ordering != "nd" or backend != "cholmod":
            return None
        if self._perm is None:
            T = self.T
            order = nested_dissection(np.asarray(x, dtype=np.float64).reshape(-1, 3),
                                      np.concatenate([T.E[:, 0], T.flaps[:, 2]]),
                                      np.concatenate([T.E[:, 1], T.flaps[:, 3]]))
            self._perm = (3 * order[:, None] + np.arange(3)).ravel()
        return self._perm

    def _rotations(self, x):
        """Per-vertex rotations ``(n,3,3)`` from the factored pose to ``x``, or None when
        ``x`` is that pose (or rotation is switched off)."""
        if not self.rotate_preconditioner or self._x_fact is None or \
                np.array_equal(self._x_fact, x):
            return None
        if self._incidence is None:
            self._incidence = _edge_incidence(self.T.E, self.T.n_vertices)
        return _vertex_rotations(self._x_fact.reshape(-1, 3), x.reshape(-1, 3), self.T.E,
                                 self._incidence, self.T.F)

    def _moved(self, x, x_rot) -> bool:
        """Whether ``x`` moved so far from ``x_rot`` (where the preconditioner's rotations were
        fitted) that they must be fitted again: some vertex moved by more than a quarter of
        the mean edge length of the factored pose."""
        if not self.rotate_preconditioner:
            return False
        if self._h is None:
            X = self._x_fact.reshape(-1, 3)
            E = self.T.E
            self._h = float(np.mean(np.sqrt(np.einsum("ij,ij->i", X[E[:, 1]] - X[E[:, 0]],
                                                      X[E[:, 1]] - X[E[:, 0]]))))
        d = (x - x_rot).reshape(-1, 3)
        return float(np.einsum("ij,ij->i", d, d).max()) > (0.25 * self._h) ** 2

    def _preconditioner(self, x_cur, R="fit"):
        """``v ↦ P v`` with ``P ≈ (JᵀWJ + δI)⁻¹`` at ``x_cur``: the cached factor, rotated
        by the per-vertex rotations ``R (n,3,3)`` (default ``"fit"``: :meth:`_rotations` to
        ``x_cur``; None: not rotated), zero on pinned DOFs and (without pins) off the rigid
        modes of ``x_cur``: a factorization from an earlier pose amplifies *its* rigid modes
        by 1/δ, which are not rigid for the current pose."""
        free = self._free
        project = self._rigid_complement(x_cur) if x_cur is not None else None
        if isinstance(R, str):
            R = self._rotations(x_cur) if x_cur is not None else None
        chol = self._chol

        def precond(v):
            if R is not None:
                v = np.einsum("nji,nj->ni", R, v.reshape(-1, 3)).ravel()  # Rᵀ v
            out = chol.solve(v)
            if R is not None:
                out = np.einsum("nij,nj->ni", R, out.reshape(-1, 3)).ravel()
            out[~free] = 0.0
            return out if project is None else project(out)

        return precond

    def _rigid_complement(self, x):
        """``v ↦ v`` minus its orthogonal projection onto the rigid motions at ``x (3n,)``
        that the pins leave free (all six without pins, none with three non-collinear pins;
        zero on the pinned DOFs), or None where there are none."""
        if not self.pinned.size:
            return rigid_complement(x)
        free = np.flatnonzero(self._free)
        Qf = rigid_modes(x.reshape(-1, 3), free, np.flatnonzero(self._dof_pinned))
        if Qf.shape[1] == 0:
            return None
        Q = np.zeros((x.shape[0], Qf.shape[1]))
        Q[free] = Qf
        return lambda v: v - np.einsum("ij,j->i", Q, np.einsum("ij,i->j", Q, v))

    def _pcg(self, J, w, b, delta, precond, max_iter=None, rtol=None, x0=None):
        """Solve (JᵀWJ + δI) x = b on the free DOFs by CG preconditioned with ``precond``
        (from :meth:`_preconditioner`; without pins its range excludes the current rigid
        motions, so CG runs on their complement), at most ``max_iter`` iterations (default
        ``cg_max_iter``), to the relative residual ``rtol`` (default ``cg_tol``); with ``x0``,
        continued from ``x0`` (CG on the residual left there, to ``rtol`` of ``b``; the
        iterations counted are the continuation's). Returns ``(x, iterations, converged)``."""
        free = self._free
        JT = J.T  # one transposed view per solve, not one per CG iteration

        def matvec(v):
            out = JT @ (w * (J @ v)) + delta * v
            out[~free] = 0.0
            return out

        rtol = self.cg_tol if rtol is None else rtol
        if x0 is not None:  # continue from x0: the correction for the residual left there
            r0 = b - matvec(x0)
            rn = float(np.linalg.norm(r0))
            if rn <= rtol * float(np.linalg.norm(b)):
                return x0, 0, True
            rtol, b = rtol * float(np.linalg.norm(b)) / rn, r0
        res = pcg(matvec, b, precond=precond, rtol=rtol,
                  max_iter=self.cg_max_iter if max_iter is None else max_iter)
        x = res.x if x0 is None else x0 + res.x
        return x, res.iterations, res.status == "converged"

    def half_gradient(self, x, z_target, w, tube=None) -> np.ndarray:
        """``g = Jᵀ W_eff r``, half the gradient of :meth:`merit`'s ``f``, at the flattened
        pose ``x (3n,)``; zero on pinned DOFs. ``w`` and ``tube`` as used by :meth:`solve`
        (weights of non-positive targets already zeroed)."""
        J, z = lta_jacobian(x.reshape(-1, 3), self.T, return_values=True)
        _, r, w_eff = self.merit(z, z_target, w, tube)
        g = J.T @ (w_eff * r)
        g[self._dof_pinned] = 0.0
        return g

    def _large_residual(self, J, w_eff, s, y) -> bool:
        """Whether the curvature of ``f`` along the last step ``s`` (the secant ``s·y``)
        differs from its Gauss–Newton curvature ``sᵀJᵀWJs`` by more than
        :data:`SUBSPACE_GATE` (relative): where it does not, the dropped second-order term
        is negligible and the Gauss–Newton step is kept (it converges fast there)."""
        Js = J @ s
        sGs = float(w_eff @ (Js * Js))
        return not (sGs > 0 and abs(float(s @ y) / sGs - 1.0) <= SUBSPACE_GATE)

    def subspace_step(self, x, g, p, s_prev, y_prev, z_target, w, h: float = 1.0, tube=None):
        """The step that minimises the second-order model of ``f`` on ``span{p, s_prev}``.

        Parameters
        ----------
        x : (3n,) float64 array
            Current pose.
        g : (3n,) float64 array
            Half gradient of ``f`` at ``x`` (:meth:`half_gradient`).
        p : (3n,) float64 array
            Gauss–Newton step (a descent direction: ``g·p < 0``).
        s_prev, y_prev : (3n,) float64 arrays or None
            The previous accepted step and the change of ``g`` along it (None on a frame's
            first iteration: then ``p`` is only rescaled).
        z_target, w : (e+i+m,) float64 arrays
            As used by :meth:`solve`.
        tube : (i,) float64 array, optional
            As used by :meth:`solve`.
        h : float
            Length scale of the pose (mean edge length): the finite-difference product
            moves no coordinate by more than ``1e-6 h``.

        Returns
        -------
        (3n,) float64 array
            ``d = c₁ p + c₂ s_prev`` minimising ``g·d + ½ dᵀHd`` (``H`` half the Hessian of
            ``f``, including the term ``Σ w ρ ∇²ρ`` that Gauss–Newton drops); ``p`` rescaled
            to the model's minimum along it where the model is not convex on the plane (or
            its minimiser is no descent direction); ``p`` itself where ``pᵀHp <= 0``.

        Notes
        -----
        ``H p`` is a forward difference of :meth:`half_gradient` (one Jacobian evaluation),
        ``H s_prev ≈ y_prev`` the secant of the last step. On real meshes the keyframe
        descriptors are far from integrable, the residual at the minimum is large and the
        dropped term is comparable to ``JᵀWJ``: on the horse (8.4k vertices) the generalised
        eigenvalues of ``H`` against ``JᵀWJ`` spread over [0.4, 1.7] at a solved frame, so
        Gauss–Newton (a Richardson iteration on ``H`` preconditioned by ``JᵀWJ``) converges
        linearly, by a factor of ~0.4 per iteration, and overshoots by a steady factor.
        The plane of the Gauss–Newton step and the last step is the one nonlinear conjugate
        gradients preconditioned by ``JᵀWJ`` search. Newton–CG steps (``H`` applied in CG,
        the cached factor as preconditioner) were measured and rejected: ``H`` has a
        negative eigenvalue (a mode spread over hundreds of vertices) on most horse frames
        until close to the solution, so CG stops at negative curvature after 2–5
        iterations; three horse frames took 10, 6 and 24 Newton iterations (Gauss–Newton
        11, 33, 40; subspace steps 8, 6, 24), refactoring at every iteration, with ~1 s of
        element Hessians per iteration on top. Projecting each element's Hessian onto its
        positive part took more iterations than Gauss–Newton.
        """
        pmax = float(np.abs(p).max())
        if not pmax > 0:
            return p
        eps = 1e-6 * h / pmax
        Hp = (self.half_gradient(x + eps * p, z_target, w, tube) - g) / eps
        pHp = float(p @ Hp)
        gp = float(g @ p)
        if s_prev is not None and y_prev is not None:
            sHp = float(s_prev @ Hp)
            sHs = float(s_prev @ y_prev)
            M = np.array([[pHp, sHp], [sHp, sHs]])
            if pHp > 0 and sHs > 0 and pHp * sHs - sHp * sHp > 1e-12 * pHp * sHs:
                c = np.linalg.solve(M, [-gp, -float(g @ s_prev)])
                d = c[0] * p + c[1] * s_prev
                if float(g @ d) < 0:
                    return d
        if pHp > 0:
            return p * (-gp / pHp)
        return p

    def solve(self, z_target, weights, V_init, tube=None) -> ReconstructionResult:
        """Reconstruct one frame.

        Parameters
        ----------
        z_target : (e+i+m,) float64 array
            Target LΘA descriptors ``z_k``.
        weights : (e+i+m,) float64 array
            Energy weights (from :func:`shellspline.shells.descriptors.lta_weights`); entries for
            non-positive target lengths or areas are set to zero here (paper §7).
        V_init : (n,3) float64 array
            Initial guess; pinned vertices keep these positions.
        tube : (i,) float64 array, optional
            Tube weights of the dihedral angles (see :meth:`merit`); default none.

        Returns
        -------
        ReconstructionResult
        """
        T = self.T
        if tube is not None:
            tube = np.asarray(tube, dtype=np.float64)
            if tube.shape != (T.n_interior,):
                raise ShellsplineError(f"`tube` must have shape ({T.n_interior},), got "
                                       f"{tube.shape}")
            if not tube.any():
                tube = None
        z_target = np.asarray(z_target, dtype=np.float64)
        w = self.active_weights(z_target, weights)
        # a step may not shrink a triangle below this (the barrier keeps iterates far above)
        a_floor = self.area_floor(z_target)
        x = np.array(V_init, dtype=np.float64, copy=True).ravel()
        J, z = lta_jacobian(x.reshape(-1, 3), T, return_values=True)
        f, r, w_eff = self.merit(z, z_target, w, tube)
        g = J.T @ (w_eff * r)
        g[self._dof_pinned] = 0.0
        g0 = float(np.linalg.norm(g))
        res = ReconstructionResult(V=x.reshape(-1, 3), energies=[f], grad_norms=[g0],
                                   status="stalled")
        facts0 = self._chol.n_factorizations if self._chol is not None else 0
        if not (np.isfinite(f) and np.isfinite(g0)):
            res.status = "failed"
            res.message = "initial guess is degenerate (non-finite energy)"
            return res
        # round-off level of the energy (relative to the targets' own energy) and of the
        # gradient: a frame this close is exact (e.g. identical keyframes)
        f_tiny = 1e-20 * float(w @ (z_target * z_target))
        g_tiny = 1e-12 * np.sqrt(max(f, 0.0) * float(w.sum())) + tol.zero
        if g0 <= g_tiny or f <= f_tiny:
            res.status = "converged"
            res.message = "initial guess is stationary"
            return res
        cycle = getattr(self, "_cycle", None)
        if self.amortize_refresh and cycle is not None and cycle[1] and \
                self._last_cg * cycle[1] > cycle[0]:
            # the last frame cost more CG iterations than this factor's average per frame
            # (factorization included): the per-frame cost grows as the frames move away from
            # the factored pose, so refactoring now keeps the average smallest
            self._stale = True
        x_rot, R = None, None  # pose at which the preconditioner's rotations were fitted
        stall = 0
        s_prev = y_prev = None  # the last accepted step and the change of g along it
        f_old = f_older = f
        # length scale of the finite-difference products in subspace_step
        h = _mean_edge_length(x, T.E) if self.subspace else 1.0
        eta = self.cg_tol  # CG's relative tolerance (the forcing term, see forcing)
        for it in range(1, self.max_iter + 1):
            # iterates where a cached factor is often too far (a frame's start, after a
            # large step): where it was the last time, it is refreshed without a try
            kind = "start" if it == 1 else "large step" if f_old - f > STALE_DECREASE * f_old \
                else None
            if kind is not None and self._stale_at.get(kind) and not self.rotate_preconditioner:
                self._stale = True
            fresh = self._stale or self._chol is None
            if fresh:
                self._refresh(J, w_eff, x)
                x_rot, R = x, None
            elif x_rot is None or self._moved(x, x_rot):
                x_rot, R = x, self._rotations(x)
            precond = self._preconditioner(x, R)
            # a cached factor gets refresh_cg CG iterations: one that needs more is too far
            # from this iterate (after a large step, at a frame's start), and is refreshed
            # here and the solve repeated, instead of finishing the solve with it
            p, ncg, ok = self._pcg(J, w_eff, -g, self._delta, precond,
                                   self.cg_max_iter if fresh else
                                   min(self.cg_max_iter, 2 * self.refresh_cg), eta)
            res.cg_iterations += ncg
            self._cycle[0] += ncg
            if kind is not None and not fresh:
                self._stale_at[kind] = not ok
            if not fresh and not ok:
                self._refresh(J, w_eff, x)
                x_rot, R, fresh = x, None, True
                precond = self._preconditioner(x, R)
                p, ncg, ok = self._pcg(J, w_eff, -g, self._delta, precond, self.cg_max_iter,
                                       eta)
                res.cg_iterations += ncg
                self._cycle[0] += ncg
            if not ok or ncg > self.refresh_cg:
                self._stale = True
            # backtracking line search (Armijo); a step may not collapse a triangle
            slope = float(g @ p)
            if -slope <= self.dtol * f and ok and eta > self.cg_tol:
                # a loose inner solve (the forcing term) underestimates the decrement -g·p:
                # the frame is judged on the solve continued to cg_tol, as without the
                # forcing term
                eta = self.cg_tol
                p, ncg, ok = self._pcg(J, w_eff, -g, self._delta, precond, self.cg_max_iter,
                                       eta, x0=p)
                res.cg_iterations += ncg
                self._cycle[0] += ncg
                if not ok:  # as for a solve to cg_tol that fails: refactor at the next step
                    self._stale = True
                slope = float(g @ p)
            if slope >= 0:  # not a descent direction: fall back to preconditioned gradient
                p = -precond(g)
                slope = float(g @ p)
                self._stale = True
            # the Gauss–Newton decrement: the decrease the model still predicts at its
            # minimiser p (f = Σ w ρ², g = Jᵀ W ρ is half its gradient: the model
            # f + 2 g·p + pᵀ JᵀWJ p drops by -g·p there); below dtol·f the frame is converged
            if -slope <= self.dtol * f and ok:
                res.iterations = it - 1
                res.status = "converged"
                res.message = "Gauss–Newton decrement below dtol"
                break
            if self.subspace and s_prev is not None and \
                    f_old - f <= SUBSPACE_TAIL * f_old and \
                    (f_old - f > SUBSPACE_RATE * (f_older - f_old) or
                     self._large_residual(J, w_eff, s_prev, y_prev)):
                p = self.subspace_step(x, g, p, s_prev, y_prev, z_target, w, h, tube)
                slope = float(g @ p)

            def trial(alpha):  # the merit at x + alpha p; inf where a triangle collapses
                Vn = (x + alpha * p).reshape(-1, 3)
                # one descriptor evaluation: its areas are the collapse test's (a collapsed
                # edge's angles are nan there, never used)
                with np.errstate(divide="ignore", invalid="ignore"):
                    zn = lta_descriptors(Vn, T)
                if not np.all(zn[self._sA] > a_floor):
                    return np.inf, None
                return self.merit(zn, z_target, w, tube)[0], None

            # Armijo on f with f'(0) = 2 g·p; the quadratic-interpolation backtracking is kept
            # in [0.1, 0.5] alpha (large-residual frames overshoot by a steady factor)
            ls = backtracking(trial, f, 2.0 * slope, c1=1e-4, shrink=0.5, max_steps=40,
                              interpolate=True)
            accepted, alpha, fn = ls.accepted, ls.alpha, ls.value
            xn = x + alpha * p
            if not accepted:
                if not fresh:  # retry once with a preconditioner refreshed at this iterate
                    self._stale = True
                    continue
                res.iterations = it
                gn_ = float(np.linalg.norm(g))
                if gn_ <= self.gtol * g0 or gn_ <= g_tiny or f <= f_tiny:
                    res.status = "converged"
                    res.message = "converged (no further decrease at round-off level)"
                else:
                    res.message = (f"stalled: line search failed at |g|/|g0| = "
                                   f"{gn_ / g0:.1e}")
                break
            s_prev, g_prev = xn - x, g
            x = xn
            f_older, f_old, f = f_old, f, fn
            J, z = lta_jacobian(x.reshape(-1, 3), T, return_values=True)
            f, r, w_eff = self.merit(z, z_target, w, tube)
            g = J.T @ (w_eff * r)
            g[self._dof_pinned] = 0.0
            y_prev = g - g_prev
            gn = float(np.linalg.norm(g))
            if self.forcing > 0:
                ratio = gn / res.grad_norms[-1]
                # cg_tol is the floor, also above the ceiling (a looser cg_tol asked for)
                eta = max(self.cg_tol, min(self.cg_tol_max, self.forcing * ratio * ratio))
            res.record(f, gn)
            res.iterations = it
            if gn <= self.gtol * g0 or gn <= g_tiny or f <= f_tiny:
                res.status = "converged"
                res.message = "gradient norm reduced below gtol"
                break
            # progress test: the energy stopped decreasing for 3 iterations in a row while
            # the gradient criterion does not hold
            stall = stall + 1 if f_old - f <= self.ftol * f_old else 0
            if stall >= 3:
                res.message = (f"stalled: energy decrease below ftol for 3 iterations at "
                               f"|g|/|g0| = {gn / g0:.1e}")
                break
        else:
            res.status = "limit"
            res.message = (f"iteration limit ({self.max_iter}) reached at |g|/|g0| = "
                           f"{res.grad_norms[-1] / g0:.1e}")
        res.V = x.reshape(-1, 3)
        res.factorizations = (self._chol.n_factorizations if self._chol is not None else 0) - facts0
        if getattr(self, "_cycle", None) is not None:
            self._cycle[1] += 1
            self._last_cg = res.cg_iterations
        return res


class _LowerAssembler:
    """Assembles the lower triangle of ``Jᵀ W J`` straight from the per-element gradient
    blocks stored in the Jacobian's data array (lengths: 6, angles: 12, areas: 9 entries per
    row), on a fixed CSC pattern.

    Each element's DOFs are sorted once (a per-row permutation), so its lower-triangle pairs
    are the same ``k(k+1)/2`` local index pairs for every element. ``values`` forms each
    element's outer product ``(w g) gᵀ`` (contiguous, ``k²`` products) and sums the entries
    of the lower triangle into their positions with one sparse 0/1 matrix per chunk of
    elements (a CSR matrix-vector product: a row per position touched, its terms in element
    order, so every position's sum runs in the order of the former ``bincount`` scatter of
    ``(w g_a) g_b``, bit-identical). Temporaries stay bounded (about 64 MB) however large the
    mesh. Persistent memory: about 5 bytes per element pair and one shared array of ones
    (horse: 40 MB instead of 19 MB with one int32 position per pair; estimated 350 MB
    instead of 230 MB at 150k vertices; forked workers share it).

    Horse (8.4k vertices), best CPU time of one assembly, same process: 39 ms with
    fancy-indexed gathers of the pairs and ``bincount`` (before), 27 ms here (cactus, 5.2k:
    21 → 16 ms). Measured and not kept: products formed pair-major and scattered by the same
    ``bincount`` (-24 %); a pair-major ``bincount`` (-30 to -50 %, but its sums run in
    another order: round-off, and the horse then took 360 instead of 359 iterations and
    2153 instead of 2126 CG iterations).
    """

    CHUNK = 4_000_000  # element pairs per chunk in ``values``

    def __init__(self, T: Topology):
        from .descriptors import pattern

        P = pattern(T)
        N = 3 * T.n_vertices
        e, i, m = T.n_edges, T.n_interior, T.n_faces
        self._blocks, r0, off = [], 0, 0
        for rows, k in ((e, 6), (i, 12), (m, 9)):
            cols = P.indices[off:off + rows * k].reshape(rows, k)
            # DOFs of one vertex are consecutive: sorting by column sorts the vertices
            perm = np.argsort(cols, axis=1, kind="stable").astype(np.int8)
            a, b = np.tril_indices(k)  # sorted order: a >= b  <=>  col[a] >= col[b]
            self._blocks.append((r0, rows, k, off, perm, a, b))
            r0 += rows
            off += rows * k
        self.N = N

        def block_keys(blk, lo, hi):
            r0, rows, k, off, perm, a, b = blk
            cols = np.take_along_axis(
                P.indices[off:off + rows * k].reshape(rows, k)[lo:hi], perm[lo:hi], axis=1
            ).astype(np.int64)
            return (cols[:, b] * np.int64(N) + cols[:, a]).ravel()  # CSC key: col*N + row

        diag_keys = np.arange(N, dtype=np.int64) * (N + 1)
        keys = np.concatenate([block_keys(blk, 0, blk[1]) for blk in self._blocks] +
                              [diag_keys])
        keys.sort()
        # sort-then-mask: numpy 2.4's np.unique is ~80x slower on large int64 arrays
        keys = keys[np.concatenate([[True], keys[1:] != keys[:-1]])]
        self.indices = (keys % N).astype(np.int32)
        self.indptr = np.concatenate([[0], np.cumsum(np.bincount(keys // N, minlength=N))]
                                     ).astype(np.int32)
        self.nnz = len(keys)
        self.diag_pos = np.searchsorted(keys, diag_keys)
        # per block, per chunk of elements lo:hi, the positions it touches (int32; None: the
        # rows are all positions) and the 0/1 matrix from its outer products (hi - lo, k, k),
        # flattened, to those positions
        self._scatter = []
        longest = 0
        for blk in self._blocks:
            r0, rows, k, off, perm, a, b = blk
            step = max(1, self.CHUNK // len(a))
            chunks = []
            for lo in range(0, rows, step):
                hi = min(lo + step, rows)
                pos = np.searchsorted(keys, block_keys(blk, lo, hi))
                # the product (w g_i) g_j with (i, j) = (perm[a], perm[b]), i.e. (w g_a) g_b
                # of the sorted gradients
                col = (np.arange(hi - lo)[:, None] * (k * k)
                       + perm[lo:hi, a].astype(np.int64) * k + perm[lo:hi, b]).ravel()
                touched = np.sort(pos)
                touched = touched[np.concatenate([[True], touched[1:] != touched[:-1]])]
                if 4 * len(touched) > self.nnz:  # a row per position: no index of the rows
                    row, touched = pos, None
                else:  # a row per position touched (many chunks of a large mesh)
                    row, touched = np.searchsorted(touched, pos), touched.astype(np.int32)
                S = sp.csr_matrix((np.ones(len(col)), (row, col)), shape=(
                    self.nnz if touched is None else len(touched), (hi - lo) * k * k))
                S.sort_indices()  # a row's terms in element order (col grows with the element)
                longest = max(longest, S.nnz)
                chunks.append((lo, hi, touched, S))
            self._scatter.append(chunks)
        # every S holds ones: one shared array (views) instead of 8 bytes per element pair
        ones = np.ones(longest)
        for chunks in self._scatter:
            for _, _, _, S in chunks:
                S.data = ones[:S.nnz]

    def values(self, jdata, w):
        """Lower-triangle values of ``Jᵀ diag(w) J`` and its diagonal."""
        data = np.zeros(self.nnz)
        for (r0, rows, k, off, perm, a, b), chunks in zip(self._blocks, self._scatter):
            g_all = jdata[off:off + rows * k].reshape(rows, k)
            for lo, hi, touched, S in chunks:
                g = g_all[lo:hi]
                prod = (w[r0 + lo:r0 + hi, None] * g)[:, :, None] * g[:, None, :]
                if touched is None:
                    data += S @ prod.ravel()
                else:
                    data[touched] += S @ prod.ravel()
        return data, data[self.diag_pos].copy()


def _mean_edge_length(x, E) -> float:
    """Mean edge length of the flattened pose ``x (3n,)``."""
    X = x.reshape(-1, 3)
    d = X[E[:, 1]] - X[E[:, 0]]
    return float(np.mean(np.sqrt(np.einsum("ij,ij->i", d, d)))) if len(E) else 1.0


def _edge_incidence(E, n):
    """Unsigned vertex–edge incidence ``(n,e)`` sparse matrix (sums per-edge values onto both
    end vertices)."""
    e = len(E)
    return sp.csr_matrix((np.ones(2 * e), (E.T.ravel(), np.tile(np.arange(e), 2))),
                         shape=(n, e))


def _vertex_rotations(Xa, Xb, E, incidence=None, F=None):
    """Rotation part ``R_v`` of the local deformation gradient at every vertex from pose
    ``Xa (n,3)`` to ``Xb (n,3)``. Returns ``(n,3,3)``.

    The gradient is fitted to the incident edge vectors, ``A_v = (Σ e_b e_aᵀ)(Σ e_a e_aᵀ)⁻¹``
    (with the vertex normals ``n_b n_aᵀ`` added when the faces ``F`` are given, so that a flat
    one-ring still determines it), and ``R_v = polar(A_v)`` (determinant +1). Dividing by
    ``Σ e_a e_aᵀ`` matters: the plain Procrustes rotation ``polar(Σ e_b e_aᵀ)`` of an
    anisotropic one-ring turns under a pure stretch, and for a stiff membrane such spurious
    rotations make the rotated preconditioner worse than none.
    """
    n = len(Xa)
    ea = Xa[E[:, 1]] - Xa[E[:, 0]]
    eb = Xb[E[:, 1]] - Xb[E[:, 0]]
    if incidence is None:
        incidence = _edge_incidence(E, n)
    S = np.asarray(incidence @ (eb[:, :, None] * ea[:, None, :]).reshape(-1, 9)).reshape(-1, 3, 3)
    C = np.asarray(incidence @ (ea[:, :, None] * ea[:, None, :]).reshape(-1, 9)).reshape(-1, 3, 3)
    if F is not None:
        def normals(X):
            fn = np.cross(X[F[:, 1]] - X[F[:, 0]], X[F[:, 2]] - X[F[:, 0]])
            vn = np.stack([sum(np.bincount(F[:, c], fn[:, d], minlength=n) for c in range(3))
                           for d in range(3)], axis=1)
            return vn / np.maximum(np.linalg.norm(vn, axis=1, keepdims=True), tol.zero)

        na, nb = normals(Xa), normals(Xb)
        sc = np.trace(C, axis1=1, axis2=2)[:, None, None] / 2.0
        S = S + sc * (nb[:, :, None] * na[:, None, :])
        C = C + sc * (na[:, :, None] * na[:, None, :])
    scale = np.maximum(np.trace(C, axis1=1, axis2=2), tol.zero)[:, None, None]
    # S (C + εI)⁻¹: the ridge keeps a flat one-ring (without F) or a vertex without edges
    # solvable and does not change polar(A) of a rigid motion (C (C + εI)⁻¹ is symmetric)
    ridge = 1e-9 * np.eye(3)
    A = np.linalg.solve((C / scale + ridge).transpose(0, 2, 1),
                        (S / scale).transpose(0, 2, 1)).transpose(0, 2, 1)
    U, _, Vt = np.linalg.svd(A)
    d = np.sign(np.linalg.det(U @ Vt))
    U[:, :, 2] *= np.where(d == 0, 1.0, d)[:, None]
    return U @ Vt


def rigid_complement(x):
    """The orthogonal projection onto the complement of the infinitesimal rigid motions at
    the flattened pose ``x (3n,)``, in closed form.

    Parameters
    ----------
    x : (3n,) float64 array

    Returns
    -------
    callable
        ``v (3n,) ↦ v − t − ω × c`` with the centred positions ``c``, the mean ``t`` of the
        vectors of ``v`` and ``ω = I⁻¹ Σ c_i × v_i`` (``I`` the inertia tensor of ``c``).

    Notes
    -----
    The translations ``e_a`` and rotations ``e_a × c`` span the rigid motions; about the
    centroid their Gram matrix is block diagonal (``n I₃`` and ``I``), so the projection is
    ``t + ω × c`` without an orthonormal basis: a few O(n) sums instead of building the
    ``(3n,6)`` basis and its QR factorization (horse, 8.4k vertices: ~2 ms per Gauss–Newton
    iteration) and two ``(3n,6)`` products per preconditioner application. ``I`` is
    pseudo-inverted (collinear points have one rotation less).
    """
    X = np.asarray(x, dtype=np.float64).reshape(-1, 3)
    c = X - X.mean(axis=0)
    inertia = np.eye(3) * float(np.einsum("ij,ij->", c, c)) - c.T @ c
    inv = np.linalg.pinv(inertia, rcond=1e-12, hermitian=True)
    n = len(X)

    def project(v):
        V = v.reshape(-1, 3)
        M = c.T @ V                                    # Σ c_i v_iᵀ: Σ c_i × v_i from it
        a, b, d = inv @ [M[1, 2] - M[2, 1], M[2, 0] - M[0, 2], M[0, 1] - M[1, 0]]
        W = np.array([[0.0, d, -b], [-d, 0.0, a], [b, -a, 0.0]])   # c @ W = ω × c
        return (V - (c @ W + V.sum(axis=0) / n)).ravel()

    return project


def reconstruct(z_target, weights, V_init, T: Topology, **options) -> ReconstructionResult:
    """One-shot Gauss–Newton reconstruction (see :class:`GaussNewton` for the options).

    Parameters
    ----------
    z_target : (e+i+m,) float64 array
    weights : (e+i+m,) float64 array
    V_init : (n,3) float64 array
    T : Topology

    Returns
    -------
    ReconstructionResult

    Examples
    --------
    Recover a sphere's shape from its own descriptors, starting from a distorted copy:

    >>> import numpy as np, trimesh
    >>> from shellspline.mesh.topology import topology
    >>> from shellspline.shells.descriptors import lta_descriptors, lta_weights
    >>> m = trimesh.creation.icosphere(subdivisions=1)
    >>> V, T = np.asarray(m.vertices), topology(m.faces)
    >>> res = reconstruct(lta_descriptors(V, T), lta_weights(V, T), 1.1 * V, T)
    >>> res.success, bool(np.allclose(lta_descriptors(res.V, T), lta_descriptors(V, T), atol=1e-6))
    (True, True)
    """
    return GaussNewton(T, **options).solve(z_target, weights, V_init)


def rigid_placement(V, V_target, weights=None, fixed=None):
    """Rigidly move ``V`` onto ``V_target`` in the least-squares sense (Kabsch, no scaling).

    Parameters
    ----------
    V : (n,3) float64 array
    V_target : (n,3) float64 array
    weights : (n,) float64 array, optional
        Non-negative per-vertex weights.
    fixed : (p,) int array, optional
        Vertices that must not move (pinned vertices). Only the rigid motions that keep them
        in place are used: a rotation about the point (one vertex), about the line (collinear
        vertices), or none (three or more non-collinear vertices). They stay bit-identical.

    Returns
    -------
    (n,3) float64 array
        ``V @ R.T + t`` with the optimal rotation ``R`` (det +1) and translation ``t``.
    """
    V = np.asarray(V, dtype=np.float64)
    Y = np.asarray(V_target, dtype=np.float64)
    w = np.ones(len(V)) if weights is None else np.asarray(weights, dtype=np.float64)
    w = w / w.sum()
    if fixed is not None and len(fixed):
        return _placement_about_fixed(V, Y, w, np.asarray(fixed, dtype=np.int64))
    cx, cy = w @ V, w @ Y
    H = (V - cx).T @ ((Y - cy) * w[:, None])
    U, _, Wt = np.linalg.svd(H)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Wt.T @ U.T)) or 1.0])
    R = Wt.T @ D @ U.T
    return (V - cx) @ R.T + cy


def _placement_about_fixed(V, Y, w, fixed):
    P = V[fixed]
    c = P.mean(axis=0)
    sv = np.linalg.svd(P - c, compute_uv=False) if len(P) > 1 else np.zeros(3)
    scale = max(np.abs(V - c).max(), tol.zero)
    out = V.copy()
    if sv[0] <= 1e-9 * scale:  # one point: rotation about it
        H = (V - c).T @ ((Y - c) * w[:, None])
        U, _, Wt = np.linalg.svd(H)
        D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Wt.T @ U.T)) or 1.0])
        out = (V - c) @ (Wt.T @ D @ U.T).T + c
    elif len(sv) < 2 or sv[1] <= 1e-9 * scale:  # collinear: rotation about the line
        _, _, Vt = np.linalg.svd(P - c)
        u = Vt[0]
        a = (V - c) - np.outer((V - c) @ u, u)
        b = (Y - c) - np.outer((Y - c) @ u, u)
        th = np.arctan2(w @ np.einsum("ij,ij->i", np.cross(a, b), np.broadcast_to(u, a.shape)),
                        w @ np.einsum("ij,ij->i", a, b))
        K = np.array([[0, -u[2], u[1]], [u[2], 0, -u[0]], [-u[1], u[0], 0]])
        R = np.eye(3) + np.sin(th) * K + (1 - np.cos(th)) * (K @ K)
        out = (V - c) @ R.T + c
    out[fixed] = V[fixed]
    return out

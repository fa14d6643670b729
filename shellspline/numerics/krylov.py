"""Preconditioned conjugate gradients and the Steihaug–Toint trust-region CG.

Both work on flat vectors with callables: ``matvec(v) = H v``, ``precond(r) ≈ P⁻¹ r`` and an
optional ``project(v)``, the orthogonal projection onto the subspace the system lives on
(e.g. the complement of the rigid motions of a rigid-invariant energy); ``b`` is projected
once, every product ``H p`` again. Both return a :class:`KrylovResult` (a
:class:`~shellspline.numerics.result.SolverResult`): ``energies`` holds the quadratic model
``q(x) = ½ xᵀHx − bᵀx`` and ``grad_norms`` the residual norms ``‖b − Hx‖`` per iteration.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .result import SolverResult

__all__ = ["KrylovResult", "pcg", "steihaug"]


@dataclass(kw_only=True)
class KrylovResult(SolverResult):
    """What :func:`pcg` and :func:`steihaug` return.

    Attributes
    ----------
    x : (N,) float64 array
        The (approximate) solution or trust-region step.
    status : {"converged", "stalled", "limit"}
        ``"converged"``: relative residual ``rtol`` reached (Steihaug: also the boundary, a
        direction of negative curvature followed to the boundary, or the truncation test);
        ``"stalled"``: negative curvature in plain CG; ``"limit"``: ``max_iter``.
    message : str
        ``"converged"``, ``"boundary"``, ``"negative curvature"``, ``"truncated"``,
        ``"maximum iterations"`` or ``"zero right-hand side"``.
    model_decrease : float
        ``−q(x) = bᵀx − ½ xᵀHx`` (:func:`steihaug`; NaN for :func:`pcg`).
    step_norm : float
        ``‖x‖_P = √(xᵀPx)`` in the preconditioner's norm (:func:`steihaug`; NaN for
        :func:`pcg`).
    """

    x: np.ndarray
    model_decrease: float = float("nan")
    step_norm: float = float("nan")


def _identity(v):
    return v


def _dot(a, b) -> float:
    """Dot product without BLAS (no thread-pool start-up on small vectors, as in the
    Gauss–Newton reconstruction's CG, which runs many short solves)."""
    return float(np.einsum("i,i->", a, b))


def pcg(matvec, b, *, precond=None, project=None, rtol: float = 1e-6,
        max_iter: int = 200) -> KrylovResult:
    """Preconditioned CG for ``H x = b`` (``H`` symmetric, positive definite on the range of
    ``project``), stopped at relative residual ``rtol`` or truncated at negative curvature.

    Parameters
    ----------
    matvec : callable
        ``v -> H v`` for ``v (N,)``.
    b : (N,) float array
    precond : callable, optional
        ``r -> P⁻¹ r`` (default: identity).
    project : callable, optional
        Orthogonal projection onto the subspace of the system (default: none).
    rtol : float
        Stop when ``‖r‖ <= rtol ‖b‖`` (``b`` projected).
    max_iter : int

    Returns
    -------
    KrylovResult
        At negative curvature in the first iteration ``x`` is the preconditioned residual
        ``P⁻¹ b`` (a descent direction for the quadratic model), later the last iterate.

    Examples
    --------
    >>> import numpy as np
    >>> H = np.diag([1.0, 2.0, 4.0]); b = np.ones(3)
    >>> r = pcg(lambda v: H @ v, b, rtol=1e-12)
    >>> r.status, bool(np.allclose(r.x, [1.0, 0.5, 0.25]))
    ('converged', True)
    """
    precond = _identity if precond is None else precond
    project = _identity if project is None else project
    r = project(np.array(b, dtype=np.float64, copy=True))
    x = np.zeros_like(r)
    bn = float(np.sqrt(_dot(r, r)))
    if bn == 0.0:
        return KrylovResult(x=x, status="converged", energies=[0.0], grad_norms=[0.0],
                            message="zero right-hand side")
    qs, rs = [0.0], [bn]
    z = precond(r)
    p = z.copy()
    rz = _dot(r, z)
    for it in range(1, int(max_iter) + 1):
        Hp = project(matvec(p))
        pHp = _dot(p, Hp)
        if not pHp > 0:
            if it == 1:  # the preconditioned residual: a descent direction of the model
                x = z
                qs.append(0.5 * pHp - rz)
                rs.append(float(np.linalg.norm(r - Hp)))
            else:        # the last iterate again
                qs.append(qs[-1])
                rs.append(rs[-1])
            return KrylovResult(x=x, status="stalled", iterations=it, energies=qs,
                                grad_norms=rs, message="negative curvature")
        alpha = rz / pHp
        x += alpha * p
        r -= alpha * Hp
        rn = float(np.sqrt(_dot(r, r)))
        rs.append(rn)
        # q(x) = ½xᵀHx − bᵀx = −½ bᵀx (rᵀx = 0 in CG), and bᵀp_k = r_{k−1}ᵀz_{k−1}: the
        # model drops by ½ α rᵀz per step, no extra vector operation
        qs.append(qs[-1] - 0.5 * alpha * rz)
        if rn <= rtol * bn:
            return KrylovResult(x=x, status="converged", iterations=it, energies=qs,
                                grad_norms=rs, message="converged")
        z = precond(r)
        rz_new = _dot(r, z)
        p = z + (rz_new / rz) * p
        rz = rz_new
    return KrylovResult(x=x, status="limit", iterations=int(max_iter), energies=qs,
                        grad_norms=rs, message="maximum iterations")


def steihaug(matvec, b, radius: float, *, precond=None, project=None, rtol: float = 1e-6,
             max_iter: int = 200, truncate: float = 0.0) -> KrylovResult:
    """Steihaug–Toint CG for the trust-region model ``m(d) = −bᵀd + ½ dᵀHd`` with
    ``‖d‖_P <= radius`` in the norm of the preconditioner ``P`` (``precond`` applies ``P⁻¹``).

    Stops at the boundary (also along negative curvature), at relative residual ``rtol`` or,
    with ``truncate > 0``, when the model decrease stalls (Nash & Sofer 1990: after 5
    iterations, when the last iteration's decrease times the iteration count is below
    ``truncate`` times the total decrease). ``‖d‖_P`` is carried by the recurrences of Conn,
    Gould & Toint (*Trust-Region Methods*, 2000, §7.5.1), no products with ``P``.

    Parameters
    ----------
    matvec, precond, project : callables, see :func:`pcg`
    b : (N,) float array
    radius : float
        Trust-region radius in the ``P`` norm (``inf``: plain preconditioned CG that
        follows negative curvature to infinity is not possible, so give a finite radius
        for indefinite ``H``).
    rtol : float
    max_iter : int
    truncate : float

    Returns
    -------
    KrylovResult
        ``x`` the step ``d``, ``model_decrease = −m(d) >= 0``, ``step_norm = ‖d‖_P``;
        ``message`` ``"boundary"``, ``"negative curvature"``, ``"converged"``,
        ``"truncated"``, ``"maximum iterations"`` or ``"zero right-hand side"``.
    """
    precond = _identity if precond is None else precond
    project = _identity if project is None else project
    r = project(np.array(b, dtype=np.float64, copy=True))
    d = np.zeros_like(r)
    Hd = np.zeros_like(r)
    if float(np.linalg.norm(r)) == 0.0:
        return KrylovResult(x=d, status="converged", energies=[0.0], grad_norms=[0.0],
                            message="zero right-hand side", model_decrease=0.0,
                            step_norm=0.0)
    bn = float(np.linalg.norm(r))
    b = np.asarray(b, dtype=np.float64)
    z = precond(r)
    p = z.copy()
    rz = float(r @ z)
    dMd, dMp, pMp = 0.0, 0.0, rz
    qs, rs = [0.0], [bn]
    reason = ""

    it = 0
    for it in range(1, int(max_iter) + 1):
        Hp = project(matvec(p))
        pHp = float(p @ Hp)
        alpha = rz / pHp if pHp > 0 else np.inf
        if not pHp > 0 or dMd + 2 * alpha * dMp + alpha * alpha * pMp >= radius * radius:
            # to the boundary along p: ‖d + τp‖_P = radius
            tau = (-dMp + np.sqrt(max(dMp * dMp + pMp * (radius * radius - dMd), 0.0))) / pMp
            d = d + tau * p
            Hd = Hd + tau * Hp
            dec = float(b @ d) - 0.5 * float(d @ Hd)
            qs.append(-dec)
            rs.append(float(np.linalg.norm(r - tau * Hp)))
            return KrylovResult(x=d, status="converged", iterations=it, energies=qs,
                                grad_norms=rs,
                                message="negative curvature" if not pHp > 0 else "boundary",
                                model_decrease=dec, step_norm=radius)
        q_old = -qs[-1]
        d = d + alpha * p
        Hd = Hd + alpha * Hp
        dMd += 2 * alpha * dMp + alpha * alpha * pMp
        r = r - alpha * Hp
        rn = float(np.linalg.norm(r))
        q_new = float(b @ d) - 0.5 * float(d @ Hd)      # the model decrease −m(d)
        rs.append(rn)
        qs.append(-q_new)
        if rn <= rtol * bn:
            break
        if truncate and it > 5 and it * (q_new - q_old) < truncate * q_new:
            reason = "truncated"
            break
        z = precond(r)
        rz_new = float(r @ z)
        beta = rz_new / rz
        rz = rz_new
        dMp = beta * (dMp + alpha * pMp)
        pMp = rz + beta * beta * pMp
        p = z + beta * p
    converged = rs[-1] <= rtol * bn
    dec = -qs[-1]
    status = "converged" if converged or reason else "limit"
    message = "converged" if converged else reason or "maximum iterations"
    return KrylovResult(x=d, status=status, iterations=it, energies=qs, grad_norms=rs,
                        message=message, model_decrease=dec,
                        step_norm=float(np.sqrt(max(dMd, 0.0))))

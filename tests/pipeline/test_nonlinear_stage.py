"""The nonlinear stage never returns a result with more defects than its LΘA start."""
from __future__ import annotations

import numpy as np

import data_synth
import shellspline as ss
import shellspline.shells.nonlinear as nonlinear
from shellspline.mesh.topology import topology
from shellspline.metrics import sequence_defects
from shellspline.pipeline.reconstruction import SEAM_POP
from shellspline.pipeline.stages import worse_than_start


def _start():
    d = data_synth.generate("ellipsoids", n_vertices=100)
    V = ss.interpolate((d["V"], d["F"]), frames=[0, 6, 12], K=12, eta=0.1).V
    return d, V, topology(d["F"])


def test_worse_than_start_names_each_new_defect():
    d, V, T = _start()
    frames = [0, 6, 12]
    ref = sequence_defects(V, T, frames)
    assert ref["flipped_faces"] == ref["folded_edges"] == 0 and ref["pop"] < SEAM_POP
    assert worse_than_start(V, V, T, frames, "natural") == ""
    # frame 1 mirrored through its centroid's plane x = c: every face flips in steps 0->1, 1->2
    W = V.copy()
    c = W[1, :, 0].mean()
    W[1, :, 0] = 2 * c - W[1, :, 0]
    got = sequence_defects(W, T, frames)
    assert got["flipped_faces"] > 0
    msg = worse_than_start(W, V, T, frames, "natural")
    assert f"flipped faces {got['flipped_faces']} > 0" in msg
    # a jump of frame 3 (no element defect): a pop above SEAM_POP is named, below it not
    J = V.copy()
    J[3] += 0.5 * np.ptp(V[0], axis=0)
    assert sequence_defects(J, T, frames)["pop"] > SEAM_POP
    assert worse_than_start(J, V, T, frames, "natural").startswith("pop ")
    assert worse_than_start(J, J, T, frames, "natural") == ""


def test_nonlinear_stage_returns_its_start_when_the_result_is_worse(monkeypatch):
    d, V, T = _start()
    real = nonlinear.nonlinear_spline

    def mirrored(*args, **kw):  # the real solve, then a mirrored in-between frame
        res = real(*args, **kw)
        c = res.V[1, :, 0].mean()
        res.V = res.V.copy()
        res.V[1, :, 0] = 2 * c - res.V[1, :, 0]
        return res

    monkeypatch.setattr(nonlinear, "nonlinear_spline", mirrored)
    res = ss.interpolate((d["V"], d["F"]), frames=[0, 6, 12], K=12, eta=0.1, method="nonlinear",
                         solver_options={"max_iter": 2})
    nl = res.report["nonlinear"]
    assert nl["start_returned"] and "the start is returned" in nl["message"]
    assert "flipped faces" in nl["message"]
    assert np.allclose(res.V, V, atol=1e-9 * np.ptp(V))  # the LΘA start, placed alike
    assert sequence_defects(res.V, T, [0, 6, 12])["flipped_faces"] == 0
    # not what was asked for: never a success (the CLI's exit code and the batch status)
    from shellspline.pipeline.report import convergence_problems
    assert any("refused" in p for p in convergence_problems(res.report))
    # without the tampering the result is kept
    monkeypatch.setattr(nonlinear, "nonlinear_spline", real)
    res = ss.interpolate((d["V"], d["F"]), frames=[0, 6, 12], K=12, eta=0.1, method="nonlinear",
                         solver_options={"max_iter": 2})
    assert res.report["nonlinear"]["start_returned"] is False


def _tet_half_turn():
    V0 = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]])
    F = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    return np.stack([V0, V0 * [-1.0, -1.0, 1.0]]), F


def test_nonlinear_spline_through_an_exact_half_turn():
    """Two keyframes a half-turn apart about z: the straight average of the end shells (the
    midpoint solves' default start) collapses every face but the base to a segment, where
    the midpoint solve had no Hessian (it crashed with "Eigenvalues did not converge",
    reported as an internal error). The spline now starts those midpoints elsewhere and
    gives a fold-free sequence."""
    from shellspline.metrics import sequence_defects

    Vs, F = _tet_half_turn()
    res = ss.interpolate((Vs, F), K=6, method="nonlinear", solver_options={"max_time_s": 30})
    assert res.report["nonlinear"]["success"]
    d = sequence_defects(res.V, ss.topology(F), [0, 6])
    assert d["collapsed_faces"] == 0 and d["flipped_faces"] == 0
    np.testing.assert_array_equal(res.V[[0, 6]], Vs)


def test_geodesic_from_a_degenerate_start_fails_instead_of_raising():
    """A path solve started at a shell with collapsed triangles says "failed"."""
    from shellspline.shells.geodesic import discrete_geodesic

    Vs, F = _tet_half_turn()
    init = 0.5 * (Vs[0] + Vs[1])[None]           # three faces collapse to segments
    with np.errstate(all="ignore"):
        g = discrete_geodesic(Vs[0], Vs[1], 2, ss.topology(F), init=init)
    assert g.status == "failed" and not g.success and "degenerate" in g.message


def test_nonlinear_spline_between_one_shape_twice_converges_at_once():
    """Keyframes that are one shape (a hold, or poses a rigid motion apart once aligned):
    the spline energy is round-off (~1e-28) and so is its gradient, which no iteration
    reduces; it ran 500 iterations and reported "maximum number of iterations reached"."""
    Vs, F = _tet_half_turn()
    res = ss.interpolate((np.stack([Vs[0], Vs[0]]), F), K=6, method="nonlinear")
    rec = res.report["nonlinear"]
    assert rec["success"] and rec["status"] == "converged" and rec["nit"] == 0
    assert "round-off" in rec["message"]
    assert np.allclose(res.V, Vs[0], atol=1e-12)

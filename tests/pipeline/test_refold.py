"""A multiresolution run whose coarse frames do not all converge decimates again with the
keyframes' folds coarsened (shellspline.pipeline.stages.multires_sequence, REFOLD_AREA; see
shellspline.mesh.decimate.decimate's fold_area) and keeps the run with fewer unconverged
frames; the work of the other is reported as discarded."""
import numpy as np
import data_synth
import data_synth.stress as stress
import shellspline as ss
from shellspline.pipeline import stages


def _z_fold():
    """A strip folding into a Z at the middle keyframe (data_synth.stress.z_fold): its fine
    faces fold over there."""
    d = stress.z_fold(nx=61, ny=15, frames=(0, 4, 8))
    return d["V"], d["F"]


def _forced(monkeypatch, first_unconverged):
    """Make the first coarse run count ``first_unconverged`` unconverged frames (the real
    count afterwards): the retry's plumbing on a mesh small enough for a test."""
    real = stages._unconverged
    calls = []

    def fake(records):
        calls.append(len(records))
        return first_unconverged if len(calls) == 1 else real(records)
    monkeypatch.setattr(stages, "_unconverged", fake)
    return calls


def test_an_unconverged_coarse_run_is_decimated_again_with_the_folds_coarsened(monkeypatch):
    Vs, F = _z_fold()
    plain = ss.interpolate((Vs, F), frames=[0, 4, 8], coarse=120, workers=1)
    assert "refolded" not in plain.report["multires"]          # every coarse frame converged
    _forced(monkeypatch, 3)
    res = ss.interpolate((Vs, F), frames=[0, 4, 8], coarse=120, workers=1)
    m = res.report["multires"]
    assert m["refolded"] == {"fold_area": stages.REFOLD_AREA, "unconverged_before": 3,
                             "unconverged_after": 0, "kept": True}
    # the coarse mesh is another one: decimated with the folds coarsened
    assert m["decimation"]["folded_corners"] > 0
    assert m["coarse_faces"] == m["decimation"]["n_faces"] != m["first_decimation"]["n_faces"]
    assert m["first_decimation"] == {k: v for k, v in plain.report["multires"]["decimation"]
                                     .items()} | {"seconds": m["first_decimation"]["seconds"]}
    # the first coarse run's solves are reported as discarded work, all of them
    work = res.report["gauss_newton"]["work"]
    first = plain.report["gauss_newton"]["work"]
    assert work["by_kind"]["redecimated_discarded"] == {
        k: first[k] for k in ("solves", "iterations", "cg_iterations", "factorizations")}
    assert work["discarded_solves"] >= first["solves"]
    for j, f in enumerate([0, 4, 8]):
        assert np.array_equal(res.V[f], Vs[j])


def test_the_first_run_stays_when_the_second_is_no_better(monkeypatch):
    Vs, F = _z_fold()
    plain = ss.interpolate((Vs, F), frames=[0, 4, 8], coarse=120, workers=1)
    calls = []

    def fake(records):   # the second run counts as worse: the first is kept
        calls.append(1)
        return 2 if len(calls) == 1 else 5
    monkeypatch.setattr(stages, "_unconverged", fake)
    res = ss.interpolate((Vs, F), frames=[0, 4, 8], coarse=120, workers=1)
    m = res.report["multires"]
    assert m["refolded"]["kept"] is False and "first_decimation" not in m
    assert np.array_equal(res.V, plain.V)
    assert res.report["gauss_newton"]["work"]["by_kind"]["redecimated_discarded"]["solves"] > 0


def test_no_retry_without_folds(monkeypatch):
    """A mesh whose keyframes nowhere fold over decimates the same with fold_area: no second
    run even when frames did not converge."""
    d = data_synth.generate("ellipsoids", n_vertices=300)
    _forced(monkeypatch, 2)
    res = ss.interpolate((d["V"], d["F"]), frames=list(d["frames"]), coarse=100, workers=1)
    assert "refolded" not in res.report["multires"]
    assert "redecimated_discarded" not in res.report["gauss_newton"]["work"]["by_kind"]


def test_the_kept_runs_fixpoint_records_only(monkeypatch):
    """With fixpoint iterations, the report lists those of the run that was kept (the
    discarded run's were listed too before)."""
    Vs, F = _z_fold()
    _forced(monkeypatch, 3)
    res = ss.interpolate((Vs, F), frames=[0, 4, 8], coarse=120, workers=1, fixpoint=1)
    assert res.report["multires"]["refolded"]["kept"] is True
    assert len(res.report["fixpoint"]) == 1

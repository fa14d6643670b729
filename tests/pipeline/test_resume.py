"""Frames stopped at their iteration limit while still converging steadily are resumed after
the reconstruction passes (shellspline.pipeline.reconstruction.resume_steady), without
changing any other frame."""
import numpy as np
import pytest

import data_synth.stress as stress
import shellspline as ss
from shellspline.pipeline import reconstruction as R
from shellspline.pipeline import stages
from shellspline.shells import reconstruct

LIMIT = 12


def _geometric(rate, n=30, c=1.0):
    """Energies ``1 + c rate^k``: decreases ``c rate^k (1 − rate)``, shrinking by ``rate``."""
    return 1.0 + c * rate ** np.arange(n)


@pytest.mark.parametrize("rate", [0.5, 0.8, 0.9])
def test_steady_tail_projects_the_geometric_rate_to_the_criterion(rate):
    """Closed form: the last decrease is ``d = c rate^(n−2) (1 − rate)`` and the criterion
    ``d rate^m ≤ dtol f`` holds after ``m = log(dtol f / d) / log(rate)`` more iterations;
    a budget just above ``m`` grants the resume, one just below refuses it."""
    e = _geometric(rate)
    d = e[-2] - e[-1]
    dtol = 1e-12
    m = np.log(dtol * e[-1] / d) / np.log(rate)
    assert m > 2
    assert R.steady_tail(e, dtol, budget=int(np.ceil(m)) + 1)
    assert not R.steady_tail(e, dtol, budget=int(np.floor(m)) - 1)


def test_steady_tail_refuses_unsteady_tails():
    e = _geometric(0.7)
    assert not R.steady_tail(e[:10], 1e-9)               # fewer than 10 decreases
    bumpy = e.copy()
    bumpy[-3] = bumpy[-4]                                # one step without decrease
    assert not R.steady_tail(bumpy, 1e-9)
    assert not R.steady_tail(1.0 + 1e-3 * np.arange(30, 0, -1), 1e-9)   # constant pace
    nan = e.copy()
    nan[-1] = np.nan
    assert not R.steady_tail(nan, 1e-9)
    assert not R.steady_tail(e, 1e-9, budget=0)
    assert R.steady_tail(e, 1e-2)                       # already below the criterion


@pytest.fixture(scope="module")
def sliver_runs():
    """data_synth.stress.slivers (384 vertices) with the solver's limit lowered to LIMIT
    (as a default, so the resume applies), once with the resume and once without."""
    d = stress.slivers()
    init = reconstruct.GaussNewton.__init__

    def low_default(self, T, **kw):
        kw.setdefault("max_iter", LIMIT)
        init(self, T, **kw)

    out = {}
    mp = pytest.MonkeyPatch()
    try:
        mp.setattr(reconstruct.GaussNewton, "__init__", low_default)
        for budget in (R.RESUME_ITER, 0):
            mp.setattr(stages, "RESUME_ITER", budget)
            out[budget] = ss.interpolate((d["V"], d["F"]), frames=list(d["frames"]),
                                         pinned=d.get("pinned"), coarse="none")
    finally:
        mp.undo()
    return d, out


def test_resumed_frames_converge_and_no_other_frame_changes(sliver_runs):
    d, out = sliver_runs
    on, off = out[R.RESUME_ITER], out[0]
    rec_on = {r["frame"]: r for r in on.report["frames"]}
    rec_off = {r["frame"]: r for r in off.report["frames"]}
    resumed = [k for k, r in rec_on.items() if r.get("resumed")]
    # the frames of a seam's bridge are re-solved together after the resume (their status is
    # the bridge's); every other frame is compared
    bridged = {k for k in rec_on if rec_on[k].get("bridged") or rec_off[k].get("bridged")}
    alone = [k for k in resumed if k not in bridged]
    assert len(alone) >= 3                    # the case exercises the resume
    assert not any("to_go" in r for r in rec_on.values())
    assert not any(r.get("resumed") for r in rec_off.values())
    for k, r in rec_on.items():
        if k in bridged:
            continue
        if k in resumed:
            assert rec_off[k]["status"] == "limit" and rec_off[k]["nit"] == LIMIT
            assert r["status"] == "converged" and r["success"]
            assert r["nit"] > LIMIT
            assert r["energy_final"] < rec_off[k]["energy_final"]
            assert r["energy_initial"] == rec_off[k]["energy_initial"]
        else:   # the same record but for the time it took
            assert {**r, "seconds": 0} == {**rec_off[k], "seconds": 0}
    # frames not resumed are the same solutions (placement is one rigid fit per frame of the
    # whole sequence, so compare shapes: edge lengths)
    E = ss.topology(d["F"]).E

    def lengths(V):
        return np.linalg.norm(V[:, E[:, 1]] - V[:, E[:, 0]], axis=-1)

    same = [k for k in rec_on if k not in resumed and k not in bridged]
    assert len(same) >= 5
    np.testing.assert_allclose(lengths(on.V[same]), lengths(off.V[same]), rtol=1e-9, atol=0)
    # (the bridges' limit follows the frames', here the lowered one, so their frames are
    # compared above only where no bridge re-solved them)
    assert set(on.report["gauss_newton"]["resumed"]) == set(resumed)


def test_a_user_limit_holds(monkeypatch):
    """``gn_options={"max_iter": …}`` (``--max-iter``) is a hard limit: nothing is resumed."""
    d = stress.slivers()
    res = ss.interpolate((d["V"], d["F"]), frames=list(d["frames"]), pinned=d.get("pinned"),
                         coarse="none", gn_options={"max_iter": LIMIT})
    recs = res.report["frames"]
    assert any(r["status"] == "limit" for r in recs)
    assert all(r["nit"] <= LIMIT and not r.get("resumed") and "to_go" not in r
               for r in recs)

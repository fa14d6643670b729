"""All the Gauss–Newton work of a reconstruction (report["gauss_newton"]["work"],
pipeline.reconstruction.GaussNewtonWork): every solve counted once, kept or not, against
an independent count of the solver's calls."""
import numpy as np
import pytest

import shellspline as ss
from data_synth import stress
from shellspline.pipeline import bridge as B
from shellspline.pipeline import reconstruction as R
from shellspline.pipeline import stages
from shellspline.shells import reconstruct

KEPT_KINDS = ("first_pass", "continued", "resumed")


@pytest.fixture
def solver_calls(monkeypatch):
    """Counts of every ``GaussNewton.solve`` and every bridge's joint solve made in this
    process: solves, iterations, CG iterations, factorizations (a bridge's factorizations
    counted where its frames' blocks are factored)."""
    calls = {"gn": np.zeros(4, int), "bridge": np.zeros(4, int)}
    solve, bridge_solve, factor = (reconstruct.GaussNewton.solve, B.SeamBridge.solve,
                                   B._FrameTerms.factor)

    def gn_spy(self, *args, **kw):
        r = solve(self, *args, **kw)
        calls["gn"] += (1, r.iterations, r.cg_iterations, r.factorizations)
        return r

    def bridge_spy(self, *args, **kw):
        br = bridge_solve(self, *args, **kw)
        calls["bridge"] += (1, br.iterations, br.cg_iterations, 0)
        return br

    def factor_spy(self, coefs):
        calls["bridge"][3] += len(coefs)
        return factor(self, coefs)

    monkeypatch.setattr(reconstruct.GaussNewton, "solve", gn_spy)
    monkeypatch.setattr(B.SeamBridge, "solve", bridge_spy)
    monkeypatch.setattr(B._FrameTerms, "factor", factor_spy)
    return calls


def _row(d):
    return np.array([d["solves"], d["iterations"], d["cg_iterations"], d["factorizations"]])


def _kinds(work, kinds):
    return sum((_row(work["by_kind"][k]) for k in kinds if k in work["by_kind"]),
               np.zeros(4, int))


def test_work_counts_every_solve_of_continuations_and_bridges(solver_calls):
    """The flexing joint: its continuations replace first-pass frames and stop at a frame
    that is not lower (discarded), and its seams are bridged. The frame records count 70
    iterations; the solver did more, and the work counts exactly what it did."""
    d = stress.joint()
    gn = ss.interpolate((d["V"], d["F"]), frames=d["frames"], workers=1).report["gauss_newton"]
    work = gn["work"]
    by = work["by_kind"]
    assert by["replaced"]["solves"] > 0 and by["continuation_discarded"]["solves"] > 0
    assert by["bridge"]["solves"] + by.get("bridge_discarded", {"solves": 0})["solves"] > 0
    everything = solver_calls["gn"] + solver_calls["bridge"]
    assert _row(work).tolist() == everything.tolist()
    assert _kinds(work, ("bridge", "bridge_discarded")).tolist() == \
        solver_calls["bridge"].tolist()
    assert _row(work).tolist() == _kinds(work, R.WORK_KINDS).tolist()
    assert work["discarded_solves"] == _kinds(work, R.DISCARDED_KINDS)[0]
    # the records count the kept solves: the first pass's and the continuations' kept frames
    kept = _kinds(work, KEPT_KINDS)
    assert (kept[1], kept[2], kept[3]) == (gn["iterations_total"], gn["cg_iterations_total"],
                                           gn["factorizations_total"])
    assert work["iterations"] > gn["iterations_total"]
    assert work["factorizations"] > gn["factorizations_total"]


def test_work_equals_the_kept_solves_without_continuations_or_seams(solver_calls):
    # no warm starts: one pass of runs, no continuation, no bridge; every solve is kept
    d = stress.joint()
    gn = ss.interpolate((d["V"], d["F"]), frames=d["frames"], warm_start=False,
                        workers=1).report["gauss_newton"]
    work = gn["work"]
    assert list(work["by_kind"]) == ["first_pass"] and work["discarded_solves"] == 0
    assert _row(work).tolist() == solver_calls["gn"].tolist()
    assert solver_calls["bridge"].tolist() == [0, 0, 0, 0]
    assert (work["solves"], work["iterations"], work["cg_iterations"],
            work["factorizations"]) == (gn["frames"], gn["iterations_total"],
                                        gn["cg_iterations_total"], gn["factorizations_total"])


def test_resumed_rounds_are_counted(solver_calls, monkeypatch):
    """The sliver tube with the frames' limit lowered to 12 (as a default, so that the frames
    still converging there are resumed, as in test_resume): the resume rounds are solves of
    their own, and the frame records add them to the frame's first solve."""
    init = reconstruct.GaussNewton.__init__

    def low_default(self, T, **kw):
        kw.setdefault("max_iter", 12)
        init(self, T, **kw)

    monkeypatch.setattr(reconstruct.GaussNewton, "__init__", low_default)
    d = stress.slivers()
    gn = ss.interpolate((d["V"], d["F"]), frames=list(d["frames"]), pinned=d.get("pinned"),
                        coarse="none", workers=1).report["gauss_newton"]
    work = gn["work"]
    assert gn["resumed"] and work["by_kind"]["resumed"]["solves"] >= len(gn["resumed"])
    assert _row(work).tolist() == (solver_calls["gn"] + solver_calls["bridge"]).tolist()
    kept = _kinds(work, KEPT_KINDS)
    assert (kept[1], kept[2], kept[3]) == (gn["iterations_total"], gn["cg_iterations_total"],
                                           gn["factorizations_total"])


def test_coarse_and_fine_levels_and_trial_starts_are_counted(solver_calls, monkeypatch):
    """``coarse`` and ``fine``: the coarse level's solves count too (``by_resolution``), and
    so do the two solves from both starts of a run's first frame (given_starts; every first
    frame here, with the ambiguity bound raised)."""
    monkeypatch.setattr(stages, "START_AMBIGUITY", np.inf)
    d = stress.joint()
    res = ss.interpolate((d["V"], d["F"]), frames=d["frames"], coarse=200, fine=True,
                         workers=1)
    gn, mr = res.report["gauss_newton"], res.report["multires"]
    work = gn["work"]
    n_first = len(mr["fine_starts"]["solved_both"])
    assert n_first == 4   # the first frames of the four runs
    assert work["by_kind"]["trial_start"]["solves"] == n_first
    assert work["by_kind"]["trial_start_discarded"]["solves"] == n_first
    assert _row(work).tolist() == (solver_calls["gn"] + solver_calls["bridge"]).tolist()
    levels = work["by_resolution"]
    assert set(levels) == {"coarse", "fine"}
    assert (_row(levels["coarse"]) + _row(levels["fine"])).tolist() == _row(work).tolist()
    # the coarse level's kept solves are its frame records
    coarse = mr["coarse_frames"]
    assert levels["coarse"]["iterations"] >= sum(r["nit"] for r in coarse) > 0
    assert work["iterations"] > gn["iterations_total"] + sum(r["nit"] for r in coarse)


def test_two_workers_count_what_one_counts(monkeypatch):
    """On a process pool the workers count their solves and the parent adds them up: the same
    totals as one worker, kind by kind, but for the speculative continuations an idle worker
    may start (solves one worker never makes)."""
    monkeypatch.setattr(R, "SERIAL_RECONSTRUCT_WORK", 0)  # this small case: use the pool
    d = stress.joint()
    works = [ss.interpolate((d["V"], d["F"]), frames=d["frames"], pinned=d["pinned"],
                            coarse="none", workers=w).report["gauss_newton"]["work"]
             for w in (1, 2)]
    one, two = works
    assert one["by_kind"]["first_pass"]["solves"] > 0 and "replaced" in one["by_kind"]
    assert "speculative_discarded" not in one["by_kind"]
    spec = two["by_kind"].pop("speculative_discarded", None)
    assert two["by_kind"] == one["by_kind"]
    extra = _row(spec) if spec else np.zeros(4, int)
    assert (_row(two) - extra).tolist() == _row(one).tolist()
    assert two["discarded_solves"] - extra[0] == one["discarded_solves"]


def test_speculative_continuations_count_the_frames_no_run_keeps():
    """GapContinuations.count_speculation: a speculative continuation whose direction won
    keeps the frames that beat the first pass; of the rest, the first is the frame the
    continuation given the energies stops at, the others were speculation. One whose
    direction lost kept nothing."""
    runs = R.reconstruction_runs(np.arange(1, 10), [0, 10], 10, False)
    g = R.GapContinuations(runs, np.zeros((11, 4, 3)), "reconstruct (continue)")
    work = R.GaussNewtonWork()

    def solved(nits):
        out = []
        for j, n in enumerate(nits):
            rec = {"nit": n, "cg_iterations": 10 * n, "factorizations": 1,
                   "energy_final": 1.0 + j}
            work.add("continued", rec)
            out.append((j, None, rec))
        return out

    g._spec = {0: {"out": solved([3, 4, 5, 6]), "worse_than": np.array([2.0, 3.0, 2.0, 9.0])},
               1: {"out": solved([7, 8])}}
    g.count_speculation(work)
    by = work.record()["by_kind"]
    assert by["continued"]["iterations"] == 3 + 4
    assert by["continuation_discarded"]["iterations"] == 5
    assert by["speculative_discarded"]["iterations"] == 6 + 7 + 8
    assert by["speculative_discarded"]["solves"] == 3
    assert work.record()["solves"] == 6 and work.record()["discarded_solves"] == 4


def test_gated_run_counts_its_dropped_frames(gated_run):
    """solve_run with a gate that opens after three frames with energies that only the first
    beats: the frames kept and the frame the run given the energies would stop at are
    counted as such, the third as speculation; every solve is counted once."""
    run = gated_run
    free = run()
    e = np.array([rec["energy_final"] for _, _, rec in free])
    worse = e * 0.5
    worse[0] = e[0] * 2.0          # only the first frame beats its energy
    calls = []

    def gate():
        calls.append(1)
        return (R.GATE_WAIT, None) if len(calls) <= 3 else (R.GATE_GO, worse)

    work = R.GaussNewtonWork()
    kept = run(gate=gate, work=work, kind="continued")
    by = work.record()["by_kind"]
    assert len(kept) == 1 and by["continued"]["solves"] == 1
    assert by["continuation_discarded"]["solves"] == 1
    assert by["speculative_discarded"]["solves"] == 1
    nits = [rec["nit"] for _, _, rec in free[:3]]   # the same frames, the same solves
    assert [by[k]["iterations"] for k in ("continued", "continuation_discarded",
                                          "speculative_discarded")] == nits


def test_summary_line_shows_kept_and_all_work(capsys):
    from pathlib import Path
    from types import SimpleNamespace

    from shellspline.cli.main import _summary

    K = 4
    per = {"flipped": [0] * 5, "folded": [0] * 5, "collapsed": [0] * 5}
    rep = {"parameters": {"fine": False},
           "quality": {"keyframes_exact": True, "flipped_faces": 0, "collapsed_faces": 0,
                       "folded_edges": 0, "degenerate_faces": 0, "pop": 1.0,
                       "per_frame": per},
           "gauss_newton": {"frames": 3, "converged": 3, "iterations_total": 399,
                            "iterations_median": 9, "iterations_max": 28,
                            "factorizations_total": 170,
                            "work": {"solves": 5, "iterations": 512, "cg_iterations": 900,
                                     "factorizations": 214, "discarded_solves": 2,
                                     "by_kind": {}}},
           "frames": [{"frame": k} for k in (1, 2, 3)],
           "timings": {"total": 1.0}}
    res = SimpleNamespace(report=rep, K=K, V=np.zeros((K + 1, 8, 3)))
    _summary(res, Path("out"), quiet=False)
    err = capsys.readouterr().err
    assert ("Gauss–Newton: 3/3 frames converged, 399 iterations in kept solves (median 9, "
            "max 28), 512 in all; 170 factorizations (214 in all)") in err

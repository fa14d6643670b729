"""Seams between the two runs of a keyframe gap (issue 13: pops are switches between local
minima of the reconstruction): the jump measure and the seam records."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from shellspline.pipeline import reconstruction as R
from shellspline.progress import Progress


def _shape(seed=0, n=30):
    return np.random.default_rng(seed).normal(size=(n, 3))


def _rigid(V, seed):
    rot = Rotation.random(random_state=seed).as_matrix()
    return V @ rot.T + np.array([1.0, -2.0, 0.5]) * seed


def test_seam_jump_is_one_for_a_steady_motion_and_ignores_rigid_placement():
    P = _shape()
    frames = [P * (1.0 + 0.01 * k) for k in range(4)]          # uniform non-rigid growth
    assert R.seam_jump(*frames) == pytest.approx(1.0, rel=1e-6)
    # each frame placed anywhere in space: the reconstruction leaves rigid motions free
    moved = [_rigid(V, s + 1) for s, V in enumerate(frames)]
    assert R.seam_jump(*moved) == pytest.approx(1.0, rel=1e-6)
    # a vertex that jumps by 10x the typical step at the seam
    after = [V.copy() for V in frames[2:]]
    step = np.linalg.norm(frames[1] - frames[0], axis=1).max()
    for V in after:
        V[0] += [10.0 * step, 0.0, 0.0]
    ratio = R.seam_jump(frames[0], frames[1], *after)
    assert 8.0 < ratio < 12.0
    # with pins nothing is placed rigidly: a rigid move is a real step
    assert R.seam_jump(frames[0], frames[1], _rigid(frames[2], 3), _rigid(frames[3], 3),
                       pinned=np.array([0])) > 10.0


def _rec(k, continued=False):
    return {"frame": k, "status": "converged", "success": True, "energy_final": 1.0,
            **({"continued": True} if continued else {})}


def _gap(bump, continued=()):
    """One keyframe gap 0..10 solved from both ends: the forward run grows the shape, the
    backward run is the same motion with vertex 0 moved by ``bump`` (another local minimum);
    frames in ``continued`` were taken over by the backward run's continuation."""
    P = _shape(3)
    fwd = {k: P * (1.0 + 0.01 * k) for k in range(11)}
    bwd = {k: fwd[k].copy() for k in fwd}
    for k in bwd:
        bwd[k][0] += bump
    Vinit = np.stack([fwd[0]] + [fwd[k] for k in range(1, 10)] + [bwd[10]])
    runs = R.reconstruction_runs(np.arange(1, 10), [0, 10], 10, False)
    results = {k: (fwd[k], _rec(k)) for k in range(1, 6)}
    results.update({k: (bwd[k], _rec(k)) for k in range(6, 10)})
    results.update({k: (bwd[k], _rec(k, True)) for k in continued})
    return runs, results, Vinit


def test_seam_records_find_the_jump_between_two_minima():
    runs, results, Vinit = _gap(np.array([0.5, 0.0, 0.0]))
    seams = R.seam_records(runs, results, Vinit)
    step = 0.01 * np.linalg.norm(_shape(3), axis=1).max()    # the growth's largest step
    # the bump is 0.5 / step ≈ 15 typical steps; a rigid fit absorbs a little of it
    assert [s["frame"] for s in seams] == [6] and 0.7 * 0.5 / step < seams[0]["jump"] < 0.5 / step
    # the backward run continued into the forward half (frames 4, 5): the seam moved to 4
    runs, results, Vinit = _gap(np.array([0.5, 0.0, 0.0]), continued=(4, 5))
    assert [s["frame"] for s in R.seam_records(runs, results, Vinit)] == [4]
    # two runs that meet in the same minimum: no seam
    runs, results, Vinit = _gap(np.zeros(3))
    assert R.seam_records(runs, results, Vinit) == []


def test_pops_and_flips_of_a_flexing_joint_sit_on_the_recorded_seams():
    # data_synth.stress.joint (0° -> 150° -> 30°): the runs from the two keyframes of each gap
    # settle into different minima; every jump the quality check sees (sequence_defects, an
    # independent measurement after placement) is a seam the reconstruction recorded, and no
    # run jumps inside itself
    import shellspline as ss
    from data_synth import stress

    d = stress.joint()
    res = ss.interpolate((d["V"], d["F"]), frames=d["frames"])
    q = res.report["quality"]
    seams = {r["frame"]: r["seam_jump"] for r in res.report["frames"] if "seam_jump" in r}
    pops = np.flatnonzero(np.array(q["per_frame"]["pop"]) > R.SEAM_POP)
    flips = np.flatnonzero(np.array(q["per_frame"]["flipped"]) > 0)
    assert set(pops.tolist()) <= set(seams) and set(flips.tolist()) <= set(seams)
    assert all(j > R.SEAM_DETECT for j in seams.values())
    # a recorded seam is not a keyframe and lies inside a gap
    assert not set(seams) & set(int(f) for f in d["frames"])


def test_seam_defects_count_the_steps_of_each_seam_and_its_kept_bridge():
    from shellspline.pipeline.report import seam_defects

    per = {"flipped": [0, 1, 0, 2, 3, 0, 0, 4, 0, 5, 0],
           "folded": [0, 0, 0, 0, 1, 1, 0, 0, 0, 0, 7],
           "collapsed": [0] * 11}
    frames = [{"frame": 4, "seam_jump": 3.0,
               "bridge": {"kept": True, "frames": [2, 3, 4, 5]}},   # steps 1->2 ... 5->6
              {"frame": 9, "seam_jump": 2.0, "bridge": {"kept": False, "frames": [7, 8, 9, 10]}}]
    rep = {"quality": {"per_frame": per}, "frames": frames}
    got = seam_defects(rep)
    # a kept bridge: its window's steps and the step out of it; a refused one: the seam's step
    assert got["frames"] == [2, 3, 4, 5, 6, 9]
    assert (got["flipped"], got["folded"], got["collapsed"]) == (0 + 2 + 3 + 0 + 0 + 5, 2, 0)
    # a multiresolution run records its seams on the coarse frames (the output's frames)
    mr = {"quality": {"per_frame": per}, "frames": [],
          "multires": {"coarse_frames": [{"frame": 7, "seam_jump": 4.0}]}}
    assert seam_defects(mr) == {"flipped": 4, "folded": 0, "collapsed": 0, "frames": [7]}
    # the batch's one-line warning says it too
    from shellspline.batch.sequence import quality_warning

    q = {"keyframes_exact": True, "flipped_faces": 14, "folded_edges": 9, "per_frame": per}
    line = quality_warning({"quality": q, "frames": frames})
    assert "14 flipped faces" in line and "12 of these at the seams" in line
    assert "[2, 3, 4, 5, 6, 9]" in line
    assert "seams" not in quality_warning({"quality": q, "frames": []})
    # no seam, no per-frame record: nothing
    assert seam_defects({"quality": {"per_frame": per}, "frames": []})["flipped"] == 0
    assert seam_defects({})["frames"] == []


def test_every_defect_of_the_sliver_joint_is_counted_at_a_seam():
    # data_synth.stress.slivers (the flexing joint with slivers): its new flipped faces and
    # folded edges all sit at the seams (measured: 3 and 1), and seam_defects finds all of them
    import shellspline as ss
    from data_synth import stress
    from shellspline.pipeline.report import seam_defects

    d = stress.slivers()
    rep = ss.interpolate((d["V"], d["F"]), frames=d["frames"]).report
    q = rep["quality"]
    at = seam_defects(rep)
    assert q["flipped_faces"] > 0 and q["folded_edges"] > 0     # the case has defects to find
    assert (at["flipped"], at["folded"], at["collapsed"]) == \
        (q["flipped_faces"], q["folded_edges"], q["collapsed_faces"])
    flipped = np.flatnonzero(np.array(q["per_frame"]["flipped"])).tolist()
    assert set(flipped) <= set(at["frames"])


def test_gap_continuations_start_on_the_pool_and_change_no_frame(monkeypatch):
    """The continuation of a keyframe gap (continued_runs) is handed to the process pool as
    soon as the gap's two runs are solved, while other runs still go on, instead of in a
    second pass after all of them. Each run starts its solver afresh, so the frames, records
    and continued flags are those of the separate pass, bit for bit."""
    import shellspline as ss
    from data_synth import stress

    monkeypatch.setattr(R, "SERIAL_RECONSTRUCT_WORK", 0)  # this small case: use the pool
    d = stress.joint()

    def run():
        ev = []
        res = ss.interpolate((d["V"], d["F"]), frames=d["frames"], pinned=d["pinned"],
                             coarse="none", workers=2, progress=ev.append)
        end = next(i for i, e in enumerate(ev)
                   if e["kind"] == "stage_end" and e["stage"] == "reconstruct")
        early = [e for e in ev[:end]
                 if e["kind"] == "advance" and e["stage"] == "reconstruct (continue)"]
        return res, early

    piped, early = run()
    monkeypatch.setattr(R.GapContinuations, "ready", lambda self, results: [])
    separate, none = run()
    assert len(early) >= 1 and none == []
    cont = [f["frame"] for f in piped.report["frames"] if f.get("continued")]
    assert cont and cont == [f["frame"] for f in separate.report["frames"]
                             if f.get("continued")]
    assert np.array_equal(piped.V, separate.V)
    keep = ("frame", "status", "nit", "energy_final", "cg_iterations")
    assert [{k: f[k] for k in keep} for f in piped.report["frames"]] == \
        [{k: f[k] for k in keep} for f in separate.report["frames"]]


def test_gap_continuations_pair_the_runs_of_each_gap():
    """GapContinuations hands out each gap's continuation once, when both of its runs are
    in the results, and the same tasks as continued_runs over all runs."""
    ks = np.setdiff1d(np.arange(1, 20), [10])
    runs = R.reconstruction_runs(ks, [0, 10, 20], 20, False)
    Vinit = np.zeros((21, 4, 3))
    results = {}
    rng = np.random.default_rng(0)
    g = R.GapContinuations(runs, Vinit, "reconstruct (continue)")
    assert [[tuple(r) for r, _ in gap] for gap in g.gaps] == \
        [[tuple(range(1, 6)), tuple(range(9, 5, -1))],
         [tuple(range(11, 16)), tuple(range(19, 15, -1))]]
    for r, _ in runs:  # the runs finish in this order
        for k in r:
            results[int(k)] = (rng.standard_normal((4, 3)),
                               {"energy_final": float(rng.random())})
        got = g.ready(results)
        done = int(r[-1])
        assert len(got) == (1 if done in (6, 16) else 0)
    assert g.ready(results) == []  # each gap once
    every = R.continued_runs(runs, results, Vinit)
    assert g.submitted == {tuple(int(k) for k in t[0]) for t in every}


def test_seams_bridged_on_the_pool_as_their_gaps_finish_change_no_frame(monkeypatch):
    """A gap whose continuation is solved while other work is still on the pool gets its seam
    bridged there (GapContinuations.bridges_ready), instead of after all the passes; the
    bridge sees the same frames, so the sequence and every record are those of the bridges
    run at the end, bit for bit."""
    import shellspline as ss
    from data_synth import stress

    monkeypatch.setattr(R, "SERIAL_RECONSTRUCT_WORK", 0)  # this small case: use the pool
    d = stress.joint(angles=(0.0, 150.0, 0.0, 150.0), frames=(0, 10, 20, 30))
    on_pool = []
    keep = R.GapContinuations.record_bridge

    def spy(self, out):
        on_pool.append(out[0])
        keep(self, out)

    monkeypatch.setattr(R.GapContinuations, "record_bridge", spy)

    def run():
        return ss.interpolate((d["V"], d["F"]), frames=d["frames"], pinned=d["pinned"],
                              coarse="none", workers=2)

    early = run()
    monkeypatch.setattr(R.GapContinuations, "bridges_ready", lambda self, *a: [])
    late = run()
    bridged = [f["frame"] for f in late.report["frames"] if "bridge" in f]
    assert len(bridged) >= 2 and on_pool and set(on_pool) <= set(bridged)
    assert np.array_equal(early.V, late.V)
    drop = ("seconds",)
    assert [{k: v for k, v in f.items() if k not in drop} for f in early.report["frames"]] == \
        [{k: v for k, v in f.items() if k not in drop} for f in late.report["frames"]]


def test_speculative_continuations_change_no_frame(monkeypatch):
    """An idle worker starts a gap's continuation from the run that is solved before the
    gap's other run is (GapContinuations.speculate); the energies to beat reach it through
    shared memory once known, or it is stopped when the other direction wins. The frames and
    records are those of continuations started after both runs, bit for bit."""
    import shellspline as ss
    from data_synth import stress

    monkeypatch.setattr(R, "SERIAL_RECONSTRUCT_WORK", 0)  # this small case: use the pool
    d = stress.joint(angles=(0.0, 150.0), frames=(0, 20))
    specs = []
    settle = R.GapContinuations.settle

    def spy(self, progress):
        settle(self, progress)
        specs.append({i: dict(v) for i, v in self._spec.items()})

    monkeypatch.setattr(R.GapContinuations, "settle", spy)

    def run():
        return ss.interpolate((d["V"], d["F"]), frames=d["frames"], pinned=d["pinned"],
                              coarse="none", workers=2)

    fast = run()
    final = specs[-1] if specs else {}
    used = [i for i, v in final.items() if v.get("done")]
    monkeypatch.setattr(R.GapContinuations, "speculate", lambda self, *a: [])
    plain = run()
    assert final  # the pair's first run to finish left a worker idle: it speculated
    assert np.array_equal(fast.V, plain.V)
    drop = ("seconds",)
    assert [{k: v for k, v in f.items() if k not in drop} for f in fast.report["frames"]] == \
        [{k: v for k, v in f.items() if k not in drop} for f in plain.report["frames"]]


def test_gated_run_keeps_what_the_run_given_its_energies_keeps(gated_run):
    """solve_run with a gate: energies not known for the first frames, then known (GO): the
    frames kept are those of the same run given worse_than from the start, also where
    frames already solved must be dropped; ABORT stops it."""
    run = gated_run

    free = run()
    e = np.array([rec["energy_final"] for _, _, rec in free])
    assert np.all(e > 0)
    for keep in (5, 2):   # the gate opens after frame 3: a later cut, and one in the past
        worse = e * 2.0
        worse[keep] = e[keep] * 0.5
        given = run(worse_than=worse)
        calls = []

        def gate():
            calls.append(1)
            return (R.GATE_WAIT, None) if len(calls) <= 3 else (R.GATE_GO, worse)

        gated = run(gate=gate)
        assert len(given) == keep and [k for k, _, _ in gated] == [k for k, _, _ in given]
        assert all(np.array_equal(a[1], b[1]) for a, b in zip(gated, given))
    stopped = run(gate=lambda: (R.GATE_ABORT, None))
    assert stopped == []


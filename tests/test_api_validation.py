"""Input errors of the documented Python API are one-line ShellsplineErrors, never raw
numpy/Python errors, and nothing is silently misread (pins, K, keyframes, linear_blend, bc,
write_sequence, viz sources)."""
from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
import trimesh

import shellspline as ss
from shellspline.errors import ShellsplineError
from shellspline.pipeline.options import InterpolationOptions, interpolation_problem
from shellspline.timeline import linear_blend


@pytest.fixture(scope="module")
def kf():
    m = trimesh.creation.icosphere(subdivisions=1)
    Vs = np.stack([m.vertices, m.vertices * [1.5, 1, 1], m.vertices * [1, 1.5, 1]])
    return ss.keyframes_from_arrays(Vs, m.faces, frames=[0, 10, 20])


def _problem(kf, **kw):
    return interpolation_problem(InterpolationOptions(method="linear"), kf, **kw)


def _one_line(exc):
    msg = str(exc.value)
    assert msg and "\n" not in msg
    return msg


# 1. pins ------------------------------------------------------------------------------------
def test_bool_pin_mask_is_a_mask(kf):
    mask = np.zeros(kf.n, bool)
    mask[[2, 7]] = True
    assert _problem(kf, pinned=mask).pinned.tolist() == [2, 7]
    res = ss.interpolate(kf, method="linear", pinned=mask)
    assert res.report["parameters"]["pinned_vertices"] == 2
    with pytest.raises(ShellsplineError) as e:
        _problem(kf, pinned=mask[:5])
    assert "mask" in _one_line(e)


def test_non_integer_pins_refused_duplicates_counted_once(kf):
    with pytest.raises(ShellsplineError) as e:
        _problem(kf, pinned=[1.9])
    assert "integer" in _one_line(e)
    assert _problem(kf, pinned=[5, 5, 5]).pinned.tolist() == [5]
    assert _problem(kf, pinned=[3.0, 1]).pinned.tolist() == [1, 3]
    res = ss.interpolate(kf, method="linear", pinned=[5, 5, 5])
    assert res.report["parameters"]["pinned_vertices"] == 1


def test_pin_file_path_is_read_and_missing_file_is_one_line(kf, tmp_path):
    f = tmp_path / "pins.txt"
    f.write_text("4 2 # comment\n2\n")
    assert _problem(kf, pinned=str(f)).pinned.tolist() == [2, 4]
    with pytest.raises(ShellsplineError) as e:
        _problem(kf, pinned=str(tmp_path / "nofile.txt"))
    assert "nofile.txt" in _one_line(e)


# 2. K ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("K", [20.5, "22", True, float("nan")])
def test_non_integer_K_refused(kf, K):
    with pytest.raises(ShellsplineError) as e:
        _problem(kf, K=K)
    assert "`K`" in _one_line(e)


@pytest.mark.parametrize("kw, message", [
    ({"K": 1}, "K=1 is too small for 3 keyframes"),
    ({"bc": "hermite", "frames": None}, "bc='hermite' needs explicit `frames`: "),
    ({"coarse": 2}, "`coarse` must be 'auto', 'none', a vertex count >= 4 or a fraction in "
                    "(0, 1), got 2"),
], ids=str)
def test_messages_name_the_keywords(kw, message):
    """The API's messages keep its keywords (the command line says --K, --bc hermite,
    --coarse: tests/cli/test_cli.py); a bad ``coarse`` names every accepted value."""
    m = trimesh.creation.icosphere(subdivisions=1)
    Vs = np.stack([m.vertices, m.vertices * [1.5, 1, 1], m.vertices * [1, 1.5, 1]])
    with pytest.raises(ShellsplineError) as e:
        ss.interpolate((Vs, m.faces), **kw)
    assert _one_line(e).startswith(message), str(e.value)


def test_integer_K_accepted(kf):
    assert _problem(kf, K=np.int64(22)).K == 22
    assert _problem(kf, K=22).K == 22


# 3. raw errors ------------------------------------------------------------------------------
@pytest.mark.parametrize("kw, word", [({"eta": "big"}, "eta"), ({"mu": None}, "mu"),
                                      ({"workers": "x"}, "workers"),
                                      ({"gn_options": {"foo": 1}}, "max_iter"),
                                      ({"gn_options": [1]}, "gn_options"),
                                      ({"fade_angle": "a"}, "fade_angle")])
def test_bad_options_are_shellspline_errors(kf, kw, word):
    with pytest.raises(ShellsplineError) as e:
        ss.interpolate(kf, **kw)
    assert word in _one_line(e)


def test_valid_gn_option_accepted(kf):
    res = ss.interpolate(kf, frames=[0, 2, 4], gn_options={"max_iter": 2})
    assert res.V.shape[0] == 5


def test_bad_keyframes_arguments(kf):
    Vs, F = kf.V, kf.F
    for bad in (None, [Vs[0], Vs[1]], (Vs, F, F), Vs, 3):
        with pytest.raises(ShellsplineError) as e:
            ss.interpolate(bad, frames=[0, 10])
        assert "keyframes" in _one_line(e)
    for bad in (None, [1, 2], 3):
        with pytest.raises(ShellsplineError) as e:
            ss.read_keyframes(bad)
        _one_line(e)


@pytest.mark.parametrize("args", [
    ([[0.0], [1.0], [2.0]], [0, 10, 20], 15),   # K before the last keyframe
    ([[0.0], [1.0], [2.0]], [0, 10, 20], -1),
    ([[0.0], [1.0]], [0, 10, 20], 20),           # frames and keyframes disagree
    ([[0.0], [1.0], [2.0]], [0, 4, 2], 4),       # not increasing
    ([[0.0], [1.0]], [0, 4], 4.5),
    ([[0.0], [1.0]], ["0", "4"], 4),
    ([[0.0], [1.0, 2.0]], [0, 4], 4),            # ragged
])
def test_linear_blend_refuses_bad_input(args):
    with pytest.raises(ShellsplineError) as e:
        linear_blend(*args)
    _one_line(e)


def test_linear_blend_bc():
    with pytest.raises(ShellsplineError) as e:
        linear_blend([[0.0], [1.0]], [0, 4], 8, bc="foo")
    assert "bc" in _one_line(e)
    upper = linear_blend([[0.0], [1.0]], [0, 4], 8, bc="PERIODIC")
    assert np.array_equal(upper, linear_blend([[0.0], [1.0]], [0, 4], 8, bc="periodic"))
    assert upper[8, 0] == 0.0 and upper[6, 0] == 0.5


# 4. write_sequence --------------------------------------------------------------------------
def test_write_sequence_refuses_non_finite(tmp_path):
    V = np.random.default_rng(0).random((3, 4, 3))
    F = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    for bad in (np.nan, np.inf):
        W = V.copy()
        W[1, 2, 0] = bad
        with pytest.raises(ShellsplineError) as e:
            ss.write_sequence(tmp_path / "out", W, F)
        assert "NaN/inf" in _one_line(e)
        assert not (tmp_path / "out").exists()


# 5., 6. viz sources -------------------------------------------------------------------------
def _seq(tmp_path, name, report, fmt="obj"):
    V = np.random.default_rng(0).random((3, 4, 3))
    F = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    return ss.write_sequence(tmp_path / name, V, F, report, fmt=fmt)


def _cli(*args):
    return subprocess.run([sys.executable, "-m", "shellspline", *map(str, args)],
                          capture_output=True, text=True, timeout=300)


@pytest.mark.parametrize("report", [{"parameters": {"frames": "abc"}}, [1, 2],
                                    {"parameters": [1]}, {"mesh": "x"}])
def test_malformed_report_is_a_one_line_error(tmp_path, report):
    from shellspline import viz

    out = _seq(tmp_path, "o", {"K": 2})
    (out / "report.json").write_text(json.dumps(report))
    with pytest.raises(ShellsplineError) as e:
        viz.load_source(out)
    assert "report.json" in _one_line(e)
    if report == [1, 2]:
        r = _cli("plot", out, "-o", tmp_path / "p.png")
        assert r.returncode == 2, r.stderr
        assert "report.json" in r.stderr and "internal" not in r.stderr


def test_glb_file_is_a_source(tmp_path):
    from shellspline import viz

    out = _seq(tmp_path, "glbseq", {"parameters": {"frames": [0, 2]}}, fmt="glb")
    glb = out / "animation.glb"
    s = viz.load_source(glb)
    assert s.V.shape == (3, 4, 3) and s.frames.tolist() == [0, 2] and s.label == "glbseq"
    assert viz.scene_up_axis(glb) == "y"


# 7. pins of a welded mesh ------------------------------------------------------------------
def test_interpolate_pins_number_the_solve_mesh(tmp_path):
    """read_keyframes(pinned=) numbers the files' vertices; interpolate(pinned=) the solve
    mesh's (kf.V); kf.source.solve_vertices maps the former to the latter."""
    from data_synth.dcc import write_dcc

    paths = write_dcc("dcc_tube", tmp_path / "in")
    keys = [p for p in paths if p.suffix == ".obj"]
    frames = [int(x) for x in (tmp_path / "in" / "frames.txt").read_text().split()]
    kf = ss.read_keyframes(keys, frames=frames)
    assert kf.source is not None and kf.source.n_source != kf.n
    idx = [i for i in range(kf.source.n_source) if kf.source.to_solve[i] >= 0][-3:]
    kf_pinned = ss.read_keyframes(keys, frames=frames, pinned=idx)
    mapped = kf.source.solve_vertices(idx)
    assert kf_pinned.pinned.tolist() == mapped.tolist()
    p1 = _problem(kf_pinned).pinned
    p2 = _problem(kf, pinned=mapped).pinned
    assert p1.tolist() == p2.tolist()


# 8. options a run cannot apply -------------------------------------------------------------
@pytest.mark.parametrize("kw, option, why", [
    (dict(method="linear", coarse=20), "coarse", "method='linear'"),
    (dict(method="linear", fine=True), "fine", "method='linear'"),
    (dict(method="linear", transfer="displacement"), "transfer", "method='linear'"),
    (dict(method="linear", reference="keyframe"), "reference", "method='linear'"),
    (dict(method="linear", spline="discrete"), "spline", "method='linear'"),
    (dict(method="linear", fade_angle=0.2), "fade_angle", "method='linear'"),
    (dict(method="linear", fixpoint=1), "fixpoint", "method='linear'"),
    (dict(method="linear", rigid_track="spline"), "rigid_track", "method='linear'"),
    (dict(method="linear", solver_options={"max_time_s": 5.0}), "solver_options",
     "method='linear'"),
    (dict(solver_options={"max_time_s": 5.0}), "solver_options", "method='lta'"),
    # the reference geodesic takes max_time_s only: the rest was recorded, not applied
    (dict(reference="geodesic", solver_options={"max_time_s": 5.0, "max_iter": 1}),
     "solver_options", "'max_iter' does not apply to method='lta'"),
    (dict(pinned=[0, 1, 2, 3], rigid_track="linear"), "rigid_track", "pinned vertices fix"),
    (dict(pinned=[0, 1, 2, 3], rigid_subset=[10, 20, 30]), "rigid_subset",
     "pinned vertices fix"),
], ids=lambda v: ",".join(v) if isinstance(v, dict) else None)
def test_an_option_the_run_cannot_apply_is_refused(kf, kw, option, why):
    """Before, each of these ran and report["parameters"] recorded the option as applied."""
    with pytest.raises(ShellsplineError) as e:
        ss.interpolate(kf, **kw)
    msg = _one_line(e)
    assert msg.startswith(f"`{option}` ") and why in msg, msg


def test_what_this_mesh_leaves_unused_is_a_message_and_recorded_as_applied(kf):
    """A coarse vertex count not below the mesh's and a transfer where nothing is prolonged
    may come from options shared by meshes of every size: a message each, and the report
    records what was applied (``coarse="none"``, ``transfer=None``)."""
    said = []
    res = ss.interpolate(kf, coarse=500, transfer="displacement",
                         progress=lambda ev: ev["kind"] == "message" and said.append(ev["text"]))
    assert said[:2] == ["coarse=500 is not below the 42 vertices of this mesh: it is solved "
                        "at full resolution",
                        "transfer='displacement' is not applied: these 42 vertices are "
                        "solved at full resolution (coarse=500), so nothing is prolonged"]
    p = res.report["parameters"]
    assert p["coarse"] == "none" and p["transfer"] is None and "multires" not in res.report
    full = ss.interpolate(kf, coarse="none")
    assert np.array_equal(res.V, full.V) and full.report["parameters"]["transfer"] is None
    # coarse="none" with a transfer (one set of options for a full and a multiresolution
    # run): a message, the same frames
    said.clear()
    nt = ss.interpolate(kf, coarse="none", transfer="displacement",
                        progress=lambda ev: ev["kind"] == "message" and said.append(ev["text"]))
    assert said == ["transfer='displacement' is not applied: coarse='none' solves at full "
                    "resolution, so nothing is prolonged"]
    assert np.array_equal(nt.V, full.V) and nt.report["parameters"]["transfer"] is None
    # one set of Gauss–Newton options for every method: a message with linear blending;
    # what a run applies is still accepted: the weights of linear blending's energies,
    # coarse="none", a rigid track that one pin leaves a rotation to choose for
    said.clear()
    lin = ss.interpolate(kf, method="linear", coarse="none", eta=0.5,
                         gn_options={"max_iter": 3},
                         progress=lambda ev: ev["kind"] == "message" and said.append(ev["text"]))
    assert said == ["gn_options={'max_iter': 3} is not applied: method='linear' reconstructs "
                    "nothing (no Gauss–Newton)"]
    assert lin.report["parameters"]["eta"] == 0.5 and lin.report["parameters"]["gn_options"] is None
    assert ss.interpolate(kf, pinned=[0], rigid_track="linear").report["parameters"][
        "rigid_track"] == "linear"


def test_a_coarse_fraction_that_keeps_every_vertex_is_said_so(kf):
    """0.999 of the 42 vertices rounds to 42 (coarse_target): the note says that, not that
    a fraction "is not below the 42 vertices"; the run is at full resolution."""
    said = []
    res = ss.interpolate(kf, coarse=0.999,
                         progress=lambda ev: ev["kind"] == "message" and said.append(ev["text"]))
    assert said[:1] == ["coarse=0.999 keeps all 42 vertices of this mesh (0.999 × 42 rounds to "
                        "42): it is solved at full resolution"]
    assert res.report["parameters"]["coarse"] == "none" and "multires" not in res.report


@pytest.mark.parametrize("method, key", [("geodesic", "bogus"), ("nonlinear", "bogus"),
                                         ("geodesic", "gtol"),  # the nonlinear spline's
                                         ("nonlinear", "callback"),  # set by the run
                                         ("nonlinear", "energy")])  # eta, mu, lam make it
def test_unknown_solver_options_are_refused_up_front(kf, method, key):
    """Before, an unknown key reached the solver's call after the LΘA start was computed:
    a raw TypeError (unexpected keyword, or ``callback`` given twice), or ``energy=3`` taken
    as the energy."""
    with pytest.raises(ShellsplineError) as e:
        ss.interpolate(kf, method=method, solver_options={"max_time_s": 5.0, key: 3})
    msg = _one_line(e)
    from shellspline.pipeline.options import SOLVER_OPTIONS

    assert msg.startswith(f"`solver_options`: unknown option {key!r} for method={method!r}; "
                          f"valid: "), msg
    assert msg.endswith(", ".join(SOLVER_OPTIONS[method])) and "max_iter" in msg, msg
    # the keys the stages leave to the caller are accepted, the list is the solver's own
    assert "tol" in SOLVER_OPTIONS["geodesic"] and "gtol" in SOLVER_OPTIONS["nonlinear"]
    for k in SOLVER_OPTIONS[method]:
        assert InterpolationOptions(method=method, solver_options={k: 1}).solver_options == {k: 1}


@pytest.mark.parametrize("method, key, value, what", [
    ("nonlinear", "max_iter", "x", "a positive integer"),  # int() inside the stage before
    ("geodesic", "max_iter", 2.5, "a positive integer"),
    ("geodesic", "tol", "x", "a finite non-negative number"),  # a comparison in the solver
    ("nonlinear", "gtol", -1.0, "a finite non-negative number"),
    ("nonlinear", "max_iter", True, "a positive integer"),
    ("geodesic", "max_time_s", 0, "a positive number of seconds"),
    ("lta", "max_time_s", float("nan"), "a positive number of seconds"),  # reference geodesic
])
def test_solver_option_values_are_checked_up_front(kf, method, key, value, what):
    """A numeric solver option with a value of the wrong kind is a one-line error naming the
    key, before any work (it was a raw ValueError/TypeError from inside the solver, or, for
    the reference geodesic, only once its solve started)."""
    extra = {"reference": "geodesic"} if method == "lta" else {}
    with pytest.raises(ShellsplineError) as e:
        ss.interpolate(kf, method=method, solver_options={key: value}, **extra)
    assert _one_line(e) == f"`solver_options`: {key!r} must be {what}, got {value!r}"


def test_pins_fix_placement():
    from shellspline.pipeline.interpolation import pins_fix_placement

    m = trimesh.creation.icosphere(subdivisions=1)
    V, F = m.vertices, m.faces
    Vkey = np.stack([V, V * [1.5, 1, 1]])
    tri = [0, 1, 2]
    assert pins_fix_placement(Vkey, F, tri)
    assert not pins_fix_placement(Vkey, F, tri[:2]) and not pins_fix_placement(Vkey, F, None)
    # on one line: a rotation about it is left to the track
    line = V.copy()
    line[[0, 1, 2]] = [[0, 0, 0], [1, 0, 0], [2, 0, 0]]
    assert not pins_fix_placement(line[None], F, tri)
    # a second piece without pins is placed by the track
    two = np.concatenate([V, V + 5.0])
    F2 = np.concatenate([F, F + len(V)])
    assert not pins_fix_placement(two[None], F2, tri)
    assert pins_fix_placement(two[None], F2, tri + [len(V) + i for i in tri])


def test_job_file_keys_are_checked_like_the_command_line(tmp_path):
    """A key of a sequence's own entry that its method cannot use is refused when the job
    is loaded; one from [defaults] applies where it can (the Fig. 3 regression job sets
    the paper's spline for its LΘA sequences beside a linear baseline)."""
    import data_synth

    data_synth.write_batch("ellipsoids", tmp_path / "seqs", 1, 100)
    p = tmp_path / "job.toml"
    base = ('[job]\noutput = "out"\nworkers = 1\n[defaults]\nspline = "discrete"\n'
            'max_iter = 30\n[[sequences]]\nglob = "seqs/*"\nmethod = "linear"\n')
    p.write_text(base)
    job = ss.load_job(p)
    assert ss.run_batch(job).exit_code == 0
    rep = json.loads(next((tmp_path / "out").glob("*/report.json")).read_text())
    assert rep["parameters"]["method"] == "linear" and rep["parameters"]["gn_options"] is None
    assert rep["parameters"]["spline"] is None  # not the [defaults] one: linear has none
    for extra, key in (('spline = "discrete"\n', "spline"), ("coarse = 50\n", "coarse")):
        p.write_text(base + extra)
        with pytest.raises(ShellsplineError) as e:
            ss.load_job(p)
        assert f"[[sequences]] #1: '{key}' does not apply to method = 'linear'" in _one_line(e)
    p.write_text(base.replace('method = "linear"', 'coarse = "none"\nfine = true'))
    with pytest.raises(ShellsplineError) as e:
        ss.load_job(p)
    assert "'fine' does not apply with coarse = 'none'" in _one_line(e)

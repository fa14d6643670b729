"""The ``spline`` option end to end: the continuous-time spline of the descriptors reaches the
solve (targets = scipy's cubic spline through the keyframe descriptors; with the keyframe
reference, the weighted continuous spline), keyframes stay exact, the discrete default is
untouched, and the option reaches report.json, the CLI and the batch schema."""
import json
from pathlib import Path

import numpy as np
import pytest
from scipy.interpolate import CubicSpline

import data_synth
import shellspline as ss
from shellspline.cli.main import main
from shellspline.pipeline.options import InterpolationOptions


@pytest.fixture(scope="module")
def ellipsoids():
    return data_synth.generate("ellipsoids", n_vertices=200)


@pytest.fixture(scope="module")
def runs(ellipsoids):
    d = ellipsoids
    return {sp: ss.interpolate((d["V"], d["F"]), frames=d["frames"], eta=0.1, spline=sp)
            for sp in ("discrete", "continuous")}


def test_continuous_targets_are_scipy_cubic_splines_of_the_keyframe_descriptors(ellipsoids,
                                                                                  runs):
    d, res = ellipsoids, runs["continuous"]
    fr = np.asarray(d["frames"])
    K = res.K
    # the keyframes' own descriptors, independently of the pipeline (angles of these smooth
    # ellipsoids are far from ±π: no branch choice or clamping is involved)
    T = ss.topology(d["F"])
    Zkey = ss.lta_descriptors(np.asarray(d["V"], dtype=np.float64), T)
    ref = CubicSpline(fr, Zkey, bc_type="natural")(np.arange(K + 1))
    assert np.abs(res.Z - ref).max() <= 1e-9 * np.abs(Zkey).max()
    for j, f in enumerate(fr):  # keyframes exact, in the output and in the targets
        assert np.array_equal(res.V[f], d["V"][j])
    assert res.report["parameters"]["spline"] == "continuous"
    assert res.report["quality"]["keyframes_exact"]
    gn = res.report["gauss_newton"]
    assert gn["converged"] == gn["frames"]
    # the reconstruction solved for these targets (not the discrete ones)
    assert np.abs(res.V - runs["discrete"].V).max() > 1e-6 * np.ptp(d["V"])


def test_discrete_default_is_the_papers_spline_and_differs(ellipsoids, runs):
    d, res = ellipsoids, runs["discrete"]
    fr = np.asarray(d["frames"])
    T = ss.topology(d["F"])
    Zkey = ss.lta_descriptors(np.asarray(d["V"], dtype=np.float64), T)
    assert res.report["parameters"]["spline"] == "discrete"
    assert np.allclose(res.Z, ss.lta_spline(Zkey, fr, res.K), rtol=0, atol=1e-9)
    # the two splines differ between keyframes (by the discrete one's velocity kink)
    assert np.abs(runs["continuous"].Z - res.Z).max() > 1e-4 * np.abs(Zkey).max()
    default = ss.interpolate((d["V"], d["F"]), frames=d["frames"], eta=0.1)
    assert np.array_equal(default.V, res.V)


def test_continuous_periodic_closes(ellipsoids):
    d = ellipsoids
    res = ss.interpolate((d["V"], d["F"]), frames=[0, 4, 8], K=12, bc="periodic", eta=0.1,
                         spline="continuous")
    fr = np.array([0, 4, 8])
    ref = CubicSpline([0, 4, 8, 12], np.vstack([res.Z[fr], res.Z[:1]]),
                      bc_type="periodic")(np.arange(13))
    assert np.abs(res.Z - ref).max() <= 1e-9 * np.abs(res.Z).max()
    assert np.array_equal(res.V[12], res.V[0]) and np.array_equal(res.V[0], d["V"][0])


def test_continuous_with_the_keyframe_reference(ellipsoids):
    """Weights that vary in time (each frame weighted by its nearest keyframe): the targets
    are the continuous limit of the weighted spline, computed here from the keyframes and
    their weights by shells.lta_spline, and the discrete keyframe-reference run differs."""
    from shellspline.timeline import keyframe_bracket

    d = ellipsoids
    fr = np.asarray(d["frames"])
    res = ss.interpolate((d["V"], d["F"]), frames=fr, eta=0.1, reference="keyframe",
                         spline="continuous")
    K = res.K
    T = ss.topology(d["F"])
    V = np.asarray(d["V"], dtype=np.float64)
    j0, j1, t = keyframe_bracket(fr, K)
    W = ss.lta_weights(V, T, eta=0.1)[np.where(t <= 0.5, j0, j1)]
    ref = ss.lta_spline(ss.lta_descriptors(V, T), fr, K, weights=W, spline="continuous")
    assert np.abs(res.Z - ref).max() <= 1e-9 * np.abs(ref).max()
    disc = ss.lta_spline(ss.lta_descriptors(V, T), fr, K, weights=W)
    assert np.abs(disc - ref).max() > 1e-4 * np.abs(ref).max()
    for j, f in enumerate(fr):
        assert np.array_equal(res.V[f], d["V"][j])
    assert res.report["parameters"]["reference"] == "keyframe"
    assert res.report["parameters"]["spline"] == "continuous"
    gn = res.report["gauss_newton"]
    assert gn["converged"] == gn["frames"]


def test_spline_option_is_checked():
    assert InterpolationOptions(spline=" Continuous", reference="keyframe").spline == "continuous"
    with pytest.raises(ValueError, match="`spline` must be one of 'discrete', 'continuous'") as e:
        InterpolationOptions(spline="cubic")
    assert "\n" not in str(e.value)


def test_cli_flag_reaches_the_report(tmp_path, capsys):
    d = tmp_path / "ell"
    data_synth.write("ellipsoids", d, n_vertices=150)
    poses = sorted(str(p) for p in Path(d).glob("pose_*.obj"))
    out = tmp_path / "out"
    rc = main(["interpolate", *poses, "--frames", str(d / "frames.txt"), "-o", str(out),
               "--eta", "0.1", "--spline", "continuous", "-q"])
    assert rc == 0
    assert json.loads((out / "report.json").read_text())["parameters"]["spline"] == "continuous"
    capsys.readouterr()
    rc = main(["interpolate", *poses, "--frames", str(d / "frames.txt"), "-o",
               str(tmp_path / "o2"), "--spline", "continuous", "--reference", "keyframe", "-q"])
    rep = json.loads((tmp_path / "o2" / "report.json").read_text())["parameters"]
    assert rc == 0 and rep["spline"] == "continuous" and rep["reference"] == "keyframe"
    with pytest.raises(SystemExit) as e:
        main(["interpolate", *poses, "-o", str(tmp_path / "o3"), "--spline", "cubic"])
    assert e.value.code == 2


def test_batch_key(tmp_path):
    data_synth.write_batch("ellipsoids", tmp_path / "seqs", 1, 100)
    base = ('[job]\noutput = "out"\nworkers = 1\n[defaults]\neta = 0.1\n'
            '[[sequences]]\nglob = "seqs/*"\n')
    p = tmp_path / "job.toml"
    p.write_text(base)
    assert ss.load_job(p).sequences[0].params["spline"] == "discrete"
    p.write_text(base + 'spline = " Continuous"\n')
    job = ss.load_job(p)
    assert job.sequences[0].params["spline"] == "continuous"
    summary = ss.run_batch(job)
    assert summary.exit_code == 0
    rep = json.loads(next((tmp_path / "out").glob("*/report.json")).read_text())
    assert rep["parameters"]["spline"] == "continuous"
    p.write_text(base + 'spline = "cubic"\n')
    with pytest.raises(ValueError, match="key 'spline': must be one of discrete, continuous, "
                                         "got 'cubic'"):
        ss.load_job(p)

"""The ``spline`` option end to end: the continuous-time spline of the descriptors reaches the
solve (targets = scipy's cubic spline through the keyframe descriptors; with the keyframe
reference, the weighted continuous spline), keyframes stay exact, it is the default of
``interpolate``, the CLI and the batch schema while ``spline="discrete"`` still gives the
paper's spline (and the paper-reproducing regression pipeline pins it), and the option and the
meaning of the per-frame energies reach report.json."""
import json
from pathlib import Path

import numpy as np
import pytest
from scipy.interpolate import CubicSpline

import data_synth
import shellspline as ss
from shellspline.cli.main import main
from shellspline.pipeline.options import DEFAULT_SPLINE, InterpolationOptions
from shellspline.pipeline.report import ENERGY_TERMS, sequence_energies

REPO = Path(__file__).resolve().parents[2]


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


def test_default_is_continuous_and_discrete_is_the_papers_spline(ellipsoids, runs):
    d, res = ellipsoids, runs["discrete"]
    fr = np.asarray(d["frames"])
    T = ss.topology(d["F"])
    Zkey = ss.lta_descriptors(np.asarray(d["V"], dtype=np.float64), T)
    assert res.report["parameters"]["spline"] == "discrete"
    # spline="discrete" is the paper's time-discrete spline (shells.lta_spline's default)
    assert np.allclose(res.Z, ss.lta_spline(Zkey, fr, res.K), rtol=0, atol=1e-9)
    # the two splines differ between keyframes (by the discrete one's velocity kink)
    assert np.abs(runs["continuous"].Z - res.Z).max() > 1e-4 * np.abs(Zkey).max()
    assert DEFAULT_SPLINE == "continuous" and InterpolationOptions().spline == "continuous"
    default = ss.interpolate((d["V"], d["F"]), frames=d["frames"], eta=0.1)
    assert default.report["parameters"]["spline"] == "continuous"
    assert np.array_equal(default.V, runs["continuous"].V)
    assert np.array_equal(default.Z, runs["continuous"].Z)


def test_no_velocity_kink_in_the_default_targets(ellipsoids, runs):
    """What the default buys. Both splines are a cubic in the frame index on each keyframe
    gap, so their second differences D(k) = z[k+1] - 2 z[k] + z[k-1] are linear in k inside a
    gap. At the interior keyframe f a curve that is C² (no kink) has D(f) = z''(f) + (jump of
    z''')/6 with everything read off the neighbours' D (extrapolated to f); what is left over
    is the jump of the velocity. The continuous targets leave nothing (and match scipy's
    z''), the discrete ones leave their kink."""
    d = ellipsoids
    fr = np.asarray(d["frames"])
    f = int(fr[1])
    assert f - 2 > fr[0] and f + 2 < fr[2]  # two in-between frames each side

    def kink(Z):
        D = Z[2:] - 2 * Z[1:-1] + Z[:-2]  # D[k-1] is D(k)
        Dl, Dr = 2 * D[f - 2] - D[f - 3], 2 * D[f] - D[f + 1]  # z''(f) from each side
        jump3 = (D[f + 1] - D[f]) - (D[f - 2] - D[f - 3])
        return D[f - 1] - (Dl + Dr) / 2 - jump3 / 6, (Dl + Dr) / 2

    Zkey = ss.lta_descriptors(np.asarray(d["V"], dtype=np.float64), ss.topology(d["F"]))
    scale = np.abs(Zkey).max()
    kc, z2c = kink(runs["continuous"].Z)
    kd, _ = kink(runs["discrete"].Z)
    assert np.abs(kc).max() <= 1e-9 * scale
    assert np.allclose(z2c, CubicSpline(fr, Zkey, bc_type="natural")(f, 2), rtol=0,
                       atol=1e-9 * scale)
    assert np.linalg.norm(kd) > 0.02 * np.linalg.norm(z2c)


@pytest.mark.parametrize("reference", ["constant", "keyframe"])
def test_two_keyframes_both_splines_give_the_same_path(ellipsoids, reference):
    """One keyframe gap, natural ends: both splines have zero energy on the same path (the
    linear path of the descriptors for a constant reference; with the keyframe reference the
    path whose flux w z' is constant, which both reach), so the default changes nothing."""
    d = ellipsoids
    V2 = np.asarray(d["V"], dtype=np.float64)[[0, 2]]
    res = {sp: ss.interpolate((V2, d["F"]), frames=[0, 8], eta=0.1, reference=reference,
                              spline=sp) for sp in ("discrete", "continuous")}
    Zd, Zc = res["discrete"].Z, res["continuous"].Z
    scale = np.abs(Zd).max()
    assert np.abs(Zd - Zc).max() <= 1e-12 * scale
    if reference == "constant":  # the linear path of the descriptors, an independent oracle
        Zkey = ss.lta_descriptors(V2, ss.topology(d["F"]))
        t = np.arange(9)[:, None] / 8.0
        assert np.abs(Zc - ((1 - t) * Zkey[0] + t * Zkey[1])).max() <= 1e-12 * scale
    assert np.abs(res["discrete"].V - res["continuous"].V).max() <= 1e-6 * np.ptp(V2)


def test_report_says_what_the_per_frame_energies_are(ellipsoids, runs):
    d = ellipsoids
    for sp, r in runs.items():
        assert r.report["energies"]["per_frame_terms"] == ENERGY_TERMS[sp]
    lin = ss.interpolate((d["V"], d["F"]), frames=d["frames"], method="linear")
    assert lin.report["energies"]["per_frame_terms"] == ENERGY_TERMS[None]
    # the claim of the continuous label: on the continuous targets the eq. 11 terms are
    # w z''(k)^2 / 4 at the frames between keyframes (constant reference; z'' from scipy), and
    # 0 after the last keyframe (its tangent line)
    fr = np.asarray(d["frames"])
    V = np.asarray(d["V"], dtype=np.float64)
    T = ss.topology(d["F"])
    Zkey = ss.lta_descriptors(V, T)
    K = int(fr[-1]) + 3
    Z = ss.lta_spline(Zkey, fr, K, spline="continuous")
    W = ss.lta_weights(V[0], T, eta=0.1)
    Vseq = ss.interpolate((V, d["F"]), frames=fr, K=K, method="linear").V
    E = np.asarray(sequence_energies(Vseq, Z, T, "natural", W)["lta_spline_energy_per_frame"])
    k = np.setdiff1d(np.arange(1, int(fr[-1])), fr)
    z2 = CubicSpline(fr, Zkey, bc_type="natural")(k, 2)
    assert np.allclose(E[k], (W * z2 ** 2).sum(axis=1) / 4, rtol=1e-9, atol=0)
    assert np.all(E[int(fr[-1]) + 1:K] <= 1e-20 * E.max())


def test_the_paper_regression_pipeline_pins_the_discrete_spline():
    """pipelines/regression_ellipsoids.toml reproduces paper Fig. 3 with expected values of
    the discrete spline: every sequence runs it, whatever the default."""
    job = ss.load_job(REPO / "pipelines" / "regression_ellipsoids.toml")
    assert job.sequences and all(q.params["spline"] == "discrete" for q in job.sequences)


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
               "--eta", "0.1", "-q"])
    assert rc == 0  # no --spline: the default
    assert json.loads((out / "report.json").read_text())["parameters"]["spline"] == "continuous"
    capsys.readouterr()
    rc = main(["interpolate", *poses, "--frames", str(d / "frames.txt"), "-o",
               str(tmp_path / "o2"), "--spline", "discrete", "--reference", "keyframe", "-q"])
    rep = json.loads((tmp_path / "o2" / "report.json").read_text())["parameters"]
    assert rc == 0 and rep["spline"] == "discrete" and rep["reference"] == "keyframe"
    with pytest.raises(SystemExit) as e:
        main(["interpolate", *poses, "-o", str(tmp_path / "o3"), "--spline", "cubic"])
    assert e.value.code == 2


def test_batch_key(tmp_path):
    data_synth.write_batch("ellipsoids", tmp_path / "seqs", 1, 100)
    base = ('[job]\noutput = "out"\nworkers = 1\n[defaults]\neta = 0.1\n'
            '[[sequences]]\nglob = "seqs/*"\n')
    p = tmp_path / "job.toml"
    p.write_text(base)
    assert ss.load_job(p).sequences[0].params["spline"] == "continuous"  # the default
    p.write_text(base + 'spline = " Discrete"\n')
    job = ss.load_job(p)
    assert job.sequences[0].params["spline"] == "discrete"
    summary = ss.run_batch(job)
    assert summary.exit_code == 0
    rep = json.loads(next((tmp_path / "out").glob("*/report.json")).read_text())
    assert rep["parameters"]["spline"] == "discrete"
    p.write_text(base + 'spline = "cubic"\n')
    with pytest.raises(ValueError, match="key 'spline': must be one of discrete, continuous, "
                                         "got 'cubic'"):
        ss.load_job(p)

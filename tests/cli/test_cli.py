"""The command line end to end: synthetic data, shared data, and every bad input."""
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import data_synth
import shellspline as ss
from shellspline.cli.main import main
from conftest import shared_data

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def ell_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("ell")
    data_synth.write("ellipsoids", d, n_vertices=200)
    return d


def _poses(d):
    return sorted(str(p) for p in Path(d).glob("pose_*.obj"))


def test_interpolate_end_to_end(ell_dir, tmp_path, capsys):
    out = tmp_path / "out"
    rc = main(["interpolate", *_poses(ell_dir), "--frames", str(ell_dir / "frames.txt"),
               "-o", str(out), "--eta", "0.1"])
    assert rc == 0
    files = sorted(out.glob("frame_*.obj"))
    assert len(files) == 13 and files[0].name == "frame_0000.obj"
    rep = json.loads((out / "report.json").read_text())
    assert rep["parameters"]["eta"] == 0.1 and rep["parameters"]["K"] == 12
    assert rep["quality"]["keyframes_exact"] and rep["quality"]["flipped_faces"] == 0
    assert "write" in rep["timings"] and "read" in rep["timings"]
    # output keyframes are the input keyframes bit for bit
    V, F, _ = ss.read_sequence(out)
    for j, p in enumerate(_poses(ell_dir)):
        Vin, Fin = ss.read_mesh(p)
        assert np.array_equal(V[6 * j], Vin) and np.array_equal(F, Fin)
    err = capsys.readouterr().err
    assert "wrote 13 frames" in err and "Gauss–Newton" in err


def test_linear_method_and_K(ell_dir, tmp_path):
    out = tmp_path / "lin"
    assert main(["interpolate", *_poses(ell_dir), "--K", "8", "--method", "linear", "-o", str(out),
                 "-q"]) == 0
    assert len(list(out.glob("frame_*.obj"))) == 9


def test_existing_output_is_not_overwritten(ell_dir, tmp_path, capsys):
    out = tmp_path / "o"
    out.mkdir()
    (out / "keep.txt").write_text("precious")
    rc = main(["interpolate", *_poses(ell_dir), "-o", str(out), "--method", "linear", "-q"])
    assert rc == 2 and (out / "keep.txt").read_text() == "precious"
    assert str(out) in capsys.readouterr().err


def test_refuses_to_write_into_inputs(ell_dir, capsys):
    rc = main(["interpolate", *_poses(ell_dir), "-o", str(ell_dir), "--method", "linear", "-q",
               "--overwrite"])
    assert rc == 2
    assert len(_poses(ell_dir)) == 3


def test_bad_inputs_give_one_line_errors(ell_dir, tmp_path, capsys):
    other = tmp_path / "other"
    data_synth.write("ellipsoids", other, n_vertices=500)
    bad = tmp_path / "bad.obj"
    bad.write_text("this is not a mesh\n")
    cases = [
        ([_poses(ell_dir)[0], _poses(other)[1]], "vertices"),
        ([_poses(ell_dir)[0], str(tmp_path / "missing.obj")], "missing.obj"),
        ([_poses(ell_dir)[0], str(bad)], "bad.obj"),
        ([_poses(ell_dir)[0]], "2"),
    ]
    for files, phrase in cases:
        rc = main(["interpolate", *files, "-o", str(tmp_path / "x"), "-q"])
        err = capsys.readouterr().err
        assert rc == 2, files
        assert phrase in err and "Traceback" not in err
        assert len(err.strip().splitlines()) == 1
    assert not (tmp_path / "x").exists()
    rc = main(["interpolate", *_poses(ell_dir), "--frames", "0,5,5", "-o", str(tmp_path / "y")])
    assert rc == 2 and "strictly increasing" in capsys.readouterr().err


def test_console_script_runs_as_module(ell_dir, tmp_path):
    out = tmp_path / "m"
    r = subprocess.run([sys.executable, "-m", "shellspline", "interpolate", *_poses(ell_dir),
                        "-o", str(out), "--method", "linear"], capture_output=True, text=True,
                       cwd=REPO)
    assert r.returncode == 0, r.stderr
    assert (out / "report.json").exists()


def test_unit_sphere_shared_data(tmp_path):
    D = shared_data("unit_sphere")
    out = tmp_path / "sphere"
    files = [D / "unitSphere1.ply", D / "unitSphere1_defX.ply", D / "unitSphere1_defY.ply"]
    rc = main(["interpolate", *map(str, files), "--frames", "0,3,6", "--eta", "0.01", "-o",
               str(out), "-q", "--workers", "2"])
    assert rc == 0
    rep = json.loads((out / "report.json").read_text())
    assert rep["quality"]["flipped_faces"] == 0 and rep["quality"]["degenerate_faces"] == 0
    assert rep["gauss_newton"]["converged"] == 4


def test_overflowing_numbers_are_usage_errors(ell_dir, tmp_path, capsys):
    for extra in (["--frames", "0,6,99999999999999999999999"], ["--K", "100000000000"],
                  ["--K", "-3"], ["--max-iter", "0"]):
        rc = main(["interpolate", *_poses(ell_dir), "-o", str(tmp_path / "o"), "-q", *extra])
        err = capsys.readouterr().err
        assert rc == 2 and len(err.strip().splitlines()) == 1 and "Traceback" not in err


def test_report_is_world_readable_strict_json(ell_dir, tmp_path):
    out = tmp_path / "r"
    assert main(["interpolate", *_poses(ell_dir), "-o", str(out), "-q", "--K", "6"]) == 0
    assert (out / "report.json").stat().st_mode & 0o777 == 0o644
    json.loads((out / "report.json").read_text(), parse_constant=lambda c: pytest.fail(c))


def test_overwrite_never_deletes_the_pinned_or_frames_file(ell_dir, tmp_path, capsys):
    out = tmp_path / "prev"
    assert main(["interpolate", *_poses(ell_dir), "-o", str(out), "-q", "--method",
                 "linear"]) == 0
    (out / "pinned.txt").write_text("0\n")
    rc = main(["interpolate", *_poses(ell_dir), "-o", str(out), "-q", "--overwrite",
               "--pinned", str(out / "pinned.txt")])
    assert rc == 2 and (out / "pinned.txt").exists()


def test_nonlinear_ftol_from_the_command_line(ell_dir, tmp_path, capsys):
    out = tmp_path / "nl"
    rc = main(["interpolate", *_poses(ell_dir), "--K", "4", "--eta", "0.1", "--method",
               "nonlinear", "--ftol", "1e-4", "-o", str(out), "-q"])
    # an ftol stop is not convergence (the gradient criterion does not hold): written, exit 1
    assert rc == 1
    nl = json.loads((out / "report.json").read_text())["nonlinear"]
    E = nl["energy_history"]
    assert not nl["success"] and "ftol" in nl["message"], nl["message"]
    assert len(E) > 3 and E[-4] - E[-1] <= 1e-4 * E[-1]
    assert "ftol" in capsys.readouterr().err  # the one-line note of the stalled stage
    for extra in (["--ftol", "1e-4"], ["--ftol", "-1", "--method", "nonlinear"]):
        rc = main(["interpolate", *_poses(ell_dir), "-o", str(tmp_path / "o"), "-q", *extra])
        err = capsys.readouterr().err
        assert rc == 2 and "--ftol" in err and len(err.strip().splitlines()) == 1


def test_nonlinear_progress_lines_and_summary(ell_dir, tmp_path, capsys):
    """Off a terminal the nonlinear stage logs one line per outer iteration (the numbers of
    report.json's histories) and the summary states the energy and gradient reduction."""
    out = tmp_path / "nl"
    rc = main(["interpolate", *_poses(ell_dir), "--K", "4", "--eta", "0.1", "--method",
               "nonlinear", "-o", str(out)])
    err = capsys.readouterr().err
    assert rc == 0
    nl = json.loads((out / "report.json").read_text())["nonlinear"]
    lines = [ln.split() for ln in err.splitlines() if ln.split()[:2] == ["nonlinear", "it"]]
    assert len(lines) == nl["nit"] + 1 == len(nl["energy_history"])
    g0 = nl["grad_norm_history"][0]
    for k, ln in enumerate(lines):
        assert int(ln[2]) == k
        assert float(ln[4]) == pytest.approx(nl["energy_history"][k], rel=1e-6)
        assert float(ln[6]) == pytest.approx(nl["grad_norm_history"][k] / g0, rel=0.06)
    summary = [ln for ln in err.splitlines() if ln.startswith("nonlinear: converged")]
    red = nl["grad_norm_final"] / nl["grad_norm_initial"]
    assert len(summary) == 1 and f"|g|/|g0| {red:.1e}" in summary[0] and red <= 1e-6


def test_nonlinear_exit_code_is_decided_by_the_nonlinear_stage(ell_dir, tmp_path, capsys):
    """--method nonlinear writes the nonlinear result: LΘA start frames at --max-iter do not
    make it exit 1 when the nonlinear stage converged (they stay in report.json and the
    summary); a nonlinear stage that stalls still exits 1, and so does LΘA at --max-iter."""
    from shellspline.batch.sequence import quality_warning

    base = ["interpolate", *_poses(ell_dir), "--K", "4", "--eta", "0.1", "--max-iter", "1"]
    out = tmp_path / "nl"
    rc = main([*base, "--method", "nonlinear", "-o", str(out)])
    err = capsys.readouterr().err
    rep = json.loads((out / "report.json").read_text())
    gn, nl = rep["gauss_newton"], rep["nonlinear"]
    limit = gn["iteration_limit"]
    assert limit and gn["converged"] < gn["frames"]  # the start frames did hit --max-iter
    assert nl["success"] and nl["grad_norm_final"] <= 1e-6 * nl["grad_norm_initial"]
    assert rc == 0, err
    assert f"start frames: {len(limit)} at the iteration limit (frames {limit})" in err
    assert quality_warning(rep) == ""  # batch: the same verdict
    # the nonlinear stage stalls (ftol stop): exit 1 whatever the start frames did
    rc = main([*base, "--method", "nonlinear", "--ftol", "1e-2", "-o", str(tmp_path / "st"),
               "-q"])
    rep = json.loads((tmp_path / "st" / "report.json").read_text())
    assert not rep["nonlinear"]["success"] and rc == 1
    assert "nonlinear did not converge" in quality_warning(rep)
    # the nonlinear stage at its own iteration limit (library: solver_options): a problem
    from shellspline.pipeline.report import convergence_problems

    kf = ss.read_keyframes(_poses(ell_dir))
    with pytest.warns(RuntimeWarning, match="maximum number of iterations"):
        res = ss.interpolate(kf, K=4, method="nonlinear", eta=0.1, gn_options={"max_iter": 1},
                             solver_options={"max_iter": 1})
    assert not res.report["nonlinear"]["success"] and res.report["nonlinear"]["nit"] == 1
    assert convergence_problems(res.report) == ["nonlinear did not converge"]
    # without the nonlinear stage the Gauss–Newton frames are the output: exit 1
    rc = main([*base, "-o", str(tmp_path / "lta"), "-q"])
    rep = json.loads((tmp_path / "lta" / "report.json").read_text())
    assert rep["gauss_newton"]["iteration_limit"] and rc == 1
    assert "Gauss–Newton converged on" in quality_warning(rep)


def test_progress_bar_on_a_terminal_draws_the_described_state():
    import io

    from shellspline.cli.main import _Bar

    class Tty(io.StringIO):
        def isatty(self):
            return True

    s = Tty()
    bar = _Bar(stream=s)
    bar({"kind": "stage_start", "stage": "nonlinear", "total": 1000, "done": 0})
    bar({"kind": "advance", "stage": "nonlinear", "done": 500, "total": 1000,
         "text": "it   3  F 1.5  |g|/|g0| 1.0e-03"})
    drawn = s.getvalue().split("\r\033[K")[-1]
    assert "[" + "#" * 15 + "." * 15 + "]" in drawn and "|g|/|g0| 1.0e-03" in drawn
    assert "eta" not in drawn and "\n" not in drawn  # redrawn in place, no log line
    bar({"kind": "stage_end", "stage": "nonlinear", "seconds": 2.0, "total": 1000})
    assert s.getvalue().endswith("nonlinear       2.000 s\n")


def test_summary_names_the_seams_and_their_bridges(tmp_path, capsys):
    # the flexing tube of data_synth.stress: each gap's two runs meet in different minima
    import json

    import trimesh

    from data_synth import stress

    d = stress.joint()
    paths = []
    for i, V in enumerate(d["V"]):
        p = tmp_path / f"pose{i}.obj"
        trimesh.Trimesh(V, d["F"], process=False).export(p)
        paths.append(str(p))
    out = tmp_path / "out"
    rc = main(["interpolate", *paths, "--frames", "0,10,20", "-o", str(out)])
    err = capsys.readouterr().err
    rep = json.loads((out / "report.json").read_text())
    seams = [r for r in rep["frames"] if "seam_jump" in r]
    kept = [r for r in seams if r["bridge"]["kept"]]
    assert rc in (0, 1) and seams and kept
    line = next(ln for ln in err.splitlines() if ln.startswith("seams: "))
    assert line.startswith(f"seams: {len(seams)} ") and f"{len(kept)} bridged" in line
    assert f"{kept[0]['bridge']['step_ratio_before']:.2f} -> " in line


# A child that is the console script (argv[0] .../shellspline) and raises SIGINT at itself
# while the package is being imported (at its first import of numpy): a Ctrl-C during
# start-up, made deterministic.
_CTRL_C_AT_IMPORT = """
import builtins, signal, sys
sys.argv = ["/usr/local/bin/shellspline", "motion", "distance", "a.bvh", "b.bvh"]
real = builtins.__import__
def hooked(name, *args, **kw):
    if name == "numpy":
        builtins.__import__ = real
        signal.raise_signal(signal.SIGINT)
    return real(name, *args, **kw)
builtins.__import__ = hooked
from shellspline.cli.main import main
sys.exit(main())
"""


def _sigint_default():
    """preexec_fn: SIGINT at Python's default (a background runner may ignore it)."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_DFL)


def test_ctrl_c_during_start_up_is_one_line_and_exit_130(tmp_path, monkeypatch, capsys):
    """Ctrl-C while the command started (importing the package, building the parser) printed
    a KeyboardInterrupt traceback; later ones said "interrupted; no output was written",
    exit 130. Now the same line and code from the first line of the package on."""
    import shellspline.cli.main as cli_main

    def interrupted():
        raise KeyboardInterrupt

    monkeypatch.setattr(cli_main, "_build_parser", interrupted)
    try:
        code = main(["motion", "distance", "a.bvh", "b.bvh"])
    except KeyboardInterrupt:
        pytest.fail("KeyboardInterrupt escaped main() during start-up")
    err = capsys.readouterr().err
    assert code == 130 and err == "shellspline: interrupted; no output was written\n"
    r = subprocess.run([sys.executable, "-c", _CTRL_C_AT_IMPORT], cwd=tmp_path,
                       capture_output=True, text=True, timeout=120, preexec_fn=_sigint_default)
    assert r.returncode == 130, r.stderr
    assert r.stderr == "shellspline: interrupted; no output was written\n", r.stderr
    assert r.stdout == "" and list(tmp_path.iterdir()) == []
    # a program of the user's that imports shellspline keeps Python's own Ctrl-C
    r = subprocess.run([sys.executable, "-c", "import signal, shellspline; print(signal."
                        "getsignal(signal.SIGINT) is signal.default_int_handler)"],
                       capture_output=True, text=True, timeout=120, preexec_fn=_sigint_default)
    assert r.returncode == 0 and r.stdout.strip() == "True", r.stderr


# --- options the run cannot use ----------------------------------------------------------------
@pytest.mark.parametrize("extra, flag, why", [
    (["--method", "linear", "--coarse", "50"], "--coarse", "--method linear"),
    (["--method", "linear", "--fine"], "--fine", "--method linear"),
    (["--method", "linear", "--transfer", "gradient"], "--transfer", "--method linear"),
    (["--method", "linear", "--reference", "keyframe"], "--reference", "--method linear"),
    (["--method", "linear", "--spline", "continuous"], "--spline", "--method linear"),
    (["--method", "linear", "--fade-angle", "0.2"], "--fade-angle", "--method linear"),
    (["--method", "linear", "--rigid-track", "fit"], "--rigid-track", "--method linear"),
    (["--coarse", "none", "--fine"], "--fine", "--coarse none"),
    (["--fine"], "--fine", "--coarse auto solves these 162 vertices at full resolution"),
    (["--method", "geodesic", "--coarse", "50", "--fine"], "--fine", "--method geodesic"),
], ids=lambda v: " ".join(v) if isinstance(v, list) else None)
def test_an_option_the_run_cannot_use_is_refused(ell_dir, tmp_path, capsys, extra, flag, why):
    """An option given that the run would not use is exit 2 with one line naming the flag,
    why and what to do, before anything is computed or written; a default value given
    explicitly counts too (before, --method linear took all of these and report.json
    recorded them as applied)."""
    out = tmp_path / "o"
    rc = main(["interpolate", *_poses(ell_dir), "--frames", str(ell_dir / "frames.txt"),
               "-o", str(out), "-q", *extra])
    err = capsys.readouterr().err
    assert rc == 2 and len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert err.startswith(f"shellspline: error: {flag} ") and why in err, err
    assert "drop it" in err and not out.exists()


def test_rigid_placement_options_with_pins_that_fix_the_placement(ell_dir, tmp_path, capsys):
    """Three or more pins not on one line fix every frame's rigid placement: --rigid-track
    and --rigid-subset would change nothing, so they are refused; one pin leaves a rotation
    free, and the track is used."""
    pins = tmp_path / "pins.txt"
    pins.write_text("0 1 2 3 4 5 6 7 8 9\n")
    base = ["interpolate", *_poses(ell_dir), "--frames", str(ell_dir / "frames.txt"), "-q",
            "--pinned", str(pins)]
    for extra in (["--rigid-track", "spline"], ["--rigid-subset", str(pins)]):
        rc = main([*base, "-o", str(tmp_path / "o"), *extra])
        err = capsys.readouterr().err
        assert rc == 2 and len(err.strip().splitlines()) == 1, err
        assert err.startswith(f"shellspline: error: {extra[0]} has no effect here: the pinned "
                              "vertices fix every frame's rigid placement"), err
    assert not (tmp_path / "o").exists()
    pins.write_text("0\n")
    out = tmp_path / "one"
    assert main([*base, "-o", str(out), "--rigid-track", "spline"]) == 0
    assert json.loads((out / "report.json").read_text())["parameters"]["rigid_track"] == "spline"


def test_a_coarse_fraction_that_keeps_every_vertex_is_a_note_in_flags(ell_dir, tmp_path,
                                                                        capsys):
    """0.999 of the 162 vertices rounds to 162: the note says so in the command line's
    spelling (it read "--coarse 0.999 is not below the 162 vertices"), the run is at full
    resolution and report.json records coarse "none"."""
    out = tmp_path / "frac"
    assert main(["interpolate", *_poses(ell_dir), "--frames", str(ell_dir / "frames.txt"),
                 "-o", str(out), "--coarse", "0.999"]) == 0
    notes = [ln for ln in capsys.readouterr().err.splitlines() if ln.startswith("  note: ")]
    assert notes == ["  note: --coarse 0.999 keeps all 162 vertices of this mesh (0.999 × 162 "
                     "rounds to 162): it is solved at full resolution"]
    rep = json.loads((out / "report.json").read_text())
    assert rep["parameters"]["coarse"] == "none" and "multires" not in rep


def test_options_this_mesh_leaves_unused_are_a_note_and_recorded_as_applied(ell_dir, tmp_path,
                                                                             capsys):
    """A --coarse count not below the mesh's vertices, and a --transfer where nothing is
    prolonged, serve meshes of every size: the run goes on with one note each, and
    report.json records what was applied (coarse "none", transfer null), not the value
    given."""
    base = ["interpolate", *_poses(ell_dir), "--frames", str(ell_dir / "frames.txt")]
    out = tmp_path / "big"
    assert main([*base, "-o", str(out), "--coarse", "5000", "--transfer", "displacement"]) == 0
    notes = [ln for ln in capsys.readouterr().err.splitlines() if ln.startswith("  note: ")]
    assert notes == ["  note: --coarse 5000 is not below the 162 vertices of this mesh: it is "
                     "solved at full resolution",
                     "  note: --transfer displacement is not applied: these 162 vertices are "
                     "solved at full resolution (--coarse 5000), so nothing is prolonged"]
    rep = json.loads((out / "report.json").read_text())
    assert rep["parameters"]["coarse"] == "none" and rep["parameters"]["transfer"] is None
    assert "multires" not in rep
    # the same frames as a run at full resolution without them
    ref = tmp_path / "ref"
    assert main([*base, "-o", str(ref), "-q", "--coarse", "none"]) == 0
    assert np.array_equal(ss.read_sequence(out)[0], ss.read_sequence(ref)[0])
    assert json.loads((ref / "report.json").read_text())["parameters"]["transfer"] is None
    # a transfer that is applied is recorded as given
    mr = tmp_path / "mr"
    assert main([*base, "-o", str(mr), "-q", "--coarse", "50", "--transfer",
                 "displacement"]) == 0
    rep = json.loads((mr / "report.json").read_text())
    assert rep["parameters"]["transfer"] == "displacement" and "multires" in rep
    # --coarse none with a --transfer (a full run compared with a multiresolution one, the
    # same options for both): a note, and the frames of the run without it
    capsys.readouterr()
    nt = tmp_path / "none_transfer"
    assert main([*base, "-o", str(nt), "--coarse", "none", "--transfer", "displacement"]) == 0
    notes = [ln for ln in capsys.readouterr().err.splitlines() if ln.startswith("  note: ")]
    assert notes == ["  note: --transfer displacement is not applied: --coarse none solves at "
                     "full resolution, so nothing is prolonged"]
    assert json.loads((nt / "report.json").read_text())["parameters"]["transfer"] is None
    assert np.array_equal(ss.read_sequence(nt)[0], ss.read_sequence(ref)[0])
    # linear blending: --max-iter (one set of options for every method) is a note, the
    # weights of its report's energies and --coarse none apply
    capsys.readouterr()
    lin = {}
    for eta in ("1e-3", "0.5"):
        o = tmp_path / f"lin{eta}"
        assert main([*base, "-o", str(o), "--method", "linear", "--coarse", "none",
                     "--eta", eta, "--max-iter", "5"]) == 0
        lin[eta] = json.loads((o / "report.json").read_text())
        notes = [ln for ln in capsys.readouterr().err.splitlines() if "note:" in ln]
        assert notes == ["  note: --max-iter 5 is not applied: --method linear reconstructs "
                         "nothing (no Gauss–Newton)"]
    assert lin["0.5"]["parameters"]["eta"] == 0.5
    assert lin["0.5"]["parameters"]["gn_options"] is None  # before: {"max_iter": 5}, then {}
    E = {k: r["energies"]["lta_output_energy_per_frame"] for k, r in lin.items()}
    assert E["0.5"][1] > 10 * E["1e-3"][1]


def test_time_line_lists_nested_stages_inside_their_stage(ell_dir, tmp_path, capsys):
    """The ``time:`` line listed every stage side by side, the reference geodesic beside the
    describe stage that runs it (its seconds counted twice), and reading and writing after
    the total that leaves them out: the parts added up to more than the total. Now a stage
    timed inside another is in parentheses after it, and the top-level parts (reading and
    writing included) add up to at most the total; report.json keeps its timings keys and
    says which stage holds which (``timings_within``)."""
    import re

    out = tmp_path / "geo"
    assert main(["interpolate", *_poses(ell_dir), "--frames", str(ell_dir / "frames.txt"),
                 "-o", str(out), "--eta", "0.1", "--reference", "geodesic",
                 "--coarse", "80"]) == 0
    (line,) = [ln for ln in capsys.readouterr().err.splitlines() if ln.startswith("time: ")]
    rep = json.loads((out / "report.json").read_text())
    t = rep["timings"]
    assert rep["timings_within"] == {"coarse reference geodesic": "coarse describe"}
    assert t["coarse reference geodesic"] <= t["coarse describe"]  # really inside it
    assert f"coarse describe {t['coarse describe']:.2f}s (reference geodesic " \
           f"{t['coarse reference geodesic']:.2f}s), " in line
    body, total = re.fullmatch(r"time: (.*); total (\d+\.\d\d)s", line).groups()
    top = [m.rsplit(" ", 1) for m in re.sub(r"(\d\ds) \([^()]*\)", r"\1", body).split(", ")]
    names = [name for name, _ in top]
    # every stage once, at the top level unless timed inside another
    assert names[0] == "read" and names[-1] == "write" and "coarse describe" in names
    assert names[1:-1] == [k for k in t if k not in ("read", "write", "total",
                                                     "coarse reference geodesic")]
    assert [float(v.rstrip("s")) for _, v in top] == [round(t[k], 2) for k in names]
    assert float(total) == round(t["total"] + t["read"] + t["write"], 2)
    assert sum(t[k] for k in names) <= t["total"] + t["read"] + t["write"]


def test_fine_summary_lists_the_coarse_seams_its_quality_line_counts(capsys):
    """With --fine the quality line counted defects "at the seams" of the coarse solve
    (report.seam_defects reads multires.coarse_frames) while the seams line only looked at the
    refined frames: the horse pair said "at the seams (steps into frames [1, 2, 3, 4]): 1
    flipped" with no seams line at all. The coarse seams are now listed."""
    from types import SimpleNamespace

    from shellspline.cli.main import _summary

    K = 4
    per = {"flipped": [0, 0, 0, 1, 0], "folded": [0] * 5, "collapsed": [0] * 5}
    rep = {"parameters": {"fine": True},
           "quality": {"keyframes_exact": True, "flipped_faces": 1, "collapsed_faces": 0,
                       "folded_edges": 0, "degenerate_faces": 0, "pop": 1.08,
                       "per_frame": per},
           "gauss_newton": {"frames": 3, "converged": 3, "iterations_total": 46,
                            "iterations_median": 17, "iterations_max": 18,
                            "factorizations_total": 34},
           "frames": [{"frame": k} for k in (1, 2, 3)],
           "multires": {"coarse_vertices": 1000, "coarse_frames": [
               {"frame": 1}, {"frame": 2},
               {"frame": 3, "seam_jump": 1.46,
                "bridge": {"kept": True, "frames": [1, 2, 3], "step_ratio_before": 1.73,
                           "step_ratio_after": 1.12}}]},
           "timings": {"total": 1.0}}
    res = SimpleNamespace(report=rep, K=K, V=np.zeros((K + 1, 8, 3)))
    assert _summary(res, Path("out"), quiet=False) == 1
    err = capsys.readouterr().err
    assert "seams of the coarse solve: 1 (the two runs of a gap meet in different minima: " \
           "frames [3]), 1 bridged (window step ratio 1.73 -> 1.12)" in err
    assert "at the seams (steps into frames [1, 2, 3, 4]): 1 flipped" in err


def test_geodesic_time_limit_is_one_note(ell_dir, tmp_path, capsys):
    """A --method geodesic run stopped by --max-time printed its note twice, once as the
    solver's warning ("geodesic_interpolation: not converged: ...") and once as the
    pipeline's message ("geodesic: not converged: ..."); once now, exit 1, report "limit"."""
    out = tmp_path / "g"
    rc = main(["interpolate", *_poses(ell_dir), "--frames", str(ell_dir / "frames.txt"),
               "--method", "geodesic", "--max-time", "1e-9", "--eta", "0.1", "-o", str(out)])
    err = capsys.readouterr().err
    assert rc == 1, err
    notes = [ln for ln in err.splitlines() if ln.startswith("  note: ") and "time limit" in ln]
    assert len(notes) == 1, notes
    assert "geodesic: NOT converged" in err
    rec = json.loads((out / "report.json").read_text())["geodesic"]
    assert rec["status"] == "limit" and rec["time_limit_reached"]


def test_fps_that_the_output_format_does_not_use_is_a_note(ell_dir, tmp_path, capsys):
    """``--fps 30 --format obj`` (or ply, pc2) ran without a word, and nothing in OUT keeps
    the rate: OBJ/PLY frames carry no time and a PC2 cache counts it in frames. A note says
    so; GLB, MDD and USD use it silently, and no --fps, no note."""
    base = ["interpolate", *_poses(ell_dir), "--method", "linear", "--K", "4"]
    for fmt, said in (("obj", "writes one file per frame, with no time"),
                      ("pc2", "counts time in frames")):
        assert main([*base, "--fps", "30", "--format", fmt, "-o", str(tmp_path / fmt)]) == 0
        notes = [ln for ln in capsys.readouterr().err.splitlines() if "note:" in ln]
        assert notes == [f"  note: --fps 30 is not applied: --format {fmt} {said}"
                         + ("" if fmt == "obj" else " (start frame 0, one sample per frame)")]
    for args in (["--fps", "30", "--format", "mdd"], ["--format", "obj"]):
        out = tmp_path / "_".join(a.strip("-") for a in args)
        assert main([*base, *args, "-o", str(out)]) == 0
        assert "note:" not in capsys.readouterr().err
    times = np.frombuffer((tmp_path / "fps_30_format_mdd" / "animation.mdd").read_bytes(),
                          ">f4", count=5, offset=8)
    np.testing.assert_allclose(times, np.arange(5) / 30, rtol=1e-6)


def test_report_records_the_output_format_and_fps(ell_dir, tmp_path):
    """report.json says what was written: the format, and the fps where the format carries
    time in seconds (null for OBJ/PLY frames and a PC2 cache, which count frames)."""
    base = ["interpolate", *_poses(ell_dir), "--method", "linear", "--K", "4", "-q"]
    for args, want in ((["--fps", "30", "--format", "mdd"], {"format": "mdd", "fps": 30.0}),
                       (["--format", "glb"], {"format": "glb", "fps": 24.0}),
                       (["--fps", "30", "--format", "pc2"], {"format": "pc2", "fps": None}),
                       ([], {"format": "obj", "fps": None})):
        out = tmp_path / ("_".join(a.strip("-") for a in args) or "default")
        assert main([*base, *args, "-o", str(out)]) == 0
        assert json.loads((out / "report.json").read_text())["output"] == want


def test_linear_report_records_unused_parameters_as_null(ell_dir, tmp_path):
    """--method linear blends per vertex: no reference meshes, no LΘA spline, no fade of
    bending weights, no rigid placement, no reconstruction (Gauss–Newton, warm starts,
    workers, fixpoint iterations, the geodesic/nonlinear solver), no multiresolution.
    report.json listed them at their defaults as if applied (coarse "auto", fine false,
    fixpoint 0, solver_options {} ...); they are null (as transfer is where nothing is
    prolonged)."""
    unused = ("reference", "spline", "fade_angle", "rigid_track", "transfer", "coarse",
              "fine", "fixpoint", "solver_options", "gn_options", "warm_start", "workers",
              "rigid_subset_vertices")
    out = tmp_path / "lin"
    assert main(["interpolate", *_poses(ell_dir), "--method", "linear", "--K", "4", "-q",
                 "-o", str(out)]) == 0
    params = json.loads((out / "report.json").read_text())["parameters"]
    assert sorted(k for k, v in params.items() if v is None) == sorted(unused)
    assert params["method"] == "linear" and params["eta"] == 1e-3  # still applied
    assert (params["bc"], params["K"], params["frames"]) == ("natural", 4, [0, 2, 4])
    out = tmp_path / "lta"
    assert main(["interpolate", *_poses(ell_dir), "--K", "4", "-q", "-o", str(out)]) == 0
    params = json.loads((out / "report.json").read_text())["parameters"]
    assert (params["reference"], params["rigid_track"]) == ("constant", "fit")
    assert params["spline"] == "continuous" and params["fade_angle"] == 0.5
    assert (params["coarse"], params["fine"], params["fixpoint"]) == ("auto", False, 0)
    assert (params["gn_options"], params["solver_options"]) == ({}, {})
    assert (params["warm_start"], params["workers"], params["rigid_subset_vertices"]) == \
        (True, 1, 0)
    assert [k for k, v in params.items() if v is None] == ["transfer"]  # nothing prolonged


@pytest.mark.parametrize("extra, message", [
    (["--coarse", "2"], "--coarse must be 'auto', 'none', a vertex count >= 4 or a fraction "
                        "in (0, 1), got '2'"),
    (["--coarse", "bogus"], "--coarse must be 'auto', 'none', a vertex count >= 4 or a "
                            "fraction in (0, 1), got 'bogus'"),
    (["--bc", "hermite"], "--bc hermite needs explicit --frames: "),
    (["--K", "1"], "--K 1 is too small for 3 keyframes"),
    (["--frames", "0,5,10", "--K", "8"], "--K 8 is smaller than the last keyframe frame 10"),
    (["--bc", "periodic", "--frames", "0,5,10", "--K", "10"],
     "with --bc periodic the keyframes must lie before --K 10 "),
], ids=lambda v: " ".join(v) if isinstance(v, list) else None)
def test_errors_name_the_flags(ell_dir, tmp_path, capsys, extra, message):
    """The command line's errors name its flags (--coarse, --bc hermite, --K 1), not the
    Python keywords (`coarse`, bc='hermite', `K`=1); the API keeps its own spelling."""
    rc = main(["interpolate", *_poses(ell_dir), "-o", str(tmp_path / "o"), "-q", *extra])
    err = capsys.readouterr().err
    assert rc == 2 and err.startswith(f"shellspline: error: {message}"), err
    assert "`" not in err and not (tmp_path / "o").exists()
    assert not any(f"{k}=" in err.split("got")[0] for k in ("coarse", "bc", "K", "frames"))

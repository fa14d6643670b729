"""Hostile input and faults through the command line (issue 14): the output location, a full
disk, the exception family, internal errors, warnings, negative-looking option values,
identical keyframes, time limits, and the inputs that already behave.

Every error case asserts the exit code and a one-line message that names the file or option.
The read-side cases of a byte-order mark, lying PLY headers, huge coordinates, quads and
seams are in ``test_io.py``; signals and worker processes in the process tests.
"""
from __future__ import annotations

import errno
import hashlib
import json
import os
import shutil
import subprocess
import sys
import warnings
from collections import namedtuple
from pathlib import Path

import numpy as np
import pytest

import data_synth
import shellspline as ss
import shellspline.io as ssio
import shellspline.pipeline.describe as sspipeline
from shellspline.cli.main import main

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def ell(tmp_path_factory):
    d = tmp_path_factory.mktemp("hostile_ell")
    data_synth.write("ellipsoids", d, n_vertices=200)
    return d


def _poses(d) -> list[str]:
    return sorted(str(p) for p in Path(d).glob("pose_*.obj"))


def _run(capsys, *args):
    rc = main([str(a) for a in args])
    return rc, capsys.readouterr().err


def _assert_one_line_error(err: str, *names) -> str:
    """One line ``shellspline: error: ...`` naming every one of ``names``; no traceback."""
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    line = lines[0]
    assert line.startswith("shellspline: error: "), line
    assert "Traceback" not in err and "[Errno" not in err, err
    for name in names:
        assert str(name) in line, f"{name!r} not in {line!r}"
    return line


def _digest(paths) -> dict:
    return {str(p): hashlib.sha256(Path(p).read_bytes()).hexdigest() for p in paths}


def _no_leftovers(parent: Path, name: str) -> None:
    left = [p.name for p in parent.iterdir() if p.name.startswith(f".{name}.")]
    assert not left, f"temporary files left behind: {left}"


# ------------------------------------------------------------------------------------------
# The output location: checked before any computing, errors name the user's path
# ------------------------------------------------------------------------------------------
def test_output_under_an_existing_file_is_refused_before_computing(ell, tmp_path, capsys):
    blocker = tmp_path / "notes.txt"
    blocker.write_text("not a directory")
    out = blocker / "out"
    # not quiet: a refusal after computing would print the stage lines first
    rc, err = _run(capsys, "interpolate", *_poses(ell), "-o", out)
    line = _assert_one_line_error(err, out, "notes.txt")
    assert rc == 2 and "is a file" in line and "File exists" not in line
    assert blocker.read_text() == "not a directory"


def test_output_that_is_an_existing_file_is_refused(ell, tmp_path, capsys):
    f = tmp_path / "out.obj"
    f.write_text("x")
    rc, err = _run(capsys, "interpolate", *_poses(ell), "-o", f, "-q")
    assert rc == 2 and "not a directory" in _assert_one_line_error(err, f)


def _unwritable_dir(tmp_path: Path) -> Path:
    """A directory in which nothing can be created, also for root (which ignores the
    permission bits): a read-only directory for a normal user, sysfs for root."""
    if os.name == "posix" and os.geteuid() != 0:
        d = tmp_path / "readonly"
        d.mkdir()
        d.chmod(0o555)
        return d
    d = Path("/sys/kernel")
    if not d.is_dir():
        pytest.skip("running as root without /sys: no directory that root cannot write")
    try:
        (d / "shellspline-probe").mkdir()
    except OSError:
        return d
    (d / "shellspline-probe").rmdir()
    pytest.skip("/sys/kernel is writable here")


def test_unwritable_output_directory_is_refused_before_computing(ell, tmp_path, capsys):
    parent = _unwritable_dir(tmp_path)
    out = parent / "new" / "out"
    try:
        rc, err = _run(capsys, "interpolate", *_poses(ell), "-o", out)
    finally:
        if parent.is_relative_to(tmp_path):
            parent.chmod(0o755)
    line = _assert_one_line_error(err, out, parent)
    assert rc == 2 and "cannot write" in line
    assert not (parent / "new").exists()


def test_too_little_free_space_is_refused_before_computing(ell, tmp_path, capsys, monkeypatch):
    usage = namedtuple("usage", "total used free")
    monkeypatch.setattr(ssio.sequences.shutil, "disk_usage", lambda p: usage(10**6, 10**6 - 1000, 1000))
    out = tmp_path / "new" / "out"
    rc, err = _run(capsys, "interpolate", *_poses(ell), "-o", out)
    line = _assert_one_line_error(err, out)
    assert rc == 2 and "not enough space" in line and "MB" in line
    assert not (tmp_path / "new").exists()


@pytest.mark.parametrize("fmt", ["obj", "ply", "glb"])
def test_space_estimate_never_exceeds_the_real_output(tmp_path, monkeypatch, fmt):
    # the check must never refuse an output that fits: with exactly the bytes that the
    # output really takes free, it passes
    rng = np.random.default_rng(1)
    V = rng.normal(size=(7, 300, 3)) * 123.456
    F = np.array([[i % 300, (i + 1) % 300, (i + 7) % 300] for i in range(596)])
    out = ss.write_sequence(tmp_path / "real", V, F, fmt=fmt)
    real = sum(p.stat().st_size for p in out.iterdir() if p.name != "report.json")
    usage = namedtuple("usage", "total used free")
    monkeypatch.setattr(ssio.sequences.shutil, "disk_usage", lambda p: usage(real, 0, real))
    ss.check_output_dir(tmp_path / "other", n_frames=7, n_vertices=300, n_faces=596, fmt=fmt)
    monkeypatch.setattr(ssio.sequences.shutil, "disk_usage", lambda p: usage(real, 0, real // 100))
    with pytest.raises(ss.ShellsplineError, match="not enough space"):
        ss.check_output_dir(tmp_path / "other", n_frames=7, n_vertices=300, n_faces=596,
                            fmt=fmt)


def test_check_output_dir_creates_nothing(tmp_path):
    target = tmp_path / "a" / "b" / "out"
    assert ss.check_output_dir(target, n_frames=3, n_vertices=10, n_faces=16) == target
    assert list(tmp_path.iterdir()) == []


def test_full_disk_while_writing_names_the_file_in_out(ell, tmp_path, capsys, monkeypatch):
    real = ssio.sequences.write_obj_frame

    def full_disk(path, V, faces_block):
        if Path(path).name == "frame_0003.obj":
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))
        return real(path, V, faces_block)

    monkeypatch.setattr(ssio.sequences, "write_obj_frame", full_disk)
    out = tmp_path / "out"
    rc, err = _run(capsys, "interpolate", *_poses(ell), "-o", out, "-q", "--method", "linear")
    line = _assert_one_line_error(err, out / "frame_0003.obj")
    assert rc == 2 and "no space left on device writing" in line
    assert ".tmp-" not in line  # never the hidden temporary directory
    assert not out.exists()
    _no_leftovers(tmp_path, "out")
    # the Python API keeps the errno for callers that test it
    with pytest.raises(OSError) as info:
        ss.write_sequence(tmp_path / "api", np.zeros((5, 4, 3)) + np.arange(4)[:, None],
                          np.array([[0, 1, 2], [0, 2, 3]]))
    assert info.value.errno == errno.ENOSPC and str(tmp_path / "api") in str(info.value)


def test_full_disk_while_updating_the_report_names_report_json(ell, tmp_path, capsys,
                                                             monkeypatch):
    import shellspline.cli.main as sscli

    def full_disk(*args, **kwargs):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(sscli.json, "dump", full_disk)
    out = tmp_path / "out"
    rc, err = _run(capsys, "interpolate", *_poses(ell), "-o", out, "-q", "--method", "linear")
    line = _assert_one_line_error(err, out / "report.json")
    assert rc == 2 and "no space left on device writing" in line
    assert not [p.name for p in out.iterdir() if p.name.startswith(".report.")]


def test_full_disk_while_rendering_names_the_output_file(ell, tmp_path, capsys, monkeypatch):
    seq = tmp_path / "seq"
    assert main(["interpolate", *_poses(ell), "-o", str(seq), "-q", "--method", "linear"]) == 0
    real = Path.write_bytes

    def full_disk(self, data):
        if ".tmp-" in self.name:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(self))
        return real(self, data)

    monkeypatch.setattr(Path, "write_bytes", full_disk)
    glb = tmp_path / "anim.glb"
    rc, err = _run(capsys, "render", seq, "--glb", glb, "-q")
    line = _assert_one_line_error(err, glb)
    assert rc == 2 and "no space left on device writing" in line and ".tmp-" not in line
    assert not glb.exists() and not [p for p in tmp_path.iterdir() if ".tmp-" in p.name]


def test_output_over_an_input_is_refused_and_the_input_kept(ell, capsys):
    before = _digest(_poses(ell))
    rc, err = _run(capsys, "interpolate", *_poses(ell), "-o", _poses(ell)[0], "--overwrite",
                   "-q")
    assert rc == 2 and "refusing" in _assert_one_line_error(err, _poses(ell)[0])
    assert _digest(_poses(ell)) == before


# ------------------------------------------------------------------------------------------
# Exit codes: bad input (2) is told apart from a bug (3); warnings are one-line notes
# ------------------------------------------------------------------------------------------
def _cannot_reshape(*args, **kwargs):
    return np.arange(12).reshape(5, 3)  # numpy's own ValueError, raised deep inside


def test_internal_error_is_exit_3_and_says_it_is_a_bug(ell, tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(sspipeline, "lta_descriptors", _cannot_reshape)
    monkeypatch.delenv("SHELLSPLINE_DEBUG", raising=False)
    rc, err = _run(capsys, "interpolate", *_poses(ell), "-o", tmp_path / "out", "-q")
    assert rc == 3, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err
    assert lines[0].startswith("shellspline: internal error")
    for part in ("a bug", "ValueError", "cannot reshape", "SHELLSPLINE_DEBUG=1"):
        assert part in lines[0]
    assert not (tmp_path / "out").exists()


def test_internal_error_traceback_on_request(ell, tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(sspipeline, "lta_descriptors", _cannot_reshape)
    monkeypatch.setenv("SHELLSPLINE_DEBUG", "1")
    rc, err = _run(capsys, "interpolate", *_poses(ell), "-o", tmp_path / "out", "-q")
    assert rc == 3 and "Traceback" in err and "_cannot_reshape" in err
    assert err.strip().splitlines()[-1].startswith("shellspline: internal error")


def test_warnings_reach_the_user_as_one_line_notes(ell, tmp_path, capsys, monkeypatch):
    real = sspipeline.lta_descriptors

    def noisy(*args, **kwargs):
        np.float64(1.0) / np.float64(0.0)  # numpy: "divide by zero encountered ..."
        warnings.warn("first line\n  second line", RuntimeWarning)
        return real(*args, **kwargs)

    monkeypatch.setattr(sspipeline, "lta_descriptors", noisy)
    rc, err = _run(capsys, "interpolate", *_poses(ell), "-o", tmp_path / "out", "-q")
    assert rc in (0, 1), err
    notes = [line for line in err.splitlines() if "note:" in line]
    assert any("divide by zero encountered" in n and "test_hostile.py" in n for n in notes), err
    assert any("first line second line" in n for n in notes), err
    # Python's own format: "file:line: RuntimeWarning: message" and then the source line
    assert "RuntimeWarning:" not in err and "warnings.warn(" not in err
    assert "np.float64(1.0) / np.float64(0.0)" not in err
    # once per run, not once per process
    rc, err = _run(capsys, "interpolate", *_poses(ell), "-o", tmp_path / "again", "-q")
    assert sum("first line second line" in line for line in err.splitlines()) == 1, err


@pytest.mark.parametrize("option,value,says", [
    ("--frames", "-3,5,10", "frames"),
    ("--eta", "-1e-3", "eta"),
    ("--K", "-3", "K"),
    ("--coarse", "-5", "coarse"),
    ("--max-time", "-5", "--max-time"),
])
def test_negative_looking_option_values_reach_their_check(ell, tmp_path, capsys, option, value,
                                                          says):
    # argparse alone takes "-3,5,10" and "-1e-3" for options: "expected one argument"
    rc, err = _run(capsys, "interpolate", *_poses(ell), option, value, "-o", tmp_path / "o",
                   "-q")
    line = _assert_one_line_error(err, says)
    assert rc == 2 and "expected one argument" not in line
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("call", [
    lambda V, F: ss.interpolate((V, F), K=1),  # K too small for three keyframes
    lambda V, F: ss.interpolate((V, F), method="cubic"),
    lambda V, F: ss.interpolate((V, F), coarse="some"),
    lambda V, F: ss.interpolate((V, F), eta=-1.0),
    lambda V, F: ss.interpolate((V, F), frames=[0, 4, 2]),
    lambda V, F: ss.interpolate((V, F), workers=0),
    lambda V, F: ss.decimate(V, F, target=2),
    lambda V, F: ss.decimate(V, F, target=1.5),
    lambda V, F: ss.read_frames("0,x"),
    lambda V, F: ss.write_sequence("unused", V[:, :, :2], F),
    lambda V, F: ss.check_output_dir("unused", fmt="stl"),
    lambda V, F: ss.LTASpline([0, 3, 2], 6),
    lambda V, F: ss.nonlinear_spline(V, [0, 6, 12], 12, ss.topology(F), max_time_s=-1.0),
], ids=["K-too-small", "method", "coarse", "eta", "frames-order", "workers", "decimate-count",
        "decimate-fraction", "read_frames", "write-shape", "check-fmt", "LTASpline-frames",
        "max_time_s"])
def test_api_input_errors_are_shellspline_errors(ell, call):
    kf = ss.read_keyframes(_poses(ell))
    with pytest.raises(ss.ShellsplineError) as info:
        call(kf.V, kf.F)
    assert "\n" not in str(info.value) and isinstance(info.value, ValueError)


# ------------------------------------------------------------------------------------------
# Identical keyframes, time limits
# ------------------------------------------------------------------------------------------
@pytest.mark.parametrize("copies", [2, 3])
def test_identical_keyframes_succeed(ell, tmp_path, capsys, copies):
    first = _poses(ell)[0]
    out = tmp_path / "same"
    rc, err = _run(capsys, "interpolate", *[first] * copies, "-o", out, "-q")
    assert rc == 0, err
    V, F, rep = ss.read_sequence(out)
    V0, _ = ss.read_mesh(first)
    assert np.abs(V - V0).max() <= 1e-9 * np.abs(V0).max()  # every frame is the keyframe


def test_max_time_bounds_the_nonlinear_stage_from_its_start(tmp_path, capsys):
    # unbounded, this problem's stage takes ~10 s (its first evaluation alone ~1 s)
    d = tmp_path / "ell"
    data_synth.write("ellipsoids", d, n_vertices=500)
    out = tmp_path / "out"
    rc, err = _run(capsys, "interpolate", *_poses(d), "--frames", d / "frames.txt",
                   "--method", "nonlinear", "--eta", "0.1", "--max-time", "0.5", "-o", out)
    assert rc == 1, err
    rep = json.loads((out / "report.json").read_text())
    nl = rep["nonlinear"]
    assert not nl["success"] and "time limit" in nl["message"]
    assert rep["timings"]["nonlinear"] < 0.5 + 2.0, rep["timings"]
    assert "RuntimeWarning" not in err
    # the solver's warning and the pipeline's message about it: one note
    assert len([line for line in err.splitlines() if "note:" in line and "time limit" in line]) == 1
    V, _, _ = ss.read_sequence(out)
    assert np.isfinite(V).all()


def test_nonlinear_time_limit_before_the_first_evaluation_returns_the_start(ell):
    kf = ss.read_keyframes(_poses(ell))
    init = ss.linear_blend(kf.V, [0, 6, 12], 12)
    with pytest.warns(RuntimeWarning, match="time limit"):
        res = ss.nonlinear_spline(kf.V, [0, 6, 12], 12, ss.topology(kf.F), eta=0.1, init=init,
                                  max_time_s=1e-9)
    assert not res.success and "before the first evaluation" in res.message
    assert res.energies.size == 0 and np.isnan(res.energy) and res.nit == 0
    assert np.allclose(res.V, init, rtol=0, atol=1e-12)


# ------------------------------------------------------------------------------------------
# Inputs that already behave
# ------------------------------------------------------------------------------------------
def _write_obj(path, V, F, *, vt=False, vn=False, negative=False, crlf=False,
               extra_vertices=()):
    nl = "\r\n" if crlf else "\n"
    rows = [f"v {x:.17g} {y:.17g} {z:.17g}" for x, y, z in V]
    rows += [f"v {x:.17g} {y:.17g} {z:.17g}" for x, y, z in extra_vertices]
    if vt:
        rows += [f"vt {i / len(V):.6f} 0.5" for i in range(len(V))]
    if vn:
        rows += ["vn 0 0 1"]
    for f in F:
        idx = [(i - len(V) - len(extra_vertices)) if negative else i + 1 for i in f]
        if vt and vn:
            toks = [f"{i}/{i}/1" if not negative else f"{i}/{i}/-1" for i in idx]
        elif vn:
            toks = [f"{i}//1" if not negative else f"{i}//-1" for i in idx]
        else:
            toks = [str(i) for i in idx]
        rows.append("f " + " ".join(toks))
    Path(path).write_bytes((nl.join(rows) + nl).encode("ascii"))


def _write_binary_ply_with_extras(path, V, F):
    head = ("ply\nformat binary_little_endian 1.0\ncomment extra properties\n"
            f"element vertex {len(V)}\nproperty double x\nproperty double y\nproperty double z\n"
            "property float nx\nproperty float ny\nproperty float nz\n"
            "property uchar red\nproperty uchar green\nproperty uchar blue\n"
            f"element face {len(F)}\nproperty list uchar int vertex_indices\n"
            "property int material\nend_header\n")
    vert = np.zeros(len(V), dtype=[("p", "<f8", 3), ("n", "<f4", 3), ("c", "u1", 3)])
    vert["p"], vert["n"], vert["c"] = V, (0, 0, 1), (200, 10, 10)
    face = np.zeros(len(F), dtype=[("k", "u1"), ("i", "<i4", 3), ("mat", "<i4")])
    face["k"], face["i"], face["mat"] = 3, F, 7
    Path(path).write_bytes(head.encode("ascii") + vert.tobytes() + face.tobytes())


@pytest.fixture(scope="module")
def reference(ell, tmp_path_factory):
    """The linear-method output of the clean keyframes: what every harmless variant of the
    same meshes must reproduce bit for bit."""
    out = tmp_path_factory.mktemp("hostile_ref") / "out"
    assert main(["interpolate", *_poses(ell), "-o", str(out), "-q", "--method", "linear"]) == 0
    return ss.read_sequence(out)


@pytest.mark.parametrize("variant", ["vt-vn", "vn", "negative", "crlf", "negative-vt-vn-crlf",
                                     "binary-ply-extras"])
def test_harmless_file_variants_give_the_same_result(ell, reference, tmp_path, capsys,
                                                     variant):
    files = []
    for j, p in enumerate(_poses(ell)):
        V, F = ss.read_mesh(p)
        if variant == "binary-ply-extras":
            f = tmp_path / f"k{j}.ply"
            _write_binary_ply_with_extras(f, V, F)
        else:
            f = tmp_path / f"k{j}.obj"
            _write_obj(f, V, F, vt="vt" in variant, vn="vn" in variant,
                       negative="negative" in variant, crlf="crlf" in variant)
        files.append(f)
    out = tmp_path / "out"
    rc, err = _run(capsys, "interpolate", *files, "-o", out, "-q", "--method", "linear")
    assert rc == 0, err
    V, F, _ = ss.read_sequence(out)
    assert np.array_equal(V, reference[0]) and np.array_equal(F, reference[1])


def test_isolated_vertices_are_carried_along(ell, reference, tmp_path, capsys):
    files = []
    for j, p in enumerate(_poses(ell)):
        V, F = ss.read_mesh(p)
        f = tmp_path / f"k{j}.obj"
        _write_obj(f, V, F, extra_vertices=[(5.0, 5.0, 5.0 + j)])
        files.append(f)
    out = tmp_path / "out"
    rc, err = _run(capsys, "interpolate", *files, "-o", out, "-q", "--method", "linear")
    assert rc == 0, err
    V, F, _ = ss.read_sequence(out)
    n = reference[0].shape[1]
    assert np.array_equal(V[:, :n], reference[0]) and np.array_equal(F, reference[1])
    assert np.array_equal(V[[0, 10, 20], n], [[5, 5, 5], [5, 5, 6], [5, 5, 7]])  # keyframes
    assert np.all(np.diff(V[:, n, 2]) > 0)  # and moves between them


def _hostile_inputs(d: Path, ell: Path) -> list:
    """``(id, argv after 'interpolate', names the message must contain)``."""
    poses = _poses(ell)
    (d / "empty.obj").write_bytes(b"")
    (d / "truncated.ply").write_bytes(b"ply\nformat binary_little_endian 1.0\n"
                                      b"element vertex 162\nproperty double x\n")
    (d / "truncated-body.ply").write_bytes(b"ply\nformat ascii 1.0\nelement vertex 3\n"
                                           b"property float x\nproperty float y\n"
                                           b"property float z\nelement face 1\n"
                                           b"property list uchar int vertex_indices\n"
                                           b"end_header\n0 0 0\n1 0 0\n")
    (d / "a_directory.obj").mkdir()
    other = d / "other"
    data_synth.write("ellipsoids", other, n_vertices=500)
    (d / "frames_short.txt").write_text("0 6\n")
    (d / "frames_text.txt").write_text("0 six 12\n")
    (d / "pinned_range.txt").write_text("0 1 99999\n")
    (d / "pinned_text.txt").write_text("0, x\n")
    return [
        ("empty-file", [d / "empty.obj", *poses[1:]], ["empty.obj"]),
        ("truncated-header", [d / "truncated.ply", *poses[1:]], ["truncated.ply"]),
        ("truncated-body", [d / "truncated-body.ply", *poses[1:]], ["truncated-body.ply"]),
        ("directory", [d / "a_directory.obj", *poses[1:]], ["a_directory.obj"]),
        ("missing-file", [d / "missing.obj", *poses[1:]], ["missing.obj"]),
        ("vertex-counts", [poses[0], _poses(other)[1]], [Path(_poses(other)[1]).name]),
        ("one-keyframe", [poses[0]], ["keyframe"]),
        ("frames-order", [*poses, "--frames", "0,6,6"], ["frames"]),
        ("frames-count", [*poses, "--frames", d / "frames_short.txt"], ["frames"]),
        ("frames-text", [*poses, "--frames", d / "frames_text.txt"], ["frames_text.txt"]),
        ("frames-missing", [*poses, "--frames", d / "nope.txt"], ["nope.txt"]),
        ("pinned-range", [*poses, "--pinned", d / "pinned_range.txt"], ["pinned_range.txt"]),
        ("pinned-text", [*poses, "--pinned", d / "pinned_text.txt"], ["pinned_text.txt"]),
        ("pinned-missing", [*poses, "--pinned", d / "nope_pinned.txt"], ["nope_pinned.txt"]),
    ]


_HOSTILE_IDS = ["empty-file", "truncated-header", "truncated-body", "directory",
                "missing-file", "vertex-counts", "one-keyframe", "frames-order", "frames-count",
                "frames-text", "frames-missing", "pinned-range", "pinned-text",
                "pinned-missing"]


@pytest.fixture(scope="module")
def hostile(ell, tmp_path_factory):
    d = tmp_path_factory.mktemp("hostile_inputs")
    return {case[0]: case for case in _hostile_inputs(d, ell)}


@pytest.mark.parametrize("case", _HOSTILE_IDS)
def test_bad_inputs_are_one_line_errors_naming_the_file(hostile, tmp_path, capsys, case):
    _, argv, names = hostile[case]
    out = tmp_path / "out"
    rc, err = _run(capsys, "interpolate", *argv, "-o", out)
    _assert_one_line_error(err, *names)
    assert rc == 2 and not out.exists()
    _no_leftovers(tmp_path, "out")


def test_hostile_cases_through_the_console_script(ell, hostile, tmp_path):
    """The installed entry point (a real process): exit 2 and one line, no traceback."""
    blocker = tmp_path / "file"
    blocker.write_text("x")
    cases = [
        (["interpolate", *_poses(ell), "-o", blocker / "out"], "is a file"),
        (["interpolate", *_poses(ell), "--frames", "-3,5,10", "-o", tmp_path / "o"], "frames"),
        (["interpolate", *hostile["empty-file"][1], "-o", tmp_path / "o"], "empty.obj"),
    ]
    env = dict(os.environ, PYTHONWARNINGS="default")
    env.pop("SHELLSPLINE_DEBUG", None)
    for argv, says in cases:
        proc = subprocess.run([sys.executable, "-m", "shellspline", *map(str, argv)],
                              capture_output=True, text=True, timeout=120, env=env)
        assert proc.returncode == 2, proc.stderr
        _assert_one_line_error(proc.stderr, says)
        assert proc.stdout == ""


# ------------------------------------------------------------------------------------------
# Motion, camera and mesh files as real tools get them wrong: one line naming the file and
# the problem, exit 2, never a traceback (and never an internal error passed off as input)
# ------------------------------------------------------------------------------------------
_BVH = ("HIERARCHY\nROOT Hips\n{\n OFFSET 0 0 0\n CHANNELS 6 Xposition Yposition Zposition "
        "Zrotation Xrotation Yrotation\n JOINT Left Leg\n {\n  OFFSET 0 -1 0\n  CHANNELS 3 "
        "Zrotation Xrotation Yrotation\n  End Site\n  {\n   OFFSET 0 -1 0\n  }\n }\n}\nMOTION\n"
        "Frames: 3\nFrame Time: 0.0333333\n" + "0 1 0 0 0 0 10 0 0\n" * 3)
_TUM = "".join(f"{t} {t} 0 0 0 0 0 1\n" for t in range(5))
_PLY_HEAD = ("ply\nformat ascii 1.0\nelement vertex 3\nproperty {} x\nproperty float y\n"
             "property float z\nelement face 1\nproperty list uchar int vertex_indices\n"
             "end_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n")
_READER_CASES = {
    # name: (file name, content, command before/after the file, words the message must hold)
    "bvh-no-motion": ("a.bvh", _BVH.split("MOTION")[0], ["motion", "close", "{f}", "-o",
                                                           "{o}.bvh"], ["no MOTION section"]),
    "bvh-1.#QNAN": ("b.bvh", _BVH.replace("10 0 0\n", "1.#QNAN 0 0\n", 1),
                    ["motion", "close", "{f}", "-o", "{o}.bvh"], [":19: frame 0", "'1.#QNAN'"]),
    "bvh-short-line": ("c.bvh", _BVH[:-3] + "\n", ["motion", "close", "{f}", "-o", "{o}.bvh"],
                       ["frame 2 has 8 values"]),
    "poses-empty": ("e.txt", "", ["path", "{f}", "-o", "{o}.txt"], ["no poses"]),
    "poses-nan": ("n.txt", _TUM.replace("2 2 0", "2 nan 0"), ["path", "{f}", "-o", "{o}.txt"],
                  [":3:", "non-finite"]),
    "poses-colmap": ("images.txt", "# Image list with two lines of data per image:\n"
                     "1 1 0 0 0 0 0 0 1 a.png\n\n", ["path", "{f}", "-o", "{o}.txt"],
                     ["COLMAP images.txt is not supported"]),
    "poses-nerf-json": ("transforms.json", '{"camera_angle_x": 0.7, "frames": [{"file_path": '
                        '"a.png", "transform_matrix": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, '
                        '0], [0, 0, 0, 1]]}]}', ["path", "{f}", "-o", "{o}.json"],
                        ["NeRF/instant-ngp transforms.json is not supported"]),
    "poses-quaternion-columns": ("q.txt", _TUM.replace("0 0 0 1", "0 0 5 1"),
                                 ["motion", "close", "{f}", "-o", "{o}.txt"],
                                 [":1:", "quaternion norm"]),
    "ply-unknown-type": ("p.ply", _PLY_HEAD.format("float128"),
                         ["interpolate", "{f}", "{f}", "-o", "{o}"], ["unknown type"]),
}


@pytest.mark.parametrize("case", sorted(_READER_CASES))
def test_reader_refusals_are_one_line_naming_the_file(tmp_path, capsys, case):
    name, content, argv, says = _READER_CASES[case]
    f = tmp_path / name
    f.write_text(content)
    out = tmp_path / "out"
    argv = [a.format(f=f, o=out) for a in argv]
    rc, err = _run(capsys, *argv)
    _assert_one_line_error(err, name, *says)
    assert rc == 2

"""Batch jobs: TOML validation, local and Dask executors, manifests and resume, failures,
interruption, a killed Dask worker, the shipped pipelines."""
from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

import data_synth
import shellspline as ss
from shellspline import batch
from shellspline.batch.executors import inner_workers
from shellspline.batch.manifest import input_digest, manifest_matches, sequence_key
from shellspline.batch.sequence import publish, run_sequence
from shellspline.cli.main import main

REPO = Path(__file__).resolve().parents[2]
PIPELINES = REPO / "pipelines"


def _job(tmp: Path, body: str, name: str = "job.toml") -> Path:
    p = tmp / name
    p.write_text(body)
    return p


def _synth_job(tmp: Path, names, *, workers=2, defaults="", extra="", vertices=150,
               output="out") -> Path:
    seqs = "".join(f'\n[[sequences]]\nname = "{n}"\nsynth = "ellipsoids"\n{extra}'
                   for n in names)
    return _job(tmp, f'[job]\nname = "t"\noutput = "{output}"\nworkers = {workers}\n\n'
                     f'[defaults]\nvertices = {vertices}\n{defaults}\n{seqs}')


def _cli(capsys, *args):
    rc = main(["batch", *map(str, args)])
    return rc, capsys.readouterr().err


def _summary(root: Path) -> dict:
    return json.loads((root / "summary.json").read_text())


def _status(root: Path) -> dict:
    return {o["name"]: o["status"] for o in _summary(root)["sequences"]}


def _leftovers(root: Path) -> list:
    return [p.name for p in root.iterdir() if p.name.startswith(".")
            and p.name != batch.LOCK_NAME]


def _reference(vertices=150, **kw):
    """The same sequence computed directly through the public API (the oracle)."""
    d = data_synth.generate("ellipsoids", vertices)
    return ss.interpolate((d["V"], d["F"]), frames=d["frames"], **kw)


def _env():
    env = dict(os.environ)
    env["PYTHONPATH"] = str(REPO) + os.pathsep + env.get("PYTHONPATH", "")
    return env


# ------------------------------------------------------------------------------------------
# Job files
# ------------------------------------------------------------------------------------------
BAD_JOBS = [
    ('[job]\noutput = "o"\n[[sequences]]\nname = "a"\nsynth = "ellipsoids"\netaa = 1\n',
     "unknown key 'etaa'"),
    ('[job]\noutput = "o"\n[defaults]\nbc = "clamped"\n[[sequences]]\nname = "a"\n'
     'synth = "ellipsoids"\n', "key 'bc'"),
    ('[job]\noutput = "o"\nworkers = 0\n[[sequences]]\nname = "a"\nsynth = "ellipsoids"\n',
     "key 'workers'"),
    ('[job]\noutput = "o"\n[[sequences]]\nname = "a"\nsynth = "ellipsoids"\neta = -1\n',
     "key 'eta'"),
    ('[job]\noutput = "o"\n[[sequences]]\nname = "a"\nsynth = "ellipsoids"\n'
     'formats = ["stl"]\n', "key 'formats'"),
    ('[job]\noutput = "o"\n[[sequences]]\nname = "a"\nsynth = "ellipsoids"\n'
     'fade_angle = -0.5\n', "key 'fade_angle'"),
    ('[job]\noutput = "o"\n[[sequences]]\nglob = "nothing/*"\n', "key 'glob'"),
    ('[job]\noutput = "o"\n[[sequences]]\nname = "a"\nsynth = "ellipsoids"\n'
     '[[sequences]]\nname = "a"\nsynth = "cactus"\n', "two sequences are named 'a'"),
    ('[job]\noutput = "o"\n[[sequences]]\nname = "a"\nsynth = "torus"\n', "key 'synth'"),
    ('[job]\noutput = "o"\n[[sequences]]\nname = "a"\nsynth = "ellipsoids"\n'
     'synth_params = {axes = [[1, 1]]}\n', "key 'synth_params'"),
    ('[job]\noutput = "o"\nexecutor = "ray"\n[[sequences]]\nname = "a"\nsynth = "ellipsoids"\n',
     "key 'executor'"),
    ('[job]\noutput = "o"\nscheduler = "http://x"\n[[sequences]]\nname = "a"\n'
     'synth = "ellipsoids"\n', "key 'scheduler'"),
    ('[job]\noutput = "o"\n', "[[sequences]]"),
    ('[job\noutput = "o"\n', "invalid TOML"),
    ('[job]\noutput = "o"\n[[sequences]]\nname = "a"\nkeyframes = ["a.obj", "typo.obj"]\n',
     "key 'keyframes': file"),
    ('[job]\noutput = "o"\n[[sequences]]\nname = "a"\nsynth = "ellipsoids"\n[regression]\n'
     'expected = {a = {half_axis = 1}}\n', "unknown metric 'half_axis'"),
    ('[job]\noutput = "o"\n[[sequences]]\nname = "a"\nsynth = "ellipsoids"\n'
     'frames = [2, 6, 12]\n', "key 'frames': must start at 0"),
    ('[job]\noutput = "o"\n[[sequences]]\nname = "a"\nsynth = "ellipsoids"\n'
     'frames = "2 6 12"\n', "#1 key 'frames': must start at 0"),
    ('[job]\noutput = "o"\n[defaults]\nframes = [1, 2]\n[[sequences]]\nname = "a"\n'
     'synth = "ellipsoids"\n', "[defaults] key 'frames': must start at 0"),
    ('[job]\noutput = "o"\n[[sequences]]\nname = "a"\nsynth = "ellipsoids"\n'
     'frames = [0, 10]\n', "key 'frames': sequence 'a': 2 frames [0, 10] for 3 keyframes"),
    ('[job]\noutput = "o"\n[[sequences]]\nname = "a"\nsynth = "ellipsoids"\n'
     'method = "linear"\nmax_time = 30\n', "key 'max_time'"),
]


@pytest.mark.parametrize("body, needle", BAD_JOBS)
def test_bad_job_file_is_one_line_exit_2(tmp_path, capsys, body, needle):
    p = _job(tmp_path, body)
    rc, err = _cli(capsys, p)
    assert rc == 2
    assert err.count("\n") == 1 and err.startswith("shellspline: error: ")
    assert str(p) in err and needle in err
    assert not (tmp_path / "o").exists()  # nothing ran


def test_overrides_and_precedence(tmp_path):
    d = data_synth.write_batch("ellipsoids", tmp_path / "seqs", 2, 100)
    (d[1] / "frames.txt").write_text("0 5 10\n")
    p = _job(tmp_path, '[job]\noutput = "out"\n[defaults]\neta = 0.5\nframes = [0, 4, 8]\n'
                       'bc = "natural"\n'
                       '[[sequences]]\nglob = "seqs/*"\nname = "d_{dir}"\nmethod = "linear"\n'
                       '[[sequences]]\nname = "x"\nkeyframes = ["seqs/ellipsoids_00/pose_00.obj",'
                       ' "seqs/ellipsoids_00/pose_01.obj", "seqs/ellipsoids_00/pose_02.obj"]\n'
                       'bc = "periodic"\nK = 9\n')
    job = ss.load_job(p)
    s = {q.name: q for q in job.sequences}
    assert sorted(s) == ["d_ellipsoids_00", "d_ellipsoids_01", "x"]
    assert job.output == (tmp_path / "out").resolve()
    # a directory's frames.txt beats [defaults].frames; the entry's own values beat defaults
    assert s["d_ellipsoids_01"].frames_path == str((d[1] / "frames.txt").resolve())
    assert s["d_ellipsoids_01"].frames is None
    assert s["d_ellipsoids_01"].params["method"] == "linear"
    assert s["d_ellipsoids_01"].params["eta"] == 0.5
    assert s["x"].frames == [0, 4, 8] and s["x"].frames_path is None
    assert s["x"].params["bc"] == "periodic" and s["x"].params["K"] == 9
    assert s["x"].params["fade_angle"] == 0.5  # the default of interpolate
    assert s["x"].keyframes[0] == str((d[0] / "pose_00.obj").resolve())


def test_glob_never_takes_the_output_root_for_a_sequence(tmp_path, capsys):
    data_synth.write_batch("ellipsoids", tmp_path / "shots", 2, 100)
    p = _job(tmp_path, '[job]\noutput = "shots/_out/all"\n[[sequences]]\nglob = "shots/*"\n')
    for _ in range(2):  # the second run finds shots/_out, which holds the output root
        rc, err = _cli(capsys, p, "-q")
        assert rc == 0, err
        assert sorted(_status(tmp_path / "shots" / "_out" / "all")) == \
            ["ellipsoids_00", "ellipsoids_01"]
    # an output root given on the command line is left out in the same way
    for _ in range(2):
        assert _cli(capsys, p, "-q", "-o", tmp_path / "shots" / "_o2")[0] == 0
    assert sorted(_status(tmp_path / "shots" / "_o2")) == ["ellipsoids_00", "ellipsoids_01"]


def test_glob_leaves_out_macos_resource_forks(tmp_path):
    # macOS writes ._name beside every file on exFAT/network drives: binary, not a keyframe
    d = data_synth.write_batch("ellipsoids", tmp_path / "shots", 1, 100)[0]
    poses = sorted(p.name for p in Path(d).glob("pose_*.obj"))
    for name in poses:
        (Path(d) / f"._{name}").write_bytes(b"\x00\x05\x16\x07Mac OS X")
    p = _job(tmp_path, '[job]\noutput = "out"\n[defaults]\nkeyframe_pattern = "*.obj"\n'
                       '[[sequences]]\nglob = "shots/*"\n')
    (seq,) = ss.load_job(p).sequences
    assert [Path(k).name for k in seq.keyframes] == poses


def test_glob_leaves_out_hidden_folders_unless_the_pattern_names_them(tmp_path):
    """``shots/*`` matched ``.Trashes``, ``.git`` and other hidden folders (Path.glob matches
    hidden names): the job was refused ("'.Trashes' is not usable as a directory name"), and
    one named otherwise would have become a sequence. A hidden name is matched only by a
    pattern component that starts with '.', as in a shell."""
    shots = tmp_path / "shots"
    real = [Path(d).name for d in data_synth.write_batch("ellipsoids", shots, 2, 100)]
    hidden = data_synth.write_batch("ellipsoids", tmp_path / "h", 1, 100)[0]
    shutil.copytree(hidden, shots / ".backup")  # keyframes inside
    (shots / ".Trashes").mkdir()
    (shots / ".git" / "objects").mkdir(parents=True)
    shutil.copytree(hidden, shots / real[0] / ".old")

    def dirs(pattern):
        p = _job(tmp_path, '[job]\noutput = "out"\n[[sequences]]\n'
                           f'glob = "{pattern}"\nname = "s{{dir}}"\n')
        return sorted(Path(s.directory).relative_to(shots).as_posix()
                      for s in ss.load_job(p).sequences)

    assert dirs("shots/*") == sorted(real)
    assert dirs(str(shots / "*")) == sorted(real)  # an absolute pattern too
    assert dirs("shots/**") == [".", *sorted(real)]
    p = _job(tmp_path, '[job]\noutput = "out"\n[[sequences]]\nglob = "shots/*"\n')
    assert sorted(s.name for s in ss.load_job(p).sequences) == sorted(real)
    # named explicitly: matched
    assert dirs("shots/.*") == [".Trashes", ".backup", ".git"]
    assert dirs("shots/.backup") == [".backup"]
    assert dirs("shots/*/.old") == [f"{real[0]}/.old"]
    assert dirs("shots/.g*/*") == [".git/objects"]


def test_output_may_not_replace_an_input(tmp_path, capsys):
    data_synth.write_batch("ellipsoids", tmp_path / "seqs", 1, 100)
    p = _job(tmp_path, '[job]\noutput = "seqs"\n[[sequences]]\nglob = "seqs/*"\n')
    rc, err = _cli(capsys, p)
    assert rc == 2 and "would contain the input" in err


def test_inner_workers_split():
    assert inner_workers(5, 2) == [1] * 5
    assert inner_workers(1, 4) == [4]
    assert inner_workers(2, 5) == [3, 2]


# ------------------------------------------------------------------------------------------
# Local executor: outputs, manifest, resume
# ------------------------------------------------------------------------------------------
def test_local_batch_outputs_manifest_and_resume(tmp_path, capsys):
    p = _synth_job(tmp_path, ["a", "b", "c"],
                   extra="")
    text = p.read_text().replace('name = "b"\nsynth = "ellipsoids"\n',
                                 'name = "b"\nsynth = "ellipsoids"\neta = 0.1\n')
    p.write_text(text)
    root = tmp_path / "out"
    rc, err = _cli(capsys, p, "-q")
    assert rc == 0, err
    assert _status(root) == {"a": "done", "b": "done", "c": "done"}
    # same arrays as a direct library call on the same keyframes
    V, F, rep = ss.read_sequence(root / "a")
    ref = _reference()
    assert np.array_equal(V, ref.V) and np.array_equal(F, ref.F)
    assert np.array_equal(ss.read_sequence(root / "b")[0], _reference(eta=0.1).V)
    m = json.loads((root / "a" / "manifest.json").read_text())
    assert m["shellspline_version"] == ss.__version__
    assert m["parameters"]["params"]["eta"] == 1e-3 and m["parameters"]["frames"] == [0, 6, 12]
    assert m["inputs"]["synth"] == {"name": "ellipsoids", "vertices": 150, "params": {}}
    assert set(m["outputs"]) >= {"frame_0000.obj", "frame_0012.obj", "report.json",
                                 "metrics.json"}
    metrics = json.loads((root / "a" / "metrics.json").read_text())
    assert metrics["keyframe_error"] == 0.0
    assert np.allclose(metrics["half_axes"], np.abs(ref.V - ref.V.mean(1, keepdims=True))
                       .max(1))
    assert (root / "batch.log").read_text().count("a: done") == 1
    mtimes = {q: (root / q / "frame_0005.obj").stat().st_mtime_ns for q in "abc"}

    # re-run: everything is up to date, nothing is rewritten
    rc, err = _cli(capsys, p, "-q")
    assert rc == 0 and _status(root) == {"a": "skipped", "b": "skipped", "c": "skipped"}
    assert all((root / q / "frame_0005.obj").stat().st_mtime_ns == mtimes[q] for q in "abc")

    # a changed parameter, an incomplete output and a stale temp dir of a killed run
    p.write_text(p.read_text().replace("eta = 0.1", "eta = 0.2"))
    (root / "c" / "frame_0007.obj").unlink()
    (root / ".a.stage-deadbeef").mkdir()
    (root / ".a.stage-deadbeef" / "frame_0000.obj").write_text("partial")
    rc, err = _cli(capsys, p, "-q")
    assert rc == 0
    assert _status(root) == {"a": "skipped", "b": "done", "c": "done"}
    assert np.array_equal(ss.read_sequence(root / "b")[0], _reference(eta=0.2).V)
    assert (root / "c" / "frame_0007.obj").is_file()
    assert _leftovers(root) == []

    # --force redoes everything
    rc, err = _cli(capsys, p, "-q", "--force", "--workers", "1")
    assert rc == 0 and set(_status(root).values()) == {"done"}


def test_changed_input_file_redoes_only_its_sequence(tmp_path):
    import hashlib

    dirs = data_synth.write_batch("ellipsoids", tmp_path / "seqs", 2, 100)
    p = _job(tmp_path, '[job]\noutput = "out"\n[[sequences]]\nglob = "seqs/*"\n')
    root = tmp_path / "out"
    assert ss.run_batch(ss.load_job(p)).exit_code == 0
    # move one vertex of one keyframe a little
    f = dirs[1] / "pose_02.obj"
    d = data_synth.generate("ellipsoids", 100, **data_synth.variants("ellipsoids", 2)[1])
    V = d["V"][2].copy()
    V[0] *= 1.01
    data_synth.write_mesh(f, V, d["F"])
    s = ss.run_batch(ss.load_job(p))
    assert s.exit_code == 0
    assert {o["name"]: o["status"] for o in s.sequences} == {dirs[0].name: "skipped",
                                                            dirs[1].name: "done"}
    m = json.loads((root / dirs[1].name / "manifest.json").read_text())
    rec = m["inputs"]["keyframes"][2]
    assert rec["path"] == str(f.resolve())
    assert rec["sha256"] == hashlib.sha256(f.read_bytes()).hexdigest()
    assert m["inputs"]["frames_file"]["sha256"] == hashlib.sha256(
        (dirs[1] / "frames.txt").read_bytes()).hexdigest()
    assert np.array_equal(ss.read_sequence(root / dirs[1].name)[0][12], V)


def test_python_api_and_progress_events(tmp_path):
    p = _synth_job(tmp_path, ["one"], workers=2)
    events = []
    summary = ss.run_batch(ss.load_job(p), progress=events.append)
    assert summary.exit_code == 0 and summary.count("done") == 1
    kinds = [e["kind"] for e in events]
    assert kinds[0] == "batch_start" and "sequence_end" in kinds
    stages = [e["event"]["stage"] for e in events if e["kind"] == "sequence_event"
              and e["event"]["kind"] == "stage_end"]
    assert "reconstruct" in stages and "write" in stages
    # one sequence, two workers: the spare worker reconstructs frames inside the sequence
    rep = json.loads((tmp_path / "out" / "one" / "report.json").read_text())
    assert rep["parameters"]["workers"] == 2


# ------------------------------------------------------------------------------------------
# Failures
# ------------------------------------------------------------------------------------------
def test_shipped_batch_obj_with_corrupt_sequences(tmp_path, capsys):
    (tmp_path / "pipelines").mkdir()
    shutil.copy(PIPELINES / "batch_obj.toml", tmp_path / "pipelines")
    dirs = data_synth.write_batch("ellipsoids", tmp_path / "synth" / "batch", 4, 100)
    # mismatched connectivity: the second keyframe's faces differ from the first one's
    text = (dirs[1] / "pose_01.obj").read_text().splitlines()
    i = next(k for k, line in enumerate(text) if line.startswith("f "))
    a, b, c = text[i].split()[1:]
    text[i] = f"f {a} {c} {b}"
    (dirs[1] / "pose_01.obj").write_text("\n".join(text) + "\n")
    # an unreadable file
    (dirs[2] / "pose_02.obj").write_bytes(b"\x00\xffnot a mesh\n")
    rc, err = _cli(capsys, tmp_path / "pipelines" / "batch_obj.toml", "-q")
    assert rc == 1
    root = tmp_path / "out" / "batch_obj"
    s = _summary(root)
    by = {o["name"]: o for o in s["sequences"]}
    assert [by[d.name]["status"] for d in dirs] == ["done", "failed", "failed", "done"]
    assert "pose_01.obj" in by[dirs[1].name]["reason"] and \
        "\n" not in by[dirs[1].name]["reason"]
    assert "pose_02.obj" in by[dirs[2].name]["reason"]
    assert s["counts"] == {"done": 2, "skipped": 0, "failed": 2, "interrupted": 0}
    assert s["exit_code"] == 1
    assert not (root / dirs[1].name).exists() and not (root / dirs[2].name).exists()
    assert "failed" in err and dirs[2].name in err  # the table is printed on failure
    assert _leftovers(root) == []


# ------------------------------------------------------------------------------------------
# Interruption and crashes (a real process, real signals)
# ------------------------------------------------------------------------------------------
def _default_signals():
    """preexec_fn: SIGINT/SIGTERM at SIG_DFL and unblocked in the child, whatever the test
    runner inherited (a background job of a non-interactive shell ignores SIGINT)."""
    for s in (signal.SIGINT, signal.SIGTERM):
        signal.signal(s, signal.SIG_DFL)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, [signal.SIGINT, signal.SIGTERM])


def _start(args, cwd):
    return subprocess.Popen([sys.executable, "-m", "shellspline", "batch", *map(str, args)],
                            cwd=cwd, env=_env(), stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, preexec_fn=_default_signals)


def _wait_for(cond, timeout=60.0):
    t = time.monotonic() + timeout
    while time.monotonic() < t:
        if cond():
            return True
        time.sleep(0.05)
    return False


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_interrupt_then_resume(tmp_path, sig):
    names = ["s0", "s1", "s2", "s3"]
    p = _synth_job(tmp_path, names, workers=1, defaults="delay = 0.6")
    root = tmp_path / "out"
    proc = _start([p, "-q"], tmp_path)
    try:
        assert _wait_for(lambda: (root / "s0" / "manifest.json").is_file())
        time.sleep(0.3)  # s1 is being solved or written
        proc.send_signal(sig)
        out, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert proc.returncode == 128 + sig, err  # 130 SIGINT, 143 SIGTERM
    assert "re-run" in err and err.strip().splitlines()[-1].startswith("shellspline: interrupt")
    st = _status(root)
    assert st["s0"] == "done" and "interrupted" in st.values()
    assert _summary(root)["interrupted"] is True and _summary(root)["exit_code"] == 128 + sig
    assert _leftovers(root) == []  # the running sequence's staging directory is gone
    done_before = [n for n in names if st[n] == "done"]
    for n in names:  # an output exists exactly when it is complete
        assert (root / n).exists() == (n in done_before)
    rc = subprocess.run([sys.executable, "-m", "shellspline", "batch", str(p), "-q"],
                        cwd=tmp_path, env=_env(), capture_output=True, text=True).returncode
    assert rc == 0
    st2 = _status(root)
    assert all(st2[n] == "skipped" for n in done_before)
    assert all(st2[n] == "done" for n in names if n not in done_before)


def test_a_sequence_published_before_the_interrupt_took_effect_is_done(tmp_path):
    """A stop signal can arrive after a task moved its complete output into place and before
    its result reached the parent (test_interrupt_then_resume[SIGTERM] once found s1 on disk
    but not done): the summary reports an output this run published as done, and one that
    another run published as interrupted (it is not this run's work)."""
    from shellspline.batch import run as batch_run
    from shellspline.batch.manifest import input_digest, read_manifest, sequence_key

    p = _synth_job(tmp_path, ["s0", "s1"], workers=1)
    job = ss.load_job(p)
    assert ss.run_batch(job).exit_code == 0
    todo = [(spec, sequence_key(spec, input_digest(spec))) for spec in job.sequences]
    this_run = read_manifest(Path(job.sequences[0].out))["run"]
    got = batch_run._collect(job, {}, todo, this_run)        # no result arrived for either
    assert [o["status"] for o in got] == ["done", "done"]
    assert [o["status"] for o in batch_run._collect(job, {}, todo, "another-run")] == \
        ["interrupted", "interrupted"]
    assert [o["status"] for o in batch_run._collect(job, {}, todo[1:], this_run)] == \
        ["interrupted", "done"]                              # s0 was not to run


@pytest.mark.parametrize("kind", ["file", "under_a_file"])
def test_unusable_output_root_is_one_line_exit_2(tmp_path, capsys, kind):
    p = _synth_job(tmp_path, ["a"])
    (tmp_path / "blocker").write_text("")
    out = tmp_path / "blocker" if kind == "file" else tmp_path / "blocker" / "out"
    rc, err = _cli(capsys, p, "-o", out, "-q")
    assert rc == 2 and err.count("\n") == 1 and f"output root '{out}'" in err
    assert (tmp_path / "blocker").read_text() == ""


def _worker_pid(proc):
    kids = Path(f"/proc/{proc.pid}/task/{proc.pid}/children")
    pids = kids.read_text().split() if kids.exists() else []
    return int(pids[0]) if pids else None


def _signal_first_worker(p, cwd, sig):
    """Run job ``p``, send ``sig`` to its first worker process mid-sequence; (rc, stderr)."""
    if not Path("/proc/self/task").is_dir():
        pytest.skip("finds the worker process through /proc (Linux)")
    proc = _start([p, "-q"], cwd)
    try:
        assert _wait_for(lambda: _worker_pid(proc) is not None)
        time.sleep(0.3)
        os.kill(_worker_pid(proc), sig)
        out, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
    return proc.returncode, err


def test_ctrl_c_belongs_to_the_parent_not_the_worker(tmp_path):
    """A terminal's Ctrl-C reaches every process of the job; only the parent acts on it
    (it stops the workers itself). A SIGINT reaching a worker alone changes nothing."""
    p = _synth_job(tmp_path, ["w0"], workers=1, defaults="delay = 1.0")
    rc, err = _signal_first_worker(p, tmp_path, signal.SIGINT)
    assert rc == 0, err
    assert _status(tmp_path / "out") == {"w0": "done"}


def test_killed_local_worker_fails_only_its_sequence(tmp_path):
    p = _synth_job(tmp_path, ["k0", "k1", "k2"], workers=1, defaults="delay = 1.0")
    root = tmp_path / "out"
    rc, err = _signal_first_worker(p, tmp_path, signal.SIGKILL)
    assert rc == 1, err
    s = _summary(root)
    by = {o["name"]: o for o in s["sequences"]}
    assert by["k0"]["status"] == "failed" and "killed by signal 9" in by["k0"]["reason"]
    assert by["k1"]["status"] == by["k2"]["status"] == "done"
    assert not (root / "k0").exists() and _leftovers(root) == []


# ------------------------------------------------------------------------------------------
# Dask
# ------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def cluster():
    distributed = pytest.importorskip("distributed")
    c = distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                 host="127.0.0.1", dashboard_address=None)
    yield c
    c.close()


def test_dask_gives_the_same_outputs_as_local(tmp_path, cluster, capsys):
    p = _synth_job(tmp_path, ["d0", "d1", "d2"], workers=2,
                   defaults='formats = ["obj", "ply"]')
    text = p.read_text().replace('name = "d1"\nsynth = "ellipsoids"\n',
                                 'name = "d1"\nsynth = "ellipsoids"\nbc = "periodic"\nK = 15\n')
    p.write_text(text)
    rc, err = _cli(capsys, p, "-q", "-o", tmp_path / "local")
    assert rc == 0, err
    rc, err = _cli(capsys, p, "-q", "-o", tmp_path / "dask", "--scheduler",
                   cluster.scheduler_address)
    assert rc == 0, err
    s = _summary(tmp_path / "dask")
    assert s["executor"] == "dask" and s["counts"]["done"] == 3
    for n in ("d0", "d1", "d2"):
        Vl, Fl, _ = ss.read_sequence(tmp_path / "local" / n)
        Vd, Fd, _ = ss.read_sequence(tmp_path / "dask" / n)
        assert np.array_equal(Vl, Vd) and np.array_equal(Fl, Fd)
        assert np.array_equal(ss.read_sequence(tmp_path / "dask" / n / "ply")[0], Vd)
        ml = json.loads((tmp_path / "local" / n / "manifest.json").read_text())
        md = json.loads((tmp_path / "dask" / n / "manifest.json").read_text())
        assert ml["key"] == md["key"]
    assert Vd.shape[0] == 13 and ss.read_sequence(tmp_path / "dask" / "d1")[0].shape[0] == 16
    # and a re-run through Dask skips what the local run... wrote elsewhere: its own outputs
    rc, err = _cli(capsys, p, "-q", "-o", tmp_path / "dask", "--scheduler",
                   cluster.scheduler_address)
    assert rc == 0 and set(_status(tmp_path / "dask").values()) == {"skipped"}


def test_dask_worker_killed_mid_job_loses_and_duplicates_nothing(tmp_path, cluster):
    distributed = pytest.importorskip("distributed")
    names = [f"w{i}" for i in range(4)]
    p = _synth_job(tmp_path, names, workers=2, defaults="delay = 1.5")
    job = ss.load_job(p)
    result = {}

    def run():
        result["summary"] = ss.run_batch(job, scheduler=cluster.scheduler_address)

    t = threading.Thread(target=run)
    t.start()
    killed = {}
    # Read the in-process scheduler's state instead of opening a second Client in this
    # process: closing a second client next to the batch's own could leave the batch's
    # as_completed waiting forever (seen intermittently).
    sched = cluster.scheduler

    def busy():
        proc = {a: [ts.key for ts in ws.processing] for a, ws in list(sched.workers.items())
                if ws.processing}
        return proc or None

    assert _wait_for(busy, 60)
    time.sleep(0.5)  # the task is inside its delay (solved, not yet written)
    worker, keys = next(iter(busy().items()))
    killed["pid"] = sched.workers[worker].pid
    killed["names"] = [k.split("-")[1] for k in keys]
    os.kill(killed["pid"], signal.SIGKILL)
    t.join(120)
    assert not t.is_alive()
    s = result["summary"]
    assert s.exit_code == 0, s.table()
    assert [o["name"] for o in s.sequences] == names  # each exactly once
    assert all(o["status"] == "done" for o in s.sequences)
    for o in s.sequences:
        if o["name"] in killed["names"]:  # retried on another (or the restarted) worker
            assert not o["worker"].endswith(f":{killed['pid']}")
    root = tmp_path / "out"
    assert sorted(q.name for q in root.iterdir() if q.is_dir()) == names
    ref = _reference()
    for n in names:
        V, F, _ = ss.read_sequence(root / n)
        assert np.array_equal(V, ref.V)
        assert manifest_matches(root / n, json.loads(
            (root / n / "manifest.json").read_text())["key"]) is not None
    assert _leftovers(root) == []
    log = (root / "batch.log").read_text()
    assert all(log.count(f"{n}: done") == 1 for n in names)


def test_missing_dask_is_a_one_line_error(tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "distributed", None)
    p = _synth_job(tmp_path, ["a"])
    rc, err = _cli(capsys, p, "--executor", "dask")
    assert rc == 2 and 'pip install "shellspline[dask]"' in err and err.count("\n") == 1


# ------------------------------------------------------------------------------------------
# The regression pipeline
# ------------------------------------------------------------------------------------------
def test_regression_pipeline_passes_and_catches_a_perturbation(tmp_path, capsys):
    out = tmp_path / "out"
    rc, err = _cli(capsys, PIPELINES / "regression_ellipsoids.toml", "-o", out)
    assert rc == 0, err
    s = _summary(out)
    assert s["regression"]["passed"] and len(s["regression"]["checks"]) >= 40
    assert "regression: passed" in err
    # the same job with one stored half-axis off by 0.5 %: a regression, exit 1
    (tmp_path / "p" / "expected").mkdir(parents=True)
    shutil.copy(PIPELINES / "regression_ellipsoids.toml", tmp_path / "p")
    exp = json.loads((PIPELINES / "expected" / "regression_ellipsoids.json").read_text())
    exp["sequences"]["fig3_natural"]["half_axes"][4][1] *= 1.005
    (tmp_path / "p" / "expected" / "regression_ellipsoids.json").write_text(json.dumps(exp))
    rc, err = _cli(capsys, tmp_path / "p" / "regression_ellipsoids.toml", "-o", out)
    assert rc == 1
    s = _summary(out)
    assert set(_status(out).values()) == {"skipped"}  # compared from the stored metrics
    bad = [c for c in s["regression"]["checks"] if not c["ok"]]
    assert [(c["sequence"], c["metric"]) for c in bad] == [("fig3_natural", "half_axes")]
    assert "REGRESSION" in err and "regression: FAILED" in err


def test_compare_regression_modes():
    reg = {"expected": {"s": {"gn_iterations_total": 10, "keyframe_kinks": [0.1, 0.2],
                              "gn_converged": 5}},
           "tolerances": {"gn_iterations_total": {"rtol": 0.2, "atol": 0, "mode": "max"},
                          "keyframe_kinks": {"rtol": 0, "atol": 1e-3, "mode": "close"},
                          "gn_converged": {"rtol": 0, "atol": 0, "mode": "min"}}}

    def ok(**m):
        return {c["metric"]: c["ok"] for c in batch.compare_regression(
            reg, {"s": m})["checks"]}
    base = dict(gn_iterations_total=12, keyframe_kinks=[0.1005, 0.2], gn_converged=5)
    assert all(ok(**base).values())
    assert not ok(**{**base, "gn_iterations_total": 13})["gn_iterations_total"]
    assert ok(**{**base, "gn_iterations_total": 3})["gn_iterations_total"]
    assert not ok(**{**base, "keyframe_kinks": [0.1, 0.2015]})["keyframe_kinks"]
    assert not ok(**{**base, "keyframe_kinks": [0.1]})["keyframe_kinks"]
    assert not ok(**{**base, "gn_converged": 4})["gn_converged"]
    assert ok(**{**base, "gn_converged": 6})["gn_converged"]
    assert not batch.compare_regression(reg, {})["passed"]


# ------------------------------------------------------------------------------------------
# Renders and plots (shellspline.viz)
# ------------------------------------------------------------------------------------------
def test_renders_and_plots_inside_the_atomic_output(tmp_path, capsys):
    pytest.importorskip("pyvista")
    pytest.importorskip("matplotlib")
    viz = pytest.importorskip("shellspline.viz")
    if not all(hasattr(viz, f) for f in ("render_strip", "plot_half_axes")):
        pytest.skip("shellspline.viz has no render_strip/plot_half_axes yet")
    p = _synth_job(tmp_path, ["r0", "r1"], vertices=100,
                   defaults='render = ["strip"]\nplots = ["half_axes"]')
    p.write_text(p.read_text().replace('name = "r1"\nsynth = "ellipsoids"\n',
                                       'name = "r1"\nsynth = "ellipsoids"\nmethod = "linear"\n'))
    rc, err = _cli(capsys, p, "-q")
    assert rc == 0, err
    root = tmp_path / "out"
    for n in ("r0", "r1"):
        for f in ("strip.png", "half_axes.png"):
            assert (root / n / f).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        assert {"strip.png", "half_axes.png"} <= set(
            json.loads((root / n / "manifest.json").read_text())["outputs"])
    assert (root / "half_axes.png").read_bytes()[:4] == b"\x89PNG"  # both sequences compared


def test_missing_viz_extra_is_a_one_line_error(tmp_path, capsys, monkeypatch):
    import importlib.util

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec",
                        lambda name, *a: None if name == "pyvista" else real(name, *a))
    p = _synth_job(tmp_path, ["a"], defaults='render = ["strip"]')
    rc, err = _cli(capsys, p)
    assert rc == 2 and 'pip install "shellspline[viz]"' in err and err.count("\n") == 1
    assert not (tmp_path / "out").exists()


def test_a_task_that_runs_twice_does_not_rewrite_or_duplicate(tmp_path):
    p = _synth_job(tmp_path, ["t"], vertices=100)
    job = ss.load_job(p)
    spec = job.sequences[0]
    key = sequence_key(spec, input_digest(spec))
    first = run_sequence(spec, key, run_id="run-1")
    assert first["status"] == "done" and first["reason"] == ""
    out = Path(spec.out)
    stamp = (out / "manifest.json").stat().st_mtime_ns
    # the same task again (a Dask retry after the first attempt had finished): kept as is
    again = run_sequence(spec, key, run_id="run-1", force=True)
    assert again["status"] == "done" and "earlier attempt" in again["reason"]
    assert (out / "manifest.json").stat().st_mtime_ns == stamp
    # a second writer that finished while the first was writing: its output is discarded
    staging = tmp_path / "out" / ".t.stage-0123456789ab"
    shutil.copytree(out, staging)
    assert publish(staging, out, key, lambda m: True) == "existing"
    assert not staging.exists() and (out / "manifest.json").stat().st_mtime_ns == stamp
    # a forced re-run of a new batch replaces the output atomically
    forced = run_sequence(spec, key, run_id="run-2", force=True)
    assert forced["status"] == "done" and forced["reason"] == ""
    assert json.loads((out / "manifest.json").read_text())["run"] == "run-2"
    assert sorted(q.name for q in (tmp_path / "out").iterdir()) == ["t"]


def test_missing_usd_extra_fails_the_batch_up_front(tmp_path, capsys, monkeypatch):
    """``formats = ["usd"]`` without pxr: one line, exit 2, nothing written (not one failure
    per sequence after its solve)."""
    monkeypatch.setitem(sys.modules, "pxr", None)  # import pxr (what require_usd does) fails
    p = _synth_job(tmp_path, ["a", "b"], defaults='formats = ["obj", "usd"]')
    rc, err = _cli(capsys, p)
    assert rc == 2 and err.count("\n") == 1, err
    assert "job.toml" in err and "sequence a and 1 more" in err and "shellspline[usd]" in err
    assert "internal error" not in err
    assert not (tmp_path / "out").exists()
    with pytest.raises(ImportError, match=r"shellspline\[usd\]"):  # the library alike
        batch.run_batch(ss.load_job(p))
    assert not (tmp_path / "out").exists()


def test_reference_key_takes_what_the_cli_takes(tmp_path):
    """`reference = "geodesic"` was refused by the job schema although the API and the CLI
    take it; a typo still gets the one-line key error."""
    for ref, want in (('"geodesic"', "geodesic"), ('"Keyframe"', "keyframe"), ("1", 1)):
        p = _job(tmp_path, '[job]\noutput = "o"\n[[sequences]]\nname = "a"\n'
                           f'synth = "ellipsoids"\nreference = {ref}\n')
        assert ss.load_job(p).sequences[0].params["reference"] == want
    p = _job(tmp_path, '[job]\noutput = "o"\n[[sequences]]\nname = "a"\nsynth = "ellipsoids"\n'
                       'reference = "geodesics"\n')
    with pytest.raises(ValueError, match="key 'reference'.*'geodesic'"):
        ss.load_job(p)


# ------------------------------------------------------------------------------------------
# Audit fixes: --write-expected with a failed sequence, geodesic max_time, static frames
# checks, plain-int regression notes
# ------------------------------------------------------------------------------------------
def test_write_expected_with_a_failed_sequence_still_reports(tmp_path, capsys):
    p = _job(tmp_path, '[job]\nname = "t"\noutput = "out"\nworkers = 2\n\n'
                       '[defaults]\nvertices = 150\nmethod = "lta"\n\n'
                       '[[sequences]]\nname = "good"\nsynth = "ellipsoids"\n\n'
                       '[[sequences]]\nname = "broken"\nsynth = "ellipsoids"\n'
                       'frames = [0, 6, 12]\nK = 3\n\n'
                       '[regression]\nexpected = "expected.json"\n')
    rc, err = _cli(capsys, p, "--write-expected", "-q")
    assert rc == 1, err
    out = tmp_path / "out"
    s = _summary(out)
    assert _status(out) == {"good": "done", "broken": "failed"}
    broken = [o for o in s["sequences"] if o["name"] == "broken"][0]
    assert broken["reason"]
    assert s["regression"] is None and s["exit_code"] == 1
    assert any("expected values not written" in e and "broken" in e for e in s["errors"])
    assert not (tmp_path / "expected.json").exists()
    # the table (with the failure's reason) and the note were printed
    assert "broken" in err and broken["reason"][:40] in err
    assert "expected values not written" in err
    assert "wrote expected values" not in err


def _interpolate_keywords(spec, monkeypatch) -> dict:
    """The keywords a sequence's run passes to ``shellspline.interpolate`` (stopped there)."""
    import shellspline.pipeline as pipeline

    seen = {}

    def fake_interpolate(*args, **kw):
        seen.update(kw)
        raise RuntimeError("stop here")

    monkeypatch.setattr(pipeline, "interpolate", fake_interpolate)
    out = run_sequence(spec, "k")
    assert out["status"] == "failed" and "stop here" in out["reason"]
    return seen


def test_geodesic_takes_max_time_as_interpolate_does(tmp_path, monkeypatch):
    p = _synth_job(tmp_path, ["g"], defaults='method = "geodesic"\nmax_time = 30\n')
    job = batch.load_job(p)
    spec = job.sequences[0]
    assert spec.params["method"] == "geodesic" and spec.params["max_time"] == 30.0
    seen = _interpolate_keywords(spec, monkeypatch)
    assert seen["method"] == "geodesic"
    assert seen["solver_options"]["max_time_s"] == 30.0


def test_max_time_bounds_the_reference_geodesic_of_an_lta_sequence(tmp_path, monkeypatch):
    # as `shellspline interpolate --reference geodesic --max-time`: an lta sequence with the
    # geodesic reference takes max_time (it was refused: "nonlinear or geodesic only"), and
    # passes it as the reference solve's limit; without that reference it is still refused
    p = _synth_job(tmp_path, ["g"], defaults='reference = "geodesic"\nmax_time = 30\n')
    spec = batch.load_job(p).sequences[0]
    assert spec.params["method"] == "lta" and spec.params["max_time"] == 30.0
    seen = _interpolate_keywords(spec, monkeypatch)
    assert seen["reference"] == "geodesic" and seen["solver_options"] == {"max_time_s": 30.0}
    p = _synth_job(tmp_path, ["g"], defaults="max_time = 30\n")
    with pytest.raises(ss.ShellsplineError) as e:
        batch.load_job(p)
    assert "reference = 'geodesic'" in str(e.value)


def test_frames_not_fitting_explicit_keyframes_is_exit_2(tmp_path, capsys):
    tet = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n"
    for i in range(3):
        (tmp_path / f"k{i}.obj").write_text(tet)
    p = _job(tmp_path, '[job]\noutput = "o"\n[[sequences]]\nname = "three"\n'
                       'keyframes = ["k0.obj", "k1.obj", "k2.obj"]\nframes = [0, 10]\n')
    rc, err = _cli(capsys, p)
    assert rc == 2
    assert err.count("\n") == 1 and str(p) in err
    assert "[[sequences]] #1 key 'frames'" in err and "sequence 'three'" in err
    assert "3 keyframes" in err
    assert not (tmp_path / "o").exists()


def test_regression_note_names_the_element_in_plain_ints():
    exp = [[1.0, 1.0, 1.0]] * 5
    got = [list(r) for r in exp]
    got[3][0] = 2.0
    reg = {"expected": {"s": {"half_axes": exp}},
           "tolerances": {"half_axes": {"rtol": 0.0, "atol": 1e-6, "mode": "close"}}}
    r = batch.compare_regression(reg, {"s": {"half_axes": got}})
    assert r["checks"][0]["note"] == "element (3, 0)"
    table = batch.regression_table(r)
    assert "REGRESSION (element (3, 0))" in table and "np." not in table

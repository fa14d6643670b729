"""Faults: killed parents, stop signals, and a batch output among its inputs.

Real subprocesses and real signals. Every child is started with SIGINT and SIGTERM at their
default disposition and unblocked (``_default_signals``), so the tests do not depend on what
the test runner inherited (a background job of a non-interactive shell ignores SIGINT).
Worker processes are found through ``/proc`` (Linux); elsewhere these tests skip.
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

import data_synth

REPO = Path(__file__).resolve().parents[1]

pytestmark = pytest.mark.skipif(not Path("/proc/self/task").is_dir(),
                                reason="finds worker processes through /proc (Linux)")

#: the stop deadline the README promises for SIGINT/SIGTERM to the parent
STOP_S = 2.0


def _default_signals():
    """preexec_fn: SIGINT/SIGTERM at SIG_DFL and unblocked, whatever the runner inherited."""
    for s in (signal.SIGINT, signal.SIGTERM):
        signal.signal(s, signal.SIG_DFL)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, [signal.SIGINT, signal.SIGTERM])


def _env():
    env = dict(os.environ)
    env["PYTHONPATH"] = str(REPO) + os.pathsep + env.get("PYTHONPATH", "")
    return env


def _popen(args, cwd, **kw):
    return subprocess.Popen(args, cwd=cwd, env=_env(), stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, preexec_fn=_default_signals,
                            **kw)


def _children(pid: int) -> list[int]:
    """Children of every thread of ``pid`` (Dask starts its workers from a helper thread)."""
    out = []
    for task in Path(f"/proc/{pid}/task").glob("*"):
        try:
            out += [int(x) for x in (task / "children").read_text().split()]
        except OSError:
            continue
    return out


def _descendants(pid: int) -> list[int]:
    out, todo = [], [pid]
    while todo:
        for c in _children(todo.pop()):
            out.append(c)
            todo.append(c)
    return out


def _alive(pid: int) -> bool:
    """Running (a zombie waiting for a reaper counts as gone)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat.rsplit(")", 1)[1].split()[0] not in ("Z", "X")


def _cmdline(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()[:200]
    except OSError:
        return "?"


def _wait_for(cond, timeout=30.0, step=0.02) -> bool:
    t = time.monotonic() + timeout
    while time.monotonic() < t:
        if cond():
            return True
        time.sleep(step)
    return cond()


def _cleanup(proc, pids):
    for p in [proc.pid, *pids]:
        try:
            os.kill(p, signal.SIGKILL)
        except OSError:
            pass
    try:
        proc.communicate(timeout=10)
    except (subprocess.TimeoutExpired, ValueError):
        pass


# ------------------------------------------------------------------------------------------
# interpolate --workers 2: a pool of frame workers
# ------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def slow_keyframes(tmp_path_factory):
    """1000-vertex ellipsoid keyframes; at frames 0,500,1000 their reconstruction runs in the
    process pool for tens of seconds (8 s for frames 0,100,200 on the loaded 2-core VM), so a
    signal always finds the workers busy."""
    d = tmp_path_factory.mktemp("slow")
    data_synth.write_keyframes(data_synth.generate("ellipsoids", 1000), d)
    return sorted(d.glob("pose_*.obj"))


def _start_interpolate(keyframes, out: Path, **kw):
    args = [sys.executable, "-m", "shellspline", "interpolate", *map(str, keyframes),
            "--frames", "0,500,1000", "-o", str(out), "--coarse", "none", "--workers", "2",
            "-q"]
    proc = _popen(args, out.parent, **kw)
    assert _wait_for(lambda: len(_children(proc.pid)) >= 2 or proc.poll() is not None), \
        "no pool workers appeared"
    assert proc.poll() is None, proc.communicate()
    workers = _descendants(proc.pid)
    time.sleep(0.5)  # the workers are solving frames
    return proc, workers


def test_pool_workers_die_with_a_killed_parent(tmp_path, slow_keyframes):
    """SIGKILL (an OOM killer, a CI timeout) leaves no worker behind, and the caller's pipes
    close: reading the child's output to the end returns."""
    out = tmp_path / "out"
    proc, workers = _start_interpolate(slow_keyframes, out)
    try:
        assert len(workers) >= 2
        proc.kill()
        t0 = time.monotonic()
        proc.communicate(timeout=10)  # EOF on stdout and stderr: no worker holds them
        assert _wait_for(lambda: not any(map(_alive, workers)), timeout=2.0), \
            [w for w in workers if _alive(w)]
        assert time.monotonic() - t0 < 3.0
    finally:
        _cleanup(proc, workers)
    assert not out.exists()


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_stop_signal_to_the_parent_only_stops_interpolate(tmp_path, slow_keyframes, sig):
    """What ``kill PID``, systemd and CI runners send: exit 128+signal within 2 s, no output,
    no temporary directory, no worker left."""
    out = tmp_path / "out"
    proc, workers = _start_interpolate(slow_keyframes, out)
    try:
        os.kill(proc.pid, sig)
        t0 = time.monotonic()
        _, err = proc.communicate(timeout=30)
        took = time.monotonic() - t0
        assert proc.returncode == 128 + sig, err
        assert took < STOP_S, took
        assert "interrupted" in err and err.count("\n") == 1, err
        assert not any(map(_alive, workers))
    finally:
        _cleanup(proc, workers)
    assert list(tmp_path.iterdir()) == []  # neither OUT nor a hidden temporary sibling


def test_ctrl_c_to_the_process_group_stops_interpolate(tmp_path, slow_keyframes):
    """A terminal's Ctrl-C reaches the parent and every worker at once."""
    out = tmp_path / "out"
    proc, workers = _start_interpolate(slow_keyframes, out, start_new_session=True)
    try:
        os.killpg(proc.pid, signal.SIGINT)
        t0 = time.monotonic()
        _, err = proc.communicate(timeout=30)
        assert proc.returncode == 130, err
        assert time.monotonic() - t0 < STOP_S
        assert not any(map(_alive, workers))
    finally:
        _cleanup(proc, workers)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("how", ["no_prctl", "pool_in_a_thread"])
def test_pool_watchdog_alone_stops_orphaned_workers(tmp_path, how):
    """Where the kernel's parent-death signal does not exist (simulated: prctl disabled), or
    is not armed because the pool was started from another thread than the main one (the
    signal would follow that thread), the workers' watchdog notices the dead parent."""
    script = tmp_path / "pool.py"
    script.write_text(textwrap.dedent(f"""
        import os, sys, threading, time
        import shellspline.parallel as par
        if {how == "no_prctl"}:
            par.set_pdeathsig = lambda sig: False  # as on a platform without prctl

        def work(i):
            # one write per line: two workers' print() calls (text, then newline) interleave
            os.write(1, f"{{os.getpid()}}\\n".encode())
            time.sleep(60)

        def run():
            with par.process_pool(2) as ex:
                list(ex.map(work, range(2)))

        if {how == "pool_in_a_thread"}:
            t = threading.Thread(target=run)
            t.start()
            t.join()
        else:
            run()
    """))
    proc = _popen([sys.executable, str(script)], tmp_path)
    workers = []
    try:
        for _ in range(2):
            workers.append(int(proc.stdout.readline()))
        proc.kill()
        proc.communicate(timeout=10)
        # the watchdog polls every 0.2 s; the margin is for a loaded machine (2 s failed once
        # with eight agents sharing two cores)
        assert _wait_for(lambda: not any(map(_alive, workers)), timeout=5.0)
    finally:
        _cleanup(proc, workers)


# ------------------------------------------------------------------------------------------
# batch: one worker process per sequence
# ------------------------------------------------------------------------------------------
def _batch_job(tmp: Path, names, delay: float, workers: int = 2,
               executor: str = "local") -> Path:
    """Synthetic sequences that sleep ``delay`` seconds with their staging directory written,
    before publishing it."""
    seqs = "".join(f'\n[[sequences]]\nname = "{n}"\nsynth = "ellipsoids"\n' for n in names)
    p = tmp / "job.toml"
    p.write_text(f'[job]\nname = "t"\noutput = "out"\nworkers = {workers}\n'
                 f'executor = "{executor}"\n\n'
                 f'[defaults]\nvertices = 100\ndelay = {delay}\n{seqs}')
    return p


def _staging(root: Path) -> list[str]:
    return sorted(p.name for p in root.glob(".*.stage-*")) if root.is_dir() else []


def _start_batch(tmp: Path, job: Path, n_running: int, **kw):
    """Start ``shellspline batch JOB`` and wait until ``n_running`` sequences have written
    their staging directories (they are then inside their delay); (process, workers)."""
    proc = _popen([sys.executable, "-m", "shellspline", "batch", str(job), "-q"], tmp, **kw)
    root = tmp / "out"
    # a Dask LocalCluster takes a few seconds to start on a loaded machine
    assert _wait_for(lambda: len(_staging(root)) >= n_running or proc.poll() is not None,
                     timeout=120), "the sequences did not start"
    assert proc.poll() is None, proc.communicate()
    workers = _descendants(proc.pid)
    assert len(workers) >= n_running, workers
    return proc, workers


def _lock_is_free(path: Path) -> bool:
    import fcntl

    with open(path, "a+") as fh:
        try:
            fcntl.flock(fh.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            return False
        fcntl.flock(fh.fileno(), fcntl.LOCK_UN)
        return True


def test_batch_workers_die_with_a_killed_parent(tmp_path):
    """After a SIGKILL of the batch, its workers end at once: they neither keep the job lock
    (an immediate rerun is not refused) nor publish a sequence later."""
    delay = 3.0
    job = _batch_job(tmp_path, ["a", "b"], delay)
    root = tmp_path / "out"
    proc, workers = _start_batch(tmp_path, job, 2)
    try:
        proc.kill()
        proc.communicate(timeout=10)
        assert _wait_for(lambda: not any(map(_alive, workers)), timeout=2.0), \
            [w for w in workers if _alive(w)]
        assert _lock_is_free(root / ".batch.lock")
        time.sleep(delay + 1.0)  # an orphan would have published by now
        assert not (root / "a").exists() and not (root / "b").exists()
    finally:
        _cleanup(proc, workers)


_STOPS = [(signal.SIGINT, False), (signal.SIGTERM, False), (signal.SIGINT, True)]
_STOP_IDS = ["SIGINT", "SIGTERM", "ctrl_c_to_the_group"]


@pytest.mark.parametrize("executor", ["local", "dask"])
@pytest.mark.parametrize("sig,group", _STOPS, ids=_STOP_IDS)
def test_stop_signals_stop_batch(tmp_path, sig, group, executor):
    """SIGINT or SIGTERM to the parent alone, or Ctrl-C to the whole group, while both
    sequences have their staging directories written: exit 128+signal within 2 s, workers
    gone (the local pool's, or the processes of the Dask LocalCluster), no staging directory
    left, lock released."""
    if executor == "dask":
        pytest.importorskip("distributed")
    delay = 30.0  # the sequences would take this long: only a working stop ends the test
    job = _batch_job(tmp_path, ["a", "b"], delay, executor=executor)
    root = tmp_path / "out"
    proc, workers = _start_batch(tmp_path, job, 2, start_new_session=group)
    try:
        assert len(_staging(root)) == 2  # the stop has temporary output to remove
        if group:
            os.killpg(proc.pid, sig)
        else:
            os.kill(proc.pid, sig)
        t0 = time.monotonic()
        _, err = proc.communicate(timeout=60)
        took = time.monotonic() - t0
        assert proc.returncode == 128 + sig, err
        assert took < STOP_S, took
        # one line, the command's: worker processes (Dask's are spawned children that import
        # the command's script) never run its start-up interrupt guard
        assert err.count("shellspline: interrupted") <= 1, err
        # with Dask, multiprocessing's resource tracker ends when the parent's pipe closes,
        # so just after the parent
        grace = 1.0 if executor == "dask" else 0.0
        _wait_for(lambda: not any(map(_alive, workers)), timeout=grace)
        left = {w: _cmdline(w) for w in workers if _alive(w)}
        assert not left, left
    finally:
        _cleanup(proc, workers)
    import json

    s = json.loads((root / "summary.json").read_text())
    assert s["interrupted"] is True and s["exit_code"] == 128 + sig
    assert s["executor"] == executor
    assert sorted(p.name for p in root.iterdir()) == [".batch.lock", "batch.log",
                                                       "summary.json"]  # no staging left
    assert _lock_is_free(root / ".batch.lock")


@pytest.mark.parametrize("case", ["root_is_glob_dir", "root_inside_glob_dir",
                                  "root_is_keyframe_folder", "cli_output_is_glob_dir"])
def test_batch_output_among_the_inputs_is_refused(tmp_path, case):
    """An output root that is, or lies inside, a folder holding a sequence's keyframes is a
    one-line exit-2 error, and nothing is written there."""
    shots = tmp_path / "shots"
    dirs = data_synth.write_batch("ellipsoids", shots, 2, 100)
    seq = ('[[sequences]]\nkeyframes = ["shots/ellipsoids_00/pose_00.obj", '
           '"shots/ellipsoids_00/pose_01.obj"]\nname = "x"\nframes = [0, 4]\n'
           if case == "root_is_keyframe_folder" else '[[sequences]]\nglob = "shots/*"\n')
    output = {"root_is_glob_dir": "shots/ellipsoids_00",
              "root_inside_glob_dir": "shots/ellipsoids_00/out",
              "root_is_keyframe_folder": "shots/ellipsoids_00",
              "cli_output_is_glob_dir": "elsewhere"}[case]
    (tmp_path / "job.toml").write_text(f'[job]\noutput = "{output}"\n{seq}')
    before = {d: sorted(p.name for p in d.iterdir()) for d in dirs}
    extra = ["-o", str(dirs[0])] if case == "cli_output_is_glob_dir" else []
    r = subprocess.run([sys.executable, "-m", "shellspline", "batch", "job.toml", "-q",
                        *extra], cwd=tmp_path, env=_env(), capture_output=True, text=True,
                       timeout=60, preexec_fn=_default_signals)
    assert r.returncode == 2, r.stderr
    assert r.stderr.count("\n") == 1 and "keyframe folder" in r.stderr, r.stderr
    assert {d: sorted(p.name for p in d.iterdir()) for d in dirs} == before
    assert not (tmp_path / "elsewhere").exists()


# ------------------------------------------------------------------------------------------
# Stop signals inside one process
# ------------------------------------------------------------------------------------------
def test_stop_signals_unwind_raise_with_the_shell_exit_code_and_keep_an_ignored_sigint():
    from shellspline.parallel import Interrupted, interrupt_exit_code, stop_signals_unwind

    old_int = signal.signal(signal.SIGINT, signal.SIG_IGN)  # a background job of a script
    old_term = signal.getsignal(signal.SIGTERM)
    try:
        with pytest.raises(Interrupted) as info:
            with stop_signals_unwind():
                assert signal.getsignal(signal.SIGINT) == signal.SIG_IGN
                os.kill(os.getpid(), signal.SIGINT)  # ignored: nothing happens
                os.kill(os.getpid(), signal.SIGTERM)
                time.sleep(5)  # the handler interrupts this
        assert info.value.signum == signal.SIGTERM and info.value.exit_code == 143
        assert isinstance(info.value, KeyboardInterrupt)  # every Ctrl-C cleanup applies
        assert signal.getsignal(signal.SIGINT) == signal.SIG_IGN  # handlers restored
        assert signal.getsignal(signal.SIGTERM) == old_term
        assert interrupt_exit_code(KeyboardInterrupt()) == 130
        assert interrupt_exit_code(Interrupted(signal.SIGINT)) == 130
    finally:
        signal.signal(signal.SIGINT, old_int)

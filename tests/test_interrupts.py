"""Stop signals at awkward moments: while pool workers are forked, after some outputs of a
command were written, and in ``multiprocessing`` children of the command line.

Real subprocesses and real signals where the moment matters (an after-fork hook that sends
SIGINT makes the race with the forks deterministic).
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import threading
from pathlib import Path
from types import SimpleNamespace

import pytest

REPO = Path(__file__).resolve().parents[1]
posix = pytest.mark.skipif(not hasattr(signal, "pthread_sigmask") or os.name != "posix",
                           reason="signal masks and fork (POSIX)")


def _default_signals():
    for s in (signal.SIGINT, signal.SIGTERM):
        signal.signal(s, signal.SIG_DFL)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, [signal.SIGINT, signal.SIGTERM])


def _run(args, cwd, timeout=120):
    env = dict(os.environ)
    env["PYTHONPATH"] = str(REPO) + os.pathsep + env.get("PYTHONPATH", "")
    return subprocess.run(args, cwd=cwd, env=env, capture_output=True, text=True,
                          timeout=timeout, preexec_fn=_default_signals)


@posix
def test_deferred_signal_raised_when_block_left():
    from shellspline.parallel import Interrupted, stop_signals_deferred, stop_signals_unwind

    # Python's own Ctrl-C handler, whatever this process inherited: a test run started as a
    # background job of a non-interactive shell has SIGINT ignored (the shell's rule), which
    # stop_signals_unwind rightly leaves alone
    inherited = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        reached = []
        with pytest.raises(Interrupted) as info:
            with stop_signals_unwind():
                with stop_signals_deferred():
                    # to this thread: a process-directed kill may go to another thread of
                    # pytest's process that does not block it
                    signal.pthread_kill(threading.get_ident(), signal.SIGINT)
                    reached.append("after kill")  # held: the block goes on
                reached.append("after block")  # never: raised when the block is left
        assert reached == ["after kill"]
        assert info.value.signum == signal.SIGINT and info.value.exit_code == 130
        # handlers and mask restored
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
        assert signal.SIGINT not in signal.pthread_sigmask(signal.SIG_BLOCK, [])
    finally:
        signal.signal(signal.SIGINT, inherited)


@posix
def test_deferred_without_signal_changes_nothing():
    from shellspline.parallel import stop_signals_deferred

    before = (signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM),
              signal.pthread_sigmask(signal.SIG_BLOCK, []))
    with stop_signals_deferred():
        assert signal.SIGINT in signal.pthread_sigmask(signal.SIG_BLOCK, [])
    assert before == (signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM),
                      signal.pthread_sigmask(signal.SIG_BLOCK, []))


@posix
@pytest.mark.skipif(sys.platform != "linux", reason="fork start method (Linux)")
def test_sigint_while_pool_workers_fork_is_not_swallowed(tmp_path):
    """A SIGINT handled in the parent's after-fork hooks was raised where Python ignores
    exceptions ("Exception ignored in ... _releaseLock"), and the run completed, exit 0."""
    script = tmp_path / "fork_sigint.py"
    script.write_text(textwrap.dedent("""
        import os, signal, sys
        from shellspline.parallel import Interrupted, process_pool, stop_signals_unwind

        # every fork of the parent is followed by a Ctrl-C, in the after-fork hooks
        os.register_at_fork(after_in_parent=lambda: os.kill(os.getpid(), signal.SIGINT))
        try:
            with stop_signals_unwind():
                with process_pool(2, method="fork") as ex:
                    result = ex.submit(abs, -3).result()
        except Interrupted as exc:
            print("interrupted", exc.signum)
            sys.exit(exc.exit_code)
        print("completed", result)
        sys.exit(0)
    """))
    r = _run([sys.executable, str(script)], tmp_path)
    assert r.returncode == 130, (r.stdout, r.stderr)
    assert r.stdout.strip() == f"interrupted {int(signal.SIGINT)}"
    assert "Exception ignored" not in r.stderr and "Traceback" not in r.stderr, r.stderr


@posix
def test_interrupted_pool_shuts_down_quietly(tmp_path):
    """Interrupt while tasks run: workers stopped, no traceback at exit (the executor's
    management thread is ended and forgotten, never woken through a closed pipe)."""
    script = tmp_path / "pool_stop.py"
    script.write_text(textwrap.dedent("""
        import os, signal, sys, time, threading
        from shellspline.parallel import Interrupted, process_pool, stop_signals_unwind

        try:
            with stop_signals_unwind():
                with process_pool(2) as ex:
                    futs = [ex.submit(time.sleep, 30) for _ in range(4)]
                    time.sleep(0.5)
                    os.kill(os.getpid(), signal.SIGINT)
                    time.sleep(30)
        except Interrupted as exc:
            print("interrupted")
            sys.exit(exc.exit_code)
    """))
    r = _run([sys.executable, str(script)], tmp_path)
    assert r.returncode == 130 and r.stdout.strip() == "interrupted", (r.stdout, r.stderr)
    assert "Traceback" not in r.stderr and "Exception" not in r.stderr, r.stderr


def test_interrupted_line_names_written_outputs():
    from shellspline.cli import startup

    startup.forget_outputs()
    assert startup.interrupted_line() == startup.INTERRUPTED
    startup.output_written("a.gif")
    line = startup.interrupted_line()
    assert "a.gif" in line and "no output was written" not in line
    startup.forget_outputs()
    assert startup.interrupted_line() == startup.INTERRUPTED


def test_render_interrupted_after_gif_says_gif_was_written(tmp_path, monkeypatch, capsys):
    from shellspline import viz
    from shellspline.cli.main import main

    gif, png = tmp_path / "x.gif", tmp_path / "x.png"

    def animation(seq, path, **kw):
        Path(path).write_bytes(b"GIF89a")
        return Path(path)

    def strip(seq, path, **kw):
        raise KeyboardInterrupt

    monkeypatch.setattr(viz, "load_source", lambda out: SimpleNamespace(K=4, frames=None))
    monkeypatch.setattr(viz, "checked_output", lambda *a, **k: None)
    monkeypatch.setattr(viz, "render_animation", animation)
    monkeypatch.setattr(viz, "render_strip", strip)
    rc = main(["render", str(tmp_path), "--gif", str(gif), "--strip", str(png)])
    err = capsys.readouterr().err
    assert rc == 130
    assert gif.exists() and not png.exists()
    assert "no output was written" not in err
    assert f"interrupted; written before the interrupt: {gif}" in err
    # the next command starts afresh
    monkeypatch.setattr(viz, "render_animation", strip)
    assert main(["render", str(tmp_path), "--gif", str(gif)]) == 130
    assert "no output was written" in capsys.readouterr().err


@posix
def test_startup_guard_inactive_in_spawned_children(tmp_path):
    """A spawned child of the command (a Dask worker) runs the command's script as
    ``__mp_main__`` with its ``sys.argv``: the start-up guard must stay off there."""
    script = tmp_path / "shellspline"  # named like the console script: the command line
    script.write_text(textwrap.dedent("""
        import multiprocessing as mp, signal
        import shellspline  # the package face calls startup.guard()

        def report(q):
            q.put(getattr(signal.getsignal(signal.SIGINT), "__name__", "?"))

        if __name__ == "__main__":
            print("parent", getattr(signal.getsignal(signal.SIGINT), "__name__", "?"))
            ctx = mp.get_context("spawn")
            q = ctx.Queue()
            p = ctx.Process(target=report, args=(q,))
            p.start()
            print("child", q.get(timeout=100))
            p.join()
    """))
    r = _run([sys.executable, str(script)], tmp_path)
    assert r.returncode == 0, r.stderr
    lines = dict(line.split() for line in r.stdout.splitlines())
    assert lines["parent"] == "_interrupted"  # the guard is on in the command itself
    assert lines["child"] == "default_int_handler"

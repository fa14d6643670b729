"""Worker processes that never outlive their parent, and stop signals that unwind.

One place for the process machinery of the pipeline, the frame writer and the batch executor:

* :func:`start_method` — ``"fork"`` on Linux (workers inherit the parent's prepared solver and
  arrays without copies), ``"spawn"`` elsewhere.
* :func:`process_pool` — a :class:`~concurrent.futures.ProcessPoolExecutor` whose workers die
  with the parent whatever kills it (SIGKILL included) and are terminated, not waited for,
  when the block is left by an exception (Ctrl-C, SIGTERM, an error).
* :func:`die_with_parent` — what every worker calls first: on Linux a parent-death signal
  (``prctl(PR_SET_PDEATHSIG)``), elsewhere a watchdog thread that polls ``os.getppid()``;
  :func:`parent_alive` tells a worker whether its parent still wants its result.
* :func:`stop_processes` — SIGTERM, a short grace, then SIGKILL (the batch's own workers).
* :class:`Interrupted` and :func:`stop_signals_unwind` — SIGTERM (and SIGINT) raised as an
  exception in the main thread, so that temporary outputs are removed on the way out and the
  process exits with ``128 + signal`` (130 for SIGINT, 143 for SIGTERM).
"""
from __future__ import annotations

import contextlib
import multiprocessing as mp
import os
import platform
import signal
import threading
import time

__all__ = ["Interrupted", "interrupt_exit_code", "stop_signals_unwind", "stop_signals_deferred",
           "start_method",
           "process_pool", "stop_processes", "die_with_parent", "parent_alive", "set_pdeathsig"]

#: how often a worker's watchdog looks for its parent (seconds): the delay between a parent's
#: death and its workers' where the parent-death signal does not exist
WATCHDOG_PERIOD_S = 0.2
#: how long terminated workers get to exit before they are killed (seconds)
TERMINATE_GRACE_S = 1.0

_PR_SET_PDEATHSIG = 1  # <linux/prctl.h>
_STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)
_KILL = getattr(signal, "SIGKILL", signal.SIGTERM)  # Windows: TerminateProcess either way
_parent = {"pid": None}  # set in a worker by die_with_parent


class Interrupted(KeyboardInterrupt):
    """A stop signal (SIGINT, SIGTERM) received by the main thread, raised as an exception.

    A subclass of :class:`KeyboardInterrupt`, so every ``except KeyboardInterrupt`` cleanup
    path (temporary directories, batch staging, worker shutdown) handles it the same way.

    Attributes
    ----------
    signum : int
        The signal number.
    exit_code : int
        ``128 + signum``, the shell's convention (130 SIGINT, 143 SIGTERM).
    """

    def __init__(self, signum: int):
        super().__init__(signal.Signals(signum).name)
        self.signum = int(signum)
        self.exit_code = 128 + self.signum


def interrupt_exit_code(exc: BaseException) -> int:
    """The exit code of a process stopped by ``exc``: ``128 + signal`` for an
    :class:`Interrupted`, 130 for a plain :class:`KeyboardInterrupt` (Ctrl-C)."""
    return getattr(exc, "exit_code", 130)


def _raise_interrupted(signum, frame):
    raise Interrupted(signum)


@contextlib.contextmanager
def stop_signals_unwind():
    """Inside the block, SIGTERM and SIGINT raise :class:`Interrupted` in the main thread.

    SIGINT keeps an inherited ``SIG_IGN`` (a background job of a non-interactive shell is meant
    to ignore Ctrl-C); SIGTERM is always handled. The previous handlers are restored on exit.
    Outside the main thread (where handlers cannot be set) the block runs unchanged.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    old = {}
    try:
        for s in _STOP_SIGNALS:
            if s == signal.SIGINT and signal.getsignal(s) == signal.SIG_IGN:
                continue
            old[s] = signal.signal(s, _raise_interrupted)
        yield
    finally:
        for s, h in old.items():
            signal.signal(s, h)


def _set_handler(signum: int, handler) -> None:
    # signal.signal runs the pending Python handlers first and, when one raises, does not
    # set the new handler: set it anyway before the exception goes on
    try:
        signal.signal(signum, handler)
    except BaseException:
        signal.signal(signum, handler)
        raise


@contextlib.contextmanager
def stop_signals_deferred():
    """Inside the block, SIGINT and SIGTERM are held and acted upon when the block is left.

    For the code that forks worker processes: a stop signal handled while the parent runs
    its after-fork hooks (``logging``'s ``_releaseLock``, ``os.register_at_fork``) raises its
    exception where Python ignores it (``Exception ignored in: ...``), so the run went on as
    if there had been no Ctrl-C. Here the signals are blocked in this thread (a forked child
    inherits the mask; the pool worker unblocks them once its own handlers are set) and
    their Python handlers only record them (a signal another thread received); when the
    block is left the handlers are restored and a recorded signal is handled then, by its
    own handler (:class:`Interrupted` raised at a safe point). Handlers ``SIG_IGN`` and
    ``SIG_DFL`` are left as they are (still blocked until the block ends). Outside the main
    thread the block runs unchanged.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    pending: list[int] = []

    def record(signum, frame):
        pending.append(signum)

    old = {}
    try:
        for s in _STOP_SIGNALS:
            h = signal.getsignal(s)
            if callable(h):
                _set_handler(s, record)
                old[s] = h
        mask = (signal.pthread_sigmask(signal.SIG_BLOCK, _STOP_SIGNALS)
                if hasattr(signal, "pthread_sigmask") else None)
        try:
            yield
        finally:
            if mask is not None:  # a pending signal is delivered here, to ``record``
                signal.pthread_sigmask(signal.SIG_SETMASK, mask)
    finally:
        error = None
        for s, h in old.items():
            try:
                _set_handler(s, h)
            except BaseException as exc:  # a new signal, handled by a restored handler
                error = error or exc
        if error is not None:
            raise error
    if pending:
        signum = pending[0]
        handler = old.get(signum)
        if callable(handler):
            handler(signum, None)
        else:  # pragma: no cover - recorded only by a callable handler's replacement
            raise Interrupted(signum)


def start_method() -> str:
    """``"fork"`` on Linux (workers share the parent's arrays copy-on-write), else
    ``"spawn"`` (fork is unsafe with macOS system libraries and absent on Windows)."""
    if platform.system() == "Linux" and "fork" in mp.get_all_start_methods():
        return "fork"
    return "spawn"


def set_pdeathsig(sig: int) -> bool:
    """``prctl(PR_SET_PDEATHSIG, sig)`` on Linux; False where it is not available."""
    if platform.system() != "Linux":
        return False
    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        return libc.prctl(_PR_SET_PDEATHSIG, int(sig), 0, 0, 0) == 0
    except (OSError, AttributeError):  # pragma: no cover - no libc prctl
        return False


def _watchdog(parent_pid: int, sig: int) -> None:
    while os.getppid() == parent_pid:
        time.sleep(WATCHDOG_PERIOD_S)
    try:
        os.kill(os.getpid(), sig)
        time.sleep(5.0)  # a handler that unwinds gets this long
    finally:
        os._exit(1)


def die_with_parent(parent_pid: int, sig: int = _KILL, pdeathsig: bool = True) -> None:
    """Make this (worker) process receive ``sig`` when process ``parent_pid`` dies.

    On Linux the kernel's parent-death signal (``prctl(PR_SET_PDEATHSIG)``; it fires when
    the *thread* that forked this process exits, so pass ``pdeathsig=False`` unless that was
    the parent's main thread). Where it is not available or not armed, a daemon thread polls
    ``os.getppid()`` every :data:`WATCHDOG_PERIOD_S` seconds and sends ``sig`` to this process
    (then exits it 5 s later if ``sig`` was handled); not both, so that a worker that forks
    (a batch worker starting its own pool) has no extra thread. A parent that is already gone
    when this runs is detected too.

    Parameters
    ----------
    parent_pid : int
        The parent's pid, taken in the parent (``os.getpid()``) before starting the worker.
    sig : int
        The signal to receive: ``SIGKILL`` for pool workers (nothing to clean up), ``SIGTERM``
        for a worker whose handler removes its temporary output.
    pdeathsig : bool
        Use the Linux parent-death signal where it exists.
    """
    _parent["pid"] = int(parent_pid)
    if hasattr(signal, "pthread_sigmask"):  # a worker must never keep SIGTERM blocked
        signal.pthread_sigmask(signal.SIG_UNBLOCK, [sig, signal.SIGTERM])
    armed = pdeathsig and set_pdeathsig(sig)
    if os.getppid() != parent_pid:  # the parent died before the signal was armed
        os.kill(os.getpid(), sig)
        os._exit(1)
    if not armed:
        threading.Thread(target=_watchdog, args=(int(parent_pid), int(sig)), daemon=True,
                         name="shellspline-parent-watchdog").start()


def parent_alive() -> bool:
    """False in a worker whose parent has died (True in a process that is no worker)."""
    return _parent["pid"] is None or os.getppid() == _parent["pid"]


def _pool_worker_init(parent_pid, pdeathsig, initializer, initargs):
    # Ctrl-C reaches every process of the terminal's group: stopping is the parent's business
    # (it terminates the pool). SIGTERM kills a worker outright: nothing of it needs cleanup.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    die_with_parent(parent_pid, _KILL, pdeathsig)
    if initializer is not None:
        initializer(*initargs)


def stop_processes(procs, grace: float = TERMINATE_GRACE_S) -> None:
    """SIGTERM every live process of ``procs`` (:class:`multiprocessing.Process`), wait up to
    ``grace`` seconds in all, then SIGKILL those still alive and reap them."""
    procs = [p for p in procs if p.is_alive()]
    for p in procs:
        with contextlib.suppress(OSError, ValueError):
            p.terminate()
    deadline = time.monotonic() + grace
    for p in procs:
        p.join(max(0.0, deadline - time.monotonic()))
    for p in procs:
        if p.is_alive():
            with contextlib.suppress(OSError, ValueError):
                p.kill()
            p.join(5.0)


@contextlib.contextmanager
def process_pool(workers: int, initializer=None, initargs=(), method: str | None = None):
    """A process pool whose workers die with this process and never delay a stop.

    Parameters
    ----------
    workers : int
        Number of worker processes (>= 1).
    initializer, initargs
        Called in each worker after it is set up (see
        :class:`~concurrent.futures.ProcessPoolExecutor`).
    method : {"fork", "spawn"}, optional
        Start method; default :func:`start_method`.

    Yields
    ------
    concurrent.futures.ProcessPoolExecutor

    Notes
    -----
    Every worker ignores SIGINT (a terminal's Ctrl-C is handled by the parent), dies on
    SIGTERM, and dies with the parent (:func:`die_with_parent`, SIGKILL). Leaving the block
    normally waits for the pool; leaving it by an exception (Ctrl-C, :class:`Interrupted`, an
    error) cancels pending tasks and terminates the workers at once (killing them after
    :data:`TERMINATE_GRACE_S`), so a stop never waits for running tasks. Workers are forked
    in ``submit``, with SIGINT and SIGTERM deferred (:func:`stop_signals_deferred`): a stop
    arriving meanwhile is raised when ``submit`` returns, never lost in an after-fork hook.
    """
    method = method or start_method()
    pdeathsig = threading.current_thread() is threading.main_thread()
    with stop_signals_deferred():
        ex = _Pool(max_workers=workers, mp_context=mp.get_context(method),
                   initializer=_pool_worker_init,
                   initargs=(os.getpid(), pdeathsig, initializer, tuple(initargs)))
    try:
        yield ex
    except BaseException:
        _stop_pool(ex)
        raise
    ex.shutdown(wait=True)


def _pool_class():
    from concurrent.futures import ProcessPoolExecutor

    class Pool(ProcessPoolExecutor):
        """Workers are forked (started) in ``submit``: stop signals are deferred meanwhile
        (:func:`stop_signals_deferred`)."""

        def submit(self, fn, /, *args, **kwargs):
            with stop_signals_deferred():
                return super().submit(fn, *args, **kwargs)

    return Pool


def _Pool(**kwargs):
    global _POOL
    if _POOL is None:
        _POOL = _pool_class()
    return _POOL(**kwargs)


_POOL = None


def _stop_pool(ex) -> None:
    """Stop a pool at once and quietly: pending tasks cancelled, workers terminated (the
    executor's own shutdown would wait for the running tasks), its management thread
    ended and forgotten (else ``concurrent.futures`` wakes it at exit through a pipe the
    thread may have closed: ``OSError: [Errno 9] Bad file descriptor``)."""
    procs = list((getattr(ex, "_processes", None) or {}).values())
    manager = getattr(ex, "_executor_manager_thread", None)
    with contextlib.suppress(OSError, ValueError, RuntimeError):
        ex.shutdown(wait=False, cancel_futures=True)
    stop_processes(procs)
    if manager is not None:
        manager.join(TERMINATE_GRACE_S + 5.0)
        if not manager.is_alive():
            with contextlib.suppress(Exception):
                from concurrent.futures import process as cfp

                cfp._threads_wakeups.pop(manager, None)

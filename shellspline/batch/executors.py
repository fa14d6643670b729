"""Executors: where the sequences of a batch run.

* :class:`LocalExecutor` — one forked (or spawned) process per sequence, at most ``workers``
  at a time; spare workers go to the frames inside the sequences.
* :class:`DaskExecutor` — one Dask task per sequence, on a ``LocalCluster`` of worker
  processes or on a running scheduler.

Both have one method, ``run(todo, on_event, outcomes, run_id, force)``: it fills
``outcomes[name]`` with each sequence's outcome record as it arrives and reports
``sequence_start``/``sequence_event``/``sequence_end``/``tick`` events. A stop signal
(:class:`KeyboardInterrupt`, :class:`shellspline.parallel.Interrupted`) stops the workers
before it propagates, so that no worker outlives the run or writes after it.
"""
from __future__ import annotations

import contextlib
import logging
import multiprocessing as mp
import os
import signal
import socket
import threading

from ..errors import ShellsplineError
from .outroot import HELD_LOCKS
from .sequence import run_sequence
from .summary import outcome, reason

__all__ = ["LocalExecutor", "DaskExecutor", "make_executor", "inner_workers", "child_main",
           "dask_task", "import_distributed"]

_STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


def make_executor(name: str, workers: int, scheduler: str | None = None):
    """The executor called ``name`` ("local" or "dask"); checks that Dask is installed."""
    if name == "local":
        return LocalExecutor(workers)
    if name == "dask":
        return DaskExecutor(workers, scheduler)
    raise ShellsplineError(f"executor must be 'local' or 'dask', got {name!r}")


def inner_workers(n_seq: int, workers: int) -> list[int]:
    """Processes inside each of ``n_seq`` sequences: spare workers go to the first ones.

    Examples
    --------
    >>> inner_workers(2, 5)
    [3, 2]
    >>> inner_workers(5, 2)
    [1, 1, 1, 1, 1]
    """
    if n_seq >= workers:
        return [1] * n_seq
    base, extra = divmod(workers, n_seq)
    return [base + (1 if i < extra else 0) for i in range(n_seq)]


# ------------------------------------------------------------------------------------------
# Local processes
# ------------------------------------------------------------------------------------------
def _raise_interrupt(signum, frame):
    raise KeyboardInterrupt


@contextlib.contextmanager
def _stop_signals_blocked():
    """Hold SIGINT/SIGTERM while a worker is started: it inherits the mask and unblocks them
    once its own handlers are set, and the parent has registered it before a pending
    Ctrl-C interrupts the parent."""
    if not hasattr(signal, "pthread_sigmask"):  # pragma: no cover - not POSIX
        yield
        return
    old = signal.pthread_sigmask(signal.SIG_BLOCK, _STOP_SIGNALS)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)


def child_main(conn, spec, key, n_inner, run_id, force, parent_pid, pdeathsig):
    """Entry point of a local worker process: run one sequence, send events and the outcome.

    Ctrl-C is the parent's business (a terminal sends SIGINT to every process of the job):
    the worker ignores SIGINT and unwinds on the parent's SIGTERM, removing its staging
    directory. It receives SIGTERM too when the parent dies, whatever killed it
    (:func:`shellspline.parallel.die_with_parent`), and closes its copy of the inherited
    lock file, so an orphan neither keeps the output root locked nor publishes a sequence.
    """
    from ..parallel import die_with_parent

    for fh in list(HELD_LOCKS):  # forked: the parent's lock stays the parent's
        fh.close()
    HELD_LOCKS.clear()
    signal.signal(signal.SIGTERM, _raise_interrupt)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    die_with_parent(parent_pid, signal.SIGTERM, pdeathsig)
    if hasattr(signal, "pthread_sigmask"):
        signal.pthread_sigmask(signal.SIG_UNBLOCK, _STOP_SIGNALS)
    try:
        from threadpoolctl import threadpool_limits

        # the process pool is the parallelism: BLAS threads on top only oversubscribe
        threadpool_limits(limits=max(1, n_inner))
    except ImportError:  # pragma: no cover - a required dependency
        pass
    try:
        result = run_sequence(spec, key, n_inner,
                              emit=lambda ev: conn.send(("event", spec.name, ev)),
                              run_id=run_id, force=force)
        conn.send(("result", spec.name, result))
    except KeyboardInterrupt:
        os._exit(130)
    finally:
        conn.close()


def _drain(conn, on_event, outcomes) -> bool:
    """Read every message waiting on a worker's pipe; True once the pipe is closed."""
    try:
        while conn.poll():
            kind, name, payload = conn.recv()
            if kind == "event":
                on_event({"kind": "sequence_event", "name": name, "event": payload})
            else:
                outcomes[name] = payload
                on_event({"kind": "sequence_end", "name": name, "outcome": payload})
    except (EOFError, OSError):
        return True
    return False


class LocalExecutor:
    """One process per sequence (:func:`child_main`), at most ``workers`` at a time.

    Parameters
    ----------
    workers : int
        Processes in all; with fewer sequences than workers the spare ones reconstruct frames
        inside the sequences (:func:`inner_workers`).
    """

    name = "local"

    def __init__(self, workers: int):
        self.workers = int(workers)

    def run(self, todo, on_event, outcomes, run_id: str, force: bool) -> None:
        """Run ``todo`` (a list of ``(SequenceSpec, key)``); see the module docstring."""
        from multiprocessing.connection import wait

        from ..parallel import start_method, stop_processes

        self._ctx = mp.get_context(start_method())
        # the Linux parent-death signal follows the forking thread: armed only from the main one
        self._ids = (os.getpid(), threading.current_thread() is threading.main_thread())
        queue = list(zip(todo, inner_workers(len(todo), self.workers)))
        queue.reverse()
        running = {}  # conn -> (proc, spec)
        slots = min(self.workers, len(todo))
        try:
            while queue or running:
                while queue and len(running) < slots:
                    self._start(queue.pop(), running, on_event, run_id, force)
                ready = set(wait(list(running) + [r[0].sentinel for r in running.values()],
                                 timeout=1.0))
                for conn in list(running):
                    proc = running[conn][0]
                    if conn in ready or proc.sentinel in ready:
                        self._reap(conn, running, on_event, outcomes)
                on_event({"kind": "tick"})
        except KeyboardInterrupt:
            # SIGTERM: a child unwinds and removes its staging directory; one still busy after
            # the grace time is killed (run_batch then removes what it left)
            stop_processes([proc for proc, spec in running.values()])
            raise

    def _start(self, item, running, on_event, run_id, force) -> None:
        (spec, key), n_inner = item
        parent_conn, child_conn = self._ctx.Pipe(duplex=False)
        proc = self._ctx.Process(target=child_main, args=(child_conn, spec, key, n_inner,
                                                           run_id, force, *self._ids),
                                 name=f"shellspline-batch-{spec.name}")
        with _stop_signals_blocked():
            proc.start()
            running[parent_conn] = (proc, spec)
        child_conn.close()
        on_event({"kind": "sequence_start", "name": spec.name})

    @staticmethod
    def _reap(conn, running, on_event, outcomes) -> None:
        """Read a worker's messages; once it has exited, record its outcome."""
        proc, spec = running[conn]
        eof = _drain(conn, on_event, outcomes)
        if not eof and proc.is_alive():
            return
        proc.join()
        _drain(conn, on_event, outcomes)  # anything sent just before the exit
        conn.close()
        del running[conn]
        if spec.name not in outcomes:  # the process died without an outcome
            code = proc.exitcode
            why = (f"worker process killed by signal {-code}" if code and code < 0
                   else f"worker process exited with code {code} without a result")
            o = outcome(spec, "failed", why, worker=f"{socket.gethostname()}:{proc.pid}")
            outcomes[spec.name] = o
            on_event({"kind": "sequence_end", "name": spec.name, "outcome": o})


# ------------------------------------------------------------------------------------------
# Dask
# ------------------------------------------------------------------------------------------
def import_distributed():
    """``dask.distributed``, or a one-line error naming the extra to install."""
    try:
        import distributed
    except ImportError:
        raise ShellsplineError('the Dask executor needs dask.distributed: pip install '
                               '"shellspline[dask]"') from None
    return distributed


def dask_task(spec, key: str | None, run_id: str, force: bool) -> dict:
    """A Dask task: one whole sequence (the task reads or generates its own inputs)."""
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=1):
        return run_sequence(spec, key, 1, emit=None, run_id=run_id, force=force)


class DaskExecutor:
    """One Dask task per sequence.

    Parameters
    ----------
    workers : int
        Worker processes of the ``LocalCluster`` started when no scheduler is given.
    scheduler : str or None
        Address of a running scheduler (``tcp://HOST:PORT``).

    Raises
    ------
    ShellsplineError
        When dask.distributed is not installed.
    """

    name = "dask"

    def __init__(self, workers: int, scheduler: str | None = None):
        self.workers, self.scheduler = int(workers), scheduler
        self._distributed = import_distributed()

    def _connect(self):
        """(client, cluster or None)."""
        distributed = self._distributed
        if self.scheduler is not None:
            try:
                return distributed.Client(self.scheduler, timeout="10s"), None
            except (OSError, TimeoutError) as exc:
                raise ShellsplineError(f"cannot connect to the Dask scheduler at "
                                       f"{self.scheduler}: {reason(exc)}") from None
        cluster = distributed.LocalCluster(n_workers=self.workers, threads_per_worker=1,
                                           processes=True, host="127.0.0.1",
                                           dashboard_address=None)
        try:
            return distributed.Client(cluster), cluster
        except BaseException:
            cluster.close()
            raise

    def run(self, todo, on_event, outcomes, run_id: str, force: bool) -> None:
        """Run ``todo`` (a list of ``(SequenceSpec, key)``); see the module docstring."""
        client, cluster = self._connect()
        self._log_level = logging.getLogger("distributed").level
        futures = {}
        try:
            for spec, key in todo:
                fut = client.submit(dask_task, spec, key, run_id, force,
                                    key=f"shellspline-{spec.name}-{run_id}", pure=False)
                futures[fut] = spec
                on_event({"kind": "sequence_start", "name": spec.name})
            for fut in self._distributed.as_completed(list(futures)):
                spec = futures[fut]
                try:
                    o = fut.result()
                except Exception as exc:  # KilledWorker after repeated worker deaths, ...
                    o = outcome(spec, "failed", reason(exc), worker="dask")
                outcomes[spec.name] = o
                on_event({"kind": "sequence_end", "name": spec.name, "outcome": o})
        except KeyboardInterrupt:
            self._stop(client, cluster, futures)
            raise
        finally:
            client.close()
            if cluster is not None:
                cluster.close()
            logging.getLogger("distributed").setLevel(self._log_level)

    @staticmethod
    def _stop(client, cluster, futures) -> None:
        """A stop signal: cancel the tasks and, on our own ``LocalCluster``, kill its worker
        processes at once (:func:`_kill_local_workers`). Tasks already running on the
        workers of a remote scheduler finish there (Dask cannot interrupt a running task;
        their outputs appear complete or not at all)."""
        if cluster is None:
            client.cancel(list(futures))
            return
        # the nannies would report the deaths, the workers a cancellation: not news
        logging.getLogger("distributed").setLevel(logging.CRITICAL)
        _kill_local_workers(cluster)


def _kill_local_workers(cluster, wait: float = 1.5) -> None:
    """Close the nannies of a ``LocalCluster`` and SIGKILL their worker processes.

    A graceful close waits about 4 s for busy workers, and a worker killed under a running
    nanny is restarted (a fresh process that the cluster's close then waits for). So, on the
    cluster's event loop, each nanny's close is started first (from then on it restarts
    nothing), its worker is killed before it acts on the close, and the closes are awaited
    (at most ``wait`` seconds). :func:`~shellspline.run_batch` removes the staging
    directories the workers leave.
    """
    import asyncio

    kill = getattr(signal, "SIGKILL", signal.SIGTERM)
    nannies = list(cluster.workers.values())
    pids = [getattr(n, "pid", None) for n in nannies]

    def kill_all():
        for pid in pids:
            if pid:
                with contextlib.suppress(OSError):
                    os.kill(pid, kill)

    async def close_and_kill():
        closing = [asyncio.ensure_future(n.close(timeout=wait, reason="shellspline-stop"))
                   for n in nannies]
        await asyncio.sleep(0)  # every close has begun: the nannies restart nothing
        kill_all()
        await asyncio.gather(*closing, return_exceptions=True)

    try:
        done = asyncio.run_coroutine_threadsafe(close_and_kill(), cluster.loop.asyncio_loop)
        done.result(timeout=wait + 0.5)
    except Exception:  # pragma: no cover - a slow close or another Dask layout: make sure
        kill_all()     # the workers are dead; the cluster's own close follows

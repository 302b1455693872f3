"""Where the tasks of a sweep run: local processes or a Dask cluster.

Every executor has one job: take an iterable of ``(key, args)`` tasks and a
picklable, importable function, keep a bounded number of them in flight, and
yield ``(key, result)`` as each finishes.  Workers only compute; the caller
(the parent process) does all the writing, so the results do not depend on
the executor, the number of workers or the order in which tasks finish.

* :class:`InlineExecutor`: this process, one task after another (``--jobs 1``).
* :class:`LocalExecutor`: a :class:`concurrent.futures.ProcessPoolExecutor`
  of ``jobs`` processes (the default).
* :class:`DaskExecutor`: an existing ``dask.distributed`` scheduler
  (``--scheduler tcp://HOST:PORT``) or a ``LocalCluster`` it starts
  (``--dask-local N``).  Needs the ``distributed`` package
  (``pip install 'dkfsim[cluster]'``), imported only when asked for.

Executors are context managers; leaving the ``with`` block early (an error,
Ctrl-C) cancels what has not started and stops the local workers.
"""

from __future__ import annotations

import logging
import os
import signal
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from typing import Any

from dkfsim.core.errors import DkfsimError
from dkfsim.core.extras import optional
from dkfsim.core.threads import call_single_threaded, pin_process

Task = tuple[Any, tuple]


def available_cpus() -> int:
    """CPUs this process may run on (the default of ``--jobs``)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


class Executor:
    """Base class: ``imap_unordered(fn, tasks)`` yields ``(key, fn(*args))``."""

    #: Short description for messages ("4 local processes", "Dask at tcp://...").
    label = "executor"
    #: Number of workers (sets how many tasks are kept in flight).
    workers = 1

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False

    def close(self) -> None:
        pass

    def imap_unordered(self, fn: Callable, tasks: Iterable[Task]) -> Iterator[tuple[Any, Any]]:
        raise NotImplementedError

    def in_flight(self) -> int:
        """How many tasks to keep submitted: enough to keep every worker busy
        without queueing the whole sweep (cheap to cancel on Ctrl-C)."""
        return 2 * self.workers


class InlineExecutor(Executor):
    """Run every task in this process, in order."""

    label = "this process"
    workers = 1

    def imap_unordered(self, fn, tasks):
        for key, args in tasks:
            yield key, fn(*args)


# =========================================================================== local processes
def _watch_parent(parent_pid: int) -> None:
    """Exit when the parent disappears (``kill -9`` of the sweep must not leave
    orphaned workers computing for nobody)."""
    while True:
        time.sleep(0.5)
        if os.getppid() != parent_pid:
            os._exit(1)


def _init_local_worker(parent_pid: int) -> None:
    pin_process()                     # one BLAS thread: the parallelism is the processes
    # Ctrl-C reaches the whole process group; only the parent handles it.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    threading.Thread(target=_watch_parent, args=(parent_pid,), daemon=True).start()


class LocalExecutor(Executor):
    """``jobs`` worker processes on this machine."""

    def __init__(self, jobs: int):
        if isinstance(jobs, bool) or not isinstance(jobs, int) or jobs < 1:
            raise DkfsimError(f"--jobs: must be an integer >= 1, got {jobs!r}")
        self.workers = jobs
        self.label = f"{jobs} local process{'es' if jobs != 1 else ''}"
        self._pool: ProcessPoolExecutor | None = None

    def _start(self) -> ProcessPoolExecutor:
        if self._pool is None:
            self._pool = ProcessPoolExecutor(max_workers=self.workers,
                                             initializer=_init_local_worker,
                                             initargs=(os.getpid(),))
        return self._pool

    def imap_unordered(self, fn, tasks):
        pool = self._start()
        todo = iter(tasks)
        active: dict = {}
        limit = self.in_flight()
        try:
            while True:
                while len(active) < limit:
                    item = next(todo, None)
                    if item is None:
                        break
                    key, args = item
                    active[pool.submit(fn, *args)] = key
                if not active:
                    return
                finished, _ = wait(list(active), return_when=FIRST_COMPLETED)
                for fut in finished:
                    key = active.pop(fut)
                    yield key, fut.result()
        except BrokenProcessPool:
            raise DkfsimError("a worker process died unexpectedly (out of memory, or killed); "
                              "every task finished before that is saved: re-run the same "
                              "command to resume") from None

    def close(self) -> None:
        pool, self._pool = self._pool, None
        if pool is None:
            return
        kill_pool(pool)


def kill_pool(pool) -> None:
    """Stop a process pool now: cancel what has not started, terminate the workers.

    Tasks already running are abandoned, not awaited: their results would be
    thrown away anyway (the caller has stopped listening).
    """
    procs = list((getattr(pool, "_processes", None) or {}).values())
    pool.shutdown(wait=False, cancel_futures=True)
    for p in procs:
        if p.is_alive():
            p.terminate()
    for p in procs:
        p.join(timeout=5)


def local(jobs: int | None = None) -> Executor:
    """``jobs`` local processes (default: every available CPU); 1 means this process."""
    jobs = available_cpus() if jobs is None else jobs
    if isinstance(jobs, bool) or not isinstance(jobs, int) or jobs < 1:
        raise DkfsimError(f"--jobs: must be an integer >= 1, got {jobs!r}")
    return InlineExecutor() if jobs == 1 else LocalExecutor(jobs)


# =========================================================================== Dask
def _distributed():
    return optional("distributed")


class DaskExecutor(Executor):
    """Tasks on a Dask cluster: an existing scheduler (``address``) or a new
    ``LocalCluster`` of ``n_workers`` single-threaded workers.

    ``processes=False`` runs the LocalCluster's workers as threads of this
    process (quick to start, for tests; the GIL serialises the work).  Remote
    workers must have the same dkfsim installed (they import it by name).
    """

    def __init__(self, address: str | None = None, n_workers: int | None = None, *,
                 processes: bool = True, timeout: float = 10.0):
        if (address is None) == (n_workers is None):
            raise ValueError("give exactly one of address and n_workers")
        distributed = _distributed()
        self._cluster = None
        self._futures: dict = {}
        if address is not None:
            if not isinstance(address, str) or "://" not in address:
                raise DkfsimError(f"--scheduler: expected an address like tcp://HOST:PORT, "
                                  f"got {address!r}")
            try:
                self._client = distributed.Client(address, timeout=timeout)
            except (OSError, TimeoutError) as exc:
                raise DkfsimError(f"--scheduler {address}: cannot connect to a Dask scheduler "
                                  f"there ({exc})") from None
            nthreads = self._client.nthreads()
            self.workers = max(1, sum(nthreads.values()))
            self.label = f"Dask scheduler {address} ({len(nthreads)} workers, {self.workers} threads)"
        else:
            if isinstance(n_workers, bool) or not isinstance(n_workers, int) or n_workers < 1:
                raise DkfsimError(f"--dask-local: must be an integer >= 1, got {n_workers!r}")
            self._cluster = distributed.LocalCluster(
                n_workers=n_workers, threads_per_worker=1, processes=processes,
                dashboard_address=None, silence_logs=logging.ERROR)
            self._client = distributed.Client(self._cluster)
            self.workers = n_workers
            kind = "processes" if processes else "threads"
            self.label = f"Dask LocalCluster ({n_workers} worker {kind})"

    def imap_unordered(self, fn, tasks):
        distributed = _distributed()
        client = self._client
        todo = iter(tasks)
        keys = self._futures

        def submit_one() -> Any | None:
            item = next(todo, None)
            if item is None:
                return None
            key, args = item
            fut = client.submit(call_single_threaded, fn, *args, pure=False)
            keys[fut] = key
            return fut

        first = [f for f in (submit_one() for _ in range(self.in_flight())) if f is not None]
        if not first:
            return
        ac = distributed.as_completed(first, with_results=True)
        for fut, result in ac:
            key = keys.pop(fut)
            nxt = submit_one()
            if nxt is not None:
                ac.add(nxt)
            yield key, result

    def close(self) -> None:
        if self._futures:
            try:
                self._client.cancel(list(self._futures))
            except Exception:  # noqa: BLE001  (closing anyway)
                pass
            self._futures.clear()
        self._client.close()
        if self._cluster is not None:
            self._cluster.close()


def make_executor(*, jobs: int | None = None, scheduler: str | None = None,
                  dask_local: int | None = None, dask_processes: bool = True) -> Executor:
    """The executor the command-line flags ask for (at most one of
    ``scheduler`` and ``dask_local``; ``jobs`` applies to local processes only)."""
    if scheduler is not None and dask_local is not None:
        raise DkfsimError("--scheduler and --dask-local: give at most one of them")
    if (scheduler is not None or dask_local is not None) and jobs is not None:
        raise DkfsimError("--jobs applies to local processes only; with --scheduler or "
                          "--dask-local the cluster's workers set the parallelism")
    if scheduler is not None:
        return DaskExecutor(address=scheduler)
    if dask_local is not None:
        return DaskExecutor(n_workers=dask_local, processes=dask_processes)
    return local(jobs)

"""Where the runs of ``montecarlo``, ``sweep`` and ``maxdelay`` happen: this process,
local processes or a Dask cluster -- one executor for the three commands.

Every executor has one job: take an iterable of ``(key, args)`` tasks and a
picklable, importable function, keep a bounded number of them in flight, and
yield ``(key, result)`` as each finishes, exactly once per task.  Workers only
compute; the caller (the parent process) assembles or writes the results by
key, so they do not depend on the executor, the number of workers or the order
in which tasks finish.  :func:`in_order` gives them back in task order (and a
task's error at its place in that order), :meth:`Executor.map` as a list.

* :class:`InlineExecutor`: this process, one task after another (``--jobs 1``).
* :class:`LocalExecutor`: a :class:`concurrent.futures.ProcessPoolExecutor`
  of ``jobs`` processes (the default: every CPU this process may use).  A
  worker that dies (killed, out of memory) breaks the pool: the tasks that
  were in flight are run again on a new pool, each at most
  :data:`MAX_RETRIES` times, then reported; results already back are kept.
* :class:`DaskExecutor`: an existing ``dask.distributed`` scheduler
  (``--scheduler tcp://HOST:PORT``) or a ``LocalCluster`` it starts
  (``--dask-local N``).  Needs the ``distributed`` package
  (``pip install 'dkfsim[cluster]'``), imported only when asked for.  Dask
  re-runs the task of a lost worker itself (``allowed-failures``) and reports
  it as killed after that.

Executors are context managers; leaving the ``with`` block early (an error,
Ctrl-C) cancels what has not started and stops the local workers.
docs/design.md (Experiments) and docs/decisions.md say why.
"""

from __future__ import annotations

import contextlib
import logging
import os
import signal
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from typing import Any

from dkfsim.core.errors import DkfsimError
from dkfsim.core.extras import optional
from dkfsim.core.threads import call_single_threaded, pin_process

Task = tuple[Any, tuple]

#: How many times a task whose worker process died is run again before it is reported.
MAX_RETRIES = 2


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

    def map(self, fn: Callable, arglist: Iterable[tuple], on_done: Callable | None = None) -> list:
        """``[fn(*args) for args in arglist]``, computed on this executor; ``on_done()``
        after each task finishes (in any order)."""
        return [r for _, r in in_order(self, fn, enumerate(arglist), on_done)]

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
    # Ctrl-C reaches the whole process group: it ends a worker at once, as SIGTERM does (the
    # parent, interrupted too, stops the pool and reports; the CLI turns SIGTERM into an
    # interruption, docs/decisions.md #108).  A worker that ignored SIGINT computed on for
    # nobody while its parent was busy or gone (issue 34 §3, decision 261); one whose parent
    # disappears exits within half a second (:func:`_watch_parent`).
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    threading.Thread(target=_watch_parent, args=(parent_pid,), daemon=True).start()
    pin_process()                     # one BLAS thread: the parallelism is the processes


class LocalExecutor(Executor):
    """``jobs`` worker processes on this machine."""

    def __init__(self, jobs: int):
        check_jobs(jobs, every_cpu=False)
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
        todo = iter(tasks)
        retry: deque = deque()             # (key, args) of tasks whose worker died
        crashes: dict = {}                 # key -> how many times its worker died
        active: dict = {}                  # future -> (key, args)
        limit = self.in_flight()
        while True:
            pool = self._start()
            broken: list = []              # tasks in flight when a worker died
            dead = False
            while len(active) < limit:
                item = retry.popleft() if retry else next(todo, None)
                if item is None:
                    break
                try:
                    active[pool.submit(fn, *item[1])] = item
                except BrokenProcessPool:  # the pool broke before this one was sent
                    retry.appendleft(item)
                    dead = True
                    break
            if not active and not dead:
                return
            finished, _ = wait(list(active), return_when=FIRST_COMPLETED)
            if dead or any(isinstance(f.exception(), BrokenProcessPool) for f in finished):
                # A worker died and the pool with it: every task still in flight lost its
                # result (those back already keep theirs); they run again, on a new pool.
                finished = list(active)
                wait(finished)
            for fut in finished:
                item = active.pop(fut)
                if isinstance(fut.exception(), BrokenProcessPool):
                    broken.append(item)
                else:
                    yield item[0], fut.result()
            if broken or dead:
                self.close()
                for key, _args in broken:
                    crashes[key] = crashes.get(key, 0) + 1
                    if crashes[key] > MAX_RETRIES:
                        raise DkfsimError(
                            f"a worker process died {crashes[key]} times while running "
                            f"{describe(key)} (out of memory, or killed); the tasks finished "
                            "before are kept (a sweep: re-run the same command to resume)")
                retry.extendleft(reversed(broken))

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
    manager = getattr(pool, "_executor_manager_thread", None)
    writer = getattr(getattr(pool, "_result_queue", None), "_writer", None)   # (shutdown forgets it)
    pool.shutdown(wait=False, cancel_futures=True)
    for p in procs:
        if p.is_alive():
            p.terminate()
    for p in procs:
        p.join(timeout=5)
    # A worker stopped while it was sending a result leaves half a message in the result pipe,
    # and the manager thread blocks for ever reading the rest: this process still holds a
    # writing end, so the reader never sees the pipe end. The interpreter joins that thread at
    # exit, so an interrupted command hung instead of ending (1 in 10 under load). With the
    # workers gone, closing that end makes the read fail and the manager treat the pool as
    # broken and stop. (Nothing else could still write there.)
    if writer is not None and not any(p.is_alive() for p in procs):
        with contextlib.suppress(OSError):
            writer.close()
    # The pool's manager thread notices its dead workers and closes its wake-up pipe; until it
    # has, an interpreter exiting now may write to that pipe as it closes ("Bad file descriptor",
    # printed at the exit of an interrupted command): wait for it.
    if manager is not None:
        manager.join(timeout=5)


def local(jobs: int | None = None, tasks: int | None = None) -> Executor:
    """``jobs`` local processes (default: every available CPU), at most ``tasks`` of
    them when that is known; 1 means this process."""
    check_jobs(jobs)
    jobs = available_cpus() if jobs is None else jobs
    if tasks is not None:
        jobs = max(1, min(jobs, tasks))
    return InlineExecutor() if jobs == 1 else LocalExecutor(jobs)


def check_jobs(jobs, *, every_cpu: bool = True) -> None:
    """``--jobs``: an integer >= 1, or None (every CPU) where ``every_cpu``."""
    if (jobs is None and not every_cpu) or (
            jobs is not None and (isinstance(jobs, bool) or not isinstance(jobs, int) or jobs < 1)):
        raise DkfsimError(f"--jobs: must be an integer >= 1, got {jobs!r}")


# =========================================================================== task order
def describe(key) -> str:
    """A task's key for messages (a string key is its own description)."""
    if isinstance(key, _Numbered):
        key = key[1]
    return key if isinstance(key, str) else f"task {key!r}"


class _Numbered(tuple):
    """``(position in task order, key)``: what :func:`in_order` submits."""


class _Raised:
    """A task's exception, carried back as a result so that it is raised in task order."""

    def __init__(self, exc: BaseException):
        self.exc = exc


def _capture(fn, *args):
    try:
        return fn(*args)
    except Exception as exc:  # noqa: BLE001  (re-raised by in_order, at its place)
        return _Raised(exc)


def in_order(executor: Executor, fn: Callable, tasks: Iterable[Task],
             on_done: Callable | None = None) -> Iterator[tuple[Any, Any]]:
    """``(key, fn(*args))`` in the order of ``tasks``, computed on ``executor``.

    A result that finishes early waits (at most about :meth:`Executor.in_flight` of
    them) until every earlier one is given back; a task that raised re-raises its
    exception at its place, so the first failing task in task order is the one
    reported, whatever the executor.  ``on_done()`` is called as each task finishes.
    """
    keys: list = []

    def numbered():
        for key, args in tasks:
            keys.append(key)
            yield _Numbered((len(keys) - 1, key)), (fn, *args)

    pending: dict[int, Any] = {}
    nxt = 0
    for slot, result in executor.imap_unordered(_capture, numbered()):
        if on_done is not None:
            on_done()
        pending[slot[0]] = result
        while nxt in pending:
            got = pending.pop(nxt)
            if isinstance(got, _Raised):
                raise got.exc
            yield keys[nxt], got
            nxt += 1
    if nxt != len(keys):             # an executor must give back every task it was given
        raise RuntimeError(f"{executor.label}: {len(keys) - nxt} of {len(keys)} tasks came back "
                           f"with no result (the first: {describe(keys[nxt])})")


# =========================================================================== Dask
def dask_distributed():
    """The ``distributed`` package (Dask), imported; a clear error naming how to install it
    when it is missing (what the CLI checks before any work)."""
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
        distributed = dask_distributed()
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
        distributed = dask_distributed()
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
        try:
            for fut, result in ac:
                key = keys.pop(fut)
                nxt = submit_one()
                if nxt is not None:
                    ac.add(nxt)
                yield key, result
        except distributed.KilledWorker as exc:
            raise DkfsimError(f"Dask: the workers running a task died too often ({exc}); the "
                              "tasks finished before are kept (a sweep: re-run the same "
                              "command to resume)") from None

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
                  dask_local: int | None = None, dask_processes: bool = True,
                  tasks: int | None = None) -> Executor:
    """The executor the command-line flags ask for (at most one of
    ``scheduler`` and ``dask_local``; ``jobs`` applies to local processes only, at
    most ``tasks`` of them)."""
    if scheduler is not None and dask_local is not None:
        raise DkfsimError("--scheduler and --dask-local: give at most one of them")
    if (scheduler is not None or dask_local is not None) and jobs is not None:
        raise DkfsimError("--jobs applies to local processes only; with --scheduler or "
                          "--dask-local the cluster's workers set the parallelism")
    if scheduler is not None:
        return DaskExecutor(address=scheduler)
    if dask_local is not None:
        return DaskExecutor(n_workers=dask_local, processes=dask_processes)
    return local(jobs, tasks)


def executor_for(executor=None, jobs: int | None = None, tasks: int | None = None):
    """``(executor, owned)`` for a library call: ``executor`` given (an
    :class:`Executor`, used and left open; or a callable making one, closed by the
    caller), else ``jobs`` local processes for ``tasks`` tasks."""
    if isinstance(executor, Executor):
        return executor, False
    if executor is not None:
        return executor(), True
    return local(jobs, tasks), True

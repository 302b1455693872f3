"""A test run that Ctrl-C and SIGTERM stop, with every process it started, within seconds.

A pytest plugin (``tests/conftest.py`` imports its hooks; ``-p interrupts`` loads it in a session
of its own, as ``tests/test_interrupts.py`` does).  Without it (issue 34 §3), Ctrl-C during
``make test`` waited for pytest-xdist's workers to wind down (finishing their test, writing their
summary), and SIGTERM to pytest left its workers, and what they had started, running on:

* the controller (the ``pytest`` process, with or without ``-n``): SIGINT and SIGTERM raise
  KeyboardInterrupt, so pytest and xdist stop as they do on Ctrl-C, and arm a deadline: after
  :data:`GRACE_S` seconds every process it started, at any depth, is killed and it exits
  (130 for SIGINT, 143 for SIGTERM);
* each xdist worker: a thread watches its parent; when the controller is gone (killed with
  SIGKILL, or past its deadline) the worker kills every process it started and exits.

dkfsim's own worker pools end with their parent too (:mod:`dkfsim.experiments.executors`);
this plugin covers what a test starts otherwise (``dkfsim`` as a subprocess, its pools).
"""

from __future__ import annotations

import os
import signal
import threading
import time

import psutil

#: Seconds the controller gives pytest and xdist to stop on their own after SIGINT or SIGTERM.
GRACE_S = 2.5
#: How often a worker looks at its parent.
WATCH_S = 0.25


def kill_descendants() -> None:
    """SIGKILL every process this one started, children first found, grandchildren included."""
    try:
        procs = psutil.Process().children(recursive=True)
    except psutil.Error:
        return
    for p in procs:
        try:
            p.kill()
        except psutil.Error:
            pass
    psutil.wait_procs(procs, timeout=2)


class _Deadline:
    """The controller's deadline: armed once, by the first SIGINT or SIGTERM."""

    armed = False


def _deadline(status: int) -> None:
    time.sleep(GRACE_S)
    kill_descendants()
    os._exit(status)


def _on_signal(signum, _frame):
    if not _Deadline.armed:
        _Deadline.armed = True
        threading.Thread(target=_deadline, args=(128 + signum,), daemon=True).start()
    raise KeyboardInterrupt


def _watch_parent(parent: int) -> None:
    while os.getppid() == parent:
        time.sleep(WATCH_S)
    kill_descendants()
    os._exit(1)


def pytest_configure(config) -> None:
    if threading.current_thread() is not threading.main_thread():
        return                                     # (signals belong to the main thread)
    if hasattr(config, "workerinput"):             # an xdist worker
        threading.Thread(target=_watch_parent, args=(os.getppid(),), daemon=True).start()
        return
    for sig in (signal.SIGINT, signal.SIGTERM):
        if signal.getsignal(sig) is not signal.SIG_IGN:   # (a run in the background keeps ignoring)
            signal.signal(sig, _on_signal)

"""What the sub-commands that run scenarios share: loading the scenario with ``--set``,
``--seed`` and ``--steps``, the executor and the number of workers the flags ask for, and the
progress: a tqdm bar on a terminal, elsewhere (a log, a pipe, a batch job) one line about every
:data:`PROGRESS_EVERY_S` seconds (:class:`ProgressLines`)."""

from __future__ import annotations

import os
import sys
import time

from tqdm import tqdm

from dkfsim.config.load import load_scenario
from dkfsim.core.files import printable
from dkfsim.experiments import executors


def load_from_args(args):
    """The scenario of ``args.scenario`` with ``--set``, ``--seed`` and ``--steps`` applied."""
    overrides = list(args.overrides)
    for key in ("seed", "steps"):
        val = getattr(args, key, None)
        if val is not None:
            overrides.append(f"{key}={val}")
    return load_scenario(args.scenario, overrides=overrides)


def executor_from_args(args, tasks: int | None = None):
    """A callable making the executor the flags ask for (called once work is checked), or
    None for the library's default (``--jobs`` local processes).  A missing Dask package
    is reported here, before any work."""
    if args.scheduler is None and args.dask_local is None:
        return None
    executors.dask_distributed()

    def make():
        return executors.make_executor(scheduler=args.scheduler, dask_local=args.dask_local,
                                       tasks=tasks)
    return make


def workers_from_args(args, tasks: int | None = None) -> int:
    """How many runs at once the flags ask for (for the cost estimate)."""
    if args.dask_local is not None:
        return args.dask_local
    if args.scheduler is not None:
        return 1
    n = args.jobs or executors.available_cpus()
    return max(1, min(n, tasks)) if tasks else n


def more_workers_hint(args) -> str:
    """``", or more --jobs"`` (or ``--dask-local`` workers) when the flags can add workers to
    this machine; nothing for a cluster of ``--scheduler`` (its workers are its own)."""
    if args.scheduler is not None:
        return ""
    if args.dask_local is not None:
        return ", or more --dask-local workers"
    return ", or more --jobs" if (args.jobs or executors.available_cpus()) < executors.available_cpus() \
        else ""


#: Seconds between two progress lines when stderr is not a terminal (``DKFSIM_PROGRESS_EVERY``
#: sets another, e.g. 60 for a batch job's log).
PROGRESS_EVERY_S = 10.0


def progress_every() -> float:
    """:data:`PROGRESS_EVERY_S`, or what ``DKFSIM_PROGRESS_EVERY`` says (seconds, > 0)."""
    try:
        value = float(os.environ.get("DKFSIM_PROGRESS_EVERY", PROGRESS_EVERY_S))
    except ValueError:
        return PROGRESS_EVERY_S
    return value if value > 0 else PROGRESS_EVERY_S


def duration(s: float) -> str:
    """``42 s``, ``3m05s``, ``1h02m``."""
    s = max(0.0, s)
    if s < 60:
        return f"{s:.0f} s"
    m, sec = divmod(int(round(s)), 60)
    h, m = divmod(m, 60)
    return f"{h}h{m:02d}m" if h else f"{m}m{sec:02d}s"


class ProgressLines:
    """``progress(done, total)`` that writes one line to stderr about every
    :func:`progress_every` seconds, and one at the end after those: ``dkfsim montecarlo
    paper_case1: 37/100 runs, 1m12s, about 2m03s left``; a command done within the first interval
    writes none.  For stderr that is not a terminal: a log keeps every line."""

    def __init__(self, what: str, unit: str = "runs"):
        self.what, self.unit = printable(what), unit
        self.t0 = self.last = time.monotonic()
        self.every = progress_every()
        self.initial: int | None = None      # done at the first report (a resumed sweep: more than 0)
        self.first = self.t0                 # ... and when
        self.said = False                    # a line was written (then the end gets one too)

    def __call__(self, done: int, total: int) -> None:
        now = time.monotonic()
        if self.initial is None:                 # the rate counts from the first report (after start-up)
            self.initial, self.first = done, now
        if now - self.last < self.every and not (done >= total and self.said):
            return                       # (a command shorter than one interval says nothing)
        self.last, self.said = now, True
        elapsed = now - self.t0
        new, spent = done - self.initial, now - self.first
        left = f", about {duration(spent / new * (total - done))} left" if new > 0 and done < total else ""
        try:
            print(f"{self.what}: {done}/{total} {self.unit}, {duration(elapsed)}{left}", file=sys.stderr,
                  flush=True)
        except (OSError, ValueError):
            pass


def progress_bar(args, total: int | None, desc: str, unit: str = "run"):
    """The progress bar of a command: tqdm on stderr counting ``unit``, when stderr is a
    terminal and ``--quiet`` is not given; else None."""
    if args.quiet or not sys.stderr.isatty():
        return None
    return tqdm(total=total, unit=unit, desc=printable(desc), leave=False, file=sys.stderr,
                dynamic_ncols=True)


def progress_of(args, total: int, what: str, unit: str = "run"):
    """``(progress(done, total), close)`` of a command: the tqdm bar on a terminal, one line
    about every 10 s elsewhere (:class:`ProgressLines`), nothing with ``--quiet``."""
    bar = progress_bar(args, total, what, unit)
    if bar is not None:
        return (lambda done, _total: bar.update(done - bar.n)), bar.close
    if args.quiet:
        return None, (lambda: None)
    return ProgressLines(f"dkfsim {what}", unit + "s"), (lambda: None)

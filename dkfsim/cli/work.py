"""What the sub-commands that run scenarios share: loading the scenario with ``--set``,
``--seed`` and ``--steps``, the executor and the number of workers the flags ask for, and the
progress bar (a tqdm bar on a terminal)."""

from __future__ import annotations

import sys

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


def progress_bar(args, total: int | None, desc: str, unit: str = "run"):
    """The progress bar of a command: tqdm on stderr counting ``unit``, when stderr is a
    terminal and ``--quiet`` is not given; else None."""
    if args.quiet or not sys.stderr.isatty():
        return None
    return tqdm(total=total, unit=unit, desc=printable(desc), leave=False, file=sys.stderr,
                dynamic_ncols=True)

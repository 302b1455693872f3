"""What every sub-command shares: the scenario arguments, ``--yes``, loading, and where
runs happen (``--jobs``, ``--scheduler``, ``--dask-local``), ``--quiet`` and the progress bar
(one meaning for ``montecarlo``, ``sweep`` and ``maxdelay``: docs/decisions.md)."""

from __future__ import annotations

import argparse
import sys

from tqdm import tqdm

from dkfsim.config.load import load_scenario
from dkfsim.core.errors import DkfsimError
from dkfsim.core.files import printable
from dkfsim.experiments import executors


class OutputError(DkfsimError):
    """Standard output cannot be written (``> /dev/full``, a full disk): the command's files are
    written, but what it would print is lost."""


def say(text, file=None, **kw) -> None:
    """Print a line (or a multi-line table) for the user, every control character but the
    newline and tab escaped: names read from files never reach a terminal raw (a
    scenario named ``"\\e]0;PWNED\\a"`` would retitle it)."""
    stream = sys.stdout if file is None else file
    try:
        print(printable(text, keep="\n\t"), file=stream, **kw)
    except BrokenPipeError:
        raise
    except OSError as exc:
        raise OutputError(f"cannot write to standard {'error' if stream is sys.stderr else 'output'} "
                          f"({exc.strerror or exc})") from None


def add_scenario_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("scenario", metavar="FILE", help="scenario YAML file (see docs/scenarios.md)")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="override a scenario key by its dotted path, value parsed as YAML; "
                        "repeatable (e.g. --set links.default.latency.d_t=2 --set protocol=flood)")


def add_yes_arg(p: argparse.ArgumentParser) -> None:
    p.add_argument("--yes", action="store_true",
                   help="run even when the estimated time is above 10 minutes (the estimate is "
                        "printed and the command stops without it); work that cannot fit in memory "
                        "is refused either way")


def load_from_args(args):
    """The scenario of ``args.scenario`` with ``--set``, ``--seed`` and ``--steps`` applied."""
    overrides = list(args.overrides)
    for key in ("seed", "steps"):
        val = getattr(args, key, None)
        if val is not None:
            overrides.append(f"{key}={val}")
    return load_scenario(args.scenario, overrides=overrides)


def add_executor_args(p: argparse.ArgumentParser) -> None:
    """``--jobs`` / ``--scheduler`` / ``--dask-local`` (one of them) and ``--quiet``."""
    where = p.add_mutually_exclusive_group()
    where.add_argument("--jobs", type=int, metavar="J",
                       help="worker processes on this machine (1 = this process; default: every "
                            "CPU this process may use, at most one per run); results do not "
                            "depend on it")
    where.add_argument("--scheduler", metavar="tcp://HOST:PORT",
                       help="run on an existing Dask distributed cluster (its workers need the "
                            "same dkfsim installed); needs dkfsim[cluster]")
    where.add_argument("--dask-local", type=int, metavar="N",
                       help="start a Dask LocalCluster of N single-threaded worker processes on "
                            "this machine; needs dkfsim[cluster]")
    p.add_argument("--quiet", action="store_true",
                   help="no progress bar and nothing on stdout (errors are still reported); the "
                        "bar is drawn on stderr only when it is a terminal")


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


def progress_bar(args, total: int | None, desc: str, unit: str = "run"):
    """The progress bar of a command: tqdm on stderr counting ``unit``, when stderr is a
    terminal and ``--quiet`` is not given; else None."""
    if args.quiet or not sys.stderr.isatty():
        return None
    return tqdm(total=total, unit=unit, desc=printable(desc), leave=False, file=sys.stderr,
                dynamic_ncols=True)

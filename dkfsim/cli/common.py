"""What every sub-command shares and ``dkfsim --help`` may import: printing, the scenario
arguments, ``--yes``, and the flags of where runs happen (``--jobs``, ``--scheduler``,
``--dask-local``) and ``--quiet`` (one meaning for ``montecarlo``, ``sweep`` and ``maxdelay``:
docs/decisions.md).  Nothing here imports a stage above ``core``: loading a scenario, the
executors and the progress bar are :mod:`dkfsim.cli.work`."""

from __future__ import annotations

import argparse
import sys

from dkfsim.core.errors import DkfsimError
from dkfsim.core.files import printable


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

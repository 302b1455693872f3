"""The ``dkfsim`` command line: one module per sub-command, argparse only here.

Every sub-command validates its input first; a :class:`~dkfsim.core.errors.DkfsimError`
(bad scenario, bad flag, unwritable folder, too much work) becomes a
one-paragraph message on stderr and exit status 2, never a traceback.

Only the module of the sub-command being run is imported (:data:`COMMANDS`): ``dkfsim
--help`` imports none of them, ``dkfsim list`` only the registries, so a command pays for
the stages it uses and no more (docs/decisions.md, "Start-up").
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import os
import signal
import sys
import warnings

from dkfsim.cli.common import OutputError
from dkfsim.core.errors import DkfsimError
from dkfsim.core.files import printable, shown
from dkfsim.core.threads import pin_process
from dkfsim.core.version import __version__

EPILOG = """\
examples:
  dkfsim run scenarios/paper_case1.yaml --out out/case1
  dkfsim run scenarios/paper_case1.yaml --out out/d0 --set links.default.latency.d_t=0 --steps 500
  dkfsim validate scenarios/paper_case2.yaml
  dkfsim list estimators
"""

#: The sub-commands in help order: name -> (module of ``dkfsim.cli`` whose ``configure(parser)``
#: adds its arguments and ``func``, its line in ``dkfsim --help``).
COMMANDS = {
    "run": ("run", "simulate one scenario and write summary.json, rows.csv and run.npz"),
    "validate": ("validate", "check a scenario file without running it"),
    "list": ("list", "list the registered components: estimators, latency models, ..."),
    "montecarlo": ("montecarlo", "N independent runs of a scenario: MSE with confidence intervals, "
                                 "ANEES, traffic"),
    "plot": ("plot", "draw figures from run or Monte Carlo folders, or a sweep"),
    "report": ("report", "write one self-contained HTML page for a run, Monte Carlo or sweep"),
    "sweep": ("sweep", "parameter sweep x Monte Carlo runs into a resumable SQLite file"),
    "maxdelay": ("maxdelay", "largest delay bound (or, --axis rate, least link rate) for which a metric "
                             "stays within a tolerance (Monte Carlo, worst case, paper bound)"),
}


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The ``dkfsim`` parser: every sub-command's arguments, or (``command`` given: what
    :func:`main` builds) only that one's, the others a line of help each (not imported)."""
    parser = argparse.ArgumentParser(
        prog="dkfsim",
        description="Discrete-event simulator of the anti-delay distributed Kalman filter "
                    "(buffer + finite-time exchange + optimal matrix-weighted fusion) over networks "
                    "with time-varying latency.",
        epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--version", action="version", version=f"dkfsim {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, (module, line) in COMMANDS.items():
        p = sub.add_parser(name, help=line)
        if command is None or command == name:
            importlib.import_module(f"dkfsim.cli.{module}").configure(p)
    return parser


def command_of(argv: list[str]) -> str:
    """The sub-command ``argv`` names (its first word that is not an option), or ``""``."""
    return next((a for a in argv if not a.startswith("-")), "")


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised where the process is, so that it ends as Ctrl-C does: output being
    staged is removed, a sweep keeps the tasks it saved (docs/decisions.md #108)."""


def _on_sigterm(_signum, _frame):
    raise Terminated


def _usable_streams() -> None:
    """stdout and stderr that never make a command fail after its work is done: a closed one
    (``>&-``: Python sets it to None) writes to /dev/null, and text an ASCII-only stream cannot
    encode (``PYTHONIOENCODING=ascii``, a C locale) is written as backslash escapes."""
    for name in ("stdout", "stderr"):
        stream = getattr(sys, name)
        if stream is None:
            setattr(sys, name, open(os.devnull, "w", encoding="utf-8"))
        else:
            with contextlib.suppress(AttributeError, ValueError, OSError):
                stream.reconfigure(errors="backslashreplace")


def _escaped_warnings() -> None:
    """Warnings (a third-party one too: matplotlib's "Glyph 27 missing from font") are shown
    through the one escaper, :func:`~dkfsim.core.files.printable`: a name holding ESC or BEL
    that reaches a warning does not reach the terminal raw."""
    shown = warnings.showwarning
    if shown in _ESCAPING:             # (installed once: main may run twice in a process)
        return

    def show(message, category, filename, lineno, file=None, line=None):
        shown(printable(message), category, printable(filename), lineno, file,
              None if line is None else printable(line))
    _ESCAPING.append(show)
    warnings.showwarning = show


#: The warning displays :func:`_escaped_warnings` installed.
_ESCAPING: list = []


def _discard_stdout() -> None:
    """Point stdout at /dev/null (its reader is gone or it cannot take more), so that the
    interpreter's final flush cannot fail after the command ended."""
    with contextlib.suppress(OSError, ValueError):
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())


def _error(text: str) -> None:
    with contextlib.suppress(OSError, ValueError):
        print(printable(text), file=sys.stderr)


def main(argv=None) -> int:
    """Run ``dkfsim ARGV``; the exit status.  SIGTERM ends the command as Ctrl-C does while it
    runs; the handler this process had before is back when it returns (a test or a script that
    calls it in its own process keeps its own)."""
    previous = signal.signal(signal.SIGTERM, _on_sigterm)
    try:
        return _main(argv)
    finally:
        signal.signal(signal.SIGTERM, previous)


def _main(argv) -> int:
    pin_process()                     # one BLAS thread here and in every worker we start
    _usable_streams()
    _escaped_warnings()
    argv = sys.argv[1:] if argv is None else list(argv)
    parser = build_parser(command_of(argv))
    args = parser.parse_args(argv)
    if not getattr(args, "command", None):
        parser.print_help()
        return 2
    try:
        status = args.func(args)
        try:
            sys.stdout.flush()        # a closed pipe or a full device shows here, inside the try
        except BrokenPipeError:
            raise
        except OSError as exc:
            raise OutputError(f"cannot write to standard output ({exc.strerror or exc})") from None
        return status
    except OutputError as exc:
        _discard_stdout()
        _error(f"dkfsim {args.command}: error: {exc}")
        return 2
    except DkfsimError as exc:
        _error(f"dkfsim {args.command}: error: {exc}")
        return 2
    except KeyboardInterrupt as exc:
        if isinstance(exc, Terminated):
            _error("dkfsim: terminated")
            return 143                # 128 + SIGTERM
        _error("dkfsim: interrupted")
        return 130
    except BrokenPipeError:
        # The reader went away (``dkfsim ... | head``): end quietly, as Unix tools do.
        _discard_stdout()
        return 141
    except OSError as exc:
        # The last net for an I/O failure no layer above put into words (the readers and
        # writers do: open_regular, staged, replacing, the sweep database): the file and the
        # OS's reason, never a traceback.
        where = f"{shown(exc.filename)}: " if exc.filename else ""
        _error(f"dkfsim {args.command}: error: {where}{exc.strerror or exc}")
        return 2


if __name__ == "__main__":
    sys.exit(main())

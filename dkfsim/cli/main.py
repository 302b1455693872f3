"""The ``dkfsim`` command line: one module per sub-command, argparse only here.

Every sub-command validates its input first; a :class:`~dkfsim.core.errors.DkfsimError`
(bad scenario, bad flag, unwritable folder, too much work) becomes a
one-paragraph message on stderr and exit status 2, never a traceback.
"""

from __future__ import annotations

import argparse
import os
import sys

from dkfsim.cli import list as list_cmd
from dkfsim.cli import maxdelay, montecarlo, plot, report, run, sweep
from dkfsim.core.errors import DkfsimError
from dkfsim.core.files import printable
from dkfsim.core.threads import pin_process
from dkfsim.core.version import __version__

EPILOG = """\
examples:
  dkfsim run scenarios/paper_case1.yaml --out out/case1
  dkfsim run scenarios/paper_case1.yaml --out out/d0 --set links.default.latency.d_t=0 --steps 500
  dkfsim validate scenarios/paper_case2.yaml
  dkfsim list estimators
"""

#: The sub-command modules (each ``add_command(subparsers)``), in help order.
COMMANDS = (run, list_cmd, montecarlo, plot, report, sweep, maxdelay)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="dkfsim",
        description="Discrete-event simulator of the anti-delay distributed Kalman filter "
                    "(buffer + finite-time exchange + optimal matrix-weighted fusion) over networks "
                    "with time-varying latency.",
        epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--version", action="version", version=f"dkfsim {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for module in COMMANDS:
        module.add_command(sub)
    return parser


def main(argv=None) -> int:
    pin_process()                     # one BLAS thread here and in every worker we start
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "command", None):
        parser.print_help()
        return 2
    try:
        status = args.func(args)
        sys.stdout.flush()            # a closed pipe shows here, inside the try
        return status
    except DkfsimError as exc:
        print(printable(f"dkfsim {args.command}: error: {exc}"), file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("dkfsim: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        # The reader went away (``dkfsim ... | head``): end quietly, as Unix tools do,
        # with stdout pointed at /dev/null so the interpreter's final flush cannot fail.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141


if __name__ == "__main__":
    sys.exit(main())

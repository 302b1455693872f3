"""The ``dkfsim`` command line.

Every sub-command validates its input first; a :class:`~dkfsim.core.errors.DkfsimError`
(bad scenario, bad flag, unwritable folder) becomes a one-paragraph message on
stderr and exit status 2, never a traceback.
"""

from __future__ import annotations

import argparse
import os
import sys

from dkfsim import __version__
from dkfsim.core.errors import DkfsimError
from dkfsim.core.folders import check_target
from dkfsim.core.resources import check_run, estimate_run, human_bytes, human_seconds
from dkfsim.core.threads import pin_process

EPILOG = """\
examples:
  dkfsim run scenarios/paper_case1.yaml --out out/case1
  dkfsim run scenarios/paper_case1.yaml --out out/d0 --set links.default.latency.d_t=0 --steps 500
  dkfsim validate scenarios/paper_case2.yaml
"""


#: Modules that add a sub-command (``add_command(subparsers)``), in help order.
COMMAND_MODULES: tuple[str, ...] = ("dkfsim.experiments.montecarlo", "dkfsim.report.plots",
                                     "dkfsim.experiments.sweep", "dkfsim.experiments.maxdelay")


def add_scenario_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("scenario", metavar="FILE", help="scenario YAML file (see README: 'Scenario files')")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="override a scenario key by its dotted path, value parsed as YAML; "
                        "repeatable (e.g. --set links.default.latency.d_t=2 --set protocol=flood)")


def add_yes_arg(p: argparse.ArgumentParser) -> None:
    p.add_argument("--yes", action="store_true",
                   help="run even when the estimated time is above 10 minutes (the estimate is "
                        "printed and the command stops without it); work that cannot fit in memory "
                        "is refused either way")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="dkfsim",
        description="Discrete-event simulator of the anti-delay distributed Kalman filter "
                    "(buffer + finite-time exchange + optimal matrix-weighted fusion) over networks "
                    "with time-varying latency.",
        epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--version", action="version", version=f"dkfsim {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")

    p = sub.add_parser("run", help="simulate one scenario and write summary.json and run.npz",
                       description="Simulate one scenario: truth, sensors, the SimPy network, every node's "
                                   "anti-delay DKF, fusion and the baselines. Writes DIR/summary.json and "
                                   "DIR/run.npz (the arrays listed in docs/design.md, section 8) and prints an MSE table. "
                                   "DIR is replaced as a whole, atomically, when the run is done.")
    add_scenario_args(p)
    p.add_argument("--out", required=True, metavar="DIR", help="output folder (created if missing)")
    p.add_argument("--seed", type=int, help="override the scenario seed (same as --set seed=N)")
    p.add_argument("--steps", type=int, help="override the number of ticks K (same as --set steps=K)")
    p.add_argument("--save", default="auto", choices=["auto", "full", "estimates", "summary"],
                   help="what run.npz keeps: full (everything, including the n*n*K arrival log), "
                        "estimates (no arrival log), summary (no run.npz); auto = full unless the "
                        "arrival log would exceed 20 million entries (default: auto)")
    p.add_argument("--burn-in", type=int, metavar="ROWS",
                   help="rows skipped before averaging the MSE (default: 10%% of the ticks)")
    p.add_argument("--quiet", action="store_true", help="no progress bar and no table")
    add_yes_arg(p)
    p.set_defaults(func=cmd_run)

    p = sub.add_parser("validate", help="check a scenario file without running it",
                       description="Load and validate a scenario (schema, matrices, topology, "
                                   "protocol and buffer rules); print what would run, or the first "
                                   "problem with its file and key path.")
    add_scenario_args(p)
    p.set_defaults(func=cmd_validate)

    # Commands that live beside the concept they drive: each module defines
    # ``add_command(subparsers)`` and sets ``func`` on its parser.
    import importlib
    for name in COMMAND_MODULES:
        importlib.import_module(name).add_command(sub)
    return parser


def load_from_args(args):
    from dkfsim.config.schema import load_scenario
    overrides = list(args.overrides)
    for key in ("seed", "steps"):
        val = getattr(args, key, None)
        if val is not None:
            overrides.append(f"{key}={val}")
    return load_scenario(args.scenario, overrides=overrides)


def cmd_validate(args) -> int:
    sc = load_from_args(args)
    est = estimate_run(sc)
    if est.seconds > 60:               # a large graph: do not spend minutes on its exact diameter
        from dkfsim.core.resources import exchange_shape
        L, arcs, _ = exchange_shape(sc)
        shape = f"{arcs} directed links, buffer length L ~ {L}"
    else:
        xg = sc.exchange()
        shape = (f"{len(xg.arcs)} directed links (d_g = {xg.d_g}), buffer length "
                 f"L = {sc.resolved_buffer_length()}")
    print(f"{args.scenario}: ok — {sc.name}: {len(sc.sensors)} sensors, nx = {sc.nx}, "
          f"{sc.steps} ticks of {sc.model.T} s, protocol {sc.protocol} on {shape} "
          f"(d_t = {sc.resolved_d_t()}), fusion {sc.fusion}; a run needs about "
          f"{human_bytes(est.bytes)} and {human_seconds(est.seconds)} (rough estimate)")
    return 0


def cmd_run(args) -> int:
    from dkfsim.engine.driver import run
    sc = load_from_args(args)
    if args.burn_in is not None and not 0 <= args.burn_in < sc.steps:
        raise DkfsimError(f"--burn-in: must be in [0, steps) = [0, {sc.steps}), got {args.burn_in}")
    check_target(args.out)                 # before the run: a bad --out costs nothing
    check_run(sc, save=args.save, yes=args.yes)
    progress = None
    bar = None
    if not args.quiet and sys.stderr.isatty():
        from tqdm import tqdm
        bar = tqdm(total=sc.steps, unit="tick", desc=sc.name, leave=False)

        def progress(k, K):
            bar.update(k - bar.n)
    try:
        res = run(sc, save=args.save, progress=progress, yes=True)   # checked above
    finally:
        if bar is not None:
            bar.close()
    out = res.save(args.out, burn_in=args.burn_in)
    if not args.quiet:
        print(res.table(args.burn_in))
        print(f"wrote {out / 'summary.json'}" + ("" if res.info["save"] == "summary" else f" and {out / 'run.npz'}"))
    return 0


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
        print(f"dkfsim {args.command}: error: {exc}", file=sys.stderr)
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

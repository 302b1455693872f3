"""``dkfsim run``: one scenario, one result folder."""

from __future__ import annotations

import sys

from dkfsim.cli.common import add_scenario_args, add_yes_arg, say
from dkfsim.cli.work import load_from_args, progress_of
from dkfsim.config.plan import RunPlan
from dkfsim.core.errors import DkfsimError
from dkfsim.core.folders import check_target
from dkfsim.engine.driver import check_run_measured, simulate
from dkfsim.engine.estimate import buffer_warning
from dkfsim.report.tables import run_table


def configure(p) -> None:
    """``dkfsim run``'s arguments (its parser made by :func:`dkfsim.cli.main.build_parser`)."""
    p.description = ("Simulate one scenario: truth, sensors, the SimPy network, every node's "
                     "anti-delay DKF, fusion and the listed estimators. Writes DIR/summary.json, "
                     "DIR/rows.csv (the tidy rows: one per estimate and state component) and "
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


def cmd_run(args) -> int:
    sc = load_from_args(args)
    if args.burn_in is not None and not 0 <= args.burn_in < sc.steps:
        raise DkfsimError(f"--burn-in: must be in [0, steps) = [0, {sc.steps}), got {args.burn_in}")
    check_target(args.out)                 # before the run: a bad --out costs nothing
    plan = RunPlan.of(sc, args.save)       # (the plan validation worked out: one per command)
    check_run_measured(plan, yes=args.yes)
    warning = buffer_warning(plan)
    if warning:
        say(f"dkfsim run: warning: {warning}", file=sys.stderr)
    progress, close = progress_of(args, int(sc.steps), f"run {sc.name}", unit="tick")
    try:
        res = simulate(plan, progress)     # (the process runs BLAS on one thread: main)
    finally:
        close()
    out = res.save(args.out, burn_in=args.burn_in)
    if not args.quiet:
        say(run_table(res, args.burn_in))
        say(f"wrote {out / 'summary.json'}, {out / 'rows.csv'}"
            + ("" if res.info["save"] == "summary" else f" and {out / 'run.npz'}"))
    return 0

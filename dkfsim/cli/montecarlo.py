"""``dkfsim montecarlo``: N independent runs of a scenario, pooled per estimate."""

from __future__ import annotations

from dkfsim.cli.common import add_executor_args, add_scenario_args, add_yes_arg, say
from dkfsim.cli.work import executor_from_args, load_from_args, more_workers_hint, progress_of, workers_from_args
from dkfsim.core.errors import DkfsimError
from dkfsim.core.folders import check_target
from dkfsim.experiments import executors
from dkfsim.experiments.montecarlo import check_burn_in, check_montecarlo, check_reference, montecarlo


def configure(p) -> None:
    """``dkfsim montecarlo``'s arguments (its parser made by :func:`dkfsim.cli.main.build_parser`)."""
    p.description = ("Run a scenario N times with derived seeds (run r uses derive_seed(seed, r), "
                     "the same whatever N and --jobs) and pool the results per estimate and state "
                     "component: MSE over time with 95% confidence intervals, ANEES with its 95% "
                     "t-interval over runs and the consistency verdict, the paired difference and "
                     "ratio of the MSE to a reference estimate (--relative-to), disagreement between nodes, messages, bytes, lost packets and "
                     "late information (packet rows). Writes DIR/runs.csv (one row per run x estimate x "
                     "component), DIR/curves.npz (per-tick curves and one example run) and "
                     "DIR/summary.json, and prints a table.")
    add_scenario_args(p)
    p.add_argument("--runs", type=int, required=True, metavar="N",
                   help="number of independent runs (>= 1)")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder (created if missing)")
    p.add_argument("--burn-in", type=int, metavar="ROWS",
                   help="rows skipped before time-averaging MSE, ANEES and disagreement "
                        "(default: 10%% of the ticks)")
    p.add_argument("--steps", type=int, metavar="K",
                   help="override the number of ticks K of every run (same as --set steps=K)")
    p.add_argument("--seed", type=int, metavar="S",
                   help="override the base seed from which every run's seed derives (same as --set seed=S)")
    p.add_argument("--relative-to", dest="relative_to", metavar="NAME",
                   help="reference estimate of the paired comparisons (difference and ratio of "
                        "the MSE, run by run; default: centralized when the scenario has it)")
    add_executor_args(p)
    add_yes_arg(p)
    p.set_defaults(func=cmd_montecarlo)


def cmd_montecarlo(args) -> int:
    if args.runs < 1:
        raise DkfsimError(f"--runs: must be >= 1, got {args.runs}")
    executors.check_jobs(args.jobs)
    sc = load_from_args(args)
    check_burn_in(args.burn_in, int(sc.steps))
    check_reference(sc, args.relative_to)
    check_target(args.out)                 # before any run: a bad --out costs nothing
    check_montecarlo(sc, args.runs, workers_from_args(args, args.runs), yes=args.yes, yes_flag="--yes",
                     hint="fewer --runs or --steps" + more_workers_hint(args))
    make = executor_from_args(args, args.runs)
    progress, close = progress_of(args, args.runs, f"montecarlo {sc.name}")
    try:
        res = montecarlo(sc, args.runs, jobs=args.jobs, burn_in=args.burn_in, progress=progress,
                         yes=True, executor=make, relative_to=args.relative_to)                  # checked above
    finally:
        close()
    out = res.save(args.out)               # (the per-estimate pooling is cached: once for both)
    if not args.quiet:
        say(res.table())
        say(f"wrote {out / 'runs.csv'}, {out / 'curves.npz'} and {out / 'summary.json'}")
    return 0

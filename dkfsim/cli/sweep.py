"""``dkfsim sweep``: a grid of scenario keys x Monte Carlo runs into a resumable SQLite file."""

from __future__ import annotations

import argparse
import sys
import time
from collections import Counter

from dkfsim.cli.common import add_executor_args, add_yes_arg
from dkfsim.cli.common import say as say_line
from dkfsim.cli.work import ProgressLines, executor_from_args, more_workers_hint, workers_from_args
from dkfsim.core.errors import DkfsimError
from dkfsim.experiments.montecarlo import check_reference
from dkfsim.experiments.sweep import Sweep, export, is_database, load_sweep, run_sweep, tasks_done
from dkfsim.experiments.sweep.results import export_format, read_results
from dkfsim.experiments.sweep.summary import write_summary

HELP = """\
Run a parameter sweep: every parameter set of the grid (the cartesian product of the
grid's value lists) times `runs` Monte Carlo runs, run r using seed
derive_seed(scenario seed, r). Results go to an SQLite file, one transaction per task;
interrupt it at any point (Ctrl-C, kill) and re-run the same command to resume: tasks
already in the file are skipped. A sweep may grow: raise runs, add grid values or append
estimators and re-run; only the new tasks are computed. Changes that would alter stored
results (fewer runs, removed values, other grid keys, burn_in, a changed scenario) are refused.

sweep file keys:
  scenario   scenario file, relative to the sweep file (required)
  grid       mapping of dotted scenario keys (as --set) to lists of values (default: none)
  set        list of fixed "dotted.key=value" overrides, applied before the grid
  runs       Monte Carlo runs per parameter set (default: 1)
  burn_in    rows skipped before time averages (default: null = 10% of the ticks)
  output     results database (default: <sweep file stem>.sqlite beside the sweep file)

database: tables meta (the sweep definition), params (one row per parameter set, with its
resolved scenario), tasks (one row per finished (param_hash, run)) and results (the tidy
rows: one per parameter set, run, estimate and state component, with mse, anees,
disagreement, messages_per_tick, bytes_per_tick, lost, late).

summary: when the sweep is complete, <database stem>.summary.csv beside the database holds
one row per parameter set, estimate and state component: runs, mse with its 95% Student-t
interval over runs (mse_ci95_lo, mse_ci95_hi), anees with its t-interval over runs
(anees_ci95_lo, anees_ci95_hi) and the verdict anees_consistent (the interval covers nx),
the per-tick chi-square band anees_band95_lo/hi (not a test of the time average),
messages_per_tick, bytes_per_tick, late (means over runs), and the paired comparison with
the reference estimate (relative_to: --relative-to NAME, default centralized) at the same
grid point, run by run: mse_diff and mse_ratio with their 95% intervals.
Draw it with: dkfsim plot DATABASE --x KEY [--hue KEY] [--metric mse] [--relative-to NAME].

examples:
  dkfsim sweep scenarios/sweep_delay_bound.yaml --jobs 4
  dkfsim sweep scenarios/sweep_delay_bound.yaml --dask-local 4 --export out/delay.parquet
  dkfsim sweep scenarios/sweep_delay_bound.yaml --scheduler tcp://10.0.0.5:8786
  dkfsim sweep out/sweep_delay_bound.sqlite --export out/delay.csv     (export only)
"""


def configure(p) -> None:
    """``dkfsim sweep``'s arguments (its parser made by :func:`dkfsim.cli.main.build_parser`)."""
    p.description = HELP
    p.formatter_class = argparse.RawDescriptionHelpFormatter
    p.add_argument("file", metavar="FILE",
                   help="a sweep YAML file to run or resume; or a sweep database (.sqlite) to "
                        "export with --export, computing nothing")
    add_executor_args(p)
    p.add_argument("--db", metavar="PATH",
                   help="results database (overrides the sweep file's output)")
    p.add_argument("--export", metavar="PATH",
                   help="when the sweep is complete, write every result row to PATH (.csv or "
                        ".parquet, by suffix; Parquet needs pyarrow), sorted by parameter set, "
                        "run, estimate and component")
    p.add_argument("--dry-run", action="store_true",
                   help="validate, list the parameter sets and how many of their runs are done; "
                        "compute nothing")
    p.add_argument("--relative-to", dest="relative_to", metavar="NAME",
                   help="reference estimate of the summary's paired columns (mse_diff, "
                        "mse_ratio; default: centralized when the sweep has it)")
    add_yes_arg(p)
    p.set_defaults(func=cmd_sweep)


def cmd_sweep(args) -> int:
    say = (lambda *_: None) if args.quiet else say_line
    if is_database(args.file):
        if args.export is None:
            raise DkfsimError(f"{args.file} is a sweep database: give --export PATH to export "
                              "it, or give the sweep YAML file to run or resume it")
        if args.jobs is not None or args.scheduler or args.dask_local is not None or args.db:
            raise DkfsimError(f"{args.file} is a sweep database: only --export applies "
                              "(nothing is computed)")
        export_format(args.export)
        table = read_results(args.file)
        out, n = export(args.file, args.export, table)
        say(f"wrote {out} ({n} rows)")
        out, n = write_summary(args.file, relative_to=args.relative_to, table=table)
        say(f"wrote {out} ({n} rows: mean and 95 % interval per grid point, estimate and component)")
        return 0
    sweep = load_sweep(args.file, output=args.db, yes=args.yes)
    if args.relative_to is not None:          # refused before any work
        for p in sweep.parameter_sets:
            check_reference(p.scenario, args.relative_to)
    if args.dry_run:
        return _dry_run(sweep, say)
    if args.export is not None:
        export_format(args.export)       # a bad name or a missing pyarrow before any work
    make = executor_from_args(args)      # a missing Dask package is reported before any work
    say(f"{sweep.source}: {len(sweep.parameter_sets)} parameter set(s) x {sweep.runs} "
        f"run(s) = {sweep.n_tasks} tasks -> {sweep.output}")
    started = time.monotonic()
    rep = run_sweep(sweep, executor=make, jobs=args.jobs,
                    progress=not args.quiet and (sys.stderr.isatty() or ProgressLines(f"dkfsim sweep {sweep.name}")),
                    yes=args.yes,
                    workers=workers_from_args(args), yes_flag="--yes",
                    hint="fewer runs or a smaller grid in the sweep file" + more_workers_hint(args))
    rate = f" on {rep.executor} ({rep.runs_per_minute:.1f} runs/min)" if rep.computed else ""
    # The progress lines count from the start; the time estimate's trial runs and a first compile
    # of the kernels come before the tasks (on the sidelink sweep: 34 s), so say both times.
    total = time.monotonic() - started
    before = f"; {_duration(total)} in all, with the time estimate and start-up" \
        if total > rep.wall_s + STARTUP_SAID_ABOVE_S else ""
    say(f"done: {rep.skipped} already in the database, {rep.computed} computed in "
        f"{_duration(rep.wall_s)}{rate}{before}")
    table = read_results(rep.db)
    if args.export is not None:
        out, n = export(rep.db, args.export, table)
        say(f"wrote {out} ({n} rows)")
    out, n = write_summary(rep.db, relative_to=args.relative_to, table=table)
    say(f"wrote {out} ({n} rows: mean and 95 % interval per grid point, estimate and component; "
        f"draw it with dkfsim plot {rep.db} --x KEY)")
    return 0


def _dry_run(sweep: Sweep, say) -> int:
    done = tasks_done(sweep.output, sweep)
    say(f"{sweep.source}: scenario {sweep.scenario_path}, {len(sweep.parameter_sets)} parameter "
        f"set(s) x {sweep.runs} run(s) = {sweep.n_tasks} tasks; results in {sweep.output}")
    per_set = Counter(h for h, r in done if r < sweep.runs)      # (never a loop over the runs)
    for p in sweep.parameter_sets:
        n = per_set[p.param_hash]
        say(f"  [{p.index}] {p.param_hash}  {n}/{sweep.runs} done  {p.describe()}")
    return 0


#: Seconds of start-up before a sweep's tasks (the time estimate's trials, a first compile) above
#: which its last line gives the whole time beside the tasks'.
STARTUP_SAID_ABOVE_S = 5.0


def _duration(s: float) -> str:
    if s < 60:
        return f"{s:.1f} s"
    m, s = divmod(int(round(s)), 60)
    h, m = divmod(m, 60)
    return f"{h}h{m:02d}m{s:02d}s" if h else f"{m}m{s:02d}s"

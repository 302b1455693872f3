"""``dkfsim run`` (one scenario, one result folder) and ``dkfsim validate`` (check, run nothing)."""

from __future__ import annotations

from dkfsim.cli.common import add_scenario_args, add_yes_arg, load_from_args, progress_bar, say
from dkfsim.config.plan import RunPlan
from dkfsim.core.errors import DkfsimError
from dkfsim.core.folders import check_target
from dkfsim.core.resources import human_bytes, human_seconds
from dkfsim.engine.driver import simulate
from dkfsim.engine.estimate import check_run, estimate_run
from dkfsim.report.tables import run_table


def add_command(sub) -> None:
    p = sub.add_parser("run", help="simulate one scenario and write summary.json, rows.csv and run.npz",
                       description="Simulate one scenario: truth, sensors, the SimPy network, every node's "
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

    p = sub.add_parser("validate", help="check a scenario file without running it",
                       description="Load and validate a scenario (schema, matrices, topology, "
                                   "protocol and buffer rules); print what would run, or the first "
                                   "problem with its file and key path.")
    add_scenario_args(p)
    p.set_defaults(func=cmd_validate)


def cmd_validate(args) -> int:
    sc = load_from_args(args)
    plan = RunPlan.of(sc)
    est = estimate_run(plan)
    if est.seconds > 60:               # a large graph: do not spend minutes on its exact diameter
        shape = f"{plan.n_exchange_links} directed links, buffer length L ~ {plan.L_estimate}"
    elif plan.graph_changes:          # mobility: links come and go (docs/mobility.md)
        B = plan.connect_window
        shape = (f"{len(plan.exchange_arcs)} directed links that come and go "
                 f"({'every B = ' + str(B) + ' ticks a connected union' if B else 'never a connected union'}), "
                 f"buffer length L = {plan.buffer_length()}")
    else:
        xg = plan.exchange
        shape = (f"{len(xg.arcs)} directed links (d_g = {xg.d_g}), buffer length "
                 f"L = {plan.buffer_length()}")
    channel = ""
    if sc.medium is not None:         # a shared radio channel (docs/design.md §3)
        m = sc.medium
        cw = getattr(m.access, "cw", None)
        channel = (f"; {len(m.members(sc.n))} nodes on one shared channel of {m.rate:g} bit/s "
                   f"({m.access.kind}" + (f", cw {cw})" if cw is not None else ")"))
    say(f"{args.scenario}: ok — {sc.name}: {len(sc.sensors)} sensors, nx = {sc.nx}, "
          f"{sc.steps} ticks of {sc.model.T} s, protocol {sc.protocol} on {shape} "
          f"(d_t = {plan.d_t}), fusion {sc.fusion}{channel}; a run needs about "
          f"{human_bytes(est.bytes)} and {human_seconds(est.seconds)} (rough estimate)")
    return 0


def cmd_run(args) -> int:
    sc = load_from_args(args)
    if args.burn_in is not None and not 0 <= args.burn_in < sc.steps:
        raise DkfsimError(f"--burn-in: must be in [0, steps) = [0, {sc.steps}), got {args.burn_in}")
    check_target(args.out)                 # before the run: a bad --out costs nothing
    plan = RunPlan.of(sc, args.save)       # (the plan validation worked out: one per command)
    check_run(plan, yes=args.yes)
    bar = progress_bar(args, sc.steps, sc.name, unit="tick")
    progress = None if bar is None else (lambda k, _K: bar.update(k - bar.n))
    try:
        res = simulate(plan, progress)     # (the process runs BLAS on one thread: main)
    finally:
        if bar is not None:
            bar.close()
    out = res.save(args.out, burn_in=args.burn_in)
    if not args.quiet:
        say(run_table(res, args.burn_in))
        say(f"wrote {out / 'summary.json'}, {out / 'rows.csv'}"
            + ("" if res.info["save"] == "summary" else f" and {out / 'run.npz'}"))
    return 0

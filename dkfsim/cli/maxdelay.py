"""``dkfsim maxdelay``: the largest delay for which a metric stays within a tolerance."""

from __future__ import annotations

import sys

from dkfsim.cli.common import add_executor_args, add_scenario_args, add_yes_arg, say
from dkfsim.cli.work import executor_from_args, load_from_args, progress_bar
from dkfsim.core.files import printable
from dkfsim.core.folders import check_target
from dkfsim.experiments.maxdelay import METRICS, Candidate, MaxDelay, Settings
from dkfsim.experiments.maxdelay.report import REFERENCE
from dkfsim.report.maxdelay import save_maxdelay


def configure(p) -> None:
    """``dkfsim maxdelay``'s arguments (its parser made by :func:`dkfsim.cli.main.build_parser`)."""
    p.description = ("Find the largest delay for which the anti-delay DKF's metric stays within a "
                     "tolerance, three ways: (1) empirically, with a sequential Monte Carlo search "
                     "(galloping then bisection over the delay; at each candidate, runs in batches "
                     "until the confidence interval of the metric minus the tolerance is entirely "
                     "below or above 0); (2) the deterministic worst case: every link at its largest "
                     "latency, one run per candidate, covariance metric; (3) the paper's theoretical "
                     "bound (Remark bound_of_delay, eq. delay_bound). The delay is d_t of a "
                     "uniform_steps latency model, or a scale s multiplying the time parameters of "
                     "continuous models (constant value, uniform low/high, exponential, lognormal, gamma, pareto time parameters, empirical scale, gilbert_elliott states, jitter). "
                     "Writes DIR/maxdelay.json and DIR/maxdelay.png/.pdf and prints the three answers.")
    add_scenario_args(p)
    p.add_argument("--out", required=True, metavar="DIR", help="output folder (created if missing)")
    p.add_argument("--estimate", default="fused", metavar="NAME",
                   help="with --metric mse: the estimate whose MSE is searched (fused, local, or the "
                        "name of one of the scenario's estimators) (default: fused)")
    p.add_argument("--metric", default="fused_mse", choices=list(METRICS),
                   help="what must stay within tolerance: " +
                        "; ".join(f"{k}: {v}" for k, v in METRICS.items()) + " (default: fused_mse)")
    p.add_argument("--component", metavar="NAME",
                   help="state component of the metric: a name (position, velocity, acceleration for "
                        "constant_acceleration; x0, x1, ... otherwise), an index, or all (the sum "
                        "over components) (default: the first component)")
    g = p.add_mutually_exclusive_group(required=True)
    g.add_argument("--tolerance", type=float, metavar="X",
                   help="absolute tolerance: the metric must stay <= X (> 0)")
    g.add_argument("--relative", type=float, metavar="R",
                   help="relative tolerance: the metric must stay <= R x its zero-delay value (R > 1); "
                        "decided on paired runs (same seeds) so the zero-delay value's own "
                        "uncertainty is accounted for")
    p.add_argument("--confidence", type=float, default=0.95, metavar="C",
                   help="confidence level of the intervals (default: 0.95)")
    p.add_argument("--batch", type=int, default=5, metavar="B",
                   help="Monte Carlo runs added per look at a candidate; the first look is after B "
                        "runs (>= 2) (default: 5)")
    p.add_argument("--max-runs", type=int, default=40, metavar="N",
                   help="cap of runs per candidate; a candidate still undecided then is reported "
                        "'undecided' (default: 40)")
    p.add_argument("--max-delay", type=int, default=32, metavar="D",
                   help="largest d_t tried for a uniform_steps model (default: 32)")
    p.add_argument("--scale-step", type=float, default=0.25, metavar="DS",
                   help="grid step of the latency scale s for continuous models (default: 0.25)")
    p.add_argument("--max-scale", type=float, default=16.0, metavar="S",
                   help="largest latency scale tried for continuous models (default: 16)")
    p.add_argument("--axis", choices=["delay", "rate"], default="delay",
                   help="delay: the largest delay (default); rate: the least link rate (bit/s) at which "
                        "the metric stays within the tolerance, with a lower bound from the packet sizes "
                        "(docs/traffic.md)")
    p.add_argument("--link", metavar="U,V",
                   help="with --axis rate: search the rate of this one link (both directions on an "
                        "undirected topology) (default: every link)")
    for flag, meta, what in (("--max-rate", "R", "the fastest limited rate tried, bit/s; candidate 0 is no limit"),
                             ("--min-rate", "R", "the slowest rate tried, bit/s"),
                             ("--rate-step", "F", "the factor between two candidate rates (> 1)")):
        default = getattr(Settings, flag[2:].replace("-", "_"))
        p.add_argument(flag, type=float, default=default, metavar=meta,
                       help=f"with --axis rate: {what} (default: {default:g})")
    p.add_argument("--burn-in", type=int, metavar="ROWS",
                   help="rows skipped before time-averaging the metric (default: 10%% of the ticks)")
    p.add_argument("--steps", type=int, help="override the number of ticks K (same as --set steps=K); "
                                             "fewer ticks make every run cheaper")
    p.add_argument("--seed", type=int, help="override the base seed from which run r's seed derives "
                                            "(same as --set seed=S)")
    add_executor_args(p)
    add_yes_arg(p)
    p.set_defaults(func=cmd_maxdelay)


class _Progress:
    """tqdm on a terminal; otherwise one line per decided candidate on stderr."""

    def __init__(self, args):
        self.quiet = args.quiet
        self.paired = args.relative is not None
        self.reference = REFERENCE[args.axis]
        self.bar = progress_bar(args, None, "maxdelay")

    def __call__(self, runs: int = 0, label: str | None = None, done: Candidate | None = None):
        if self.quiet:
            return
        if self.bar is not None:
            if label:
                self.bar.set_description(printable(label))
            if runs:
                self.bar.update(runs)
            if done is not None:
                self.bar.write(printable(_done_line(label, done, self.paired, self.reference)), file=sys.stderr)
        elif done is not None:
            say(_done_line(label, done, self.paired, self.reference), file=sys.stderr, flush=True)

    def close(self):
        if self.bar is not None:
            self.bar.close()


def _done_line(label, c: Candidate, paired: bool = False, reference: str = "zero delay") -> str:
    """A decided candidate.  With a relative tolerance the decision is on the paired excess, run
    by run over the same run at the ``reference`` (zero delay; on the rate axis, unlimited rate),
    not on the mean against ``R x`` the reference's mean: a mean a little above that can still be
    *within* (the line says so)."""
    excess = f"paired excess over R x the same run at {reference}" if paired else "excess over tolerance"
    return (f"maxdelay: {label}: {c.runs} run{'s' * (c.runs != 1)}, mean {c.mean:.4g} "
            f"[{c.ci[0]:.4g}, {c.ci[1]:.4g}], {excess} {c.excess_mean:+.3g} "
            f"[{c.excess_ci[0]:+.3g}, {c.excess_ci[1]:+.3g}] -> {c.decision}"
            + (" (decided on the paired excess)" if paired else ""))


def cmd_maxdelay(args) -> int:
    sc = load_from_args(args)
    st = Settings(metric=args.metric, estimate=args.estimate, tolerance=args.tolerance, relative=args.relative,
                  confidence=args.confidence, batch=args.batch, max_runs=args.max_runs,
                  burn_in=args.burn_in, jobs=args.jobs, max_delay=args.max_delay,
                  scale_step=args.scale_step, max_scale=args.max_scale, component=args.component,
                  axis=args.axis, link=args.link, max_rate=args.max_rate, min_rate=args.min_rate,
                  rate_step=args.rate_step)
    check_target(args.out)                 # before any run: a bad --out costs nothing
    prog = _Progress(args)
    try:
        res = MaxDelay(sc, st, progress=prog, yes=args.yes, executor=executor_from_args(args),
                       yes_flag="--yes").run()
    finally:
        prog.close()
    out = save_maxdelay(res, args.out)
    if not args.quiet:
        say(res.table())
        say(f"wrote {out / 'maxdelay.json'}, {out / 'maxdelay.png'} and {out / 'maxdelay.pdf'}")
    return 0

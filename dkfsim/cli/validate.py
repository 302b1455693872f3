"""``dkfsim validate``: check a scenario file, run nothing; say what a run would be."""

from __future__ import annotations

import sys

from dkfsim.cli.common import add_scenario_args, say
from dkfsim.config.load import load_scenario
from dkfsim.config.plan import RunPlan
from dkfsim.core.resources import check_memory, human_bytes, human_seconds
from dkfsim.engine.estimate import VALIDATE_HINT, buffer_warning, estimate_run


def configure(p) -> None:
    """``dkfsim validate``'s arguments (its parser made by :func:`dkfsim.cli.main.build_parser`)."""
    p.description = ("Load and validate a scenario (schema, matrices, topology, protocol and buffer "
                     "rules); print what would run, or the first problem with its file and key path.")
    add_scenario_args(p)
    p.set_defaults(func=cmd_validate)


def cmd_validate(args) -> int:
    sc = load_scenario(args.scenario, overrides=list(args.overrides))
    plan = RunPlan.of(sc)
    est = estimate_run(plan)
    check_memory(est, hint=VALIDATE_HINT)   # (what dkfsim run refuses before it starts; a long run is only said)
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
    warning = buffer_warning(plan)
    if warning:
        say(f"dkfsim validate: warning: {warning}", file=sys.stderr)
    return 0


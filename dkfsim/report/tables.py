"""Tables printed for a person: a run's MSE per estimate and its packet counts."""

from __future__ import annotations

from dkfsim.core.text import aligned

#: One line per estimate name that is not self-explanatory (the vocabulary of docs/estimators.md).
DESCRIPTIONS = {
    "fused": "the anti-delay DKF, fused ({fusion})",
    "local": "the DKF nodes' own estimates (mean over nodes)",
    "local_only": "each node alone (mean over nodes)",
    "centralized": "every measurement on time",
    "fusion_centre": "the DKF's fusion at one node, fed over the network",
}


def run_table(res, burn_in: int | None = None) -> str:
    """MSE per state component of every estimate of a run, its packet counts, divergence."""
    m = res.metrics(burn_in)
    sc = res.scenario
    rows = [("estimate", *res.components, "")]
    for name in res.estimates:
        what = DESCRIPTIONS.get(name, "").format(fusion=sc.fusion)
        rows.append((name, *("%.4g" % v for v in m[name]), what))
    lines = [f"{sc.name}: {sc.steps} ticks, {sc.n} nodes, protocol {sc.protocol}, "
             f"L = {res.info['buffer_length']} (d_t = {res.info['d_t']}, d_g = {res.info['d_g']}), "
             f"MSE after {m['burn_in']} burn-in rows"]
    lines += aligned(rows, left=(0, -1))
    c = res.counts
    extra = "".join(f", {label} {c[key]}" for key, label in
                    (("copies", "duplicate copies"), ("queue_dropped", "dropped by full queues"),
                     ("crash_dropped", "dropped at crashed nodes"))
                    if c.get(key))
    lines.append(f"packets: sent {c['sent']}, delivered {c['delivered']}, lost {c['lost']}, "
                 f"in flight at end {c['in_flight']}{extra}; late "
                 f"{'packet rows' if c.get('late_unit') == 'packet_rows' else 'contributions'} {c['late']}")
    if res.diverged:
        lines.append("DIVERGED: " + ", ".join(res.diverged) + " hold non-finite values (the "
                     "model or the numbers overflow float64); their MSE is inf or nan")
    lines.append(f"wall time {res.info['wall_time_s']:.2f} s")
    return "\n".join(lines)

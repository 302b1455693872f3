"""Tables printed for a person: a run's MSE per estimate, its packet counts and, on a shared
radio channel (``medium:``), what the channel did."""

from __future__ import annotations

import math

from dkfsim.config.results import RADIO_CAUSES
from dkfsim.core.text import aligned

#: The terms of a port's packet identity ``sent + copies = delivered + lost + queue_dropped +
#: crash_dropped + in_flight`` (docs/design.md §3), in the order a table shows them.
PACKET_TERMS = ("sent", "copies", "delivered", "lost", "queue_dropped", "crash_dropped", "in_flight")
#: The parts of ``lost`` a run counts by cause (present only where the run has that cause), and
#: what a table calls them; the rest of ``lost`` is the links' own loss (``loss``, Gilbert-Elliott).
LOST_CAUSES = {"outage_lost": "outage", "range_lost": "out of range", "collision_lost": "collision"}
#: Column heads of a packets table, by term (counts of packets).
PACKET_HEADS = {"sent": "sent", "copies": "duplicate copies", "delivered": "delivered", "lost": "lost",
                "link_lost": "lost: link loss", **{k: f"lost: {v}" for k, v in LOST_CAUSES.items()},
                "queue_dropped": "dropped: full queue", "crash_dropped": "dropped: crashed node",
                "in_flight": "in flight at end"}


def count(value):
    """A count read from a result file: a finite number (an int when it is whole), else None."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        return None
    return int(value) if float(value).is_integer() else float(value)


def packet_columns(traffics: list[dict | None]) -> list[str]:
    """The columns of a packets table for these counts (``traffic`` blocks of ``summary.json``):
    every term of the identity, ``lost`` split by the causes any of them has."""
    causes = [k for k in LOST_CAUSES if any(t and count(t.get(k)) for t in traffics)]
    split = ["link_lost", *causes] if causes else []
    return ["sent", "copies", "delivered", "lost", *split, "queue_dropped", "crash_dropped", "in_flight"]


def packet_row(traffic: dict | None, columns: list[str]) -> list:
    """One estimator's counts in ``columns`` (None: not modelled, or not a number)."""
    if not traffic:
        return [None] * len(columns)
    out = []
    for key in columns:
        if key == "link_lost":
            lost, parts = count(traffic.get("lost")), [count(traffic.get(k)) or 0 for k in LOST_CAUSES]
            out.append(None if lost is None else lost - sum(parts))
        else:                            # (a term the counts lack is zero: an estimator without a port)
            out.append(count(traffic[key]) if key in traffic else 0)
    return out

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
    if c.get("channel"):                 # a run with ``medium:`` (docs/channel.md)
        lines.append(channel_line(c["channel"]))
    for name, facts in res.facts.items():     # a fusion centre that lost nodes says so (decision 220)
        if isinstance(facts, dict) and facts.get("nodes_excluded"):
            lines.append(f"{name}: {facts['nodes_excluded']} of {sc.n - 1} nodes left its fusion (unheard for "
                         "longer than its margin, or a radar's omega never reached it): its estimate "
                         "uses the others only; a larger margin keeps them (docs/fusion_centre.md)")
    if res.diverged:
        lines.append("DIVERGED: " + ", ".join(res.diverged) + " hold non-finite values (the "
                     "model or the numbers overflow float64); their MSE is inf or nan")
    lines.append(f"wall time {res.info['wall_time_s']:.2f} s")
    return "\n".join(lines)


def collided_percent(ch: dict) -> float:
    """The share of an estimator's frames that collided, in percent (0 without frames)."""
    return 100.0 * ch["frames_collided"] / ch["frames"] if ch["frames"] else 0.0


def channel_line(ch: dict) -> str:
    """One line on the shared channel as an estimator's copy of it saw it (summary.json
    ``traffic.<estimate>.channel``): the channel's utilisation (background included), the
    estimator's own frames, collided and refused by full radio queues, their mean access delay,
    and the background's frames on the air (and collided, and refused)."""
    dropped = f", {ch['background_dropped']} refused by full queues" if ch.get("background_dropped") else ""
    if ch.get("losses") is not None:
        return radio_line(ch, dropped)
    return (f"channel: utilisation {ch['utilisation']:.3g}, {ch['frames']} frames "
            f"({collided_percent(ch):.3g} % collided, {ch['frames_dropped']} dropped by full radio queues), "
            f"mean access delay {1e3 * ch['access_delay_mean']:.3g} ms; background "
            f"{background_on_air(ch)} frames on the air ({ch['background_collided']} collided){dropped}")


def radio_line(ch: dict, dropped: str = "") -> str:
    """A spatial radio's line (docs/radio.md): the mean CBR, the estimator's own frames and their
    access delay, the frames on the air (background included) and their (frame, receiver) pairs,
    received and lost by cause."""
    pairs, losses = ch.get("pairs") or 0, ch["losses"]
    received = f"{100.0 * ch.get('pairs_received', 0) / pairs:.3g} %" if pairs else "none"
    causes = ", ".join(f"{name.replace('_', ' ')} {losses[name]}" for name in RADIO_CAUSES
                       if losses.get(name) is not None)
    return (f"radio: CBR {ch.get('cbr_mean', 0.0):.3g} (mean over {len(ch.get('cbr') or [])} vehicles), "
            f"{ch['frames']} frames ({ch['frames_dropped']} dropped by full radio queues), mean access delay "
            f"{1e3 * ch['access_delay_mean']:.3g} ms; {ch.get('frames_on_air', 0)} frames on the air (background "
            f"{ch['background_sent']}{dropped}), {pairs} (frame, receiver) pairs: {received} received; lost: "
            f"{causes}")


def background_on_air(ch: dict) -> int:
    """The background frames that went on the air (``background_sent`` counts those that did not
    collide, ``background_collided`` those that did)."""
    return int(ch["background_sent"]) + int(ch["background_collided"])

"""The rate axis of ``dkfsim maxdelay --axis rate``: the least link rate within a tolerance.

The bandwidth twin of the delay axis (docs/traffic.md, "The least rate an estimate needs"):
candidate ``0`` is a link so fast that every transmission rounds to 0 ns (:data:`NO_LIMIT`,
the run without a rate: the reference of ``--relative``), candidate ``j >= 1`` the rate
``max_rate / step^(j - 1)`` bits per second, down to ``min_rate``.  A larger index is a slower
link, so the search of :mod:`~dkfsim.experiments.maxdelay.search` (galloping, bisection,
sequential Monte Carlo at each candidate) finds the largest index -- the least rate -- within
the tolerance, unchanged.

Beside it, a lower bound from the packet sizes (:func:`rate_lower_bound`): below it the
busiest link's transmitter has more to send per second (the contents of the estimate's
packets, measured in the run without a rate limit, plus the link's background) than the rate,
its utilisation would exceed 1, and its queue grows without bound.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from typing import Any

from dkfsim.config.load import load_scenario
from dkfsim.config.plan import RunPlan
from dkfsim.core.errors import DkfsimError
from dkfsim.engine.driver import Run
from dkfsim.experiments.maxdelay.axis import search_base
from dkfsim.protocols.base import PACKET_HEADER

#: Candidate 0: every transmission of a scenario takes 0 ns (a 1 GiB packet: 8.6 ns), the run
#: without a rate (docs/traffic.md).
NO_LIMIT = 1.0e15


def parse_link(text) -> tuple[int, int] | None:
    """``--link U,V`` -> ``(U, V)`` (None: every link)."""
    if text is None:
        return None
    if isinstance(text, (tuple, list)) and len(text) == 2:
        parts = [str(p) for p in text]
    else:
        parts = str(text).replace(" ", "").split(",")
    if len(parts) != 2 or not all(p.isdigit() for p in parts):
        raise DkfsimError(f"--link: expected two node numbers U,V (e.g. --link 0,1), got {text!r}")
    return int(parts[0]), int(parts[1])


@dataclass
class RateAxis:
    """How candidate ``j`` becomes a scenario: ``--set`` overrides on ``base``.

    Every link (``link`` None): ``links.default.rate = r``, and each ``links.overrides`` entry
    that gives its own ``rate`` keeps its ratio to the scenario's default rate (set to ``r``
    when the scenario has no default rate).  One link: its ``links.overrides`` entry gets
    ``rate: r`` (a link has one entry), or an entry ``{link: [u, v], rate: r}`` is appended,
    both directions on an undirected topology.
    """

    mode = "rate"
    step: float
    max_rate: float
    max_index: int
    base: Any                   # Scenario
    link: tuple[int, int] | None
    ratios: list                # [(override index, its rate / the default rate), ...]
    overrides_list: list        # the scenario's links.overrides (one-link mode appends to it)
    T: float
    steps: int
    #: one-link mode: the index of the link's own override (None: one is appended)
    link_override: int | None = None

    def value(self, j: int) -> float:
        """Candidate ``j``'s rate (bits per second)."""
        if j == 0:
            return NO_LIMIT
        return float(f"{self.max_rate / self.step ** (j - 1):.6g}")

    def label(self, j: int) -> str:
        return "rate unlimited" if j == 0 else f"rate = {self.value(j):.4g} bit/s"

    @property
    def name(self) -> str:
        return "rate" if self.link is None else f"rate of link {self.link[0]}-{self.link[1]}"

    def overrides(self, j: int) -> list[str]:
        r = self.value(j)
        if self.link is not None:
            entries = [dict(e) for e in self.overrides_list]
            if self.link_override is not None:
                entries[self.link_override]["rate"] = r
            else:
                entries.append({"link": list(self.link), "rate": r})
            return ["links.overrides=" + json.dumps(entries)]
        return [f"links.default.rate={r!r}"] + \
            [f"links.overrides.{i}.rate={min(max(r * f, 1.0), 1e18)!r}" for i, f in self.ratios]

    def scenario(self, j: int, overrides: list[str] | None = None):
        return load_scenario(self.base, overrides=self.overrides(j) if overrides is None else overrides)

    def worst_overrides(self, j: int) -> list[str] | None:
        """No worst case on this axis (a latency notion): the lower bound stands in."""
        del j                  # (the delay axis's signature)
        return None

    def describe(self) -> dict:
        keys = ([f"links.overrides.{self.link_override}.rate" if self.link_override is not None else
                 f"links.overrides (+ an entry {{link: [{self.link[0]}, {self.link[1]}], rate}})"]
                if self.link is not None else
                ["links.default.rate"] + [f"links.overrides.{i}.rate (x {f:g})" for i, f in self.ratios])
        return {"mode": "rate", "name": self.name, "step": self.step, "max": self.max_rate,
                "min": self.value(self.max_index), "no_limit": NO_LIMIT, "link": self.link, "keys": keys,
                "untouched": "queues, background and latencies stay as they are"}


def make_rate_axis(scenario, *, max_rate: float, min_rate: float, step: float, link=None,
                   keep: str | None = None) -> RateAxis:
    """The rate axis of ``scenario`` (DkfsimError for bad bounds or an unknown link).  The base
    keeps only the estimator named ``keep`` and pins a random topology's seed, as the delay
    axis does."""
    for flag, v in (("--max-rate", max_rate), ("--min-rate", min_rate)):
        if not (isinstance(v, (int, float)) and math.isfinite(v) and 1.0 <= v <= 1e18):
            raise DkfsimError(f"{flag}: must be a rate in bits per second between 1 and 1e18, got {v}")
    if not min_rate <= max_rate:
        raise DkfsimError(f"--min-rate ({min_rate:g}) must not exceed --max-rate ({max_rate:g})")
    if not (math.isfinite(step) and step > 1.0):
        raise DkfsimError(f"--rate-step: must be a factor > 1 between two candidate rates, got {step}")
    J = 1 + int(math.floor(math.log(max_rate / min_rate) / math.log(step) + 1e-9))
    if J > 10_000:
        raise DkfsimError(f"--rate-step {step:g} from --max-rate {max_rate:g} to --min-rate {min_rate:g} "
                          f"gives {J} candidates (at most 10000): take a larger step")
    data = scenario.to_dict()
    pair = parse_link(link)
    if pair is not None:
        arcs = set(RunPlan.of(scenario).exchange.arcs)
        if pair not in arcs:
            raise DkfsimError(f"--link {pair[0]},{pair[1]}: not a link the scenario's exchange uses "
                              f"(links: {', '.join(f'{u},{v}' for u, v in sorted(arcs)[:12])}"
                              f"{', ...' if len(arcs) > 12 else ''})")
    base = search_base(scenario, keep)
    links = data.get("links", {})
    default_rate = (links.get("default") or {}).get("rate")
    overrides = list(links.get("overrides") or [])
    ratios = [(i, (ov["rate"] / default_rate) if default_rate else 1.0)
              for i, ov in enumerate(overrides) if ov.get("rate") is not None]
    own = None if pair is None else next(
        (i for i, ov in enumerate(scenario.links.overrides) if scenario.link_matches(ov.link, *pair)), None)
    return RateAxis(step=float(step), max_rate=float(max_rate), max_index=J, base=base, link=pair,
                    ratios=[] if pair is not None else ratios, overrides_list=overrides,
                    T=float(scenario.model.T), steps=int(scenario.steps), link_override=own)


def rate_lower_bound(axis: RateAxis, estimate: str) -> dict:
    """The least rate at which no link the axis moves has more to send per second than it can.

    Per directed link, from ONE run without a rate limit (candidate 0, the base seed): the
    payload the estimate put on it (its bytes less a :data:`PACKET_HEADER` per packet -- the
    headers are what coalescing can save: a rate-limited exchange may send fewer, fuller packets
    or more, emptier ones, but the same contents) plus the background's mean bits per second,
    over the share of the candidate rate the link gets; the largest over the links (``rate``).
    Below it that link's transmitter is busy more than all the time.  ``demand_rate`` is the
    same with the headers: the rate at which the traffic as sent without a limit fills the link."""
    sc = axis.scenario(0)
    res = Run(sc, save="estimates").run()
    traffic = res.traffic.get(estimate)
    if traffic is None or not traffic.get("per_link"):
        return {"error": f"the estimate {estimate!r} sends nothing over the scenario's links"}
    span = float(sc.steps) * float(sc.model.T)
    share = dict(axis.ratios)
    best = None
    for row in traffic["per_link"]:
        u, v = row["link"]
        if axis.link is not None and not sc.link_matches(axis.link, u, v):
            continue
        spec = sc.link_spec(u, v)
        bg = spec.background
        bg_bps = 0.0 if bg is None else bg.packets_per_second * bg.size * 8.0
        own_bps = row["bytes"] * 8.0 / span
        payload_bps = (row["bytes"] - PACKET_HEADER * row["sent"]) * 8.0 / span
        factor = 1.0 if axis.link is not None else _share(sc, u, v, share)
        need = (payload_bps + bg_bps) / factor
        if best is None or need > best["rate"]:
            best = {"rate": need, "link": [u, v], "bytes_per_tick": row["bytes"] / sc.steps,
                    "packets_per_tick": row["sent"] / sc.steps, "payload_bit_per_s": payload_bps,
                    "own_bit_per_s": own_bps, "background_bit_per_s": bg_bps, "share": factor,
                    "demand_rate": (own_bps + bg_bps) / factor}
    if best is None:
        return {"error": "the estimate sends nothing over the link the axis moves"}
    best["estimate"] = estimate
    best["rule"] = (f"per directed link: ((the estimate's bytes - {PACKET_HEADER} x its packets) x 8 / (K T) "
                    "in one run without a rate limit + background packets_per_second x size x 8) / the "
                    "link's share of the candidate rate; the largest over the links the axis moves. Below "
                    "it that link cannot carry the contents the estimate sends (utilisation > 1, a queue "
                    "without bound). demand_rate: the same with the headers (the traffic as sent "
                    "without a limit; a rate-limited exchange may coalesce more or fewer packets)")
    return best


def _share(sc, u: int, v: int, ratios: dict) -> float:
    """The factor on the candidate rate of link ``u -> v`` (every-link mode): its last matching
    override's ratio, else 1."""
    f = 1.0
    for i, ov in enumerate(sc.links.overrides):
        if i in ratios and sc.link_matches(ov.link, u, v):
            f = ratios[i]
    return f

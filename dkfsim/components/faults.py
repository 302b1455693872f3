"""Faults: what can go wrong on a link or at a node, and when.

Link faults live in ``links.default`` and ``links.overrides`` next to the
latency model (an override's key replaces the default's); sensor faults in a
top-level ``faults`` key.  Times are SI seconds of simulated time (``t_k =
k T``); windows are half-open, ``[start, end)``.  docs/latency_models.md has
the same with worked examples.

Link keys
---------
``loss`` (probability, default 0)
    Each packet is dropped with this probability (stream ``("link", u, v,
    "loss")``, one uniform per packet while ``loss > 0``).
``duplicate`` (probability, default 0)
    A packet that is *not* lost arrives twice with this probability (stream
    ``("link", u, v, "duplicate")``, one uniform per packet).  The copy gets
    its own latency: the link's whole latency recipe (model, schedule,
    jitter) drawn from the streams ``("link", u, v, "duplicate", ...)``, so
    the originals' draws do not change; the copy itself is never lost or
    duplicated.  Protocols treat a copy like any packet (tree: an equal
    sequence number is stale; flood: nothing new in it).
``jitter`` (a nested latency model, default none)
    Added to every packet's latency (streams ``("link", u, v, "jitter",
    ...)``, e.g. ``("link", u, v, "jitter", "latency")``).  Not scaled by the
    schedule.
``schedule`` (a list, default none)
    Time-varying scale of the latency: a packet sent at ``t`` takes
    ``round(f(t) * latency) + jitter``.  Items::

        {kind: step, at: s, factor: x}                    # f = x from t = at on
        {kind: ramp, from: s, to: s, start_factor: a, end_factor: b}
                                                          # linear a -> b on [from, to], then b

    ``f = 1`` before the first item; afterwards the latest item that has
    started decides.  Items must be in time order and may not overlap (a
    ramp ends before the next item starts).  Factors are >= 0.  A single
    mapping is a one-item list.
``outages`` (a list of ``[start, end]`` windows, default none)
    Every packet *sent* during a window is dropped.  Such packets count as
    ``lost`` (and also in ``outage_lost``, a part of ``lost``).  Packets
    already travelling when an outage starts still arrive.

The per-packet draws happen whatever the packet's fate (lost, in an outage
or not), so adding loss, duplication, jitter or an outage leaves every other
draw of the run unchanged (common random numbers).

Sensor faults
-------------
``faults: {crashes: [{node: i, start: s, end: s}, ...]}``.  During ``[start,
end)`` node ``i`` is down: it does not measure (its contribution for a row
whose tick falls in the window does not exist anywhere: not at the node, not
at any other node, not in the arrival log), does not send, and every packet
that arrives at it is dropped (counted as ``crash_dropped``).  Its filter
keeps running the window rule on what it holds -- it predicts, with whatever
information for the window rows it received before the crash -- so its
estimates are exactly those the arrival log implies (docs/design.md §6).
After the window it resumes with what it holds: nothing is retransmitted,
so what its neighbours sent it during the crash is lost for it, as it is
under packet loss.

Counting identity (per link and in total)::

    sent + copies = delivered + lost + queue_dropped + crash_dropped + in_flight

``sent``: packets handed to the link by a node; ``copies``: extra arrivals the
link made; ``delivered``: arrivals handed to the receiving node's protocol
(copies included); ``lost``: packets dropped by the link (``loss``, the
Gilbert-Elliott state loss, outages); ``crash_dropped``: arrivals at a node
that was down; ``in_flight``: still travelling when the run ends.
"""

from __future__ import annotations

import bisect
from dataclasses import dataclass
from typing import Annotated, Any, Literal, Union

import numpy as np
from pydantic import AfterValidator, BeforeValidator, ConfigDict, Discriminator, Field, Tag, model_validator

from dkfsim.components.latency import LatencyParams
from dkfsim.components.traffic import Background, Queue
from dkfsim.core.files import clip
from dkfsim.core.params import MAX_MAGNITUDE, MAX_SECONDS, StrictModel, custom_error, seconds_to_ns

Seconds = Annotated[float, Field(strict=True, ge=0, le=MAX_SECONDS, allow_inf_nan=False)]
Factor = Annotated[float, Field(strict=True, ge=0, le=MAX_MAGNITUDE, allow_inf_nan=False)]


# --------------------------------------------------------------------------- schedules
class ScheduleStep(StrictModel):
    """From ``at`` (s) on, the latency is multiplied by ``factor``."""

    kind: Literal["step"] = "step"
    at: Seconds
    factor: Factor

    @property
    def start(self) -> float:
        return self.at

    @property
    def end(self) -> float:
        return self.at


class ScheduleRamp(StrictModel):
    """Linear change of the factor from ``start_factor`` at ``from`` (s) to
    ``end_factor`` at ``to`` (s); ``end_factor`` afterwards."""

    model_config = ConfigDict(extra="forbid", frozen=True, serialize_by_alias=True)

    kind: Literal["ramp"] = "ramp"
    from_: Seconds = Field(alias="from")
    to: Seconds
    start_factor: Factor = 1.0
    end_factor: Factor

    @model_validator(mode="after")
    def _ordered(self):
        if self.to <= self.from_:
            raise custom_error(f"must be > from ({self.from_!r}), got {self.to!r}", "to")
        return self

    @property
    def start(self) -> float:
        return self.from_

    @property
    def end(self) -> float:
        return self.to


def _kind(value: Any):
    return value.get("kind") if isinstance(value, dict) else getattr(value, "kind", None)


ScheduleItem = Annotated[
    Union[Annotated[ScheduleStep, Tag("step")], Annotated[ScheduleRamp, Tag("ramp")]],
    # (no custom_error_context: a dict there would make the type unhashable)
    Discriminator(_kind, custom_error_type="dkfsim",
                  custom_error_message="unknown or missing schedule kind; valid kinds: step, ramp")]


def _one_or_list(value: Any) -> Any:
    return [value] if isinstance(value, dict) else value


def _check_schedule(items: tuple) -> tuple:
    for i in range(1, len(items)):
        prev, cur = items[i - 1], items[i]
        if cur.start < prev.end or (cur.start == prev.start):
            raise custom_error(f"starts at {cur.start!r} s, before item {i - 1} ends "
                               f"({prev.end!r} s); list items in time order without overlap",
                               str(i))
    return items


Schedule = Annotated[tuple[ScheduleItem, ...], BeforeValidator(_one_or_list),
                     AfterValidator(_check_schedule)]


class ScaleSchedule:
    """Runtime form of a schedule: ``factor(t_ns)``, exact breakpoints in ns."""

    __slots__ = ("starts", "items", "ends")

    def __init__(self, items):
        _check_schedule(tuple(items))
        self.items = tuple(items)
        self.starts = [seconds_to_ns(it.start) for it in self.items]
        self.ends = [seconds_to_ns(it.end) for it in self.items]

    def factor(self, t_ns: int) -> float:
        i = bisect.bisect_right(self.starts, t_ns) - 1
        if i < 0:
            return 1.0
        it = self.items[i]
        if it.kind == "step" or t_ns >= self.ends[i]:
            return float(it.factor if it.kind == "step" else it.end_factor)
        a, b = it.start_factor, it.end_factor
        f = a + (b - a) * ((t_ns - self.starts[i]) / (self.ends[i] - self.starts[i]))
        return min(max(f, min(a, b)), max(a, b))

    def max_factor(self) -> float:
        """The largest factor the schedule ever applies (1 before the first item)."""
        fs = [1.0] if not self.items or self.starts[0] > 0 else []
        for it in self.items:
            fs += [it.factor] if it.kind == "step" else [it.start_factor, it.end_factor]
        return float(max(fs))


# --------------------------------------------------------------------------- windows
def _window(value: Any) -> tuple[float, float]:
    if isinstance(value, dict) and set(value) == {"start", "end"}:
        value = [value["start"], value["end"]]
    if not isinstance(value, (list, tuple)) or len(value) != 2:
        raise custom_error(f"must be a window [start, end] in seconds, got {clip(value)}")
    out = []
    for x in value:
        if isinstance(x, bool) or not isinstance(x, (int, float)) or not x == x \
                or x in (float("inf"), float("-inf")):
            raise custom_error(f"window bounds must be finite numbers, got {clip(value)}")
        out.append(float(x))
    start, end = out
    if start < 0 or end <= start:
        raise custom_error(f"must satisfy 0 <= start < end, got [{start!r}, {end!r}]")
    return start, end


Window = Annotated[tuple[float, float], BeforeValidator(_window)]


class Windows:
    """Half-open time windows ``[start, end)`` in ns, merged; ``t in windows``."""

    __slots__ = ("starts", "ends")

    def __init__(self, windows):
        merged: list[list[int]] = []
        for a, b in sorted((seconds_to_ns(a), seconds_to_ns(b)) for a, b in windows):
            if merged and a <= merged[-1][1]:
                merged[-1][1] = max(merged[-1][1], b)
            else:
                merged.append([a, b])
        self.starts = [a for a, _ in merged]
        self.ends = [b for _, b in merged]

    def __contains__(self, t_ns: int) -> bool:
        i = bisect.bisect_right(self.starts, t_ns) - 1
        return i >= 0 and t_ns < self.ends[i]

    def __bool__(self) -> bool:
        return bool(self.starts)


# --------------------------------------------------------------------------- link spec
@dataclass(frozen=True)
class LinkSpec:
    """Settings of one directed link: latency model, loss and the link faults."""

    latency: LatencyParams
    loss: float = 0.0
    duplicate: float = 0.0
    jitter: LatencyParams | None = None
    schedule: tuple = ()
    outages: tuple = ()
    #: bits per second (None: infinitely fast), the waiting room and the background load
    #: (:mod:`dkfsim.components.traffic`)
    rate: float | None = None
    queue: Queue | None = None
    background: Background | None = None

    @property
    def plain(self) -> bool:
        """True when only the latency model and ``loss`` matter to the latency (``rate`` is not
        part of it: ``buffer_length: auto`` ignores transmission and queueing)."""
        return not (self.duplicate or self.jitter is not None or self.schedule or self.outages)

    def sup_ns(self, T_ns: int) -> int | None:
        """Largest latency (ns) a packet can take: ``round(sup * max factor) + sup jitter``."""
        sup = self.latency.sup_ns(T_ns)
        if sup is None:
            return None
        if self.schedule:
            sup = int(round(sup * ScaleSchedule(self.schedule).max_factor()))
        if self.jitter is not None:
            j = self.jitter.sup_ns(T_ns)
            if j is None:
                return None
            sup += j
        return sup

    def bound_steps(self, T_ns: int) -> int | None:
        """Smallest ``d`` with every latency ``<= d * T`` (``None`` if unbounded)."""
        if self.plain:
            return self.latency.bound_steps(T_ns)
        sup = self.sup_ns(T_ns)
        return None if sup is None else -(-sup // int(T_ns))

    def unbounded_models(self, T_ns: int) -> list[str]:
        """Names of the models that make this link unbounded (for messages)."""
        out = [] if self.latency.sup_ns(T_ns) is not None else [self.latency.model]
        if self.jitter is not None and self.jitter.sup_ns(T_ns) is None:
            out.append(f"{self.jitter.model} (jitter)")
        return out


# --------------------------------------------------------------------------- sensor faults
class Crash(StrictModel):
    """Node ``node`` is down during ``[start, end)`` seconds."""

    node: Annotated[int, Field(strict=True, ge=0)]
    start: Seconds
    end: Seconds

    @model_validator(mode="after")
    def _ordered(self):
        if self.end <= self.start:
            raise custom_error(f"must be > start ({self.start!r}), got {self.end!r}", "end")
        return self


class Faults(StrictModel):
    """The top-level ``faults`` key."""

    crashes: tuple[Crash, ...] = ()

    def check(self, n: int) -> None:
        """Cross-checks that need the network size (called by the scenario)."""
        for i, c in enumerate(self.crashes):
            if c.node >= n:
                raise custom_error(f"node {c.node} is out of range 0..{n - 1}",
                                   f"faults.crashes.{i}.node")


class CrashSchedule:
    """Runtime crash windows: ``down(node, t_ns)``."""

    __slots__ = ("windows",)

    def __init__(self, faults: Faults | None, n: int):
        per: list[list] = [[] for _ in range(n)]
        for c in (faults.crashes if faults is not None else ()):
            per[c.node].append((c.start, c.end))
        self.windows = [Windows(w) if w else None for w in per]

    def __bool__(self) -> bool:
        return any(w is not None for w in self.windows)

    def down(self, node: int, t_ns: int) -> bool:
        w = self.windows[node]
        return w is not None and t_ns in w

    def mask(self, K: int, T_ns: int):
        """(n, K) bool: node i was down at tick k = r + 1 (its row r does not exist)."""
        out = np.zeros((len(self.windows), K), dtype=bool)
        for i, w in enumerate(self.windows):
            if w is not None:
                out[i] = [(r + 1) * T_ns in w for r in range(K)]
        return out

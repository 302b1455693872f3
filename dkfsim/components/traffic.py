"""What a link carries besides latency: its rate, its waiting room, its background load.

Three link keys (``links.default`` and ``links.overrides``; docs/design.md §3, "Links that
carry the traffic"), each absent by default (an infinitely fast link, nothing waits):

``rate`` (bits per second)
    A packet of ``size`` bytes takes ``size * 8 / rate`` seconds to transmit, rounded to the
    nearest nanosecond (:func:`transmission_ns`); one first-in-first-out transmitter per
    directed link.
``queue`` (``{packets: N}`` or ``{bytes: B}``)
    The waiting room, not counting the packet in transmission (an M/M/1/K system has
    ``K = N + 1``); a packet that does not fit is dropped (drop-tail, ``queue_dropped``).
``background`` (``{arrivals: poisson|periodic, packets_per_second, size, sizes, offset}``)
    Other traffic on the link: packets of ``size`` bytes (``sizes: exponential``: of mean
    ``size``) arriving as a Poisson process or periodically from ``offset`` seconds (``random``:
    each link's or radio's own keyed offset, uniform over one period); their
    instants and sizes are keyed draws of the link, so every estimator sees the same
    background.

A link with background or a queue limit needs a rate (nothing else would make them matter).
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import Field, model_validator

from dkfsim.core.params import MAX_NS, NS_PER_S, NonNegSeconds, StrictModel, custom_error

#: Largest rate a link may have (bits per second): far beyond any radio; 1e15 already makes
#: every packet of a scenario take 0 ns.
MAX_RATE = 1e18
#: Smallest rate (bits per second).
MIN_RATE = 1.0

#: Bits per second (a link's ``rate``).
Rate = Annotated[float, Field(strict=True, ge=MIN_RATE, le=MAX_RATE, allow_inf_nan=False)]
#: Largest background packet (bytes) and rate of background packets (per second).
MAX_PACKET_BYTES = 1 << 30
MAX_PACKETS_PER_SECOND = 1e9


def transmission_ns(nbytes: int, rate: float) -> int:
    """Nanoseconds a packet of ``nbytes`` bytes takes at ``rate`` bits per second: the nearest
    integer (halves up), at most :data:`~dkfsim.core.params.MAX_NS`."""
    ns = nbytes * 8.0 * NS_PER_S / rate
    return MAX_NS if ns >= MAX_NS else int(ns + 0.5)


class Queue(StrictModel):
    """A link's waiting room: at most ``packets`` packets or ``bytes`` bytes wait (the packet in
    transmission not counted); one of the two."""

    packets: Annotated[int, Field(strict=True, ge=0, le=1 << 40)] | None = None
    bytes: Annotated[int, Field(strict=True, ge=0, le=1 << 50)] | None = None

    @model_validator(mode="after")
    def _one(self) -> Queue:
        if (self.packets is None) == (self.bytes is None):
            raise custom_error("give exactly one of packets (waiting packets) or bytes (waiting bytes), "
                               "e.g. {packets: 10}")
        return self


class Background(StrictModel):
    """Background packets on a link: their arrival process, rate and size."""

    arrivals: Literal["poisson", "periodic"] = "poisson"
    packets_per_second: Annotated[float, Field(strict=True, gt=0, le=MAX_PACKETS_PER_SECOND,
                                               allow_inf_nan=False)]
    size: Annotated[int, Field(strict=True, ge=1, le=MAX_PACKET_BYTES)]
    sizes: Literal["fixed", "exponential"] = "fixed"
    offset: NonNegSeconds | Literal["random"] = 0.0

    @model_validator(mode="after")
    def _offset_periodic(self) -> Background:
        if self.offset != 0.0 and self.arrivals != "periodic":
            raise custom_error("offset is the first arrival of periodic background; a Poisson "
                               "process starts at 0", "offset")
        return self


class TrafficKeys(StrictModel):
    """A link's traffic keys, defined once for ``links.default`` and each ``links.overrides``
    entry (the scenario's link models inherit them): each absent by default."""

    rate: Rate | None = None
    queue: Queue | None = None
    background: Background | None = None


#: The traffic keys' names, in order (an override replaces each one it gives).
TRAFFIC_KEYS: tuple[str, ...] = tuple(TrafficKeys.model_fields)


def background_packets(scenario: Any, arcs: Any, copies: int) -> float:
    """Background packets a run of ``scenario`` on the directed links ``arcs`` sends, each an event
    of the network: the channel's frames (``medium.background``, per member) and each link's
    (``links.*.background``, per arc that has it), in each of the run's ``copies`` of the network
    (the engine's :func:`~dkfsim.engine.estimate.channel_copies`).  What the run's time estimate
    counts, so that a background of a billion packets per second is a run of years, refused
    before it starts."""
    seconds = int(scenario.steps) * float(scenario.model.T)
    medium, links = scenario.medium, scenario.links
    per_second = 0.0
    if medium is not None and medium.background is not None:
        per_second += medium.background.packets_per_second * len(medium.members(scenario.n))
    if links.default.background is not None or any(ov.background is not None for ov in links.overrides):
        for u, v in arcs:
            background = scenario.link_spec(u, v).background
            per_second += background.packets_per_second if background is not None else 0.0
    return per_second * seconds * copies

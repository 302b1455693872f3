"""A directed link: what happens to a packet once it has left its sender.

A :class:`Link` is the propagation part of the network and nothing else (docs/design.md §3):
the keyed draws of a packet's latency, loss, duplication and jitter, the link's faults
(a schedule that scales the latency, outages that lose what is handed over during them) and,
with ``mobility:``, its state over time (up or out of range at each tick, and a loss and an
extra latency that follow the pair's distance).  How a packet gets *onto* the link -- at
once, through a rate-limited transmitter, or as a frame on a shared radio channel -- is the
business of a medium (:mod:`dkfsim.network.media`); counting and delivering are the port's
(:mod:`dkfsim.network.port`).

Draws are keyed, the common-random-numbers rule of docs/design.md §3: a packet's fate is a
pure function of (the link, the instant it was handed over, its number among the packets
its port handed to the link at that instant), drawn by
:func:`dkfsim.core.streams.keyed_uniform` from the link's named keys (``("link", u, v,
"latency")``, ``"loss"``, ``"duplicate"``, ``"jitter"``, ...).  So two estimators that send
over one link at one instant see the same delay, adding loss or a fault leaves every other
draw unchanged, and adding a link changes no other link's draws.  Packets on one link
overtake each other when a later draw is shorter: links reorder.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from dkfsim.components.faults import LinkSpec, ScaleSchedule, Windows
from dkfsim.components.latency import TrackSinrSampler
from dkfsim.core.params import MAX_NS
from dkfsim.core.streams import key64, keyed_uniform


def as_spec(spec: Any) -> LinkSpec:
    """A :class:`LinkSpec` from anything with ``.latency`` and ``.loss``."""
    if isinstance(spec, LinkSpec):
        return spec
    return LinkSpec(latency=spec.latency, loss=float(spec.loss),
                    duplicate=float(getattr(spec, "duplicate", 0.0) or 0.0),
                    jitter=getattr(spec, "jitter", None),
                    schedule=tuple(getattr(spec, "schedule", None) or ()),
                    outages=tuple(getattr(spec, "outages", None) or ()),
                    rate=getattr(spec, "rate", None), queue=getattr(spec, "queue", None),
                    background=getattr(spec, "background", None))


class Recipe:
    """The latency of a packet on one link: model draw, times the schedule's factor at the
    send time, plus jitter; and whether the model lost it (``gilbert_elliott``)."""

    __slots__ = ("model", "_sched", "_jitter")

    def __init__(self, spec: LinkSpec, prefix: tuple, seed: int, T_ns: int):
        self.model = spec.latency.sampler(prefix, seed, T_ns)
        self._sched = ScaleSchedule(spec.schedule) if spec.schedule else None
        self._jitter = spec.jitter.sampler(prefix + ("jitter",), seed, T_ns) \
            if spec.jitter is not None else None

    def set_sinr(self, sinr_at: Any) -> None:
        """Hand the sender's SINR to a model that draws at it (``cellular_sinr``, ``sinr: track``)."""
        if isinstance(self.model, TrackSinrSampler):
            self.model.sinr_at = sinr_at

    def draw(self, t_ns: int, seq: int) -> tuple[int, bool]:
        lat, lost = self.model.draw(t_ns, seq)
        if self._sched is not None:
            f = self._sched.factor(t_ns)
            if f != 1.0:
                scaled = lat * f
                lat = MAX_NS if scaled >= MAX_NS else int(round(scaled))
        if self._jitter is not None:
            lat = min(lat + self._jitter.draw(t_ns, seq)[0], MAX_NS)
        return lat, lost


class Link:
    """Directed link ``src -> dst``: its settings, its keyed draws and its state over time.

    :param spec: a :class:`~dkfsim.components.faults.LinkSpec` (or anything with ``.latency``
        and ``.loss``); its ``rate``, ``queue`` and ``background`` are the medium's
        (:mod:`dkfsim.network.media.fifo`), not the link's.
    :param key: the prefix of the link's draw names, ``("link", src, dst)`` by default.
    """

    __slots__ = ("id", "src", "dst", "spec", "loss", "duplicate", "plain", "T_ns", "prefix", "seed", "near",
                 "_main", "_copy", "_loss_key", "_dup_key", "_outages", "_faultless", "_up", "changes",
                 "_near_loss", "_near_extra")

    def __init__(self, link_id: int, src: int, dst: int, spec: Any, seed: int, T_ns: int,
                 key: tuple | None = None):
        spec = as_spec(spec)
        self.id, self.src, self.dst, self.spec = link_id, src, dst, spec
        self.T_ns = int(T_ns)
        self.loss = float(spec.loss)
        self.duplicate = float(spec.duplicate)
        #: the prefix of the link's draw names, and the run's seed (a medium on the link keys
        #: its own draws, e.g. the background's, under the same prefix)
        self.prefix: tuple = ("link", src, dst) if key is None else tuple(key)
        self.seed = int(seed)
        #: whether its loss and latency follow its pair's distance (:meth:`set_distance`)
        self.near = False
        #: per tick ``0 .. K`` (:meth:`set_schedule`): up or not; None: always up
        self._up: np.ndarray | None = None
        #: whether the link is down at some tick ``1 .. K`` (the ticks a run sends at); an
        #: attribute, not a property: the port reads it for every packet
        self.changes = False
        self._near_loss: list[float] | None = None
        self._near_extra: list[int] | None = None
        prefix = self.prefix
        self._main = Recipe(spec, prefix, seed, T_ns)
        self._loss_key = key64(seed, *prefix, "loss") if self.loss > 0 else None
        self._dup_key = key64(seed, *prefix, "duplicate") if self.duplicate > 0 else None
        self._copy = Recipe(spec, prefix + ("duplicate",), seed, T_ns) if self.duplicate > 0 else None
        self._outages = Windows(spec.outages) if spec.outages else None
        #: nothing but the latency model acts on a packet's fate (no loss, duplication, outage,
        #: schedule or jitter)
        self._faultless = spec.plain and not self.loss > 0
        #: The latency model's own ``draw(t_ns, seq) -> (ns, lost)`` when nothing else acts on
        #: the link: :meth:`transmit`'s fast path (the same values).  None otherwise.
        self.plain = self._main.model.draw if self._faultless else None

    # -- state over time (mobility) ----------------------------------------------------
    def set_schedule(self, up: np.ndarray) -> None:
        """The link comes and goes: ``up[k]`` is True while it is up at tick ``k``
        (docs/design.md §3); a packet handed to it while it is down is lost (``range_lost``)."""
        self._up = np.ascontiguousarray(up, dtype=bool)
        self.changes = not bool(self._up[1:].all())

    def set_distance(self, loss: list[float] | None, extra: list[int] | None) -> None:
        """The link's loss and extra latency follow its pair's distance, per tick ``0 .. K``
        (:meth:`~dkfsim.components.mobility.DistanceLinks.per_tick`, ``mobility.links``,
        decision 176): a loss probability, extra latency ns (None: not given), taken at the
        hand-over tick (a rate from distance is the transmitter's,
        :mod:`dkfsim.network.media.fifo`)."""
        if loss is None and extra is None:
            return
        self.near = True
        self._near_loss, self._near_extra = loss, extra
        if loss is not None and self._loss_key is None:
            self._loss_key = key64(self.seed, *self.prefix, "loss")
        self._faultless = False
        self.plain = None

    def set_sinr(self, sinr_at: Any) -> None:
        """The sender's SINR (run seconds -> dB) for a ``cellular_sinr`` latency with ``sinr:
        track`` (decision 181); nothing for any other model."""
        for recipe in (self._main, self._copy):
            if recipe is not None:
                recipe.set_sinr(sinr_at)

    def tick_of(self, t_ns: int, size: int) -> int:
        """The tick instant ``t_ns`` is in, at most ``size - 1`` (a per-tick table's last row)."""
        return min(t_ns // self.T_ns, size - 1)

    def is_up(self, t_ns: int) -> bool:
        """Whether the link is up at instant ``t_ns`` (the state of the tick ``t_ns`` is in)."""
        up = self._up
        return up is None or bool(up[self.tick_of(t_ns, len(up))])

    def up_per_tick(self) -> np.ndarray | None:
        """Whether the link is up at each tick ``0 .. K`` (read only), None when it is always up."""
        if self._up is None:
            return None
        view = self._up.view()
        view.flags.writeable = False
        return view

    def came_up(self) -> list[int]:
        """The ticks ``k >= 1`` at which the link comes up (down at tick ``k - 1``)."""
        up = self._up
        if up is None or not self.changes:
            return []
        return (np.flatnonzero(up[1:] & ~up[:-1]) + 1).tolist()

    def min_latency_ns(self) -> int:
        """A lower bound (ns) of the latency of any packet that arrives (0 when a schedule may
        scale it down: then no bound is claimed)."""
        return 0 if self.spec.schedule else self.spec.latency.inf_ns()

    def vector_latency(self) -> tuple[int, int, int] | None:
        """The link's latency as a batch of packets draws it in one compiled loop
        (:meth:`~dkfsim.components.latency.Sampler.vector`) when nothing but the latency model
        acts on a packet; None otherwise."""
        return self._main.model.vector() if self.plain is not None else None

    # -- a packet's fate -----------------------------------------------------------------
    def transmit(self, t_ns: int, seq: int = 0) -> tuple[tuple[int, ...], str | None]:
        """The arrivals of a packet handed over at ``t_ns`` as number ``seq`` of its port at
        that instant, counted from when it leaves the sender: ``(latencies, why lost)`` --
        ``()`` and ``"lost"`` or ``"outage"`` when it is lost, one latency, or two when it is
        duplicated."""
        lat, lost = self._main.draw(t_ns, seq)
        loss = self.loss
        near = self.near
        if near and self._near_loss is not None:
            loss = 1.0 - (1.0 - loss) * (1.0 - self._near_loss[self.tick_of(t_ns, len(self._near_loss))])
        if self._loss_key is not None and keyed_uniform(self._loss_key, t_ns, seq) < loss:
            lost = True
        if self._outages is not None and t_ns in self._outages:
            return (), "outage"
        if lost:
            return (), "lost"
        extra = 0
        if near and self._near_extra is not None:
            extra = self._near_extra[self.tick_of(t_ns, len(self._near_extra))]
        if self._dup_key is not None and self._copy is not None \
                and keyed_uniform(self._dup_key, t_ns, seq) < self.duplicate:
            return (min(lat + extra, MAX_NS), min(self._copy.draw(t_ns, seq)[0] + extra, MAX_NS)), None
        if extra:
            lat = min(lat + extra, MAX_NS)
        return (lat,), None

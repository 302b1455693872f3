"""A shared radio channel (``medium:``, issue 22; docs/design.md §3, "A shared radio channel").

Vehicles do not have a private wire per neighbour: the scenario's ``medium:`` puts its
``nodes`` on one channel of ``rate`` bits per second.  They transmit one frame at a time under
``access`` (a simplified IEEE 802.11p / ITS-G5 broadcast CSMA: a backoff for every frame, no
acknowledgement, no retransmission), and a frame reaches every neighbour on the channel at once.
Every member has one radio: a first-in-first-out waiting room (``queue``, drop-tail) fed by its
estimators' frames and its own ``background`` (awareness messages: per vehicle, keyed draws).

``medium: {rate, access: {kind: csma, slot, aifs, cw}, preamble, queue, background, nodes}``;
a frame of ``size`` bytes is on the air ``preamble + size * 8 / rate`` seconds, the second
term rounded as :func:`~dkfsim.components.traffic.transmission_ns`, at least 1 ns
(:meth:`dkfsim.network.media.channel.Channel.airtime`).  The access rule is a component: its
parameter model (an :class:`AccessParams` with its ``kind``) is registered in
:data:`~dkfsim.core.registry.MEDIA`, its implementation in :mod:`dkfsim.network.media`
(docs/extending.md, "Add a medium").
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Annotated, Any, Literal

import numpy as np
from pydantic import Field, field_validator, model_validator

from dkfsim.components.mobility import Mobility
from dkfsim.components.radio import RadioParams
from dkfsim.components.traffic import Background, Queue, Rate
from dkfsim.components.trajectories import Trajectory, TrajectoryParams
from dkfsim.core.params import NonNegSeconds, StrictModel, custom_error, fix_kind, registered, seconds_to_ns
from dkfsim.core.registry import MEDIA

#: Bytes of a frame's header: :data:`dkfsim.protocols.base.PACKET_HEADER` (a test keeps them equal).
FRAME_HEADER = 16


def smallest_frame(nx: int) -> int:
    """Bytes of the smallest frame an estimator sends: a header and one state vector."""
    return FRAME_HEADER + 8 * nx


#: Largest contention window (slots): IEEE 802.11's largest, CWmax = 1023.
MAX_CW = 1023
#: Largest slot, AIFS and preamble (seconds): far beyond any radio (802.11p: 13 us and 110 us).
MAX_SLOT_S = 1.0


class AccessParams(StrictModel):
    """The keys of a shared channel's access rule (``medium.access``): ``kind`` and the rule's own.

    A subclass declares its kind as a class keyword, ``class MyParams(AccessParams,
    kind="my_mac")``: the model is registered in :data:`~dkfsim.core.registry.MEDIA` under it
    (its docstring's first line is what ``dkfsim list media`` prints), and ``medium.access:
    {kind: my_mac, ...}`` validates with it.  Its implementation, an
    :class:`~dkfsim.network.media.channel.Access`, registers under the same name.
    """

    kind: str = ""

    def __init_subclass__(cls, kind: str | None = None, **kwargs: Any) -> None:
        if kind is not None:
            fix_kind(cls, kind)
        super().__init_subclass__(**kwargs)

    @classmethod
    def __pydantic_init_subclass__(cls, kind: str | None = None, **kwargs: Any) -> None:
        super().__pydantic_init_subclass__(**kwargs)
        if kind is not None:           # the model is complete: register it
            MEDIA.add(kind, params=cls)


class Csma(AccessParams, kind="csma"):
    """The shared channel's default access rule: slotted CSMA with a backoff for every frame.

    (docs/design.md §3) The channel's slot boundaries after it last became idle at ``t`` are
    ``t + aifs + m * slot``; a node's head frame draws a backoff uniform in ``0 .. cw`` slots
    and is sent that many boundaries after the first one at or after it became head, while the
    channel stays idle."""

    slot: Annotated[float, Field(strict=True, gt=0, le=MAX_SLOT_S, allow_inf_nan=False)] = 13.0e-6
    aifs: Annotated[float, Field(strict=True, ge=0, le=MAX_SLOT_S, allow_inf_nan=False)] = 110.0e-6
    cw: Annotated[int, Field(strict=True, ge=0, le=MAX_CW)] = 15

    @property
    def slot_ns(self) -> int:
        return seconds_to_ns(self.slot)

    @property
    def aifs_ns(self) -> int:
        return seconds_to_ns(self.aifs)

    @model_validator(mode="after")
    def _whole_slot(self) -> Csma:
        if self.slot_ns < 1:
            raise custom_error(f"a slot of {self.slot!r} s is under one nanosecond (the clock's unit); "
                               "give at least 1e-9 (802.11p: 13.0e-6)", "slot")
        return self


class Edca(Csma, kind="edca"):
    """IEEE 802.11p's access rule (802.11-2016 EDCA, as ns-3 runs it): a frame that finds the
    medium idle and no backoff pending goes once the medium has been idle for AIFS; one that finds
    it busy draws a backoff; a post-backoff after every own frame; EIFS after a frame in error.

    (docs/radio.md) Each radio counts its backoff in idle slots ``t_idle + aifs + m * slot`` of
    its own view of the medium, frozen while it senses it busy; ``eifs`` replaces ``aifs`` after
    a frame the radio received in error (802.11p at 10 MHz: SIFS 32 us + an ACK at 6 Mbit/s 88 us
    + AIFS 110 us = 230 us)."""

    eifs: Annotated[float, Field(strict=True, ge=0, le=MAX_SLOT_S, allow_inf_nan=False)] = 230.0e-6

    @property
    def eifs_ns(self) -> int:
        return seconds_to_ns(self.eifs)


#: ``medium.access``: any registered access rule (``csma`` when ``kind`` is absent).
if TYPE_CHECKING:
    AccessField = AccessParams
else:
    AccessField = registered(AccessParams, MEDIA, "csma")


#: Most bystanders a channel may carry.
MAX_BYSTANDERS = 10_000


class Bystanders(StrictModel):
    """``medium.bystanders``: vehicles on the channel beside the scenario's nodes (docs/radio.md):
    no sensor, no estimator, only their ``medium.background`` frames -- the traffic a group of
    vehicles running the DKF shares the air with.  Bystander ``j`` is node ``n + j`` of the channel
    (``n`` the scenario's nodes), ``vehicles`` gives each its trajectory as ``mobility.vehicles``
    does (its own entry ``j``, else ``default``; a ``road`` places it by ``j``)."""

    count: Annotated[int, Field(strict=True, ge=1, le=MAX_BYSTANDERS)]
    vehicles: dict[str, Trajectory]

    @field_validator("vehicles", mode="before")
    @classmethod
    def _trajectories(cls, v: Any) -> Any:
        return Mobility.parse_vehicles(v)       # (the one parser of vehicle keys)

    @model_validator(mode="after")
    def _every_one(self) -> Bystanders:
        for key in self.vehicles:
            if key != "default" and (len(key) > 6 or not 0 <= int(key) < self.count):
                raise custom_error(f"bystander {key} is out of range 0..{self.count - 1}", f"vehicles.{key}")
        if "default" not in self.vehicles:
            missing = [j for j in range(self.count) if str(j) not in self.vehicles]
            if missing:
                raise custom_error(f"bystander {missing[0]} has no trajectory ({len(missing)} without one); give "
                                   "it one, or a 'default' trajectory", "vehicles")
        return self

    def trajectory(self, j: int) -> TrajectoryParams:
        """Bystander ``j``'s trajectory, placed for it."""
        return (self.vehicles.get(str(j)) or self.vehicles["default"]).for_node(j)

    def positions(self, K: int, T: float, speed: float = 1.0) -> np.ndarray:
        """Every bystander's position (m) at ``t_k = k T``: ``(K + 1, count, 2)``."""
        t = np.arange(K + 1) * float(T) * float(speed)
        out = np.empty((K + 1, self.count, 2))
        for j in range(self.count):
            out[:, j, :] = self.trajectory(j).positions(t)
        return out


class Medium(StrictModel):
    """The scenario's shared channel: who is on it, its rate, its access rule, each radio's
    waiting room and each vehicle's background frames."""

    rate: Rate
    access: AccessField = Field(default_factory=Csma)
    preamble: Annotated[float, Field(strict=True, ge=0, le=MAX_SLOT_S, allow_inf_nan=False)] = 40.0e-6
    queue: Queue | None = None
    background: Background | None = None
    nodes: Literal["all"] | Annotated[tuple[Annotated[int, Field(strict=True, ge=0)], ...],
                                      Field(min_length=2)] = "all"
    #: each vehicle hands its frames of tick ``k`` to its radio a keyed uniform ``[0, jitter)``
    #: seconds late (per vehicle and tick), as vehicles that do not share a clock do (absent: 0,
    #: and a stored scenario without it keeps its hash)
    generation_jitter: NonNegSeconds | None = None
    #: a spatial radio (:mod:`dkfsim.components.radio`); None: one collision domain
    radio: RadioParams | None = None
    #: vehicles on the channel beside the nodes, sending only background (a spatial radio's)
    bystanders: Bystanders | None = None

    @field_validator("nodes", mode="before")
    @classmethod
    def _nodes_shape(cls, value: Any) -> Any:
        """One plain message for a ``nodes`` that is neither ``all`` nor a list of two or more
        nodes (the union type's own message lists both alternatives' internals)."""
        if isinstance(value, str) and value != "all":
            raise custom_error(f"give 'all' or a list of at least two node numbers, got {value!r}")
        if isinstance(value, (list, tuple)) and len(value) < 2:
            raise custom_error("a channel needs at least two nodes: give 'all' or a list of two or "
                               f"more node numbers, got {list(value)!r}")
        return value

    def members(self, n: int) -> tuple[int, ...]:
        """The nodes on the channel, in increasing order, then its bystanders ``n .. n + count - 1``."""
        nodes = tuple(range(n)) if self.nodes == "all" else tuple(sorted(set(self.nodes)))
        return nodes + (tuple(range(n, n + self.bystanders.count)) if self.bystanders is not None else ())

    def check(self, n: int) -> None:
        """``nodes`` against the scenario's ``n`` nodes (a
        error naming ``medium.nodes.<i>``)."""
        if self.nodes != "all":
            for i, node in enumerate(self.nodes):
                if node >= n:
                    raise custom_error(f"node {node} is out of range 0..{n - 1}", f"medium.nodes.{i}")
                if node in self.nodes[:i]:
                    raise custom_error(f"node {node} is listed twice", f"medium.nodes.{i}")

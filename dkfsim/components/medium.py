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
from pydantic import Field, PrivateAttr, ValidationInfo, field_validator, model_validator
from pydantic_core import PydanticCustomError

from dkfsim.components.fcd import read_fcd
from dkfsim.components.latency import located
from dkfsim.components.mobility import Mobility, check_vehicle_keys
from dkfsim.components.radio import RadioParams
from dkfsim.components.traffic import Background, Queue, Rate
from dkfsim.components.trajectories import SumoFcd, Trajectory, TrajectoryParams
from dkfsim.core.errors import DkfsimError
from dkfsim.core.files import clip
from dkfsim.core.params import (
    MAX_SECONDS,
    Name,
    NonNegSeconds,
    StrictModel,
    Text,
    custom_error,
    fix_kind,
    registered,
    seconds_to_ns,
)
from dkfsim.core.registry import MEDIA
from dkfsim.core.streams import key64, keyed_uniform

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
    """IEEE 802.11p's access rule (802.11-2016 EDCA): AIFS on an idle medium, backoff when busy,
    EIFS after an error.

    A frame that finds the medium idle and no
    backoff pending goes once the medium has been idle for AIFS (ns-3's ad-hoc MAC waits DIFS
    after the frame even on a long-idle medium, its QoS MAC the next slot boundary); one that
    finds it busy draws a backoff; a post-backoff after every own frame; EIFS after a frame in
    error.

    (docs/radio.md) Each radio counts its backoff in idle slots ``t_idle + aifs + m * slot`` of
    its own view of the medium, frozen while it senses it busy; ``eifs`` replaces ``aifs`` after
    a frame the radio received in error (802.11p at 10 MHz: SIFS 32 us + an ACK at 6 Mbit/s 88 us
    + AIFS 110 us = 230 us)."""

    eifs: Annotated[float, Field(strict=True, ge=0, le=MAX_SLOT_S, allow_inf_nan=False)] = 230.0e-6

    @property
    def eifs_ns(self) -> int:
        return seconds_to_ns(self.eifs)


#: Resource reservation intervals LTE-V2X allows (s): 20 and 50 ms, and 100 ms to 1 s in 100 ms steps.
RRI_ALLOWED = (0.02, 0.05) + tuple(round(0.1 * k, 1) for k in range(1, 11))


class Sps(AccessParams, kind="sps"):
    """C-V2X sidelink (LTE-V2X mode 4): sensing-based semi-persistent scheduling on the spatial
    radio (docs/radio.md, "C-V2X sidelink").

    Time runs in 1 ms subframes and the band in ``subchannels``; a packet takes the sub-channels
    its size needs (``subchannel_bytes`` each at the configured MCS) in one subframe.  Each
    vehicle keeps a reservation every ``rri`` seconds for a counter of transmissions drawn
    uniformly in 5..15 (``rri`` >= 0.1 s), 10..30 (0.05) or 25..75 (0.02) (3GPP TS 36.321
    §5.14.1.1); when it runs out the vehicle keeps it with probability ``p_keep``, else selects
    anew.  A selection (3GPP TS 36.213 §14.1.1.6) looks at the last 1000 subframes: it excludes the
    candidates whose 100 ms images it transmitted in (it could not sense them) and those reserved
    by a vehicle whose control message it received above ``rsrp_threshold`` (raised by
    ``threshold_step`` until ``candidates`` of them remain), then picks at random among that
    fraction with the lowest average RSSI.  A packet that does not fit its reservation (too big,
    or its next occurrence later than ``budget`` after the packet) follows ``misfit``:
    ``reselect`` (a new reservation; 3GPP's MAC) or ``one_shot`` (a selection for that packet
    alone, the reservation kept; Molina-Masegosa et al., IEEE Access 2020)."""

    subchannels: Annotated[int, Field(strict=True, ge=1, le=100)] = 4
    subchannel_bytes: Annotated[int, Field(strict=True, ge=1, le=1 << 20)] = 190
    #: the share of the band's noise (``medium.radio.noise``) one sub-channel's data takes: its
    #: data resource blocks over the band's (10 of 50 at 10 MHz)
    noise_share: Annotated[float, Field(strict=True, gt=0, le=1, allow_inf_nan=False)] = 0.2
    rri: Annotated[float, Field(strict=True, gt=0, le=1, allow_inf_nan=False)] = 0.1
    p_keep: Annotated[float, Field(strict=True, ge=0, le=1, allow_inf_nan=False)] = 0.0
    #: dBm: a reservation received above it is excluded from a selection (the analytic model's
    #: sensing power)
    rsrp_threshold: Annotated[float, Field(strict=True, ge=-400, le=400, allow_inf_nan=False)] = -90.5
    #: dB (at least 0.1: each raise must change the threshold, and a selection takes at most a few
    #: thousand of them)
    threshold_step: Annotated[float, Field(strict=True, ge=0.1, le=100, allow_inf_nan=False)] = 3.0
    candidates: Annotated[float, Field(strict=True, gt=0, le=1, allow_inf_nan=False)] = 0.2
    #: s: the latest a packet goes after its arrival (the selection window's end, T2)
    budget: Annotated[float, Field(strict=True, ge=0.001, le=1, allow_inf_nan=False)] = 0.1
    misfit: Literal["reselect", "one_shot"] = "reselect"
    #: dBm: a sub-channel whose power (RSSI) in a subframe reaches it is busy, for the CBR
    cbr_threshold: Annotated[float, Field(strict=True, ge=-400, le=400, allow_inf_nan=False)] = -94.0

    @field_validator("rri")
    @classmethod
    def _allowed(cls, rri: float) -> float:
        if not any(abs(rri - a) < 1e-9 for a in RRI_ALLOWED):
            raise custom_error(f"LTE-V2X reserves every 0.02, 0.05 or 0.1 .. 1.0 s in steps of 0.1; got {rri!r}")
        return rri

    @property
    def rri_ms(self) -> int:
        return int(round(self.rri * 1000))

    @property
    def budget_ms(self) -> int:
        return max(1, int(self.budget * 1000 + 1e-9))

    @property
    def counter_range(self) -> tuple[int, int]:
        """The reselection counter's range for ``rri`` (3GPP TS 36.321 §5.14.1.1)."""
        return (5, 15) if self.rri_ms >= 100 else ((10, 30) if self.rri_ms == 50 else (25, 75))


#: ``medium.access``: any registered access rule (``csma`` when ``kind`` is absent).
if TYPE_CHECKING:
    AccessField = AccessParams
else:
    AccessField = registered(AccessParams, MEDIA, "csma")


#: Most bystanders a channel may carry.
MAX_BYSTANDERS = 10_000


class FcdTraffic(StrictModel):
    """``medium.bystanders.sumo_fcd``: every vehicle of a SUMO FCD file but those named, each a
    ``sumo_fcd`` trajectory (in the order of their ids)."""

    file: Text
    exclude: Annotated[list[Name], Field(max_length=MAX_BYSTANDERS)] = []
    time_offset: Annotated[float, Field(strict=True, ge=-MAX_SECONDS, le=MAX_SECONDS, allow_inf_nan=False)] = 0.0
    #: keep this share of the vehicles (a fixed subset: vehicle ``v`` is kept when the uniform keyed
    #: by its id is below ``fraction``), to thin the traffic to a lower density
    fraction: Annotated[float, Field(strict=True, gt=0, le=1, allow_inf_nan=False)] = 1.0

    def kept(self, ids: list[str]) -> list[str]:
        """The vehicles of ``ids`` kept (sorted), the excluded left out."""
        out = sorted(set(ids) - set(self.exclude))
        if self.fraction < 1.0:
            out = [v for v in out if keyed_uniform(key64(0, "bystander", v), 0, 0) < self.fraction]
        return out


class Bystanders(StrictModel):
    """``medium.bystanders``: vehicles on the channel beside the scenario's nodes (docs/radio.md):
    no sensor, no estimator, only their ``medium.background`` frames -- the traffic a group of
    vehicles running the DKF shares the air with.  Bystander ``j`` is node ``n + j`` of the channel
    (``n`` the scenario's nodes).  Either ``count`` and ``vehicles``, each one's trajectory given as
    ``mobility.vehicles`` gives them (its own entry ``j``, else ``default``; a ``road`` places it
    by ``j``), or ``sumo_fcd: {file, exclude}``: every other vehicle of a SUMO run, on the air
    while it is on the road."""

    count: Annotated[int, Field(strict=True, ge=1, le=MAX_BYSTANDERS)] | None = None
    vehicles: dict[str, Trajectory] | None = None
    sumo_fcd: FcdTraffic | None = None
    #: ``sumo_fcd``'s vehicles, worked out when validated (not stored: the scenario keeps the key)
    _fcd: list[Any] | None = PrivateAttr(default=None)

    @field_validator("vehicles", mode="before")
    @classmethod
    def _trajectories(cls, v: Any) -> Any:
        return Mobility.parse_vehicles(v)       # (the one parser of vehicle keys)

    @model_validator(mode="after")
    def _from_fcd(self, info: ValidationInfo) -> Bystanders:
        """``sumo_fcd``: a trajectory per vehicle of the file but the excluded (the file read once)."""
        fcd = self.sumo_fcd
        if fcd is None:
            if self.count is None or self.vehicles is None:
                raise custom_error("give count and vehicles, or sumo_fcd: {file, exclude}")
            return self
        if self.count is not None or self.vehicles is not None:
            raise custom_error("give either sumo_fcd or count and vehicles, not both", "sumo_fcd")
        try:
            path, _ = located(fcd.file, None, info)
        except PydanticCustomError as err:     # (located names the key "file": here it is sumo_fcd's)
            raise custom_error(str((err.context or {}).get("reason", err)), "sumo_fcd.file") from None
        try:
            ids = fcd.kept(list(read_fcd(path).vehicles))
        except DkfsimError as err:
            raise custom_error(str(err), "sumo_fcd.file") from None
        if not 1 <= len(ids) <= MAX_BYSTANDERS:
            raise custom_error(f"{len(ids)} vehicles of {path.name} are left as bystanders; give 1 .. "
                               f"{MAX_BYSTANDERS}", "sumo_fcd.exclude")
        context = info.context
        self._fcd = [SumoFcd.model_validate({"file": fcd.file, "vehicle": v, "time_offset": fcd.time_offset},
                                            context=context) for v in ids]
        return self

    @model_validator(mode="after")
    def _every_one(self) -> Bystanders:
        if self.vehicles is not None and self.count is not None:
            check_vehicle_keys(self.vehicles, self.count, "bystander", "vehicles")
        return self

    def trajectory(self, j: int) -> TrajectoryParams:
        """Bystander ``j``'s trajectory, placed for it."""
        if self._fcd is not None:
            return self._fcd[j]
        assert self.vehicles is not None
        return (self.vehicles.get(str(j)) or self.vehicles["default"]).for_node(j)

    @property
    def n(self) -> int:
        """How many bystanders."""
        if self._fcd is not None:
            return len(self._fcd)
        assert self.count is not None
        return self.count

    def positions(self, K: int, T: float, speed: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
        """Every bystander's position (m) at ``t_k = k T`` and whether it is on the road then:
        ``(K + 1, count, 2)`` and ``(K + 1, count)`` bool."""
        t = np.arange(K + 1) * float(T) * float(speed)
        out = np.empty((K + 1, self.n, 2))
        present = np.empty((K + 1, self.n), dtype=bool)
        for j in range(self.n):
            traj = self.trajectory(j)
            out[:, j, :] = traj.positions(t)
            present[:, j] = traj.present(t)
        return out, present


def _plain(value: Any) -> Any:
    """A numpy scalar as the Python number it holds (a message prints ``1``, not ``np.int64(1)``)."""
    return value.item() if isinstance(value, np.generic) else value


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
        node numbers (the union type's own message lists both alternatives' internals, and says
        "at least 2 items" of a list of two with a bad entry)."""
        if isinstance(value, str) and value == "all":
            return value
        if not isinstance(value, (list, tuple)):
            raise custom_error("give 'all' or a list of at least two distinct node numbers, got "
                               f"{clip(_plain(value))}")
        if len(value) < 2:
            raise custom_error("a channel needs at least two nodes: give 'all' or a list of two or "
                               f"more node numbers, got {clip([_plain(v) for v in value])}")
        for i, node in enumerate(value):
            if isinstance(node, bool) or not isinstance(node, int) or node < 0:
                raise custom_error(f"a node number is an integer >= 0, got {clip(_plain(node))} (nodes is "
                                   "'all' or a list of at least two distinct node numbers)", str(i))
        return value

    @model_validator(mode="after")
    def _sidelink_on_a_radio(self) -> Medium:
        if isinstance(self.access, Sps) and self.radio is None:
            raise custom_error("sps (C-V2X sidelink) runs on the spatial radio: give medium.radio "
                               "(e.g. radio: {} for its defaults)", "access")
        if isinstance(self.access, Sps) and self.radio is not None:
            floor = self.radio.noise + 10.0 * np.log10(self.access.noise_share)
            if self.access.cbr_threshold <= floor:
                raise custom_error(f"{self.access.cbr_threshold} dBm is at or below one sub-channel's noise "
                                   f"({floor:.1f} dBm: radio.noise plus noise_share), so every sub-channel would "
                                   "always be busy; give a higher threshold (3GPP: -94)", "access.cbr_threshold")
        return self

    def members(self, n: int) -> tuple[int, ...]:
        """The nodes on the channel, in increasing order, then its bystanders ``n .. n + count - 1``."""
        nodes = tuple(range(n)) if self.nodes == "all" else tuple(sorted(set(self.nodes)))
        return nodes + (tuple(range(n, n + self.bystanders.n)) if self.bystanders is not None else ())

    def check(self, n: int) -> None:
        """``nodes`` against the scenario's ``n`` nodes (a
        error naming ``medium.nodes.<i>``)."""
        if self.nodes != "all":
            for i, node in enumerate(self.nodes):
                if node >= n:
                    raise custom_error(f"node {node} is out of range 0..{n - 1}", f"medium.nodes.{i}")
                if node in self.nodes[:i]:
                    raise custom_error(f"node {node} is listed twice", f"medium.nodes.{i}")

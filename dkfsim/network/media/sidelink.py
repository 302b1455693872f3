"""C-V2X sidelink (``medium.access.kind: sps``, issue 33; docs/radio.md, "C-V2X sidelink"):
LTE-V2X mode 4's sensing-based semi-persistent scheduling on the spatial radio.

The radio is the 802.11p radio's (:mod:`~dkfsim.network.media.radio`: positions, path loss,
shadowing, fading, keyed draws, the reception rule); what differs is the access and what a
receiver does.  Time runs in 1 ms subframes and the band in ``subchannels``:

- each vehicle holds a reservation -- a subframe every ``rri`` and the sub-channels its packets
  need -- for a counter of transmissions (:class:`~dkfsim.components.medium.Sps`); a packet goes
  in the reservation's next occurrence when it fits (size, and within ``budget`` of its
  arrival), else by ``misfit`` in a new reservation or a one-shot resource;
- a selection senses the last 1000 subframes (3GPP TS 36.213 §14.1.1.6; the engine's
  :func:`~dkfsim.network.radio_kernels.sps_select`): it leaves out what it could not sense and
  what others announced they will use, heard strongly, and picks among the least loaded;
- at a receiver every packet of a subframe is decided on its own, from its SINR over its
  sub-channels (interference: the other packets overlapping them): lost to ``half_duplex`` (the
  receiver transmitted in that subframe), ``sensing``, ``propagation``, or a collision --
  ``reservation_collision`` when an overlapping packet was on a reservation, ``collision`` when
  only one-shots overlapped it.  A receiver that detects a packet learns its sender's reservation
  from its control message; CBR is the share of sub-channels whose power reaches
  ``cbr_threshold``.

The events run in the compiled engine :func:`~dkfsim.network.radio_kernels.run_sps`.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from typing_extensions import override

from dkfsim.components.medium import Medium as MediumSpec
from dkfsim.components.medium import Sps
from dkfsim.components.radio import Z_MAX, Z_STEPS
from dkfsim.core.registry import MEDIA
from dkfsim.core.streams import key64
from dkfsim.network import radio_kernels as rk
from dkfsim.network.media.base import Frame
from dkfsim.network.media.channel import NEVER, Access, Channel, Radio
from dkfsim.network.media.radio import SpatialChannel, mw


class SpsSchedule(Access):
    """The sidelink's access as the one-domain channel's wake-ups read it: when the next
    subframe with a transmission starts; the scheduling itself is the engine's."""

    def __init__(self, params: Any, channel: Channel, seed: int):
        super().__init__(params, channel, seed)
        self.vs: np.ndarray | None = None

    @override
    def head(self, radio: Radio, t: int) -> None:
        raise NotImplementedError("the sidelink schedules in its engine")

    @override
    def next_start(self) -> int:
        assert self.vs is not None
        due = self.vs[rk.T_SF]
        due = due[due >= 0]
        return int(due.min()) * rk.SUBFRAME if len(due) else NEVER

    @override
    def next_airtime(self) -> int:
        return rk.SUBFRAME

    @override
    def start(self, ts: int) -> list[Radio]:
        raise NotImplementedError("the sidelink schedules in its engine")


@MEDIA.register("sps", params=Sps)
class SidelinkChannel(SpatialChannel):
    """One copy of the C-V2X sidelink (see the module)."""

    CAUSES = (("sensing", rk.SENSING), ("half_duplex", rk.HALF_DUPLEX), ("propagation", rk.PROPAGATION),
              ("reservation_collision", rk.RESERVATION_COLLISION), ("collision", rk.COLLISION))
    COLLIDED = (rk.COLLISION, rk.RESERVATION_COLLISION)
    NFATES = rk.NFATES
    B_ROWS = (rk.VB_POS, rk.VB_LEN)
    Q_ROWS = (rk.VQ_HEAD, rk.VQ_LEN)
    KERNELS = ("run_sps", "sps_push")
    #: per slot: first sub-channel, sub-channels, on a reservation, the interval it announces
    sx: np.ndarray

    @override
    def make_access(self, spec: MediumSpec, seed: int) -> Access:
        self.schedule = SpsSchedule(spec.access, self, seed)
        return self.schedule

    @override
    def _setup(self, spec: MediumSpec, seed: int, record: bool) -> None:
        a = spec.access
        radio = spec.radio
        assert isinstance(a, Sps) and radio is not None
        m = len(self.nodes)
        self.sps = a
        self.vrows = np.zeros((rk.NVS, m), dtype=np.int64)
        self.vrows[[rk.T_SF, rk.VB_LEN, rk.VK_HANDED, rk.VD_AT]] = -1
        self.schedule.vs = self.vrows
        #: per vehicle: its scheduling draws' key
        self.skey = np.array([key64(seed, "sidelink", self.index, int(node), "sps") for node in self.nodes],
                             dtype=np.uint64)
        #: what each vehicle heard of each other's reservation: (subframe, interval, first
        #: sub-channel, sub-channels; never heard: a subframe long past) and its power (mW)
        self.kn = np.zeros((m, m, 4), dtype=np.int64)
        self.kn[:, :, 0] = -(1 << 40)
        self.kr = np.zeros((m, m))
        #: each vehicle's power per sub-channel over the last 1000 subframes, whether it
        #: transmitted in each, and which subframe each ring entry holds
        self.rssi = np.zeros((m, rk.WINDOW_SF, a.subchannels))
        self.txh = np.zeros((m, rk.WINDOW_SF), dtype=np.bool_)
        self.tag = np.full(rk.WINDOW_SF, -1, dtype=np.int64)
        self._istx = np.zeros(m, dtype=np.int64)
        cands = a.budget_ms * a.subchannels
        self._ex = np.zeros(cands, dtype=np.bool_)
        #: the estimators' packets whose budget ran out in the waiting room (numbers), per engine call
        self._gone = np.zeros(m * self.queue.shape[1], dtype=np.int64)
        self._metric = np.zeros(cands)
        lo, hi = a.counter_range
        q = spec.queue
        self.sp = np.zeros(rk.NSP, dtype=np.int64)
        self.sp[[rk.SP_S, rk.SP_BYTES, rk.SP_P, rk.SP_LO, rk.SP_HI, rk.SP_BUDGET, rk.SP_ONESHOT, rk.SP_T, rk.SP_RX,
                 rk.SP_PL]] = a.subchannels, a.subchannel_bytes, a.rri_ms, lo, hi, a.budget_ms, \
            int(a.misfit == "one_shot"), self.T_ns, self.rule[0], self.pl_kind
        self.sp[rk.SP_MAXP] = -1 if q is None or q.packets is None else q.packets
        self.sp[rk.SP_MAXB] = -1 if q is None or q.bytes is None else q.bytes
        self.sp[rk.SP_RECORD] = int(record)
        self.sf = np.zeros(rk.NSF)
        self.sf[[rk.SF_POWER, rk.SF_SIGMA, rk.SF_ZMAX, rk.SF_ZSTEPS, rk.SF_SENS, rk.SF_NOISE, rk.SF_SHARE, rk.SF_KEEP,
                 rk.SF_RSRP, rk.SF_STEP, rk.SF_FRAC, rk.SF_CBR, rk.SF_WIDTH, rk.SF_FLOOR]] = \
            radio.power, self.sigma, Z_MAX, Z_STEPS, self.sens, self.noise, a.noise_share, a.p_keep, \
            mw(a.rsrp_threshold), 10.0 ** (a.threshold_step / 10.0), a.candidates, mw(a.cbr_threshold), self.width, \
            self.floor

    @override
    def _grew_slots(self, size: int, old: int) -> None:
        sx = np.zeros((size, 4), dtype=np.int64)
        if old:
            sx[:old] = self.sx[:old]
        self.sx = sx

    @override
    def _push_args(self) -> tuple:
        return (self.E, self.vrows, self.queue, self._gone, self.skey, self.kn, self.kr, self.rssi, self.txh, self.tag,
                self.sp, self.sf, self._ex, self._metric)

    @override
    def _state(self) -> tuple:
        return (self.E, self.vrows, self.queue, self._gone, self.bg, self.skey, self._rkeys, self.nodes, self._x, self._y,
                self.absent, self.p, self.d, self.u, self.fate, self.si, self.sx, self.free, self.onair, self._loss,
                self.kn, self.kr, self.rssi, self.txh, self.tag, self._istx, self.pairs, self.fates, self.ticks,
                self._window, self._counted, self.periods, self.dropped, self.log, self.own, self.sp, self.sf, self._plp,
                *self._tables, self._ex, self._metric)

    @override
    def _grow(self, what: int) -> None:
        super()._grow(what)
        if what == rk.G_QUEUE:
            self._gone = np.zeros(self.queue.size // 4, dtype=np.int64)

    @override
    def _arrive(self, radio: Radio, frame: Frame, now: int) -> bool:
        self.E[rk.E_NGONE] = 0
        ok = super()._arrive(radio, frame, now)
        self._expired()
        return ok

    @override
    def _ended(self) -> None:
        super()._ended()
        self._expired()

    def _expired(self) -> None:
        """The estimators' packets whose budget ran out before they could go: refused (their
        port counts them ``queue_dropped``)."""
        n = int(self.E[rk.E_NGONE])
        for fid in self._gone[:n].tolist():
            frame = self._frames.pop(fid)
            self.pending -= 1
            self._refused[frame.owner] = self._refused.get(frame.owner, 0) + 1
            if frame.done is not None:
                frame.done(frame, False)
        self.E[rk.E_NGONE] = 0

    @override
    def stats(self, end_ns: int) -> dict[str, float | int]:
        """:meth:`SpatialChannel.stats`, the background packets whose budget ran out among the
        dropped."""
        out = super().stats(end_ns)
        out["background_dropped"] = int(out["background_dropped"]) + int(self.E[rk.E_EXPIRED])
        return out

    # ------------------------------------------------------------------ busy time
    @override
    def busy_unit(self, span_ns: int) -> float:
        """The sub-channel-subframes of ``span_ns``."""
        return span_ns / rk.SUBFRAME * self.sps.subchannels

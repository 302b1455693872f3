"""The spatial radio (``medium.radio``, issue 32; docs/radio.md): a shared channel where each
receiver decides for itself.

The waiting rooms, background, generation jitter and wake-ups are the one-domain
:class:`~dkfsim.network.media.channel.Channel`'s; what differs is what a transmission does.  A
frame sent by ``s`` at ``ts`` reaches every other member ``r`` at the power of
:mod:`dkfsim.components.radio` (path loss at their distance at the tick of ``ts``, keyed
shadowing and fading per frame and receiver), and at ``r``:

- below ``sensitivity`` it is not detected (lost: ``sensing``);
- at or above ``carrier_sense`` ``r`` senses the medium busy while it is on the air (its access
  rule freezes; :mod:`~dkfsim.network.media.slotted`), below it ``r`` may transmit over it;
- ``r`` locks on it when ``r`` is neither transmitting nor locked on another frame, else it is
  lost (``receiver_busy``); of frames starting at one instant a free receiver locks on the
  strongest; a receiver that starts transmitting loses the frame it was locked on
  (``receiver_busy``); with ``capture: X`` a locked receiver switches to a later frame at least
  ``X`` dB stronger (the first is then lost: ``collision``);
- a locked frame is received by the ``reception`` rule from its SINR over the frame, chunk by
  chunk as the interference (every other frame on the air at ``r``) changes, with a keyed
  uniform per frame and receiver; lost, it is ``propagation`` when it would have been lost
  without interference too (or had none), else ``collision``.

So hidden terminals, spatial reuse and capture emerge.  Each (frame, receiver) pair is counted
once, in ``pdr_by_distance`` and by cause; a receiver's channel busy ratio (CBR) is the time it
senses the medium busy (its own transmissions included).
"""

from __future__ import annotations

from array import array
from collections.abc import Iterator, Mapping
from typing import Any

import numpy as np
from typing_extensions import override

from dkfsim.components.medium import Medium as MediumSpec
from dkfsim.components.radio import (
    Z_MAX,
    Z_STEPS,
    Lognormal,
    PerTable,
    fading_table,
    normal_quantiles,
    path_loss_db,
)
from dkfsim.core.backend import Backend
from dkfsim.core.jit import bind
from dkfsim.core.registry import MEDIA
from dkfsim.core.streams import key64, keyed_uniforms
from dkfsim.network import radio_kernels as rk
from dkfsim.network.media.base import Frame
from dkfsim.network.media.channel import NEVER, Access, Channel
from dkfsim.network.media.slotted import SlottedAccess

#: The causes of a lost (frame, receiver) pair, named as the analytic 802.11p model names them
#: (:data:`~dkfsim.network.radio_kernels.SENSING` ...).
CAUSES = ("sensing", "receiver_busy", "propagation", "collision")
#: Receivers per frame in a draw's sequence number (a frame's draws: ``seq = k * SEQ + node``).
SEQ = 1 << 24


def _mw(dbm: float) -> float:
    return float(10.0 ** (dbm / 10.0))


def reception_rule(model: Any) -> tuple[int, np.ndarray, np.ndarray]:
    """``medium.radio.reception`` as :func:`~dkfsim.network.radio_kernels.error_rate` reads it:
    (kind, SINR points dB, PER points; a threshold's one point)."""
    if isinstance(model, PerTable):
        return rk.TABLE, np.array([x for x, _ in model.table]), np.array([y for _, y in model.table])
    return rk.THRESHOLD, np.array([model.sinr]), np.zeros(1)


def _fill(p: np.ndarray, u: np.ndarray, slot: int, loss: np.ndarray, keys: np.ndarray, handed: int, seq0: int,
          nodes: np.ndarray, i: int, power: float, sigma: float, table: np.ndarray, z_max: float, z_steps: float,
          absent: np.ndarray) -> None:
    """:func:`~dkfsim.network.radio_kernels.fill` on the numpy path: the same bits, vectorised
    over the members (tests/test_radio.py)."""
    draws = keyed_uniforms(keys[:, None], handed, seq0 + nodes)        # (shadow, fade, rx) x members
    dbm = power - loss
    if sigma > 0.0:
        dbm = dbm - sigma * normal_quantiles(draws[0])
    if len(table) > 1:
        x = (np.clip(normal_quantiles(draws[1]), -z_max, z_max) + z_max) * z_steps
        j = np.minimum(x.astype(np.int64), len(table) - 2)
        lo = table[j]
        dbm = dbm + (lo + (x - j) * (table[j + 1] - lo))
    row = p[slot]
    row[:] = [10.0 ** x for x in (dbm / 10.0).tolist()]       # (the C library's pow, as compiled: not numpy's)
    row[i] = 0.0
    if absent[i]:
        row[:] = -1.0
    else:
        row[absent] = -1.0
    u[slot] = draws[2]


class Losses(Mapping[int, bool]):
    """A frame's :attr:`~dkfsim.network.media.base.Frame.lost_at` on the radio: receiver node ->
    whether it lost the frame to a collision, for the members that lost it, read from the
    frame's fates (a copy): a port asks only of its links' receivers, so nothing is built for
    the hundreds of others."""

    __slots__ = ("fate", "pos_of", "nodes")

    def __init__(self, fate: np.ndarray, pos_of: dict[int, int], nodes: np.ndarray):
        self.fate, self.pos_of, self.nodes = fate, pos_of, nodes

    def __getitem__(self, node: int) -> bool:
        i = self.pos_of.get(node)
        if i is None or self.fate[i] in (rk.RECEIVED, rk.SENDER):
            raise KeyError(node)
        return bool(self.fate[i] == rk.COLLISION)

    def __contains__(self, node: object) -> bool:
        i = self.pos_of.get(node) if isinstance(node, int) else None
        return i is not None and self.fate[i] not in (rk.RECEIVED, rk.SENDER)

    def _lost(self) -> np.ndarray:
        return np.flatnonzero((self.fate != rk.RECEIVED) & (self.fate != rk.SENDER))

    def __iter__(self) -> Iterator[int]:
        return iter(self.nodes[self._lost()].tolist())

    def __len__(self) -> int:
        return len(self._lost())


class RadioChannel(Channel):
    """One copy of the spatial radio channel (see the module).

    :param positions: every node's position (m) at ticks ``0 .. K``, ``(K + 1, n, 2)``; a frame
        started in ``[t_k, t_{k+1})`` sees the positions of tick ``k``.
    """

    #: the frames on the air, a row each (:mod:`~dkfsim.network.radio_kernels`): power (mW),
    #: distance (m), decision draws, each pair's fate, who senses it; sender, start and end
    overlapping = True                      # (a radio that senses nothing may start over a frame)
    p: np.ndarray
    d: np.ndarray
    u: np.ndarray
    fate: np.ndarray
    sensed: np.ndarray
    si: np.ndarray

    def __init__(self, env: Any, spec: MediumSpec, members: tuple[int, ...], seed: int, positions: np.ndarray,
                 T_ns: int, index: int = 0, record: bool = False, backend: Backend | None = None,
                 presence: np.ndarray | None = None):
        radio = spec.radio
        assert radio is not None
        self.params = radio
        super().__init__(env, spec, members, seed, index, record, T_ns, backend)
        backend = self.backend
        k = rk.compiled() if backend.compiled else rk
        m = len(members)
        self.nodes = np.asarray(members, dtype=np.int64)
        self.pos_of = {node: i for i, node in enumerate(members)}
        self.positions = np.asarray(positions, dtype=np.float64)[:, list(members), :]
        #: their x and y, each contiguous per tick
        self._x, self._y = np.ascontiguousarray(self.positions[:, :, 0]), np.ascontiguousarray(self.positions[:, :, 1])
        #: whether each member is off the road at each tick; one that is sends nothing and is no
        #: receiver
        self.absent = np.zeros((len(self.positions), m), dtype=np.bool_) if presence is None else \
            ~np.asarray(presence, dtype=bool)[:, list(members)]
        self._anyone_absent = bool(self.absent.any())
        self.noise, self.sens, self.cs = _mw(radio.noise), _mw(radio.sensitivity), _mw(radio.carrier_sense)
        #: shadowing's sigma (dB; 0: none) and the fading gain (dB) tabulated against the normal
        #: quantile (:func:`~dkfsim.components.radio.fading_table`; fewer than two points: none)
        self.sigma = radio.shadowing.sigma if isinstance(radio.shadowing, Lognormal) else 0.0
        self.fade_table = fading_table(radio.fading)
        self.capture = 0.0 if radio.capture is None else _mw(radio.capture)
        self.rule = reception_rule(radio.reception)
        #: per member: the keys of its frames' shadowing, fading and decision draws
        self._keys = {node: np.array([key64(seed, "radio", index, node, what) for what in ("shadow", "fade", "rx")],
                                     dtype=np.uint64) for node in members}
        #: per sender: (hand-over instant, frames started with it) for the draws' keys
        self._keyed: dict[int, tuple[int, int]] = {}
        self.ri = np.zeros((rk.NRI, m), dtype=np.int64)
        self.ri[rk.LOCKED] = -1
        self.rf = np.zeros((rk.NRF, m))
        self.rf[rk.LOCK_AIR] = 1.0
        self._went = np.zeros(m, dtype=np.int64)
        #: the frames on the air, a slot each (their rows of p, d, u, fate, sensed, si)
        self._slot_of: dict[int, Frame] = {}
        self._free: list[int] = []
        self._grow(8)
        # statistics
        self.edges = radio.bins.edges()
        self.width = float(self.edges[1])
        self.pairs = np.zeros((len(self.edges) - 1, 5), dtype=np.int64)
        self.fates = np.zeros(5, dtype=np.int64)
        self.started_frames = 0
        #: each member's busy ns per tick (row ``k``: ``[k T, (k+1) T)``; the last row, beyond)
        self.ticks = np.zeros((len(self.positions), m), dtype=np.int64)
        #: whose frames' pairs are counted: started in ``[window[0], window[1])`` (by default the
        #: run, its positions' ticks) by a ``counted`` member (:meth:`measure`)
        self._window = np.array([0, (len(self.positions) - 1) * T_ns], dtype=np.int64)
        self._counted = np.ones(m, dtype=np.bool_)
        kind, tab_x, tab_y = self.rule
        i1 = np.zeros(1, dtype=np.int64)
        self._close = bind(k.close, self.ri, self.rf, kind, tab_x, tab_y, 1.0, 0)
        self._fill_k = bind(k.fill, self.p, self.u, 0, np.zeros(m), self._keys[members[0]], 0, 0, self.nodes, 0, 1.0,
                            1.0, self.fade_table, 1.0, 1.0, self.absent[0]) if backend.compiled else _fill
        self._start_k = bind(k.start, self.ri, self.rf, self.p, self.fate, self.sensed, self.si, i1, 0, 1.0, 1.0,
                             1.0, self._went)
        self._end_k = bind(k.end, self.ri, self.rf, self.p, self.d, self.u, self.fate, self.sensed, self.si, i1, 0,
                           kind, tab_x, tab_y, 1.0, 1.0, self.pairs, self.fates, self._went, self.ticks, 1,
                           self._window, self._counted)

    def _grow(self, size: int) -> None:
        """Room for ``size`` frames on the air at once (the slots' rows, kept)."""
        m = len(self.nodes)
        old = len(self.si) if hasattr(self, "si") else 0

        def grown(a: np.ndarray | None, dtype: Any) -> np.ndarray:
            new = np.zeros((size, m), dtype=dtype)
            if a is not None:
                new[:old] = a
            return new
        self.p = grown(self.p if old else None, np.float64)
        self.d = grown(self.d if old else None, np.float64)
        self.u = grown(self.u if old else None, np.float64)
        self.fate = grown(self.fate if old else None, np.int8)
        self.sensed = grown(self.sensed if old else None, np.bool_)
        si = np.zeros((size, 3), dtype=np.int64)
        if old:
            si[:old] = self.si
        self.si = si
        self._free.extend(range(size - 1, old - 1, -1))

    @override
    def make_access(self, spec: MediumSpec, seed: int) -> Access:
        """The access rule as each radio runs it on its own view of the medium: a
        :class:`~dkfsim.network.media.slotted.SlottedAccess` (a one-domain rule names its
        per-radio form as ``on_radio``)."""
        impl = MEDIA.get(spec.access.kind).implementation
        impl = getattr(impl, "on_radio", None) or impl
        if not issubclass(impl, SlottedAccess):
            raise ValueError(f"medium.access.kind {spec.access.kind!r} is a rule for one collision domain; "
                             "with medium.radio give a rule each radio runs on its own view (edca or csma)")
        self.slotted = impl(spec.access, self, seed)
        return self.slotted

    # ------------------------------------------------------------------ the air
    def _fill(self, slot: int, node: int, i: int, handed: int, seq0: int, ts: int) -> None:
        """Slot ``slot``'s rows for a frame sent by ``node`` (member ``i``) at ``ts``: its distance
        to every member and the path loss there (the model's, vectorised), then its power (mW) and
        decision draws (:func:`~dkfsim.network.radio_kernels.fill`)."""
        rp = self.params
        k = min(ts // self.T_ns, len(self._x) - 1)
        x, y = self._x[k], self._y[k]
        d = np.hypot(x - x[i], y - y[i], out=self.d[slot])
        loss = path_loss_db(rp.path_loss, d, rp.frequency)
        self._fill_k(self.p, self.u, slot, loss, self._keys[node], handed, seq0, self.nodes, i, rp.power,
                     self.sigma, self.fade_table, Z_MAX, float(Z_STEPS), self.absent[k])

    @override
    def sends(self, node: int, t: int) -> bool:
        """A member off the road at ``t`` sends none of its background then."""
        absent = self.absent
        return not self._anyone_absent or not absent[min(t // self.T_ns, len(absent) - 1), self.pos_of[node]]

    @override
    def _start(self, ts: int) -> None:
        starters = self.access.start(ts)
        if not starters:
            raise RuntimeError(f"radio channel: no head is due at {ts} ns")
        kind, tab_x, tab_y = self.rule
        self._close(self.ri, self.rf, kind, tab_x, tab_y, self.noise, ts)
        if len(self._free) < len(starters):
            self._grow(2 * len(self.si) + len(starters))
        slots = np.empty(len(starters), dtype=np.int64)
        for n, radio in enumerate(starters):
            frame = radio.queue.popleft()
            radio.queued_bytes -= frame.size
            frame.start = ts
            frame.end = ts + self.airtime(frame.size)
            radio.on_air = frame
            self.on_air.append(frame)
            node = radio.node
            i = self.pos_of[node]
            handed, k = self._keyed.get(node, (-1, 0))
            k = k + 1 if handed == frame.handed else 0
            self._keyed[node] = (frame.handed, k)
            slot = self._free.pop()
            self._fill(slot, node, i, frame.handed, k * SEQ, ts)
            self.si[slot] = (i, ts, frame.end)
            self._slot_of[slot] = frame
            slots[n] = slot
            self.started_frames += 1
            self._periods.extend((ts, frame.end, 1, frame.done is None, 0))
        went = self._start_k(self.ri, self.rf, self.p, self.fate, self.sensed, self.si, slots, ts, self.sens,
                             self.cs, self.capture, self._went)
        self.slotted.busy(self._went, ts, went)
        self._next_end = min(f.end for f in self.on_air)

    @override
    def _end(self, te: int) -> None:
        ending = sorted((slot for slot, f in self._slot_of.items() if f.end == te), key=lambda s: self.si[s, 0])
        kind, tab_x, tab_y = self.rule
        self._close(self.ri, self.rf, kind, tab_x, tab_y, self.noise, te)
        slots = np.asarray(ending, dtype=np.int64)
        went = self._end_k(self.ri, self.rf, self.p, self.d, self.u, self.fate, self.sensed, self.si, slots, te,
                           kind, tab_x, tab_y, self.noise, self.width, self.pairs, self.fates, self._went,
                           self.ticks, self.T_ns, self._window, self._counted)
        frames = [self._slot_of.pop(slot) for slot in ending]
        if not self._slot_of:
            self.rf[rk.TOTAL] = 0.0             # (nothing on the air: no rounding left over)
        self.slotted.clear(self._went, te, self.ri[rk.RXERR], went)     # (their errors read and cleared)
        self.on_air = [f for f in self.on_air if f.end != te]
        self._next_end = min((f.end for f in self.on_air), default=NEVER)
        radios, access, nodes = self.radios, self.access, self.nodes
        for slot, frame in zip(ending, frames):
            fate = self.fate[slot]
            self._free.append(slot)
            radio = radios[frame.node]
            radio.on_air = None
            if self.ended is not None:
                lost = np.flatnonzero((fate != rk.RECEIVED) & (fate != rk.SENDER))
                self.ended.append((frame.node, frame.start, frame.end, len(lost) < len(nodes) - 1, frame.done is None))
            if frame.done is not None:
                self.pending -= 1
                frame.lost_at = Losses(fate.copy(), self.pos_of, nodes)
                own = self._owned.get(frame.owner)
                if own is None:
                    own = self._owned[frame.owner] = array("q")
                own.extend((frame.end, bool((fate == rk.COLLISION).any()), frame.start - frame.handed))
                frame.done(frame, True)
            if self._sent is not None:
                self._sent(radio, te)
            if radio.queue:
                access.head(radio, te)

    # ------------------------------------------------------------------ statistics
    def measure(self, senders: Any = None, start: int = 0, end: int | None = None) -> None:
        """Count from now on only the pairs of frames that ``senders`` (members' node numbers;
        None: every member) start in ``[start, end)`` ns (``end`` None: the run's last tick) --
        e.g. the vehicles away from a road's ends, for a comparison with a model of an endless
        road (tests/test_radio_analytic.py).  CBR is every member's as before."""
        if senders is not None:
            self._counted[:] = False
            self._counted[[self.pos_of[int(node)] for node in senders]] = True
        self._window[:] = (start, self._window[1] if end is None else end)

    def busy_per_tick(self, T_ns: int, K: int) -> np.ndarray:
        """(K, members): ns each member sensed the medium busy (its own transmissions included) in
        ``[k T, (k+1) T)``, ``k = 0 .. K-1``, periods still open counted up to now (the channel
        brought up to ``K T`` or now)."""
        now = min(K * T_ns, self.env.now)
        self.advance(now)
        ticks = np.zeros((K, len(self.nodes)))
        rows = min(K, len(self.ticks) - 1)       # (the kernel's last row holds what lies beyond)
        ticks[:rows] = self.ticks[:rows]
        ri = self.ri
        for r in np.flatnonzero(ri[rk.SENSE_N] > 0).tolist():
            a = int(ri[rk.BUSY_FROM, r])
            for k in range(a // T_ns, min(K, -(-now // T_ns))):
                ticks[k, r] += min(now, (k + 1) * T_ns) - max(a, k * T_ns)
        return ticks

    def cbr(self, end_ns: int) -> np.ndarray:
        """Each member's channel busy ratio over ``[0, end_ns]``: the time it sensed the medium
        busy over ``end_ns`` -- exact while the channel has not gone past ``end_ns``, else from the
        per-tick rows (whole ticks; a last partial tick counts its share of its tick)."""
        if end_ns <= 0:
            return np.zeros(len(self.nodes))
        now = min(end_ns, self.env.now)
        self.advance(now)
        if self.now <= end_ns:
            ri = self.ri
            return (ri[rk.BUSY_NS] + np.where(ri[rk.SENSE_N] > 0, now - ri[rk.BUSY_FROM], 0)) / end_ns
        T = self.T_ns
        K = -(-end_ns // T)
        busy = self.busy_per_tick(T, K)
        total = busy[: end_ns // T].sum(axis=0)
        if end_ns % T:
            total = total + busy[-1] * ((end_ns % T) / T)
        return total / end_ns

    @override
    def series(self, owner: Any, T_ns: int, K: int) -> dict[str, np.ndarray]:
        """Each member's CBR per tick as ``run.npz`` keeps it: ``cbr`` (K, members), row ``k`` the
        busy fraction of ``[k T, (k+1) T)``, and ``cbr_nodes`` (members,)."""
        return {"cbr": self.busy_per_tick(T_ns, K) / T_ns, "cbr_nodes": self.nodes.copy()}

    @override
    def report(self, owner: Any, end: int) -> dict[str, Any]:
        """The one-domain block (``frames``, ``frames_collided``: the owner's frames some receiver
        lost to a collision, ...; ``utilisation``: the mean CBR) and the radio's own:
        ``pdr_by_distance`` (``bins_m``: the bins' edges, ``pdr`` per bin, null where no pair
        fell, ``frames``: the (frame, receiver) pairs per bin, and each cause's count per bin),
        ``cbr`` per member and ``cbr_mean``, ``losses``: every pair lost, by cause."""
        out = super().report(owner, end)
        cbr = self.cbr(end)
        pairs = self.pairs
        frames = pairs.sum(axis=1)
        with np.errstate(invalid="ignore", divide="ignore"):
            pdr = pairs[:, rk.RECEIVED] / frames
        block: dict[str, Any] = {"bins_m": [float(x) for x in self.edges], "pdr": [None if f == 0 else float(x)
                                                                             for x, f in zip(pdr, frames)],
                                 "frames": frames.tolist()}
        for c, name in enumerate(CAUSES, start=1):
            block[name] = pairs[:, c].tolist()
        out.update(utilisation=float(cbr.mean()) if len(cbr) else 0.0, cbr=[float(x) for x in cbr],
                   cbr_mean=float(cbr.mean()) if len(cbr) else 0.0, pdr_by_distance=block,
                   losses={name: int(self.fates[c]) for c, name in enumerate(CAUSES, start=1)},
                   pairs=int(self.fates.sum()), pairs_received=int(self.fates[rk.RECEIVED]))
        return out

    @override
    def stats(self, end_ns: int) -> dict[str, float | int]:
        """Frames on the air and the background's, as the one-domain channel counts them (a
        frame ``collided`` when some receiver lost it to a collision is not known per period
        here: ``collisions`` counts the pairs lost to a collision)."""
        self.advance(min(end_ns, self.env.now))
        p = np.frombuffer(self._periods, dtype=np.int64).reshape(-1, 5)
        p = p[p[:, 0] < end_ns]
        dropped = np.frombuffer(self._dropped, dtype=np.int64)
        return {"utilisation": 0.0, "frames_on_air": int(len(p)), "collisions": int(self.fates[rk.COLLISION]),
                "background_sent": int(p[:, 3].sum()), "background_collided": 0,
                "background_dropped": int((dropped <= end_ns).sum())}


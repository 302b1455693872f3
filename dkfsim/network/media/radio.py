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
from typing import Any

import numpy as np
from typing_extensions import override

from dkfsim.components.medium import Medium as MediumSpec
from dkfsim.components.radio import error_rate, fading_db, path_loss_db, shadowing_db
from dkfsim.core.registry import MEDIA
from dkfsim.core.streams import key64, keyed_uniforms
from dkfsim.network.media.channel import NEVER, Access, Channel
from dkfsim.network.media.slotted import SlottedAccess

#: The fate of a (frame, receiver) pair: received, or the cause of its loss (named as the
#: analytic 802.11p model names them); the sender's own entry is :data:`SENDER`.
RECEIVED, SENSING, RECEIVER_BUSY, PROPAGATION, COLLISION = range(5)
CAUSES = ("sensing", "receiver_busy", "propagation", "collision")
PENDING, SENDER = 5, -1
#: Receivers per frame in a draw's sequence number (a frame's draws: ``seq = k * SEQ + node``).
SEQ = 1 << 24


def _mw(dbm: float) -> float:
    return float(10.0 ** (dbm / 10.0))


class _OnAir:
    """A frame on the air: its sender's position ``i``, its power (mW) and distance (m) at every
    member, which members sense it, and each pair's fate."""

    __slots__ = ("frame", "i", "id", "p", "d", "sensed", "fate", "t_key", "seq0")

    def __init__(self, frame: Any, i: int, ident: int, p: np.ndarray, d: np.ndarray, t_key: int, seq0: int):
        self.frame, self.i, self.id, self.p, self.d = frame, i, ident, p, d
        self.t_key, self.seq0 = t_key, seq0
        self.sensed: np.ndarray = np.zeros(0, dtype=bool)
        self.fate: np.ndarray = np.zeros(0, dtype=np.int8)


class RadioChannel(Channel):
    """One copy of the spatial radio channel (see the module).

    :param positions: every node's position (m) at ticks ``0 .. K``, ``(K + 1, n, 2)``; a frame
        started in ``[t_k, t_{k+1})`` sees the positions of tick ``k``.
    """

    def __init__(self, env: Any, spec: MediumSpec, members: tuple[int, ...], seed: int, positions: np.ndarray,
                 T_ns: int, index: int = 0, record: bool = False):
        radio = spec.radio
        assert radio is not None
        self.params = radio
        super().__init__(env, spec, members, seed, index, record, T_ns)
        m = len(members)
        self.nodes = np.asarray(members, dtype=np.int64)
        self.pos_of = {node: i for i, node in enumerate(members)}
        self.positions = np.asarray(positions, dtype=np.float64)[:, list(members), :]
        self.noise, self.sens, self.cs = _mw(radio.noise), _mw(radio.sensitivity), _mw(radio.carrier_sense)
        self.capture = None if radio.capture is None else _mw(radio.capture)
        self._keys = {node: tuple(key64(seed, "radio", index, node, what) for what in ("shadow", "fade", "rx"))
                      for node in members}
        #: per sender: (hand-over instant, frames started with it) for the draws' keys
        self._keyed: dict[int, tuple[int, int]] = {}
        self._air: dict[int, _OnAir] = {}
        self._ids = 0
        # each receiver
        self.locked = np.full(m, -1, dtype=np.int64)
        self.lock_p = np.zeros(m)
        self.lock_air = np.ones(m)
        self.logpsr = np.zeros(m)
        self.chunk_t = np.zeros(m, dtype=np.int64)
        self.interfered = np.zeros(m, dtype=bool)
        self.tx = np.zeros(m, dtype=bool)
        self.total = np.zeros(m)                 # mW of every frame on the air at each member
        self.n_air = np.zeros(m, dtype=np.int64)  # frames on the air each member receives power of
        self.sense_n = np.zeros(m, dtype=np.int64)
        self.busy_from = np.zeros(m, dtype=np.int64)
        self.busy_ns = np.zeros(m, dtype=np.int64)
        self.rx_error = np.zeros(m, dtype=bool)
        # statistics
        self.edges = radio.bins.edges()
        self.pairs = np.zeros((len(self.edges) - 1, 5), dtype=np.int64)
        self.fates = np.zeros(5, dtype=np.int64)
        self.started_frames = 0
        self._owned_lost: dict[Any, list[int]] = {}

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

    @override
    def start_time(self, access: Access) -> int:
        return access.next_start()            # (a radio that senses nothing may start over a frame)

    @override
    def wake_time(self) -> int:
        access = self.access
        ts = access.next_start()
        return min(self._next_end, ts + access.next_airtime() if ts < NEVER else NEVER)

    # ------------------------------------------------------------------ the air
    def _received_power(self, node: int, i: int, handed: int, seq0: int, ts: int) -> tuple[np.ndarray, np.ndarray]:
        """(mW, m) of a frame sent by ``node`` (member ``i``) at every member, and the distances."""
        rp = self.params
        k = min(ts // self.T_ns, len(self.positions) - 1)
        xy = self.positions[k]
        d = np.hypot(xy[:, 0] - xy[i, 0], xy[:, 1] - xy[i, 1])
        dbm = rp.power - path_loss_db(rp.path_loss, d, rp.frequency)
        shadow, fade, _ = self._keys[node]
        seq = seq0 + self.nodes
        if rp.shadowing.model != "none":
            dbm = dbm - shadowing_db(rp.shadowing, keyed_uniforms(shadow, handed, seq))
        if rp.fading.model != "none":
            dbm = dbm + fading_db(rp.fading, keyed_uniforms(fade, handed, seq))
        p = 10.0 ** (dbm / 10.0)
        p[i] = 0.0
        return p, d

    def _close(self, t: int) -> None:
        """Every locked receiver's chunk up to ``t`` (its interference is about to change)."""
        idx = np.flatnonzero((self.locked >= 0) & (self.chunk_t < t))
        if not len(idx):
            return
        lp = self.lock_p[idx]
        sinr = lp / (self.noise + np.maximum(self.total[idx] - lp, 0.0))
        per = error_rate(self.params.reception, 10.0 * np.log10(sinr))
        frac = (t - self.chunk_t[idx]) / self.lock_air[idx]
        with np.errstate(divide="ignore"):
            self.logpsr[idx] += frac * np.log1p(-per)
        self.chunk_t[idx] = t

    @override
    def _start(self, ts: int) -> None:
        starters = self.access.start(ts)
        if not starters:
            raise RuntimeError(f"radio channel: no head is due at {ts} ns")
        self._close(ts)
        new: list[_OnAir] = []
        for radio in starters:
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
            p, d = self._received_power(node, i, frame.handed, k * SEQ, ts)
            self._ids += 1
            new.append(_OnAir(frame, i, self._ids, p, d, frame.handed, k * SEQ))
            self.started_frames += 1
            self._periods.extend((ts, frame.end, 1, frame.done is None, 0))
        locked, tx = self.locked, self.tx
        for rec in new:                       # half duplex: a sender loses what it was receiving
            i = rec.i
            if locked[i] >= 0:
                self._air[int(locked[i])].fate[i] = RECEIVER_BUSY
                locked[i] = -1
            tx[i] = True
        powers = np.stack([rec.p for rec in new])
        strongest = powers.argmax(axis=0)
        free = (locked < 0) & ~tx
        for f, rec in enumerate(new):
            p = rec.p
            detected = p >= self.sens
            fate = np.where(detected, RECEIVER_BUSY, SENSING).astype(np.int8)
            lock = free & detected & (strongest == f)
            if self.capture is not None:       # a locked receiver switches to a much stronger frame
                switch = (locked >= 0) & detected & (strongest == f) & (p >= self.lock_p * self.capture)
                for r in np.flatnonzero(switch).tolist():
                    self._air[int(locked[r])].fate[r] = COLLISION
                lock |= switch
            fate[lock] = PENDING
            fate[rec.i] = SENDER
            rec.fate = fate
            locked[lock] = rec.id
            self.lock_p[lock] = p[lock]
            self.lock_air[lock] = rec.frame.end - ts
            self.logpsr[lock] = 0.0
            self.chunk_t[lock] = ts
            self.interfered[lock] = False
            rec.sensed = p >= self.cs
            rec.sensed[rec.i] = True
            self._air[rec.id] = rec
            self.total += p
            self.n_air += p > 0
        busy = locked >= 0
        self.interfered[busy] |= self.n_air[busy] > 1
        before = self.sense_n.copy()
        for rec in new:
            self.sense_n += rec.sensed
        went = np.flatnonzero((before == 0) & (self.sense_n > 0))
        self.busy_from[went] = ts
        self.slotted.busy(went, ts)
        self._next_end = min(f.end for f in self.on_air)

    @override
    def _end(self, te: int) -> None:
        ending = sorted((rec for rec in self._air.values() if rec.frame.end == te), key=lambda rec: rec.i)
        self._close(te)
        before = self.sense_n.copy()
        reception = self.params.reception
        for rec in ending:
            L = np.flatnonzero(self.locked == rec.id)
            if len(L):
                lp = self.lock_p[L]
                psr_noise = 1.0 - error_rate(reception, 10.0 * np.log10(lp / self.noise))
                psr = np.exp(self.logpsr[L])
                u = keyed_uniforms(self._keys[rec.frame.node][2], rec.t_key, rec.seq0 + self.nodes[L])
                ok = u < psr
                alone = ~self.interfered[L] | (u >= psr_noise)
                rec.fate[L] = np.where(ok, RECEIVED, np.where(alone, PROPAGATION, COLLISION))
                self.rx_error[L] = ~ok
                self.locked[L] = -1
            del self._air[rec.id]
            self.total -= rec.p
            self.n_air -= rec.p > 0
            self.sense_n -= rec.sensed
            self.tx[rec.i] = False
            self._count_pairs(rec)
        if not self._air:
            self.total[:] = 0.0
        went = np.flatnonzero((before > 0) & (self.sense_n == 0))
        self.busy_ns[went] += te - self.busy_from[went]
        self.slotted.clear(went, te, self.rx_error[went])
        self.rx_error[went] = False
        self.on_air = [f for f in self.on_air if f.end != te]
        self._next_end = min((f.end for f in self.on_air), default=NEVER)
        radios, access, nodes = self.radios, self.access, self.nodes
        for rec in ending:
            frame = rec.frame
            radio = radios[frame.node]
            radio.on_air = None
            lost = np.flatnonzero((rec.fate != RECEIVED) & (rec.fate != SENDER))
            if self.ended is not None:
                self.ended.append((frame.node, frame.start, frame.end, len(lost) < len(nodes) - 1, frame.done is None))
            if frame.done is not None:
                self.pending -= 1
                frame.lost_at = dict(zip(nodes[lost].tolist(), (rec.fate[lost] == COLLISION).tolist()))
                own = self._owned.get(frame.owner)
                if own is None:
                    own = self._owned[frame.owner] = array("q")
                own.extend((frame.end, bool((rec.fate == COLLISION).any()), frame.start - frame.handed))
                frame.done(frame, True)
            access.sent(radio, te)
            if radio.queue:
                access.head(radio, te)

    def _count_pairs(self, rec: _OnAir) -> None:
        fate = rec.fate
        pair = fate >= 0
        self.fates += np.bincount(fate[pair], minlength=5)[:5]
        width = float(self.edges[1])
        b = (rec.d // width).astype(np.int64)
        keep = pair & (b < len(self.pairs))
        self.pairs += np.bincount(b[keep] * 5 + fate[keep], minlength=self.pairs.size).reshape(self.pairs.shape)

    # ------------------------------------------------------------------ statistics
    def cbr(self, end_ns: int) -> np.ndarray:
        """Each member's channel busy ratio over ``[0, end_ns]``: the time it sensed the medium
        busy (its own transmissions included) over ``end_ns``, brought up to ``end_ns`` or now."""
        now = min(end_ns, self.env.now)
        self.advance(now)
        busy = self.busy_ns + np.where(self.sense_n > 0, now - self.busy_from, 0)
        return busy / end_ns if end_ns > 0 else np.zeros(len(busy))

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
            pdr = pairs[:, RECEIVED] / frames
        block: dict[str, Any] = {"bins_m": [float(x) for x in self.edges], "pdr": [None if f == 0 else float(x)
                                                                             for x, f in zip(pdr, frames)],
                                 "frames": frames.tolist()}
        for c, name in enumerate(CAUSES, start=1):
            block[name] = pairs[:, c].tolist()
        out.update(utilisation=float(cbr.mean()) if len(cbr) else 0.0, cbr=[float(x) for x in cbr],
                   cbr_mean=float(cbr.mean()) if len(cbr) else 0.0, pdr_by_distance=block,
                   losses={name: int(self.fates[c]) for c, name in enumerate(CAUSES, start=1)},
                   pairs=int(self.fates.sum()), pairs_received=int(self.fates[RECEIVED]))
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
        return {"utilisation": 0.0, "frames_on_air": int(len(p)), "collisions": int(self.fates[COLLISION]),
                "background_sent": int(p[:, 3].sum()), "background_collided": 0,
                "background_dropped": int((dropped <= end_ns).sum())}


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
  ``X`` dB stronger (within ``capture_window`` of the first's start, if given; the first is then
  lost: ``collision``);
- a locked frame is received by the ``reception`` rule from its SINR over the frame, chunk by
  chunk as the interference (every other frame on the air at ``r``) changes, with a keyed
  uniform per frame and receiver; lost, it is ``propagation`` when it would have been lost
  without interference too (or had none), else ``collision``.

So hidden terminals, spatial reuse and capture emerge.  Each (frame, receiver) pair is counted
once, in ``pdr_by_distance`` and by cause; a receiver's channel busy ratio (CBR) is the time it
senses the medium busy (its own transmissions included).
"""

from __future__ import annotations

import math
from array import array
from collections.abc import Callable, Iterator, Mapping
from types import ModuleType
from typing import Any, ClassVar

import numpy as np
from typing_extensions import override

from dkfsim.components.medium import Medium as MediumSpec
from dkfsim.components.radio import (
    C_LIGHT,
    MIN_DISTANCE_M,
    Z_MAX,
    Z_STEPS,
    FreeSpace,
    LogDistance,
    Lognormal,
    NoLoss,
    PerTable,
    TwoRayInterference,
    WinnerB1,
    fading_table,
)
from dkfsim.core.backend import Backend
from dkfsim.core.jit import bind
from dkfsim.core.registry import MEDIA
from dkfsim.core.streams import key64
from dkfsim.network import radio_kernels as rk
from dkfsim.network.media.base import Frame
from dkfsim.network.media.channel import NEVER, Access, Channel, Radio
from dkfsim.network.media.slotted import SlottedAccess


def mw(dbm: float) -> float:
    """A power in dBm as mW."""
    return float(10.0 ** (dbm / 10.0))


def reception_rule(model: Any) -> tuple[int, np.ndarray, np.ndarray]:
    """``medium.radio.reception`` as :func:`~dkfsim.network.radio_kernels.error_rate` reads it:
    (kind, SINR points dB, PER points; a threshold's one point)."""
    if isinstance(model, PerTable):
        return rk.TABLE, np.array([x for x, _ in model.table]), np.array([y for _, y in model.table])
    return rk.THRESHOLD, np.array([model.sinr]), np.zeros(1)


def path_loss_form(model: Any, frequency: float) -> tuple[int, np.ndarray]:
    """``medium.radio.path_loss`` as :func:`~dkfsim.network.radio_kernels.path_loss` reads it:
    (model, parameters) -- the models of :func:`dkfsim.components.radio.path_loss_db`, which a test
    holds the compiled form to."""
    plp = np.zeros(6)
    plp[rk.P_MIN_D], plp[rk.P_FREQ], plp[rk.P_C] = MIN_DISTANCE_M, frequency, C_LIGHT
    if isinstance(model, NoLoss):
        return rk.PL_NONE, plp
    if isinstance(model, FreeSpace):
        return rk.PL_FREE_SPACE, plp
    if isinstance(model, LogDistance):
        d0 = model.reference_distance
        plp[rk.P_A], plp[rk.P_C2] = d0, model.exponent
        plp[rk.P_B] = model.reference_loss if model.reference_loss is not None else \
            20.0 * math.log10(4.0 * math.pi * d0 * frequency / C_LIGHT)
        return rk.PL_LOG_DISTANCE, plp
    if isinstance(model, TwoRayInterference):
        plp[rk.P_A], plp[rk.P_B] = model.height, model.permittivity
        return rk.PL_TWO_RAY, plp
    if isinstance(model, WinnerB1):
        plp[rk.P_A] = model.height - model.environment_height
        return rk.PL_WINNER_B1, plp
    raise TypeError(f"no path-loss model {type(model).__name__}")


class Losses(Mapping[int, bool]):
    """A frame's :attr:`~dkfsim.network.media.base.Frame.lost_at` on the radio: receiver node ->
    whether it lost the frame to a collision, for the members that lost it -- every member but
    the sender that did not receive it, those off the road included -- read from the frame's
    fates (a copy): a port asks only of its links' receivers, so nothing is built for the
    hundreds of others."""

    __slots__ = ("fate", "pos_of", "nodes", "collided", "sender")

    def __init__(self, fate: np.ndarray, pos_of: dict[int, int], nodes: np.ndarray,
                 collided: tuple[int, ...] = (rk.COLLISION,), sender: int = -1):
        self.fate, self.pos_of, self.nodes, self.collided, self.sender = fate, pos_of, nodes, collided, sender

    def __getitem__(self, node: int) -> bool:
        i = self.pos_of.get(node)
        if i is None or i == self.sender or self.fate[i] == rk.RECEIVED:
            raise KeyError(node)
        return int(self.fate[i]) in self.collided

    def __contains__(self, node: object) -> bool:
        i = self.pos_of.get(node) if isinstance(node, int) else None
        return i is not None and i != self.sender and self.fate[i] != rk.RECEIVED

    def _lost(self) -> np.ndarray:
        lost = self.fate != rk.RECEIVED
        if self.sender >= 0:
            lost[self.sender] = False
        return np.flatnonzero(lost)

    def __iter__(self) -> Iterator[int]:
        return iter(self.nodes[self._lost()].tolist())

    def __len__(self) -> int:
        return len(self._lost())


class SpatialChannel(Channel):
    """What every access on the spatial radio shares (802.11p's :class:`RadioChannel`, the C-V2X
    sidelink's :class:`~dkfsim.network.media.sidelink.SidelinkChannel`): the members' positions
    and presence, the frames' keyed powers, the waiting rooms and background as arrays, the
    estimators' frames by number, the compiled engine's statuses, the pairs counted by distance
    and cause.  A subclass names its engine (:attr:`KERNELS`), its per-vehicle rows, its causes
    and its busy time.

    :param positions: every node's position (m) at ticks ``0 .. K``, ``(K + 1, n, 2)``; a frame
        started in ``[t_k, t_{k+1})`` sees the positions of tick ``k``.
    """

    overlapping = True                      # (a radio that senses nothing may start over a frame)
    #: an access that is a spatial channel of its own (the sidelink's) runs on the radio
    #: (:attr:`~dkfsim.network.media.channel.Access.spatial`)
    spatial: ClassVar[bool] = True
    #: the causes of a lost pair this access reports, by name and fate code
    CAUSES: ClassVar[tuple[tuple[str, int], ...]] = ()
    #: the fate codes a port counts as ``collision_lost``
    COLLIDED: ClassVar[tuple[int, ...]] = (rk.COLLISION,)
    #: fate codes in ``pairs`` and ``fates``
    NFATES: ClassVar[int] = 5
    #: the rows of the per-vehicle array holding the background block's position and length
    B_ROWS: ClassVar[tuple[int, int]] = (rk.B_POS, rk.B_LEN)
    #: the engine's run and push kernels (:mod:`~dkfsim.network.radio_kernels`), taking
    #: :meth:`_state` and :meth:`_push_args`
    KERNELS: ClassVar[tuple[str, str]] = ("run", "push")
    #: the slots of frames on the air, a row each (:mod:`~dkfsim.network.radio_kernels`): power
    #: (mW), distance (m), decision draws, each pair's fate; sender, start, end, frame number and
    #: hand-over; the slots on the air, the free ones, the estimators' frames that ended
    p: np.ndarray
    d: np.ndarray
    u: np.ndarray
    fate: np.ndarray
    si: np.ndarray
    onair: np.ndarray
    free: np.ndarray
    own: np.ndarray
    #: per vehicle: the engine's rows (waiting room, background block, ... :data:`B_ROWS`)
    vrows: np.ndarray

    def __init__(self, env: Any, spec: MediumSpec, members: tuple[int, ...], seed: int, positions: np.ndarray,
                 T_ns: int, index: int = 0, record: bool = False, backend: Backend | None = None,
                 presence: np.ndarray | None = None):
        radio = spec.radio
        assert radio is not None
        if list(members) != sorted(members):
            raise ValueError("a radio channel's members must be in increasing order")
        self.params = radio
        super().__init__(env, spec, members, seed, index, record, T_ns, backend)
        m = len(members)
        self.nodes = np.asarray(members, dtype=np.int64)
        self.pos_of = {node: i for i, node in enumerate(members)}
        self.positions = np.asarray(positions, dtype=np.float64)[:, list(members), :]
        #: their x and y, each contiguous per tick
        self._x, self._y = np.ascontiguousarray(self.positions[:, :, 0]), np.ascontiguousarray(self.positions[:, :, 1])
        #: whether each member is off the road at each tick; one that is sends nothing and is no
        #: receiver; C-ordered, as every array the engine takes (one compiled signature)
        self.absent = np.zeros((len(self.positions), m), dtype=np.bool_) if presence is None else \
            np.ascontiguousarray(~np.asarray(presence, dtype=bool)[:, list(members)])
        self.noise, self.sens = mw(radio.noise), mw(radio.sensitivity)
        self.floor = 0.0 if radio.interference_floor is None else mw(radio.interference_floor)
        self.rule = reception_rule(radio.reception)
        self.pl_kind, self._plp = path_loss_form(radio.path_loss, radio.frequency)
        self.sigma = radio.shadowing.sigma if isinstance(radio.shadowing, Lognormal) else 0.0
        #: per member: the keys of its frames' shadowing, fading and decision draws
        self._rkeys = np.array([[key64(seed, "radio", index, node, what) for what in ("shadow", "fade", "rx")]
                                for node in members], dtype=np.uint64).reshape(m, 3)
        self._tables = (fading_table(radio.fading), self.rule[1], self.rule[2])
        # the engine's state (radio_kernels, "the engine's state")
        self.E = np.zeros(rk.NE, dtype=np.int64)
        self.E[rk.E_NEXT_END] = NEVER
        self.queue = np.zeros((m, 4, 4), dtype=np.int64)
        self.bg = np.zeros((m, 64, 3), dtype=np.int64)
        self._loss = np.zeros(m)
        self.p = np.zeros((0, m))
        # statistics
        self.edges = radio.bins.edges()
        self.width = float(self.edges[1])
        self.pairs = np.zeros((len(self.edges) - 1, self.NFATES), dtype=np.int64)
        self.fates = np.zeros(self.NFATES, dtype=np.int64)
        #: each member's busy time per tick (row ``k``: ``[k T, (k+1) T)``; the last row, beyond)
        self.ticks = np.zeros((len(self.positions), m), dtype=np.int64)
        #: whose frames' pairs are counted: started in ``[window[0], window[1])`` (by default the
        #: run, its positions' ticks) by a ``counted`` member (:meth:`measure`)
        self._window = np.array([0, (len(self.positions) - 1) * T_ns], dtype=np.int64)
        self._counted = np.ones(m, dtype=np.bool_)
        #: every frame started: (start, end, 1, background, 0); the instants of background frames
        #: a full waiting room dropped; with ``record``, every frame ended (:attr:`ended`)
        self.periods = np.zeros((256, 5), dtype=np.int64)
        self.dropped = np.zeros(64, dtype=np.int64)
        self.log = np.zeros((64 if record else 0, 5), dtype=np.int64)
        #: the estimators' frames in the waiting rooms or on the air, by number
        self._frames: dict[int, Frame] = {}
        self._fid = 0
        self._takes = [2] * m
        self._setup(spec, seed, record)
        self._grow_slots(8)
        for i, node in enumerate(members):
            if self.radios[node].background is not None:
                self._refill(i)
        self._run, self._push = self._engine(rk.compiled() if self.backend.compiled else rk)

    def _setup(self, spec: MediumSpec, seed: int, record: bool) -> None:
        """The access's own state (its per-vehicle rows :attr:`vrows` among it)."""
        raise NotImplementedError

    def _engine(self, k: ModuleType) -> tuple[Callable, Callable]:
        """The engine's run and push kernels of ``k`` (compiled or not; :attr:`KERNELS`), bound."""
        run, push = (getattr(k, name) for name in self.KERNELS)
        return (rk.quiet(bind(run, 0, 0, *self._state())),
                rk.quiet(bind(push, 0, 0, 0, 0, 0, 0, *self._push_args())))

    def _state(self) -> tuple:
        """The engine's arrays, in its run kernel's order."""
        raise NotImplementedError

    def _push_args(self) -> tuple:
        """The arrays the push kernel takes after the frame's own arguments."""
        raise NotImplementedError

    def _grow_slots(self, size: int) -> None:
        """Room for ``size`` frames on the air at once (the slots' rows kept; the new ones free)."""
        m = len(self.nodes)
        old = len(self.p)
        first = old == 0

        def grown(a: np.ndarray | None, shape: tuple, dtype: Any) -> np.ndarray:
            new = np.zeros(shape, dtype=dtype)
            if a is not None and old:
                new[:old] = a[:old]
            return new
        self.p = grown(self.p, (size, m), np.float64)
        self.d = grown(None if first else self.d, (size, m), np.float64)
        self.u = grown(None if first else self.u, (size, m), np.float64)
        self.fate = grown(None if first else self.fate, (size, m), np.int8)
        self.si = grown(None if first else self.si, (size, rk.NSI), np.int64)
        self.onair = grown(None if first else self.onair, (size,), np.int64)
        nfree = int(self.E[rk.E_NFREE])
        free = np.zeros(size, dtype=np.int64)
        if not first:
            free[:nfree] = self.free[:nfree]
        free[nfree:nfree + size - old] = np.arange(size - 1, old - 1, -1)
        self.free = free
        self.E[rk.E_NFREE] = nfree + size - old
        self.own = np.zeros(size, dtype=np.int64)
        self._grew_slots(size, old)

    def _grew_slots(self, size: int, old: int) -> None:
        """The access's own per-slot arrays grown from ``old`` to ``size`` rows."""

    def _grow(self, what: int) -> None:
        """Double the buffer the engine found full (:data:`~dkfsim.network.radio_kernels.GROW`)."""
        if what == rk.G_SLOTS:
            self._grow_slots(2 * len(self.p) + len(self.nodes))
        elif what == rk.G_QUEUE:
            m, cap = self.queue.shape[:2]
            head = self.vrows[self.Q_ROWS[0]]
            order = (head[:, None] + np.arange(cap)) % cap    # (each ring unrolled from its head)
            queue = np.zeros((m, 2 * cap, 4), dtype=np.int64)
            queue[:, :cap] = np.take_along_axis(self.queue, order[:, :, None], axis=1)
            self.queue = queue
            head[:] = 0
        elif what == rk.G_PERIODS:
            self.periods = np.concatenate([self.periods, np.zeros_like(self.periods)])
        elif what == rk.G_DROPPED:
            self.dropped = np.concatenate([self.dropped, np.zeros_like(self.dropped)])
        else:
            self._drain_log()
            self.log = np.zeros((2 * len(self.log) + len(self.p), 5), dtype=np.int64)

    #: the rows of the per-vehicle array holding the waiting room's first entry and length
    Q_ROWS: ClassVar[tuple[int, int]] = (rk.Q_HEAD, rk.Q_LEN)

    def _refill(self, i: int) -> None:
        """Radio ``i``'s next background packets into its block, never splitting an instant: 4
        at first, twice as many each time up to the block's width (a short run of hundreds of
        radios draws few)."""
        bg = self.radios[int(self.nodes[i])].background
        assert bg is not None
        want = self._takes[i] = min(2 * self._takes[i], self.bg.shape[1])
        times, sizes = bg.take(want)
        n = len(times)
        if n > self.bg.shape[1]:
            wide = np.zeros((self.bg.shape[0], 2 * n, 3), dtype=np.int64)
            wide[:, :self.bg.shape[1]] = self.bg
            self.bg = wide
        row = self.bg[i]
        row[:n, rk.G_TIME] = times
        row[:n, rk.G_SIZE] = sizes
        row[:n, rk.G_AIR] = [self.airtime(size) for size in sizes]
        pos, length = self.B_ROWS
        self.vrows[pos, i], self.vrows[length, i] = 0, n

    # ------------------------------------------------------------------ the engine
    @override
    def _arrive(self, radio: Radio, frame: Frame, now: int) -> bool:
        i = self.pos_of[radio.node]
        if self.vrows[self.Q_ROWS[1], i] >= self.queue.shape[1]:
            self._grow(rk.G_QUEUE)
        fid = self._fid
        self.E[rk.E_NHOOK] = 0
        ok = self._push(i, frame.size, frame.handed, fid, self.airtime(frame.size), now, *self._push_args())
        if ok:
            self._frames[fid] = frame
            self._fid += 1
        self._changed()                     # (a head may be due now: the wake-up must see it)
        self._called_back()
        return bool(ok)

    @override
    def advance(self, t: int) -> None:
        """Bring the channel up to instant ``t`` (:meth:`Channel.advance`), in the engine: it
        returns to Python only for what Python keeps (see the class)."""
        if t <= self.now:
            return
        held = self._held
        while True:
            th = held[0][0] if held else NEVER
            status = self._run(t, th, *self._state())
            self._changed()
            if status == rk.DONE:
                break
            if status == rk.YIELD:
                self._called_back()
                self._ended()
            elif status == rk.HELD:
                self._release(th)
            elif status == rk.REFILL:
                self._refill(int(self.E[rk.E_ARG]))
            else:
                self._grow(int(self.E[rk.E_ARG]))
        self.now = t
        if self.ended is not None:
            self._drain_log()

    def _changed(self) -> None:
        """The engine ran: what Python caches of its state is stale."""

    def _called_back(self) -> None:
        """The calls the engine left to Python (a researcher's access rule's), in order."""

    def _ended(self) -> None:
        """The estimators' frames that ended: each told its fates (``lost_at``) and counted."""
        n = int(self.E[rk.E_NOWN])
        collided = list(self.COLLIDED)
        for s in self.own[:n].tolist():
            frame = self._frames.pop(int(self.si[s, rk.S_FID]))
            frame.start, frame.end = int(self.si[s, rk.S_START]), int(self.si[s, rk.S_END])
            fate = self.fate[s].copy()
            self.pending -= 1
            frame.lost_at = Losses(fate, self.pos_of, self.nodes, self.COLLIDED, int(self.si[s, rk.S_I]))
            own = self._owned.get(frame.owner)
            if own is None:
                own = self._owned[frame.owner] = array("q")
            own.extend((frame.end, bool(np.isin(fate, collided).any()), frame.start - frame.handed))
            assert frame.done is not None
            frame.done(frame, True)
        self.E[rk.E_NOWN] = 0

    def _drain_log(self) -> None:
        """The engine's log of ended frames into :attr:`ended` (with ``record``)."""
        n = int(self.E[rk.E_NLOG])
        if self.ended is not None and n:
            self.ended.extend((a, b, c, bool(ok), bool(bg)) for a, b, c, ok, bg in self.log[:n].tolist())
        self.E[rk.E_NLOG] = 0

    @override
    def first_end(self) -> int:
        return int(self.E[rk.E_NEXT_END])

    @property
    def started_frames(self) -> int:
        """Frames started so far."""
        return int(self.E[rk.E_STARTED])

    # ------------------------------------------------------------------ statistics
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

    @override
    def series(self, owner: Any, T_ns: int, K: int) -> dict[str, np.ndarray]:
        """Each member's CBR per tick as ``run.npz`` keeps it: ``cbr`` (K, members), row ``k`` the
        busy fraction of ``[k T, (k+1) T)``, and ``cbr_nodes`` (members,)."""
        return {"cbr": self.busy_per_tick(T_ns, K) / self.busy_unit(T_ns), "cbr_nodes": self.nodes.copy()}

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
        for name, c in self.CAUSES:
            block[name] = pairs[:, c].tolist()
        out.update(utilisation=float(cbr.mean()) if len(cbr) else 0.0, cbr=[float(x) for x in cbr],
                   cbr_mean=float(cbr.mean()) if len(cbr) else 0.0, pdr_by_distance=block,
                   losses={name: int(self.fates[c]) for name, c in self.CAUSES},
                   pairs=int(self.fates.sum()), pairs_received=int(self.fates[rk.RECEIVED]))
        return out

    @override
    def stats(self, end_ns: int) -> dict[str, float | int]:
        """Frames on the air and the background's, as the one-domain channel counts them (a
        frame ``collided`` when some receiver lost it to a collision is not known per period
        here: ``collisions`` counts the pairs lost to a collision)."""
        self.advance(min(end_ns, self.env.now))
        p = self.periods[:int(self.E[rk.E_NPER])]
        p = p[p[:, 0] < end_ns]
        dropped = self.dropped[:int(self.E[rk.E_NDROP])]
        return {"utilisation": 0.0, "frames_on_air": int(len(p)),
                "collisions": int(sum(self.fates[c] for c in self.COLLIDED)),
                "background_sent": int(p[:, 3].sum()), "background_collided": 0,
                "background_dropped": int((dropped <= end_ns).sum())}

    def busy_unit(self, span_ns: int) -> float:
        """What a member's busy amount over ``span_ns`` is out of (:meth:`busy_per_tick`'s unit;
        a whole tick's for ``T_ns``): the time itself."""
        return float(span_ns)

    def busy_per_tick(self, T_ns: int, K: int) -> np.ndarray:
        """(K, members): each member's busy amount (:meth:`busy_unit`) in ``[k T, (k+1) T)``, ``k =
        0 .. K-1``, as the engine's rows hold it (the channel brought up to ``K T`` or now; the
        rows' last holds what lies beyond)."""
        self.advance(min(K * T_ns, self.env.now))
        ticks = np.zeros((K, len(self.nodes)))
        rows = min(K, len(self.ticks) - 1)
        ticks[:rows] = self.ticks[:rows]
        return ticks

    def cbr(self, end_ns: int) -> np.ndarray:
        """Each member's channel busy ratio over ``[0, end_ns]``: its busy amount (:meth:`busy_until`)
        over the whole (:meth:`busy_unit`)."""
        if end_ns <= 0:
            return np.zeros(len(self.nodes))
        return self.busy_until(end_ns) / self.busy_unit(end_ns)

    def busy_until(self, end_ns: int) -> np.ndarray:
        """Each member's busy amount over ``[0, end_ns]`` (``end_ns > 0``) from the per-tick rows
        (:meth:`busy_per_tick`): whole ticks, and a last partial tick its share of its tick."""
        T = self.T_ns
        busy = self.busy_per_tick(T, -(-end_ns // T))
        total = busy[: end_ns // T].sum(axis=0)
        if end_ns % T:
            total = total + busy[-1] * ((end_ns % T) / T)
        return total


class RadioChannel(SpatialChannel):
    """One copy of the spatial radio channel under a per-radio CSMA rule (``edca``, ``csma``;
    see the module).

    Its events run in a compiled engine (:func:`~dkfsim.network.radio_kernels.run`) over arrays:
    the waiting rooms, each radio's background, the access rule's counts, the frames on the air
    and the receivers.  Python keeps the estimators' frames (numbered into the waiting rooms),
    the frames held back by generation jitter, and the calls back: an estimator's frame that
    ended, a researcher's access rule.
    """

    #: the causes of a lost pair, named as the analytic 802.11p model names them
    CAUSES = (("sensing", rk.SENSING), ("receiver_busy", rk.RECEIVER_BUSY), ("propagation", rk.PROPAGATION),
              ("collision", rk.COLLISION))
    #: who senses each frame on the air; a scratch list of slots; a researcher's rule's calls back
    sensed: np.ndarray
    sl: np.ndarray
    hooks: np.ndarray

    @override
    def _setup(self, spec: MediumSpec, seed: int, record: bool) -> None:
        radio = spec.radio
        assert radio is not None
        m = len(self.nodes)
        self.cs = mw(radio.carrier_sense)
        self.capture = 0.0 if radio.capture is None else mw(radio.capture)
        cwin = math.inf if radio.capture_window is None else round(radio.capture_window * 1e9)
        self.ri = np.zeros((rk.NRI, m), dtype=np.int64)
        self.ri[rk.LOCKED] = -1
        self.rf = np.zeros((rk.NRF, m))
        self.rf[rk.LOCK_AIR] = 1.0
        self.vrows = np.zeros((rk.NRQ, m), dtype=np.int64)
        self.vrows[[rk.ON_AIR, rk.B_LEN, rk.K_HANDED]] = -1
        self._went = np.zeros(m, dtype=np.int64)
        self._sbuf = np.zeros(m, dtype=np.int64)
        acc = self.slotted
        q = spec.queue
        self.ip = np.zeros(rk.NIP, dtype=np.int64)
        self.ip[[rk.I_RULE, rk.I_SLOT, rk.I_CW, rk.I_AIFS, rk.I_EIFS, rk.I_T, rk.I_RECORD, rk.I_PL, rk.I_RX]] = \
            acc.rule, acc.slot, acc.cw, acc.aifs, acc.eifs, self.T_ns, int(record), self.pl_kind, self.rule[0]
        self.ip[rk.I_MAXP] = -1 if q is None or q.packets is None else q.packets
        self.ip[rk.I_MAXB] = -1 if q is None or q.bytes is None else q.bytes
        self.ip[rk.I_SENT] = int(acc.rule == rk.CUSTOM and type(acc).sent is not Access.sent)
        self.fp = np.zeros(rk.NFP)
        self.fp[[rk.F_POWER, rk.F_SIGMA, rk.F_ZMAX, rk.F_ZSTEPS, rk.F_SENS, rk.F_CS, rk.F_NOISE, rk.F_CAPTURE,
                 rk.F_WIDTH, rk.F_FLOOR, rk.F_CWIN]] = radio.power, self.sigma, Z_MAX, Z_STEPS, self.sens, self.cs, \
            self.noise, self.capture, self.width, self.floor, cwin

    @override
    def _grew_slots(self, size: int, old: int) -> None:
        m = len(self.nodes)
        sensed = np.zeros((size, m), dtype=np.bool_)
        if old:
            sensed[:old] = self.sensed[:old]
        self.sensed = sensed
        self.sl = np.zeros(size, dtype=np.int64)
        self.hooks = np.zeros((2 * size + 4, 3), dtype=np.int64)

    @override
    def _push_args(self) -> tuple:
        return (self.E, self.vrows, self.queue, *self._access, self.hooks, self.ip)

    @override
    def _state(self) -> tuple:
        acc = self.slotted
        return (self.E, self.vrows, self.queue, self.bg, acc.idle_at, acc.origin, acc.count, acc.due, acc.head_on,
                acc.air, acc.bkey, acc.dr, self._rkeys, self.nodes, self._x, self._y, self.absent, self.ri, self.rf,
                self.p, self.d, self.u, self.fate, self.sensed, self.si, self.free, self.onair, self._sbuf, self.sl,
                self._went, self._loss, self.pairs, self.fates, self.ticks, self._window, self._counted,
                self.periods, self.dropped, self.log, self.own, self.hooks, self.ip, self.fp, self._plp,
                *self._tables)

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

    @property
    def _access(self) -> tuple:
        acc = self.slotted
        return acc.idle_at, acc.origin, acc.count, acc.due, acc.head_on, acc.air, acc.bkey, acc.dr

    @override
    def _changed(self) -> None:
        self.slotted.changed()

    @override
    def _called_back(self) -> None:
        n = int(self.E[rk.E_NHOOK])
        if not n:
            return
        acc, nodes = self.slotted, self.nodes
        for what, i, t in self.hooks[:n].tolist():
            if what == rk.H_HEAD:
                acc.on_head(i, t, bool(acc.idle_at[i] >= 0))
            else:
                acc.sent(self.radios[int(nodes[i])], t)
        self.E[rk.E_NHOOK] = 0
        acc.changed()

    # ------------------------------------------------------------------ busy time
    @override
    def busy_per_tick(self, T_ns: int, K: int) -> np.ndarray:
        """(K, members): ns each member sensed the medium busy (its own transmissions included) in
        ``[k T, (k+1) T)``, ``k = 0 .. K-1``, periods still open counted up to now (the channel
        brought up to ``K T`` or now)."""
        ticks = super().busy_per_tick(T_ns, K)
        now = min(K * T_ns, self.env.now)
        ri = self.ri
        for r in np.flatnonzero(ri[rk.SENSE_N] > 0).tolist():
            a = int(ri[rk.BUSY_FROM, r])
            for k in range(a // T_ns, min(K, -(-now // T_ns))):
                ticks[k, r] += min(now, (k + 1) * T_ns) - max(a, k * T_ns)
        return ticks

    @override
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
        return super().cbr(end_ns)


#: 802.11p's causes of a lost (frame, receiver) pair by name (:attr:`RadioChannel.CAUSES`).
CAUSES = tuple(name for name, _ in RadioChannel.CAUSES)

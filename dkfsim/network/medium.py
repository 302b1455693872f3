"""The shared radio channel (``medium:``; docs/design.md §3, "A shared radio channel").

One :class:`Channel` is one collision domain: every member senses every other.  Each member
has one radio, a first-in-first-out waiting room of frames (its estimators' and its
background's) whose head contends for the channel under slotted CSMA with a backoff for every
frame:

- the channel's slot boundaries after it last became idle at ``t_idle`` are
  ``t_idle + aifs + m * slot``, ``m = 0, 1, ...`` (``t_idle = 0`` at the start);
- a frame that becomes its radio's head at ``h`` draws a backoff ``b`` uniform in
  ``0 .. cw`` (the keyed draw ``("channel", c, node, "backoff")`` at ``(h, attempt)``,
  ``attempt`` the number of earlier draws of that node at ``h``), joins at the first boundary
  at or after ``h`` and is sent ``b`` boundaries later if the channel stays idle;
- a transmission that starts first freezes the other heads' remaining counts (boundaries
  not yet passed), which resume from the next idle period's boundaries;
- frames that start at one boundary collide: each is lost for every receiver; the channel
  is busy until the longest ends;
- when its frame ends, a radio with more frames draws a fresh backoff (keyed by that instant).

The engine is event driven over the run's SimPy environment, and lazy: its state is brought
up to date (:meth:`Channel.advance`) when a frame is offered and by wake-up events while an
estimator's frame waits or is on the air, about one per frame, at a transmission's end (never
one per slot; :meth:`Channel._wake`).  Its statistics come from a log of busy periods, so they
are those of any instant however far the channel has been brought.  At one instant it takes the transmission ends, then the arrivals
(background first, then the estimators' frames as they are handed over), then a start at a
boundary -- so a frame handed over exactly at a boundary joins it.
"""

from __future__ import annotations

from array import array
from collections import deque
from collections.abc import Callable
from heapq import heapify, heappop, heappush
from typing import Any

import numpy as np
from simpy.events import URGENT, Event

from dkfsim.components.medium import Medium
from dkfsim.components.traffic import transmission_ns
from dkfsim.core.params import MAX_NS, seconds_to_ns
from dkfsim.core.streams import key64, keyed_uniform
from dkfsim.network.events import Scheduled
from dkfsim.network.transmitter import BackgroundArrivals

_NEVER = MAX_NS + 1


class Frame:
    """One frame on the channel: its sender, size, hand-over instant and, for an estimator's
    frame, what it carries and whom to tell when it ends (``done(frame, ok)``; None: a
    background frame)."""

    __slots__ = ("node", "size", "handed", "parts", "done", "start", "end")

    def __init__(self, node: int, size: int, handed: int, parts: Any = None,
                 done: Callable[[Frame, bool], None] | None = None):
        self.node, self.size, self.handed, self.parts, self.done = node, size, handed, parts, done
        self.start = self.end = -1


class Radio:
    """One member's radio: its waiting room (the head contending, the frame on the air apart),
    its backoff state and its background."""

    __slots__ = ("node", "queue", "queued_bytes", "on_air", "key", "drawn_at", "drawn", "background")

    def __init__(self, node: int, key: int, background: BackgroundArrivals | None):
        self.node = node
        self.queue: deque[Frame] = deque()
        self.queued_bytes = 0
        self.on_air: Frame | None = None
        self.key = key
        self.drawn_at, self.drawn = -1, 0
        self.background = background


class Channel:
    """One copy of the shared channel (each estimator's port has its own unless shared).

    :param spec: the scenario's :class:`~dkfsim.components.medium.Medium`.
    :param members: the nodes on the channel.
    :param index: the channel's number ``c`` in its draws' keys (one channel: 0).
    :param record: keep ``(node, start, end, ok, background)`` of every frame that ended
        (:attr:`ended`; for the checks of the access rule).
    """

    def __init__(self, env: Any, spec: Medium, members: tuple[int, ...], seed: int, index: int = 0,
                 record: bool = False):
        self.env = env
        self.spec = spec
        self.slot, self.aifs, self.cw = spec.access.slot_ns, spec.access.aifs_ns, int(spec.access.cw)
        self.rate, self.preamble = float(spec.rate), seconds_to_ns(spec.preamble)
        self.max_packets = spec.queue.packets if spec.queue is not None else None
        self.max_bytes = spec.queue.bytes if spec.queue is not None else None
        self._bounded = spec.queue is not None
        self.radios: dict[int, Radio] = {}
        #: the contending heads (a frame waiting, none on the air): ``(boundary, node, airtime)``,
        #: a heap; ``boundary`` counts the idle boundaries of the whole run (:attr:`passed` of
        #: earlier idle periods, then this one's), so freezing changes no entry
        self._heads: list[tuple[int, int, int]] = []
        #: the boundaries of the earlier idle periods that passed (each period: those before the
        #: boundary at which its transmission started)
        self.passed = 0
        self._airtimes: dict[int, int] = {}
        #: (instant of the next background frame, node) of every member with background
        self._arrivals: list[tuple[int, int]] = []
        for node in members:
            prefix = ("channel", index, node)
            bg = BackgroundArrivals(spec.background, prefix, seed) if spec.background is not None else None
            self.radios[node] = Radio(node, key64(seed, *prefix, "backoff"), bg)
            if bg is not None:
                self._arrivals.append((bg.next_time(), node))
        heapify(self._arrivals)
        self.t_idle = 0
        #: the frames on the air (one, or several colliding)
        self.on_air: list[Frame] = []
        #: when the first frame on the air ends (never: none on the air)
        self._next_end = _NEVER
        self.collided = False
        #: the instant processed up to (ends and arrivals at it included, starts before it)
        self.now = -1
        self._next_start: int | None = None
        #: the shortest airtime of the heads due at :meth:`next_start`
        self._next_air = 1
        #: estimators' frames waiting or on the air (wake-ups are needed only while any is)
        self.pending = 0
        self._wakes: set[int] = set()
        # statistics
        #: every busy period: (start, end, frames, background frames, collided), flat; and
        #: the instants of background frames a full waiting room dropped (:meth:`stats` reads
        #: them as of any instant, however far the channel has been brought)
        self._periods = array("q")
        self._dropped = array("q")
        #: with ``record``: (node, start, end, ok, background) of every frame that ended
        self.ended: list[tuple[int, int, int, bool, bool]] | None = [] if record else None

    # ------------------------------------------------------------------ offering
    def offer(self, frame: Frame) -> bool:
        """Hand over ``frame`` now at its node's radio: False when the waiting room is full
        (drop-tail: nothing of it is sent)."""
        now = self.env.now
        if now > self.now:                  # (brought to now already: nothing to do, decision 235)
            self.advance(now)
        ok = self._arrive(self.radios[frame.node], frame, now)
        if ok:
            self.pending += 1
        self._wake()
        return ok

    def _arrive(self, radio: Radio, frame: Frame, now: int) -> bool:
        queue = radio.queue
        if self._bounded:
            if self.max_packets is not None and len(queue) >= self.max_packets:
                return False
            if self.max_bytes is not None and radio.queued_bytes + frame.size > self.max_bytes:
                return False
        queue.append(frame)
        radio.queued_bytes += frame.size
        if radio.on_air is None and len(queue) == 1:
            self._head(radio, now)
        return True

    def airtime(self, size: int) -> int:
        """ns a frame of ``size`` bytes is on the air: the preamble plus ``size * 8 / rate``
        (:func:`~dkfsim.components.traffic.transmission_ns`), at least 1 ns."""
        air = self._airtimes.get(size)
        if air is None:
            air = self._airtimes[size] = max(1, min(self.preamble + transmission_ns(size, self.rate), MAX_NS))
        return air

    def _head(self, radio: Radio, t: int) -> None:
        """The radio's first waiting frame becomes head at ``t``: a fresh backoff, counted from
        the first boundary at or after ``t`` (the next idle period's first while the channel is
        busy)."""
        if radio.drawn_at != t:
            radio.drawn_at = t
            drawn = 0
        else:
            drawn = radio.drawn
        radio.drawn = drawn + 1
        cw = self.cw
        count = int(keyed_uniform(radio.key, t, drawn) * (cw + 1))
        if count > cw:                      # (a draw next to 1 may round up to cw + 1)
            count = cw
        first = self.t_idle + self.aifs
        join = 0 if self.on_air or t <= first else -(-(t - first) // self.slot)
        size = radio.queue[0].size
        air = self._airtimes.get(size)
        heappush(self._heads, (self.passed + join + count, radio.node,
                               air if air is not None else self.airtime(size)))
        self._next_start = None

    # ------------------------------------------------------------------ the engine

    def next_start(self) -> int:
        """When the next transmission starts if nothing more is handed over (never: no head,
        or the channel busy)."""
        if self.on_air:
            return _NEVER
        if self._next_start is None:
            heads = self._heads
            if not heads:
                self._next_start = _NEVER
            else:
                best = heads[0][0]
                self._next_start = self.t_idle + self.aifs + (best - self.passed) * self.slot
                # the heads tied with the first are a subtree at the top of the heap: none when
                # neither child of the root is
                n = len(heads)
                if (n > 1 and heads[1][0] == best) or (n > 2 and heads[2][0] == best):
                    self._next_air = min(air for b, _, air in heads if b == best)
                else:
                    self._next_air = heads[0][2]
        return self._next_start

    def advance(self, t: int) -> None:
        """Bring the channel up to instant ``t``: every transmission end and arrival at or
        before ``t`` and every start before ``t``, in time order.

        Brought to ``t`` once, it has nothing more to do at ``t`` (so a second call returns at
        once; many frames are offered at one instant): what is handed over at ``t`` joins a
        boundary at or after ``t``, so it adds no start before ``t`` and no end or arrival at it."""
        if t <= self.now:
            return
        arrivals = self._arrivals
        while True:
            te = self._next_end
            ta = arrivals[0][0] if arrivals else _NEVER
            if self.on_air:
                ts = _NEVER
            else:
                cached = self._next_start
                ts = cached if cached is not None else self.next_start()
            if te <= t and te <= ta:
                self._end(te)
            elif ta <= t and ta <= ts:
                self._background(ta)
            elif ts < t:
                self._start(ts)
            else:
                break
        self.now = t

    def _background(self, ta: int) -> None:
        _, node = heappop(self._arrivals)
        radio = self.radios[node]
        bg = radio.background
        assert bg is not None
        _, sizes = bg.until(ta)
        for size in sizes:
            if not self._arrive(radio, Frame(node, int(size), ta), ta):
                self._dropped.append(ta)
        heappush(self._arrivals, (bg.next_time(), node))

    def _start(self, ts: int) -> None:
        heads, on_air, radios = self._heads, self.on_air, self.radios
        best = heads[0][0]
        end, first_end = ts, -1
        background = 0
        while heads and heads[0][0] == best:    # (in node order: the order of their ends' news)
            _, node, air = heappop(heads)   # (air: the airtime of the frame at the head)
            radio = radios[node]
            frame = radio.queue.popleft()
            radio.queued_bytes -= frame.size
            frame.start = ts
            frame.end = fe = ts + air
            radio.on_air = frame
            on_air.append(frame)
            if fe > end:
                end = fe
            if first_end < 0 or fe < first_end:
                first_end = fe
            if frame.done is None:
                background += 1
        # the others are frozen: the boundaries before this one are spent, the rest count on
        self.passed = best
        if not on_air:
            raise RuntimeError(f"channel: no head is due at the boundary {ts} ns")
        self._next_end = first_end
        n = len(on_air)
        self.collided = n > 1
        self._periods.extend((ts, end, n, background, n > 1))
        self._next_start = None

    def _end(self, te: int) -> None:
        on_air = self.on_air
        if len(on_air) == 1:
            done, on_air = on_air, []
        else:
            done = [f for f in on_air if f.end == te]
            on_air = [f for f in on_air if f.end != te]
        self.on_air = on_air
        if on_air:
            self._next_end = min(f.end for f in on_air)
        else:                               # idle from now: the new heads count from here
            self._next_end = _NEVER
            self.t_idle = te
            self._next_start = None
        ok = not self.collided
        radios, ended = self.radios, self.ended
        for frame in done:
            radio = radios[frame.node]
            radio.on_air = None
            if ended is not None:
                ended.append((frame.node, frame.start, frame.end, ok, frame.done is None))
            if frame.done is not None:
                self.pending -= 1
                frame.done(frame, ok)
            if radio.queue:
                self._head(radio, te)

    # ------------------------------------------------------------------ wake-ups
    def _wake(self) -> None:
        """While an estimator's frame waits or is on the air: a wake-up at the next end, that
        of the frame on the air or of the first frame due to start if nothing more is handed
        over.  A frame handed over before that start can only make a frame start and end
        earlier through :meth:`offer`, which wakes earlier; background that starts earlier delays
        every estimator's frame.  So every end of an estimator's frame is seen at its instant
        (its deliveries are scheduled then), with one wake-up per frame when nothing interferes."""
        if not self.pending:
            return
        if self.on_air:
            t = self._next_end
        else:
            ts = self._next_start
            t = (ts if ts is not None else self.next_start()) + self._next_air
        if t in self._wakes or t > MAX_NS:
            return
        self._wakes.add(t)
        Scheduled(self.env, self._woken, URGENT, t - self.now)     # (now: brought to the present)

    def _woken(self, _event: Event) -> None:
        now = self.env.now
        self._wakes.discard(now)
        if now > self.now:
            self.advance(now)
        self._wake()

    # ------------------------------------------------------------------ statistics
    def stats(self, end_ns: int) -> dict[str, float | int]:
        """The channel over ``[0, end_ns]`` (brought up to ``end_ns``, or to now if that is
        earlier), whatever happened after it: the busy fraction of it (collisions included),
        the frames that started before ``end_ns`` (all, and the background's that collided or
        not), the collisions among them, and the background frames a full waiting room dropped
        up to ``end_ns``."""
        self.advance(min(end_ns, self.env.now))
        p = np.frombuffer(self._periods, dtype=np.int64).reshape(-1, 5)
        p = p[p[:, 0] < end_ns]
        busy = int((np.minimum(p[:, 1], end_ns) - p[:, 0]).sum())
        collided = p[:, 4] > 0
        dropped = np.frombuffer(self._dropped, dtype=np.int64)
        return {"utilisation": busy / end_ns if end_ns > 0 else 0.0,
                "frames_on_air": int(p[:, 2].sum()), "collisions": int(collided.sum()),
                "background_sent": int(p[~collided, 3].sum()), "background_collided": int(p[collided, 3].sum()),
                "background_dropped": int((dropped <= end_ns).sum())}

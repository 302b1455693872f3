"""The shared radio channel (``medium:``; docs/design.md §3, "A shared radio channel").

One :class:`Channel` is one collision domain: every member senses every other.  Each member
has one radio, a first-in-first-out waiting room of frames (its estimators' and its
background's) whose first frame, the head, contends for the channel under the channel's
access rule (``medium.access``: an :class:`Access`, e.g. :mod:`~dkfsim.network.media.csma`).
What the channel itself decides, whatever the rule:

- a frame of ``size`` bytes is on the air ``preamble + size * 8 / rate`` (:meth:`Channel.airtime`);
- frames that start at one instant collide: each is lost for every receiver; the channel is
  busy until the longest ends, and a frame starts only while it is idle;
- when its frame ends, a radio with more frames makes the next one its head.

The engine is event driven over the run's SimPy environment, and lazy: its state is brought
up to date (:meth:`Channel.advance`) when a frame is offered and by wake-up events while an
estimator's frame waits or is on the air, about one per frame, at a transmission's end (never
one per slot; :meth:`Channel._wake`).  Its statistics come from a log of busy periods, so they
are those of any instant however far the channel has been brought.  At one instant it takes
the transmission ends, then the arrivals (background first, then the estimators' frames as
they are handed over), then a start -- so a frame handed over exactly at a slot boundary
joins it.
"""

from __future__ import annotations

from array import array
from collections import deque
from heapq import heapify, heappop, heappush
from typing import Any, ClassVar

import numpy as np
from simpy.events import URGENT, Event
from typing_extensions import override

from dkfsim.components.medium import Medium as MediumSpec
from dkfsim.components.traffic import transmission_ns
from dkfsim.core.backend import Backend
from dkfsim.core.params import MAX_NS, NS_PER_S, seconds_to_ns
from dkfsim.core.registry import MEDIA
from dkfsim.core.streams import key64, keyed_uniform
from dkfsim.network.events import Scheduled
from dkfsim.network.media.background import BackgroundArrivals
from dkfsim.network.media.base import Frame, Medium

#: An instant after every instant of a run: "never".
NEVER = MAX_NS + 1


class Radio:
    """One member's radio: its waiting room (the head contending, the frame on the air apart)
    and its background; ``state`` is its access rule's to keep (e.g. a backoff)."""

    __slots__ = ("node", "queue", "queued_bytes", "on_air", "background", "state")

    def __init__(self, node: int, background: BackgroundArrivals | None):
        self.node = node
        self.queue: deque[Frame] = deque()
        self.queued_bytes = 0
        self.on_air: Frame | None = None
        self.background = background
        self.state: Any = None


class Access:
    """A shared channel's access rule: when the radios' head frames start (a researcher's MAC
    is one subclass, registered in :data:`~dkfsim.core.registry.MEDIA` under the
    ``medium.access.kind`` it implements; docs/extending.md, "Add a medium").

    The channel calls :meth:`head` when a radio's first waiting frame becomes its head,
    :meth:`next_start` to learn when the next transmission starts (while the channel is idle),
    :meth:`start` at that instant to take the radios that start then, and :meth:`idle` when the
    channel becomes idle.  The rule reads the channel (``channel.on_air``: busy while not
    empty; ``channel.airtime``) and never changes it.

    :param params: the ``medium.access`` block (its registered parameter model).
    :param channel: the channel it decides for; ``seed`` keys its draws.
    """

    #: :meth:`next_start` as last worked out while the channel is idle, or None: not known (the
    #: channel then asks :meth:`next_start`); a rule that caches it clears it whenever the heads
    #: or the idle period change, so the channel's hot loop reads it without a call (a subclass
    #: of such a rule that overrides :meth:`next_start` keeps it None or up to date)
    start_at: int | None = None
    #: whether the rule runs on each radio's own view of the medium, so a spatial radio
    #: (``medium.radio``) can take it (a one-domain rule may name such a form as ``on_radio``)
    spatial: ClassVar[bool] = False

    def __init__(self, params: Any, channel: Channel, seed: int):
        self.params = params
        self.channel = channel
        self.seed = seed

    def head(self, radio: Radio, t: int) -> None:
        """``radio``'s first waiting frame became its head at ``t``."""
        raise NotImplementedError

    def next_start(self) -> int:
        """When the next transmission starts if nothing more is handed over (:data:`NEVER`:
        no head, or the channel busy)."""
        raise NotImplementedError

    def next_airtime(self) -> int:
        """The shortest airtime of the frames that start at :meth:`next_start` (for the
        channel's wake-ups: the first end it must see)."""
        raise NotImplementedError

    def start(self, ts: int) -> list[Radio]:
        """The radios whose head starts at ``ts`` (= :meth:`next_start`), in node order; they
        are no longer heads."""
        raise NotImplementedError

    def next_end(self) -> int:
        """When the first frame to start ends if nothing more happens, on one collision domain
        (the channel's wake-up while idle): the next start plus its shortest airtime
        (:data:`NEVER`: no head)."""
        ts = self.next_start()
        return ts + self.next_airtime() if ts < NEVER else NEVER

    def soonest_end(self) -> int:
        """When the first head frame would end if nothing more happens (for an overlapping
        medium's wake-ups, where a head due later may end first): by default one collision
        domain's rule, :meth:`next_end`."""
        return self.next_end()

    def idle(self, te: int) -> None:
        """The channel became idle at ``te``."""

    def started(self, ts: int) -> None:
        """The radios :meth:`start` returned are on the air from ``ts`` (one collision domain:
        every radio senses them)."""

    def sent(self, radio: Radio, te: int) -> None:
        """``radio``'s frame on the air ended at ``te`` (before its next head, if any)."""


class Channel(Medium):
    """One copy of the shared channel (each estimator's port has its own unless shared).

    :param spec: the scenario's :class:`~dkfsim.components.medium.Medium` (``medium:``).
    :param members: the nodes on the channel.
    :param index: the channel's number ``c`` in its draws' keys (one channel: 0).
    :param record: keep ``(node, start, end, ok, background)`` of every frame that ended
        (:attr:`ended`; for the checks of the access rule).
    :param backend: the run's kernel path (default: the environment's).
    """

    kind = "channel"
    broadcast = True
    report_name: ClassVar[str] = "channel"
    #: whether a frame may start while others are on the air (a spatial radio, where a sender
    #: senses only some of them); False: one collision domain, nothing starts while one is on it
    overlapping: ClassVar[bool] = False

    def __init__(self, env: Any, spec: MediumSpec, members: tuple[int, ...], seed: int, index: int = 0,
                 record: bool = False, T_ns: int = 0, backend: Backend | None = None):
        self.env = env
        #: the run's kernel path (an access rule's kernels compiled or not)
        self.backend = backend if backend is not None else Backend.from_environment()
        self.spec = spec
        self.rate, self.preamble = float(spec.rate), seconds_to_ns(spec.preamble)
        self.max_packets = spec.queue.packets if spec.queue is not None else None
        self.max_bytes = spec.queue.bytes if spec.queue is not None else None
        self._bounded = spec.queue is not None
        self.index = index
        self.radios: dict[int, Radio] = {}
        self._airtimes: dict[int, int] = {}
        #: (instant of the next background frame, node) of every member with background
        self._arrivals: list[tuple[int, int]] = []
        for node in members:
            prefix = ("channel", index, node)
            bg = BackgroundArrivals(spec.background, prefix, seed, first_block=8) if spec.background is not None else None
            self.radios[node] = Radio(node, bg)
            if bg is not None:
                self._arrivals.append((bg.next_time(), node))
        heapify(self._arrivals)
        #: the frames on the air (one, or several colliding)
        self.on_air: list[Frame] = []
        #: when the first frame on the air ends (never: none on the air)
        self._next_end = NEVER
        self.collided = False
        #: the instant processed up to (ends and arrivals at it included, starts before it)
        self.now = -1
        #: estimators' frames waiting or on the air (wake-ups are needed only while any is)
        self.pending = 0
        self._wakes: set[int] = set()
        #: ``generation_jitter`` (ns), and each radio's key of it and the instant its last frame
        #: reaches it (frames held back by the jitter wait in ``_held``: (instant, order, frame))
        self.jitter_ns, self.T_ns = seconds_to_ns(spec.generation_jitter or 0.0), int(T_ns)
        if self.jitter_ns and self.T_ns <= 0:
            raise ValueError("a channel with generation_jitter needs the tick length T_ns")
        self._jitter_keys = {node: key64(seed, "channel", index, node, "jitter") for node in members} \
            if self.jitter_ns else {}
        self._ready: dict[int, int] = {}
        self._held: list[tuple[int, int, Frame]] = []
        self._held_count = 0
        #: the access rule (``medium.access.kind``), and its hooks a rule may leave as they are
        #: (None then: not called, on the per-event path)
        self.access: Access = self.make_access(spec, seed)
        rule = type(self.access)
        self._started = self.access.started if rule.started is not Access.started else None
        self._sent = self.access.sent if rule.sent is not Access.sent else None
        # statistics
        #: every busy period: (start, end, frames, background frames, collided), flat; and
        #: the instants of background frames a full waiting room dropped (:meth:`stats` reads
        #: them as of any instant, however far the channel has been brought)
        self._periods = array("q")
        self._dropped = array("q")
        #: per owner (port): (end, collided, hand-over to start ns) of its frames that ended, flat,
        #: and how many of its frames a full waiting room refused
        self._owned: dict[Any, array] = {}
        self._refused: dict[Any, int] = {}
        #: with ``record``: (node, start, end, ok, background) of every frame that ended
        self.ended: list[tuple[int, int, int, bool, bool]] | None = [] if record else None

    def make_access(self, spec: MediumSpec, seed: int) -> Access:
        """The access rule's implementation for this channel (``medium.access.kind``)."""
        return MEDIA.get(spec.access.kind).implementation(spec.access, self, seed)

    # ------------------------------------------------------------------ offering
    def offer(self, frame: Frame) -> bool:
        """Hand over ``frame`` now at its node's radio: False when the waiting room is full
        (drop-tail: nothing of it is sent).  With ``generation_jitter`` the frame reaches the
        radio later (:meth:`_hold`), and is taken: a full waiting room then drops it as lost."""
        now = self.env.now
        if now > self.now:                  # (brought to now already: nothing to do, decision 235)
            self.advance(now)
        if self.jitter_ns and self._hold(frame, now):
            return True
        ok = self._arrive(self.radios[frame.node], frame, now)
        if ok:
            self.pending += 1
        else:
            self._refused[frame.owner] = self._refused.get(frame.owner, 0) + 1
        self._wake()
        return ok

    @override
    def leaves_at_once(self, nbytes: int) -> bool:
        return False                        # (a frame is on the air at least 1 ns)

    def _hold(self, frame: Frame, now: int) -> bool:
        """Hold ``frame`` back until its vehicle's generation instant of this tick, ``now`` plus
        the keyed uniform ``[0, jitter)`` of (vehicle, tick) -- never before the vehicle's
        previous frame (its frames keep their order); False when that is now."""
        node = frame.node
        delay = int(keyed_uniform(self._jitter_keys[node], now // self.T_ns, 0) * self.jitter_ns)
        ready = max(now + delay, self._ready.get(node, 0))
        self._ready[node] = ready
        if ready <= now:
            return False
        heappush(self._held, (ready, self._held_count, frame))
        self._held_count += 1
        self.pending += 1
        self._wake()
        return True

    def _release(self, th: int) -> None:
        """The held frames due at ``th`` reach their radios (a full waiting room refuses them:
        ``frame.done(frame, False)`` on a frame never on the air, which its port counts as
        ``queue_dropped``)."""
        held = self._held
        while held and held[0][0] == th:
            frame = heappop(held)[2]
            self.pending -= 1
            if self._arrive(self.radios[frame.node], frame, th):
                self.pending += 1
            else:
                self._refused[frame.owner] = self._refused.get(frame.owner, 0) + 1
                if frame.done is not None:
                    frame.done(frame, False)

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
            self.access.head(radio, now)
        return True

    def airtime(self, size: int) -> int:
        """ns a frame of ``size`` bytes is on the air: the preamble plus ``size * 8 / rate``
        (:func:`~dkfsim.components.traffic.transmission_ns`), at least 1 ns."""
        air = self._airtimes.get(size)
        if air is None:
            air = self._airtimes[size] = max(1, min(self.preamble + transmission_ns(size, self.rate), MAX_NS))
        return air

    # ------------------------------------------------------------------ the engine
    def advance(self, t: int) -> None:
        """Bring the channel up to instant ``t``: every transmission end and arrival at or
        before ``t`` and every start before ``t``, in time order.

        Brought to ``t`` once, it has nothing more to do at ``t`` (so a second call returns at
        once; many frames are offered at one instant): what is handed over at ``t`` starts at
        or after ``t``, so it adds no start before ``t`` and no end or arrival at it."""
        if t <= self.now:
            return
        arrivals, access, held, overlapping = self._arrivals, self.access, self._held, self.overlapping
        while True:
            te = self._next_end
            ta = arrivals[0][0] if arrivals else NEVER
            th = held[0][0] if held else NEVER
            if self.on_air and not overlapping:
                ts = NEVER
            else:
                cached = access.start_at
                ts = cached if cached is not None else access.next_start()
            if te <= t and te <= ta and te <= th and te <= ts:
                self._end(te)
            elif ta <= t and ta <= ts and ta <= th:
                self._background(ta)
            elif th <= t and th <= ts:
                self._release(th)
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
        for size in bg.until(ta):
            if not self._arrive(radio, Frame(node, size, ta), ta):
                self._dropped.append(ta)
        heappush(self._arrivals, (bg.next_time(), node))

    def _start(self, ts: int) -> None:
        on_air = self.on_air
        end, first_end = ts, -1
        background = 0
        for radio in self.access.start(ts):     # (in node order: the order of their ends' news)
            frame = radio.queue.popleft()
            radio.queued_bytes -= frame.size
            frame.start = ts
            frame.end = fe = ts + self.airtime(frame.size)
            radio.on_air = frame
            on_air.append(frame)
            if fe > end:
                end = fe
            if first_end < 0 or fe < first_end:
                first_end = fe
            if frame.done is None:
                background += 1
        if not on_air:
            raise RuntimeError(f"channel: no head is due at {ts} ns")
        if self._started is not None:
            self._started(ts)
        self._next_end = first_end
        n = len(on_air)
        self.collided = n > 1
        self._periods.extend((ts, end, n, background, n > 1))

    def _end(self, te: int) -> None:
        done = self.on_air
        access = self.access
        if len(done) == 1:                  # idle from now: the new heads count from here
            self.on_air = []
            self._next_end = NEVER
            access.idle(te)
        else:
            on_air = self.on_air = [f for f in done if f.end != te]
            done = [f for f in done if f.end == te]
            if on_air:
                self._next_end = min(f.end for f in on_air)
            else:
                self._next_end = NEVER
                access.idle(te)
        ok = not self.collided
        radios, ended, sent = self.radios, self.ended, self._sent
        for frame in done:
            radio = radios[frame.node]
            radio.on_air = None
            if ended is not None:
                ended.append((frame.node, frame.start, frame.end, ok, frame.done is None))
            if frame.done is not None:
                self.pending -= 1
                own = self._owned.get(frame.owner)
                if own is None:
                    own = self._owned[frame.owner] = array("q")
                own.extend((te, not ok, frame.start - frame.handed))
                frame.done(frame, ok)
            if sent is not None:
                sent(radio, te)
            if radio.queue:
                access.head(radio, te)

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
        if not self.overlapping:
            t = self._next_end if self.on_air else self.access.next_end()
        else:                               # (the first end among those on the air and the heads')
            t = min(self.first_end(), self.access.soonest_end())
        if self._held and self._held[0][0] < t:
            t = self._held[0][0]
        if t in self._wakes or t > MAX_NS:
            return
        self._wakes.add(t)
        Scheduled(self.env, self._woken, URGENT, t - self.now)     # (now: brought to the present)

    def first_end(self) -> int:
        """When the first frame on the air ends (:data:`NEVER`: none on the air)."""
        return self._next_end

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

    def report(self, owner: Any, end: int) -> dict[str, Any]:
        """The channel over ``[0, end]`` as ``owner`` saw it (:meth:`stats`: every frame,
        background included) and ``owner``'s frames that ended by ``end``: ``frames`` (collided
        or not), ``frames_collided`` and ``access_delay_mean`` (s, hand-over to start of
        transmission); ``frames_dropped``: those a full waiting room refused."""
        stats: dict[str, Any] = dict(self.stats(end))
        flat = self._owned.get(owner)
        done = np.frombuffer(flat, dtype=np.int64).reshape(-1, 3) if flat else np.zeros((0, 3), np.int64)
        done = done[done[:, 0] <= end]
        stats.update(frames=len(done), frames_collided=int(done[:, 1].sum()),
                     frames_dropped=self._refused.get(owner, 0),
                     access_delay_mean=float(done[:, 2].mean()) / NS_PER_S if len(done) else 0.0)
        return stats

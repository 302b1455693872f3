"""Slotted access where each radio has its own view of the medium: ``edca`` (IEEE 802.11p), and
``csma`` on a spatial radio (docs/radio.md, "The access rules").

A radio counts its backoff in the slot boundaries ``origin + m * slot`` of its current idle
period, ``origin = t_idle + aifs`` (``eifs`` after a frame it received in error), ``t_idle`` the
instant *it* sensed the medium become idle; a transmission that it senses freezes its count at
the boundaries passed before it.  The channel tells each radio's view: :meth:`busy` and
:meth:`clear` for the radios whose view changed (a spatial radio: those that sensed the frame;
one collision domain: every radio, :meth:`idle`).  Two rules differ only in when they draw:

``csma`` (:class:`RadioCsma`)
    a backoff uniform in ``0 .. cw`` for every head frame, counted from the first boundary at or
    after it became head (the one-domain rule of :mod:`~dkfsim.network.media.csma`, per radio);
``edca`` (:class:`EdcaAccess`, 802.11-2016 §10.22.2, as ns-3 runs it)
    a head frame that finds its radio's medium idle and no backoff pending goes once the medium
    has been idle for AIFS, without a backoff; one that finds it busy draws a backoff; after
    every own transmission a post-backoff is drawn and counted down, head frame or not.

State is kept in arrays over the radios, so a frame sensed by hundreds of radios costs a few
vector operations, not a Python loop.
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
from typing_extensions import override

from dkfsim.components.medium import Edca
from dkfsim.core.jit import bind
from dkfsim.core.registry import MEDIA
from dkfsim.core.streams import key64, keyed_uniform
from dkfsim.network import radio_kernels as rk
from dkfsim.network.media.channel import NEVER, Access, Channel, Radio


class Backoff:
    """A radio's backoff draws: its key, and the instant and count of its last draws (the one
    draw every slotted rule makes: :mod:`~dkfsim.network.media.csma`, :class:`SlottedAccess`)."""

    __slots__ = ("key", "drawn_at", "drawn")

    def __init__(self, key: int):
        self.key = key
        self.drawn_at, self.drawn = -1, 0

    def draw(self, t: int, cw: int) -> int:
        """A backoff uniform in ``0 .. cw`` at ``t``: the keyed draw at ``(t, attempt)``,
        ``attempt`` the number of earlier draws at ``t``."""
        if self.drawn_at != t:
            self.drawn_at = t
            drawn = 0
        else:
            drawn = self.drawn
        self.drawn = drawn + 1
        count = int(keyed_uniform(self.key, t, drawn) * (cw + 1))
        return cw if count > cw else count  # (a draw next to 1 may round up to cw + 1)


class SlottedAccess(Access):
    """The per-radio slotted engine (see the module); a subclass says when a backoff is drawn."""

    spatial = True
    #: the backoff draws' name in their key ``("channel", c, node, name)``
    draws: ClassVar[str] = "backoff"
    #: the rule as the radio's compiled engine runs it (:data:`~dkfsim.network.radio_kernels.EDCA`,
    #: ``CSMA``); ``CUSTOM``, a researcher's: the engine calls :meth:`on_head` and :meth:`sent` back
    rule: ClassVar[int] = rk.CUSTOM

    def __init__(self, params: Any, channel: Channel, seed: int):
        super().__init__(params, channel, seed)
        self.slot, self.aifs, self.cw = params.slot_ns, params.aifs_ns, int(params.cw)
        self.eifs = int(getattr(params, "eifs_ns", self.aifs))
        self.radios: list[Radio] = [channel.radios[node] for node in sorted(channel.radios)]
        #: a radio's position in the arrays
        self.pos = {radio.node: i for i, radio in enumerate(self.radios)}
        m = len(self.radios)
        #: each radio's backoff key, and its draws' last instant and count at it (:meth:`draw`)
        self.bkey = np.array([key64(seed, "channel", channel.index, radio.node, self.draws) for radio in self.radios],
                             dtype=np.uint64)
        self.dr = np.zeros((2, m), dtype=np.int64)
        self.dr[rk.DRAWN_AT] = -1
        #: the instant each radio's medium became idle (-1: it senses it busy); boundary 0 of
        #: its count; its backoff in slots from ``origin`` (-1: none pending); when its head
        #: frame starts if the medium stays idle (NEVER: no head, or busy)
        self.idle_at = np.zeros(m, dtype=np.int64)
        self.origin = np.full(m, self.aifs, dtype=np.int64)
        self.count = np.full(m, -1, dtype=np.int64)
        self.due = np.full(m, NEVER, dtype=np.int64)
        self.head_on = np.zeros(m, dtype=bool)
        self.air = np.ones(m, dtype=np.int64)
        self._all = np.arange(m)
        #: the radios that started last (one domain: they sensed no error, they sent)
        self._started = np.zeros(0, dtype=np.int64)
        self._out = np.zeros(m, dtype=np.int64)
        #: each radio's "its last frame received was in error" for one domain (kept all 0 but
        #: after a collision)
        self._no_error = np.zeros(m, dtype=np.int64)
        #: the earliest ``due`` (-1: to be worked out again)
        self._best = -1
        k = rk.compiled() if channel.backend.compiled else rk
        state = (self.idle_at, self.origin, self.count, self.due, self.head_on)
        self._busy = bind(k.busy, *state, self._all, 0, 0, 1, NEVER)
        self._clear = bind(k.clear, *state, self._all, 0, 0, 1, 1, 1, self._no_error)
        self._start = bind(k.take_due, self.due, self.head_on, self.count, 0, NEVER, self._out)
        self._first_air = bind(k.first_air, self.due, self.air, 0)
        self._soonest = bind(k.soonest_end, self.due, self.air)
        self._draw = rk.quiet(bind(k.draw, self.bkey, self.dr, 0, 0, 1))
        self._on_head = rk.quiet(bind(k.on_head, self.rule or rk.EDCA, 0, 0, True, self.origin, self.count,
                                      self.due, self.bkey, self.dr, 1, 1))

    def changed(self) -> None:
        """The counts changed outside these methods (the radio's engine): :meth:`next_start` works
        the earliest due instant out again."""
        self._best = -1

    def draw(self, i: int, t: int) -> int:
        """A backoff uniform in ``0 .. cw`` for radio ``i`` at ``t``: the keyed draw at ``(t,
        attempt)``, ``attempt`` the number of its earlier draws at ``t``
        (:func:`~dkfsim.network.radio_kernels.draw`, the engine's own)."""
        return int(self._draw(self.bkey, self.dr, i, t, self.cw))

    @override
    def head(self, radio: Radio, t: int) -> None:
        i = self.pos[radio.node]
        self.head_on[i] = True
        self.air[i] = self.channel.airtime(radio.queue[0].size)
        self.on_head(i, t, bool(self.idle_at[i] >= 0))
        self._best = -1

    def on_head(self, i: int, t: int, idle: bool) -> None:
        """Radio ``i``'s head frame arrived at ``t`` (its medium idle or not): set its count and
        due instant (a built-in rule: :func:`~dkfsim.network.radio_kernels.on_head`; a
        researcher's overrides this)."""
        if self.rule == rk.CUSTOM:
            raise NotImplementedError
        self._on_head(self.rule, i, t, idle, self.origin, self.count, self.due, self.bkey, self.dr, self.cw, self.slot)

    def busy(self, nodes: np.ndarray | None, t: int, n: int = -1) -> None:
        """The radios at positions ``nodes[:n]`` (None: all; ``n`` -1: every one of ``nodes``)
        sense the medium busy from ``t``: each idle one's count keeps the boundaries not passed
        before ``t`` (:func:`~dkfsim.network.radio_kernels.busy`)."""
        sel = self._all if nodes is None else nodes
        if self._busy(self.idle_at, self.origin, self.count, self.due, self.head_on, sel,
                      len(sel) if n < 0 else n, t, self.slot, NEVER):
            self._best = -1

    def clear(self, nodes: np.ndarray, t: int, error: np.ndarray | None = None, n: int = -1) -> None:
        """The radios at positions ``nodes[:n]`` (``n`` -1: every one) sense the medium idle from
        ``t`` (``error``, over every radio: those whose last frame received was in error count from
        ``t + eifs``; read and cleared; :func:`~dkfsim.network.radio_kernels.clear`)."""
        if self._clear(self.idle_at, self.origin, self.count, self.due, self.head_on, nodes,
                       len(nodes) if n < 0 else n, t, self.slot, self.aifs, self.eifs,
                       self._no_error if error is None else error):
            self._best = -1

    @override
    def idle(self, te: int) -> None:
        """One collision domain: every radio senses idle from ``te``; after a collision, EIFS for
        every radio but those that sent."""
        error = None
        if self.channel.collided and self.eifs != self.aifs:
            error = np.ones(len(self.radios), dtype=np.int64)
            error[self._started] = 0
        self.clear(self._all, te, error)

    @override
    def next_start(self) -> int:
        if self._best < 0:                  # (worked out again after any change of ``due``)
            self._best = int(self.due.min())
        return self._best

    @override
    def next_airtime(self) -> int:
        return int(self._first_air(self.due, self.air, self.next_start()))

    @override
    def soonest_end(self) -> int:
        """The first end among every radio's head if nothing more happens: a head due later may
        end first (each radio keeps its own view; :func:`~dkfsim.network.radio_kernels.soonest_end`)."""
        return int(self._soonest(self.due, self.air))

    @override
    def start(self, ts: int) -> list[Radio]:
        n = self._start(self.due, self.head_on, self.count, ts, NEVER, self._out)
        self._best = -1
        sel = self._started = self._out[:n].copy()
        radios = self.radios
        return [radios[i] for i in sel.tolist()]

    @override
    def started(self, ts: int) -> None:
        """One collision domain: every radio senses the transmissions that started at ``ts``."""
        self.busy(None, ts)


@MEDIA.register("edca", params=Edca)
class EdcaAccess(SlottedAccess):
    """IEEE 802.11p EDCA (see the module): immediate access on an idle medium, a backoff drawn
    when busy, a post-backoff after every own frame, EIFS after a frame received in error
    (:func:`~dkfsim.network.radio_kernels.on_head`)."""

    draws = "edca"
    rule = rk.EDCA

    @override
    def sent(self, radio: Radio, te: int) -> None:
        i = self.pos[radio.node]
        self.count[i] = self.draw(i, te)    # the post-backoff, counted once the medium is idle


class RadioCsma(SlottedAccess):
    """``csma`` where each radio has its own view of the medium (a spatial radio): a backoff
    for every head frame, as :class:`~dkfsim.network.media.csma.CsmaAccess` draws it, counted
    in the radio's own idle slots (:func:`~dkfsim.network.radio_kernels.on_head`).  With every
    radio sensing every frame it is that rule, bit for bit (tests/test_radio.py)."""

    draws = "backoff"
    rule = rk.CSMA

"""``csma``: slotted CSMA with a backoff for every frame, the shared channel's default access rule
(a simplified IEEE 802.11p / ITS-G5 broadcast; docs/design.md §3).

- the channel's slot boundaries after it last became idle at ``t_idle`` are
  ``t_idle + aifs + m * slot``, ``m = 0, 1, ...`` (``t_idle = 0`` at the start);
- a frame that becomes its radio's head at ``h`` draws a backoff ``b`` uniform in
  ``0 .. cw`` (the keyed draw ``("channel", c, node, "backoff")`` at ``(h, attempt)``,
  ``attempt`` the number of earlier draws of that node at ``h``), joins at the first boundary
  at or after ``h`` and is sent ``b`` boundaries later if the channel stays idle;
- a transmission that starts first freezes the other heads' remaining counts (boundaries
  not yet passed), which resume from the next idle period's boundaries;
- frames that start at one boundary collide (the channel's rule).
"""

from __future__ import annotations

from heapq import heappop, heappush

from typing_extensions import override

from dkfsim.components.medium import Csma
from dkfsim.core.registry import MEDIA
from dkfsim.core.streams import key64
from dkfsim.network.media.channel import NEVER, Access, Channel, Radio
from dkfsim.network.media.slotted import Backoff, RadioCsma


@MEDIA.register("csma", params=Csma)
class CsmaAccess(Access):
    """Slotted CSMA with a backoff for every frame (see the module)."""

    #: the rule on a spatial radio, where each radio has its own view of the medium
    on_radio = RadioCsma

    def __init__(self, params: Csma, channel: Channel, seed: int):
        super().__init__(params, channel, seed)
        self.slot, self.aifs, self.cw = params.slot_ns, params.aifs_ns, int(params.cw)
        for node, radio in channel.radios.items():
            radio.state = Backoff(key64(seed, "channel", channel.index, node, "backoff"))
        #: the contending heads (a frame waiting, none on the air): ``(boundary, node, airtime)``,
        #: a heap; ``boundary`` counts the idle boundaries of the whole run (:attr:`passed` of
        #: earlier idle periods, then this one's), so freezing changes no entry
        self._heads: list[tuple[int, int, int]] = []
        #: the boundaries of the earlier idle periods that passed (each period: those before the
        #: boundary at which its transmission started)
        self.passed = 0
        self.t_idle = 0
        self.start_at = None
        #: the shortest airtime of the heads due at :meth:`next_start`
        self._next_air = 1

    def head(self, radio: Radio, t: int) -> None:
        """A fresh backoff, counted from the first boundary at or after ``t`` (the next idle
        period's first while the channel is busy)."""
        count = radio.state.draw(t, self.cw)
        first = self.t_idle + self.aifs
        channel = self.channel
        join = 0 if channel.on_air or t <= first else -(-(t - first) // self.slot)
        heappush(self._heads, (self.passed + join + count, radio.node, channel.airtime(radio.queue[0].size)))
        self.start_at = None

    def next_start(self) -> int:
        if self.channel.on_air:
            return NEVER
        if self.start_at is None:
            heads = self._heads
            if not heads:
                self.start_at = NEVER
            else:
                best = heads[0][0]
                self.start_at = self.t_idle + self.aifs + (best - self.passed) * self.slot
                # the heads tied with the first are a subtree at the top of the heap: none when
                # neither child of the root is
                n = len(heads)
                if (n > 1 and heads[1][0] == best) or (n > 2 and heads[2][0] == best):
                    self._next_air = min(air for b, _, air in heads if b == best)
                else:
                    self._next_air = heads[0][2]
        return self.start_at

    @override
    def next_airtime(self) -> int:
        self.next_start()
        return self._next_air

    @override
    def next_end(self) -> int:
        ts = self.start_at                  # (valid while set: every change of the heads clears it)
        if ts is None:
            ts = self.next_start()
        return ts + self._next_air if ts < NEVER else NEVER

    @override
    def start(self, ts: int) -> list[Radio]:
        heads, radios = self._heads, self.channel.radios
        best = heads[0][0]
        out = []
        while heads and heads[0][0] == best:
            out.append(radios[heappop(heads)[1]])
        # the others are frozen: the boundaries before this one are spent, the rest count on
        self.passed = best
        self.start_at = None
        return out

    @override
    def idle(self, te: int) -> None:
        self.t_idle = te
        self.start_at = None


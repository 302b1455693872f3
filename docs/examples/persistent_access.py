"""``persistent``: a MAC for docs/extending.md -- 1-persistent CSMA on the shared channel.

A radio with a frame to send waits only for the channel to be idle, then sends at once, without
a backoff: frames that become ready while the channel is busy all go the instant it becomes
idle, and collide (the channel's rule).  ``csma`` (the default access rule) draws a backoff
for every frame; this rule shows what the backoff is for.  One file, two classes: the
parameters declare the kind (``medium.access.kind: persistent``), the access rule implements
the four steps a shared channel asks of it (:class:`dkfsim.network.media.channel.Access`).
"""

from __future__ import annotations

from typing_extensions import override

from dkfsim.components.medium import AccessParams
from dkfsim.core.registry import MEDIA
from dkfsim.network.media.channel import NEVER, Access, Channel, Radio


class PersistentParams(AccessParams, kind="persistent"):
    """1-persistent CSMA: send at once when the channel is idle, no backoff."""


@MEDIA.register("persistent")
class Persistent(Access):
    """1-persistent CSMA: each head frame starts the first instant the channel is idle."""

    def __init__(self, params: PersistentParams, channel: Channel, seed: int):
        super().__init__(params, channel, seed)
        #: node -> the instant its head frame became ready
        self.ready: dict[int, int] = {}
        #: when the channel last became idle
        self.t_idle = 0

    def head(self, radio: Radio, t: int) -> None:
        self.ready[radio.node] = t

    def next_start(self) -> int:
        if self.channel.on_air or not self.ready:
            return NEVER
        return max(self.t_idle, min(self.ready.values()))

    def next_airtime(self) -> int:
        ts = self.next_start()
        radios = self.channel.radios
        return min(self.channel.airtime(radios[n].queue[0].size)
                   for n, r in self.ready.items() if max(self.t_idle, r) == ts)

    def start(self, ts: int) -> list[Radio]:
        going = sorted(n for n, r in self.ready.items() if max(self.t_idle, r) == ts)
        for n in going:
            del self.ready[n]
        return [self.channel.radios[n] for n in going]

    @override
    def idle(self, te: int) -> None:
        self.t_idle = te

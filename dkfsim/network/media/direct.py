"""``direct``: a link without a ``rate``: a frame leaves its sender the instant it is handed over.

Nothing waits and nothing is counted here: the packet's fate is its link's keyed draws alone
(:meth:`dkfsim.network.links.Link.transmit`), drawn at the hand-over instant.  Stateless, so
one instance serves every port.
"""

from __future__ import annotations

from typing_extensions import override

from dkfsim.core.registry import MEDIA
from dkfsim.network.media.base import Frame, Medium


@MEDIA.register("direct", description="a link without a rate: a packet leaves its sender at once "
                "(its latency, loss and faults are the link's)")
class Direct(Medium):
    """A link without a rate: every frame leaves at its hand-over."""

    kind = "direct"
    passive = True

    def offer(self, frame: Frame) -> bool:
        frame.start = frame.end = frame.handed
        if frame.done is not None:
            frame.done(frame, True)
        return True

    @override
    def leaves_at_once(self, nbytes: int) -> bool:
        return True


#: The one instance every port uses.
DIRECT = Direct()

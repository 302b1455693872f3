"""The medium seam: what a port hands over (a :class:`Frame`) and what a medium promises.

ns-3 splits a node's network device from the channel it sends on; dkfsim splits a port (the
estimator's side: numbering, counting, delivering) from the medium (the sender's side of the
air: waiting rooms, access, transmission) and from the link (propagation).  A port calls
:meth:`Medium.offer` with each frame, in the order its estimator sends; the medium answers
at once whether the frame found room, and later -- at once for a frame that leaves at its
hand-over, at the end of its transmission for one that waits -- calls ``frame.done(frame,
ok)`` exactly once: ``ok`` when it has left (``frame.start``, ``frame.end`` set), not ``ok``
when it was lost on the air (a collision).  Every estimator's port has its own copy of each
medium (the same background and draws in each), unless the network shares them
(``links.shared_queues``, or a port opened ``share_with`` another).

A new medium is one subclass, registered in :data:`~dkfsim.core.registry.MEDIA`
(docs/extending.md, "Add a medium").
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any, ClassVar

import numpy as np


class Frame:
    """One frame handed to a medium: its sender, size (bytes), hand-over instant (ns), what it
    carries (``parts``: the port's, opaque to the medium) and whom to tell when it is done
    (``done(frame, ok)``; None: a background frame, nobody's); ``start`` and ``end`` of its
    transmission once it has one, ``owner`` the port whose frame it is (None: background);
    ``lost_at``, set by a medium whose receivers decide each for itself (a spatial radio) before
    ``done(frame, True)``: a mapping receiver node -> whether it lost the frame to a collision,
    holding every receiver that lost it (None: every receiver got it)."""

    __slots__ = ("node", "size", "handed", "parts", "done", "start", "end", "owner", "lost_at")

    def __init__(self, node: int, size: int, handed: int, parts: Any = None,
                 done: Callable[[Frame, bool], None] | None = None, owner: Any = None):
        self.node, self.size, self.handed, self.parts, self.done = node, size, handed, parts, done
        self.owner = owner
        self.start = self.end = -1
        self.lost_at: Mapping[int, bool] | None = None


class Medium:
    """How frames leave their sender (one copy per port unless shared; see the module)."""

    #: The medium's name in :data:`~dkfsim.core.registry.MEDIA` (``dkfsim list media``).
    kind: ClassVar[str] = ""
    #: True for a broadcast medium: the parts of one flush of a sender on it go as one frame
    #: (every receiver hears it); False: each part is a frame of its own, on its own link.
    broadcast: ClassVar[bool] = False
    #: True for a medium whose frames leave at their hand-over and that keeps nothing: the port
    #: draws their propagation at once without offering them (what :meth:`offer` would do).
    passive: ClassVar[bool] = False
    #: True for a medium that decides a frame's departure when it is handed over (a point-to-point
    #: transmitter): the port asks :meth:`depart` instead of making a :class:`Frame`.
    synchronous: ClassVar[bool] = False

    def offer(self, frame: Frame) -> bool:
        """Hand ``frame`` over now: False when it finds no room (nothing of it is sent, and
        ``done`` is never called); True when it was taken, ``frame.done`` then being called
        exactly once, now or later."""
        raise NotImplementedError

    def depart(self, owner: Any, nbytes: int, handed: int) -> int | None:
        """A :attr:`synchronous` medium's :meth:`offer` of one part of ``nbytes`` bytes handed over
        at ``handed`` by ``owner``: the instant its transmission ends (it has left then), or None
        when it finds no room."""
        raise NotImplementedError(f"{type(self).__name__} is not synchronous")

    def lane(self) -> tuple[Any, int] | None:
        """A FIFO transmitter's table and column (:data:`~dkfsim.network.port_kernels.Fifos`)
        when the port's compiled loop can run the medium itself (a packet's departure there, one
        step with its draw); None (the default): the port asks :meth:`depart` or :meth:`offer`."""
        return None

    def leaves_at_once(self, nbytes: int) -> bool:
        """Whether a frame of ``nbytes`` bytes handed over now may leave its sender at this
        very instant (its transmission taking no time): what a port's lookahead asks before
        an exchange knows whether a packet can reach its receiver at the instant it is sent.
        True when unsure."""
        return True

    def report(self, owner: Any, end: int) -> dict[str, Any] | None:
        """The medium's block of ``owner``'s counts over ``[0, end]`` (``traffic.<estimate>.<kind>``
        in summary.json), None when it has none."""
        return None

    def link_report(self, owner: Any, link: Any, end: int) -> dict[str, Any]:
        """What the medium adds to ``owner``'s counts of ``link`` over ``[0, end]`` (default:
        nothing)."""
        return {}

    def interval_log(self, owner: Any, end: int) -> np.ndarray | None:
        """``(frames, 3)`` int64: (hand-over, start, end) ns of every frame the medium's waiting
        room held up to ``end`` as ``owner`` saw it (``start < 0``: dropped), for the per-tick
        queue and utilisation series of ``run.npz``; None for a medium without one."""
        return None

    def series(self, owner: Any, T_ns: int, K: int) -> dict[str, np.ndarray]:
        """The medium's per-tick arrays of ``run.npz`` as ``owner`` saw them over ``K`` ticks of
        ``T_ns`` (e.g. a spatial radio's CBR per vehicle); none by default."""
        return {}

    def own_delays(self, owner: Any) -> np.ndarray:
        """ns from hand-over to the start of transmission of each of ``owner``'s frames."""
        return np.zeros(0, dtype=np.int64)

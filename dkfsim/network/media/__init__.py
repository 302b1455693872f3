"""Media: how a frame handed over at a node leaves it (docs/design.md §3, "Media").

A port (:mod:`dkfsim.network.port`) hands every frame to the medium of its links; the medium
decides when the frame is on the air and when it has left its sender, or why it never does
(a full waiting room, a collision), and tells the frame's owner once.  The link then draws
the frame's propagation (:mod:`dkfsim.network.links`).  One implementation per medium, each
owning its queue and its counters, registered in :data:`~dkfsim.core.registry.MEDIA`
(``dkfsim list media``):

* :mod:`~dkfsim.network.media.direct` -- a link without a ``rate``: the frame leaves at once;
* :mod:`~dkfsim.network.media.fifo` -- a link with a ``rate``: a first-in-first-out
  transmitter with its waiting room and background load;
* :mod:`~dkfsim.network.media.channel` -- the shared radio channel of ``medium:``, one
  collision domain whose access rule (``medium.access.kind``, e.g.
  :mod:`~dkfsim.network.media.csma`) is one more registered implementation;
* :mod:`~dkfsim.network.media.radio` -- with ``medium.radio``, the spatial radio where each
  receiver decides (802.11p's ``edca``, ``csma`` per radio), and
  :mod:`~dkfsim.network.media.sidelink` -- C-V2X's ``sps`` on it.
"""

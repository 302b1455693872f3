"""Background frames of a link or a radio: their instants and sizes, keyed draws.

A rate-limited link (:mod:`dkfsim.network.media.fifo`) and every radio of a shared channel
(:mod:`dkfsim.network.media.channel`) carry other traffic beside the estimators': packets of
a given size arriving as a Poisson process or periodically (``background:``,
:class:`~dkfsim.components.traffic.Background`).  Their instants and sizes are pure functions
of the link's (or radio's) key and the packet's index, so every estimator's copy of the medium
sees the same background.
"""

from __future__ import annotations

import math

import numpy as np

from dkfsim.components.traffic import Background
from dkfsim.core.params import MAX_NS, NS_PER_S, seconds_to_ns
from dkfsim.core.streams import key64, keyed_uniform, keyed_uniforms

#: Background packets drawn at once (a block of keyed draws).  The instants are integer sums of
#: rounded gaps, so the block size changes no value; 512 keeps a link's first block, which
#: every port's copy of the medium draws, cheap (one math.log per packet).
BLOCK = 512
#: Longest gap between two Poisson background packets (ns), about 6.5 days.
MAX_GAP_NS = 1 << 49


def _log(u: np.ndarray) -> np.ndarray:
    """``log`` of each entry by the C library's ``log`` (``math.log``): numpy's vectorised
    ``log`` may differ in the last bit from one machine to another."""
    return np.array([math.log(x) for x in u.tolist()], dtype=np.float64)


def background_keys(prefix: tuple, seed: int) -> tuple[int, int]:
    """The keys of a background's draws: its arrival gaps' and its sizes' (``prefix``: the
    link's, ``("link", u, v)``, or the radio's, ``("channel", c, node)``)."""
    return key64(seed, *prefix, "background", "arrival"), key64(seed, *prefix, "background", "size")


class BackgroundArrivals:
    """The background packets of one link or radio, in order: ``(instant ns, size bytes)``, keyed draws.

    Packet ``i``'s draws are pure functions of (the link's key, ``i``): a Poisson process's
    gaps ``round(-ln(u_i) / lambda)`` ns (the first from 0), a periodic one's instants
    ``offset + round(i / lambda)`` (``offset: random``: a keyed uniform over one period, per link
    or radio); exponential sizes ``max(1, round(-ln(v_i) * size))``.
    """

    def __init__(self, spec: Background, prefix: tuple, seed: int, first_block: int = BLOCK):
        self.spec = spec
        #: packets of the next block drawn: ``first_block``, doubling up to :data:`BLOCK` (a
        #: radio among hundreds that a short run hears send a few times draws few)
        self._block = max(1, min(first_block, BLOCK))
        #: the keys of the arrival gaps (or nothing, periodic) and of the sizes
        self.gap_key, self.size_key = background_keys(prefix, seed)
        #: a periodic process's first instant: ``offset``, or with ``random`` a keyed uniform over
        #: one period (the gaps' key at (0, -1): no Poisson gap uses it)
        if spec.offset == "random":
            # (held at MAX_NS, "never", as the instants are: a rate of 1e-300 per second made it
            # infinite, and int() of it raised)
            self.offset_ns = int(min(keyed_uniform(self.gap_key, 0, -1) * NS_PER_S / spec.packets_per_second, MAX_NS))
        else:
            self.offset_ns = seconds_to_ns(spec.offset)
        self._times = np.empty(0, dtype=np.int64)
        self._sizes = np.empty(0, dtype=np.int64)
        #: the block's instants and sizes as Python ints (a radio takes one packet at a time)
        self._tl: list[int] = []
        self._sl: list[int] = []
        self._drawn = 0          # packets drawn so far
        self._last = 0           # instant of the last packet drawn (the Poisson gaps' origin)
        self._pos = 0            # position of the next packet in the block

    def _draw_block(self) -> None:
        spec, lo, n = self.spec, self._drawn, self._block
        self._block = min(2 * n, BLOCK)
        idx = np.arange(lo, lo + n, dtype=np.int64)
        zeros = np.zeros(n, dtype=np.int64)
        # (at most MAX_NS: a rate of 1e-300 per second made it infinite, packet 0 of a periodic
        # process at 0 * inf, not a number, and the engine read an instant below zero)
        period = min(NS_PER_S / spec.packets_per_second, float(MAX_NS))
        if spec.arrivals == "poisson":
            gaps = np.floor(-_log(keyed_uniforms(self.gap_key, idx, zeros)) * period + 0.5)
            # a gap is at most 2^49 ns (6.5 days), so a block's sum cannot overflow
            times = self._last + np.cumsum(np.minimum(gaps, MAX_GAP_NS).astype(np.int64))
        else:
            times = self.offset_ns + np.floor(np.minimum(idx * period + 0.5, MAX_NS))
        times = np.minimum(times, MAX_NS).astype(np.int64)
        if spec.sizes == "exponential":
            sizes = np.maximum(1, np.floor(-_log(keyed_uniforms(self.size_key, idx, zeros)) * spec.size + 0.5))
        else:
            sizes = np.full(n, spec.size)
        self._times, self._sizes = times, sizes.astype(np.int64)
        self._tl, self._sl = self._times.tolist(), self._sizes.tolist()
        self._last, self._drawn, self._pos = int(times[-1]), lo + n, 0

    def next_block(self) -> tuple[np.ndarray, np.ndarray]:
        """The next :data:`BLOCK` packets not yet taken, taken now: (instants, sizes) int64 --
        for a transmitter that runs in a kernel (:class:`~dkfsim.network.media.fifo.FifoTable`);
        the same packets :meth:`until` gives, block by block."""
        if self._pos >= len(self._times):
            self._draw_block()
        times, sizes = self._times[self._pos:], self._sizes[self._pos:]
        self._pos = len(self._times)
        return times, sizes

    def next_time(self) -> int:
        """The instant of the next packet not yet taken."""
        if self._pos >= len(self._tl):
            self._draw_block()
        return self._tl[self._pos]

    def until(self, t_ns: int) -> list[int]:
        """The sizes of the packets not yet taken whose instant is ``<= t_ns``, in order, taken now."""
        sizes: list[int] = []
        while True:
            if self._pos >= len(self._tl):
                self._draw_block()
            times, pos = self._tl, self._pos
            while pos < len(times) and times[pos] <= t_ns:
                sizes.append(self._sl[pos])
                pos += 1
            self._pos = pos
            if pos < len(times):
                return sizes

    def take(self, n: int) -> tuple[list[int], list[int]]:
        """The next ``n`` packets not yet taken and any more at the last one's instant, taken now:
        (instants, sizes) -- a block for a radio's engine, which takes an instant's packets
        together (:func:`~dkfsim.network.radio_kernels.background`), so a block never splits one."""
        times: list[int] = []
        sizes: list[int] = []
        while True:
            if self._pos >= len(self._tl):
                self._draw_block()
            if len(times) >= n and (self._tl[self._pos] != times[-1] or times[-1] >= MAX_NS):
                return times, sizes             # (instants held at MAX_NS: "never", none to group)
            times.append(self._tl[self._pos])
            sizes.append(self._sl[self._pos])
            self._pos += 1

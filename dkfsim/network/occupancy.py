"""A rate-limited link over time: how many packets wait and how busy the transmitter is, per tick.

Computed after the run from the link's interval log -- one row ``(hand-over, start, end)`` ns
per packet its transmitter carried (the port's own and the background; ``start < 0``: dropped,
it occupied nothing) -- so nothing is added to the per-packet work.  A packet waits in
``[hand-over, start)`` and occupies the transmitter in ``[start, end)``; tick ``k`` (1..K)
covers ``[(k - 1) T, k T)``.  Per tick:

``queue_length``
    the time-averaged number of packets waiting (not counting the one in transmission), i.e.
    the waiting time that falls in the tick over ``T``;
``utilisation``
    the busy time that falls in the tick over ``T``.

Little's law ties them to the per-packet delays: over ``[0, t_K]`` the mean of ``queue_length``
is the accepted packets' arrival rate times their mean wait (exactly, when no packet still waits
at ``t_K``).
"""

from __future__ import annotations

import numpy as np

from dkfsim.core.params import MAX_NS, NS_PER_S


def _covered(starts: np.ndarray, ends: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """``F(x) = |union of [starts, ends) counted with multiplicity, cut at x|`` at each edge:
    ``sum(clip(x - a, 0, b - a))``, by sorting (int64 ns)."""
    a = np.sort(starts)
    b = np.sort(ends)
    ca = np.concatenate(([0], np.cumsum(a)))
    cb = np.concatenate(([0], np.cumsum(b)))
    na = np.searchsorted(a, edges, side="left")      # intervals begun before x
    nb = np.searchsorted(b, edges, side="left")      # ... and ended before x
    return (na * edges - ca[na]) - (nb * edges - cb[nb])


def per_tick(log: np.ndarray, T_ns: int, K: int) -> tuple[np.ndarray, np.ndarray]:
    """``(queue_length, utilisation)``, each ``(K,)``, from an interval log ``(packets, 3)``
    (hand-over, start, end ns; ``start < 0``: dropped): time averages over each tick."""
    log = np.asarray(log, dtype=np.int64).reshape(-1, 3)
    kept = log[log[:, 1] >= 0]
    edges = np.arange(K + 1, dtype=np.int64) * int(T_ns)
    waited = np.diff(_covered(kept[:, 0], kept[:, 1], edges))
    busy = np.diff(_covered(kept[:, 1], kept[:, 2], edges))
    return waited / float(T_ns), busy / float(T_ns)


def mean_waiting(log: np.ndarray, end_ns: int) -> float:
    """Time-averaged number of packets waiting over ``[0, end_ns]`` (0 for an empty span)."""
    if end_ns <= 0:
        return 0.0
    log = np.asarray(log, dtype=np.int64).reshape(-1, 3)
    kept = log[log[:, 1] >= 0]
    edges = np.array([end_ns], dtype=np.int64)
    return float(_covered(kept[:, 0], kept[:, 1], edges)[0]) / end_ns


def fifo(arrivals: np.ndarray, services: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Start and end (ns) of packets served first in first out by one transmitter, every one
    accepted, ``arrivals`` in service order: Lindley's recursion ``start_i = max(a_i,
    end_{i-1})`` in closed form, ``end_i = S_i + max_{j <= i}(a_j - S_{j-1})`` with ``S`` the
    cumulative service time (vectorised; the Python transmitter's numbers while nothing is
    dropped and no end reaches ``MAX_NS``)."""
    a = np.asarray(arrivals, dtype=np.int64)
    s = np.asarray(services, dtype=np.int64)
    S = np.cumsum(s)
    end = S + np.maximum.accumulate(a - (S - s))
    return end - s, end


def transmission_times(sizes: np.ndarray, rate: float) -> np.ndarray:
    """:func:`~dkfsim.components.traffic.transmission_ns` of each size (bytes), vectorised: the
    same float operations, halves up, at most ``MAX_NS``."""
    ns = np.asarray(sizes, dtype=np.float64) * 8.0 * NS_PER_S / rate
    return np.where(ns >= MAX_NS, MAX_NS, np.floor(ns + 0.5)).astype(np.int64)

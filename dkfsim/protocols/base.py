"""What every exchange protocol shares: rows, holdings, late accounting, flushes.

Protocols forward on receipt, not at ticks (docs/design.md §2), and
coalesce: everything a node learns at one instant leaves in one packet per
out-link, sent by a flush event that runs after every delivery at that
instant (zero-latency chains included) and before the tick update.

What a packet carries: for each row it mentions, an information-form
aggregate ``(theta, omega)`` and the set of origins it includes, as a
bitmask.  With fixed weights the aggregate is a *linear function of that
set* (``sum_o c_o (theta_o, omega_o)``, ``c_o`` the product of the weights
along the path from ``o``), so the bitmask stands for it on the wire: a protocol
reports what a node newly holds to the run's :class:`~dkfsim.model.holdings.Holdings`,
which materialises the numbers for every node at once when the window filter updates.  Traffic
is counted with the nominal size of the numbers (:func:`row_bytes`).

A contribution for a row that is already final at the receiver is *late*:
counted and discarded.  Without the arrival log a late (packet, row) pair
counts once; with it (``--save full``), each late (receiver, origin, row)
contribution counts once (docs/design.md §3); ``counts()["late_unit"]`` says which.  Nothing is
forwarded for a final row: every node finalises a row at the same tick.
The protocols themselves are :mod:`dkfsim.protocols.tree` and
:mod:`dkfsim.protocols.flood`.

A protocol is a subclass of :class:`Exchange` that implements three hooks:
:meth:`~Exchange.measure` (every measuring node gains its own contribution),
:meth:`~Exchange.accept` (a delivered aggregate for a live row) and
:meth:`~Exchange.flush` (what a node sends); from them it calls the public
helpers :meth:`~Exchange.measuring_nodes`, :meth:`~Exchange.gain`,
:meth:`~Exchange.schedule_flush` and :meth:`~Exchange.send`.  Overriding
:meth:`~Exchange.schedule_flush` (with :meth:`~Exchange.flush_later`)
changes *when* a node sends (docs/examples/tick_flood.py).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from simpy.events import Event

from dkfsim.components.faults import CrashSchedule
from dkfsim.core.backend import Backend
from dkfsim.core.bits import mask_words, set_bits
from dkfsim.model.holdings import Holdings
from dkfsim.network.events import PRIORITY_FLUSH, Clock, Scheduled
from dkfsim.network.links import Link
from dkfsim.network.network import Network
from dkfsim.network.port import Port

#: Bytes of a packet's header (sequence number, sender, receiver, length).
PACKET_HEADER = 16
#: Bytes a combined frame (``tree`` on a shared channel) adds per part behind its one
#: ``PACKET_HEADER``: the part's receiver and sequence number (decision 228).
PART_HEADER = 8


def info_bytes(nx: int, vectors: int = 1, matrices: int = 1) -> int:
    """Nominal bytes of a message of ``vectors`` nx-vectors and ``matrices`` symmetric nx x nx
    matrices (upper triangles): the header (stamp, sender) and 8-byte floats."""
    return PACKET_HEADER + 8 * (vectors * nx + matrices * nx * (nx + 1) // 2)


def row_bytes(nx: int, n: int) -> int:
    """Nominal bytes of one row of a packet: the row number, ``theta`` (nx floats),
    the upper triangle of ``omega`` and the origin bitmask."""
    return 8 + 8 * (nx + nx * (nx + 1) // 2) + -(-n // 8)


class Wiring:
    """The links an exchange runs over, indexed locally: ``links[e]`` is link ``e``
    (``lid[link.id] == e``), ``out_links[j]`` node ``j``'s out-links in order, ``reverse[e]``
    the local index of the link back (``None`` without one); on a graph that changes
    (``mobility:``), ``came_up[k]`` the links that come up at tick ``k`` (down at ``k - 1``)."""

    def __init__(self, links: Sequence[Link], n: int):
        self.links = list(links)
        self.lid = {link.id: i for i, link in enumerate(self.links)}
        self.n_links = len(self.links)
        self.out_links: list[list[Link]] = [[] for _ in range(n)]
        for link in self.links:
            self.out_links[link.src].append(link)
        by_arc = {(l.src, l.dst): i for i, l in enumerate(self.links)}
        self.reverse = [by_arc.get((l.dst, l.src)) for l in self.links]
        self.came_up: dict[int, list[Link]] = {}
        for link in self.links:
            for k in link.came_up():
                self.came_up.setdefault(k, []).append(link)


def exchange_counts(late: int, late_per_node: list[int], logged: bool, duplicates: int,
                    stale: int) -> dict[str, Any]:
    """An exchange's own counts as :meth:`Exchange.counts` reports them (``late`` counts
    contributions when the arrival log is kept, ``logged``, else packet rows)."""
    return {"late": late, "late_per_node": list(late_per_node),
            "late_unit": "contributions" if logged else "packet_rows",
            "duplicates": duplicates, "stale": stale}


class RowState:
    """Per-row exchange state of all nodes (lives while the row is in the window): ``held[i]``
    the origins node ``i`` holds (a bitmask); for ``tree``, per link the last message stored
    (``inbox``), its number (``inseq``) and the last one sent (``sent``)."""

    __slots__ = ("held", "inbox", "inseq", "sent")

    def __init__(self, n: int, n_links: int, tree: bool):
        self.held = [0] * n
        if tree:
            self.inbox = [0] * n_links
            self.inseq = [0] * n_links
            self.sent = [0] * n_links


class Exchange:
    """Common machinery: rows, holdings, late accounting, the arrival log, flushes.

    :param holdings: the :class:`~dkfsim.model.holdings.Holdings` told of every newly held
        contribution (:meth:`gain`).
    :param arrival: optional (n, n, K) array filled with ``inf``: the arrival
        log of docs/design.md §8 (late arrivals are logged too).
    :param late_horizon: with the arrival log, how many final rows keep their
        holdings so that a late contribution is counted once; older late bits
        are counted per packet.
    :param nx: the state size and :param T_ns: the tick period (ns), for
        the nominal packet size and for protocols that act on the tick grid.
    :param backend: the run's :class:`~dkfsim.core.backend.Backend` (numba or numpy).
    """

    tree = False
    #: How holdings are kept (``summary.json``'s ``exchange``): origin bitmasks, in Python.
    bookkeeping = "masks"
    #: The graph the protocol runs on (:func:`dkfsim.components.topology.make_exchange`):
    #: ``"tree"`` (an undirected tree, or a spanning tree of the topology) or ``"digraph"``
    #: (every arc of the topology; undirected edges both ways).
    graph = "digraph"

    def __init__(self, env: Clock, n: int, holdings: Holdings, arrival: np.ndarray | None = None,
                 late_horizon: int = 4096, nx: int = 1, T_ns: int = 1, backend: Backend | None = None):
        self.env = env
        #: the run's backend: a protocol with kernels of its own compiles them on the numba path
        self.backend = backend if backend is not None else Backend.from_environment()
        self.T_ns = int(T_ns)
        self.row_bytes = row_bytes(nx, n)
        self.n = n
        self.holdings = holdings
        self.arrival = arrival
        #: with the arrival log: node, origin mask, row, ns (flat, four entries per item) of
        #: every newly held or late contribution, written into ``arrival`` in bulk
        #: (:meth:`write_log`); each cell is written at most once, so order does not matter.
        self._log: list[int] | None = [] if arrival is not None else None
        self.late_horizon = late_horizon
        self.rows: dict[int, RowState] = {}
        self.final: dict[int, list[int]] = {}
        self.late = 0
        self.late_per_node = [0] * n
        self.duplicates = 0
        self.stale = 0
        self._flush_due = [False] * n
        #: nodes whose flush is due at this instant, in the order they became due
        self._flush_queue: list[int] = []
        #: per node, an event callback that flushes it (:meth:`flush_later`)
        self._flush_cb = [self._make_flush(j) for j in range(n)]

    # -- wiring ----------------------------------------------------------------
    def open_port(self, network: Network, name: str, links: list[Link]) -> Port:
        """The port this exchange sends through, named ``name``, reporting on ``links``: one whose
        packets are Python objects delivered one by one to :meth:`receive` (a protocol whose
        bookkeeping runs in batches opens a :class:`~dkfsim.network.port.RecordPort`)."""
        return network.port(name, self.receive, links)

    def attach(self, port: Port, links: Sequence[Link]) -> None:
        """Send through ``port`` over ``links`` (the exchange graph's arcs, in order).

        Links are indexed locally, ``0 .. len(links) - 1`` (``self.lid[link.id]``).
        """
        self.port = port
        wiring = Wiring(links, self.n)
        self.links, self.lid, self.n_links = wiring.links, wiring.lid, wiring.n_links
        self.out_links, self.reverse = wiring.out_links, wiring.reverse
        #: tick -> the links that come up then (a graph that changes; empty otherwise)
        self.came_up = wiring.came_up
        self._late_packets = [0] * self.n_links
        #: per link: the number of the last packet sent (links reorder: receivers keep the newest)
        self.seq = [0] * self.n_links

    def send(self, link: Link, items: Sequence[tuple[int, int]]) -> None:
        """Send one packet on ``link`` carrying ``items``, ``(row, origin mask)`` pairs (numbered
        per link, sized ``PACKET_HEADER + len(items) * row_bytes``)."""
        i = self.lid[link.id]
        self.seq[i] += 1
        self.port.send(link, (self.seq[i], items), PACKET_HEADER + len(items) * self.row_bytes)

    def send_frame(self, parts: Sequence[tuple[Link, Sequence[tuple[int, int]]]], frame_bytes: int) -> None:
        """Send one frame of ``frame_bytes`` bytes from one node carrying ``parts``,
        ``(link, items)`` pairs: each part is the packet :meth:`send` would put on its link
        (numbered per link, counted with its own size).  Without a shared channel it is
        exactly those packets, in order; on one, a single frame contends for the channel
        (:meth:`dkfsim.network.links.Port.send_frame`)."""
        seq, lid, size = self.seq, self.lid, self.row_bytes
        out = []
        for link, items in parts:
            i = lid[link.id]
            seq[i] += 1
            out.append((link, (seq[i], items), PACKET_HEADER + len(items) * size))
        self.port.send_frame(out, frame_bytes)

    def _make_flush(self, j: int) -> Callable[[Event], None]:
        def cb(_event: Event, j: int = j) -> None:
            self._flush_due[j] = False
            self.flush(j)
        return cb

    def schedule_flush(self, node: int) -> None:
        """Hook: ``node`` has something new to send.  Default: flush it at this instant, after
        every delivery of the instant (once, however often it is asked).  A protocol that
        sends at other times overrides it, usually with :meth:`flush_later`."""
        if not self._flush_due[node]:
            self._flush_due[node] = True
            self._flush_queue.append(node)
            if len(self._flush_queue) == 1:
                Scheduled(self.env, self._flush_all, PRIORITY_FLUSH)

    def flush_later(self, node: int, delay: int) -> None:
        """Flush ``node`` ``delay`` ns from now (after that instant's deliveries), unless a flush
        of it is already due."""
        if not self._flush_due[node]:
            self._flush_due[node] = True
            Scheduled(self.env, self._flush_cb[node], PRIORITY_FLUSH, delay)

    def _flush_all(self, _event: Event) -> None:
        """Flush every due node, first due first; what a flush sends with zero latency is
        delivered before the next node flushes (as separate events of higher priority
        would be), so a zero-latency chain joins the flushes of the same instant."""
        queue, due = self._flush_queue, self._flush_due
        deliver_now = self.port.deliver_now
        k = 0
        while k < len(queue):
            j = queue[k]
            k += 1
            due[j] = False
            self.flush(j)
            deliver_now()
        queue.clear()

    # -- rows ------------------------------------------------------------------
    def open_row(self, row: int) -> None:
        self.rows[row] = RowState(self.n, self.n_links, self.tree)

    def close_row(self, row: int) -> None:
        """``row`` became final: keep only its holdings, for late accounting per contribution
        (only with the arrival log; without it late counts need no per-origin state)."""
        st = self.rows.pop(row, None)
        if st is not None and self.arrival is not None:
            self.final[row] = st.held
            self.final.pop(row - self.late_horizon, None)
            if self._log is not None and len(self._log) > 400_000:    # 100 000 entries: bound its memory
                self.write_log()

    def finish(self) -> None:
        """The run is over: write what is still buffered (the arrival log)."""
        self.write_log()

    def write_log(self) -> None:
        """Write the logged arrivals into the arrival array (seconds)."""
        if not self._log or self.arrival is None:
            return
        log, self._log = self._log, []
        k, o = set_bits(mask_words(log[1::4], -(-self.n // 64)))
        nodes, rows = np.array(log[0::4], dtype=np.intp), np.array(log[2::4], dtype=np.intp)
        self.arrival[nodes[k], o, rows[k]] = np.array(log[3::4], dtype=np.int64)[k] / 1e9

    # -- holdings --------------------------------------------------------------
    def gain(self, node: int, row: int, st: RowState, bits: int) -> None:
        """``node`` now holds the contributions ``bits`` (origin mask) of live ``row``, whose
        state is ``st``; the bits must be new to it (``bits & st.held[node] == 0``)."""
        st.held[node] |= bits
        self.holdings.add(node, bits, row)
        if self._log is not None:            # the arrival log (--save full) only
            self._log.extend((node, bits, row, self.env.now))

    def count_late(self, node: int, row: int, mask: int) -> None:
        """Contributions ``mask`` for ``row`` reached ``node`` after the row became final: count
        them (per packet row, or per new contribution with the arrival log) and log them."""
        if self.arrival is None:          # no log: one late (packet, row) pair
            self.late += 1
            self.late_per_node[node] += 1
            return
        held = self.final.get(row)
        if held is None:          # older than the horizon: cannot deduplicate
            c = mask.bit_count()
            self.late += c
            self.late_per_node[node] += c
            return
        new = mask & ~held[node]
        if not new:
            return
        held[node] |= new
        c = new.bit_count()
        self.late += c
        self.late_per_node[node] += c
        if self._log is not None:
            self._log.extend((node, new, row, self.env.now))

    # -- protocol hooks ----------------------------------------------------------
    #: :class:`dkfsim.components.faults.CrashSchedule` (set by the estimator) or None.  A
    #: node that is down does not measure; the network drops what arrives at
    #: it, so it never has anything to send while down.
    crashes: CrashSchedule | None = None

    def measuring_nodes(self) -> Sequence[int]:
        """The nodes that measure now: all but those in a crash window."""
        if not self.crashes:
            return range(self.n)
        now = self.env.now
        return [i for i in range(self.n) if not self.crashes.down(i, now)]

    def measure(self, row: int) -> None:
        """Hook: at ``row``'s tick every measuring node gains its own contribution (and
        schedules what it sends)."""
        raise NotImplementedError

    def receive(self, link: Link, payload: Any) -> None:
        """Deliver a packet: late rows are counted, live ones go to :meth:`accept`."""
        seq, items = payload
        late = False
        for row, mask in items:
            st = self.rows.get(row)
            if st is None:
                self.count_late(link.dst, row, mask)
                late = True
            else:
                self.accept(link, seq, row, st, mask)
        if late:
            self._late_packets[self.lid[link.id]] += 1

    def accept(self, link: Link, seq: int, row: int, st: RowState, mask: int) -> None:
        """Hook: packet number ``seq`` on ``link`` carries the aggregate ``mask`` (origins) for
        live ``row`` (state ``st``): gain what is new to ``link.dst`` and relay it."""
        raise NotImplementedError

    def flush(self, node: int) -> None:
        """Hook: ``node``'s flush is due: :meth:`send` what it has for its out-links."""
        raise NotImplementedError

    @property
    def late_packets(self) -> list[int]:
        """Per link: delivered packets that carried a contribution for a row already final at
        the receiver."""
        return self._late_packets

    def counts(self) -> dict[str, Any]:
        """The exchange's own counts: ``late`` (in ``late_unit``), per node, duplicates, stale."""
        return exchange_counts(self.late, self.late_per_node, self.arrival is not None, self.duplicates,
                               self.stale)

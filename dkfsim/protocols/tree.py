"""``tree``: the paper's Algorithm 2 on a tree, asynchronous and exact (unit weights).

Node ``i`` sends neighbour ``j`` the aggregate of its own contribution and
the latest message from every other neighbour.  On a tree these subtrees
are disjoint, so that set is ``held_i minus msg(j -> i)``.  It never uses
the paper's ``Theta_i - msg(j -> i)`` update, which subtracts a stale
message under asynchrony (docs/design.md §5).  Messages carry a per-link
sequence number; a message for a row supersedes the stored one only if its
number is higher (links reorder).

On a graph that changes (``mobility:``) the tree is rebuilt whenever the links up change
(:attr:`TreeExchange.tree_changes`, worked out by the run plan): from that tick on node
``i`` sends only on the arcs of the new spanning forest, and on each arc new to it sends
at once everything it holds for the window's rows but what came from that neighbour (the
arc's last sent message is forgotten).  Holdings are sets, so nothing is counted twice
whatever the tree was; packets in flight on an arc that left the tree are still accepted
(docs/design.md §5).

A node's flush is one frame carrying every neighbour's message (each different: a message to
``j`` leaves out ``j``'s subtree) behind one header, each part with its receiver and number
(:data:`~dkfsim.protocols.base.PART_HEADER`): on a broadcast medium (the shared channel) one
contention and one preamble per flush instead of one per neighbour (decision 228); on any
other medium each part is its own packet.

The bookkeeping runs in batches (:mod:`dkfsim.protocols.tree_kernels`): the packets delivered
at one instant in one call, the nodes due to flush at one instant in one call, whatever the
medium.  A packet is a record of its port (:class:`~dkfsim.network.port.RecordPort`): its
number as the tag, one ``(row, origin words)`` record per item.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from simpy.events import Event

from dkfsim.core.bits import set_bits
from dkfsim.core.jit import bind
from dkfsim.core.registry import PROTOCOLS
from dkfsim.network.events import PRIORITY_FLUSH, Scheduled
from dkfsim.network.links import Link
from dkfsim.network.network import Network
from dkfsim.network.port import Port, RecordPort
from dkfsim.protocols import tree_kernels as tk
from dkfsim.protocols.base import PACKET_HEADER, PART_HEADER, Exchange, Wiring, exchange_counts

#: Packets per link and instant the port answers for at once (:meth:`RecordPort.lookahead <dkfsim.network.port.RecordPort.lookahead>`): more
#: are asked for when a flush needs them.
LOOKAHEAD = 2


@PROTOCOLS.register("tree")
class TreeExchange(Exchange):
    """The paper's Algorithm 2 on a tree, asynchronous and exact (unit weights)."""

    tree = True
    graph = "tree"
    #: tick -> the arcs of the tree from that tick on (a graph that changes), else None:
    #: set by the estimator before :meth:`attach`
    tree_changes: dict[int, list[tuple[int, int]]] | None = None

    port: RecordPort

    # -- wiring ----------------------------------------------------------------------
    def open_port(self, network: Network, name: str, links: list[Link]) -> RecordPort:
        """A record port: one ``(row, origin words)`` record per item."""
        self.W = -(-self.holdings.info.theta.shape[1] // 64)
        return network.record_port(name, self.receive_records, links, width=1 + self.W, backend=self.backend)

    def attach(self, port: Port, links: Sequence[Link]) -> None:
        if not isinstance(port, RecordPort):
            raise TypeError("the tree exchange sends through the record port its open_port opened")
        self.port = port
        wiring = Wiring(links, self.n)
        self.links, self.lid, self.n_links = wiring.links, wiring.lid, wiring.n_links
        n, E, S, W = self.n, self.n_links, self.holdings.S, self.W
        k = self._k = tk.compiled() if self.backend.compiled else tk
        #: link id -> local index (-1: not one of the exchange's)
        self._local = np.full(1 + max((l.id for l in self.links), default=-1), -1, dtype=np.int64)
        for e, link in enumerate(self.links):
            self._local[link.id] = e
        src = np.array([l.src for l in self.links], dtype=np.int64)
        order = np.argsort(src, kind="stable")              # each node's out-links in link order
        node = np.zeros((4, n + 1), dtype=np.int64)
        node[tk.OUTPTR] = np.searchsorted(src[order], np.arange(n + 1))
        arcs = np.zeros((8, E), dtype=np.int64)
        arcs[tk.SRC], arcs[tk.DST] = src, [l.dst for l in self.links]
        arcs[tk.REV] = [-1 if r is None else r for r in wiring.reverse]
        arcs[tk.INTREE] = 0 if self.tree_changes is not None else 1    # (a changing graph: the first tree at tick 1)
        arcs[tk.OUT], arcs[tk.LID] = order, [l.id for l in self.links]
        logged = self.arrival is not None
        H = self.late_horizon if logged else 1
        z = np.zeros
        self.X = tk.Tree(z(15, np.int64), np.full(S, -1, np.int64), z((S, n, W), np.uint64),
                         z((S, E, W), np.uint64), z((S, E), np.int64), z((S, E, W), np.uint64), z((n, S), np.uint8),
                         node, arcs, z((H, n if logged else 0, W), np.uint64), np.full(H, -1, np.int64),
                         z((2, W), np.uint64))
        CT = self.X.CT
        CT[tk.LO], CT[tk.HI] = 0, -1
        CT[tk.LOGON] = int(logged)
        CT[tk.HEADER], CT[tk.ROWB], CT[tk.PARTB] = PACKET_HEADER, self.row_bytes, PART_HEADER
        #: the most out-links of a node: one node's flush fits in ``deg`` parts of ``deg * S`` items
        self._maxdeg = int(np.diff(node[tk.OUTPTR]).max()) if n else 0
        self.O = self._out(max(64, self._maxdeg + 1), max(256, self._maxdeg * S + 1))
        self._flush_pending = False
        self._by_arc = {(l.src, l.dst): e for e, l in enumerate(self.links)}
        self._in_tree: set[int] = set()
        self._fresh = np.zeros(0, dtype=np.int64)
        self._all = np.arange(n, dtype=np.int64)
        #: the smallest packet (one row)
        self._smallest = PACKET_HEADER + self.row_bytes
        # the kernels, bound to their arguments' types (one call each skips numba's dispatch)
        X, O, i = self.X, self.O, np.zeros(1, np.int64)
        self._measure = bind(k.measure, X, O, 0, i, i)
        self._receive = bind(k.receive, X, O, np.zeros((1, 4), np.int64), port.records().view(np.uint64), i)
        self._flush = bind(k.flush, X, O, np.zeros((1, LOOKAHEAD), np.int8), i)
        self._receive_flush = bind(k.receive_flush, X, O, np.zeros((1, 4), np.int64), port.records().view(np.uint64),
                                   i, np.zeros((1, LOOKAHEAD), np.int8), i)
        #: whether no packet of the exchange ever arrives at the instant it is sent (e.g. every
        #: link rate-limited; worked out on the first delivery, the port's media all known then):
        #: a delivery and the flushes it makes due then run in one kernel call, with the
        #: lookahead ``_never`` ("not now" for every packet)
        self._quiet: bool | None = None
        self._never = np.zeros((E, LOOKAHEAD), dtype=np.int8)

    def _out(self, parts: int, items: int) -> tk.Out:
        """Output buffers for up to ``parts`` parts (and frames) and ``items`` items or gains."""
        z = np.zeros
        return tk.Out(z((3, items), np.int64), z((items, self.W), np.uint64), z((parts, 7), np.int64),
                      z((parts, 2), np.int64), z((items, 1 + self.W), np.uint64))

    def _room(self, parts: int, items: int) -> None:
        """Output buffers at least this large."""
        O = self.O
        if len(O.parts) < parts or O.gain.shape[1] < items:
            self.O = self._out(max(parts, 2 * len(O.parts)), max(items, 2 * O.gain.shape[1]))

    @property
    def late_packets(self) -> list[int]:
        """Per link: delivered packets that carried a contribution for a row already final."""
        return self.X.link[tk.LATE_LINK].tolist()

    # -- rows ------------------------------------------------------------------------
    def open_row(self, row: int) -> None:
        pass                                       # (the row opens in :meth:`measure`)

    def close_row(self, row: int) -> None:
        """``row`` became final (done in the kernels' next call: nothing reads it before)."""
        self.X.CT[tk.FINAL] = row + 1

    def finish(self) -> None:
        pass                                       # (the arrival log is written as it comes)

    # -- the protocol's steps ---------------------------------------------------------
    def measure(self, row: int) -> None:
        fresh = self._fresh
        if self.tree_changes is not None:
            arcs = self.tree_changes.get(row + 1)          # row's tick: a new tree from now on
            if arcs is not None:
                fresh = self.retree(arcs)
        nodes = self._all if self.crashes is None else np.asarray(self.measuring_nodes(), dtype=np.int64)
        self._room(0, len(nodes))
        self._measure(self.X, self.O, row, nodes, fresh)
        self._gains()

    def retree(self, arcs: list[tuple[int, int]]) -> np.ndarray:
        """The tree is now ``arcs``: send only on them; the arcs new to it, whose senders are up
        (each sends everything it holds for the window's rows, its last sent message
        forgotten: :func:`~dkfsim.protocols.tree_kernels.measure`)."""
        tree = {self._by_arc[a] for a in arcs}
        new = sorted(tree - self._in_tree)
        self._in_tree = tree
        intree = self.X.link[tk.INTREE]
        intree[:] = 0
        intree[sorted(tree)] = 1
        now = self.env.now
        if self.crashes is not None:            # a node that is down sends nothing
            new = [e for e in new if not self.crashes.down(int(self.X.link[tk.SRC, e]), now)]
        return np.array(new, dtype=np.int64)

    def receive_records(self, batch: np.ndarray, records: np.ndarray) -> None:
        """The packets delivered now, in the order they were sent (one call per instant): packet
        ``k`` came over link id ``batch[k, 0]`` as number ``batch[k, 1]`` with the items
        ``records[batch[k, 2]:batch[k, 3]]``."""
        if len(batch) * self.holdings.S > self.O.gain.shape[1]:     # (a packet has at most S rows)
            self._room(0, int((batch[:, 3] - batch[:, 2]).sum()))
        if self._quiet is None:
            self._quiet = self.port.never_now(self.links, LOOKAHEAD, self._smallest)
        if self._quiet and not self._flush_pending and self.env.peek() > self.env.now:
            # (what _gains(at_once=True) and _flush_all would do next, without asking the port)
            self._flush_pending = True
            used = np.zeros(self.n_links, dtype=np.int64)
            status = self._receive_flush(self.X, self.O, batch, records.view(np.uint64), self._local, self._never, used)
            self._flush_all(None, status)
            return
        self._receive(self.X, self.O, batch, records.view(np.uint64), self._local)
        self._gains(at_once=True)

    def _flush_all(self, _event: Event | None, status: int | None = None) -> None:
        """Flush the due nodes, first due first: in one kernel call while the port can say which
        packets reach their receiver at this instant (those are delivered before the next node
        flushes, as separate events of higher priority would be); a flush whose packets it
        cannot answer for goes through the port and is delivered before the rest go on.
        ``status``: a flush call's already made (:meth:`receive_records`)."""
        X, port = self.X, self.port
        ahead = None
        while True:
            if status is None:
                if ahead is None:
                    ahead = port.lookahead(self.links, LOOKAHEAD, self._smallest)
                used = np.zeros(self.n_links, dtype=np.int64)
                status = self._flush(X, self.O, ahead, used)
            if status < 0:
                raise RuntimeError("tree exchange: the output buffers cannot hold one node's flush")
            self._gains()
            sent = self._send()
            if status == tk.DONE:
                break
            if status == tk.ASK:
                port.deliver_now()              # (what it sent that arrives now, in order)
                ahead = None
            elif status == tk.ROOM:
                self._room(2 * len(self.O.parts), 2 * self.O.gain.shape[1])
                if sent:
                    ahead = None
            status = None
        self._flush_pending = False

    # -- glue ------------------------------------------------------------------------
    def _gains(self, at_once: bool = False) -> None:
        """Hand the gains of the last kernel call to the holdings (and the arrival log), and
        make the flush due if the call made nodes due: ``at_once``, the flush runs now when
        nothing else happens at this instant (the event it would be is the next one anyway)."""
        X, O = self.X, self.O
        g = int(X.CT[tk.NG])
        if g:
            X.CT[tk.NG] = 0
            nodes, rows, words = O.gain[0, :g], O.gain[1, :g], O.gw[:g]
            if self.arrival is not None:
                kk, o = set_bits(words)
                self.arrival[nodes[kk], o, rows[kk]] = self.env.now / 1e9
                keep = O.gain[2, :g] == 0
                if not keep.all():
                    nodes, rows, words = nodes[keep], rows[keep], words[keep]
            if len(nodes):
                self.holdings.add_words(nodes, rows, words)
        if X.CT[tk.QLEN] > X.CT[tk.QHEAD] and not self._flush_pending:
            self._flush_pending = True
            if at_once and self.env.peek() > self.env.now:
                self._flush_all(None)
            else:
                Scheduled(self.env, self._flush_all, PRIORITY_FLUSH)

    def _send(self) -> bool:
        """Hand the frames of the last flush call to the port, in order; whether there were any."""
        X, O = self.X, self.O
        nf = int(X.CT[tk.NF])
        if not nf:
            return False
        npart, ni = int(X.CT[tk.NP]), int(X.CT[tk.NI])
        X.CT[tk.NF] = X.CT[tk.NP] = X.CT[tk.NI] = 0
        self.port.send_records(O.parts[:npart], O.recs[:ni].view(np.int64), O.frames[:nf])
        return True

    def counts(self) -> dict[str, Any]:
        CT = self.X.CT
        return exchange_counts(int(CT[tk.LATE]), self.X.node[tk.LATE_NODE, :self.n].tolist(),
                               self.arrival is not None, 0, int(CT[tk.STALE]))

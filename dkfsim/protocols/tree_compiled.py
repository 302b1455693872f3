"""``tree`` with its instants compiled: a twin of :class:`~dkfsim.protocols.tree.TreeExchange`
(the same protocol, packets, counts and folds), one kernel call per tick instead of Python
per packet.

SimPy runs the clock, but the exchange has no events of its own: its state is its own
(no other estimator reads it) and the tick's update is the first thing that reads what it
folded, so the tick's measure runs, in one kernel call, every instant since the last tick at
which its packets arrived (deliveries, then flushes, as the Python protocol's events would
have run them), then the tick's own deliveries and flushes, in the order the Python
protocol's events come (docs/design.md §2; docs/decisions.md 158).  Inside, the kernels of
:mod:`dkfsim.protocols.tree_compiled_kernels` keep every row's holdings, messages and
sequence numbers as uint64 words, draw each packet's latency from its link's keys, keep
packets in flight on a heap and fold new contributions straight into the run's
:class:`~dkfsim.model.holdings.Holdings`.

A twin by composition, not a subclass: it is not an :class:`~dkfsim.protocols.base.Exchange`
(its port delivers nothing; ``receive`` is None), and shares with one only the local
indexing of the links (:class:`~dkfsim.protocols.base.Wiring`) and the form of the counts
(:func:`~dkfsim.protocols.base.exchange_counts`).  The engine decides where it runs, once
per run (:func:`exchange_class`, :func:`usable`, :class:`~dkfsim.core.backend.Backend`):
the compiled exchange on the numba path, no crashes, and every link plain (no loss,
duplication, outage, schedule or jitter) with a ``constant`` or ``uniform_steps`` latency.
Anything else runs the Python protocol.  docs/design.md §5 ("Compiled tree").
"""

from __future__ import annotations

import numpy as np

from dkfsim.core.backend import EXCHANGE_ENV, Backend  # noqa: F401  (EXCHANGE_ENV re-exported)
from dkfsim.core.jit import entry_point
from dkfsim.core.registry import PROTOCOLS
from dkfsim.model.holdings import Holdings
from dkfsim.network.occupancy import fifo, transmission_times
from dkfsim.network.transmitter import busy_within, link_stats
from dkfsim.protocols import tree_compiled_kernels as tk
from dkfsim.protocols.base import PACKET_HEADER, Wiring, exchange_counts, row_bytes
from dkfsim.protocols.tree import TreeExchange


def usable(protocol: str, links, crashes) -> bool:
    """Whether ``protocol`` has a compiled twin that can run over these ``links`` with these
    crash windows (see the module)."""
    return (PROTOCOLS.get(protocol).implementation is TreeExchange and not crashes
            and all(link.compiled_latency() is not None for link in links))


def exchange_class(protocol: str, backend: Backend) -> type:
    """The class that runs ``protocol`` on ``backend``: its compiled twin when the backend's
    exchange is compiled and it has one (``tree``), else the registered implementation."""
    impl = PROTOCOLS.get(protocol).implementation
    if backend.compiled_exchange and impl is TreeExchange:
        return CompiledTreeExchange
    return impl


class CompiledTreeExchange:
    """The ``tree`` protocol with its instants compiled (identical packets, counts and folds).

    The constructor and the hooks the anti-delay DKF calls are those of an
    :class:`~dkfsim.protocols.base.Exchange`: :meth:`attach`, :meth:`open_row`,
    :meth:`measure`, :meth:`close_row`, :meth:`finish`, :meth:`counts`, :attr:`late_packets`.
    """

    tree = TreeExchange.tree
    graph = TreeExchange.graph
    bookkeeping = "masks, compiled"
    #: Its kernels deliver its packets: the port it is attached to delivers none.
    receive = None
    #: (Runs only without crash windows.)
    crashes = None
    #: Packets the pool holds at first (it doubles when a flush needs more).
    initial_pool = 64

    def __init__(self, env, n: int, holdings: Holdings, arrival=None, late_horizon: int = 4096, nx: int = 1,
                 T_ns: int = 1):
        self.env = env
        self.n = n
        self.holdings = holdings
        self.arrival = arrival
        self.late_horizon = late_horizon
        self.T_ns = int(T_ns)
        self.row_bytes = row_bytes(nx, n)
        self._k = tk.compiled()
        self.W = -(-holdings.info.theta.shape[1] // 64)
        self.CT = np.zeros(13, dtype=np.int64)
        #: queueing delay (ns) and link of each packet a transmitter accepted (CT[ND] of them)
        self.dly = np.zeros(0, dtype=np.int64)
        self.dlk = np.zeros(0, dtype=np.int64)
        self.dlt = np.zeros(0, dtype=np.int64)
        self.dls = np.zeros(0, dtype=np.int64)

    def attach(self, port, links) -> None:
        """Run over ``links`` (the exchange graph's arcs, in order), reporting the counts to ``port``."""
        self.port = port
        self.wiring = wiring = Wiring(links, self.n)
        self.links, self.n_links = wiring.links, wiring.n_links
        n, E, S, W = self.n, self.n_links, self.holdings.S, self.W
        self.G = np.array([[l.src, l.dst, -1 if r is None else r, 0]
                           for l, r in zip(self.links, wiring.reverse)], dtype=np.int64).reshape(E, 4)
        order = np.argsort(self.G[:, 0], kind="stable")      # out-links of a node in link order
        self.out_ptr = np.searchsorted(self.G[order, 0], np.arange(n + 1)).astype(np.int64)
        self.out_idx = order.astype(np.int64)
        forms = [l.compiled_latency() for l in self.links]
        self.lkind = np.array([f[0] for f in forms], dtype=np.int64)
        self.lkey = np.array([f[1] for f in forms], dtype=np.uint64)
        self.lpar = np.array([f[2] for f in forms], dtype=np.int64)
        self.dinst = np.full(E, -1, dtype=np.int64)
        self.dcnt = np.zeros(E, dtype=np.int64)
        self.lseq = np.zeros(E, dtype=np.int64)
        self.rowid = np.full(S, -1, dtype=np.int64)
        self.held = np.zeros((S, n, W), dtype=np.uint64)
        self.inbox = np.zeros((S, E, W), dtype=np.uint64)
        self.inseq = np.zeros((S, E), dtype=np.int64)
        self.sent = np.zeros((S, E, W), dtype=np.uint64)
        self.dirty = np.zeros((n, S), dtype=np.uint8)
        self.due = np.zeros(n, dtype=np.uint8)
        self.queue = np.zeros(n + 1, dtype=np.int64)
        self.counts_ = np.zeros((4, E), dtype=np.int64)     # sent, delivered, late packets, bytes
        self._transmitters(links)
        self.late_node = np.zeros(n, dtype=np.int64)
        deg = int(np.diff(self.out_ptr).max()) if n else 0
        self.outp = np.full(max(deg, 1), -1, dtype=np.int64)
        self.new = np.zeros(W, dtype=np.uint64)
        self.out = np.zeros(W, dtype=np.uint64)
        self._pool(max(self.initial_pool, 4 * E) if self.initial_pool > 1 else 1)
        self._grow_delays(max(1024, 4 * E))
        logf = self.arrival is not None
        # With the arrival log: the holdings of the last late_horizon final rows (late accounting).
        K = self.holdings.info.theta.shape[0]
        H = min(self.late_horizon, K + 1) if logf else 1     # never more than the rows
        self.fheld = np.zeros((H, n if logf else 1, W), dtype=np.uint64)
        self.frow = np.full(H, -1, dtype=np.int64)
        # The kernels' arguments (tree_compiled_kernels: Rows, Links, Pool, Log; the holdings' Fold).
        self._k_rows = tk.Rows(self.CT, self.rowid, self.held, self.inbox, self.inseq, self.sent, self.dirty,
                               self.due, self.queue, self.new, self.out)
        self._k_links = tk.Links(self.G, self.out_ptr, self.out_idx, self.lkind, self.lkey, self.lpar, self.dinst,
                                 self.dcnt, self.lseq, self.counts_, self.late_node, PACKET_HEADER, self.row_bytes,
                                 self.T_ns)
        #: the transmitters, or None without a rate (the kernels compiled without them)
        self._k_tx = self.tx if self.rated else None
        if self._k_tx is not None:
            self._k.start_background(self._k_tx)
        self._k_fold = self.holdings.fold_target
        self._k_log = tk.Log(logf, self.arrival if logf else np.empty((1, 1, 1)), self.fheld, self.frow)
        self._bind()
        # Compiled entry points of exactly these argument types (numba's per-call type
        # dispatch skipped); each kernel called once with nothing to do (row -1; empty heap).
        k = self._k
        self._tick = entry_point(k.tick, -1, -1, -1, *self._args)
        self._advance = entry_point(k.advance, -1, -1, 0, *self._args)

    def _transmitters(self, links) -> None:
        """The links' transmitters as the kernels keep them (:class:`tree_compiled_kernels.Tx`);
        each background's first packet is drawn by the kernel
        (:func:`~dkfsim.protocols.tree_compiled_kernels.start_background`)."""
        E = len(links)
        forms = [link.compiled_traffic() for link in links]
        rate = np.zeros(E)
        qcap = np.full(E, -1, dtype=np.int64)
        bgk = np.zeros(E, dtype=np.int64)
        bgkey = np.zeros(E, dtype=np.uint64)
        bgskey = np.zeros(E, dtype=np.uint64)
        bgper, bgsize = np.zeros(E), np.zeros(E)
        bgexp = np.zeros(E, dtype=np.bool_)
        bgoff = np.zeros(E, dtype=np.int64)
        for e, f in enumerate(forms):
            if f is not None:
                rate[e], qcap[e], bgk[e], bgkey[e], bgskey[e], bgper[e], bgsize[e], bgexp[e], bgoff[e] = f
        # the next background packet: none (MAX_NS) or, before the first, index -1 at 0
        bgt = np.where(bgk > 0, 0, tk.MAX_NS).astype(np.int64)
        bgi = np.full(E, -1, dtype=np.int64)
        ring = np.zeros((E, max(1, int(qcap.max(initial=1)))), dtype=np.int64)
        zeros = [np.zeros(E, dtype=np.int64) for _ in range(5)]    # rhead rlen free_at busy bgs
        self.tx = tk.Tx(rate, qcap, ring, zeros[0], zeros[1], zeros[2], zeros[3], bgk, bgkey, bgskey, bgper, bgsize,
                        bgexp, bgoff, bgi, bgt, zeros[4], np.zeros((2, E), dtype=np.int64), np.zeros(E, dtype=np.int64))
        self.rated = bool(rate.any())

    def _pool(self, P: int) -> None:
        """A packet pool of ``P`` slots (the heap holds at most that many); grows, keeping
        the packets in flight."""
        S, W = self.holdings.S, self.W
        pk = np.zeros((P, 3), dtype=np.int64)
        rows = np.zeros((P, S), dtype=np.int64)
        masks = np.zeros((P, S, W), dtype=np.uint64)
        heap = tuple(np.zeros(P, dtype=np.int64) for _ in range(3))
        free = np.arange(P - 1, -1, -1, dtype=np.int64)
        if hasattr(self, "pk"):
            P0, nfree = self.pk.shape[0], int(self.CT[tk.NFREE])
            pk[:P0], rows[:P0], masks[:P0] = self.pk, self.pk_rows, self.pk_masks
            for new, old in zip(heap, self.heap):
                new[:P0] = old
            free[:nfree] = self.free[:nfree]
            free[nfree:nfree + P - P0] = np.arange(P - 1, P0 - 1, -1)
            self.CT[tk.NFREE] = nfree + P - P0
        else:
            self.CT[tk.NFREE] = P
        self.pk, self.pk_rows, self.pk_masks, self.heap, self.free = pk, rows, masks, heap, free

    def _grow_delays(self, size: int) -> None:
        """Room for ``size`` queueing delays (what the transmitters accepted so far kept)."""
        grown = []
        for old in (self.dly, self.dlk, self.dlt, self.dls):
            a = np.zeros(size, dtype=np.int64)
            a[:len(old)] = old
            grown.append(a)
        self.dly, self.dlk, self.dlt, self.dls = grown

    def _bind(self) -> None:
        """The kernels' arguments (rebuilt when the pool grows)."""
        self._k_pool = tk.Pool(*self.heap, self.free, self.pk, self.pk_rows, self.pk_masks, self.outp, self.dly,
                               self.dlk, self.dlt, self.dls)
        self._args = (self._k_rows, self._k_links, self._k_tx, self._k_pool, self._k_fold, self._k_log)

    # -- rows ------------------------------------------------------------------
    def open_row(self, row: int) -> None:
        """Nothing: :meth:`measure` opens the row in the kernel (what arrives before it cannot
        touch the row's slot in the holdings: the row that used it is final)."""

    def close_row(self, row: int) -> None:
        """``row`` became final: what arrives for it from now on is late."""
        self.CT[tk.LO] = row + 1
        slot = row % self.holdings.S
        if self.rowid[slot] == row:
            self.rowid[slot] = -1
            if self.arrival is not None:          # keep its holdings: late ones count once
                self.fheld[row % len(self.frow)] = self.held[slot]
                self.frow[row % len(self.frow)] = row

    # -- the clock -------------------------------------------------------------
    def measure(self, row: int) -> None:
        """The tick: every instant since the last one, then the new row and this instant's
        deliveries and flushes (:func:`~dkfsim.protocols.tree_compiled_kernels.tick`)."""
        now, until = self.env.now, self.port.until
        while self._tick(row, now, until, *self._args) == tk.NEED_ROOM:
            self._grow()

    def _grow(self) -> None:
        """Room for the next node's flush: a pool twice as large, more queueing delays."""
        if int(self.CT[tk.NFREE]) < self.outp.shape[0]:
            self._pool(2 * self.pk.shape[0])
        if int(self.CT[tk.ND]) + self.outp.shape[0] > len(self.dly):
            self._grow_delays(2 * len(self.dly))
        self._bind()

    # -- results ---------------------------------------------------------------
    def finish(self) -> None:
        """Run the instants after the last tick up to the port's last instant, then write the
        kernels' per-link counts into the port (what ``port.counts()`` reports); the arrival
        log is already written."""
        until = self.port.until
        while self._advance(until + 1, until, 0, *self._args) == tk.NEED_ROOM:
            self._grow()
        sent, delivered, _, nbytes = (row.tolist() for row in self.counts_)
        qdrop = self.tx.qdrop.tolist()
        for i, link in enumerate(self.links):
            self.port.set_counts(link, sent=sent[i], delivered=delivered[i], bytes=nbytes[i],
                                 queue_dropped=qdrop[i])
        if self.rated:
            self._link_stats()

    def _link_stats(self) -> None:
        """Each rate-limited link's utilisation, queueing delays and background (the port's
        :meth:`~dkfsim.network.links.Port.set_link_stats`), as the Python transmitters report them."""
        end = int(self.port.until if self.port.until is not None else self.env.now)
        self._k.traffic_until(end, self._k_tx)
        rate, free_at, busy, bgc = self.tx.rate, self.tx.free_at, self.tx.busy, self.tx.bgc
        nd = int(self.CT[tk.ND])
        order = np.argsort(self.dlk[:nd], kind="stable")         # by link, hand-over order kept
        dly, dlt, dls = self.dly[:nd][order], self.dlt[:nd][order], self.dls[:nd][order]
        cut = np.searchsorted(self.dlk[:nd][order], np.arange(len(self.links) + 1))
        for e, link in enumerate(self.links):
            if rate[e] > 0:
                mine = slice(cut[e], cut[e + 1])
                used = busy_within(int(busy[e]), int(free_at[e]), end)
                self.port.set_link_stats(link, link_stats(dly[mine], used, int(bgc[0, e]), int(bgc[1, e]), end))
                logs = None
                if int(bgc[1, e]) == 0:           # no background dropped: the closed form
                    logs = self._merge(link, dlt[mine], dls[mine], dly[mine], end)
                if logs is None:
                    logs = self._replay(link, dlt[mine], dls[mine], dly[mine], end)
                self.port.set_link_log(link, *logs)

    @staticmethod
    def _merge(link, handed: np.ndarray, sizes: np.ndarray, delays: np.ndarray,
               end: int) -> tuple[np.ndarray, np.ndarray] | None:
        """The interval logs (own, background) of ``link``'s transmitter when the queue dropped
        no background packet: the port's accepted packets and the background up to ``end``
        merged in first-in-first-out order (background first at one instant) and served by
        :func:`~dkfsim.network.occupancy.fifo`.  None when it does not reproduce the kernels'
        queueing delays (:meth:`_replay` then decides)."""
        bg = link.transmitter().background
        times, bsizes = bg.until(end) if bg is not None else ([], [])
        t = np.concatenate([np.asarray(times, dtype=np.int64), handed])
        nbytes = np.concatenate([np.asarray(bsizes, dtype=np.int64), sizes])
        kind = np.concatenate([np.zeros(len(times), dtype=np.int64), np.ones(len(handed), dtype=np.int64)])
        order = np.lexsort((np.arange(len(t)), kind, t))
        starts, ends = np.empty_like(t), np.empty_like(t)
        starts[order], ends[order] = fifo(t[order], transmission_times(nbytes[order], link.rate))
        own = np.stack([handed, starts[len(times):], ends[len(times):]], axis=1)
        if not np.array_equal(own[:, 1] - own[:, 0], delays) or (len(ends) and ends.max() >= tk.MAX_NS):
            return None
        k = len(times)
        return own, np.stack([t[:k], starts[:k], ends[:k]], axis=1)

    @staticmethod
    def _replay(link, handed: np.ndarray, sizes: np.ndarray, delays: np.ndarray,
                end: int) -> tuple[np.ndarray, np.ndarray]:
        """The interval logs (own, background) of ``link``'s transmitter
        (:mod:`~dkfsim.network.occupancy`): the
        port's accepted packets (hand-over instants, sizes) offered again, in order, to a fresh
        transmitter with the link's background -- the queue-length series is computed after
        the run, not in the kernels.  The replay must reproduce the kernels' queueing delays."""
        tx = link.transmitter(record=True)
        own = np.empty((len(handed), 3), dtype=np.int64)
        for i, (t, size) in enumerate(zip(handed.tolist(), sizes.tolist())):
            got = tx.offer(t, size)
            own[i] = (t, *got) if got is not None else (t, -1, -1)
        tx.advance(end)
        if not np.array_equal(own[:, 1] - own[:, 0], delays):
            raise RuntimeError(f"link {link.src} -> {link.dst}: the transmitter's replay differs "
                               "from the compiled tree's queueing delays")
        return own, tx.log()

    @property
    def late_packets(self) -> list[int]:
        """Per link: delivered packets that carried a contribution for a row already final."""
        return self.counts_[2].tolist()

    def counts(self) -> dict:
        """The exchange's own counts, as :meth:`Exchange.counts <dkfsim.protocols.base.Exchange.counts>`."""
        return exchange_counts(int(self.CT[tk.LATE]), self.late_node.tolist(), self.arrival is not None, 0,
                               int(self.CT[tk.STALE]))

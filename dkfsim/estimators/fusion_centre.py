"""``fusion_centre``: the DKF's fusion run at one node, fed over the network (issue 22 §2).

The idealised ``fused`` estimate combines every node's estimate at the instant it is
computed, with no packets.  A fusion centre at node ``at`` does the same from what reaches
it: right after the scenario's DKF computes row ``r = k-1`` at tick ``k``, every other node
sends the centre its estimate ``x_i[r]`` and its held-origin masks of the last ``W = L + M``
rows (its window, and the last ``M`` final rows; ``M``: ``margin``, default ``L``), plus the information matrix
``omega_o[row]`` of each measurement-dependent origin (a radar) it holds and has not carried
before.  Packets are relayed hop by hop along a shortest path of the DKF's exchange graph,
through the DKF's own transmitters and channel (docs/design.md §7, "The fusion centre").

The centre keeps each node's newest estimate (an older one arriving later is ignored) and a
*shadow* of the nodes' covariance recursion: a :class:`~dkfsim.model.holdings.Holdings`,
:class:`~dkfsim.estimators.window.WindowFilter` and
:class:`~dkfsim.estimators.fusion.CrossCovariance` of buffer length ``W``, fed with the masks
the packets carried (never the measurements: the shadow's information vectors are zero, and a
radar's ``omega`` is known only for entries a packet carried).  A node whose newest estimate is
of an older row ``r_i`` enters as ``Phi^(r - r_i) x_i``: that node's filter with empty holdings
for the later rows, which is what the shadow runs for it, so the fusion of design §7 is exact
for what the centre holds.  When the shadow must make a row final before it knows that node's
final holdings of it (more than ``M`` ticks without a packet), the node leaves the fusion for
the rest of the run (``nodes_excluded``; docs/decisions.md #220); so does a node whose masks hold
a radar entry whose ``omega`` no packet delivered (each node carries a given one once).  The centre fuses row ``k-1``
in an event of priority :data:`~dkfsim.network.events.PRIORITY_FUSE`, after the packets sent at
the update and their zero-latency relays: at zero latency and no rate limit it equals ``fused``.
Its packets take one path, its port's, whatever the media (decision 240).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from simpy.events import Event

from dkfsim.components.estimators import EstimatorParams, FusionCentreParams
from dkfsim.config.plan import RunPlan
from dkfsim.core.resources import B_FLOAT, C_FLOP, C_FUSION_ROW, C_NODE_ROW, C_PACKET, C_ROW, C_TICK, Cost
from dkfsim.estimators.base import DKFView, Estimate, Estimator, EstimatorResult, RunContext
from dkfsim.estimators.fusion import FUSERS, CrossCovariance
from dkfsim.estimators.window import WindowFilter
from dkfsim.model.holdings import Holdings
from dkfsim.model.system import Information
from dkfsim.network.events import PRIORITY_FUSE, Scheduled
from dkfsim.network.links import Link
from dkfsim.network.port import Port
from dkfsim.protocols.base import PACKET_HEADER


def next_hops(arcs: list[tuple[int, int]], n: int, at: int) -> tuple[np.ndarray, np.ndarray]:
    """Each node's next hop toward ``at`` on a shortest path over the directed ``arcs`` (the
    lowest-index neighbour among equals; a breadth-first search from ``at`` over the reversed
    arcs), -1 for ``at`` itself and for a node that cannot reach it; and each node's hops to
    ``at`` on that path (0 for ``at``, -1 for a node that cannot reach it)."""
    import networkx as nx  # (lazy: a centre's start, not every command, needs it)
    graph = nx.DiGraph()
    graph.add_nodes_from(range(n))
    graph.add_edges_from((v, u) for u, v in arcs)              # reversed: distances *to* at
    dist = np.full(n, -1, dtype=np.intp)
    for node, d in nx.single_source_shortest_path_length(graph, at).items():
        dist[node] = d
    hop = np.full(n, -1, dtype=np.intp)
    for u, v in sorted(arcs):
        if u != at and dist[u] > 0 and dist[v] == dist[u] - 1 and hop[u] < 0:
            hop[u] = v
    return hop, dist


def packet_bytes(nx: int, n: int, rows: int, omegas: int) -> int:
    """Nominal bytes of a node's packet to the centre: header, row number, the estimate,
    ``rows`` origin masks and the upper triangles of ``omegas`` carried ``omega`` matrices."""
    return PACKET_HEADER + 8 + 8 * nx + rows * (-(-n // 8)) + omegas * 8 * (nx * (nx + 1) // 2)


class FusionCentre(Estimator, params=FusionCentreParams):
    """The scenario DKF's matrix-weighted fusion at node ``at``, from packets only."""

    #: Its packets and their nominal sizes (bytes; docs/estimators.md, "Packet sizes").
    packets = ("one per node but `at` and tick, relayed hop by hop to `at`: 16-byte header + 8 (row) "
               "+ 8 nx (the estimate) + W ceil(n/8) (held-origin masks of the last W = L + margin rows) "
               "+ 8 nx(nx+1)/2 per measurement-dependent omega carried the first time")
    #: Its port is opened ``share_with`` the DKF's (:meth:`start`): no copy of the media of its own.
    own_media = False

    params: FusionCentreParams
    port: Port
    dkf: DKFView

    def __init__(self, params: FusionCentreParams, ctx: RunContext):
        super().__init__(params, ctx)
        self.at = int(params.at)
        #: optional log for tests: per fuse ``(k, newest, excluded, known masks of the
        #: shadow's rows k-W .. k-1, Xi of row k-1)``; None: not kept
        self.log: list[tuple] | None = None

    @classmethod
    def cost(cls, params: EstimatorParams, plan: RunPlan) -> Cost:
        assert isinstance(params, FusionCentreParams)
        sc = plan.scenario
        n, nx, K = sc.n, sc.nx, int(sc.steps)
        L, _ = plan.buffer_length_bound(plan.dkf().buffer_length)
        W = L + (L if params.margin is None else params.margin)
        S, N = min(W, K) + 1, n * nx
        c = Cost(params.label)
        c.seconds = K * (C_TICK + min(W, K) * (C_ROW + n * C_NODE_ROW + C_FUSION_ROW) + 2 * n * C_PACKET
                         + N ** 3 * C_FLOP)
        c.memory["fusion centre"] = (S * (N * N + n * (2 * nx + 3 * nx * nx)) * B_FLOAT + 3 * S * n * n
                                     + K * n * nx * B_FLOAT + K * (nx + nx * nx) * B_FLOAT)
        return c

    # -- running -------------------------------------------------------------------
    def start(self) -> None:
        ctx = self.ctx
        assert ctx.dkf is not None        # (the scenario's DKF starts first)
        self.dkf = dkf = ctx.dkf          # the scenario's DKF, with its fusion (validation checked)
        sys_, K, n, nx = ctx.system, ctx.K, ctx.n, ctx.nx
        self.Phi = sys_.Phi
        self.L = L = int(dkf.L)
        margin = self.params.margin
        self.M = L if margin is None else int(margin)   # the final rows a packet repeats
        self.W = W = L + self.M
        self.fuser = FUSERS[dkf.fusion]
        info = ctx.info
        # Which origins' information depends on the measurement (radar): only entries a packet
        # carried are known to the centre.  Linear sensors' omega is the model's.
        self.varying = np.array([info.varying and getattr(s, "convert", None) is not None
                                 for s in sys_.sensors], dtype=bool)
        self.vary = bool(self.varying.any())
        self.cols = [np.flatnonzero(info.column_sensor == o) for o in range(n)]
        omega, factor = info.omega, info.factor
        if self.varying.any():
            omega, factor = omega.copy(), factor.copy()
            omega[:, self.varying] = 0.0
            for o in np.flatnonzero(self.varying):
                factor[:, :, self.cols[o]] = 0.0
        self.info = Information(theta=np.zeros_like(info.theta), omega=omega, factor=factor,
                                column_sensor=info.column_sensor)
        #: (K, n): the centre has origin o's omega of row r (always for a linear sensor)
        self.have_omega = np.broadcast_to(~self.varying, (K, n)).copy()
        self.holdings = Holdings(self.info, dkf.weights, W, per_origin=True, backend=ctx.backend)
        self.window = WindowFilter(sys_.Phi, sys_.Q, sys_.x0_mean, sys_.P0, self.holdings, ctx.backend)
        self.xcov = CrossCovariance(self.window, sys_.P0)
        S = self.holdings.S
        #: what the centre knows node i holds of each shadow row (folded or pending)
        self.known = np.zeros((S, n, n), dtype=bool)
        self.newest = np.full(n, -1, dtype=np.int64)
        #: per node: the row of its newest packet (a Python list: one packet costs no numpy
        #: call; ``newest`` is its array as of the last fusion).  The estimate of that row is
        #: the DKF's ``x_local[row, i]`` (never written again), read at the fusion.
        self.newest_rows = [-1] * n
        self.x0 = np.asarray(sys_.x0_mean, float)
        self._nodes = np.arange(n)
        self.excluded = np.zeros(n, dtype=bool)
        # The senders' side: what each node held of the last W rows, what omegas it carried.
        self.sent_held = np.zeros((W, n, n), dtype=bool)
        self.carried = np.zeros((W, n, n), dtype=bool)
        self.hop, dist = next_hops(ctx.plan.exchange_arcs, n, self.at)
        net = ctx.network
        self.out: list[Link | None] = [net.link(i, int(h)) if h >= 0 else None for i, h in enumerate(self.hop)]
        links = [l for l in self.out if l is not None]
        # Through the DKF's media (its queues and channel): the centre's load is part of the DKF's
        # cost; its own counters and keyed draws (sequence numbers from 1 << 32).
        self.port = net.port(self.name, self.receive, links, share_with=dkf.port)
        self.x = np.empty((K, nx))
        self.P = np.empty((K, nx, nx))
        self.k = 0
        self.received = self.ignored = self.stale_rows = 0
        self.Phi_pow = np.eye(nx)[None]
        #: node -> (first row, masks of every node) of its newest packet since the last fusion
        self.pending: dict[int, tuple[int, np.ndarray]] = {}

    def on_measure(self, row: int) -> None:
        self.holdings.open_row(row)
        self.known[row % self.holdings.S] = False
        self.carried[row % self.W] = False

    def on_update(self, k: int) -> None:
        """Every node sends its estimate of row ``k-1`` (the DKF has just computed it)."""
        self.k = k
        r = k - 1
        W, n, nx = self.W, self.ctx.n, self.ctx.nx
        held = self.dkf.held
        window = np.arange(max(r - self.L + 1, 0), r + 1)  # the DKF's window as of this tick
        self.sent_held[window % W] = held[window % held.shape[0]]
        lo = max(r - W + 1, 0)
        idx = np.arange(lo, r + 1) % W
        masks = self.sent_held[idx]                          # (rows, n, n)
        vary = self.vary
        crashes, now = self.ctx.crashes, int(self.ctx.env.now)
        out_links, at, send = self.out, self.at, self.port.send
        entries: list[tuple[int, int, np.ndarray, np.ndarray]] = []
        nbytes = packet_bytes(nx, n, len(idx), 0)
        for i in range(n):
            if crashes is not None and i != at and crashes.down(i, now):
                continue                          # a node that is down sends nothing
            if vary:
                entries = []
                new = masks[:, i] & self.varying & ~self.carried[idx, i]
                if new.any():
                    self.carried[idx, i] |= new
                    info = self.ctx.info
                    for j, o in zip(*np.nonzero(new)):
                        row = lo + int(j)
                        entries.append((row, int(o), info.omega[row, o], info.factor[row][:, self.cols[o]]))
                nbytes = packet_bytes(nx, n, len(idx), len(entries))
            # (read-only from here on) The packet models carrying node i's estimate x_i[r] too
            # (its nominal size ``nbytes`` counts it); the centre reads that estimate from the
            # DKF's x_local[r, i] once the packet is accepted, so the tuple leaves it out.
            payload = (i, r, lo, masks, entries, nbytes)
            out = out_links[i]
            if i == at:
                self.accept(payload)
            elif out is not None:
                send(out, payload, nbytes)
        Scheduled(self.ctx.env, self._fuse, PRIORITY_FUSE)

    def receive(self, link: Link, payload: Any) -> None:
        """A packet reaches ``link.dst``: the centre takes it, a relay forwards it at once."""
        node = link.dst
        if node == self.at:
            self.received += 1
            self.accept(payload)
            return
        out = self.out[node]
        if out is not None:                      # (a node that is down received nothing: crash_dropped)
            self.port.send(out, payload, payload[-1])

    def accept(self, payload: tuple) -> None:
        """Node ``i``'s estimate of ``row`` and its holdings, into the centre's state."""
        i, row, lo, masks, entries, _ = payload
        for r_e, o, om, fac in entries:         # an omega is the same whoever brings it, whenever
            self.info.omega[r_e, o] = om
            self.info.factor[r_e][:, self.cols[o]] = fac
            self.have_omega[r_e, o] = True
        if self.excluded[i] or row <= self.newest_rows[i]:
            self.ignored += 1                    # older than what the centre has, or left out
            return
        self.pending[i] = (lo, masks)           # folded at the fusion: the newest masks hold the rest
        self.newest_rows[i] = row               # (its estimate: the DKF's x_local[row, i])

    def _fuse(self, _event: Event | None) -> None:
        k = self.k
        r = k - 1
        self.newest[:] = self.newest_rows
        self._fold(k)
        newest, excluded = self.newest, self.excluded
        done = k - self.W                 # the shadow's row that becomes final now
        low = int(newest.min())
        if done >= 0 and low + 1 - self.L < done:
            # a node whose final holdings of that row the centre does not know leaves the fusion
            excluded |= (newest + 1 - self.L) < done
        self.window.update(k, on_rows=self.xcov.on_rows)
        Xi = self.xcov.Xi[r % self.holdings.S]
        # each node's newest estimate (the prior mean before its first packet)
        xs = self.dkf.x_local[np.maximum(newest, 0), self._nodes]
        if low < 0:
            xs[newest < 0] = self.x0
        everyone = not excluded.any()
        if low < r:                       # (else no estimate is older than row r)
            stale = np.flatnonzero(newest < r) if everyone else np.flatnonzero((newest < r) & ~excluded)
            if len(stale):
                self.stale_rows += len(stale)
                xs[stale] = np.einsum("sij,sj->si", self._powers(r - newest[stale]), xs[stale])
        if everyone:
            self.x[r], self.P[r] = self.fuser(Xi, xs)
        else:
            sel = np.flatnonzero(~excluded)
            self.x[r], self.P[r] = self.fuser(_sub(Xi, sel, self.ctx.nx), xs[sel])
        if self.log is not None:
            idx = np.arange(max(k - self.W, 0), k) % self.holdings.S
            self.log.append((k, self.newest.copy(), self.excluded.copy(), self.known[idx].copy(), Xi.copy()))

    def _powers(self, ages: np.ndarray) -> np.ndarray:
        """``Phi^age`` for each of ``ages`` (cached)."""
        pw = self.Phi_pow
        top = int(ages.max())
        if top >= len(pw):
            more = [pw[-1]]
            for _ in range(len(pw), top + 1):
                more.append(self.Phi @ more[-1])
            self.Phi_pow = pw = np.concatenate([pw, np.stack(more[1:])])
        return pw[ages]

    def _fold(self, k: int) -> None:
        """Add what the newest packets of this tick taught the centre to the shadow's holdings:
        for each node, the origins its masks hold that the centre did not know, for the shadow's
        rows that can still change (``k - W .. k - 1``).  A node's masks only grow, so its newest
        packet says everything the older ones of this tick said."""
        if not self.pending:
            return
        k0 = max(k - self.W, 0)
        nodes = np.fromiter(self.pending, dtype=np.intp, count=len(self.pending))
        stack = np.zeros((k - k0, len(nodes), self.known.shape[2]), dtype=bool)   # (rows, nodes, origins)
        for j, (i, (lo, masks)) in enumerate(self.pending.items()):
            a, b = max(lo, k0), lo + len(masks)
            if a < b:
                stack[a - k0:b - k0, j] = masks[a - lo:, i]
        self.pending.clear()
        if not self.vary:
            self.holdings.add_unknown(stack, nodes, k0, self.known)
            return
        slots = np.arange(k0, k) % self.holdings.S
        new = stack & ~self.known[slots[:, None], nodes]
        rr, jj = np.nonzero(new.any(axis=2))
        if not len(jj):
            return
        sel, rows, who = new[rr, jj], k0 + rr, nodes[jj]
        # a node that holds a radar entry whose omega no packet brought leaves the fusion
        bad = np.unique(who[(sel & ~self.have_omega[rows]).any(axis=1)])
        if len(bad):
            self.excluded[bad] = True
            keep = ~np.isin(who, bad)
            sel, rows, who, rr = sel[keep], rows[keep], who[keep], rr[keep]
        self.known[slots[rr], who] |= sel
        self.holdings.add_held(who, rows, sel)

    def finish(self) -> EstimatorResult:
        facts = {"packets_received": self.received, "packets_ignored": self.ignored,
                 "stale_rows_used": self.stale_rows, "nodes_excluded": int(self.excluded.sum()),
                 "at": self.at, "rows_carried": self.W}
        return EstimatorResult({self.name: Estimate(self.x, self.P)}, traffic=self.port.counts(), facts=facts)


def _sub(Xi: np.ndarray, nodes: np.ndarray, nx: int) -> np.ndarray:
    """The cross-covariances of ``nodes`` only."""
    idx = (nodes[:, None] * nx + np.arange(nx)).reshape(-1)
    return Xi[np.ix_(idx, idx)]

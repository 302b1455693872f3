"""``centralized_delayed``: a fusion centre fed over direct links, with the same buffer.

Each sensor sends its row to the centre at its tick over a direct link with
the scenario's *default* link settings (latency model, loss, jitter,
schedule, outages, duplication: the earlier copy counts); the per-link
overrides name links of the graph, which the centre is not on.  The links'
draws are named ``("direct", <sensor name>, ...)``.  The packets go through
the estimator's port like any other: with a ``rate`` in the default settings
each direct link has its transmitter (its ``queue`` and ``background`` too,
docs/traffic.md), and on a shared channel (``medium:``) each sensor's packet
is a unicast frame contending with every other frame and the background.  The
centre runs the anti-delay window filter with the DKF's buffer length ``L``: a
row arriving after it became final is late.  A crashed sensor sends nothing.
Traffic: the port's (``sent + copies = delivered + lost + queue_dropped +
crash_dropped + in_flight``).  Where nothing but the links' draws acts on the
packets, :meth:`CentralizedDelayed.arrival_ticks` works their arrivals out in
closed form: the tests' oracle for the port.
"""

from __future__ import annotations

import numpy as np
from typing_extensions import override

from dkfsim.components.estimators import CentralizedDelayedParams, EstimatorParams
from dkfsim.config.plan import RunPlan
from dkfsim.core.resources import B_FLOAT, C_NODE_ROW, C_PACKET, C_ROW, C_TICK, Cost
from dkfsim.estimators.base import Estimate, Estimator, EstimatorResult
from dkfsim.estimators.window import WindowFilter
from dkfsim.model.holdings import Holdings
from dkfsim.network.links import Link
from dkfsim.network.media.fifo import Fifo
from dkfsim.protocols.base import info_bytes


class CentralizedDelayed(Estimator, params=CentralizedDelayedParams):
    """The window filter of a fusion centre that receives every sensor over its own link."""

    #: Its packets and their nominal sizes (bytes; docs/estimators.md, "Packet sizes").
    packets = ("one per sensor and tick on its direct link: 16 + 8 (nx + nx(nx+1)/2) "
               "(the measurement's information vector and matrix)")

    @classmethod
    @override
    def cost(cls, params: EstimatorParams, plan: RunPlan) -> Cost:
        scenario = plan.scenario
        K, n, nx = int(scenario.steps), scenario.n, scenario.nx
        L = min(plan.L_estimate, K)
        # per (sensor, row): its arrival tick, and the indices that order the usable ones (6 ints)
        return Cost(params.label, memory={"centralized_delayed": K * n * (7 * 8 + 2 * nx * B_FLOAT)
                                          + (L + 1) * (2 * nx + 3 * nx * nx) * B_FLOAT},
                    seconds=K * (C_TICK + L * (C_ROW + C_NODE_ROW) + n * C_PACKET))

    def start(self) -> None:
        """Open the port on each sensor's direct link to the centre (decision 229)."""
        ctx = self.ctx
        s, K = ctx.system, ctx.K
        self._direct = self._direct_links()
        self._ticks = np.zeros((s.n, K), dtype=np.int64)
        self._measured = ctx.measured()
        self._size = self.packet_bytes()
        self._port = self.open_port(self._receive, self._direct, until=K * ctx.T_ns)

    def on_measure(self, row: int) -> None:
        """Row ``row``'s tick: every sensor that measured sends its packet to the centre."""
        m, send, size = self._measured, self._port.send, self._size
        for i, link in enumerate(self._direct):
            if m is None or m[row, i]:                     # a crashed sensor sends nothing
                send(link, (i, row), size)

    def _direct_links(self) -> list:
        """Each sensor's direct link to the centre (``("direct", name)``, the default link
        settings), added to the network in sensor order."""
        ctx = self.ctx
        spec = ctx.scenario.link_spec(-1, -1)              # the default settings
        return [ctx.network.extra_link(("direct", name), spec, i, -1) for i, name in enumerate(ctx.system.names)]

    def _receive(self, _link: Link, payload: tuple[int, int]) -> None:
        i, row = payload
        if self._ticks[i, row] == 0:                       # the first copy counts
            self._ticks[i, row] = -(-self.ctx.env.now // self.ctx.T_ns)

    def arrival_ticks(self) -> tuple[np.ndarray, dict]:
        """The closed form of the port's work where nothing but the links' draws and their
        transmitters act (no channel, no crash of the centre): the tick (1-based) at which the
        centre holds sensor i's row r, 0 if never (``(n, K)`` ints: the first ``k`` with
        ``t_k >= t_{r+1} + latency``), and the counts per sensor (``sent``, ``lost``,
        ``queue_dropped``: ``(n,)`` ints).  Call it after :meth:`start` (it uses the direct
        links); the tests compare it with the run."""
        ctx = self.ctx
        s, K, T_ns = ctx.system, ctx.K, ctx.T_ns
        ticks = np.zeros((s.n, K), dtype=np.int64)
        m = ctx.measured()
        sent, lost, dropped = (np.zeros(s.n, dtype=np.int64) for _ in range(3))   # per sensor
        size = self.packet_bytes()
        for i, link in enumerate(self._direct):
            tx = Fifo(link).tx if link.spec.rate is not None else None
            for r in range(K):
                if m is not None and not m[r, i]:          # a crashed sensor sends nothing
                    continue
                t = (r + 1) * T_ns
                sent[i] += 1
                wait = 0                                   # hand-over to the end of transmission
                if tx is not None:
                    got = tx.offer(t, size)
                    if got is None:                        # the waiting room is full
                        dropped[i] += 1
                        continue
                    wait = got[1] - t
                arrivals, why = link.transmit(t, 0)
                lost[i] += why is not None
                if arrivals:
                    ticks[i, r] = -(-(t + wait + min(arrivals)) // T_ns)
        return ticks, {"sent": sent, "lost": lost, "queue_dropped": dropped}

    def packet_bytes(self) -> int:
        """A sensor's packet: header and its measurement's information vector and matrix."""
        return info_bytes(self.ctx.system.nx)

    def finish(self) -> EstimatorResult:
        ctx = self.ctx
        s, K = ctx.system, ctx.K
        L = ctx.plan.buffer_length()
        held = Holdings(ctx.info, np.ones((1, s.n)), L, backend=ctx.backend)
        w = WindowFilter(s.Phi, s.Q, s.x0_mean, s.P0, held, ctx.backend)
        ticks = self._ticks
        rows = np.arange(K)
        usable = (ticks > 0) & (ticks <= rows + L) & (ticks <= K)
        order = np.argsort(ticks[usable], kind="stable")
        sensor_idx, row_idx = np.nonzero(usable)
        sensor_idx, row_idx, at = sensor_idx[order], row_idx[order], ticks[usable][order]
        bounds = np.searchsorted(at, np.arange(1, K + 2))
        x = np.empty((K, s.nx))
        P = np.empty((K, s.nx, s.nx))
        for k in range(1, K + 1):
            held.open_row(k - 1)
            for j in range(bounds[k - 1], bounds[k]):
                held.add(0, 1 << int(sensor_idx[j]), int(row_idx[j]))
            w.update(k)
            slot = (k - 1) % w.S
            x[k - 1], P[k - 1] = w.state.x[slot, 0], w.state.P[slot, 0]
        late = int(((ticks > rows + L) & (ticks <= K)).sum())
        return EstimatorResult({self.name: Estimate(x, P)}, traffic={**self._port.counts(), "late": late})

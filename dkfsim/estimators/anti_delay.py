"""The anti-delay DKF (the paper's Algorithms 1 and 2, and its Step 2 fusion).

Every node keeps a window of the last ``L`` rows and re-runs it at each tick
with everything it holds (:class:`~dkfsim.estimators.window.WindowFilter`,
batched over nodes); an exchange protocol (:mod:`dkfsim.protocols`) carries
the contributions; the optimal matrix-weighted fusion combines the nodes'
real-time estimates with their exact cross-covariances
(:mod:`dkfsim.estimators.fusion`).  docs/design.md §§4-7 state the
semantics; this module wires them to the run's clock and network.

The scenario's own DKF is configured by the top-level keys (``protocol``,
``weights``, ``spanning_tree``, ``buffer_length``, ``fusion``) and writes the
contract's arrays: ``x_fused``/``P_fused`` (estimate ``fused``),
``x_local``/``P_local`` (estimate ``local``: each node's real-time estimate),
``x_final``, ``arrival``, ``weights_A``, ``buffer_length``.  More instances
can be listed as estimators (``{kind: anti_delay_dkf, name: dkf_L5,
buffer_length: 5}``): each runs on the same network and draws, with its own
``buffer_length`` / ``fusion`` / ``weights``; its estimate is ``<name>``
(fused; per node with ``fusion: none``).
"""

from __future__ import annotations

import numpy as np

from dkfsim.components.estimators import AntiDelayParams, EstimatorParams, NoBufferParams
from dkfsim.components.topology import paper_weights
from dkfsim.config.plan import RunPlan
from dkfsim.core.registry import PROTOCOLS
from dkfsim.core.resources import (
    B_FLOAT,
    C_CONTRIBUTION,
    C_FLOP,
    C_FUSION_ROW,
    C_NODE_ROW,
    C_PACKET,
    C_ROW,
    C_TICK,
    Cost,
)
from dkfsim.estimators.base import DKFView, Estimate, Estimator, EstimatorResult, RunContext
from dkfsim.estimators.fusion import FUSERS, CrossCovariance
from dkfsim.estimators.window import WindowFilter
from dkfsim.model.holdings import Holdings
from dkfsim.network.port import Port

#: Largest P_local (entries) kept: 400 MB.
P_LOCAL_LIMIT = 50_000_000


class AntiDelayDKF(Estimator, params=AntiDelayParams):
    """The anti-delay distributed Kalman filter with optimal matrix-weighted fusion."""

    #: Its packets and their nominal sizes (bytes; docs/estimators.md, "Packet sizes").
    packets = ("one per out-link and instant with news: 16-byte header + per row 8 (row number) + 8 (nx + nx(nx+1)/2) (theta, omega's upper triangle) + ceil(n/8) (origin mask)")

    params: AntiDelayParams
    port: Port                  # (opened by start)

    def __init__(self, params: AntiDelayParams, ctx: RunContext, main: bool = False):
        super().__init__(params, ctx)
        #: The scenario's own instance (writes the contract's array names).
        self.main = main
        #: Its settings, unset keys resolved against the scenario's (the run plan's).
        self.settings = ctx.plan.dkf(None if main else params)
        self.fusion = self.settings.fusion

    # -- configuration ------------------------------------------------------------
    @classmethod
    def cost(cls, params: EstimatorParams, plan: RunPlan) -> Cost:
        """From the plan's buffer length for this instance (exact, or the cheap bound)."""
        assert isinstance(params, AntiDelayParams)
        sc = plan.scenario
        n, nx, K = sc.n, sc.nx, int(sc.steps)
        settings = plan.dkf(params)
        L, _ = plan.buffer_length_bound(settings.buffer_length)
        fusion, arcs, save = settings.fusion, plan.n_exchange_links, plan.save
        S, rows, N = min(L, K) + 1, min(L, K), n * nx
        c = Cost(params.label or "anti_delay_dkf")
        c.seconds = K * (C_TICK + rows * (C_ROW + n * C_NODE_ROW) + 1.5 * arcs * C_PACKET
                         + n * n * C_CONTRIBUTION)
        c.memory["window filters"] = (S * n * (2 * nx + 3 * nx * nx) * B_FLOAT
                                      + (S * n * n if fusion != "none" else 0))      # held flags
        c.memory["x_local, x_final"] = 2 * K * n * nx * B_FLOAT
        if save in ("full", "estimates"):
            c.memory["P_local"] = min(K * n * nx * nx, P_LOCAL_LIMIT) * B_FLOAT
        if save == "full":
            c.memory["arrival log (n x n x K)"] = n * n * K * B_FLOAT
        if fusion != "none":
            c.seconds += K * ((rows * 4 + 1) * N ** 3 * C_FLOP + rows * C_FUSION_ROW)
            c.memory["cross-covariances"] = S * N * N * B_FLOAT
            c.memory["x_fused, P_fused"] = K * (nx + nx * nx) * B_FLOAT
        return c

    # -- running -------------------------------------------------------------------
    def start(self) -> None:
        """Set up the window, the holdings, the fusion and the exchange the plan and the
        backend say (validation has checked all of it: nothing here raises); the scenario's own
        instance offers itself to the estimators that build on it (``ctx.dkf``)."""
        ctx, plan, backend = self.ctx, self.ctx.plan, self.ctx.backend
        sys_, K, n, nx = ctx.system, ctx.K, ctx.n, ctx.nx
        self.L = plan.buffer_length(self.settings.buffer_length)
        self.A = paper_weights(plan.exchange.graph) if self.settings.weights == "paper" else np.ones((n, n))
        self.holdings = Holdings(ctx.info, self.A, self.L, per_origin=self.fusion != "none", backend=backend)
        self.window = WindowFilter(sys_.Phi, sys_.Q, sys_.x0_mean, sys_.P0, self.holdings, backend)
        self.xcov = CrossCovariance(self.window, sys_.P0) if self.fusion != "none" else None
        self.arrival = np.full((n, n, K), np.inf) if (self.main and ctx.save == "full") else None
        links = ctx.exchange_links()
        protocol = PROTOCOLS.get(plan.protocol).implementation
        self.exchange = protocol(ctx.env, n, self.holdings, arrival=self.arrival,
                                 late_horizon=plan.kept_final_rows(self.L), nx=nx, T_ns=ctx.T_ns, backend=backend)
        self.exchange.crashes = ctx.crashes
        if plan.tree_schedule is not None:
            self.exchange.tree_changes = plan.tree_schedule
        self.port = self.exchange.open_port(ctx.network, self.name, links)
        self.exchange.attach(self.port, links)
        self.x_local = np.empty((K, n, nx))
        # P_local is the one (K, n, nx, nx) array: skip it when nothing will save it
        # or when it alone would take more than a few hundred megabytes.
        keep_P = ctx.save in ("full", "estimates") and K * n * nx * nx <= P_LOCAL_LIMIT
        self.P_local = np.empty((K, n, nx, nx)) if keep_P else None
        self.x_final = np.empty((K, n, nx))
        if self.xcov is not None:
            self.x_fused = np.empty((K, nx))
            self.P_fused = np.empty((K, nx, nx))
        if self.main:                     # what a fusion centre builds on (set before it starts)
            ctx.dkf = DKFView(L=self.L, fusion=self.fusion, weights=self.A, held=self.holdings.held,
                              x_local=self.x_local, port=self.port)

    def on_measure(self, row: int) -> None:
        self.exchange.open_row(row)
        self.holdings.open_row(row)
        self.exchange.measure(row)

    def on_update(self, k: int) -> None:
        L, w = self.L, self.window
        w.update(k, on_rows=self.xcov.on_rows if self.xcov is not None else None)
        row = k - 1
        slot = row % w.S
        st = w.state
        self.x_local[row] = st.x[slot]
        if self.P_local is not None:
            self.P_local[row] = st.P[slot]
        if self.xcov is not None:
            self.x_fused[row], self.P_fused[row] = FUSERS[self.fusion](self.xcov.Xi[slot], st.x[slot])
        done = k - L                      # this row leaves the window: final
        if done >= 0:
            self.x_final[done] = st.x[done % w.S]
            self.exchange.close_row(done)

    def finish(self) -> EstimatorResult:
        K, st = self.ctx.K, self.window.state
        self.exchange.finish()
        # Rows still in the window at the end were never final: keep their last value.
        for row in range(max(K - self.L + 1, 0), K):
            self.x_final[row] = st.x[row % self.window.S]
        local = Estimate(self.x_local, self.P_local)
        fused = Estimate(self.x_fused, self.P_fused) if self.xcov is not None else None
        if self.main:
            estimates = {"local": local} if fused is None else {"fused": fused, "local": local}
        else:
            estimates = {self.name: fused or local}
        arrays = {}
        if self.main:
            arrays = {"buffer_length": np.array(self.L), "weights_A": self.A, "x_final": self.x_final}
            if self.arrival is not None:
                arrays["arrival"] = self.arrival
        traffic = self.port.counts()
        traffic.update(self.exchange.counts())
        for entry, late in zip(traffic["per_link"], self.exchange.late_packets):
            entry["late_packets"] = late
        return EstimatorResult(estimates, arrays, traffic,
                               {"buffer_length": self.L, "exchange": self.exchange.bookkeeping})



class NoBuffer(AntiDelayDKF, params=NoBufferParams):
    """The anti-delay DKF without its buffer: ``L = 1`` (late information is dropped)."""

    def __init__(self, params: EstimatorParams, ctx: RunContext):
        super().__init__(AntiDelayParams(name=params.label, buffer_length=1), ctx)

    @classmethod
    def cost(cls, params: EstimatorParams, plan: RunPlan) -> Cost:
        return AntiDelayDKF.cost(AntiDelayParams(name=params.label, buffer_length=1), plan)

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

from dkfsim.components.estimators import AntiDelayParams, NoBufferParams
from dkfsim.components.topology import paper_weights
from dkfsim.config.schema import FUSION_MEMORY_LIMIT
from dkfsim.core.errors import ScenarioError
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
from dkfsim.estimators.base import Estimate, Estimator, EstimatorResult
from dkfsim.estimators.fusion import FUSERS, CrossCovariance
from dkfsim.estimators.window import WindowFilter
from dkfsim.network.links import Port
from dkfsim.protocols.tree import TreeExchange
from dkfsim.protocols.tree_compiled import CompiledTreeExchange
from dkfsim.protocols.tree_compiled import usable as compiled_tree_usable

#: Largest P_local (entries) kept: 400 MB.
P_LOCAL_LIMIT = 50_000_000


def late_horizon(scenario, n: int, L: int) -> int:
    """How many final rows keep their holdings so that a late contribution counts once.

    Nothing is sent for a final row, so with a latency bound of ``d`` steps per
    hop a late packet arrives at most ``d + 1`` rows after its row became
    final: keep that many.  Unbounded latency: 4096 rows, fewer on large
    networks so that the holdings (n masks of n bits per row) stay near 64 MB.
    """
    bound = scenario.latency_bound_steps()
    if bound is not None:
        return bound + 2
    per_row = n * (n // 8 + 32)
    return int(max(L + 2, min(4096, (64 << 20) // per_row)))


class AntiDelayDKF(Estimator, params=AntiDelayParams):
    """The anti-delay distributed Kalman filter with optimal matrix-weighted fusion."""

    params: AntiDelayParams
    port: Port                  # (opened by start)

    def __init__(self, params: AntiDelayParams, ctx, main: bool = False):
        super().__init__(params, ctx)
        sc = ctx.scenario
        #: The scenario's own instance (writes the contract's array names).
        self.main = main
        self.buffer_length = params.buffer_length if params.buffer_length is not None else sc.buffer_length
        self.fusion = params.fusion if params.fusion is not None else sc.fusion
        self.weights = params.weights if params.weights is not None else sc.weights

    # -- configuration ------------------------------------------------------------
    @staticmethod
    def resolve_L(scenario, buffer_length) -> int:
        """``auto`` -> ``d_t d_g + 1``, ``paper`` -> ``max(d_t, 1)``, an integer -> itself."""
        if isinstance(buffer_length, int):
            return buffer_length
        if buffer_length == scenario.buffer_length:
            return scenario.resolved_buffer_length()
        d_t = scenario.resolved_d_t()
        return max(d_t, 1) if buffer_length == "paper" else d_t * scenario.exchange().d_g + 1

    @classmethod
    def cost(cls, params, scenario, *, L: int, arcs: int, save: str = "estimates") -> Cost:
        """``L``: the scenario's buffer length (an instance with its own uses that)."""
        n, nx, K = scenario.n, scenario.nx, int(scenario.steps)
        if params.buffer_length is not None:
            L = cls.resolve_L(scenario, params.buffer_length)
        fusion = params.fusion or scenario.fusion
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
        ctx, sc = self.ctx, self.ctx.scenario
        sys_, K, n, nx = ctx.system, ctx.K, ctx.n, ctx.nx
        xg = sc.exchange()
        self.L = self.resolve_L(sc, self.buffer_length)
        if self.fusion != "none":
            # Validation checks the scenario's own fusion with a cheap bound of L
            # on large graphs; this is the exact check, for every instance.
            need = (min(self.L, K) + 1) * (n * nx) ** 2 * B_FLOAT
            if need > FUSION_MEMORY_LIMIT:
                where = "fusion" if self.main else next(
                    f"estimators.{i}" for i, p in enumerate(sc.estimators) if p.label == self.name)
                raise ScenarioError(
                    f"fusion: {self.fusion} keeps the cross-covariances of all {n} nodes for "
                    f"{min(self.L, K) + 1} window rows, {need / 2**30:.1f} GiB of memory; use "
                    "fusion: none for a network this large (or a shorter buffer_length)",
                    source=sc.source, path=where)
        self.A = paper_weights(xg.graph) if self.weights == "paper" else np.ones((n, n))
        self.window = WindowFilter(sys_.Phi, sys_.Q, sys_.x0_mean, sys_.P0, ctx.info, self.A, self.L,
                                   per_origin=self.fusion != "none")
        self.xcov = CrossCovariance(self.window, sys_.P0) if self.fusion != "none" else None
        self.arrival = np.full((n, n, K), np.inf) if (self.main and ctx.save == "full") else None
        links = ctx.exchange_links()
        protocol = PROTOCOLS.get(sc.protocol).implementation
        if protocol is TreeExchange and compiled_tree_usable(links, self.window.kernels, ctx.crashes):
            protocol = CompiledTreeExchange
        self.exchange = protocol(ctx.env, n, self.window, arrival=self.arrival,
                                 late_horizon=late_horizon(sc, n, self.L), nx=nx, T_ns=ctx.T_ns)
        self.exchange.crashes = ctx.crashes
        self.exchange.attach(self.open_port(self.exchange.receive, links), links)
        self.x_local = np.empty((K, n, nx))
        # P_local is the one (K, n, nx, nx) array: skip it when nothing will save it
        # or when it alone would take more than a few hundred megabytes.
        keep_P = ctx.save in ("full", "estimates") and K * n * nx * nx <= P_LOCAL_LIMIT
        self.P_local = np.empty((K, n, nx, nx)) if keep_P else None
        self.x_final = np.empty((K, n, nx))
        if self.xcov is not None:
            self.x_fused = np.empty((K, nx))
            self.P_fused = np.empty((K, nx, nx))

    def on_measure(self, row: int) -> None:
        self.exchange.open_row(row)
        self.window.begin_row(row)
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

    def __init__(self, params, ctx):
        super().__init__(AntiDelayParams(name=params.label, buffer_length=1), ctx)

    @classmethod
    def cost(cls, params, scenario, **shape):
        return AntiDelayDKF.cost(AntiDelayParams(name=params.label, buffer_length=1), scenario, **shape)

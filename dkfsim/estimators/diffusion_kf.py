"""The ``diffusion_kf`` estimator: the diffusion Kalman filter of Cattivelli & Sayed.

F. S. Cattivelli, A. H. Sayed, "Diffusion Strategies for Distributed Kalman
Filtering and Smoothing", IEEE TAC 55(9), 2010, Algorithm 1 (diffusion KF
with measurement and estimate exchange).  Per tick ``k`` node ``i``, from
its prediction ``(xbar_i, Pbar_i)``:

1. *incremental update* with the measurements of its closed neighbourhood
   ``J_i`` (itself and the neighbours heard from), in information form
   (the paper's sequential update gives the same result):
   ``P_psi_i^-1 = Pbar_i^-1 + sum_{j in J_i} H_j' R_j^-1 H_j``,
   ``psi_i = P_psi_i (Pbar_i^-1 xbar_i + sum_{j in J_i} H_j' R_j^-1 y_j)``;
2. *diffusion step*: ``xhat_i = sum_{j in J_i} c_ij psi_j`` (convex weights:
   Metropolis or uniform over ``J_i``), ``P_i = P_psi_i`` (the paper's);
3. prediction ``xbar_i <- Phi xhat_i``, ``Pbar_i <- Phi P_i Phi' + Q``.

Timing (docs/consensus.md): two sub-slots of ``T/2``.  At ``t_k`` a node
sends its measurement information (``U_j``, ``u_j``); at ``t_k + T/2`` it runs
the incremental update with the measurements that have arrived and sends
``psi_i``; at ``t_{k+1}`` it combines the ``psi_j`` that have arrived.  A
neighbour missing at a step is left out (its weight goes to the node
itself); a measurement arriving after ``t_k + T/2`` or a ``psi`` after
``t_{k+1}`` is dropped and counted late.  On a complete graph with zero
latency every node holds every measurement after step 1, so every node is
the centralized filter.  Runs on the scenario's full topology.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from typing_extensions import override

from dkfsim.components.estimators import DiffusionParams, EstimatorParams
from dkfsim.estimators.rounds import RoundBased, solve_pair


class DiffusionKF(RoundBased, params=DiffusionParams):
    """Cattivelli & Sayed's diffusion KF at every node, batched over nodes."""

    #: Its packets and their nominal sizes (bytes; docs/estimators.md, "Packet sizes").
    packets = ("two per out-link and tick: 16-byte header + 8 (nx + nx(nx+1)/2) (measurement information), then 16-byte header + 8 nx (psi)")

    params: DiffusionParams

    @classmethod
    @override
    def slots_of(cls, params: EstimatorParams) -> int:
        return 2

    def start(self) -> None:
        self.start_rounds(self.ctx.topology_links(), 2)

    def setup(self) -> None:
        super().setup()
        if self.params.weights == "uniform":
            self.S = self.weight_matrix(np.ones(self.E, dtype=bool))

    def arc_weights(self, on: np.ndarray) -> np.ndarray:
        """``uniform``: ``c_ij = 1 / (|N_i| + 1)`` over the arcs ``on``; else Metropolis."""
        if self.params.weights != "uniform":
            return super().arc_weights(on)
        indeg = np.bincount(self.dst[on], minlength=self.n)
        return np.where(on, 1.0 / (1.0 + indeg[self.dst]), 0.0)

    def boxes(self) -> dict[str, dict[str, tuple[int, ...]]]:
        nx = self.nx
        return {"meas": {"u": (nx,), "U": (nx, nx)}, "psi": {"psi": (nx,)}}

    def deadline(self, g: int) -> int:
        return self.T_ns + (g + 1) * self.dt          # the next sub-slot

    def begin_tick(self, k: int) -> None:
        self.xbar, self.Pbar = self.predict()
        self.msg = {"u": self.theta[k - 1], "U": self.omega_at(k)}

    @override
    def step(self, k: int, l: int) -> None:
        g0 = (k - 1) * 2
        box = self.box["meas"]
        have = self.fresh("meas", g0, g0)
        Ombar, qbar = solve_pair(self.Pbar, self.xbar)
        self.P, self.psi = solve_pair(Ombar + self.msg["U"] + self.nsum(box.f["U"], have),
                                      qbar + self.msg["u"] + self.nsum(box.f["u"], have))

    def message(self, g: int) -> tuple[str, dict[str, Any], int]:
        if g % 2 == 0:
            return "meas", self.msg, self.info_bytes(1, 1)
        return "psi", {"psi": self.psi}, self.info_bytes(1, 0)

    def end_tick(self, k: int) -> None:
        if self.params.diffusion:
            g1 = (k - 1) * 2 + 1
            self.x = self.mix(self.psi, self.box["psi"].f["psi"], self.fresh("psi", g1, g1))
        else:
            self.x = self.psi
        self.record(k, self.x, self.P)

    def facts(self) -> dict:
        return {**super().facts(), "weights": self.params.weights, "diffusion": bool(self.params.diffusion)}

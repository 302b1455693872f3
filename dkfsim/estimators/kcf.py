"""The ``kcf`` estimator: the Kalman-consensus filter of Olfati-Saber.

R. Olfati-Saber, "Kalman-Consensus Filter: Optimality, Stability, and
Performance", Proc. 48th IEEE CDC (2009), Algorithm 1.  Each node ``i`` keeps a
prior ``(xbar_i, Pbar_i)``; per tick ``k`` it sends its measurement
information ``u_i = H_i' R_i^-1 y_i``, ``U_i = H_i' R_i^-1 H_i`` and its prior
``xbar_i`` to its neighbours (one message per link per tick), then

    y_i = sum_{j in J_i} u_j,   S_i = sum_{j in J_i} U_j      (J_i = N_i and i)
    M_i = (Pbar_i^-1 + S_i)^-1
    xhat_i = xbar_i + M_i (y_i - S_i xbar_i) + gamma_i M_i sum_{j in N_i} (xbar_j - xbar_i)
    gamma_i = eps / (1 + ||M_i||_F)
    Pbar_i <- Phi M_i Phi' + Q,  xbar_i <- Phi xhat_i.

The reported covariance is ``M_i`` (the paper's; it ignores the consensus
term).  ``eps = 0`` makes each node the Kalman filter of its neighbourhood's
measurements.  Timing (docs/consensus.md): one sub-slot per tick; the message
of tick ``k`` is sent at ``t_k`` and used at ``t_{k+1}``; a neighbour whose
message of tick ``k`` has not arrived by then is left out of both sums, and
the message is dropped and counted late when it comes.  Runs on the
scenario's full topology (:mod:`dkfsim.estimators.rounds`).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from typing_extensions import override

from dkfsim.components.estimators import EstimatorParams, KCFParams
from dkfsim.estimators.rounds import RoundBased, solve_pair


class KCF(RoundBased, params=KCFParams):
    """Olfati-Saber's Kalman-consensus filter at every node, batched over nodes."""

    #: Its packets and their nominal sizes (bytes; docs/estimators.md, "Packet sizes").
    packets = ("one per out-link and tick: 16-byte header + 8 (2 nx + nx(nx+1)/2) (u, xbar, U)")

    params: KCFParams

    WORK = 3

    @classmethod
    @override
    def slots_of(cls, params: EstimatorParams) -> int:
        return 1

    def start(self) -> None:
        self.start_rounds(self.ctx.topology_links(), 1)

    def boxes(self) -> dict[str, dict[str, tuple[int, ...]]]:
        nx = self.nx
        return {"m": {"u": (nx,), "U": (nx, nx), "xbar": (nx,)}}

    def begin_tick(self, k: int) -> None:
        self.xbar, self.Pbar = self.predict()
        self.msg = {"u": self.theta[k - 1], "U": self.omega_at(k), "xbar": self.xbar}

    @override
    def message(self, g: int) -> tuple[str, dict[str, Any], int]:
        return "m", self.msg, self.info_bytes(2, 1)

    def end_tick(self, k: int) -> None:
        box = self.box["m"]
        have = self.fresh("m", k - 1, k - 1)
        y = self.msg["u"] + self.nsum(box.f["u"], have)
        S = self.msg["U"] + self.nsum(box.f["U"], have)
        Ombar, qbar = solve_pair(self.Pbar, self.xbar)
        M, x_nf = solve_pair(Ombar + S, qbar + y)
        eps = float(self.params.eps)
        if eps > 0:
            # sum_j (xbar_j - xbar_i) over the neighbours heard from
            cnt = self.A @ have.astype(float)
            diff = self.nsum(box.f["xbar"], have) - cnt[:, None] * self.xbar
            gamma = eps / (1.0 + np.sqrt(np.einsum("nij,nij->n", M, M)))
            x_nf = x_nf + gamma[:, None] * np.einsum("nij,nj->ni", M, diff)
        self.x, self.P = x_nf, M
        self.record(k, self.x, self.P)

    def facts(self) -> dict:
        return {**super().facts(), "eps": float(self.params.eps)}

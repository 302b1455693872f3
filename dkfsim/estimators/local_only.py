"""``local_only``: every node filters its own measurements only (no communication).

Reported per node, ``(K, n, nx)``; metrics average over the nodes.  Its
traffic is zero.  (The scenario key of earlier versions was ``local``,
still accepted in a ``baselines:`` list.)
"""

from __future__ import annotations

from typing_extensions import override

from dkfsim.components.estimators import LocalOnlyParams
from dkfsim.core.resources import B_FLOAT, C_NODE_ROW, C_ROW, Cost
from dkfsim.estimators.base import Estimate, Estimator, existing_information_bytes
from dkfsim.estimators.window import batched_filter


class LocalOnly(Estimator, params=LocalOnlyParams):
    """Each node's Kalman filter of its own measurements, batched over nodes."""

    #: Its packets and their nominal sizes (bytes; docs/estimators.md, "Packet sizes").
    packets = ("none (no communication)")

    @classmethod
    @override
    def cost(cls, params, plan) -> Cost:
        scenario = plan.scenario
        K, n, nx = int(scenario.steps), scenario.n, scenario.nx
        return Cost(params.label, memory={"local_only": K * n * (nx + nx * nx) * B_FLOAT
                                          + existing_information_bytes(scenario)},
                    seconds=K * (C_ROW + n * C_NODE_ROW))

    def estimate(self) -> Estimate:
        s = self.ctx.system
        omega, theta = self.ctx.existing_information()
        x, P = batched_filter(s.Phi, s.Q, s.x0_mean, s.P0, omega, theta, self.ctx.backend)
        return Estimate(x, P)                 # traffic: zero (no port)

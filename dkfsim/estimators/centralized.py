"""``centralized``: the Kalman filter that holds every measurement on time (the lower bound).

It sees the run's truth and measurement noise, so its error is what the
anti-delay DKF would reach with no delay at all; measurements a crash
prevented do not exist for it either.  It has no network model: its traffic
is not applicable (``None``), not zero.
"""

from __future__ import annotations

from typing_extensions import override

from dkfsim.components.estimators import CentralizedParams
from dkfsim.core.resources import B_FLOAT, C_TICK, Cost
from dkfsim.estimators.base import Estimate, Estimator, existing_information_bytes
from dkfsim.estimators.window import centralized_filter


class Centralized(Estimator, params=CentralizedParams):
    """The centralized information filter with every measurement on time."""

    #: Its packets and their nominal sizes (bytes; docs/estimators.md, "Packet sizes").
    packets = ("none (no network model)")

    network_model = False
    @classmethod
    @override
    def cost(cls, params, plan) -> Cost:
        scenario = plan.scenario
        K, nx = int(scenario.steps), scenario.nx
        copy = existing_information_bytes(scenario)
        per_row = copy > 0 or any(s.kind != "linear" for s in scenario.sensors)     # omega per row
        sums = K * (nx + (nx * nx if per_row else 0)) * B_FLOAT                      # over the sensors
        return Cost(params.label, memory={"centralized": K * (nx + nx * nx) * B_FLOAT + sums + copy},
                    seconds=K * C_TICK)

    def estimate(self) -> Estimate:
        s = self.ctx.system
        omega, theta = self.ctx.existing_information()
        x, P = centralized_filter(s.Phi, s.Q, s.x0_mean, s.P0, omega.sum(axis=-3), theta.sum(axis=1),
                                  self.ctx.backend)
        return Estimate(x, P)

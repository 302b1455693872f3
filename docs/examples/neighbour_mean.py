"""``neighbour_mean``: each node averages its own Kalman filter with its neighbours' latest.

A deliberately small estimator for docs/extending.md: every node runs a
Kalman filter of its own measurements; at each tick it sends its estimate
to its out-neighbours (one packet per link, over the run's delayed, lossy
links); its reported estimate is the plain mean of its own and the newest
estimate received from each neighbour (none yet: left out).  It is not a
good filter -- it ignores the correlations and the ages of what it averages
-- but it shows every part of the interface: a parameter model that declares
the kind, an implementation that names it and uses the run's network and
clock, its cost and its estimate.  Use it in a scenario with::

    plugins: [path/to/neighbour_mean.py]
    estimators: [{kind: neighbour_mean}, {kind: neighbour_mean, name: nm_self, weight_self: 0.5}]
"""

from __future__ import annotations

from typing import Annotated

import numpy as np
from pydantic import Field
from typing_extensions import override

from dkfsim.components.estimators import EstimatorParams
from dkfsim.core.resources import B_FLOAT, C_PACKET, C_TICK, Cost
from dkfsim.estimators.base import Estimate, Estimator, existing_information_bytes
from dkfsim.estimators.window import batched_filter


class NeighbourMeanParams(EstimatorParams, kind="neighbour_mean"):
    """Each node averages its own Kalman filter with its neighbours' latest estimates."""

    #: Weight of the node's own estimate (None: an equal share with each neighbour heard from).
    weight_self: Annotated[float, Field(strict=True, gt=0, le=1)] | None = None


class NeighbourMean(Estimator, params=NeighbourMeanParams):
    """Own Kalman filter, then the mean with the neighbours' latest estimates."""

    #: What it sends, as ``dkfsim list`` prints it (docs/estimators.md, "Packet sizes").
    packets = "one per exchange link and tick: 16-byte header + 8 nx (its estimate)"

    @classmethod
    @override
    def cost(cls, params, plan) -> Cost:
        """Its own filter's ``x`` and ``P``, the reported ``x``, and what ``existing_information()``
        copies; one packet per exchange link and tick (the run plan's buffer length and save
        mode do not matter to it)."""
        scenario, arcs = plan.scenario, plan.n_exchange_links
        K, n, nx = int(scenario.steps), scenario.n, scenario.nx
        memory = K * n * (2 * nx + nx * nx) * B_FLOAT + existing_information_bytes(scenario)
        return Cost(params.label, memory={params.label: memory}, seconds=K * (C_TICK + arcs * C_PACKET))

    def start(self) -> None:
        ctx = self.ctx
        s = ctx.system
        omega, theta = ctx.existing_information()
        self.own, _ = batched_filter(s.Phi, s.Q, s.x0_mean, s.P0, omega, theta, ctx.backend)   # (K, n, nx)
        self.links = ctx.exchange_links()                # the links the scenario's protocol uses
        self.open_port(self._receive, self.links)
        self.latest = {}                                  # (receiver, sender) -> (tick, estimate)
        self.x = np.empty_like(self.own)

    def _receive(self, link, payload) -> None:
        tick, x = payload
        old = self.latest.get((link.dst, link.src))
        if old is None or tick > old[0]:                  # links reorder: keep the newest
            self.latest[(link.dst, link.src)] = (tick, x)

    def on_measure(self, row: int) -> None:
        for link in self.links:                           # one packet per link and tick
            self.port.send(link, (row, self.own[row, link.src]), nbytes=16 + 8 * self.ctx.nx)

    def on_update(self, k: int) -> None:
        row, w = k - 1, self.params.weight_self
        for i in range(self.ctx.n):
            heard = [x for (dst, _), (_, x) in self.latest.items() if dst == i]
            if not heard:
                self.x[row, i] = self.own[row, i]
            elif w is None:
                self.x[row, i] = np.mean([self.own[row, i], *heard], axis=0)
            else:
                self.x[row, i] = w * self.own[row, i] + (1 - w) * np.mean(heard, axis=0)

    def estimate(self) -> Estimate:
        return Estimate(self.x)            # the port's counts are its traffic; nothing is ever late

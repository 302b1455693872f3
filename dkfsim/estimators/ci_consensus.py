"""The ``ci_consensus`` estimator: consensus on information over the same delayed links.

The distributed Kalman filter of Battistelli & Chisci (Automatica 2014,
"Kullback-Leibler average, consensus on probability densities, and
distributed state estimation with guaranteed stability"), the family of the
reference the paper compares against, run on the same truth, measurements,
graph and link latency/loss draws as the anti-delay DKF.

Each node ``i`` keeps an information pair ``(Omega_i, q_i) = (P_i^-1, P_i^-1 x_i)``.
Per tick ``k`` (time ``t_k``, row ``r = k-1``):

1. *prediction* (covariance form, then back to information form with one
   batched solve): ``x -> Phi x``, ``P -> Phi P Phi' + Q``;
2. *correction with its own data only*: ``Omega_i += omega_i`` (of row ``r``
   when a sensor's information varies per row), ``q_i += theta_i[r]``, unscaled;
3. ``L_c`` *consensus rounds* (the entry's key ``rounds``): the pairs are
   replaced by convex combinations ``sum_j pi_ij (Omega_j, q_j)`` with
   Metropolis weights.

The estimate of row ``r`` is the pair after the last round of tick ``k``,
reported as ``x = Omega^-1 q``, ``P = Omega^-1``.  With ``L_c = 0`` this is
each node's local Kalman filter.

Why CI and not CM / CMCI
------------------------
B&C analyse consensus on measurements (CM), on information (CI, consensus on
the whole posterior: their Kullback-Leibler average, i.e. iterated covariance
intersection) and the hybrid CMCI, which averages prior and novel
information separately and scales the novel part by the number of nodes.  We
use CI because it is the only one whose guarantees survive the delays and
losses simulated here: every combination is a convex combination of
consistent pairs (covariance intersection), so each ``P_i`` stays an upper
bound of the true error covariance whatever the correlations, whichever
neighbour pairs happen to have arrived, and with any number of rounds (even
one), and it is stable under collective observability on a strongly
connected graph.  CM and CMCI need the novel information of *all* nodes to
be averaged in the same rounds, with the network size as the scale; with
missing or stale packets that scale over-counts information and the filter
becomes overconfident, so the comparison would measure a mis-tuned filter
rather than the method.  The price of CI, which the comparison shows, is
conservatism: at consensus every measurement counts with weight ``1/n``.

Weights
-------
``pi_ij = 1 / (1 + max(d_i, d_j))`` for each arc ``j -> i`` of the exchange
graph, ``d`` the number of in-neighbours (the degree on an undirected
topology, whose arcs are both directions of every edge: the usual symmetric,
doubly stochastic Metropolis matrix); ``pi_ii = 1 - sum_j pi_ij``.  On a
digraph the same formula with in-degrees gives a row-stochastic matrix with
positive diagonal: the nodes still agree (strong connectivity) and CI stays
consistent, but the agreed value is not the plain average.  The graph is
the scenario's protocol graph: the one the DKF's protocol runs on (with
``spanning_tree: true`` that is the spanning tree).

Timing with delays (integer nanoseconds, as :mod:`dkfsim.network.links`)
-------------------------------------------------------------------
``T / L_c`` must be a whole number of nanoseconds (``dt``).  Round ``l`` of
tick ``k`` (``l = 0..L_c-1``) is the instant ``t_k + l dt``:

* at ``t_k`` (``l = 0``) node ``i`` predicts and corrects, then sends its pair;
* at ``t_k + l dt`` (``l >= 1``) it first averages (consensus step ``l``), then
  sends the new pair;
* at ``t_{k+1}`` it first performs the last averaging of tick ``k`` -- the
  result is the estimate of row ``k-1`` -- and then starts tick ``k+1``.
  The last row is finished at ``t_{K+1}``; packets still in flight then are
  counted as ``in_flight``.

Each send puts one packet per out-link ``i -> j`` through this estimator's
own port on the run's one :class:`~dkfsim.network.links.Network`, which the
DKF uses too: a packet's latency and loss are keyed by (link, send instant,
seq), so a consensus packet sent on a link at the instant a DKF packet is
sent there sees the same delay (common random numbers, docs/design.md §3).
A packet is stamped with its round (tick and ``l``); a receiver keeps, per
in-link, the packet with the newest stamp (links reorder).  An averaging at
an instant uses every packet delivered at or before it (deliveries have
priority over the averaging at the same instant, as in the DKF), but not
the packets sent at that instant -- even with zero latency they are used at
the next round, which makes zero latency the textbook synchronous consensus.
A neighbour's latest pair is used again if nothing newer arrived; if it is
from an older tick ``s < k`` it is first predicted forward ``k - s`` steps
(``P -> Phi^m P Phi^m' + sum_{i<m} Phi^i Q Phi^i'``); a neighbour from which
nothing has arrived yet is left out and its weight goes to ``pi_ii``.
With ``L_c = 0`` nothing is sent.

Numerics: no explicit inverse; ``(P, x)`` from ``(Omega, q)`` and back are one
batched linear solve each with right-hand side ``[I | v]``; matrices are
symmetrised after each solve.  The averaging is a fixed sparse
(nodes x arcs) matrix product, so a run is bit-for-bit repeatable.

Crash windows (``faults.crashes``): a crashed node does not measure (no
correction for those rows), sends nothing, drops what arrives, and keeps its
own pair through the averaging; it still predicts, as the DKF's nodes do.

The rounds, links, packets and weights are the shared machinery of
:mod:`dkfsim.estimators.rounds` (docs/consensus.md); unlike the other
round-based estimators, ``ci_consensus`` keeps a pair from an older tick and
predicts it forward (posteriors can be; partial sums cannot), so it drops
nothing as late.

Side facts (underscored keys, :func:`ci_consensus`): packets ``sent``,
``delivered``, ``lost``, ``in_flight``, the number of rounds, and how many
neighbour pairs were used (``used``) and how many of them had to be predicted
from an older tick (``stale``).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from typing_extensions import override

from dkfsim.components.estimators import CIParams, EstimatorParams
from dkfsim.config.plan import RunPlan
from dkfsim.core.resources import B_FLOAT, C_NODE_ROW, C_PACKET, C_ROW, C_TICK, Cost
from dkfsim.estimators.base import existing_information_bytes
from dkfsim.estimators.rounds import Powers as _Powers
from dkfsim.estimators.rounds import RoundBased, metropolis_weights
from dkfsim.estimators.rounds import solve_pair as _solve_pair
from dkfsim.estimators.window import predict
from dkfsim.protocols.base import info_bytes

__all__ = ["CIConsensus", "metropolis_weights"]


class CIConsensus(RoundBased, params=CIParams):
    """Every node's CI filter and its exchange, on the run's network.

    The filter steps are batched over nodes; rounds are events at
    ``t_k + l T / rounds`` on the run's clock; packets go through the
    estimator's own port over the exchange graph's links.
    """

    #: Its packets and their nominal sizes (bytes; docs/estimators.md, "Packet sizes").
    packets = ("one per out-link and round: 16-byte header + 8 (nx + nx(nx+1)/2) (q, Omega)")

    params: CIParams
    DROP_LATE = False           # older pairs are predicted forward, never dropped

    @classmethod
    @override
    def cost(cls, params: EstimatorParams, plan: RunPlan) -> Cost:
        assert isinstance(params, CIParams)
        scenario, arcs = plan.scenario, plan.n_exchange_links
        K, n, nx = int(scenario.steps), scenario.n, scenario.nx
        return Cost(params.label,
                    memory={"ci_consensus": K * n * (nx + nx * nx) * B_FLOAT + arcs * (nx + nx * nx) * 2 * B_FLOAT
                            + existing_information_bytes(scenario)},
                    seconds=K * (C_ROW + n * C_NODE_ROW) + K * params.rounds * (
                        C_TICK + 3 * C_ROW + arcs * C_PACKET + n * 2 * C_NODE_ROW))

    def start(self) -> None:
        self.rounds = int(self.params.rounds)
        self.start_rounds(self.ctx.exchange_links() if self.rounds > 0 else [], self.rounds)

    def setup(self) -> None:
        s = self.ctx.system
        n, nx = self.n, self.nx
        self.x = np.broadcast_to(np.asarray(s.x0_mean, float), (n, nx)).copy()
        self.P = np.broadcast_to(np.asarray(s.P0, float), (n, nx, nx)).copy()
        #: the information pair (set by each tick's prediction, before anything reads it)
        self.Om, self.q = np.zeros((n, nx, nx)), np.zeros((n, nx))
        self.used = self.stale = 0
        self.powers = _Powers(self.Phi, self.Q)
        self.nbytes = info_bytes(nx)

    def boxes(self) -> dict[str, dict[str, tuple[int, ...]]]:
        nx = self.nx
        return {"pair": {"Om": (nx, nx), "q": (nx,), "x": (nx,), "P": (nx, nx)}}

    # -- the filter steps (batched over nodes) -----------------------------
    def _predict_correct(self, k: int) -> None:
        xp, Pp = predict(self.Phi, self.Q, self.x, self.P)
        Omp, qp = _solve_pair(Pp, xp)
        self._set_pair(Omp + self.omega_at(k), qp + self.theta[k - 1])

    def _set_pair(self, Om: np.ndarray, q: np.ndarray) -> None:
        # New arrays every time: packets in flight hold references to the old ones.
        self.Om = 0.5 * (Om + np.swapaxes(Om, -1, -2))
        self.q = q
        self.P, self.x = _solve_pair(self.Om, self.q)

    def _average(self, k: int) -> None:
        """One consensus step at tick ``k`` with the newest pair held from each in-link."""
        box = self.box["pair"]
        have = self.current(box.stamp >= 0)
        Om_nb, q_nb = box.f["Om"], box.f["q"]
        age = k - (box.stamp // self.rounds + 1)
        old = np.flatnonzero(have & (age > 0))
        if old.size:
            F, Qm = self.powers.get(age[old])
            Pm = F @ box.f["P"][old] @ np.swapaxes(F, -1, -2) + Qm
            xm = np.einsum("aij,aj->ai", F, box.f["x"][old])
            Om_old, q_old = _solve_pair(Pm, xm)
            Om_nb, q_nb = Om_nb.copy(), q_nb.copy()
            Om_nb[old], q_nb[old] = Om_old, q_old
        self.used += int(have.sum())
        self.stale += int(old.size)
        self.port.count_late(old.size)        # its ``late``: neighbour pairs used a tick late or more
        n, nx = self.n, self.nx
        # Arcs with nothing received hold zeros; their weight goes to pi_ii.
        self_w = 1.0 - self.S @ have.astype(float)
        Om = self_w[:, None, None] * self.Om + (self.S @ Om_nb.reshape(-1, nx * nx)).reshape(n, nx, nx)
        q = self_w[:, None] * self.q + self.S @ q_nb
        down = self._down()
        if down.size:                 # a crashed node does not take part: it keeps its pair
            Om[down], q[down] = self.Om[down], self.q[down]
        self._set_pair(Om, q)

    # -- the round hooks -------------------------------------------------------
    def local_tick(self, k: int) -> None:
        self._predict_correct(k)
        self.record(k, self.x, self.P)

    def begin_tick(self, k: int) -> None:
        self._predict_correct(k)

    @override
    def step(self, k: int, l: int) -> None:
        self._average(k)

    def end_tick(self, k: int) -> None:
        self._average(k)
        self.record(k, self.x, self.P)

    @override
    def message(self, g: int) -> tuple[str, dict[str, Any], int]:
        return "pair", {"Om": self.Om, "q": self.q, "x": self.x, "P": self.P}, self.nbytes

    # -- the result -------------------------------------------------------------
    def facts(self) -> dict:
        return {"rounds": self.rounds, "used": self.used, "stale": self.stale}

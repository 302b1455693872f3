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

Side facts (underscored keys, :func:`ci_consensus`): packets ``sent``,
``delivered``, ``lost``, ``in_flight``, the number of rounds, and how many
neighbour pairs were used (``used``) and how many of them had to be predicted
from an older tick (``stale``).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse

from dkfsim.core.linalg import solve
from dkfsim.core.registry import ESTIMATORS
from dkfsim.core.resources import B_FLOAT, C_NODE_ROW, C_PACKET, C_ROW, C_TICK, Cost
from dkfsim.components.estimators import CIParams
from dkfsim.estimators.base import Estimate, Estimator, EstimatorResult
from dkfsim.network.links import PRIORITY_UPDATE, Scheduled


# --------------------------------------------------------------------------- helpers
def metropolis_weights(n: int, arcs) -> np.ndarray:
    """``pi`` of each arc ``(u, v)`` (u sends to v): ``1 / (1 + max(d_u, d_v))``.

    ``d`` counts in-neighbours.  ``pi_vv = 1 - sum`` over v's in-arcs.
    """
    arcs = np.asarray(arcs, dtype=np.intp).reshape(-1, 2)
    indeg = np.bincount(arcs[:, 1], minlength=n)
    return 1.0 / (1.0 + np.maximum(indeg[arcs[:, 0]], indeg[arcs[:, 1]]))


def _solve_pair(A: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(A^-1, A^-1 v)`` for a batch of SPD ``A`` by one solve, ``A^-1`` symmetrised."""
    nx = A.shape[-1]
    rhs = np.empty(A.shape[:-1] + (nx + 1,))
    rhs[..., :nx] = np.eye(nx)
    rhs[..., nx] = v
    sol = solve(A, rhs)
    M = sol[..., :nx]
    return 0.5 * (M + np.swapaxes(M, -1, -2)), sol[..., nx]


class _Powers:
    """``Phi^m`` and ``Q_m = sum_{i<m} Phi^i Q Phi^i'`` for m = 0, 1, ..., grown on demand."""

    def __init__(self, Phi, Q):
        self.Phi, self.Q = Phi, Q
        nx = Phi.shape[0]
        self.F = [np.eye(nx)]
        self.Qm = [np.zeros((nx, nx))]
        self._F = self._Q = None

    def get(self, m: np.ndarray):
        top = int(m.max())
        if top >= len(self.F) or self._F is None:
            while len(self.F) <= top:
                self.F.append(self.Phi @ self.F[-1])
                Qn = self.Phi @ self.Qm[-1] @ self.Phi.T + self.Q
                self.Qm.append(0.5 * (Qn + Qn.T))
            self._F, self._Q = np.array(self.F), np.array(self.Qm)
        return self._F[m], self._Q[m]


class CIConsensus(Estimator):
    """Every node's CI filter and its exchange, on the run's network.

    The filter steps are batched over nodes; rounds are events at
    ``t_k + l T / rounds`` on the run's clock; packets go through the
    estimator's own port over the exchange graph's links.
    """

    Params = CIParams

    @classmethod
    def cost(cls, params, scenario, *, L: int, arcs: int, save: str = "estimates") -> Cost:
        K, n, nx = int(scenario.steps), scenario.n, scenario.nx
        return Cost(params.label,
                    memory={"ci_consensus": K * n * (nx + nx * nx) * B_FLOAT + arcs * (nx + nx * nx) * 2 * B_FLOAT},
                    seconds=K * (C_ROW + n * C_NODE_ROW) + K * params.rounds * (
                        C_TICK + 3 * C_ROW + arcs * C_PACKET + n * 2 * C_NODE_ROW))

    def start(self) -> None:
        ctx = self.ctx
        s = ctx.system
        self.Phi, self.Q = np.asarray(s.Phi, float), np.asarray(s.Q, float)
        omega, theta = ctx.existing_information()          # crashed sensors measure nothing
        self.omega, self.theta = np.asarray(omega, float), np.asarray(theta, float)
        self.K, self.n, self.nx = self.theta.shape
        self._omega_per_row = self.omega.ndim == 4
        self.rounds = Lc = int(self.params.rounds)
        self.T_ns = ctx.T_ns
        self.dt = self.T_ns // Lc if Lc > 0 else self.T_ns
        n, nx = self.n, self.nx
        self.x = np.broadcast_to(np.asarray(s.x0_mean, float), (n, nx)).copy()
        self.P = np.broadcast_to(np.asarray(s.P0, float), (n, nx, nx)).copy()
        self.Om = self.q = None
        self.crashes = ctx.crashes
        self.env = ctx.env
        self.used = self.stale = 0
        arcs = ctx.scenario.exchange().arcs if Lc > 0 else []
        self.links = [ctx.network.link(u, v) for u, v in arcs]
        self.lid = {link.id: a for a, link in enumerate(self.links)}
        E = len(self.links)
        self.src = np.array([u for u, _ in arcs], dtype=np.intp)
        self.dst = np.array([v for _, v in arcs], dtype=np.intp)
        pi = metropolis_weights(n, arcs) if E else np.zeros(0)
        # S[v, a] = pi_a for arc a = (u -> v): the neighbour part of the averaging.
        self.S = scipy.sparse.csr_matrix((pi, (self.dst, np.arange(E))), shape=(n, E))
        # Newest pair received on each arc: stamp = global round index (-1: none).
        self.arc_stamp = np.full(E, -1, dtype=np.int64)
        self.arc_Om = np.zeros((E, nx, nx))
        self.arc_q = np.zeros((E, nx))
        self.arc_x = np.zeros((E, nx))
        self.arc_P = np.zeros((E, nx, nx))
        self.powers = _Powers(self.Phi, self.Q)
        self.x_out = np.empty((self.K, n, nx))
        self.P_out = np.empty((self.K, n, nx, nx))
        # The last averaging of tick K happens at t_{K+1}: deliveries count until then.
        self.port = ctx.network.port(self.name, self._receive, self.links, until=(self.K + 1) * self.T_ns)
        self.nbytes = 16 + 8 * (nx + nx * (nx + 1) // 2)
        if Lc == 0:
            for k in range(1, self.K + 1):
                self._predict_correct(k)
                self._record(k)
        else:
            self._g = 0
            Scheduled(self.env, self._instant, PRIORITY_UPDATE, self.T_ns)

    # -- the filter steps (batched over nodes) -----------------------------
    def _predict_correct(self, k: int) -> None:
        xp = self.x @ self.Phi.T
        Pp = self.Phi @ self.P @ self.Phi.T + self.Q
        Omp, qp = _solve_pair(Pp, xp)
        omega = self.omega[k - 1] if self._omega_per_row else self.omega
        self._set_pair(Omp + omega, qp + self.theta[k - 1])

    def _set_pair(self, Om, q) -> None:
        # New arrays every time: packets in flight hold references to the old ones.
        self.Om = 0.5 * (Om + np.swapaxes(Om, -1, -2))
        self.q = q
        self.P, self.x = _solve_pair(self.Om, self.q)

    def _average(self, k: int) -> None:
        """One consensus step at tick ``k`` with the newest pair held from each in-link."""
        have = self.arc_stamp >= 0
        Om_nb, q_nb = self.arc_Om, self.arc_q
        age = k - (self.arc_stamp // self.rounds + 1)
        old = np.flatnonzero(have & (age > 0))
        if old.size:
            F, Qm = self.powers.get(age[old])
            Pm = F @ self.arc_P[old] @ np.swapaxes(F, -1, -2) + Qm
            xm = np.einsum("aij,aj->ai", F, self.arc_x[old])
            Om_old, q_old = _solve_pair(Pm, xm)
            Om_nb, q_nb = Om_nb.copy(), q_nb.copy()
            Om_nb[old], q_nb[old] = Om_old, q_old
        self.used += int(have.sum())
        self.stale += int(old.size)
        n, nx = self.n, self.nx
        # Arcs with nothing received hold zeros; their weight goes to pi_ii.
        self_w = 1.0 - self.S @ have.astype(float)
        Om = self_w[:, None, None] * self.Om + (self.S @ Om_nb.reshape(-1, nx * nx)).reshape(n, nx, nx)
        q = self_w[:, None] * self.q + self.S @ q_nb
        down = self._down()
        if down.size:                 # a crashed node does not take part: it keeps its pair
            Om[down], q[down] = self.Om[down], self.q[down]
        self._set_pair(Om, q)

    def _down(self) -> np.ndarray:
        """Nodes inside a crash window now."""
        if not self.crashes or self.rounds == 0:
            return np.zeros(0, dtype=np.intp)
        now = self.env.now
        return np.array([i for i in range(self.n) if self.crashes.down(i, now)], dtype=np.intp)

    def _record(self, k: int) -> None:
        self.x_out[k - 1] = self.x
        self.P_out[k - 1] = self.P

    # -- the network ---------------------------------------------------------
    def _send(self, stamp: int) -> None:
        state = (stamp, self.Om, self.q, self.x, self.P)
        send = self.port.send
        down = set(self._down().tolist())
        for link in self.links:
            if link.src not in down:          # a crashed node sends nothing
                send(link, state, self.nbytes)

    def _receive(self, link, payload) -> None:
        stamp, Om, q, x, P = payload
        a, u = self.lid[link.id], link.src
        if stamp > self.arc_stamp[a]:
            self.arc_stamp[a] = stamp
            self.arc_Om[a] = Om[u]
            self.arc_q[a] = q[u]
            self.arc_x[a] = x[u]
            self.arc_P[a] = P[u]

    def _instant(self, _event) -> None:
        g = self._g                  # global round index: tick g // Lc + 1, round g % Lc
        self._g += 1
        Lc = self.rounds
        k, l = g // Lc + 1, g % Lc
        if l == 0:
            if k > 1:
                self._average(k - 1)
                self._record(k - 1)
            if k > self.K:
                return
            self._predict_correct(k)
        else:
            self._average(k)
        self._send(g)
        Scheduled(self.env, self._instant, PRIORITY_UPDATE, self.dt)

    # -- the result -------------------------------------------------------------
    def finish(self) -> EstimatorResult:
        traffic = self.port.counts()
        traffic["late"] = self.stale        # neighbour pairs used after arriving a tick late
        facts = {"rounds": self.rounds, "used": self.used, "stale": self.stale}
        return EstimatorResult({self.name: Estimate(self.x_out, self.P_out)}, traffic=traffic,
                               facts=facts)


ESTIMATORS.add("ci_consensus", implementation=CIConsensus)

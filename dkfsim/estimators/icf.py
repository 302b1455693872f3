"""The ``icf`` estimator: the information-weighted consensus filter of Kamal et al.

A. T. Kamal, J. A. Farrell, A. K. Roy-Chowdhury, "Information Weighted
Consensus Filters and Their Application in Distributed Camera Networks",
IEEE TAC 58(12), 2013, Algorithm 1.  Each node ``i`` with prior
``(xbar_i, Jbar_i = Pbar_i^-1)`` starts the consensus of tick ``k`` from

    V_i^0 = Jbar_i / N + U_i,     v_i^0 = Jbar_i xbar_i / N + u_i

(``U_i = H_i' R_i^-1 H_i``, ``u_i = H_i' R_i^-1 y_i``: the prior weighted by
1/N), runs ``rounds`` consensus iterations ``V_i <- sum_j pi_ij V_j`` (and
``v`` alike), and ends with ``xhat_i = V_i^-1 v_i``, ``J_i = N V_i``, then
predicts.  The paper's iteration ``v_i + eps sum_j (v_j - v_i)`` is one doubly
stochastic consensus matrix; we use the Metropolis one (no step size to tune,
the same weights as ``ci_consensus``).  On a complete graph with weights 1/N
one round is the exact average, i.e. the centralized filter.

Timing (docs/consensus.md): iteration ``l`` runs at sub-slot ``l`` of ``T``
and the last one at ``t_{k+1}``; a neighbour without a message of the
current tick is left out and its weight goes to the node itself; messages
of a finished tick are dropped and counted late.  Runs on the scenario's
full topology (:mod:`dkfsim.estimators.rounds`).
"""

from __future__ import annotations

from typing import Any

from typing_extensions import override

from dkfsim.components.estimators import ICFParams
from dkfsim.estimators.rounds import RoundBased, solve_pair, sym


class ICF(RoundBased, params=ICFParams):
    """Kamal et al.'s ICF at every node, batched over nodes."""

    #: Its packets and their nominal sizes (bytes; docs/estimators.md, "Packet sizes").
    packets = ("one per out-link and round: 16-byte header + 8 (nx + nx(nx+1)/2) (v, V)")

    params: ICFParams

    def start(self) -> None:
        self.start_rounds(self.ctx.topology_links(), int(self.params.rounds))

    def boxes(self) -> dict[str, dict[str, tuple[int, ...]]]:
        nx = self.nx
        return {"iv": {"V": (nx, nx), "v": (nx,)}}

    def begin_tick(self, k: int) -> None:
        xbar, Pbar = self.predict()
        Jbar, jbar = solve_pair(Pbar, xbar)
        self.V = Jbar / self.n + self.omega_at(k)
        self.v = jbar / self.n + self.theta[k - 1]

    def _iterate(self, k: int) -> None:
        box = self.box["iv"]
        have = self.fresh("iv", (k - 1) * self.slots)
        self.V = sym(self.mix(self.V, box.f["V"], have))
        self.v = self.mix(self.v, box.f["v"], have)

    @override
    def step(self, k: int, l: int) -> None:
        self._iterate(k)

    @override
    def message(self, g: int) -> tuple[str, dict[str, Any], int]:
        return "iv", {"V": self.V, "v": self.v}, self.info_bytes(1, 1)

    def end_tick(self, k: int) -> None:
        self._iterate(k)
        Pv, self.x = solve_pair(self.V, self.v)      # xhat = V^-1 v
        self.P = Pv / self.n                         # (N V)^-1
        self.record(k, self.x, self.P)

    def facts(self) -> dict:
        return {**super().facts(), "rounds": self.slots}

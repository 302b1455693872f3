"""The ``hcmci`` estimator: hybrid consensus on measurements and information.

G. Battistelli, L. Chisci, G. Mugnai, A. Farina, A. Graziano, "Consensus-Based
Linear and Nonlinear Filtering", IEEE TAC 60(5), 2015, Table I (HCMCI).  Each
node ``i`` keeps an information pair ``(Omega_i, q_i)``.  Per tick ``k``:

1. prediction in information form (``P -> Phi P Phi' + Q``);
2. its novel information ``(dOmega_i, dq_i) = (H_i' R_i^-1 H_i, H_i' R_i^-1 y_i)``;
3. ``rounds`` consensus steps on *both* pairs at once (consensus on
   information, CI, for the prior; on measurements, CM, for the novel part):
   ``X_i <- sum_j pi_ij X_j`` with Metropolis weights;
4. correction ``Omega_i = Omega_i + omega dOmega_i``, ``q_i = q_i + omega dq_i``.

``omega`` rescales the averaged novel information: with ``omega = 1`` a
measurement counts at most once in any node's information whatever arrived,
so the filter stays consistent under delays and loss and is stable under
collective observability (the paper's Theorem 1 holds for any ``omega`` in
``[1, n]``); ``omega = n`` recovers the centralized filter at full consensus
but over-counts before it.

Timing (docs/consensus.md): round ``l`` at sub-slot ``l`` of ``T``, the last at
``t_{k+1}``; a neighbour without a message of the current tick is left out
(its weight goes to the node itself); messages of a finished tick are
dropped and counted late.  Runs on the scenario's full topology.
"""

from __future__ import annotations

from typing import Any

from typing_extensions import override

from dkfsim.components.estimators import HCMCIParams
from dkfsim.estimators.rounds import RoundBased, solve_pair, sym


class HCMCI(RoundBased, params=HCMCIParams):
    """Battistelli et al.'s HCMCI at every node, batched over nodes."""

    #: Its packets and their nominal sizes (bytes; docs/estimators.md, "Packet sizes").
    packets = ("one per out-link and round: 16-byte header + 8 (2 nx + 2 nx(nx+1)/2) (q, dq, Omega, dOmega)")

    params: HCMCIParams

    WORK = 4

    def start(self) -> None:
        self.start_rounds(self.ctx.topology_links(), int(self.params.rounds))
        w = self.params.omega
        self.w = float(self.n if w == "n" else w)

    def boxes(self) -> dict[str, dict[str, tuple[int, ...]]]:
        nx = self.nx
        return {"h": {"Om": (nx, nx), "q": (nx,), "dOm": (nx, nx), "dq": (nx,)}}

    def begin_tick(self, k: int) -> None:
        xbar, Pbar = self.predict()
        Om, q = solve_pair(Pbar, xbar)
        self.s = {"Om": Om, "q": q, "dOm": self.omega_at(k), "dq": self.theta[k - 1]}

    def _average(self, k: int) -> None:
        box = self.box["h"]
        have = self.fresh("h", (k - 1) * self.slots)
        self.s = {key: self.mix(own, box.f[key], have) for key, own in self.s.items()}
        self.s["Om"], self.s["dOm"] = sym(self.s["Om"]), sym(self.s["dOm"])

    @override
    def step(self, k: int, l: int) -> None:
        self._average(k)

    @override
    def message(self, g: int) -> tuple[str, dict[str, Any], int]:
        return "h", self.s, self.info_bytes(2, 2)

    def end_tick(self, k: int) -> None:
        self._average(k)
        s = self.s
        self.P, self.x = solve_pair(s["Om"] + self.w * s["dOm"], s["q"] + self.w * s["dq"])
        self.record(k, self.x, self.P)

    def facts(self) -> dict:
        return {**super().facts(), "rounds": self.slots, "omega": self.w}

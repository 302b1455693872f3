"""Round-based exchange shared by the consensus-type estimators (docs/consensus.md).

``ci_consensus``, ``kcf``, ``icf``, ``diffusion_kf`` and ``hcmci`` all split a
tick into ``slots`` sub-slots of ``dt = T / slots`` (whole nanoseconds) and,
at every sub-slot instant, do one step of their algorithm and send one
packet per out-link through their own port of the run's network.  This
module holds what they share:

* the clock: global round ``g`` at ``t_1 + g dt`` is tick ``k = g // slots + 1``,
  sub-slot ``l = g % slots``; at ``l = 0`` the previous tick is finished
  (:meth:`RoundBased.end_tick`, which records row ``k - 2``) and the new one
  begun (:meth:`RoundBased.begin_tick`), otherwise :meth:`RoundBased.step`
  runs; then the node's message goes out (:meth:`RoundBased.message`).
  The last tick is finished at ``t_{K+1}``;
* the links (one packet per arc, a crashed sender sends nothing; on a shared channel one
  broadcast frame per node carries them), the
  receive side (per arc and per *box* -- a kind of message -- the newest
  stamp is kept; a message whose last usable instant has passed is dropped
  and counted ``late``; an older stamp than the one held is ``superseded``);
* Metropolis weights and the masked convex combination that leaves out a
  neighbour without a fresh message and gives its weight to the node itself;
* on a graph that changes (``mobility:``), the current neighbours: the computations of
  tick ``k`` (its sub-slots, and its end at ``t_{k+1}``) use the arcs up at tick ``k``
  only (a message counts as fresh only on such an arc; nothing is sent on a down arc), and
  the weights of that graph's degrees, so a node without a neighbour filters alone and
  mixes again when its links return (docs/consensus.md);
* the information-form helpers (one batched solve, no explicit inverse).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np
from typing_extensions import override

from dkfsim.core.linalg import solve
from dkfsim.core.resources import B_FLOAT, C_NODE_ROW, C_PACKET, C_ROW, C_TICK, Cost
from dkfsim.estimators.base import Estimate, Estimator, existing_information_bytes
from dkfsim.estimators.window import predict
from dkfsim.network.events import PRIORITY_UPDATE, Scheduled
from dkfsim.network.links import Link
from dkfsim.network.port import Port
from dkfsim.protocols.base import info_bytes

if TYPE_CHECKING:
    import scipy.sparse

    from dkfsim.components.estimators import EstimatorParams
    from dkfsim.config.plan import RunPlan


# --------------------------------------------------------------------------- helpers
def metropolis_weights(n: int, arcs: Any) -> np.ndarray:
    """``pi`` of each arc ``(u, v)`` (u sends to v): ``1 / (1 + max(d_u, d_v))``.

    ``d`` counts in-neighbours.  ``pi_vv = 1 - sum`` over v's in-arcs.
    """
    arcs = np.asarray(arcs, dtype=np.intp).reshape(-1, 2)
    indeg = np.bincount(arcs[:, 1], minlength=n)
    return 1.0 / (1.0 + np.maximum(indeg[arcs[:, 0]], indeg[arcs[:, 1]]))


def solve_pair(A: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(A^-1, A^-1 v)`` for a batch of SPD ``A`` by one solve, ``A^-1`` symmetrised."""
    nx = A.shape[-1]
    rhs = np.empty(A.shape[:-1] + (nx + 1,))
    rhs[..., :nx] = np.eye(nx)
    rhs[..., nx] = v
    sol = solve(A, rhs)
    M = sol[..., :nx]
    return 0.5 * (M + np.swapaxes(M, -1, -2)), sol[..., nx]


def sym(A: np.ndarray) -> np.ndarray:
    """``(A + A') / 2`` over the last two axes."""
    return 0.5 * (A + np.swapaxes(A, -1, -2))


class Powers:
    """``Phi^m`` and ``Q_m = sum_{i<m} Phi^i Q Phi^i'`` for m = 0, 1, ..., grown on demand."""

    def __init__(self, Phi: np.ndarray, Q: np.ndarray) -> None:
        self.Phi, self.Q = Phi, Q
        nx = Phi.shape[0]
        self.F = [np.eye(nx)]
        self.Qm = [np.zeros((nx, nx))]
        self._F: np.ndarray | None = None
        self._Q: np.ndarray | None = None

    def get(self, m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        top = int(m.max())
        if top >= len(self.F) or self._F is None:
            while len(self.F) <= top:
                self.F.append(self.Phi @ self.F[-1])
                Qn = self.Phi @ self.Qm[-1] @ self.Phi.T + self.Q
                self.Qm.append(0.5 * (Qn + Qn.T))
            self._F, self._Q = np.array(self.F), np.array(self.Qm)
        assert self._Q is not None
        return self._F[m], self._Q[m]


class Box:
    """The newest message of one kind received on each arc: ``stamp`` (-1: none) and fields."""

    def __init__(self, E: int, shapes: dict[str, tuple]):
        self.stamp = np.full(E, -1, dtype=np.int64)
        self.f = {key: np.zeros((E,) + tuple(shape)) for key, shape in shapes.items()}

    def store(self, a: int, u: int, fields: dict) -> None:
        for key, arr in self.f.items():
            arr[a] = fields[key][u]


# --------------------------------------------------------------------------- the base
class RoundBased(Estimator):
    """Rounds at sub-slots of ``T`` over a set of arcs, packets through the estimator's port.

    A subclass sets up its state in :meth:`setup`, declares its boxes and
    implements :meth:`begin_tick`, :meth:`step`, :meth:`end_tick` and
    :meth:`message`.  ``slots = 0`` means no exchange: :meth:`local_tick`
    runs for every tick at start.
    """

    port: Port                  # (opened by start_rounds)
    #: Drop (and count ``late``) a message once its last usable instant has passed.
    DROP_LATE = True
    #: Batched per-node matrix operations of one sub-slot (for :meth:`cost`).
    WORK = 2

    @classmethod
    def slots_of(cls, params: EstimatorParams) -> int:
        """Sub-slots per tick of an entry (default: its ``rounds``)."""
        return int(getattr(params, "rounds", 1))

    @classmethod
    @override
    def cost(cls, params: EstimatorParams, plan: RunPlan) -> Cost:
        scenario, arcs = plan.scenario, plan.n_exchange_links
        K, n, nx = int(scenario.steps), scenario.n, scenario.nx
        return Cost(params.label, memory={params.label: K * n * (nx + nx * nx) * B_FLOAT
                                          + existing_information_bytes(scenario)},
                    seconds=K * (C_ROW + n * C_NODE_ROW) + K * cls.slots_of(params) * (
                        C_TICK + 3 * C_ROW + arcs * C_PACKET + n * cls.WORK * C_NODE_ROW))

    # -- what a subclass provides ------------------------------------------------
    def setup(self) -> None:
        """Set the filter state before the first tick (default: every node's posterior
        ``x``, ``P`` is the prior; a tick starts by predicting it)."""
        s = self.ctx.system
        n, nx = self.n, self.nx
        self.x = np.broadcast_to(np.asarray(s.x0_mean, float), (n, nx)).copy()
        self.P = np.broadcast_to(np.asarray(s.P0, float), (n, nx, nx)).copy()

    def predict(self) -> tuple[np.ndarray, np.ndarray]:
        """Every node's predicted ``(x, P)`` from its posterior ``self.x``, ``self.P``, ``P``
        symmetrized."""
        xp, Pp = predict(self.Phi, self.Q, self.x, self.P)
        return xp, sym(Pp)

    def info_bytes(self, vectors: int, matrices: int) -> int:
        """Nominal size of a message of ``vectors`` nx-vectors and ``matrices`` symmetric
        nx x nx matrices: a 16-byte header (stamp, sender) and 8-byte floats."""
        return info_bytes(self.nx, vectors, matrices)

    def boxes(self) -> dict[str, dict[str, tuple[int, ...]]]:
        """Message kinds: name -> {field: shape of one node's value}."""
        return {}

    def deadline(self, g: int) -> int:
        """Last instant (ns) at which a message stamped ``g`` can be used: default the
        end of its tick, ``t_{k+1}``."""
        return (g // self.slots + 2) * self.T_ns

    def begin_tick(self, k: int) -> None:
        raise NotImplementedError

    def step(self, k: int, l: int) -> None:
        """Sub-slot ``l >= 1`` of tick ``k``."""

    def end_tick(self, k: int) -> None:
        """At ``t_{k+1}``, before tick ``k+1`` begins: finish tick ``k`` and record row ``k-1``."""
        raise NotImplementedError

    def message(self, g: int) -> tuple[str, dict[str, Any], int]:
        """What every node sends at global round ``g``: (box, {field: (n, ...) array}, nbytes)."""
        raise NotImplementedError

    def local_tick(self, k: int) -> None:
        """Tick ``k`` without any exchange (``slots = 0``)."""
        raise NotImplementedError

    # -- the machinery -------------------------------------------------------------
    def start_rounds(self, links: list[Link], slots: int) -> None:
        """Open the port on ``links`` (e.g. ``ctx.topology_links()``) and schedule the sub-slot
        instants (call from ``start``)."""
        ctx = self.ctx
        s = ctx.system
        self.Phi, self.Q = np.asarray(s.Phi, float), np.asarray(s.Q, float)
        omega, theta = ctx.existing_information()          # crashed sensors measure nothing
        self.omega, self.theta = np.asarray(omega, float), np.asarray(theta, float)
        self.K, self.n, self.nx = self.theta.shape
        self._omega_per_row = self.omega.ndim == 4
        self.slots = slots
        self.T_ns = ctx.T_ns
        self.dt = self.T_ns // slots if slots > 0 else self.T_ns
        self.crashes = ctx.crashes
        self.env = ctx.env
        self.superseded = 0
        self.links = list(links) if slots > 0 else []
        arcs = [(link.src, link.dst) for link in self.links]
        self.lid = {link.id: a for a, link in enumerate(self.links)}
        # Per sending node, its arcs (index, link) in the links' order: one broadcast frame each.
        # The network's arcs are sorted, so the frames' parts are the links in their order.
        out: dict[int, list[tuple[int, Link]]] = {}
        for a, link in enumerate(self.links):
            out.setdefault(link.src, []).append((a, link))
        self._out_arcs = list(out.items())
        E = self.E = len(self.links)
        n = self.n
        self.src = np.array([u for u, _ in arcs], dtype=np.intp)
        self.dst = np.array([v for _, v in arcs], dtype=np.intp)
        pi = metropolis_weights(n, arcs) if E else np.zeros(0)
        import scipy.sparse  # (lazy: a consensus run's start, not every command)
        # S[v, a] = pi_a for arc a = (u -> v): the neighbour part of a combination.
        self.S = scipy.sparse.csr_matrix((pi, (self.dst, np.arange(E))), shape=(n, E))
        # A[v, a] = 1 for arc a = (u -> v): sums over in-neighbours.
        self.A = scipy.sparse.csr_matrix((np.ones(E), (self.dst, np.arange(E))), shape=(n, E))
        self.box = {name: Box(E, shapes) for name, shapes in self.boxes().items()}
        # A graph that changes: the arcs' states per tick (K + 1, E), else None.
        self._up_table: np.ndarray | None = None
        if any(link.changes for link in self.links):        # (then every link of the graph has states)
            states = [link.up_per_tick() for link in self.links]
            self._up_table = np.stack([u for u in states if u is not None], axis=1)
        #: (E,) the arcs up at the tick being computed (all of them on a fixed graph)
        self.up_now = np.ones(E, dtype=bool)
        self._up_tick = -1
        self.setup()
        self.x_out = np.empty((self.K, n, self.nx))
        self.P_out = np.empty((self.K, n, self.nx, self.nx))
        # The last tick is finished at t_{K+1}: deliveries count until then.
        self.open_port(self._receive, self.links, until=(self.K + 1) * self.T_ns)
        if slots == 0:
            for k in range(1, self.K + 1):
                self.local_tick(k)
        else:
            self._g = 0
            Scheduled(self.env, self._instant, PRIORITY_UPDATE, self.T_ns)

    def omega_at(self, k: int) -> np.ndarray:
        """Every node's measurement information matrix of row ``k - 1`` (n, nx, nx)."""
        return self.omega[k - 1] if self._omega_per_row else self.omega

    def record(self, k: int, x: np.ndarray, P: np.ndarray) -> None:
        self.x_out[k - 1] = x
        self.P_out[k - 1] = P

    def _down(self) -> np.ndarray:
        """Nodes inside a crash window now."""
        if not self.crashes or self.slots == 0:
            return np.zeros(0, dtype=np.intp)
        now = self.env.now
        return np.array([i for i in range(self.n) if self.crashes.down(i, int(now))], dtype=np.intp)

    def follow_graph(self, k: int) -> None:
        """On a graph that changes: take the arcs up at tick ``k`` (the tick being computed),
        and the weights of that graph's degrees (a down arc weighs nothing)."""
        table = self._up_table
        if table is None:
            return
        k = min(k, table.shape[0] - 1)
        if k == self._up_tick:
            return
        self._up_tick = k
        up = table[k]
        if np.array_equal(up, self.up_now):
            return
        self.up_now = up.copy()
        self.S = self.weight_matrix(up)

    def arc_weights(self, on: np.ndarray) -> np.ndarray:
        """(E,) the weight of each arc in the graph of the arcs ``on`` (0 off it): Metropolis
        by default (a subclass with other weights overrides it)."""
        pi = np.zeros(self.E)
        idx = np.flatnonzero(on)
        if idx.size:
            pi[idx] = metropolis_weights(self.n, np.column_stack([self.src[idx], self.dst[idx]]))
        return pi

    def weight_matrix(self, on: np.ndarray) -> scipy.sparse.csr_matrix:
        """``S[v, a] = pi_a`` for arc ``a = (u -> v)`` of the graph of the arcs ``on``."""
        import scipy.sparse
        return scipy.sparse.csr_matrix((self.arc_weights(on), (self.dst, np.arange(self.E))),
                                       shape=(self.n, self.E))

    def current(self, have: np.ndarray) -> np.ndarray:
        """``have`` restricted to the arcs up at the tick being computed (unchanged on a
        fixed graph)."""
        return have if self._up_table is None else have & self.up_now

    def fresh(self, box: str, first: int, last: int | None = None) -> np.ndarray:
        """(E,) bool: the arc holds a message of ``box`` stamped in ``[first, last]`` (and, on
        a graph that changes, is up at the tick being computed)."""
        st = self.box[box].stamp
        return self.current((st >= first) if last is None else (st >= first) & (st <= last))

    def mix(self, own: np.ndarray, nb: np.ndarray, have: np.ndarray) -> np.ndarray:
        """``pi_ii' own_i + sum_j pi_ij nb_j`` over the arcs in ``have``; the weight of the
        others goes to the node itself (``pi_ii' = 1 - sum of the used pi_ij``).  A node
        that is down keeps ``own``."""
        shape = own.shape
        self_w = 1.0 - self.S @ have.astype(float)
        nbm = nb.reshape(self.E, math.prod(nb.shape[1:])) * have[:, None]   # (E may be 0)
        out = self_w.reshape((-1,) + (1,) * (own.ndim - 1)) * own + (self.S @ nbm).reshape(shape)
        down = self._down()
        if down.size:
            out[down] = own[down]
        return out

    def nsum(self, nb: np.ndarray, have: np.ndarray) -> np.ndarray:
        """``sum_j nb_j`` over each node's in-arcs in ``have`` (n, ...)."""
        nbm = nb.reshape(self.E, math.prod(nb.shape[1:])) * have[:, None]   # (E may be 0)
        return (self.A @ nbm).reshape((self.n,) + nb.shape[1:])

    def _send(self, g: int) -> None:
        """Every node's message of round ``g``, broadcast: one frame per node carrying the same
        content to each of its out-links that is up (a crashed node sends nothing).  Without a
        shared channel, one packet per link, in the links' order (decision 227)."""
        box, fields, nbytes = self.message(g)
        state = (g, box, fields)
        send_frame = self.port.send_frame
        down = set(self._down().tolist())
        up = self.up_now
        for node, arcs in self._out_arcs:
            if node in down:
                continue
            parts = [(link, state, nbytes) for a, link in arcs if up[a]]   # nothing on a down arc
            if parts:
                send_frame(parts, nbytes)

    def _receive(self, link: Link, payload: Any) -> None:
        g, box, fields = payload
        if self.DROP_LATE and self.env.now > self.deadline(g):
            self.port.count_late()
            return
        a = self.lid[link.id]
        b = self.box[box]
        if g > b.stamp[a]:
            b.stamp[a] = g
            b.store(a, link.src, fields)
        else:
            self.superseded += 1

    def _instant(self, _event: Any) -> None:
        g = self._g                  # global round index: tick g // slots + 1, sub-slot g % slots
        self._g += 1
        k, l = g // self.slots + 1, g % self.slots
        if l == 0:
            if k > 1:
                self.follow_graph(k - 1)         # tick k - 1 ends with its own graph
                self.end_tick(k - 1)
            if k > self.K:
                return
            self.follow_graph(k)
            self.begin_tick(k)
        else:
            self.step(k, l)
        self._send(g)
        Scheduled(self.env, self._instant, PRIORITY_UPDATE, self.dt)

    # -- the result ---------------------------------------------------------------
    def estimate(self) -> Estimate:
        return Estimate(self.x_out, self.P_out)

    def facts(self) -> dict[str, Any]:
        """Sub-slots per tick, messages dropped late, messages superseded by a newer one (a
        subclass adds its own: ``{**super().facts(), ...}``)."""
        return {"slots": self.slots, "late": self.port.counts()["late"], "superseded": self.superseded}

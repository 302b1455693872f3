"""Vehicles that move: the ``mobility:`` key and the time-varying graph it makes (issue 23).

``mobility: {vehicles: {default: <trajectory>, 0: <trajectory>, ...}, range: {model: disk,
radius: R}}`` gives every node a trajectory (:mod:`dkfsim.components.trajectories`: its own
entry, else ``default``) and a range model (docs/mobility.md).

A link ``u -> v`` of the scenario's topology is *up* at tick ``k`` while the pair is in
range at ``t_k = k T``: with ``range: {model: disk, radius: R}``, while the distance between
the two vehicles is at most ``R`` metres.  The state of tick ``k`` holds for every instant of
``[t_k, t_{k+1})`` (docs/design.md §3, "Links that come and go").  A :class:`LinkSchedule`
is that table, worked out once by the run plan (:mod:`dkfsim.config.plan`) and read by the
network (a packet handed to a link that is down is lost, ``range_lost``) and the protocols
(flood's resend on link-up, the consensus filters' current neighbours).

:meth:`LinkSchedule.connect_window` gives ``B``, the shortest length such that every
interval of ``B`` consecutive ticks has a (strongly) connected union graph: the quantity
of the finite-time result on time-varying graphs (docs/design.md §6).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Literal

import numpy as np
from pydantic import field_validator

from dkfsim.components.traffic import Rate
from dkfsim.components.trajectories import Trajectory, TrajectoryParams
from dkfsim.core.files import clip
from dkfsim.core.params import NonNegReal, PosReal, Probability, StrictModel, custom_error

#: Largest link schedule (ticks x arcs, one byte each) a scenario may ask for (256 MiB).
SCHEDULE_LIMIT = 1 << 28


class DiskRange(StrictModel):
    """A pair is in range while the vehicles are at most ``radius`` metres apart."""

    model: Literal["disk"] = "disk"
    #: metres
    radius: PosReal

    def in_range(self, distance: np.ndarray) -> np.ndarray:
        """Which distances (m) are in range."""
        return distance <= self.radius


def _table(points: list, what: str) -> list:
    """A piecewise-linear table ``[[distance, value], ...]``: distances strictly increasing."""
    if not points:
        raise custom_error(f"give at least one [distance, {what}] point")
    d = [p[0] for p in points]
    if any(b <= a for a, b in zip(d, d[1:])):
        raise custom_error(f"the distances of the [distance, {what}] points must strictly increase, got {clip(d)}")
    return points


class DistanceLinks(StrictModel):
    """``mobility.links``: a link's quality from its pair's distance at the hand-over tick
    (decision 176).  Tables are piecewise linear in the distance (m) and held constant
    beyond their first and last points."""

    #: ``[[d, p], ...]``: loss probability, combined with the link's own ``loss`` as
    #: ``1 - (1 - loss)(1 - p(d))`` and decided with the link's keyed loss uniform
    loss: list[tuple[NonNegReal, Probability]] | None = None
    #: seconds per metre added to every latency draw (propagation, processing)
    latency_per_m: NonNegReal = 0.0
    #: ``[[d, bit/s], ...]``: the link's transmitter rate, replacing ``links.*.rate`` (held to the
    #: same range, :data:`~dkfsim.components.traffic.MIN_RATE` .. ``MAX_RATE``)
    rate: list[tuple[NonNegReal, Rate]] | None = None

    @field_validator("loss")
    @classmethod
    def _loss(cls, v: Any) -> Any:
        return v if v is None else _table(v, "loss probability")

    @field_validator("rate")
    @classmethod
    def _rate(cls, v: Any) -> Any:
        return v if v is None else _table(v, "bit/s")

    @staticmethod
    def _interp(table: list, distance: np.ndarray) -> np.ndarray:
        return np.interp(distance, [p[0] for p in table], [p[1] for p in table])

    def per_tick(self, distance: np.ndarray) -> tuple[list[float] | None, list[int] | None, list[float] | None]:
        """For one arc's distances per tick: (loss probability, extra latency ns, rate bit/s)
        per tick, each None when not given."""
        d = np.asarray(distance, dtype=float)
        loss = self._interp(self.loss, d).tolist() if self.loss is not None else None
        extra = np.rint(d * self.latency_per_m * 1e9).astype(np.int64).tolist() if self.latency_per_m > 0 else None
        rate = self._interp(self.rate, d).tolist() if self.rate is not None else None
        return loss, extra, rate


def check_vehicle_keys(vehicles: dict, n: int, noun: str, where: str) -> None:
    """Every key of ``vehicles`` (parsed by :meth:`Mobility.parse_vehicles`) is ``default`` or one
    of ``0 .. n-1``, and every one of those has a trajectory (its own or the default); the error
    names ``where.<key>`` and calls them ``noun`` ("node", "bystander")."""
    for key in vehicles:
        if key != "default" and (len(key) > 18 or not 0 <= int(key) < n):
            raise custom_error(f"{noun} {key} is out of range 0..{n - 1}", f"{where}.{key}")
    if "default" not in vehicles:
        missing = [i for i in range(n) if str(i) not in vehicles]
        if missing:
            raise custom_error(f"{noun} {missing[0]} has no trajectory ({len(missing)} {noun}(s) without one); "
                               "give it one, or a 'default' trajectory", where)


class Mobility(StrictModel):
    """The top-level ``mobility`` key: a trajectory per vehicle (node), the radio range, the
    link quality from distance and a speed factor."""

    #: ``default`` and/or node numbers -> a trajectory (:mod:`dkfsim.components.trajectories`)
    vehicles: dict[str, Trajectory]
    range: DiskRange
    #: link quality from distance (None: the link models alone, as without ``mobility:``)
    links: DistanceLinks | None = None
    #: every trajectory is evaluated at ``speed * t`` (decision 180)
    speed: PosReal = 1.0

    @field_validator("vehicles", mode="before")
    @classmethod
    def _keys(cls, v: Any) -> Any:
        return cls.parse_vehicles(v)

    @staticmethod
    def parse_vehicles(v: Any) -> Any:
        """Keys are ``default`` or node numbers (YAML reads ``0:`` as an integer)."""
        if not isinstance(v, dict):
            return v
        out = {}
        for key in v:
            if isinstance(key, bool) or not (key == "default" or isinstance(key, int)
                                             or (isinstance(key, str) and key.isdigit())):
                raise custom_error(f"a vehicle key is a node number or 'default', got {clip(key)}", clip(key, 40))
            name = str(key) if not isinstance(key, str) else (key if key == "default" else key.lstrip("0") or "0")
            if name in out:
                raise custom_error(f"vehicle {name} is given twice (as {clip(key)} and as another key naming "
                                   "the same node, e.g. 0 and '0'); give each node one trajectory", clip(key, 40))
            out[name] = v[key]
        if not out:
            raise custom_error("give at least one vehicle (or a default trajectory)")
        return out

    def check(self, n: int) -> None:
        """Cross-checks that need the network size (called by the scenario): every key a node,
        every node a trajectory."""
        check_vehicle_keys(self.vehicles, n, "node", "mobility.vehicles")

    @property
    def rate_from_distance(self) -> bool:
        """True when ``links.rate`` gives every topology link a rate from the pair's distance."""
        return self.links is not None and self.links.rate is not None

    def trajectory(self, node: int) -> TrajectoryParams:
        """Node ``node``'s trajectory: its own entry, else the default (placed for the node:
        :meth:`~dkfsim.components.trajectories.TrajectoryParams.for_node`)."""
        return (self.vehicles.get(str(node)) or self.vehicles["default"]).for_node(node)

    def sinr_at(self, node: int) -> Any:
        """Node ``node``'s recorded SINR as a function of run seconds (``speed`` applied), or
        None when its trajectory records none (only a ``track`` does)."""
        traj = self.trajectory(node)
        if not hasattr(traj, "sinr_function"):
            return None
        return traj.sinr_function(float(self.speed))

    def positions(self, n: int, K: int, T: float) -> np.ndarray:
        """Every vehicle's position (m) at ``t_k = k T``, ``k = 0 .. K``: ``(K + 1, n, 2)``."""
        t = np.arange(K + 1) * float(T)
        if self.speed != 1.0:
            t = t * float(self.speed)
        out = np.empty((K + 1, n, 2))
        for i in range(n):
            out[:, i, :] = self.trajectory(i).positions(t)
        return out


class LinkSchedule:
    """``up[k, a]``: whether arc ``a`` (of ``arcs``) is up at tick ``k`` (``k = 0 .. K``).

    :param up: a boolean ``(K + 1, len(arcs))`` array.
    :param arcs: the topology's arcs, in the network's link order.
    """

    def __init__(self, up: np.ndarray, arcs: Sequence[tuple[int, int]], distance: np.ndarray | None = None,
                 quality: DistanceLinks | None = None):
        self.up = np.ascontiguousarray(up, dtype=bool)
        #: ``(K + 1, len(arcs))`` metres between each arc's ends per tick, kept only with a
        #: link quality from distance (``quality``, ``mobility.links``)
        self.distance = distance
        self.quality = quality
        #: node -> its recorded SINR (run seconds -> dB) for ``cellular_sinr`` with ``sinr:
        #: track`` (set by the run plan for ``track`` vehicles)
        self.sinr: dict[int, Any] = {}
        self.arcs: list[tuple[int, int]] = [(int(a[0]), int(a[1])) for a in arcs]
        if self.up.shape != (self.up.shape[0], len(self.arcs)):
            raise ValueError(f"up must have one column per arc, got shape {self.up.shape}")
        #: whether some arc is down at some tick ``1 .. K`` (the ticks a run sends at): a
        #: schedule that never changes runs exactly as the fixed graph
        self.changes = not bool(self.up[1:].all())

    @classmethod
    def from_positions(cls, positions: np.ndarray, arcs: Sequence[tuple[int, int]], rng: DiskRange,
                       quality: DistanceLinks | None = None) -> LinkSchedule:
        """The schedule of ``arcs`` for vehicle ``positions`` (``(K + 1, n, 2)`` metres, row
        ``k`` at ``t_k``) under the range model ``rng``; with ``quality`` the distances are
        kept for the links' quality (``mobility.links``)."""
        pos = np.asarray(positions, dtype=float)
        if not arcs:
            return cls(np.zeros((pos.shape[0], 0), dtype=bool), arcs)
        a = np.asarray(arcs, dtype=np.intp)
        up = np.empty((pos.shape[0], len(a)), dtype=bool)
        dist = np.empty((pos.shape[0], len(a))) if quality is not None else None
        step = max(1, (1 << 21) // len(a))                  # ticks per block: a few MB of distances
        for k in range(0, pos.shape[0], step):
            p = pos[k:k + step]
            d = np.hypot(*(p[:, a[:, 0], :] - p[:, a[:, 1], :]).transpose(2, 0, 1))
            up[k:k + step] = rng.in_range(d)
            if dist is not None:
                dist[k:k + step] = d
        return cls(up, arcs, dist, quality)

    @property
    def K(self) -> int:
        return self.up.shape[0] - 1

    def column(self, arc: int) -> bytes:
        """Arc ``arc``'s state per tick as bytes (``col[k]`` is 1 when up): cheap per packet."""
        return self.up[:, arc].astype(np.uint8).tobytes()

    def came_up(self, k: int) -> list[int]:
        """The arcs up at tick ``k`` that were down at tick ``k - 1`` (none at tick 0)."""
        if k <= 0 or k > self.K:
            return []
        return np.flatnonzero(self.up[k] & ~self.up[k - 1]).tolist()

    def connect_window(self, n: int, arcs: Sequence[int] | None = None) -> int | None:
        """``B``: the smallest length such that the union of the graphs of every ``B``
        consecutive ticks in ``1 .. K`` is strongly connected (over the arcs numbered
        ``arcs``, default all); None when even the union of ticks ``1 .. K`` is not.

        Ticks with the same links form segments (``a_i`` the first tick of segment ``i``).
        Two pointers over segments: for each ``i`` the first segment ``j(i)`` whose union
        with ``i .. j(i) - 1`` is connected, which never decreases with ``i``; a start
        ``s`` in segment ``i`` then needs ``max(1, a_j(i) - s + 1)`` ticks, most at
        ``s = a_i``, so ``B`` is the smallest value with ``a_j(i) - a_i + 1 <= B`` for every
        segment with ``a_i <= K - B + 1``.  One connectivity check per segment step."""
        K = self.K
        if n <= 1 or K < 1:
            return 1
        cols = np.arange(len(self.arcs)) if arcs is None else np.asarray(list(arcs), dtype=np.intp)
        up = self.up[1:, cols]
        pairs = np.asarray([self.arcs[c] for c in cols], dtype=np.intp).reshape(-1, 2)
        change = np.flatnonzero((up[1:] != up[:-1]).any(axis=1)) + 1
        starts = np.concatenate([[0], change])             # segment starts, 0-based (tick - 1)
        rows = up[starts]
        M = len(starts)
        count = np.zeros(len(cols), dtype=np.int64)
        span = np.full(M, np.iinfo(np.int64).max, dtype=np.int64)
        j = -1                                              # segments i .. j are in the window
        for i in range(M):
            while (j < i or not _strongly_connected(n, pairs, count > 0)) and j < M - 1:
                j += 1
                count += rows[j]
            if j < i or not _strongly_connected(n, pairs, count > 0):
                break                                   # no later start connects either
            span[i] = starts[j] - starts[i] + 1 if j > i else 1
            count -= rows[i]
        worst = np.maximum.accumulate(span)             # worst[m]: max span over segments 0..m
        for B in range(1, K + 1):
            m = int(np.searchsorted(starts, K - B, side="right")) - 1     # segments with a_i <= K - B + 1
            if worst[m] <= B:
                return B
        return None


def _strongly_connected(n: int, pairs: np.ndarray, on: np.ndarray) -> bool:
    """Whether the arcs ``pairs[a]`` (``(E, 2)``) with ``on[a]`` make a strongly connected
    graph on nodes ``0 .. n-1``."""
    used = pairs[on]
    if len(used) < n:
        return False                # (a strongly connected digraph on n > 1 nodes has >= n arcs)
    import scipy.sparse.csgraph  # (lazy: only a changing graph's connectivity needs it)
    graph = scipy.sparse.csr_matrix((np.ones(len(used)), (used[:, 0], used[:, 1])), shape=(n, n))
    return int(scipy.sparse.csgraph.connected_components(graph, directed=True, connection="strong")[0]) == 1


def link_pairs(schedule: LinkSchedule) -> tuple[np.ndarray, np.ndarray]:
    """The schedule per pair of vehicles: ``pairs`` ``(E, 2)`` (``u < v``, sorted), one per
    unordered pair with an arc of the topology, and ``up`` ``(K + 1, E)``: whether the pair's
    link is up at tick ``k`` (one of its arcs up; a disk range puts both up together).  What
    ``run.npz`` keeps as ``mobility_links`` and ``links_up`` (decision 187)."""
    cols: dict[tuple[int, int], list[int]] = {}
    for a, (u, v) in enumerate(schedule.arcs):
        cols.setdefault((min(u, v), max(u, v)), []).append(a)
    pairs = sorted(cols)
    up = np.zeros((schedule.up.shape[0], len(pairs)), dtype=bool)
    for e, pair in enumerate(pairs):
        up[:, e] = schedule.up[:, cols[pair]].any(axis=1)
    return np.array(pairs, dtype=np.int64).reshape(-1, 2), up


def link_uptime(pairs: np.ndarray, up: np.ndarray) -> list[list]:
    """``[u, v, fraction]`` per pair: the fraction of the rows of ``up`` (``(K, E)``, the run's
    ticks ``1 .. K``) at which the pair's link was up -- summary.json's ``mobility.link_uptime``."""
    frac = up.mean(axis=0) if up.shape[0] else np.zeros(up.shape[1])
    return [[int(u), int(v), float(f)] for (u, v), f in zip(pairs.tolist(), frac.tolist())]

"""Memory and time a command will need, estimated before it starts.

Every command that can be asked for too much (``run``, ``montecarlo``,
``sweep``, ``maxdelay``) first builds an :class:`Estimate` from the
validated scenario and settings -- array sizes exactly, CPU time from a
small cost model calibrated on this project's benchmarks (right within a
factor of a few) -- and calls :func:`check`:

* more memory than the machine has available (:func:`available_memory`:
  the smaller of the free RAM and a cgroup limit, times
  :data:`MEMORY_FRACTION`) is refused with a message that says what takes
  the room and what to change;
* an estimated wall time above :data:`TIME_LIMIT_S` (10 minutes) stops with
  the estimate and the way to proceed (``--yes`` / ``yes=True``).

Nothing has been computed when either happens, so nothing is lost.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field

from dkfsim.core.errors import DkfsimError

#: Above this estimated wall time a command asks for --yes.
TIME_LIMIT_S = 600.0
#: Share of the available memory a command may plan to use.
MEMORY_FRACTION = 0.8

# Cost model (seconds; one core, one BLAS thread), calibrated with tools/bench.py.
C_TICK = 40e-6          # per tick: events, bookkeeping
C_ROW = 25e-6           # per re-run window row: numpy calls
C_NODE_ROW = 2.0e-6     # per node and re-run row: the batched information step
C_PACKET = 12e-6        # per packet: send, deliver, flush
C_CONTRIBUTION = 0.3e-6  # per (receiver, origin, row) contribution folded in
C_FLOP = 0.15e-9        # per floating-point operation of the fusion's dense products
C_FUSION_ROW = 60e-6    # per re-run row with fusion: the calls around those products
C_VALIDATE = 3e-3       # per scenario validation (a sweep's parameter sets)
C_VISIT = 1.0e-6        # per node or edge visited by a breadth-first search (networkx)
#: Below this many visits an exact all-pairs search is cheap enough to just do.
CHEAP_VISITS = 2_000_000
B_FLOAT = 8


class ResourceError(DkfsimError):
    """A command would not fit in memory, or would take long without --yes."""


def human_bytes(n: float) -> str:
    for unit, size in (("TiB", 2**40), ("GiB", 2**30), ("MiB", 2**20), ("KiB", 2**10)):
        if n >= size:
            return f"{n / size:.3g} {unit}"
    return f"{n:.0f} B"


def human_seconds(s: float) -> str:
    if s >= 86400 * 365:
        return f"{s / (86400 * 365):.3g} years"
    for unit, size in (("days", 86400), ("h", 3600), ("min", 60)):
        if s >= size:
            return f"{s / size:.3g} {unit}"
    return f"{s:.2g} s"


def available_memory() -> int:
    """Bytes this process may still use: free RAM (``MemAvailable``), capped by a cgroup limit."""
    avail = None
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    avail = int(line.split()[1]) * 1024
                    break
    except OSError:
        pass
    if avail is None:
        try:
            avail = os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
        except (ValueError, OSError, AttributeError):
            avail = 8 << 30                       # unknown platform: assume a modest machine
    try:
        with open("/sys/fs/cgroup/memory.max") as fh:
            limit = fh.read().strip()
        with open("/sys/fs/cgroup/memory.current") as fh:
            used = int(fh.read().strip())
        if limit != "max":
            avail = min(avail, int(limit) - used)
    except (OSError, ValueError):
        pass
    return max(int(avail), 0)


@dataclass
class Estimate:
    """What a piece of work needs: memory by item (bytes) and CPU seconds on one core."""

    what: str
    memory: dict = field(default_factory=dict)
    seconds: float = 0.0
    workers: int = 1

    @property
    def bytes(self) -> float:
        return float(sum(self.memory.values()))

    @property
    def wall_seconds(self) -> float:
        return self.seconds / max(1, self.workers)

    def biggest(self, k: int = 3) -> str:
        items = sorted(self.memory.items(), key=lambda kv: -kv[1])[:k]
        return ", ".join(f"{name} {human_bytes(size)}" for name, size in items if size > 0)


def check(est: Estimate, *, yes: bool = False, hint: str = "", yes_flag: str = "--yes") -> None:
    """Refuse ``est`` if it cannot fit; ask for ``yes`` if it takes long (see the module docstring)."""
    room = available_memory() * MEMORY_FRACTION
    if est.bytes > room:
        raise ResourceError(
            f"{est.what} needs about {human_bytes(est.bytes)} of memory ({est.biggest()}), more than "
            f"the {human_bytes(room)} this machine can give it" + (f"; {hint}" if hint else ""))
    if est.wall_seconds > TIME_LIMIT_S and not yes:
        par = f" on {est.workers} workers" if est.workers > 1 else ""
        raise ResourceError(
            f"{est.what} would take about {human_seconds(est.wall_seconds)}{par} (a rough estimate, "
            f"within a factor of a few; memory about {human_bytes(est.bytes)}); add {yes_flag} to "
            "run it anyway" + (f", or {hint}" if hint else ""))


# =========================================================================== one run
def _dkf_costs(n: int, nx: int, K: int, L: int, arcs: int, fusion: str) -> tuple[float, float]:
    """(seconds, bytes of the window and fusion state) of the anti-delay DKF."""
    S = min(L, K) + 1
    rows = min(L, K)                           # re-run rows per tick, at worst
    N = n * nx
    sec = K * (C_TICK + rows * (C_ROW + n * C_NODE_ROW) + 1.5 * arcs * C_PACKET
               + n * n * C_CONTRIBUTION)
    window = S * n * (2 * nx + 3 * nx * nx) * B_FLOAT + S * n * n
    if fusion != "none":
        sec += K * ((rows * 4 + 1) * N ** 3 * C_FLOP + rows * C_FUSION_ROW)
        window += S * N * N * B_FLOAT
    return sec, window


def exchange_shape(scenario) -> tuple[int, int, float]:
    """``(L, arcs, seconds)``: the buffer length, the number of links and the time to
    find them, without an all-pairs search on a large graph that is not a tree
    (whose diameter is then estimated from below by two searches)."""
    from dkfsim.components import topology as topo
    graph = scenario.graph()
    if topo.is_tree(graph) or not (scenario.protocol == "flood" or scenario.spanning_tree) \
            or topo.all_pairs_work(graph) <= CHEAP_VISITS:
        xg = scenario.exchange()
        return scenario.resolved_buffer_length(), len(xg.arcs), 0.0
    work = topo.all_pairs_work(graph)
    lower, _ = topo.diameter_bounds(graph)
    if isinstance(scenario.buffer_length, int):
        L = scenario.buffer_length
    else:
        d_t = scenario.resolved_d_t() or 0
        L = max(d_t, 1) if scenario.buffer_length == "paper" else d_t * lower + 1
    arcs = 2 * (scenario.n - 1) if scenario.spanning_tree else \
        graph.number_of_edges() * (1 if graph.is_directed() else 2)
    return L, arcs, work * C_VISIT


def estimate_run(scenario, save: str = "auto") -> Estimate:
    """Memory and time of one run of ``scenario`` (its DKF and every baseline it lists)."""
    from dkfsim.engine.results import resolve_save_mode
    n, nx, K = scenario.n, scenario.nx, int(scenario.steps)
    L, arcs, search = exchange_shape(scenario)
    m_total = sum(s.m for s in scenario.sensors)
    mode = resolve_save_mode(save, n, K)
    est = Estimate(f"{scenario.name}: a run of {K} ticks on {n} nodes")
    f = B_FLOAT
    varying = any(getattr(s, "kind", "linear") != "linear" for s in scenario.sensors)
    est.memory["truth and measurements"] = K * (nx + m_total) * f
    est.memory["information contributions"] = K * n * nx * f * (1 + (nx if varying else 0))
    est.memory["x_local, x_final"] = 2 * K * n * nx * f
    if mode in ("full", "estimates"):
        est.memory["P_local"] = min(K * n * nx * nx, 50_000_000) * f
    if mode == "full":
        est.memory["arrival log (n x n x K)"] = n * n * K * f
    sec, window = _dkf_costs(n, nx, K, L, arcs, scenario.fusion)
    est.memory["window filters" + (" and cross-covariances" if scenario.fusion != "none" else "")] = window
    if scenario.fusion != "none":
        est.memory["x_fused, P_fused"] = K * (nx + nx * nx) * f
    for name in scenario.baselines:
        if name == "centralized":
            sec += K * C_TICK
            est.memory["centralized"] = K * (nx + nx * nx) * f
        elif name == "local":
            sec += K * (C_ROW + n * C_NODE_ROW)
            est.memory["local"] = K * n * (nx + nx * nx) * f
        elif name == "no_buffer":
            s2, w2 = _dkf_costs(n, nx, K, 1, arcs, scenario.fusion)
            sec += s2
            est.memory["no_buffer"] = w2 + K * n * (2 * nx + nx * nx) * f
        elif name == "ci_consensus":
            rounds = int(getattr(scenario, "consensus_rounds", 1))
            sec += K * (C_ROW + n * C_NODE_ROW) + K * rounds * (C_TICK + 3 * C_ROW + arcs * C_PACKET
                                                                 + n * 2 * C_NODE_ROW)
            est.memory["ci_consensus"] = K * n * (nx + nx * nx) * f + arcs * (nx + nx * nx) * 2 * f
        elif name == "centralized_delayed":
            s2, w2 = _dkf_costs(1, nx, K, L, 0, "none")
            sec += s2 + K * n * C_PACKET
            est.memory["centralized_delayed"] = w2 + K * n * (8 + 2 * nx * f)
    est.memory["graph and bookkeeping"] = (n + arcs) * 200 + min(L, K) * (n + 3 * arcs) * 40
    est.seconds = sec + search
    return est


def check_run(scenario, *, save: str = "auto", yes: bool = False) -> Estimate:
    """:func:`check` one run; returns its estimate."""
    est = estimate_run(scenario, save)
    check(est, yes=yes, hint="fewer steps or nodes, a shorter buffer_length, fusion: none, "
                             "or --save estimates (no n x n x K arrival log)")
    return est


def repeat(est: Estimate, what: str, count: float, workers: int, extra_bytes: float = 0.0,
           extra_seconds: float = 0.0) -> Estimate:
    """``count`` runs like ``est`` on ``workers`` processes (each holding one run at a time)."""
    out = Estimate(what, workers=max(1, workers))
    for name, size in est.memory.items():
        out.memory[f"{name} (x {min(out.workers, max(1, math.ceil(count)))} workers)"] = \
            size * min(out.workers, max(1, math.ceil(count)))
    if extra_bytes:
        out.memory["results kept"] = extra_bytes
    out.seconds = est.seconds * count + extra_seconds
    return out

"""Memory and time a command will need, estimated before it starts.

Every command that can be asked for too much (``run``, ``montecarlo``,
``sweep``, ``maxdelay``) first builds a :class:`Cost` from the
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

try:
    import resource
except ImportError:  # pragma: no cover  (not a Unix)
    resource = None  # type: ignore[assignment]
from dataclasses import dataclass, field
from typing import Literal, cast

from dkfsim.core.errors import DkfsimError, ResourceError

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

#: What a run keeps (``--save``, resolved): everything, no arrival log, summary.json only.
SaveMode = Literal["full", "estimates", "summary"]
#: What ``--save`` accepts.
SAVE_MODES = ("auto", "full", "estimates", "summary")
#: ``save: auto`` keeps the (n, n, K) arrival log only while it stays below this
#: many entries (160 MB); beyond, it saves the estimates only.
FULL_LOG_LIMIT = 20_000_000


def resolve_save_mode(save: str, n: int, K: int) -> SaveMode:
    """The mode a run of ``n`` nodes and ``K`` ticks keeps (``auto`` resolved)."""
    if save == "auto":
        return "full" if n * n * K <= FULL_LOG_LIMIT else "estimates"
    if save in ("full", "estimates", "summary"):
        return cast(SaveMode, save)
    raise DkfsimError(f"--save: unknown mode {save!r}; choose one of {', '.join(SAVE_MODES)}")


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
    left = _address_space_left()
    if left is not None:
        avail = min(avail, left)
    return max(int(avail), 0)


def _address_space_left() -> int | None:
    """Address space this process may still map under ``RLIMIT_AS`` (``ulimit -v``); None if
    unlimited or unknown."""
    if resource is None:  # pragma: no cover  (not a Unix)
        return None
    try:
        soft, _hard = resource.getrlimit(resource.RLIMIT_AS)
        if soft == resource.RLIM_INFINITY:
            return None
        with open("/proc/self/statm") as fh:
            size = int(fh.read().split()[0]) * os.sysconf("SC_PAGE_SIZE")
        return max(soft - size, 0)
    except (OSError, ValueError, IndexError):
        return None


@dataclass
class Cost:
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


def check(est: Cost, *, yes: bool = False, hint: str = "", yes_flag: str = "--yes") -> None:
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


# =========================================================================== many runs
def repeat(est: Cost, what: str, count: float, workers: int, extra_bytes: float = 0.0,
           extra_seconds: float = 0.0) -> Cost:
    """``count`` runs like ``est`` on ``workers`` processes (each holding one run at a time)."""
    out = Cost(what, workers=max(1, workers))
    for name, size in est.memory.items():
        out.memory[f"{name} (x {min(out.workers, max(1, math.ceil(count)))} workers)"] = \
            size * min(out.workers, max(1, math.ceil(count)))
    if extra_bytes:
        out.memory["results kept"] = extra_bytes
    out.seconds = est.seconds * count + extra_seconds
    return out

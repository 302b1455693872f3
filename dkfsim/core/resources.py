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

Time is estimated as *events*, then seconds: a run's events are its estimator ticks, the
packets sent, the (node, row) pairs its window filters re-run and the rows its fusion re-runs
(:data:`EVENT_KINDS`, what :func:`dkfsim.engine.driver.run_events` counts in a run); an
estimate that matters measures them on a short trial of the run
(:func:`dkfsim.engine.driver.trial_events`), and :func:`event_seconds` turns them into seconds
with the seconds per event ``tools/bench.py --calibrate`` fitted and stored in
:data:`CALIBRATION` (docs/performance.md, "Estimates").
"""

from __future__ import annotations

import functools
import math
import os
from pathlib import Path

try:
    import resource
except ImportError:  # pragma: no cover  (not a Unix)
    resource = None  # type: ignore[assignment]
from dataclasses import dataclass, field
from typing import Literal, cast

from dkfsim.core.errors import DkfsimError, ResourceError
from dkfsim.core.files import read_json

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
C_RADIO_MEMBER = 0.13e-6  # per vehicle a frame on a spatial radio visits: its power, draws, receiver
#                           steps (0.11-0.19 us with shadowing and fading, 300 to 3,000 vehicles)
#: Below this many visits an exact all-pairs search is cheap enough to just do.
CHEAP_VISITS = 2_000_000
B_FLOAT = 8

#: The kinds of events a run counts and an estimate predicts (docs/performance.md, "Estimates").
EVENT_KINDS = ("ticks", "packets", "node_rows", "fused_rows")
#: Seconds of CPU per event, fitted by ``tools/bench.py --calibrate`` (one core, one BLAS thread,
#: compiled kernels): ``ticks``, ``packets``, ``node_rows`` per event, ``fusion_flops`` per fused
#: row and cubed fusion size ``(n nx)^3``, and the machine and date of the fit.
CALIBRATION = Path(__file__).resolve().parents[1] / "data" / "calibration" / "seconds_per_event.json"


@functools.cache
def seconds_per_event() -> dict:
    """The stored calibration (:data:`CALIBRATION`)."""
    return read_json(CALIBRATION, what="the stored calibration of seconds per event")


def event_seconds(events: dict, fusion_size: int) -> float:
    """CPU seconds of ``events`` (counts by :data:`EVENT_KINDS`) whose fusion is ``fusion_size``
    = ``n nx`` wide, at the calibrated seconds per event."""
    s = seconds_per_event()
    return (events.get("ticks", 0) * s["ticks"] + events.get("packets", 0) * s["packets"]
            + events.get("node_rows", 0) * s["node_rows"]
            + events.get("fused_rows", 0) * float(fusion_size) ** 3 * s["fusion_flops"])


def human_count(n: float) -> str:
    """``1.2 million`` and the like, for counts of events."""
    for word, size in (("billion", 1e9), ("million", 1e6), ("thousand", 1e3)):
        if n >= size:
            return f"{n / size:.3g} {word}"
    return f"{n:.0f}"

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
    """What a piece of work needs: memory by item (bytes) and CPU seconds on one core.

    ``events``: the events it predicts by kind (:data:`EVENT_KINDS`; empty for an analytic guess)
    and ``how`` they were predicted (e.g. "measured on a trial of 54 ticks")."""

    what: str
    memory: dict = field(default_factory=dict)
    seconds: float = 0.0
    workers: int = 1
    events: dict = field(default_factory=dict)
    how: str = ""

    @property
    def n_events(self) -> float:
        return float(sum(self.events.values()))

    def events_text(self) -> str:
        """``"2.1 million events (…), measured on …"`` or ``""`` without events."""
        if not self.events:
            return ""
        parts = ", ".join(f"{human_count(v)} {k.replace('_', '-')}" for k, v in self.events.items() if v)
        return f"{human_count(self.n_events)} events ({parts})" + (f", {self.how}" if self.how else "")

    @property
    def bytes(self) -> float:
        return float(sum(self.memory.values()))

    @property
    def wall_seconds(self) -> float:
        return self.seconds / max(1, self.workers)

    def biggest(self, k: int = 3) -> str:
        items = sorted(self.memory.items(), key=lambda kv: -kv[1])[:k]
        return ", ".join(f"{name} {human_bytes(size)}" for name, size in items if size > 0)


def check_memory(est: Cost, *, hint: str = "") -> None:
    """Refuse ``est`` if it cannot fit in memory (what :func:`check` refuses first)."""
    room = available_memory() * MEMORY_FRACTION
    if est.bytes > room:
        raise ResourceError(
            f"{est.what} needs about {human_bytes(est.bytes)} of memory ({est.biggest()}), more than "
            f"the {human_bytes(room)} this machine can give it" + (f"; {hint}" if hint else ""))


def check(est: Cost, *, yes: bool = False, hint: str = "", yes_flag: str = "--yes",
          memory_hint: str | None = None) -> None:
    """Refuse ``est`` if it cannot fit; ask for ``yes`` if it takes long (see the module docstring).
    ``hint`` says what shortens it, ``memory_hint`` (default: ``hint``) what shrinks it: for many
    runs not the same (fewer runs or more workers take less time, not less memory)."""
    check_memory(est, hint=hint if memory_hint is None else memory_hint)
    if est.wall_seconds > TIME_LIMIT_S and not yes:
        par = f" on {est.workers} workers" if est.workers > 1 else ""
        basis = f"{est.events_text()}; " if est.events else "a rough estimate, within a factor of a few; "
        raise ResourceError(
            f"{est.what} would take about {human_seconds(est.wall_seconds)}{par} ({basis}memory about "
            f"{human_bytes(est.bytes)}); add {yes_flag} to run it anyway" + (f", or {hint}" if hint else ""))


# =========================================================================== many runs
def many_runs_memory_hint(workers: int, smaller: str, first: str = "") -> str:
    """What shrinks the memory of many runs on ``workers`` processes: ``first`` (what the command
    keeps of every run or candidate), fewer workers (each holds one run at a time; named without
    a flag: they come from ``--jobs``, ``--dask-local``, a scheduler or a given executor), or
    ``smaller`` runs.  Never "more workers", which shortens the time and adds memory."""
    parts = [first] if first else []
    if workers > 1:
        parts.append(f"fewer workers (each of the {workers} holds one run)")
    return ", ".join(parts + [f"or {smaller}"]) if parts else smaller


def repeat(est: Cost, what: str, count: float, workers: int, extra_bytes: float = 0.0,
           extra_seconds: float = 0.0) -> Cost:
    """``count`` runs like ``est`` on ``workers`` processes (each holding one run at a time)."""
    out = Cost(what, workers=max(1, workers), events={k: v * count for k, v in est.events.items()},
               how=est.how)
    for name, size in est.memory.items():
        out.memory[f"{name} (x {min(out.workers, max(1, math.ceil(count)))} workers)"] = \
            size * min(out.workers, max(1, math.ceil(count)))
    if extra_bytes:
        out.memory["results kept"] = extra_bytes
    out.seconds = est.seconds * count + extra_seconds
    return out

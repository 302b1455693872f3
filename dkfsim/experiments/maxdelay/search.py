"""The search of ``dkfsim maxdelay``: metrics of one run, candidates and their decisions.

A candidate collects per-run values until its Student-t interval of the excess over the
tolerance decides it; galloping and bisection (Monte Carlo) or a scan (worst case) walk
the axis.  See :mod:`dkfsim.experiments.maxdelay` and docs/design.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from dkfsim.analysis.metrics import mse_per_component, t_interval
from dkfsim.config.load import load_scenario
from dkfsim.engine.driver import Run

#: Metric name -> description (help text and JSON).
METRICS = {
    "mse": "squared error of the estimate --estimate (default fused), component --component (sum "
           "over components with 'all'; per-node estimates: mean over nodes), time average after burn-in",
    "fused_mse": "squared error of the fused estimate, component --component (sum over "
                 "components with 'all'), time average after burn-in",
    "trace_P": "trace of P_fused, time average after burn-in (--component is ignored); "
               "random only through the latencies",
    "fused_var": "P_fused[c, c] of --component (trace with 'all'), time average after burn-in",
    "local_mse": "squared error of every node's own real-time estimate, mean over nodes, "
                 "time average after burn-in",
}
#: Metrics computed from covariances only (no measurement data enters them).
COVARIANCE_METRICS = ("trace_P", "fused_var")
#: Metrics that need the fusion step.
FUSED_METRICS = ("fused_mse", "trace_P", "fused_var")



#: Old metric names: the ``mse`` of one estimate.
MSE_OF = {"fused_mse": "fused", "local_mse": "local"}


def tracked_estimate(st) -> str:
    """The estimate whose metric the search tracks (``fused`` for the covariance metrics)."""
    return MSE_OF.get(st.metric, st.estimate if st.metric == "mse" else "fused")


# =========================================================================== metrics
def metric_value(arrays, metric: str, comp: int | None, burn: int, estimate: str = "fused") -> float:
    """The per-run value of ``metric`` (``comp`` None = all components)."""
    if metric in MSE_OF or metric == "mse":
        mse = mse_per_component(np.asarray(arrays[f"x_{MSE_OF.get(metric, estimate)}"]),
                                np.asarray(arrays["truth"]), burn)
        return float(mse.sum() if comp is None else mse[comp])
    if metric == "trace_P":
        return covariance_value(arrays, "trace_P", None, burn)
    if metric == "fused_var":
        return covariance_value(arrays, "fused_var", comp, burn)
    raise ValueError(f"unknown metric {metric!r}")


def of_the_dkf(st) -> bool:
    """Whether the search tracks one of the anti-delay DKF's estimates (``fused``, ``local``):
    the worst case and the paper's bound follow its covariance and say nothing of another
    estimator's."""
    return tracked_estimate(st) in ("fused", "local")


def covariance_value(arrays, metric: str, comp: int | None, burn: int, estimate: str = "fused") -> float:
    """The covariance counterpart of ``metric`` (of ``estimate``, for ``mse``: the DKF's ``fused``
    or ``local``): what its expectation is when the filter's covariances are the true error
    covariances (always, here)."""
    if metric == "local_mse" or (metric == "mse" and estimate == "local"):
        P = np.asarray(arrays["P_local"])[burn:]
        d = np.diagonal(P, axis1=2, axis2=3)          # (K, n, nx)
        return float(d.mean(axis=(0, 1)).sum() if comp is None else d[:, :, comp].mean())
    P = np.asarray(arrays["P_fused"])[burn:]
    d = np.diagonal(P, axis1=1, axis2=2)              # (K, nx)
    if metric == "trace_P" or comp is None:
        return float(d.sum(axis=1).mean())
    return float(d[:, comp].mean())



# =========================================================================== runs
def _simulate(base, overrides: list, seed: int | None, metric: str, comp, burn: int,
              covariance: bool = False, estimate: str = "fused") -> tuple[float, dict[str, int]]:
    """The metric of one run, and the run's events (``RunResult.info["events"]``)."""
    ov = list(overrides) + ([] if seed is None else [f"seed={int(seed)}"])
    sc = load_scenario(base, overrides=ov)
    res = Run(sc, save="estimates").run()
    if covariance:
        return covariance_value(res.arrays, metric, comp, burn, estimate), res.info["events"]
    return metric_value(res.arrays, metric, comp, burn, estimate), res.info["events"]


class Runner:
    """Runs simulations on an executor (:mod:`dkfsim.experiments.executors`), results in
    task order; counts them, and their events (``events``: summed by kind)."""

    def __init__(self, executor, on_run=None):
        self.executor = executor
        self.runs = 0
        self.on_run = on_run
        self.events: dict[str, int] = {}

    def map(self, tasks: list[tuple]) -> list[float]:
        if not tasks:
            return []
        out = []
        for value, events in self.executor.map(_simulate, tasks, on_done=lambda: self._count(1)):
            out.append(value)
            for key, count in events.items():
                self.events[key] = self.events.get(key, 0) + int(count)
        return out

    def _count(self, k: int) -> None:
        self.runs += k
        if self.on_run is not None:
            self.on_run(k)


# =========================================================================== one candidate
WITHIN, EXCEEDS, UNDECIDED = "within", "exceeds", "undecided"


@dataclass
class Candidate:
    """Everything measured at one candidate delay."""

    index: int
    delay: float
    deterministic: bool
    values: list = field(default_factory=list)     # per-run metric
    excess: list = field(default_factory=list)     # per-run metric - tolerance (paired for relative)
    decision: str = UNDECIDED
    mean: float = math.nan
    ci: tuple = (math.nan, math.nan)
    excess_mean: float = math.nan
    excess_ci: tuple = (math.nan, math.nan)
    order: int = 0                                 # evaluation order

    @property
    def runs(self) -> int:
        return len(self.values)

    @property
    def looks_within(self) -> bool:
        """The direction the search takes: decided, or by the point estimate."""
        if self.decision != UNDECIDED:
            return self.decision == WITHIN
        return self.excess_mean <= 0

    def to_dict(self) -> dict:
        return {"index": self.index, "delay": self.delay, "order": self.order,
                "runs": self.runs, "deterministic": self.deterministic,
                "decision": self.decision, "mean": json_number(self.mean), "ci": [json_number(v) for v in self.ci],
                "excess_mean": json_number(self.excess_mean), "excess_ci": [json_number(v) for v in self.excess_ci],
                "values": [json_number(v) for v in self.values]}


def json_number(v):
    """A float for JSON (non-finite values are encoded by :func:`dkfsim.core.folders.to_json`)."""
    return None if v is None else float(v)


def interval(samples, level: float):
    """Mean and Student-t interval (a zero-width interval for one deterministic value)."""
    a = np.asarray(samples, float)
    if a.size == 1:
        return float(a[0]), (float(a[0]), float(a[0]))
    m, lo, hi = t_interval(a, level)
    return float(m), (float(lo), float(hi))


def classify(c: Candidate, level: float) -> None:
    """Set the mean, intervals and decision of a candidate from its samples."""
    c.mean, c.ci = interval(c.values, level)
    c.excess_mean, c.excess_ci = interval(c.excess, level)
    lo, hi = c.excess_ci
    if c.deterministic:
        c.decision = WITHIN if c.excess_mean <= 0 else EXCEEDS
    elif hi < 0:
        c.decision = WITHIN
    elif lo > 0:
        c.decision = EXCEEDS
    else:
        c.decision = UNDECIDED


# =========================================================================== the search
@dataclass
class SearchResult:
    """Outcome of one search over the delay axis.

    ``status``: ``decided`` (answer within, answer + 1 exceeds, both at the
    confidence level), ``undecided`` (a candidate at the boundary hit the run
    cap: ``answer`` is the largest delay decided *within* below it),
    ``capped`` (within up to the largest candidate), ``none`` (even zero
    delay exceeds the tolerance).
    """

    status: str
    answer: int | None            # candidate index
    point: int | None             # largest index the search saw as within (by the mean if undecided)
    first_exceeding: int | None
    non_monotone: bool
    candidates: dict


def gallop_bisect(evaluate, J: int) -> tuple[int | None, int | None]:
    """Largest ``lo`` that looks within and smallest ``hi`` above it that does
    not (``hi`` None: capped at ``J``; ``lo`` None: index 0 does not)."""
    if not evaluate(0).looks_within:
        return None, 0
    lo, hi, j = 0, None, 1
    while j <= J:
        if evaluate(j).looks_within:
            lo = j
            if j == J:
                break
            j = min(2 * j, J)
        else:
            hi = j
            break
    if hi is None:
        return lo, None
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if evaluate(mid).looks_within:
            lo = mid
        else:
            hi = mid
    return lo, hi


def summarise(cands: dict, lo, hi) -> SearchResult:
    within = sorted(j for j, c in cands.items() if c.decision == WITHIN)
    exceeds = sorted(j for j, c in cands.items() if c.decision == EXCEEDS)
    non_mono = bool(within and exceeds and within[-1] > exceeds[0])
    if lo is None:
        status = "none" if cands[0].decision == EXCEEDS else "undecided"
        return SearchResult(status, None, None, 0, non_mono, cands)
    safe = max((j for j in within if j <= lo), default=None)
    if hi is None and safe == lo:
        status = "capped"
    elif safe is not None and safe + 1 in cands and cands[safe + 1].decision == EXCEEDS:
        status = "decided"
    else:
        status = "undecided"
    return SearchResult(status, safe, lo, hi, non_mono, cands)


class Evaluator:
    """``evaluate(j)`` of a :class:`MaxDelay` with its runner; ``cands`` its candidates."""

    def __init__(self, md, runner):
        self.md, self.runner = md, runner

    @property
    def cands(self) -> dict:
        return self.md.cands

    def __call__(self, j: int):
        return self.md.evaluate(j, self.runner)


def empirical_search(evaluate, J: int) -> SearchResult:
    """:func:`gallop_bisect`, then make sure ``answer + 1`` is evaluated: when it
    turns out *within* (possible when the boundary candidate was undecided),
    the answer moves up and the next one is evaluated, up to the boundary."""
    lo, hi = gallop_bisect(evaluate, J)
    while True:
        res = summarise(evaluate.cands, lo, hi)
        nxt = 0 if res.answer is None else res.answer + 1
        if lo is None or nxt > J or nxt in res.candidates:
            return res
        evaluate(nxt)


def worst_case_scan(evaluate, J: int) -> SearchResult:
    """Deterministic worst case: scan ``0, 1, 2, ...`` up to the first candidate
    that exceeds.  A delay *bound* allows every smaller constant delay too, and
    the fused covariance need not grow with the delay (fusing more correlated
    local estimates can be worse), so the answer is the largest ``j`` with
    every ``j' <= j`` within, not a bisection's boundary."""
    cands = {}
    for j in range(J + 1):
        c = evaluate(j)
        cands[j] = c
        if c.decision == EXCEEDS:
            return SearchResult("none" if j == 0 else "decided", None if j == 0 else j - 1,
                                None if j == 0 else j - 1, j, _decreases(cands), cands)
    return SearchResult("capped", J, J, None, _decreases(cands), cands)


def _decreases(cands: dict) -> bool:
    vals = [cands[j].mean for j in sorted(cands)]
    return any(b < a - 1e-12 * max(abs(a), 1.0) for a, b in zip(vals, vals[1:]))


"""The largest tolerable delay: ``dkfsim maxdelay FILE --tolerance X | --relative R``.

Three answers to "how much delay can this network take before the estimate
gets worse than a tolerance?", side by side:

1. **Empirical** (Monte Carlo, sequential).  The delay axis is ``d_t`` of a
   ``uniform_steps`` latency model (integers ``0, 1, 2, ...``) or, for
   continuous latency models, a scale ``s`` on a grid ``0, ds, 2 ds, ...``
   that multiplies every time parameter of every latency model (see
   :meth:`~dkfsim.components.latency.LatencyParams.scaled_keys`).  A candidate delay is evaluated with Monte Carlo runs
   in batches (run ``r`` uses seed ``derive_seed(seed, r)`` of
   :mod:`dkfsim.experiments.montecarlo`, the same ``r`` at every candidate: common
   random numbers) and stops as soon as the Student-t confidence interval of
   the metric's excess over the tolerance is entirely below 0 (*within*) or
   entirely above (*exceeds*), or when ``--max-runs`` is reached
   (*undecided*).  Candidates are chosen by galloping (0, 1, 2, 4, ...) and
   then bisection, which assumes the metric grows with the delay: few runs far
   from the boundary, more near it.
2. **Deterministic worst case.**  The covariance recursion does not depend on
   the data, only on when information arrives.  With every link at its
   maximum latency (constant ``d_t T``, or the scaled model's supremum) the
   arrival pattern is fixed, so ONE run gives the worst-case covariance
   metric: ``P_fused[c, c]`` (the expected squared error of component c) or
   ``trace(P_fused)``, time-averaged after burn-in.  Same search, one run per
   candidate.
3. **The paper's bound** (Remark ``bound_of_delay``, eq. ``delay_bound``),
   from :mod:`dkfsim.analysis.bounds`, for the covariance tolerance of (2).

Relative tolerance ``--relative R`` means metric(d) <= R * metric(0).  The
zero-delay value is estimated from the same runs (the same seeds, so the same
truth and measurements) and its uncertainty is carried by pairing: per run
``r`` the excess is ``m_d[r] - R * m_0[r]`` and the decision uses the
t-interval of those paired differences.  For the worst case the zero-delay
value is deterministic.

Runs hold the graph fixed (a random topology generator without
``params.seed`` gets the scenario seed, i.e. the graph of the base
scenario) and drop every listed estimator but the one measured (they do not change the anti-delay DKF's
estimates).  The buffer length follows the candidate delay when it is
``auto`` (``d_t d_g + 1``).
"""

from __future__ import annotations

import json
import math
import signal
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from dkfsim.analysis.bounds import paper_bound_for_scenario
from dkfsim.analysis.metrics import default_burn_in, mse_per_component, t_interval
from dkfsim.components.latency import parse_latency
from dkfsim.config.load import load_scenario, scenario_hash
from dkfsim.config.schema import Scenario
from dkfsim.core.errors import DkfsimError
from dkfsim.core.extras import optional, pyplot
from dkfsim.core.folders import staged, write_json
from dkfsim.core.registry import LATENCY_MODELS
from dkfsim.core.resources import Cost, check, repeat
from dkfsim.core.threads import pin_process, single_thread
from dkfsim.engine.driver import Run
from dkfsim.engine.estimate import estimate_run
from dkfsim.engine.results import versions
from dkfsim.experiments.montecarlo import components_of, derive_seed

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

#: Random topology generators; maxdelay pins their seed so the graph is the same in every run.
RANDOM_GENERATORS = ("random_tree", "random_regular", "erdos_renyi")


#: Old metric names: the ``mse`` of one estimate.
MSE_OF = {"fused_mse": "fused", "local_mse": "local"}


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


def covariance_value(arrays, metric: str, comp: int | None, burn: int) -> float:
    """The covariance counterpart of ``metric``: what its expectation is when
    the filter's covariances are the true error covariances (always, here)."""
    if metric == "local_mse":
        P = np.asarray(arrays["P_local"])[burn:]
        d = np.diagonal(P, axis1=2, axis2=3)          # (K, n, nx)
        return float(d.mean(axis=(0, 1)).sum() if comp is None else d[:, :, comp].mean())
    P = np.asarray(arrays["P_fused"])[burn:]
    d = np.diagonal(P, axis1=1, axis2=2)              # (K, nx)
    if metric == "trace_P" or comp is None:
        return float(d.sum(axis=1).mean())
    return float(d[:, comp].mean())


# =========================================================================== delay axis
def _seconds(x: float) -> str:
    """Seconds rounded to whole nanoseconds, as YAML text that round-trips."""
    return repr(round(float(x) * 1e9) / 1e9)


def _const(seconds: float) -> str:
    return f"{{model: constant, value: {_seconds(seconds)}}}"


def _value_at(lat: dict, dotted: str):
    node = lat
    for part in dotted.split("."):
        node = node[part]
    return node


def _scaled_keys(path: str, lat: dict) -> list[str] | None:
    """The dotted keys (under ``path``) a latency scale multiplies, as the model declares
    them (:meth:`~dkfsim.components.latency.LatencyParams.scaled_keys`); None if it cannot
    be scaled."""
    keys = parse_latency(lat).scaled_keys()
    return None if keys is None else [f"{path}.{k}" for k in keys]


def _scale_overrides(path: str, lat: dict, s: float) -> list[str]:
    """Overrides multiplying every time parameter of the latency model at ``path`` by ``s``."""
    keys = parse_latency(lat).scaled_keys()
    if keys is None:
        raise DkfsimError(f"{path}: latency model {lat['model']!r} cannot be scaled")  # excluded by make_axis
    return [f"{path}.{k}={repr(float(_value_at(lat, k)) * s)}" for k in keys]


def _scalable(lat: dict) -> bool:
    return parse_latency(lat).scaled_keys() is not None


def scalable_models() -> list[str]:
    """Latency models a scale can multiply (those declaring ``scale_keys``, or nesting models)."""
    return [e.name for e in LATENCY_MODELS.entries()
            if e.params.scale_keys is not None or e.params.nests_models]


@dataclass
class DelayAxis:
    """How a candidate index ``j`` becomes a scenario: ``--set`` overrides on ``base``.

    ``mode = "d_t"``: ``d_t = j`` on every ``uniform_steps`` latency model
    (and ``links.d_t = j`` when the scenario sets it).  ``mode = "scale"``:
    ``s = j * step``; every time parameter (as each model declares,
    nested models recursively) of every latency *and jitter*
    model is multiplied by ``s``; ``s = 0`` makes them ``constant 0``;
    ``links.d_t``, when set, becomes ``ceil(s * links.d_t)``.  Schedules (a
    factor on the latency over time) are left as they are.

    ``base`` is the scenario with every estimator but the measured one dropped and a random
    topology's seed pinned (so every run has the base scenario's graph).
    """

    mode: str
    step: float
    max_index: int
    base: object                # Scenario
    specs: list                 # [(dotted path, latency dict), ...]: every latency model
    jitters: list               # [(dotted path, latency dict), ...]: every jitter model
    T: float
    T_ns: int
    steps: int
    links_d_t: int | None

    # ------------------------------------------------------------------ values
    def value(self, j: int):
        return int(j) if self.mode == "d_t" else round(j * self.step, 12)

    def label(self, j: int) -> str:
        return f"d_t = {j}" if self.mode == "d_t" else f"s = {self.value(j):g}"

    @property
    def name(self) -> str:
        return "d_t" if self.mode == "d_t" else "latency scale s"

    def _links_d_t(self, j: int) -> list[str]:
        if self.links_d_t is None:
            return []
        if self.mode == "d_t":
            return [f"links.d_t={j}"]
        return [f"links.d_t={self._scaled_d_t(j)}"]

    def _scaled_d_t(self, j: int) -> int:
        return math.ceil(self.value(j) * self.links_d_t - 1e-9)

    # ------------------------------------------------------------------ overrides
    def overrides(self, j: int) -> list[str]:
        """``--set`` overrides that turn ``base`` into candidate ``j``."""
        if self.mode == "d_t":
            return [f"{path}.d_t={j}" for path, _ in self.specs] + self._links_d_t(j)
        s = self.value(j)
        out = []
        for path, lat in self.specs + self.jitters:
            out += [f"{path}={_const(0.0)}"] if s == 0 else _scale_overrides(path, lat, s)
        return out + self._links_d_t(j)

    def _sup(self, lat: dict, s: float) -> float | None:
        """Largest latency (s) of a model scaled by ``s``; ``None`` when unbounded."""
        sup = parse_latency(lat, self.base.base_dir).sup_ns(self.T_ns)
        return None if sup is None else s * sup / 1e9

    def worst_overrides(self, j: int) -> list[str] | None:
        """Every latency (and jitter) at its largest value, constant; ``None``
        when one is unbounded and there is no ``links.d_t`` to stand in."""
        out = []
        for path, lat in self.specs:
            if self.mode == "d_t":
                sup = j * self.T
            else:
                sup = self._sup(lat, self.value(j))
                if sup is None:
                    if self.links_d_t is None:
                        return None
                    sup = self._scaled_d_t(j) * self.T
            out.append(f"{path}={_const(sup)}")
        for path, lat in self.jitters:
            sup = self._sup(lat, 1.0 if self.mode == "d_t" else self.value(j))
            if sup is None:
                return None
            out.append(f"{path}={_const(sup)}")
        return out + self._links_d_t(j)

    def limit_overrides(self) -> list[str]:
        """No information ever arrives within the run (latency ``(K + 1) T``;
        a buffer of one row: nothing could fill a longer one)."""
        v = _const((self.steps + 1) * self.T)
        return [f"{path}={v}" for path, _ in self.specs] + \
            [f"{path}={_const(0.0)}" for path, _ in self.jitters] + ["buffer_length=1"]

    def scenario(self, j: int, overrides: list[str] | None = None):
            return load_scenario(self.base, overrides=self.overrides(j) if overrides is None else overrides)

    def describe(self) -> dict:
        if self.mode == "d_t":
            keys = [f"{path}.d_t" for path, _ in self.specs]
        else:
            keys = [k for path, lat in self.specs + self.jitters for k in _scaled_keys(path, lat)]
        if self.links_d_t is not None:
            keys.append("links.d_t" + ("" if self.mode == "d_t" else " (ceil(s * links.d_t))"))
        return {"mode": self.mode, "name": self.name, "step": self.step,
                "max": self.value(self.max_index), "keys": keys,
                "untouched": "schedules (time-varying factors) stay as they are" +
                             ("; jitter models stay as they are" if self.mode == "d_t" and self.jitters
                              else "")}


def make_axis(scenario, *, max_delay: int, scale_step: float, max_scale: float,
              keep: str | None = None) -> DelayAxis:
    """The delay axis of ``scenario`` (raises DkfsimError when it has none).  The base
    scenario keeps only the estimator named ``keep`` (the searched one, if listed)."""
    data = scenario.to_dict()
    kept = [e for e in data.get("estimators", []) if (e.get("name") or e["kind"]) == keep]
    pin = ["estimators=" + json.dumps(kept)]
    top = data.get("topology", {})
    if top.get("generator") in RANDOM_GENERATORS and "seed" not in (top.get("params") or {}):
        pin.append(f"topology.params.seed={int(scenario.seed)}")
    base = load_scenario(scenario, overrides=pin)
    links = data.get("links", {})
    default = links.get("default", {})
    specs = [("links.default.latency", default.get("latency", {"model": "constant", "value": 0.0}))]
    jitters = [("links.default.jitter", default["jitter"])] if default.get("jitter") else []
    for i, ov in enumerate(links.get("overrides", []) or []):
        if ov.get("latency") is not None:
            specs.append((f"links.overrides.{i}.latency", ov["latency"]))
        if ov.get("jitter") is not None:
            jitters.append((f"links.overrides.{i}.jitter", ov["jitter"]))
    models = {lat["model"] for _, lat in specs}
    where = ", ".join(f"{p} = {lat['model']}" for p, lat in specs)
    for path, lat in specs:
        if lat["model"] != "uniform_steps" and not _scalable(lat):
            raise DkfsimError(
                f"{path}: latency model {lat['model']!r} is neither uniform_steps (whose d_t maxdelay "
                f"searches) nor scalable ({', '.join(scalable_models())}: maxdelay "
                "multiplies their time parameters by a scale s); use one of those models")
    if "uniform_steps" in models and len(models) > 1:
        raise DkfsimError(
            f"the latency models mix uniform_steps (integer steps, searched over d_t) with continuous "
            f"ones (searched over a scale) ({where}); maxdelay moves one delay axis: make every latency "
            "model uniform_steps, or every one continuous")
    mode = "d_t" if models == {"uniform_steps"} else "scale"
    if mode == "scale":
        for path, lat in jitters:
            if not _scalable(lat):
                raise DkfsimError(f"{path}: jitter model {lat['model']!r} cannot be scaled; use one of "
                                  f"{', '.join(scalable_models())}")
    if mode == "d_t":
        if max_delay < 1:
            raise DkfsimError(f"--max-delay: must be >= 1, got {max_delay}")
        J, step = int(max_delay), 1.0
    else:
        if not scale_step > 0 or not math.isfinite(scale_step):
            raise DkfsimError(f"--scale-step: must be a finite number > 0, got {scale_step}")
        if not (max_scale >= scale_step and math.isfinite(max_scale)):
            raise DkfsimError(f"--max-scale: must be a finite number >= --scale-step ({scale_step}), "
                              f"got {max_scale}")
        J, step = int(math.floor(max_scale / scale_step + 1e-9)), float(scale_step)
    return DelayAxis(mode=mode, step=step, max_index=J, base=base, specs=specs, jitters=jitters,
                     T=float(scenario.model.T), T_ns=int(scenario.T_ns), steps=int(scenario.steps),
                     links_d_t=links.get("d_t"))


def latencies_deterministic(sc) -> bool:
    """True when no random draw can change any covariance of a run of ``sc``:
    every used link has a constant latency (and jitter), no loss and no
    duplicates, and every sensor is linear (its information does not depend
    on its measurement)."""
    if any(s.kind != "linear" for s in sc.sensors):
        return False
    for u, v in sc.exchange().arcs:
        spec = sc.link_spec(u, v)
        if spec.loss > 0 or (getattr(spec, "duplicate", 0.0) or 0.0) > 0:
            return False
        for lat in (spec.latency, getattr(spec, "jitter", None)):
            if lat is not None and not lat.deterministic:
                return False
    return True


# =========================================================================== runs
def _simulate(base, overrides: list, seed: int | None, metric: str, comp, burn: int,
              covariance: bool = False, estimate: str = "fused") -> float:
    ov = list(overrides) + ([] if seed is None else [f"seed={int(seed)}"])
    sc = load_scenario(base, overrides=ov)
    res = Run(sc, save="estimates").run()
    if covariance:
        return covariance_value(res.arrays, metric, comp, burn)
    return metric_value(res.arrays, metric, comp, burn, estimate)


def _init_worker() -> None:
    pin_process()                     # one BLAS thread: the parallelism is the processes
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _task(args):
    return _simulate(*args)


class Runner:
    """Runs simulations here or on ``jobs`` worker processes; counts them."""

    def __init__(self, jobs: int = 1, on_run=None):
        self.jobs = jobs
        self.pool = None
        self.runs = 0
        self.on_run = on_run

    def __enter__(self):
        if self.jobs > 1:
            self.pool = ProcessPoolExecutor(max_workers=self.jobs, initializer=_init_worker)
        return self

    def __exit__(self, exc_type, exc, tb):
        if self.pool is not None:
            if exc_type is not None:
                procs = list((getattr(self.pool, "_processes", None) or {}).values())
                self.pool.shutdown(wait=False, cancel_futures=True)
                for p in procs:
                    if p.is_alive():
                        p.terminate()
            else:
                self.pool.shutdown(wait=True)
        return False

    def map(self, tasks: list[tuple]) -> list[float]:
        if not tasks:
            return []
        if self.pool is None:
            out = []
            for t in tasks:
                out.append(_simulate(*t))
                self._count(1)
            return out
        out = list(self.pool.map(_task, tasks))
        self._count(len(tasks))
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
                "decision": self.decision, "mean": _num(self.mean), "ci": [_num(v) for v in self.ci],
                "excess_mean": _num(self.excess_mean), "excess_ci": [_num(v) for v in self.excess_ci],
                "values": [_num(v) for v in self.values]}


def _num(v):
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


class _Evaluator:
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


# =========================================================================== the command's engine
@dataclass
class Settings:
    metric: str = "fused_mse"
    estimate: str = "fused"            # the estimate whose mse the Monte Carlo search tracks (metric mse)
    component: str | int | None = None  # a name, an index, "all"; None = the first component
    tolerance: float | None = None     # absolute
    relative: float | None = None      # relative to zero delay
    confidence: float = 0.95
    batch: int = 5
    max_runs: int = 40
    burn_in: int | None = None
    jobs: int = 1
    max_delay: int = 32
    scale_step: float = 0.25
    max_scale: float = 16.0


def check_settings(st: Settings) -> None:
    if st.metric not in METRICS:
        raise DkfsimError(f"--metric: unknown metric {st.metric!r}; choose one of {', '.join(METRICS)}")
    if (st.tolerance is None) == (st.relative is None):
        raise DkfsimError("give exactly one of --tolerance (absolute) and --relative (a factor of the "
                          "zero-delay value)")
    if st.tolerance is not None and not (st.tolerance > 0 and math.isfinite(st.tolerance)):
        raise DkfsimError(f"--tolerance: must be a finite number > 0, got {st.tolerance}")
    if st.relative is not None and not (st.relative > 1 and math.isfinite(st.relative)):
        raise DkfsimError(f"--relative: must be a finite factor > 1 (metric <= factor x its zero-delay "
                          f"value), got {st.relative}")
    if not 0 < st.confidence < 1:
        raise DkfsimError(f"--confidence: must be in (0, 1), got {st.confidence}")
    if st.batch < 2:
        raise DkfsimError(f"--batch: must be >= 2 (a confidence interval needs two runs), got {st.batch}")
    if st.max_runs < st.batch:
        raise DkfsimError(f"--max-runs: must be >= --batch ({st.batch}), got {st.max_runs}")
    if st.jobs < 1:
        raise DkfsimError(f"--jobs: must be >= 1, got {st.jobs}")
    for flag, value in (("--batch", st.batch), ("--max-runs", st.max_runs), ("--max-delay", st.max_delay)):
        if value > 10**9:
            raise DkfsimError(f"{flag}: at most 10^9, got {value}")


def resolve_component(scenario, metric: str, text) -> tuple[int | None, str]:
    """``--component`` (a name, an index or ``all``) -> (index or None, name)."""
    names = components_of(scenario)
    if metric == "trace_P":
        return None, "all"
    if text is None:
        return 0, names[0]
    t = str(text)
    if t == "all":
        return None, "all"
    if t in names:
        return names.index(t), t
    if t.lstrip("-").isdigit() and 0 <= int(t) < len(names):
        return int(t), names[int(t)]
    raise DkfsimError(f"--component: unknown component {t!r}; choose one of {', '.join(names)}, "
                      f"an index 0..{len(names) - 1}, or all")


class MaxDelay:
    """Runs the three answers for one scenario (see the module docstring)."""

    def __init__(self, scenario, settings: Settings, progress=None, yes: bool = False):
        check_settings(settings)
        self.sc = scenario
        self.st = settings
        if settings.metric == "mse" and settings.estimate not in ("fused", "local") \
                and settings.estimate not in {p.label for p in scenario.estimators}:
            raise DkfsimError(f"--estimate {settings.estimate!r}: not an estimate of this scenario; "
                              "choose fused, local or one of its estimators: "
                              + ", ".join(p.label for p in scenario.estimators))
        if (settings.metric in FUSED_METRICS or (settings.metric == "mse" and settings.estimate == "fused")) \
                and scenario.fusion == "none":
            raise DkfsimError(f"--metric {settings.metric}: the scenario has fusion: none, so there is "
                              "no fused estimate; set fusion: matrix (or diagonal) or use --metric local_mse")
        K = int(scenario.steps)
        self.burn = default_burn_in(K) if settings.burn_in is None else int(settings.burn_in)
        if not 0 <= self.burn < K:
            raise DkfsimError(f"--burn-in: must be in [0, steps) = [0, {K}), got {settings.burn_in}")
        self.comp, self.comp_name = resolve_component(scenario, settings.metric, settings.component)
        self.axis = make_axis(scenario, max_delay=settings.max_delay, scale_step=settings.scale_step,
                              max_scale=settings.max_scale,
                              keep=settings.estimate if settings.metric == "mse" else None)
        check(self.estimate(), yes=yes, hint="a larger --scale-step, a smaller --max-scale or "
                                             "--max-delay, fewer --max-runs or --steps")
        self.seeds = [derive_seed(int(scenario.seed), r) for r in range(settings.max_runs)]
        self.progress = progress or (lambda *a, **k: None)
        self.notes: list[str] = []
        if scenario.buffer_length != "auto":
            self.notes.append(f"buffer_length is {scenario.buffer_length!r}, not auto: it does not follow "
                              "the candidate delay")
        self.cands: dict[int, Candidate] = {}
        self.ref: list[float] = []                  # zero-delay values by run (relative)
        self.wc: dict[int, Candidate] = {}
        self._order = 0
        self._scen_cache: dict[int, tuple] = {}

    def estimate(self) -> Cost:
        """Memory and time of the search at its worst: every look at every candidate the
        galloping and bisection can visit, and the worst-case scan over the whole axis."""
        J, st = self.axis.max_index, self.st
        looks = 2 * math.ceil(math.log2(J + 2)) + 3
        runs = looks * st.max_runs + (J + 3)
        one = estimate_run(self.axis.base, "estimates")
        return repeat(one, f"{self.sc.name}: maxdelay over {J + 1} candidates ({self.axis.name})",
                      runs, st.jobs, extra_bytes=(J + 1) * 2048)

    # ------------------------------------------------------------------ helpers
    def _candidate_scenario(self, j: int):
        """``(overrides, deterministic)`` of candidate ``j`` (validated once)."""
        if j not in self._scen_cache:
            ov = self.axis.overrides(j)
            try:
                sc = self.axis.scenario(j, ov)
            except DkfsimError as exc:
                raise DkfsimError(f"candidate {self.axis.label(j)}: the rewritten scenario is invalid: "
                                  f"{exc}") from None
            det = self.st.metric in COVARIANCE_METRICS and latencies_deterministic(sc)
            self._scen_cache[j] = (ov, det)
        return self._scen_cache[j]

    def _tasks(self, ov, runs, covariance=False):
        return [(self.axis.base, ov, self.seeds[r], self.st.metric, self.comp, self.burn, covariance,
                 self.st.estimate) for r in runs]

    def _reference(self, upto: int, runner: Runner) -> list[float]:
        """Zero-delay values of runs ``0 .. upto-1`` (cached; the pairs of relative mode)."""
        if len(self.ref) < upto:
            data, det = self._candidate_scenario(0)
            if det:
                if not self.ref:
                    self.ref = runner.map(self._tasks(data, [0]))
                self.ref = self.ref + [self.ref[0]] * (upto - len(self.ref))
            else:
                self.ref += runner.map(self._tasks(data, range(len(self.ref), upto)))
        return self.ref[:upto]

    # ------------------------------------------------------------------ empirical
    def evaluate(self, j: int, runner: Runner) -> Candidate:
        if j in self.cands:
            return self.cands[j]
        st = self.st
        data, det = self._candidate_scenario(j)
        det_ref = det and (st.relative is None or self._candidate_scenario(0)[1])
        c = Candidate(index=j, delay=self.axis.value(j), deterministic=det_ref)
        self._order += 1
        c.order = self._order
        self.progress(label=self.axis.label(j))
        while True:
            n0 = c.runs
            n1 = 1 if c.deterministic else min(n0 + st.batch, st.max_runs)
            if j == 0 and st.relative is not None:
                new = self._reference(n1, runner)[n0:n1]
            else:
                new = runner.map(self._tasks(data, range(n0, n1)))
            c.values += new
            if st.relative is None:
                c.excess = [v - st.tolerance for v in c.values]
            else:
                ref = self._reference(n1, runner)
                c.excess = [v - st.relative * m0 for v, m0 in zip(c.values, ref)]
            classify(c, st.confidence)
            if c.decision != UNDECIDED or c.deterministic or c.runs >= st.max_runs:
                break
        self.cands[j] = c
        self.progress(done=c, label=self.axis.label(j))
        return c

    # ------------------------------------------------------------------ worst case
    def worst_value(self, ov: list, runner: Runner) -> float:
        """The covariance metric of ONE run with overrides ``ov`` (no seed: nothing random)."""
        return runner.map([(self.axis.base, ov, None, self.st.metric, self.comp, self.burn, True)])[0]

    def evaluate_worst(self, j: int, runner: Runner, tol: float, value: float | None = None):
        if j in self.wc:
            return self.wc[j]
        ov = self.axis.worst_overrides(j)
        if ov is None:
            return None
        v = self.worst_value(ov, runner) if value is None else value
        c = Candidate(index=j, delay=self.axis.value(j), deterministic=True, values=[v],
                      excess=[v - tol])
        self._order += 1
        c.order = self._order
        classify(c, self.st.confidence)
        self.wc[j] = c
        return c

    # ------------------------------------------------------------------ everything
    @single_thread
    def run(self) -> "MaxDelayResult":
        t0 = time.perf_counter()
        st, J = self.st, self.axis.max_index
        with Runner(st.jobs, on_run=lambda k: self.progress(runs=k)) as runner:
            # 1. empirical
            emp = empirical_search(_Evaluator(self, runner), J)
            runs_empirical = runner.runs
            # 2. deterministic worst case
            self.progress(label="worst case")
            wc_data0 = self.axis.worst_overrides(0)
            wc = None
            wc_tol = None
            limit = None
            if wc_data0 is not None:
                ref0 = self.worst_value(wc_data0, runner)
                wc_tol = st.tolerance if st.relative is None else st.relative * ref0
                self.evaluate_worst(0, runner, wc_tol, value=ref0)
                wc = worst_case_scan(lambda j: self.evaluate_worst(j, runner, wc_tol), J)
                limit = self.worst_value(self.axis.limit_overrides(), runner)
            else:
                self.notes.append("worst case not computed: a latency (or jitter) model is unbounded "
                                  "and links.d_t is not set, so there is no largest latency")
            runs_total = runner.runs
        # 3. the paper's bound
        paper = self._paper_bound(wc_tol if wc_tol is not None else st.tolerance)
        wall = time.perf_counter() - t0
        return MaxDelayResult(self, emp, wc, wc_tol, limit, paper, runs_empirical, runs_total, wall)

    def _paper_bound(self, cov_tol):
        if cov_tol is None:
            return {"error": "no covariance tolerance (relative tolerance without a worst case)"}
        nx = self.sc.nx
        per_lambda = self.st.metric == "trace_P" or self.comp is None
        p_tol = cov_tol / nx if per_lambda else cov_tol
        try:
            b = paper_bound_for_scenario(self.sc, p_tol)
        except ValueError as exc:
            return {"error": str(exc)}
        d = b.terms()
        d["covariance_tolerance"] = cov_tol
        d["p_tol_rule"] = ("lambda_max(P) <= tol / nx guarantees trace(P) <= tol" if per_lambda else
                           "lambda_max(P) <= tol guarantees P[c, c] <= tol")
        d["log10_lambda_max_bound"] = {str(k): b.log10_lambda_max_bound(k) for k in range(0, 9)}
        d["d_star_in_axis_units"] = None
        if b.d_star is not None and math.isfinite(b.d_star):
            if self.axis.mode == "d_t":
                d["d_star_in_axis_units"] = b.d_star
            else:
                sup0 = self._sup_at_scale_one()
                if sup0:
                    d["d_star_in_axis_units"] = b.d_star * self.axis.T / sup0
        d["_object"] = b
        return d

    def _sup_at_scale_one(self) -> float | None:
        """Largest per-hop delay (s) at scale 1: latency sup plus jitter sup."""
        ax = self.axis
        lat = [ax._sup(l, 1.0) for _, l in ax.specs]
        jit = [ax._sup(l, 1.0) for _, l in ax.jitters]
        if any(v is None for v in jit):
            return None
        if any(v is None for v in lat):
            if ax.links_d_t is None:
                return None
            lat = [ax.links_d_t * ax.T]
        total = max(lat) + (max(jit) if jit else 0.0)
        return total if total > 0 else None


# =========================================================================== result
def maxdelay(scenario, progress=None, yes: bool = False, **settings) -> "MaxDelayResult":
    """The maximum allowable delay of ``scenario`` (a Scenario, a path or a mapping).

    ``settings`` are the fields of :class:`Settings` (the ``dkfsim maxdelay``
    flags: ``relative=1.5`` or ``tolerance=...``, ``metric``, ``jobs``, ...).
    A search estimated above 10 minutes needs ``yes`` (:mod:`dkfsim.core.resources`).
    """
    sc = scenario if isinstance(scenario, Scenario) else load_scenario(scenario)
    unknown = sorted(set(settings) - set(Settings.__dataclass_fields__))
    if unknown:
        raise DkfsimError(f"maxdelay: unknown setting {unknown[0]!r}; known: "
                          + ", ".join(Settings.__dataclass_fields__))
    return MaxDelay(sc, Settings(**settings), progress=progress, yes=yes).run()


class MaxDelayResult:
    def __init__(self, md: MaxDelay, emp: SearchResult, wc: SearchResult | None, wc_tol, limit,
                 paper: dict, runs_empirical: int, runs_total: int, wall: float):
        self.md, self.emp, self.wc, self.wc_tol, self.limit = md, emp, wc, wc_tol, limit
        self.paper, self.runs_empirical, self.runs_total, self.wall = paper, runs_empirical, runs_total, wall
        st = md.st
        self.reference = None
        if st.relative is not None and md.ref:
            det = md._candidate_scenario(0)[1]
            m, ci = interval(md.ref[:1] if det else md.ref, st.confidence)
            self.reference = {"runs": 1 if det else len(md.ref), "deterministic": det,
                              "mean": m, "ci": list(ci),
                              "tolerance": st.relative * m,
                              "tolerance_ci": [st.relative * ci[0], st.relative * ci[1]]}

    @property
    def answer(self):
        a = self.emp.answer
        return None if a is None else self.md.axis.value(a)

    def _search_dict(self, res: SearchResult | None, cands: dict) -> dict | None:
        if res is None:
            return None
        ax = self.md.axis

        def at(j):
            if j is None or j not in cands:
                return None
            c = cands[j]
            return {"delay": c.delay, "runs": c.runs, "mean": _num(c.mean), "ci": [_num(v) for v in c.ci],
                    "excess_ci": [_num(v) for v in c.excess_ci], "decision": c.decision}
        return {
            "status": res.status,
            "answer": None if res.answer is None else ax.value(res.answer),
            "point_estimate": None if res.point is None else ax.value(res.point),
            "first_exceeding": None if res.first_exceeding is None else ax.value(res.first_exceeding),
            "non_monotone": res.non_monotone,
            "at_answer": at(res.answer),
            "at_answer_plus_1": at(None if res.answer is None else res.answer + 1),
            "candidates": [c.to_dict() for c in sorted(cands.values(), key=lambda c: c.index)],
        }

    def to_dict(self) -> dict:
        md, st, sc = self.md, self.md.st, self.md.sc
        paper = {k: v for k, v in self.paper.items() if k != "_object"}
        return {
            "scenario": sc.name, "source": sc.source, "scenario_hash": scenario_hash(sc),
            "steps": sc.steps, "base_seed": sc.seed,
            "seed_rule": "run r uses dkfsim.experiments.montecarlo.derive_seed(base_seed, r) at every candidate "
                         "(common random numbers)",
            "axis": md.axis.describe(),
            "metric": {"name": st.metric, "description": METRICS[st.metric],
                       "component": md.comp_name, "burn_in": md.burn},
            "tolerance": {"kind": "absolute" if st.relative is None else "relative",
                          "value": st.tolerance, "relative": st.relative, "reference": self.reference,
                          "rule": ("per run: metric - tolerance" if st.relative is None else
                                   "per run r: metric_d[r] - relative * metric_0[r] (paired, same seeds)")},
            "confidence": st.confidence, "batch": st.batch, "max_runs": st.max_runs,
            "empirical": {**self._search_dict(self.emp, md.cands), "runs": self.runs_empirical},
            "worst_case": None if self.wc is None else {
                **self._search_dict(self.wc, md.wc),
                "metric": "covariance counterpart: " + ("trace(P)" if st.metric == "trace_P" or
                                                         md.comp is None else
                                                         f"P[{md.comp_name}]") +
                          (" of the node estimates, mean over nodes" if st.metric == "local_mse" else
                           " of the fused estimate"),
                "tolerance": self.wc_tol,
                "no_exchange_limit": self.limit,
                "never_exceeds": None if self.limit is None or self.wc_tol is None else
                bool(self.limit <= self.wc_tol)},
            "paper_bound": paper,
            "runs_total": self.runs_total,
            "notes": md.notes + self._notes(),
            "wall_time_s": self.wall,
            "versions": versions(),
        }

    def _notes(self) -> list[str]:
        out = []
        if self.emp.non_monotone:
            out.append("empirical: a delay decided within lies above one decided exceeding: the metric "
                       "is not monotone in the delay here, and the bisection's answer is not the "
                       "largest delay with the property")
        if self.wc is not None and self.wc.non_monotone:
            out.append("worst case: the covariance metric decreases somewhere along the delay axis "
                       "(optimal fusion of local estimates that share stale information can be worse "
                       "than of less correlated ones); the worst-case answer is the largest delay with "
                       "every smaller one within (a scan), so it accounts for that")
        if self.limit is not None and self.wc_tol is not None and self.limit <= self.wc_tol:
            out.append(f"even with no exchange at all within the run the covariance metric is "
                       f"{self.limit:.4g} <= {self.wc_tol:.4g}: no delay can break this tolerance")
        return out

    def save(self, out_dir) -> Path:
        """Write ``maxdelay.json`` and the figure; the folder is replaced atomically."""
        data = self.to_dict()
        with staged(out_dir, "maxdelay") as tmp:
            write_json(tmp / "maxdelay.json", data)
            self.plot(tmp)
        return Path(out_dir)

    # ------------------------------------------------------------------ text
    def table(self) -> str:
        md, st, ax = self.md, self.md.st, self.md.axis
        d = self.to_dict()
        unit = "d_t" if ax.mode == "d_t" else "s"
        tol = (f"<= {st.tolerance:g}" if st.relative is None else
               f"<= {st.relative:g} x zero-delay value")
        lines = [f"{md.sc.name}: largest {ax.name} with {st.metric}"
                 f"{'' if st.metric == 'trace_P' else ' (' + md.comp_name + ')'} {tol}, "
                 f"{100 * st.confidence:g}% confidence, {md.sc.steps} ticks, burn-in {md.burn}"]
        if self.reference:
            r = self.reference
            how = "deterministic" if r["deterministic"] else f"{r['runs']} runs"
            lines.append(f"  zero-delay value {r['mean']:.4g} [{r['ci'][0]:.4g}, {r['ci'][1]:.4g}] "
                         f"({how}) -> tolerance {r['tolerance']:.4g}")
        e = d["empirical"]
        lines.append(f"  (1) empirical:   {_answer_text(e, unit)}  ({self.runs_empirical} runs)")
        for key, what in (("at_answer", "at answer"), ("at_answer_plus_1", "at answer+1")):
            a = e[key]
            if a:
                lines.append(f"        {what:12s} {unit} = {a['delay']:g}: mean {a['mean']:.4g} "
                             f"CI [{a['ci'][0]:.4g}, {a['ci'][1]:.4g}]; excess over tolerance CI "
                             f"[{a['excess_ci'][0]:+.3g}, {a['excess_ci'][1]:+.3g}]; {a['runs']} runs, "
                             f"{a['decision']}")
        w = d["worst_case"]
        if w is None:
            lines.append("  (2) worst case:  not computed (unbounded latency without links.d_t)")
        else:
            lines.append(f"  (2) worst case:  {_answer_text(w, unit)}  (every link at its largest "
                         f"latency; tolerance {w['tolerance']:.4g}; no-exchange limit "
                         f"{w['no_exchange_limit']:.4g})")
        p = d["paper_bound"]
        if "error" in p:
            lines.append(f"  (3) paper bound: not computed: {p['error']}")
        else:
            ds = p["d_star"]
            lines.append(
                f"  (3) paper bound: d* = {_fmt(ds)} -> "
                f"{'d_t <= %d' % p['d_t_bound'] if p['meaningful'] else 'MEANINGLESS (no delay guaranteed)'}; "
                f"terms: n = {p['n']}, "
                f"n_bar = {p['n_bar']}, Z = {p['Z']}, alpha_bar = {p['alpha_used']:.4g}, "
                f"eta = {p['eta']:.6g}, gamma_hat = {p['gamma_hat']:.4g}, omega_min = {p['omega_min']:.4g} "
                f"(literal {p['omega_min_literal']:.4g}), p_tol = {p['p_tol']:.4g}")
            lines.append(f"        guaranteed lambda_max(P) <= 10^{p['log10_lambda_max_bound']['0']:.3g} at "
                         f"d_t = 0, 10^{p['log10_lambda_max_bound']['1']:.3g} at d_t = 1, "
                         f"10^{p['log10_lambda_max_bound']['4']:.3g} at d_t = 4")
            if p["note"]:
                lines.append(f"        {p['note']}")
        for n in d["notes"]:
            lines.append(f"  note: {n}")
        lines.append(f"  {self.runs_total} runs in {self.wall:.1f} s")
        return "\n".join(lines)

    # ------------------------------------------------------------------ plot
    def plot(self, out: Path) -> None:
        """``maxdelay.png`` / ``.pdf``: the metric against the delay (top) and the
        excess over the tolerance that the decisions use (bottom)."""
        plt = pyplot()
        MaxNLocator = optional("matplotlib.ticker").MaxNLocator
        md, st, ax = self.md, self.md.st, self.md.axis
        fig, (top, bot) = plt.subplots(2, 1, figsize=(10, 7), sharex=True,
                                       gridspec_kw={"height_ratios": [3, 2]})
        cs = sorted(md.cands.values(), key=lambda c: c.index)
        x = np.array([c.delay for c in cs], float)
        colours = {WITHIN: "C2", EXCEEDS: "C3", UNDECIDED: "0.5"}
        # -- top: the metric
        top.fill_between(x, [c.ci[0] for c in cs], [c.ci[1] for c in cs], color="C0", alpha=0.25, lw=0,
                         label=f"{100 * st.confidence:g}% confidence band (Monte Carlo)")
        top.plot(x, [c.mean for c in cs], "-", color="C0", lw=1.2, label=f"{st.metric}, Monte Carlo mean")
        for c in cs:
            top.plot([c.delay], [c.mean], "o", color=colours[c.decision], ms=5, zorder=5)
            top.annotate(str(c.runs), (c.delay, c.ci[1] if math.isfinite(c.ci[1]) else c.mean),
                         textcoords="offset points", xytext=(0, 3), ha="center", fontsize=7, color="0.3")
        for dec, col in colours.items():
            top.plot([], [], "o", color=col, ms=5,
                     label={WITHIN: "decided within", EXCEEDS: "decided exceeds",
                            UNDECIDED: "undecided (run cap)"}[dec])
        if st.relative is None:
            top.axhline(st.tolerance, color="k", ls="--", lw=1, label=f"tolerance {st.tolerance:g}")
        elif self.reference:
            r = self.reference
            top.axhline(r["tolerance"], color="k", ls="--", lw=1,
                        label=f"tolerance {st.relative:g} x zero-delay mean")
            top.axhspan(*r["tolerance_ci"], color="k", alpha=0.08, lw=0,
                        label=f"{st.relative:g} x its confidence interval")
        if self.emp.answer is not None:
            top.axvline(ax.value(self.emp.answer), color="C0", ls=":", lw=2,
                        label=f"empirical answer {ax.value(self.emp.answer):g} ({self.emp.status})")
        ws = sorted(md.wc.values(), key=lambda c: c.index)
        if ws:
            top.plot([c.delay for c in ws], [c.mean for c in ws], "s-", color="C1", ms=3.5, lw=1,
                     label="worst case: every link at its largest latency (covariance)")
            if st.relative is not None and self.wc_tol is not None:
                top.axhline(self.wc_tol, color="C1", ls="--", lw=0.8, label="worst-case tolerance")
            if self.limit is not None:
                top.axhline(self.limit, color="C1", ls=(0, (1, 3)), lw=1,
                            label="worst case with no exchange at all")
            if self.wc is not None and self.wc.answer is not None:
                top.axvline(ax.value(self.wc.answer), color="C1", ls=":", lw=2,
                            label=f"worst-case answer {ax.value(self.wc.answer):g} ({self.wc.status})")
        p = self.paper
        if "error" not in p:
            dax = p.get("d_star_in_axis_units")
            if p["meaningful"] and dax is not None:
                top.axvline(dax, color="C4", ls="-.", lw=1.5, label=f"paper bound {dax:.3g}")
            txt = (f"paper bound, eq. (delay_bound): d_t <= {_fmt(p['d_star'])}"
                   + ("" if p["meaningful"] else " (meaningless)") +
                   f"\nit guarantees lambda_max(P) <= 10^{p['log10_lambda_max_bound']['0']:.3g} at d_t = 0, "
                   f"10^{p['log10_lambda_max_bound']['1']:.3g} at d_t = 1")
            top.text(0.01, 0.98, txt, transform=top.transAxes, va="top", fontsize=7.5, color="C4",
                     bbox=dict(boxstyle="round", fc="white", ec="C4", alpha=0.85))
        top.set_ylabel(st.metric if st.metric == "trace_P" else f"{st.metric} ({md.comp_name})")
        top.set_title(f"{md.sc.name}: largest {ax.name} within tolerance", fontsize=10)
        top.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0)
        top.grid(alpha=0.3)
        # -- bottom: what the decisions use
        for c in cs:
            lo, hi = c.excess_ci
            top_err = [[c.excess_mean - lo], [hi - c.excess_mean]] if math.isfinite(lo) else None
            bot.errorbar([c.delay], [c.excess_mean], yerr=top_err, fmt="o", color=colours[c.decision],
                         ms=4, capsize=3)
        if ws and self.wc_tol is not None:
            bot.plot([c.delay for c in ws], [c.mean - self.wc_tol for c in ws], "s-", color="C1", ms=3,
                     lw=0.8, label="worst case minus its tolerance")
        bot.axhline(0.0, color="k", lw=1)
        bot.plot([], [], "o", color="0.3", label="Monte Carlo: mean and CI of " +
                 ("metric - tolerance" if st.relative is None else
                  f"metric_d[r] - {st.relative:g} metric_0[r] (paired runs)"))
        bot.set_ylabel("excess over tolerance")
        bot.set_xlabel(ax.name)
        bot.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0)
        bot.grid(alpha=0.3)
        if ax.mode == "d_t":
            bot.xaxis.set_major_locator(MaxNLocator(integer=True))
        fig.tight_layout()
        for ext in ("png", "pdf"):
            fig.savefig(out / f"maxdelay.{ext}", dpi=150)
        plt.close(fig)


def _fmt(v) -> str:
    if v is None:
        return "n/a"
    if isinstance(v, float) and math.isinf(v):
        return "-inf" if v < 0 else "inf"
    return f"{v:.4g}"


def _answer_text(e: dict, unit: str) -> str:
    s = e["status"]
    if s == "decided":
        return f"{unit} = {e['answer']:g} (decided: {unit} = {e['first_exceeding']:g} exceeds)"
    if s == "capped":
        return f"{unit} >= {e['answer']:g} (within up to the largest candidate; raise the cap)"
    if s == "none":
        return "none: even zero delay exceeds the tolerance"
    a = "none" if e["answer"] is None else f"{e['answer']:g}"
    pe = "n/a" if e["point_estimate"] is None else f"{e['point_estimate']:g}"
    return f"{unit} = {a} (undecided: run cap hit near the boundary; by the means {pe})"

"""The engine of ``dkfsim maxdelay``: settings, the three answers for one scenario.

:class:`MaxDelay` runs the Monte Carlo search, the deterministic worst case and the
paper's bound; :func:`maxdelay` is the library entry point.  See
:mod:`dkfsim.experiments.maxdelay` and docs/design.md.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from dkfsim.analysis.bounds import paper_bound_for_scenario
from dkfsim.analysis.metrics import default_burn_in
from dkfsim.config.plan import RunPlan
from dkfsim.config.schema import named
from dkfsim.core.errors import DkfsimError
from dkfsim.core.resources import EVENT_KINDS, Cost, check, many_runs_memory_hint
from dkfsim.core.threads import single_thread
from dkfsim.engine.driver import trial, trial_estimate
from dkfsim.engine.estimate import TRIAL_ABOVE_S, estimate_run, smaller_run_hint, trial_is_short
from dkfsim.experiments import executors
from dkfsim.experiments.maxdelay.axis import DelayAxis, latencies_deterministic, make_axis
from dkfsim.experiments.maxdelay.rate import RateAxis, make_rate_axis, parse_link, rate_lower_bound
from dkfsim.experiments.maxdelay.report import MaxDelayResult
from dkfsim.experiments.maxdelay.search import (
    COVARIANCE_METRICS,
    EXCEEDS,
    FUSED_METRICS,
    METRICS,
    UNDECIDED,
    WITHIN,
    Candidate,
    Evaluator,
    Runner,
    classify,
    empirical_search,
    gallop_bisect,
    metric_value,
    of_the_dkf,
    tracked_estimate,
    worst_case_scan,
)
from dkfsim.experiments.montecarlo import components_of, derive_seed, with_keywords


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
    jobs: int | None = None            # local processes; None = every available CPU
    max_delay: int = 32
    scale_step: float = 0.25
    max_scale: float = 16.0
    axis: str = "delay"                # "delay" or "rate" (the least rate within the tolerance)
    link: str | tuple | None = None    # rate axis: "U,V", one link's rate (None: every link)
    max_rate: float = 1e9              # rate axis: the fastest limited candidate (bit/s)
    min_rate: float = 1e4              # ... the slowest
    rate_step: float = 1.25            # ... the factor between two candidates

#: The axes of ``--axis``.
AXES = ("delay", "rate")
#: Axes longer than this are not enumerated to estimate the search: its cost is bounded below
#: by the candidates' bookkeeping and one run each (the worst-case scan), which is refused.
MAX_ENUMERATED = 10**6


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
    executors.check_jobs(st.jobs)
    if st.axis not in AXES:
        raise DkfsimError(f"--axis: unknown axis {st.axis!r}; choose delay (the largest delay) or rate "
                          "(the least link rate)")
    if st.link is not None:
        if st.axis != "rate":
            raise DkfsimError("--link: names the link whose rate --axis rate searches; add --axis rate")
        parse_link(st.link)
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


def _option_name(flags: bool) -> Callable[[str], str]:
    """How a hint names an option: as the command line's flag (``--max-delay``), or as the Python
    API's keyword (``max_delay``) when not ``flags``."""
    return lambda flag: flag if flags else flag[2:].replace("-", "_")


class MaxDelay:
    """Runs the three answers for one scenario (see the module docstring)."""

    def __init__(self, scenario, settings: Settings, progress=None, yes: bool = False,
                 executor=None, yes_flag: str = "yes=True"):
        check_settings(settings)
        self.executor = executor
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
        keep = settings.estimate if settings.metric == "mse" else None
        self.axis: DelayAxis | RateAxis
        if settings.axis == "rate":
            self.axis = make_rate_axis(scenario, max_rate=settings.max_rate, min_rate=settings.min_rate,
                                       step=settings.rate_step, link=settings.link, keep=keep)
        else:
            self.axis = make_axis(scenario, max_delay=settings.max_delay, scale_step=settings.scale_step,
                                  max_scale=settings.max_scale, keep=keep)
        self.seeds = [derive_seed(int(scenario.seed), r) for r in range(settings.max_runs)]
        self.progress = progress or (lambda *_, **__: None)
        self.notes: list[str] = []
        if scenario.buffer_length != "auto" and settings.axis == "delay":
            self.notes.append(f"buffer_length is {scenario.buffer_length!r}, not auto: it does not follow "
                              "the candidate delay")
        self.cands: dict[int, Candidate] = {}
        #: the events of every run the search made, summed (what :meth:`estimate` predicted)
        self.events: dict[str, int] = {}
        self.ref: list[float] = []                  # zero-delay values by run (relative)
        self.wc: dict[int, Candidate] = {}
        self._order = 0
        self._scen_cache: dict[int, tuple] = {}
        flags = yes_flag.startswith("--")
        check(self.estimate(), yes=yes, yes_flag=yes_flag, hint=self.hint(flags=flags),
              memory_hint=many_runs_memory_hint(self.workers, smaller_run_hint(_option_name(flags)("--steps")),
                                                first=self.axis_hint(flags)))

    def hint(self, flags: bool = True) -> str:
        """What a refusal suggests: only the settings that shorten this search (its axis: the
        delay's ``--max-delay`` for a ``uniform_steps`` model, ``--scale-step`` and ``--max-scale``
        for a scaled one, the rate's own), as flags or as keywords."""
        name = _option_name(flags)
        more = [f"more {name('--jobs')}"] if self.workers < executors.available_cpus() else []
        return ", ".join([self.axis_hint(flags), f"a smaller {name('--batch')} or {name('--max-runs')}",
                          f"fewer {name('--steps')}"] + more)

    def axis_hint(self, flags: bool = True) -> str:
        """The settings that shorten this search's axis (fewer candidates: less time, and less
        memory for what the search keeps of each)."""
        name = _option_name(flags)
        if self.st.axis == "rate":
            return f"a larger {name('--rate-step')}, a narrower {name('--max-rate')}/{name('--min-rate')}"
        if getattr(self.axis, "mode", None) == "d_t":
            return f"a smaller {name('--max-delay')}"
        return f"a larger {name('--scale-step')}, a smaller {name('--max-scale')}"

    def visits(self, jstar: int) -> list[int]:
        """The candidates the empirical search visits, in order, when every candidate up to
        ``jstar`` is within and every one above exceeds (:func:`gallop_bisect`, then the
        candidate above the answer)."""
        J, seen = self.axis.max_index, []

        def evaluate(j):
            seen.append(j)
            return Candidate(index=j, delay=0.0, deterministic=True, decision=WITHIN if j <= jstar else EXCEEDS)
        lo, _ = gallop_bisect(evaluate, J)
        if lo is not None and lo + 1 <= J and lo + 1 not in seen:
            seen.append(lo + 1)
        return list(dict.fromkeys(seen))

    def expected_runs(self, answers: list[int] | None = None) -> list[tuple[float, dict[int, float]]]:
        """The runs the search is expected to make, as ``(weight, {candidate: runs})`` over the
        answers it may find (``answers``; default: spread evenly on a log scale of the axis, 0,
        1, 3, 7, 15, ... and every candidate within).

        For each answer: the candidates the search visits (:meth:`visits`), one look (``batch``
        runs; one run for a deterministic candidate) at a candidate far from the answer and three
        beside it, the paired zero-delay runs of a relative tolerance, and the worst-case scan
        (one run per candidate up to the one past the answer, and one for the no-exchange limit).
        A noisy metric close to its tolerance over many candidates takes more looks than this
        expects (the rate search of docs/traffic.md: about three times as many runs)."""
        J, st = self.axis.max_index, self.st
        if answers is None:
            answers = sorted({min(2 ** m - 1, J) for m in range(0, int(math.log2(J + 1)) + 2)} | {J})
        det = st.metric in COVARIANCE_METRICS and latencies_deterministic(self.axis.base)
        det0 = self.candidate_scenario(0)[1]            # (zero delay: often deterministic)
        worst = self.axis.worst_overrides(0) is not None and st.axis == "delay" and of_the_dkf(st)
        out = []
        for jstar in answers:
            runs: dict[int, float] = {}
            for j in self.visits(jstar):
                near = jstar < J and abs(j - jstar) <= 1
                runs[j] = 1.0 if det or (j == 0 and det0) else float(min(st.max_runs, (3 if near else 1) * st.batch))
            if st.relative is not None and not det0:
                runs[0] = max(runs.values())       # the paired zero-delay runs, as many as the most
            if worst:
                for j in range(min(jstar + 1, J) + 1):
                    runs[j] = runs.get(j, 0.0) + 1.0
                runs[J] = runs.get(J, 0.0) + 1.0       # (the no-exchange limit, as costly as the last)
            out.append((1.0 / len(answers), runs))
        return out

    def likely_answers(self, values: dict[int, float]) -> list[int]:
        """Where the answer lies by the trials' metric ``values`` at the galloping's candidates
        (one short run each, so a rough look): every candidate from the last of them within the
        tolerance to the one before the first past it; all the axis when the first is past it
        already or the trials say nothing (not a number)."""
        J, st = self.axis.max_index, self.st
        if not values or any(not math.isfinite(v) for v in values.values()):
            return list(range(J + 1))
        tol = st.relative * values[0] if st.relative is not None else st.tolerance
        if tol is None:                          # (check_settings: one of them is set)
            return list(range(J + 1))
        keys = sorted(values)
        past = [j for j in keys if values[j] > tol]
        if not past:
            return [J]                          # within everywhere: capped
        hi = past[0]
        lo = max([j for j in keys if j < hi], default=None)
        return [0] if lo is None else list(range(lo, hi))

    def _lower_bound(self) -> Cost:
        """The cost of a search over more than :data:`MAX_ENUMERATED` candidates, bounded below
        without enumerating them (``--scale-step 1e-12`` makes 10^12): their bookkeeping, and one
        run of the base scenario per candidate."""
        J = self.axis.max_index
        one = estimate_run(RunPlan.of(self.axis.base, "estimates"))
        total = Cost(f"{named(self.sc)}: maxdelay over {J + 1:.3g} candidates ({self.axis.name}), at "
                     "least one run each", workers=max(1, self.workers))
        total.seconds = (J + 1) * one.seconds
        total.memory["one run per worker"] = one.bytes * total.workers
        total.memory["candidates"] = (J + 1) * 2048
        return total

    def estimate(self, force_trial: bool = False) -> Cost:
        """Memory and time of the search as :meth:`expected_runs` expects it: each candidate's run
        guessed (the scenario of that candidate) with the answer anywhere; when that is long (or
        ``force_trial``), measured on trials at the galloping's candidates (0, 1, 2, 4, ..., J:
        their events, interpolated between them, and their metric, which says where the answer
        lies: :meth:`likely_answers`)."""
        J = self.axis.max_index
        if J + 1 > MAX_ENUMERATED:
            return self._lower_bound()
        anchors = sorted({0, J} | {min(2 ** m, J) for m in range(int(math.log2(max(J, 1))) + 1)})
        plans = {j: RunPlan.of(self.axis.scenario(j, self.axis.overrides(j)), "estimates") for j in anchors}
        ones = {j: estimate_run(plan) for j, plan in plans.items()}
        expected = self.expected_runs()
        guess = sum(w * sum(n * _between(ones, j, "seconds") for j, n in runs.items()) for w, runs in expected)
        measured = force_trial or guess / max(1, self.workers) > TRIAL_ABOVE_S
        measured = measured and all(trial_is_short(plan, ones[j]) for j, plan in plans.items())
        if measured:
            values = {}
            for j, plan in plans.items():
                res = trial(plan, "estimates")
                ones[j] = trial_estimate(plan, res)
                burn = min(self.burn, int(res.scenario.steps) // 2)
                values[j] = self.trial_value(res, burn)
            expected = self.expected_runs(self.likely_answers(values))
        total_runs = sum(w * sum(runs.values()) for w, runs in expected)
        total = Cost(f"{named(self.sc)}: maxdelay over {J + 1} candidates ({self.axis.name}), about "
                     f"{total_runs:.0f} runs expected", workers=max(1, self.workers))
        total.seconds = sum(w * sum(n * _between(ones, j, "seconds") for j, n in runs.items()) for w, runs in expected)
        if measured:
            total.events = {k: sum(w * sum(n * _between(ones, j, k) for j, n in runs.items()) for w, runs in expected)
                            for k in EVENT_KINDS}
            total.how = (f"expected from trials at {len(anchors)} of the {J + 1} candidates (their events, "
                         "interpolated, and their metric: where the answer lies)")
        biggest = max(one.bytes for one in ones.values())
        total.memory["one run per worker"] = biggest * total.workers
        total.memory["candidates"] = (J + 1) * 2048
        return total

    def trial_value(self, res, burn: int) -> float:
        """The searched metric of a trial run (NaN when it cannot say)."""
        try:
            return metric_value(res.arrays, self.st.metric, self.comp, burn, self.st.estimate)
        except (KeyError, ValueError):
            return float("nan")

    @property
    def workers(self) -> int:
        """How many runs at once: the executor's workers, else ``jobs`` (at most a batch)."""
        if isinstance(self.executor, executors.Executor):
            return self.executor.workers
        return min(self.st.jobs or executors.available_cpus(), self.st.batch)

    # ------------------------------------------------------------------ helpers
    def candidate_scenario(self, j: int):
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
            data, det = self.candidate_scenario(0)
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
        data, det = self.candidate_scenario(j)
        det_ref = det and (st.relative is None or self.candidate_scenario(0)[1])
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
        return runner.map([(self.axis.base, ov, None, self.st.metric, self.comp, self.burn, True,
                             self.st.estimate)])[0]

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
        ex, own = executors.executor_for(self.executor, st.jobs, st.batch)
        try:
            runner = Runner(ex, on_run=lambda k: self.progress(runs=k))
            # 1. empirical
            emp = empirical_search(Evaluator(self, runner), J)
            runs_empirical = runner.runs
            # 2. deterministic worst case
            self.progress(label="worst case")
            # (another estimator than the DKF's: no worst case, and the report says why)
            wc_data0 = self.axis.worst_overrides(0) if of_the_dkf(st) else None
            wc = None
            wc_tol = None
            limit = None
            if wc_data0 is not None and isinstance(self.axis, DelayAxis):
                ref0 = self.worst_value(wc_data0, runner)
                tol = st.tolerance if st.relative is None else st.relative * ref0
                assert tol is not None          # (check_settings: one of tolerance and relative is set)
                wc_tol = tol
                self.evaluate_worst(0, runner, tol, value=ref0)
                wc = worst_case_scan(lambda j: self.evaluate_worst(j, runner, tol), J)
                limit = self.worst_value(self.axis.limit_overrides(), runner)
            elif isinstance(self.axis, RateAxis):
                self.notes.append("worst case not computed: it is a latency notion; on the rate axis "
                                  "the lower bound from the packet sizes stands beside the empirical answer")
            elif of_the_dkf(st):
                self.notes.append("worst case not computed: a latency (or jitter) model is unbounded "
                                  "and links.d_t is not set, so there is no largest latency")
            runs_total = runner.runs
            self.events = dict(runner.events)
        finally:
            if own:
                ex.close()
        # 3. the paper's bound (delay), or the lower bound from the packet sizes (rate)
        bound = None
        if isinstance(self.axis, RateAxis):
            self.progress(label="lower bound from the packet sizes")
            paper = {"error": "the paper's bound is on the delay, not the rate"}
            bound = rate_lower_bound(self.axis, tracked_estimate(st))
        elif not of_the_dkf(st):
            paper = {"error": f"the paper's bound is on the anti-delay DKF, not on {st.estimate}"}
        else:
            paper = self._paper_bound(wc_tol if wc_tol is not None else st.tolerance)
        wall = time.perf_counter() - t0
        return MaxDelayResult(self, emp, wc, wc_tol, limit, paper, runs_empirical, runs_total, wall,
                              rate_bound=bound)

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
        d["p_tol_rule"] = (f"p_tol = tol / nx = {cov_tol:.4g} / {nx}, as lambda_max(P) <= tol / nx "
                           "guarantees trace(P) <= tol" if per_lambda else
                           "p_tol = tol, as lambda_max(P) <= tol guarantees P[c, c] <= tol")
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
        assert isinstance(ax, DelayAxis)       # (the paper's bound: the delay axis only)
        lat = [ax.sup_seconds(l, 1.0) for _, l in ax.specs]
        jit = [ax.sup_seconds(l, 1.0) for _, l in ax.jitters]
        if any(v is None for v in jit):
            return None
        if any(v is None for v in lat):
            if ax.links_d_t is None:
                return None
            lat = [ax.links_d_t * ax.T]
        lat_s = [v for v in lat if v is not None]      # (none is None now)
        jit_s = [v for v in jit if v is not None]
        total = max(lat_s) + (max(jit_s) if jit_s else 0.0)
        return total if total > 0 else None


def _between(ones: dict, j: int, key: str) -> float:
    """The estimate ``key`` ("seconds" or an event kind) of candidate ``j``, linear between the
    candidates of ``ones`` around it."""
    def value(a: int) -> float:
        one = ones[a]
        return float(one.seconds if key == "seconds" else one.events.get(key, 0.0))
    keys = sorted(ones)
    lo = max(a for a in keys if a <= j)
    hi = min(a for a in keys if a >= j)
    if lo == hi:
        return value(lo)
    return value(lo) + (value(hi) - value(lo)) * (j - lo) / (hi - lo)


# =========================================================================== result
def maxdelay(scenario, progress=None, yes: bool = False, executor=None, *, seed: int | None = None,
             steps: int | None = None, overrides: Sequence[str] = (), **settings) -> "MaxDelayResult":
    """The maximum allowable delay of ``scenario`` (a Scenario, a path or a mapping).

    ``settings`` are the fields of :class:`Settings` (the ``dkfsim maxdelay``
    flags: ``relative=1.5`` or ``tolerance=...``, ``metric``, ``jobs``, ...).
    ``executor``: where the runs happen (as :func:`dkfsim.experiments.montecarlo.montecarlo`);
    the result does not depend on it.
    A search estimated above 10 minutes needs ``yes`` (:mod:`dkfsim.core.resources`).
    ``seed`` (the base seed), ``steps`` and ``overrides`` (``dotted.key=value``, as ``--set``):
    the keywords of :func:`dkfsim.run`, :func:`dkfsim.montecarlo` and :func:`dkfsim.sweep`.
    """
    sc = with_keywords(scenario, seed, steps, overrides)
    unknown = sorted(set(settings) - set(Settings.__dataclass_fields__))
    if unknown:
        raise DkfsimError(f"maxdelay: unknown setting {unknown[0]!r}; known: "
                          + ", ".join(Settings.__dataclass_fields__))
    return MaxDelay(sc, Settings(**settings), progress=progress, yes=yes, executor=executor).run()


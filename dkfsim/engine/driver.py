"""One run: the draws, the shared network, the clock, and every estimator on them.

:func:`run` validates and checks a scenario, then a :class:`Run` simulates it
inside one SimPy environment (docs/design.md §2): the truth and every
sensor's measurements are drawn up front from their own streams; one
:class:`~dkfsim.network.links.Network` holds every link of the topology; the
scenario's anti-delay DKF and every listed estimator get the same
:class:`~dkfsim.estimators.base.RunContext`, with the run's
:class:`~dkfsim.config.plan.RunPlan` (what the scenario implies, worked out once)
and its :class:`~dkfsim.core.backend.Backend` (how it computes, chosen here once;
``summary.json`` records it).  At ``t_k`` every estimator's
``on_measure`` runs (priority ``NORMAL``, with the deliveries of that
instant); then, as an event of lower priority than every delivery and
relay at ``t_k``, every estimator's ``on_update``.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping, Sequence
from os import PathLike
from typing import Any

import numpy as np
import simpy
from simpy.events import NORMAL, Event

from dkfsim.components.faults import CrashSchedule
from dkfsim.components.mobility import link_pairs, link_uptime
from dkfsim.config.load import load_scenario
from dkfsim.config.plan import RunPlan
from dkfsim.config.schema import Scenario
from dkfsim.core.backend import Backend
from dkfsim.core.jit import kernels_cached
from dkfsim.core.progress import progress_callback
from dkfsim.core.registry import ESTIMATORS
from dkfsim.core.resources import Cost, check, check_memory
from dkfsim.core.threads import single_thread
from dkfsim.engine.estimate import RUN_HINT, TRIAL_ABOVE_S, estimate_run, scaled_events, trial_is_short, trial_ticks
from dkfsim.engine.results import RunResult
from dkfsim.estimators.anti_delay import AntiDelayDKF, AntiDelayParams
from dkfsim.estimators.base import Estimator, EstimatorResult, RunContext
from dkfsim.model.system import LinearGaussianSystem, build_system
from dkfsim.model.trajectory import track_truth
from dkfsim.network.events import PRIORITY_UPDATE, Scheduled
from dkfsim.network.network import Network


def run_events(results: Sequence[tuple[Estimator, EstimatorResult]], K: int) -> dict[str, int]:
    """What a run did, counted as its estimate predicts it (:mod:`dkfsim.engine.estimate`):
    ``ticks`` (K per estimator), ``packets`` (every estimator's packets sent, and the background
    frames of its copy of a shared channel), ``node_rows`` (the (node, row) pairs the window
    filters re-ran: every anti-delay DKF, a fusion centre's shadow) and ``fused_rows`` (the rows
    their fusion's cross-covariance recursion re-ran)."""
    out = {"ticks": K * len(results), "packets": 0, "node_rows": 0, "fused_rows": 0}
    for est, res in results:
        traffic = res.traffic or {}
        out["packets"] += int(traffic.get("sent") or 0)
        channel = traffic.get("channel") or {}
        out["packets"] += int(channel.get("background_sent", 0)) + int(channel.get("background_collided", 0))
        window = getattr(est, "window", None)
        if window is not None:
            out["node_rows"] += int(window.node_rows)
            if getattr(est, "xcov", None) is not None:
                out["fused_rows"] += int(window.rows_run)
    return out


class Run:
    """The runtime state of one run (configuration stays in the scenario)."""

    def __init__(self, scenario: Scenario, *, save: str = "auto",
                 progress: Callable[[int, int], None] | None = None, system: LinearGaussianSystem | None = None,
                 plan: RunPlan | None = None, backend: Backend | None = None):
        """``system`` and ``plan``: the scenario's :func:`~dkfsim.model.system.build_system`
        and :class:`~dkfsim.config.plan.RunPlan`, when the caller already has them (the runs
        of a Monte Carlo differ only by their seed and share both, ``plan.with_seed``; a run
        reads them, never changes them).  A ``plan`` brings its own save mode.  ``backend``:
        this one instead of the environment's (the trial of an estimate runs on numpy,
        :mod:`dkfsim.engine.estimate`)."""
        self.scenario = scenario
        self.K = K = int(scenario.steps)
        seed = int(scenario.seed)
        self.plan = plan = RunPlan.of(scenario, save) if plan is None else plan
        system = build_system(scenario) if system is None else system
        self.progress = progress
        # Everything random but the network is drawn up front, from its own streams.
        truth = track_truth(scenario) if scenario.truth is not None else system.simulate_truth(K, seed)
        ys = system.simulate_measurements(truth, seed)
        crashes = CrashSchedule(scenario.faults, system.n) or None
        env = simpy.Environment()
        self.backend = Backend.from_environment() if backend is None else backend
        positions, presence = plan.radio_places or (None, None)
        network = Network(env, plan.arcs, scenario.link_spec, seed, system.T_ns, crashes=crashes,
                          shared_queues=bool(scenario.links.shared_queues), schedule=plan.link_schedule,
                          medium=scenario.medium, n=system.n, backend=self.backend, positions=positions,
                          presence=presence)
        self.ctx = RunContext(scenario=scenario, plan=plan, backend=self.backend, system=system, truth=truth, ys=ys,
                              info=system.information(ys), crashes=crashes, env=env, network=network)
        self.dkf = AntiDelayDKF(AntiDelayParams(), self.ctx, main=True)
        self.estimators = [self.dkf] + [ESTIMATORS.get(p.kind).implementation(p, self.ctx)
                                        for p in scenario.estimators]
        self.k = 0

    # -- the clock -------------------------------------------------------------------
    def _measure(self, _event: Event) -> None:
        self.k += 1
        for est in self.estimators:
            est.on_measure(self.k - 1)
        Scheduled(self.ctx.env, self._update, PRIORITY_UPDATE)

    def _update(self, _event: Event) -> None:
        k = self.k
        for est in self.estimators:
            est.on_update(k)
        if self.progress is not None and (k % max(1, self.K // 100) == 0 or k == self.K):
            self.progress(k, self.K)
        if k < self.K:
            Scheduled(self.ctx.env, self._measure, NORMAL, self.ctx.T_ns)

    def run(self) -> RunResult:
        ctx = self.ctx
        t0 = time.perf_counter()
        # A diverging filter overflows; it is reported (RunResult.diverged), not warned about.
        with np.errstate(all="ignore"):
            for est in self.estimators:
                est.start()
            end = self.K * ctx.T_ns
            for port in ctx.network.ports:
                if port.until is None:
                    port.until = end
            Scheduled(ctx.env, self._measure, NORMAL, ctx.T_ns)
            ctx.env.run(until=max([end] + [p.until for p in ctx.network.ports if p.until is not None]) + 1)
            results = [(est, est.finish()) for est in self.estimators]
        return self._result(results, time.perf_counter() - t0)

    def _result(self, results: Sequence[tuple[Estimator, EstimatorResult]], wall: float) -> RunResult:
        ctx, sc = self.ctx, self.scenario
        sys_, K = ctx.system, self.K
        arrays = {"t": sys_.times(K), "truth": ctx.truth,
                  "Phi": sys_.Phi, "Q": sys_.Q, "x0_mean": sys_.x0_mean, "P0": sys_.P0}
        H, R = sys_.H, sys_.R              # properties that build a tuple: once, not per sensor
        for i in range(sys_.n):
            arrays[f"H_{i}"] = H[i]
            arrays[f"R_{i}"] = R[i]
            arrays[f"y_{i}"] = ctx.ys[i]
            convert = getattr(sys_.sensors[i], "convert", None)
            if convert is not None:
                # A non-linear sensor enters the filters as a converted linear
                # measurement z = H x + noise(Rc[r]): keep both so run.npz alone
                # can recompute every estimate.
                arrays[f"z_{i}"], arrays[f"Rc_{i}"] = convert(ctx.ys[i])
        if ctx.crashes is not None:      # (n, K): node i was down at row r's tick
            arrays["crashed"] = ctx.crashes.mask(K, sys_.T_ns)
        estimates, traffic, facts = {}, {}, {}
        for est, res in results:
            arrays.update(res.arrays)
            for name, e in res.estimates.items():
                estimates[name] = e
                arrays[f"x_{name}"] = e.x
                if e.P is not None:
                    arrays[f"P_{name}"] = e.P
                traffic[name] = res.traffic
            if res.facts and est is not self.dkf:
                facts[est.name] = res.facts
        counts = dict(results[0][1].traffic or {})    # the scenario's DKF: the run's packets
        if self.dkf.port is not None:     # its rate-limited links over time (none: nothing added)
            arrays.update(self.dkf.port.link_series(sys_.T_ns, K))
            arrays.update(self.dkf.port.channel_series(sys_.T_ns, K))
        plan = self.plan
        info = {
            "buffer_length": self.dkf.L,
            "d_t": plan.d_t,
            "d_g": plan.exchange.d_g,
            "n_links": len(plan.exchange.arcs),
            "wall_time_s": wall,
            "save": ctx.save,
            "kernels": self.backend.kernels,
            "node_rows": self.dkf.window.node_rows,
            "events": run_events(results, K),
            "exchange": self.dkf.exchange.bookkeeping,
            "backend": self.backend.record(),
        }
        schedule = plan.link_schedule
        if schedule is not None:          # mobility: what the figures of a moving network need
            pairs, up = link_pairs(schedule)
            arrays["positions"] = np.ascontiguousarray(plan.positions[1:])     # rows: ticks 1 .. K
            arrays["links_up"] = up[1:].astype(np.uint8)
            arrays["mobility_links"] = pairs
            info["mobility"] = {"link_uptime": link_uptime(pairs, up[1:])}
        return RunResult(sc, arrays, counts, info, estimates=list(estimates), traffic=traffic,
                         facts=facts)


# =========================================================================== estimates
#: The backend of a trial when the compiled kernels are not on disk yet: the numpy kernels (none
#: to compile; a run's events are the same on every path).
TRIAL_BACKEND = Backend("numpy")
#: The kernel modules a trial off the spatial radio runs: when numba's disk cache holds them, a
#: trial runs compiled (loading them takes well under a second; a maxdelay refusal that tried
#: eight candidates took 23 s of CPU on the numpy kernels, 5 s compiled).
TRIAL_KERNELS = ("dkfsim.estimators.kernels", "dkfsim.model.holdings_kernels", "dkfsim.network.port_kernels",
                 "dkfsim.protocols.tree_kernels")


def trial_backend(sc: Any) -> Backend:
    """A trial's backend: the environment's when its kernels are compiled already (numba's disk
    cache holds :data:`TRIAL_KERNELS`) or the scenario is on a spatial radio, whose event engine
    as Python costs far more than compiling it (a trial of the highway: about 120 s against
    1 s); else :data:`TRIAL_BACKEND`, which compiles nothing."""
    env = Backend.from_environment()
    medium = getattr(sc, "medium", None)
    if medium is not None and medium.radio is not None:
        return env
    return env if env.compiled and kernels_cached(TRIAL_KERNELS) else TRIAL_BACKEND


def trial(plan: RunPlan, save: str = "summary") -> RunResult:
    """A trial of ``plan``'s scenario: its first :func:`~dkfsim.engine.estimate.trial_ticks`
    ticks, on :func:`trial_backend`'s kernels."""
    sc = plan.scenario
    K, P = int(sc.steps), trial_ticks(plan)
    short = load_scenario(sc, overrides=[f"steps={P}"]) if P < K else sc
    with np.errstate(all="ignore"):
        return Run(short, save=save, backend=trial_backend(sc)).run()


def trial_events(plan: RunPlan) -> tuple[dict[str, float], int]:
    """The events of a run of ``plan``'s scenario, measured on a :func:`trial` (nothing kept) and
    scaled to its ticks; and the trial's ticks."""
    res = trial(plan)
    P = int(res.scenario.steps)
    return scaled_events(res.info["events"], P, int(plan.scenario.steps)), P


def trial_estimate(plan: RunPlan, res: RunResult) -> Cost:
    """The estimate of a run of ``plan`` from its :func:`trial` ``res``."""
    P = int(res.scenario.steps)
    return estimate_run(plan, events=scaled_events(res.info["events"], P, int(plan.scenario.steps)),
                        how=f"measured on a trial of {P} ticks")


def measured_estimate(plan: RunPlan, runs: float = 1, workers: int = 1, force: bool = False,
                      guess: Cost | None = None) -> Cost:
    """The estimate of one run of ``plan``: its analytic ``guess`` (:func:`estimate_run`, made
    here when not given), or, when ``runs`` such runs on ``workers`` would take more than
    :data:`~dkfsim.engine.estimate.TRIAL_ABOVE_S` by the guess (or ``force``), its events measured
    on a trial (:func:`trial_events`) -- unless the trial itself would be long
    (:func:`~dkfsim.engine.estimate.trial_is_short`)."""
    if guess is None:
        guess = estimate_run(plan)
    if not force and guess.seconds * runs / max(1, workers) <= TRIAL_ABOVE_S:
        return guess
    if not trial_is_short(plan, guess):      # (the trial itself would be long: the guess decides)
        return guess
    events, ticks = trial_events(plan)
    return estimate_run(plan, events=events, how=f"measured on a trial of {ticks} ticks")


def check_run_measured(plan: RunPlan, *, yes: bool = False) -> Cost:
    """:func:`~dkfsim.core.resources.check` one run on :func:`measured_estimate`; the estimate.
    Memory is refused on the analytic guess, before any trial: it is exact, a trial measures
    time only, and a run that cannot fit may not fit its trial either (a sidelink's state per
    pair of vehicles does not shrink with the ticks)."""
    guess = estimate_run(plan)
    check_memory(guess, hint=RUN_HINT)
    est = measured_estimate(plan, guess=guess)
    check(est, yes=yes, hint=RUN_HINT)
    return est


def simulate(plan: RunPlan, progress: Callable[[int, int], None] | None = None) -> RunResult:
    """Run the scenario of ``plan`` (validated, its resources checked: :func:`run` does both)
    and return its result; ``progress(tick, K)`` is called as the run goes."""
    with np.errstate(all="ignore"):          # an exploding truth is reported, not warned about
        sim = Run(plan.scenario, save=plan.save, progress=progress, plan=plan)
    return sim.run()


@single_thread
def run(scenario: Scenario | str | PathLike | Mapping[str, Any], *, seed: int | None = None,
        steps: int | None = None, overrides: Sequence[str] = (), save: str = "auto",
        progress: bool | Callable[[int, int], None] | None = None, yes: bool = False) -> RunResult:
    """Simulate one scenario and return its :class:`~dkfsim.engine.results.RunResult`.

    ``scenario`` is a :class:`~dkfsim.config.schema.Scenario`, a path to a
    scenario file or a mapping.  ``seed`` and ``steps`` override the
    scenario's, ``overrides`` (``dotted.key=value``) are ``--set``: the keywords of
    :func:`dkfsim.montecarlo`, :func:`dkfsim.sweep` and :func:`dkfsim.maxdelay`.  A run that cannot fit in memory
    raises :class:`~dkfsim.core.errors.ResourceError`; one estimated to take
    more than 10 minutes does too unless ``yes`` (:mod:`dkfsim.core.resources`).
    ``progress``: True for a ``tqdm.auto`` bar (a widget in notebooks), or a
    callable ``progress(tick, K)``.  BLAS runs on one thread during the call (:mod:`dkfsim.core.threads`).
    """
    extra = [*overrides, *(f"{key}={int(val)}" for key, val in (("seed", seed), ("steps", steps))
                           if val is not None)]
    if extra or not isinstance(scenario, Scenario):   # validated exactly as --set would be
        scenario = load_scenario(scenario, overrides=extra)
    plan = RunPlan.of(scenario, save)
    check_run_measured(plan, yes=yes)
    with progress_callback(progress, int(scenario.steps), scenario.name, "tick") as callback:
        return simulate(plan, callback)

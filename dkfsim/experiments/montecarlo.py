"""Monte Carlo over independent runs: ``dkfsim montecarlo FILE --runs N``.

Run ``r`` (``r = 0 .. N-1``) is the scenario with its seed replaced by
:func:`derive_seed` ``(scenario.seed, r)``, so run ``r`` is the same run
whatever ``N`` and whatever the number of worker processes ``J``.  Every
random stream of a run derives from that seed (truth, sensors, links, and a
*random topology* too: fix ``topology.params.seed`` to keep one graph over
all runs).

What the runs share is validated and built once (:class:`Template`: the
pinned scenario, its graphs and its system; run ``r`` is a copy with its
seed, docs/design.md §9).  Each run is scored where it ran
(:func:`run_rows`) and sends back only small data: per estimate the squared error per tick and component ``(K, nx)``
(averaged over nodes for per-node estimates), the NEES per tick ``(K,)``
and per-run scalars.  The parent folds the runs in run order, whatever order
they finish in, so every output is identical for any ``J``.

Estimates of a run (the one vocabulary: docs/design.md and docs/estimators.md):
``fused`` (the anti-delay DKF's fused estimate, absent with ``fusion: none``),
``local`` (each DKF node's own real-time estimate, per node), then every
estimator the scenario lists under its name (``centralized``,
``local_only``, ``no_buffer``, ``ci_consensus``, ...).  Per-node estimates
are scored by the mean over nodes (squared error, NEES) and have a
``disagreement`` (:func:`dkfsim.analysis.metrics.disagreement`); the others
have ``disagreement = NaN``.  Every per-run number is a tidy row
(:func:`dkfsim.analysis.metrics.score_scored`): ``runs.csv`` has the columns of a
run's ``rows.csv`` and a sweep's export.  Traffic comes from each
estimator's own port on the run's network (messages, nominal bytes, lost
packets, late information); the idealised ``centralized`` filter has none
(NaN).
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from functools import cached_property
from pathlib import Path

import numpy as np

from dkfsim.analysis.frames import curves_dataset, rows_frame
from dkfsim.analysis.metrics import (
    anees_consistent,
    anees_summary,
    default_burn_in,
    nees_band,
    row_columns,
    squared_error,
    t_interval,
    t_interval_from_moments,
)
from dkfsim.analysis.paired import paired_block, reference_of
from dkfsim.components.topology import generator_params
from dkfsim.config.dynamics import component_names
from dkfsim.config.load import load_scenario, scenario_hash, stored_scenario
from dkfsim.config.plan import RunPlan
from dkfsim.config.results import MonteCarloSummary, read_curves, read_record, read_rows
from dkfsim.config.schema import Scenario, named
from dkfsim.core.errors import DkfsimError
from dkfsim.core.folders import staged, write_json
from dkfsim.core.progress import progress_callback
from dkfsim.core.resources import Cost, check, many_runs_memory_hint, repeat
from dkfsim.core.text import aligned
from dkfsim.core.threads import single_thread
from dkfsim.engine.driver import Run, measured_estimate
from dkfsim.engine.estimate import smaller_run_hint
from dkfsim.engine.results import versions, write_rows
from dkfsim.experiments import executors
from dkfsim.model.system import build_system


#: Columns of ``runs.csv``, in order.
# =========================================================================== seeds, names
def derive_seed(base_seed: int, run: int) -> int:
    """The seed of Monte Carlo run ``run`` under scenario seed ``base_seed``.

    ``numpy.random.SeedSequence(entropy=base_seed, spawn_key=(run,))``, its
    first 64 state bits cut to 63 (so the seed fits a signed 64-bit column).
    A pure function of the two numbers: run ``r`` does not depend on how many
    runs or workers there are.
    """
    if int(base_seed) < 0 or int(run) < 0:
        raise ValueError("base_seed and run must be >= 0")
    words = np.random.SeedSequence(entropy=int(base_seed), spawn_key=(int(run),)).generate_state(
        2, dtype=np.uint32)
    return int(words[0]) | (int(words[1]) & 0x7FFF_FFFF) << 32


def components_of(scenario) -> list[str]:
    """The scenario's state component names (see :func:`dkfsim.config.dynamics.component_names`)."""
    return component_names(scenario.model.kind, scenario.nx)


def check_burn_in(burn_in: int | None, K: int) -> int:
    if burn_in is None:
        return default_burn_in(K)
    if not 0 <= int(burn_in) < K:
        raise DkfsimError(f"--burn-in: must be in [0, steps) = [0, {K}), got {burn_in}")
    return int(burn_in)


# =========================================================================== one run
def pinned_topology(scenario) -> list[str]:
    """Overrides that keep a random topology fixed across Monte Carlo runs.

    A seeded generator without ``topology.params.seed`` draws its graph from
    the scenario seed; Monte Carlo runs vary that seed to redraw noise and
    latencies, not the network, so the graph is pinned to the *base* seed.
    """
    sc = scenario if isinstance(scenario, Scenario) else load_scenario(scenario)
    topo = sc.topology
    if "seed" in (generator_params(topo.generator) or ((), ()))[1] and "seed" not in (topo.params or {}):
        return [f"topology.params.seed={int(sc.seed)}"]
    return []


class Template:
    """What every run of a Monte Carlo shares, validated and built once.

    ``scenario``: the base scenario with its random topology pinned
    (:func:`pinned_topology`), validated once; ``plan``: its
    :class:`~dkfsim.config.plan.RunPlan` (graphs, delay bound, buffer lengths, worked out
    here once); ``system``: its :func:`~dkfsim.model.system.build_system`.  Nothing of
    these depends on the seed, so run ``r`` is ``scenario`` with the seed replaced
    (:meth:`scenario_for`: a copy, not a re-validation) simulated on ``system`` with
    the plan (:meth:`plan_for`: the same facts, shared) -- the same run, field for field,
    as ``load_scenario(scenario, overrides=pinned + ["seed=S"])`` would give
    (tests/test_montecarlo_setup.py).  A scenario with ``plugins`` is re-validated and
    planned per run as before: validation is what imports the plugins, and a fresh
    worker process may not have them yet.
    """

    def __init__(self, scenario):
        sc = scenario if isinstance(scenario, Scenario) else load_scenario(scenario)
        self.scenario = load_scenario(sc, overrides=pinned_topology(sc))
        plain = not self.scenario.plugins
        self.plan = RunPlan.of(self.scenario, "estimates").resolve() if plain else None
        self.system = build_system(self.scenario) if plain else None

    def scenario_for(self, seed: int) -> Scenario:
        """The scenario of the run with seed ``seed``."""
        if self.scenario.plugins:
            return load_scenario(self.scenario, overrides=[f"seed={int(seed)}"])
        return self.scenario.model_copy(update={"seed": int(seed)})

    def plan_for(self, scenario: Scenario) -> RunPlan:
        """The plan of ``scenario`` (:meth:`scenario_for`): the template's, shared."""
        return self.plan.with_seed(scenario) if self.plan is not None else RunPlan.of(scenario, "estimates")


def run_rows(scenario, seed: int, burn_in: int | None = None, *,
             curves: bool = True) -> tuple[list[dict], dict | None]:
    """Simulate ``scenario`` with seed ``seed`` and score every estimate.

    Returns ``(rows, curves)``.  ``rows``: the run's tidy rows
    (:meth:`~dkfsim.engine.results.RunResult.rows`, with ``seed``).
    ``curves`` (None unless ``curves``): ``t`` (K,), ``components``,
    ``estimates``, ``se`` (A, K, nx) squared error per tick, ``nees`` (A, K),
    ``example_truth`` (K, nx), ``example_x`` (A, K, nx) (node 0 for per-node
    estimates), ``example_node0`` (K, nx) (``x_local`` of node 0).

    ``scenario`` is a :class:`~dkfsim.config.schema.Scenario`, a dict, a file
    or a :class:`Template` (many runs of one scenario: validated and built once);
    ``burn_in`` defaults to 10 % of the ticks.
    """
    rows, out, _events = run_scored(scenario, seed, burn_in, curves=curves)
    return rows, out


def run_scored(scenario, seed: int, burn_in: int | None = None, *,
               curves: bool = True) -> tuple[list[dict], dict | None, dict[str, int]]:
    """:func:`run_rows`, and the run's events (``RunResult.info["events"]``: what its estimate
    predicted, :mod:`dkfsim.engine.estimate`)."""
    tpl = scenario if isinstance(scenario, Template) else Template(scenario)
    sc = tpl.scenario_for(seed)
    burn = check_burn_in(burn_in, int(sc.steps))
    with np.errstate(all="ignore"):          # a diverging run gives inf / nan rows, no warnings
        res = Run(sc, save="estimates", system=tpl.system, plan=tpl.plan_for(sc)).run()
        scored = res.scored(burn)            # one NEES per estimate, for the rows and the curves
        rows = [{**row, "seed": int(seed)} for row in res.rows(burn, scored)]
        out = _curves(res, scored) if curves else None
        if out is not None:
            out["packets"] = {name: packet_counts(t) for name, t in res.traffic.items()}
        return rows, out, dict(res.info["events"])


#: The counts of a run's traffic a Monte Carlo averages per estimate: the terms of the identity
#: ``sent + copies = delivered + lost + queue_dropped + crash_dropped + in_flight`` and the causes
#: of ``lost`` (docs/design.md §3).
PACKET_COUNTS = ("sent", "copies", "delivered", "lost", "outage_lost", "range_lost", "collision_lost",
                 "queue_dropped", "crash_dropped", "in_flight")


def packet_counts(traffic: dict | None) -> dict[str, int] | None:
    """The :data:`PACKET_COUNTS` of one estimator's traffic (None: not modelled)."""
    if traffic is None:
        return None
    return {k: int(traffic.get(k, 0) or 0) for k in PACKET_COUNTS}


def _curves(res, scored: dict) -> dict:
    """Per-tick curves of one finished run (see :func:`run_rows`)."""
    truth = res.arrays["truth"]
    names = res.estimates
    K, nx = truth.shape
    se = np.empty((len(names), K, nx))
    nees = np.full((len(names), K), np.nan)
    ex = np.empty((len(names), K, nx))
    for a, name in enumerate(names):
        s = scored[name]
        se[a] = squared_error(s.x, truth)
        if s.nees is not None:
            nees[a] = s.nees
        ex[a] = s.x if s.x.ndim == 2 else s.x[:, 0]
    return {"t": np.asarray(res.arrays["t"]), "components": res.components, "estimates": names,
            "se": se, "nees": nees, "example_truth": truth, "example_x": ex,
            "example_node0": np.asarray(res.arrays["x_local"])[:, 0]}


# =========================================================================== one task
def _one(template: Template, r: int, seed: int, burn_in: int) -> tuple[list[dict], dict]:
    """Run ``r`` where it runs (a worker, or this process): its rows and curves."""
    try:
        rows, curves, events = run_scored(template, seed, burn_in)
    except DkfsimError as exc:      # e.g. a random topology that is disconnected for this seed
        raise DkfsimError(f"run {r} (seed {seed}): {exc}") from None
    assert curves is not None                   # (asked for: run_scored's curves=True)
    curves["events"] = events
    if r != 0:       # only run 0 is kept as the example: do not ship the rest
        for key in ("example_truth", "example_x", "example_node0"):
            del curves[key]
    return rows, curves


# =========================================================================== pooling
class _Fold:
    """Running pool of the per-tick curves, fed in run order (Welford)."""

    def __init__(self):
        self.n = 0
        self.mean = self.m2 = self.nees_sum = None
        self.first = None
        #: the runs' events, summed (what the estimate predicted)
        self.events: dict[str, int] = {}
        #: per estimate, its packet counts summed over the runs (None: not modelled)
        self.packets: dict[str, dict[str, int] | None] = {}

    def add(self, curves: dict) -> None:
        for key, count in curves.get("events", {}).items():
            self.events[key] = self.events.get(key, 0) + int(count)
        for name, counts in curves.get("packets", {}).items():
            total = self.packets.setdefault(name, None if counts is None else dict.fromkeys(counts, 0))
            if total is not None and counts is not None:
                for key, v in counts.items():
                    total[key] += v
        se, nees = curves["se"], curves["nees"]
        if self.n == 0:
            self.first = curves
            self.mean = np.zeros_like(se)
            self.m2 = np.zeros_like(se)
            self.nees_sum = np.zeros_like(nees)
        elif curves["estimates"] != self.first["estimates"]:
            raise DkfsimError("runs report different estimates "
                              f"({self.first['estimates']} vs {curves['estimates']})")
        self.n += 1
        d = se - self.mean
        self.mean += d / self.n
        self.m2 += d * (se - self.mean)
        self.nees_sum += nees


@single_thread
def montecarlo(scenario, runs: int, jobs: int | None = None, burn_in: int | None = None,
               progress=None, yes: bool = False, executor=None,
               relative_to: str | None = None, *, seed: int | None = None, steps: int | None = None,
               overrides: Sequence[str] = ()) -> "MonteCarloResult":
    """``runs`` independent runs of ``scenario``.

    ``scenario``: a Scenario, a path or a mapping.  Run ``r`` uses seed
    ``derive_seed(scenario.seed, r)``.  Where the runs happen: ``executor`` (a
    :mod:`dkfsim.experiments.executors` executor, left open, or a callable making one),
    else ``jobs`` local processes (default: every available CPU, at most ``runs``;
    1 runs in this process).  ``progress``: True for a ``tqdm.auto`` bar (a widget in
    notebooks), or a callable ``progress(done, total)`` called after each run.
    The result does not depend on where the runs happened: they are folded in run
    order, and a failing run is reported as the first one in run order.  Work that
    cannot fit in memory is refused, and work estimated above 10 minutes needs ``yes``
    (:mod:`dkfsim.core.resources`).  ``relative_to``: the reference estimate of the paired
    comparisons (default ``centralized`` when the scenario has it; :func:`check_reference`).
    ``seed`` (the base seed), ``steps`` and ``overrides`` (``dotted.key=value``, as ``--set``):
    the keywords of :func:`dkfsim.run`, :func:`dkfsim.sweep` and :func:`dkfsim.maxdelay`.
    """
    if isinstance(runs, bool) or not isinstance(runs, int) or runs < 1:
        raise DkfsimError(f"--runs: must be an integer >= 1, got {runs!r}")
    executors.check_jobs(jobs)
    sc = with_keywords(scenario, seed, steps, overrides)
    burn = check_burn_in(burn_in, int(sc.steps))
    check_reference(sc, relative_to)
    workers = executor.workers if isinstance(executor, executors.Executor) else \
        min(jobs or executors.available_cpus(), runs)
    check_montecarlo(sc, runs, workers, yes=yes)
    with progress_callback(progress, runs, sc.name, "run") as callback:
        res = _montecarlo(sc, runs, jobs, burn, callback, executor)
    res.relative_to = relative_to
    return res


def _montecarlo(sc, runs: int, jobs, burn: int, progress, executor) -> "MonteCarloResult":
    seeds = [derive_seed(sc.seed, r) for r in range(runs)]
    rows: list[dict] = []
    fold = _Fold()
    t0 = time.perf_counter()
    done = 0

    def tick():
        nonlocal done
        done += 1
        if progress is not None:
            progress(done, runs)

    template = Template(sc)
    tasks = ((f"run {r} (seed {seed})", (template, r, seed, burn)) for r, seed in enumerate(seeds))
    ex, own = executors.executor_for(executor, jobs, runs)
    try:
        for r, (_key, (run_rows_, curves)) in enumerate(executors.in_order(ex, _one, tasks, tick)):
            rows.extend({**row, "run": r} for row in run_rows_)
            fold.add(curves)
    finally:
        if own:
            ex.close()
    wall = time.perf_counter() - t0
    return MonteCarloResult(sc, runs, ex.workers, burn, seeds, rows, fold, wall, ex.label, template.plan)


def with_keywords(scenario, seed: int | None = None, steps: int | None = None,
                  overrides: Sequence[str] = ()) -> Scenario:
    """``scenario`` (a Scenario, a path or a mapping) with the API's ``seed``, ``steps`` and
    ``overrides`` applied, validated as ``--set`` would be."""
    extra = [*overrides, *(f"{k}={int(v)}" for k, v in (("seed", seed), ("steps", steps)) if v is not None)]
    if isinstance(scenario, Scenario) and not extra:
        return scenario
    return load_scenario(scenario, overrides=extra)


def scenario_estimates(sc) -> list[str]:
    """The estimate names a run of ``sc`` gives, as far as the scenario says (the DKF's
    ``fused`` -- none with ``fusion: none`` -- and ``local``, then each listed estimator's name)."""
    dkf = ["local"] if sc.fusion == "none" else ["fused", "local"]
    return [*dkf, *(p.label for p in sc.estimators)]


def check_reference(sc, relative_to: str | None) -> None:
    """``--relative-to NAME`` names an estimate of the scenario: checked before any run."""
    if relative_to is None:
        return
    why = "; the scenario has fusion: none, so there is no fused estimate" \
        if relative_to == "fused" and sc.fusion == "none" else ""
    reference_of(scenario_estimates(sc), relative_to, sc.name, why=why)


def load_montecarlo(folder, *, data_files: bool = False) -> "MonteCarloResult":
    """Read a folder written by ``dkfsim montecarlo`` (or :meth:`MonteCarloResult.save`) back.

    Everything is checked before use (docs/security.md): ``summary.json`` against
    :class:`~dkfsim.config.results.MonteCarloSummary`, every row of ``runs.csv``
    (:func:`~dkfsim.config.results.read_rows`), every header of ``curves.npz`` before its
    data (:func:`~dkfsim.config.results.read_curves`); the scenario is re-validated from the
    copy in ``summary.json`` as data (its ``plugins:`` are never imported, and the files its
    ``file:`` keys name are not opened unless ``data_files=True``, as
    :func:`~dkfsim.engine.results.load_run`).  Nothing is unpickled or imported.  Raises
    :class:`DkfsimError`.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise DkfsimError(f"{folder}: no such folder (give the folder dkfsim montecarlo wrote)")
    for name in ("summary.json", "runs.csv", "curves.npz"):
        if not (folder / name).is_file():
            raise DkfsimError(f"{folder}: no {name} (a Monte Carlo folder holds summary.json, "
                              "runs.csv and curves.npz)")
    path = folder / "summary.json"
    summary = read_record(path, MonteCarloSummary, "summary.json")
    if not summary.get("scenario_config"):
        raise DkfsimError(f"{path}: no scenario_config (written by an older dkfsim?)")
    source = summary.get("source")
    scenario = stored_scenario(summary["scenario_config"], source=source, label=str(path), data_files=data_files)
    scenario.set_source(source)
    rows = read_rows(folder / "runs.csv")
    curves = read_curves(folder / "curves.npz", scenario.steps, summary.get("components"))
    try:
        return MonteCarloResult.restored(scenario, summary, rows, curves)
    except DkfsimError as exc:
        raise DkfsimError(f"{folder}: {exc}") from None


def estimate_montecarlo(sc, runs: int, jobs: int, force_trial: bool = False) -> Cost:
    """Memory and time of ``runs`` runs on ``jobs`` processes, rows and curves included (the
    events of one run measured on a trial when the guess is long, or ``force_trial``)."""
    one = measured_estimate(RunPlan.of(Template(sc).scenario, "estimates"), runs, min(jobs, runs), force_trial)
    estimates = 2 + len(sc.estimators)
    K, nx = int(sc.steps), sc.nx
    kept = runs * estimates * nx * 600 + 6 * estimates * K * nx * 8     # rows; pooled curves
    return repeat(one, f"{named(sc)}: a Monte Carlo of {runs} runs x {K} ticks", runs,
                  min(jobs, runs), extra_bytes=kept)


#: The refusal's hint of the Python API (the command line names its own flags).
API_HINT = "fewer runs or steps, or more jobs"


def check_montecarlo(sc, runs: int, jobs: int, *, yes: bool = False, hint: str = API_HINT,
                     yes_flag: str = "yes=True") -> Cost:
    """Refuse a Monte Carlo that cannot fit, ask for ``yes`` above 10 minutes; ``hint`` and
    ``yes_flag`` say what the caller can change (its flags or its keywords)."""
    est = estimate_montecarlo(sc, runs, jobs)
    dashes = "--" if yes_flag.startswith("--") else ""          # (flags, or the API's keywords)
    check(est, yes=yes, yes_flag=yes_flag, hint=hint, memory_hint=many_runs_memory_hint(
        est.workers, smaller_run_hint(f"{dashes}steps"), first=f"fewer {dashes}runs (their rows are kept)"))
    return est


# =========================================================================== the result
class MonteCarloResult:
    """Pooled result of :func:`montecarlo`.

    ``rows``: the tidy per-run table (``runs.csv``), in run order.
    ``t, components, estimates, mse, mse_ci_lo, mse_ci_hi, nees, nees_band``
    and ``example`` (run 0): the arrays of ``curves.npz``.
    """

    def __init__(self, scenario, runs, jobs, burn_in, seeds, rows, fold: _Fold, wall,
                 executor: str = "this process", plan: RunPlan | None = None):
        self.scenario = scenario
        #: the facts of its runs (graphs, buffer length): its Template's plan
        self.plan = RunPlan.of(scenario) if plan is None else plan
        self.runs = runs
        self.jobs = jobs
        self.executor = executor
        self.burn_in = burn_in
        self.seeds = seeds
        self.rows = rows
        self.wall_time_s = wall
        first = fold.first
        self.t = first["t"]
        self.components = list(first["components"])
        self.estimates = list(first["estimates"])
        self.mse = fold.mean
        self.mse_ci_lo, self.mse_ci_hi = t_interval_from_moments(fold.mean, fold.m2, fold.n)
        self.nees = fold.nees_sum / fold.n
        self.nees_band = nees_band(runs, len(self.components))
        self.example = {"example_truth": first["example_truth"], "example_x": first["example_x"],
                        "example_node0": first["example_node0"]}
        #: the runs' events, summed (``RunResult.info["events"]`` of each)
        self.events = dict(fold.events)
        #: per estimate, the mean over runs of each packet count (:data:`PACKET_COUNTS`; None: not
        #: modelled, as for ``centralized``)
        self.packets = {name: None if c is None else {k: v / runs for k, v in c.items()}
                        for name, c in fold.packets.items()}
        #: the reference estimate of the paired comparisons (None: ``centralized`` if present)
        self.relative_to: str | None = None

    @property
    def reference(self) -> str | None:
        """The estimate the paired blocks compare with: ``relative_to``, else ``centralized``
        when the runs have it, else None (no paired comparison)."""
        return reference_of(self.estimates, self.relative_to)

    @classmethod
    def restored(cls, scenario, summary: dict, rows: list[dict], curves: dict) -> "MonteCarloResult":
        """A result read back from its folder (:func:`load_montecarlo`): ``summary`` (a checked
        ``summary.json``), ``rows`` (the checked ``runs.csv``), ``curves`` (the checked
        ``curves.npz``).  Its summary and table are recomputed from those rows and curves."""
        self = cls.__new__(cls)
        self.scenario = scenario
        self.plan = RunPlan.of(scenario)
        self.runs = int(summary["runs"])
        self.jobs = summary.get("jobs")
        self.executor = "(read back from its folder)"
        self.burn_in = check_burn_in(summary.get("burn_in"), int(scenario.steps))
        seeds = {int(r["run"]): int(r["seed"]) for r in rows}
        self.seeds = [seeds[r] for r in sorted(seeds)]
        self.rows = rows
        self.wall_time_s = float(summary.get("wall_time_s") or 0.0)
        self.t = np.asarray(curves["t"], dtype=float)
        self.components = list(curves["components"])
        self.estimates = list(curves["estimates"])
        A, K, nx = len(self.estimates), len(self.t), len(self.components)
        self.mse = np.asarray(curves["mse"], dtype=float)
        nan = np.full((A, K, nx), np.nan)
        self.mse_ci_lo = np.asarray(curves.get("mse_ci_lo", nan), dtype=float)
        self.mse_ci_hi = np.asarray(curves.get("mse_ci_hi", nan), dtype=float)
        self.nees = np.asarray(curves.get("nees", np.full((A, K), np.nan)), dtype=float)
        self.nees_band = nees_band(self.runs, nx)
        self.example = {k: np.asarray(curves[k], dtype=float) if k in curves else None
                        for k in ("example_truth", "example_x", "example_node0")}
        self.events = {}
        self.packets = {name: e.get("packets") for name, e in summary["estimates"].items()}
        self.relative_to = summary.get("relative_to")
        have = {(r["estimate"], r["component"]) for r in rows}
        missing = [(e, c) for e in self.estimates for c in self.components if (e, c) not in have]
        if missing or len(self.seeds) != self.runs:
            raise DkfsimError("runs.csv does not match curves.npz and summary.json ("
                              + (f"no row for estimate {missing[0][0]}, component {missing[0][1]}"
                                 if missing else f"{len(self.seeds)} runs, summary.json says {self.runs}")
                              + ")")
        if self.relative_to not in (None, *self.estimates):
            self.relative_to = None
        return self

    def __repr__(self) -> str:
        sc = self.scenario
        lines = [f"MonteCarloResult {sc.name}: {self.runs} runs x {sc.steps} ticks (base seed "
                 f"{sc.seed}), burn-in {self.burn_in} rows",
                 f"  MSE over runs with 95 % interval ({', '.join(self.components)}):"]
        width = max(len(n) for n in self.estimates)
        for name in self.estimates:
            cells = []
            for comp in self.components:
                mean, lo, hi = t_interval(self.column(name, "mse", comp))
                cells.append(f"{mean:.4g}" + ("" if math.isnan(lo) else f" ± {(hi - lo) / 2:.2g}"))
            lines.append(f"    {name.ljust(width)}  " + "   ".join(cells))
        lines.append("  (± is the 95 % half-width; .to_frame(): the runs.csv rows, "
                     ".to_xarray(): the curves)")
        return "<" + "\n".join(lines) + ">"

    def to_frame(self):
        """The per-run tidy rows (``runs.csv``) as a pandas DataFrame."""
        return rows_frame(self.rows, row_columns())

    def to_xarray(self):
        """The pooled curves (``curves.npz``) as an :class:`xarray.Dataset` on (``estimate``,
        ``tick``, ``state``): ``mse``, ``mse_ci_lo``, ``mse_ci_hi``, ``nees``; the NEES band
        and the run count are attributes."""
        sc = self.scenario
        return curves_dataset(self.t, self.estimates, self.components,
                              {"mse": self.mse, "mse_ci_lo": self.mse_ci_lo,
                               "mse_ci_hi": self.mse_ci_hi, "nees": self.nees},
                              attrs={"scenario": sc.name, "runs": self.runs,
                                     "base_seed": int(sc.seed), "burn_in": self.burn_in,
                                     "nees_band95": [float(v) for v in self.nees_band]})

    # ------------------------------------------------------------------ access
    def column(self, estimate: str, key: str, component: str | None = None) -> np.ndarray:
        """Per-run values of ``key`` (a ``runs.csv`` column) for one estimate, in run order.

        ``component`` defaults to the first one (per-run scalars such as
        ``anees`` repeat over components).
        """
        comp = self.components[0] if component is None else component
        vals = [row[key] for row in self.rows if row["estimate"] == estimate and row["component"] == comp]
        if not vals:
            raise KeyError(f"no rows for estimate {estimate!r}, component {comp!r}")
        return np.asarray(vals, dtype=float)

    def estimate_summary(self, estimate: str) -> dict:
        a = self.estimates.index(estimate)
        nx = len(self.components)
        out: dict = {"mse": {}, "mse_ci95": {}}
        for comp in self.components:
            mean, lo, hi = t_interval(self.column(estimate, "mse", comp))
            out["mse"][comp] = float(mean)
            out["mse_ci95"][comp] = [float(lo), float(hi)]
        an = anees_summary(self.nees[a], self.runs, nx, self.burn_in)
        per_run = self.column(estimate, "anees")
        _, lo, hi = t_interval(per_run) if not np.isnan(per_run).any() else (0, np.nan, np.nan)
        out["anees"] = float(an["anees"])
        out["anees_band95"] = [float(v) for v in an["band"]]
        out["anees_fraction_in_band"] = float(an["fraction_in_band"])
        out["anees_ci95"] = [float(lo), float(hi)]
        out["anees_consistent"] = anees_consistent(out["anees_ci95"], nx)
        ref = self.reference
        out["paired"] = None if ref is None else paired_block(self.rows, estimate, ref, self.components)
        out["packets"] = self.packets.get(estimate)
        for key in ("disagreement", "messages_per_tick", "bytes_per_tick", "lost", "late"):
            mean = float(np.mean(self.column(estimate, key)))
            out[key] = None if math.isnan(mean) else mean      # NaN rows: not modelled for it
        return out

    @cached_property
    def estimate_summaries(self) -> dict[str, dict]:
        """:meth:`estimate_summary` of every estimate, in order: the ``estimates`` block of
        :meth:`summary`, which :meth:`table` prints too (pooled once per result)."""
        return {name: self.estimate_summary(name) for name in self.estimates}

    def summary(self) -> dict:
        """The ``summary.json`` content."""
        sc = self.scenario
        return {
            "scenario": sc.name,
            "scenario_hash": scenario_hash(sc),
            "source": sc.source,
            "runs": self.runs,
            "base_seed": sc.seed,
            "seed_rule": "run r uses derive_seed(base_seed, r): SeedSequence(entropy=base_seed, "
                         "spawn_key=(r,)), first 64 state bits cut to 63",
            "steps": sc.steps,
            "protocol": sc.protocol,
            "fusion": sc.fusion,
            "buffer_length": self.plan.buffer_length(),
            "d_t": self.plan.d_t,
            "d_g": self.plan.exchange.d_g,
            "burn_in": self.burn_in,
            "jobs": self.jobs,
            "wall_time_s": self.wall_time_s,
            "versions": versions(),
            "components": self.components,
            "relative_to": self.reference,
            "notes": {
                "mse": "mean over runs of the per-run time average after burn-in; mse_ci95: "
                       "Student-t interval over runs",
                "anees": "time average after burn-in of the mean NEES over runs; anees_ci95: "
                         "Student-t interval over runs of the per-run time averages; "
                         "anees_consistent: anees_ci95[0] <= nx <= anees_ci95[1] (the consistency "
                         "verdict; null for a single run); anees_band95: per-tick 95% chi-square "
                         "band chi2.ppf([0.025, 0.975], runs*nx)/runs of the mean NEES at one tick "
                         "(not a band for the time average), anees_fraction_in_band: fraction of "
                         "ticks after burn-in whose mean NEES is inside it; per-node estimates: "
                         "NEES averaged over nodes (docs/statistics.md)",
                "paired": "per estimate against the reference estimate (relative_to), run by run "
                          "on common random numbers: mse_diff = mean over runs of mse - reference "
                          "mse, mse_diff_ci95 its Student-t interval over the paired runs; mse_ratio "
                          "= exp(mean of log(mse / reference mse)), mse_ratio_ci95 the exponentiated "
                          "t-interval of those log-ratios; null: no reference in these runs",
                "packets": "per estimate, the mean over runs of its packet counts: sent + copies = "
                           "delivered + lost + queue_dropped + crash_dropped + in_flight, and the parts "
                           "of lost by cause (outage_lost, range_lost, collision_lost); null: not modelled",
                "traffic": "messages_per_tick = packets the estimator sent / K; bytes_per_tick = "
                           "nominal bytes of those packets / K (16-byte header; the DKF: per row "
                           "8 + 8*(nx + nx(nx+1)/2) + ceil(n/8)); lost = packets, late = "
                           "contributions (the DKF) or stale packets; means over runs; null = "
                           "not modelled for that estimate",
            },
            "estimates": self.estimate_summaries,
            "scenario_config": sc.to_dict(),
        }

    # ------------------------------------------------------------------ output
    def save(self, out_dir) -> Path:
        """Write ``runs.csv``, ``curves.npz`` and ``summary.json`` into ``out_dir``."""
        summary = self.summary()
        examples = {k: v for k, v in self.example.items() if v is not None}
        with staged(out_dir, "montecarlo") as tmp:
            write_rows(tmp / "runs.csv", self.rows)
            np.savez(tmp / "curves.npz",
                     t=self.t, components=np.array(self.components), estimates=np.array(self.estimates),
                     mse=self.mse, mse_ci_lo=self.mse_ci_lo, mse_ci_hi=self.mse_ci_hi,
                     nees=self.nees, nees_band=self.nees_band, **examples)
            write_json(tmp / "summary.json", summary)
        return Path(out_dir)

    def table(self) -> str:
        """Algorithm x component: MSE with its 95 % CI; ANEES with its 95 % t-interval over runs
        and the consistency verdict; then the paired comparison with the reference estimate."""
        head: tuple[str, ...] = ("estimate", "component", "MSE", "95% CI", "ANEES", "95% CI (runs)",
                                 "consistent")
        summaries = self.estimate_summaries
        body: list[tuple[str, ...]] = []
        for name, s in summaries.items():
            for c, comp in enumerate(self.components):
                lo, hi = s["mse_ci95"][comp]
                ci = "-" if math.isnan(lo) else f"[{lo:.4g}, {hi:.4g}]"
                if c == 0 and not math.isnan(s["anees"]):
                    extra = (f"{s['anees']:.3f}", _pair(s["anees_ci95"], ".3f"),
                             {True: "yes", False: "no", None: "-"}[s["anees_consistent"]])
                else:
                    extra = ("", "", "")
                body.append((name if c == 0 else "", comp, f"{s['mse'][comp]:.4g}", ci, *extra))
        sc = self.scenario
        lines = [f"{sc.name}: {self.runs} runs x {sc.steps} ticks (base seed {sc.seed}), "
                 f"burn-in {self.burn_in} rows, on {self.executor}, {self.wall_time_s:.1f} s; "
                 f"ANEES expected {len(self.components)} (consistent: its interval covers it)",
                 *aligned([head, *body], left=(0, 1))]
        ref = self.reference
        if ref is not None and self.runs > 1:
            head = ("estimate", "component", f"MSE - {ref}", "95% CI (paired)", f"MSE / {ref}",
                    "95% CI (paired)")
            body = []
            for name, s in summaries.items():
                if name == ref:
                    continue
                p = s["paired"]
                for c, comp in enumerate(self.components):
                    d, r = p["mse_diff"][comp], p["mse_ratio"][comp]
                    body.append((name if c == 0 else "", comp, "-" if d is None else f"{d:.4g}",
                                 _pair(p["mse_diff_ci95"][comp]), "-" if r is None else f"{r:.4g}",
                                 _pair(p["mse_ratio_ci95"][comp])))
            if body:
                lines += ["", f"paired with {ref} over the {self.runs} runs (same draws; "
                              "ratio: exponentiated t-interval of the per-run log-ratios)",
                          *aligned([head, *body], left=(0, 1))]
        return "\n".join(lines)


def _pair(v, spec: str = ".4g") -> str:
    """``[lo, hi]`` of an interval, ``-`` when unknown."""
    if v is None or v[0] is None or v[1] is None or math.isnan(v[0]) or math.isnan(v[1]):
        return "-"
    return f"[{v[0]:{spec}}, {v[1]:{spec}}]"

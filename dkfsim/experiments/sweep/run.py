"""Running a sweep: the tasks left in the database go to an executor, the results come back here.

:func:`run_task` is what a worker computes; :func:`run_sweep` checks the database,
estimates the cost of what is left, submits it and writes every result as it arrives.
See :mod:`dkfsim.experiments.sweep` and docs/design.md.
"""

from __future__ import annotations

import os
import statistics
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from tqdm.auto import tqdm

from dkfsim.analysis.frames import rows_frame
from dkfsim.config.load import load_scenario
from dkfsim.config.plan import RunPlan
from dkfsim.core.errors import DkfsimError
from dkfsim.core.files import printable
from dkfsim.core.resources import EVENT_KINDS, Cost, check, many_runs_memory_hint
from dkfsim.core.threads import single_thread
from dkfsim.engine.driver import measured_estimate
from dkfsim.engine.estimate import TRIAL_ABOVE_S, estimate_run, smaller_run_hint
from dkfsim.experiments import executors
from dkfsim.experiments.montecarlo import derive_seed, run_scored
from dkfsim.experiments.sweep.definition import ParameterSet, Sweep, load_sweep
from dkfsim.experiments.sweep.grid import summarize
from dkfsim.experiments.sweep.results import read_results
from dkfsim.experiments.sweep.store import SweepDB, missing_estimates, tasks_done


# =========================================================================== one task (workers)
def run_task(scenario: dict, seed: int, burn_in: int | None, base_dir: str | None = None,
             only: list[str] | None = None) -> tuple[list[dict], float, dict[str, int]]:
    """Simulate and score one task where it runs; send back only the rows.

    Returns ``(rows, wall seconds, events)``; rows as
    :func:`dkfsim.experiments.montecarlo.run_rows` gives them, with plain Python numbers;
    ``only``: just the rows of these estimates; events: the run's (``RunResult.info["events"]``).
    """
    t0 = time.perf_counter()
    rows, _, events = run_scored(load_scenario(scenario, base_dir=base_dir), int(seed), burn_in=burn_in,
                                 curves=False)
    return [{k: _plain(v) for k, v in row.items()} for row in rows
            if only is None or row["estimate"] in only], time.perf_counter() - t0, events


def _only(scenario: dict, estimators: list[str] | None) -> dict:
    """``scenario`` running just the estimators named (all when None): an estimator's
    rows do not depend on the others it runs beside."""
    if estimators is None:
        return scenario
    return {**scenario, "estimators": [e for e in scenario.get("estimators", [])
                                       if (e.get("name") or e.get("kind")) in estimators]}


def _plain(v: Any) -> Any:
    if isinstance(v, (str, bool)) or v is None:
        return v
    if isinstance(v, int):
        return int(v)
    if isinstance(v, np.integer):
        return int(v)
    if isinstance(v, np.floating):
        return float(v)
    if isinstance(v, float):
        return float(v)
    return v



# =========================================================================== running
@dataclass
class SweepReport:
    """What :func:`run_sweep` did."""

    db: Path
    total: int
    skipped: int
    computed: int
    wall_s: float
    executor: str
    #: the computed tasks' events, summed (what the estimate predicted)
    events: dict = field(default_factory=dict)

    @property
    def runs_per_minute(self) -> float:
        return 60.0 * self.computed / self.wall_s if self.wall_s > 0 else float("nan")

    def __repr__(self) -> str:
        return (f"<SweepReport {self.db}: {self.total} tasks ({self.skipped} already stored, "
                f"{self.computed} computed in {self.wall_s:.1f} s on {self.executor}); "
                ".to_frame(): the stored rows, .summary(): mean and 95 % interval per grid point>")

    def to_frame(self):
        """Every stored row as a pandas DataFrame: the grid columns, then the tidy columns
        (the export's table, :func:`dkfsim.experiments.sweep.results.read_results`)."""
        columns, rows = read_results(self.db)
        return rows_frame(rows, columns)

    def summary(self, relative_to: str | None = None):
        """Per grid point, estimate and component: mean, 95 % interval, ANEES verdict, traffic,
        paired comparison with ``relative_to`` (default ``centralized``)
        (:func:`dkfsim.experiments.sweep.grid.summarize`; the file ``dkfsim sweep`` writes)."""
        columns, rows = summarize(*read_results(self.db), relative_to=relative_to)
        return rows_frame(rows, columns)


#: The refusal's hint of the Python API (``dkfsim sweep`` names its own flags).
API_HINT = "fewer runs or a smaller grid (the sweep file), or more jobs"


@single_thread
def run_sweep(sweep: Sweep | str | os.PathLike, *, seed: int | None = None, steps: int | None = None,
              overrides: Sequence[str] = (), burn_in: int | None = None, executor=None,
              jobs: int | None = None, progress: bool | Callable[[int, int], None] | None = None, db: str | os.PathLike | None = None,
              yes: bool = False, workers: int | None = None, hint: str = API_HINT,
              yes_flag: str = "yes=True") -> SweepReport:
    """Run (or resume) a sweep; return a :class:`SweepReport`.

    ``executor`` is a :mod:`dkfsim.experiments.executors` executor, or a callable that
    makes one (called only once the database is checked and some task is
    left to run; the executor it returns is closed here).  Default: ``jobs``
    local processes, every CPU if None.  ``progress``: a ``tqdm.auto`` bar (a
    widget in notebooks; default: when stderr is a terminal), or a callable
    ``progress(done, total)`` called after each task.  ``db`` overrides the output file.
    The remaining tasks are estimated first (``workers``: how many run at
    once, when ``executor`` is a callable): refused if they cannot fit in
    memory, and needing ``yes`` above 10 minutes (``hint`` and ``yes_flag``: what the refusal
    tells the caller to change, its keywords or, from ``dkfsim sweep``, its flags).
    ``seed``, ``steps`` and ``overrides`` (``dotted.key=value``, as ``--set``) change the sweep's
    scenario, ``burn_in`` its burn-in: the keywords of :func:`dkfsim.run`,
    :func:`dkfsim.montecarlo` and :func:`dkfsim.maxdelay` (a sweep given as a file or a mapping).
    """
    extra = [*overrides, *(f"{k}={int(v)}" for k, v in (("seed", seed), ("steps", steps)) if v is not None)]
    if isinstance(sweep, Sweep) and (extra or burn_in is not None):
        raise DkfsimError("seed, steps, overrides and burn_in change a sweep's file: give the sweep file "
                          "(or mapping), not a loaded Sweep")
    if not isinstance(sweep, Sweep):
        sweep = load_sweep(sweep, output=db, yes=yes, overrides=extra, burn_in=burn_in)
    path = Path(db) if db is not None else sweep.output
    if progress is None:
        progress = sys.stderr.isatty()
    if workers is None:
        workers = executor.workers if isinstance(executor, executors.Executor) else \
            (jobs or executors.available_cpus())
    # Estimated before the database is created or changed: a refusal leaves no trace.
    est = estimate_tasks(sweep, tasks_done(path, sweep), workers)
    check(est, yes=yes, hint=hint, yes_flag=yes_flag, memory_hint=many_runs_memory_hint(
        est.workers, smaller_run_hint("steps in the sweep file")))
    with SweepDB(path, sweep) as store:
        done, missing = store.done(), missing_estimates(store, sweep)
        # Runs not done yet (every estimate), then estimators added to runs done before.
        todo: list[tuple[ParameterSet, int, list[str] | None]] = [
            (p, r, None) for p, r in sweep.tasks() if (p.param_hash, r) not in done]
        todo += [(p, r, missing[p.param_hash, r]) for p, r in sweep.tasks()
                 if (p.param_hash, r) in missing]
        skipped = sweep.n_tasks - len(todo)
        if not todo:
            executor, own = executors.InlineExecutor(), True   # nothing to start
        else:
            executor, own = executors.executor_for(executor, jobs, len(todo))
        label = executor.label
        t0 = time.perf_counter()
        computed = 0
        events: dict[str, int] = {}
        bar = None
        if progress is True and todo:
            bar = tqdm(total=sweep.n_tasks, initial=skipped, unit="run", desc=printable(sweep.name),
                       file=sys.stderr, dynamic_ncols=True, smoothing=0.1)
        report = progress if callable(progress) else None
        try:
            if todo:
                tasks = (((p.param_hash, r, seed, only is None),
                          (_only(p.scenario.to_dict(), only), seed, sweep.burn_in,
                           p.scenario.base_dir, only))
                         for p, r, only in todo for seed in (derive_seed(p.base_seed, r),))
                for (h, r, seed, whole), (rows, wall, ev) in executor.imap_unordered(run_task, tasks):
                    store.write_task(h, r, seed, rows, wall, whole=whole)
                    computed += 1
                    for key, count in ev.items():
                        events[key] = events.get(key, 0) + count
                    if bar is not None:
                        bar.update(1)
                    if report is not None:
                        report(skipped + computed, sweep.n_tasks)
        except KeyboardInterrupt:
            if bar is not None:
                bar.close()
                bar = None
            print(f"dkfsim sweep: interrupted; {skipped + computed} of {sweep.n_tasks} tasks are "
                  f"saved in {path}: re-run the same command to resume", file=sys.stderr)
            raise
        finally:
            if bar is not None:
                bar.close()
            if own:
                executor.close()
        wall = time.perf_counter() - t0
    return SweepReport(db=path, total=sweep.n_tasks, skipped=skipped, computed=computed,
                       wall_s=wall, executor=label, events=events)


#: The parameter sets of a sweep measured on a trial, at most (spread over the grid); the others'
#: guesses are scaled by what the trials found (their median measured / guessed time).
MAX_TRIALS = 12


def estimate_tasks(sweep: Sweep, done: set, workers: int, force_trial: bool = False) -> Cost:
    """Memory and time of the tasks of ``sweep`` not yet in ``done``: each parameter set's run
    guessed, and measured on a trial (:func:`~dkfsim.engine.driver.measured_estimate`) when the
    guess of what is left is long (or ``force_trial``): every set's, or :data:`MAX_TRIALS` of them
    and the others scaled alike."""
    est = Cost(f"{sweep.source}: {sweep.n_tasks - len(done):,} tasks left of {sweep.n_tasks:,}",
               workers=max(1, workers))
    sets = sweep.parameter_sets
    left = [sweep.runs - sum((p.param_hash, r) in done for r in range(min(sweep.runs, 10**6))) for p in sets]
    plans = [RunPlan.of(p.scenario, "estimates") for p in sets]
    guesses = [estimate_run(plan) for plan in plans]
    long = sum(g.seconds * n for g, n in zip(guesses, left)) / est.workers > TRIAL_ABOVE_S
    ones = list(guesses)
    if long or force_trial:
        chosen = [i for i in range(len(sets)) if left[i]]
        if len(chosen) > MAX_TRIALS:
            chosen = [chosen[round(j * (len(chosen) - 1) / (MAX_TRIALS - 1))] for j in range(MAX_TRIALS)]
        for i in chosen:
            ones[i] = measured_estimate(plans[i], force=True)
        if chosen and len(chosen) < len(sets):
            ratio = statistics.median(ones[i].seconds / max(guesses[i].seconds, 1e-12) for i in chosen)
            events = {k: statistics.median(ones[i].events[k] / max(guesses[i].seconds, 1e-12) for i in chosen)
                      for k in EVENT_KINDS}
            for i in set(range(len(sets))) - set(chosen):
                g = guesses[i]
                ones[i] = Cost(g.what, g.memory, g.seconds * ratio, events={k: v * g.seconds for k, v in events.items()},
                               how=f"scaled from the trials of {len(chosen)} parameter sets")
        est.how = ones[chosen[0]].how if len(chosen) == len(sets) else \
            f"measured on trials of {len(chosen)} of the {len(sets)} parameter sets, the others scaled alike"
        est.events = {k: 0.0 for k in EVENT_KINDS}
    biggest = 0.0
    for one, n in zip(ones, left):
        est.seconds += one.seconds * n
        biggest = max(biggest, one.bytes)
        for k, v in one.events.items():
            est.events[k] = est.events.get(k, 0.0) + v * n
    est.memory["one run per worker"] = biggest * est.workers
    est.memory["task list"] = (sweep.n_tasks - len(done)) * 200.0
    return est

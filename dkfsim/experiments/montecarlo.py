"""Monte Carlo over independent runs: ``dkfsim montecarlo FILE --runs N``.

Run ``r`` (``r = 0 .. N-1``) is the scenario with its seed replaced by
:func:`derive_seed` ``(scenario.seed, r)``, so run ``r`` is the same run
whatever ``N`` and whatever the number of worker processes ``J``.  Every
random stream of a run derives from that seed (truth, sensors, links, and a
*random topology* too: fix ``topology.params.seed`` to keep one graph over
all runs).

Each run is scored where it ran (:func:`run_rows`) and sends back only small
data: per algorithm the squared error per tick and component ``(K, nx)``
(averaged over nodes for per-node algorithms), the NEES per tick ``(K,)``
and per-run scalars.  The parent folds the runs in run order, whatever order
they finish in, so every output is identical for any ``J``.

Algorithms of a run (names in every output):

========================  ===========================  =========================
algorithm                 arrays                       note
========================  ===========================  =========================
``anti_delay_dkf``        ``x_fused``, ``P_fused``     absent with ``fusion: none``
``anti_delay_dkf_local``  ``x_local``, ``P_local``     per node
``<baseline>``            ``x_<baseline>``, ...        in the scenario's order;
                                                       ``local`` is ``x_local_only``
========================  ===========================  =========================

Per-node algorithms are scored by the mean over nodes (squared error, NEES)
and have a ``disagreement`` (:func:`dkfsim.analysis.metrics.disagreement`); the
others have ``disagreement = NaN``.

Traffic per run (``messages_per_tick`` = packets sent / K, ``lost``
packets, ``late`` contributions):

* ``anti_delay_dkf`` and ``anti_delay_dkf_local``: the run's network counts;
* ``no_buffer`` (and any baseline that reports ``counts_<name>``): its own
  network's counts;
* ``ci_consensus`` (and any baseline that reports ``<name>_sent``): its own
  packets; ``late`` is ``<name>_late`` if reported, else ``<name>_stale``
  (for ``ci_consensus``: neighbour pairs used after being predicted forward
  from an older tick, i.e. information that arrived late);
* ``centralized_delayed``: one direct packet per sensor and tick; ``lost``
  counted from the same draws the baseline used;
* ``local``: no communication (zeros);
* ``centralized`` (idealised, no network model) and anything else that
  reports no counts: NaN.

``bytes_per_tick`` is ``messages_per_tick`` times the nominal size of a
packet carrying ONE window row (:func:`dkfsim.analysis.metrics.packet_bytes`).  The
engine does not count rows per packet; an anti-delay packet carries every
changed row of its window, so for ``anti_delay_dkf`` this is a lower bound
of the nominal traffic (exact for ``no_buffer``, whose window is one row).
"""

from __future__ import annotations

import csv
import math
import signal
import sys
import time
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from pathlib import Path

import numpy as np

from dkfsim.core.errors import DkfsimError
from dkfsim.experiments.executors import kill_pool
from dkfsim.core.folders import check_target, csv_cell, staged, write_json
from dkfsim.core.resources import Estimate, check, estimate_run, repeat
from dkfsim.core.threads import pin_process, single_thread
from dkfsim.analysis.metrics import (anees_summary, default_burn_in, disagreement, nees_band, nees_per_tick,
                      packet_bytes, squared_error, t_interval, t_interval_from_moments)

#: Columns of ``runs.csv``, in order.
CSV_COLUMNS = ("run", "seed", "algorithm", "component", "mse", "anees", "disagreement",
               "messages_per_tick", "bytes_per_tick", "lost", "late")

#: Algorithm names of the anti-delay DKF's own estimates, by array.
OWN_ALGORITHMS = (("anti_delay_dkf", "x_fused", "P_fused"),
                  ("anti_delay_dkf_local", "x_local", "P_local"))

#: Baselines whose arrays are not named after them.
BASELINE_ARRAYS = {"local": "local_only"}

_NOT_ALGORITHMS = {"x_local", "x_final", "x_fused", "x0_mean"}


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


def component_names(scenario) -> list[str]:
    """The scenario's state component names (see :func:`dkfsim.config.schema.component_names`)."""
    from dkfsim.config.schema import component_names as names
    return names(scenario.model.kind, scenario.nx)


def algorithms_of(arrays, baselines) -> list[tuple[str, str, str]]:
    """``(algorithm, x key, P key)`` of every estimate in a run's arrays, in output order."""
    out = [(name, xk, pk) for name, xk, pk in OWN_ALGORITHMS if xk in arrays]
    seen = {xk for _, xk, _ in out}
    for b in baselines:
        xk = "x_" + BASELINE_ARRAYS.get(b, b)
        if xk in arrays and xk not in seen:
            out.append((b, xk, "P_" + xk[2:]))
            seen.add(xk)
    # Estimates a baseline returned under another name: keep them, after the rest.
    for xk in sorted(arrays):
        if xk.startswith("x_") and xk not in _NOT_ALGORITHMS and xk not in seen:
            out.append((xk[2:], xk, "P_" + xk[2:]))
    return out


def _check_burn_in(burn_in: int | None, K: int) -> int:
    if burn_in is None:
        return default_burn_in(K)
    if not 0 <= int(burn_in) < K:
        raise DkfsimError(f"--burn-in: must be in [0, steps) = [0, {K}), got {burn_in}")
    return int(burn_in)


# =========================================================================== one run
def _traffic(name: str, sim, res) -> dict:
    """Per-run packet counts of one algorithm (see the module docstring)."""
    n, nx, K = sim.system.n, sim.system.nx, sim.K
    nan = float("nan")
    counts = res.counts
    sent = lost = late = nan
    if name in ("anti_delay_dkf", "anti_delay_dkf_local"):
        sent, lost, late = counts["sent"], counts["lost"], counts["late"]
    elif name == "local":
        sent = lost = late = 0
    elif isinstance(counts.get(f"counts_{name}"), dict):
        own = counts[f"counts_{name}"]
        sent, lost, late = own.get("sent", nan), own.get("lost", nan), own.get("late", nan)
    elif f"{name}_sent" in counts:                  # flat side facts, e.g. ci_consensus_sent
        sent, lost = counts[f"{name}_sent"], counts.get(f"{name}_lost", nan)
        late = counts.get(f"{name}_late", counts.get(f"{name}_stale", nan))
    elif name == "centralized_delayed":
        from dkfsim.estimators.baselines import direct_arrival_ticks
        sent = n * K
        lost = int((direct_arrival_ticks(sim) == 0).sum())
    if f"late_{name}" in counts:
        late = counts[f"late_{name}"]
    mpt = sent / K
    return {"messages_per_tick": float(mpt), "bytes_per_tick": float(mpt * packet_bytes(nx, n, 1)),
            "lost": lost, "late": late}


def pinned_topology(scenario) -> list[str]:
    """Overrides that keep a random topology fixed across Monte Carlo runs.

    A seeded generator without ``topology.params.seed`` draws its graph from
    the scenario seed; Monte Carlo runs vary that seed to redraw noise and
    latencies, not the network, so the graph is pinned to the *base* seed.
    """
    from dkfsim.config.schema import load_scenario
    from dkfsim.components.topology import GENERATOR_PARAMS
    sc = load_scenario(scenario)
    topo = sc.topology
    if "seed" in GENERATOR_PARAMS[topo.generator][1] and "seed" not in (topo.params or {}):
        return [f"topology.params.seed={int(sc.seed)}"]
    return []


def run_rows(scenario, seed: int, burn_in: int | None = None) -> tuple[list[dict], dict]:
    """Simulate ``scenario`` with seed ``seed`` and score every algorithm.

    Returns ``(rows, curves)``.  ``rows``: one dict per algorithm x component
    with keys ``seed, algorithm, component, mse`` (time average of the
    squared error after ``burn_in`` rows), ``anees`` (time-averaged NEES
    after burn-in; NaN without covariance), ``disagreement`` (NaN for single
    estimates), ``messages_per_tick, bytes_per_tick, lost, late``.
    ``curves``: ``t`` (K,), ``components``, ``algorithms``, ``se``
    (A, K, nx) squared error per tick, ``nees`` (A, K), ``example_truth``
    (K, nx), ``example_x`` (A, K, nx) (node 0 for per-node algorithms),
    ``example_node0`` (K, nx) (``x_local`` of node 0).

    ``scenario`` is a :class:`~dkfsim.config.schema.Scenario`, a dict or a file;
    ``burn_in`` defaults to 10 % of the ticks.
    """
    from dkfsim.config.schema import load_scenario
    from dkfsim.engine.driver import Simulation
    sc = load_scenario(scenario, overrides=pinned_topology(scenario) + [f"seed={int(seed)}"])
    burn = _check_burn_in(burn_in, int(sc.steps))
    with np.errstate(all="ignore"):          # a diverging run gives inf / nan rows, no warnings
        sim = Simulation(sc, save="estimates")
        res = sim.run()
        return _score(sc, sim, res, seed, burn)


def _score(sc, sim, res, seed: int, burn: int) -> tuple[list[dict], dict]:
    """Rows and curves of one finished run (see :func:`run_rows`)."""
    K = int(sc.steps)
    arrays = res.arrays
    truth = arrays["truth"]
    algs = algorithms_of(arrays, sc.baselines)
    comps = component_names(sc)
    A, nx = len(algs), truth.shape[1]
    se = np.empty((A, K, nx))
    nees = np.full((A, K), np.nan)
    ex = np.empty((A, K, nx))
    rows = []
    for a, (name, xk, pk) in enumerate(algs):
        x = np.asarray(arrays[xk])
        se[a] = squared_error(x, truth)
        if pk in arrays:
            nees[a] = nees_per_tick(x, np.asarray(arrays[pk]), truth)
        ex[a] = x if x.ndim == 2 else x[:, 0]
        mse = se[a, burn:].mean(axis=0)
        anees = float(nees[a, burn:].mean())
        dis = disagreement(x, burn) if x.ndim == 3 else float("nan")
        traffic = _traffic(name, sim, res)
        for c, comp in enumerate(comps):
            rows.append({"seed": int(seed), "algorithm": name, "component": comp,
                         "mse": float(mse[c]), "anees": anees, "disagreement": dis, **traffic})
    curves = {"t": np.asarray(arrays["t"]), "components": comps, "algorithms": [a[0] for a in algs],
              "se": se, "nees": nees, "example_truth": truth, "example_x": ex,
              "example_node0": np.asarray(arrays["x_local"])[:, 0]}
    return rows, curves


# =========================================================================== workers
_WORKER_SCENARIO = None


def _init_worker(scenario) -> None:
    """Keep the scenario once per worker; leave Ctrl-C to the parent (no worker tracebacks)."""
    global _WORKER_SCENARIO
    pin_process()                     # one BLAS thread: the parallelism is the processes
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    _WORKER_SCENARIO = scenario


def _one(scenario, r: int, seed: int, burn_in: int) -> tuple[int, list[dict], dict]:
    try:
        rows, curves = run_rows(scenario, seed, burn_in)
    except DkfsimError as exc:      # e.g. a random topology that is disconnected for this seed
        raise DkfsimError(f"run {r} (seed {seed}): {exc}") from None
    if r != 0:       # only run 0 is kept as the example: do not ship the rest
        for key in ("example_truth", "example_x", "example_node0"):
            del curves[key]
    return r, rows, curves


def _worker_run(r: int, seed: int, burn_in: int):
    return _one(_WORKER_SCENARIO, r, seed, burn_in)




# =========================================================================== pooling
class _Fold:
    """Running pool of the per-tick curves, fed in run order (Welford)."""

    def __init__(self):
        self.n = 0
        self.mean = self.m2 = self.nees_sum = None
        self.first = None

    def add(self, curves: dict) -> None:
        se, nees = curves["se"], curves["nees"]
        if self.n == 0:
            self.first = curves
            self.mean = np.zeros_like(se)
            self.m2 = np.zeros_like(se)
            self.nees_sum = np.zeros_like(nees)
        elif curves["algorithms"] != self.first["algorithms"]:
            raise DkfsimError("runs report different algorithms "
                              f"({self.first['algorithms']} vs {curves['algorithms']})")
        self.n += 1
        d = se - self.mean
        self.mean += d / self.n
        self.m2 += d * (se - self.mean)
        self.nees_sum += nees


@single_thread
def montecarlo(scenario, runs: int, jobs: int = 1, burn_in: int | None = None,
               progress=None, yes: bool = False) -> "MonteCarloResult":
    """``runs`` independent runs of ``scenario`` on ``jobs`` local processes.

    ``scenario``: a Scenario, a path or a mapping.  Run ``r`` uses seed
    ``derive_seed(scenario.seed, r)``.  ``jobs = 1`` runs in this process.
    ``progress(done, total)`` is called after each run.  The result does not
    depend on ``jobs``.  Work that cannot fit in memory is refused, and work
    estimated above 10 minutes needs ``yes`` (:mod:`dkfsim.core.resources`).
    """
    from dkfsim.config.schema import Scenario, load_scenario
    if isinstance(runs, bool) or not isinstance(runs, int) or runs < 1:
        raise DkfsimError(f"--runs: must be an integer >= 1, got {runs!r}")
    if isinstance(jobs, bool) or not isinstance(jobs, int) or jobs < 1:
        raise DkfsimError(f"--jobs: must be an integer >= 1, got {jobs!r}")
    sc = scenario if isinstance(scenario, Scenario) else load_scenario(scenario)
    burn = _check_burn_in(burn_in, int(sc.steps))
    check_montecarlo(sc, runs, jobs, yes=yes)
    seeds = [derive_seed(sc.seed, r) for r in range(runs)]
    rows: list[dict] = []
    fold = _Fold()
    t0 = time.perf_counter()

    def take(r, run_rows_, curves):
        rows.extend({"run": r, **row} for row in run_rows_)
        fold.add(curves)

    if jobs == 1:
        for r, seed in enumerate(seeds):
            take(*_one(sc, r, seed, burn))
            if progress is not None:
                progress(r + 1, runs)
    else:
        pending: dict[int, tuple] = {}
        nxt = 0
        pool = ProcessPoolExecutor(max_workers=min(jobs, runs), initializer=_init_worker,
                                   initargs=(sc,))
        try:
            # Keep at most 2 * jobs runs submitted: results that finish early wait
            # in `pending` until every earlier run is folded.
            todo = iter(enumerate(seeds))
            active = set()
            index = {}
            done_count = 0
            while True:
                while len(active) < 2 * jobs:
                    item = next(todo, None)
                    if item is None:
                        break
                    fut = pool.submit(_worker_run, item[0], item[1], burn)
                    index[fut] = item[0]
                    active.add(fut)
                if not active:
                    break
                finished, active = wait(active, return_when=FIRST_COMPLETED)
                for fut in finished:
                    r = index.pop(fut)
                    try:
                        pending[r] = fut.result()[1:]
                    except DkfsimError as exc:   # raised in run order, as with jobs = 1
                        pending[r] = exc
                    done_count += 1
                    if progress is not None:
                        progress(done_count, runs)
                while nxt in pending:
                    got = pending.pop(nxt)
                    if isinstance(got, BaseException):
                        raise got
                    take(nxt, *got)
                    nxt += 1
        except BaseException:
            kill_pool(pool)
            raise
        pool.shutdown(wait=True)
    wall = time.perf_counter() - t0
    return MonteCarloResult(sc, runs, jobs, burn, seeds, rows, fold, wall)


def estimate_montecarlo(sc, runs: int, jobs: int) -> Estimate:
    """Memory and time of ``runs`` runs on ``jobs`` processes, rows and curves included."""
    one = estimate_run(sc, "estimates")
    algorithms = 2 + len(sc.baselines)
    K, nx = int(sc.steps), sc.nx
    kept = runs * algorithms * nx * 600 + 6 * algorithms * K * nx * 8     # rows; pooled curves
    return repeat(one, f"{sc.name}: a Monte Carlo of {runs} runs x {K} ticks", runs,
                  min(jobs, runs), extra_bytes=kept)


def check_montecarlo(sc, runs: int, jobs: int, *, yes: bool = False) -> Estimate:
    est = estimate_montecarlo(sc, runs, jobs)
    check(est, yes=yes, hint="fewer runs or steps, or more --jobs")
    return est


# =========================================================================== the result
class MonteCarloResult:
    """Pooled result of :func:`montecarlo`.

    ``rows``: the tidy per-run table (``runs.csv``), in run order.
    ``t, components, algorithms, mse, mse_ci_lo, mse_ci_hi, nees, nees_band``
    and ``example`` (run 0): the arrays of ``curves.npz``.
    """

    def __init__(self, scenario, runs, jobs, burn_in, seeds, rows, fold: _Fold, wall):
        self.scenario = scenario
        self.runs = runs
        self.jobs = jobs
        self.burn_in = burn_in
        self.seeds = seeds
        self.rows = rows
        self.wall_time_s = wall
        first = fold.first
        self.t = first["t"]
        self.components = list(first["components"])
        self.algorithms = list(first["algorithms"])
        self.mse = fold.mean
        self.mse_ci_lo, self.mse_ci_hi = t_interval_from_moments(fold.mean, fold.m2, fold.n)
        self.nees = fold.nees_sum / fold.n
        self.nees_band = nees_band(runs, len(self.components))
        self.example = {"example_truth": first["example_truth"], "example_x": first["example_x"],
                        "example_node0": first["example_node0"]}

    # ------------------------------------------------------------------ access
    def column(self, algorithm: str, key: str, component: str | None = None) -> np.ndarray:
        """Per-run values of ``key`` (a ``runs.csv`` column) for one algorithm, in run order.

        ``component`` defaults to the first one (per-run scalars such as
        ``anees`` repeat over components).
        """
        comp = self.components[0] if component is None else component
        vals = [row[key] for row in self.rows if row["algorithm"] == algorithm and row["component"] == comp]
        if not vals:
            raise KeyError(f"no rows for algorithm {algorithm!r}, component {comp!r}")
        return np.asarray(vals, dtype=float)

    def algorithm_summary(self, algorithm: str) -> dict:
        a = self.algorithms.index(algorithm)
        nx = len(self.components)
        out = {"mse": {}, "mse_ci95": {}}
        for comp in self.components:
            mean, lo, hi = t_interval(self.column(algorithm, "mse", comp))
            out["mse"][comp] = float(mean)
            out["mse_ci95"][comp] = [float(lo), float(hi)]
        an = anees_summary(self.nees[a], self.runs, nx, self.burn_in)
        per_run = self.column(algorithm, "anees")
        _, lo, hi = t_interval(per_run) if not np.isnan(per_run).any() else (0, np.nan, np.nan)
        out["anees"] = float(an["anees"])
        out["anees_band95"] = [float(v) for v in an["band"]]
        out["anees_fraction_in_band"] = float(an["fraction_in_band"])
        out["anees_ci95"] = [float(lo), float(hi)]
        for key in ("disagreement", "messages_per_tick", "bytes_per_tick", "lost", "late"):
            mean = float(np.mean(self.column(algorithm, key)))
            out[key] = None if math.isnan(mean) else mean      # NaN rows: not modelled for it
        return out

    def summary(self) -> dict:
        from dkfsim.engine.results import versions
        from dkfsim.config.schema import scenario_hash
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
            "buffer_length": sc.resolved_buffer_length(),
            "d_t": sc.resolved_d_t(),
            "d_g": sc.exchange().d_g,
            "burn_in": self.burn_in,
            "jobs": self.jobs,
            "wall_time_s": self.wall_time_s,
            "versions": versions(),
            "components": self.components,
            "notes": {
                "mse": "mean over runs of the per-run time average after burn-in; mse_ci95: "
                       "Student-t interval over runs",
                "anees": "time average after burn-in of the mean NEES over runs; anees_band95: "
                         "per-tick 95% chi-square band chi2.ppf([0.025, 0.975], runs*nx)/runs; "
                         "anees_fraction_in_band: fraction of ticks after burn-in whose mean NEES "
                         "is inside it; anees_ci95: Student-t interval of the per-run time averages; "
                         "per-node algorithms: NEES averaged over nodes",
                "traffic": "messages_per_tick = packets sent / K; bytes_per_tick assumes ONE "
                           "window row per packet (16 + 8*(nx + nx(nx+1)/2) + ceil(n/8) bytes); "
                           "lost = packets, late = contributions; means over runs; null = not "
                           "modelled for that algorithm",
            },
            "algorithms": {name: self.algorithm_summary(name) for name in self.algorithms},
            "scenario_config": sc.to_dict(),
        }

    # ------------------------------------------------------------------ output
    def save(self, out_dir) -> Path:
        """Write ``runs.csv``, ``curves.npz`` and ``summary.json`` into ``out_dir``."""
        summary = self.summary()
        with staged(out_dir, "montecarlo") as tmp:
            with open(tmp / "runs.csv", "w", newline="") as fh:
                w = csv.writer(fh, lineterminator="\n")
                w.writerow(CSV_COLUMNS)
                for row in self.rows:
                    w.writerow([csv_cell(row[c]) for c in CSV_COLUMNS])
            np.savez(tmp / "curves.npz",
                     t=self.t, components=np.array(self.components), algorithms=np.array(self.algorithms),
                     mse=self.mse, mse_ci_lo=self.mse_ci_lo, mse_ci_hi=self.mse_ci_hi,
                     nees=self.nees, nees_band=self.nees_band, **self.example)
            write_json(tmp / "summary.json", summary)
        return Path(out_dir)

    def table(self) -> str:
        """Algorithm x component: MSE with its 95 % CI; ANEES with its per-tick band."""
        head = ("algorithm", "component", "MSE", "95% CI", "ANEES", "95% band (per tick)", "in band")
        body = []
        for name in self.algorithms:
            s = self.algorithm_summary(name)
            for c, comp in enumerate(self.components):
                lo, hi = s["mse_ci95"][comp]
                ci = "-" if math.isnan(lo) else f"[{lo:.4g}, {hi:.4g}]"
                if c == 0 and not math.isnan(s["anees"]):
                    b = s["anees_band95"]
                    extra = (f"{s['anees']:.3f}", f"[{b[0]:.3f}, {b[1]:.3f}]",
                             f"{100 * s['anees_fraction_in_band']:.0f}%")
                else:
                    extra = ("", "", "")
                body.append((name if c == 0 else "", comp, f"{s['mse'][comp]:.4g}", ci, *extra))
        rows = [head, *body]
        widths = [max(len(r[i]) for r in rows) for i in range(len(head))]
        left = {0, 1}
        fmt = lambda r: "  " + "  ".join(v.ljust(w) if i in left else v.rjust(w)  # noqa: E731
                                         for i, (v, w) in enumerate(zip(r, widths))).rstrip()
        sc = self.scenario
        lines = [f"{sc.name}: {self.runs} runs x {sc.steps} ticks (base seed {sc.seed}), "
                 f"burn-in {self.burn_in} rows, {self.jobs} job(s), {self.wall_time_s:.1f} s; "
                 f"ANEES expected {len(self.components)}",
                 fmt(head), "  " + "  ".join("-" * w for w in widths)]
        lines += [fmt(r) for r in body]
        return "\n".join(lines)


# =========================================================================== CLI
def add_command(subparsers) -> None:
    from dkfsim.cli.main import add_scenario_args, add_yes_arg
    p = subparsers.add_parser(
        "montecarlo", help="N independent runs of a scenario: MSE with confidence intervals, ANEES, traffic",
        description="Run a scenario N times with derived seeds (run r uses derive_seed(seed, r), "
                    "the same whatever N and --jobs) and pool the results per algorithm and state "
                    "component: MSE over time with 95% confidence intervals, ANEES with its 95% "
                    "chi-square band, disagreement between nodes, messages, bytes, lost packets and "
                    "late contributions. Writes DIR/runs.csv (one row per run x algorithm x "
                    "component), DIR/curves.npz (per-tick curves and one example run) and "
                    "DIR/summary.json, and prints a table.")
    add_scenario_args(p)
    p.add_argument("--runs", type=int, required=True, metavar="N",
                   help="number of independent runs (>= 1)")
    p.add_argument("--jobs", type=int, default=1, metavar="J",
                   help="worker processes on this machine (>= 1; 1 runs in this process; "
                        "results do not depend on it) (default: 1)")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder (created if missing)")
    p.add_argument("--burn-in", type=int, metavar="ROWS",
                   help="rows skipped before time-averaging MSE, ANEES and disagreement "
                        "(default: 10%% of the ticks)")
    p.add_argument("--steps", type=int, metavar="K",
                   help="override the number of ticks K of every run (same as --set steps=K)")
    p.add_argument("--seed", type=int, metavar="S",
                   help="override the base seed from which every run's seed derives (same as --set seed=S)")
    p.add_argument("--quiet", action="store_true",
                   help="no progress bar and no table (the bar is shown on stderr only when it is a terminal)")
    add_yes_arg(p)
    p.set_defaults(func=cmd_montecarlo)


def cmd_montecarlo(args) -> int:
    from dkfsim.cli.main import load_from_args
    if args.runs < 1:
        raise DkfsimError(f"--runs: must be >= 1, got {args.runs}")
    if args.jobs < 1:
        raise DkfsimError(f"--jobs: must be >= 1, got {args.jobs}")
    sc = load_from_args(args)
    _check_burn_in(args.burn_in, int(sc.steps))
    check_target(args.out)                 # before any run: a bad --out costs nothing
    check_montecarlo(sc, args.runs, args.jobs, yes=args.yes)
    bar = progress = None
    if not args.quiet and sys.stderr.isatty():
        from tqdm import tqdm
        bar = tqdm(total=args.runs, unit="run", desc=sc.name, leave=False, file=sys.stderr)

        def progress(done, total):
            bar.update(done - bar.n)
    try:
        res = montecarlo(sc, args.runs, jobs=args.jobs, burn_in=args.burn_in, progress=progress,
                         yes=True)                              # checked above
    finally:
        if bar is not None:
            bar.close()
    out = res.save(args.out)
    if not args.quiet:
        print(res.table())
        print(f"wrote {out / 'runs.csv'}, {out / 'curves.npz'} and {out / 'summary.json'}")
    return 0

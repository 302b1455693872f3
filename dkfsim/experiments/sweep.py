"""Parameter sweeps: ``dkfsim sweep SWEEP.yaml``.

A sweep file names a scenario, a grid of scenario keys (dotted paths, as
``--set``) whose cartesian product gives the *parameter sets*, fixed
overrides, and a number of Monte Carlo runs per parameter set::

    scenario: paper_case1.yaml          # relative to the sweep file
    grid:
      links.default.latency.d_t: [0, 1, 2, 3, 4]
      protocol: [tree, flood]
    set: ["steps=300", "baselines=[centralized]"]
    runs: 20
    burn_in: null                       # rows; null = 10 % of the ticks
    output: results.sqlite              # default: <sweep file stem>.sqlite beside it

A *task* is (parameter set, run ``r``); run ``r`` uses seed
``derive_seed(base seed of the parameter set, r)``
(:func:`dkfsim.experiments.montecarlo.derive_seed`) and is scored by
:func:`dkfsim.experiments.montecarlo.run_rows`.  Workers only compute
(:mod:`dkfsim.experiments.executors`); this process writes every result into one SQLite
file, one transaction per task, so a task's rows are there entirely or not
at all.  Re-running the same command after an interruption (Ctrl-C,
``kill -9``, a lost cluster) skips the tasks already in the file.

Decisions:

* **The tidy rows every output shares**: one row per (parameter set, run,
  estimate, state component), every registered metric a column
  (:func:`dkfsim.analysis.metrics.score`), the grid values in front.  NaN
  (not applicable) is stored as NULL (SQLite has no NaN) and exported as an
  empty cell / Parquet null.
* **The file stores its sweep definition** (grid, ``set``, ``runs``,
  ``burn_in`` and the hash of every resolved parameter set's scenario) and
  refuses to resume from a different one, including a changed scenario file
  that changes what a parameter set simulates.  Editing comments, moving the
  files or changing ``output`` does not matter.
* ``param_hash`` is the sha256 (first 20 hex digits) of the canonical JSON of
  the parameter set's grid values, so it does not depend on the grid's order.
* Tasks are submitted run-major (run 0 of every parameter set, then run 1,
  ...), so an interrupted sweep holds a balanced picture.
* Exports are sorted by (parameter set in grid order, run, estimate, component), so the
  file is byte-identical whatever executor, worker count or interruptions
  produced the database.
* One process at a time may write a database (an advisory lock on the file);
  a second ``dkfsim sweep`` on it stops with a clear message.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import math
import os
import sqlite3
import stat
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterator, Mapping

import numpy as np
import yaml
from tqdm import tqdm

try:
    import fcntl
except ImportError:  # pragma: no cover  (Windows)
    fcntl = None

from dkfsim.experiments import executors
from dkfsim.core.errors import DkfsimError, ScenarioError
from dkfsim.config.load import load_scenario, scenario_hash
from dkfsim.core.registry import METRICS
from dkfsim.core.resources import C_VALIDATE, Cost, check
from dkfsim.core.version import __version__
from dkfsim.engine.estimate import estimate_run
from dkfsim.experiments.montecarlo import derive_seed, run_rows
from dkfsim.core.threads import single_thread
from dkfsim.config.yaml import parse_yaml, yaml_error_text
from dkfsim.core.extras import optional
from dkfsim.core.params import suggest
from dkfsim.core.files import MAX_YAML_BYTES, check_plain_data, read_text
from dkfsim.core.folders import write_csv

#: Version of the database layout (``meta.format``).
DB_FORMAT = 2

#: Keys a sweep file may have.
SWEEP_KEYS = ("scenario", "grid", "set", "runs", "burn_in", "output")

#: Metrics of :func:`dkfsim.experiments.montecarlo.run_rows` stored per component.
#: The key columns of a stored row; the metrics (every registered one) follow.
KEY_COLUMNS = ("param_hash", "run", "seed", "estimate", "component")

_SQLITE_MAGIC = b"SQLite format 3\x00"


# =========================================================================== YAML
def _yaml_value(value: Any) -> str:
    """``value`` as YAML flow text for a ``key=value`` override."""
    text = yaml.safe_dump(value, default_flow_style=True, width=1 << 30, allow_unicode=True)
    if text.endswith("\n...\n"):
        text = text[:-5]
    return text.strip()


def _canonical(obj: Any) -> str:
    return json.dumps(obj, sort_keys=True, separators=(",", ":"), ensure_ascii=True,
                      allow_nan=False)


def _short(value: Any) -> str:
    text = json.dumps(value, ensure_ascii=False)
    return text if len(text) <= 40 else text[:37] + "..."


# =========================================================================== the definition
@dataclass(frozen=True)
class ParameterSet:
    """One point of the grid: its values, hash and resolved scenario."""

    index: int
    values: dict
    param_hash: str
    scenario: Any            # dkfsim.config.schema.Scenario
    scenario_hash: str

    @property
    def base_seed(self) -> int:
        return int(self.scenario.seed)

    def describe(self) -> str:
        if not self.values:
            return "(no grid)"
        return ", ".join(f"{k}={_short(v)}" for k, v in self.values.items())


@dataclass(frozen=True)
class Sweep:
    """A validated sweep: every parameter set already loads as a scenario."""

    source: str
    scenario_path: Path
    grid: tuple[tuple[str, tuple], ...]
    overrides: tuple[str, ...]
    runs: int
    burn_in: int | None
    output: Path
    parameter_sets: tuple[ParameterSet, ...] = field(repr=False)

    @property
    def name(self) -> str:
        return Path(self.source).stem if self.source != "<dict>" else "sweep"

    @property
    def n_tasks(self) -> int:
        return len(self.parameter_sets) * self.runs

    def definition(self) -> dict:
        """What the database stores; :meth:`identity` of it must match to resume."""
        return {
            "format": DB_FORMAT,
            "scenario_file": str(self.scenario_path),
            "grid": [[k, list(v)] for k, v in self.grid],
            "set": list(self.overrides),
            "runs": self.runs,
            "burn_in": self.burn_in,
            "parameter_sets": [{"param_hash": p.param_hash, "values": p.values,
                                "scenario_hash": p.scenario_hash} for p in self.parameter_sets],
        }

    def tasks(self) -> Iterator[tuple[ParameterSet, int]]:
        """Every (parameter set, run), run-major."""
        for r in range(self.runs):
            for p in self.parameter_sets:
                yield p, r


def identity(definition: Mapping) -> dict:
    """The parts of a definition that decide the results (not file names)."""
    return {
        "format": definition.get("format"),
        "grid": definition.get("grid"),
        "set": definition.get("set"),
        "runs": definition.get("runs"),
        "burn_in": definition.get("burn_in"),
        "scenarios": [[p.get("param_hash"), p.get("scenario_hash")]
                      for p in definition.get("parameter_sets", [])],
    }


def _err(source: str, key: str | None, message: str) -> DkfsimError:
    return DkfsimError(f"{source}: {key}: {message}" if key else f"{source}: {message}")


def load_sweep(source, *, output: str | os.PathLike | None = None, yes: bool = False) -> Sweep:
    """Read and validate a sweep file (or a mapping: paths relative to the
    current folder).  Every parameter set is loaded as a scenario here, so a
    bad grid key or value fails before anything runs.  ``output`` overrides
    the file's ``output``.  A grid too large to validate in memory is
    refused, one that takes over 10 minutes to validate needs ``yes``.
    Raises :class:`DkfsimError`."""
    if isinstance(source, Mapping):
        data, label, base = dict(source), "<dict>", Path.cwd()
        check_plain_data(data)
    else:
        label = os.fspath(source)
        path = Path(label)
        if is_database(path):
            raise _err(label, None, "this is a sweep database, not a sweep file: export it "
                                    "with dkfsim sweep DB --export FILE")
        text = read_text(path, limit=MAX_YAML_BYTES, what="sweep file", missing="sweep file not found")
        try:
            data = parse_yaml(text)
        except yaml.YAMLError as exc:
            raise _err(label, None, yaml_error_text(exc)) from None
        base = path.parent
        if data is None:
            raise _err(label, None, "empty file: expected a mapping with at least 'scenario'")
    if not isinstance(data, dict):
        raise _err(label, None, f"top level must be a mapping of sweep keys "
                                f"({', '.join(SWEEP_KEYS)}), got {type(data).__name__}")
    if "sensors" in data and "scenario" not in data:
        raise _err(label, None, "this is a scenario file, not a sweep: write a sweep file that "
                                "names it (scenario: FILE, grid: ...), or use 'dkfsim run' / "
                                "'dkfsim montecarlo' on it")
    for key in data:
        if key not in SWEEP_KEYS:
            raise _err(label, str(key), f"unknown key{suggest(key, SWEEP_KEYS)} "
                                        f"(valid: {', '.join(SWEEP_KEYS)})")

    # scenario
    scen = data.get("scenario")
    if scen is None:
        raise _err(label, "scenario", "required key is missing (the scenario file to sweep)")
    if not isinstance(scen, str) or not scen.strip():
        raise _err(label, "scenario", f"must be a file name, got {scen!r}")
    scenario_path = (base / scen) if not Path(scen).is_absolute() else Path(scen)
    if not scenario_path.is_file():
        raise _err(label, "scenario", f"file not found: {scenario_path}"
                   + (" (paths are relative to the sweep file)" if not Path(scen).is_absolute()
                      else ""))

    # grid
    grid_raw = data.get("grid")
    if grid_raw is None:
        grid_raw = {}
    if not isinstance(grid_raw, dict):
        raise _err(label, "grid", f"must be a mapping of dotted scenario keys to lists of "
                                  f"values, got {type(grid_raw).__name__}")
    grid: list[tuple[str, tuple]] = []
    for key, values in grid_raw.items():
        if not isinstance(key, str) or not key.strip() or any(p == "" for p in key.split(".")):
            raise _err(label, f"grid.{key}", "keys must be dotted scenario paths such as "
                                             "links.default.latency.d_t")
        if not isinstance(values, list):
            raise _err(label, f"grid.{key}", f"must be a list of values (e.g. [0, 1, 2]), got "
                                             f"{_short(values)}")
        if not values:
            raise _err(label, f"grid.{key}", "empty list: give at least one value")
        seen: dict[str, int] = {}
        for i, v in enumerate(values):
            c = _canonical(v) if _finite_json(v) else repr(v)
            if c in seen:
                raise _err(label, f"grid.{key}", f"value {_short(v)} is listed twice "
                                                 f"(entries {seen[c]} and {i})")
            seen[c] = i
            if not _finite_json(v):
                raise _err(label, f"grid.{key}", f"value {v!r} is not plain data (numbers must "
                                                 "be finite; lists and mappings are fine)")
        grid.append((key, tuple(values)))

    # set
    sets = data.get("set")
    if sets is None:
        sets = []
    if isinstance(sets, str):
        sets = [sets]
    if not isinstance(sets, list) or not all(isinstance(s, str) for s in sets):
        raise _err(label, "set", 'must be a list of "dotted.key=value" strings, e.g. '
                                 '["steps=300", "baselines=[centralized]"]')
    for s in sets:
        if "=" not in s:
            raise _err(label, "set", f"bad override {s!r}: expected dotted.key=value")
        k = s.partition("=")[0].strip()
        if k in grid_raw:
            raise _err(label, "set", f"{k} is both in set and in grid; keep it in one place")

    # runs, burn_in
    runs = data.get("runs", 1)
    if isinstance(runs, bool) or not isinstance(runs, int):
        raise _err(label, "runs", f"must be an integer >= 1, got {runs!r}")
    if runs < 1:
        raise _err(label, "runs", f"must be >= 1, got {runs}")
    burn_in = data.get("burn_in")
    if burn_in is not None and (isinstance(burn_in, bool) or not isinstance(burn_in, int)
                                or burn_in < 0):
        raise _err(label, "burn_in", f"must be null or an integer >= 0 (rows), got {burn_in!r}")

    # output
    if output is not None:
        out = Path(output)
    else:
        out_raw = data.get("output")
        if out_raw is None:
            stem = Path(label).stem if label != "<dict>" else "sweep"
            out = base / f"{stem}.sqlite"
        elif not isinstance(out_raw, str) or not out_raw.strip():
            raise _err(label, "output", f"must be a file name, got {out_raw!r}")
        else:
            out = Path(out_raw) if Path(out_raw).is_absolute() else base / out_raw

    n_sets = math.prod(len(values) for _, values in grid)
    check(Cost(f"{label}: validating {n_sets:,} parameter sets",
                   memory={"validated scenarios": n_sets * 50_000.0}, seconds=n_sets * C_VALIDATE),
          yes=yes, hint="a smaller grid")
    psets = _parameter_sets(label, scenario_path, grid, list(sets), burn_in)
    return Sweep(source=label, scenario_path=scenario_path, grid=tuple(grid),
                 overrides=tuple(sets), runs=runs, burn_in=burn_in, output=out,
                 parameter_sets=tuple(psets))


def _finite_json(v: Any) -> bool:
    if isinstance(v, float):
        return math.isfinite(v)
    if isinstance(v, (str, int, bool)) or v is None:
        return True
    if isinstance(v, list):
        return all(_finite_json(x) for x in v)
    if isinstance(v, dict):
        return all(isinstance(k, str) and _finite_json(x) for k, x in v.items())
    return False


def _parameter_sets(label, scenario_path, grid, sets, burn_in) -> list[ParameterSet]:
    keys = [k for k, _ in grid]
    out = []
    for index, combo in enumerate(itertools.product(*(v for _, v in grid))):
        values = dict(zip(keys, combo))
        overrides = sets + [f"{k}={_yaml_value(v)}" for k, v in values.items()]
        try:
            sc = load_scenario(scenario_path, overrides=overrides)
        except ScenarioError as exc:
            where = f"parameter set {index} ({', '.join(f'{k}={_short(v)}' for k, v in values.items())})" \
                if values else "the scenario with set"
            raise DkfsimError(f"{label}: {where}: {exc}") from None
        if burn_in is not None and not burn_in < sc.steps:
            raise _err(label, "burn_in", f"must be less than steps ({sc.steps}) of every "
                                         f"parameter set, got {burn_in}")
        h = hashlib.sha256(_canonical(values).encode()).hexdigest()[:20]
        out.append(ParameterSet(index, values, h, sc, scenario_hash(sc)))
    return out


# =========================================================================== one task (workers)
def run_task(scenario: dict, seed: int, burn_in: int | None,
             base_dir: str | None = None) -> tuple[list[dict], float]:
    """Simulate and score one task where it runs; send back only the rows.

    Returns ``(rows, wall seconds)``; rows as :func:`dkfsim.experiments.montecarlo.run_rows`
    gives them, with plain Python numbers.
    """
    t0 = time.perf_counter()
    rows, _curves = run_rows(load_scenario(scenario, base_dir=base_dir), int(seed), burn_in=burn_in)
    return [{k: _plain(v) for k, v in row.items()} for row in rows], time.perf_counter() - t0


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


def _sql_value(v: Any) -> Any:
    if isinstance(v, float) and math.isnan(v):
        return None
    return v


# =========================================================================== the database
def _q(name: str) -> str:
    return '"' + name.replace('"', '""') + '"'


SCHEMA = """
CREATE TABLE IF NOT EXISTS meta (
    key   TEXT PRIMARY KEY,
    value TEXT NOT NULL
);
CREATE TABLE IF NOT EXISTS params (
    param_hash    TEXT PRIMARY KEY,
    idx           INTEGER NOT NULL UNIQUE,
    values_json   TEXT NOT NULL,
    scenario_hash TEXT NOT NULL,
    base_seed     INTEGER NOT NULL,
    scenario_json TEXT NOT NULL
);
CREATE TABLE IF NOT EXISTS tasks (
    param_hash TEXT NOT NULL,
    run        INTEGER NOT NULL,
    seed       INTEGER NOT NULL,
    wall_s     REAL,
    finished   TEXT NOT NULL,
    UNIQUE (param_hash, run)
);
CREATE TABLE IF NOT EXISTS results (
    param_hash TEXT NOT NULL,
    run        INTEGER NOT NULL,
    seed       INTEGER NOT NULL,
    estimate   TEXT NOT NULL,
    component  TEXT NOT NULL,
    UNIQUE (param_hash, run, estimate, component)
);
"""


def is_database(path) -> bool:
    """True when ``path`` is a regular SQLite file (by its header; a FIFO is never opened)."""
    try:
        if not stat.S_ISREG(os.stat(path).st_mode):
            return False
        with open(path, "rb") as fh:
            return fh.read(16) == _SQLITE_MAGIC
    except OSError:
        return False


class SweepDB:
    """The results file of one sweep.  Only the parent process writes it."""

    def __init__(self, path, sweep: Sweep | None = None, *, readonly: bool = False):
        self.path = Path(path)
        self._lock_fh = None
        label = str(self.path)
        if readonly:
            if not self.path.exists():
                raise DkfsimError(f"{label}: file not found")
            if not is_database(self.path):
                raise DkfsimError(f"{label}: not an SQLite file (a sweep database was expected)")
            # A plain connection (a read-only one cannot recover a WAL left by kill -9).
            self.conn = sqlite3.connect(self.path, isolation_level=None, timeout=30)
            self.definition = self._stored_definition()
            if self.definition is None:
                raise DkfsimError(f"{label}: not a dkfsim sweep database (no sweep definition)")
            return
        if self.path.exists() and self.path.stat().st_size > 0 and not is_database(self.path):
            raise DkfsimError(f"{label}: exists and is not an SQLite file; refusing to "
                              "overwrite it (choose another output)")
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._lock()
            self.conn = sqlite3.connect(self.path, isolation_level=None, timeout=30)
            self.conn.execute("PRAGMA journal_mode=WAL")
            self.conn.execute("PRAGMA synchronous=FULL")
        except sqlite3.Error as exc:
            raise DkfsimError(f"{label}: cannot open the sweep database ({exc})") from None
        except OSError as exc:
            raise DkfsimError(f"{label}: cannot create the sweep database "
                              f"({exc.strerror})") from None
        try:
            self._setup(sweep)
        except BaseException:
            self.close()
            raise

    # -- opening -----------------------------------------------------------------
    def _lock(self) -> None:
        if fcntl is None:  # pragma: no cover  (no advisory locks: trust the user)
            return
        fh = open(self.path, "ab")
        try:
            fcntl.flock(fh.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            fh.close()
            raise DkfsimError(f"{self.path}: another dkfsim sweep is writing this database; "
                              "wait for it to finish (or stop it) and re-run") from None
        self._lock_fh = fh

    def _stored_definition(self) -> dict | None:
        try:
            row = self.conn.execute("SELECT value FROM meta WHERE key='definition'").fetchone()
        except sqlite3.DatabaseError:
            return None
        return json.loads(row[0]) if row else None

    def _setup(self, sweep: Sweep | None) -> None:
        label = str(self.path)
        tables = {r[0] for r in self.conn.execute(
            "SELECT name FROM sqlite_master WHERE type='table'")}
        if tables and "meta" not in tables:
            raise DkfsimError(f"{label}: an SQLite file that is not a dkfsim sweep database; "
                              "refusing to write into it (choose another output)")
        stored = self._stored_definition() if "meta" in tables else None
        if sweep is None:
            if stored is None:
                raise DkfsimError(f"{label}: not a dkfsim sweep database")
            self.definition = stored
            return
        new = sweep.definition()
        if stored is not None:
            if identity(stored) != identity(new):
                raise DkfsimError(f"{label} was made by a different sweep definition "
                                  f"({_difference(stored, new)}); refusing to mix their results. "
                                  "Write to another file (output: in the sweep file, or --db "
                                  "PATH), or delete this one to start over.")
            self.definition = stored
            return
        self.conn.execute("BEGIN IMMEDIATE")
        try:
            for stmt in SCHEMA.split(";"):
                if stmt.strip():
                    self.conn.execute(stmt)
            meta = {"format": str(DB_FORMAT), "definition": _canonical(new),
                    "sweep_file": sweep.source, "dkfsim_version": __version__,
                    "created": time.strftime("%Y-%m-%dT%H:%M:%S%z")}
            self.conn.executemany("INSERT INTO meta(key, value) VALUES (?, ?)", meta.items())
            self.conn.executemany(
                "INSERT INTO params(param_hash, idx, values_json, scenario_hash, base_seed, "
                "scenario_json) VALUES (?, ?, ?, ?, ?, ?)",
                [(p.param_hash, p.index, _canonical(p.values), p.scenario_hash, p.base_seed,
                  _canonical(p.scenario.to_dict())) for p in sweep.parameter_sets])
            self.conn.execute("COMMIT")
        except BaseException:
            self.conn.execute("ROLLBACK")
            raise
        self.definition = new

    # -- reading -------------------------------------------------------------------
    def done(self) -> set[tuple[str, int]]:
        return {(h, r) for h, r in self.conn.execute("SELECT param_hash, run FROM tasks")}

    def columns(self) -> list[str]:
        return [r[1] for r in self.conn.execute("PRAGMA table_info(results)")]

    # -- writing -------------------------------------------------------------------
    def write_task(self, param_hash: str, run: int, seed: int, rows: list[dict],
                   wall_s: float | None) -> None:
        """All rows of one task (tidy: one per estimate and component), or nothing (one
        transaction).  A metric column is added the first time a row has it."""
        conn = self.conn
        conn.execute("BEGIN IMMEDIATE")
        try:
            have = set(self.columns())
            metrics = [k for k in (rows[0] if rows else {}) if k not in KEY_COLUMNS]
            for c in metrics:
                if c not in have:
                    conn.execute(f"ALTER TABLE results ADD COLUMN {_q(c)}")
            conn.execute("INSERT INTO tasks(param_hash, run, seed, wall_s, finished) "
                         "VALUES (?, ?, ?, ?, ?)",
                         (param_hash, run, seed, wall_s, time.strftime("%Y-%m-%dT%H:%M:%S%z")))
            names = list(KEY_COLUMNS) + metrics
            for row in rows:
                if row["seed"] != seed:
                    raise RuntimeError(f"task ({param_hash}, {run}): rows carry seed {row['seed']}, "
                                       f"expected {seed}")
                conn.execute(f"INSERT INTO results({', '.join(map(_q, names))}) VALUES "
                             f"({', '.join('?' * len(names))})",
                             [param_hash, run, seed, row["estimate"], row["component"],
                              *(_sql_value(row.get(m)) for m in metrics)])
            conn.execute("COMMIT")
        except BaseException:
            conn.execute("ROLLBACK")
            raise

    def close(self) -> None:
        conn = getattr(self, "conn", None)
        if conn is not None:
            conn.close()
            self.conn = None
        if self._lock_fh is not None:
            self._lock_fh.close()
            self._lock_fh = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False


def _difference(stored: dict, new: dict) -> str:
    a, b = identity(stored), identity(new)
    if a["format"] != b["format"]:
        return (f"database format {a['format'] or 1} of an earlier dkfsim, this one writes "
                f"format {b['format']}; keep that file, and give this sweep another --db")
    parts = []
    for key in ("grid", "set", "runs", "burn_in"):
        if a[key] != b[key]:
            parts.append(f"{key}: {_short(a[key])} in the file, {_short(b[key])} now")
    if not parts and a["scenarios"] != b["scenarios"]:
        parts.append("the scenario resolves differently (the scenario file changed)")
    return "; ".join(parts) or "the stored definition differs"


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

    @property
    def runs_per_minute(self) -> float:
        return 60.0 * self.computed / self.wall_s if self.wall_s > 0 else float("nan")


@single_thread
def run_sweep(sweep: Sweep | str | os.PathLike, *, executor=None, jobs: int | None = None,
              progress: bool | None = None, db: str | os.PathLike | None = None,
              yes: bool = False, workers: int | None = None) -> SweepReport:
    """Run (or resume) a sweep; return a :class:`SweepReport`.

    ``executor`` is a :mod:`dkfsim.experiments.executors` executor, or a callable that
    makes one (called only once the database is checked and some task is
    left to run; the executor it returns is closed here).  Default: ``jobs``
    local processes, every CPU if None.  ``progress``: a tqdm bar on stderr
    (default: when stderr is a terminal).  ``db`` overrides the output file.
    The remaining tasks are estimated first (``workers``: how many run at
    once, when ``executor`` is a callable): refused if they cannot fit in
    memory, and needing ``yes`` above 10 minutes.
    """
    if not isinstance(sweep, Sweep):
        sweep = load_sweep(sweep, output=db, yes=yes)
    path = Path(db) if db is not None else sweep.output
    if progress is None:
        progress = sys.stderr.isatty()
    if workers is None:
        workers = executor.workers if isinstance(executor, executors.Executor) else \
            (jobs or executors.available_cpus())
    # Estimated before the database is created or changed: a refusal leaves no trace.
    check(estimate_tasks(sweep, tasks_done(path, sweep), workers), yes=yes,
          hint="fewer runs, a smaller grid, or more workers")
    with SweepDB(path, sweep) as store:
        done = store.done()
        todo = [(p, r) for p, r in sweep.tasks() if (p.param_hash, r) not in done]
        skipped = sweep.n_tasks - len(todo)
        own = executor is None or not isinstance(executor, executors.Executor)
        if not todo:
            executor, own = executors.InlineExecutor(), True   # nothing to start
        elif executor is None:
            executor = executors.local(jobs)
        elif own:
            executor = executor()
        label = executor.label
        t0 = time.perf_counter()
        computed = 0
        bar = None
        if progress and todo:
            bar = tqdm(total=sweep.n_tasks, initial=skipped, unit="run", desc=sweep.name,
                       file=sys.stderr, dynamic_ncols=True, smoothing=0.1)
        try:
            if todo:
                tasks = (((p.param_hash, r, seed),
                          (p.scenario.to_dict(), seed, sweep.burn_in, p.scenario.base_dir))
                         for p, r in todo for seed in (derive_seed(p.base_seed, r),))
                for (h, r, seed), (rows, wall) in executor.imap_unordered(run_task, tasks):
                    store.write_task(h, r, seed, rows, wall)
                    computed += 1
                    if bar is not None:
                        bar.update(1)
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
                       wall_s=wall, executor=label)


def estimate_tasks(sweep: Sweep, done: set, workers: int) -> Cost:
    """Memory and time of the tasks of ``sweep`` not yet in ``done``."""
    est = Cost(f"{sweep.source}: {sweep.n_tasks - len(done):,} tasks left of {sweep.n_tasks:,}",
                   workers=max(1, workers))
    biggest = 0.0
    for p in sweep.parameter_sets:
        one = estimate_run(p.scenario, "estimates")
        left = sweep.runs - sum((p.param_hash, r) in done for r in range(min(sweep.runs, 10**6)))
        est.seconds += one.seconds * left
        biggest = max(biggest, one.bytes)
    est.memory["one run per worker"] = biggest * est.workers
    est.memory["task list"] = (sweep.n_tasks - len(done)) * 200.0
    return est


# =========================================================================== reading, export
def read_results(db: str | os.PathLike) -> tuple[list[str], list[list]]:
    """``(columns, rows)`` of a sweep database, sorted by (parameter set in grid order,
    run, estimate in output order, component in state order): the grid values first
    (one column per grid key), then ``param_hash, run, seed, estimate, component`` and
    the metrics in registry order -- the tidy schema of every output."""
    store = SweepDB(db, readonly=True)
    try:
        definition = store.definition
        grid_keys = [k for k, _ in definition["grid"]]
        stored = [c for c in store.columns() if c not in KEY_COLUMNS]
        order = list(METRICS.names())
        metric_cols = sorted(stored, key=lambda c: (order.index(c) if c in order else len(order), c))
        select = ", ".join(["p.values_json"] + [f"r.{_q(c)}" for c in KEY_COLUMNS + tuple(metric_cols)])
        # rowid: the order the task's rows were written in (estimates, then components).
        cur = store.conn.execute(
            f"SELECT {select} FROM results r JOIN params p ON p.param_hash = r.param_hash "
            "ORDER BY p.idx, r.run, r.rowid")
        rows = []
        for values_json, *rest in cur:
            values = json.loads(values_json)
            rows.append([values.get(k) for k in grid_keys] + rest)
    finally:
        store.close()
    taken = set(KEY_COLUMNS) | set(metric_cols)
    names = [k if k not in taken else f"param:{k}" for k in grid_keys]
    return names + list(KEY_COLUMNS) + metric_cols, rows


def export(db: str | os.PathLike, to: str | os.PathLike) -> tuple[Path, int]:
    """Write the results of ``db`` to ``to`` (``.csv`` or ``.parquet``), sorted
    by key (see :func:`read_results`); return ``(path, number of rows)``."""
    to = Path(to)
    suffix = to.suffix.lower()
    if suffix not in (".csv", ".parquet", ".pq"):
        raise DkfsimError(f"--export {to}: unknown format {suffix or '(no suffix)'!r}; "
                          "use a .csv or .parquet file name")
    columns, rows = read_results(db)
    try:
        to.parent.mkdir(parents=True, exist_ok=True)
        if suffix == ".csv":
            write_csv(to, columns, rows)
        else:
            _write_parquet(to, columns, rows)
    except OSError as exc:
        raise DkfsimError(f"--export {to}: cannot write ({exc.strerror})") from None
    return to, len(rows)


def _write_parquet(path: Path, columns, rows) -> None:
    pa, pq = optional("pyarrow"), optional("pyarrow.parquet")
    arrays = []
    for j, _name in enumerate(columns):
        col = [row[j] for row in rows]
        if any(isinstance(v, (list, dict)) for v in col):
            col = [None if v is None else _canonical(v) for v in col]
        try:
            arr = pa.array(col)
        except (pa.ArrowInvalid, pa.ArrowTypeError):
            arr = pa.array([None if v is None else _canonical(v) for v in col], type=pa.string())
        arrays.append(arr)
    table = pa.Table.from_arrays(arrays, names=list(columns))
    tmp = path.with_name(path.name + ".tmp")
    pq.write_table(table, tmp)
    os.replace(tmp, path)


def tasks_done(path: Path, sweep: Sweep) -> set:
    """``(param_hash, run)`` of the tasks already in the database at ``path`` (none if
    there is no database yet); a database of another sweep definition is an error."""
    if not Path(path).exists():
        return set()
    store = SweepDB(path, readonly=True)
    try:
        if identity(store.definition) != identity(sweep.definition()):
            raise DkfsimError(f"{path} was made by a different sweep definition "
                              f"({_difference(store.definition, sweep.definition())})")
        return {(h, r) for h, r in store.conn.execute("SELECT param_hash, run FROM tasks")}
    finally:
        store.close()

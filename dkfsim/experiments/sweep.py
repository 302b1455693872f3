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

* **One row per (parameter set, run, algorithm)**, components as columns:
  ``mse_<component>`` for the per-component MSE, and one column per
  per-run metric (``anees``, ``disagreement``, ``messages_per_tick``,
  ``bytes_per_tick``, ``lost``, ``late``).  A metric that ever differs
  between the components of one algorithm gets ``<metric>_<component>``
  columns instead, so nothing is dropped.  NaN (not modelled) is stored as
  NULL (SQLite has no NaN) and exported as an empty cell / Parquet null.
* **The file stores its sweep definition** (grid, ``set``, ``runs``,
  ``burn_in`` and the hash of every resolved parameter set's scenario) and
  refuses to resume from a different one, including a changed scenario file
  that changes what a parameter set simulates.  Editing comments, moving the
  files or changing ``output`` does not matter.
* ``param_hash`` is the sha256 (first 20 hex digits) of the canonical JSON of
  the parameter set's grid values, so it does not depend on the grid's order.
* Tasks are submitted run-major (run 0 of every parameter set, then run 1,
  ...), so an interrupted sweep holds a balanced picture.
* Exports are sorted by (parameter set in grid order, run, algorithm), so the
  file is byte-identical whatever executor, worker count or interruptions
  produced the database.
* One process at a time may write a database (an advisory lock on the file);
  a second ``dkfsim sweep`` on it stops with a clear message.
"""

from __future__ import annotations

import difflib
import hashlib
import itertools
import json
import math
import os
import re
import sqlite3
import stat
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterator, Mapping

import yaml

from dkfsim.experiments import executors
from dkfsim.core.errors import DkfsimError, ScenarioError
from dkfsim.core.resources import C_VALIDATE, Estimate, check, estimate_run
from dkfsim.core.threads import single_thread
from dkfsim.core.files import MAX_YAML_BYTES, check_plain_data, parse_yaml, read_text, yaml_error_text

#: Version of the database layout (``meta.format``).
DB_FORMAT = 1

#: Keys a sweep file may have.
SWEEP_KEYS = ("scenario", "grid", "set", "runs", "burn_in", "output")

#: Metrics of :func:`dkfsim.experiments.montecarlo.run_rows` stored per component.
PER_COMPONENT = ("mse",)

#: Column order of metrics in exports (others follow alphabetically).
METRIC_ORDER = ("mse", "anees", "disagreement", "messages_per_tick", "bytes_per_tick",
                "lost", "late")

#: Key columns of ``results`` (in export order).
KEY_COLUMNS = ("param_hash", "run", "seed", "algorithm")

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


def _suggest(word: str, names) -> str:
    close = difflib.get_close_matches(str(word), list(names), n=1)
    return f"; did you mean {close[0]!r}?" if close else ""


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
            raise _err(label, str(key), f"unknown key{_suggest(key, SWEEP_KEYS)} "
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
    check(Estimate(f"{label}: validating {n_sets:,} parameter sets",
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
    from dkfsim.config.schema import load_scenario, scenario_hash
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
    from dkfsim.experiments.montecarlo import run_rows
    from dkfsim.config.schema import load_scenario
    t0 = time.perf_counter()
    rows, _curves = run_rows(load_scenario(scenario, base_dir=base_dir), int(seed), burn_in=burn_in)
    return [{k: _plain(v) for k, v in row.items()} for row in rows], time.perf_counter() - t0


def _plain(v: Any) -> Any:
    if isinstance(v, (str, bool)) or v is None:
        return v
    if isinstance(v, int):
        return int(v)
    try:
        import numpy as np
        if isinstance(v, np.integer):
            return int(v)
        if isinstance(v, np.floating):
            return float(v)
    except ImportError:  # pragma: no cover
        pass
    if isinstance(v, float):
        return float(v)
    return v


def _same(a: Any, b: Any) -> bool:
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    return a == b and type(a) is type(b)


def widen(rows: list[dict]) -> list[tuple[str, int, dict]]:
    """Tidy rows (one per algorithm x component) -> one ``(algorithm, seed,
    columns)`` per algorithm, in the order the algorithms first appear."""
    by_alg: dict[str, list[dict]] = {}
    for row in rows:
        by_alg.setdefault(row["algorithm"], []).append(row)
    out = []
    for alg, group in by_alg.items():
        seeds = {row["seed"] for row in group}
        if len(seeds) != 1:
            raise RuntimeError(f"run_rows gave several seeds for {alg}: {seeds}")
        cols: dict[str, Any] = {}
        metrics = [k for k in group[0] if k not in ("seed", "algorithm", "component")]
        for m in metrics:
            vals = [row.get(m) for row in group]
            if m in PER_COMPONENT or not all(_same(vals[0], v) for v in vals[1:]):
                for row, v in zip(group, vals):
                    cols[f"{m}_{row['component']}"] = v
            else:
                cols[m] = vals[0]
        out.append((alg, group[0]["seed"], cols))
    return out


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
    algorithm  TEXT NOT NULL,
    UNIQUE (param_hash, run, algorithm)
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
        try:
            import fcntl
        except ImportError:  # pragma: no cover  (no advisory locks: trust the user)
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
            from dkfsim import __version__
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
        """All rows of one task, or nothing (one transaction)."""
        wide = widen(rows)
        conn = self.conn
        conn.execute("BEGIN IMMEDIATE")
        try:
            have = set(self.columns())
            for _alg, _seed, cols in wide:
                for c in cols:
                    if c not in have:
                        conn.execute(f"ALTER TABLE results ADD COLUMN {_q(c)}")
                        have.add(c)
            conn.execute("INSERT INTO tasks(param_hash, run, seed, wall_s, finished) "
                         "VALUES (?, ?, ?, ?, ?)",
                         (param_hash, run, seed, wall_s, time.strftime("%Y-%m-%dT%H:%M:%S%z")))
            for alg, row_seed, cols in wide:
                if row_seed != seed:
                    raise RuntimeError(f"task ({param_hash}, {run}): rows carry seed {row_seed}, "
                                       f"expected {seed}")
                names = list(KEY_COLUMNS) + list(cols)
                conn.execute(f"INSERT INTO results({', '.join(map(_q, names))}) VALUES "
                             f"({', '.join('?' * len(names))})",
                             [param_hash, run, seed, alg, *(_sql_value(v) for v in cols.values())])
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
    parts = []
    for key in ("grid", "set", "runs", "burn_in"):
        if a[key] != b[key]:
            parts.append(f"{key}: {_short(a[key])} in the file, {_short(b[key])} now")
    if not parts and a["scenarios"] != b["scenarios"]:
        parts.append("the scenario resolves differently (the scenario file changed)")
    if not parts:
        parts.append(f"database format {a['format']}, expected {b['format']}")
    return "; ".join(parts)


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
    from dkfsim.experiments.montecarlo import derive_seed
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
            from tqdm import tqdm
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


def estimate_tasks(sweep: Sweep, done: set, workers: int) -> Estimate:
    """Memory and time of the tasks of ``sweep`` not yet in ``done``."""
    est = Estimate(f"{sweep.source}: {sweep.n_tasks - len(done):,} tasks left of {sweep.n_tasks:,}",
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
def _metric_rank(col: str) -> tuple:
    for i, m in enumerate(METRIC_ORDER):
        if col == m or col.startswith(m + "_"):
            return (i, "")
    return (len(METRIC_ORDER), col)


def read_results(db: str | os.PathLike) -> tuple[list[str], list[list]]:
    """``(columns, rows)`` of a sweep database, sorted by (parameter set in
    grid order, run, algorithm): the grid values first (one column per grid
    key), then ``param_hash, run, seed, algorithm`` and the metrics."""
    store = SweepDB(db, readonly=True)
    try:
        definition = store.definition
        grid_keys = [k for k, _ in definition["grid"]]
        metric_cols = [c for c in store.columns() if c not in KEY_COLUMNS]
        # Stable: by metric, then component in the order the columns were made.
        metric_cols = sorted(metric_cols, key=lambda c: (_metric_rank(c),))
        select = ", ".join(["p.values_json"] + [f"r.{_q(c)}" for c in KEY_COLUMNS + tuple(metric_cols)])
        cur = store.conn.execute(
            f"SELECT {select} FROM results r JOIN params p ON p.param_hash = r.param_hash "
            "ORDER BY p.idx, r.run, r.algorithm")
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
            _write_csv(to, columns, rows)
        else:
            _write_parquet(to, columns, rows)
    except OSError as exc:
        raise DkfsimError(f"--export {to}: cannot write ({exc.strerror})") from None
    return to, len(rows)


def _cell(v: Any) -> Any:
    if v is None:
        return ""
    if isinstance(v, float):
        return repr(v)
    if isinstance(v, (list, dict)):
        return _canonical(v)
    return v


def _write_csv(path: Path, columns, rows) -> None:
    import csv
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(columns)
        for row in rows:
            w.writerow([_cell(v) for v in row])
    os.replace(tmp, path)


def _write_parquet(path: Path, columns, rows) -> None:
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError:
        raise DkfsimError("Parquet export needs the 'pyarrow' package, which is not installed: "
                          "pip install 'dkfsim[cluster]' (or pip install pyarrow), or export "
                          "to a .csv file") from None
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


# =========================================================================== throughput
def throughput(scenario: str | os.PathLike | None = None, *, steps: int = 1000, jobs: int = 2,
               runs: int | None = None, executor=None, overrides=()) -> dict:
    """Measured sweep throughput: ``runs`` Monte Carlo runs of ``scenario``
    (default ``scenarios/paper_case1.yaml``) at ``steps`` ticks through the
    whole sweep machinery (executor, scoring, SQLite writes), into a
    temporary database.

    ``executor`` defaults to ``jobs`` local processes; ``runs`` to ``4 *
    jobs``.  Worker start-up is included (it is part of what a sweep costs).
    Returns ``{"scenario", "steps", "runs", "executor", "wall_s",
    "runs_per_minute"}``.
    """
    if scenario is None:
        scenario = Path(__file__).resolve().parents[2] / "scenarios" / "paper_case1.yaml"
    runs = 4 * jobs if runs is None else runs
    with tempfile.TemporaryDirectory(prefix="dkfsim-throughput-") as tmp:
        sweep = load_sweep({"scenario": str(Path(scenario).resolve()),
                            "set": [f"steps={int(steps)}", *overrides], "runs": runs,
                            "output": str(Path(tmp) / "throughput.sqlite")})
        rep = run_sweep(sweep, executor=executor, jobs=jobs, progress=False)
    return {"scenario": str(scenario), "steps": int(steps), "runs": rep.computed,
            "executor": rep.executor, "wall_s": rep.wall_s,
            "runs_per_minute": rep.runs_per_minute}


# =========================================================================== CLI
HELP = """\
Run a parameter sweep: every parameter set of the grid (the cartesian product of the
grid's value lists) times `runs` Monte Carlo runs, run r using seed
derive_seed(scenario seed, r). Results go to an SQLite file, one transaction per task;
interrupt it at any point (Ctrl-C, kill) and re-run the same command to resume: tasks
already in the file are skipped.

sweep file keys:
  scenario   scenario file, relative to the sweep file (required)
  grid       mapping of dotted scenario keys (as --set) to lists of values (default: none)
  set        list of fixed "dotted.key=value" overrides, applied before the grid
  runs       Monte Carlo runs per parameter set (default: 1)
  burn_in    rows skipped before time averages (default: null = 10% of the ticks)
  output     results database (default: <sweep file stem>.sqlite beside the sweep file)

database: tables meta (the sweep definition), params (one row per parameter set, with its
resolved scenario), tasks (one row per finished (param_hash, run)) and results (one row
per parameter set, run and algorithm: mse_<component>, anees, disagreement,
messages_per_tick, bytes_per_tick, lost, late).

examples:
  dkfsim sweep scenarios/sweep_delay_bound.yaml --jobs 4
  dkfsim sweep scenarios/sweep_delay_bound.yaml --dask-local 4 --export out/delay.parquet
  dkfsim sweep scenarios/sweep_delay_bound.yaml --scheduler tcp://10.0.0.5:8786
  dkfsim sweep scenarios/sweep_delay_bound.sqlite --export out/delay.csv     (export only)
"""


def add_command(subparsers) -> None:
    import argparse
    p = subparsers.add_parser(
        "sweep", help="parameter sweep x Monte Carlo runs into a resumable SQLite file",
        description=HELP, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("file", metavar="FILE",
                   help="a sweep YAML file to run or resume; or a sweep database (.sqlite) to "
                        "export with --export, computing nothing")
    where = p.add_mutually_exclusive_group()
    where.add_argument("--jobs", type=int, metavar="J",
                       help="local worker processes (1 = this process; default: every CPU)")
    where.add_argument("--scheduler", metavar="tcp://HOST:PORT",
                       help="run the tasks on an existing Dask distributed cluster (its workers "
                            "need the same dkfsim installed); needs dkfsim[cluster]")
    where.add_argument("--dask-local", type=int, metavar="N",
                       help="start a Dask LocalCluster of N single-threaded worker processes on "
                            "this machine; needs dkfsim[cluster]")
    p.add_argument("--db", metavar="PATH",
                   help="results database (overrides the sweep file's output)")
    p.add_argument("--export", metavar="PATH",
                   help="when the sweep is complete, write every result row to PATH (.csv or "
                        ".parquet, by suffix; Parquet needs pyarrow), sorted by parameter set, "
                        "run and algorithm")
    p.add_argument("--dry-run", action="store_true",
                   help="validate, list the parameter sets and how many of their runs are done; "
                        "compute nothing")
    p.add_argument("--quiet", action="store_true", help="no progress bar and no summary lines")
    from dkfsim.cli.main import add_yes_arg
    add_yes_arg(p)
    p.set_defaults(func=cmd_sweep)


def cmd_sweep(args) -> int:
    say = (lambda *a: None) if args.quiet else print
    if is_database(args.file):
        if args.export is None:
            raise DkfsimError(f"{args.file} is a sweep database: give --export PATH to export "
                              "it, or give the sweep YAML file to run or resume it")
        if args.jobs is not None or args.scheduler or args.dask_local is not None or args.db:
            raise DkfsimError(f"{args.file} is a sweep database: only --export applies "
                              "(nothing is computed)")
        out, n = export(args.file, args.export)
        say(f"wrote {out} ({n} rows)")
        return 0
    sweep = load_sweep(args.file, output=args.db, yes=args.yes)
    if args.dry_run:
        return _dry_run(sweep, say)
    if args.export is not None:
        suffix = Path(args.export).suffix.lower()
        if suffix not in (".csv", ".parquet", ".pq"):
            raise DkfsimError(f"--export {args.export}: unknown format {suffix or '(no suffix)'!r}; "
                              "use a .csv or .parquet file name")
        if suffix != ".csv":
            try:
                import pyarrow  # noqa: F401
            except ImportError:
                raise DkfsimError("--export to Parquet needs the 'pyarrow' package: pip install "
                                  "'dkfsim[cluster]', or export to .csv") from None
    if args.scheduler is not None or args.dask_local is not None:
        executors._distributed()          # a missing package is reported before any work

    def make():
        return executors.make_executor(jobs=args.jobs, scheduler=args.scheduler,
                                       dask_local=args.dask_local)

    say(f"{sweep.source}: {len(sweep.parameter_sets)} parameter set(s) x {sweep.runs} "
        f"run(s) = {sweep.n_tasks} tasks -> {sweep.output}")
    workers = args.jobs or args.dask_local or (1 if args.scheduler else executors.available_cpus())
    rep = run_sweep(sweep, executor=make, progress=not args.quiet and sys.stderr.isatty(),
                    yes=args.yes, workers=workers)
    rate = f" on {rep.executor} ({rep.runs_per_minute:.1f} runs/min)" if rep.computed else ""
    say(f"done: {rep.skipped} already in the database, {rep.computed} computed in "
        f"{_duration(rep.wall_s)}{rate}")
    if args.export is not None:
        out, n = export(rep.db, args.export)
        say(f"wrote {out} ({n} rows)")
    return 0


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


def _dry_run(sweep: Sweep, say) -> int:
    done = tasks_done(sweep.output, sweep)
    say(f"{sweep.source}: scenario {sweep.scenario_path}, {len(sweep.parameter_sets)} parameter "
        f"set(s) x {sweep.runs} run(s) = {sweep.n_tasks} tasks; results in {sweep.output}")
    for p in sweep.parameter_sets:
        n = sum((p.param_hash, r) in done for r in range(sweep.runs))
        say(f"  [{p.index}] {p.param_hash}  {n}/{sweep.runs} done  {p.describe()}")
    return 0


def _duration(s: float) -> str:
    if s < 60:
        return f"{s:.1f} s"
    m, s = divmod(int(round(s)), 60)
    h, m = divmod(m, 60)
    return f"{h}h{m:02d}m{s:02d}s" if h else f"{m}m{s:02d}s"

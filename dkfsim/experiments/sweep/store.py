"""The sweep database: one SQLite file per sweep, written only by the parent process.

One transaction per task (its rows are there entirely or not at all), the sweep
definition stored in ``meta`` and checked on resume, an advisory lock so one process
at a time writes it.  See :mod:`dkfsim.experiments.sweep` and docs/design.md.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import sqlite3
import tempfile
import time
import urllib.parse
from pathlib import Path
from types import ModuleType
from typing import Any, BinaryIO

fcntl: ModuleType | None
try:
    import fcntl
except ImportError:  # pragma: no cover  (Windows)
    fcntl = None

from dkfsim.config.results import SweepDefinition, SweepParams, validate
from dkfsim.core.errors import DkfsimError
from dkfsim.core.files import open_regular, parse_json
from dkfsim.core.version import __version__
from dkfsim.experiments.sweep.definition import (
    DB_FORMAT,
    KEY_COLUMNS,
    MAX_DATABASE_BYTES,
    Sweep,
    canonical_json,
    is_database,
    short_json,
)


def _sql_value(v: Any) -> Any:
    if isinstance(v, float) and math.isnan(v):
        return None
    return v



# =========================================================================== the database
def _rollback(conn) -> None:
    """Roll back the open transaction, if SQLite has not already (a full disk ends it)."""
    if conn.in_transaction:
        with contextlib.suppress(sqlite3.Error):
            conn.execute("ROLLBACK")


def _write_new(conn, sweep: Sweep) -> None:
    """Schema, definition and parameter sets of a new database, in one transaction."""
    conn.execute("BEGIN IMMEDIATE")
    try:
        for stmt in SCHEMA.split(";"):
            if stmt.strip():
                conn.execute(stmt)
        meta = {"format": str(DB_FORMAT), "definition": canonical_json(sweep.definition()),
                "sweep_file": sweep.source, "dkfsim_version": __version__,
                "created": time.strftime("%Y-%m-%dT%H:%M:%S%z")}
        conn.executemany("INSERT INTO meta(key, value) VALUES (?, ?)", meta.items())
        conn.executemany(
            "INSERT INTO params(param_hash, idx, values_json, scenario_hash, base_seed, "
            "scenario_json) VALUES (?, ?, ?, ?, ?, ?)",
            [(p.param_hash, p.index, canonical_json(p.values), p.scenario_hash, p.base_seed,
              canonical_json(p.scenario.to_dict())) for p in sweep.parameter_sets])
        conn.execute("COMMIT")
    except BaseException:
        _rollback(conn)
        raise


@contextlib.contextmanager
def damaged(path):
    """Turn an SQLite error met while reading ``path`` (a dropped table, a malformed file, a
    full disk) into a :class:`DkfsimError` naming the file and SQLite's reason."""
    try:
        yield
    except sqlite3.Error as exc:
        raise DkfsimError(f"{path}: cannot read the sweep database ({exc}); is it damaged?") from None


def quote_name(name: str) -> str:
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



class SweepDB:
    """The results file of one sweep.  Only the parent process writes it."""

    def __init__(self, path, sweep: Sweep | None = None, *, readonly: bool = False):
        self.path = Path(path)
        self._lock_fh: BinaryIO | None = None
        label = str(self.path)
        if readonly:
            if not self.path.exists():
                raise DkfsimError(f"{label}: file not found")
            if not is_database(self.path):
                raise DkfsimError(f"{label}: not an SQLite file (a sweep database was expected)")
            # A plain connection (a read-only one cannot recover a WAL left by kill -9).
            with damaged(self.path):
                self.conn = sqlite3.connect(self.path, isolation_level=None, timeout=30)
            try:
                try:
                    definition = self._stored_definition()
                except DkfsimError:
                    if not self._reopen_immutable():
                        raise
                    definition = self._stored_definition()
                if definition is None:
                    raise DkfsimError(f"{label}: not a dkfsim sweep database (no sweep definition)")
                self.definition: dict = definition
            except BaseException:
                self.close()
                raise
            return
        if self.path.exists() and self.path.stat().st_size > 0 and not is_database(self.path):
            raise DkfsimError(f"{label}: exists and is not an SQLite file; refusing to "
                              "overwrite it (choose another output)")
        self.created = False         # this object made the file (it removes it if it saves nothing)
        self.written = 0             # tasks saved through it
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            if sweep is not None and (not self.path.exists() or self.path.stat().st_size == 0):
                self._create(sweep)
            self._lock()
            self.conn = sqlite3.connect(self.path, isolation_level=None, timeout=30)
            # A rollback journal, not a write-ahead log: a transaction a full disk stops is rolled
            # back and its journal deleted without needing new space, and a saved task lives in the
            # database file alone -- nothing is left beside it (a WAL could hold saved tasks the
            # disk had no room to fold in, and its -wal and -shm files stayed).
            self.conn.execute("PRAGMA journal_mode=DELETE")
            self.conn.execute("PRAGMA synchronous=FULL")
            self._setup(sweep)
        except sqlite3.Error as exc:
            self._abandon()
            raise DkfsimError(f"{label}: cannot open the sweep database ({exc}; a full disk?); "
                              f"{self._left()}") from None
        except OSError as exc:
            self._abandon()
            raise DkfsimError(f"{label}: cannot create the sweep database "
                              f"({exc.strerror}); {self._left()}") from None
        except BaseException:
            self._abandon()
            raise

    # -- opening -----------------------------------------------------------------
    def _create(self, sweep: Sweep) -> None:
        """Make the database whole (schema, definition, parameter sets) in a file beside it and
        link it into place in one step: no process, and no later sweep, ever sees an empty or
        header-only database, whatever stops this one (a full disk, a kill).  A database
        another process linked first is kept (the lock then decides who writes)."""
        fd, tmp = tempfile.mkstemp(prefix=f".{self.path.name}.new-", suffix=".sqlite", dir=self.path.parent)
        os.close(fd)
        try:
            conn = sqlite3.connect(tmp, isolation_level=None)
            try:
                _write_new(conn, sweep)
            except sqlite3.Error as exc:
                raise DkfsimError(f"{self.path}: cannot create the sweep database ({exc}; a full "
                                  "disk?); nothing was written") from None
            finally:
                conn.close()
            try:
                os.link(tmp, self.path)
                self.created = True
            except FileExistsError:
                if self.path.stat().st_size == 0:           # an empty file (an older lock): ours
                    os.replace(tmp, self.path)
                    self.created = True
            except OSError:               # a filesystem without hard links: a rename, if still free
                if not self.path.exists():
                    os.replace(tmp, self.path)
                    self.created = True
        finally:
            with contextlib.suppress(OSError):
                os.unlink(tmp)

    def _lock(self) -> None:
        if fcntl is None:  # pragma: no cover  (no advisory locks: trust the user)
            return
        fh = open_regular(self.path, limit=MAX_DATABASE_BYTES, what="sweep database")   # (never creates one)
        try:
            fcntl.flock(fh.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            fh.close()
            raise DkfsimError(f"{self.path}: another dkfsim sweep is writing this database; "
                              "wait for it to finish (or stop it) and re-run") from None
        self._lock_fh = fh

    def _reopen_immutable(self) -> bool:
        """Read a database that was closed cleanly (no write-ahead log left) without writing
        anything next to it: on a full disk, SQLite cannot make the ``-shm`` file a normal
        reader needs.  False when there is a log to recover (only a normal open can)."""
        wal = self.path.with_name(self.path.name + "-wal")
        if wal.exists() and wal.stat().st_size > 0:
            return False
        self.conn.close()
        uri = "file:" + urllib.parse.quote(str(self.path.absolute())) + "?immutable=1"
        with damaged(self.path):
            self.conn = sqlite3.connect(uri, uri=True, isolation_level=None)
        return True

    def _stored_definition(self) -> dict | None:
        """The stored sweep definition (checked: a database may come from anyone), or None
        when the file has no ``meta`` table or no definition in it (not a sweep database)."""
        try:
            row = self.conn.execute("SELECT value FROM meta WHERE key='definition'").fetchone()
        except sqlite3.OperationalError as exc:
            if str(exc).startswith("no such table"):
                return None
            raise DkfsimError(f"{self.path}: cannot read the sweep database ({exc}; a full disk?)") from None
        except sqlite3.DatabaseError as exc:
            raise DkfsimError(f"{self.path}: a damaged SQLite file ({exc})") from None
        if not row:
            return None
        label = f"{self.path} (meta.definition)"
        data = parse_json(row[0], label, "sweep definition")
        validate(SweepDefinition, data, label)
        return data

    # -- reading what a result holds -------------------------------------------------
    def meta(self) -> dict[str, str]:
        """The ``meta`` table: ``definition``, ``sweep_file``, ``dkfsim_version``, ``created``."""
        with damaged(self.path):
            rows = self.conn.execute("SELECT key, value FROM meta").fetchall()
        return {str(k): v if isinstance(v, str) else str(v) for k, v in rows}

    def params(self) -> list[dict]:
        """The parameter sets, by ``idx``: ``idx, param_hash, base_seed, values, scenario``
        (the JSON columns parsed and checked)."""
        with damaged(self.path):
            rows = self.conn.execute("SELECT idx, param_hash, base_seed, values_json, scenario_json "
                                     "FROM params ORDER BY idx").fetchall()
        out = []
        for i, (idx, h, seed, values, scenario) in enumerate(rows):
            label = f"{self.path} (params row {i + 1})"
            item = {"idx": idx, "param_hash": h, "base_seed": seed,
                    "values": parse_json(values, f"{label}: values_json", "grid values"),
                    "scenario": parse_json(scenario, f"{label}: scenario_json", "stored scenario")}
            validate(SweepParams, item, label)
            out.append(item)
        return out

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
            problem = growth_problem(self.conn, stored, sweep)
            if problem:
                raise DkfsimError(f"{label} was made by a different sweep definition "
                                  f"({problem}); refusing to mix their results. "
                                  "Write to another file (output: in the sweep file, or --db "
                                  "PATH), or delete this one to start over.")
            if canonical_json(stored) != canonical_json(new):
                self._grow(sweep, new)
            self.definition = new
            return
        _write_new(self.conn, sweep)         # (an empty SQLite file made by someone else)
        self.definition = new

    def _grow(self, sweep: Sweep, new: dict) -> None:
        """The sweep grew (more runs, grid values or estimators; :func:`growth_problem`
        allowed it): store its definition and parameter sets, keep every result."""
        conn = self.conn
        conn.execute("BEGIN IMMEDIATE")
        try:
            conn.execute("UPDATE meta SET value=? WHERE key='definition'", (canonical_json(new),))
            conn.execute("INSERT OR REPLACE INTO meta(key, value) VALUES ('grown', ?)",
                         (time.strftime("%Y-%m-%dT%H:%M:%S%z"),))
            conn.execute("UPDATE params SET idx = -1 - idx")       # idx is UNIQUE: out of the way
            for p in sweep.parameter_sets:
                conn.execute(
                    "INSERT INTO params(param_hash, idx, values_json, scenario_hash, base_seed, "
                    "scenario_json) VALUES (?, ?, ?, ?, ?, ?) ON CONFLICT(param_hash) DO UPDATE "
                    "SET idx=excluded.idx, values_json=excluded.values_json, "
                    "scenario_hash=excluded.scenario_hash, scenario_json=excluded.scenario_json",
                    (p.param_hash, p.index, canonical_json(p.values), p.scenario_hash, p.base_seed,
                     canonical_json(p.scenario.to_dict())))
            conn.execute("COMMIT")
        except BaseException:
            _rollback(conn)
            raise

    # -- reading -------------------------------------------------------------------
    def done(self) -> set[tuple[str, int]]:
        """``(param_hash, run)`` of the tasks computed whole (every estimate of their time)."""
        return {(h, r) for h, r in self.conn.execute("SELECT param_hash, run FROM tasks")}

    def estimates_done(self) -> dict[tuple[str, int], set[str]]:
        """The estimates stored per ``(param_hash, run)`` (estimators added later are
        computed for the runs already done as tasks of their own)."""
        out: dict[tuple[str, int], set[str]] = {}
        for h, r, e in self.conn.execute("SELECT DISTINCT param_hash, run, estimate FROM results"):
            out.setdefault((h, r), set()).add(e)
        return out

    def columns(self) -> list[str]:
        return [r[1] for r in self.conn.execute("PRAGMA table_info(results)")]

    # -- writing -------------------------------------------------------------------
    def write_task(self, param_hash: str, run: int, seed: int, rows: list[dict],
                   wall_s: float | None, whole: bool = True) -> None:
        """All rows of one task (tidy: one per estimate and component), or nothing (one
        transaction).  A metric column is added the first time a row has it.  ``whole``:
        a run with every estimate (recorded in ``tasks``); else the rows of estimators
        added to a run already done."""
        conn = self.conn
        conn.execute("BEGIN IMMEDIATE")
        try:
            have = set(self.columns())
            metrics = [k for k in (rows[0] if rows else {}) if k not in KEY_COLUMNS]
            for c in metrics:
                if c not in have:
                    conn.execute(f"ALTER TABLE results ADD COLUMN {quote_name(c)}")
            if whole:
                conn.execute("INSERT INTO tasks(param_hash, run, seed, wall_s, finished) "
                             "VALUES (?, ?, ?, ?, ?)",
                             (param_hash, run, seed, wall_s, time.strftime("%Y-%m-%dT%H:%M:%S%z")))
            names = list(KEY_COLUMNS) + metrics
            for row in rows:
                if row["seed"] != seed:
                    raise RuntimeError(f"task ({param_hash}, {run}): rows carry seed {row['seed']}, "
                                       f"expected {seed}")
                conn.execute(f"INSERT INTO results({', '.join(map(quote_name, names))}) VALUES "
                             f"({', '.join('?' * len(names))})",
                             [param_hash, run, seed, row["estimate"], row["component"],
                              *(_sql_value(row.get(m)) for m in metrics)])
            conn.execute("COMMIT")
            self.written += 1
        except (sqlite3.OperationalError, OSError) as exc:      # a full disk, an I/O error
            _rollback(conn)
            kept = ("the tasks saved before it are kept, re-run the same command to resume" if self.written
                    or not self.created else "no task was saved, so the new database is removed")
            raise DkfsimError(f"{self.path}: cannot save the results of task ({param_hash}, run {run}) "
                              f"({exc}; a full disk?): {kept}") from None
        except BaseException:
            _rollback(conn)
            raise

    def close(self) -> None:
        conn = getattr(self, "conn", None)
        if conn is not None:
            conn.close()
            del self.conn                 # (closed: getattr above finds none)
        if self._lock_fh is not None:
            self._lock_fh.close()
            self._lock_fh = None

    def _left(self) -> str:
        """What a failed sweep leaves, in words (after :meth:`_abandon`)."""
        if self.created and not self.path.exists():
            return "nothing was written"
        return "the database holds what it held before"

    def _abandon(self) -> None:
        """Close; a database this object created and saved no task into is removed (a sweep
        stopped by a full disk leaves nothing behind; one that saved tasks keeps them)."""
        self.close()
        if getattr(self, "created", False) and not self.written:
            for suffix in ("", "-journal", "-wal", "-shm"):
                with contextlib.suppress(OSError):
                    os.unlink(f"{self.path}{suffix}")

    def __enter__(self):
        return self

    def __exit__(self, exc_type, *exc):
        if exc_type is not None:
            self._abandon()
        else:
            self.close()
        return False


def _format_problem(stored: dict, new: dict) -> str | None:
    a, b = stored.get("format"), new.get("format")
    if a != b:
        return (f"database format {a or 1} of an earlier dkfsim, this one writes "
                f"format {b}; keep that file, and give this sweep another --db")
    return None


def _labels(estimators: list) -> list[str]:
    return [e.get("name") or e.get("kind") for e in estimators]


def growth_problem(conn, stored: dict, sweep: Sweep) -> str | None:
    """Why the database (``conn``, its definition ``stored``) cannot take ``sweep``, or None.

    A sweep may grow: more ``runs``, more values of its grid keys, more estimators (listed
    after the ones it had).  Task ``(parameter set, run)`` is the same task whatever the
    number of runs or the other grid values (its seed is ``derive_seed(base seed, run)``,
    its ``param_hash`` depends on its own values only) and one estimator's rows do not
    depend on the others, so every stored row stays valid.  What would change stored rows,
    or leave rows that are no longer part of the sweep, is refused: a changed scenario or
    ``set`` (beyond added estimators), ``burn_in``, grid keys, fewer runs, a removed grid
    value, a removed, changed or reordered estimator."""
    new = sweep.definition()
    problem = _format_problem(stored, new)
    if problem:
        return problem
    if stored.get("burn_in") != new["burn_in"]:
        return (f"burn_in: {short_json(stored.get('burn_in'))} in the file, {short_json(new['burn_in'])} "
                "now (it changes every stored row)")
    keys_a = [k for k, _ in stored.get("grid", [])]
    keys_b = [k for k, _ in sweep.grid]
    if sorted(keys_a) != sorted(keys_b):
        return (f"grid keys: {short_json(keys_a)} in the file, {short_json(keys_b)} now (a sweep can grow "
                "by values of its grid keys, not by keys)")
    if new["runs"] < stored.get("runs", 0):
        return (f"runs: {stored.get('runs')} in the file, {new['runs']} now (runs can be raised, "
                "not lowered)")
    now = {p.param_hash: p for p in sweep.parameter_sets}
    scenarios = dict(conn.execute("SELECT param_hash, scenario_json FROM params"))
    for old in stored.get("parameter_sets", []):
        h = old.get("param_hash")
        values = ", ".join(f"{k}={short_json(v)}" for k, v in (old.get("values") or {}).items())
        if h not in now:
            return (f"grid: the parameter set {values or '(no grid)'} has results in the file but "
                    "is no longer in the grid (values can be added, not removed)")
        if old.get("scenario_hash") == now[h].scenario_hash:
            continue
        a, b = json.loads(scenarios.get(h, "{}")), json.loads(canonical_json(now[h].scenario.to_dict()))
        est_a, est_b = a.pop("estimators", []), b.pop("estimators", [])
        if a != b:
            return (f"the parameter set {values or '(no grid)'} resolves differently (the scenario "
                    "file or set changed)")
        if est_b[:len(est_a)] != est_a:
            return (f"estimators: {short_json(_labels(est_a))} in the file, {short_json(_labels(est_b))} now "
                    "(estimators can be added after the existing ones, not removed, changed or "
                    "reordered)")
    return None


def tasks_done(path: Path, sweep: Sweep) -> set:
    """``(param_hash, run)`` of the tasks already in the database at ``path`` with every
    estimate ``sweep`` asks for (none if there is no database yet); a database the sweep
    cannot grow from is an error."""
    if not Path(path).exists():
        return set()
    store = SweepDB(path, readonly=True)
    try:
        problem = growth_problem(store.conn, store.definition, sweep)
        if problem:
            raise DkfsimError(f"{path} was made by a different sweep definition ({problem})")
        missing = missing_estimates(store, sweep)
        check_shared_growth(path, sweep, missing)
        return {t for t in store.done() if t not in missing}
    finally:
        store.close()


def check_shared_growth(path, sweep: Sweep, missing: dict[tuple[str, int], list[str]]) -> None:
    """Refuse to grow a sweep by estimators when its queues are shared (``links.shared_queues``,
    docs/traffic.md): the added estimators would run alone on the stored runs, whereas with
    shared queues every estimator's packets wait behind the others', so their rows would not
    be those of a run of the whole list (and the stored rows would no longer be either).
    ``missing``: :func:`missing_estimates` of the stored runs."""
    shared = {p.param_hash: p for p in sweep.parameter_sets if p.scenario.links.shared_queues}
    for (h, _run), added in missing.items():
        if h in shared:
            raise DkfsimError(
                f"{sweep.source}: estimators: adding {short_json(added)} to the runs stored in {path} "
                f"is refused because links.shared_queues is true (parameter set "
                f"{shared[h].describe()}): every estimator's packets share the queues, so estimators "
                "added to finished runs cannot be run alone. Write the grown sweep to a new database "
                "(--db PATH, or output: in the sweep file), or run without links.shared_queues")


def missing_estimates(store: "SweepDB", sweep: Sweep) -> dict[tuple[str, int], list[str]]:
    """Per task already done, the estimators of ``sweep`` it has no rows for (in order)."""
    done, have = store.done(), store.estimates_done()
    labels = {p.param_hash: [e.label for e in p.scenario.estimators] for p in sweep.parameter_sets}
    out = {}
    for h, r in sorted(done):
        if h in labels and r < sweep.runs:
            missing = [e for e in labels[h] if e not in have.get((h, r), set())]
            if missing:
                out[(h, r)] = missing
    return out


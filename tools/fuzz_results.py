#!/usr/bin/env python
"""Mutation fuzzer for result folders and sweep databases: reading any of them ends cleanly.

The sibling of tools/fuzz_scenarios.py for what dkfsim *reads back* (issues 20, 30): a run
folder, a Monte Carlo folder and a sweep database of paper case 1, a run on the shared channel
with the fusion centre (``channel``), a run and a Monte Carlo of moving vehicles (``mobility``,
``mobility_mc``), the fusion centre over rate-limited links with background (``centre``) and a
sweep of the channel's rate (``sweep_channel``) are made once, small and legitimate (the
*bases*); a mutant is a copy of one with one mutation applied; the reading commands run on it:
``dkfsim plot`` (PNG only), ``dkfsim report`` and, for a run folder, ``dkfsim.load_run``.
The contract, per mutant: every command either succeeds or ends in a
:class:`dkfsim.DkfsimError` with a one-paragraph message -- no other exception (a traceback),
no hang (the time limit), no MemoryError under the worker's address-space cap, no crash, no
raw control character and no content of a file the result names in what it prints or writes
(``finding:bad_message:leak``), no file opened outside the mutant and the output but the
interpreter, the package and the caches (tools/fuzz_scenarios' audit hook), no peak above 3 GiB.
Outcome classes are those of tools/fuzz_scenarios.py (``clean_error``, ``ran``,
``finding:<Type>``, ``finding:bad_message:<Type>``, ``memory``, ``timeout``, ``crash``); the
phase is the command that ended it.

Mutations (every one deterministic):

* the JSON files (``summary.json`` of the run and the Monte Carlo): every key path gets every
  leaf mutation of tools/fuzz_scenarios.VOCABULARY (type swaps, odd numbers, ``[]``/``{}``,
  1000-level nesting, 10^5 zeros, deletion, an unknown key) and a 5 MB string;
* whole files (every file of every base, the database included): emptied, truncated to a
  third and two thirds, bytes flipped at five seeded places, replaced by random bytes;
* npz members (``run.npz``, ``curves.npz``): dtype swaps (text, object, integer, bool),
  no rows, no columns, an extra axis, deleted, renamed to mathtext, a corrupt deflate stream,
  and a claim of 60 M rows of zeros in a few compressed megabytes;
* CSV files (``rows.csv``, ``runs.csv``): a cell of text, of 1 MB, empty; a column dropped;
* the sweep database: every column of every table set to NULL, text, a 5 MB string, -1,
  1e300 or a blob; every table dropped; the JSON of ``meta.definition``,
  ``params.values_json`` and ``params.scenario_json`` replaced by non-JSON, a list, 1000
  levels of nesting, names with mathtext;
* the stored scenario (``scenario_config``, ``params.scenario_json``) naming a file outside the
  result: a track, an empirical trace (a canary whose content must not show), a SUMO FCD file
  that is a FIFO, ``/dev/zero``, a path relative to the scenario file the result names;
* names holding terminal escapes (the scenario, a sensor, the estimate ``centralized``, in
  every file that holds them); a 40 MB string in ``summary.json``.

Usage::

    python tools/fuzz_results.py [--limit N] [--seed S] [--timeout S] [--jobs J]
                                 [--base NAME ...] [--family KIND ...] [--examples K] [--json OUT]

It prints the counts per base and per kind of mutation (cases, tracebacks, bad messages, hangs,
mutants over 3 GiB, mutants that opened a file outside their inputs).

tests/test_fuzz_results.py draws mutants from the same enumeration with Hypothesis.  The exit
status is 1 when there is any finding.
"""

from __future__ import annotations

import os

if __name__ == "__main__":
    for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import contextlib  # noqa: E402
import copy  # noqa: E402
import functools  # noqa: E402
import io  # noqa: E402
import json  # noqa: E402
import random  # noqa: E402
import re  # noqa: E402
import shutil  # noqa: E402
import sqlite3  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402
import zipfile  # noqa: E402
from collections import Counter  # noqa: E402
from dataclasses import asdict  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any, Callable, NamedTuple  # noqa: E402

import numpy as np  # noqa: E402

TOOLS = Path(__file__).resolve().parent
sys.path.insert(0, str(TOOLS))

import fuzz_scenarios as fz  # noqa: E402

import dkfsim  # noqa: E402
from dkfsim.core.errors import DkfsimError  # noqa: E402

ROOT = TOOLS.parent
CASE1 = ROOT / "scenarios" / "paper_case1.yaml"
BASES = ("run", "mc", "sweep", "channel", "mobility", "centre", "mobility_mc", "sweep_channel")
#: The bases that are sweep databases (the others are folders).
SWEEPS = ("sweep", "sweep_channel")
#: Estimate names of the bases (the ``names_escape`` mutation renames ``centralized``).
RENAMED = "centralized"
#: A name holding terminal escapes: retitle the window, ring the bell, clear the screen.
ESCAPED_NAME = "e\x1b]0;PWNED\x07\x1b[2J"
#: Seconds a mutant may take, every command together.
DEFAULT_TIMEOUT = 30.0
#: Mutants checked by default (a seeded sample of the enumeration; every whole-file and
#: database mutation is always included).
DEFAULT_LIMIT = 1500
HUGE_TEXT = "x" * 5_000_000
BOMB_ROWS = 60_000_000


class ResultMutant(NamedTuple):
    """A mutant by name: ``scenario`` is the base (``run``, ``mc``, ``sweep``; the field keeps
    tools/fuzz_scenarios' name so its worker machinery applies), ``path`` the file and the place
    in it, ``mutation`` what is done there."""

    scenario: str
    path: tuple
    mutation: str

    @property
    def label(self) -> str:
        return f"{self.scenario}:{fz.dotted(self.path)}:{self.mutation}"


# =========================================================================== the bases
@functools.lru_cache(maxsize=None)
def base_dir() -> Path:
    """The legitimate bases, made once per process in a temporary folder: a run, a Monte Carlo
    and a sweep of paper case 1; a run on the shared channel with the fusion centre
    (``channel``), a run and a Monte Carlo of moving vehicles (``mobility``, ``mobility_mc``),
    the fusion centre over rate-limited links with background (``centre``) and a sweep of the
    channel's rate (``sweep_channel``)."""
    d = Path(tempfile.mkdtemp(prefix="fuzz_results_bases_"))
    sc = dkfsim.load_scenario(CASE1, overrides=["steps=20", "estimators=[{kind: centralized}, "
                                                "{kind: ci_consensus, rounds: 1}]"])
    dkfsim.run(sc).save(d / "run")
    dkfsim.montecarlo(sc, runs=2, jobs=1).save(d / "mc")
    _sweep(d / "sweep", {"scenario": str(CASE1), "grid": {"links.default.latency.d_t": [0, 2]},
                         "set": ["steps=20", "estimators=[{kind: centralized}]"], "runs": 2})
    centre = "estimators=[{kind: fusion_centre, at: 0, margin: 5}, {kind: centralized}]"
    channel = dkfsim.load_scenario(ROOT / "scenarios" / "channel_its_g5.yaml", overrides=["steps=20", centre])
    dkfsim.run(channel).save(d / "channel")
    mobility = dkfsim.load_scenario(ROOT / "scenarios" / "mobility_convoy.yaml",
                                    overrides=["steps=20", "estimators=[{kind: centralized}]"])
    dkfsim.run(mobility).save(d / "mobility")
    dkfsim.montecarlo(mobility, runs=2, jobs=1).save(d / "mobility_mc")
    rated = dkfsim.load_scenario(CASE1, overrides=[
        "steps=20", centre, "links.default.rate=2.0e6", "links.default.queue={packets: 10}",
        "links.default.background={arrivals: poisson, packets_per_second: 50.0, size: 250}"])
    dkfsim.run(rated).save(d / "centre")
    _sweep(d / "sweep_channel", {"scenario": str(ROOT / "scenarios" / "channel_its_g5.yaml"),
                                 "grid": {"medium.rate": [1.0e6, 6.0e6]}, "set": ["steps=20", centre], "runs": 1})
    return d


def _sweep(folder: Path, definition: dict) -> None:
    folder.mkdir()
    (folder / "s.yaml").write_text(json.dumps(definition))
    dkfsim.sweep(folder / "s.yaml", jobs=1, progress=False)
    for leftover in folder.glob("s.sqlite-*"):
        leftover.unlink()


def base_files(base: str) -> list[str]:
    folder = base_dir() / base
    names = ["s.sqlite"] if base in SWEEPS else sorted(p.name for p in folder.iterdir() if not p.name.startswith("."))
    return names


@functools.lru_cache(maxsize=None)
def base_json(base: str, name: str) -> dict:
    return json.loads((base_dir() / base / name).read_text())


@functools.lru_cache(maxsize=None)
def base_npz(base: str, name: str) -> dict:
    with np.load(base_dir() / base / name) as z:
        return {k: z[k] for k in z.files}


@functools.lru_cache(maxsize=None)
def base_tables(base: str = "sweep") -> dict[str, list[str]]:
    with contextlib.closing(sqlite3.connect(base_dir() / base / "s.sqlite")) as conn:
        tables = [r[0] for r in conn.execute("SELECT name FROM sqlite_master WHERE type='table'")]
        return {t: [r[1] for r in conn.execute(f'PRAGMA table_info("{t}")')] for t in tables}


# =========================================================================== the vocabulary
#: Leaf mutations of JSON values (fuzz_scenarios' vocabulary without its whole-scenario ones).
JSON_MUTATIONS = {m.name: m for m in fz.VOCABULARY if m.applies != fz._is_root} | {
    "huge_string": fz._replace("huge_string", lambda _old: HUGE_TEXT)}
FILE_MUTATIONS = ("empty", "truncate_1/3", "truncate_2/3", "flip_bytes", "random_bytes")
NPZ_MUTATIONS = ("as_text", "as_object", "as_int", "as_bool", "no_rows", "no_columns", "extra_axis",
                 "delete", "rename_mathtext", "claim_60M_rows", "deflated_and_flipped")
CSV_MUTATIONS = ("cell_text", "cell_1MB", "cell_empty", "drop_column")
SQL_VALUES = {"NULL": None, "text": "abc", "5MB_text": HUGE_TEXT, "-1": -1, "1e300": 1e300,
              "blob": b"\x00\x01"}
JSON_CELLS = ("definition", "values_json", "scenario_json")
JSON_CELL_VALUES = {"not_json": "{not json", "a_list": "[1, 2]", "nested_1000": "[" * 1000 + "]" * 1000,
                    "mathtext_names": None, "empty_object": "{}"}
#: Whole-file mutations of a JSON file: a 40 MB string under a key of its own.
BIG_JSON_MUTATIONS = ("json_40MB_string",)
#: Edits of the stored scenario (summary.json's ``scenario_config``, a sweep's
#: ``params.scenario_json``) naming files outside the result: reading must open none of them.
STORED_MUTATIONS = ("stored_track_canary", "stored_track_fifo", "stored_fcd_fifo", "stored_track_dev_zero",
                    "stored_empirical_canary", "stored_relative_canary")
#: Names holding terminal escapes (a sensor, the scenario, an estimate): nothing raw on a terminal.
NAME_MUTATIONS = ("names_escape",)


def enumerate_mutants(bases=BASES) -> list[ResultMutant]:
    """Every mutant of the given bases, in a fixed order."""
    out: list[ResultMutant] = []
    for base in bases:
        for name in base_files(base):
            out += [ResultMutant(base, (name,), m) for m in FILE_MUTATIONS]
            if name == "summary.json":
                out += [ResultMutant(base, (name,), m) for m in STORED_MUTATIONS + BIG_JSON_MUTATIONS]
            if name.endswith(".json"):
                data = base_json(base, name)
                for path, value in fz.walk(data):
                    for m in JSON_MUTATIONS.values():
                        if path != () and m.applies(path, value):
                            out.append(ResultMutant(base, (name, *path), m.name))
            elif name.endswith(".npz"):
                for member in base_npz(base, name):
                    out += [ResultMutant(base, (name, member), m) for m in NPZ_MUTATIONS
                            if m != "claim_60M_rows" or member in ("t", "truth", "x_fused", "mse")]
            elif name.endswith(".csv"):
                out += [ResultMutant(base, (name, col), m) for col in (0, 1, 3, 4) for m in CSV_MUTATIONS]
            elif name.endswith(".sqlite"):
                out += [ResultMutant(base, (name, "scenario_json"), m) for m in STORED_MUTATIONS]
                for table, cols in base_tables(base).items():
                    out.append(ResultMutant(base, (name, table), "drop_table"))
                    out += [ResultMutant(base, (name, table, col), f"set_{v}") for col in cols for v in SQL_VALUES]
                for cell in JSON_CELLS:
                    out += [ResultMutant(base, (name, cell), f"json_{v}") for v in JSON_CELL_VALUES]
        out += [ResultMutant(base, (base_files(base)[0],), m) for m in NAME_MUTATIONS]
    return out


def family(spec: ResultMutant) -> str:
    """What a mutant changes: ``file`` (whole-file damage), ``json``, ``npz``, ``csv``, ``sql``,
    ``stored`` (files named by the stored scenario), ``names`` (terminal escapes), ``big``
    (a huge JSON string)."""
    m = spec.mutation
    if m in FILE_MUTATIONS:
        return "file"
    if m in STORED_MUTATIONS:
        return "stored"
    if m in NAME_MUTATIONS:
        return "names"
    if m in BIG_JSON_MUTATIONS:
        return "big"
    return {".json": "json", ".npz": "npz", ".csv": "csv", ".sqlite": "sql"}[Path(spec.path[0]).suffix]


def select(specs: list[ResultMutant], limit: int, seed: int) -> list[ResultMutant]:
    """Every file and database mutant plus a seeded sample of ``limit`` others (JSON and npz)."""
    always = [i for i, s in enumerate(specs) if family(s) in ("file", "stored", "names", "big")
              or s.scenario in SWEEPS]
    always_set = set(always)
    rest = [i for i in range(len(specs)) if i not in always_set]
    if 0 < limit < len(rest):
        keep = always_set | set(random.Random(seed).sample(rest, limit))
        return [s for i, s in enumerate(specs) if i in keep]
    return list(specs)


# =========================================================================== applying a mutation
def _file(path: Path, mutation: str, seed: int) -> None:
    data = path.read_bytes()
    rng = random.Random(seed)
    if mutation == "empty":
        data = b""
    elif mutation.startswith("truncate_"):
        data = data[:len(data) * int(mutation[-3]) // 3]
    elif mutation == "flip_bytes":
        b = bytearray(data)
        for _ in range(5):
            i = rng.randrange(len(b))
            b[i] ^= 1 << rng.randrange(8)
        data = bytes(b)
    elif mutation == "random_bytes":
        data = rng.randbytes(max(64, len(data)))
    path.write_bytes(data)


def _npz(path: Path, member: str, mutation: str) -> None:
    arrays = dict(base_npz(path.parent.name, path.name))
    a = arrays[member]
    if mutation == "claim_60M_rows":
        shape = (BOMB_ROWS,) + a.shape[1:] if member != "mse" else (a.shape[0], BOMB_ROWS, a.shape[2])
        _bomb(path, member, shape, {k: v for k, v in arrays.items() if k != member})
        return
    if mutation == "deflated_and_flipped":       # a corrupt deflate stream in one member
        np.savez_compressed(path, **arrays)
        with zipfile.ZipFile(path) as z:
            info = z.getinfo(member + ".npy")
        data = bytearray(path.read_bytes())
        head = info.header_offset
        start = head + 30 + int.from_bytes(data[head + 26:head + 28], "little") + \
            int.from_bytes(data[head + 28:head + 30], "little")
        for i in range(start + 2, start + info.compress_size - 1, max(1, info.compress_size // 8)):
            data[i] ^= 0x5A
        path.write_bytes(bytes(data))
        return
    if mutation == "delete":
        del arrays[member]
    elif mutation == "rename_mathtext":
        arrays[("x_" if member.startswith("x_") else "") + "$\\nosuch$" + member] = arrays.pop(member)
    else:
        arrays[member] = {
            "as_text": lambda: a.astype(str),
            "as_object": lambda: np.array([None, "x"], dtype=object),
            "as_int": lambda: a.astype(np.int64) if a.dtype.kind in "biuf" else np.arange(a.size),
            "as_bool": lambda: a.astype(bool) if a.dtype.kind in "biuf" else np.ones(a.size, bool),
            "no_rows": lambda: a[:0] if a.ndim else np.zeros(0, a.dtype),
            "no_columns": lambda: a.reshape(a.shape[0], -1)[:, :0] if a.ndim else np.zeros((1, 0), a.dtype),
            "extra_axis": lambda: a[..., None],
        }[mutation]()
    _savez(path, arrays)


def _savez(path: Path, arrays: dict) -> None:
    """``np.savez`` that may write an object array (pickled): what a hostile folder holds."""
    with zipfile.ZipFile(path, "w") as z:
        for k, v in arrays.items():
            with z.open(k + ".npy", "w") as fh:
                np.lib.format.write_array(fh, np.asanyarray(v), allow_pickle=True)


def _bomb(path: Path, member: str, shape: tuple, others: dict) -> None:
    """``member`` claims ``shape`` of float64 zeros, deflated as they are streamed (60 M rows
    take a few MB); the other arrays as they were."""
    chunk = bytes(16 << 20)
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED, compresslevel=9) as z:
        with z.open(member + ".npy", "w", force_zip64=True) as fh:
            np.lib.format.write_array_header_2_0(fh, {"descr": "<f8", "fortran_order": False, "shape": shape})
            left = 8 * int(np.prod(shape))
            while left > 0:
                fh.write(chunk[:min(left, len(chunk))])
                left -= len(chunk)
        for k, v in others.items():
            with z.open(k + ".npy", "w") as fh:
                np.lib.format.write_array(fh, np.asanyarray(v))


def _csv(path: Path, col: int, mutation: str) -> None:
    lines = path.read_text().splitlines()
    rows = [line.split(",") for line in lines]
    if mutation == "drop_column":
        rows = [r[:col] + r[col + 1:] for r in rows]
    else:
        new = {"cell_text": "abc", "cell_1MB": "9" * 1_000_000, "cell_empty": ""}[mutation]
        if len(rows) > 1 and col < len(rows[1]):
            rows[1][col] = new
    path.write_text("\n".join(",".join(r) for r in rows) + "\n")


def _sql(path: Path, where: tuple, mutation: str) -> None:
    with contextlib.closing(sqlite3.connect(path)) as conn:
        if mutation == "drop_table":
            conn.execute(f'DROP TABLE "{where[0]}"')
        elif mutation.startswith("set_"):
            table, col = where
            value = SQL_VALUES[mutation[4:]]
            try:
                conn.execute(f'UPDATE "{table}" SET "{col}" = ?', (value,))
            except sqlite3.IntegrityError:          # a NOT NULL or UNIQUE column: one row only
                conn.execute(f'UPDATE OR IGNORE "{table}" SET "{col}" = ? WHERE rowid = 1',
                             (value if value is not None else "null",))
        elif mutation.startswith("json_"):
            cell, kind = where[0], mutation[5:]
            table, col, key = ("meta", "value", "key = 'definition'") if cell == "definition" else \
                ("params", cell, "1 = 1")
            if kind == "mathtext_names":
                for rowid, text in conn.execute(f'SELECT rowid, "{col}" FROM "{table}" WHERE {key}').fetchall():
                    data = json.loads(text)
                    data = _mathtext(data)
                    conn.execute(f'UPDATE "{table}" SET "{col}" = ? WHERE rowid = ?', (json.dumps(data), rowid))
            else:
                conn.execute(f'UPDATE "{table}" SET "{col}" = ? WHERE {key}', (JSON_CELL_VALUES[kind],))
        conn.commit()


def _mathtext(data: Any) -> Any:
    """Every string of ``data`` (keys too) prefixed with mathtext matplotlib cannot parse."""
    if isinstance(data, dict):
        return {"$\\nosuch$" + k if k not in ("grid", "runs", "set") else k: _mathtext(v) for k, v in data.items()}
    if isinstance(data, list):
        return [_mathtext(v) for v in data]
    return "$\\nosuch$" + data if isinstance(data, str) else data


def _stored(cfg: dict, mutation: str) -> dict:
    """The stored scenario ``cfg`` naming a file outside the result (:data:`STORED_MUTATIONS`:
    ``stored_<what>_<kind>``): every vehicle a ``track`` or ``sumo_fcd`` of that file, or the
    default latency an ``empirical`` trace of it; ``relative``: a track named relative to the
    scenario file the result names."""
    _, what, kind = mutation.split("_", 2)
    file = fz._special(kind)
    if what == "relative":
        file, what = os.path.relpath(file, ROOT / "scenarios"), "track"
    cfg = copy.deepcopy(cfg)
    if what == "empirical":
        cfg.setdefault("links", {}).setdefault("default", {})["latency"] = {"model": "empirical", "file": file}
        return cfg
    traj = {"kind": "track", "file": file} if what == "track" else {"kind": "sumo_fcd", "file": file, "vehicle": "v0"}
    mobility = cfg.get("mobility")
    if isinstance(mobility, dict) and isinstance(mobility.get("vehicles"), dict):
        mobility["vehicles"] = {k: dict(traj) for k in mobility["vehicles"]}
    else:
        cfg["mobility"] = {"vehicles": {"default": traj}, "range": {"model": "disk", "radius": 1000.0}}
    return cfg


def _renamed(data: Any, old: str, new: str) -> Any:
    """``data`` with every key and string equal to ``old`` replaced by ``new`` (the stored
    scenario left alone: ``centralized`` is an estimator kind there)."""
    if isinstance(data, dict):
        return {(new if k == old else k): (v if k == "scenario_config" else _renamed(v, old, new))
                for k, v in data.items()}
    if isinstance(data, list):
        return [_renamed(v, old, new) for v in data]
    return new if data == old else data


def _escaped_scenario(sc: dict) -> dict:
    return {**sc, "name": ESCAPED_NAME, "sensors": [{**sc["sensors"][0], "name": ESCAPED_NAME}, *sc["sensors"][1:]]}


def _names(target: Path, base: str) -> None:
    """The ``names_escape`` mutation: the scenario, its first sensor and the estimate
    ``centralized`` named :data:`ESCAPED_NAME`, in every file that holds them."""
    if base in SWEEPS:
        with contextlib.closing(sqlite3.connect(target / "s.sqlite")) as conn:
            conn.execute("UPDATE results SET estimate=? WHERE estimate=?", (ESCAPED_NAME, RENAMED))
            for rowid, text in conn.execute("SELECT rowid, scenario_json FROM params").fetchall():
                conn.execute("UPDATE params SET scenario_json=? WHERE rowid=?",
                             (json.dumps(_escaped_scenario(json.loads(text))), rowid))
            conn.commit()
        return
    data = _renamed(base_json(base, "summary.json"), RENAMED, ESCAPED_NAME)
    data["scenario"], data["scenario_config"] = ESCAPED_NAME, _escaped_scenario(data["scenario_config"])
    (target / "summary.json").write_text(json.dumps(data))
    for name in ("rows.csv", "runs.csv"):
        if (target / name).exists():
            lines = (target / name).read_text().splitlines()
            (target / name).write_text("\n".join(",".join(ESCAPED_NAME if c == RENAMED else c for c in line.split(","))
                                                 for line in lines) + "\n")
    for name in ("run.npz", "curves.npz"):
        if (target / name).exists():
            arrays = {(k[:-len(RENAMED)] + ESCAPED_NAME if k.endswith("_" + RENAMED) else k): v
                      for k, v in base_npz(base, name).items()}
            for key in ("estimates", "algorithms"):
                if key in arrays:
                    arrays[key] = np.array([ESCAPED_NAME if str(x) == RENAMED else str(x) for x in arrays[key]])
            _savez(target / name, arrays)


def _stored_sql(path: Path, mutation: str) -> None:
    with contextlib.closing(sqlite3.connect(path)) as conn:
        for rowid, text in conn.execute("SELECT rowid, scenario_json FROM params").fetchall():
            conn.execute("UPDATE params SET scenario_json=? WHERE rowid=?",
                         (json.dumps(_stored(json.loads(text), mutation)), rowid))
        conn.commit()


def build_mutant(spec: ResultMutant, into: Path) -> Path:
    """A copy of the base of ``spec`` inside ``into`` with the mutation applied; returns what the
    commands read (the folder, or the database file).  Files a mutation names outside the
    result (a canary, a FIFO) go to tools/fuzz_scenarios' :func:`mutant_dir`."""
    shutil.rmtree(fz.mutant_dir(), ignore_errors=True)
    src = base_dir() / spec.scenario
    target = into / spec.scenario
    shutil.copytree(src, target)
    name, *where = spec.path
    path = target / name
    m = spec.mutation
    if m == "none":                   # the base itself (a check of the checker)
        pass
    elif m in FILE_MUTATIONS:
        _file(path, m, seed=hash(spec.label) & 0xFFFF)
    elif m in NAME_MUTATIONS:
        _names(target, spec.scenario)
    elif m in STORED_MUTATIONS and name.endswith(".sqlite"):
        _stored_sql(path, m)
    elif m in STORED_MUTATIONS:
        data = copy.deepcopy(base_json(spec.scenario, name))
        data["scenario_config"] = _stored(data["scenario_config"], m)
        path.write_text(json.dumps(data))
    elif m in BIG_JSON_MUTATIONS:
        data = copy.deepcopy(base_json(spec.scenario, name))
        data["fuzz_big"] = "x" * 40_000_000
        path.write_text(json.dumps(data))
    elif name.endswith(".json"):
        data = copy.deepcopy(base_json(spec.scenario, name))
        JSON_MUTATIONS[m].edit(data, tuple(where))
        limit = sys.getrecursionlimit()
        sys.setrecursionlimit(max(limit, 10_000))          # (the 1000-level nesting mutation)
        try:
            path.write_text(json.dumps(data))
        finally:
            sys.setrecursionlimit(limit)
    elif name.endswith(".npz"):
        _npz(path, where[0], m)
    elif name.endswith(".csv"):
        _csv(path, where[0], m)
    elif name.endswith(".sqlite"):
        _sql(path, tuple(where), m)
    return target / "s.sqlite" if spec.scenario in SWEEPS else target


# =========================================================================== checking one mutant
#: Characters that must never reach a terminal raw (C0 and C1 controls but newline and tab).
RAW_CONTROL = re.compile("[\x00-\x08\x0b-\x1f\x7f-\x9f]")
#: The bases read by ``dkfsim.load_run`` too (run folders), and the ``--x`` of each sweep.
RUN_BASES = ("run", "channel", "mobility", "centre")
SWEEP_X = {"sweep": "d_t", "sweep_channel": "rate"}


def _command(argv: list[str]) -> tuple[int, str]:
    """``dkfsim ARGV`` in this process: (exit status, what it wrote on stderr and stdout).
    Warnings are shown (to the captured stderr), as a user's terminal shows them.  Exceptions
    other than the ones the CLI turns into exit statuses propagate (findings)."""
    from dkfsim.cli.main import main
    from dkfsim.report.plots.style import png_resolution
    err, out = io.StringIO(), io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out), png_resolution(40), \
            warnings.catch_warnings():
        warnings.simplefilter("default")
        status = main(argv)
    return status, err.getvalue() + out.getvalue()


def _leak(text: str, terminal: bool = True) -> str:
    """What makes ``text`` unfit for a terminal (``terminal``: what a command printed) or a shared
    file (a report) ("" if nothing): a raw control character on a terminal, or the content of a
    file the result names (the canary) anywhere."""
    if terminal and RAW_CONTROL.search(text):
        return f"raw control character {RAW_CONTROL.search(text).group()!r} in the output"
    if fz.CANARY in text:
        return "the output quotes a file the result names"
    return ""


def check_mutant(spec: ResultMutant) -> fz.Outcome:
    """Build ``spec`` and run the reading commands on it; classify (see the module docstring)."""
    fields = dict(scenario=spec.scenario, path=fz.dotted(spec.path), mutation=spec.mutation)
    start = time.perf_counter()
    phase = "build"
    errors = []
    with tempfile.TemporaryDirectory(prefix="fuzz_results_") as tmp:
        into, out = Path(tmp) / "input", Path(tmp) / "out"
        into.mkdir()
        out.mkdir()
        target = build_mutant(spec, into)
        commands: list[tuple[str, Callable]] = [
            ("plot", lambda: _command(["plot", str(target), "--format", "png", "--out", str(out / "figs")]
                                      + (["--x", SWEEP_X[spec.scenario]] if spec.scenario in SWEEPS else []))),
            ("report", lambda: _command(["report", str(target), "--out", str(out / "r.html")]))]
        if spec.scenario in RUN_BASES:
            commands.append(("load_run", lambda: (dkfsim.load_run(target), (0, ""))[1]))
        fz.watch_opens(into, out)
        try:
            for phase, run in commands:
                try:
                    status, err = run()
                except DkfsimError as exc:          # (load_run raises; the CLI returns 2)
                    status, err = 2, f"dkfsim: error: {exc}\n"
                if status not in (0, 2):
                    return fz.Outcome(**fields, cls=f"finding:exit_{status}", phase=phase, error=err[:300],
                                      seconds=time.perf_counter() - start)
                report = out / "r.html"
                leak = _leak(err) or (_leak(report.read_text(errors="replace"), terminal=False)
                                      if phase == "report" and report.exists() else "")
                if leak:
                    return fz.Outcome(**fields, cls="finding:bad_message:leak", phase=phase,
                                      error=f"{leak}: {fz._first_line(ascii(err))}",
                                      seconds=time.perf_counter() - start, details=ascii(err[-4000:]))
                if status == 2:
                    problem = fz.message_problem(err.strip()) or ("Traceback" in err and "traceback") or ""
                    if problem:
                        return fz.Outcome(**fields, cls="finding:bad_message:DkfsimError", phase=phase,
                                          error=f"{problem}: {fz._first_line(err)}",
                                          seconds=time.perf_counter() - start, details=err[-4000:])
                    errors.append(fz._first_line(err))
        except fz.Overrun as exc:
            return fz.Outcome(**fields, cls="timeout", phase=phase, error="time limit hit",
                              location=fz._innermost_dkfsim_frame(exc), seconds=time.perf_counter() - start,
                              details=fz._traceback_text(exc))
        except Exception as exc:  # noqa: BLE001  (everything else breaks the contract)
            cls = "memory" if isinstance(exc, MemoryError) else f"finding:{type(exc).__name__}"
            return fz.Outcome(**fields, cls=cls, phase=phase, error=fz._first_line(f"{type(exc).__name__}: {exc}"),
                              location=fz._innermost_dkfsim_frame(exc), seconds=time.perf_counter() - start,
                              details=fz._traceback_text(exc))
    cls = "clean_error" if errors else "ran"
    return fz.Outcome(**fields, cls=cls, phase=phase, error=errors[0] if errors else "",
                      seconds=time.perf_counter() - start)


class ResultChecker(fz.MutantChecker):
    """tools/fuzz_scenarios' worker pool (time limit, memory cap, stack dumps) running
    :func:`check_mutant` of this module."""

    def __init__(self, jobs: int = fz.MAX_JOBS, timeout: float = DEFAULT_TIMEOUT):
        base_dir()                    # made once, before the workers fork
        super().__init__(jobs, timeout, check=check_mutant)


# =========================================================================== main
def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--limit", type=int, default=DEFAULT_LIMIT,
                        help=f"JSON and npz mutants to check, a seeded sample (default {DEFAULT_LIMIT}; 0: all); "
                             "whole-file and database mutants are always checked")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--timeout", type=float, default=DEFAULT_TIMEOUT)
    parser.add_argument("--jobs", type=int, default=fz.MAX_JOBS)
    parser.add_argument("--base", action="append", choices=BASES)
    parser.add_argument("--family", action="append", choices=("file", "json", "npz", "csv", "sql", "stored",
                                                               "names", "big"),
                        help="only mutants of this kind (repeatable; default: all)")
    parser.add_argument("--examples", type=int, default=3)
    parser.add_argument("--json", metavar="OUT")
    args = parser.parse_args(argv)
    everything = enumerate_mutants(args.base or BASES)
    if args.family:
        everything = [spec for spec in everything if family(spec) in args.family]
    specs = select(everything, args.limit, args.seed)
    print(f"checking {len(specs)} of {len(everything)} mutants on {min(args.jobs, fz.MAX_JOBS)} worker(s), "
          f"{args.timeout:g} s each at most", file=sys.stderr)
    step = max(1, len(specs) // 20)
    done = Counter()

    def progress(o: fz.Outcome) -> None:
        done[o.acceptable] += 1
        if sum(done.values()) % step == 0:
            print(f"  {sum(done.values())}/{len(specs)} checked, {done[False]} findings", file=sys.stderr)

    start = time.monotonic()
    with ResultChecker(args.jobs, args.timeout) as checker:
        outcomes = checker.check_all(specs, progress)
    print(f"done in {time.monotonic() - start:.0f} s", file=sys.stderr)
    by_label = {spec.label: spec for spec in specs}
    bases = fz.surface_counts(outcomes, lambda o: o.scenario)
    families = fz.surface_counts(outcomes, lambda o: family(by_label[o.label]))
    print("per base:")
    fz.print_surfaces(bases)
    print("per kind of mutation:")
    fz.print_surfaces(families)
    fz.print_report(outcomes, args.examples)
    if args.json:
        Path(args.json).write_text(json.dumps({
            "total": len(everything), "checked": len(outcomes), "counts": Counter(o.cls for o in outcomes),
            "bases": bases, "families": families, "outcomes": [asdict(o) for o in outcomes]}, indent=1))
    return int(any(not o.acceptable for o in outcomes))


if __name__ == "__main__":
    sys.exit(main())

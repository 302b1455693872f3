#!/usr/bin/env python
"""Mutation fuzzer for result folders and sweep databases: reading any of them ends cleanly.

The sibling of tools/fuzz_scenarios.py for what dkfsim *reads back* (issue 20): a run folder,
a Monte Carlo folder and a sweep database are made once, small and legitimate (the *bases*);
a mutant is a copy of one with one mutation applied; the reading commands run on it:
``dkfsim plot`` (PNG only), ``dkfsim report`` and, for a run folder, ``dkfsim.load_run``.
The contract, per mutant: every command either succeeds or ends in a
:class:`dkfsim.DkfsimError` with a one-paragraph message -- no other exception (a traceback),
no hang (the time limit), no MemoryError under the worker's address-space cap, no crash.
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
  levels of nesting, names with mathtext.

Usage::

    python tools/fuzz_results.py [--limit N] [--seed S] [--timeout S] [--jobs J]
                                 [--base run|mc|sweep ...] [--examples K] [--json OUT]

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
import shutil  # noqa: E402
import sqlite3  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
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
BASES = ("run", "mc", "sweep")
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
    """The three legitimate bases, made once per process in a temporary folder."""
    d = Path(tempfile.mkdtemp(prefix="fuzz_results_bases_"))
    sc = dkfsim.load_scenario(CASE1, overrides=["steps=20", "estimators=[{kind: centralized}, "
                                                "{kind: ci_consensus, rounds: 1}]"])
    dkfsim.run(sc).save(d / "run")
    dkfsim.montecarlo(sc, runs=2).save(d / "mc")
    (d / "sweep").mkdir()
    (d / "sweep" / "s.yaml").write_text(json.dumps({
        "scenario": str(CASE1), "grid": {"links.default.latency.d_t": [0, 2]},
        "set": ["steps=20", "estimators=[{kind: centralized}]"], "runs": 2}))
    dkfsim.sweep(d / "sweep" / "s.yaml", jobs=1, progress=False)
    for leftover in (d / "sweep").glob("s.sqlite-*"):
        leftover.unlink()
    return d


def base_files(base: str) -> list[str]:
    folder = base_dir() / base
    names = ["s.sqlite"] if base == "sweep" else sorted(p.name for p in folder.iterdir() if not p.name.startswith("."))
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


def enumerate_mutants(bases=BASES) -> list[ResultMutant]:
    """Every mutant of the given bases, in a fixed order."""
    out: list[ResultMutant] = []
    for base in bases:
        for name in base_files(base):
            out += [ResultMutant(base, (name,), m) for m in FILE_MUTATIONS]
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
                for table, cols in base_tables().items():
                    out.append(ResultMutant(base, (name, table), "drop_table"))
                    out += [ResultMutant(base, (name, table, col), f"set_{v}") for col in cols for v in SQL_VALUES]
                for cell in JSON_CELLS:
                    out += [ResultMutant(base, (name, cell), f"json_{v}") for v in JSON_CELL_VALUES]
    return out


def select(specs: list[ResultMutant], limit: int, seed: int) -> list[ResultMutant]:
    """Every file and database mutant plus a seeded sample of ``limit`` others (JSON and npz)."""
    always = [i for i, s in enumerate(specs) if s.mutation in FILE_MUTATIONS or s.scenario == "sweep"]
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


def build_mutant(spec: ResultMutant, into: Path) -> Path:
    """A copy of the base of ``spec`` inside ``into`` with the mutation applied; returns what the
    commands read (the folder, or the database file)."""
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
    return target / "s.sqlite" if spec.scenario == "sweep" else target


# =========================================================================== checking one mutant
def _command(argv: list[str]) -> tuple[int, str]:
    """``dkfsim ARGV`` in this process: (exit status, stderr).  Exceptions other than the ones the
    CLI turns into exit statuses propagate (findings)."""
    from dkfsim.cli.main import main
    from dkfsim.report.plots.style import png_resolution
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()), png_resolution(40):
        status = main(argv)
    return status, err.getvalue()


def check_mutant(spec: ResultMutant) -> fz.Outcome:
    """Build ``spec`` and run the reading commands on it; classify (see the module docstring)."""
    fields = dict(scenario=spec.scenario, path=fz.dotted(spec.path), mutation=spec.mutation)
    start = time.perf_counter()
    phase = "build"
    errors = []
    with tempfile.TemporaryDirectory(prefix="fuzz_results_") as tmp:
        target = build_mutant(spec, Path(tmp))
        commands: list[tuple[str, Callable]] = [
            ("plot", lambda: _command(["plot", str(target), "--format", "png", "--out", str(Path(tmp) / "figs")]
                                      + (["--x", "d_t"] if spec.scenario == "sweep" else []))),
            ("report", lambda: _command(["report", str(target), "--out", str(Path(tmp) / "r.html")]))]
        if spec.scenario == "run":
            commands.append(("load_run", lambda: (dkfsim.load_run(target), (0, ""))[1]))
        try:
            for phase, run in commands:
                try:
                    status, err = run()
                except DkfsimError as exc:          # (load_run raises; the CLI returns 2)
                    status, err = 2, f"dkfsim: error: {exc}\n"
                if status not in (0, 2):
                    return fz.Outcome(**fields, cls=f"finding:exit_{status}", phase=phase, error=err[:300],
                                      seconds=time.perf_counter() - start)
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
    parser.add_argument("--examples", type=int, default=3)
    parser.add_argument("--json", metavar="OUT")
    args = parser.parse_args(argv)
    everything = enumerate_mutants(args.base or BASES)
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
    by_base = Counter((o.scenario, o.cls) for o in outcomes)
    print("per base: " + ", ".join(f"{b} {c}: {n}" for (b, c), n in sorted(by_base.items())))
    fz.print_report(outcomes, args.examples)
    if args.json:
        Path(args.json).write_text(json.dumps({
            "total": len(everything), "checked": len(outcomes), "counts": Counter(o.cls for o in outcomes),
            "outcomes": [asdict(o) for o in outcomes]}, indent=1))
    return int(any(not o.acceptable for o in outcomes))


if __name__ == "__main__":
    sys.exit(main())

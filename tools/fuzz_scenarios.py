#!/usr/bin/env python
"""Mutation fuzzer for scenario files: every bad input must fail cleanly or run.

The contract checked for every mutant of a shipped scenario: EITHER

* validation (``dkfsim.load_scenario``) raises a :class:`dkfsim.DkfsimError`
  whose message is one paragraph (not empty, no newline, under
  ``MESSAGE_LIMIT`` characters: the CLI prints it as it is), OR
* validation succeeds and a short run (``dkfsim.run(..., save="summary")``,
  ``RUN_STEPS`` steps, the scenario's seed) ends within the time limit, either
  normally or with such a DkfsimError (e.g. a resource refusal).

Outcome classes: ``clean_error`` and ``ran`` keep the contract.  The others
are findings: ``finding:<ExceptionType>`` (any other exception: a bug that
would show a traceback), ``finding:bad_message:<ExceptionType>`` (a
DkfsimError with a multi-line, empty or huge message), ``memory`` (a
MemoryError: each worker's address space is capped at ``MEMORY_LIMIT``, so
an absurd allocation fails there instead of exhausting the machine),
``timeout`` (no answer within the time limit; the traceback taken at the
limit names where it was stuck) and ``crash`` (the worker died, e.g. on a
segfault).

Mutants.  Each shipped scenario is loaded by path (so relative data files
resolve), turned into ``to_dict()``, its ``file`` keys made absolute (a
mapping has no folder to resolve them against) and its ``steps`` set to
``RUN_STEPS``: that is the *base*.  A mutant is a base with one mutation
applied at one key path: every value of the nested mapping, leaves and
containers alike, gets every mutation of ``VOCABULARY`` that applies to it
(replacement by odd values, numeric scaling, matrix scaling, deletion, an
unknown key); the root gets the whole-structure mutations (duplicated or no
sensors, 10**12 steps, 10**7 consensus rounds, a 20000-node random tree).
Besides the shipped scenarios, three synthetic bases put the surfaces of issue 30 on paper
case 1 (``rate_links``: rate, queue and background on the default and on overrides;
``fcd_mobility``: every vehicle a ``sumo_fcd`` of a generated FCD file, a link quality from
distance; ``centre_links``: the fusion centre over rate-limited links), and mutations aim at
them: every SUMO FCD file replaced by a hostile one (a 100 MB attribute, 50 MB of text, +-1e308
coordinates, times 1e-300 apart, entity bombs, an external entity, deep nesting, ...), every
``file``/``dataset`` key by a FIFO, a device, a directory or a canary file whose content no
message may quote, and whole-scenario ones (a link background of 1e9 packets/s, two overrides
of one link, 8128 overrides, a channel queue of one byte, rates from distance of 1e-300 and
1e100 bit/s, a vehicle given as 0 and '0', a fusion centre named with 10 000 characters).
Each worker records what it opens (an audit hook) and its peak memory per mutant: opening a
file outside the mutant's inputs and the allowed roots, or a peak above 3 GiB, is a finding;
the report counts them per surface (``--surface`` checks one).
The enumeration is deterministic; ``--limit`` checks a seeded random subset
of the leaf mutants plus every whole-structure one.

tests/test_fuzz_scenarios.py draws mutants from the same vocabulary with
Hypothesis and asserts the contract.

Usage::

    python tools/fuzz_scenarios.py [--limit N] [--seed S] [--timeout S] [--jobs J]
                                   [--scenario NAME ...] [--surface NAME ...] [--examples K]
                                   [--json OUT]

The exit status is 1 when there is any finding.
"""

from __future__ import annotations

import os

if __name__ == "__main__":
    # One BLAS thread per worker (set before numpy loads): the fuzzer runs at
    # most two worker processes on cores shared with other work.
    for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import atexit  # noqa: E402
import copy  # noqa: E402
import faulthandler  # noqa: E402
import functools  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import multiprocessing  # noqa: E402
import random  # noqa: E402
import re  # noqa: E402
import resource  # noqa: E402
import shutil  # noqa: E402
import signal  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
import traceback  # noqa: E402
import warnings  # noqa: E402
from collections import Counter, defaultdict  # noqa: E402
from dataclasses import asdict, dataclass  # noqa: E402
from multiprocessing.connection import wait  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any, Callable, Iterable, NamedTuple  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import dkfsim  # noqa: E402
from dkfsim.core.errors import DkfsimError  # noqa: E402

SCENARIO_DIR = ROOT / "scenarios"
#: Shipped YAML files that are not scenarios: the sweep files, named ``sweep_*.yaml``.
NOT_SCENARIOS = frozenset(p.name for p in SCENARIO_DIR.glob("sweep_*.yaml"))
DKFSIM_DIR = Path(dkfsim.__file__).resolve().parent

#: Steps of every mutant's run (the mutant's own ``steps`` key, so a mutation of it sticks).
RUN_STEPS = 4
#: Seconds a mutant may take, validation and run together.
DEFAULT_TIMEOUT = 10.0
#: Extra seconds before the parent kills a worker deaf to its time limit (stuck in C code).
STUCK_GRACE = 5.0
#: Address-space cap of a worker (bytes).
MEMORY_LIMIT = 4 << 30
#: A clean error message is shorter than this.
MESSAGE_LIMIT = 2000
#: Leaf mutants checked by default.  Measured: 6000 took 3 minutes on 2 idle cores
#: (60 mutants/s, plus 10 s per timeout), so this takes about 5, leaving room for busy cores.
DEFAULT_LIMIT = 12000
MAX_JOBS = 2
#: Outcome classes that keep the contract.
ACCEPTABLE = frozenset({"clean_error", "ran"})
#: The key the ``add_unknown_key`` mutation adds.
UNKNOWN_KEY = "fuzz_unknown_key"

KeyPath = tuple  # of str (mapping keys) and int (list indices); () is the root


# =========================================================================== scenarios and bases
def shipped_scenarios() -> list[str]:
    """Names (file stems) of the shipped scenarios, sorted."""
    return sorted(p.stem for p in SCENARIO_DIR.glob("*.yaml") if p.name not in NOT_SCENARIOS)


def absolute_files(data: Any, base_dir: Path) -> Any:
    """``data`` with every string value of a key named ``file`` made absolute
    against ``base_dir`` (the scenario's folder), recursively."""
    if isinstance(data, dict):
        return {key: (os.path.normpath(base_dir / value)
                      if key == "file" and isinstance(value, str) else absolute_files(value, base_dir))
                for key, value in data.items()}
    if isinstance(data, list):
        return [absolute_files(value, base_dir) for value in data]
    return data


@functools.lru_cache(maxsize=None)
def base(name: str) -> dict:
    """The base mapping of shipped scenario ``name`` (see the module docstring).

    Cached and shared: callers must not edit it (``build_mutant`` deep-copies).
    """
    if name in SYNTHETIC:
        data = dkfsim.load_scenario(_synthetic(name)).to_dict()
    else:
        path = SCENARIO_DIR / f"{name}.yaml"
        data = absolute_files(dkfsim.load_scenario(path).to_dict(), path.parent)
    data["steps"] = RUN_STEPS
    return data


def base_names() -> list[str]:
    """Every base: the shipped scenarios, then the synthetic ones (:data:`SYNTHETIC`)."""
    return shipped_scenarios() + list(SYNTHETIC)


def value_at(data: Any, path: KeyPath) -> Any:
    """The value at ``path`` in ``data``."""
    for key in path:
        data = data[key]
    return data


def walk(data: Any, path: KeyPath = ()) -> Iterable[tuple[KeyPath, Any]]:
    """Every (key path, value) of ``data`` in pre-order, the root ``()`` first."""
    yield path, data
    if isinstance(data, dict):
        for key, value in data.items():
            yield from walk(value, path + (key,))
    elif isinstance(data, list):
        for index, value in enumerate(data):
            yield from walk(value, path + (index,))


def dotted(path: KeyPath) -> str:
    """``sensors.0.R`` for ``("sensors", 0, "R")``; ``<root>`` for ``()``."""
    return ".".join(str(key) for key in path) or "<root>"


# =========================================================================== the mutation vocabulary
@dataclass(frozen=True)
class Mutation:
    """One way to break a scenario.

    ``applies(path, value)`` says whether it makes sense at ``path`` (whose
    current value is ``value``); ``edit(root, path)`` applies it to ``root``
    in place.
    """

    name: str
    applies: Callable[[KeyPath, Any], bool]
    edit: Callable[[dict, KeyPath], None]


def _is_member(path: KeyPath, _value: Any) -> bool:
    return path != ()


def _is_number(path: KeyPath, value: Any) -> bool:
    return path != () and isinstance(value, (int, float)) and not isinstance(value, bool)


def _is_scalar(path: KeyPath, value: Any) -> bool:
    return path != () and not isinstance(value, (list, dict))


def _is_matrix(path: KeyPath, value: Any) -> bool:
    """A non-empty list of non-empty lists of numbers."""
    return (path != () and isinstance(value, list) and bool(value)
            and all(isinstance(row, list) and row and all(_is_number(path, x) for x in row)
                    for row in value))


def _is_mapping(_path: KeyPath, value: Any) -> bool:
    return isinstance(value, dict)


def _is_root(path: KeyPath, _value: Any) -> bool:
    return path == ()


def _replace(name: str, new: Callable[[Any], Any],
             applies: Callable[[KeyPath, Any], bool] = _is_member) -> Mutation:
    """Replace the value at the path by ``new(old value)``."""
    def edit(root: dict, path: KeyPath) -> None:
        parent = value_at(root, path[:-1])
        parent[path[-1]] = new(parent[path[-1]])
    return Mutation(name, applies, edit)


def _constant(name: str, make: Callable[[], Any]) -> Mutation:
    """Replace the value by a fresh ``make()``, except where it already is that value."""
    def applies(path: KeyPath, value: Any) -> bool:
        new = make()
        return path != () and not (type(new) is type(value) and new == value)
    return _replace(name, lambda _old: make(), applies)


def _deep_list(depth: int = 1000) -> list:
    """``[[[...[1]...]]]``, ``depth`` lists deep."""
    value: Any = 1
    for _ in range(depth):
        value = [value]
    return value


def _times_1e6(value: int | float) -> int | float:
    """value * 1e6, keeping an integer an integer (so strict integer keys take it)."""
    return value * 10**6 if isinstance(value, int) else value * 1e6


def _scale_matrix(factor: float) -> Callable[[list], list]:
    return lambda rows: [[x * factor for x in row] for row in rows]


def _delete(root: dict, path: KeyPath) -> None:
    parent = value_at(root, path[:-1])
    del parent[path[-1]]


def _add_unknown_key(root: dict, path: KeyPath) -> None:
    value_at(root, path)[UNKNOWN_KEY] = 1


def _whole(edit: Callable[[dict], None]) -> Callable[[dict, KeyPath], None]:
    return lambda root, _path: edit(root)


def _duplicate_sensor(root: dict) -> None:
    root["sensors"].append(copy.deepcopy(root["sensors"][0]))


def _duplicate_sensor_renamed(root: dict) -> None:
    sensor = copy.deepcopy(root["sensors"][0])
    sensor["name"] += "_copy"
    root["sensors"].append(sensor)


def _drop_sensors(root: dict) -> None:
    root["sensors"] = []


def _steps_1e12(root: dict) -> None:
    root["steps"] = 10**12


def _consensus_rounds_1e7(root: dict) -> None:
    """10**7 rounds per tick, with the ci_consensus estimator that runs them.

    A base is ``to_dict()`` output (an ``estimators:`` list of ``{kind, ...}``
    entries); the older spelling (``baselines:`` names with a top-level
    ``consensus_rounds``) is handled too, so a mapping written either way works.
    """
    rounds = 10**7
    found = False
    old = root.get("baselines")
    if isinstance(old, list):
        root["consensus_rounds"] = rounds
        found = "ci_consensus" in old
    for entry in root.get("estimators") or []:
        if isinstance(entry, dict) and entry.get("kind") == "ci_consensus":
            entry["rounds"] = rounds
            found = True
    if not found:
        if isinstance(old, list) and "estimators" not in root:
            old.append("ci_consensus")
        else:
            root.setdefault("estimators", []).append({"kind": "ci_consensus", "rounds": rounds})


def _random_tree_20000(root: dict) -> None:
    """20000 copies of the first sensor on a random tree."""
    first = root["sensors"][0]
    root["sensors"] = [dict(copy.deepcopy(first), name=f"s{i}") for i in range(20000)]
    root["topology"] = {"directed": False, "generator": "random_tree"}


#: Every mutation, in the order the enumeration applies them at a path.
VOCABULARY: tuple[Mutation, ...] = (
    _constant("None", lambda: None),
    _constant("True", lambda: True),
    _constant("'x'", lambda: "x"),
    _constant("''", lambda: ""),
    _constant("'1e3'", lambda: "1e3"),
    _constant("0", lambda: 0),
    _constant("-1", lambda: -1),
    _constant("1", lambda: 1),
    _constant("2**62", lambda: 2**62),
    _constant("2**63", lambda: 2**63),
    _constant("-2**63", lambda: -2**63),
    _constant("1e300", lambda: 1e300),
    _constant("-1e300", lambda: -1e300),
    _constant("1e-300", lambda: 1e-300),
    _constant("nan", lambda: math.nan),
    _constant("inf", lambda: math.inf),
    _constant("[]", lambda: []),
    _constant("{}", lambda: {}),
    _constant("[[1]]", lambda: [[1]]),
    _constant("deep_list_1000", _deep_list),
    _constant("zeros_1e5", lambda: [0] * 10**5),
    _replace("wrap_in_list", lambda old: [old]),
    _replace("wrap_in_dict", lambda old: {"value": old}, _is_scalar),
    _replace("times_1e6", _times_1e6, _is_number),
    _replace("negate", lambda old: -old, _is_number),
    _replace("plus_0.5", lambda old: old + 0.5, _is_number),
    _replace("matrix_times_1e150", _scale_matrix(1e150), _is_matrix),
    _replace("matrix_times_1e300", _scale_matrix(1e300), _is_matrix),
    Mutation("delete", _is_member, _delete),
    # An unknown sibling of every key of a mapping is one mutant per mapping, not per key.
    Mutation("add_unknown_key", _is_mapping, _add_unknown_key),
    Mutation("duplicate_sensor", _is_root, _whole(_duplicate_sensor)),
    Mutation("duplicate_sensor_renamed", _is_root, _whole(_duplicate_sensor_renamed)),
    Mutation("drop_sensors", _is_root, _whole(_drop_sensors)),
    Mutation("steps_1e12", _is_root, _whole(_steps_1e12)),
    Mutation("consensus_rounds_1e7", _is_root, _whole(_consensus_rounds_1e7)),
    Mutation("random_tree_20000", _is_root, _whole(_random_tree_20000)),
)


# =========================================================================== the new surfaces (issue 30)
# Rate-limited links, the shared channel (``medium:``), mobility and SUMO FCD files, the fusion
# centre: bases that use them (besides the shipped scenarios that do), mutations aimed at them,
# and mutations of the data files a scenario names (a FIFO, a device, a directory, a file whose
# content must never be quoted).  Mutated files are written into a scratch folder of the process.

#: Bases made here (from paper_case1) rather than shipped: each puts one new surface on it.
SYNTHETIC = ("rate_links", "fcd_mobility", "centre_links")
#: A line no message may quote: the content of a data file the scenario names.
CANARY = "CANARY-30-SECRET"
#: Bytes of the attribute of the ``fcd_huge_attribute`` mutation (the issue's 100 MB).
HUGE_ATTRIBUTE = 100_000_000


@functools.lru_cache(maxsize=None)
def own_dir() -> Path:
    """A scratch folder of this process (and of the workers it forks), removed at its exit:
    the synthetic bases' FCD file, the mutated data files, the workers' working folder."""
    d = Path(tempfile.mkdtemp(prefix="fuzz_scenarios_files_"))
    owner = os.getpid()
    atexit.register(lambda: os.getpid() == owner and shutil.rmtree(d, ignore_errors=True))
    return d


def mutant_dir() -> Path:
    """Where the current mutant's files go (emptied by :func:`build_mutant`)."""
    d = own_dir() / f"mutant-{os.getpid()}"
    d.mkdir(exist_ok=True)
    return d


def fcd_text(vehicles: int = 12, steps: int = 20, dt: float = 0.5, attrs=None, times=None) -> str:
    """A small SUMO FCD file: ``vehicles`` vehicles ``v0 ..`` over ``steps`` timesteps, 10 m
    apart and moving at 6 m/s.  ``attrs(k, v)`` may replace a sample's attributes, ``times``
    the timesteps' times."""
    lines = ['<?xml version="1.0" encoding="UTF-8"?>', "<fcd-export>"]
    for k in range(steps):
        t = times[k] if times is not None else f"{k * dt:.2f}"
        lines.append(f'  <timestep time="{t}">')
        for v in range(vehicles):
            a = {"id": f"v{v}", "x": f"{10.0 * v + 3.0 * k:.2f}", "y": f"{5.0 * (v % 3):.2f}",
                 "angle": "90.00", "type": "car", "speed": "6.00", "pos": "0", "lane": "e_0"}
            if attrs is not None:
                a = attrs(k, v, a)
            if a is not None:
                lines.append("    <vehicle " + " ".join(f'{key}="{val}"' for key, val in a.items()) + "/>")
        lines.append("  </timestep>")
    lines.append("</fcd-export>")
    return "\n".join(lines) + "\n"


@functools.lru_cache(maxsize=None)
def fcd_base_file() -> str:
    path = own_dir() / "base.fcd.xml"
    path.write_text(fcd_text())
    return str(path)


def _synthetic(name: str) -> dict:
    """The mapping of synthetic base ``name`` before validation (see :data:`SYNTHETIC`)."""
    data = copy.deepcopy(base("paper_case1"))
    links = data.setdefault("links", {})
    if name == "rate_links":
        links["default"].update(rate=2.0e6, queue={"packets": 20},
                                background={"arrivals": "poisson", "packets_per_second": 50.0, "size": 250})
        links["overrides"] = [
            {"link": [0, 1], "rate": 1.0e6, "queue": {"bytes": 50000},
             "background": {"arrivals": "periodic", "packets_per_second": 10.0, "size": 300, "offset": 0.001}},
            {"link": [1, 4], "loss": 0.1}]
    elif name == "fcd_mobility":
        fcd = fcd_base_file()
        data["mobility"] = {
            "vehicles": {"default": {"kind": "sumo_fcd", "file": fcd, "vehicle": "v0"},
                         **{str(i): {"kind": "sumo_fcd", "file": fcd, "vehicle": f"v{i}", "time_offset": 0.5}
                            for i in range(1, len(data["sensors"]))}},
            "range": {"model": "disk", "radius": 1000.0},
            "links": {"loss": [[0.0, 0.0], [500.0, 0.5]], "latency_per_m": 1.0e-9,
                      "rate": [[0.0, 1.0e7], [1000.0, 1.0e6]]}}
    elif name == "centre_links":
        links["default"].update(rate=5.0e6, queue={"packets": 10})
        data["estimators"] = [{"kind": "fusion_centre", "at": 0, "margin": 5}, {"kind": "centralized"}]
    return data


def _fcd_file(name: str, make: Callable[[Path], None]) -> Mutation:
    """Replace a SUMO FCD file (a ``file`` key ending ``.xml``) by a file ``make`` writes."""
    def edit(root: dict, path: KeyPath) -> None:
        target = mutant_dir() / f"{name}.xml"
        make(target)
        value_at(root, path[:-1])[path[-1]] = str(target)
    return Mutation(name, _is_fcd_file, edit)


def _is_fcd_file(path: KeyPath, value: Any) -> bool:
    return bool(path) and path[-1] == "file" and isinstance(value, str) and value.endswith(".xml")


def _is_data_file(path: KeyPath, value: Any) -> bool:
    """A ``file`` or ``dataset`` key: a table or an FCD file the scenario names."""
    return bool(path) and path[-1] in ("file", "dataset") and isinstance(value, str)


def _stream_xml(target: Path, head: str, filler: bytes, size: int, tail: str) -> None:
    with open(target, "wb") as fh:
        fh.write(head.encode())
        chunk = filler * ((1 << 20) // len(filler))
        left = size
        while left > 0:
            fh.write(chunk[:left])
            left -= len(chunk)
        fh.write(tail.encode())


def _write(text: str | bytes) -> Callable[[Path], None]:
    return lambda p: p.write_bytes(text if isinstance(text, bytes) else text.encode())


def _sample(edit: Callable[[dict], dict | None], k0: int = 0, v0: int = 0) -> Callable[[Path], None]:
    """An FCD file whose sample (timestep ``k0``, vehicle ``v0``) is ``edit``-ed."""
    return _write(fcd_text(attrs=lambda k, v, a: edit(dict(a)) if (k, v) == (k0, v0) else a))


_BILLION_LAUGHS = ('<?xml version="1.0"?><!DOCTYPE fcd-export [<!ENTITY a "aaaaaaaaaa">'
                   + "".join(f'<!ENTITY {chr(98 + i)} "{("&" + chr(97 + i) + ";") * 10}">' for i in range(8))
                   + ']><fcd-export><timestep time="0">&i;</timestep></fcd-export>')
_EXTERNAL = ('<?xml version="1.0"?><!DOCTYPE fcd-export [<!ENTITY x SYSTEM "file:///etc/passwd">]>'
             '<fcd-export><timestep time="0"><vehicle id="&x;" x="0" y="0"/></timestep></fcd-export>')

FCD_MUTATIONS: tuple[Mutation, ...] = (
    _fcd_file("fcd_huge_attribute", lambda p: _stream_xml(
        p, '<fcd-export><timestep time="0"><vehicle id="v0" x="0" y="0" type="', b"x", HUGE_ATTRIBUTE,
        '"/></timestep></fcd-export>')),
    _fcd_file("fcd_huge_text", lambda p: _stream_xml(
        p, '<fcd-export><timestep time="0">', b"text ", 50_000_000, "</timestep></fcd-export>")),
    _fcd_file("fcd_coords_1e308", _write(fcd_text(attrs=lambda k, v, a: (
        {**a, "x": "1e308" if k % 2 else "-1e308"} if v == 0 else a)))),
    _fcd_file("fcd_nan_coordinate", _sample(lambda a: {**a, "x": "nan"}, 3, 2)),
    _fcd_file("fcd_x_not_a_number", _sample(lambda a: {**a, "y": "12abc"}, 1, 1)),
    _fcd_file("fcd_missing_x", _sample(lambda a: {k: v for k, v in a.items() if k != "x"}, 2, 0)),
    _fcd_file("fcd_duplicate_vehicle", _write(fcd_text(attrs=lambda _k, v, a: {**a, "id": "v0"} if v == 1 else a))),
    _fcd_file("fcd_time_backwards", _write(fcd_text(times=[f"{t:g}" for t in [0, 1, 0.5] + list(range(2, 19))]))),
    _fcd_file("fcd_time_1e300", _write(fcd_text(times=[f"{k}" for k in range(19)] + ["1e300"]))),
    _fcd_file("fcd_tiny_time_steps", _write(fcd_text(times=[f"{k}e-300" for k in range(20)]))),
    _fcd_file("fcd_billion_laughs", _write(_BILLION_LAUGHS)),
    _fcd_file("fcd_external_entity", _write(_EXTERNAL)),
    _fcd_file("fcd_deep_nesting", _write('<fcd-export><timestep time="0">' + "<a>" * 200_000
                                         + "</a>" * 200_000 + "</timestep></fcd-export>")),
    _fcd_file("fcd_vehicle_id_1MB", _sample(lambda a: {**a, "id": "v" * 1_000_000})),
    _fcd_file("fcd_many_vehicles", lambda p: p.write_text(
        '<fcd-export><timestep time="0">'
        + "".join(f'<vehicle id="w{i}" x="0" y="0"/>' for i in range(300_000)) + "</timestep></fcd-export>")),
    _fcd_file("fcd_wrong_root", _write("<root><timestep time='0'/></root>")),
    _fcd_file("fcd_no_timestep", _write("<fcd-export/>")),
    _fcd_file("fcd_empty", _write(b"")),
    _fcd_file("fcd_binary", _write(random.Random(30).randbytes(20000))),
    _fcd_file("fcd_truncated", _write(fcd_text()[:3000])),
    _fcd_file("fcd_utf16", _write(fcd_text().replace('encoding="UTF-8"', 'encoding="UTF-16"').encode("utf-16"))),
)


def _special(kind: str) -> str:
    """A path of the given kind in the mutant's folder (or a system one)."""
    d = mutant_dir()
    if kind == "fifo":
        if not (d / "fifo").exists():
            os.mkfifo(d / "fifo")
        return str(d / "fifo")
    if kind == "symlink_fifo":
        if not (d / "link.xml").is_symlink():
            os.mkfifo(d / "fifo2")
            os.symlink(d / "fifo2", d / "link.xml")
        return str(d / "link.xml")
    if kind == "directory":
        (d / "folder").mkdir(exist_ok=True)
        return str(d / "folder")
    if kind == "canary":                   # a table (or anything) whose content must stay unread
        (d / "canary.txt").write_text(f"{CANARY}-HEADER a b\n1,{CANARY}-CELL,3\n2 3 {CANARY}\n")
        return str(d / "canary.txt")
    return {"dev_zero": "/dev/zero", "dev_null": "/dev/null"}[kind]


def _data_file(kind: str) -> Mutation:
    """Replace a ``file`` or ``dataset`` key by ``file: <a path of this kind>``."""
    def edit(root: dict, path: KeyPath) -> None:
        parent = value_at(root, path[:-1])
        del parent[path[-1]]
        parent["file"] = _special(kind)
    return Mutation(f"file_{kind}", _is_data_file, edit)


DATA_FILE_MUTATIONS = tuple(_data_file(k) for k in ("fifo", "symlink_fifo", "dev_zero", "dev_null",
                                                     "directory", "canary"))


def _first_edge(root: dict) -> list[int] | None:
    edges = (root.get("topology") or {}).get("edges")
    return list(edges[0]) if edges else None


def _background_1e9(root: dict) -> None:
    default = root.setdefault("links", {}).setdefault("default", {})
    default.setdefault("rate", 1.0e6)
    default["background"] = {"arrivals": "poisson", "packets_per_second": 1.0e9, "size": 100}


def _override_twice(root: dict) -> None:
    edge = _first_edge(root)
    root.setdefault("links", {}).setdefault("overrides", []).extend(
        [{"link": edge, "loss": 0.1}, {"link": edge[::-1], "loss": 0.2}])


def _overrides_complete_128(root: dict) -> None:
    """128 nodes on a complete graph and one override per edge (8128): validation time."""
    first = root["sensors"][0]
    root["sensors"] = [dict(copy.deepcopy(first), name=f"s{i}") for i in range(128)]
    edges = [[u, v] for u in range(128) for v in range(u + 1, 128)]
    root["topology"] = {"directed": False, "generator": "edges", "edges": edges}
    root["protocol"], root["spanning_tree"] = "tree", True
    root.pop("mobility", None)
    root.pop("medium", None)
    root["links"] = {"default": {"latency": {"model": "constant", "value": 0.0}},
                     "overrides": [{"link": e, "loss": 0.01} for e in edges]}


def _medium(root: dict) -> dict:
    root.setdefault("links", {}).setdefault("default", {})
    for key in ("rate", "queue", "background"):
        root["links"]["default"].pop(key, None)
    root["links"]["overrides"] = []
    return root.setdefault("medium", {"rate": 6.0e6})


def _medium_background_1e9(root: dict) -> None:
    _medium(root)["background"] = {"arrivals": "poisson", "packets_per_second": 1.0e9, "size": 100}


def _medium_queue_bytes_1(root: dict) -> None:
    _medium(root)["queue"] = {"bytes": 1}


def _mobility_rate(value: float) -> Callable[[dict], None]:
    def edit(root: dict) -> None:
        root["mobility"]["links"] = {**(root["mobility"].get("links") or {}), "rate": [[0.0, value]]}
        root.pop("medium", None)
    return edit


def _vehicle_key_twice(root: dict) -> None:
    vehicles = root["mobility"]["vehicles"]
    one = copy.deepcopy(next(iter(vehicles.values())))
    vehicles.pop("0", None)
    vehicles[0], vehicles["0"] = one, copy.deepcopy(one)


def _centre_name_10000(root: dict) -> None:
    root.setdefault("estimators", []).append({"kind": "fusion_centre", "at": 0, "name": "f" * 10_000})


def _root_with(key: str | None = None, edges: bool = False) -> Callable[[KeyPath, Any], bool]:
    def applies(path: KeyPath, value: Any) -> bool:
        return path == () and (key is None or value.get(key) is not None) and (not edges or bool(_first_edge(value)))
    return applies


SURFACE_ROOT_MUTATIONS: tuple[Mutation, ...] = (
    Mutation("traffic_background_1e9", _root_with(), _whole(_background_1e9)),
    Mutation("traffic_override_twice", _root_with(edges=True), _whole(_override_twice)),
    Mutation("traffic_overrides_complete_128", _root_with(), _whole(_overrides_complete_128)),
    Mutation("medium_background_1e9", _root_with(), _whole(_medium_background_1e9)),
    Mutation("medium_queue_bytes_1", _root_with(), _whole(_medium_queue_bytes_1)),
    Mutation("mobility_rate_1e-300", _root_with("mobility"), _whole(_mobility_rate(1e-300))),
    Mutation("mobility_rate_1e100", _root_with("mobility"), _whole(_mobility_rate(1e100))),
    Mutation("mobility_vehicle_key_twice", _root_with("mobility"), _whole(_vehicle_key_twice)),
    Mutation("centre_name_10000", _root_with(), _whole(_centre_name_10000)),
)

VOCABULARY += FCD_MUTATIONS + DATA_FILE_MUTATIONS + SURFACE_ROOT_MUTATIONS
MUTATIONS = {m.name: m for m in VOCABULARY}


class MutantSpec(NamedTuple):
    """A mutant by name: small and picklable; ``build_mutant`` makes the mapping."""

    scenario: str
    path: KeyPath
    mutation: str

    @property
    def label(self) -> str:
        return f"{self.scenario}:{dotted(self.path)}:{self.mutation}"


def mutation_paths(name: str) -> list[KeyPath]:
    """Every key path of scenario ``name``'s base, the root first."""
    return [path for path, _ in walk(base(name))]


def mutations_at(name: str, path: KeyPath) -> list[Mutation]:
    """The mutations of ``VOCABULARY`` that apply at ``path`` of scenario ``name``."""
    value = value_at(base(name), path)
    return [m for m in VOCABULARY if m.applies(path, value)]


def enumerate_mutants(names: Iterable[str] | None = None) -> list[MutantSpec]:
    """Every mutant of the given scenarios (default: all shipped), in a fixed order."""
    return [MutantSpec(name, path, m.name)
            for name in (base_names() if names is None else names)
            for path in mutation_paths(name)
            for m in mutations_at(name, path)]


def select(specs: list[MutantSpec], limit: int, seed: int) -> list[MutantSpec]:
    """Every whole-structure mutant plus a seeded random sample of ``limit`` others
    (all of them when ``limit`` is 0 or not smaller), in enumeration order."""
    leaves = [i for i, spec in enumerate(specs) if spec.path != ()]
    if 0 < limit < len(leaves):
        keep = set(random.Random(seed).sample(leaves, limit))
        return [spec for i, spec in enumerate(specs) if spec.path == () or i in keep]
    return list(specs)


def build_mutant(spec: MutantSpec) -> dict:
    """The scenario mapping of ``spec`` (its mutated files, if any, in :func:`mutant_dir`)."""
    shutil.rmtree(mutant_dir(), ignore_errors=True)
    root = copy.deepcopy(base(spec.scenario))
    MUTATIONS[spec.mutation].edit(root, spec.path)
    return root


# =========================================================================== what a check may open and use
#: Peak resident memory (MiB) a worker may reach on one mutant.
PEAK_LIMIT_MB = 3 * 1024
_WATCH: dict[str, Any] = {"on": False, "opened": [], "allowed": ()}


def _audit(event: str, args: tuple) -> None:
    """The workers' audit hook (``sys.addaudithook``): the path of every ``open`` and SQLite
    connection while a check's commands run."""
    if _WATCH["on"] and event in ("open", "sqlite3.connect") and args:
        path = args[0]
        if isinstance(path, (str, bytes, os.PathLike)):
            _WATCH["opened"].append(os.fsdecode(path))


def allowed_roots() -> list[str]:
    """What every check may open: the interpreter and its packages (``sys.prefix``, the base
    installation's standard library), the dkfsim package (its shipped data and, in an editable
    install, its modules, numba's cache beside them and its metadata ``dkfsim.egg-info``), the
    fuzzers themselves (tools/, whose source a traceback quotes), numba's and matplotlib's caches, the
    kernel's pseudo-files (/proc, /sys, /dev/null, /dev/urandom) and the worker's scratch folder
    (its working folder and its temporary files)."""
    import matplotlib

    roots = {sys.prefix, sys.base_prefix, sys.exec_prefix, str(DKFSIM_DIR), str(DKFSIM_DIR.parent / "dkfsim.egg-info"),
             str(ROOT / "tools"), "/proc", "/sys", "/dev/null", "/dev/urandom", str(own_dir() / "cwd"),
             matplotlib.get_cachedir(), matplotlib.get_configdir()}
    if os.environ.get("NUMBA_CACHE_DIR"):
        roots.add(os.environ["NUMBA_CACHE_DIR"])
    return sorted(os.path.abspath(r) for r in roots)


def watch_opens(*inputs: str | os.PathLike) -> None:
    """Record what the check opens from now on; ``inputs``: the files and folders it is given
    (and writes), which it may open besides :func:`allowed_roots`."""
    allowed = [os.path.abspath(p) for p in inputs] + [os.path.realpath(p) for p in inputs]   # (a link's target)
    _WATCH.update(on=True, opened=[], allowed=tuple(allowed))


def stray_opens() -> list[str]:
    """What the check opened outside its inputs and the allowed roots (and stop recording)."""
    _WATCH["on"] = False
    allowed = _WATCH["allowed"] + tuple(_ROOTS)
    out = []
    for p in dict.fromkeys(_WATCH["opened"]):
        full = os.path.abspath(p)
        if not any(full == r or full.startswith(r.rstrip("/") + "/") for r in allowed):
            out.append(full)
    return out


_ROOTS: list[str] = []


def _reset_peak() -> None:
    """Start a new peak of resident memory (``VmHWM``) for this process (Linux)."""
    try:
        with open("/proc/self/clear_refs", "w") as fh:
            fh.write("5")
    except OSError:
        pass


def _peak_mb() -> float:
    try:
        with open("/proc/self/status", "rb") as fh:
            return next(int(line.split()[1]) for line in fh if line.startswith(b"VmHWM:")) / 1024
    except (OSError, StopIteration, ValueError):
        return 0.0


def scenario_inputs(mutant: Any) -> list[str]:
    """The files a scenario names (its ``file`` keys): what validating and running it reads."""
    out, stack = [], [mutant]
    while stack:                         # (iterative: a mutant may be nested 1000 levels deep)
        node = stack.pop()
        if isinstance(node, dict):
            out += [v for k, v in node.items() if k == "file" and isinstance(v, str)]
            stack.extend(node.values())
        elif isinstance(node, list):
            stack.extend(node)
    return out


def surface(spec) -> str:
    """The surface a mutant of a scenario aims at: ``traffic`` (a link's rate, queue or
    background), ``medium``, ``mobility``, ``fcd`` (a SUMO FCD file), ``data_files`` (what a
    ``file``/``dataset`` key names), ``fusion_centre``, or ``other``."""
    m, path = spec.mutation, spec.path
    for prefix, name in (("fcd_", "fcd"), ("file_", "data_files"), ("traffic_", "traffic"),
                         ("medium_", "medium"), ("mobility_", "mobility"), ("centre_", "fusion_centre")):
        if m.startswith(prefix):
            return name
    if spec.scenario == "fcd_mobility" and path[:1] == ("mobility",):
        return "fcd"
    if path[:1] in (("medium",), ("mobility",)):
        return path[0]
    if path[:1] == ("links",) and any(k in ("rate", "queue", "background") for k in path):
        return "traffic"
    if path[:1] == ("estimators",) and len(path) > 1:
        entry = value_at(base(spec.scenario), path[:2])
        if isinstance(entry, dict) and entry.get("kind") == "fusion_centre":
            return "fusion_centre"
    return "other"


# =========================================================================== checking one mutant
@dataclass
class Outcome:
    """What one mutant did.

    ``cls`` is the outcome class (module docstring); ``phase`` ``validate``
    or ``run`` (where it ended; ``""`` when unknown); ``error`` the first
    line of the error; ``location`` the innermost frame in the dkfsim
    package (``dkfsim/x.py:LINE (function)``); ``details`` the traceback or
    stack dump of a finding.
    """

    scenario: str
    path: str
    mutation: str
    cls: str
    phase: str
    error: str = ""
    location: str = ""
    seconds: float = 0.0
    details: str = ""
    #: peak resident memory of the worker on this mutant (MiB; 0: not measured)
    peak_mb: float = 0.0
    #: files opened outside the mutant's inputs and the allowed roots (:func:`stray_opens`)
    stray: str = ""

    @property
    def acceptable(self) -> bool:
        return self.cls in ACCEPTABLE and not self.stray and self.peak_mb <= PEAK_LIMIT_MB

    @property
    def label(self) -> str:
        return f"{self.scenario}:{self.path}:{self.mutation}"

    def report(self) -> str:
        """A multi-line account of a finding, for a failing test."""
        return (f"{self.cls} in phase {self.phase or '?'} after {self.seconds:.1f} s, peak "
                f"{self.peak_mb:.0f} MiB\nmutant:   {self.label}\nlocation: {self.location}\n"
                f"error:    {self.error}\nopened:   {self.stray or '(nothing outside its inputs)'}\n"
                f"{self.details}")


def message_problem(message: str) -> str:
    """What makes ``message`` not a one-paragraph error message ("" if nothing)."""
    if not message.strip():
        return "empty message"
    if "\n" in message:
        return "message has a newline"
    if len(message) >= MESSAGE_LIMIT:
        return f"message has {len(message)} characters"
    if CANARY in message:
        return "message quotes the content of a data file"
    if re.search(r"\d{40}", message):
        return "message prints a number of 40 digits or more"
    return ""


def _first_line(text: str, width: int = 300) -> str:
    line = text.strip().split("\n", 1)[0] if text.strip() else ""
    return line if len(line) <= width else line[:width - 3] + "..."


def _where(filename: str, lineno: int | None, function: str) -> str:
    """``dkfsim/x.py:LINE (function)``; the line is ``?`` when the frame has none."""
    line = "?" if lineno is None else lineno
    return f"{Path(filename).resolve().relative_to(DKFSIM_DIR.parent)}:{line} ({function})"


def _innermost_dkfsim_frame(err: BaseException) -> str:
    frames = [f for f in traceback.extract_tb(err.__traceback__)
              if Path(f.filename).resolve().is_relative_to(DKFSIM_DIR)]
    return _where(frames[-1].filename, frames[-1].lineno, frames[-1].name) if frames else "<no dkfsim frame>"


def _traceback_text(err: BaseException, limit: int = 4000) -> str:
    """The traceback, its middle cut out if long (a RecursionError's is thousands of lines)."""
    text = "".join(traceback.format_exception(err))
    half = limit // 2
    return text if len(text) <= limit else f"{text[:half]}\n[...]\n{text[-half:]}"


class Overrun(BaseException):
    """Raised in a worker when a mutant overruns its time (SIGALRM).

    A BaseException, so that no ``except Exception`` of the code under test
    swallows it.
    """


def _validate(mutant: dict):
    """Phase 1 (a function of its own so that stack dumps show the phase)."""
    return dkfsim.load_scenario(mutant)


def _simulate(scenario) -> None:
    """Phase 2 (a function of its own so that stack dumps show the phase)."""
    dkfsim.run(scenario, save="summary")


def check_mutant(spec: MutantSpec) -> Outcome:
    """Validate and run ``spec`` in this process and classify what happened.

    No time or memory limit here: :class:`MutantChecker` runs this in a
    worker that sets them (the time limit raises :class:`Overrun`).
    """
    mutant = build_mutant(spec)
    watch_opens(*scenario_inputs(mutant))
    phase = "validate"
    start = time.perf_counter()
    fields = dict(scenario=spec.scenario, path=dotted(spec.path), mutation=spec.mutation)
    try:
        scenario = _validate(mutant)
        phase = "run"
        _simulate(scenario)
    except Overrun as err:
        return Outcome(**fields, cls="timeout", phase=phase,
                       error=f"time limit hit after {time.perf_counter() - start:.1f} s",
                       location=_innermost_dkfsim_frame(err), seconds=time.perf_counter() - start,
                       details=_traceback_text(err))
    except DkfsimError as err:
        problem = message_problem(str(err))
        if not problem:
            return Outcome(**fields, cls="clean_error", phase=phase, error=_first_line(str(err)),
                           seconds=time.perf_counter() - start)
        return Outcome(**fields, cls=f"finding:bad_message:{type(err).__name__}", phase=phase,
                       error=f"{problem}: {_first_line(str(err))}",
                       location=_innermost_dkfsim_frame(err), seconds=time.perf_counter() - start,
                       details=_traceback_text(err))
    except Exception as err:  # everything else breaks the contract
        cls = "memory" if isinstance(err, MemoryError) else f"finding:{type(err).__name__}"
        return Outcome(**fields, cls=cls, phase=phase,
                       error=_first_line(f"{type(err).__name__}: {err}"),
                       location=_innermost_dkfsim_frame(err), seconds=time.perf_counter() - start,
                       details=_traceback_text(err))
    return Outcome(**fields, cls="ran", phase="run", seconds=time.perf_counter() - start)


# =========================================================================== worker processes
_DUMP_FRAME = re.compile(r'File "([^"]+)", line (\d+) in (\S+)')


def _read_dump(path: str) -> tuple[str, str, str]:
    """(text, innermost dkfsim frame, phase) of a faulthandler stack dump."""
    try:
        text = Path(path).read_text(errors="replace")
    except OSError:
        text = ""
    location, phase = "<no stack dump>", ""
    for match in _DUMP_FRAME.finditer(text):       # most recent call first
        filename, line, function = match.groups()
        if location == "<no stack dump>" and Path(filename).resolve().is_relative_to(DKFSIM_DIR):
            location = _where(filename, int(line), function)
        if not phase and function in ("_validate", "_simulate"):
            phase = "validate" if function == "_validate" else "run"
    return text, location, phase


def _on_alarm(_signum, _frame) -> None:
    raise Overrun


def _worker_main(conn, dump_path: str, timeout: float, check: Callable = None) -> None:
    """Check the mutants sent over ``conn`` one at a time until it sends None.

    Limits: the address space is capped at ``MEMORY_LIMIT``; after
    ``timeout`` seconds SIGALRM raises :class:`Overrun` in the mutant's code
    (its traceback says where it was).  Code stuck in one C call never sees
    the alarm: the parent then sends SIGUSR1, which makes faulthandler write
    the stack to ``dump_path`` (as a fatal signal does), and kills the worker.
    Warnings are silenced: they are not part of the contract.  ``check`` (default
    :func:`check_mutant`) turns a spec into an :class:`Outcome` (tools/fuzz_results.py
    passes its own).  Each outcome gets the worker's peak resident memory on the mutant and
    the files its commands opened outside their inputs (an audit hook, ``sys.addaudithook``,
    installed here: every child records its own); the worker works in its own scratch folder,
    its temporary files there too.
    """
    check = check or check_mutant
    _soft, hard = resource.getrlimit(resource.RLIMIT_AS)
    cap = MEMORY_LIMIT if hard == resource.RLIM_INFINITY else min(MEMORY_LIMIT, hard)
    resource.setrlimit(resource.RLIMIT_AS, (cap, hard))
    resource.setrlimit(resource.RLIMIT_CORE, (0, resource.getrlimit(resource.RLIMIT_CORE)[1]))
    warnings.simplefilter("ignore")
    signal.signal(signal.SIGALRM, _on_alarm)
    cwd = own_dir() / "cwd"
    cwd.mkdir(exist_ok=True)
    os.chdir(cwd)
    tempfile.tempdir = str(cwd)
    _ROOTS[:] = allowed_roots()
    sys.addaudithook(_audit)
    with open(dump_path, "w") as dump:
        faulthandler.enable(file=dump)
        faulthandler.register(signal.SIGUSR1, file=dump, all_threads=False)
        while (spec := conn.recv()) is not None:
            signal.setitimer(signal.ITIMER_REAL, timeout)
            _reset_peak()
            try:
                outcome = check(spec)
                outcome.peak_mb = _peak_mb()
                stray = stray_opens()
                outcome.stray = f"{len(stray)} file(s): {', '.join(stray[:3])}" if stray else ""
                reply = ("outcome", outcome)
            except Exception:  # a bug of the fuzzer itself: stop the parent loudly
                reply = ("harness_error", traceback.format_exc())
            finally:
                signal.setitimer(signal.ITIMER_REAL, 0)
            conn.send(reply)


class _Worker:
    """One worker process, its pipe, and the mutant it is checking."""

    def __init__(self, context, timeout: float, check: Callable | None = None):
        self._context, self._timeout, self._check = context, timeout, check
        fd, self.dump_path = tempfile.mkstemp(prefix="fuzz_scenarios_", suffix=".stack")
        os.close(fd)
        self._spawn()
        self.index: int | None = None
        self.spec: MutantSpec | None = None
        self.started = self.deadline = 0.0

    def _spawn(self) -> None:
        self.conn, child = self._context.Pipe()
        self.process = self._context.Process(target=_worker_main, daemon=True,
                                             args=(child, self.dump_path, self._timeout, self._check))
        self.process.start()
        child.close()

    def _respawn(self) -> None:
        """Replace the process (a timed-out mutant may have left its state half-built)."""
        if self.process.is_alive():
            self.process.kill()
        self.process.join()
        self.conn.close()
        self._spawn()

    def start(self, index: int, spec: MutantSpec) -> None:
        self.index, self.spec = index, spec
        self.started = time.monotonic()
        self.deadline = self.started + self._timeout + STUCK_GRACE
        self.conn.send(spec)

    def finish(self) -> Outcome:
        """The outcome of the current mutant; call when the pipe is ready or the
        deadline has passed.  A worker that timed out, hung or died is replaced."""
        if self.conn.poll():
            try:
                kind, outcome = self.conn.recv()
            except EOFError:                            # died (a crash): reap it
                self.process.join()
            else:
                if kind == "harness_error":
                    raise RuntimeError(f"the fuzzer failed on {self.spec.label}:\n{outcome}")
                if outcome.cls == "timeout":
                    self._respawn()
                return outcome
        elapsed = time.monotonic() - self.started
        stuck = self.process.is_alive()
        if stuck:                                       # deaf to SIGALRM: in one long C call
            os.kill(self.process.pid, signal.SIGUSR1)
            self.process.join(1.0)
        code = None if stuck else self.process.exitcode
        dump, location, phase = _read_dump(self.dump_path)
        self._respawn()                                 # (the new process empties the dump file)
        fields = dict(scenario=self.spec.scenario, path=dotted(self.spec.path),
                      mutation=self.spec.mutation, phase=phase, location=location,
                      seconds=elapsed, details=dump[-4000:])
        if stuck:
            return Outcome(**fields, cls="timeout",
                           error=f"stuck in one call for more than {elapsed:.1f} s")
        died = f"signal {signal.Signals(-code).name}" if code < 0 else f"exit code {code}"
        return Outcome(**fields, cls="crash", error=f"worker died ({died}): {_first_line(dump)}")

    def close(self) -> None:
        if self.process.is_alive():
            self.conn.send(None)
            self.process.join(5)
            if self.process.is_alive():
                self.process.kill()
                self.process.join()
        self.conn.close()
        Path(self.dump_path).unlink(missing_ok=True)


class MutantChecker:
    """Checks mutants in up to ``jobs`` worker processes, each mutant under
    ``timeout`` seconds and the memory cap.  Use as a context manager.

    Workers are forked, so they start at once with dkfsim already imported
    (and the fuzzer module need not be importable by name: the tests load it
    by path).  ``check``: what a worker does with a spec (default :func:`check_mutant`).
    """

    def __init__(self, jobs: int = MAX_JOBS, timeout: float = DEFAULT_TIMEOUT, check: Callable | None = None):
        context = multiprocessing.get_context("fork")
        self._workers = [_Worker(context, timeout, check) for _ in range(max(1, min(jobs, MAX_JOBS)))]

    def __enter__(self) -> MutantChecker:
        return self

    def __exit__(self, *_exc) -> None:
        for worker in self._workers:
            worker.close()

    def check(self, spec: MutantSpec) -> Outcome:
        return self.check_all([spec])[0]

    def check_all(self, specs: Iterable[MutantSpec],
                  on_outcome: Callable[[Outcome], None] | None = None) -> list[Outcome]:
        """The outcomes of ``specs``, in their order; ``on_outcome`` sees each as it ends."""
        todo = iter(enumerate(specs))
        outcomes: dict[int, Outcome] = {}
        busy: dict[Any, _Worker] = {}

        def feed(worker: _Worker) -> None:
            job = next(todo, None)
            if job is not None:
                worker.start(*job)
                busy[worker.conn] = worker

        for worker in self._workers:
            feed(worker)
        while busy:
            soonest = min(worker.deadline for worker in busy.values())
            ready = wait(list(busy), timeout=max(0.0, soonest - time.monotonic()))
            for conn, worker in list(busy.items()):
                if conn in ready or time.monotonic() >= worker.deadline:
                    del busy[conn]
                    outcome = worker.finish()
                    outcomes[worker.index] = outcome
                    if on_outcome is not None:
                        on_outcome(outcome)
                    feed(worker)
        return [outcomes[i] for i in sorted(outcomes)]


# =========================================================================== report
def signature(outcome: Outcome) -> tuple[str, str]:
    """What makes two findings the same: the outcome class and the innermost
    dkfsim frame.  A timeout is about the size that was asked for, and where
    a long loop happens to be interrupted varies: timeouts group by phase,
    top-level key and mutation instead."""
    if outcome.cls == "timeout":
        top = outcome.path.split(".", 1)[0]
        return outcome.cls, f"{outcome.phase or '?'} of {top}:{outcome.mutation} mutants"
    if outcome.cls in ACCEPTABLE and outcome.stray:
        return "stray_open", f"of {outcome.mutation} mutants"
    if outcome.cls in ACCEPTABLE and outcome.peak_mb > PEAK_LIMIT_MB:
        return "peak_memory", f"of {outcome.mutation} mutants"
    return outcome.cls, f"at {outcome.location}"


#: The columns of the per-surface table: what each counts.
SURFACE_COLUMNS = ("cases", "ok", "tracebacks", "bad_messages", "hangs", "over_3GiB", "stray_opens", "crashes")


def surface_counts(outcomes: list[Outcome], surface_of: Callable[[Outcome], str]) -> dict[str, Counter]:
    """Per surface: cases, acceptable ones, tracebacks (``finding:<Type>``), bad messages,
    hangs (``timeout``), mutants over the memory bound (``memory``, or a peak above
    :data:`PEAK_LIMIT_MB`), mutants that opened a file outside their inputs, crashes."""
    table: dict[str, Counter] = defaultdict(Counter)
    for o in outcomes:
        c = table[surface_of(o)]
        c["cases"] += 1
        c["ok"] += o.acceptable
        c["tracebacks"] += o.cls.startswith("finding:") and not o.cls.startswith("finding:bad_message")
        c["bad_messages"] += o.cls.startswith("finding:bad_message")
        c["hangs"] += o.cls == "timeout"
        c["over_3GiB"] += o.cls == "memory" or o.peak_mb > PEAK_LIMIT_MB
        c["stray_opens"] += bool(o.stray)
        c["crashes"] += o.cls == "crash"
    return dict(table)


def print_surfaces(table: dict[str, Counter], out=sys.stdout) -> None:
    width = max([len(s) for s in table] + [len("surface")])
    print(f"{'surface':<{width}}  " + "  ".join(f"{c:>12}" for c in SURFACE_COLUMNS), file=out)
    for name in sorted(table):
        print(f"{name:<{width}}  " + "  ".join(f"{table[name][c]:>12}" for c in SURFACE_COLUMNS), file=out)
    total = sum(table.values(), Counter())
    print(f"{'all':<{width}}  " + "  ".join(f"{total[c]:>12}" for c in SURFACE_COLUMNS) + "\n", file=out)


def print_report(outcomes: list[Outcome], examples: int, out=sys.stdout) -> None:
    """The outcome-class table, then the findings grouped by signature
    (most frequent first) with up to ``examples`` mutants each (0: all)."""
    classes = Counter(o.cls for o in outcomes)
    phases = Counter((o.cls, o.phase) for o in outcomes)
    width = max([len(c) for c in classes] + [len("class")])
    print(f"{len(outcomes)} mutants\n", file=out)
    print(f"{'class':<{width}}  {'count':>6}  {'validate':>8}  {'run':>6}", file=out)
    for cls, count in sorted(classes.items(), key=lambda item: (item[0] not in ACCEPTABLE, -item[1])):
        print(f"{cls:<{width}}  {count:>6}  {phases[cls, 'validate']:>8}  {phases[cls, 'run']:>6}",
              file=out)
    groups: dict[tuple[str, str], list[Outcome]] = defaultdict(list)
    for o in outcomes:
        if not o.acceptable:
            groups[signature(o)].append(o)
    if not groups:
        print("\nno findings", file=out)
        return
    print(f"\n{len(groups)} distinct findings, most frequent first:", file=out)
    for (cls, where), members in sorted(groups.items(), key=lambda item: -len(item[1])):
        print(f"\n[{len(members)}] {cls} {where}", file=out)
        for o in members[:examples or len(members)]:
            at = f" at {o.location}" if cls == "timeout" else ""
            print(f"    {o.label}  ({o.phase or '?'}, {o.seconds:.1f} s)  {o.error}{at}", file=out)
        if examples and len(members) > examples:
            print(f"    ... {len(members) - examples} more", file=out)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--limit", type=int, default=DEFAULT_LIMIT,
                        help=f"leaf mutants to check, a seeded random subset (default {DEFAULT_LIMIT}; "
                             "0: all); the whole-structure mutants are always checked")
    parser.add_argument("--seed", type=int, default=0, help="seed of the subset (default 0)")
    parser.add_argument("--timeout", type=float, default=DEFAULT_TIMEOUT,
                        help=f"seconds per mutant (default {DEFAULT_TIMEOUT:g})")
    parser.add_argument("--jobs", type=int, default=MAX_JOBS, help=f"worker processes (at most {MAX_JOBS})")
    parser.add_argument("--scenario", action="append", choices=base_names(),
                        help="only this base (repeatable; default: all)")
    parser.add_argument("--surface", action="append",
                        choices=("traffic", "medium", "mobility", "fcd", "data_files", "fusion_centre", "other"),
                        help="only mutants aimed at this surface (repeatable; default: all)")
    parser.add_argument("--examples", type=int, default=3,
                        help="mutants listed per finding signature (default 3; 0: all)")
    parser.add_argument("--json", metavar="OUT", help="write every outcome and the counts as JSON")
    args = parser.parse_args(argv)

    everything = enumerate_mutants(args.scenario)
    if args.surface:
        everything = [spec for spec in everything if surface(spec) in args.surface]
    specs = select(everything, args.limit, args.seed)
    print(f"checking {len(specs)} of {len(everything)} mutants on {min(args.jobs, MAX_JOBS)} "
          f"worker(s), {args.timeout:g} s each at most", file=sys.stderr)
    step = max(1, len(specs) // 20)
    done = Counter()

    def progress(outcome: Outcome) -> None:
        done[outcome.acceptable] += 1
        total = sum(done.values())
        if total % step == 0 or total == len(specs):
            print(f"  {total}/{len(specs)} checked, {done[False]} findings", file=sys.stderr)

    start = time.monotonic()
    with MutantChecker(args.jobs, args.timeout) as checker:
        outcomes = checker.check_all(specs, progress)
    print(f"done in {time.monotonic() - start:.0f} s", file=sys.stderr)
    by_label = {spec.label: spec for spec in specs}
    table = surface_counts(outcomes, lambda o: surface(by_label[o.label]))
    print_surfaces(table)
    print_report(outcomes, args.examples)
    if args.json:
        Path(args.json).write_text(json.dumps({
            "total": len(everything), "checked": len(outcomes),
            "counts": Counter(o.cls for o in outcomes), "surfaces": table,
            "outcomes": [asdict(o) for o in outcomes]}, indent=1))
    return int(any(not o.acceptable for o in outcomes))


if __name__ == "__main__":
    sys.exit(main())

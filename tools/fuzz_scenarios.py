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
The enumeration is deterministic; ``--limit`` checks a seeded random subset
of the leaf mutants plus every whole-structure one.

tests/test_fuzz_scenarios.py draws mutants from the same vocabulary with
Hypothesis and asserts the contract.

Usage::

    python tools/fuzz_scenarios.py [--limit N] [--seed S] [--timeout S] [--jobs J]
                                   [--scenario NAME ...] [--examples K] [--json OUT]

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
import copy  # noqa: E402
import faulthandler  # noqa: E402
import functools  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import multiprocessing  # noqa: E402
import random  # noqa: E402
import re  # noqa: E402
import resource  # noqa: E402
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
    path = SCENARIO_DIR / f"{name}.yaml"
    data = absolute_files(dkfsim.load_scenario(path).to_dict(), path.parent)
    data["steps"] = RUN_STEPS
    return data


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
            for name in (shipped_scenarios() if names is None else names)
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
    """The scenario mapping of ``spec``."""
    root = copy.deepcopy(base(spec.scenario))
    MUTATIONS[spec.mutation].edit(root, spec.path)
    return root


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

    @property
    def acceptable(self) -> bool:
        return self.cls in ACCEPTABLE

    @property
    def label(self) -> str:
        return f"{self.scenario}:{self.path}:{self.mutation}"

    def report(self) -> str:
        """A multi-line account of a finding, for a failing test."""
        return (f"{self.cls} in phase {self.phase or '?'} after {self.seconds:.1f} s\n"
                f"mutant:   {self.label}\nlocation: {self.location}\nerror:    {self.error}\n"
                f"{self.details}")


def message_problem(message: str) -> str:
    """What makes ``message`` not a one-paragraph error message ("" if nothing)."""
    if not message.strip():
        return "empty message"
    if "\n" in message:
        return "message has a newline"
    if len(message) >= MESSAGE_LIMIT:
        return f"message has {len(message)} characters"
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
    passes its own).
    """
    check = check or check_mutant
    _soft, hard = resource.getrlimit(resource.RLIMIT_AS)
    cap = MEMORY_LIMIT if hard == resource.RLIM_INFINITY else min(MEMORY_LIMIT, hard)
    resource.setrlimit(resource.RLIMIT_AS, (cap, hard))
    resource.setrlimit(resource.RLIMIT_CORE, (0, resource.getrlimit(resource.RLIMIT_CORE)[1]))
    warnings.simplefilter("ignore")
    signal.signal(signal.SIGALRM, _on_alarm)
    with open(dump_path, "w") as dump:
        faulthandler.enable(file=dump)
        faulthandler.register(signal.SIGUSR1, file=dump, all_threads=False)
        while (spec := conn.recv()) is not None:
            signal.setitimer(signal.ITIMER_REAL, timeout)
            try:
                reply = ("outcome", check(spec))
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
    return outcome.cls, f"at {outcome.location}"


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
    parser.add_argument("--scenario", action="append", choices=shipped_scenarios(),
                        help="only this shipped scenario (repeatable; default: all)")
    parser.add_argument("--examples", type=int, default=3,
                        help="mutants listed per finding signature (default 3; 0: all)")
    parser.add_argument("--json", metavar="OUT", help="write every outcome and the counts as JSON")
    args = parser.parse_args(argv)

    everything = enumerate_mutants(args.scenario)
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
    print_report(outcomes, args.examples)
    if args.json:
        Path(args.json).write_text(json.dumps({
            "total": len(everything), "checked": len(outcomes),
            "counts": Counter(o.cls for o in outcomes),
            "outcomes": [asdict(o) for o in outcomes]}, indent=1))
    return int(any(not o.acceptable for o in outcomes))


if __name__ == "__main__":
    sys.exit(main())

"""What a sweep is: the sweep file, its grid of parameter sets and the definition a database stores.

:func:`load_sweep` reads and validates a sweep file (every parameter set is loaded as a
scenario before anything runs); the store compares the definitions of stored and new sweeps
(:mod:`dkfsim.experiments.sweep.store`).  The sweep as a whole is described in :mod:`dkfsim.experiments.sweep` and
docs/design.md (Experiments).
"""

from __future__ import annotations

import hashlib
import itertools
import json
import math
import os
import stat
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterator, Mapping

import yaml

from dkfsim.config.load import load_scenario, scenario_hash
from dkfsim.config.yaml import parse_yaml, yaml_error_text
from dkfsim.core.errors import DkfsimError, ScenarioError
from dkfsim.core.files import MAX_YAML_BYTES, check_plain_data, read_text
from dkfsim.core.params import suggest
from dkfsim.core.resources import C_VALIDATE, Cost, check

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


def canonical_json(obj: Any) -> str:
    return json.dumps(obj, sort_keys=True, separators=(",", ":"), ensure_ascii=True,
                      allow_nan=False)


def short_json(value: Any) -> str:
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
        return ", ".join(f"{k}={short_json(v)}" for k, v in self.values.items())


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
        """What the database stores; a later definition must be this one or grow from it
        (:func:`dkfsim.experiments.sweep.store.growth_problem`)."""
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
                                             f"{short_json(values)}")
        if not values:
            raise _err(label, f"grid.{key}", "empty list: give at least one value")
        seen: dict[str, int] = {}
        for i, v in enumerate(values):
            c = canonical_json(v) if _finite_json(v) else repr(v)
            if c in seen:
                raise _err(label, f"grid.{key}", f"value {short_json(v)} is listed twice "
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
            where = f"parameter set {index} ({', '.join(f'{k}={short_json(v)}' for k, v in values.items())})" \
                if values else "the scenario with set"
            raise DkfsimError(f"{label}: {where}: {exc}") from None
        if burn_in is not None and not burn_in < sc.steps:
            raise _err(label, "burn_in", f"must be less than steps ({sc.steps}) of every "
                                         f"parameter set, got {burn_in}")
        h = hashlib.sha256(canonical_json(values).encode()).hexdigest()[:20]
        out.append(ParameterSet(index, values, h, sc, scenario_hash(sc)))
    return out



def is_database(path) -> bool:
    """True when ``path`` is a regular SQLite file (by its header; a FIFO is never opened)."""
    try:
        if not stat.S_ISREG(os.stat(path).st_mode):
            return False
        with open(path, "rb") as fh:
            return fh.read(16) == _SQLITE_MAGIC
    except OSError:
        return False


"""What a sweep is: the sweep file, its grid of parameter sets and the definition a database stores.

:func:`load_sweep` reads a sweep file, validates its keys with the schema
:class:`dkfsim.config.sweep.SweepFile` and loads every parameter set as a scenario before
anything runs; the store compares the definitions of stored and new sweeps
(:mod:`dkfsim.experiments.sweep.store`).  The sweep as a whole is described in :mod:`dkfsim.experiments.sweep` and
docs/design.md (Experiments).
"""

from __future__ import annotations

import hashlib
import itertools
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterator, Mapping

import yaml
from pydantic import ValidationError

from dkfsim.config.load import load_scenario, scenario_hash
from dkfsim.config.messages import convert
from dkfsim.config.sweep import SWEEP_KEYS, SweepFile, canonical_json, short_json
from dkfsim.config.yaml import parse_yaml, yaml_error_text
from dkfsim.core.errors import DkfsimError, ScenarioError
from dkfsim.core.files import MAX_YAML_BYTES, check_plain_data, open_regular, read_text
from dkfsim.core.resources import C_VALIDATE, Cost, check

#: Version of the database layout (``meta.format``).
DB_FORMAT = 2

#: Metrics of :func:`dkfsim.experiments.montecarlo.run_rows` stored per component.
#: The key columns of a stored row; the metrics (every registered one) follow.
KEY_COLUMNS = ("param_hash", "run", "seed", "estimate", "component")

_SQLITE_MAGIC = b"SQLite format 3\x00"
#: Largest sweep database read (bytes): far beyond any sweep (a million tasks of a few rows).
MAX_DATABASE_BYTES = 1 << 40



# =========================================================================== YAML
def _yaml_value(value: Any) -> str:
    """``value`` as YAML flow text for a ``key=value`` override."""
    text = yaml.safe_dump(value, default_flow_style=True, width=1 << 30, allow_unicode=True)
    if text.endswith("\n...\n"):
        text = text[:-5]
    return text.strip()



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


def _read(source) -> tuple[Any, str, Path]:
    """``(data, label, base folder)`` of a sweep file (or a mapping: paths relative to the
    current folder), before validation."""
    if isinstance(source, Mapping):
        data = dict(source)
        check_plain_data(data)
        return data, "<dict>", Path.cwd()
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
    if data is None:
        raise _err(label, None, "empty file: expected a mapping with at least 'scenario'")
    return data, label, path.parent


def load_sweep(source, *, output: str | os.PathLike | None = None, yes: bool = False,
               overrides: Sequence[str] = (), burn_in: int | None = None) -> Sweep:
    """Read and validate a sweep file (or a mapping: paths relative to the
    current folder) with the schema :class:`~dkfsim.config.sweep.SweepFile`.  Every
    parameter set is loaded as a scenario here, so a bad grid key or value fails before
    anything runs.  ``output`` overrides the file's ``output``, ``overrides`` are added to its
    ``set`` (``dotted.key=value``, as ``--set``) and ``burn_in`` replaces its ``burn_in``.  A grid
    too large to validate in memory is refused, one that takes over 10 minutes to validate needs
    ``yes``.  Raises :class:`DkfsimError` (:class:`ScenarioError` for a key of the file)."""
    data, label, base = _read(source)
    if isinstance(data, dict) and (overrides or burn_in is not None):
        data = {**data, "set": [*(data.get("set") or []), *overrides]}
        if burn_in is not None:
            data["burn_in"] = burn_in
    if not isinstance(data, dict):
        raise _err(label, None, f"top level must be a mapping of sweep keys "
                                f"({', '.join(SWEEP_KEYS)}), got {type(data).__name__}")
    if "sensors" in data and "scenario" not in data:
        raise _err(label, None, "this is a scenario file, not a sweep: write a sweep file that "
                                "names it (scenario: FILE, grid: ...), or use 'dkfsim run' / "
                                "'dkfsim montecarlo' on it")
    try:
        f = SweepFile.model_validate(data, context={"base_dir": base})
    except ValidationError as exc:
        raise convert(exc, data, label, {}) from None
    if output is not None:
        out = Path(output)
    elif f.output is not None:
        out = f.output
    else:
        out = base / f"{Path(label).stem if label != '<dict>' else 'sweep'}.sqlite"
    n_sets = math.prod(len(values) for _, values in f.grid)
    check(Cost(f"{label}: validating {n_sets:,} parameter sets",
                   memory={"validated scenarios": n_sets * 50_000.0}, seconds=n_sets * C_VALIDATE),
          yes=yes, hint="a smaller grid")
    psets = _parameter_sets(label, f.scenario, list(f.grid), list(f.overrides), f.burn_in)
    return Sweep(source=label, scenario_path=f.scenario, grid=f.grid, overrides=f.overrides,
                 runs=f.runs, burn_in=f.burn_in, output=out, parameter_sets=tuple(psets))


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
    """True when ``path`` is a regular SQLite file (by its header; opened as every file dkfsim
    reads, :func:`~dkfsim.core.files.open_regular`: a FIFO is never waited on)."""
    try:
        with open_regular(path, limit=MAX_DATABASE_BYTES, what="sweep database") as fh:
            return fh.read(16) == _SQLITE_MAGIC
    except (DkfsimError, OSError):
        return False


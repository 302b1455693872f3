"""The schema of a sweep file: its keys validated in one place, as a scenario's are.

A sweep file (docs/design.md, "Sweeps") names a scenario file and a grid of its keys;
:func:`dkfsim.experiments.sweep.load_sweep` reads it, validates it with :class:`SweepFile`
and then loads every parameter set as a scenario.  A problem is one message in the
scenario style (:func:`dkfsim.config.messages.convert`):
``<file>: <dotted.key>: <what is wrong>``, e.g. ``s.yaml: grid.protocol: empty list``.

Relative paths (``scenario``, ``output``) resolve against the folder given as the
``base_dir`` of the validation context (the sweep file's folder).
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Annotated, Any

from pydantic import Field, ValidationInfo, field_validator, model_validator
from pydantic_core import PydanticCustomError

from dkfsim.core.params import TEXT_LIMIT, StrictModel, Text, custom_error, suggest

#: Keys a sweep file may have.
SWEEP_KEYS = ("scenario", "grid", "set", "runs", "burn_in", "output")


def canonical_json(obj: Any) -> str:
    """``obj`` as JSON with sorted keys and no spaces: equal data, equal text (hashes, comparisons)."""
    return json.dumps(obj, sort_keys=True, separators=(",", ":"), ensure_ascii=True,
                      allow_nan=False)


def short_json(value: Any) -> str:
    """``value`` as JSON cut to 40 characters, for messages."""
    text = json.dumps(value, ensure_ascii=False)
    return text if len(text) <= 40 else text[:37] + "..."


def finite_json(v: Any) -> bool:
    """True when ``v`` is plain data JSON can hold exactly: finite numbers, text, booleans, null,
    and lists and string-keyed mappings of them."""
    if isinstance(v, float):
        return math.isfinite(v)
    if isinstance(v, (str, int, bool)) or v is None:
        return True
    if isinstance(v, list):
        return all(finite_json(x) for x in v)
    if isinstance(v, dict):
        return all(isinstance(k, str) and finite_json(x) for k, x in v.items())
    return False


def _base(info: ValidationInfo) -> Path:
    base = (info.context or {}).get("base_dir")
    return Path(base) if base is not None else Path.cwd()


def _file_name(value: Any) -> str:
    if not isinstance(value, str) or not value.strip():
        raise custom_error(f"must be a file name, got {value!r}")
    return value


def _grid_entry(key: Any, values: Any) -> tuple[str, tuple]:
    """One grid key and its values, checked (messages point at ``grid.<key>``)."""
    where = f"{key}"
    if not isinstance(key, str) or not key.strip() or any(p == "" for p in key.split(".")):
        raise custom_error("keys must be dotted scenario paths such as links.default.latency.d_t", where)
    if len(key) > TEXT_LIMIT:
        raise custom_error(f"a key of {len(key):,} characters; keys are at most {TEXT_LIMIT:,}", where[:40] + "...")
    if not isinstance(values, list):
        raise custom_error(f"must be a list of values (e.g. [0, 1, 2]), got {short_json(values)}", where)
    if not values:
        raise custom_error("empty list: give at least one value", where)
    seen: dict[str, int] = {}
    for i, v in enumerate(values):
        c = canonical_json(v) if finite_json(v) else repr(v)
        if c in seen:
            raise custom_error(f"value {short_json(v)} is listed twice (entries {seen[c]} and {i})", where)
        seen[c] = i
        if not finite_json(v):
            raise custom_error(f"value {v!r} is not plain data (numbers must be finite; lists and "
                               "mappings are fine)", where)
    return key, tuple(values)


class SweepFile(StrictModel):
    """A sweep file's keys (docs/design.md, "Sweeps"), validated; paths resolved.

    ``scenario`` is the scenario file to sweep (it must exist), ``grid`` its dotted keys with
    the values each takes (every combination is a parameter set), ``overrides`` (key ``set``)
    the ``dotted.key=value`` settings every parameter set shares, ``runs`` the Monte Carlo
    runs per parameter set, ``burn_in`` the rows left out of the metrics (``None``: the
    default), ``output`` the database (``None``: ``<sweep file stem>.sqlite`` beside it).
    """

    scenario: Path
    grid: tuple[tuple[str, tuple], ...] = ()
    overrides: tuple[Text, ...] = Field(default=(), alias="set")
    runs: Annotated[int, Field(strict=True, ge=1)] = 1
    burn_in: int | None = None
    output: Path | None = None

    @model_validator(mode="before")
    @classmethod
    def _reject_unknown_keys(cls, data: Any) -> Any:
        """Unknown keys first (a typo explains the rest), with the closest and every valid key;
        then the one required key."""
        if not isinstance(data, dict):
            return data
        for key in data:
            if key not in SWEEP_KEYS:
                raise PydanticCustomError("unknown_key", "{reason}", {
                    "reason": f"unknown key{suggest(key, SWEEP_KEYS)} (valid: {', '.join(SWEEP_KEYS)})",
                    "key": str(key)})
        if data.get("scenario") is None:
            raise custom_error("required key is missing (the scenario file to sweep)", "scenario")
        return data

    @field_validator("scenario", mode="before")
    @classmethod
    def _scenario_file(cls, value: Any, info: ValidationInfo) -> Path:
        name = _file_name(value)
        path = Path(name) if Path(name).is_absolute() else _base(info) / name
        if not path.is_file():
            raise custom_error(f"file not found: {path}" + ("" if Path(name).is_absolute() else
                                                            " (paths are relative to the sweep file)"))
        return path

    @field_validator("grid", mode="before")
    @classmethod
    def _grid(cls, value: Any) -> tuple:
        if value is None:
            return ()
        if not isinstance(value, dict):
            raise custom_error(f"must be a mapping of dotted scenario keys to lists of values, got "
                               f"{type(value).__name__}")
        return tuple(_grid_entry(k, v) for k, v in value.items())

    @field_validator("overrides", mode="before")
    @classmethod
    def _overrides(cls, value: Any) -> tuple:
        if value is None:
            return ()
        if isinstance(value, str):
            value = [value]
        if not isinstance(value, list) or not all(isinstance(s, str) for s in value):
            raise custom_error('must be a list of "dotted.key=value" strings, e.g. '
                               '["steps=300", "baselines=[centralized]"]')
        for s in value:
            if "=" not in s:
                raise custom_error(f"bad override {s!r}: expected dotted.key=value")
        return tuple(value)

    @field_validator("runs", mode="before")
    @classmethod
    def _runs(cls, value: Any) -> Any:
        if isinstance(value, bool) or not isinstance(value, int):
            raise custom_error(f"must be an integer >= 1, got {value!r}")
        return value

    @field_validator("burn_in", mode="before")
    @classmethod
    def _burn_in(cls, value: Any) -> Any:
        if value is not None and (isinstance(value, bool) or not isinstance(value, int) or value < 0):
            raise custom_error(f"must be null or an integer >= 0 (rows), got {value!r}")
        return value

    @field_validator("output", mode="before")
    @classmethod
    def _output(cls, value: Any, info: ValidationInfo) -> Path | None:
        if value is None:
            return None
        name = _file_name(value)
        # (``../out/x.sqlite`` beside ``scenarios/``: ``out/x.sqlite``, as a person writes it)
        return Path(name) if Path(name).is_absolute() else Path(os.path.normpath(_base(info) / name))

    @model_validator(mode="after")
    def _set_apart_from_grid(self):
        keys = {k for k, _ in self.grid}
        for s in self.overrides:
            k = s.partition("=")[0].strip()
            if k in keys:
                raise custom_error(f"{k} is both in set and in grid; keep it in one place", "set")
        return self

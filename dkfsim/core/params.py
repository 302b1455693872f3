"""The base of every parameter model, the field types they share, and the limits.

A parameter model is a frozen pydantic class: the keys of one scenario
component, validated where it is declared.  :class:`StrictModel` rejects
unknown keys with a "did you mean" hint (:func:`suggest`, the one such
helper); :func:`custom_error` raises a message verbatim, pointing at one
of the model's own keys; :func:`dispatch` validates a mapping with the
parameter model its ``model`` / ``kind`` key names in a registry.

Limits (docs/decisions.md #32): every time and delay a run can reach is at
most :data:`MAX_NS` nanoseconds (sums of two stay in int64, the clock's
type); matrix and vector entries and factors are at most
:data:`MAX_MAGNITUDE` (a product of three stays within float64).
"""

from __future__ import annotations

import difflib
from decimal import ROUND_HALF_EVEN, Decimal
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import BaseModel, BeforeValidator, ConfigDict, Field, SerializeAsAny, ValidationInfo, model_validator
from pydantic_core import PydanticCustomError

from dkfsim.core.files import clip

NS_PER_S = 1_000_000_000
#: Every time and delay a run can reach is at most this many nanoseconds (about 146 years).
MAX_NS = 2**62
#: The same limit in seconds: the largest value a time or latency key may take.
MAX_SECONDS = MAX_NS / NS_PER_S
#: Largest magnitude of a matrix entry, vector entry or factor.
MAX_MAGNITUDE = 1e100
_SYM_RTOL = 1e-9
_EIG_TOL = 1e-12


# =========================================================================== errors and hints
def custom_error(reason: str, key: str | None = None) -> PydanticCustomError:
    """A validation error whose message is ``reason`` verbatim.

    ``key`` is a dotted path relative to the model being validated; the
    scenario loader appends it to the error location, so a model can point
    at one of its own fields (``R``) or at a nested key (``prior.cov``).
    """
    ctx: dict[str, Any] = {"reason": reason}
    if key:
        ctx["key"] = key
    return PydanticCustomError("dkfsim", "{reason}", ctx)


def suggest(word: Any, choices) -> str:
    """``" (did you mean 'x'?)"`` for the closest of ``choices``, else ``""``."""
    match = difflib.get_close_matches(str(word), [str(c) for c in choices], n=1)
    return f" (did you mean '{match[0]}'?)" if match else ""


class StrictModel(BaseModel):
    """Base of parameter models: frozen, and unknown keys are an error.

    An unknown key is reported with the closest allowed key, e.g.
    ``unknown key (did you mean 'buffer_length'?)``.
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    @model_validator(mode="before")
    @classmethod
    def _reject_unknown_keys(cls, data: Any) -> Any:
        if isinstance(data, dict):
            allowed = [f.alias or name for name, f in cls.model_fields.items()]
            for key in data:
                if key not in allowed:
                    hint = suggest(key, allowed)
                    if not hint:
                        hint = "; allowed keys: " + ", ".join(allowed)
                    raise PydanticCustomError(
                        "unknown_key", "{reason}",
                        {"reason": f"unknown key{hint}", "key": str(key)})
        return data

    def to_dict(self) -> dict:
        """Plain data (lists, floats, str) that validates back to an equal model."""
        return self.model_dump(mode="json", exclude_none=True)


def dispatch(registry, default: str | None = None, base: type | None = None):
    """A ``BeforeValidator`` that validates a mapping with the parameter model its
    ``registry.key`` names (``default`` when the key is absent), one of those that subclass
    ``base`` when given (a family whose members are not all of one kind: the media).  Errors
    keep their key paths; an unknown name gets the registry's "did you mean"."""
    key = registry.key

    def fits(entry) -> bool:
        return entry.params is not None and (base is None or issubclass(entry.params, base))

    def validate(value: Any, info: ValidationInfo) -> Any:
        if isinstance(value, BaseModel):
            return value
        if not isinstance(value, dict):
            raise custom_error(f"must be a mapping, got {type(value).__name__} {_short(value)}")
        names = [e.name for e in registry.entries() if fits(e)]
        name = value.get(key, default)
        if name is None:
            raise custom_error(f"missing key '{key}' (one of: {', '.join(names)})")
        try:
            entry = registry.get(name)
        except KeyError as err:
            if len(names) == len(registry.names()):
                raise custom_error(err.args[0], key) from None
            raise custom_error(f"unknown {registry.family} {clip(name)}{suggest(name, names)}; valid here: "
                               + ", ".join(names), key) from None
        if entry.params is None or not fits(entry):
            raise custom_error(f"{registry.family} {name!r} cannot be named here; valid here: {', '.join(names)}", key)
        if name != entry.name:                       # an alias: validate under the real name
            value = {**value, key: entry.name}
        return entry.params.model_validate(value, context=info.context)
    return BeforeValidator(validate)


def _short(value: Any) -> str:
    text = " ".join(repr(value).split())
    return text if len(text) <= 60 else text[:56] + " ..."


def fix_kind(cls: type, kind: str) -> None:
    """Make ``kind`` a subclass's ``Literal[kind] = kind`` field, from ``__init_subclass__``
    (before pydantic collects the fields): a component family whose subclasses declare their
    kind in the class statement (``class MyMac(AccessParams, kind="my_mac")``)."""
    annotations = dict(cls.__dict__.get("__annotations__", {}))
    annotations["kind"] = Literal[kind]
    cls.__annotations__ = annotations
    type.__setattr__(cls, "kind", kind)


def registered(base: type, registry, default: str | None = None):
    """The field type of a component chosen by name: any registered parameter model that
    subclasses ``base`` (serialised as its own class), dispatched on ``registry.key``."""
    return Annotated[SerializeAsAny[base], dispatch(registry, default, base)]


# =========================================================================== time
def seconds_to_ns(seconds: float) -> int:
    """Seconds to the nearest integer nanosecond, computed in decimal.

    Decimal arithmetic on ``repr`` avoids binary rounding: 0.015 s is exactly
    15_000_000 ns (a float product gives 15000000.000000002).
    """
    return int((Decimal(repr(float(seconds))) * NS_PER_S).to_integral_value(ROUND_HALF_EVEN))


def round_ns(seconds: np.ndarray) -> np.ndarray:
    """Seconds to int64 nanoseconds, rounded and clamped to ``[0, MAX_NS]``."""
    ns = np.rint(np.asarray(seconds, dtype=float) * NS_PER_S)
    return np.clip(ns, 0, MAX_NS).astype(np.int64)


# =========================================================================== field types
NonNegSeconds = Annotated[float, Field(strict=True, ge=0, le=MAX_SECONDS, allow_inf_nan=False)]
PosSeconds = Annotated[float, Field(strict=True, gt=0, le=MAX_SECONDS, allow_inf_nan=False)]
#: A positive dimensionless parameter (a shape, a tail index, a scale factor).
PosReal = Annotated[float, Field(strict=True, gt=0, le=MAX_MAGNITUDE, allow_inf_nan=False)]
NonNegReal = Annotated[float, Field(strict=True, ge=0, le=MAX_MAGNITUDE, allow_inf_nan=False)]
Probability = Annotated[float, Field(strict=True, ge=0, le=1, allow_inf_nan=False)]
StrictInt = Annotated[int, Field(strict=True)]
StrictBool = Annotated[bool, Field(strict=True)]
#: Longest name (a scenario, a sensor, an estimator, an estimate, a component): a name becomes a
#: table cell, a figure label, a file's column.  One rule, applied when a scenario is validated
#: and when a result is read back (:mod:`dkfsim.config.results`), so that no run is written that
#: its readers would refuse.
NAME_LIMIT = 200
#: Longest other text: a path, a column of a data file, a module, a ``--set`` entry.
TEXT_LIMIT = 10_000
#: A name (see :data:`NAME_LIMIT`).
Name = Annotated[str, Field(strict=True, min_length=1, max_length=NAME_LIMIT)]
#: A path, a column or other text (see :data:`TEXT_LIMIT`).
Text = Annotated[str, Field(strict=True, min_length=1, max_length=TEXT_LIMIT)]


def _number(x: Any) -> float:
    if isinstance(x, bool) or not isinstance(x, (int, float, np.integer, np.floating)):
        raise custom_error(f"entries must be numbers, got {_short(x)}")
    value = float(x)
    if not np.isfinite(value):
        raise custom_error(f"entries must be finite, got {x!r}")
    if abs(value) > MAX_MAGNITUDE:
        raise custom_error(f"entries must be at most {MAX_MAGNITUDE:g} in magnitude, got {x!r} "
                           "(a product of three such numbers must stay within float64)")
    return value


def _to_matrix(value: Any) -> tuple[tuple[float, ...], ...]:
    if isinstance(value, np.ndarray):
        value = value.tolist()
    if isinstance(value, (list, tuple)):
        if len(value) == 0:
            raise custom_error("must not be empty")
        if all(isinstance(row, (list, tuple)) for row in value):
            rows = [tuple(_number(x) for x in row) for row in value]
            widths = {len(r) for r in rows}
            if len(widths) != 1:
                raise custom_error(f"rows have different lengths {[len(r) for r in rows]}")
            if 0 in widths:
                raise custom_error("rows must not be empty")
            return tuple(rows)
        if any(isinstance(row, (list, tuple)) for row in value):
            raise custom_error("mixes numbers and lists; write a list of rows")
        return (tuple(_number(x) for x in value),)
    if isinstance(value, dict) or value is None:
        raise custom_error("must be a matrix (a list of rows), a flat list or a number")
    return ((_number(value),),)


def _to_vector(value: Any) -> tuple[float, ...]:
    if isinstance(value, np.ndarray):
        value = value.tolist()
    if isinstance(value, (list, tuple)):
        if len(value) == 0:
            raise custom_error("must not be empty")
        if all(isinstance(x, (list, tuple)) and len(x) == 1 for x in value):
            value = [x[0] for x in value]
        if any(isinstance(x, (list, tuple)) for x in value):
            raise custom_error("must be a flat list of numbers")
        return tuple(_number(x) for x in value)
    if isinstance(value, dict) or value is None:
        raise custom_error("must be a list of numbers")
    return (_number(value),)


#: A matrix: a list of rows (a scalar is 1 x 1, a flat list one row); finite, bounded entries.
Matrix = Annotated[tuple[tuple[float, ...], ...], BeforeValidator(_to_matrix)]
#: A vector: a flat list (a scalar is a 1-vector, an n x 1 column is flattened).
Vector = Annotated[tuple[float, ...], BeforeValidator(_to_vector)]


def shape_of(m: tuple[tuple[float, ...], ...]) -> tuple[int, int]:
    return len(m), len(m[0])


def check_square(m, size: int | None = None, key: str | None = None) -> np.ndarray:
    """``m`` as an array, square (and ``size x size`` when given)."""
    rows, cols = shape_of(m)
    if rows != cols:
        raise custom_error(f"must be square, got {rows} x {cols}", key)
    if size is not None and rows != size:
        raise custom_error(f"must be {size} x {size}, got {rows} x {cols}", key)
    return np.array(m, dtype=float)


def check_spd(a: np.ndarray, key: str | None, semi: bool) -> None:
    """Symmetric positive (semi)definite, with tolerances relative to the scale."""
    what = "symmetric positive semidefinite" if semi else "symmetric positive definite"
    scale = max(1.0, float(np.max(np.abs(a))))
    asym = np.abs(a - a.T)
    if np.max(asym) > _SYM_RTOL * scale:
        i, j = np.unravel_index(int(np.argmax(asym)), a.shape)
        raise custom_error(f"not {what} (not symmetric: [{i}][{j}] = {a[i, j]:g} but "
                           f"[{j}][{i}] = {a[j, i]:g})", key)
    eig = np.linalg.eigvalsh((a + a.T) / 2)
    top = float(np.max(np.abs(eig)))
    tol = _EIG_TOL * max(1.0, top)
    low = float(eig.min())
    if (semi and low < -tol) or (not semi and low <= tol):
        scale_note = f", not above {_EIG_TOL:g} x the largest eigenvalue {top:.6g}" if tol > _EIG_TOL else ""
        raise custom_error(f"not {what} (min eigenvalue {low:.6g}{scale_note})", key)

"""Link latency models.

A latency model says how long a packet handed to a directed link ``u -> v``
takes to arrive.  It is drawn per packet from the link's own random stream.
Simulated time is kept in integer nanoseconds (DESIGN.md section 2), so every
model samples *integer nanoseconds*; continuous draws are rounded to the
nearest nanosecond.

In a scenario file a model is a mapping whose ``model`` key picks the kind;
the remaining keys are its parameters.  Units are SI seconds unless the key
says otherwise (``d_t`` counts sampling periods).

``constant``
    ``value`` (seconds, >= 0, default 0): every packet takes exactly ``value``.
    Bound: ``ceil(value / T)`` steps.
``uniform_steps``
    ``d_t`` (integer steps, >= 0): the paper's delay model (section V).  The
    latency is ``d * T`` with ``d`` uniform on ``{0, 1, ..., d_t}``, i.e.
    exactly ``d * T_ns`` nanoseconds (each value with probability
    ``1 / (d_t + 1)``).  Bound: ``d_t`` steps.
``uniform``
    ``low``, ``high`` (seconds, ``0 <= low <= high``): continuous uniform on
    ``[low, high]``.  Bound: ``ceil(high / T)`` steps.
``exponential``
    ``mean`` (seconds, > 0) and ``offset`` (seconds, >= 0, default 0):
    ``offset + Exp(mean)``.  Unbounded: ``bound_steps`` is ``None``, so a
    scenario must state ``links.d_t`` or an explicit ``buffer_length``.

Every model offers

* ``sample_ns(rng, size, T_ns) -> np.ndarray`` of ``int64`` nanoseconds,
* ``sup_ns(T_ns) -> int | None``: the largest latency it can produce (``None``
  when unbounded),
* ``bound_steps(T_ns) -> int | None``: the smallest ``d`` such that every
  latency is ``<= d * T`` (``ceil(sup / T)``), ``None`` when unbounded,
* ``to_dict()``: the mapping that recreates it (``parse_latency``).

Adding a model (lognormal, gamma, pareto, empirical, gilbert_elliott, ...)
means writing one more subclass of :class:`LatencyBase` with a
``model: Literal["name"] = "name"`` field, decorating it with
:func:`register`, and placing it before the line that builds
:data:`LatencyModel` at the end of this module.

This module also holds :class:`StrictModel`, the base of every scenario
model (frozen, unknown keys rejected with a "did you mean" suggestion).
"""

from __future__ import annotations

import difflib
from decimal import ROUND_HALF_EVEN, Decimal
from typing import Annotated, Any, ClassVar, Literal, Union

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, TypeAdapter, model_validator
from pydantic_core import PydanticCustomError

NS_PER_S = 1_000_000_000
# Latencies are capped here so that adding them to an int64 clock cannot overflow
# (about 146 years of simulated time).
_MAX_NS = 2**62


# --------------------------------------------------------------------------- base model
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


def suggest(word: str, choices) -> str:
    """``" (did you mean 'x'?)"`` for the closest of ``choices``, else ``""``."""
    match = difflib.get_close_matches(str(word), [str(c) for c in choices], n=1)
    return f" (did you mean '{match[0]}'?)" if match else ""


class StrictModel(BaseModel):
    """Base of scenario models: frozen, and unknown keys are an error.

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


# --------------------------------------------------------------------------- helpers
def seconds_to_ns(seconds: float) -> int:
    """Seconds to the nearest integer nanosecond, computed in decimal.

    Decimal arithmetic on ``repr`` avoids binary rounding: 0.015 s is exactly
    15_000_000 ns (a float product gives 15000000.000000002).
    """
    return int((Decimal(repr(float(seconds))) * NS_PER_S).to_integral_value(ROUND_HALF_EVEN))


def _ceil_div(a: int, b: int) -> int:
    return -(-a // b)


def _round_ns(seconds: np.ndarray) -> np.ndarray:
    ns = np.rint(np.asarray(seconds, dtype=float) * NS_PER_S)
    return np.clip(ns, 0, _MAX_NS).astype(np.int64)


NonNegSeconds = Annotated[float, Field(strict=True, ge=0, allow_inf_nan=False)]
PosSeconds = Annotated[float, Field(strict=True, gt=0, allow_inf_nan=False)]


class LatencyBase(StrictModel):
    """Interface of every latency model (see the module docstring)."""

    model: str
    #: True when the model has a finite supremum.
    bounded: ClassVar[bool] = True

    def sample_ns(self, rng: np.random.Generator, size, T_ns: int) -> np.ndarray:
        """Draw ``size`` latencies (int or shape) as int64 nanoseconds."""
        raise NotImplementedError

    def sup_ns(self, T_ns: int) -> int | None:
        """Largest latency the model can produce, in ns; ``None`` if unbounded."""
        raise NotImplementedError

    def bound_steps(self, T_ns: int) -> int | None:
        """Smallest ``d`` with latency ``<= d * T`` always; ``None`` if unbounded."""
        sup = self.sup_ns(T_ns)
        if sup is None:
            return None
        return _ceil_div(sup, int(T_ns))

    def to_dict(self) -> dict:
        """Plain mapping (with the ``model`` key) that ``parse_latency`` accepts."""
        return self.model_dump(mode="json")


#: name -> class of every known latency model.
LATENCY_MODELS: dict[str, type[LatencyBase]] = {}


def register(cls: type[LatencyBase]) -> type[LatencyBase]:
    """Class decorator adding a latency model to :data:`LATENCY_MODELS`."""
    name = cls.model_fields["model"].default
    if not isinstance(name, str) or name in LATENCY_MODELS:
        raise ValueError(f"latency model {cls.__name__} needs a unique default 'model' name")
    LATENCY_MODELS[name] = cls
    return cls


# --------------------------------------------------------------------------- models
@register
class Constant(LatencyBase):
    """Every packet takes ``value`` seconds."""

    model: Literal["constant"] = "constant"
    value: NonNegSeconds = 0.0

    def sample_ns(self, rng, size, T_ns):
        return np.full(size, min(seconds_to_ns(self.value), _MAX_NS), dtype=np.int64)

    def sup_ns(self, T_ns):
        return seconds_to_ns(self.value)


@register
class UniformSteps(LatencyBase):
    """``d * T`` with ``d`` uniform on ``{0..d_t}`` (the paper's model)."""

    model: Literal["uniform_steps"] = "uniform_steps"
    d_t: Annotated[int, Field(strict=True, ge=0)]

    def sample_ns(self, rng, size, T_ns):
        d = rng.integers(0, self.d_t + 1, size=size, dtype=np.int64)
        return d * np.int64(T_ns)

    def sup_ns(self, T_ns):
        return self.d_t * int(T_ns)

    def bound_steps(self, T_ns):
        return self.d_t


@register
class Uniform(LatencyBase):
    """Continuous uniform on ``[low, high]`` seconds."""

    model: Literal["uniform"] = "uniform"
    low: NonNegSeconds = 0.0
    high: NonNegSeconds

    @model_validator(mode="after")
    def _ordered(self):
        if self.high < self.low:
            raise custom_error(f"must be >= low ({self.low!r}), got {self.high!r}", "high")
        return self

    def sample_ns(self, rng, size, T_ns):
        lo, hi = seconds_to_ns(self.low), seconds_to_ns(self.high)
        return np.clip(_round_ns(rng.uniform(self.low, self.high, size=size)), lo, hi)

    def sup_ns(self, T_ns):
        return seconds_to_ns(self.high)


@register
class Exponential(LatencyBase):
    """``offset + Exp(mean)`` seconds; unbounded."""

    model: Literal["exponential"] = "exponential"
    mean: PosSeconds
    offset: NonNegSeconds = 0.0
    bounded: ClassVar[bool] = False

    def sample_ns(self, rng, size, T_ns):
        draw = _round_ns(rng.exponential(self.mean, size=size))
        return np.minimum(draw + np.int64(seconds_to_ns(self.offset)), _MAX_NS)

    def sup_ns(self, T_ns):
        return None


# --------------------------------------------------------------------------- union
#: Field type accepting any registered model, discriminated on ``model``.
LatencyModel = Annotated[Union[tuple(LATENCY_MODELS.values())], Field(discriminator="model")]

_ADAPTER = TypeAdapter(LatencyModel)


def parse_latency(data: dict | LatencyBase) -> LatencyBase:
    """Validate a mapping such as ``{"model": "constant", "value": 0.02}``.

    Raises pydantic's ``ValidationError`` on bad input; scenario files go
    through :func:`dkfsim.scenario.load_scenario`, which reports errors with
    their key path.
    """
    if isinstance(data, LatencyBase):
        return data
    return _ADAPTER.validate_python(data)

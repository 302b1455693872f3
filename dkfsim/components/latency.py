"""Link latency models.

A latency model says how long a packet handed to a directed link ``u -> v``
takes to arrive.  It is drawn per packet from the link's own random streams.
Simulated time is kept in integer nanoseconds (docs/design.md §2), so every
model samples *integer nanoseconds*; continuous draws are rounded to the
nearest nanosecond.  docs/latency_models.md explains every model and its
parameters with examples; this docstring is the reference next to the code.

In a scenario file a model is a mapping whose ``model`` key picks the kind;
the remaining keys are its parameters.  Units are SI seconds unless the key
says otherwise (``d_t`` counts sampling periods; probabilities and factors
have no unit).

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
    ``offset + Exp(mean)``.  Unbounded.
``lognormal``
    ``median`` (seconds, > 0), ``sigma`` (standard deviation of the
    *natural log* of the latency, no unit, >= 0) and ``offset`` (seconds,
    >= 0, default 0): ``offset + median * exp(sigma * Z)``, ``Z ~ N(0, 1)``
    (so ``mu = ln(median)``; the mean is ``offset + median * exp(sigma^2/2)``).
    Unbounded (bounded by ``offset + median`` when ``sigma = 0``).
``gamma``
    ``shape`` (k, > 0, no unit), ``scale`` (theta, seconds, > 0), ``offset``
    (seconds, >= 0, default 0): ``offset + Gamma(k, theta)``, mean
    ``offset + k * theta``.  Unbounded.
``pareto``
    ``alpha`` (tail index, > 0, no unit), ``scale`` (seconds, > 0: the
    *minimum* of the Pareto part), ``offset`` (seconds, >= 0, default 0):
    ``offset + scale * U^(-1/alpha)`` (classical Pareto, ``P(X > x) =
    (scale / x)^alpha`` for ``x >= scale``).  Heavy tailed: the mean is
    infinite for ``alpha <= 1``, the variance for ``alpha <= 2``.  Unbounded.
``empirical``
    Latencies taken from a measured trace (e.g. the CICV5G 5G traces, see
    docs/latency_models.md).  ``file``: a CSV or whitespace-separated table,
    optionally with a header line; relative paths resolve against the
    scenario file's folder (the working directory for a scenario given as a
    mapping), then the repository root, then its ``scenarios/`` folder.
    ``column`` (default ``delay_ms``): a header name, matched ignoring case
    and punctuation (so ``delay_ms`` finds ``delay(ms)``), or a 0-based
    index.  ``unit`` (``ms`` (default) or ``s``): the unit of the column.
    ``one_way`` (default ``false``): ``true`` halves every value -- the
    usual one-way ~ RTT/2 reading of a *round-trip* trace such as CICV5G
    (the file's numbers are used as they are otherwise).  ``scale`` (> 0,
    default 1): a factor on every value.  ``mode``: ``resample`` (default:
    i.i.d. draws from the trace's values, uniform over its rows) or
    ``replay`` (the trace in its order, one row per packet, cycling; each
    link starts at row ``start`` if given, else at a row drawn uniformly from
    its latency stream).  Bounded in both modes: ``sup`` is the largest
    value of the trace (after ``one_way`` and ``scale``).
``gilbert_elliott``
    A two-state Markov channel per link, stepped once per packet:
    ``p_good_to_bad`` and ``p_bad_to_good`` (probabilities per packet),
    ``good`` and ``bad`` (nested latency models, any kind but
    ``gilbert_elliott``), ``loss_good`` and ``loss_bad`` (probability that a
    packet sent in that state is lost, default 0), ``initial``
    (``stationary`` (default), ``good`` or ``bad``: the state of a link's
    first packet).  The stationary probability of the bad state is
    ``p_good_to_bad / (p_good_to_bad + p_bad_to_good)``; a bad burst lasts
    ``1 / p_bad_to_good`` packets on average (geometric).  Bounded iff both
    nested models are: ``sup`` is the larger of the two.

Every model offers

* ``sample_ns(rng, size, T_ns) -> np.ndarray`` of ``int64`` nanoseconds:
  i.i.d. draws, or for a stateful model (``empirical`` replay,
  ``gilbert_elliott``) the latencies of a fresh sequence seeded from ``rng``,
* ``sampler(rng_for, T_ns) -> Sampler``: the per-link state a link draws from
  (see below),
* ``sup_ns(T_ns) -> int | None``: the largest latency it can produce (``None``
  when unbounded),
* ``bound_steps(T_ns) -> int | None``: the smallest ``d`` such that every
  latency is ``<= d * T`` (``ceil(sup / T)``), ``None`` when unbounded,
* ``to_dict()``: the mapping that recreates it (``parse_latency``).

Random streams and samplers
---------------------------
A link draws from ``model.sampler(rng_for, T_ns)``: ``rng_for(*name)`` gives
the link's stream named ``("link", u, v, *name)`` (docs/design.md §1).
:meth:`Sampler.block` returns the next ``size`` packets' latencies and, for a
model that also loses packets (``gilbert_elliott``), their "lost" flags.
Streams used, per link:

* i.i.d. models and ``empirical``: ``("link", u, v, "latency")`` -- the
  same draws, in the same order, as before samplers existed (blocks of 256;
  the k-th packet on a link gets the k-th draw, lost or not);
* ``gilbert_elliott``: ``(..., "state")`` (the first uniform picks the
  initial state, one more per packet steps the chain), ``(..., "good",
  "latency")`` and ``(..., "bad", "latency")`` (both advance once per packet
  whatever the state, so changing one state's model leaves the other's
  draws alone), ``(..., "state_loss")`` (one uniform per packet when either
  loss is positive).

Adding a model means writing one more subclass of :class:`LatencyBase` with a
``model: Literal["name"] = "name"`` field, decorating it with
:func:`register`, and placing it before the line that builds
:data:`LatencyModel` at the end of this module (before :data:`NestedLatency`
if ``gilbert_elliott`` may nest it).

This module also holds :class:`StrictModel`, the base of every scenario
model (frozen, unknown keys rejected with a "did you mean" suggestion).
"""

from __future__ import annotations

import difflib
import math
import os
from decimal import ROUND_HALF_EVEN, Decimal
from pathlib import Path
from typing import Annotated, Any, Callable, ClassVar, Literal, Union

import numpy as np
from pydantic import (BaseModel, ConfigDict, Field, PrivateAttr, TypeAdapter, ValidationInfo,
                      model_validator)
from pydantic_core import PydanticCustomError

from dkfsim.core.streams import stream

NS_PER_S = 1_000_000_000
#: Every time and delay a run can reach is at most this many nanoseconds (about 146
#: years), so that sums of two of them stay within int64 (the clock's type).
MAX_NS = 2**62
_MAX_NS = MAX_NS
#: The same limit in seconds: the largest value a time or latency key may take.
MAX_SECONDS = MAX_NS / NS_PER_S
#: Largest magnitude of a matrix entry, vector entry or factor: a product of
#: three such numbers stays within float64 (1.8e308).
MAX_MAGNITUDE = 1e100


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


NonNegSeconds = Annotated[float, Field(strict=True, ge=0, le=MAX_SECONDS, allow_inf_nan=False)]
PosSeconds = Annotated[float, Field(strict=True, gt=0, le=MAX_SECONDS, allow_inf_nan=False)]
#: A positive dimensionless parameter (a shape, a tail index, a scale factor).
PosReal = Annotated[float, Field(strict=True, gt=0, le=MAX_MAGNITUDE, allow_inf_nan=False)]


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

    def sampler(self, rng_for: Callable[..., np.random.Generator], T_ns: int) -> "Sampler":
        """Per-link draws: i.i.d. blocks from the stream ``rng_for("latency")``."""
        return _IIDSampler(self, rng_for("latency"), int(T_ns))

    def to_dict(self) -> dict:
        """Plain mapping (with the ``model`` key) that ``parse_latency`` accepts."""
        return self.model_dump(mode="json")


# --------------------------------------------------------------------------- samplers
class Sampler:
    """The per-link state of a latency model: successive blocks of packets."""

    __slots__ = ()

    def block(self, size: int) -> tuple[np.ndarray, np.ndarray | None]:
        """Latencies (int64 ns) of the next ``size`` packets, and their "lost"
        flags (bool) for a model that loses packets, else ``None``."""
        raise NotImplementedError


class _IIDSampler(Sampler):
    __slots__ = ("model", "rng", "T_ns")

    def __init__(self, model, rng, T_ns):
        self.model, self.rng, self.T_ns = model, rng, T_ns

    def block(self, size):
        return np.asarray(self.model.sample_ns(self.rng, size, self.T_ns), dtype=np.int64), None


def rng_family(rng: np.random.Generator) -> Callable[..., np.random.Generator]:
    """Named child streams seeded by one draw of ``rng`` (for ``sample_ns`` of
    a stateful model, which needs several streams but is given one)."""
    seed = int(rng.integers(0, 2**63))
    return lambda *name: stream(seed, *name)


def _size_of(size) -> int:
    return int(np.prod(size)) if np.ndim(size) else int(size)


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


class ShiftedDraw(LatencyBase):
    """``offset + draw`` seconds for a continuous law: the shared part of the
    unbounded models (one rounding to ns, one shift, one cap)."""

    offset: NonNegSeconds = 0.0
    bounded: ClassVar[bool] = False

    def draw_s(self, rng, size) -> np.ndarray:
        """The law's draws in seconds, before the offset."""
        raise NotImplementedError

    def sample_ns(self, rng, size, T_ns):
        draw = _round_ns(self.draw_s(rng, size))
        return np.minimum(draw + np.int64(seconds_to_ns(self.offset)), _MAX_NS)

    def sup_ns(self, T_ns):
        return None


@register
class Exponential(ShiftedDraw):
    """``offset + Exp(mean)`` seconds; unbounded."""

    model: Literal["exponential"] = "exponential"
    mean: PosSeconds

    def draw_s(self, rng, size):
        return rng.exponential(self.mean, size=size)


@register
class Lognormal(ShiftedDraw):
    """``offset + median * exp(sigma * Z)`` seconds; unbounded unless ``sigma = 0``."""

    model: Literal["lognormal"] = "lognormal"
    median: PosSeconds
    sigma: Annotated[float, Field(strict=True, ge=0, le=MAX_MAGNITUDE, allow_inf_nan=False)]

    def draw_s(self, rng, size):
        return rng.lognormal(math.log(self.median), self.sigma, size=size)

    def sup_ns(self, T_ns):
        if self.sigma == 0:
            return int(_round_ns(self.median)) + seconds_to_ns(self.offset)
        return None


@register
class Gamma(ShiftedDraw):
    """``offset + Gamma(shape, scale)`` seconds; unbounded."""

    model: Literal["gamma"] = "gamma"
    shape: PosReal
    scale: PosSeconds

    def draw_s(self, rng, size):
        return rng.gamma(self.shape, self.scale, size=size)


@register
class Pareto(ShiftedDraw):
    """``offset + scale * U^(-1/alpha)`` seconds (classical Pareto); unbounded."""

    model: Literal["pareto"] = "pareto"
    alpha: PosReal
    scale: PosSeconds

    def draw_s(self, rng, size):
        # numpy's pareto is the Lomax (Pareto II) law; 1 + Lomax is the classical one.
        with np.errstate(over="ignore"):
            return self.scale * (1.0 + rng.pareto(self.alpha, size=size))


# ----------------------------------------------------------------------- empirical traces
from dkfsim.core.datafiles import DataFileError, locate, read_table  # noqa: E402


def located(file: str | None, dataset: str | None, info: ValidationInfo | None) -> tuple[Path, str]:
    """:func:`dkfsim.core.datafiles.locate` inside a validator: the path and the key it came
    from; a validation error on the ``file`` / ``dataset`` key if there is none."""
    base = (info.context or {}).get("base_dir") if info is not None else None
    try:
        return locate(file, dataset, base)
    except DataFileError as err:
        raise custom_error(str(err), "dataset" if dataset is not None else "file") from None

_UNIT_S = {"ms": 1e-3, "s": 1.0}
_COLUMNS: dict[tuple, np.ndarray] = {}


def read_column(path: str | os.PathLike, column: str | int) -> np.ndarray:
    """One numeric column of latencies (float64, finite, >= 0) of a table
    (:func:`dkfsim.core.datafiles.read_table`).

    ``column`` is a header name (matched ignoring case and punctuation:
    ``delay_ms`` finds ``delay(ms)``) or a 0-based index.  Raises
    :class:`~dkfsim.core.datafiles.DataFileError` naming the line of any problem.
    """
    table = read_table(path)
    key = (str(table.path), id(table), column)
    cached = _COLUMNS.get(key)
    if cached is not None:
        return cached
    values = []
    for no, v in table.floats(table.column_index(column)):
        if not math.isfinite(v) or v < 0:
            raise DataFileError(f"{table.path.name} line {no}: latency {v!r} must be a finite "
                                "number >= 0")
        values.append(v)
    out = np.array(values, dtype=float)
    out.setflags(write=False)
    _COLUMNS[key] = out
    return out


class _ReplaySampler(Sampler):
    __slots__ = ("values", "pos")

    def __init__(self, values, start):
        self.values = values
        self.pos = int(start) % len(values)

    def block(self, size):
        n = len(self.values)
        idx = (self.pos + np.arange(size)) % n
        self.pos = (self.pos + size) % n
        return self.values[idx], None


@register
class Empirical(LatencyBase):
    """Latencies from a measured trace, resampled or replayed (see the module docstring)."""

    model: Literal["empirical"] = "empirical"
    file: Annotated[str, Field(strict=True, min_length=1)] | None = None
    dataset: Annotated[str, Field(strict=True, min_length=1)] | None = None
    column: Annotated[str, Field(strict=True, min_length=1)] | Annotated[int, Field(strict=True, ge=0)] = "delay_ms"
    unit: Literal["ms", "s"] = "ms"
    one_way: Annotated[bool, Field(strict=True)] = False
    scale: PosReal = 1.0
    mode: Literal["resample", "replay"] = "resample"
    start: Annotated[int, Field(strict=True, ge=0)] | None = None

    # The resolved file (absolute path); the values live in a module cache.
    _path: str | None = PrivateAttr(default=None)

    @model_validator(mode="after")
    def _load(self, info: ValidationInfo):
        if self.start is not None and self.mode != "replay":
            raise custom_error("only used with mode: replay", "start")
        path, key = located(self.file, self.dataset, info)
        try:
            values = read_column(path, self.column)
        except DataFileError as err:
            raise custom_error(str(err), "column" if "column" in str(err) else key) from None
        if self.start is not None and self.start >= len(values):
            raise custom_error(f"must be < {len(values)} (the trace's rows), got {self.start}",
                               "start")
        self._path = str(path)
        return self

    def to_dict(self) -> dict:
        return self.model_dump(mode="json", exclude_none=True)

    def trace_s(self) -> np.ndarray:
        """The trace's latencies in seconds, after ``unit``, ``one_way`` and ``scale``."""
        raw = read_column(self._path, self.column)
        return raw * (_UNIT_S[self.unit] * self.scale * (0.5 if self.one_way else 1.0))

    def values_ns(self) -> np.ndarray:
        """The trace's latencies as int64 ns, in file order."""
        key = (self._path, self.column, self.unit, self.one_way, self.scale, "ns")
        out = _COLUMNS.get(key)
        if out is None:
            out = _round_ns(self.trace_s())
            out.setflags(write=False)
            _COLUMNS[key] = out
        return out

    def _start(self, rng) -> int:
        n = len(self.values_ns())
        return self.start if self.start is not None else int(rng.integers(0, n))

    def sample_ns(self, rng, size, T_ns):
        vals = self.values_ns()
        if self.mode == "resample":
            return vals[rng.integers(0, len(vals), size=size)]
        flat, _ = _ReplaySampler(vals, self._start(rng)).block(_size_of(size))
        return flat.reshape(size)

    def sampler(self, rng_for, T_ns):
        if self.mode == "resample":
            return super().sampler(rng_for, T_ns)
        return _ReplaySampler(self.values_ns(), self._start(rng_for("latency")))

    def sup_ns(self, T_ns):
        return int(self.values_ns().max())


# ----------------------------------------------------------------------- Gilbert-Elliott
#: Any model registered so far (the models ``gilbert_elliott`` may nest).
NestedLatency = Annotated[Union[tuple(LATENCY_MODELS.values())], Field(discriminator="model")]

Probability = Annotated[float, Field(strict=True, ge=0, le=1, allow_inf_nan=False)]


class _GESampler(Sampler):
    __slots__ = ("m", "state_rng", "loss_rng", "good", "bad", "bad_now")

    def __init__(self, m, rng_for, T_ns):
        self.m = m
        self.state_rng = rng_for("state")
        self.good = m.good.sampler(lambda *name: rng_for("good", *name), T_ns)
        self.bad = m.bad.sampler(lambda *name: rng_for("bad", *name), T_ns)
        self.loss_rng = rng_for("state_loss") if (m.loss_good > 0 or m.loss_bad > 0) else None
        u0 = self.state_rng.random()
        if m.initial == "stationary":
            self.bad_now = bool(u0 < m.stationary_bad())
        else:
            self.bad_now = m.initial == "bad"

    def states(self, size: int) -> np.ndarray:
        """The next ``size`` packets' states (True = bad); steps the chain."""
        u = self.state_rng.random(size).tolist()
        p_gb, p_bg = self.m.p_good_to_bad, self.m.p_bad_to_good
        out = np.empty(size, dtype=bool)
        bad = self.bad_now
        for k in range(size):
            out[k] = bad
            bad = (u[k] >= p_bg) if bad else (u[k] < p_gb)
        self.bad_now = bad
        return out

    def block(self, size):
        bad = self.states(size)
        g, _ = self.good.block(size)
        b, _ = self.bad.block(size)
        lat = np.where(bad, b, g)
        if self.loss_rng is None:
            return lat, None
        u = self.loss_rng.random(size)
        return lat, u < np.where(bad, self.m.loss_bad, self.m.loss_good)


@register
class GilbertElliott(LatencyBase):
    """Two-state (good/bad) Markov channel per link: latency and loss depend on the state."""

    model: Literal["gilbert_elliott"] = "gilbert_elliott"
    p_good_to_bad: Probability
    p_bad_to_good: Probability
    good: NestedLatency
    bad: NestedLatency
    loss_good: Probability = 0.0
    loss_bad: Probability = 0.0
    initial: Literal["stationary", "good", "bad"] = "stationary"

    @model_validator(mode="after")
    def _check(self):
        if self.initial == "stationary" and self.p_good_to_bad + self.p_bad_to_good == 0:
            raise custom_error("with p_good_to_bad = p_bad_to_good = 0 the chain has no "
                               "stationary law; set initial: good or bad", "initial")
        return self

    @property
    def bounded(self) -> bool:  # type: ignore[override]
        return self.good.bounded and self.bad.bounded

    def stationary_bad(self) -> float:
        """Stationary probability of the bad state."""
        return self.p_good_to_bad / (self.p_good_to_bad + self.p_bad_to_good)

    def sampler(self, rng_for, T_ns):
        return _GESampler(self, rng_for, int(T_ns))

    def sample_ns(self, rng, size, T_ns):
        lat, _ = self.sampler(rng_family(rng), T_ns).block(_size_of(size))
        return lat.reshape(size)

    def sup_ns(self, T_ns):
        a, b = self.good.sup_ns(T_ns), self.bad.sup_ns(T_ns)
        return None if a is None or b is None else max(a, b)


# --------------------------------------------------------------------------- union
#: Field type accepting any registered model, discriminated on ``model``.
LatencyModel = Annotated[Union[tuple(LATENCY_MODELS.values())], Field(discriminator="model")]

_ADAPTER = TypeAdapter(LatencyModel)


def parse_latency(data: dict | LatencyBase, base_dir: str | os.PathLike | None = None) -> LatencyBase:
    """Validate a mapping such as ``{"model": "constant", "value": 0.02}``.

    ``base_dir`` is where a relative ``empirical`` file is looked up first
    (default: the working directory).  Raises pydantic's ``ValidationError``
    on bad input; scenario files go through
    :func:`dkfsim.config.schema.load_scenario`, which reports errors with their
    key path.
    """
    if isinstance(data, LatencyBase):
        return data
    return _ADAPTER.validate_python(data, context={"base_dir": base_dir})

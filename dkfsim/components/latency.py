"""Link latency models: parameters, distribution and per-link draws.

A latency model says how long a packet handed to a directed link takes to
arrive.  Simulated time is integer nanoseconds (docs/design.md §2), so every
model gives *integer nanoseconds*; continuous draws are rounded to the
nearest nanosecond and clamped at 2^62 ns (such a packet never arrives).
docs/latency_models.md explains every model with examples; in a scenario
a model is a mapping whose ``model`` key names it.  Units are SI seconds
unless a key says otherwise (``d_t`` counts sampling periods).

``constant {value}``
    every packet takes ``value`` s.  Bound: ``ceil(value / T)`` steps.
``uniform_steps {d_t}``
    the paper's model: ``d T`` with ``d`` uniform on ``0..d_t``.  Bound: ``d_t``.
``uniform {low, high}``
    continuous uniform on ``[low, high]`` s.  Bound: ``ceil(high / T)``.
``exponential {mean, offset}``, ``lognormal {median, sigma, offset}``,
``gamma {shape, scale, offset}``, ``pareto {alpha, scale, offset}``
    ``offset`` plus the law (lognormal: ``median exp(sigma Z)``; pareto:
    classical, ``scale`` its minimum).  Unbounded.
``empirical {file | dataset, column, unit, one_way, scale, mode, start}``
    a measured trace: ``resample`` draws its values i.i.d.; ``replay`` plays
    it in order, one row per tick of the run (row ``start + k`` for a packet
    sent during tick ``k``, cycling; ``start`` drawn per link when absent).
    Bounded by its largest value.
``cellular_sinr {sinr, one_way, scale}``
    a cellular (V2N) link: the CICV5G round trips of the SINR's bin (quantiles
    fitted by tools/fit_sinr_latency.py).  Bounded by the bin's largest value.
``gilbert_elliott {p_good_to_bad, p_bad_to_good, good, bad, loss_good, loss_bad, initial}``
    a two-state Markov channel per link, stepped once per tick: latency and
    loss depend on the state at the send instant.

Draws are keyed (the common-random-numbers rule, docs/design.md §3): the
latency of a packet is ``from_uniform(u)`` with ``u =
keyed_uniform(key(link, "latency"), send instant, seq)``, ``seq`` the
packet's number among those its sender put on the link at that instant.
Two estimators sending over one link at one instant therefore see the same
delay, and a draw never depends on how many packets came before.  Each
model offers ``from_uniform(u, T_ns)`` (its quantile function, vectorised),
``sample_ns(rng, size, T_ns)`` (i.i.d. draws, for tests and tables),
``sampler(prefix, seed, T_ns)`` (the per-link keyed draws), ``sup_ns`` and
``bound_steps``.  A new model is one more registered subclass of
:class:`LatencyParams` (docs/extending.md).
"""

from __future__ import annotations

import functools
import math
import os
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, ClassVar, Literal

import numpy as np
from pydantic import Field, PrivateAttr, TypeAdapter, ValidationInfo, model_validator
from typing_extensions import override

from dkfsim.core.datafiles import DATA_DIR, DataFileError, locate, read_table
from dkfsim.core.errors import DkfsimError
from dkfsim.core.files import read_json
from dkfsim.core.params import (
    MAX_NS,
    NS_PER_S,
    NonNegSeconds,
    PosReal,
    PosSeconds,
    Probability,
    StrictModel,
    custom_error,
    registered,
    round_ns,
    seconds_to_ns,
)
from dkfsim.core.registry import LATENCY_MODELS
from dkfsim.core.streams import key64, keyed_uniform, stream


class LatencyParams(StrictModel):
    """Interface of every latency model (see the module docstring)."""

    model: str
    #: True when the model has a finite supremum.
    bounded: ClassVar[bool] = True
    #: The keys a latency scale ``s`` multiplies (``maxdelay``'s continuous axis): the
    #: model's time parameters, or a factor with the same effect; None: not scalable.
    scale_keys: ClassVar[tuple[str, ...] | None] = None
    #: True when the model's own parameters include latency models (scaled through them).
    nests_models: ClassVar[bool] = False

    @property
    def deterministic(self) -> bool:
        """True when every packet takes the same latency (no draw matters)."""
        return False

    def scaled_keys(self) -> list[str] | None:
        """Dotted keys (relative to the model) a latency scale multiplies; None if none can."""
        if self.scale_keys is not None:
            return [k for k in self.scale_keys if getattr(self, k) is not None]
        if not self.nests_models:
            return None
        out = []
        for key, value in self:
            if isinstance(value, LatencyParams):
                sub = value.scaled_keys()
                if sub is None:
                    return None
                out += [f"{key}.{k}" for k in sub]
        return out

    def from_uniform(self, u, T_ns: int) -> np.ndarray:
        """Latencies (int64 ns) for uniforms ``u`` in (0, 1): the quantile function."""
        raise NotImplementedError

    def sample_ns(self, rng: np.random.Generator, size, T_ns: int) -> np.ndarray:
        """``size`` i.i.d. latencies (int64 ns) drawn with ``rng``."""
        u = 1.0 - rng.random(size)                   # (0, 1]
        return self.from_uniform(np.minimum(u, 1.0 - 2.0 ** -53), T_ns)

    def sup_ns(self, T_ns: int) -> int | None:
        """Largest latency the model can produce, in ns; ``None`` if unbounded."""
        raise NotImplementedError

    def inf_ns(self) -> int:
        """A lower bound (ns) of the latencies the model can produce (0: it may produce none at
        all): what lets a port say at once that a packet cannot arrive at the instant it is sent."""
        return 0

    def bound_steps(self, T_ns: int) -> int | None:
        """Smallest ``d`` with latency ``<= d * T`` always; ``None`` if unbounded."""
        sup = self.sup_ns(T_ns)
        return None if sup is None else -(-sup // int(T_ns))

    def sampler(self, prefix: tuple, seed: int, T_ns: int) -> "Sampler":
        """The keyed draws of one link (streams named ``prefix + (...,)``)."""
        return KeyedSampler(self, key64(seed, *prefix, "latency"), int(T_ns))


class Sampler:
    """The draws of one latency model on one link: ``draw(t_ns, seq) -> (ns, lost)``."""

    __slots__ = ()

    def draw(self, t_ns: int, seq: int) -> tuple[int, bool]:
        raise NotImplementedError

    def vector(self) -> tuple[int, int, int] | None:
        """The model as a batch of packets draws it in one compiled loop
        (:mod:`dkfsim.network.port_kernels`): ``(0, 0, ns)`` a constant, ``(1, key, d_t)``
        uniform steps; None for a model drawn one packet at a time."""
        return None


class KeyedSampler(Sampler):
    """An i.i.d. model: the quantile of one keyed uniform per packet."""

    __slots__ = ("model", "key", "T_ns")

    def __init__(self, model, key, T_ns):
        self.model, self.key, self.T_ns = model, key, T_ns

    def draw(self, t_ns, seq):
        return int(self.model.from_uniform(keyed_uniform(self.key, t_ns, seq), self.T_ns)), False


def _clamped(ns) -> np.ndarray:
    return np.clip(np.rint(ns), 0, MAX_NS).astype(np.int64)


def _clamped_one(ns: float) -> int:
    """:func:`_clamped` of one latency, without numpy's array wrappers (a port draws one packet at
    a time, and ``np.clip`` was most of a draw): the same rounding, half to even."""
    if not ns < MAX_NS:
        return MAX_NS if ns == ns else int(_clamped(ns))     # (NaN: as the array path gives it)
    return round(float(ns)) if ns > 0 else 0


# =========================================================================== bounded models
@LATENCY_MODELS.register("constant")
class Constant(LatencyParams):
    """Every packet takes ``value`` seconds."""

    model: Literal["constant"] = "constant"
    value: NonNegSeconds = 0.0
    scale_keys: ClassVar = ("value",)
    deterministic: ClassVar[bool] = True

    @override
    def from_uniform(self, u, T_ns):
        return np.full(np.shape(u), min(seconds_to_ns(self.value), MAX_NS), dtype=np.int64)

    @override
    def sup_ns(self, T_ns):
        return seconds_to_ns(self.value)

    @override
    def inf_ns(self):
        return min(seconds_to_ns(self.value), MAX_NS)

    @override
    def sampler(self, prefix, seed, T_ns):
        return _Fixed(min(seconds_to_ns(self.value), MAX_NS))


class _Fixed(Sampler):
    __slots__ = ("ns",)

    def __init__(self, ns):
        self.ns = ns

    @override
    def draw(self, t_ns, seq):
        return self.ns, False

    @override
    def vector(self):
        return 0, 0, self.ns


@LATENCY_MODELS.register("uniform_steps")
class UniformSteps(LatencyParams):
    """``d * T`` with ``d`` uniform on ``{0..d_t}`` (the paper's model)."""

    model: Literal["uniform_steps"] = "uniform_steps"
    d_t: Annotated[int, Field(strict=True, ge=0)]

    @property
    def deterministic(self) -> bool:
        return self.d_t == 0

    def from_uniform(self, u, T_ns):
        d = np.floor(np.asarray(u, float) * (self.d_t + 1)).astype(np.int64)
        return np.minimum(d, self.d_t) * np.int64(T_ns)

    def sup_ns(self, T_ns):
        return self.d_t * int(T_ns)

    @override
    def bound_steps(self, T_ns):
        return self.d_t

    def sampler(self, prefix, seed, T_ns):
        return _Steps(self.d_t, key64(seed, *prefix, "latency"), int(T_ns))


class _Steps(Sampler):
    """``uniform_steps`` without numpy on the hot path (one packet at a time)."""

    __slots__ = ("d_t", "key", "T_ns")

    def __init__(self, d_t, key, T_ns):
        self.d_t, self.key, self.T_ns = d_t, key, T_ns

    def draw(self, t_ns, seq):
        return min(int(keyed_uniform(self.key, t_ns, seq) * (self.d_t + 1)), self.d_t) * self.T_ns, False

    @override
    def vector(self):
        return 1, self.key, self.d_t


@LATENCY_MODELS.register("uniform")
class Uniform(LatencyParams):
    """Continuous uniform on ``[low, high]`` seconds."""

    model: Literal["uniform"] = "uniform"
    low: NonNegSeconds = 0.0
    high: NonNegSeconds
    scale_keys: ClassVar = ("low", "high")

    @property
    def deterministic(self) -> bool:
        return self.low == self.high

    @model_validator(mode="after")
    def _ordered(self):
        if self.high < self.low:
            raise custom_error(f"must be >= low ({self.low!r}), got {self.high!r}", "high")
        return self

    @override
    def inf_ns(self):
        return seconds_to_ns(self.low)

    @override
    def from_uniform(self, u, T_ns):
        lo, hi = seconds_to_ns(self.low), seconds_to_ns(self.high)
        return np.clip(_clamped((self.low + np.asarray(u, float) * (self.high - self.low)) * NS_PER_S), lo, hi)

    @override
    def sup_ns(self, T_ns):
        return seconds_to_ns(self.high)


# =========================================================================== unbounded laws
class ShiftedLaw(LatencyParams):
    """``offset + law`` seconds: the shared part of the unbounded models."""

    offset: NonNegSeconds = 0.0
    bounded: ClassVar[bool] = False

    def quantile_s(self, u: np.ndarray) -> np.ndarray:
        """The law's quantile function in seconds, before the offset."""
        raise NotImplementedError

    @override
    def from_uniform(self, u, T_ns):
        with np.errstate(over="ignore"):
            ns = (self.offset + self.quantile_s(np.asarray(u, float))) * NS_PER_S
        return _clamped_one(ns) if type(u) is float else _clamped(ns)

    @override
    def sup_ns(self, T_ns):
        return None

    @override
    def inf_ns(self):
        return max(0, seconds_to_ns(self.offset) - 1)      # (the laws reach 0 themselves)


@LATENCY_MODELS.register("exponential")
class Exponential(ShiftedLaw):
    """``offset + Exp(mean)`` seconds; unbounded."""

    model: Literal["exponential"] = "exponential"
    mean: PosSeconds
    scale_keys: ClassVar = ("mean", "offset")

    def quantile_s(self, u):
        return -self.mean * np.log(u)          # u and 1 - u are alike; log(u) keeps the tail exact


@LATENCY_MODELS.register("lognormal")
class Lognormal(ShiftedLaw):
    """``offset + median * exp(sigma * Z)`` seconds; unbounded unless ``sigma = 0``."""

    model: Literal["lognormal"] = "lognormal"
    median: PosSeconds
    sigma: Annotated[float, Field(strict=True, ge=0, le=1e100, allow_inf_nan=False)]
    scale_keys: ClassVar = ("median", "offset")

    @property
    def deterministic(self) -> bool:
        return self.sigma == 0

    def quantile_s(self, u):
        from scipy.special import ndtri  # (lazy: scipy.special only where a lognormal draws)
        return self.median * np.exp(self.sigma * ndtri(u))

    @override
    def sup_ns(self, T_ns):
        if self.sigma == 0:
            return int(round_ns(self.median)) + seconds_to_ns(self.offset)
        return None


@LATENCY_MODELS.register("gamma")
class Gamma(ShiftedLaw):
    """``offset + Gamma(shape, scale)`` seconds; unbounded."""

    model: Literal["gamma"] = "gamma"
    shape: PosReal
    scale: PosSeconds
    scale_keys: ClassVar = ("scale", "offset")

    def quantile_s(self, u):
        from scipy.special import gammaincinv  # (lazy: scipy.special only where a gamma draws)
        return self.scale * gammaincinv(self.shape, u)


@LATENCY_MODELS.register("pareto")
class Pareto(ShiftedLaw):
    """``offset + scale * U^(-1/alpha)`` seconds (classical Pareto); unbounded."""

    model: Literal["pareto"] = "pareto"
    alpha: PosReal
    scale: PosSeconds
    scale_keys: ClassVar = ("scale", "offset")

    def quantile_s(self, u):
        return self.scale * u ** (-1.0 / self.alpha)

    @override
    def inf_ns(self):
        # (one ns less than offset + scale: the quantile's rounding cannot go below that)
        return max(0, seconds_to_ns(self.offset + self.scale) - 1)


# =========================================================================== empirical traces
_UNIT_S = {"ms": 1e-3, "s": 1.0}
_COLUMNS: dict[tuple, np.ndarray] = {}


#: Why a scenario read back from a result does not open a ``file:`` it names
#: (:func:`dkfsim.config.load.stored_scenario`; docs/security.md).
STORED_FILE_REFUSAL = ("a data file of a scenario read back from a result: reading a result never opens "
                       "the files it names (they could be any file on this machine)")


def located(file: str | None, dataset: str | None, info: ValidationInfo | None) -> tuple[Path, str]:
    """:func:`dkfsim.core.datafiles.locate` inside a validator: the path and the key it came
    from; a validation error on the ``file`` / ``dataset`` key if there is none.  With
    ``data_files: False`` in the validation context (a scenario read back from a result) a
    ``file`` is refused before anything is looked up (:data:`STORED_FILE_REFUSAL`); a shipped
    ``dataset`` is part of the package and is read."""
    context = (info.context or {}) if info is not None else {}
    base = context.get("base_dir")
    if file is not None and context.get("data_files") is False:
        raise custom_error(STORED_FILE_REFUSAL, "file")
    try:
        return locate(file, dataset, base)
    except DataFileError as err:
        raise custom_error(str(err), "dataset" if dataset is not None else "file") from None


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


@LATENCY_MODELS.register("empirical")
class Empirical(LatencyParams):
    """Latencies from a measured trace, resampled or replayed one row per tick."""

    model: Literal["empirical"] = "empirical"
    file: Annotated[str, Field(strict=True, min_length=1)] | None = None
    dataset: Annotated[str, Field(strict=True, min_length=1)] | None = None
    column: Annotated[str, Field(strict=True, min_length=1)] | Annotated[int, Field(strict=True, ge=0)] = "delay_ms"
    unit: Literal["ms", "s"] = "ms"
    one_way: Annotated[bool, Field(strict=True)] = False
    scale: PosReal = 1.0
    mode: Literal["resample", "replay"] = "resample"
    start: Annotated[int, Field(strict=True, ge=0)] | None = None
    scale_keys: ClassVar = ("scale",)

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

    def trace_s(self) -> np.ndarray:
        """The trace's latencies in seconds, after ``unit``, ``one_way`` and ``scale``."""
        assert self._path is not None         # (set by _load, the validator)
        raw = read_column(self._path, self.column)
        return raw * (_UNIT_S[self.unit] * self.scale * (0.5 if self.one_way else 1.0))

    def values_ns(self) -> np.ndarray:
        """The trace's latencies as int64 ns, in file order."""
        key = (self._path, self.column, self.unit, self.one_way, self.scale, "ns")
        out = _COLUMNS.get(key)
        if out is None:
            out = round_ns(self.trace_s())
            out.setflags(write=False)
            _COLUMNS[key] = out
        return out

    @override
    def from_uniform(self, u, T_ns):
        vals = self.values_ns()
        return vals[np.minimum((np.asarray(u, float) * len(vals)).astype(np.int64), len(vals) - 1)]

    def sampler(self, prefix, seed, T_ns):
        if self.mode == "resample":
            return super().sampler(prefix, seed, T_ns)
        vals = self.values_ns()
        start = self.start if self.start is not None else \
            min(int(keyed_uniform(key64(seed, *prefix, "start"), 0, 0) * len(vals)), len(vals) - 1)
        return _Replay(vals, start, int(T_ns))

    @override
    def sup_ns(self, T_ns):
        return int(self.values_ns().max())


class _Replay(Sampler):
    """Row ``start + k`` (cycling) for a packet sent during tick ``k``."""

    __slots__ = ("values", "start", "T_ns")

    def __init__(self, values, start, T_ns):
        self.values, self.start, self.T_ns = values, start, T_ns

    @override
    def draw(self, t_ns, seq):
        return int(self.values[(self.start + t_ns // self.T_ns) % len(self.values)]), False


# =========================================================================== Gilbert-Elliott
#: The latency model of a Gilbert-Elliott state (any registered model; to a type checker: the
#: base model, which every registered one subclasses).
if TYPE_CHECKING:
    _StateModel = LatencyParams
else:
    _StateModel = registered(LatencyParams, LATENCY_MODELS)


@LATENCY_MODELS.register("gilbert_elliott")
class GilbertElliott(LatencyParams):
    """Two-state (good/bad) Markov channel per link, one step per tick."""

    model: Literal["gilbert_elliott"] = "gilbert_elliott"
    p_good_to_bad: Probability
    p_bad_to_good: Probability
    good: _StateModel
    bad: _StateModel
    loss_good: Probability = 0.0
    loss_bad: Probability = 0.0
    initial: Literal["stationary", "good", "bad"] = "stationary"
    nests_models: ClassVar[bool] = True

    @model_validator(mode="after")
    def _check(self):
        for key in ("good", "bad"):
            if isinstance(getattr(self, key), GilbertElliott):
                raise custom_error("a state's latency model cannot itself be gilbert_elliott", key)
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

    def sampler(self, prefix, seed, T_ns):
        return _GESampler(self, tuple(prefix), int(seed), int(T_ns))

    @override
    def from_uniform(self, u, T_ns):
        raise TypeError("gilbert_elliott is a Markov chain: draw through sampler() or sample_ns()")

    def sample_ns(self, rng, size, T_ns):
        """Latencies of ``size`` successive ticks of one link, one packet each."""
        s = self.sampler(("sample", int(rng.integers(0, 2**62))), 0, T_ns)
        n = int(np.prod(size))
        return np.array([s.draw(k * int(T_ns), 0)[0] for k in range(n)], dtype=np.int64).reshape(size)

    def sup_ns(self, T_ns):
        a, b = self.good.sup_ns(T_ns), self.bad.sup_ns(T_ns)
        return None if a is None or b is None else max(a, b)


class _GESampler(Sampler):
    """The chain's state per tick (generated in blocks from the link's ``state`` stream),
    each state's latency drawn keyed, the state's loss keyed too."""

    __slots__ = ("m", "T_ns", "rng", "states", "bad_now", "good", "bad", "loss_key")

    def __init__(self, m, prefix, seed, T_ns):
        self.m, self.T_ns = m, T_ns
        self.rng = stream(seed, *prefix, "state")
        u0 = self.rng.random()
        self.bad_now = bool(u0 < m.stationary_bad()) if m.initial == "stationary" else m.initial == "bad"
        self.states: list[bool] = []
        self.good = m.good.sampler(prefix + ("good",), seed, T_ns)
        self.bad = m.bad.sampler(prefix + ("bad",), seed, T_ns)
        self.loss_key = key64(seed, *prefix, "state_loss") if (m.loss_good > 0 or m.loss_bad > 0) else None

    def state(self, tick: int) -> bool:
        """True when the channel is bad during tick ``tick`` (0-based)."""
        p_gb, p_bg = self.m.p_good_to_bad, self.m.p_bad_to_good
        while len(self.states) <= tick:
            for u in self.rng.random(1024).tolist():
                self.states.append(self.bad_now)
                self.bad_now = (u >= p_bg) if self.bad_now else (u < p_gb)
        return self.states[tick]

    def draw(self, t_ns, seq):
        bad = self.state(t_ns // self.T_ns)
        lat, _ = (self.bad if bad else self.good).draw(t_ns, seq)
        if self.loss_key is None:
            return lat, False
        p = self.m.loss_bad if bad else self.m.loss_good
        return lat, keyed_uniform(self.loss_key, t_ns, seq) < p


# =========================================================================== cellular (V2N) by SINR
#: The shipped fit of ``cellular_sinr`` (tools/fit_sinr_latency.py writes it; a test recomputes it).
SINR_FIT_FILE = DATA_DIR / "cicv5g" / "sinr_latency_fit.json"


class SinrTable:
    """A fit's SINR-binned quantile functions as arrays, built once (a ``track`` link draws one
    packet at a time, and rebuilding them from the JSON lists cost more than the draw)."""

    __slots__ = ("edges", "levels", "quantiles")

    def __init__(self, fit: dict):
        self.edges = np.asarray(fit["bin_edges_db"], float)
        self.levels = np.asarray(fit["levels"], float)
        self.quantiles = [np.asarray(entry["quantiles_ms"], float) for entry in fit["bins"]]

    def latency_ms(self, u, sinr_db) -> np.ndarray:
        """Round-trip latencies (ms) for uniforms ``u`` at SINRs ``sinr_db`` (broadcast): the
        quantile function of the SINR's bin, linear between the fit's quantile levels."""
        u, sinr = np.broadcast_arrays(np.asarray(u, float), np.asarray(sinr_db, float))
        which = np.searchsorted(self.edges, sinr, side="right")
        out = np.empty(u.shape)
        for b, q in enumerate(self.quantiles):
            sel = which == b
            out[sel] = np.interp(u[sel], self.levels, q)
        return out


@functools.cache
def sinr_table() -> SinrTable:
    """:class:`SinrTable` of the shipped fit (read and built once)."""
    return SinrTable(read_json(SINR_FIT_FILE, what="the cellular_sinr fit"))


def sinr_latency_ms(u, sinr_db, fit: dict) -> np.ndarray:
    """Round-trip latencies (ms) for uniforms ``u`` at SINRs ``sinr_db`` under ``fit`` (a fit
    being made, as tools/fit_sinr_latency.py checks it; runs use :func:`sinr_table`)."""
    return SinrTable(fit).latency_ms(u, sinr_db)


@LATENCY_MODELS.register("cellular_sinr")
class CellularSinr(LatencyParams):
    """A cellular (V2N, car -> cloud -> car) link: CICV5G latencies of the SINR's bin."""

    model: Literal["cellular_sinr"] = "cellular_sinr"
    #: The link's SINR (dB), constant for the run, or ``track``: the sender's recorded SINR at
    #: each packet's send instant (a ``track`` vehicle of ``mobility:``, decision 181).
    sinr: Annotated[float, Field(strict=True, ge=-50, le=80, allow_inf_nan=False)] | Literal["track"]
    one_way: Annotated[bool, Field(strict=True)] = False
    scale: PosReal = 1.0
    scale_keys: ClassVar = ("scale",)

    def factor(self) -> float:
        """Seconds per recorded millisecond after ``one_way`` and ``scale``."""
        return 1e-3 * self.scale * (0.5 if self.one_way else 1.0)

    def at_sinr(self, u, sinr_db) -> np.ndarray:
        """Latencies (int64 ns) for uniforms ``u`` at SINRs ``sinr_db`` (dB)."""
        return _clamped(sinr_table().latency_ms(u, sinr_db) * self.factor() * NS_PER_S)

    @override
    def from_uniform(self, u, T_ns):
        if self.sinr == "track":
            raise DkfsimError("cellular_sinr with sinr: track draws at the sender's recorded SINR, which "
                              "only a run with a 'track' vehicle under mobility: has; give a number (dB)")
        return self.at_sinr(u, self.sinr)

    @override
    def sup_ns(self, T_ns):
        if self.sinr != "track":
            return int(self.from_uniform(1.0, T_ns))
        edges = [float(e) for e in sinr_table().edges]
        probes = [edges[0] - 1.0] + edges                  # one SINR in every bin
        return int(np.max(self.at_sinr(np.ones(len(probes)), probes)))

    @override
    def sampler(self, prefix, seed, T_ns):
        if self.sinr != "track":
            return super().sampler(prefix, seed, T_ns)
        return TrackSinrSampler(self, key64(seed, *prefix, "latency"))


class TrackSinrSampler(Sampler):
    """``cellular_sinr`` with ``sinr: track``: one keyed uniform per packet, the quantile of the
    bin of the sender's SINR at the send instant (:attr:`sinr_at`, run seconds -> dB, set by
    the network from the sender's trajectory)."""

    __slots__ = ("model", "key", "sinr_at")

    def __init__(self, model: CellularSinr, key: int):
        self.model, self.key = model, key
        self.sinr_at = None

    def draw(self, t_ns, seq):
        if self.sinr_at is None:
            raise DkfsimError("cellular_sinr with sinr: track needs the sender to be a 'track' vehicle "
                              "of mobility:")
        sinr = float(self.sinr_at(t_ns / NS_PER_S))
        return int(self.model.at_sinr(keyed_uniform(self.key, t_ns, seq), sinr)), False


#: The field type of a latency model in a scenario (any registered model).
LatencyModel = registered(LatencyParams, LATENCY_MODELS)


def parse_latency(data: dict | LatencyParams, base_dir: str | os.PathLike | None = None) -> LatencyParams:
    """Validate a mapping such as ``{"model": "constant", "value": 0.02}``.

    ``base_dir`` is where a relative ``empirical`` file is looked up (default:
    the working directory).  Raises pydantic's ``ValidationError`` on bad
    input; scenario files go through :func:`dkfsim.config.load.load_scenario`,
    which reports errors with their key path.
    """
    if isinstance(data, LatencyParams):
        return data
    return TypeAdapter(LatencyModel).validate_python(data, context={"base_dir": base_dir})

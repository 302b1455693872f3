"""Scenario schema, loading, validation and ``--set`` overrides.

A scenario is a YAML mapping (the README's "Scenario files"); :func:`load_scenario`
reads it, applies ``dotted.key=value`` overrides to the raw mapping, and
validates it into a frozen :class:`Scenario`.  *All* validation happens
here, in one pass: field checks in the pydantic models, cross-field checks
(shapes, graph, protocol, buffer) in ``Scenario._check_consistency``.  Every
problem raises :class:`dkfsim.core.errors.ScenarioError` with a one-line message
``<file or "<dict>">: <dotted.key.path>: <what is wrong>``.

Decisions where docs/design.md leaves a choice:

* Matrices are lists of lists.  A scalar is a 1x1 matrix and a flat list is
  a single row (so ``H: [1, 0, 0]`` and ``R: 0.8`` work).  Vectors (the prior
  mean) are flat lists; a scalar is a 1-vector and an n x 1 column is
  flattened.  Entries must be finite numbers.
* R and P0 must be symmetric positive definite, Q symmetric positive
  semidefinite (tolerance ``1e-12 * max(1, max|eig|)``), symmetry exact up to
  ``1e-9`` relative.
* ``name`` defaults to the file's stem (``"unnamed"`` for a dict); sensor
  names must be unique.  ``kind: constant_acceleration`` must not give
  ``Phi``; ``kind: linear`` must.
* ``fusion: null`` means ``none``.  Integers and booleans are strict (``steps:
  3.0`` or ``directed: 1`` is an error); floats accept integers.
* ``links.d_t``, when given, is *the* delay bound used for the buffer length,
  even if the latency models have a smaller or larger one (so an
  under-estimated bound can be studied).  Otherwise ``d_t`` is the largest
  ``bound_steps`` over the links the protocol uses.  ``buffer_length: paper``
  needs a bound too.
* ``spanning_tree: true`` also applies to ``flood`` (flood then runs on the
  same BFS spanning tree); it is an error on a directed topology.
* The source file is remembered (``scenario.source``) but is not part of
  ``to_dict``, the hash, or equality: two scenarios are equal when their
  ``to_dict`` are.
* The YAML loader rejects duplicate keys and reads ``1e-3`` as a float (YAML
  1.1 would read it as a string).
"""

from __future__ import annotations

import copy
import hashlib
import json
import os
import re
from decimal import Decimal
from pathlib import Path
from typing import Annotated, Any, Literal, Mapping, Sequence, Union

import networkx
import numpy as np
import yaml
from pydantic import (AfterValidator, BaseModel, BeforeValidator, Discriminator, Field, PrivateAttr, Tag,
                      ValidationError, ValidationInfo, field_validator, model_validator)

from dkfsim.core.errors import DkfsimError, ScenarioError
from dkfsim.core.files import MAX_YAML_BYTES, check_plain_data, clip, parse_yaml, read_text, yaml_error_text
from dkfsim.components.faults import Faults, LinkSpec, Schedule, Window
from dkfsim.components.latency import (LATENCY_MODELS, MAX_MAGNITUDE, MAX_NS, MAX_SECONDS, Constant,
                            LatencyModel, StrictModel, custom_error, located, suggest)
from dkfsim.components import topology as topo
#: Baselines a scenario may ask for; extend this single tuple.
KNOWN_BASELINES: tuple[str, ...] = ("centralized", "centralized_delayed", "local", "no_buffer",
                                     "ci_consensus")

PROTOCOLS = ("tree", "flood")
WEIGHTS = ("unit", "paper")
FUSIONS = ("matrix", "diagonal", "none")
MODEL_KINDS = ("constant_acceleration", "constant_velocity", "linear")
SENSOR_KINDS = ("linear", "radar")

_SYM_RTOL = 1e-9
_EIG_TOL = 1e-12


# =========================================================================== matrices
def _number(x: Any) -> float:
    if isinstance(x, bool) or not isinstance(x, (int, float, np.integer, np.floating)):
        raise custom_error(f"entries must be numbers, got {x!r}")
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


Matrix = Annotated[tuple[tuple[float, ...], ...], BeforeValidator(_to_matrix)]
Vector = Annotated[tuple[float, ...], BeforeValidator(_to_vector)]
StrictInt = Annotated[int, Field(strict=True)]
StrictBool = Annotated[bool, Field(strict=True)]


def _shape(m: tuple[tuple[float, ...], ...]) -> tuple[int, int]:
    return len(m), len(m[0])


def _check_square(m, what_size: int | None = None, key: str | None = None) -> np.ndarray:
    rows, cols = _shape(m)
    if rows != cols:
        raise custom_error(f"must be square, got {rows} x {cols}", key)
    if what_size is not None and rows != what_size:
        raise custom_error(f"must be {what_size} x {what_size}, got {rows} x {cols}", key)
    return np.array(m, dtype=float)


def _check_spd(a: np.ndarray, key: str | None, semi: bool) -> None:
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
        scale = f", not above {_EIG_TOL:g} x the largest eigenvalue {top:.6g}" if tol > _EIG_TOL else ""
        raise custom_error(f"not {what} (min eigenvalue {low:.6g}{scale})", key)


# =========================================================================== sub-models
def component_names(kind: str | None, nx: int) -> list[str]:
    """Names of the state components, for tables, CSV columns and plots.

    ``position, velocity, acceleration`` for ``constant_acceleration``;
    ``x, vx, y, vy, ...`` for ``constant_velocity`` (``position, velocity``
    with one axis); ``x0, x1, ...`` otherwise.
    """
    if kind == "constant_acceleration" and nx == 3:
        return ["position", "velocity", "acceleration"]
    if kind == "constant_velocity" and nx in (2, 4, 6):
        if nx == 2:
            return ["position", "velocity"]
        return [name for axis in "xyz"[: nx // 2] for name in (axis, "v" + axis)]
    return [f"x{i}" for i in range(nx)]


class Model(StrictModel):
    """Target dynamics ``x[k+1] = Phi x[k] + w``, ``w ~ N(0, Q)``, period ``T`` s.

    ``constant_velocity`` (``dims`` axes, default 2, and the spectral density
    ``q`` of the white-noise acceleration, m^2/s^3) is the discretised
    white-noise-acceleration model with state ``[x, vx, y, vy, ...]``: per
    axis ``Phi = [[1, T], [0, 1]]``, ``Q = q [[T^3/3, T^2/2], [T^2/2, T]]``.
    """

    kind: Literal["constant_acceleration", "constant_velocity", "linear"]
    T: Annotated[float, Field(strict=True, gt=0, le=MAX_SECONDS, allow_inf_nan=False)]
    Phi: Matrix | None = None
    Q: Matrix | None = None
    dims: Annotated[int, Field(strict=True, ge=1, le=3)] | None = None
    q: Annotated[float, Field(strict=True, ge=0, le=MAX_MAGNITUDE, allow_inf_nan=False)] | None = None

    @model_validator(mode="after")
    def _check(self):
        T_ns_exact = Decimal(repr(float(self.T))) * 10**9
        if T_ns_exact != T_ns_exact.to_integral_value():
            raise custom_error(f"must be a whole number of nanoseconds, got {self.T!r} s "
                               f"({format(T_ns_exact.normalize(), 'f')} ns)", "T")
        if self.kind == "constant_velocity":
            for key in ("Phi", "Q"):
                if getattr(self, key) is not None:
                    raise custom_error("not used with kind: constant_velocity (Phi and Q are "
                                       "built from T, dims and q); remove it or use kind: "
                                       "linear", key)
            if self.q is None:
                raise custom_error("required with kind: constant_velocity (spectral density "
                                   "of the white-noise acceleration, m^2/s^3)", "q")
            return self
        for key in ("dims", "q"):
            if getattr(self, key) is not None:
                raise custom_error("only used with kind: constant_velocity", key)
        if self.Q is None:
            raise custom_error("required key is missing", "Q")
        if self.kind == "constant_acceleration":
            if self.Phi is not None:
                raise custom_error("not used with kind: constant_acceleration (Phi is built "
                                   "from T); remove it or use kind: linear", "Phi")
            n = 3
        else:
            if self.Phi is None:
                raise custom_error("required with kind: linear", "Phi")
            n = _check_square(self.Phi, key="Phi").shape[0]
        q = _check_square(self.Q, n, "Q")
        _check_spd(q, "Q", semi=True)
        return self

    @property
    def nx(self) -> int:
        if self.kind == "constant_velocity":
            return 2 * (self.dims or 2)
        return 3 if self.kind == "constant_acceleration" else len(self.Phi)

    @property
    def T_ns(self) -> int:
        return int(Decimal(repr(float(self.T))) * 10**9)

    def Phi_matrix(self) -> np.ndarray:
        if self.kind == "constant_acceleration":
            T = self.T
            return np.array([[1.0, T, T * T / 2.0], [0.0, 1.0, T], [0.0, 0.0, 1.0]])
        if self.kind == "constant_velocity":
            return np.kron(np.eye(self.nx // 2), np.array([[1.0, self.T], [0.0, 1.0]]))
        return np.array(self.Phi, dtype=float)

    def Q_matrix(self) -> np.ndarray:
        if self.kind == "constant_velocity":
            T = self.T
            axis = self.q * np.array([[T ** 3 / 3.0, T ** 2 / 2.0], [T ** 2 / 2.0, T]])
            return np.kron(np.eye(self.nx // 2), axis)
        return np.array(self.Q, dtype=float)


class Prior(StrictModel):
    """``x[0] ~ N(mean, cov)``."""

    mean: Vector
    cov: Matrix

    @model_validator(mode="after")
    def _check(self):
        p = _check_square(self.cov, key="cov")
        _check_spd(p, "cov", semi=False)
        if len(self.mean) != p.shape[0]:
            raise custom_error(f"has {len(self.mean)} entries but cov is "
                               f"{p.shape[0]} x {p.shape[0]}", "mean")
        return self

    def mean_vector(self) -> np.ndarray:
        return np.array(self.mean, dtype=float)

    def cov_matrix(self) -> np.ndarray:
        return np.array(self.cov, dtype=float)


def _linear_kind(value: Any) -> Any:
    if value is None or value == "linear":
        return "linear"
    raise custom_error(_unknown_kind(value))


class Sensor(StrictModel):
    """``y = H x + v``, ``v ~ N(0, R)`` (``kind: linear``, the default).

    ``kind`` is left out of ``to_dict`` (absent means linear), so files
    written before sensor kinds existed keep their hash.
    """

    name: Annotated[str, Field(strict=True, min_length=1)]
    kind: Annotated[Literal["linear"], BeforeValidator(_linear_kind), Field(exclude=True)] = "linear"
    H: Matrix
    R: Matrix

    @model_validator(mode="after")
    def _check(self):
        m = len(self.H)
        r = np.array(self.R, dtype=float)
        if r.shape != (m, m):
            raise custom_error(f"must be {m} x {m} (H has {m} row{'s' * (m != 1)}), "
                               f"got {r.shape[0]} x {r.shape[1]}", "R")
        _check_spd(r, "R", semi=False)
        return self

    @property
    def m(self) -> int:
        return len(self.H)

    def H_matrix(self) -> np.ndarray:
        return np.array(self.H, dtype=float)

    def R_matrix(self) -> np.ndarray:
        return np.array(self.R, dtype=float)


Sigma = Annotated[float, Field(strict=True, gt=0, le=MAX_MAGNITUDE, allow_inf_nan=False)]


class RadarSensorSpec(StrictModel):
    """A range/azimuth radar, used as a converted measurement (:mod:`dkfsim.model.sensors`).

    ``position`` [x, y] (m), ``sigma_range`` (m), ``sigma_azimuth`` (rad,
    below pi/4: a converted measurement means nothing beyond), ``state_index``
    the state components that are the Cartesian x and y (default [0, 2], the
    ``[x, vx, y, vy]`` of ``constant_velocity``).
    """

    name: Annotated[str, Field(strict=True, min_length=1)]
    kind: Literal["radar"]
    position: Vector
    sigma_range: Sigma
    sigma_azimuth: Sigma
    state_index: tuple[StrictInt, StrictInt] = (0, 2)

    @model_validator(mode="after")
    def _check(self):
        if len(self.position) != 2:
            raise custom_error(f"must be [x, y], got {len(self.position)} entries", "position")
        if self.sigma_azimuth >= np.pi / 4:
            raise custom_error(f"must be in radians and below pi/4, got {self.sigma_azimuth!r} "
                               "(1 degree = 0.0174533 rad)", "sigma_azimuth")
        return self

    @property
    def m(self) -> int:
        return 2

    def sensor_model(self, nx: int):
        from dkfsim.model.sensors import RadarSensor
        return RadarSensor(self.position, self.sigma_range, self.sigma_azimuth, nx,
                           self.state_index)


class _UnknownSensorKind(BaseModel):
    """Reports an unknown sensor ``kind`` before any key of the entry is checked."""

    @model_validator(mode="before")
    @classmethod
    def _fail(cls, data: Any) -> Any:
        raise custom_error(_unknown_kind(data.get("kind")), "kind")


def _unknown_kind(value: Any) -> str:
    return (f"unknown sensor kind {clip(value)}{suggest(value, SENSOR_KINDS)}; valid: "
            + ", ".join(SENSOR_KINDS))


def _sensor_tag(value: Any) -> str:
    kind = value.get("kind") if isinstance(value, dict) else getattr(value, "kind", None)
    if kind is None or kind in SENSOR_KINDS:
        return kind or "linear"
    return "unknown"


#: A scenario sensor: ``kind: linear`` (default) or ``kind: radar``.
SensorSpec = Annotated[Union[Annotated[Sensor, Tag("linear")],
                             Annotated[RadarSensorSpec, Tag("radar")],
                             Annotated[_UnknownSensorKind, Tag("unknown")]],
                       Discriminator(_sensor_tag)]


class Truth(StrictModel):
    """Truth from a recorded track instead of the model (:mod:`dkfsim.model.trajectory`).

    ``dataset`` names a shipped track (``cicv5g/arterial_n8_v70_run03``),
    ``file`` the user's own, resolved against the scenario file's folder
    (:mod:`dkfsim.core.datafiles`); it is read (and cached) when the scenario is
    validated, so a missing file or column is a validation error.
    """

    file: Annotated[str, Field(strict=True, min_length=1)] | None = None
    dataset: Annotated[str, Field(strict=True, min_length=1)] | None = None
    x_column: Annotated[str, Field(strict=True, min_length=1)] = "utmX(m)"
    y_column: Annotated[str, Field(strict=True, min_length=1)] = "utmY(m)"
    time_column: Annotated[str, Field(strict=True, min_length=1)] = "pub_time(ms)"
    time_unit: Literal["s", "ms", "us", "ns"] = "ms"
    origin: Literal["first", "none"] = "first"
    start: Annotated[float, Field(strict=True, ge=0, le=MAX_SECONDS, allow_inf_nan=False)] = 0.0
    resample: Literal["linear"] = "linear"
    #: Centred moving-average window (s) applied to the recorded positions; 0 = off.
    smooth: Annotated[float, Field(strict=True, ge=0, le=MAX_SECONDS, allow_inf_nan=False)] = 0.0

    _path: str | None = PrivateAttr(default=None)

    @model_validator(mode="after")
    def _load(self, info: ValidationInfo):
        from dkfsim.model import trajectory
        path, key = located(self.file, self.dataset, info)
        try:
            self._read(path)
        except trajectory.TrackError as err:
            raise custom_error(str(err), key if err.key == "file" else err.key) from None
        self._path = str(path)
        return self

    def _read(self, path):
        from dkfsim.model import trajectory
        return trajectory.read_track(path, self.time_column, self.x_column, self.y_column,
                                     self.time_unit)

    def track(self):
        """The :class:`dkfsim.model.trajectory.Track` (read once, then cached)."""
        return self._read(self._path)


class Topology(StrictModel):
    """How the sensors are linked (see :mod:`dkfsim.components.topology`)."""

    directed: StrictBool = False
    generator: Literal["path", "star", "balanced_tree", "random_tree", "ring",
                       "random_regular", "erdos_renyi", "edges"]
    params: dict[str, Any] = Field(default_factory=dict)
    edges: tuple[tuple[StrictInt, StrictInt], ...] | None = None

    @field_validator("params", mode="before")
    @classmethod
    def _params_none(cls, v):
        return {} if v is None else v


Probability = Annotated[float, Field(strict=True, ge=0, le=1, allow_inf_nan=False)]


class LinkSettings(StrictModel):
    """A link's latency and faults (see :mod:`dkfsim.components.faults`); ``None`` = no such fault."""

    latency: LatencyModel = Field(default_factory=Constant)
    loss: Probability = 0.0
    duplicate: Probability | None = None
    jitter: LatencyModel | None = None
    schedule: Schedule | None = None
    outages: tuple[Window, ...] | None = None


class LinkOverride(StrictModel):
    link: tuple[StrictInt, StrictInt]
    latency: LatencyModel | None = None
    loss: Probability | None = None
    duplicate: Probability | None = None
    jitter: LatencyModel | None = None
    schedule: Schedule | None = None
    outages: tuple[Window, ...] | None = None


class Links(StrictModel):
    default: LinkSettings = Field(default_factory=LinkSettings)
    overrides: tuple[LinkOverride, ...] = ()
    d_t: Annotated[int, Field(strict=True, ge=0)] | None = None


def _check_baseline(name: str) -> str:
    if name not in KNOWN_BASELINES:
        raise custom_error(f"unknown baseline {name!r}{suggest(name, KNOWN_BASELINES)}; "
                           f"valid baselines: {', '.join(KNOWN_BASELINES)}")
    return name


def _buffer_length(value: Any) -> Any:
    if isinstance(value, str) and value in ("auto", "paper"):
        return value
    if isinstance(value, int) and not isinstance(value, bool) and value >= 1:
        return value
    hint = suggest(value, ("auto", "paper")) if isinstance(value, str) else ""
    raise custom_error(f"must be 'auto', 'paper' or an integer >= 1, got {clip(value)}{hint}")


def _fusion_none(value: Any) -> Any:
    return "none" if value is None else value


# =========================================================================== scenario
class Scenario(StrictModel):
    """A validated, immutable scenario (see the module docstring)."""

    name: Annotated[str, Field(strict=True, min_length=1)] = "unnamed"
    seed: Annotated[int, Field(strict=True, ge=0)] = 0
    steps: Annotated[int, Field(strict=True, ge=1)] = 1000
    model: Model
    prior: Prior
    sensors: Annotated[tuple[SensorSpec, ...], Field(min_length=1)]
    topology: Topology
    links: Links = Field(default_factory=Links)
    protocol: Literal["tree", "flood"] = "tree"
    weights: Literal["unit", "paper"] = "unit"
    spanning_tree: StrictBool = False
    buffer_length: Annotated[Literal["auto", "paper"] | int, BeforeValidator(_buffer_length)] = "auto"
    fusion: Annotated[Literal["matrix", "diagonal", "none"], BeforeValidator(_fusion_none)] = "matrix"
    baselines: tuple[Annotated[str, AfterValidator(_check_baseline)], ...] = ("centralized",)
    #: Consensus rounds per tick of the ``ci_consensus`` baseline (0 = local filters).
    consensus_rounds: Annotated[int, Field(strict=True, ge=0)] = 1
    #: Truth from a recorded track instead of the model (:mod:`dkfsim.model.trajectory`).
    truth: Truth | None = None
    #: Sensor faults (crash windows), see :mod:`dkfsim.components.faults`.
    faults: Faults | None = None

    _source: str | None = PrivateAttr(default=None)
    _base_dir: str | None = PrivateAttr(default=None)
    # (key, graph, exchange graph or None); the key holds every field the graph
    # depends on, so a model_copy(update=...) never sees a stale graph.
    _cache: Any = PrivateAttr(default=None)

    # ------------------------------------------------------------------ validation
    @field_validator("sensors", mode="before")
    @classmethod
    def _sensor_mappings(cls, v):
        # Checked here so that the message names sensors.<i>, not the kind's union tag.
        if isinstance(v, (list, tuple)):
            for i, s in enumerate(v):
                if not isinstance(s, (dict, BaseModel)):
                    raise custom_error(f"must be a mapping, got {type(s).__name__} {s!r}", str(i))
        return v

    @field_validator("baselines", mode="after")
    @classmethod
    def _unique_baselines(cls, v):
        for i, name in enumerate(v):
            if name in v[:i]:
                raise custom_error(f"{name!r} is listed twice", str(i))
        return v

    @model_validator(mode="after")
    def _check_consistency(self):
        nx_ = self.model.nx
        if len(self.prior.mean) != nx_:
            raise custom_error(f"has {len(self.prior.mean)} entries but the state has "
                               f"{nx_} (model)", "prior.mean")
        if len(self.prior.cov) != nx_:
            raise custom_error(f"must be {nx_} x {nx_}, got {len(self.prior.cov)} x "
                               f"{len(self.prior.cov)}", "prior.cov")
        names: dict[str, int] = {}
        for i, s in enumerate(self.sensors):
            if s.kind == "radar":
                ix, iy = s.state_index
                if ix == iy or not (0 <= ix < nx_ and 0 <= iy < nx_):
                    raise custom_error(f"must be two different state indices in 0..{nx_ - 1} "
                                       f"(the position's x and y), got [{ix}, {iy}]",
                                       f"sensors.{i}.state_index")
            else:
                rows, cols = _shape(s.H)
                if cols != nx_:
                    raise custom_error(f"must have {nx_} columns (the state size), got "
                                       f"{rows} x {cols}", f"sensors.{i}.H")
            if s.name in names:
                raise custom_error(f"{s.name!r} is already the name of sensors.{names[s.name]}",
                                   f"sensors.{i}.name")
            names[s.name] = i
        if self.truth is not None:
            self._check_truth()
        if "ci_consensus" in self.baselines and self.consensus_rounds > 0 \
                and self.model.T_ns % self.consensus_rounds:
            raise custom_error(f"{self.consensus_rounds} rounds do not divide T = {self.model.T} s into "
                               f"whole nanoseconds (ci_consensus runs a round every T/rounds)",
                               "consensus_rounds")
        self._check_network()
        self._check_time_range()
        return self

    def _check_truth(self) -> None:
        if self.model.kind != "constant_velocity" or self.model.nx != 4:
            raise custom_error("a recorded track gives the state [x, vx, y, vy]: needs model "
                               "kind: constant_velocity with dims: 2", "truth")
        need = self.truth.start + self.steps * self.model.T
        have = self.truth.track().duration
        if need > have + 1e-9:
            named = (f"truth.dataset {self.truth.dataset}" if self.truth.dataset is not None
                     else f"truth.file {self.truth.file}")
            raise custom_error(
                f"the run needs {need:g} s of track (truth.start {self.truth.start:g} s + "
                f"{self.steps} steps x {self.model.T:g} s) but {named} covers {have:g} s; use at "
                f"most {int((have - self.truth.start) / self.model.T + 1e-9)} steps", "steps")

    def _check_network(self) -> None:
        top = self.topology
        if self.weights == "paper" and self.protocol == "flood":
            raise custom_error("'paper' weights are not defined for protocol: flood (the paper "
                               "weighs the messages of the tree exchange only); use weights: "
                               "unit, or protocol: tree", "weights")
        if self.protocol == "tree" and top.directed:
            raise custom_error("'tree' needs an undirected topology (topology.directed is "
                               "true); use protocol: flood on a directed graph", "protocol")
        if self.spanning_tree and top.directed:
            raise custom_error("a spanning tree needs an undirected topology "
                               "(topology.directed is true)", "spanning_tree")
        n = self.n
        try:
            graph = topo.build_graph(top, n, self.seed)
            topo.check_connected(graph)
        except topo.GraphSpecError as err:
            key = "topology." + err.key if err.key else "topology"
            hint = ""
            if top.generator in ("random_regular", "erdos_renyi") and "connected" in err.reason:
                hint = " (try another params.seed or a denser graph)"
            raise custom_error(err.reason + hint, key) from None
        if self.protocol == "tree" and not self.spanning_tree and not topo.is_tree(graph):
            raise custom_error(
                f"'tree' needs a tree but the topology has cycles ({n} nodes, "
                f"{graph.number_of_edges()} edges); set spanning_tree: true to run on a BFS "
                "spanning tree, or use protocol: flood", "protocol")
        for i, ov in enumerate(self.links.overrides):
            u, v = ov.link
            for node in (u, v):
                if not 0 <= node < n:
                    raise custom_error(f"node {node} is out of range 0..{n - 1}",
                                       f"links.overrides.{i}.link")
            if not graph.has_edge(u, v):
                what = "an arc" if graph.is_directed() else "an edge"
                raise custom_error(f"[{u}, {v}] is not {what} of the topology",
                                   f"links.overrides.{i}.link")
        if self.faults is not None:
            self.faults.check(n)
        self._cache = (self._graph_key(), graph, None)
        if self.buffer_length in ("auto", "paper") and self.resolved_d_t() is None:
            unbounded = sorted({name for u, v in self.exchange().arcs
                                for name in self.link_spec(u, v).unbounded_models(self.T_ns)})
            raise custom_error(
                f"{self.buffer_length!r} needs a delay bound, but latency model "
                f"{', '.join(unbounded)} is unbounded; set an explicit links.d_t (delay bound "
                "in steps) or an integer buffer_length", "buffer_length")

    def _check_time_range(self) -> None:
        """Every time the run can reach fits the int64 nanosecond clock (:data:`MAX_NS`)."""
        T_ns = self.T_ns
        limit = f"the {MAX_SECONDS:.4g} s (2^62 ns, about 146 years) an int64 nanosecond clock can hold"
        if (self.steps + 1) * T_ns > MAX_NS:
            most = MAX_NS // T_ns - 1
            fix = f"use at most {most} steps" if most >= 1 else "T itself is too long"
            raise custom_error(f"{self.steps} steps of T = {self.model.T:g} s reach "
                               f"{(self.steps + 1) * self.model.T:.4g} s of simulated time, beyond {limit}; "
                               f"{fix}", "steps")
        places = [("links.default", None)] + [(f"links.overrides.{i}", tuple(ov.link))
                                              for i, ov in enumerate(self.links.overrides)]
        for key, link in places:
            spec = self.link_spec(*link) if link is not None else self.link_spec(-1, -1)
            sup = spec.sup_ns(T_ns)
            if sup is not None and sup > MAX_NS:
                raise custom_error(f"the largest latency it can produce, {sup / 1e9:.4g} s (after "
                                   f"schedule factors and jitter), is beyond {limit}", key)
        d_t = self.resolved_d_t()
        if d_t is not None and d_t * T_ns > MAX_NS:
            raise custom_error(f"a delay bound of {d_t} steps of {self.model.T:g} s is beyond {limit}",
                               "links.d_t" if self.links.d_t is not None else "links")
        # L <= d_t (n - 1) + 1 (the diameter is below n): the exact L only when that bound is too large.
        if isinstance(self.buffer_length, int) or (d_t or 0) * (self.n - 1) * T_ns > MAX_NS:
            if self.resolved_buffer_length() * T_ns > MAX_NS:
                raise custom_error(f"L = {self.resolved_buffer_length()} rows of {self.model.T:g} s span "
                                   f"more than {limit}; use a smaller delay bound or buffer_length",
                                   "buffer_length")

    # ------------------------------------------------------------------ derived values
    @property
    def source(self) -> str | None:
        """The file this scenario was loaded from (None for a dict)."""
        return self._source

    @property
    def base_dir(self) -> str | None:
        """The folder relative ``file:`` paths resolved against (None: the working directory)."""
        return self._base_dir

    @property
    def nx(self) -> int:
        """State dimension."""
        return self.model.nx

    @property
    def n(self) -> int:
        """Number of sensors (= nodes)."""
        return len(self.sensors)

    @property
    def T_ns(self) -> int:
        """Sampling period in integer nanoseconds."""
        return self.model.T_ns

    def _graph_key(self) -> tuple:
        return (self.seed, self.n, self.topology.model_dump_json(), self.protocol,
                self.spanning_tree)

    def _cached(self) -> tuple:
        key = self._graph_key()
        if self._cache is None or self._cache[0] != key:
            graph = topo.build_graph(self.topology, self.n, self.seed)
            self._cache = (key, graph, None)
        return self._cache

    def graph(self) -> networkx.Graph | networkx.DiGraph:
        """A copy of the topology graph (nodes 0..n-1)."""
        return self._cached()[1].copy()

    def exchange(self) -> topo.ExchangeGraph:
        """The graph the protocol runs on (cached :func:`dkfsim.components.topology.exchange_graph`)."""
        key, graph, xg = self._cached()
        if xg is None:
            xg = topo.make_exchange(graph, self.protocol, self.spanning_tree)
            self._cache = (key, graph, xg)
        return xg

    def link_spec(self, u: int, v: int) -> LinkSpec:
        """Settings of the directed link ``u -> v``.

        The default merged with the last matching override; ``link: [u, v]``
        matches ``u -> v``, and also ``v -> u`` on an undirected topology.
        An override replaces the whole latency model, the loss, and each
        fault key it gives (duplicate, jitter, schedule, outages).
        """
        keys = ("latency", "loss", "duplicate", "jitter", "schedule", "outages")
        spec = {k: getattr(self.links.default, k) for k in keys}
        for ov in self.links.overrides:
            a, b = ov.link
            if (a, b) == (u, v) or (not self.topology.directed and (b, a) == (u, v)):
                spec.update({k: getattr(ov, k) for k in keys if getattr(ov, k) is not None})
        return LinkSpec(latency=spec["latency"], loss=float(spec["loss"]),
                        duplicate=float(spec["duplicate"] or 0.0), jitter=spec["jitter"],
                        schedule=tuple(spec["schedule"] or ()),
                        outages=tuple(spec["outages"] or ()))

    def resolved_d_t(self) -> int | None:
        """Delay bound in steps: ``links.d_t`` if set, else the largest
        ``bound_steps`` over the links the protocol uses (None if unbounded)."""
        if self.links.d_t is not None:
            return self.links.d_t
        return self.latency_bound_steps()

    def latency_bound_steps(self) -> int | None:
        """The largest per-hop delay in steps the links can produce (None if unbounded),
        whatever ``links.d_t`` assumes.  Without overrides every link has the
        default settings, so the exchange graph (which may need a costly
        spanning tree) is not built."""
        if not self.links.overrides:
            return self.link_spec(-1, -1).bound_steps(self.T_ns)
        bound = 0
        for u, v in self.exchange().arcs:
            b = self.link_spec(u, v).bound_steps(self.T_ns)
            if b is None:
                return None
            bound = max(bound, b)
        return bound

    def resolved_buffer_length(self) -> int:
        """The buffer length L (docs/design.md §4).

        ``auto``: ``d_t * d_g + 1``; ``paper``: ``max(d_t, 1)``; an integer: itself.
        """
        if isinstance(self.buffer_length, int):
            return self.buffer_length
        d_t = self.resolved_d_t()
        if d_t is None:  # excluded by validation
            raise ScenarioError("no delay bound", source=self.source, path="buffer_length")
        if self.buffer_length == "paper":
            return max(d_t, 1)
        return d_t * self.exchange().d_g + 1

    # ------------------------------------------------------------------ identity
    def to_dict(self) -> dict:
        """Plain data (lists, floats, str) that :func:`load_scenario` turns back
        into an equal scenario; ``source`` is not included."""
        return self.model_dump(mode="json", exclude_none=True)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Scenario):
            return NotImplemented
        return self.to_dict() == other.to_dict()

    def __hash__(self) -> int:
        return hash(scenario_hash(self))


def scenario_hash(scenario: Scenario) -> str:
    """sha256 hex digest of the canonical JSON of ``scenario.to_dict()``."""
    text = json.dumps(scenario.to_dict(), sort_keys=True, separators=(",", ":"),
                      ensure_ascii=True, allow_nan=False)
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


# =========================================================================== YAML
def _parse_yaml(text: str, source: str) -> Any:
    try:
        return parse_yaml(text)
    except yaml.YAMLError as err:
        raise ScenarioError(yaml_error_text(err), source=source) from None


# =========================================================================== overrides
_INDEX = re.compile(r"^-?\d+$")


def _apply_override(data: dict, text: str, source: str) -> str:
    """Apply one ``dotted.key=value`` to ``data`` in place; return the key."""
    if not isinstance(text, str) or "=" not in text:
        raise ScenarioError(f"bad override {clip(text)}: expected dotted.key=value "
                            "(e.g. links.default.latency.d_t=0)", source=source)
    key, _, raw = text.partition("=")
    key = key.strip()
    parts = key.split(".")
    if not key or any(p == "" for p in parts):
        raise ScenarioError(f"bad override {clip(text)}: empty key component", source=source)
    try:
        value = parse_yaml(raw) if raw.strip() else None
    except yaml.YAMLError as err:
        raise ScenarioError(f"bad override value {clip(raw)}: {yaml_error_text(err)}",
                            source=source, path=key) from None
    node: Any = data
    for depth, part in enumerate(parts):
        here = ".".join(parts[:depth + 1])
        last = depth == len(parts) - 1
        if isinstance(node, list):
            if not _INDEX.match(part):
                raise ScenarioError(f"override {clip(text)}: {parts[depth - 1] if depth else key} "
                                    f"is a list; {part!r} is not an index", source=source,
                                    path=here)
            idx = int(part)
            if not 0 <= idx < len(node):
                raise ScenarioError(f"override {clip(text)}: list index {idx} out of range "
                                    f"(the list has {len(node)} entries)", source=source,
                                    path=here)
            if last:
                node[idx] = value
            else:
                if node[idx] is None:
                    node[idx] = {}
                node = node[idx]
        elif isinstance(node, dict):
            if last:
                node[part] = value
            else:
                if node.get(part) is None:
                    node[part] = {}
                node = node[part]
        else:
            parent = ".".join(parts[:depth])
            raise ScenarioError(f"override {clip(text)}: {parent} is a scalar "
                                f"({clip(node)}); cannot set {part!r} inside it",
                                source=source, path=here)
    return key


def apply_overrides(data: dict, overrides: Sequence[str], source: str = "<dict>") -> dict:
    """Return a deep copy of ``data`` with the ``dotted.key=value`` overrides applied."""
    out = copy.deepcopy(data)
    for text in overrides:
        _apply_override(out, text, source)
    return out


# =========================================================================== errors
#: Tags pydantic puts in an error location for a member of a tagged union.
_UNION_TAGS = frozenset(LATENCY_MODELS) | {"linear", "radar", "unknown", "step", "ramp"}


def _loc_to_path(loc: tuple, data: Any) -> list[str]:
    """Dotted components of a pydantic ``loc``, dropping union tags."""
    parts: list[str] = []
    node = data
    for i, elem in enumerate(loc):
        last = i == len(loc) - 1
        if isinstance(node, dict) and elem in node:
            parts.append(str(elem))
            node = node[elem]
        elif isinstance(node, (list, tuple)) and isinstance(elem, int) and 0 <= elem < len(node):
            parts.append(str(elem))
            node = node[elem]
        elif (node is None or isinstance(node, dict)) and not last and elem in _UNION_TAGS:
            continue  # a union member's tag (e.g. 'uniform_steps'), not a key
        elif isinstance(elem, str) and (elem.startswith(("function-", "literal[", "int", "str"))
                                        and not last):
            continue
        else:
            parts.append(str(elem))
            node = None
    return parts


_LITERAL_FIELDS = {"generator": "generator", "protocol": "protocol", "weights": "weights",
                   "fusion": "fusion", "kind": "model kind"}
_LITERAL_VALUES = {"generator": topo.GENERATORS, "protocol": PROTOCOLS, "weights": WEIGHTS,
                   "fusion": FUSIONS, "kind": MODEL_KINDS}

_BOUND_WORDS = {"greater_than_equal": (">=", "ge"), "greater_than": (">", "gt"),
                "less_than_equal": ("<=", "le"), "less_than": ("<", "lt")}


def _reason(err: dict, path: list[str]) -> tuple[str, list[str]]:
    """Short message for one pydantic error, and the (maybe extended) path."""
    etype = err["type"]
    ctx = err.get("ctx") or {}
    inp = err.get("input")
    field = path[-1] if path else ""
    if etype in ("dkfsim", "unknown_key"):
        return str(ctx.get("reason", err["msg"])), path
    if etype == "missing":
        return "required key is missing", path
    if etype == "extra_forbidden":
        return "unknown key", path
    if etype == "union_tag_invalid":
        names = list(LATENCY_MODELS)
        tag = ctx.get("tag")
        return (f"unknown latency model {tag!r}{suggest(tag, names)}; valid models: "
                + ", ".join(names)), path + ["model"]
    if etype == "union_tag_not_found":
        return "missing key 'model' (one of: " + ", ".join(LATENCY_MODELS) + ")", path
    if etype == "literal_error" and field in _LITERAL_FIELDS:
        valid = _LITERAL_VALUES[field]
        return (f"unknown {_LITERAL_FIELDS[field]} {clip(inp)}{suggest(inp, valid)}; valid: "
                + ", ".join(valid)), path
    if etype in _BOUND_WORDS:
        word, k = _BOUND_WORDS[etype]
        bound = ctx.get(k)
        why = {MAX_SECONDS: f"{MAX_SECONDS:.10g} s = 2^62 ns, the span of the int64 nanosecond clock",
               MAX_MAGNITUDE: f"{MAX_MAGNITUDE:g}, so that products stay within float64"}
        if bound in why:
            return f"must be {word} {why[bound]}; got {clip(inp)}", path
        return f"must be {word} {bound}, got {clip(inp)}", path
    if etype in ("model_type", "model_attributes_type", "dict_type"):
        return f"must be a mapping, got {type(inp).__name__} {clip(inp)}", path
    if etype in ("int_type", "int_from_float", "int_parsing"):
        return f"must be an integer, got {clip(inp)}", path
    if etype in ("float_type", "float_parsing"):
        return f"must be a number, got {clip(inp)}", path
    if etype == "bool_type":
        return f"must be true or false, got {clip(inp)}", path
    if etype in ("tuple_type", "list_type"):
        return f"must be a list, got {type(inp).__name__} {clip(inp)}", path
    if etype in ("string_type",):
        return f"must be a string, got {clip(inp)}", path
    if etype == "finite_number":
        return f"must be a finite number, got {clip(inp)}", path
    if etype in ("too_short", "too_long") and field == "sensors":
        return "at least one sensor is required", path
    msg = " ".join(str(err["msg"]).split())
    if inp is not None and not isinstance(inp, (dict, list, tuple)):
        msg += f" (got {clip(inp)})"
    return msg, path


def _convert(exc: ValidationError, data: Any, source: str,
             override_keys: Mapping[str, str]) -> ScenarioError:
    items = []
    for err in exc.errors():
        loc = tuple(err["loc"])
        extra = (err.get("ctx") or {}).get("key") if err["type"] in ("dkfsim", "unknown_key") \
            else None
        if extra:  # the model pointed at one of its own keys: walk it with the rest
            loc = loc + tuple(str(extra).split("."))
        path = _loc_to_path(loc, data)
        reason, path = _reason(err, path)
        dotted = ".".join(path)
        for key, text in override_keys.items():
            if dotted == key or dotted.startswith(key + "."):
                reason += f" (set by override {clip(text)})"
                break
        else:
            for key, text in override_keys.items():
                if dotted and key.startswith(dotted + "."):
                    reason += f" (after override {clip(text)})"
                    break
        items.append((dotted, reason))
    first_path, first_reason = items[0]
    message = first_reason
    for dotted, reason in items[1:]:
        message += f"; {dotted}: {reason}" if dotted else f"; {reason}"
    return ScenarioError(message, source=source, path=first_path or None)


# =========================================================================== loading
def load_scenario(source: str | os.PathLike | Mapping | Scenario,
                  overrides: Sequence[str] = (), *, base_dir: str | os.PathLike | None = None) -> Scenario:
    """Load, override and validate a scenario.

    ``source`` is a path to a YAML file, a mapping, or a Scenario (re-validated
    from its ``to_dict`` so that overrides apply).  ``overrides`` are
    ``dotted.key=value`` strings, the value parsed as YAML, applied to the raw
    mapping before validation (``sensors.0.R=[[2.0]]``, ``links.d_t=5``).
    ``base_dir`` is where the relative ``file:`` paths of a mapping resolve
    (default: the working directory); a file's own folder is used for a
    path, and a Scenario keeps the folder it was loaded with.
    Raises :class:`ScenarioError` on any problem.
    """
    if isinstance(overrides, str):
        overrides = (overrides,)
    path: str | None = None
    if isinstance(source, Scenario):
        label = source.source or "<dict>"
        path = source.source
        base_dir = source.base_dir
        data: Any = source.to_dict()
    elif isinstance(source, (str, os.PathLike)):
        label = path = os.fspath(source)
        try:
            text = read_text(path, limit=MAX_YAML_BYTES, what="scenario file")
        except DkfsimError as err:
            raise ScenarioError(str(err)) from None
        data = _parse_yaml(text, label)
    elif isinstance(source, Mapping):
        label = "<dict>"
        try:
            check_plain_data(source)
        except DkfsimError as err:
            raise ScenarioError(str(err), source=label) from None
        data = copy.deepcopy(dict(source))
    else:
        raise TypeError(f"load_scenario needs a path, a mapping or a Scenario, "
                        f"got {type(source).__name__}")
    if data is None:
        raise ScenarioError("empty file: expected a mapping of scenario keys", source=label)
    if not isinstance(data, dict):
        raise ScenarioError(f"top level must be a mapping of scenario keys, got "
                            f"{type(data).__name__}", source=label)
    if "scenario" in data and ("grid" in data or "runs" in data) and "sensors" not in data:
        raise ScenarioError("this is a sweep file (it names a scenario and a grid), not a scenario: "
                            "run it with 'dkfsim sweep'", source=label)
    override_keys: dict[str, str] = {}
    for text in overrides:
        key = _apply_override(data, text, label)
        override_keys[key] = text
    if "name" not in data and path is not None:
        data["name"] = Path(path).stem
    if path is not None and base_dir is None:
        # Relative data files (traces, tracks) resolve against the file's folder.
        base_dir = Path(path).resolve().parent
    base_dir = None if base_dir is None else str(base_dir)
    try:
        scenario = Scenario.model_validate(data, context={"base_dir": base_dir})
    except ValidationError as exc:
        raise _convert(exc, data, label, override_keys) from None
    scenario._source = path
    scenario._base_dir = base_dir
    return scenario

"""The target dynamics and the prior of a scenario: its ``model`` and ``prior`` keys.

:class:`Model` (constant acceleration, constant velocity or a linear ``Phi``, ``Q``) and
:class:`Prior` are validated parameter models of :mod:`dkfsim.config.schema`;
:func:`component_names` names the state components everywhere.  See docs/design.md.
"""

from __future__ import annotations

from decimal import Decimal
from typing import Annotated, Literal

import numpy as np
from pydantic import Field, model_validator

from dkfsim.core.params import (
    MAX_MAGNITUDE,
    MAX_SECONDS,
    Matrix,
    StrictModel,
    Vector,
    check_spd,
    check_square,
    custom_error,
)

#: Units of the constant-acceleration model's components (matplotlib mathtext), for axis labels.
CA_UNITS = {"position": "m", "velocity": "m/s", "acceleration": "m/s$^2$"}
#: Units of every component name :func:`component_names` gives a kinematic model (constant
#: acceleration, or constant velocity on 1-3 axes: ``x, vx, y, vy, ...``); lengths in metres.
KINEMATIC_UNITS = {**CA_UNITS, **{a: "m" for a in "xyz"}, **{"v" + a: "m/s" for a in "xyz"}}


def component_units(components, kind: str | None = None) -> list[str]:
    """The unit of each state component (mathtext), "" where the model has none: the names of a
    kinematic model (:data:`KINEMATIC_UNITS`) when ``components`` are exactly those
    :func:`component_names` gives it; ``kind`` None (a sweep, which stores only the names)
    accepts any such set."""
    comps = list(components)
    kinds = ("constant_acceleration", "constant_velocity") if kind is None else (kind,)
    if any(comps == component_names(k, len(comps)) for k in kinds if k != "linear"):
        return [KINEMATIC_UNITS.get(c, "") for c in comps]
    return [""] * len(comps)


def state_text(components) -> str:
    """``state [x, vx, y, vy]``: the order of the state vector, for figure and table captions."""
    return "state [" + ", ".join(map(str, components)) + "]"


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
            n = check_square(self.Phi, key="Phi").shape[0]
        q = check_square(self.Q, n, "Q")
        check_spd(q, "Q", semi=True)
        return self

    @property
    def nx(self) -> int:
        if self.kind == "constant_velocity":
            return 2 * (self.dims or 2)
        if self.kind == "constant_acceleration":
            return 3
        assert self.Phi is not None            # (required with kind: linear, checked above)
        return len(self.Phi)

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
        p = check_square(self.cov, key="cov")
        check_spd(p, "cov", semi=False)
        if len(self.mean) != p.shape[0]:
            raise custom_error(f"has {len(self.mean)} entries but cov is "
                               f"{p.shape[0]} x {p.shape[0]}", "mean")
        return self

    def mean_vector(self) -> np.ndarray:
        return np.array(self.mean, dtype=float)

    def cov_matrix(self) -> np.ndarray:
        return np.array(self.cov, dtype=float)


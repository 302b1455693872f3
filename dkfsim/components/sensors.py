"""Sensor kinds: the parameters of each kind of sensor a scenario lists.

A scenario's ``sensors`` entry is validated by the parameter model its
``kind`` names in :data:`~dkfsim.core.registry.SENSOR_KINDS` (``linear``
when absent); :mod:`dkfsim.model.sensors` registers what simulates each kind.

``linear``: ``y = H x + v``, ``v ~ N(0, R)``.  ``radar``: range and azimuth
of the target from ``position``, used as a converted Cartesian measurement
(docs/radar.md says why, and not an EKF).
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

import numpy as np
from pydantic import BeforeValidator, Field, model_validator

from dkfsim.core.params import MAX_MAGNITUDE, Matrix, Name, StrictInt, StrictModel, Vector, check_spd, custom_error
from dkfsim.core.registry import SENSOR_KINDS


class SensorParams(StrictModel):
    """Keys every sensor has: its ``name`` (unique) and ``kind``."""

    name: Name
    kind: str

    @property
    def m(self) -> int:
        """Size of one measurement."""
        raise NotImplementedError


def _linear_kind(value: Any) -> Any:
    return "linear" if value is None else value


class LinearSensorParams(SensorParams):
    """``y = H x + v``, ``v ~ N(0, R)``: the default kind.

    ``kind`` is left out of ``to_dict`` (absent means linear), so files
    written before sensor kinds existed keep their hash.
    """

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
        check_spd(r, "R", semi=False)
        return self

    @property
    def m(self) -> int:
        return len(self.H)

    def check(self, nx: int, key: str) -> None:
        """Cross-check against the state size (called by the scenario's validation)."""
        rows, cols = len(self.H), len(self.H[0])
        if cols != nx:
            raise custom_error(f"must have {nx} columns (the state size), got {rows} x {cols}", f"{key}.H")

    def H_matrix(self) -> np.ndarray:
        return np.array(self.H, dtype=float)

    def R_matrix(self) -> np.ndarray:
        return np.array(self.R, dtype=float)


Sigma = Annotated[float, Field(strict=True, gt=0, le=MAX_MAGNITUDE, allow_inf_nan=False)]


class RadarSensorParams(SensorParams):
    """A range/azimuth radar, used as a converted measurement.

    ``position`` [x, y] (m), ``sigma_range`` (m), ``sigma_azimuth`` (rad,
    below pi/4: a converted measurement means nothing beyond), ``state_index``
    the state components that are the Cartesian x and y (default [0, 2], the
    ``[x, vx, y, vy]`` of ``constant_velocity``).
    """

    kind: Literal["radar"] = "radar"
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

    def check(self, nx: int, key: str) -> None:
        ix, iy = self.state_index
        if ix == iy or not (0 <= ix < nx and 0 <= iy < nx):
            raise custom_error(f"must be two different state indices in 0..{nx - 1} "
                               f"(the position's x and y), got [{ix}, {iy}]", f"{key}.state_index")


SENSOR_KINDS.add("linear", params=LinearSensorParams)
SENSOR_KINDS.add("radar", params=RadarSensorParams)

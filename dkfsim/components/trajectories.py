"""Vehicle trajectories: where a moving node is at any instant (issue 23).

A trajectory is a mapping whose ``kind`` key names it; the ``mobility:`` key
of a scenario gives one per vehicle.  Every kind offers
``positions(t_s) -> (len(t), 2)`` and ``velocities(t_s) -> (len(t), 2)``:
metres and metres per second in the plane, for run times ``t_s`` in seconds
(0 = the start of the run).  Times may be in any order and repeat.

``constant_velocity {start: [x, y], velocity: [vx, vy]}``
    ``start + velocity * t``.
``waypoints {points: [[t, x, y], ...]}``
    straight lines between the points (times strictly increasing); the
    vehicle waits at the first point before its time and stays at the last
    point after it (velocity 0 there).
``track {dataset | file, time_offset, offset, along, ...}``
    a recorded drive (a shipped CICV5G UTM track), shifted per vehicle.
``sumo_fcd {file, vehicle, ...}``
    one vehicle of a SUMO floating-car-data file.

Between samples every kind is piecewise linear; its velocity is the slope
of the segment holding ``t`` (the later one at a sample time) and 0 outside
the samples, so ``velocities`` is the derivative of ``positions`` wherever
that exists.  A new kind is one more registered subclass of
:class:`TrajectoryParams` (docs/trajectories.md).
"""

from __future__ import annotations

from typing import Annotated, Literal

import numpy as np
from pydantic import AfterValidator, PrivateAttr, TypeAdapter, model_validator
from typing_extensions import override

from dkfsim.core.params import Matrix, StrictModel, Vector, custom_error, registered
from dkfsim.core.registry import TRAJECTORIES


def _two(point: tuple[float, ...]) -> tuple[float, ...]:
    if len(point) != 2:
        raise custom_error(f"must be two numbers [x, y] (metres), got {len(point)}")
    return point


#: A point or vector of the plane, ``[x, y]``.
Point = Annotated[Vector, AfterValidator(_two)]


def run_times(t_s) -> np.ndarray:
    """``t_s`` as a 1-d float array of finite seconds (ValueError otherwise)."""
    t = np.atleast_1d(np.asarray(t_s, dtype=float))
    if t.ndim != 1:
        raise ValueError(f"times must be a 1-d array, got shape {t.shape}")
    if not np.isfinite(t).all():
        raise ValueError("times must be finite")
    return t


class TrajectoryParams(StrictModel):
    """Interface of every trajectory kind (see the module docstring)."""

    kind: str

    def positions(self, t_s) -> np.ndarray:
        """Positions (m) at run times ``t_s`` (s): shape ``(len(t), 2)``."""
        raise NotImplementedError

    def velocities(self, t_s) -> np.ndarray:
        """Velocities (m/s) at run times ``t_s`` (s): shape ``(len(t), 2)``."""
        raise NotImplementedError


@TRAJECTORIES.register("constant_velocity")
class ConstantVelocity(TrajectoryParams):
    """A straight line at constant speed: ``start + velocity * t``."""

    kind: Literal["constant_velocity"] = "constant_velocity"
    start: Point = (0.0, 0.0)
    velocity: Point = (0.0, 0.0)

    @override
    def positions(self, t_s):
        t = run_times(t_s)
        return np.asarray(self.start) + t[:, None] * np.asarray(self.velocity)

    @override
    def velocities(self, t_s):
        return np.tile(np.asarray(self.velocity, dtype=float), (len(run_times(t_s)), 1))


class Polyline:
    """Positions known at increasing times, linear in between, held outside.

    ``t`` (N,) strictly increasing seconds, ``xy`` (N, 2) metres.  The shared
    evaluator of ``waypoints``, ``track`` and ``sumo_fcd``.
    """

    __slots__ = ("t", "xy", "slopes")

    def __init__(self, t: np.ndarray, xy: np.ndarray):
        self.t = np.asarray(t, dtype=float)
        self.xy = np.asarray(xy, dtype=float).reshape(len(self.t), 2)
        if len(self.t) > 1:
            self.slopes = np.diff(self.xy, axis=0) / np.diff(self.t)[:, None]
        else:
            self.slopes = np.zeros((0, 2))

    def positions(self, t: np.ndarray) -> np.ndarray:
        # np.interp holds the end values outside [t[0], t[-1]]: the documented hold.
        return np.column_stack([np.interp(t, self.t, self.xy[:, 0]), np.interp(t, self.t, self.xy[:, 1])])

    def velocities(self, t: np.ndarray) -> np.ndarray:
        seg = np.searchsorted(self.t, t, side="right") - 1      # segment [t_k, t_k+1) holding t
        inside = (seg >= 0) & (seg < len(self.slopes))
        out = np.zeros((len(t), 2))
        out[inside] = self.slopes[seg[inside]]
        return out


@TRAJECTORIES.register("waypoints")
class Waypoints(TrajectoryParams):
    """Straight lines between timed points ``[t, x, y]``; held before the first and after the last."""

    kind: Literal["waypoints"] = "waypoints"
    points: Matrix

    _line: Polyline | None = PrivateAttr(default=None)

    @model_validator(mode="after")
    def _check(self):
        pts = np.asarray(self.points, dtype=float)
        if pts.shape[1] != 3:
            raise custom_error(f"each point must be [t, x, y] (s, m, m), got rows of {pts.shape[1]} "
                               "numbers", "points")
        step = np.diff(pts[:, 0])
        if (step <= 0).any():
            k = int(np.nonzero(step <= 0)[0][0])
            raise custom_error(f"times must be strictly increasing: point {k + 2} (t = "
                               f"{float(pts[k + 1, 0])!r}) follows point {k + 1} (t = "
                               f"{float(pts[k, 0])!r})", "points")
        self._line = Polyline(pts[:, 0], pts[:, 1:])
        return self

    def polyline(self) -> Polyline:
        """The points as a :class:`Polyline`."""
        assert self._line is not None
        return self._line

    @override
    def positions(self, t_s):
        return self.polyline().positions(run_times(t_s))

    @override
    def velocities(self, t_s):
        return self.polyline().velocities(run_times(t_s))


#: The field type of a trajectory in a scenario (any registered kind).
Trajectory = registered(TrajectoryParams, TRAJECTORIES)


def parse_trajectory(data: dict | TrajectoryParams, base_dir=None) -> TrajectoryParams:
    """Validate a mapping such as ``{"kind": "constant_velocity", "velocity": [10, 0]}``.

    ``base_dir`` is where a relative ``file`` is looked up (default: the
    working directory).  Raises pydantic's ``ValidationError`` on bad input.
    """
    if isinstance(data, TrajectoryParams):
        return data
    return TypeAdapter(Trajectory).validate_python(data, context={"base_dir": base_dir})

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
``road {spacing, lanes, lane_width, speed, start}``
    vehicles equally spaced on a straight road, placed by their number (vehicle ``i``
    ``(i // lanes) * spacing`` m along it, on lane ``i % lanes``).

Between samples every kind is piecewise linear; its velocity is the slope
of the segment holding ``t`` (the later one at a sample time) and 0 outside
the samples, so ``velocities`` is the derivative of ``positions`` wherever
that exists.  A new kind is one more registered subclass of
:class:`TrajectoryParams` (docs/trajectories.md).
"""

from __future__ import annotations

import difflib
from typing import Annotated, Literal

import numpy as np
from pydantic import AfterValidator, Field, PrivateAttr, TypeAdapter, ValidationInfo, model_validator
from typing_extensions import override

from dkfsim.components.fcd import read_fcd, unbounded_segment
from dkfsim.components.latency import located
from dkfsim.components.truth import TIME_UNITS, TrackError, read_track
from dkfsim.core.datafiles import DataFileError, read_table
from dkfsim.core.errors import DkfsimError
from dkfsim.core.files import clip, printable
from dkfsim.core.params import (
    MAX_SECONDS,
    Matrix,
    StrictModel,
    Text,
    Vector,
    custom_error,
    registered,
)
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

    def present(self, t_s) -> np.ndarray:
        """Whether the vehicle is on the road at run times ``t_s`` (bool, ``len(t)``): always,
        but for a kind that knows when it enters and leaves (``sumo_fcd``).  A spatial radio
        keeps a bystander that is not on the road off the air (docs/radio.md)."""
        return np.ones(len(run_times(t_s)), dtype=bool)

    def for_node(self, node: int) -> TrajectoryParams:  # noqa: ARG002  (a kind may place by number)
        """The trajectory of vehicle ``node`` when this one is given to it (a kind that places
        each vehicle by its number, ``road``, answers its own; every other kind, itself)."""
        return self


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
            with np.errstate(all="ignore"):     # (a step too fast for a float: unbounded(), refused by the kinds)
                self.slopes = np.diff(self.xy, axis=0) / np.diff(self.t)[:, None]
        else:
            self.slopes = np.zeros((0, 2))

    def unbounded(self) -> int | None:
        """The first segment whose speed is beyond any float, or None
        (:func:`~dkfsim.components.fcd.unbounded_segment`)."""
        return unbounded_segment(self.t, self.xy)

    def __eq__(self, other: object) -> bool:
        # Models holding a polyline compare equal when their samples are (pydantic compares
        # private attributes too): a scenario validated twice equals itself.
        return isinstance(other, Polyline) and np.array_equal(self.t, other.t) and np.array_equal(self.xy, other.xy)

    __hash__ = None  # type: ignore[assignment]

    def positions(self, t: np.ndarray) -> np.ndarray:
        # np.interp holds the end values outside [t[0], t[-1]]: the documented hold.
        return np.column_stack([np.interp(t, self.t, self.xy[:, 0]), np.interp(t, self.t, self.xy[:, 1])])

    def velocities(self, t: np.ndarray) -> np.ndarray:
        seg = np.searchsorted(self.t, t, side="right") - 1      # segment [t_k, t_k+1) holding t
        inside = (seg >= 0) & (seg < len(self.slopes))
        out = np.zeros((len(t), 2))
        out[inside] = self.slopes[seg[inside]]
        return out


class SampledTrajectory(TrajectoryParams):
    """A kind known at sample times (a :class:`Polyline` built when validated)."""

    _line: Polyline | None = PrivateAttr(default=None)

    def polyline(self) -> Polyline:
        """The samples as a :class:`Polyline` (on the samples' own clock)."""
        assert self._line is not None
        return self._line

    def sample_times(self, t: np.ndarray) -> np.ndarray:
        """The samples' clock at run times ``t`` (the same, unless the kind shifts it)."""
        return t

    def displacement(self) -> np.ndarray:
        """What is added to every position (m)."""
        return np.zeros(2)

    @override
    def positions(self, t_s):
        return self.polyline().positions(self.sample_times(run_times(t_s))) + self.displacement()

    @override
    def velocities(self, t_s):
        return self.polyline().velocities(self.sample_times(run_times(t_s)))


@TRAJECTORIES.register("road")
class Road(TrajectoryParams):
    """Vehicles equally spaced on a straight road, lane by lane, at one speed (the analytic radio
    models' highway).

    Vehicle ``i`` on lane ``i % lanes`` (lanes ``lane_width`` m apart), ``(i // lanes) * spacing`` m along
    the road from ``start``, all driving at ``speed`` m/s along x.  Given as ``default``, it
    places every vehicle by its number."""

    kind: Literal["road"] = "road"
    spacing: Annotated[float, Field(strict=True, gt=0, le=1e6, allow_inf_nan=False)]
    lanes: Annotated[int, Field(strict=True, ge=1, le=100)] = 1
    lane_width: Annotated[float, Field(strict=True, ge=0, le=100, allow_inf_nan=False)] = 4.0
    speed: Annotated[float, Field(strict=True, ge=-1e3, le=1e3, allow_inf_nan=False)] = 0.0
    start: Point = (0.0, 0.0)

    @override
    def for_node(self, node: int) -> TrajectoryParams:
        x0, y0 = self.start
        return ConstantVelocity(start=(x0 + (node // self.lanes) * self.spacing, y0 + (node % self.lanes) * self.lane_width),
                                velocity=(self.speed, 0.0))

    @override
    def positions(self, t_s):
        return self.for_node(0).positions(t_s)

    @override
    def velocities(self, t_s):
        return self.for_node(0).velocities(t_s)


@TRAJECTORIES.register("waypoints")
class Waypoints(SampledTrajectory):
    """Straight lines between timed points ``[t, x, y]``; held before the first and after the last."""

    kind: Literal["waypoints"] = "waypoints"
    points: Matrix

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
        line = Polyline(pts[:, 0], pts[:, 1:])
        k = line.unbounded()
        if k is not None:
            raise custom_error(f"the vehicle moves from point {k + 1} (t = {float(pts[k, 0])!r}) to point "
                               f"{k + 2} (t = {float(pts[k + 1, 0])!r}) at a speed beyond any number (the "
                               "times are too close for the distance)", "points")
        self._line = line
        return self


#: A signed time shift (s) or distance (m).
Shift = Annotated[float, Field(strict=True, ge=-MAX_SECONDS, le=MAX_SECONDS, allow_inf_nan=False)]


class ArcPath:
    """A :class:`Polyline` re-parametrised by distance travelled: where the vehicle is
    ``along`` metres ahead of (negative: behind) its recorded position at a time.

    The path is the polyline's points with zero-length steps removed, indexed by
    cumulative distance ``s``; beyond either end the vehicle is held there.
    """

    __slots__ = ("line", "s_t", "s", "xy", "tangents")

    def __init__(self, line: Polyline):
        self.line = line
        with np.errstate(all="ignore"):      # (a path beyond any float: not finite(), refused by the track)
            step = np.hypot(*np.diff(line.xy, axis=0).T)
            self.s_t = np.concatenate([[0.0], np.cumsum(step)])     # distance travelled at each sample
        keep = np.concatenate([[True], step > 0])
        self.s, self.xy = self.s_t[keep], line.xy[keep]
        seg = np.diff(self.xy, axis=0)
        self.tangents = seg / np.hypot(*seg.T)[:, None] if len(seg) else np.zeros((0, 2))

    def finite(self) -> bool:
        """Whether the distance travelled along the whole path is a finite number."""
        return bool(np.isfinite(self.s_t[-1]))

    def __eq__(self, other: object) -> bool:
        return isinstance(other, ArcPath) and self.line == other.line

    __hash__ = None  # type: ignore[assignment]

    def positions(self, t: np.ndarray, along: float) -> np.ndarray:
        s = np.interp(t, self.line.t, self.s_t) + along
        return np.column_stack([np.interp(s, self.s, self.xy[:, 0]), np.interp(s, self.s, self.xy[:, 1])])

    def velocities(self, t: np.ndarray, along: float) -> np.ndarray:
        speed = np.hypot(*self.line.velocities(t).T)
        s = np.interp(t, self.line.t, self.s_t) + along
        seg = np.searchsorted(self.s, s, side="right") - 1
        inside = (seg >= 0) & (seg < len(self.tangents))
        out = np.zeros((len(t), 2))
        out[inside] = self.tangents[seg[inside]] * speed[inside, None]
        return out


@TRAJECTORIES.register("track")
class RecordedTrack(TrajectoryParams):
    """A recorded drive (a shipped CICV5G track or a file), shifted in time and space per vehicle."""

    kind: Literal["track"] = "track"
    file: Text | None = None
    dataset: Text | None = None
    x_column: Text = "utmX(m)"
    y_column: Text = "utmY(m)"
    time_column: Text = "pub_time(ms)"
    time_unit: Literal["s", "ms", "us", "ns"] = "ms"
    #: Seconds the vehicle runs behind the recording: at run time t it is where the
    #: recorded car was at t - time_offset (negative: ahead).
    time_offset: Shift = 0.0
    #: Metres along the recorded path ahead of the (time-shifted) recorded car; negative: behind.
    along: Shift = 0.0
    #: A fixed displacement added to every position (m).
    offset: Point = (0.0, 0.0)
    #: The column :meth:`sinr_db` reads (the cellular link quality the car saw).
    sinr_column: Text = "sinr(db)"

    _path: str | None = PrivateAttr(default=None)
    _arc: ArcPath | None = PrivateAttr(default=None)

    @model_validator(mode="after")
    def _load(self, info: ValidationInfo):
        path, key = located(self.file, self.dataset, info)
        try:
            track = read_track(path, self.time_column, self.x_column, self.y_column, self.time_unit)
        except TrackError as err:
            raise custom_error(str(err), key if err.key == "file" else err.key) from None
        line = Polyline(track.t, np.column_stack([track.x, track.y]))
        k = line.unbounded()
        if k is not None:
            raise custom_error(f"{path.name}: the track moves from time {float(line.t[k])!r} s to "
                               f"{float(line.t[k + 1])!r} s (from its first row) at a speed beyond any "
                               "number (the times are too close for the distance)", key)
        arc = ArcPath(line)
        if not arc.finite():
            raise custom_error(f"{path.name}: the track's path is longer than any number of metres "
                               "(its coordinates are too far apart)", key)
        self._path = str(path)
        self._arc = arc
        return self

    def arc(self) -> ArcPath:
        """The recorded path (read once when the scenario is validated)."""
        assert self._arc is not None
        return self._arc

    def duration(self) -> float:
        """Seconds from the track's first sample to its last."""
        t = self.arc().line.t
        return float(t[-1] - t[0])

    @override
    def positions(self, t_s):
        t = run_times(t_s) - self.time_offset
        return self.arc().positions(t, self.along) + np.asarray(self.offset)

    @override
    def velocities(self, t_s):
        return self.arc().velocities(run_times(t_s) - self.time_offset, self.along)

    def sinr_db(self, t_s) -> np.ndarray:
        """The recorded SINR (dB) at run times ``t_s``: the last row at or before the
        vehicle's track time (the first row's before it).  Follows ``time_offset``
        (the drive's clock), not ``along``."""
        times, values = self.sinr_series()
        return _held(times, values, run_times(t_s) - self.time_offset)

    def sinr_function(self, speed: float = 1.0) -> "SinrAt":
        """:meth:`sinr_db` at one run time ``t`` evaluated at ``speed * t`` (:class:`SinrAt`)."""
        return SinrAt(self, float(speed))

    def sinr_series(self) -> tuple[np.ndarray, np.ndarray]:
        """The track's ``(times, SINR)`` column (read from its file)."""
        try:
            return sampled_column(self._path, self.time_column, self.sinr_column, self.time_unit)
        except DataFileError as err:
            raise DkfsimError(f"trajectory track {self._path}: sinr_column: {err}") from None


class SinrAt:
    """A track's recorded SINR at one run time ``t``, read at ``speed * t``: the column is read at
    the first call (a track that is never asked needs none) and kept, as a network asks once per
    packet.  A class, not a closure, so that a Monte Carlo's shared plan pickles to its worker
    processes (issue 34: ``dkfsim montecarlo scenarios/mobility_convoy.yaml --jobs 2`` stopped with
    a traceback)."""

    def __init__(self, track: "RecordedTrack", speed: float):
        self.track, self.speed = track, speed
        self.series: tuple[np.ndarray, np.ndarray] | None = None

    def __call__(self, t: float):
        if self.series is None:
            self.series = self.track.sinr_series()
        times, values = self.series
        return _held(times, values, np.asarray([t * self.speed]) - self.track.time_offset)[0]


def _held(times: np.ndarray, values: np.ndarray, t: np.ndarray) -> np.ndarray:
    """``values`` of the last sample at or before each ``t`` (the first one's before it)."""
    return values[np.clip(np.searchsorted(times, t, side="right") - 1, 0, len(times) - 1)]


def sampled_column(path, time_column: str, column: str, time_unit: str) -> tuple[np.ndarray, np.ndarray]:
    """``(t, values)`` of one numeric column of a track file, sorted by time, ``t`` in
    seconds from the first row.  Raises :class:`DataFileError` naming the line of a problem."""
    table = read_table(path)
    key = (str(table.path), id(table), time_column, column, time_unit)
    if key not in _COLUMNS:
        tcol, vcol = table.column_index(time_column), table.column_index(column)
        t = np.array([v for _, v in table.floats(tcol)])
        v = np.array([v for _, v in table.floats(vcol)])
        if not (np.isfinite(t).all() and np.isfinite(v).all()):
            raise DataFileError(f"{table.path.name}: {clip(column)} and {clip(time_column)} must be finite")
        order = np.argsort(t, kind="stable")
        _COLUMNS[key] = ((t[order] - t[order[0]]) * TIME_UNITS[time_unit], v[order])
    return _COLUMNS[key]


_COLUMNS: dict[tuple, tuple[np.ndarray, np.ndarray]] = {}


@TRAJECTORIES.register("sumo_fcd")
class SumoFcd(SampledTrajectory):
    """One vehicle of a SUMO floating-car-data file (sumo --fcd-output)."""

    kind: Literal["sumo_fcd"] = "sumo_fcd"
    file: Text
    #: The vehicle's id in the file (``<vehicle id="veh0">``).
    vehicle: Text
    #: At run time t the vehicle is where the file puts it at SUMO time t - time_offset.
    time_offset: Shift = 0.0
    #: A fixed displacement added to every position (m).
    offset: Point = (0.0, 0.0)

    @model_validator(mode="after")
    def _load(self, info: ValidationInfo):
        path, _ = located(self.file, None, info)
        try:
            data = read_fcd(path)
        except DkfsimError as err:
            raise custom_error(str(err), "file") from None
        if self.vehicle not in data.vehicles:
            # (an FCD export's vehicle ids are the one content of it a message shows: 40 characters, escaped)
            names = sorted(data.vehicles)
            close = difflib.get_close_matches(str(self.vehicle), names[:10_000], n=1)
            hint = f" (did you mean {clip(printable(close[0]), 40)}?)" if close else ""
            raise custom_error(f"no vehicle {clip(self.vehicle)} in {path.name}{hint}; its vehicles: "
                               f"{', '.join(clip(printable(v), 40) for v in names[:20])}"
                               f"{' ...' if len(names) > 20 else ''}", "vehicle")
        self._line = Polyline(*data.vehicles[self.vehicle])
        return self

    @override
    def sample_times(self, t):
        return t - self.time_offset

    @override
    def present(self, t_s):
        """Within the vehicle's samples (SUMO writes a vehicle while it is on the network)."""
        line = self.polyline()
        st = self.sample_times(run_times(t_s))
        return (st >= line.t[0]) & (st <= line.t[-1])

    @override
    def displacement(self):
        return np.asarray(self.offset, dtype=float)


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

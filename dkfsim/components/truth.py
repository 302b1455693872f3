"""The ``truth`` key: a recorded track as the truth, and how a track file is read.

``truth: {dataset: cicv5g/arterial_n8_v70_run03}`` (a shipped drive) or
``truth: {file: my_track.csv, ...}`` replaces the simulated target by a
recorded one; the file is read and checked when the scenario is validated.
:mod:`dkfsim.model.trajectory` turns the track into the run's states.
Files: CSV or whitespace separated, with a header line naming the columns
(matched exactly first, then ignoring case and punctuation, so ``utm_x_m``
finds ``utmX(m)``); only the three named columns must be numbers.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Annotated, Literal

import numpy as np
from pydantic import Field, PrivateAttr, ValidationInfo, model_validator

from dkfsim.components.latency import located
from dkfsim.core.datafiles import DataFileError, read_table
from dkfsim.core.params import MAX_SECONDS, StrictModel, custom_error

#: Seconds per unit of the time column.
TIME_UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}



class TrackError(ValueError):
    """A problem with a track file; ``key`` is the truth key it concerns."""

    def __init__(self, reason: str, key: str = "file"):
        super().__init__(reason)
        self.key = key


@dataclass(frozen=True)
class Track:
    """A recorded track: time (s, from the first row, increasing) and positions."""

    path: str
    t: np.ndarray      # (N,)
    x: np.ndarray      # (N,)
    y: np.ndarray      # (N,)

    @property
    def duration(self) -> float:
        return float(self.t[-1] - self.t[0])


_CACHE: dict[tuple, Track] = {}


def read_track(path: str | os.PathLike, time_column: str, x_column: str, y_column: str,
               time_unit: str = "ms") -> Track:
    """Read, sort and check a track (cached on the table and the columns)."""
    try:
        table = read_table(path)
        if table.header is None or len(table.lines) < 2:
            raise TrackError(f"{table.path.name} needs a header line and at least two rows")
        key = (str(table.path), id(table), time_column, x_column, y_column, time_unit)
        if key in _CACHE:
            return _CACHE[key]
        cols = []
        for c, k in ((time_column, "time_column"), (x_column, "x_column"), (y_column, "y_column")):
            try:
                cols.append(table.column_index(c))
            except DataFileError as err:
                raise TrackError(str(err), k) from None
        rows = np.array([[v for _, v in table.floats(col)] for col in cols]).T
    except DataFileError as err:
        raise TrackError(str(err)) from None
    path = table.path
    if not np.isfinite(rows).all():
        no = table.lines[int(np.nonzero(~np.isfinite(rows).all(axis=1))[0][0])][0]
        raise TrackError(f"{path.name} line {no}: values must be finite")
    order = np.argsort(rows[:, 0], kind="stable")
    rows = rows[order]
    # Subtract the first stamp before scaling: epoch milliseconds stay exact.
    with np.errstate(all="ignore"):
        t = (rows[:, 0] - rows[0, 0]) * TIME_UNITS[time_unit]
    if not np.isfinite(t).all():
        raise TrackError(f"{path.name}: its times span more seconds than any number (from "
                         f"{rows[0, 0]:.15g} to {rows[-1, 0]:.15g} {time_unit})")
    same = np.nonzero(np.diff(t) == 0)[0]
    if len(same):
        bad = same[np.any(rows[same + 1, 1:] != rows[same, 1:], axis=1)]
        if len(bad):
            raise TrackError(f"{path.name}: two rows at time {rows[bad[0], 0]:.15g} with different "
                             "positions")
        keep = np.ones(len(t), dtype=bool)
        keep[same + 1] = False
        t, rows = t[keep], rows[keep]
    if len(t) < 2:
        raise TrackError(f"{path.name} needs rows at two different times at least")
    track = Track(str(path), t, rows[:, 1].copy(), rows[:, 2].copy())
    for a in (track.t, track.x, track.y):
        a.setflags(write=False)
    _CACHE[key] = track
    return track


class TruthParams(StrictModel):
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
        path, key = located(self.file, self.dataset, info)
        try:
            self._read(path)
        except TrackError as err:
            raise custom_error(str(err), key if err.key == "file" else err.key) from None
        self._path = str(path)
        return self

    def _read(self, path):
        return read_track(path, self.time_column, self.x_column, self.y_column, self.time_unit)

    def track(self) -> Track:
        """The recorded :class:`Track` (read once, then cached)."""
        return self._read(self._path)

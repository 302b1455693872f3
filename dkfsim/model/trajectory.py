"""Truth from a recorded track instead of the model.

A scenario's optional top-level ``truth`` key names a table of time-stamped
positions (e.g. the UTM track of the car in the CICV5G data, CC BY 4.0,
Zenodo DOI 10.5281/zenodo.17475688)::

    truth: {dataset: cicv5g/arterial_n8_v70_run03,
            x_column: "utmX(m)", y_column: "utmY(m)", time_column: "pub_time(ms)",
            time_unit: ms, origin: first, start: 0, resample: linear}

The run's truth row ``r`` (tick ``k = r + 1``) is the track at ``start + k T``
seconds after the track's first time stamp:

* positions by linear interpolation between the recorded rows (``resample:
  linear``; rows are sorted by time, repeated time stamps must repeat the
  same position, a gap in the recording is bridged by a straight line);
* velocities by finite differences of the interpolated positions at the
  tick times (central, ``(p[k+1] - p[k-1]) / 2T``, using the track at time
  ``start`` for ``k = 1``; backward at the last tick), so the state is
  ``[x, vx, y, vy]`` of a ``constant_velocity`` model with ``dims: 2``;
* ``smooth`` (seconds, default 0 = off): before interpolating, replace
  each recorded position by the mean of those within ``smooth / 2`` s of it,
  for logs whose positions jitter against their time stamps (the CICV5G
  pose is stamped at publication, not at the fix);
* ``origin: first`` subtracts the track's position at the run's time 0
  (``start``), so the run starts at (0, 0); ``none`` keeps the file's
  coordinates.

The truth no longer depends on the seed (the ``("truth",)`` stream is not
used), and it does not follow the filters' model: a mismatch the user chose.

Files: CSV (a comma in the header line) or whitespace separated, with a
header line naming the columns (matched exactly first, then ignoring case
and punctuation, so ``utm_x_m`` finds ``utmX(m)``); lines starting with
``#`` are skipped; only the three named columns must be numbers.  A shipped
dataset is named by ``dataset:``, the user's own table by ``file:``, a
relative path resolving against the scenario file's folder
(:mod:`dkfsim.core.datafiles`).
"""

from __future__ import annotations

import numpy as np

from dkfsim.components.truth import Track, TrackError


def positions_at(track: Track, times: np.ndarray) -> np.ndarray:
    """Linear interpolation of the track at ``times`` (s from its first row), (len, 2)."""
    times = np.asarray(times, float)
    if times.min() < 0 or times.max() > track.duration * (1 + 1e-12):
        raise TrackError(f"times {times.min():g}..{times.max():g} s are outside the track "
                         f"(0..{track.duration:g} s)")
    return np.column_stack([np.interp(times, track.t, track.x), np.interp(times, track.t, track.y)])


def smoothed(track: Track, window: float) -> Track:
    """The track with each position replaced by the mean of the recorded positions
    within ``window / 2`` seconds of it (a centred moving average in time; the
    window shrinks at the ends).  ``window = 0`` returns the track itself."""
    if window <= 0:
        return track
    lo = np.searchsorted(track.t, track.t - window / 2, side="left")
    hi = np.searchsorted(track.t, track.t + window / 2, side="right")
    out = []
    for a in (track.x, track.y):
        c = np.concatenate([[0.0], np.cumsum(a - a[0])])
        out.append(a[0] + (c[hi] - c[lo]) / (hi - lo))
    return Track(track.path, track.t, out[0], out[1])


def cv_states(track: Track, T: float, K: int, start: float = 0.0, origin: str = "first") -> np.ndarray:
    """Truth rows ``[x, vx, y, vy]`` at ``start + k T``, ``k = 1..K``, shape (K, 4)."""
    k = np.arange(0, K + 1)
    times = start + k * T
    if times[-1] > track.duration + 1e-9:
        raise TrackError(f"a run of {K} ticks of {T:g} s from start {start:g} s needs "
                         f"{times[-1]:g} s of track, but it covers {track.duration:g} s")
    # The last tick may sit a rounding error past the track's end.
    times = np.minimum(times, track.duration)
    p = positions_at(track, times)                 # rows k = 0..K
    if origin == "first":
        p = p - p[0]
    v = np.empty((K, 2))
    if K >= 2:
        v[:-1] = (p[2:] - p[:-2]) / (2 * T)
    v[-1] = (p[K] - p[K - 1]) / T
    out = np.empty((K, 4))
    out[:, 0], out[:, 1], out[:, 2], out[:, 3] = p[1:, 0], v[:, 0], p[1:, 1], v[:, 1]
    return out


def track_truth(scenario) -> np.ndarray:
    """The truth (K, 4) of a scenario with a ``truth`` key."""
    spec = scenario.truth
    track = smoothed(spec.track(), spec.smooth)
    return cv_states(track, scenario.model.T, int(scenario.steps), spec.start, spec.origin)

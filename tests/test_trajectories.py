"""Trajectory kinds (issue 23): hand-worked positions and velocities, validation, properties."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pydantic import ValidationError

from dkfsim.components.trajectories import TrajectoryParams, parse_trajectory
from dkfsim.core.registry import TRAJECTORIES

WAYPOINTS = {"kind": "waypoints", "points": [[0, 0, 0], [10, 100, 0], [20, 100, 50]]}


# --------------------------------------------------------------------------- constant_velocity
def test_constant_velocity_by_hand():
    traj = parse_trajectory({"kind": "constant_velocity", "start": [1, 2], "velocity": [3, -1]})
    t = np.array([0.0, 2.0, -1.0, 0.5])
    assert np.array_equal(traj.positions(t), [[1, 2], [7, 0], [-2, 3], [2.5, 1.5]])
    assert np.array_equal(traj.velocities(t), [[3, -1]] * 4)
    assert traj.positions(t).shape == (4, 2) and traj.velocities(t).shape == (4, 2)


def test_constant_velocity_defaults_to_standing_at_the_origin():
    traj = parse_trajectory({"kind": "constant_velocity"})
    assert np.array_equal(traj.positions([0.0, 7.0]), np.zeros((2, 2)))


# --------------------------------------------------------------------------- waypoints
def test_waypoints_by_hand():
    traj = parse_trajectory(WAYPOINTS)
    t = np.array([-5.0, 0.0, 2.5, 10.0, 15.0, 20.0, 99.0])
    # Before t = 0: held at the first point; 2.5 s into the first leg (100 m in 10 s): 25 m;
    # the second leg climbs 50 m in 10 s; after t = 20: held at the last point.
    assert np.allclose(traj.positions(t), [[0, 0], [0, 0], [25, 0], [100, 0], [100, 25],
                                           [100, 50], [100, 50]], rtol=0, atol=1e-12)
    # Velocity: 0 while held, the leg's slope inside, the later leg at a waypoint's own time.
    assert np.allclose(traj.velocities(t), [[0, 0], [10, 0], [10, 0], [0, 5], [0, 5], [0, 0], [0, 0]],
                       rtol=0, atol=1e-12)


def test_single_waypoint_stands_still():
    traj = parse_trajectory({"kind": "waypoints", "points": [[3, 4, 5]]})
    assert np.array_equal(traj.positions([0, 3, 9]), [[4, 5]] * 3)
    assert np.array_equal(traj.velocities([0, 3, 9]), np.zeros((3, 2)))


@pytest.mark.parametrize("spec, words", [
    ({"kind": "waypoints", "points": [[0, 0, 0], [0, 1, 1]]}, "strictly increasing: point 2"),
    ({"kind": "waypoints", "points": [[0, 0, 0], [5, 1, 1], [4, 2, 2]]}, "point 3 (t = 4.0)"),
    ({"kind": "waypoints", "points": [[0, 0], [1, 1]]}, "[t, x, y]"),
    ({"kind": "waypoints", "points": [[0, 0, "a"]]}, "numbers"),
    ({"kind": "waypoints", "points": [[0, 0, float("nan")]]}, "finite"),
    ({"kind": "waypoints"}, "points"),
    ({"kind": "constant_velocity", "start": [1, 2, 3]}, "two numbers"),
    ({"kind": "constant_velocity", "velocity": "fast"}, "must be numbers"),
    ({"kind": "constant_velocity", "velocity": 5}, "two numbers"),
    ({"kind": "constant_velocity", "sped": [1, 0]}, "unknown key"),
    ({"kind": "constnt_velocity"}, "did you mean 'constant_velocity'"),
    ({"velocity": [1, 0]}, "missing key 'kind'"),
])
def test_bad_keys_are_named(spec, words):
    with pytest.raises(ValidationError) as err:
        parse_trajectory(spec)
    assert words in str(err.value)


def test_registered_family():
    assert {"constant_velocity", "waypoints"} <= set(TRAJECTORIES.names())
    for entry in TRAJECTORIES.entries():
        assert issubclass(entry.params, TrajectoryParams) and entry.description


def test_times_must_be_finite():
    with pytest.raises(ValueError, match="finite"):
        parse_trajectory(WAYPOINTS).positions([0.0, np.nan])


# --------------------------------------------------------------------------- properties
_coord = st.floats(-1e4, 1e4, allow_nan=False)


@st.composite
def _waypoints(draw):
    n = draw(st.integers(2, 6))
    steps = draw(st.lists(st.floats(0.01, 100), min_size=n - 1, max_size=n - 1))
    t0 = draw(st.floats(-50, 50))
    times = t0 + np.concatenate([[0.0], np.cumsum(steps)])
    xy = draw(st.lists(st.tuples(_coord, _coord), min_size=n, max_size=n))
    return np.column_stack([times, np.array(xy)])


@settings(max_examples=150, deadline=None)
@given(pts=_waypoints(), frac=st.floats(0, 1), seg_pick=st.integers(0, 100))
def test_interpolation_stays_on_its_segment(pts, frac, seg_pick):
    """At a time inside leg k, the position is on the segment between points k and k+1,
    at the fraction of the leg's time that has passed (independent arithmetic)."""
    traj = parse_trajectory({"kind": "waypoints", "points": pts.tolist()})
    k = seg_pick % (len(pts) - 1)
    (t0, x0, y0), (t1, x1, y1) = pts[k], pts[k + 1]
    t = t0 + frac * (t1 - t0)
    got = traj.positions(np.array([t]))[0]
    lam = (t - t0) / (t1 - t0)
    want = np.array([x0 + lam * (x1 - x0), y0 + lam * (y1 - y0)])
    scale = 1e-9 * (1 + np.abs([x0, y0, x1, y1]).max())
    assert np.allclose(got, want, rtol=0, atol=scale)
    # On the segment: inside its bounding box (up to rounding).
    assert min(x0, x1) - scale <= got[0] <= max(x0, x1) + scale
    assert min(y0, y1) - scale <= got[1] <= max(y0, y1) + scale
    # Velocity is the leg's slope when t is strictly inside it.
    if t0 < t < t1:
        v = traj.velocities(np.array([t]))[0]
        assert np.allclose(v, [(x1 - x0) / (t1 - t0), (y1 - y0) / (t1 - t0)], rtol=1e-9, atol=1e-9)


@settings(max_examples=100, deadline=None)
@given(pts=_waypoints(), dt=st.floats(0.001, 1e3))
def test_held_outside_the_points(pts, dt):
    traj = parse_trajectory({"kind": "waypoints", "points": pts.tolist()})
    t = np.array([pts[0, 0] - dt, pts[-1, 0] + dt])
    assert np.array_equal(traj.positions(t), [pts[0, 1:], pts[-1, 1:]])
    assert np.array_equal(traj.velocities(t), np.zeros((2, 2)))

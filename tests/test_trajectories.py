"""Trajectory kinds (issue 23): hand-worked positions and velocities, validation, properties."""

from __future__ import annotations

import math
from pathlib import Path

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
    ({"kind": "waypoints", "points": [[0, 0, 0], [1e-300, 1e9, 1e9]]},
     "the vehicle moves from point 1 (t = 0.0) to point 2 (t = 1e-300) at a speed beyond any number"),
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


# --------------------------------------------------------------------------- track
# The first rows of cicv5g/arterial_n8_v70_run03 (copied by hand from the file):
#   pub_time(ms)   utmX(m)        utmY(m)       sinr(db)
#   1721809961241  329231.340000  3463451.680000  22
#   1721809961297  329231.360000  3463451.710000  22
ARTERIAL = {"kind": "track", "dataset": "cicv5g/arterial_n8_v70_run03"}


def test_track_between_its_first_two_rows():
    traj = parse_trajectory(ARTERIAL)
    # Half-way between rows 1 and 2 (0.028 s after the first of two rows 0.056 s apart).
    assert np.allclose(traj.positions([0.0, 0.028]), [[329231.34, 3463451.68], [329231.35, 3463451.695]],
                       rtol=0, atol=1e-6)
    assert np.allclose(traj.velocities([0.028]), [[0.02 / 0.056, 0.03 / 0.056]], rtol=1e-6)
    assert np.array_equal(traj.sinr_db([0.0, 0.03]), [22, 22])


def test_track_shifted_in_time_and_space():
    traj = parse_trajectory({**ARTERIAL, "time_offset": 1.0, "offset": [5, -3]})
    # At run time 1.028 s the vehicle is where the car was 0.028 s into the drive, moved by (5, -3);
    # before 1 s it waits at the first row.
    assert np.allclose(traj.positions([0.0, 0.5, 1.028]),
                       [[329236.34, 3463448.68], [329236.34, 3463448.68], [329236.35, 3463448.695]],
                       rtol=0, atol=1e-6)
    assert np.allclose(traj.velocities([0.5, 1.028]), [[0, 0], [0.02 / 0.056, 0.03 / 0.056]], rtol=1e-6)


def _write(tmp_path, name, text):
    path = tmp_path / name
    path.write_text(text)
    return path


L_TRACK = "t x y sinr\n0 0 0 3\n10 100 0 7\n15 100 0 9\n25 100 100 11\n"


@pytest.mark.parametrize("along, t, pos, vel", [
    (-50.0, 10.0, (50, 0), (0, 0)),      # leader at 100 m, parked until 15 s: follower parked at 50 m
    (-50.0, 9.0, (40, 0), (10, 0)),      # leader at 90 m at 10 m/s: follower at 40 m, same speed
    (50.0, 5.0, (100, 0), (0, 10)),      # 50 + 50 = 100 m: the corner, turning north (later leg)
    (50.0, 20.0, (100, 100), (0, 0)),    # 150 + 50 = 200 m: the path's end, held
    (-50.0, 2.0, (0, 0), (0, 0)),        # 20 - 50 < 0: waiting at the start
    (-50.0, 20.0, (100, 0), (0, 10)),    # leader at 150 m; follower at the corner, moving north
    (-30.0, 20.0, (100, 20), (0, 10)),
])
def test_track_along_the_path_by_hand(tmp_path, along, t, pos, vel):
    path = _write(tmp_path, "l.txt", L_TRACK)
    traj = parse_trajectory({"kind": "track", "file": str(path), "time_column": "t", "time_unit": "s",
                             "x_column": "x", "y_column": "y", "along": along})
    assert np.allclose(traj.positions([t]), [pos], rtol=0, atol=1e-9)
    assert np.allclose(traj.velocities([t]), [vel], rtol=0, atol=1e-9)


def test_track_sinr_follows_the_drive_clock(tmp_path):
    path = _write(tmp_path, "l.txt", L_TRACK)
    traj = parse_trajectory({"kind": "track", "file": str(path), "time_column": "t", "time_unit": "s",
                             "x_column": "x", "y_column": "y", "sinr_column": "sinr", "time_offset": 5})
    # Run time t is drive time t - 5; the last row at or before it (the first row before the drive).
    assert np.array_equal(traj.sinr_db([0, 5, 14.9, 15, 29.9, 30, 99]), [3, 3, 3, 7, 9, 11, 11])


@pytest.mark.parametrize("spec, words", [
    ({"kind": "track", "dataset": "cicv5g/arterial"}, "unknown dataset"),
    ({"kind": "track"}, "exactly one of file"),
    ({**ARTERIAL, "x_column": "utmZ"}, "no column 'utmZ'"),
    ({**ARTERIAL, "offset": [1]}, "two numbers"),
    ({**ARTERIAL, "time_offset": float("inf")}, "time_offset"),
    ({**ARTERIAL, "along": "far"}, "along"),
])
def test_track_bad_keys(spec, words):
    with pytest.raises(ValidationError) as err:
        parse_trajectory(spec)
    assert words in str(err.value)


def test_track_bad_file(tmp_path):
    path = _write(tmp_path, "bad.txt", "t x y\n0 0 0\n1 oops 0\n")
    with pytest.raises(ValidationError) as err:
        parse_trajectory({"kind": "track", "file": str(path), "time_column": "t", "x_column": "x",
                          "y_column": "y"})
    # the line and the column, not the cell: a scenario may name any file (issue 30 §1)
    assert "bad.txt line 3: column 1 is not a number" in str(err.value) and "oops" not in str(err.value)


@pytest.mark.parametrize("rows, words", [
    ("0 0 0\n1e-300 1e9 1e9\n2 0 0\n", "moves from time 0.0 s to 1e-300 s (from its first row) at a speed beyond"),
    ("0 -1e308 0\n1 1e308 0\n", "moves from time 0.0 s to 1.0 s (from its first row) at a speed beyond"),
    ("0 -0.7e308 -0.7e308\n1 0.7e308 0.7e308\n", "at a speed beyond any number"),
    ("0 0 0\n1 1e308 0\n2 0 0\n3 1e308 0\n", "path is longer than any number of metres"),
    ("-1e308 0 0\n1e308 1 0\n", "times span more seconds than any number"),
])
def test_track_too_fast_or_too_long_for_a_float_is_refused_without_a_warning(tmp_path, rows, words):
    """A step whose speed, path or time span overflows a float is refused naming the file, as a
    SUMO FCD file is (it warned 'overflow encountered in divide' and ran; positions could be nan)."""
    import warnings
    path = _write(tmp_path, "fast.txt", "t x y\n" + rows)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(ValidationError) as err:
            parse_trajectory({"kind": "track", "file": str(path), "time_column": "t", "time_unit": "s",
                              "x_column": "x", "y_column": "y"})
    (problem,) = err.value.errors()
    assert problem["ctx"]["key"] == "file" and problem["msg"].startswith("fast.txt: ") and words in problem["msg"]


def test_track_without_the_sinr_column_says_so(tmp_path):
    from dkfsim.core.errors import DkfsimError
    path = _write(tmp_path, "nosinr.txt", "t x y\n0 0 0\n1 1 0\n")
    traj = parse_trajectory({"kind": "track", "file": str(path), "time_column": "t", "x_column": "x",
                             "y_column": "y"})
    with pytest.raises(DkfsimError, match="nosinr.txt.*sinr_column.*no column 'sinr\\(db\\)'"):
        traj.sinr_db([0.0])


# --------------------------------------------------------------------------- sumo_fcd
SMALL_FCD = Path(__file__).parent / "data" / "fcd" / "small.xml"


@pytest.mark.parametrize("vehicle, t, pos, vel", [
    ("veh0", 0.5, (15, 5), (10, 0)),
    ("veh0", 2.0, (30, 5), (0, 10)),      # the turn: the later leg's velocity
    ("veh0", 2.5, (30, 10), (0, 10)),
    ("veh0", 9.0, (30, 15), (0, 0)),      # left the simulation after t = 3: held
    ("veh1", 0.0, (0, -3.2), (0, 0)),     # enters at t = 1: held before
    ("veh1", 1.5, (2.5, -3.2), (5, 0)),
    ("veh1", 3.5, (20, -3.2), (10, 0)),
])
def test_sumo_fcd_by_hand(vehicle, t, pos, vel):
    traj = parse_trajectory({"kind": "sumo_fcd", "file": str(SMALL_FCD), "vehicle": vehicle})
    assert np.allclose(traj.positions([t]), [pos], rtol=0, atol=1e-12)
    assert np.allclose(traj.velocities([t]), [vel], rtol=0, atol=1e-12)


def test_sumo_fcd_relative_file_and_shifts():
    traj = parse_trajectory({"kind": "sumo_fcd", "file": "small.xml", "vehicle": "veh1", "time_offset": -1,
                             "offset": [0, 3.2]}, base_dir=SMALL_FCD.parent)
    # Run time 0.5 is SUMO time 1.5.
    assert np.allclose(traj.positions([0.5]), [[2.5, 0.0]], rtol=0, atol=1e-12)


_HEAD = '<?xml version="1.0"?>\n'
_OK_STEP = '<timestep time="0"><vehicle id="veh0" x="1" y="2"/></timestep>'
HOSTILE_FCD = {
    "bomb.xml": (_HEAD + '<!DOCTYPE lolz [<!ENTITY lol "lol"><!ENTITY lol2 "&lol;&lol;&lol;&lol;&lol;'
                 '&lol;&lol;&lol;&lol;&lol;"><!ENTITY lol3 "&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;'
                 '&lol2;&lol2;&lol2;">]>\n<fcd-export><timestep time="0"><vehicle id="&lol3;" x="1" '
                 'y="2"/></timestep></fcd-export>\n', "line 2: refused"),
    "external.xml": (_HEAD + '<!DOCTYPE fcd [<!ENTITY xxe SYSTEM "file:///etc/passwd">]>\n<fcd-export>'
                     '<timestep time="0"><vehicle id="&xxe;" x="1" y="2"/></timestep></fcd-export>\n',
                     "line 2: refused"),
    "dtd.xml": (_HEAD + '<!DOCTYPE fcd-export SYSTEM "http://example.invalid/fcd.dtd">\n<fcd-export>'
                + _OK_STEP + '</fcd-export>\n', "refused"),
    "noid.xml": (_HEAD + '<fcd-export>\n<timestep time="0">\n<vehicle x="1" y="2"/>\n</timestep>\n'
                 '</fcd-export>\n', "line 4: a <vehicle> without an id"),
    "nanx.xml": (_HEAD + '<fcd-export>\n' + _OK_STEP + '\n<timestep time="1">\n<vehicle id="veh0" '
                 'x="east" y="2"/></timestep></fcd-export>\n',
                 "line 5: vehicle 'veh0' at time 1.0: x is not a finite number"),
    "infy.xml": (_HEAD + '<fcd-export>\n<timestep time="0"><vehicle id="veh0" x="1" y="inf"/></timestep>'
                 '</fcd-export>\n', "y is not a finite number"),
    "back.xml": (_HEAD + '<fcd-export>\n<timestep time="5">\n<vehicle id="veh0" x="1" y="2"/></timestep>'
                 '\n<timestep time="4">\n<vehicle id="veh0" x="1" y="2"/></timestep></fcd-export>\n',
                 "line 5: time goes backwards: timestep time=4.0 after time=5.0"),
    "twice.xml": (_HEAD + '<fcd-export>\n<timestep time="0"><vehicle id="veh0" x="1" y="2"/>\n'
                  '<vehicle id="veh0" x="1" y="3"/></timestep></fcd-export>\n', "appears twice"),
    "notime.xml": (_HEAD + '<fcd-export>\n<timestep><vehicle id="veh0" x="1" y="2"/></timestep>'
                   '</fcd-export>\n', "line 3: <timestep> has no 'time' attribute"),
    "broken.xml": (_HEAD + '<fcd-export>\n' + _OK_STEP + '\n<timestep time="1">', "not well-formed XML"),
    "root.xml": (_HEAD + '<routes>' + _OK_STEP + '</routes>\n', "not <fcd-export>"),
    "empty.xml": (_HEAD + '<fcd-export/>\n', "has no <timestep>"),
    "fast.xml": (_HEAD + '<fcd-export>\n' + _OK_STEP + '\n<timestep time="1e-300"><vehicle id="veh0" x="1e9" '
                 'y="2"/></timestep></fcd-export>\n',
                 "vehicle 'veh0' moves from time 0.0 to 1e-300 at a speed beyond any number"),
    "other.xml": (_HEAD + '<fcd-export>' + _OK_STEP.replace("veh0", "veh_0") + '</fcd-export>\n',
                  "no vehicle 'veh0' in other.xml (did you mean 'veh_0'?)"),
}


@pytest.mark.parametrize("name", sorted(HOSTILE_FCD))
def test_sumo_fcd_hostile_files(tmp_path, name):
    text, words = HOSTILE_FCD[name]
    (tmp_path / name).write_text(text)
    with pytest.raises(ValidationError) as err:
        parse_trajectory({"kind": "sumo_fcd", "file": name, "vehicle": "veh0"}, base_dir=tmp_path)
    assert words in str(err.value)
    assert name in str(err.value)
    assert "passwd" not in str(err.value).replace("file:///etc/passwd", "")   # no file content leaked
    assert "east" not in str(err.value) and "routes" not in str(err.value)    # no value, no element name


def test_sumo_fcd_missing_file(tmp_path):
    with pytest.raises(ValidationError, match="file not found"):
        parse_trajectory({"kind": "sumo_fcd", "file": "nope.xml", "vehicle": "veh0"}, base_dir=tmp_path)


def test_sumo_fcd_without_defusedxml_says_what_to_install(tmp_path, monkeypatch):
    import sys
    (tmp_path / "f.xml").write_text(_HEAD + "<fcd-export>" + _OK_STEP + "</fcd-export>\n")
    monkeypatch.setitem(sys.modules, "defusedxml", None)          # import fails
    monkeypatch.setitem(sys.modules, "defusedxml.ElementTree", None)
    with pytest.raises(ValidationError, match="pip install defusedxml"):
        parse_trajectory({"kind": "sumo_fcd", "file": "f.xml", "vehicle": "veh0"}, base_dir=tmp_path)


def test_sumo_fcd_larger_than_a_read_chunk(tmp_path):
    """A file of several 1 MiB chunks (elements cut at chunk boundaries) reads every sample:
    veh0 at x = 2 t, y = -t; veh1 listed every other timestep at x = 100 + t."""
    steps = []
    for k in range(12_000):
        t = k * 0.5
        veh1 = f'<vehicle id="veh1" x="{100 + t:.2f}" y="7.00" speed="1.00" angle="90.00"/>' if k % 2 else ""
        steps.append(f'<timestep time="{t:.2f}"><vehicle id="veh0" x="{2 * t:.2f}" y="{-t:.2f}" '
                     f'speed="2.24" angle="117.00" lane="E0_0" pos="0.00" slope="0.00"/>{veh1}</timestep>')
    (tmp_path / "big.xml").write_text(_HEAD + "<fcd-export>\n" + "\n".join(steps) + "\n</fcd-export>\n")
    assert (tmp_path / "big.xml").stat().st_size > 2 * (1 << 20)
    veh0 = parse_trajectory({"kind": "sumo_fcd", "file": "big.xml", "vehicle": "veh0"}, base_dir=tmp_path)
    veh1 = parse_trajectory({"kind": "sumo_fcd", "file": "big.xml", "vehicle": "veh1"}, base_dir=tmp_path)
    t = np.array([0.75, 1234.75, 5999.25])
    assert np.allclose(veh0.positions(t), np.column_stack([2 * t, -t]), rtol=0, atol=1e-9)
    assert np.allclose(veh1.positions(t), np.column_stack([100 + t, [7, 7, 7]]), rtol=0, atol=1e-9)
    assert len(veh0.polyline().t) == 12_000 and len(veh1.polyline().t) == 6_000


def test_sumo_fcd_single_sample_stands_still(tmp_path):
    (tmp_path / "one.xml").write_text(_HEAD + "<fcd-export>" + _OK_STEP + "</fcd-export>\n")
    traj = parse_trajectory({"kind": "sumo_fcd", "file": "one.xml", "vehicle": "veh0"}, base_dir=tmp_path)
    assert np.array_equal(traj.positions([-1, 0, 5]), [[1, 2]] * 3)
    assert np.array_equal(traj.velocities([-1, 0, 5]), np.zeros((3, 2)))


@st.composite
def _track_and_time(draw):
    pts = draw(_waypoints())
    frac = draw(st.floats(0, 1))
    return pts, pts[0, 0] + frac * (pts[-1, 0] - pts[0, 0])


@settings(max_examples=60, deadline=None)
@given(case=_track_and_time(), gap=st.floats(0, 2e4))
def test_along_keeps_the_road_distance(case, gap):
    """A vehicle ``gap`` metres behind on the path is where the recorded car was when it had
    driven ``gap`` metres less (computed here by walking the segments), or at the start."""
    import tempfile
    import uuid
    pts, t = case
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / f"{uuid.uuid4().hex}.txt"
        path.write_text("t x y\n" + "\n".join(f"{a!r} {b!r} {c!r}" for a, b, c in pts.tolist()) + "\n")
        traj = parse_trajectory({"kind": "track", "file": str(path), "time_column": "t", "time_unit": "s",
                                 "x_column": "x", "y_column": "y", "along": -gap})
        got = traj.positions([t - pts[0, 0]])[0]
    lengths = [math.dist(pts[k, 1:], pts[k + 1, 1:]) for k in range(len(pts) - 1)]
    k = min(int(np.searchsorted(pts[:, 0], t, side="right")) - 1, len(pts) - 2)
    driven = sum(lengths[:k]) + lengths[k] * (t - pts[k, 0]) / (pts[k + 1, 0] - pts[k, 0])
    target = driven - gap
    want = pts[0, 1:]
    for j, length in enumerate(lengths):
        if target <= 0:
            break
        if target <= length:
            want = pts[j, 1:] + (pts[j + 1, 1:] - pts[j, 1:]) * (target / length)
            break
        target -= length
    else:
        want = pts[-1, 1:]              # rounding left target a hair past the end
    scale = 1e-7 * (1 + np.abs(pts[:, 1:]).max() + sum(lengths))
    assert np.allclose(got, want, rtol=0, atol=scale)


@pytest.mark.parametrize("spec", [
    {**ARTERIAL, "along": -20.0, "offset": [1, 2]},
    {"kind": "sumo_fcd", "file": str(SMALL_FCD), "vehicle": "veh1", "time_offset": 0.5},
    WAYPOINTS,
    {"kind": "constant_velocity", "velocity": [1, 2]},
])
def test_round_trips(spec):
    """Plain data and pickling (scenarios are saved, compared and sent to worker processes)
    give an equal trajectory that moves alike."""
    import pickle
    traj = parse_trajectory(spec)
    again, copied = parse_trajectory(traj.to_dict()), pickle.loads(pickle.dumps(traj))
    assert again == traj and copied == traj and hash(again) == hash(traj)
    t = np.linspace(-1, 30, 9)
    for other in (again, copied):
        assert np.array_equal(other.positions(t), traj.positions(t))
        assert np.array_equal(other.velocities(t), traj.velocities(t))
    moved = parse_trajectory({**traj.to_dict(), "offset": [9, 9]} if "offset" in traj.to_dict()
                             else {**traj.to_dict(), "kind": traj.kind})
    assert (moved != traj) == ("offset" in traj.to_dict())

"""Truth from a recorded track (dkfsim.model.trajectory, the scenario's ``truth`` key).

Interpolation and finite differences on small hand-made tables, the file
formats, path resolution, the CICV5G scenario (data: CICV5G, CC BY 4.0,
Zenodo DOI 10.5281/zenodo.17475688) and the errors.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
import yaml

from dkfsim.core.datafiles import DATA_DIR

ROOT = Path(__file__).resolve().parents[1]
CICV = ROOT / "scenarios" / "cicv5g_track.yaml"
DATA = DATA_DIR / "cicv5g" / "arterial_n8_v70_run03.txt"     # shipped inside the package

# t (ms), x, y: rows out of order, a repeated stamp, a 200 ms gap.
CSV = """# a hand-made track
time_ms,east_m,north_m,speed
100,11.0,2.0,9
0,10.0,0.0,9
200,13.0,4.0,9
200,13.0,4.0,9
400,13.0,8.0,9
500,12.0,9.0,9
"""


def write(tmp_path, text=CSV, name="track.csv"):
    p = tmp_path / name
    p.write_text(text)
    return p


def scenario_dict(file, steps=8, T=0.05, **truth):
    spec = {"file": str(file), "x_column": "east_m", "y_column": "north_m",
            "time_column": "time_ms", "time_unit": "ms"}
    spec.update(truth)
    return {
        "name": "track", "seed": 3, "steps": steps, "truth": spec,
        "model": {"kind": "constant_velocity", "dims": 2, "T": T, "q": 1.0},
        "prior": {"mean": [0, 0, 0, 0], "cov": np.eye(4).tolist()},
        "sensors": [{"name": "g0", "H": [[1, 0, 0, 0], [0, 0, 1, 0]], "R": np.eye(2).tolist()},
                    {"name": "r1", "kind": "radar", "position": [5.0, -5.0], "sigma_range": 0.2,
                     "sigma_azimuth": 0.01}],
        "topology": {"generator": "path"},
        "links": {"default": {"latency": {"model": "uniform_steps", "d_t": 1}}},
        "baselines": ["centralized", "local"],
    }


def test_read_sorts_and_drops_repeated_stamps(tmp_path):
    from dkfsim.components.truth import read_track
    tr = read_track(write(tmp_path), "time_ms", "east_m", "north_m", "ms")
    np.testing.assert_array_equal(tr.t, [0.0, 0.1, 0.2, 0.4, 0.5])
    np.testing.assert_array_equal(tr.x, [10, 11, 13, 13, 12])
    np.testing.assert_array_equal(tr.y, [0, 2, 4, 8, 9])
    assert tr.duration == 0.5


def test_interpolation_and_finite_differences_by_hand(tmp_path):
    from dkfsim.components.truth import read_track
    from dkfsim.model.trajectory import cv_states
    tr = read_track(write(tmp_path), "time_ms", "east_m", "north_m", "ms")
    X = cv_states(tr, T=0.1, K=5, origin="none")
    # Positions at t = 0.1 .. 0.5 (0.3 lies half way across the gap 0.2 -> 0.4).
    np.testing.assert_allclose(X[:, 0], [11, 13, 13, 13, 12], atol=1e-12)
    np.testing.assert_allclose(X[:, 2], [2, 4, 6, 8, 9], atol=1e-12)
    # Central differences (p[k+1] - p[k-1]) / 2T with p[0] = (10, 0); backward at the end.
    np.testing.assert_allclose(X[:, 1], [(13 - 10) / 0.2, (13 - 11) / 0.2, 0.0,
                                         (12 - 13) / 0.2, (12 - 13) / 0.1], atol=1e-9)
    np.testing.assert_allclose(X[:, 3], [(4 - 0) / 0.2, (6 - 2) / 0.2, (8 - 4) / 0.2,
                                         (9 - 6) / 0.2, (9 - 8) / 0.1], atol=1e-9)
    # Between rows: t = 0.05, 0.1, 0.15 with T = 0.05, origin: first subtracts p(0) = (10, 0).
    X = cv_states(tr, T=0.05, K=3, origin="first")
    np.testing.assert_allclose(X[:, 0], [0.5, 1.0, 2.0], atol=1e-12)
    np.testing.assert_allclose(X[:, 2], [1.0, 2.0, 3.0], atol=1e-12)
    # start shifts the run along the track (and the origin with it).
    X = cv_states(tr, T=0.1, K=2, start=0.2, origin="first")
    np.testing.assert_allclose(X[:, 0], [0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(X[:, 2], [2.0, 4.0], atol=1e-12)


def test_whitespace_table_and_loose_column_names(tmp_path):
    from dkfsim.components.truth import read_track
    text = "t(s) utmX(m) utmY(m) cell\n0 1.0 2.0 5C4\n1.5 4.0 2.0 5C4\n"
    tr = read_track(write(tmp_path, text, "ws.txt"), "t_s", "utm_x_m", "utmY(m)", "s")
    np.testing.assert_array_equal(tr.t, [0.0, 1.5])
    np.testing.assert_array_equal(tr.x, [1.0, 4.0])


def test_smoothing_is_a_centred_moving_average(tmp_path):
    from dkfsim.components.truth import read_track
    from dkfsim.model.trajectory import smoothed
    tr = read_track(write(tmp_path), "time_ms", "east_m", "north_m", "ms")
    s = smoothed(tr, 0.2)             # +-0.1 s: neighbours within 100 ms
    np.testing.assert_allclose(s.x, [10.5, 34 / 3, 12.0, 12.5, 12.5])
    np.testing.assert_allclose(s.y, [1.0, 2.0, 3.0, 8.5, 8.5])
    assert smoothed(tr, 0.0) is tr


def test_scenario_runs_on_a_hand_made_track(tmp_path):
    import dkfsim
    from dkfsim.components.truth import read_track
    from dkfsim.model.trajectory import cv_states
    p = write(tmp_path)
    sc = dkfsim.load_scenario(scenario_dict(p, steps=10))
    res = dkfsim.run(sc)
    tr = read_track(p, "time_ms", "east_m", "north_m", "ms")
    np.testing.assert_array_equal(res["truth"], cv_states(tr, 0.05, 10))
    assert np.isfinite(res["x_fused"]).all()
    # The truth is the track whatever the seed; the measurements are not.
    other = dkfsim.run(sc, seed=99)
    np.testing.assert_array_equal(other["truth"], res["truth"])
    assert not np.array_equal(other["y_0"], res["y_0"])


def test_relative_path_resolves_against_the_scenario_folder(tmp_path, monkeypatch):
    import dkfsim
    (tmp_path / "data").mkdir()
    (tmp_path / "runs").mkdir()
    write(tmp_path / "data")
    d = scenario_dict("../data/track.csv", steps=4)
    path = tmp_path / "runs" / "s.yaml"
    path.write_text(yaml.safe_dump(d))
    monkeypatch.chdir(ROOT)
    sc = dkfsim.load_scenario(path)
    assert sc.truth.file == "../data/track.csv"         # kept as written
    res = dkfsim.run(sc)
    assert res["truth"].shape == (4, 4)
    # Re-validating the scenario object (as no_buffer and overrides do) still finds it.
    assert dkfsim.load_scenario(sc, ["steps=5"]).truth.track().duration == 0.5


def test_run_longer_than_the_track_is_a_clear_error(tmp_path):
    import dkfsim
    from dkfsim.core.errors import ScenarioError
    p = write(tmp_path)
    dkfsim.load_scenario(scenario_dict(p, steps=10))            # 0.5 s: exactly the track
    with pytest.raises(ScenarioError) as info:
        dkfsim.load_scenario(scenario_dict(p, steps=11))
    msg = str(info.value)
    assert msg.startswith("<dict>: steps: ")
    for words in ("0.55 s of track", "11 steps x 0.05 s", f"truth.file {p}", "covers 0.5 s",
                  "at most 10 steps"):
        assert words in msg, msg
    with pytest.raises(ScenarioError, match=r"truth.start 0.1 s"):
        dkfsim.load_scenario(scenario_dict(p, steps=10, start=0.1))


@pytest.mark.parametrize("change, key, words", [
    ({"file": "nowhere.csv"}, "truth.file", ["file not found", "nowhere.csv"]),
    ({"x_column": "utmX"}, "truth.x_column", ["no column 'utmX'", "4 names"]),   # (the names: not shown)
    ({"time_unit": "min"}, "truth.time_unit", []),
    ({"origin": "last"}, "truth.origin", []),
    ({"start": -1.0}, "truth.start", ["must be >= 0"]),
    ({"fil": "x"}, "truth.fil", ["did you mean 'file'"]),
])
def test_truth_key_errors(tmp_path, change, key, words):
    import dkfsim
    from dkfsim.core.errors import ScenarioError
    d = scenario_dict(write(tmp_path))
    d["truth"].update(change)
    with pytest.raises(ScenarioError) as info:
        dkfsim.load_scenario(d)
    msg = str(info.value)
    assert msg.startswith(f"<dict>: {key}: "), msg
    for w in words:
        assert w in msg, msg


def test_truth_needs_the_planar_constant_velocity_state(tmp_path):
    import dkfsim
    from dkfsim.core.errors import ScenarioError
    d = scenario_dict(write(tmp_path))
    d["model"] = {"kind": "linear", "T": 0.05, "Phi": np.eye(4).tolist(), "Q": np.eye(4).tolist()}
    with pytest.raises(ScenarioError, match=r"<dict>: truth: .*constant_velocity with dims: 2"):
        dkfsim.load_scenario(d)


def test_bad_rows_are_named(tmp_path):
    import dkfsim
    from dkfsim.core.errors import ScenarioError
    d = scenario_dict(write(tmp_path, CSV.replace("400,13.0", "400,abc"), "bad.csv"))
    with pytest.raises(ScenarioError, match=r"truth.file: bad.csv line 7: column 1 is not a number$"):
        dkfsim.load_scenario(d)
    d = scenario_dict(write(tmp_path, CSV.replace("200,13.0,4.0,9\n400", "200,13.5,4.0,9\n400"),
                            "clash.csv"))
    with pytest.raises(ScenarioError, match=r"clash.csv: two rows at time 200 with different"):
        dkfsim.load_scenario(d)


def test_cicv5g_scenario_runs():
    import dkfsim
    sc = dkfsim.load_scenario(CICV, ["steps=300"])
    res = dkfsim.run(sc)
    truth = res["truth"]
    assert truth.shape == (300, 4)
    np.testing.assert_allclose(truth[0, [0, 2]], [0, 0], atol=0.05)   # origin: first
    speed = np.hypot(truth[:, 1], truth[:, 3])
    assert speed.max() < 25 and speed[-1] > 15      # up to ~20 m/s on the arterial road
    err = res["x_fused"][30:] - truth[30:]
    assert np.mean(err[:, 0] ** 2 + err[:, 2] ** 2) < 1.0   # well inside the 1 m^2 GNSS noise
    # The full scenario fits its track; one tick more than the track does not.
    full = dkfsim.load_scenario(CICV)
    have = full.truth.track().duration
    assert full.steps * full.model.T <= have
    from dkfsim.core.errors import ScenarioError
    too_many = int(have / full.model.T) + 1
    with pytest.raises(ScenarioError, match="truth.dataset cicv5g/arterial_n8_v70_run03 covers 55.21 s"):
        dkfsim.load_scenario(CICV, [f"steps={too_many}"])


def test_cicv5g_scenario_is_found_from_another_folder(tmp_path, monkeypatch):
    import dkfsim
    monkeypatch.chdir(tmp_path)
    sc = dkfsim.load_scenario(os.path.relpath(CICV, tmp_path))
    assert Path(sc.truth._path).samefile(DATA)

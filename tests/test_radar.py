"""The radar experiment (paper section V-D): converted range/azimuth measurements.

* the conversion against a hand-worked case, and its covariance against the
  spread of converted noisy measurements;
* the constant-velocity model's Phi and Q by hand;
* schema: radar keys, their errors, linear sensors unchanged;
* the radar scenario end to end;
* docs/design.md §6's oracle with per-row information: at zero latency every
  node equals a centralized filter computed here (covariance form) from the
  converted measurements; with latency <= d_t per hop every final estimate
  does;
* Monte Carlo: the fused estimate beats every radar's local-only filter
  (paired 95 % confidence intervals over runs, not single runs).
"""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pytest
import scipy.stats
import yaml
from reference import assert_close

ROOT = Path(__file__).resolve().parents[1]
RADAR = ROOT / "scenarios" / "radar_experiment.yaml"


def radar_dict():
    return yaml.safe_load(RADAR.read_text())


def load(d, overrides=()):
    import dkfsim
    return dkfsim.load_scenario(copy.deepcopy(d), overrides=list(overrides))


# ----------------------------------------------------------------------------- conversion
def test_converted_measurement_by_hand():
    from dkfsim.model.sensors import RadarSensor
    # Radar at (1, 2); the target seen at range 5 along the 3-4-5 direction.
    s = RadarSensor([1.0, 2.0], sigma_range=0.1, sigma_azimuth=0.04, nx=4)
    y = np.array([[5.0, np.arctan2(4.0, 3.0)]])
    z, Rc = s.convert(y)
    np.testing.assert_allclose(z, [[4.0, 6.0]], rtol=0, atol=1e-12)
    # R_c = J diag(0.01, 0.0016) J', J = [[0.6, -4], [0.8, 3]]:
    #   [0.36*0.01 + 16*0.0016, 0.48*0.01 - 12*0.0016] = [0.0292, -0.0144]
    #   [.., 0.64*0.01 + 9*0.0016] = 0.0208
    np.testing.assert_allclose(Rc[0], [[0.0292, -0.0144], [-0.0144, 0.0208]], rtol=1e-12)
    W = np.linalg.inv(np.array([[0.0292, -0.0144], [-0.0144, 0.0208]]))
    theta, omega, factor = s.information(y)
    assert theta.shape == (1, 4) and omega.shape == (1, 4, 4) and factor.shape == (1, 4, 2)
    idx = [0, 2]
    np.testing.assert_allclose(omega[0][np.ix_(idx, idx)], W, rtol=1e-12)
    np.testing.assert_allclose(theta[0, idx], W @ [4.0, 6.0], rtol=1e-12)
    assert np.all(omega[0][[1, 3]] == 0) and np.all(omega[0][:, [1, 3]] == 0)
    assert np.all(theta[0, [1, 3]] == 0) and np.all(factor[0][[1, 3]] == 0)
    np.testing.assert_allclose(factor[0] @ factor[0].T, omega[0], rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(s.H, [[1, 0, 0, 0], [0, 0, 1, 0]])
    np.testing.assert_allclose(s.R, np.diag([0.01, 0.0016]))


def test_state_index_places_the_position():
    from dkfsim.model.sensors import RadarSensor
    s = RadarSensor([0.0, 0.0], 0.1, 0.01, nx=6, state_index=(3, 1))
    y = np.array([[2.0, 0.3], [3.0, -1.0]])
    theta, omega, factor = s.information(y)
    z, Rc = s.convert(y)
    for r in range(2):
        W = np.linalg.inv(Rc[r])
        np.testing.assert_allclose(omega[r][np.ix_([3, 1], [3, 1])], W, rtol=1e-10)
        np.testing.assert_allclose(theta[r, [3, 1]], W @ z[r], rtol=1e-10)
        assert np.count_nonzero(omega[r]) == 4
    np.testing.assert_array_equal(s.H[0], np.eye(6)[3])
    np.testing.assert_array_equal(s.H[1], np.eye(6)[1])


def test_converted_covariance_matches_the_spread():
    """R_c is the linearised covariance: for 1 degree and 0.1 m at 6 m it must
    match the covariance of converted noisy measurements to a few per cent."""
    from dkfsim.model.sensors import RadarSensor
    s = RadarSensor([0.0, 0.0], 0.1, np.deg2rad(1.0), nx=4)
    truth = np.tile([[2.0, 0.0, 5.8, 0.0]], (200_000, 1))
    y = s.simulate(truth, np.random.default_rng(5))
    z, _ = s.convert(y)
    _, Rc = s.convert(s.polar(truth[:1]))
    C = np.cov(z.T)
    assert np.max(np.abs(C - Rc[0])) < 0.03 * np.max(np.abs(Rc[0]))
    # Conversion bias r sa^2 / 2 ~ 1e-3 m: far below sigma_range.
    assert np.all(np.abs(z.mean(axis=0) - [2.0, 5.8]) < 3e-3)


def test_measurement_noise_has_the_stated_spread():
    from dkfsim.model.sensors import RadarSensor
    s = RadarSensor([1.0, -1.0], 0.2, 0.03, nx=4)
    truth = np.column_stack([np.linspace(3, 9, 50_000), np.ones(50_000), np.full(50_000, 4.0),
                             np.zeros(50_000)])
    y = s.simulate(truth, np.random.default_rng(2))
    e = y - s.polar(truth)
    np.testing.assert_allclose(e.std(axis=0), [0.2, 0.03], rtol=0.02)
    assert abs(np.corrcoef(e.T)[0, 1]) < 0.02
    # The noise-free measurement by hand: range and azimuth of (3, 4) seen from (1, -1).
    np.testing.assert_allclose(s.polar(truth[:1]), [[np.hypot(2, 5), np.arctan2(5, 2)]])


# ----------------------------------------------------------------------------- schema
def test_constant_velocity_model_by_hand():
    d = radar_dict()
    d["model"] = {"kind": "constant_velocity", "dims": 2, "T": 0.5, "q": 2.0}
    m = load(d).model
    np.testing.assert_array_equal(m.Phi_matrix(), [[1, 0.5, 0, 0], [0, 1, 0, 0],
                                                   [0, 0, 1, 0.5], [0, 0, 0, 1]])
    block = 2.0 * np.array([[0.125 / 3, 0.125], [0.125, 0.5]])
    Q = np.zeros((4, 4))
    Q[:2, :2] = Q[2:, 2:] = block
    np.testing.assert_allclose(m.Q_matrix(), Q, rtol=1e-15)
    d["model"] = {"kind": "constant_velocity", "dims": 1, "T": 0.5, "q": 2.0}
    d["prior"] = {"mean": [0, 0], "cov": [[1, 0], [0, 1]]}
    d["sensors"] = [{"name": f"s{i}", "H": [1, 0], "R": 1.0} for i in range(3)]
    assert load(d).nx == 2


def test_radar_schema_round_trip_and_linear_unchanged():
    import dkfsim
    sc = load(radar_dict())
    assert [s.kind for s in sc.sensors] == ["radar"] * 3
    assert sc.sensors[0].state_index == (0, 2)
    assert load(sc.to_dict()) == sc
    case1 = dkfsim.load_scenario(ROOT / "scenarios" / "paper_case1.yaml")
    # Linear sensors (the default kind) serialise exactly as before sensor kinds existed.
    assert all(set(s) == {"name", "H", "R"} for s in case1.to_dict()["sensors"])
    assert all(s.kind == "linear" for s in case1.sensors)


@pytest.mark.parametrize("override, key, words", [
    ("sensors.0.sigma_range=-0.1", "sensors.0.sigma_range", ["must be > 0"]),
    ("sensors.1.sigma_azimuth=0", "sensors.1.sigma_azimuth", ["must be > 0"]),
    ("sensors.1.sigma_azimuth=1.0", "sensors.1.sigma_azimuth", ["radians"]),
    ("sensors.2.state_index=[0, 4]", "sensors.2.state_index", ["0..3", "[0, 4]"]),
    ("sensors.2.state_index=[2, 2]", "sensors.2.state_index", ["two different"]),
    ("sensors.0.position=[1, 2, 3]", "sensors.0.position", ["[x, y]"]),
    ("sensors.0.kind=radr", "sensors.0.kind", ["unknown sensor kind 'radr'", "did you mean 'radar'"]),
    ("sensors.0.sigma_rang=1", "sensors.0.sigma_rang", ["did you mean 'sigma_range'"]),
    ("model.q=-1", "model.q", ["must be >= 0"]),
    ("model.Q=[[1]]", "model.Q", ["not used with kind: constant_velocity"]),
    ("model.kind=constant_velosity", "model.kind", ["did you mean 'constant_velocity'"]),
])
def test_radar_errors(override, key, words):
    from dkfsim.core.errors import ScenarioError
    with pytest.raises(ScenarioError) as info:
        load(radar_dict(), [override])
    msg = str(info.value)
    assert msg.startswith(f"<dict>: {key}: "), msg
    assert "\n" not in msg
    for w in words:
        assert w in msg, msg


def test_missing_radar_key():
    from dkfsim.core.errors import ScenarioError
    d = radar_dict()
    del d["sensors"][1]["sigma_range"]
    with pytest.raises(ScenarioError, match=r"sensors\.1\.sigma_range: required key is missing"):
        load(d)


# ----------------------------------------------------------------------------- end to end
def test_radar_scenario_runs_end_to_end(tmp_path):
    import dkfsim
    sc = dkfsim.load_scenario(RADAR)
    assert sc.steps == 21 and sc.model.T == 0.01 and sc.n == 3
    assert sc.prior.mean[0] == 0.0 and sc.prior.mean[2] == 6.123
    res = dkfsim.run(sc)
    K, n, nx = 21, 3, 4
    assert res["x_fused"].shape == (K, nx) and res["x_local"].shape == (K, n, nx)
    for i in range(n):
        assert res[f"H_{i}"].shape == (2, nx) and res[f"R_{i}"].shape == (2, 2)
        assert res[f"y_{i}"].shape == (K, 2)
    for key in ("x_centralized", "x_centralized_delayed", "x_no_buffer"):
        assert res[key].shape == (K, nx) and np.isfinite(res[key]).all(), key
    for key in ("x_local_only", "x_ci_consensus"):            # per node
        assert res[key].shape == (K, n, nx) and np.isfinite(res[key]).all(), key
    # The polar measurements are near the truth's range and azimuth from each radar.
    for i, s in enumerate(sc.sensors):
        d = res["truth"][:, [0, 2]] - np.array(s.position)
        assert np.all(np.abs(res[f"y_{i}"][:, 0] - np.hypot(d[:, 0], d[:, 1])) < 0.6)
    out = res.save(tmp_path / "radar")
    with np.load(out / "run.npz") as z:
        assert z["y_0"].shape == (K, 2)
    # Rerun: bit-identical.
    again = dkfsim.run(sc)
    np.testing.assert_array_equal(again["x_fused"], res["x_fused"])


# ----------------------------------------------------------------------------- the oracle
def _centralized_by_hand(res, sc):
    """Covariance-form KF on all radars' converted measurements, per row, written
    independently of dkfsim.model.sensors (conversion formulas re-derived here)."""
    Phi, Q = res["Phi"], res["Q"]
    x, P = res["x0_mean"].copy(), res["P0"].copy()
    K = len(res["t"])
    xs, Ps = np.empty((K, 4)), np.empty((K, 4, 4))
    for r in range(K):
        x = Phi @ x
        P = Phi @ P @ Phi.T + Q
        for i, s in enumerate(sc.sensors):
            rng, az = res[f"y_{i}"][r]
            z = np.array(s.position) + rng * np.array([np.cos(az), np.sin(az)])
            J = np.array([[np.cos(az), -rng * np.sin(az)], [np.sin(az), rng * np.cos(az)]])
            Rc = J @ np.diag([s.sigma_range ** 2, s.sigma_azimuth ** 2]) @ J.T
            H = np.zeros((2, 4))
            H[0, s.state_index[0]] = H[1, s.state_index[1]] = 1.0
            S = H @ P @ H.T + Rc
            G = P @ H.T @ np.linalg.inv(S)
            x = x + G @ (z - H @ x)
            P = (np.eye(4) - G @ H) @ P @ (np.eye(4) - G @ H).T + G @ Rc @ G.T
        xs[r], Ps[r] = x, P
    return xs, Ps


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_zero_latency_every_node_is_the_centralized_filter(seed):
    import dkfsim
    sc = load(radar_dict(), ["links.default.latency={model: constant, value: 0}", f"seed={seed}",
                             "steps=60", "baselines=[centralized]"])
    res = dkfsim.run(sc)
    xc, Pc = _centralized_by_hand(res, sc)
    for i in range(sc.n):
        assert_close(res["x_local"][:, i], xc, f"node {i} x", tol=1e-9)
        assert_close(res["P_local"][:, i], Pc, f"node {i} P", tol=1e-9)
    assert_close(res["x_centralized"], xc, "x_centralized", tol=1e-9)


def test_bounded_latency_final_estimates_are_the_centralized_filter():
    import dkfsim
    sc = load(radar_dict(), ["steps=80", "baselines=[centralized]", "seed=4"])
    res = dkfsim.run(sc)
    L = int(res["buffer_length"])
    xc, _ = _centralized_by_hand(res, sc)
    done = sc.steps - L + 1           # rows that became final
    for i in range(sc.n):
        assert_close(res["x_final"][:done, i], xc[:done], f"node {i} final", tol=1e-9)
    # ... while the real-time estimates did miss information (the delays are real).
    assert np.max(np.abs(res["x_local"][:, 0] - xc)) > 1e-6


# ----------------------------------------------------------------------------- Monte Carlo
def _position_mse(x, truth):
    """Time-averaged (x, y) squared error; per node for (K, n, nx)."""
    if x.ndim == 3:
        truth = truth[:, None, :]
    return np.mean((x[..., 0] - truth[..., 0]) ** 2 + (x[..., 2] - truth[..., 2]) ** 2, axis=0)


def test_fused_beats_every_single_radar():
    """Paired over 150 independent runs: the time-averaged position MSE of the
    fused estimate is below each radar's local-only filter, with the upper end of
    the 95 % confidence interval of (fused - radar i) below zero for every i."""
    import dkfsim
    sc = load(radar_dict(), ["baselines=[local, centralized]"])
    runs = 150
    fused, local, cen = np.empty(runs), np.empty((runs, 3)), np.empty(runs)
    for r in range(runs):
        res = dkfsim.run(sc, seed=1000 + r, save="estimates")
        truth = res["truth"]
        fused[r] = _position_mse(res["x_fused"], truth)
        local[r] = _position_mse(res["x_local_only"], truth)
        cen[r] = _position_mse(res["x_centralized"], truth)
    t = scipy.stats.t.ppf(0.975, runs - 1)
    for i in range(3):
        d = fused - local[:, i]
        upper = d.mean() + t * d.std(ddof=1) / np.sqrt(runs)
        assert upper < 0, (i, fused.mean(), local[:, i].mean(), upper)
        # ... and by a clear margin: three radars' information against one.
        assert fused.mean() < 0.8 * local[:, i].mean()
    # The centralized filter (all data on time) is the lower bound.
    d = cen - fused
    assert d.mean() + t * d.std(ddof=1) / np.sqrt(runs) < 0


def test_run_npz_keeps_the_converted_measurements():
    """H_i, z_i and Rc_i reproduce the information the filters used, row by row."""
    import numpy as np

    import dkfsim
    from dkfsim.engine.driver import Run
    sc = dkfsim.load_scenario(RADAR, overrides=["steps=8"])
    a = dkfsim.run(sc).arrays
    info = Run(sc).ctx.info
    for i in range(3):
        z, Rc, H = a[f"z_{i}"], a[f"Rc_{i}"], a[f"H_{i}"]
        assert z.shape == (8, 2) and Rc.shape == (8, 2, 2)
        theta = np.einsum("ji,rjk,rk->ri", H, np.linalg.inv(Rc), z)      # H' Rc^-1 z
        omega = np.einsum("ji,rjk,kl->ril", H, np.linalg.inv(Rc), H)     # H' Rc^-1 H
        np.testing.assert_allclose(theta, info.theta[:, i], rtol=1e-9)
        np.testing.assert_allclose(omega, info.omega[:, i], rtol=1e-9, atol=1e-12)

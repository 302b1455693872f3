"""Metrics on hand-worked tiny arrays: intervals, the chi-square band, disagreement, NEES, sizes."""

from __future__ import annotations

import math

import numpy as np
import pytest

from dkfsim.analysis import metrics as M


def test_t_interval_hand_worked():
    # mean 3, s^2 = 10/4 = 2.5, t_{0.975, 4} = 2.7764451..., half = t * sqrt(2.5 / 5)
    mean, lo, hi = M.t_interval([1.0, 2.0, 3.0, 4.0, 5.0])
    half = 2.7764451051977934 * math.sqrt(0.5)
    assert mean == pytest.approx(3.0)
    assert lo == pytest.approx(3.0 - half, rel=1e-9)
    assert hi == pytest.approx(3.0 + half, rel=1e-9)


def test_t_interval_two_samples_and_axis():
    # two samples: t_{0.975, 1} = 12.7062047..., s = |a - b| / sqrt(2), half = t * |a - b| / 2
    samples = np.array([[0.0, 10.0], [2.0, 10.0]])      # runs along axis 0, two columns
    mean, lo, hi = M.t_interval(samples, axis=0)
    t1 = 12.706204736174694
    np.testing.assert_allclose(mean, [1.0, 10.0])
    np.testing.assert_allclose(lo, [1.0 - t1, 10.0], rtol=1e-9)
    np.testing.assert_allclose(hi, [1.0 + t1, 10.0], rtol=1e-9)


def test_quantiles_are_scipy_stats_bit_for_bit():
    # metrics avoids importing scipy.stats (half a second per process) but must give its numbers
    from scipy.stats import chi2, t
    for df in (1, 2, 3, 7, 29, 99, 999, 2999, 30_000):
        for q in (0.025, 0.05, 0.5, 0.95, 0.975):
            assert M.t_quantile(q, df) == t.ppf(q, df), (q, df)
            assert M.chi2_quantile(q, df) == chi2.ppf(q, df), (q, df)
    np.testing.assert_array_equal(M.nees_band(1000, 3), chi2.ppf([0.025, 0.975], 3000) / 1000)


def test_t_interval_of_one_sample_is_undefined():
    mean, lo, hi = M.t_interval([4.0])
    assert mean == 4.0 and math.isnan(lo) and math.isnan(hi)


def test_t_interval_from_running_moments_equals_direct():
    rng = np.random.default_rng(0)
    a = rng.normal(size=(7, 3))
    mean, m2 = a.mean(axis=0), ((a - a.mean(axis=0)) ** 2).sum(axis=0)
    lo, hi = M.t_interval_from_moments(mean, m2, 7)
    _, lo2, hi2 = M.t_interval(a)
    np.testing.assert_allclose(lo, lo2, rtol=1e-9)
    np.testing.assert_allclose(hi, hi2, rtol=1e-9)


def test_paired_lower_bound_hand_worked():
    # differences 1, 2, 3: mean 2, s = 1, t_{0.95, 2} = 2.9199856...
    lb = M.paired_lower_bound([0.0, 0.0, 0.0], [1.0, 2.0, 3.0])
    assert lb == pytest.approx(2.0 - 2.9199855803537242 / math.sqrt(3), rel=1e-9)
    # reversing the pair flips the sign of the mean: the bound is then negative
    assert M.paired_lower_bound([1.0, 2.0, 3.0], [0.0, 0.0, 0.0]) < 0


def test_nees_band_closed_form_for_two_degrees_of_freedom():
    # chi-square with 2 dof: ppf(p) = -2 ln(1 - p); one run of a 2-state filter
    band = M.nees_band(runs=1, nx=2)
    np.testing.assert_allclose(band, [-2 * math.log(0.975), -2 * math.log(0.025)], rtol=1e-10)
    # two runs of a scalar state: the same 2 dof, divided by the number of runs
    np.testing.assert_allclose(M.nees_band(runs=2, nx=1), band / 2, rtol=1e-10)


def test_nees_band_narrows_around_nx_with_more_runs():
    b10, b1000 = M.nees_band(10, 3), M.nees_band(1000, 3)
    assert b10[0] < b1000[0] < 3 < b1000[1] < b10[1]
    # normal approximation: mean nx, sd sqrt(2 nx / N)
    assert b1000[1] - 3 == pytest.approx(1.96 * math.sqrt(6 / 1000), rel=0.05)


def test_anees_summary_counts_ticks_inside_the_band():
    band = M.nees_band(4, 1)
    inside, outside = (band[0] + band[1]) / 2, band[1] * 2
    curve = np.array([100.0, inside, inside, outside, inside])      # row 0 is burn-in
    s = M.anees_summary(curve, runs=4, nx=1, burn_in=1)
    assert s["fraction_in_band"] == pytest.approx(0.75)
    assert s["anees"] == pytest.approx((3 * inside + outside) / 4)
    np.testing.assert_allclose(s["band"], band)
    none = M.anees_summary(np.full(5, np.nan), runs=4, nx=1, burn_in=1)
    assert math.isnan(none["anees"]) and math.isnan(none["fraction_in_band"])


def test_disagreement_hand_worked():
    x = np.array([[[0.0, 0.0], [2.0, 0.0], [1.0, 0.0]],
                  [[0.0, 0.0], [0.0, 0.0], [3.0, 0.0]]])
    # tick 0: mean (1,0), squared distances 1, 1, 0 -> 2/3
    # tick 1: mean (1,0), squared distances 1, 1, 4 -> 2
    np.testing.assert_allclose(M.disagreement_per_tick(x), [2 / 3, 2.0])
    assert M.disagreement(x, burn_in=1) == pytest.approx(2.0)
    assert M.disagreement(x, burn_in=0) == pytest.approx(4 / 3)


def test_squared_error_averages_over_nodes():
    truth = np.array([[1.0, 0.0], [0.0, 0.0]])
    x = np.array([[[1.0, 0.0], [3.0, 1.0]],        # errors (0,0) and (2,1)
                  [[0.0, 2.0], [0.0, 0.0]]])       # errors (0,2) and (0,0)
    np.testing.assert_allclose(M.squared_error(x, truth), [[2.0, 0.5], [0.0, 2.0]])
    np.testing.assert_allclose(M.squared_error(x[:, 1], truth), [[4.0, 1.0], [0.0, 0.0]])


def test_nees_per_tick_single_and_per_node():
    truth = np.zeros((1, 2))
    P = np.array([[[4.0, 0.0], [0.0, 1.0]]])
    # e = (2, 1): e' P^-1 e = 4/4 + 1/1 = 2
    assert M.nees_per_tick(np.array([[2.0, 1.0]]), P, truth) == pytest.approx([2.0])
    xn = np.array([[[2.0, 1.0], [0.0, 3.0]]])                     # second node: 0 + 9 = 9
    Pn = np.repeat(P[:, None], 2, axis=1)
    np.testing.assert_allclose(M.nees_per_tick(xn, Pn, truth), [5.5])


def test_packet_bytes_nominal_size():
    # Bytes are counted per packet by the port: header + rows * row_bytes (the row number,
    # theta and the upper triangle of omega as 8-byte floats, the origin bitmask).
    from dkfsim.protocols.base import PACKET_HEADER, row_bytes

    def packet_bytes(nx, n, rows=1):
        return PACKET_HEADER + rows * row_bytes(nx, n)
    # paper case 1: nx = 3 (3 + 6 numbers = 72 bytes), 12 nodes (2 bitmask bytes), 16 header
    # bytes, 8 bytes of row number per row
    assert packet_bytes(3, 12) == 16 + 8 + 72 + 2
    assert packet_bytes(3, 12, rows=3) == 16 + 3 * (8 + 74)
    assert packet_bytes(2, 8) == 16 + 8 + 8 * 5 + 1
    assert packet_bytes(2, 9) == 16 + 8 + 8 * 5 + 2


def test_existing_run_metrics_still_work():
    truth = np.zeros((4, 2))
    arrays = {"truth": truth, "x_local": np.ones((4, 3, 2)), "x_fused": np.full((4, 2), 2.0),
              "x_centralized": np.zeros((4, 2)), "x_final": np.ones((4, 3, 2)), "x0_mean": np.zeros(2)}
    from dkfsim.engine.results import RunResult
    m = RunResult(None, arrays, {}, {}).metrics(burn_in=1)      # run_metrics is res.metrics()
    assert m["fused"] == [4.0, 4.0] and m["local"] == [1.0, 1.0] and m["centralized"] == [0.0, 0.0]
    assert set(m) == {"burn_in", "fused", "local", "centralized"}

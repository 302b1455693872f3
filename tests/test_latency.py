"""Latency models: support, moments, exact nanoseconds, bounds, registry."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pydantic import ValidationError

from dkfsim.components.latency import Constant, Exponential, LatencyParams, Uniform, UniformSteps, parse_latency
from dkfsim.core.params import seconds_to_ns
from dkfsim.core.registry import LATENCY_MODELS

T_NS = 10_000_000  # T = 0.01 s
N = 200_000


def rng(seed=12345):
    return np.random.default_rng(seed)


# --------------------------------------------------------------------------- conversions
@pytest.mark.parametrize("seconds, ns", [(0.0, 0), (0.01, 10_000_000), (0.015, 15_000_000),
                                         (0.031, 31_000_000), (1e-9, 1), (2.5, 2_500_000_000),
                                         (0.1 + 0.2, 300_000_000)])
def test_seconds_to_ns_is_exact(seconds, ns):
    assert seconds_to_ns(seconds) == ns
    assert isinstance(seconds_to_ns(seconds), int)


# --------------------------------------------------------------------------- bounds
@pytest.mark.parametrize("spec, bound", [
    ({"model": "uniform_steps", "d_t": 4}, 4),
    ({"model": "uniform_steps", "d_t": 0}, 0),
    ({"model": "constant", "value": 0.02}, 2),
    ({"model": "constant", "value": 0.015}, 2),
    ({"model": "constant", "value": 0.0}, 0),
    ({"model": "constant", "value": 0.01}, 1),
    ({"model": "uniform", "low": 0.0, "high": 0.031}, 4),
    ({"model": "uniform", "low": 0.005, "high": 0.03}, 3),
    ({"model": "exponential", "mean": 0.01}, None),
    ({"model": "exponential", "mean": 0.01, "offset": 0.02}, None),
])
def test_bound_steps(spec, bound):
    assert parse_latency(spec).bound_steps(T_NS) == bound


def test_bound_steps_covers_every_sample():
    for spec in ({"model": "uniform", "low": 0.001, "high": 0.031},
                 {"model": "constant", "value": 0.015},
                 {"model": "uniform_steps", "d_t": 3}):
        m = parse_latency(spec)
        s = m.sample_ns(rng(), 10_000, T_NS)
        assert s.max() <= m.bound_steps(T_NS) * T_NS
        # and the bound is the smallest such d
        assert m.bound_steps(T_NS) == 0 or m.sup_ns(T_NS) > (m.bound_steps(T_NS) - 1) * T_NS


# --------------------------------------------------------------------------- samples
def test_constant_samples_exact_ns():
    m = Constant(value=0.015)
    s = m.sample_ns(rng(), 1000, T_NS)
    assert s.dtype == np.int64
    assert s.shape == (1000,)
    assert np.all(s == 15_000_000)


def test_default_constant_is_zero():
    assert np.all(Constant().sample_ns(rng(), 5, T_NS) == 0)


def test_uniform_steps_support_and_frequencies():
    m = UniformSteps(d_t=4)
    s = m.sample_ns(rng(), N, T_NS)
    assert s.dtype == np.int64
    assert np.all(s % T_NS == 0)
    d = s // T_NS
    values, counts = np.unique(d, return_counts=True)
    assert values.tolist() == [0, 1, 2, 3, 4]
    freq = counts / N
    # each delay value has probability 1/(d_t+1) = 0.2; 5 standard errors
    se = np.sqrt(0.2 * 0.8 / N)
    assert np.all(np.abs(freq - 0.2) < 5 * se), freq


def test_uniform_steps_zero_is_zero():
    assert np.all(UniformSteps(d_t=0).sample_ns(rng(), 100, T_NS) == 0)


def test_uniform_steps_uses_T_ns_exactly():
    s = UniformSteps(d_t=2).sample_ns(rng(), 1000, 3)  # T = 3 ns
    assert set(np.unique(s).tolist()) == {0, 3, 6}


def test_uniform_support_and_moments():
    low, high = 0.001, 0.031
    m = Uniform(low=low, high=high)
    s = m.sample_ns(rng(), N, T_NS)
    assert s.dtype == np.int64
    assert s.min() >= 1_000_000 and s.max() <= 31_000_000
    mean = (low + high) / 2 * 1e9
    sd = (high - low) / np.sqrt(12) * 1e9
    assert abs(s.mean() - mean) < 5 * sd / np.sqrt(N)
    assert abs(s.std() - sd) / sd < 0.01
    # continuous: many distinct values, not a lattice of T
    assert len(np.unique(s)) > N // 2


def test_uniform_degenerate_interval():
    s = Uniform(low=0.02, high=0.02).sample_ns(rng(), 100, T_NS)
    assert np.all(s == 20_000_000)


def test_exponential_support_and_moments():
    m = Exponential(mean=0.01, offset=0.002)
    s = m.sample_ns(rng(), N, T_NS)
    assert s.dtype == np.int64
    assert s.min() >= 2_000_000
    excess = (s - 2_000_000) / 1e9
    # Exp(mean): mean = sd = 0.01
    assert abs(excess.mean() - 0.01) < 5 * 0.01 / np.sqrt(N)
    assert abs(excess.std() - 0.01) / 0.01 < 0.02
    # P(excess > mean) = e^-1
    assert abs(np.mean(excess > 0.01) - np.exp(-1)) < 0.005


def test_samples_shape_and_reproducibility():
    for m in (Constant(value=0.01), UniformSteps(d_t=3), Uniform(high=0.02),
              Exponential(mean=0.005)):
        a = m.sample_ns(rng(7), (3, 4), T_NS)
        b = m.sample_ns(rng(7), (3, 4), T_NS)
        assert a.shape == (3, 4) and a.dtype == np.int64
        assert np.array_equal(a, b)


# --------------------------------------------------------------------------- parsing
@pytest.mark.parametrize("spec", [
    {"model": "constant", "value": 0.02},
    {"model": "uniform_steps", "d_t": 4},
    {"model": "uniform", "low": 0.001, "high": 0.031},
    {"model": "exponential", "mean": 0.01, "offset": 0.001},
])
def test_to_dict_round_trip(spec):
    m = parse_latency(spec)
    d = m.to_dict()
    assert d["model"] == spec["model"]
    assert parse_latency(d) == m
    assert type(parse_latency(d)) is type(m)


@pytest.mark.parametrize("spec", [
    {"model": "constant", "value": -0.001},
    {"model": "uniform_steps", "d_t": -1},
    {"model": "uniform_steps", "d_t": 1.5},
    {"model": "uniform", "low": -0.1, "high": 0.1},
    {"model": "uniform", "low": 0.02, "high": 0.01},
    {"model": "exponential", "mean": 0.0},
    {"model": "exponential", "mean": 0.01, "offset": -1.0},
    {"model": "constant", "value": float("inf")},
    {"model": "constant", "valu": 0.1},
    {"model": "gaussian", "mean": 0.1},
    {"value": 0.1},
])
def test_invalid_parameters_rejected(spec):
    with pytest.raises(ValidationError):
        parse_latency(spec)


def test_registry_lists_models():
    assert set(LATENCY_MODELS.names()) >= {"constant", "uniform_steps", "uniform", "exponential"}
    for entry in LATENCY_MODELS.entries():
        cls = entry.params
        assert issubclass(cls, LatencyParams)
        assert cls.model_fields["model"].default == entry.name
        assert entry.name in LATENCY_MODELS


def test_register_rejects_duplicate_name():
    from typing import Literal

    class Again(LatencyParams):
        model: Literal["constant"] = "constant"

    with pytest.raises(ValueError):
        LATENCY_MODELS.register("constant")(Again)
    assert LATENCY_MODELS.get("constant").params is Constant


def test_models_are_frozen():
    m = UniformSteps(d_t=2)
    with pytest.raises(ValidationError):
        m.d_t = 3


# =========================================================================== issue 4: new models
import math  # noqa: E402

from scipy import stats  # noqa: E402

from dkfsim.components.latency import Gamma, GilbertElliott, Lognormal, Pareto, read_column  # noqa: E402
from dkfsim.core.datafiles import DATA_DIR, resolve_data_file  # noqa: E402
from dkfsim.core.streams import key64, keyed_uniform, keyed_uniforms  # noqa: E402

CICV = DATA_DIR / "cicv5g"                  # shipped inside the package
URBAN = CICV / "urban_n8_v30_run01.txt"
N_KS = 20_000


def _seconds(model, n=N_KS, seed=2024, offset=0.0):
    return model.sample_ns(rng(seed), n, T_NS) / 1e9 - offset


# KS at a fixed seed: the samples follow the law; the same samples reject a law
# whose parameter is 10 % off (so the test has power to fail).
@pytest.mark.parametrize("model, law, wrong", [
    (Lognormal(median=0.02, sigma=0.5, offset=0.003),
     stats.lognorm(s=0.5, scale=0.02), stats.lognorm(s=0.5, scale=0.022)),
    (Gamma(shape=2.0, scale=0.005, offset=0.001),
     stats.gamma(a=2.0, scale=0.005), stats.gamma(a=2.0, scale=0.0055)),
    (Pareto(alpha=1.5, scale=0.005, offset=0.002),
     stats.pareto(b=1.5, scale=0.005), stats.pareto(b=1.65, scale=0.005)),
    (Exponential(mean=0.01, offset=0.002),
     stats.expon(scale=0.01), stats.expon(scale=0.011)),
    (Uniform(low=0.001, high=0.031),
     stats.uniform(loc=0.001, scale=0.030), stats.uniform(loc=0.001, scale=0.033)),
], ids=["lognormal", "gamma", "pareto", "exponential", "uniform"])
def test_continuous_models_follow_their_law(model, law, wrong):
    x = _seconds(model, offset=getattr(model, "offset", 0.0))
    assert stats.kstest(x, law.cdf).pvalue > 0.01
    assert stats.kstest(x, wrong.cdf).pvalue < 1e-4


def test_uniform_steps_moments():
    d_t = 4
    d = UniformSteps(d_t=d_t).sample_ns(rng(), N, T_NS) // T_NS
    mean, var = d_t / 2, ((d_t + 1) ** 2 - 1) / 12
    assert abs(d.mean() - mean) < 5 * math.sqrt(var / N)
    assert abs(d.var() - var) / var < 0.01


def test_lognormal_median_and_sigma_mean_what_they_say():
    s = Lognormal(median=0.02, sigma=0.4).sample_ns(rng(), N, T_NS) / 1e9
    assert abs(np.median(s) - 0.02) / 0.02 < 0.01
    assert abs(np.log(s).std() - 0.4) < 0.01


def test_pareto_scale_is_the_minimum():
    s = Pareto(alpha=2.5, scale=0.004, offset=0.001).sample_ns(rng(), N, T_NS)
    assert s.min() >= 5_000_000 and s.min() < 5_001_000


@pytest.mark.parametrize("spec, bound", [
    ({"model": "lognormal", "median": 0.01, "sigma": 0.5}, None),
    ({"model": "lognormal", "median": 0.015, "sigma": 0.0}, 2),
    ({"model": "gamma", "shape": 2.0, "scale": 0.01}, None),
    ({"model": "pareto", "alpha": 1.5, "scale": 0.01}, None),
    ({"model": "gilbert_elliott", "p_good_to_bad": 0.1, "p_bad_to_good": 0.5,
      "good": {"model": "constant", "value": 0.01}, "bad": {"model": "uniform", "high": 0.031}}, 4),
    ({"model": "gilbert_elliott", "p_good_to_bad": 0.1, "p_bad_to_good": 0.5,
      "good": {"model": "constant", "value": 0.01}, "bad": {"model": "pareto", "alpha": 2, "scale": 0.01}},
     None),
])
def test_new_bounds(spec, bound):
    assert parse_latency(spec).bound_steps(T_NS) == bound


@pytest.mark.parametrize("spec", [
    {"model": "lognormal", "median": 0.0, "sigma": 0.5},
    {"model": "lognormal", "median": 0.01, "sigma": -0.1},
    {"model": "lognormal", "mu": 0.01, "sigma": 0.1},
    {"model": "gamma", "shape": 0.0, "scale": 0.01},
    {"model": "gamma", "shape": 1.0, "scale": -0.01},
    {"model": "pareto", "alpha": 0.0, "scale": 0.01},
    {"model": "pareto", "alpha": 1.0},
    {"model": "gilbert_elliott", "p_good_to_bad": 1.5, "p_bad_to_good": 0.5,
     "good": {"model": "constant"}, "bad": {"model": "constant"}},
    {"model": "gilbert_elliott", "p_good_to_bad": 0.0, "p_bad_to_good": 0.0,
     "good": {"model": "constant"}, "bad": {"model": "constant"}},
    {"model": "gilbert_elliott", "p_good_to_bad": 0.1, "p_bad_to_good": 0.5,
     "good": {"model": "constant"},
     "bad": {"model": "gilbert_elliott", "p_good_to_bad": 0.1, "p_bad_to_good": 0.5,
             "good": {"model": "constant"}, "bad": {"model": "constant"}}},
    {"model": "empirical", "file": "no/such/file.txt"},
])
def test_new_invalid_parameters_rejected(spec):
    with pytest.raises(ValidationError):
        parse_latency(spec)


# --------------------------------------------------------------------------- empirical
def test_empirical_reads_the_cicv5g_column_whatever_its_spelling():
    a = read_column(URBAN, "delay(ms)")
    assert len(a) == 4432
    assert np.array_equal(a, read_column(URBAN, "delay_ms"))
    assert np.array_equal(a, read_column(URBAN, 2))
    assert (np.median(a), a.max()) == (18.0, 261.0)      # as the data README says
    with pytest.raises(ValueError, match="no column 'dealy'"):
        read_column(URBAN, "dealy")


def test_empirical_resample_reproduces_the_trace_distribution():
    m = parse_latency({"model": "empirical", "file": str(URBAN), "one_way": True})
    s = m.sample_ns(rng(), N_KS, T_NS)
    trace_ns = read_column(URBAN, "delay_ms") * 0.5e6           # one way: RTT / 2
    assert set(np.unique(s)) <= set(trace_ns.astype(np.int64))
    assert stats.ks_2samp(s, trace_ns).pvalue > 0.01
    # bounded by the trace's largest value (261 ms / 2)
    assert m.sup_ns(T_NS) == 130_500_000 and m.bound_steps(T_NS) == 14
    # and a 10 % scale is detected
    assert stats.ks_2samp(s, trace_ns * 1.1).pvalue < 1e-4


def _free_start(seed, u, v, rows):
    """The replay start of link (u, v) when the scenario gives none: one keyed draw
    from the link's ``start`` name."""
    return min(int(keyed_uniform(key64(seed, "link", u, v, "start"), 0, 0) * rows), rows - 1)


def test_empirical_replay_plays_one_row_per_tick_and_cycles():
    raw = read_column(URBAN, "delay_ms")
    m = parse_latency({"model": "empirical", "file": str(URBAN), "mode": "replay",
                       "start": 4430, "unit": "ms", "scale": 2.0})
    expect = (np.concatenate([raw[4430:], raw[:8]]) * 2e6).astype(np.int64)
    smp = m.sampler(("link", 0, 1), 7, T_NS)
    # a packet sent during tick k (t in [k T, (k+1) T)) takes row start + k, cycling,
    # whatever its instant inside the tick and its number among that instant's packets
    for k in range(10):
        for t in (k * T_NS, k * T_NS + 1, k * T_NS + T_NS // 2, (k + 1) * T_NS - 1):
            for seq in (0, 1, 5):
                assert smp.draw(t, seq) == (int(expect[k]), False), (k, t, seq)
    # the row is a function of the send instant only: a fresh sampler (another link,
    # another seed: the start is explicit) queried backwards gives the same rows
    other = m.sampler(("link", 3, 2), 99, T_NS)
    assert [other.draw(k * T_NS, 0)[0] for k in reversed(range(10))] == expect[::-1].tolist()
    # a link's sampler without start: a random start keyed by the link, then one row per
    # tick (6000 ticks: the trace of 4432 rows cycles)
    free = parse_latency({"model": "empirical", "file": str(URBAN), "mode": "replay"})
    smp = free.sampler(("link", 0, 1), 7, T_NS)
    ticks = np.arange(6000)
    got = np.array([smp.draw(int(k) * T_NS + int(k * 7919) % T_NS, int(k) % 3)[0] for k in ticks])
    start = _free_start(7, 0, 1, len(raw))
    idx = (start + ticks) % len(raw)
    assert np.array_equal(got, (raw[idx] * 1e6).astype(np.int64))
    # each link draws its own start
    starts = {_free_start(7, u, v, len(raw)) for u, v in ((0, 1), (1, 0), (1, 2), (2, 1))}
    assert len(starts) > 1
    first = {free.sampler(("link", u, v), 7, T_NS).draw(0, 0)[0] for u, v in ((0, 1), (1, 0), (1, 2), (2, 1))}
    assert first == {int(raw[_free_start(7, u, v, len(raw))] * 1e6)
                     for u, v in ((0, 1), (1, 0), (1, 2), (2, 1))}


def test_empirical_csv_relative_path_and_errors(tmp_path):
    sub = tmp_path / "scen"
    sub.mkdir()
    (sub / "trace.csv").write_text("# a comment\nt,lat_s\n0,0.010\n1,0.030\n\n2,0.020\n")
    m = parse_latency({"model": "empirical", "file": "trace.csv", "column": "lat_s",
                       "unit": "s", "mode": "replay", "start": 0}, base_dir=sub)
    smp = m.sampler(("link", 0, 1), 1, T_NS)          # replay: one row per tick
    assert [smp.draw(k * T_NS, 0)[0] for k in range(4)] == [10_000_000, 30_000_000, 20_000_000,
                                                             10_000_000]
    assert m.bound_steps(T_NS) == 3
    path, tried = resolve_data_file("trace.csv", tmp_path)
    assert path is None and tried == [tmp_path / "trace.csv"]     # the scenario's folder only
    with pytest.raises(ValidationError, match="file not found"):
        parse_latency({"model": "empirical", "file": "trace.csv"}, base_dir=tmp_path)
    (sub / "bad.csv").write_text("lat\n0.01\nabc\n")
    with pytest.raises(ValidationError, match="line 3: column 0 is not a number"):
        parse_latency({"model": "empirical", "file": "bad.csv", "column": "lat"}, base_dir=sub)
    with pytest.raises(ValidationError, match="only used with mode: replay"):
        parse_latency({"model": "empirical", "file": "trace.csv", "column": 1, "start": 0},
                      base_dir=sub)


# --------------------------------------------------------------------------- Gilbert-Elliott
def _ge(p_gb, p_bg, **kw):
    return GilbertElliott(p_good_to_bad=p_gb, p_bad_to_good=p_bg,
                          good=Constant(value=0.001), bad=Constant(value=0.1), **kw)


def test_gilbert_elliott_stationary_fraction_and_burst_length_per_tick():
    """The chain steps once per tick per link: the fraction of bad TICKS is the
    stationary law, bad bursts last 1 / p_bad_to_good ticks on average, and every
    packet sent during a tick sees that tick's state (its loss drawn per packet)."""
    p_gb, p_bg = 0.05, 0.2
    m = _ge(p_gb, p_bg, loss_good=0.01, loss_bad=0.4)
    smp = m.sampler(("link", 0, 1), 3, T_NS)
    n = 204_800                                                     # ticks
    bad = np.array([smp.state(k) for k in range(n)])
    assert abs(bad.mean() - m.stationary_bad()) < 0.01              # 0.2
    assert m.stationary_bad() == pytest.approx(p_gb / (p_gb + p_bg))
    # runs of consecutive bad ticks: geometric with mean 1 / p_bg = 5
    edges = np.diff(np.concatenate([[0], bad.astype(int), [0]]))
    runs = np.flatnonzero(edges == -1) - np.flatnonzero(edges == 1)
    assert abs(runs.mean() - 1 / p_bg) < 0.15
    good_runs_mean = (len(bad) - bad.sum()) / len(runs)
    assert abs(good_runs_mean - 1 / p_gb) < 1.0
    # an i.i.d. channel with the same bad fraction has runs of mean 1/(1-0.2) = 1.25: the
    # burstiness test can fail
    assert runs.mean() > 3
    # two packets per tick, at different instants of the tick: both see the tick's state
    offs = np.random.default_rng(0).integers(0, T_NS, size=n)
    d0 = [smp.draw(k * T_NS, 0) for k in range(n)]
    d1 = [smp.draw(k * T_NS + int(o), 1) for k, o in zip(range(n), offs)]
    lat0 = np.array([d[0] for d in d0])
    lat1 = np.array([d[0] for d in d1])
    lost0 = np.array([d[1] for d in d0])
    lost1 = np.array([d[1] for d in d1])
    assert np.array_equal(lat0 == 100_000_000, bad) and np.array_equal(lat1 == 100_000_000, bad)
    assert np.all((lat0 == 100_000_000) | (lat0 == 1_000_000))
    # losses per state
    assert abs(lost0[bad].mean() - 0.4) < 0.01
    assert abs(lost0[~bad].mean() - 0.01) < 0.002
    assert abs(lost1[bad].mean() - 0.4) < 0.01
    # ... drawn per packet: two packets of one bad tick are lost independently
    both = (lost0 & lost1)[bad].mean()
    assert abs(both - 0.4 ** 2) < 0.01, both
    # the states are a function of the tick: a fresh sampler queried out of order agrees
    again = m.sampler(("link", 0, 1), 3, T_NS)
    probe = np.random.default_rng(1).integers(0, n, size=500)
    assert all(again.state(int(k)) == bad[k] for k in probe[::-1])
    assert [again.draw(int(k) * T_NS, 0) for k in probe] == [d0[k] for k in probe]
    # another link has its own chain
    other = m.sampler(("link", 1, 0), 3, T_NS)
    other_bad = np.array([other.state(k) for k in range(n)])
    assert abs(other_bad.mean() - m.stationary_bad()) < 0.01
    assert abs(np.corrcoef(bad, other_bad)[0, 1]) < 0.02


def test_gilbert_elliott_stationary_initial_state():
    """initial: stationary starts each link's chain bad with the stationary probability."""
    m = _ge(0.05, 0.2)
    first = np.array([m.sampler(("link", i, i + 1), 11, T_NS).state(0) for i in range(4000)])
    p = m.stationary_bad()
    assert abs(first.mean() - p) < 5 * np.sqrt(p * (1 - p) / len(first))


def test_gilbert_elliott_initial_state_and_no_loss():
    smp = _ge(0.0, 0.5, initial="good").sampler(("link", 0, 1), 1, T_NS)
    assert [smp.draw(k * T_NS, 0) for k in range(100)] == [(1_000_000, False)] * 100
    assert not any(smp.state(k) for k in range(100))
    smp = _ge(0.0, 1.0, initial="bad").sampler(("link", 0, 1), 1, T_NS)
    assert [smp.draw(k * T_NS, 0)[0] for k in range(5)] == [100_000_000] + [1_000_000] * 4
    assert [smp.state(k) for k in range(5)] == [True] + [False] * 4
    # every packet of the bad tick 0 is bad; no loss model: never lost
    assert {smp.draw(t, q) for t in (0, 1, T_NS - 1) for q in range(4)} == {(100_000_000, False)}
    assert {smp.draw(T_NS + t, q) for t in (0, 1, T_NS - 1) for q in range(4)} == {(1_000_000, False)}
    # stateless sample_ns: reproducible from the generator
    m = _ge(0.1, 0.3)
    assert np.array_equal(m.sample_ns(rng(5), (4, 5), T_NS), m.sample_ns(rng(5), (4, 5), T_NS))


@pytest.mark.parametrize("spec", [
    {"model": "lognormal", "median": 0.01, "sigma": 0.3, "offset": 0.001},
    {"model": "gamma", "shape": 2.0, "scale": 0.003},
    {"model": "pareto", "alpha": 1.2, "scale": 0.002, "offset": 0.0},
    {"model": "gilbert_elliott", "p_good_to_bad": 0.1, "p_bad_to_good": 0.3,
     "good": {"model": "uniform_steps", "d_t": 1}, "bad": {"model": "exponential", "mean": 0.05},
     "loss_bad": 0.2, "initial": "bad"},
])
def test_new_models_round_trip(spec):
    m = parse_latency(spec)
    assert parse_latency(m.to_dict()) == m


def test_the_scalar_keyed_draw_is_the_vectorised_one_bit_for_bit():
    """``keyed_uniform`` (pure Python, once per packet or frame; its constants bound as
    defaults, decision 237) and ``keyed_uniforms`` (numpy uint64) are the same function: equal
    floats over keys across the 64-bit range, instants up to the latest and large seqs."""
    g = np.random.default_rng(5)
    keys = [0, 1, (1 << 63) - 1, 1 << 63, (1 << 64) - 1, key64(3, "channel", 0, 2, "backoff")]
    ts = np.concatenate([[0, 1, (1 << 62) - 1], g.integers(0, 1 << 62, size=500)])
    seqs = np.concatenate([[0, 1, 1 << 30], g.integers(0, 1 << 20, size=500)])
    for key in keys:
        want = keyed_uniforms(key, ts, seqs)
        got = np.array([keyed_uniform(key, int(t), int(q)) for t, q in zip(ts, seqs)])
        assert np.array_equal(got, want)
        assert 0.0 < got.min() and got.max() < 1.0


def test_iid_sampler_draws_are_keyed_quantiles():
    """A link draws i.i.d. models through ``sampler``: the model's quantile function of
    one keyed uniform per (send instant, seq) -- a pure function of the link, the
    instant and the packet's number at that instant, whatever was drawn before."""
    g = np.random.default_rng(0)
    ts = g.integers(0, 10**12, size=3000)
    seqs = g.integers(0, 5, size=3000)
    for m in (UniformSteps(d_t=4), Uniform(high=0.02), Exponential(mean=0.005),
              Lognormal(median=0.01, sigma=0.3)):
        smp = m.sampler(("link", 2, 3), 9, T_NS)
        draws = [smp.draw(int(t), int(q)) for t, q in zip(ts, seqs)]
        a = np.array([d[0] for d in draws])
        assert not any(d[1] for d in draws)                           # i.i.d. models never lose
        key = key64(9, "link", 2, 3, "latency")
        assert np.array_equal(a, m.from_uniform(keyed_uniforms(key, ts, seqs), T_NS))
        assert a[0] == int(m.from_uniform(keyed_uniform(key, int(ts[0]), int(seqs[0])), T_NS))
        # pure: a fresh sampler queried in reverse order gives the same draws
        again = m.sampler(("link", 2, 3), 9, T_NS)
        b = np.array([again.draw(int(t), int(q))[0] for t, q in zip(ts[::-1], seqs[::-1])])[::-1]
        assert np.array_equal(a, b)
        # another link, another seed, another seq: other draws
        for o in (m.sampler(("link", 3, 2), 9, T_NS), m.sampler(("link", 2, 3), 10, T_NS)):
            c = np.array([o.draw(int(t), int(q))[0] for t, q in zip(ts, seqs)])
            assert np.mean(a == c) < 0.3
        c = np.array([smp.draw(int(t), int(q) + 1)[0] for t, q in zip(ts, seqs)])
        assert np.mean(a == c) < 0.3


def test_keyed_draws_follow_the_model_law():
    """The keyed uniforms over a run's send instants and seqs are U(0, 1), so a link's
    draws follow the law sample_ns follows (KS, with power to reject a 10 % error)."""
    key = key64(4, "link", 0, 1, "latency")
    k = np.arange(N_KS)
    t, q = (k // 2) * T_NS, k % 2                              # two packets per tick
    u = keyed_uniforms(key, t, q)
    assert u.min() > 0 and u.max() < 1
    assert stats.kstest(u, "uniform").pvalue > 0.01
    assert all(keyed_uniform(key, int(a), int(b)) == v for a, b, v in zip(t[:200], q[:200], u[:200]))
    m = Exponential(mean=0.01, offset=0.002)
    smp = m.sampler(("link", 0, 1), 4, T_NS)
    x = np.array([smp.draw(int(a), int(b))[0] for a, b in zip(t, q)]) / 1e9 - 0.002
    assert stats.kstest(x, stats.expon(scale=0.01).cdf).pvalue > 0.01
    assert stats.kstest(x, stats.expon(scale=0.011).cdf).pvalue < 1e-4
    y = _seconds(m, offset=0.002)
    assert stats.ks_2samp(x, y).pvalue > 0.01


@settings(max_examples=300, deadline=None)
@given(st.one_of(st.floats(allow_nan=False), st.floats(min_value=-3, max_value=3),
                 st.integers(-10, 10).map(lambda k: k / 2), st.floats(min_value=2.0**62 - 4096, max_value=2.0**63)))
def test_one_latency_is_clamped_as_an_array_of_them_is(ns):
    """The per-packet rounding (a port's draw) is the array path's, half to even, clipped to
    [0, MAX_NS]: a difference would change a run's draws."""
    from dkfsim.components.latency import _clamped, _clamped_one
    assert _clamped_one(np.float64(ns)) == int(_clamped(np.float64(ns)))

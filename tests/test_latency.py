"""Latency models: support, moments, exact nanoseconds, bounds, registry."""

from __future__ import annotations

import numpy as np
import pytest
from pydantic import ValidationError

from dkfsim.latency import (LATENCY_MODELS, Constant, Exponential, LatencyBase, Uniform,
                            UniformSteps, parse_latency, register, seconds_to_ns)

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
    assert set(LATENCY_MODELS) >= {"constant", "uniform_steps", "uniform", "exponential"}
    for name, cls in LATENCY_MODELS.items():
        assert issubclass(cls, LatencyBase)
        assert cls.model_fields["model"].default == name


def test_register_rejects_duplicate_name():
    from typing import Literal

    class Again(LatencyBase):
        model: Literal["constant"] = "constant"

    with pytest.raises(ValueError):
        register(Again)
    assert LATENCY_MODELS["constant"] is Constant


def test_models_are_frozen():
    m = UniformSteps(d_t=2)
    with pytest.raises(ValidationError):
        m.d_t = 3

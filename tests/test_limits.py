"""Large networks must fail early and clearly, or fit: memory guards of a run."""

from __future__ import annotations

from pathlib import Path

import pytest
from conftest import scenario

import dkfsim
import dkfsim.config.plan as plan_module
import dkfsim.config.schema as schema
import dkfsim.estimators.anti_delay as anti_delay
from dkfsim.config.plan import RunPlan
from dkfsim.core.errors import ScenarioError


def test_matrix_fusion_too_large_is_a_clear_error(monkeypatch):
    monkeypatch.setattr(schema, "FUSION_MEMORY_LIMIT", 1_000)   # (L+1)(n nx)^2 8 = 4096 B here
    # checked when the scenario is validated
    with pytest.raises(ScenarioError, match="fusion: matrix fusion keeps the cross-covariances") as err:
        dkfsim.load_scenario(scenario(8, steps=5))
    assert "fusion: none" in str(err.value) and "fusion" == err.value.path
    assert "fusion: fusion" not in str(err.value)       # (the key once, then what it keeps)
    # fusion: none runs.
    assert dkfsim.run(dkfsim.load_scenario(scenario(8, steps=5, fusion="none")))["x_local"].shape == (5, 8, 2)


def test_p_local_is_kept_only_when_it_will_be_saved_and_fits(monkeypatch):
    sc = dkfsim.load_scenario(scenario(4, steps=6))
    assert "P_local" in dkfsim.run(sc, save="estimates").arrays
    assert "P_local" not in dkfsim.run(sc, save="summary").arrays
    monkeypatch.setattr(anti_delay, "P_LOCAL_LIMIT", 10)
    res = dkfsim.run(sc, save="full")
    assert "P_local" not in res.arrays and "x_local" in res.arrays and "arrival" in res.arrays


def test_late_bookkeeping_is_bounded_by_the_latency_bound():
    bounded = RunPlan(dkfsim.load_scenario(scenario(4, latency={"model": "uniform_steps", "d_t": 3})))
    assert bounded.late_horizon(7, 4) == 5
    unbounded = RunPlan(dkfsim.load_scenario(scenario(4, latency={"model": "exponential", "mean": 0.1},
                                                      buffer_length=3)))
    assert unbounded.late_horizon(3, 4) == 4096
    # 1000 nodes: the kept holdings stay near 64 MB instead of ~0.7 GB.
    assert unbounded.late_horizon(3, 1000) < 500


def test_a_delay_bound_longer_than_the_run_costs_no_memory():
    """L = 10^11 + 1 (a latency of 10^9 s): the window ring is capped at the run's rows."""
    d = scenario(3, steps=6, latency={"model": "constant", "value": 1e9})
    sc = dkfsim.load_scenario(d)
    assert RunPlan(sc).buffer_length() > 10**10
    res = dkfsim.run(sc)
    a = res.arrays
    # Nothing ever arrives: every node is its own local filter, no row is ever final.
    assert res.counts["delivered"] == 0 and res.counts["in_flight"] == res.counts["sent"]
    import numpy as np
    from reference import node_estimates
    ref = node_estimates(a)
    np.testing.assert_allclose(a["x_local"], ref["x_local"], rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(a["x_final"], ref["x_final"], rtol=1e-9, atol=1e-12)


def test_save_summary_removes_a_stale_run_npz(tmp_path):
    sc = dkfsim.load_scenario(scenario(3, steps=5))
    dkfsim.run(sc, seed=5).save(tmp_path)
    assert (tmp_path / "run.npz").exists()
    dkfsim.run(sc, save="summary").save(tmp_path)
    assert not (tmp_path / "run.npz").exists() and (tmp_path / "summary.json").exists()


def test_a_run_saved_as_summary_reads_back_its_rows_and_refuses_another_burn_in(tmp_path):
    """issue 24: `RunResult.to_frame()` of a `--save summary` folder (no run.npz) raised KeyError."""
    sc = dkfsim.load_scenario(scenario(3, steps=20))
    full, summary = dkfsim.run(sc, save="estimates"), dkfsim.run(sc, save="summary")
    summary.save(tmp_path)
    back = dkfsim.load(tmp_path)
    assert not back.arrays
    frame, expected = back.to_frame(), summary.to_frame()      # the rows of the run in memory
    assert list(frame.columns) == list(expected.columns) and len(frame) == len(expected)
    for col in ("estimate", "component"):
        assert list(frame[col]) == list(expected[col])
    for col in ("mse", "anees", "messages_per_tick", "bytes_per_tick"):
        assert frame[col].to_numpy() == pytest.approx(expected[col].to_numpy(), rel=1e-12, nan_ok=True)
    got, want = back.metrics(), full.metrics()
    assert set(got) == set(want) and got["burn_in"] == want["burn_in"]
    for name in full.estimates:
        assert got[name] == pytest.approx(want[name], rel=1e-12)
    assert back.to_frame(burn_in=full.metrics()["burn_in"]).shape == expected.shape
    assert frame["mse"].to_numpy() == pytest.approx(full.to_frame()["mse"].to_numpy(), rel=1e-12)
    with pytest.raises(dkfsim.DkfsimError, match=r"saved with --save summary.*burn-in 7") as err:
        back.to_frame(burn_in=7)
    assert str(tmp_path) in str(err.value)


def test_montecarlo_with_one_run_writes_valid_json(tmp_path):
    import json

    from dkfsim.experiments.montecarlo import montecarlo
    montecarlo(dkfsim.load_scenario(scenario(3, steps=10)), 1).save(tmp_path)
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["runs"] == 1


def test_an_anti_delay_instance_with_a_huge_fusion_ring_is_refused_at_validation(monkeypatch):
    """Every anti-delay DKF's fusion ring is checked when the scenario is validated, a listed
    instance with its own long buffer at its own key: a run never meets the error at its start."""
    monkeypatch.setattr(schema, "FUSION_MEMORY_LIMIT", 100 * 36 * 36 * 8)   # 100 rows of 12 x 3 states
    case1 = Path(__file__).resolve().parents[1] / "scenarios" / "paper_case1.yaml"
    with pytest.raises(ScenarioError, match=r"estimators\.1: matrix fusion .* 151 window rows") as err:
        dkfsim.load_scenario(case1, overrides=[
            "steps=300", "estimators=[{kind: centralized}, {kind: anti_delay_dkf, name: long, buffer_length: 150}]"])
    assert "paper_case1.yaml" in str(err.value)
    ok = dkfsim.load_scenario(case1, overrides=[
        "steps=300", "estimators=[{kind: anti_delay_dkf, name: short, buffer_length: 90}]"])
    assert dkfsim.run(ok).estimates[-1] == "short"


def test_the_fusion_check_on_a_large_graph_decides_from_bounds_or_the_exact_buffer(monkeypatch):
    """On a large graph that is not a tree the buffer length of ``auto`` is known only within
    cheap bounds at validation: a ring that fits at the upper bound passes, one that exceeds at
    the lower is refused with "at least", and between the two the exact L decides."""
    d = scenario(60, steps=400, latency={"model": "uniform_steps", "d_t": 2})
    d["protocol"] = "flood"
    d["topology"] = {"directed": False, "generator": "ring"}
    sc = dkfsim.load_scenario(d)
    plan = RunPlan(sc)
    monkeypatch.setattr(plan_module, "CHEAP_VISITS", 10)       # the ring's diameter counts as costly
    # bounds looser than the two sweeps give on a ring, so that the exact L lies strictly between
    monkeypatch.setattr(plan_module.topo, "diameter_bounds", lambda graph: (20, 59))
    plan = RunPlan(sc)
    assert plan.diameter_is_costly
    lower, upper = plan.diameter_bounds
    L_exact = 2 * 30 + 1                                        # the ring of 60 has diameter 30
    assert lower * 2 + 1 < L_exact < upper * 2 + 1 and plan.buffer_length() == L_exact
    dkf = plan.dkf()
    fits = plan.fusion_bytes
    assert plan.fusion_overflow(dkf, fits(upper * 2 + 1)) is None                     # fits at the upper bound
    assert plan.fusion_overflow(dkf, fits(lower * 2 + 1) - 1) == (lower * 2 + 1, fits(lower * 2 + 1), False)
    assert plan.fusion_overflow(dkf, fits(L_exact) - 1) == (L_exact, fits(L_exact), True)   # the exact L
    assert plan.fusion_overflow(dkf, fits(L_exact)) is None

"""Large networks must fail early and clearly, or fit: memory guards of a run."""

from __future__ import annotations

import pytest

import dkfsim
import dkfsim.engine.driver as simulation
from conftest import scenario
from dkfsim.core.errors import ScenarioError


def test_matrix_fusion_too_large_is_a_clear_error(monkeypatch):
    monkeypatch.setattr(simulation, "FUSION_MEMORY_LIMIT", 1_000)   # (L+1)(n nx)^2 8 = 4096 B here
    sc = dkfsim.load_scenario(scenario(8, steps=5))
    with pytest.raises(ScenarioError, match="fusion: matrix keeps the cross-covariances") as err:
        dkfsim.run(sc)
    assert "fusion: none" in str(err.value) and "fusion" == err.value.path
    # fusion: none runs.
    assert dkfsim.run(dkfsim.load_scenario(scenario(8, steps=5, fusion="none")))["x_local"].shape == (5, 8, 2)


def test_p_local_is_kept_only_when_it_will_be_saved_and_fits(monkeypatch):
    sc = dkfsim.load_scenario(scenario(4, steps=6))
    assert "P_local" in dkfsim.run(sc, save="estimates").arrays
    assert "P_local" not in dkfsim.run(sc, save="summary").arrays
    monkeypatch.setattr(simulation, "P_LOCAL_LIMIT", 10)
    res = dkfsim.run(sc, save="full")
    assert "P_local" not in res.arrays and "x_local" in res.arrays and "arrival" in res.arrays


def test_late_bookkeeping_is_bounded_by_the_latency_bound():
    bounded = dkfsim.load_scenario(scenario(4, latency={"model": "uniform_steps", "d_t": 3}))
    assert simulation.late_horizon(bounded, 4, 7) == 5
    unbounded = dkfsim.load_scenario(scenario(4, latency={"model": "exponential", "mean": 0.1},
                                              buffer_length=3))
    assert simulation.late_horizon(unbounded, 4, 3) == 4096
    # 1000 nodes: the kept holdings stay near 64 MB instead of ~0.7 GB.
    assert simulation.late_horizon(unbounded, 1000, 3) < 500


def test_a_delay_bound_longer_than_the_run_costs_no_memory():
    """L = 10^11 + 1 (a latency of 10^9 s): the window ring is capped at the run's rows."""
    d = scenario(3, steps=6, latency={"model": "constant", "value": 1e9})
    sc = dkfsim.load_scenario(d)
    assert sc.resolved_buffer_length() > 10**10
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


def test_montecarlo_with_one_run_writes_valid_json(tmp_path):
    import json
    from dkfsim.experiments.montecarlo import montecarlo
    montecarlo(dkfsim.load_scenario(scenario(3, steps=10)), 1).save(tmp_path)
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["runs"] == 1

"""Numbers that validate but used to break an estimator (issue 20 §3).

One sensor with a round-based estimator (no neighbours), an exact model (``Phi = 0``,
``Q = 0``: every estimate exact, ``tr Xi = 0``) and a key that applies to nothing
(``consensus_rounds`` without a consensus estimator).  The truths: the textbook Kalman filter of
tests/reference.py on the run's own measurements, and the exact state.
"""

from __future__ import annotations

import numpy as np
import pytest
import reference as ref
import yaml
from hostile_kit import CASE1, dkfsim_cli

import dkfsim


def case1(**changes) -> dict:
    data = yaml.safe_load(CASE1.read_text())
    data.update(changes)
    return data


@pytest.mark.parametrize("kind", ["kcf", "icf", "diffusion_kf", "hcmci", "ci_consensus"])
def test_one_sensor_runs_as_its_own_kalman_filter(kind):
    """No neighbours: every round-based estimator is the node's own Kalman filter."""
    data = case1(steps=30, estimators=[{"kind": kind}])
    data["sensors"] = data["sensors"][:1]
    data["topology"] = {"generator": "edges", "edges": []}
    res = dkfsim.run(dkfsim.load_scenario(data))
    x_ref, _ = ref.centralized(res.arrays)
    x = res[f"x_{kind}"]
    assert x.shape == (30, 1, 3) and np.isfinite(x).all()
    ref.assert_close(x[:, 0, :], x_ref, f"{kind} with one sensor", tol=1e-9)


def test_one_sensor_with_kcf_runs_from_the_command_line(tmp_path):
    data = case1(steps=10, estimators=[{"kind": "kcf"}, {"kind": "hcmci"}],
                 topology={"generator": "edges", "edges": []})
    data["sensors"] = data["sensors"][:1]
    (tmp_path / "one.yaml").write_text(yaml.safe_dump(data))
    out = dkfsim_cli("run", tmp_path / "one.yaml", "--out", tmp_path / "out").ok()
    assert "kcf" in out and "hcmci" in out


@pytest.mark.parametrize("fusion", ["matrix", "diagonal"])
def test_an_exact_model_fuses_to_the_exact_state(fusion):
    """Phi = 0, Q = 0: the state is 0 after tick 0 and every estimator knows it exactly; the fused
    estimate must be too (it was NaN from tick 0: delta = 1e-8 tr(Xi) = 0)."""
    zero = [[0.0] * 3 for _ in range(3)]
    data = case1(steps=20, fusion=fusion, model={"kind": "linear", "T": 0.01, "Phi": zero, "Q": zero})
    res = dkfsim.run(dkfsim.load_scenario(data))
    assert np.array_equal(res["truth"], np.zeros((20, 3)))
    for name in ("fused", "centralized"):
        assert np.isfinite(res[f"x_{name}"]).all() and np.isfinite(res[f"P_{name}"]).all(), name
        assert np.abs(res[f"x_{name}"]).max() < 1e-12, name
    assert not res.diverged


def test_a_key_that_applies_to_nothing_is_still_validated(tmp_path):
    (tmp_path / "s.yaml").write_text(yaml.safe_dump(case1(consensus_rounds=-1)))
    dkfsim_cli("validate", tmp_path / "s.yaml").clean_error("consensus_rounds", "integer >= 0")
    (tmp_path / "s.yaml").write_text(yaml.safe_dump(case1(consensus_rounds=3)))
    dkfsim_cli("validate", tmp_path / "s.yaml").ok()

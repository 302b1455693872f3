"""Networks large enough that packets carry many origins at once.

Packets carry origin bitmasks wider than a machine word; the window filter
unpacks them all at once (both kernel paths); the result must match the
arrival-log reference.
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import scenario
from reference import assert_close, centralized, node_estimates

import dkfsim


@pytest.mark.parametrize("kernels", ["numba", "numpy"])
@pytest.mark.parametrize("protocol", ["tree", "flood"])
@pytest.mark.parametrize("n, generator", [(40, "random_tree"), (70, "star")])   # 70 bits: wider than a word
def test_many_nodes_match_the_arrival_log_reference(protocol, kernels, n, generator, monkeypatch):
    monkeypatch.setenv("DKFSIM_KERNELS", kernels)
    d = scenario(n, steps=25, generator=generator, params={"seed": 4} if generator == "random_tree" else {},
                 latency={"model": "uniform_steps", "d_t": 1}, fusion="none", protocol=protocol)
    res = dkfsim.run(dkfsim.load_scenario(d))
    a = res.arrays
    L = int(a["buffer_length"])
    # Bounded latency: every final row is complete at every node.
    assert np.isfinite(a["arrival"][:, :, : 25 - L + 1]).all()
    ref = node_estimates(a)
    assert_close(a["x_local"], ref["x_local"], f"x_local ({n} nodes)")
    assert_close(a["x_final"], ref["x_final"], f"x_final ({n} nodes)")


def test_forty_nodes_zero_latency_equal_the_centralized_filter():
    d = scenario(40, steps=15, generator="star", latency={"model": "constant", "value": 0.0},
                 fusion="none")
    a = dkfsim.run(dkfsim.load_scenario(d)).arrays
    xc, _ = centralized(a)
    assert_close(a["x_local"], np.broadcast_to(xc[:, None, :], a["x_local"].shape), "x_local vs KF")

"""Networks large enough that packets carry many origins at once.

Above a dozen origins per mask the protocols unpack bitmasks with numpy
instead of one Python step per origin; the result must not change.
"""

from __future__ import annotations

import numpy as np
import pytest

import dkfsim
from conftest import scenario
from reference import assert_close, centralized, node_estimates


@pytest.mark.parametrize("many_bits", [0, 10**9], ids=["numpy-unpacking", "per-origin"])
@pytest.mark.parametrize("protocol", ["tree", "flood"])
def test_forty_nodes_match_the_arrival_log_reference(protocol, many_bits, monkeypatch):
    import dkfsim.protocols.base
    monkeypatch.setattr(dkfsim.protocols.base, "_MANY_BITS", many_bits)
    d = scenario(40, steps=25, generator="random_tree", params={"seed": 4},
                 latency={"model": "uniform_steps", "d_t": 1}, fusion="none", protocol=protocol)
    res = dkfsim.run(dkfsim.load_scenario(d))
    a = res.arrays
    L = int(a["buffer_length"])
    # Bounded latency: every final row is complete at every node.
    assert np.isfinite(a["arrival"][:, :, : 25 - L + 1]).all()
    ref = node_estimates(a)
    assert_close(a["x_local"], ref["x_local"], "x_local (40 nodes)")
    assert_close(a["x_final"], ref["x_final"], "x_final (40 nodes)")


def test_forty_nodes_zero_latency_equal_the_centralized_filter():
    d = scenario(40, steps=15, generator="star", latency={"model": "constant", "value": 0.0},
                 fusion="none")
    a = dkfsim.run(dkfsim.load_scenario(d)).arrays
    xc, _ = centralized(a)
    assert_close(a["x_local"], np.broadcast_to(xc[:, None, :], a["x_local"].shape), "x_local vs KF")

"""Exact timing semantics of docs/design.md §2, hand-worked on tiny paths.

A latency of d*T on one hop is "a delay of d steps": a packet sent at t_k
with latency exactly T counts for tick k+1, one nanosecond more and it
misses it; zero-latency relay chains started at t_k count for tick k.
"""

from __future__ import annotations

import numpy as np
import pytest

import dkfsim

T = 0.01


def path_scenario(n, latency, protocol="tree", L=5, steps=12):
    return {
        "name": "path", "seed": 3, "steps": steps,
        "model": {"kind": "linear", "T": T, "Phi": [[1.0]], "Q": [[0.1]]},
        "prior": {"mean": [0.0], "cov": [[1.0]]},
        "sensors": [{"name": f"s{i}", "H": [[1.0]], "R": [[1.0 + i]]} for i in range(n)],
        "topology": {"generator": "path"},
        "links": {"default": {"latency": latency}},
        "protocol": protocol, "buffer_length": L, "fusion": "none",
    }


def arrival(sc_dict):
    return dkfsim.run(dkfsim.load_scenario(sc_dict))["arrival"]


@pytest.mark.parametrize("protocol", ["tree", "flood"])
def test_zero_latency_chain_counts_for_the_same_tick(protocol):
    a = arrival(path_scenario(5, {"model": "constant", "value": 0.0}, protocol))
    t = (np.arange(1, 13) * 10_000_000) / 1e9
    # Every node holds every contribution of row r at t[r]: 4 hops, no delay.
    assert np.array_equal(a, np.broadcast_to(t, a.shape))


@pytest.mark.parametrize("protocol", ["tree", "flood"])
def test_latency_of_exactly_d_steps_arrives_at_the_tick(protocol):
    a = arrival(path_scenario(4, {"model": "constant", "value": 2 * T}, protocol, L=7))
    t = (np.arange(1, 13) * 10_000_000) / 1e9
    for i in range(4):
        for o in range(4):
            hops = abs(i - o)
            for r in range(12):
                # 2 steps per hop; the run ends at t_12, so later arrivals never happen.
                tick = r + 1 + 2 * hops
                expect = tick * 10_000_000 / 1e9 if tick <= 12 else np.inf
                assert a[i, o, r] == expect, (i, o, r, a[i, o, r], expect)
    assert a[0, 0, 0] == t[0]


def test_one_nanosecond_past_the_tick_misses_it():
    on = dkfsim.run(dkfsim.load_scenario(path_scenario(2, {"model": "constant", "value": T}, L=1)))
    late = dkfsim.run(dkfsim.load_scenario(path_scenario(2, {"model": "constant", "value": T + 1e-9}, L=2)))
    # With L = 1 a row is final at its own tick: a one-step delay is always late.
    assert on.counts["late"] > 0
    # With L = 2, latency T arrives exactly at the next tick and is used ...
    on2 = dkfsim.run(dkfsim.load_scenario(path_scenario(2, {"model": "constant", "value": T}, L=2)))
    assert on2.counts["late"] == 0
    # ... but 1 ns more misses the final tick of the row: late, never applied.
    # Row r arrives at t_{r+2} + 1 ns, after it became final at t_{r+2}; rows
    # 0..9 arrive before the run ends at t_12: 10 rows in each direction.
    assert late.counts["late"] == 20
    # ... and per link: every delivered packet carried only late information.
    for entry in late.counts["per_link"]:
        assert entry["late_packets"] == entry["delivered"] == 10
    assert all(e["late_packets"] == 0 for e in on2.counts["per_link"])
    a = late["arrival"]
    assert a[1, 0, 0] == (10_000_000 * 2 + 1) / 1e9
    # The final estimate of row 0 at node 1 therefore uses only its own measurement.
    x_own_only = dkfsim.run(dkfsim.load_scenario(
        {**path_scenario(2, {"model": "constant", "value": 1.0}, L=2)}))
    np.testing.assert_array_equal(late["x_final"][0, 1], x_own_only["x_final"][0, 1])


def test_late_unit_follows_the_arrival_log():
    """With the log, ``late`` counts (receiver, origin, row); without it, (packet, row) pairs
    (docs/design.md §3).  Two nodes: every late packet row carries the one origin the receiver
    lacks, so both units count the same 20 (rows 0..9, each direction)."""
    sc = dkfsim.load_scenario(path_scenario(2, {"model": "constant", "value": T + 1e-9}, L=2))
    full = dkfsim.run(sc, save="full")
    est = dkfsim.run(sc, save="estimates")
    assert full.counts["late_unit"] == "contributions"
    assert est.counts["late_unit"] == "packet_rows"
    assert full.counts["late"] == est.counts["late"] == 20
    on = dkfsim.run(dkfsim.load_scenario(path_scenario(2, {"model": "constant", "value": T}, L=2)),
                    save="estimates")
    assert on.counts["late"] == 0

"""A rate-limited link over time (docs/traffic.md, "What a run reports"): the per-tick queue
length and utilisation of :mod:`dkfsim.network.occupancy`, against hand-worked intervals,
Little's law on a run's own packets, the run's whole-span utilisation; every estimator's
per-link traffic in summary.json."""

from __future__ import annotations

import json

import numpy as np
import pytest
from conftest import scenario, tree_edges

from dkfsim.config.load import load_scenario
from dkfsim.engine.driver import run
from dkfsim.network.occupancy import fifo, mean_waiting, per_tick


def test_fifo_closed_form_is_lindleys_recursion():
    """``fifo``: arrivals 0, 1, 1, 10 with services 3, 1, 2, 1 start at 0, 3, 4, 10."""
    starts, ends = fifo(np.array([0, 1, 1, 10]), np.array([3, 1, 2, 1]))
    np.testing.assert_array_equal(starts, [0, 3, 4, 10])
    np.testing.assert_array_equal(ends, [3, 4, 6, 11])


def test_per_tick_by_hand():
    """Ticks of 10 ns.  Packet a: handed over at 2, starts at 2, ends at 12 (busy 8 ns in tick
    1, 2 in tick 2); b: handed over at 2, waits to 12, ends at 22 (8 + 2); c: dropped (occupies nothing);
    d: handed over at 25, waits to 31, ends at 33."""
    log = np.array([[2, 2, 12], [2, 12, 22], [5, -1, -1], [25, 31, 33]])
    queue, busy = per_tick(log, 10, 4)
    np.testing.assert_array_equal(queue, [0.8, 0.2, 0.5, 0.1])     # b 8+2 ns, d 5+1 ns
    np.testing.assert_array_equal(busy, [0.8, 1.0, 0.2, 0.2])     # a 8+2, b 8+2, d 2
    assert mean_waiting(log, 40) == pytest.approx((10 + 6) / 40)
    assert mean_waiting(log, 0) == 0.0


def _rated(latency=None):
    sc = scenario(6, edges=tree_edges(6, 51), steps=80, seed=4, buffer_length=12,
                  latency=latency or {"model": "uniform", "low": 0.0, "high": 0.02})
    sc["links"]["default"]["rate"] = 6e4
    return sc


def test_littles_law_on_a_runs_own_packets():
    """No background: per link, the time-averaged number waiting over [0, t_K] equals the
    accepted packets' rate times their mean queueing delay (the port's own statistic), and
    the utilisation series averages to the run's utilisation."""
    r = run(load_scenario(_rated()))
    t_end = r.arrays["t"][-1]
    queue, util = r.arrays["queue_length"], r.arrays["utilisation"]
    rows = {tuple(row["link"]): row for row in r.counts["per_link"]}
    waited = 0
    for e, link in enumerate(map(tuple, r.arrays["rated_links"])):
        row = rows[link]
        lam = (row["sent"] - row["queue_dropped"]) / t_end
        assert queue[:, e].mean() == pytest.approx(lam * row["queueing_delay_mean"], rel=1e-3, abs=1e-12)
        assert queue[:, e].mean() == pytest.approx(row["queue_length_mean"], rel=1e-9, abs=1e-12)
        assert util[:, e].mean() == pytest.approx(row["utilisation"], rel=1e-9)
        q = r.arrays["queueing_delay_quantiles"][e]          # the distribution the plots draw
        assert q[95] == pytest.approx(row["queueing_delay_p95"], rel=1e-9, abs=1e-15)
        assert q[0] >= 0 and np.all(np.diff(q) >= 0)
        waited += row["queueing_delay_mean"] > 0
    assert waited >= 3, "the rate was meant to make packets wait"
    assert queue.shape == util.shape == (80, len(rows)) and util.max() <= 1.0 + 1e-12


def test_every_estimators_per_link_traffic_in_summary_json(tmp_path):
    sc = _rated()
    sc["estimators"] = [{"kind": "kcf"}]
    r = run(load_scenario(sc))
    r.save(tmp_path / "run")
    saved = json.loads((tmp_path / "run" / "summary.json").read_text())
    rows = saved["traffic"]["kcf"]["per_link"]
    assert len(rows) == len(r.arrays["rated_links"]) and all("queue_length_mean" in row for row in rows)
    assert sum(row["sent"] for row in rows) == saved["traffic"]["kcf"]["sent"]
    assert rows != saved["per_link"]            # kcf's own packets, not the DKF's


def test_shared_queues_count_every_estimators_packets():
    """Shared queues: the number waiting on a link is everyone's; by Little's law its mean is
    the sum over the two DKF instances of accepted packets x mean queueing delay, over t_K (up
    to the waits that run past t_K, which the series cuts off: a few per cent here; one port's
    packets alone would be about half)."""
    sc = _rated()
    sc["links"]["shared_queues"] = True
    sc["estimators"] = [{"kind": "anti_delay_dkf", "name": "twin"}]
    r = run(load_scenario(sc))
    t_end = r.arrays["t"][-1]
    mine = {tuple(row["link"]): row for row in r.traffic["fused"]["per_link"]}
    twin = {tuple(row["link"]): row for row in r.traffic["twin"]["per_link"]}
    for e, link in enumerate(map(tuple, r.arrays["rated_links"])):
        expected = sum((row["sent"] - row["queue_dropped"]) * row["queueing_delay_mean"]
                       for row in (mine[link], twin[link])) / t_end
        got = r.arrays["queue_length"][:, e].mean()
        assert expected * 0.97 - 1e-12 <= got <= expected + 1e-12
        assert mine[link]["queue_length_mean"] == twin[link]["queue_length_mean"]
    assert r.arrays["queue_length"].max() > 0.5

"""``centralized_delayed`` through transmitters (docs/traffic.md): its direct links take the
default link's rate, queue and background like every link of the graph."""

from __future__ import annotations

import numpy as np
import pytest
from test_maxdelay import const_latency, rw_scenario

import dkfsim


def _centre(latency=0.65, steps=20, **links):
    data = rw_scenario(const_latency(latency), n=2, steps=steps)
    data["estimators"] = [{"kind": "centralized_delayed"}]
    data["links"]["default"].update(links)
    return dkfsim.run(dkfsim.load_scenario(data))


def test_hand_worked_timeline_with_periodic_background():
    """T = 1 s, latency 0.65 s, buffer L = 2 (a row is usable when it arrives by tick r + 2).
    A sensor's 32-byte packet takes 0.3 s at 2560/3 bit/s; periodic background of 64 bytes
    (0.6 s) at 0.5 s, 2.5 s, 4.5 s, ... keeps the link busy until 1.1 s, 3.1 s, ...  Row r is
    handed over at r + 1: for even r (odd instants) it waits 0.1 s, ends at r + 1.4, arrives at
    r + 2.05, tick r + 3: late; for odd r it arrives at r + 1.95, tick r + 2: in time.  Of the
    20 rows per sensor, 9 are late (r = 0, 2, ..., 16), 9 in time (r = 1, ..., 17), and rows 18
    and 19 arrive after t_K = 20 s."""
    res = _centre(rate=2560 / 3, background={"arrivals": "periodic", "packets_per_second": 0.5,
                                              "size": 64, "offset": 0.5})
    t = res.traffic["centralized_delayed"]
    assert (t["sent"], t["late"], t["delivered"], t["in_flight"], t["queue_dropped"], t["lost"]) == \
        (40, 18, 36, 4, 0, 0)
    plain = _centre().traffic["centralized_delayed"]
    assert (plain["late"], plain["delivered"]) == (0, 38)        # no rate: every row in time


def test_a_full_room_drops_the_sensors_packets():
    """Background of 90 bytes (0.84375 s at 2560/3 bit/s) every second from 0.5 s keeps the link
    busy over [m + 0.5, m + 1.34375): with no waiting room every sensor packet, handed over at a
    whole second, finds it busy and is dropped."""
    res = _centre(rate=2560 / 3, queue={"packets": 0},
                  background={"arrivals": "periodic", "packets_per_second": 1.0, "size": 90, "offset": 0.5})
    t = res.traffic["centralized_delayed"]
    assert t["queue_dropped"] == t["sent"] == 40 and t["delivered"] == 0
    assert t["sent"] == t["delivered"] + t["lost"] + t["queue_dropped"] + t["in_flight"]


#: What a rate-limited link's row adds (its transmitter's statistics).
RATE_KEYS = ("utilisation", "queueing_delay_mean", "queueing_delay_p95", "background_sent", "background_dropped",
             "queue_length_mean")


def test_rate_1e15_equals_no_rate():
    a, b = _centre(), _centre(rate=1e15)
    assert np.array_equal(a.arrays["x_centralized_delayed"], b.arrays["x_centralized_delayed"])
    fast = dict(b.traffic["centralized_delayed"])
    fast["per_link"] = [{k: v for k, v in row.items() if k not in RATE_KEYS} for row in fast["per_link"]]
    assert a.traffic["centralized_delayed"] == fast


@pytest.mark.parametrize("links", [
    {},
    {"loss": 0.3, "duplicate": 0.2},
    {"rate": 2560 / 3, "background": {"arrivals": "periodic", "packets_per_second": 0.5, "size": 64, "offset": 0.5}},
    {"rate": 2560 / 3, "queue": {"packets": 0}, "background": {"packets_per_second": 1.0, "size": 90}},
    {"latency": {"model": "uniform", "low": 0.1, "high": 1.7}, "jitter": {"model": "uniform", "high": 0.2},
     "outages": [[3.0, 6.0]]},
])
def test_the_port_delivers_what_the_closed_form_says(links):
    """``centralized_delayed`` sends through its port; where nothing but its direct links' draws
    and their transmitters act, :meth:`arrival_ticks` works the same arrivals out in closed form:
    the tick at which the centre holds each (sensor, row), and per sensor the packets sent, lost
    and dropped by a full room -- the oracle of the port's path (issue 31)."""
    from dkfsim.engine.driver import Run
    from dkfsim.estimators.centralized_delayed import CentralizedDelayed
    data = rw_scenario(const_latency(0.65), n=3, steps=30)
    data["estimators"] = [{"kind": "centralized_delayed"}]
    data["links"]["default"].update(links)
    sim = Run(dkfsim.load_scenario(data))
    res = sim.run()
    est = next(e for e in sim.estimators if isinstance(e, CentralizedDelayed))
    ticks, per = est.arrival_ticks()
    assert np.array_equal(est._ticks, np.where(ticks <= 30, ticks, 0))     # (after t_K: in flight)
    rows = {tuple(r["link"]): r for r in res.traffic["centralized_delayed"]["per_link"]}
    for i in range(3):
        row = rows[(i, -1)]
        assert (row["sent"], row["lost"], row["queue_dropped"]) == (per["sent"][i], per["lost"][i],
                                                                   per["queue_dropped"][i])
    assert (ticks > 0).sum() > 0


def test_per_link_rows_and_the_rate_bound_of_its_direct_links():
    """One row per direct link (sensor i -> the centre, -1), summing to the totals; the rate
    search's lower bound for it is its payload on a direct link (32 - 16 bytes per tick of 1 s)
    plus the background (3 x 40 bytes per second)."""
    from dkfsim.experiments.maxdelay.rate import make_rate_axis, rate_lower_bound
    res = _centre(rate=1e4, background={"packets_per_second": 3.0, "size": 40})
    t = res.traffic["centralized_delayed"]
    assert [row["link"] for row in t["per_link"]] == [(0, -1), (1, -1)]
    for key in ("sent", "delivered", "lost", "queue_dropped", "in_flight", "bytes"):
        assert sum(row[key] for row in t["per_link"]) == t[key], key
    data = rw_scenario(const_latency(0.65), n=2, steps=20)
    data["estimators"] = [{"kind": "centralized_delayed"}]
    data["links"]["default"].update(rate=1e4, background={"packets_per_second": 3.0, "size": 40})
    ax = make_rate_axis(dkfsim.load_scenario(data), max_rate=1e4, min_rate=1e3, step=10.0,
                        keep="centralized_delayed")
    bound = rate_lower_bound(ax, "centralized_delayed")
    assert bound["rate"] == (32 - 16) * 8 + 3 * 40 * 8 and bound["link"][1] == -1

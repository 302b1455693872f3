"""The compiled tree exchange is the Python tree protocol, packet for packet.

:mod:`dkfsim.protocols.tree_compiled` re-implements the ``tree`` protocol and its port
(keyed latency draws, one delivery event per instant, flushes after deliveries, zero-latency
packets delivered before the next flush) in kernels, and folds contributions into the window
in the Python protocol's order.  So against the Python protocol (``DKFSIM_EXCHANGE=python``,
same numba kernels otherwise) every count, per link too, is identical and every estimate is
the same number, bit for bit.  A case where either differs fails.
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import scenario, tree_edges

import dkfsim
from dkfsim.core.streams import keyed_uniform
from dkfsim.protocols import tree_compiled, tree_compiled_kernels

CASES = {
    # the paper's latency model, 3 states, 9 nodes
    "uniform_steps": dict(n=9, nx=3, edges=tree_edges(9, 11), latency={"model": "uniform_steps", "d_t": 3}),
    # 70 nodes: origin sets of two 64-bit words
    "two_words": dict(n=70, edges=tree_edges(70, 3), steps=25, latency={"model": "uniform_steps", "d_t": 2}),
    # a latency that is not a multiple of T: arrivals between ticks, relays landing on ticks
    "constant_off_grid": dict(n=8, edges=tree_edges(8, 4), latency={"model": "constant", "value": 0.013}),
    # zero latency: chains of relays inside one instant
    "zero_latency": dict(n=8, edges=tree_edges(8, 6)),
    # a buffer shorter than the delays: late packets, stale messages
    "short_buffer": dict(n=8, edges=tree_edges(8, 2), buffer_length=2,
                         latency={"model": "uniform_steps", "d_t": 3}),
    # no fusion: the window keeps no per-origin flags
    "no_fusion": dict(n=9, edges=tree_edges(9, 7), fusion="none", latency={"model": "uniform_steps", "d_t": 2}),
    "paper_weights_diagonal": dict(n=8, edges=tree_edges(8, 5), weights="paper", fusion="diagonal",
                                   latency={"model": "uniform_steps", "d_t": 2}),
    # half a tick: what arrives at a tick was relayed half a tick before, so its delivery
    # comes after the tick's measure (the kernel runs the instants between ticks itself)
    "relayed_to_the_tick": dict(n=16, nx=3, edges=tree_edges(16, 14), latency={"model": "constant", "value": 0.005}),
    # and a whole tick on three links: packets sent at the tick before arrive too, so the
    # tick's deliveries come before its measure
    "ticks_and_between": dict(n=16, nx=3, edges=tree_edges(16, 14), latency={"model": "constant", "value": 0.005},
                              overrides=[{"link": list(e), "latency": {"model": "constant", "value": 0.01}}
                                         for e in tree_edges(16, 14)[:3]]),
}


def _run(d, exchange, monkeypatch, save="estimates"):
    monkeypatch.setenv("DKFSIM_KERNELS", "numba")
    monkeypatch.setenv(tree_compiled.EXCHANGE_ENV, exchange)
    return dkfsim.run(dkfsim.load_scenario(d), save=save)


def _same(a, b):
    assert a.counts == b.counts                      # totals, per link, late, stale
    for name in ("x_local", "P_local", "x_final", "x_fused", "P_fused", "arrival"):
        if name in a.arrays:
            assert np.array_equal(a.arrays[name], b.arrays[name]), name


@pytest.mark.parametrize("case", list(CASES))
def test_compiled_tree_is_the_python_protocol(case, monkeypatch):
    d = scenario(**{"steps": 40, **CASES[case]})
    a, b = _run(d, "", monkeypatch), _run(d, "python", monkeypatch)
    assert a.info["exchange"] == "masks, compiled" and b.info["exchange"] == "masks"
    assert a.counts["sent"] > 0
    _same(a, b)
    if case == "short_buffer":
        assert a.counts["late"] > 0 and a.counts["stale"] > 0      # the case exercises both


@pytest.mark.parametrize("case", ["d_t_4", "ticks_and_between"])
def test_a_growing_packet_pool_keeps_the_packets_in_flight(case, monkeypatch):
    """The pool grows in the middle of a tick (between ticks too): the tick resumes where it stopped."""
    kw = dict(n=12, edges=tree_edges(12, 9), latency={"model": "uniform_steps", "d_t": 4}) if case == "d_t_4" \
        else CASES[case]
    d = scenario(**{"steps": 30, **kw})
    monkeypatch.setattr(tree_compiled.CompiledTreeExchange, "initial_pool", 1)
    a = _run(d, "", monkeypatch)
    monkeypatch.undo()
    _same(a, _run(d, "python", monkeypatch))


def test_an_extra_dkf_instance_runs_compiled_beside_the_main_one(monkeypatch):
    d = scenario(n=7, edges=tree_edges(7, 1), latency={"model": "uniform_steps", "d_t": 2})
    d["estimators"] = [{"kind": "anti_delay_dkf", "name": "dkf_L2", "buffer_length": 2}]
    _same(_run(d, "", monkeypatch), _run(d, "python", monkeypatch))


@pytest.mark.parametrize("change, value", [
    ("loss", 0.2), ("crash", None), ("latency", {"model": "uniform", "low": 0.0, "high": 0.02})])
def test_what_the_kernels_cannot_draw_runs_the_python_protocol(change, value, monkeypatch):
    d = scenario(n=6, edges=tree_edges(6, 1), steps=10, latency={"model": "uniform_steps", "d_t": 1})
    if change == "loss":
        d["links"]["default"]["loss"] = value
    elif change == "latency":
        d["links"]["default"]["latency"] = value
    else:
        d["faults"] = {"crashes": [{"node": 2, "start": 0.02, "end": 0.05}]}
    assert _run(d, "", monkeypatch).info["exchange"] == "masks"


@pytest.mark.parametrize("case", ["uniform_steps", "short_buffer", "constant_off_grid", "relayed_to_the_tick",
                                  "ticks_and_between"])
def test_the_arrival_log_is_the_python_protocols(case, monkeypatch):
    """With the log, late contributions count once each (holdings of final rows kept) and
    every arrival instant is written: the same array and counts as the Python protocol."""
    d = scenario(**{"steps": 40, **CASES[case]})
    a, b = _run(d, "", monkeypatch, "full"), _run(d, "python", monkeypatch, "full")
    assert a.info["exchange"] == "masks, compiled" and a.counts["late_unit"] == "contributions"
    assert np.isfinite(a.arrays["arrival"]).sum() > 0
    _same(a, b)
    if case == "short_buffer":
        assert a.counts["late"] > a.counts["per_link"][0]["late_packets"] > 0


def test_the_compiled_draws_are_the_keyed_uniforms():
    k = tree_compiled_kernels.compiled()
    rng = np.random.default_rng(5)
    for _ in range(2000):
        key = int(rng.integers(0, 2**63)) * 2 + int(rng.integers(0, 2))       # all 64 bits
        t, seq = int(rng.integers(0, 2**62)), int(rng.integers(0, 50))
        assert k.keyed_uniform(np.uint64(key), t, seq) == keyed_uniform(key, t, seq)


def test_zero_latency_compiled_dkf_is_the_centralized_filter(monkeypatch):
    """The oracle of tests/test_exactness.py on the compiled path: at zero latency every
    node holds everything on time, so each node's estimate is the centralized one."""
    d = scenario(n=9, nx=3, edges=tree_edges(9, 2), steps=50)
    res = _run(d, "", monkeypatch)
    assert res.info["exchange"] == "masks, compiled"
    xc = res.arrays["x_centralized"]
    err = np.abs(res.arrays["x_local"] - xc[:, None, :]).max() / np.abs(xc).max()
    assert err < 1e-9


RATE_CASES = {
    # packets queue behind each other (1 Mbit/s), unbounded room; more delays than the first array holds
    "rate": (dict(n=9, nx=3, steps=80, edges=tree_edges(9, 11), latency={"model": "uniform_steps", "d_t": 2}),
             {"rate": 2e5}),
    # a room of 2 packets that overflows, Poisson background
    "queue_background": (dict(n=8, edges=tree_edges(8, 4), latency={"model": "constant", "value": 0.013}),
                         {"rate": 3e4, "queue": {"packets": 2},
                          "background": {"packets_per_second": 40.0, "size": 60}}),
    # periodic background with an offset, zero latency, no room at all
    "periodic_no_room": (dict(n=8, edges=tree_edges(8, 6)),
                         {"rate": 1e5, "queue": {"packets": 0},
                          "background": {"arrivals": "periodic", "packets_per_second": 33.0, "size": 100,
                                         "offset": 0.003}}),
    # exponential background sizes, a short buffer: late and stale packets
    "exponential_short_buffer": (dict(n=8, edges=tree_edges(8, 2), buffer_length=2,
                                      latency={"model": "uniform_steps", "d_t": 1}),
                                 {"rate": 5e4, "background": {"packets_per_second": 20.0, "size": 200,
                                                              "sizes": "exponential"}}),
}


@pytest.mark.parametrize("case", list(RATE_CASES))
def test_compiled_transmitters_are_the_python_ones(case, monkeypatch):
    """A rate-limited tree runs compiled, with the same counts (queue drops, per-link
    utilisation, queueing delays, background) and estimates as the Python transmitters."""
    kw, traffic = RATE_CASES[case]
    d = scenario(**{"steps": 40, **kw})
    d["links"]["default"].update(traffic)
    a, b = _run(d, "", monkeypatch), _run(d, "python", monkeypatch)
    assert a.info["backend"]["exchange"] == "compiled" and b.info["backend"]["exchange"] == "python"
    _same(a, b)
    rows = a.counts["per_link"]
    if case != "periodic_no_room":                   # (no room: nothing ever waits)
        assert max(r["queueing_delay_mean"] for r in rows) > 0
    if "queue" in traffic:
        assert a.counts["queue_dropped"] > 0
    if "background" in traffic:
        assert sum(r["background_sent"] for r in rows) > 0


def test_a_growing_pool_with_transmitters(monkeypatch):
    kw, traffic = RATE_CASES["queue_background"]
    d = scenario(**{"steps": 30, **kw})
    d["links"]["default"].update(traffic)
    monkeypatch.setattr(tree_compiled.CompiledTreeExchange, "initial_pool", 1)
    a = _run(d, "", monkeypatch)
    monkeypatch.undo()
    _same(a, _run(d, "python", monkeypatch))


def test_a_queue_in_bytes_runs_the_python_exchange(monkeypatch):
    d = scenario(n=6, edges=tree_edges(6, 3), steps=20)
    d["links"]["default"].update({"rate": 1e5, "queue": {"bytes": 500}})
    assert _run(d, "", monkeypatch).info["backend"]["exchange"] == "python"

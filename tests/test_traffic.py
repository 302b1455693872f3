"""Links that carry the traffic (docs/design.md §3): rate, FIFO transmitter, queue, background.

Hand-worked timelines to the nanosecond on a bare network; queueing theory on one link's
transmitter fed by its keyed background (the code path a run's packets take: a port offers
its packets to the same :class:`~dkfsim.network.media.fifo.Transmitter`); the DKF's
exactness on a rate-limited network against the centralized filter and the arrival log;
a rate so high that every transmission rounds to 0 ns against no rate, bit for bit.
"""

from __future__ import annotations

import numpy as np
import pytest
import reference as ref
import simpy
from conftest import run_scenario, scenario, tree_edges
from test_exactness import check_against_window_reference, check_common, expected_late

from dkfsim.components.faults import LinkSpec
from dkfsim.components.latency import Constant
from dkfsim.components.traffic import Background, Queue, transmission_ns
from dkfsim.config.load import load_scenario
from dkfsim.core.errors import ScenarioError
from dkfsim.engine.driver import run
from dkfsim.network.links import Link
from dkfsim.network.media.fifo import Fifo
from dkfsim.network.network import Network

MS = 1_000_000          # ns


# ------------------------------------------------------------------ hand-worked timelines
def _network(spec: LinkSpec, until: int = 10**10):
    env = simpy.Environment()
    net = Network(env, [(0, 1)], lambda u, v: spec, seed=3, T_ns=10 * MS)
    got: list[tuple[int, str]] = []
    port = net.port("p", lambda link, payload: got.append((env.now, payload)), until=until)
    return env, net, port, got


def _send_at(env, port, link, t, payload, nbytes):
    def proc():
        yield env.timeout(t)
        port.send(link, payload, nbytes)
    env.process(proc())


def test_two_packets_at_one_instant_on_a_1_mbit_link():
    """1000 bytes at 1 Mbit/s take 8 ms; propagation 1 ms: the first arrives at 9 ms, the second
    waits for the first and arrives at 17 ms."""
    spec = LinkSpec(latency=Constant(value=0.001), rate=1e6)
    env, net, port, got = _network(spec)
    link = net.link(0, 1)
    _send_at(env, port, link, 0, "a", 1000)
    _send_at(env, port, link, 0, "b", 1000)
    env.run()
    assert got == [(9 * MS, "a"), (17 * MS, "b")]
    c = port.counts()
    row = c["per_link"][0]
    assert (c["sent"], c["delivered"], c["queue_dropped"], c["in_flight"]) == (2, 2, 0, 0)
    assert row["queueing_delay_mean"] == pytest.approx(0.004)       # (0 + 8 ms) / 2
    assert row["utilisation"] == pytest.approx(16 * MS / 10**10)


def test_a_lost_packet_occupies_the_transmitter():
    """An outage over [0, 0.5 ms) loses the packet handed over at 0, which still takes the
    transmitter for 8 ms: the one handed over at 1 ms starts at 8 ms, arrives at 17 ms."""
    spec = LinkSpec(latency=Constant(value=0.001), rate=1e6, outages=((0.0, 0.0005),))
    env, net, port, got = _network(spec)
    link = net.link(0, 1)
    _send_at(env, port, link, 0, "a", 1000)
    _send_at(env, port, link, 1 * MS, "b", 1000)
    env.run()
    assert got == [(17 * MS, "b")]
    c = port.counts()
    assert (c["sent"], c["lost"], c["outage_lost"], c["delivered"]) == (2, 1, 1, 1)
    assert c["per_link"][0]["queueing_delay_mean"] == pytest.approx((0 + 0.007) / 2)


def test_drop_tail_queue_and_packets_still_queued_are_in_flight():
    """queue {packets: 1}: of three packets handed over at 0 one transmits, one waits, one is
    dropped; a fourth at 20 ms finds the room free again.  Counting stops at 12 ms, when the
    second is still waiting: it is in flight."""
    spec = LinkSpec(latency=Constant(value=0.0), rate=1e6, queue=Queue(packets=1))
    env, net, port, got = _network(spec, until=12 * MS)
    link = net.link(0, 1)
    for name in "abc":
        _send_at(env, port, link, 0, name, 1000)
    _send_at(env, port, link, 20 * MS, "d", 1000)
    env.run()
    assert got == [(8 * MS, "a")]                   # b arrives at 16 ms, d at 28 ms: after until
    c = port.counts()
    assert (c["sent"], c["delivered"], c["queue_dropped"], c["in_flight"]) == (4, 1, 1, 2)
    assert c["sent"] + c["copies"] == (c["delivered"] + c["lost"] + c["queue_dropped"]
                                       + c["crash_dropped"] + c["in_flight"])


def test_bytes_queue_and_background_ahead_at_the_same_instant():
    """Periodic background of 500 bytes every 10 ms from 0 (4 ms each at 1 Mbit/s) is ahead of a
    packet handed over at the same instant; a {bytes: 600} room takes one 500-byte packet."""
    bg = Background(arrivals="periodic", packets_per_second=100.0, size=500)
    spec = LinkSpec(latency=Constant(value=0.0), rate=1e6, queue=Queue(bytes=600), background=bg)
    env, net, port, got = _network(spec, until=40 * MS)
    link = net.link(0, 1)
    _send_at(env, port, link, 10 * MS, "a", 500)   # background at 10 ms first: a waits 4 ms
    _send_at(env, port, link, 10 * MS, "b", 200)   # 500 bytes waiting: 200 more do not fit
    env.run()
    assert got == [(18 * MS, "a")]
    c = port.counts()
    assert c["queue_dropped"] == 1
    row = c["per_link"][0]
    assert row["background_sent"] == 5 and row["background_dropped"] == 0      # 0, 10, ..., 40 ms
    # busy: 0-4, 10-18, 20-24, 30-34 and 40-44 cut at 40 ms
    assert row["utilisation"] == pytest.approx(20 / 40)


def test_transmission_time_rounds_to_the_nearest_ns():
    assert transmission_ns(1000, 1e6) == 8 * MS
    assert transmission_ns(1, 1.6e10) == 1            # 0.5 ns: halves up
    assert transmission_ns(1, 1.7e10) == 0
    assert transmission_ns(10**4, 1e15) == 0          # every packet of a scenario at 1e15 bit/s
    assert transmission_ns(10**6, 1e15) == 8


# ------------------------------------------------------------------ queueing theory
def _transmitter(rate, background, queue=None, seed=5):
    spec = LinkSpec(latency=Constant(), rate=rate, queue=queue, background=background)
    return Fifo(Link(0, 0, 1, spec, seed, 10 * MS)).tx


#: Student's t quantile 0.995 with 29 degrees of freedom (99 % two-sided, 30 batches); a table
#: value, so that collecting this module does not import scipy.stats into every test worker (the
#: hostile tests bound the memory of CLI children forked from the worker).
T_995_29 = 2.756386


def _batch_means(x):
    """Mean and 99 % half-width of the batch means of a correlated sequence (30 batches)."""
    batches = 30
    x = np.asarray(x, dtype=float)
    m = len(x) // batches
    means = x[:m * batches].reshape(batches, m).mean(axis=1)
    half = T_995_29 * means.std(ddof=1) / np.sqrt(batches)
    return float(means.mean()), float(half)


def _check(x, formula, what):
    mean, half = _batch_means(x)
    assert abs(mean - formula) <= half, f"{what}: {mean:.6g} ± {half:.3g} (99 %) misses {formula:.6g}"
    assert half <= 0.03 * formula, f"{what}: interval half-width {half / formula:.1%} above 3 %"
    return mean, half


def _log(tx, seconds):
    tx.advance(int(seconds * 1e9))
    log = tx.log()
    return log[len(log) // 100:]                      # the first 1 % warms the queue up


@pytest.mark.parametrize("rho", [0.5, 0.8])
def test_md1_mean_wait_is_pollaczek_khinchine(rho):
    """Fixed 1000-byte packets at 8 Mbit/s (D = 1 ms), Poisson arrivals at rho / D: the mean wait
    is W = rho / (2 mu (1 - rho)); 10^6 packets."""
    mu = 1000.0
    tx = _transmitter(8e6, Background(packets_per_second=rho * mu, size=1000))
    log = _log(tx, 1e6 / (rho * mu))
    assert len(log) > 9.5e5
    _check((log[:, 1] - log[:, 0]) / 1e9, rho / (2 * mu * (1 - rho)), f"M/D/1 wait at rho={rho}")


def test_mm1_time_in_system():
    """Exponential sizes of mean 12500 bytes at 100 Mbit/s (mean service 1 ms), Poisson arrivals
    at 500/s: the mean time in system is 1 / (mu - lambda) = 2 ms."""
    tx = _transmitter(1e8, Background(packets_per_second=500.0, size=12500, sizes="exponential"))
    log = _log(tx, 2000.0)
    _check((log[:, 2] - log[:, 0]) / 1e9, 1 / (1000.0 - 500.0), "M/M/1 time in system")


def test_mm1k_drop_probability():
    """M/M/1/K with K = 5 (a room of 4 waiting), rho = 0.8: drop probability
    (1 - rho) rho^K / (1 - rho^(K+1))."""
    rho, K = 0.8, 5
    tx = _transmitter(1e8, Background(packets_per_second=800.0, size=12500, sizes="exponential"),
                      queue=Queue(packets=K - 1))
    log = _log(tx, 1250.0)
    p = (1 - rho) * rho**K / (1 - rho ** (K + 1))
    _check(log[:, 1] < 0, p, "M/M/1/K drop probability")
    assert tx.background_dropped == int(np.sum(tx.log()[:, 1] < 0))


def test_littles_law_on_the_measured_queue():
    """The time average of the number waiting, sampled every 2.9 ms (not a multiple of
    anything in the process), equals lambda times the mean wait (and Pollaczek–Khinchine's
    L_q = rho^2 / (2 (1 - rho)) for M/D/1)."""
    rho, mu, seconds = 0.5, 1000.0, 600.0
    tx = _transmitter(8e6, Background(packets_per_second=rho * mu, size=1000), seed=9)
    step = int(2.9 * MS)
    samples = [tx.waiting(t) for t in range(step, int(seconds * 1e9), step)]
    log = tx.log()
    lam_w = len(log) / seconds * float(np.mean((log[:, 1] - log[:, 0]) / 1e9))
    mean, half = _batch_means(samples)
    assert abs(mean - lam_w) <= half, f"L_q {mean:.4g} ± {half:.2g} vs lambda W {lam_w:.4g}"
    assert abs(mean - lam_w) <= 0.03 * lam_w
    assert abs(mean - rho**2 / (2 * (1 - rho))) <= half


def test_background_is_the_same_for_every_transmitter_and_blocks_join():
    """Two transmitters of one link replay the same background, whatever the instants at which
    they are brought up to date (blocks of draws join without a seam)."""
    bg = Background(packets_per_second=5e4, size=100)
    a, b = _transmitter(1e9, bg), _transmitter(1e9, bg)
    a.advance(10**9)
    for t in range(1, 10**9 + 1, 10**9 // 7):
        b.advance(t)
    b.advance(10**9)
    assert len(a.log()) > 3 * 4096 and np.array_equal(a.log(), b.log())


def test_a_huge_waiting_room_holds_only_the_packets_that_wait():
    """queue {packets: 2**40} (the largest the schema takes): the ring of waiting packets starts
    short and doubles as packets wait, and the transmitter takes what one with no bound takes.
    (The ring used to be allocated at the room's size when the link was added: 32 TiB.)"""
    bg = Background(packets_per_second=2000.0, size=1000)        # 2 Mbit/s offered on 1 Mbit/s
    huge, free = _transmitter(1e6, bg, queue=Queue(packets=2**40)), _transmitter(1e6, bg)
    assert huge.table.F.ring.nbytes <= 4096
    huge.advance(10**9)
    free.advance(10**9)
    assert np.array_equal(huge.log(), free.log()) and huge.free_at == free.free_at
    waiting = huge.waiting(10**9)
    assert waiting > 100 and huge.background_dropped == 0
    assert huge.table.F.ring.shape[1] < 4 * waiting             # doubled as needed, no more


def test_a_huge_queue_on_every_link_runs_in_little_memory():
    """A whole run with links.default.queue {packets: 2**40} on links loaded beyond their rate
    (dozens of packets waiting): the same as without a bound (no packet is dropped either
    way), its rings allocated as packets wait."""
    import tracemalloc

    base = _rated(1e5, steps=60, seed=4, latency={"model": "constant", "value": 0.001})
    base["links"]["default"]["background"] = {"packets_per_second": 45.0, "size": 250}
    huge = {**base, "links": {**base["links"], "default": {**base["links"]["default"],
                                                            "queue": {"packets": 2**40}}}}
    a = run_scenario(base)
    tracemalloc.start()
    try:
        b = run_scenario(huge)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 200 * 2**20, peak
    assert a.counts == b.counts and a.counts["sent"] > 0
    assert max(row["queue_length_mean"] for row in a.counts["per_link"]) > 16      # rings did grow
    for key in a.arrays:
        assert np.array_equal(a.arrays[key], b.arrays[key], equal_nan=True), key


# ------------------------------------------------------------------ runs
def _rated(rate, **kw):
    sc = scenario(6, edges=tree_edges(6, 51), **kw)
    sc["links"]["default"]["rate"] = rate
    return sc


@pytest.mark.parametrize("extra", [
    {},
    {"loss": 0.2, "latency": {"model": "exponential", "mean": 0.02, "offset": 0.0}, "links_d_t": 3,
     "protocol": "flood"},
])
def test_rate_1e15_equals_no_rate_bit_for_bit(extra):
    """Every transmission rounds to 0 ns: estimates and counts equal to a run without rate (on
    the Python exchange, which both take), the consensus family included."""
    ests = [{"kind": "ci_consensus", "rounds": 2}, {"kind": "diffusion_kf"}]
    plain = dict(scenario(6, edges=tree_edges(6, 51), steps=60, **extra), estimators=ests)
    fast = dict(_rated(1e15, steps=60, **extra), estimators=ests)
    a, b = run(load_scenario(plain)), run(load_scenario(fast))
    assert set(a.arrays) == set(b.arrays) - {"rated_links", "queue_length", "utilisation",
                                             "queueing_delay_quantiles"}
    for key in a.arrays:
        assert np.array_equal(a.arrays[key], b.arrays[key], equal_nan=True), key
    strip = ("utilisation", "queueing_delay_mean", "queueing_delay_p95", "background_sent",
             "background_dropped", "queue_length_mean")

    def plain_counts(t):
        return {**t, "per_link": [{k: v for k, v in r.items() if k not in strip} for r in t["per_link"]]}
    assert plain_counts(b.counts) == a.counts
    for name, t in a.traffic.items():
        assert (plain_counts(b.traffic[name]) if t is not None else None) == t, name
    assert a.counts["sent"] > 0 and (not extra or a.counts["lost"] > 0)


def test_dkf_is_exact_on_a_rate_limited_network():
    """Rate 200 kbit/s with background: packets queue (delays of ms), but a 12-row buffer holds
    everything: no contribution is late and every final row is the centralized filter."""
    sc = _rated(2e5, steps=80, seed=4, latency={"model": "uniform", "low": 0.0, "high": 0.02},
                buffer_length=12)
    sc["links"]["default"]["background"] = {"packets_per_second": 20.0, "size": 200}
    r = run_scenario(sc)
    a = r.arrays
    xs, _ = check_common(r)
    assert expected_late(a) == 0 and r.counts["late"] == 0
    delays = [row["queueing_delay_mean"] for row in r.counts["per_link"]]
    assert max(delays) > 1e-3, "the rate was meant to make packets wait"
    nfinal = 80 - 12 + 1
    for i in range(6):
        ref.assert_close(a["x_final"][:nfinal, i], xs[:nfinal], f"x_final node {i} vs centralized", 1e-9)
    check_against_window_reference(r)


def test_dkf_late_on_a_slow_link_equals_the_arrival_log():
    """At 10 kbit/s queues grow (seconds) past a 3-row buffer: ``late`` equals the count from the
    arrival log (late contributions are counted once however long they queued), and the
    estimates follow the window rule on what arrived."""
    sc = _rated(1e4, steps=80, seed=6, latency={"model": "constant", "value": 0.001}, buffer_length=3)
    r = run_scenario(sc)
    late = expected_late(r.arrays)
    assert late > 0
    assert r.counts["late"] == late
    check_against_window_reference(r)


@pytest.mark.parametrize("crash", [False, True])
def test_receive_and_flush_in_one_call_equal_the_two_calls(monkeypatch, crash):
    """On rate-limited links no packet arrives at the instant it is sent, so the tree hands a
    delivery and the flushes it makes due to one kernel call (``receive_flush``): every array
    and count equals the run that asks the port before each flush (the two calls), and the
    one-call path was taken; with a node down for a while too (its packets dropped on arrival)."""
    from dkfsim.network.port import RecordPort
    from dkfsim.protocols import tree_kernels

    sc = _rated(2e5, steps=60, seed=4, latency={"model": "uniform", "low": 0.0, "high": 0.02}, buffer_length=5)
    sc["links"]["default"]["background"] = {"packets_per_second": 20.0, "size": 200}
    if crash:
        sc["faults"] = {"crashes": [{"node": 1, "start": 0.2, "end": 0.4}]}
    calls = []
    real = tree_kernels.receive_flush
    monkeypatch.setattr(tree_kernels, "receive_flush", lambda *a: calls.append(1) or real(*a))
    monkeypatch.setenv("DKFSIM_KERNELS", "numpy")          # (the Python functions: counted)
    one = run_scenario(sc)
    taken = len(calls)
    assert taken > 100
    monkeypatch.setattr(RecordPort, "never_now", lambda self, links, q, nbytes: False)
    two = run_scenario(sc)
    assert len(calls) == taken                          # (the two calls this time)
    assert one.counts == two.counts and one.counts["delivered"] > 0
    assert (one.counts["crash_dropped"] > 0) == crash
    for key in one.arrays:
        assert np.array_equal(one.arrays[key], two.arrays[key], equal_nan=True), key


# ------------------------------------------------------------------ bad input
@pytest.mark.parametrize("links, key, words", [
    ({"default": {"rate": 0}}, "links.default.rate", ">= 1.0"),
    ({"default": {"rate": "fast"}}, "links.default.rate", "number"),
    ({"default": {"rate": 1e6, "queue": {"packets": 1, "bytes": 10}}}, "links.default.queue", "exactly one"),
    ({"default": {"rate": 1e6, "queue": {"packet": 1}}}, "links.default.queue", "did you mean"),
    ({"default": {"queue": {"packets": 3}}}, "links.default.queue", "no rate"),
    ({"default": {"rate": 1e6, "background": {"packets_per_second": 10.0, "size": 100, "offset": 1.0}}},
     "links.default.background", "periodic"),
    ({"default": {"rate": 1e6, "background": {"packets_per_second": -1.0, "size": 100}}},
     "links.default.background.packets_per_second", "> 0"),
])
def test_bad_traffic_keys_are_clear_errors(links, key, words):
    sc = scenario(4, edges=tree_edges(4, 1))
    sc["links"]["default"].update(links["default"])
    with pytest.raises(ScenarioError) as err:
        load_scenario(sc)
    text = str(err.value)
    assert key in text and words in text, text


def _twins(shared):
    sc = scenario(6, edges=tree_edges(6, 51), steps=60, latency={"model": "constant", "value": 0.001},
                  buffer_length=2)
    sc["links"]["default"]["rate"] = 2e4
    if shared:
        sc["links"]["shared_queues"] = True
    sc["estimators"] = [{"kind": "anti_delay_dkf", "name": "twin"}]
    return run(load_scenario(sc))


def _mean_delay(traffic):
    return float(np.mean([row["queueing_delay_mean"] for row in traffic["per_link"]]))


def test_each_estimator_has_its_own_queues_unless_shared():
    """Two instances of the same DKF: on their own queues they see identical links (estimates
    and traffic equal); through shared queues each waits for the other's packets too."""
    alone, shared = _twins(False), _twins(True)
    assert np.array_equal(alone.arrays["x_fused"], alone.arrays["x_twin"])
    packets = [{k: v for k, v in alone.traffic[name].items() if not k.startswith("late")}
               for name in ("fused", "twin")]          # (late: the twin counts packet rows)
    assert packets[0] == packets[1]
    assert _mean_delay(shared.traffic["fused"]) > _mean_delay(alone.traffic["fused"])
    assert _mean_delay(shared.traffic["twin"]) > _mean_delay(alone.traffic["twin"])
    assert not np.array_equal(shared.arrays["x_twin"], alone.arrays["x_twin"])

"""The port's frame and sharing API (issue 22): ``Port.send_frame`` without a channel is the
per-link sends bit for bit; a port made ``share_with`` another waits in its transmitters but
keeps its own counters, receiver and keyed sequence space (numbers from ``1 << 32``)."""

from __future__ import annotations

import simpy

from dkfsim.components.faults import LinkSpec
from dkfsim.components.latency import Constant, Uniform
from dkfsim.core.streams import key64, keyed_uniform
from dkfsim.network.network import Network
from dkfsim.network.port import SHARED_SEQ0

MS = 1_000_000          # ns
ARCS = [(0, 1), (0, 2), (0, 3), (1, 0)]


def _net(spec: LinkSpec, arcs=ARCS, seed: int = 11):
    env = simpy.Environment()
    return env, Network(env, arcs, lambda u, v: spec, seed=seed, T_ns=10 * MS)


def _at(env, t, action):
    def proc():
        yield env.timeout(t)
        action()
    env.process(proc())


def _run(spec: LinkSpec, framed: bool):
    """Three instants of a sender that broadcasts to 1, 2, 3 and unicasts to 2: as frames or as
    per-link sends; what arrives when and the counts."""
    env, net = _net(spec)
    got: list = []
    port = net.port("p", lambda link, payload: got.append((env.now, link.dst, payload)))
    links = [net.link(0, j) for j in (1, 2, 3)]
    for t in (0, 3 * MS, 3 * MS, 7 * MS):
        def act(t=t):
            parts = [(link, ("b", t), 40 + link.dst) for link in links]
            if framed:
                port.send_frame(parts, 41)
                port.send_frame([(links[1], ("u", t), 100)], 100)
            else:
                for link, payload, n in parts:
                    port.send(link, payload, n)
                port.send(links[1], ("u", t), 100)
        _at(env, t, act)
    env.run()
    return got, port.counts()


def test_send_frame_without_a_medium_is_the_per_link_sends():
    """Loss, duplication, a random latency and a rate-limited queue: the same arrivals (instant,
    order) and the same counters either way."""
    spec = LinkSpec(latency=Uniform(low=0.0, high=0.004), loss=0.3, duplicate=0.3, rate=1e5)
    framed, plain = _run(spec, True), _run(spec, False)
    assert framed == plain
    got, counts = framed
    assert counts["sent"] == 16 and counts["bytes"] == 4 * (41 + 42 + 43 + 100)
    assert counts["lost"] > 0 and counts["copies"] > 0 and len(got) > 0


def _shared_pair(spec: LinkSpec, sharer_sends: bool):
    env, net = _net(spec, arcs=[(0, 1)])
    got_a: list = []
    got_b: list = []
    a = net.port("a", lambda link, payload: got_a.append((env.now, payload)))
    b = net.port("b", lambda link, payload: got_b.append((env.now, payload)), share_with=a)
    link = net.link(0, 1)
    _at(env, 0, lambda: a.send(link, "a0", 1000))
    if sharer_sends:
        _at(env, 0, lambda: b.send(link, "b0", 1000))
    _at(env, 0, lambda: a.send(link, "a1", 1000))
    env.run()
    return net, link, a, b, got_a, got_b


def test_a_sharing_port_waits_in_the_other_ports_transmitter():
    """1000 bytes at 1 Mbit/s take 8 ms, propagation 1 ms.  At 0 the port a hands a0, then b
    (sharing a's transmitter) b0, then a a1: a0 is sent 0-8 ms (arrives 9), b0 8-16 (17), a1
    16-24 (25).  Each port receives its own packets only and counts its own."""
    spec = LinkSpec(latency=Constant(value=0.001), rate=1e6)
    net, link, a, b, got_a, got_b = _shared_pair(spec, sharer_sends=True)
    assert got_a == [(9 * MS, "a0"), (25 * MS, "a1")]
    assert got_b == [(17 * MS, "b0")]
    ca, cb = a.counts(), b.counts()
    assert (ca["sent"], ca["delivered"], cb["sent"], cb["delivered"]) == (2, 2, 1, 1)
    # the shared transmitter's log holds both ports' packets, as each port sees it
    for port in (a, b):
        log = sorted(map(tuple, port.link_log(link).tolist()))
        assert log == [(0, 0, 8 * MS), (0, 8 * MS, 16 * MS), (0, 16 * MS, 24 * MS)]
    assert ca["per_link"][0]["utilisation"] == cb["per_link"][0]["utilisation"]


def test_a_separate_port_does_not_wait_without_share_with():
    spec = LinkSpec(latency=Constant(value=0.001), rate=1e6)
    env, net = _net(spec, arcs=[(0, 1)])
    got_b: list = []
    a = net.port("a", lambda link, payload: None)
    b = net.port("b", lambda link, payload: got_b.append(env.now))
    link = net.link(0, 1)
    _at(env, 0, lambda: a.send(link, "a0", 1000))
    _at(env, 0, lambda: b.send(link, "b0", 1000))
    env.run()
    assert got_b == [9 * MS]


def test_a_sharing_ports_draws_come_from_its_own_sequence_space():
    """Latency uniform on [0, 4 ms], no rate: the sharer's packet at 0 is number 1 << 32 of
    the instant, its latency the keyed draw at (0, 1 << 32); a's two packets keep seq 0 and 1."""
    spec = LinkSpec(latency=Uniform(low=0.0, high=0.004))
    net, link, a, b, got_a, got_b = _shared_pair(spec, sharer_sends=True)
    key = key64(11, "link", 0, 1, "latency")

    def lat(seq):
        return int(Uniform(low=0.0, high=0.004).from_uniform(keyed_uniform(key, 0, seq), 10 * MS))
    assert SHARED_SEQ0 == 1 << 32
    assert got_b == [(lat(SHARED_SEQ0), "b0")]
    assert sorted(got_a) == sorted([(lat(0), "a0"), (lat(1), "a1")])
    assert lat(SHARED_SEQ0) not in (lat(0), lat(1))


def test_the_other_ports_arrivals_are_unchanged_when_the_sharer_sends_nothing():
    spec = LinkSpec(latency=Uniform(low=0.0, high=0.004), loss=0.2, rate=2e6)
    _, _, _, _, with_sharer, _ = _shared_pair(spec, sharer_sends=False)
    env, net = _net(spec, arcs=[(0, 1)])
    alone: list = []
    a = net.port("a", lambda link, payload: alone.append((env.now, payload)))
    link = net.link(0, 1)
    _at(env, 0, lambda: a.send(link, "a0", 1000))
    _at(env, 0, lambda: a.send(link, "a1", 1000))
    env.run()
    assert with_sharer == alone and len(alone) >= 1

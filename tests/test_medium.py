"""The shared radio channel (``medium:``, issue 22; docs/design.md §3, "A shared radio channel").

Timelines are worked by hand from the documented rule: slot boundaries ``t_idle + aifs + m *
slot`` after the channel last became idle; a head frame's backoff ``floor(u * (cw + 1))``, ``u``
the keyed uniform of ``("channel", 0, node, "backoff")`` at (the instant it became head, the
attempt); it is sent that many boundaries after the first boundary at or after it became head;
a start freezes the others' remaining counts; frames starting at one boundary collide.  The
draws are computed here from the key, never read from the engine.
"""

from __future__ import annotations

import subprocess
import sys

import pytest
import simpy
import yaml
from conftest import scenario, tree_edges
from hypothesis import given, settings
from hypothesis import strategies as st

from dkfsim.components.faults import Crash, CrashSchedule, Faults, LinkSpec
from dkfsim.components.latency import Constant
from dkfsim.components.medium import Csma, Medium
from dkfsim.components.traffic import Background, Queue
from dkfsim.config.load import load_scenario
from dkfsim.core.errors import ScenarioError
from dkfsim.core.streams import key64, keyed_uniform
from dkfsim.engine.driver import run
from dkfsim.network.media.base import Frame
from dkfsim.network.media.channel import Channel
from dkfsim.network.network import Network

US = 1_000                 # ns
MS = 1_000_000
SLOT, AIFS, PRE = 13 * US, 110 * US, 40 * US
RATE = 6e6
CW = 15
#: one-way propagation of link u -> v: (1 + u + 10 v) us, so every link's arrivals differ
LAT = {(u, v): (1 + u + 10 * v) * US for u in range(4) for v in range(4)}


def airtime(size: int) -> int:
    """preamble + size * 8 / rate, nearest ns."""
    return PRE + int(size * 8 * 1e9 / RATE + 0.5)


def backoff(seed: int, node: int, t: int, attempt: int = 0) -> int:
    return int(keyed_uniform(key64(seed, "channel", 0, node, "backoff"), t, attempt) * (CW + 1))


def first_boundary(t_idle: int, h: int) -> int:
    """The index of the first boundary at or after ``h`` of the idle period from ``t_idle``."""
    first = t_idle + AIFS
    return 0 if h <= first else -(-(h - first) // SLOT)


def boundary(t_idle: int, m: int) -> int:
    return t_idle + AIFS + m * SLOT


def medium(**kw) -> Medium:
    return Medium(rate=RATE, access=Csma(slot=SLOT / 1e9, aifs=AIFS / 1e9, cw=CW), preamble=PRE / 1e9, **kw)


def network(seed: int, med: Medium, n: int = 4, loss: float = 0.0, crashes: CrashSchedule | None = None):
    env = simpy.Environment()
    arcs = [(u, v) for u in range(n) for v in range(n) if u != v]
    net = Network(env, arcs, lambda u, v: LinkSpec(latency=Constant(value=LAT[(u, v)] / 1e9), loss=loss),
                  seed=seed, T_ns=10 * MS, medium=med, crashes=crashes)
    got: list = []
    port = net.port("p", lambda link, payload: got.append((env.now, link.src, link.dst, payload)))
    return env, net, port, got


def at(env, t, action):
    def proc():
        yield env.timeout(t)
        action()
    env.process(proc())


def seed_where(condition, nodes, t):
    """The first seed whose backoffs of ``nodes`` at ``t`` satisfy ``condition``."""
    for seed in range(1000):
        b = [backoff(seed, node, t) for node in nodes]
        if condition(*b):
            return seed, b
    raise AssertionError("no seed")


T0 = 1 * MS


# ------------------------------------------------------------------ hand-worked timelines
def test_two_nodes_contend_and_a_broadcast_reaches_three_neighbours():
    """At 1 ms node 0 broadcasts 100 bytes to 1, 2, 3 (one frame) and node 1 unicasts 200
    bytes to 0.  The channel has been idle since 0: the first boundary at or after 1 ms is
    index 69 (110 us + 69 x 13 us = 1.007 ms).  The smaller backoff goes first; the other
    resumes its remaining count after the first frame ends."""
    seed, (b0, b1) = seed_where(lambda a, b: a != b, (0, 1), T0)
    env, net, port, got = network(seed, medium())
    parts = [(net.link(0, j), "bcast", 100) for j in (1, 2, 3)]
    at(env, T0, lambda: port.send_frame(parts, 100))
    at(env, T0, lambda: port.send(net.link(1, 0), "uni", 200))
    env.run()
    j = first_boundary(0, T0)
    assert j == 69
    first, second = (0, 1) if b0 < b1 else (1, 0)
    size = {0: 100, 1: 200}
    start1 = boundary(0, j + min(b0, b1))
    end1 = start1 + airtime(size[first])
    start2 = boundary(end1, abs(b1 - b0))          # the frozen count: the boundaries it had left
    end2 = start2 + airtime(size[second])
    ends = {first: end1, second: end2}
    expected = sorted([(ends[0] + LAT[(0, v)], 0, v, "bcast") for v in (1, 2, 3)]
                      + [(ends[1] + LAT[(1, 0)], 1, 0, "uni")])
    assert sorted(got) == expected
    c = port.counts()
    assert (c["sent"], c["delivered"], c["lost"], c["collision_lost"], c["bytes"]) == (4, 4, 0, 0, 500)
    ch = c["channel"]
    assert (ch["frames"], ch["collisions"], ch["frames_collided"]) == (2, 0, 0)
    assert ch["access_delay_mean"] == pytest.approx(((start1 - T0) + (start2 - T0)) / 2 / 1e9)
    assert ch["utilisation"] == pytest.approx((end1 - start1 + end2 - start2) / env.now)


def test_frames_starting_at_one_boundary_collide_and_every_part_is_lost():
    seed, (b0, b1) = seed_where(lambda a, b: a == b, (0, 1), T0)
    env, net, port, got = network(seed, medium())
    at(env, T0, lambda: port.send_frame([(net.link(0, j), "x", 50) for j in (1, 2)], 50))
    at(env, T0, lambda: port.send(net.link(1, 3), "y", 400))
    env.run()
    assert got == []
    c = port.counts()
    rows = {r["link"]: r for r in c["per_link"]}
    for link in ((0, 1), (0, 2), (1, 3)):
        assert (rows[link]["sent"], rows[link]["lost"], rows[link]["collision_lost"]) == (1, 1, 1)
    ch = c["channel"]
    assert (ch["collisions"], ch["frames"], ch["frames_collided"]) == (1, 2, 2)
    start = boundary(0, first_boundary(0, T0) + b0)
    # busy until the longer frame ends
    assert ch["utilisation"] == pytest.approx(airtime(400) / env.now)
    assert env.now == start + airtime(400)


def test_a_third_nodes_count_resumes_after_each_busy_period():
    seed, b = seed_where(lambda a, b, c: len({a, b, c}) == 3, (0, 1, 2), T0)
    env, net, port, got = network(seed, medium())
    for node in (0, 1, 2):
        at(env, T0, lambda node=node: port.send(net.link(node, 3), node, 100))
    env.run()
    order = sorted(range(3), key=lambda i: b[i])
    ba, bb, bc = (b[i] for i in order)
    j = first_boundary(0, T0)
    s1 = boundary(0, j + ba)
    e1 = s1 + airtime(100)
    s2 = boundary(e1, bb - ba)
    e2 = s2 + airtime(100)
    s3 = boundary(e2, bc - bb)           # frozen twice: bc - ba left, then bc - bb
    e3 = s3 + airtime(100)
    assert sorted(got) == sorted([(e + LAT[(node, 3)], node, 3, node)
                                  for e, node in zip((e1, e2, e3), order)])


def test_drop_tail_and_a_fresh_backoff_keyed_by_the_end_of_the_frame():
    """A waiting room of 2 frames: three frames handed over at once, the third dropped; the
    second draws its backoff at the first's end (attempt 0)."""
    seed = 3
    env, net, port, got = network(seed, medium(queue=Queue(packets=2)))
    link = net.link(0, 1)
    for k in range(3):
        at(env, T0, lambda k=k: port.send(link, k, 100))
    env.run()
    s1 = boundary(0, first_boundary(0, T0) + backoff(seed, 0, T0))
    e1 = s1 + airtime(100)
    s2 = boundary(e1, backoff(seed, 0, e1))
    e2 = s2 + airtime(100)
    assert got == [(e1 + LAT[(0, 1)], 0, 1, 0), (e2 + LAT[(0, 1)], 0, 1, 1)]
    c = port.counts()
    assert (c["sent"], c["delivered"], c["queue_dropped"], c["in_flight"]) == (3, 2, 1, 0)
    assert c["channel"]["frames_dropped"] == 1


def test_periodic_background_is_ahead_and_contends():
    """Members 0 and 1, one 300-byte background frame each at 0.5 ms (periodic, 1 per second,
    offset 0.5 ms: exactly boundary 30), and node 0 hands a 100-byte frame at 0.5 ms, behind its
    background frame.  The seed is chosen so that node 0's background goes first and its own
    frame then beats node 1's frozen count."""
    h = 500 * US
    assert first_boundary(0, h) == 30 and boundary(0, 30) == h
    for seed in range(1000):
        b0, b1 = backoff(seed, 0, h), backoff(seed, 1, h)
        if b0 >= b1:
            continue
        e0 = boundary(0, 30 + b0) + airtime(300)
        bp = backoff(seed, 0, e0)
        if bp < b1 - b0:
            break
    bg = Background(arrivals="periodic", packets_per_second=1.0, size=300, offset=0.0005)
    env, net, port, got = network(seed, medium(background=bg, nodes=(0, 1)))
    at(env, h, lambda: port.send(net.link(0, 1), "p", 100))
    env.run()
    sp = boundary(e0, bp)
    ep = sp + airtime(100)
    assert got == [(ep + LAT[(0, 1)], 0, 1, "p")]
    ch = port.counts()["channel"]
    assert ch["access_delay_mean"] == pytest.approx((sp - h) / 1e9)
    # node 1's background resumes with b1 - b0 - bp left after the port's frame
    s1 = boundary(ep, b1 - b0 - bp)
    end = s1 + airtime(300) + 1
    assert port.channel is not None
    port.channel.advance(end)          # (after the run's last event: background only)
    stats = port.channel.stats(end)
    assert (stats["background_sent"], stats["collisions"]) == (2, 0)
    assert stats["utilisation"] == pytest.approx((2 * airtime(300) + airtime(100)) / end)
    # as of end, however far the channel is brought afterwards (the next background: 1.0005 s)
    port.channel.advance(1_200 * MS)
    assert port.channel.stats(end) == stats and port.channel.stats(1_200 * MS)["background_sent"] == 4


def test_each_port_has_its_own_copy_with_the_same_draws_and_share_with_shares_it():
    seed, _ = seed_where(lambda a, b: a != b, (0, 1), T0)
    env, net, a, got_a = network(seed, medium())
    got_b: list = []
    b = net.port("b", lambda link, payload: got_b.append((env.now, link.src, link.dst, payload)))
    got_c: list = []
    c = net.port("c", lambda link, payload: got_c.append((env.now, link.src, link.dst, payload)), share_with=a)
    for port in (a, b):
        at(env, T0, lambda port=port: port.send(net.link(0, 1), "x", 100))
        at(env, T0, lambda port=port: port.send(net.link(1, 0), "y", 100))
    env.run()
    assert got_a == got_b and len(got_a) == 2      # b's copy: the same as if it ran alone
    assert got_c == [] and c.channel is a.channel and b.channel is not a.channel


# ------------------------------------------------------------------ accounting
def test_the_counting_identity_holds_per_link_over_a_random_run():
    bg = Background(arrivals="poisson", packets_per_second=2000.0, size=300)
    env, net, port, got = network(7, medium(background=bg, queue=Queue(packets=3)), loss=0.2)
    links = net.links
    for k in range(200):
        t = 37 * US * k
        link = links[(k * 7) % len(links)]
        if k % 3 == 0:
            parts = [(l, k, 60) for l in links if l.src == link.src]
            at(env, t, lambda parts=parts: port.send_frame(parts, 60))
        else:
            at(env, t, lambda link=link, k=k: port.send(link, k, 200))
    port.until = 5 * MS               # some still in flight at the end
    env.run()
    c = port.counts()
    for row in [c] + c["per_link"]:
        assert row["sent"] + row["copies"] == (row["delivered"] + row["lost"] + row["queue_dropped"]
                                               + row["crash_dropped"] + row["in_flight"])
        assert row["collision_lost"] <= row["lost"]
    assert c["collision_lost"] > 0 and c["queue_dropped"] > 0 and c["in_flight"] > 0


@settings(max_examples=60, deadline=None)
@given(offers=st.lists(st.tuples(st.integers(0, 3), st.integers(0, 400), st.integers(1, 400)),
                       min_size=1, max_size=30),
       cw=st.integers(0, 7), slot=st.integers(1, 20), aifs=st.integers(0, 30),
       background=st.booleans(), seed=st.integers(0, 50))
def test_the_channel_never_carries_two_frames_unless_they_collide(offers, cw, slot, aifs, background, seed):
    """Offers (node, instant us, bytes) at 1 Mbit/s: no frame starts while another is on the
    air, only frames starting together overlap (and all of them are lost), every successful
    frame is alone on the air, and each frame offered is dropped or ends exactly once, and its sender is told at its end."""
    spec = Medium(rate=1e6, access=Csma(slot=slot * 1e-6, aifs=aifs * 1e-6, cw=cw), preamble=0.0,
                  queue=Queue(packets=4),
                  background=Background(arrivals="periodic", packets_per_second=3000.0, size=50)
                  if background else None)
    env = simpy.Environment()
    ch = Channel(env, spec, (0, 1, 2, 3), seed, record=True)
    ended: list = []
    dropped: list = []

    def offer(i, node, size):
        frame = Frame(node, size, env.now, i, lambda f, ok: ended.append((f.parts, f.start, f.end, ok, env.now)))
        if not ch.offer(frame):
            dropped.append(i)
    for i, (node, t, size) in enumerate(offers):
        at(env, t * US, lambda i=i, node=node, size=size: offer(i, node, size))
    env.run()
    assert sorted([e[0] for e in ended] + dropped) == list(range(len(offers)))
    for i, (a, sa, ea, oka, told) in enumerate(ended):
        assert told == ea                     # its sender hears of its end at that instant
        assert sa >= offers[a][1] * US and ea == sa + int(offers[a][2] * 8 * 1000 + 0.5)
        for _, sb, eb, okb, _ in ended[i + 1:]:
            if sa < eb and sb < ea:            # overlap: only a collision
                assert sa == sb and not oka and not okb
    # every frame that ended, background included: none starts while another is on the air
    # unless both start at once, and then all of them are lost; a lone frame is never lost
    ch.advance(env.now)
    assert ch.ended is not None
    air = sorted(ch.ended + [(f.node, f.start, f.end, not ch.collided, f.done is None) for f in ch.on_air],
                 key=lambda e: (e[1], e[0]))
    for i, (_, s1, e1, ok1, _) in enumerate(air):
        together = [e for e in air if e[1] == s1]
        assert ok1 == (len(together) == 1)
        for _, s2, _, ok2, _ in air[i + 1:]:
            if s2 < e1:
                assert s2 == s1 and not ok1 and not ok2
    stats = ch.stats(env.now)
    assert stats["collisions"] == len({e[1] for e in air if not e[3]})
    assert stats["frames_on_air"] == len(air)


@settings(max_examples=60, deadline=None)
@given(offers=st.lists(st.tuples(st.integers(0, 3), st.integers(0, 60), st.integers(1, 300)),
                       min_size=1, max_size=30),
       looks=st.lists(st.integers(0, 400), max_size=40), cw=st.integers(0, 7),
       background=st.booleans(), seed=st.integers(0, 50))
def test_the_timeline_is_the_same_however_often_the_channel_is_brought_up_to_date(offers, looks, cw,
                                                                                 background, seed):
    """The engine is lazy (decision 235): a copy also brought up to date at other instants
    (``looks``, us), several times at each, and again before every offer (many frames offered
    at one instant, as a broadcast round does) carries every frame at the same instants with
    the same fate, and tells its senders at the same instants, as a copy brought up to date
    only by its own offers and wake-ups."""
    spec = Medium(rate=1e6, access=Csma(slot=9e-6, aifs=20e-6, cw=cw), preamble=0.0, queue=Queue(packets=3),
                  background=Background(arrivals="periodic", packets_per_second=4000.0, size=40)
                  if background else None)

    def timeline(eager: bool):
        env = simpy.Environment()
        ch = Channel(env, spec, (0, 1, 2, 3), seed, record=True)
        told: list = []

        def offer(i, node, size):
            if eager:
                ch.advance(env.now)
                ch.advance(env.now)
            if not ch.offer(Frame(node, size, env.now, i,
                                  lambda f, ok: told.append((f.parts, f.start, f.end, ok, env.now)))):
                told.append((i, "dropped", env.now))
        for i, (node, t, size) in enumerate(offers):
            at(env, t * 10 * US, lambda i=i, node=node, size=size: offer(i, node, size))
        if eager:
            for t in looks:
                for _ in range(2):
                    at(env, t * 10 * US, lambda: ch.advance(env.now))
        at(env, 5 * MS, lambda: None)          # (both end at 5 ms: after every frame and look)
        env.run()
        return told, ch.ended, ch.stats(env.now)
    lazy, eager = timeline(False), timeline(True)
    assert lazy == eager
    assert sorted(e[0] for e in lazy[0]) == list(range(len(offers)))     # each ended or dropped once


# ------------------------------------------------------------------ runs
def _with_medium(**over):
    sc = scenario(5, edges=tree_edges(5, 1), latency={"model": "constant", "value": 0.002}, steps=40)
    sc["protocol"] = "flood"
    sc["medium"] = {"rate": 1.0e6, "background": {"arrivals": "periodic", "packets_per_second": 10.0,
                                                   "size": 300}, **over}
    return sc


def test_a_run_on_the_channel_counts_and_reports_it():
    res = run(load_scenario(_with_medium()))
    t = res.traffic["fused"]
    assert t["sent"] + t["copies"] == (t["delivered"] + t["lost"] + t["queue_dropped"] + t["crash_dropped"]
                                       + t["in_flight"])
    ch = t["channel"]
    assert ch["frames"] > 0 and 0 < ch["utilisation"] < 1 and ch["background_sent"] > 0
    assert res.counts == t


@pytest.mark.parametrize("medium, key, words", [
    ({"rate": 0}, "medium.rate", ">= 1"),
    ({"rate": 1e6, "access": {"cw": -1}}, "medium.access.cw", ">= 0"),
    ({"rate": 1e6, "access": {"cw": 4096}}, "medium.access.cw", "<= 1023"),
    ({"rate": 1e6, "access": {"slot": 0.0}}, "medium.access.slot", "> 0"),
    ({"rate": 1e6, "access": {"slot": 1e-10}}, "medium.access.slot", "one nanosecond"),
    ({"rate": 1e6, "access": {"kind": "tdma"}}, "medium.access.kind", "csma"),
    ({"rate": 1e6, "nodes": [0, 9]}, "medium.nodes.1", "out of range"),
    ({"rate": 1e6, "queue": {"packets": 0}}, "medium.queue.packets", "at least one"),
    ({"rate": 1e6, "nodes": [0]}, "medium.nodes", "at least two nodes"),
    ({"rate": 1e6, "nodes": "some"}, "medium.nodes", "give 'all' or a list"),
    ({"rate": 1e6, "nodes": [0, -1]}, "medium.nodes.1: ", "integer >= 0, got -1"),
    ({"rate": 1e6, "nodes": [0, 1.0]}, "medium.nodes.1: ", "integer >= 0, got 1.0"),
    ({"rate": 1e6, "nodes": [0, True]}, "medium.nodes.1: ", "integer >= 0, got True"),
    ({"rate": 1e6, "nodes": None}, "medium.nodes: ", "give 'all' or a list of at least two distinct"),
    ({"rate": 1e6, "nodes": {0: 1}}, "medium.nodes: ", "give 'all' or a list of at least two distinct"),
    ({"rate": 1e6, "preamble": 2.0}, "medium.preamble", "<= 1"),
])
def test_bad_medium_keys_are_clear_errors(medium, key, words):
    sc = _with_medium()
    sc["medium"] = medium
    with pytest.raises(ScenarioError) as err:
        load_scenario(sc)
    text = str(err.value)
    assert key in text and words in text, text
    assert "literal[" not in text and "tuple[" not in text, text      # no validation internals
    assert text.count(key) == 1 and "at least 2 items" not in text, text    # one problem, said once


def test_a_link_rate_on_the_channel_is_refused_with_exit_2(tmp_path):
    sc = _with_medium()
    sc["links"]["default"]["rate"] = 1e6
    path = tmp_path / "s.yaml"
    path.write_text(yaml.safe_dump(sc))
    out = subprocess.run([sys.executable, "-m", "dkfsim", "validate", str(path)], capture_output=True, text=True)
    assert out.returncode == 2, out.stderr
    assert "links.default.rate" in out.stderr and "shared channel" in out.stderr and "Traceback" not in out.stderr


def test_a_link_to_a_centre_outside_the_graph_is_on_the_channel():
    """``centralized_delayed``'s direct link from a member to the centre (dst -1) goes as a frame
    (decision 216): it arrives at the frame's end plus its latency."""
    seed = 4
    # node 3 (the last) is down the whole time: the centre's deliveries are not its
    down = CrashSchedule(Faults(crashes=(Crash(node=3, start=0.0, end=1.0),)), 4)
    env, net, port, got = network(seed, medium(), crashes=down)
    link = net.extra_link(("direct", 2), LinkSpec(latency=Constant(value=0.0005)), 2, -1)
    assert net.on_channel(link)
    at(env, T0, lambda: port.send(link, "c", 100))
    env.run()
    end = boundary(0, first_boundary(0, T0) + backoff(seed, 2, T0)) + airtime(100)
    assert got == [(end + 500 * US, 2, -1, "c")]


def test_validate_says_the_scenario_has_a_channel(tmp_path):
    path = tmp_path / "s.yaml"
    path.write_text(yaml.safe_dump(_with_medium(nodes=[0, 1, 2])))
    out = subprocess.run([sys.executable, "-m", "dkfsim", "validate", str(path)], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert "3 nodes on one shared channel of 1e+06 bit/s (csma, cw 15" in out.stdout

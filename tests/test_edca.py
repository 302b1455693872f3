"""``medium.access.kind: edca`` (IEEE 802.11p EDCA, issue 32) on one collision domain, and
``medium.generation_jitter``.

Timelines worked by hand from the rule in docs/radio.md: a frame that finds the medium idle with
no backoff pending goes once the medium has been idle for AIFS (at once when it has been); one
that finds it busy draws ``b = floor(u * (cw + 1))``, ``u`` the keyed uniform of ``("channel", 0,
node, "edca")`` at (instant, attempt), and goes ``b`` slots after the next idle period's AIFS,
its count frozen while the medium is busy; after every own frame a post-backoff is drawn at the
frame's end; after a collision the radios that did not send wait EIFS.  Draws are computed here
from the key, never read from the engine.
"""

from __future__ import annotations

import math

import pytest
import simpy
from test_medium import LAT, MS, PRE, RATE, SLOT, US, airtime, at

from dkfsim.components.faults import LinkSpec
from dkfsim.components.latency import Constant
from dkfsim.components.medium import Csma, Edca, Medium
from dkfsim.core.streams import key64, keyed_uniform
from dkfsim.network.network import Network

AIFS, EIFS, CW = 110 * US, 230 * US, 15
T0 = 1 * MS


def draw(seed: int, node: int, t: int, attempt: int = 0, name: str = "edca", cw: int = CW) -> int:
    return int(keyed_uniform(key64(seed, "channel", 0, node, name), t, attempt) * (cw + 1))


def medium(**kw) -> Medium:
    access = kw.pop("access", Edca(slot=SLOT / 1e9, aifs=AIFS / 1e9, cw=CW, eifs=EIFS / 1e9))
    return Medium(rate=RATE, access=access, preamble=PRE / 1e9, **kw)


def network(seed: int, med: Medium, n: int = 4):
    env = simpy.Environment()
    arcs = [(u, v) for u in range(n) for v in range(n) if u != v]
    net = Network(env, arcs, lambda u, v: LinkSpec(latency=Constant(value=LAT[(u, v)] / 1e9)),
                  seed=seed, T_ns=10 * MS, medium=med)
    got: list = []
    port = net.port("p", lambda link, payload: got.append((env.now, link.src, link.dst, payload)))
    return env, net, port, got


def ends(got, src):
    """The end of each frame of ``src`` (its deliveries minus the propagation)."""
    return sorted({t - LAT[(s, d)] for t, s, d, _ in got if s == src})


def test_a_frame_on_an_idle_medium_goes_at_once_and_one_within_aifs_waits_for_it():
    env, net, port, got = network(1, medium())
    at(env, 50 * US, lambda: port.send(net.link(0, 1), "early", 100))     # idle since 0: waits to 110 us
    at(env, T0, lambda: port.send(net.link(2, 3), "late", 100))           # idle for long: goes at 1 ms
    env.run()
    assert sorted(got) == [(AIFS + airtime(100) + LAT[(0, 1)], 0, 1, "early"),
                           (T0 + airtime(100) + LAT[(2, 3)], 2, 3, "late")]


def test_synchronized_senders_on_an_idle_medium_all_collide():
    """Twelve radios handing a frame over at one idle instant all go at once (no backoff): the
    case where ns-3's 802.11p delivered 0 of 1,200 frames."""
    med = medium()
    env = simpy.Environment()
    n = 12
    arcs = [(u, (u + 1) % n) for u in range(n)]
    net = Network(env, arcs, lambda u, v: LinkSpec(latency=Constant(value=1e-6)), seed=1, T_ns=10 * MS,
                  medium=med)
    got = []
    port = net.port("p", lambda link, payload: got.append(payload))
    for u in range(n):
        at(env, T0, lambda u=u: port.send(net.link(u, (u + 1) % n), u, 200))
    env.run()
    c = port.counts()
    assert got == [] and c["collision_lost"] == n
    assert c["channel"]["collisions"] == 1 and env.now == T0 + airtime(200)


def test_a_frame_that_finds_the_medium_busy_draws_a_frozen_backoff_and_a_post_backoff_follows():
    """Node 0 sends at 1 ms (at once).  Node 1's frame comes while it is on the air: it draws
    b1 at its arrival and goes b1 slots after end0 + AIFS.  Node 0's second frame, handed over
    just after its first ended, waits for its post-backoff p0 > b1 drawn at end0: b1 of its
    slots pass before node 1 starts, p0 - b1 are left after node 1's frame."""
    seed = next(s for s in range(200)
                if draw(s, 1, T0 + 10 * US) >= 3 and draw(s, 0, T0 + airtime(100)) > draw(s, 1, T0 + 10 * US) + 2)
    env, net, port, got = network(seed, medium())
    end0 = T0 + airtime(100)
    b1 = draw(seed, 1, T0 + 10 * US)
    p0 = draw(seed, 0, end0)
    at(env, T0, lambda: port.send(net.link(0, 3), "a", 100))
    at(env, T0 + 10 * US, lambda: port.send(net.link(1, 3), "b", 100))
    at(env, end0 + 1, lambda: port.send(net.link(0, 3), "c", 100))
    env.run()
    start1 = end0 + AIFS + b1 * SLOT
    end1 = start1 + airtime(100)
    # node 0's post-backoff p0 > b1: it counted b1 slots before node 1 started, then resumes
    start2 = end1 + AIFS + (p0 - b1) * SLOT
    assert ends(got, 0) == [end0, start2 + airtime(100)]
    assert ends(got, 1) == [end1]


def test_a_post_backoff_that_ran_out_leaves_the_next_frame_immediate_access():
    seed = 5
    env, net, port, got = network(seed, medium())
    end0 = T0 + airtime(100)
    p0 = draw(seed, 0, end0)
    later = end0 + AIFS + (p0 + 3) * SLOT + 7          # idle well past the post-backoff
    at(env, T0, lambda: port.send(net.link(0, 1), "a", 100))
    at(env, later, lambda: port.send(net.link(0, 1), "b", 100))
    env.run()
    assert ends(got, 0) == [end0, later + airtime(100)]


def test_after_a_collision_the_others_wait_eifs_and_the_senders_aifs():
    """Nodes 0 and 1 collide at 1 ms.  Node 2's frame, handed over during the collision, draws
    b2 and counts from end + EIFS (it saw a frame in error; the senders, with no frame to send,
    only count their post-backoffs)."""
    seed = next(s for s in range(500) if draw(s, 2, T0 + 5 * US) > 0)
    env, net, port, got = network(seed, medium())
    at(env, T0, lambda: port.send(net.link(0, 3), "a", 300))
    at(env, T0, lambda: port.send(net.link(1, 3), "b", 300))
    at(env, T0 + 5 * US, lambda: port.send(net.link(2, 3), "c", 100))
    env.run()
    end = T0 + airtime(300)
    assert ends(got, 2) == [end + EIFS + draw(seed, 2, T0 + 5 * US) * SLOT + airtime(100)]
    assert port.counts()["collision_lost"] == 2


def test_eifs_equal_to_aifs_changes_nothing_for_one_sender_alone():
    """Without a collision no radio saw a frame in error: EIFS never applies."""
    for eifs in (AIFS, 5 * AIFS):
        env, net, port, got = network(2, medium(access=Edca(slot=SLOT / 1e9, aifs=AIFS / 1e9, cw=CW,
                                                             eifs=eifs / 1e9)))
        at(env, T0, lambda port=port, net=net: port.send(net.link(0, 1), "a", 100))
        at(env, T0 + 3 * US, lambda port=port, net=net: port.send(net.link(2, 1), "b", 100))
        env.run()
        end0 = T0 + airtime(100)
        assert ends(got, 2) == [end0 + AIFS + draw(2, 2, T0 + 3 * US) * SLOT + airtime(100)]


@pytest.mark.parametrize("n", [2, 4, 8])
def test_csma_n_frames_at_one_instant_survive_with_the_closed_form_probability(n):
    """One collision domain, ``n`` frames becoming heads at one idle instant under ``csma``: a
    frame is lost iff another drew its backoff, so P(no collision) = (1 - 1/(cw+1))^(n-1).
    2,000 rounds (independent keyed draws), the fraction within its 99.9 % binomial interval."""
    cw, rounds = 7, 2000
    env = simpy.Environment()
    arcs = [(u, (u + 1) % n) for u in range(n)]
    med = Medium(rate=RATE, access=Csma(slot=SLOT / 1e9, aifs=AIFS / 1e9, cw=cw), preamble=PRE / 1e9)
    net = Network(env, arcs, lambda u, v: LinkSpec(latency=Constant(value=1e-6)), seed=11, T_ns=10 * MS,
                  medium=med)
    port = net.port("p", lambda link, payload: None)

    def rounds_():
        for _ in range(rounds):
            for u in range(n):
                port.send(net.link(u, (u + 1) % n), u, 100)
            yield env.timeout(10 * MS)
    env.process(rounds_())
    env.run()
    c = port.counts()
    frames = n * rounds
    p = (1 - 1 / (cw + 1)) ** (n - 1)
    ok = (frames - c["collision_lost"]) / frames
    half = 3.3 * math.sqrt(p * (1 - p) / frames)
    assert abs(ok - p) <= half, (ok, p, half)


def test_generation_jitter_spreads_the_hand_over_keyed_per_vehicle_and_tick():
    """Twelve synchronized radios under ``edca``: without jitter every frame collides; with a 5 ms
    jitter each goes at its own instant ``t + floor(u * 5 ms)``, ``u`` keyed by (vehicle, tick)."""
    n, jitter = 12, 5 * MS
    env = simpy.Environment()
    arcs = [(u, (u + 1) % n) for u in range(n)]
    net = Network(env, arcs, lambda u, v: LinkSpec(latency=Constant(value=1e-6)), seed=1, T_ns=10 * MS,
                  medium=medium(generation_jitter=jitter / 1e9))
    got = []
    port = net.port("p", lambda link, payload: got.append((env.now, payload)))
    for u in range(n):
        at(env, T0, lambda u=u: port.send(net.link(u, (u + 1) % n), u, 50))
    env.run()
    ready = {u: T0 + int(keyed_uniform(key64(1, "channel", 0, u, "jitter"), T0 // (10 * MS), 0) * jitter)
             for u in range(n)}
    assert len(set(ready.values())) == n
    # the first to be ready goes at once (idle for long), and nobody leaves before being ready
    first = min(ready, key=ready.get)
    arrived = dict((payload, t) for t, payload in got)
    assert arrived[first] == ready[first] + airtime(50) + 1000
    for u, t in arrived.items():
        assert t - 1000 - airtime(50) >= ready[u]

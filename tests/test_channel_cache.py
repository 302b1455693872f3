"""The one-domain channel's cached start (``Access.start_at``) and one-call wake-up
(``Access.next_end``): the cache never disagrees with a fresh ``next_start``, a rule without
the cache (the docs' ``persistent``) runs with generation jitter, and a slotted rule (``edca``) on
one collision domain wakes the channel only at frame ends (as ``next_start + next_airtime``
did before the change)."""

from __future__ import annotations

from pathlib import Path

import simpy
from test_edca import draw, medium
from test_medium import LAT, MS, US, airtime, at

from dkfsim import load_scenario, run
from dkfsim.components.faults import LinkSpec
from dkfsim.components.latency import Constant
from dkfsim.core.registry import load_plugin
from dkfsim.network.media.channel import NEVER, Channel
from dkfsim.network.media.csma import CsmaAccess
from dkfsim.network.network import Network

ROOT = Path(__file__).resolve().parents[1]
T0 = 1 * MS


def test_the_cached_start_always_equals_a_fresh_next_start(monkeypatch):
    """Whenever the channel is idle and ``start_at`` is set, working ``next_start`` out again
    gives the same start and shortest airtime (heads added by estimators, background and
    released jittered frames; starts; idle periods; collisions of frames of different sizes)."""
    checks = []

    def check(ch: Channel) -> None:
        a = ch.access
        if isinstance(a, CsmaAccess) and not ch.on_air and a.start_at is not None:
            cached, air = a.start_at, a.next_airtime()      # (both from the cache)
            a.start_at = None
            assert a.next_start() == cached
            assert cached == NEVER or a.next_airtime() == air
            checks.append(1)

    for name in ("_end", "_start", "_background", "_release", "offer", "advance", "_wake"):
        real = getattr(Channel, name)
        monkeypatch.setattr(Channel, name, lambda self, *a, _real=real, **k: (_real(self, *a, **k), check(self))[0])
    sc = load_scenario(ROOT / "scenarios/channel_its_g5.yaml",
                       overrides=["steps=40", "medium.access={kind: csma, cw: 3}", "medium.generation_jitter=0.004",
                                  "medium.background={arrivals: poisson, packets_per_second: 200, size: 120}",
                                  "estimators=[]"])
    r = run(sc)
    assert len(checks) > 1000 and r.counts["collision_lost"] > 0


def test_a_rule_without_the_cache_runs_with_generation_jitter():
    """``persistent`` (docs/examples) with ``generation_jitter``: a frame held back while no radio
    has a head (26f0f39 asked ``next_airtime`` of no heads there: ValueError)."""
    load_plugin(str(ROOT / "docs/examples/persistent_access.py"))
    sc = load_scenario(ROOT / "scenarios/channel_its_g5.yaml",
                       overrides=["steps=30", "medium.access={kind: persistent}", "medium.generation_jitter=0.005",
                                  "estimators=[]"])
    assert run(sc).counts["sent"] > 0


def test_edca_on_one_domain_wakes_only_at_frame_ends(monkeypatch):
    """Node 2's frame is on the air when nodes 0 (1000 bytes) and 1 (50 bytes) hand theirs over:
    both draw a backoff, node 0's smaller.  Node 1's frame would end before node 0's if it started
    at its due instant, but it never does before node 0's ends (one domain): the channel needs
    no wake-up there."""
    seed = next(s for s in range(500) if draw(s, 0, T0 + 10 * US) < draw(s, 1, T0 + 20 * US))
    env = simpy.Environment()
    arcs = [(u, v) for u in range(4) for v in range(4) if u != v]
    net = Network(env, arcs, lambda u, v: LinkSpec(latency=Constant(value=LAT[(u, v)] / 1e9)),
                  seed=seed, T_ns=10 * MS, medium=medium())
    got: list = []
    port = net.port("p", lambda link, payload: got.append((env.now, link.src, link.dst)))
    wakes: list[int] = []
    real = Channel._woken
    monkeypatch.setattr(Channel, "_woken", lambda self, ev: (wakes.append(env.now), real(self, ev))[1])
    at(env, T0, lambda: port.send(net.link(2, 3), "x", 100))
    at(env, T0 + 10 * US, lambda: port.send(net.link(0, 3), "a", 1000))
    at(env, T0 + 20 * US, lambda: port.send(net.link(1, 3), "b", 50))
    env.run()
    ends = {t - LAT[(s, d)] for t, s, d in got}
    assert len(ends) == 3 and min(ends) == T0 + airtime(100)
    assert set(wakes) <= ends, sorted(set(wakes) - ends)

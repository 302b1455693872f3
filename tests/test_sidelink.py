"""The C-V2X sidelink (``medium.access.kind: sps``, issue 33; docs/radio.md, "C-V2X sidelink").

Independent truths: a reservation timeline worked by hand (two vehicles choosing the same
resource, the collision and half-duplex losses it causes, the reselection when a counter runs
out, the exclusion of what a vehicle could not sense and of what it heard reserved), the 3GPP
selection's properties on random sensing histories, the keep probability against its
binomial, and the half-duplex rule on random traffic.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import simpy
from hypothesis import given, settings
from hypothesis import strategies as st
from test_medium import at

import dkfsim
from dkfsim.components.faults import LinkSpec
from dkfsim.components.latency import Constant
from dkfsim.components.medium import Medium, Sps
from dkfsim.components.radio import RadioParams
from dkfsim.components.traffic import Background
from dkfsim.core.streams import key64, keyed_uniform
from dkfsim.network import radio_kernels as rk
from dkfsim.network.media.base import Frame
from dkfsim.network.media.sidelink import SidelinkChannel
from dkfsim.network.network import Network

MS = 1_000_000
ROOT = Path(__file__).resolve().parents[1]


def line(xs, ticks: int) -> np.ndarray:
    pos = np.zeros((ticks, len(xs), 2))
    pos[:, :, 0] = np.asarray(xs, dtype=float)
    return pos


def counter(seed: int, node: int, t_ns: int, attempt: int, lo: int = 5, hi: int = 15) -> int:
    """The reselection counter vehicle ``node`` draws at ``t_ns`` as its ``attempt``-th draw there."""
    return lo + int(keyed_uniform(key64(seed, "sidelink", 0, node, "sps"), t_ns, attempt) * (hi - lo + 1))


def timeline_seed() -> tuple[int, int, int, int]:
    """A seed whose counters give the three phases below: A's first reservation runs out before
    B's, and A's second outlasts B's first by three periods."""
    for seed in range(1, 10_000):
        c_a, c_b = counter(seed, 0, 0, 1), counter(seed, 2, 0, 1)
        if c_a + 1 < c_b:
            c_a2 = counter(seed, 0, 100 * c_a * MS, 1)
            if c_a + c_a2 > c_b + 3:
                return seed, c_a, c_b, c_a2
    raise AssertionError("no seed")


def test_a_hand_worked_reservation_timeline():
    """A (0 m) and B (100 m) hand a frame over every 100 ms at +0.5 ms, C (50 m) between them
    sends nothing; one sub-channel, a budget of 2 ms (candidates: the next two subframes), no
    fading, so every choice below follows from the rules (the counters from their keyed draws):

    1. both pick subframe +1 (no history; step 3's tie goes to the first): every period both
       frames collide at C (``reservation_collision``: each would be received alone, SNR 26 dB)
       and A and B lose each other's (``half_duplex``);
    2. A's counter runs out (p_keep 0): its next frame reselects; +1 is excluded (A transmitted
       in its 100 ms images, so could not sense it) and +2 is picked: now C, A and B receive all;
    3. B's counter runs out: +1 is excluded for B as well, +2 is A's reservation, heard at -85
       dBm, above the -90.5 dBm threshold, so excluded too; nothing is left, so the threshold
       rises in 3 dB steps until A's reservation is allowed: B picks +2 and the two collide again.
    """
    seed, c_a, c_b, _ = timeline_seed()
    periods = c_b + 3
    spec = Medium(rate=6e6, access=Sps(subchannels=1, budget=0.002), radio=RadioParams())
    env = simpy.Environment()
    ch = SidelinkChannel(env, spec, (0, 1, 2), seed, line([0.0, 50.0, 100.0], periods + 2), 100 * MS, record=True)
    told: dict[int, list] = {0: [], 2: []}

    def done(frame, ok):
        assert ok
        told[frame.node].append((frame.start, dict(frame.lost_at or {})))
    for k in range(periods):
        for node in (0, 2):
            at(env, k * 100 * MS + MS // 2, lambda node=node: ch.offer(Frame(node, 150, env.now, None, done, "me")))
    env.run(until=periods * 100 * MS)
    collide = {"A": {1: True, 2: False}, "B": {1: True, 0: False}}
    n_collide = 0
    logged = []                              # (record): every packet, received by someone or by no one
    for k in range(periods):
        a_start, a_lost = told[0][k]
        b_start, b_lost = told[2][k]
        if k < c_a:                          # 1. the same resource
            assert (a_start, b_start) == ((100 * k + 1) * MS, (100 * k + 1) * MS)
            assert (a_lost, b_lost) == (collide["A"], collide["B"])
            n_collide += 1
        elif k < c_b:                        # 2. A moved to +2
            assert (a_start, b_start) == ((100 * k + 2) * MS, (100 * k + 1) * MS)
            assert a_lost == {} and b_lost == {}
        else:                                # 3. B moved onto A's reservation
            assert (a_start, b_start) == ((100 * k + 2) * MS, (100 * k + 2) * MS)
            assert (a_lost, b_lost) == (collide["A"], collide["B"])
            n_collide += 1
        heard = c_a <= k < c_b
        logged += [(0, a_start, a_start + MS, heard, False), (2, b_start, b_start + MS, heard, False)]
    assert sorted(ch.ended or []) == sorted(logged)
    losses = ch.report("me", periods * 100 * MS)["losses"]
    assert losses == {"sensing": 0, "half_duplex": 2 * n_collide, "propagation": 0,
                      "reservation_collision": 2 * n_collide, "collision": 0}


def test_a_one_shot_misfit_keeps_the_reservation():
    """``misfit: one_shot``: a frame bigger than its vehicle's reservation goes in a resource of
    its own, and the next frame that fits goes in the reservation again."""
    spec = Medium(rate=6e6, access=Sps(subchannels=4, budget=0.002, misfit="one_shot"), radio=RadioParams())
    env = simpy.Environment()
    ch = SidelinkChannel(env, spec, (0, 1), 3, line([0.0, 30.0], 10), 100 * MS)
    starts: list = []
    for k, size in enumerate((150, 500, 150)):       # 1, 3, 1 sub-channels
        at(env, k * 100 * MS + MS // 2, lambda size=size: ch.offer(Frame(0, size, env.now, None,
                                                                          lambda f, ok: starts.append(f.start), "me")))
    env.run(until=300 * MS)
    assert starts[0] == 1 * MS and starts[2] == 201 * MS     # the reservation, kept across the one-shot
    assert starts[1] in (101 * MS, 102 * MS)


def test_a_frame_larger_than_the_band_or_past_its_budget_is_dropped():
    """A frame that needs more sub-channels than the band has is refused; one still waiting when
    its budget ran out is dropped unsent: both count as the owner's dropped frames."""
    spec = Medium(rate=6e6, access=Sps(subchannels=2, budget=0.001), radio=RadioParams())
    env = simpy.Environment()
    ch = SidelinkChannel(env, spec, (0, 1), 3, line([0.0, 30.0], 10), 100 * MS)
    oks: list = []
    at(env, MS // 2, lambda: oks.append(ch.offer(Frame(0, 500, env.now, None, lambda f, ok: None, "me"))))
    for _ in range(3):                      # (three at once: one subframe, one frame each)
        at(env, MS // 2, lambda: oks.append(ch.offer(Frame(0, 100, env.now, None, lambda f, ok: oks.append(ok),
                                                           "me"))))
    env.run(until=50 * MS)
    assert oks[:1] == [False] and oks.count(False) == 3 and oks.count(True) == 4
    assert ch.report("me", 50 * MS)["frames_dropped"] == 3


# ------------------------------------------------------------------ the selection's properties
@pytest.mark.parametrize("kernels", ["numba", "numpy"])
def test_the_threshold_rises_in_steps_of_threshold_step_db(kernels):
    """Vehicle 0 selects one of two candidates (subframes +1 and +2 of one sub-channel), each
    reserved by a vehicle it heard: at -85 dBm (+1) and at -70 dBm (+2), both above -90.5 dBm, so
    nothing is left; the threshold rises 3 dB at a time (-87.5, -84.5 dBm) until the first is
    allowed, and the second stays excluded although its subframe is the quieter one.  (Raising a
    threshold in mW by 3 "mW" at once allowed both, and the quieter one was picked.)"""
    m, now = 3, 5000
    a, b = now + 1, now + 2
    vs = np.zeros((rk.NVS, m), dtype=np.int64)
    vs[rk.VD_AT] = -1
    skey = np.arange(1, m + 1, dtype=np.uint64)
    kn = np.zeros((m, m, 4), dtype=np.int64)
    kn[:, :, 0] = -(1 << 40)
    kn[0, 1] = (a - 100, 100, 0, 1)                     # heard 100 ms ago, every 100 ms: +1 ...
    kn[0, 2] = (b - 100, 100, 0, 1)                     # ... and +2
    kr = np.zeros((m, m))
    kr[0, 1], kr[0, 2] = 10.0 ** (-85 / 10), 10.0 ** (-70 / 10)
    tag = np.roll(np.arange(now - rk.WINDOW_SF, now, dtype=np.int64), now % rk.WINDOW_SF)
    rssi = np.zeros((m, rk.WINDOW_SF, 1))
    for z in range(now - rk.WINDOW_SF, now):
        rssi[0, z % rk.WINDOW_SF, 0] = 1e-9 if (z - a) % 100 == 0 else 1e-12   # +1's images are louder
    txh = np.zeros((m, rk.WINDOW_SF), dtype=np.bool_)
    sp = np.zeros(rk.NSP, dtype=np.int64)
    sp[rk.SP_S] = 1
    sf = np.zeros(rk.NSF)
    sf[rk.SF_RSRP], sf[rk.SF_STEP], sf[rk.SF_FRAC] = 10.0 ** (-90.5 / 10), 10.0 ** (3.0 / 10), 0.2
    ex, metric = np.zeros(2, dtype=np.bool_), np.zeros(2)
    k = rk.compiled() if kernels == "numba" else rk
    pick = k.sps_select(0, now, a, b, 1, vs, skey, kn, kr, rssi, txh, tag, sp, sf, ex, metric)
    assert ex.tolist() == [False, True] and pick == a * 1 + 0


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32), m=st.integers(2, 20), S=st.integers(1, 6), data=st.data())
def test_every_pick_lies_in_what_is_left_and_that_is_at_least_a_fifth(seed, m, S, data):
    """On a random sensing history (heard reservations and their powers, own transmissions,
    RSSI), a selection's pick is a candidate step 2 left, step 2 left at least 20 % of the
    candidates, and the pick is among the 20 % with the lowest mean RSSI of those left."""
    L = data.draw(st.integers(1, S))
    span = data.draw(st.integers(1, 100))
    rng = np.random.default_rng(seed)
    now = 5000
    a, b = now + 1, now + span
    vs = np.zeros((rk.NVS, m), dtype=np.int64)
    vs[rk.VD_AT] = -1
    skey = np.arange(1, m + 1, dtype=np.uint64) * np.uint64(0x9E3779B97F4A7C15)
    kn = np.zeros((m, m, 4), dtype=np.int64)
    kn[:, :, 0] = now - rng.integers(1, 1500, (m, m))
    kn[:, :, 1] = rng.choice([0, 20, 50, 100], (m, m))
    kn[:, :, 2] = rng.integers(0, S, (m, m))
    kn[:, :, 3] = rng.integers(1, S + 1, (m, m))
    kr = 10.0 ** (rng.uniform(-110, -60, (m, m)) / 10)
    rssi = rng.uniform(0, 1e-9, (m, rk.WINDOW_SF, S))
    tag = np.arange(now - rk.WINDOW_SF, now, dtype=np.int64)
    tag = np.roll(tag, now % rk.WINDOW_SF)              # (entry z % 1000 holds subframe z)
    txh = rng.random((m, rk.WINDOW_SF)) < 0.02
    sp = np.zeros(rk.NSP, dtype=np.int64)
    sp[rk.SP_S] = S
    sf = np.zeros(rk.NSF)
    sf[rk.SF_RSRP], sf[rk.SF_STEP], sf[rk.SF_FRAC] = 10.0 ** (-90.5 / 10), 10.0 ** (3.0 / 10), 0.2
    nc = span * (S - L + 1)
    ex, metric = np.zeros(nc, dtype=np.bool_), np.zeros(nc)
    v = int(rng.integers(m))
    pick = rk.compiled().sps_select(v, now, a, b, L, vs, skey, kn, kr, rssi, txh, tag, sp, sf, ex, metric)
    y, c = divmod(int(pick), S)
    assert a <= y <= b and 0 <= c <= S - L
    j = (y - a) * (S - L + 1) + c
    left = ~ex
    assert not ex[j]
    need = math.ceil(0.2 * nc - 1e-9)
    assert left.sum() >= need
    kept = np.sort(metric[left])[:max(1, min(need, int(left.sum())))]
    assert metric[j] <= kept[-1]


def test_a_reservation_is_kept_with_probability_p_keep():
    """One vehicle sending a 10 Hz beacon (the other off the road): each reselection moves its
    transmissions (the old subframe is excluded, it transmitted there), so the runs between
    moves are reservations;
    a reservation lasts a counter (uniform 5..15, mean 10) and is renewed with probability
    p_keep, so runs last 10 / (1 - p_keep) transmissions on average: held within 4.5 standard
    errors, and p_keep = 0 gives runs of exactly 5..15."""
    for p_keep in (0.0, 0.5):
        bg = Background(arrivals="periodic", packets_per_second=10, size=150, offset=0.0003)
        spec = Medium(rate=6e6, access=Sps(subchannels=1, p_keep=p_keep), radio=RadioParams(), background=bg)
        env = simpy.Environment()
        seconds = 1200
        away = np.ones((2, 2), dtype=bool)
        away[:, 1] = False
        ch = SidelinkChannel(env, spec, (0, 1), 7, line([0.0, 30.0], 2), seconds * 1000 * MS, presence=away)
        ch.advance(seconds * 1000 * MS)
        n = int(ch.E[rk.E_NPER])
        starts = ch.periods[:n, 0]
        starts = starts[starts < (seconds - 1) * 1000 * MS]
        offsets = (starts // MS) % 100
        moves = np.flatnonzero(np.diff(offsets) != 0)
        runs = np.diff(moves)
        if p_keep == 0.0:
            assert runs.min() >= 5 and runs.max() <= 15
        mean, se = runs.mean(), runs.std(ddof=1) / math.sqrt(len(runs))
        assert abs(mean - 10.0 / (1.0 - p_keep)) < 4.5 * se, (p_keep, mean, se, len(runs))


@settings(max_examples=8, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(3, 8),
       plan=st.lists(st.tuples(st.integers(0, 7), st.integers(0, 300)), min_size=5, max_size=60))
def test_a_vehicle_never_receives_in_a_subframe_it_transmits_in(seed, n, plan):
    """Random frames (every one an estimator's, so each transmission and delivery is seen): no
    frame is received by a vehicle that transmitted in the same subframe, and each such pair is
    counted ``half_duplex``."""
    spec = Medium(rate=6e6, access=Sps(subchannels=2, budget=0.02), radio=RadioParams())
    env = simpy.Environment()
    ch = SidelinkChannel(env, spec, tuple(range(n)), seed, line([15.0 * i for i in range(n)], 5), 100 * MS,
                         record=True)
    sent: list = []
    for u, t in plan:
        if u < n:
            at(env, t * MS // 2 + 1, lambda u=u: ch.offer(Frame(u, 100, env.now, None,
                                                                lambda f, ok: sent.append(f) if ok else None, "me")))
    env.run(until=400 * MS)
    busy = {(f.node, f.start) for f in sent}
    hd = 0
    for f in sent:
        for r in range(n):
            if r == f.node:
                continue
            if (r, f.start) in busy:
                assert r in (f.lost_at or {}) and not (f.lost_at or {})[r]      # lost, and not to a collision
                hd += 1
    assert ch.report("me", 400 * MS)["losses"]["half_duplex"] == hd
    # ``record`` logs each packet sent once, heard when some member received it
    assert sorted(ch.ended or []) == sorted((f.node, f.start, f.end, len(f.lost_at or {}) < n - 1, False) for f in sent)


def test_record_logs_every_packet_the_sidelink_sent_its_log_growing():
    """With ``record`` and background on 12 vehicles (hundreds of packets: the log, 64 rows at
    first, grows while the engine runs), every packet that went on the air is logged once: as
    many rows as packets started (``frames_on_air``), the background's as the background sent,
    each one subframe long, its sender a member."""
    spec = Medium(rate=6e6, access=Sps(subchannels=2), radio=RadioParams(),
                  background=Background(arrivals="periodic", packets_per_second=50, size=200, offset="random"))
    env = simpy.Environment()
    n = 12
    ch = SidelinkChannel(env, spec, tuple(range(n)), 3, line([30.0 * i for i in range(n)], 12), 100 * MS, record=True)
    env.run(until=1000 * MS)
    stats = ch.stats(1000 * MS)
    ended = ch.ended or []
    assert len(ended) == stats["frames_on_air"] > 300
    assert sum(bg for *_, bg in ended) == stats["background_sent"] == len(ended)
    assert all(e - s == MS and 0 <= node < n for node, s, e, _, _ in ended)
    assert len({(node, s) for node, s, *_ in ended}) == len(ended)


def test_an_interference_floor_changes_what_a_decision_counts_not_what_is_sent():
    """Twelve vehicles 30 m apart with background: the farther ones are below the sensitivity
    (-92 dBm beyond about 175 m).  With ``interference_floor`` at the sensitivity their packets
    add nothing to a decision's interference: the same packets go on the air in the same
    subframes (scheduling senses power, not decisions), the same pairs are not detected or lost
    to half duplex, and fewer are lost to collisions."""
    def run(floor):
        spec = Medium(rate=6e6, access=Sps(subchannels=2), radio=RadioParams(interference_floor=floor),
                      background=Background(arrivals="periodic", packets_per_second=50, size=200, offset="random"))
        env = simpy.Environment()
        ch = SidelinkChannel(env, spec, tuple(range(12)), 3, line([30.0 * i for i in range(12)], 12), 100 * MS,
                             record=True)
        env.run(until=1000 * MS)
        ch.stats(1000 * MS)                                 # (brought up to the end)
        return [(node, start) for node, start, *_ in ch.ended or []], ch.report("x", 1000 * MS)["losses"]
    sent, every = run(None)
    sent_floor, below = run(-92.0)
    assert sent_floor == sent and len(sent) > 300
    assert below["sensing"] == every["sensing"] > 0 and below["half_duplex"] == every["half_duplex"]
    collided = ("collision", "reservation_collision")
    assert sum(below[k] for k in collided) < sum(every[k] for k in collided)


def test_sps_needs_a_radio_and_an_allowed_interval():
    """``sps`` without ``medium.radio``, with an interval LTE-V2X does not allow, or with a CBR
    threshold the noise alone reaches, is refused naming the key."""
    with pytest.raises(Exception, match="spatial radio"):
        Medium(rate=6e6, access={"kind": "sps"})
    with pytest.raises(Exception, match="0.02, 0.05"):
        Sps(rri=0.03)
    assert Sps(rri=0.02).counter_range == (25, 75) and Sps(rri=0.05).counter_range == (10, 30)
    assert Sps(rri=0.3).counter_range == (5, 15)
    with pytest.raises(Exception, match="one sub-channel.s noise"):     # (noise alone: always busy)
        Medium(rate=6e6, access={"kind": "sps", "cbr_threshold": -110.0}, radio={})
    # a step too small to move the threshold (1e-300 dB: a selection looped for ever) is refused
    with pytest.raises(Exception, match="threshold_step"):
        dkfsim.load_scenario(ROOT / "scenarios" / "highway_its_g5.yaml",
                             overrides=["medium.access={kind: sps, threshold_step: 1.0e-300}"])
    assert Sps(threshold_step=0.1).threshold_step == 0.1


def test_the_sidelink_on_the_network_delivers_through_its_ports():
    """``medium.access.kind: sps`` through :class:`~dkfsim.network.network.Network`: a port's
    frames reach their links' receivers, and the channel block carries the sidelink's causes."""
    n, T = 6, 10 * MS
    med = Medium(rate=6e6, access={"kind": "sps", "rri": 0.02, "budget": 0.02}, radio=RadioParams(),
                 background=Background(arrivals="periodic", packets_per_second=10, size=300, offset="random"))
    env = simpy.Environment()
    arcs = [(u, v) for u in range(n) for v in range(n) if u != v]
    net = Network(env, arcs, lambda u, v: LinkSpec(latency=Constant(value=1e-6)), seed=2, T_ns=T, medium=med,
                  positions=line([20.0 * i for i in range(n)], 60), n=n)
    got: list = []
    port = net.port("p", lambda link, payload: got.append((link.src, link.dst, payload)))
    for k in range(40):
        at(env, k * T + 1, lambda k=k: port.send_frame([(net.link(0, v), k, 120) for v in range(1, n)], 120))
    env.run(until=50 * T)
    ch = port.counts()["channel"]
    assert set(ch["losses"]) == {"sensing", "half_duplex", "propagation", "reservation_collision", "collision"}
    assert len(got) > 100 and all(src == 0 for src, _, _ in got)
    assert ch["frames"] + ch["frames_dropped"] == 40


def _sidelink_run(kernels: str) -> tuple:
    """Vehicles on a road with shadowing and fading, some off the road, background and an
    estimator's frames on ``sps`` with one-shot misfits (for
    :func:`test_the_sidelink_is_the_same_on_both_kernel_paths`)."""
    from dkfsim.core.backend import Backend
    n, T = 20, 10 * MS
    radio = RadioParams(path_loss={"model": "winner_b1"}, shadowing={"model": "lognormal", "sigma": 3.0},
                        fading={"model": "nakagami", "m": 1.5})
    med = Medium(rate=6e6, access={"kind": "sps", "misfit": "one_shot", "rri": 0.05, "p_keep": 0.3}, radio=radio,
                 background=Background(arrivals="periodic", packets_per_second=20, size=300, offset="random"))
    pos = line([40.0 * i for i in range(n)], 60)
    presence = np.ones((60, n), dtype=bool)
    presence[:20, 3] = presence[30:, 8] = False
    env = simpy.Environment()
    arcs = [(u, v) for u in range(n) for v in range(n) if u != v]
    net = Network(env, arcs, lambda u, v: LinkSpec(latency=Constant(value=1e-6)), seed=4, T_ns=T,
                  medium=med, positions=pos, presence=presence, n=n, backend=Backend(kernels))
    got: list = []
    port = net.port("p", lambda link, payload: got.append((env.now, link.src, link.dst, payload)))
    for k in range(50):
        for u in (0, 5, 11):
            at(env, k * T + 1, lambda u=u, k=k: port.send_frame([(net.link(u, v), [u, k], 200 + 40 * (k % 7))
                                                                 for v in range(n) if v != u], 200 + 40 * (k % 7)))
    env.run(until=55 * T)
    return got, port.channel.report(port, 55 * T), port.channel.series(port, T, 55)["cbr"].tolist()


def test_the_sidelink_is_the_same_on_both_kernel_paths():
    """The sidelink's engine compiled and as Python (``DKFSIM_KERNELS=numpy``, in a process of
    its own): every delivery, every pair's count and every member's busy share are the same."""
    import json
    import os
    import subprocess
    import sys
    from pathlib import Path
    code = ("import json, sys; sys.path.insert(0, 'tests'); from test_sidelink import _sidelink_run; "
            "print(json.dumps(_sidelink_run('numpy')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         env={**os.environ, "DKFSIM_KERNELS": "numpy"}, cwd=Path(__file__).parent.parent)
    got0, r0, c0 = json.loads(json.dumps(_sidelink_run("numba")))
    got1, r1, c1 = json.loads(out.stdout)
    assert got0 == got1 and r0 == r1 and c0 == c1
    assert r0["pairs"] > 5_000 and r0["losses"]["half_duplex"] > 0 and r0["losses"]["reservation_collision"] > 0

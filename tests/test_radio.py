"""The spatial radio (``medium.radio``, issue 32; docs/radio.md).

Independent truths: the one-collision-domain channel (the radio without path loss must deliver
exactly what it delivers), the gamma CDF of Nakagami fading (closed form), and timelines worked
by hand to the nanosecond from the powers of the log-distance model (a hidden terminal,
capture in both orders).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import simpy
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import special
from test_medium import at

import dkfsim
from dkfsim.components.faults import LinkSpec
from dkfsim.components.latency import Constant
from dkfsim.components.medium import Csma, Edca, Medium
from dkfsim.components.radio import C_LIGHT, RadioParams
from dkfsim.components.traffic import Background
from dkfsim.core.errors import ScenarioError
from dkfsim.network.network import Network

US, MS = 1_000, 1_000_000
RATE, PRE = 6e6, 40 * US
LAT = 1 * US
T0 = 1 * MS
AIFS = 110 * US


def airtime(size: int) -> int:
    return PRE + int(size * 8 * 1e9 / RATE + 0.5)


def positions(xs, ticks: int = 2000) -> np.ndarray:
    """Vehicles standing at ``x = xs[i]`` on a line, for ``ticks`` ticks."""
    pos = np.zeros((ticks, len(xs), 2))
    pos[:, :, 0] = np.asarray(xs, dtype=float)
    return pos


def network(med: Medium, xs, seed: int = 1):
    n = len(xs)
    env = simpy.Environment()
    arcs = [(u, v) for u in range(n) for v in range(n) if u != v]
    net = Network(env, arcs, lambda u, v: LinkSpec(latency=Constant(value=LAT / 1e9)), seed=seed, T_ns=10 * MS,
                  medium=med, positions=positions(xs) if med.radio is not None else None)
    got: list = []
    port = net.port("p", lambda link, payload: got.append((env.now, link.src, link.dst, payload)))
    return env, net, port, got


def broadcast(net, port, u: int, payload, size: int):
    n = len(net.members)
    port.send_frame([(net.link(u, v), payload, size) for v in range(n) if v != u], size)


# ------------------------------------------------------------------ the one-domain limit
@settings(max_examples=12, deadline=None)
@given(kind=st.sampled_from(["csma", "edca"]), seed=st.integers(0, 10_000), n=st.integers(2, 6),
       cw=st.integers(0, 15), bg=st.sampled_from([None, 100.0, 400.0]),
       plan=st.lists(st.tuples(st.integers(0, 5), st.integers(0, 40), st.integers(20, 400)), min_size=1, max_size=40))
def test_without_path_loss_the_radio_delivers_what_one_collision_domain_delivers(kind, seed, n, cw, bg, plan):
    """No path loss (every member hears and senses every frame at the transmit power): each
    receiver's decision is the channel's, so every delivery (instant, link, payload), every
    per-link loss and the busy time are those of the one-domain channel -- for ``csma`` (the
    radio runs its per-radio form) and ``edca``."""
    access = Csma(cw=cw) if kind == "csma" else Edca(cw=cw)
    background = Background(arrivals="poisson", packets_per_second=bg, size=300) if bg else None
    runs = []
    for radio in (None, RadioParams(path_loss={"model": "none"})):
        med = Medium(rate=RATE, access=access, preamble=PRE / 1e9, background=background, radio=radio)
        env, net, port, got = network(med, [10.0 * i for i in range(n)], seed)
        for u, slot, size in plan:
            if u < n:
                at(env, T0 + slot * 50 * US,
                   lambda u=u, size=size, slot=slot, net=net, port=port: broadcast(net, port, u, (u, slot), size))
        env.run(until=70 * MS)             # (whole ticks: the radio counts busy time per tick)
        c = port.counts()
        runs.append((sorted(got), [(r["link"], r["lost"], r["delivered"]) for r in c["per_link"]],
                     c["channel"]["frames"], c["channel"]["utilisation"]))
    assert runs[0][:3] == runs[1][:3]
    assert runs[1][3] == pytest.approx(runs[0][3], rel=1e-12)       # (the mean of equal CBRs)


# ------------------------------------------------------------------ fading, closed form
def test_nakagami_pdr_is_the_gamma_cdf_over_a_hundred_thousand_pairs():
    """One sender, 1,000 receivers on a circle of radius d around it, 100 frames: 100,000
    (frame, receiver) pairs at one distance.  With Nakagami-m fading and a threshold, a pair is
    received iff ``g * snr >= thr`` with ``g`` gamma(m, 1/m): PDR = Q(m, m thr / snr), within
    its 99 % interval.  Every pair is counted once, lost ones as ``propagation``."""
    m, d, receivers, frames = 1.5, 1300.0, 1000, 100
    radio = RadioParams(path_loss={"model": "free_space"}, fading={"model": "nakagami", "m": m},
                        reception={"model": "threshold", "sinr": 8.0}, sensitivity=-200.0, noise=-95.0,
                        carrier_sense=-200.0, bins={"width": 2000.0, "max": 2000.0})
    med = Medium(rate=RATE, access=Edca(), radio=radio)
    angles = 2 * math.pi * np.arange(receivers) / receivers
    pos = np.zeros((2000, receivers + 1, 2))
    pos[:, 1:, 0], pos[:, 1:, 1] = d * np.cos(angles), d * np.sin(angles)
    env = simpy.Environment()
    net = Network(env, [(0, 1), (1, 0)], lambda u, v: LinkSpec(latency=Constant(value=1e-6)), seed=7,
                  T_ns=10 * MS, medium=med, positions=pos, n=receivers + 1)
    port = net.port("p", lambda link, payload: None)

    def sends():
        for k in range(frames):
            port.send(net.link(0, 1), k, 100)
            yield env.timeout(10 * MS)
    env.process(sends())
    env.run()
    ch = port.counts()["channel"]
    snr_db = 23.0 - 20 * math.log10(4 * math.pi * d * 5.9e9 / C_LIGHT) + 95.0
    p = float(special.gammaincc(m, m * 10 ** ((8.0 - snr_db) / 10)))
    pairs = receivers * frames
    assert ch["pairs"] == pairs and ch["pdr_by_distance"]["frames"] == [pairs]
    assert 0.2 < p < 0.9                       # (a distance where fading decides)
    pdr = ch["pdr_by_distance"]["pdr"][0]
    assert abs(pdr - p) <= 2.576 * math.sqrt(p * (1 - p) / pairs), (pdr, p)
    assert ch["losses"] == {"sensing": 0, "receiver_busy": 0, "propagation": pairs - ch["pairs_received"],
                            "collision": 0}


# ------------------------------------------------------------------ hand-worked timelines
#: log-distance, exponent 3, free space at 1 m (47.866 dB at 5.9 GHz): received power of 23 dBm
#: at 20 m -63.9 dBm, 100 m -84.9, 200 m -93.9, 220 m -95.1
def loss_db(d: float) -> float:
    return 20 * math.log10(4 * math.pi * 5.9e9 / C_LIGHT) + 30 * math.log10(d)


SPATIAL = dict(path_loss={"model": "log_distance", "exponent": 3.0}, sensitivity=-92.0, carrier_sense=-88.0,
               noise=-95.0, reception={"model": "threshold", "sinr": 8.0})


def test_a_hidden_terminal_loses_both_frames_at_the_receiver_between_and_nowhere_else():
    """A (x = 0) and C (x = 200) cannot hear each other (-93.9 dBm, below sensitivity and carrier
    sense); B (x = 100) hears both at -84.9 dBm.  A hands a frame over at 1 ms, C 5 us later:
    under ``edca`` each goes at once (C senses nothing).  B locks on A's, C's is lost there
    (``receiver_busy``) and A's fails (SINR 0 dB < 8: ``collision``).  D (x = -20) receives A's
    (SINR 31 dB), E (x = 220) C's; D and E are below sensitivity for the far sender."""
    assert -85.0 < 23 - loss_db(100) < -84.8 and 23 - loss_db(200) < -92
    med = Medium(rate=RATE, access=Edca(), preamble=PRE / 1e9, radio=RadioParams(**SPATIAL))
    env, net, port, got = network(med, [0.0, 100.0, 200.0, -20.0, 220.0])
    A, B, C, D, E = range(5)
    at(env, T0, lambda: broadcast(net, port, A, "a", 200))
    at(env, T0 + 5 * US, lambda: broadcast(net, port, C, "c", 200))
    env.run()
    end_a, end_c = T0 + airtime(200), T0 + 5 * US + airtime(200)
    assert sorted(got) == [(end_a + LAT, A, D, "a"), (end_c + LAT, C, E, "c")]
    rows = {r["link"]: r for r in port.counts()["per_link"]}
    assert (rows[(A, B)]["lost"], rows[(A, B)]["collision_lost"]) == (1, 1)      # locked on it, interfered
    assert (rows[(C, B)]["lost"], rows[(C, B)]["collision_lost"]) == (1, 0)      # B was busy with A's
    ch = port.counts()["channel"]
    # pairs: A's frame at B (collision), C's at B (receiver_busy), A's at C/E and C's at A/D (sensing)
    assert ch["losses"] == {"sensing": 4, "receiver_busy": 1, "propagation": 0, "collision": 1}


def test_a_sender_within_carrier_sense_defers_with_a_backoff():
    """B (x = 100) senses A's frame (-84.9 dBm >= -88): its frame, handed over during A's, draws
    the keyed backoff b and goes at end_a + AIFS + b slots; nobody loses anything."""
    from dkfsim.core.streams import key64, keyed_uniform
    med = Medium(rate=RATE, access=Edca(), preamble=PRE / 1e9, radio=RadioParams(**SPATIAL))
    env, net, port, got = network(med, [0.0, 100.0, -20.0], seed=4)
    at(env, T0, lambda: port.send(net.link(0, 2), "a", 200))
    at(env, T0 + 5 * US, lambda: port.send(net.link(1, 0), "b", 200))
    env.run()
    b = int(keyed_uniform(key64(4, "channel", 0, 1, "edca"), T0 + 5 * US, 0) * 16)
    end_a = T0 + airtime(200)
    assert sorted(got) == [(end_a + LAT, 0, 2, "a"), (end_a + AIFS + b * 13 * US + airtime(200) + LAT, 1, 0, "b")]


#: R at 0; S 10 m on one side (-54.9 dBm at R); W 165 m on the other (-91.4 dBm at R, just above the
#: sensitivity; SNR 3.6 dB, received alone under a 2 dB threshold).  S and W are 175 m apart,
#: below each other's sensitivity (-92.2 dBm): hidden, so their frames overlap at R, 36.5 dB apart.
CAPTURE_XS = [0.0, 10.0, -165.0]


@pytest.mark.parametrize("capture, window, first, heard", [
    (None, None, "S", {"S"}),      # the stronger first: it survives the weaker one (SINR 36.5 dB)
    (None, None, "W", set()),      # the weaker first: R stays on it and it fails; the stronger is lost (busy)
    (10.0, None, "W", {"S"}),      # capture 10 dB: R switches to the stronger (36.5 dB >= 10), which survives
    (40.0, None, "W", set()),      # capture 40 dB: 36.5 dB is not enough to switch
    (10.0, 20e-6, "W", {"S"}),     # the stronger starts 20 us after the weaker: within a 20 us window
    (10.0, 19e-6, "W", set()),     # ... and beyond a 19 us one: R stays on the weaker
])
def test_capture_in_both_orders(capture, window, first, heard):
    """S and W send to R 20 us apart; hidden from each other, their frames overlap at R."""
    assert -92.3 < 23 - loss_db(175) < -92 < 23 - loss_db(165) < -91.3
    radio = RadioParams(**{**SPATIAL, "reception": {"model": "threshold", "sinr": 2.0}}, capture=capture,
                        capture_window=window)
    med = Medium(rate=RATE, access=Edca(), preamble=PRE / 1e9, radio=radio)
    env, net, port, got = network(med, CAPTURE_XS)
    node = {"S": 1, "W": 2}
    second = "W" if first == "S" else "S"
    at(env, T0, lambda: port.send(net.link(node[first], 0), first, 200))
    at(env, T0 + 20 * US, lambda: port.send(net.link(node[second], 0), second, 200))
    env.run()
    start = {first: T0, second: T0 + 20 * US}
    assert sorted(got) == sorted((start[x] + airtime(200) + LAT, node[x], 0, x) for x in heard)
    rows = {r["link"]: r for r in port.counts()["per_link"]}
    lost = {x for x in ("S", "W") if rows[(node[x], 0)]["lost"]}
    assert lost == {"S", "W"} - heard


def test_the_weak_frame_alone_is_received():
    """The capture geometry's weak sender alone: its frame reaches R (SNR 3.6 dB >= 2)."""
    radio = RadioParams(**{**SPATIAL, "reception": {"model": "threshold", "sinr": 2.0}})
    env, net, port, got = network(Medium(rate=RATE, access=Edca(), preamble=PRE / 1e9, radio=radio), CAPTURE_XS)
    at(env, T0, lambda: port.send(net.link(2, 0), "W", 200))
    env.run()
    assert got == [(T0 + airtime(200) + LAT, 2, 0, "W")]


#: R at 0, W 165 m on one side (-91.4 dBm at R: received alone, SNR 3.6 dB >= 2); I 250 m on the
#: other (-96.8 dBm at R: below the sensitivity, yet enough to push W's SINR to 1.4 dB).
FLOOR_XS = [0.0, -165.0, 250.0]


@pytest.mark.parametrize("floor, heard", [(None, set()), (-92.0, {"W"}), (-97.0, set())])
def test_a_frame_below_the_interference_floor_does_not_interfere(floor, heard):
    """W and I, hidden from each other (415 m), send 20 us apart; R locks on W's frame.  I's
    frame is below R's sensitivity either way (``sensing`` there); it interferes with W's unless
    it is below ``interference_floor`` (-92 dBm: ns-3's YansWifiChannel; -97 dBm is under I's
    -96.8, so it still interferes)."""
    assert -91.5 < 23 - loss_db(165) < -91.3 and -97 < 23 - loss_db(250) < -96.7 < -92
    noise, p_w, p_i = (10 ** (x / 10) for x in (-95.0, 23 - loss_db(165), 23 - loss_db(250)))
    assert 10 * math.log10(p_w / (noise + p_i)) < 2.0 < 10 * math.log10(p_w / noise)
    radio = RadioParams(**{**SPATIAL, "reception": {"model": "threshold", "sinr": 2.0}}, interference_floor=floor)
    env, net, port, got = network(Medium(rate=RATE, access=Edca(), preamble=PRE / 1e9, radio=radio), FLOOR_XS)
    at(env, T0, lambda: port.send(net.link(1, 0), "W", 200))
    at(env, T0 + 20 * US, lambda: port.send(net.link(2, 0), "I", 200))
    env.run()
    assert {x for *_, x in got} == heard
    losses = port.counts()["channel"]["losses"]
    assert losses["sensing"] == 3                   # I's at R, W's at I, I's at W
    assert losses["collision"] == (0 if heard else 1)


def test_an_interference_floor_above_the_sensitivity_is_refused_naming_it():
    """A floor above the sensitivity would leave a locked frame out of its receiver's own sum."""
    highway = Path(__file__).resolve().parents[1] / "scenarios" / "highway_its_g5.yaml"
    with pytest.raises(ScenarioError, match=r"-90.0 dBm is above the sensitivity \(-92.0 dBm\)") as info:
        dkfsim.load_scenario(highway, overrides=["medium.radio.sensitivity=-92", "medium.radio.interference_floor=-90"])
    assert info.value.path == "medium.radio.interference_floor"
    ok = dkfsim.load_scenario(highway, overrides=["medium.radio.sensitivity=-92", "medium.radio.interference_floor=-92"])
    assert ok.medium.radio.interference_floor == -92.0


def test_a_capture_window_without_capture_is_refused_naming_it():
    highway = Path(__file__).resolve().parents[1] / "scenarios" / "highway_its_g5.yaml"
    with pytest.raises(ScenarioError, match="a capture window needs capture") as info:
        dkfsim.load_scenario(highway, overrides=["medium.radio.capture_window=2e-5"])
    assert info.value.path == "medium.radio.capture_window"
    ok = dkfsim.load_scenario(highway, overrides=["medium.radio.capture=5", "medium.radio.capture_window=2e-5"])
    assert ok.medium.radio.capture_window == 2e-5


def test_a_receiver_busy_receiving_defers_and_one_sending_loses_what_arrives():
    """A PHY receiving a frame is busy (802.11's CCA, as ns-3): B locks on A's frame although it is
    below B's carrier sense, so B's own frame waits for its end (a keyed backoff).  Half duplex: A
    and C start at one idle instant, each transmitting while the other's frame arrives -- each
    loses the other's (``receiver_busy``)."""
    from dkfsim.core.streams import key64, keyed_uniform
    radio = RadioParams(**{**SPATIAL, "carrier_sense": -60.0})     # (A's -72.9 dBm at B is below it)
    med = Medium(rate=RATE, access=Edca(), preamble=PRE / 1e9, radio=radio)
    env, net, port, got = network(med, [0.0, 40.0, 80.0], seed=2)
    A, B, C = range(3)
    at(env, T0, lambda: port.send(net.link(A, B), "a", 200))
    at(env, T0 + 20 * US, lambda: port.send(net.link(B, A), "b", 100))
    env.run()
    end_a = T0 + airtime(200)
    b = int(keyed_uniform(key64(2, "channel", 0, B, "edca"), T0 + 20 * US, 0) * 16)
    assert sorted(got) == [(end_a + LAT, A, B, "a"), (end_a + AIFS + b * 13 * US + airtime(100) + LAT, B, A, "b")]
    env, net, port, got = network(med, [0.0, 40.0, 80.0], seed=2)
    at(env, T0, lambda: port.send(net.link(A, C), "a", 200))
    at(env, T0, lambda: port.send(net.link(C, A), "c", 200))
    env.run()
    assert got == []
    rows = {r["link"]: r for r in port.counts()["per_link"]}
    assert (rows[(A, C)]["lost"], rows[(A, C)]["collision_lost"]) == (1, 0)
    # A's at C and C's at A (half duplex), C's at B (B locked on A's, the first of equals), A's at B
    assert port.counts()["channel"]["losses"] == {"sensing": 0, "receiver_busy": 3, "propagation": 0,
                                                  "collision": 1}


def test_every_pair_is_counted_once_and_cbr_is_the_sensed_busy_time():
    """A random run on a line: the pairs by fate add up to frames x (members - 1); a member
    beyond everyone's range senses only its own three frames: its CBR is their airtime over the
    run."""
    radio = RadioParams(**SPATIAL, bins={"width": 50.0, "max": 2000.0})
    med = Medium(rate=RATE, access=Edca(), preamble=PRE / 1e9, radio=radio)
    xs = [0.0, 30.0, 90.0, 160.0, 5000.0]
    env, net, port, got = network(med, xs, seed=3)
    rng = np.random.default_rng(5)
    for t, u in zip(rng.integers(0, 400 * MS, 200), rng.integers(0, 4, 200)):
        at(env, int(t), lambda u=int(u): broadcast(net, port, u, "x", 150))
    for k in range(3):
        at(env, (100 + 100 * k) * MS, lambda: port.send(net.link(4, 0), "far", 200))
    env.run(until=500 * MS)
    ch = port.counts()["channel"]
    assert ch["pairs"] == ch["frames_on_air"] * (len(xs) - 1)
    assert ch["pairs"] == ch["pairs_received"] + sum(ch["losses"].values())
    # beyond the bins (2000 m): the far member's pairs, one per other frame and four per its own
    assert sum(ch["pdr_by_distance"]["frames"]) == ch["pairs"] - (ch["frames_on_air"] - 3) - 3 * 4
    assert ch["cbr"][4] == 3 * airtime(200) / (500 * MS)
    assert min(ch["cbr"][:4]) > 0


@pytest.mark.parametrize("m", [0.5, 1.0, 1.5, 4.0])
def test_the_fading_table_is_the_gamma_inverse_cdf_within_a_thousandth_of_a_db(m):
    """The Nakagami draw interpolates the inverse CDF worked out once per m: against scipy's
    ``gammaincinv`` at random levels and deep in both tails."""
    from scipy.special import gammaincinv

    from dkfsim.components.radio import Nakagami, fading_db
    u = np.concatenate([np.random.default_rng(3).random(50_000), np.logspace(-15, -1, 500), 1 - np.logspace(-15, -1, 500)])
    exact = 10 * np.log10(gammaincinv(m, u) / m)
    assert np.abs(fading_db(Nakagami(m=m), u) - exact).max() < 1e-3


def test_the_normal_quantile_is_scipys_bit_for_bit_compiled_or_not():
    """The kernels' Cephes ``ndtri`` is ``scipy.special.ndtri`` to the bit (the tails' branches
    included), compiled and as Python."""
    from dkfsim.network import radio_kernels as rk
    u = np.concatenate([np.random.default_rng(5).random(20_000), np.logspace(-15.9, -1, 300),
                        1 - np.logspace(-15.9, -1, 300), [2.0 ** -53, 1 - 2.0 ** -53, math.exp(-2), 0.5]])
    want = special.ndtri(u)
    compiled = rk.compiled().ndtri
    assert np.array_equal([compiled(x) for x in u], want)
    assert np.array_equal([rk.ndtri(x) for x in u[::20]], want[::20])


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10**9), m=st.integers(2, 60), sigma=st.sampled_from([0.0, 3.0, 8.0]),
       fading=st.sampled_from([None, 0.5, 1.5, 3.0]), away=st.integers(0, 3), handed=st.integers(0, 2**50))
def test_the_compiled_fill_is_the_python_fill_bit_for_bit(seed, m, sigma, fading, away, handed):
    """A frame's powers and decision draws at every member (keyed shadowing, Nakagami fading by
    its table, members off the road) are the same bits compiled and as Python (the numpy path),
    and the draws are :func:`dkfsim.core.streams.keyed_uniforms`'."""
    import warnings

    from dkfsim.components.radio import Z_MAX, Z_STEPS, Nakagami, NoFading, fading_table
    from dkfsim.core.streams import key64, keyed_uniforms
    from dkfsim.network import radio_kernels as rk
    rng = np.random.default_rng(seed)
    loss = rng.uniform(40.0, 140.0, m)
    keys = np.array([key64(seed, "radio", 0, 1, w) for w in ("shadow", "fade", "rx")], dtype=np.uint64)
    nodes = np.sort(rng.choice(10 * m, m, replace=False)).astype(np.int64)
    table = fading_table(NoFading() if fading is None else Nakagami(m=fading))
    absent = np.zeros(m, dtype=np.bool_)
    absent[rng.choice(m, min(away, m), replace=False)] = True
    i = int(rng.integers(m))
    out = []
    compiled = rk.compiled().fill
    for fill in (compiled, compiled.py_func):
        p, u = np.zeros((3, m)), np.zeros((3, m))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)     # (uint64 arithmetic wraps by design)
            fill(p, u, 1, loss, keys, handed, 7 << 24, nodes, i, 23.0, sigma, table, Z_MAX, float(Z_STEPS), absent)
        out.append((p, u))
    assert np.array_equal(out[0][0], out[1][0]) and np.array_equal(out[0][1], out[1][1])
    assert np.array_equal(out[0][1][1], keyed_uniforms(keys[2], handed, (7 << 24) + nodes))
    p = out[0][0][1]
    assert p[i] == (-1.0 if absent[i] else 0.0) and np.all(p[absent] == -1.0)
    if sigma == 0.0 and fading is None and not absent.any():     # (no draw: the mean power)
        want = 10.0 ** ((23.0 - loss) / 10.0)
        want[i] = 0.0
        assert np.allclose(p, want, rtol=1e-12)


@pytest.mark.parametrize("model", [{"model": "none"}, {"model": "free_space"}, {"model": "log_distance"},
                                   {"model": "log_distance", "exponent": 2.7, "reference_distance": 10.0,
                                    "reference_loss": 60.0},
                                   {"model": "two_ray_interference"}, {"model": "two_ray_interference", "height": 3.0},
                                   {"model": "winner_b1"}, {"model": "winner_b1", "height": 2.0}])
def test_the_engines_path_loss_is_the_models(model):
    """The engine's path loss, one distance at a time (compiled), is
    :func:`dkfsim.components.radio.path_loss_db` of the model at every distance, including below
    the shortest (1 m) and across WINNER+ B1's breakpoint."""
    from dkfsim.components.radio import path_loss_db
    from dkfsim.network import radio_kernels as rk
    from dkfsim.network.media.radio import path_loss_form
    params = RadioParams(path_loss=model)
    kind, plp = path_loss_form(params.path_loss, params.frequency)
    d = np.concatenate([[0.0, 0.3, 1.0], np.geomspace(1.01, 5000.0, 3000)])
    compiled = rk.compiled().path_loss
    got = np.array([compiled(kind, plp, x) for x in d])
    assert np.allclose(got, path_loss_db(params.path_loss, d, params.frequency), rtol=1e-12, atol=1e-9)


def _road_run(kernels: str) -> tuple:
    """Vehicles on a road with shadowing, fading and some off the road, EDCA, background and
    estimator frames (for :func:`test_a_radio_run_is_the_same_on_both_kernel_paths`)."""
    from dkfsim.core.backend import Backend
    n, T = 24, 10 * MS
    radio = RadioParams(path_loss={"model": "winner_b1"}, shadowing={"model": "lognormal", "sigma": 3.0},
                        fading={"model": "nakagami", "m": 1.5}, capture=6.0)
    med = Medium(rate=RATE, access=Edca(), preamble=PRE / 1e9, radio=radio,
                 background=Background(arrivals="periodic", packets_per_second=20, size=300, offset="random"))
    pos = positions([35.0 * i for i in range(n)], ticks=40)
    presence = np.ones((40, n), dtype=bool)
    presence[:10, 3] = presence[25:, 7] = False
    env = simpy.Environment()
    arcs = [(u, v) for u in range(n) for v in range(n) if u != v]
    net = Network(env, arcs, lambda u, v: LinkSpec(latency=Constant(value=LAT / 1e9)), seed=4, T_ns=T,
                  medium=med, positions=pos, presence=presence, n=n, backend=Backend(kernels))
    got: list = []
    port = net.port("p", lambda link, payload: got.append((env.now, link.src, link.dst, payload)))
    for k in range(30):
        for u in (0, 5, 11):
            at(env, k * T + 1, lambda u=u, k=k: broadcast(net, port, u, [u, k], 200))
    env.run(until=35 * T)
    return got, port.channel.report(port, 35 * T), port.channel.series(port, T, 35)["cbr"].tolist()


def test_a_radio_run_is_the_same_on_both_kernel_paths():
    """The radio's engine compiled and as Python (``DKFSIM_KERNELS=numpy``, in a process of its
    own: a process that compiled the kernels runs them compiled): every delivery, every pair's
    count and every member's busy time are the same."""
    import json
    import os
    import subprocess
    import sys
    from pathlib import Path
    code = ("import json, sys; sys.path.insert(0, 'tests'); from test_radio import _road_run; "
            "print(json.dumps(_road_run('numpy')))")
    env = {**os.environ, "DKFSIM_KERNELS": "numpy"}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True,
                         cwd=Path(__file__).parent.parent)
    got0, r0, c0 = json.loads(json.dumps(_road_run("numba")))
    got1, r1, c1 = json.loads(out.stdout)
    assert got0 == got1 and r0 == r1 and c0 == c1
    assert r0["pairs"] > 5_000 and 0 < r0["pairs_received"] < r0["pairs"]


def _python_edca_radio(env, spec, members, positions, record):
    """A radio channel whose per-radio rule is EDCA as a researcher would write one: a
    :class:`~dkfsim.network.media.slotted.SlottedAccess` subclass with ``on_head`` and ``sent`` in
    Python (the engine calls them back)."""
    from typing_extensions import override

    from dkfsim.network.media.radio import RadioChannel
    from dkfsim.network.media.slotted import SlottedAccess

    class PythonEdca(SlottedAccess):
        draws = "edca"

        @override
        def on_head(self, i: int, t: int, idle: bool) -> None:
            c = int(self.count[i])
            if c >= 0 and idle and int(self.origin[i]) + c * self.slot < t:
                c = -1
                self.count[i] = -1
            if c >= 0:
                if idle:
                    self.due[i] = int(self.origin[i]) + c * self.slot
            elif idle:
                self.due[i] = max(t, int(self.origin[i]))
            else:
                self.count[i] = self.draw(i, t)

        @override
        def sent(self, radio, te: int) -> None:
            i = self.pos[radio.node]
            self.count[i] = self.draw(i, te)

    class Radio(RadioChannel):
        @override
        def make_access(self, spec, seed):
            self.slotted = PythonEdca(spec.access, self, seed)
            return self.slotted

    return Radio(env, spec, members, 5, positions, 10 * MS, record=record)


@pytest.mark.parametrize("record", [False, True])
def test_a_researchers_rule_in_python_runs_on_the_radio_as_the_built_in_one(record):
    """A per-radio rule in Python (the engine calls its ``on_head`` and ``sent`` back) written as
    ``edca`` is: the radio delivers what it delivers with the built-in, compiled ``edca`` --
    every pair, every busy period, every estimator frame's fates; with ``record``, every frame
    that ended is logged, each once."""
    from dkfsim.network.media.base import Frame
    from dkfsim.network.media.radio import RadioChannel
    n = 40
    radio = RadioParams(path_loss={"model": "log_distance"}, fading={"model": "nakagami", "m": 1.0})
    spec = Medium(rate=RATE, access=Edca(cw=7), preamble=PRE / 1e9, radio=radio, queue={"packets": 3},
                  background=Background(arrivals="poisson", packets_per_second=60, size=400))
    pos = positions([12.0 * i for i in range(n)], ticks=60)
    out = []
    for custom in (False, True):
        env = simpy.Environment()
        ch = _python_edca_radio(env, spec, tuple(range(n)), pos, record) if custom else \
            RadioChannel(env, spec, tuple(range(n)), 5, pos, 10 * MS, record=record)
        told: list = []

        def done(frame, ok, told=told):
            told.append((frame.node, frame.start, frame.end, ok, sorted(frame.lost_at or {})))
        for k in range(40):
            for u in (3, 17, 30):
                at(env, k * 10 * MS + 7, lambda u=u, env=env, ch=ch, done=done: ch.offer(Frame(u, 900, env.now, None,
                                                                                                done, "me")))
        env.run(until=450 * MS)
        out.append((told, ch.report("me", 450 * MS), ch.ended))
    assert out[0][0] == out[1][0] and out[0][1] == out[1][1] and out[0][2] == out[1][2]
    told, rep, ended = out[0]
    assert len(told) > 50 and rep["frames_on_air"] > 1000 and rep["background_dropped"] > 0
    if record:
        assert ended is not None and len(ended) == len(set(ended)) >= rep["frames_on_air"] - 20


def test_a_vehicle_off_the_road_neither_receives_nor_is_heard():
    """An estimator's frames through a port: a receiver off the road gets none of them (its links
    count them lost, not to a collision), and a sender off the road reaches nobody."""
    n = 4
    med = Medium(rate=RATE, access=Edca(), preamble=PRE / 1e9, radio=RadioParams(path_loss={"model": "none"}))
    presence = np.ones((100, n), dtype=bool)
    presence[:, 3] = False
    env = simpy.Environment()
    arcs = [(u, v) for u in range(n) for v in range(n) if u != v]
    net = Network(env, arcs, lambda u, v: LinkSpec(latency=Constant(value=LAT / 1e9)), seed=1, T_ns=10 * MS,
                  medium=med, positions=positions([10.0 * i for i in range(n)], 100), presence=presence, n=n)
    got: list = []
    port = net.port("p", lambda link, payload: got.append((link.src, link.dst)))
    at(env, T0, lambda: broadcast(net, port, 0, "x", 100))
    at(env, T0 + 5 * MS, lambda: broadcast(net, port, 3, "y", 100))
    env.run(until=20 * MS)
    assert sorted(got) == [(0, 1), (0, 2)]
    rows = {tuple(r["link"]): r for r in port.counts()["per_link"]}
    assert {k: rows[k]["lost"] for k in ((0, 3), (3, 0), (3, 1))} == {(0, 3): 1, (3, 0): 1, (3, 1): 1}
    assert rows[(0, 3)]["collision_lost"] == rows[(3, 0)]["collision_lost"] == 0

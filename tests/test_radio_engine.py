"""The spatial radio's compiled engine (``radio_kernels.run``) on its less-travelled paths: buffers
that grow while frames are on the air (slots, waiting rooms whose ring has wrapped, busy periods,
dropped background, the log of ended frames, a radio's background block), generation jitter
with full waiting rooms, members off the road, and a channel asked for its statistics mid-run.

Independent truths only: the same run with every buffer big from the start (nothing may depend
on when a buffer grew, or on which slot a frame took); the same run with and without queries
mid-run; counts that follow from the configuration (every (frame, receiver) pair counted once,
members off the road excluded; each ended frame logged once; each estimator's frame told once,
at its end); the engine as Python (``DKFSIM_KERNELS=numpy``, a process of its own) against the
compiled one; and timelines worked by hand.
"""

from __future__ import annotations

import signal
from typing import Any

import numpy as np
import pytest
import simpy
from hostile.hostile_kit import answers_within
from test_medium import at

from dkfsim.components.faults import LinkSpec
from dkfsim.components.latency import Constant
from dkfsim.components.medium import Csma, Edca, Medium, Sps
from dkfsim.components.radio import RadioParams
from dkfsim.components.traffic import Background
from dkfsim.core.backend import Backend
from dkfsim.core.streams import key64, keyed_uniform
from dkfsim.network import radio_kernels as rk
from dkfsim.network.media.base import Frame
from dkfsim.network.media.radio import RadioChannel
from dkfsim.network.media.sidelink import SidelinkChannel
from dkfsim.network.network import Network

US, MS = 1_000, 1_000_000
RATE, PRE = 6e6, 40 * US
AIFS, SLOT = 110 * US, 13 * US
T = 10 * MS

#: log-distance, exponent 3 (tests/test_radio.py): 23 dBm is -84.9 dBm at 100 m (sensed), -93.9 at
#: 200 m (below sensitivity)
SPATIAL = dict(path_loss={"model": "log_distance", "exponent": 3.0}, sensitivity=-92.0, carrier_sense=-88.0,
               noise=-95.0, reception={"model": "threshold", "sinr": 8.0})
FULL = dict(path_loss={"model": "winner_b1"}, shadowing={"model": "lognormal", "sigma": 3.0},
            fading={"model": "nakagami", "m": 1.5})


def airtime(size: int) -> int:
    return PRE + int(size * 8 * 1e9 / RATE + 0.5)


def line(xs, ticks: int) -> np.ndarray:
    pos = np.zeros((ticks, len(xs), 2))
    pos[:, :, 0] = np.asarray(xs, dtype=float)
    return pos


# ------------------------------------------------------------------ a run, its every output
def _run(cfg: dict, *, big: bool = False, queries: bool = False, backend: Backend | None = None) -> dict:
    """One radio channel driven directly (a :class:`Frame` per offer, ``record``): every frame
    told (the instant, its start, end, fates), every frame ended, the report, the per-tick busy
    time and the buffers' sizes at the end.  ``big``: every buffer of the engine made big before
    the run; ``queries``: the channel asked for its statistics and advanced again and again at
    ``cfg["queries"]`` instants (their answers returned too); ``backend``: the kernel path (default:
    the environment's)."""
    n, ticks, T_ns = cfg["n"], cfg["ticks"], cfg.get("T", T)
    kw: dict[str, Any] = dict(rate=RATE, access=cfg.get("access", Edca()), preamble=PRE / 1e9,
                              radio=RadioParams(**cfg["radio"]))
    for key in ("background", "queue", "generation_jitter"):
        if cfg.get(key) is not None:
            kw[key] = cfg[key]
    presence = None
    if cfg.get("absent"):
        presence = np.ones((ticks, n), dtype=bool)
        for node, a, b in cfg["absent"]:
            presence[a:b, node] = False
    env = simpy.Environment()
    ch = RadioChannel(env, Medium(**kw), tuple(range(n)), cfg.get("seed", 1), line(cfg["xs"], ticks), T_ns,
                      record=True, presence=presence, backend=backend)
    if big:
        _make_big(ch)
    told: list = []
    accepted: list = []

    def done(frame: Frame, ok: bool) -> None:
        told.append((env.now, frame.node, frame.handed, frame.start, frame.end, ok, sorted((frame.lost_at or {}).items())))

    for t, u, size in cfg["plan"]:
        at(env, t, lambda u=u, size=size: accepted.append(ch.offer(Frame(u, size, env.now, None, done, "me"))))
    answers: list = []
    if queries:
        for t in cfg.get("queries", ()):
            at(env, t, lambda: answers.append(_ask(ch, env.now, T_ns)))
    end = cfg["end"]
    env.run(until=end)
    report = ch.report("me", end)
    busy = ch.busy_per_tick(T_ns, end // T_ns)
    sizes = dict(slots=len(ch.p), queue=ch.queue.shape[1], background=ch.bg.shape[1], periods=len(ch.periods),
                 dropped=len(ch.dropped), log=len(ch.log)) if hasattr(ch, "bg") else {}
    return dict(told=told, accepted=accepted, ended=list(ch.ended or []), report=report, busy=busy.tolist(),
                answers=answers, sizes=sizes, ch=ch)


def _make_big(ch: RadioChannel) -> None:
    """Every buffer of ``ch``'s engine big before anything happens (as its own ``_grow`` makes
    them): the slots (free ones taken in another order), the waiting rooms, the busy periods,
    the dropped background, the log and every radio's background block."""
    ch._grow_slots(300)
    for _ in range(7):
        ch._grow(rk.G_QUEUE)
    for what in (rk.G_PERIODS, rk.G_DROPPED, rk.G_LOG):
        for _ in range(6):
            ch._grow(what)
    wide = np.zeros((ch.bg.shape[0], 4096, 3), dtype=np.int64)
    wide[:, :ch.bg.shape[1]] = ch.bg
    ch.bg = wide


def _ask(ch: RadioChannel, now: int, T_ns: int) -> tuple:
    """What a caller may ask a channel mid-run (several times over, brought to the same instant)."""
    for _ in range(3):
        ch.advance(now)
    k = now // T_ns
    stats = ch.stats(now)
    return (now, {key: stats[key] for key in ("frames_on_air", "background_sent", "background_dropped")},
            ch.busy_per_tick(T_ns, k).tolist(), ch.cbr(k * T_ns).tolist() if k else [],
            ch.report("me", now)["frames"], ch.series("me", T_ns, k + 1)["cbr"].shape)


def _comparable(out: dict) -> dict:
    return {key: out[key] for key in ("told", "accepted", "ended", "report", "busy")}


#: Sixty vehicles 10 m apart that sense nothing but their own frames and those they lock on
#: (carrier sense far above any power): all transmit over each other, tens of frames on the air
#: at once (slots); bursts of up to 33 frames at one radio while its ring has wrapped (waiting
#: rooms); hundreds of frames (busy periods), and the last 50 ms background alone, brought up to
#: date at once (a hundred frames in the log).
CROWD = dict(n=60, xs=[10.0 * i for i in range(60)], ticks=16, radio={**FULL, "carrier_sense": 60.0, "capture": 6.0},
             background=Background(arrivals="poisson", packets_per_second=60, size=250, sizes="exponential"),
             plan=[(k * T + 1 + (u % 5), u, 200 + u) for k in range(9) for u in range(0, 60, 2)]
             + [(k * T + 2 * MS + j * 40 * US, 7, 90 + j) for k in (1, 4) for j in range(33)]
             + [(k * T + 5 * MS, 7, 100) for k in range(8)],
             queries=[5 * MS, 20 * MS, 20 * MS, 33 * MS + 17, 60 * MS], end=14 * T)
#: Two radios whose background comes a billion a second (Poisson: two gaps in five round to
#: 0 ns, so many packets share an instant) with exponential sizes, waiting rooms of 2: background
#: blocks that must widen, hundreds of thousands dropped, rooms that grow for one instant's packets.
FLOOD = dict(n=2, xs=[0.0, 30.0], ticks=8, T=50 * US, radio=SPATIAL, queue={"packets": 2},
             background=Background(arrivals="poisson", packets_per_second=1e9, size=40, sizes="exponential"),
             plan=[(3 * US, 1, 50), (100 * US, 0, 50), (100 * US, 0, 60)], queries=[60 * US, 100 * US + 3],
             end=120 * US)
#: Twelve vehicles with generation jitter and waiting rooms of one frame, some off the road (one
#: leaves while its frames wait), several frames per vehicle and tick: frames held back and then
#: refused, frames released at one instant.
JITTER = dict(n=12, xs=[40.0 * i for i in range(12)], ticks=30, radio=FULL, queue={"packets": 1},
              generation_jitter=0.004, absent=[(3, 5, 9), (5, 0, 4), (11, 20, 30), (0, 12, 13)],
              background=Background(arrivals="periodic", packets_per_second=100, size=250, offset="random"),
              plan=[(k * T + d, u, 200 + d % 7) for k in range(25) for u in (0, 3, 5, 11) for d in (1, 2, 9_999_000)],
              queries=[40 * MS, 40 * MS + 1, 125 * MS], end=26 * T)
#: Twelve pairs of radios 20 m apart, the pairs 5 km apart (each radio hears its partner only),
#: frames of 4 ms handed over 50 us apart, then bursts of ten at one radio: frames start while
#: others are on the air, so the slots grow with frames on them (their powers and distances kept).
FAR = dict(n=24, xs=[5000.0 * (i // 2) + 20.0 * (i % 2) for i in range(24)], ticks=6, radio=SPATIAL, access=Csma(cw=7),
           background=Background(arrivals="periodic", packets_per_second=300, size=120, offset="random"),
           plan=[(k * T + 200 * US + u * 50 * US, u, 3000 - 10 * u) for k in range(4) for u in range(24)]
           + [(k * T + 5 * MS, u, 50 + j) for k in range(4) for u in (3, 11) for j in range(10)],
           queries=[1 * MS, 10 * MS, 20 * MS, 20 * MS, 30 * MS + 5], end=5 * T)
CONFIGS = {"crowd": CROWD, "flood": FLOOD, "jitter": JITTER, "far": FAR}


@pytest.mark.parametrize("name", list(CONFIGS))
def test_buffers_grown_during_a_run_give_what_big_buffers_give(name):
    """A run whose engine's buffers start small and grow while frames are on the air (the slots'
    rows kept, a wrapped ring unrolled, the log drained) gives every report, delivery, fate, log
    entry and busy time of the same run with every buffer big from the start -- which also takes
    its free slots in another order.  The small run must have grown what the configuration is
    for."""
    cfg = CONFIGS[name]
    small, big = _run(cfg), _run(cfg, big=True)
    assert _comparable(small) == _comparable(big)
    grown = small["sizes"]
    if name == "crowd":
        assert grown["slots"] > 8 and grown["queue"] > 4 and grown["periods"] > 256 and grown["log"] > 64
    elif name == "flood":
        assert grown["background"] > 64 and grown["dropped"] > 64 and grown["queue"] > 4
        assert small["report"]["background_dropped"] > 50_000
    elif name == "jitter":
        assert small["report"]["frames_dropped"] > 50 and grown["periods"] > 256
    else:
        assert grown["slots"] > 8 and grown["queue"] > 4


@pytest.mark.parametrize("name", list(CONFIGS))
def test_asking_mid_run_changes_nothing_and_answers_what_the_end_says(name):
    """``advance`` called again and again at one instant, and ``report``, ``stats``, ``cbr``,
    ``busy_per_tick`` and ``series`` asked mid-run (at tick boundaries, between them, at a held
    frame's instant), then the run continued: everything at the end is as without the questions.
    What is "as of an instant" is the same asked then or at the end: the frames started before it,
    the background sent and dropped by it, each whole tick's busy time and the CBR up to a tick
    boundary."""
    cfg = CONFIGS[name]
    plain, asked = _run(cfg), _run(cfg, queries=True)
    assert _comparable(plain) == _comparable(asked)
    ch, T_ns = plain["ch"], cfg.get("T", T)
    assert len(asked["answers"]) == len(cfg["queries"])
    for now, stats, busy, cbr, _, _ in asked["answers"]:
        later = ch.stats(now)
        assert stats == {key: later[key] for key in stats}
        k = now // T_ns
        assert busy == plain["busy"][:k]
        if k:
            assert cbr == ch.cbr(k * T_ns).tolist()


@pytest.mark.parametrize("name", list(CONFIGS))
def test_every_pair_every_ended_frame_and_every_own_frame_is_counted_once(name):
    """From the log of ended frames alone: each ended once; its (frame, receiver) pairs are the
    members on the road at its start's tick but its sender (none when the sender is off the road),
    and they add up to the report's pairs.  Every frame of the estimator taken is told once (a
    frame refused after generation jitter: never on the air), those refused at the offer not at
    all, and a radio's frames go on the air in the order they were handed over (generation jitter
    keeps it)."""
    cfg = CONFIGS[name]
    out = _run(cfg)
    n, ticks, T_ns = cfg["n"], cfg["ticks"], cfg.get("T", T)
    present = np.ones((ticks, n), dtype=bool)
    for node, a, b in cfg.get("absent", ()):
        present[a:b, node] = False
    ended, report = out["ended"], out["report"]
    assert len(ended) == len(set(ended)) and len({(e[0], e[1]) for e in ended}) == len(ended)
    pairs = 0
    for node, start, _, _, _ in ended:
        k = min(start // T_ns, ticks - 1)
        pairs += int(present[k].sum()) - 1 if present[k, node] else 0
    assert report["pairs"] == pairs == report["pairs_received"] + sum(report["losses"].values())
    assert report["frames_on_air"] >= len(ended)
    told = out["told"]
    on_air = [x for x in told if x[5]]
    refused_late = [x for x in told if not x[5]]
    assert all(x[3] == -1 for x in refused_late)
    assert sum(out["accepted"]) == len(told) + _still_waiting(out)
    own_ended = sorted((node, start, end) for node, start, end, _, bg in ended if not bg)
    assert sorted((x[1], x[3], x[4]) for x in on_air) == own_ended
    assert report["frames"] == len(on_air)
    for node in range(n):                           # (a radio's frames go in the order handed over)
        handed = [x[2] for x in sorted(on_air, key=lambda x: x[3]) if x[1] == node]
        assert handed == sorted(handed)


def _still_waiting(out: dict) -> int:
    """The estimator's frames taken but not told by the end (waiting, held or on the air)."""
    return int(out["ch"].pending)


# ------------------------------------------------------------------ both kernel paths
def _engine_run(kernels: str, name: str) -> Any:
    """:func:`_run` of a configuration on one kernel path (for the subprocess)."""
    import json
    out = _run(CONFIGS[name], backend=Backend(kernels))
    return json.loads(json.dumps({key: out[key] for key in ("told", "accepted", "ended", "report", "busy")}))


@pytest.mark.slow
@pytest.mark.parametrize("name", ["crowd", "jitter", "far"])
def test_the_growing_engine_is_the_same_on_both_kernel_paths(name):
    """A run that grows every buffer, compiled and as Python (``DKFSIM_KERNELS=numpy`` in a
    process of its own: a process that compiled the kernels runs them compiled) gives the same
    every output."""
    import json
    import os
    import subprocess
    import sys
    from pathlib import Path
    code = ("import json, sys; sys.path.insert(0, 'tests'); from test_radio_engine import _engine_run; "
            f"print(json.dumps(_engine_run('numpy', {name!r})))")
    env = {**os.environ, "DKFSIM_KERNELS": "numpy"}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True,
                         cwd=Path(__file__).parent.parent)
    assert json.loads(out.stdout) == _engine_run("numba", name)


# ------------------------------------------------------------------ hand-worked
def test_jitter_holds_two_frames_to_one_instant_and_a_room_of_one_refuses_the_second():
    """Generation jitter J = 4 ms: vehicle 0's frames handed over at t0 (tick 0) both reach its
    radio at t0 + d, d = keyed uniform of (vehicle, tick) times J.  The first becomes its head on
    an idle medium and starts then; the second finds the room of one full and is refused (told
    not ok, never on the air).  A third frame, handed over at the instant the first ends, is held
    by the same d (same tick): its post-backoff ran out by then (d > AIFS + 15 slots), so it starts
    when it arrives."""
    seed, J = 3, 4 * MS
    d = int(keyed_uniform(key64(seed, "channel", 0, 0, "jitter"), 0, 0) * J)
    assert d > AIFS + 15 * SLOT
    t0 = 1 * MS
    first_end = t0 + d + airtime(200)
    cfg = dict(n=2, xs=[0.0, 5000.0], ticks=4, radio=SPATIAL, queue={"packets": 1}, generation_jitter=J / 1e9,
               seed=seed, plan=[(t0, 0, 200), (t0, 0, 300), (first_end, 0, 100)], end=20 * MS)
    out = _run(cfg)
    assert out["accepted"] == [True, True, True]
    third = first_end + d
    assert [x[:6] for x in out["told"]] == [
        (t0 + d, 0, t0, -1, -1, False),
        (first_end, 0, t0, t0 + d, first_end, True),
        (third + airtime(100), 0, first_end, third, third + airtime(100), True)]
    assert out["report"]["frames_dropped"] == 1 and out["report"]["frames"] == 2


def test_a_sender_that_leaves_the_road_while_its_frame_waits_sends_it_to_nobody():
    """Ticks of 1 ms; every radio has a background packet of 100 bytes every 20 ms from 0.  At 0
    the three (A, B, C at x = 0, 50, 100) have one each: all go at AIFS and collide.  A sends at
    0.7 ms; B senses it and its frame, handed over 5 us later, waits for A's end, then AIFS and its
    keyed backoff b: it starts in tick 1, when B is off the road -- on the air, but nobody's: no
    pair, nobody senses it, and its owner learns that every other vehicle lost it.  At 20 ms B's background packet is dropped unseen (off the road); A's
    and C's go at once, each a pair at the other.  Pairs: 6 at AIFS, 2 of A's frame, 2 at 20 ms."""
    cfg = dict(n=3, xs=[0.0, 50.0, 100.0], ticks=40, T=1 * MS, radio=SPATIAL, seed=4, absent=[(1, 1, 40)],
               background=Background(arrivals="periodic", packets_per_second=50, size=100),
               plan=[(700 * US, 0, 200), (705 * US, 1, 200)], end=30 * MS)
    out = _run(cfg)
    b = int(keyed_uniform(key64(4, "channel", 0, 1, "edca"), 705 * US, 0) * 16)
    end_a = 700 * US + airtime(200)
    start_b = end_a + AIFS + b * SLOT
    assert start_b >= 1 * MS
    assert [x[:6] for x in out["told"]] == [(end_a, 0, 700 * US, 700 * US, end_a, True),
                                            (start_b + airtime(200), 1, 705 * US, start_b, start_b + airtime(200), True)]
    assert out["told"][1][6] == [(0, False), (2, False)]    # (no pair counted; lost at every other vehicle)
    assert sorted(e[:3] for e in out["ended"]) == sorted(
        [(r, AIFS, AIFS + airtime(100)) for r in range(3)] + [(0, 700 * US, end_a), (1, start_b, start_b + airtime(200))]
        + [(r, 20 * MS, 20 * MS + airtime(100)) for r in (0, 2)])
    rep = out["report"]
    assert rep["frames_on_air"] == 7 and rep["pairs"] == 10 and rep["background_dropped"] == 0
    busy = 2 * airtime(100) + airtime(200)          # (A: its own three; C: its own two and A's frame)
    assert rep["cbr"][0] == rep["cbr"][2] == busy / (30 * MS)


# ------------------------------------------------------------------ faults the review found (now fixed)
# RadioChannel._arrive once left the rule's cached first due instant stale after the engine's
# push; Channel._wake on an overlapping medium once woke at the first due instant plus the
# shortest airtime due then, missing a radio due later with a shorter frame; and
# BackgroundArrivals.take once looped forever on a background held at MAX_NS.


def test_a_frame_offered_after_one_due_later_at_one_instant_is_told_at_its_end():
    """A (x = 0) sends at 1 ms.  At 1.01 ms, B (x = 50, sensing A's frame) is handed a frame, which
    waits for A's end, and then C (x = 5000, far from both) one of 100 bytes, which starts at once:
    C's frame is told at its end, 1.01 ms + its airtime, before A's -- every estimator's frame is
    told at the instant it ends (Channel._wake)."""
    cfg = dict(n=3, xs=[0.0, 50.0, 5000.0], ticks=4, radio=SPATIAL,
               plan=[(1 * MS, 0, 200), (1 * MS + 10 * US, 1, 200), (1 * MS + 10 * US, 2, 100)], end=5 * MS)
    told = _run(cfg)["told"]
    assert [(x[0], x[1]) for x in told][:2] == [(1 * MS + 10 * US + airtime(100), 2), (1 * MS + airtime(200), 0)]
    assert all(x[0] == x[4] for x in told)


def test_deliveries_never_go_back_in_time():
    """The same timeline through a network's port, with an event at 1.25 ms: C's frame (ends at
    1.1833 ms) is delivered before it, and the clock never goes backwards."""
    n = 4
    med = Medium(rate=RATE, access=Edca(), preamble=PRE / 1e9, radio=RadioParams(**SPATIAL))
    env = simpy.Environment()
    arcs = [(u, v) for u in range(n) for v in range(n) if u != v]
    net = Network(env, arcs, lambda u, v: LinkSpec(latency=Constant(value=1e-6)), seed=1, T_ns=T, medium=med,
                  positions=line([0.0, 50.0, 5000.0, 5020.0], 4), n=n)
    got: list = []
    port = net.port("p", lambda link, payload: got.append((env.now, payload)))
    at(env, 1 * MS, lambda: port.send(net.link(0, 1), "a", 200))
    at(env, 1 * MS + 10 * US, lambda: port.send(net.link(1, 0), "b", 200))
    at(env, 1 * MS + 10 * US, lambda: port.send(net.link(2, 3), "c", 100))
    at(env, 1250 * US, lambda: got.append((env.now, "marker")))
    env.run(until=5 * MS)
    assert [x[1] for x in got] == ["c", "marker", "a", "b"]
    assert [x[0] for x in got] == sorted(x[0] for x in got)


def test_a_shorter_frame_due_later_at_another_radio_is_told_at_its_end():
    """A and B (5 km apart) hear nothing of each other.  B's frame of 100 bytes goes at 0.5 ms and
    ends at 673333 ns (its post-backoff drawn then).  50 us later A is handed 1000 bytes (it starts
    at once, 1.37 ms on the air) and B 10 bytes, which wait for B's post-backoff and then go: B's
    short frame ends long before A's, and is told then.  (The implementation before the compiled
    engine, 9387e4e, did the same: a fault of Channel._wake, not of the engine.)"""
    t = 673333 + 50 * US
    cfg = dict(n=2, xs=[0.0, 5000.0], ticks=4, radio=SPATIAL, plan=[(500 * US, 1, 100), (t, 0, 1000), (t, 1, 10)],
               end=5 * MS)
    told = _run(cfg)["told"]
    assert [x[1] for x in told] == [1, 1, 0]
    assert told[1][3] > t and told[1][4] == told[1][3] + airtime(10) < t + airtime(1000)
    assert all(x[0] == x[4] for x in told)


@pytest.mark.parametrize("name", ["crowd", "sixty_csma"])
def test_every_frame_is_told_at_its_end(name):
    """Every estimator's frame that went on the air is told at the instant it ends (so a port
    schedules its deliveries from the present): the crowd, and sixty radios 5 km apart under
    ``csma`` (each draws a backoff for every head) with waiting rooms of one, frames handed over by
    every radio at a few instants."""
    n = 60
    cfg = CROWD if name == "crowd" else dict(
        n=n, xs=[5000.0 * i for i in range(n)], ticks=8, radio=SPATIAL, access=Csma(cw=3), queue={"packets": 1},
        background=Background(arrivals="periodic", packets_per_second=100, size=300),
        plan=[(k * T + 3 * MS + (u % 3), u, 200 + u) for k in range(5) for u in range(n)], end=6 * T)
    told = [x for x in _run(cfg)["told"] if x[5]]
    assert len(told) > 100
    assert [x for x in told if x[0] != x[4]] == []


@pytest.mark.skipif(not hasattr(signal, "setitimer"), reason="needs SIGALRM")
def test_a_periodic_background_past_the_end_of_time_does_not_hang_the_radio():
    """A periodic background of one packet in 1e10 s: packet 0 at 0, every later one beyond the last
    instant a run can have (clipped to it).  Each radio sends its packet 0 (two frames on the air)
    and nothing more."""
    spec = Medium(rate=RATE, access=Edca(), preamble=PRE / 1e9, radio=RadioParams(path_loss={"model": "none"}),
                  background=Background(arrivals="periodic", packets_per_second=1e-10, size=100))
    RadioChannel(simpy.Environment(), spec.model_copy(update={"background": None}), (0, 1), 1, line([0.0, 10.0], 10),
                 T)                                 # (the kernels compiled or loaded before the clock runs)
    env = simpy.Environment()
    with answers_within(0.5):           # (a loop that never ends fails, not hangs)
        ch = RadioChannel(env, spec, (0, 1), 1, line([0.0, 10.0], 10), T)
        env.run(until=50 * MS)
        assert ch.report(None, 50 * MS)["frames_on_air"] == 2


@pytest.mark.parametrize("access", ["edca", "sps"])
def test_a_vehicle_beyond_every_distance_bin_is_counted_not_binned(access):
    """A vehicle 1e21 m away (a distance in bins beyond int64: its bin number once came out
    negative, and the compiled engine wrote outside the pairs table, then aborted freeing
    memory): its pairs count in ``pairs``, in no distance bin."""
    if access == "edca":
        r = _run(dict(n=3, ticks=5, radio=SPATIAL, xs=[0.0, 50.0, 1e21], end=40 * MS,
                      plan=[(1 * MS, 0, 200), (2 * MS, 2, 200)]))["report"]
    else:
        env = simpy.Environment()
        ch = SidelinkChannel(env, Medium(rate=RATE, access=Sps(), radio=RadioParams(**SPATIAL)), (0, 1, 2), 1,
                             line([0.0, 50.0, 1e21], 5), T)
        for t, u in ((1 * MS, 0), (2 * MS, 2)):
            at(env, t, lambda u=u: ch.offer(Frame(u, 200, env.now, None, lambda f, ok: None, "me")))
        env.run(until=40 * MS)
        r = ch.report("me", 40 * MS)
    binned = r["pdr_by_distance"]
    assert r["pairs"] == 4 and sum(binned["frames"]) == 1 and binned["frames"][2] == 1     # (0 -> 1 at 50 m)


@pytest.mark.parametrize("kind, offset", [("periodic", "random"), ("periodic", 0.0), ("poisson", 0.0)])
def test_a_background_of_one_packet_in_1e300_seconds_never_sends_after_its_first(kind, offset):
    """``packets_per_second: 1e-300``: an offset over one period of 1e300 s raised OverflowError
    (infinity to int), and packet 0 of a periodic process lay at 0 * inf, not a number, read by the
    engine as an instant below zero (an IndexError, or a crash when compiled).  Every instant is a
    number in ``[0, MAX_NS]``; a random offset puts the first one at "never", a fixed one at it."""
    from dkfsim.core.params import MAX_NS
    from dkfsim.network.media.background import BackgroundArrivals
    spec = Background(arrivals=kind, packets_per_second=1e-300, size=100, **({} if kind == "poisson" else
                                                                              {"offset": offset}))
    times, _ = BackgroundArrivals(spec, ("radio", 0, 0), 1, first_block=8).next_block()
    assert ((times >= 0) & (times <= MAX_NS)).all() and (np.diff(times) >= 0).all()
    if kind == "poisson":                   # (each gap held at 2^49 ns, 6.5 days)
        assert times[0] >= 2**49
    else:
        assert times[0] == (MAX_NS if offset == "random" else 0) and (times[1:] == MAX_NS).all()
    ch = RadioChannel(simpy.Environment(), Medium(rate=RATE, access=Edca(), preamble=PRE / 1e9, radio=RadioParams(),
                                                  background=spec), (0, 1), 1, line([0.0, 10.0], 10), T)
    ch.env.run(until=50 * MS)
    assert ch.report(None, 50 * MS)["frames_on_air"] == (2 if offset == 0.0 and kind == "periodic" else 0)

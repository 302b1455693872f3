"""Link quality from distance (``mobility.links``) and the speed factor (``mobility.speed``):
issue 23 §2 "latency, loss and rate may depend on distance", §6's speed axis (decisions
176-180)."""

from __future__ import annotations

import copy

import numpy as np
import pytest
import simpy
from conftest import run_scenario, scenario
from test_mobility import arrival_ticks, steps_latency, waypoints, with_mobility

from dkfsim.components.faults import LinkSpec
from dkfsim.components.latency import Constant
from dkfsim.components.mobility import DistanceLinks, LinkSchedule, Mobility
from dkfsim.core.errors import ScenarioError
from dkfsim.network.network import Network


def _network(distances, quality, latency=0.0, rate=None, T_ns=10**9):
    """Two links 0 -> 1 and 1 -> 0, always up, at ``distances[k]`` metres at tick ``k``."""
    env = simpy.Environment()
    dist = np.asarray(distances, dtype=float)
    up = np.ones((len(dist), 2), dtype=bool)
    sched = LinkSchedule(up, [(0, 1), (1, 0)], np.stack([dist, dist], axis=1), DistanceLinks(**quality))
    net = Network(env, [(0, 1), (1, 0)], lambda u, v: LinkSpec(latency=Constant(value=latency), rate=rate),
                  1, T_ns, schedule=sched)
    got = []
    port = net.port("p", lambda link, payload: got.append((env.now, payload)), until=10**12)
    return env, net, port, got


def test_loss_is_zero_inside_d0_and_one_beyond_d1_exactly_on_those_ticks():
    """Hand-worked: node 1 is 2 m from node 0 (inside d0 = 3 m) or 8 m away (beyond d1 = 7 m,
    still inside the 10 m range) following a fixed pattern; flood sends row ``r`` both ways at
    tick ``r + 1``, so exactly the packets handed over at a far tick are lost (counted in
    ``lost``, not ``range_lost``) and the others arrive ``d`` ticks later."""
    K, d = 30, 2
    far = [k % 5 in (2, 3) or 17 <= k <= 21 for k in range(K + 1)]
    xs = [(8.0 if f else 2.0, 0.0) for f in far]
    sc = with_mobility(scenario(2, edges=[(0, 1)], protocol="flood", steps=K, buffer_length=8,
                                latency=steps_latency(d)),
                       [{"kind": "constant_velocity", "start": [0.0, 0.0]}, waypoints(xs)])
    sc["mobility"]["links"] = {"loss": [[3.0, 0.0], [7.0, 1.0]]}
    run = run_scenario(sc)
    c = run.counts
    n_far = sum(far[1:K + 1])
    assert (c["sent"], c["lost"], c["range_lost"]) == (2 * K, 2 * n_far, 0), c
    assert c["delivered"] + c["in_flight"] == 2 * (K - n_far)
    ticks = arrival_ticks(run.arrays)
    for r in range(K - d):
        want = np.inf if far[r + 1] else r + 1 + d
        assert ticks[1, 0, r] == want and ticks[0, 1, r] == want, r


def test_loss_in_between_is_the_table_interpolated_and_combined_with_the_link_loss():
    q = DistanceLinks(loss=[[3.0, 0.0], [7.0, 1.0]])
    assert q.per_tick(np.array([0.0, 3.0, 4.0, 6.0, 7.0, 50.0]))[0] == [0.0, 0.0, 0.25, 0.75, 1.0, 1.0]


def test_latency_per_metre_is_added_to_the_draw_to_the_nanosecond():
    """A 1 ms constant latency plus 3.3 ns/m at the hand-over tick's distance."""
    dist = [123.4, 10.0, 0.0, 999.9]
    env, net, port, got = _network(dist, {"latency_per_m": 3.3e-9}, latency=0.001)
    sends = [(0, 0), (1_500_000_000, 1), (2_999_999_999, 2), (3_000_000_000, 3)]
    for t, k in sends:
        env.run(until=t) if t > env.now else None
        port.send(net.link(0, 1), k)
    env.run(until=10**10)
    want = [(t + 1_000_000 + int(round(dist[k] * 3.3)), k) for t, k in
            [(0, 0), (1_500_000_000, 1), (2_999_999_999, 2), (3_000_000_000, 3)]]
    assert want == [(1_000_407, 0), (1_501_000_033, 1), (3_000_999_999, 2), (3_001_003_300, 3)]
    assert sorted(got) == want


def test_rate_from_distance_gives_the_transmission_time_at_that_distance():
    """Rate 1000 bit/s at 0 m, 2000 bit/s at 100 m: a 100-byte packet takes 800 bits / rate;
    at 60 m (1600 bit/s) 0.5 s, at 0 m 0.8 s, at 100 m and beyond 0.4 s."""
    dist = [60.0, 0.0, 250.0]
    env, net, port, got = _network(dist, {"rate": [[0.0, 1000.0], [100.0, 2000.0]]})
    for t, k in [(0, 0), (1_000_000_000, 1), (2_100_000_000, 2)]:
        if t > env.now:
            env.run(until=t)
        port.send(net.link(0, 1), k, nbytes=100)
    env.run(until=10**10)
    assert sorted(got) == [(500_000_000, 0), (1_800_000_000, 1), (2_500_000_000, 2)]


def test_a_zero_quality_table_keeps_the_run_bit_for_bit():
    """A loss table that is 0 everywhere and no latency per metre: every draw the links
    make (latency, and the link's own 20 % loss through the same keyed uniform) is the one of
    the same run without ``mobility.links``."""
    n = 4
    sc = scenario(n, edges=[(0, 1), (1, 2), (2, 3)], protocol="flood", steps=30, seed=5, loss=0.2,
                  latency={"model": "uniform_steps", "d_t": 2})
    sc["mobility"] = {"vehicles": {i: {"kind": "constant_velocity", "start": [5.0 * i, 0.0]} for i in range(n)},
                      "range": {"model": "disk", "radius": 100.0}}
    zero = copy.deepcopy(sc)
    zero["mobility"]["links"] = {"loss": [[0.0, 0.0]]}
    a, b = run_scenario(zero), run_scenario(sc)
    assert set(a.arrays) == set(b.arrays)
    for key in a.arrays:
        assert np.array_equal(a.arrays[key], b.arrays[key], equal_nan=True), key
    assert a.counts == b.counts and a.counts["lost"] > 0


def test_latency_per_metre_enters_the_delay_bound():
    """``auto`` sizes the buffer with the latency at the range's radius: 0.1 s + 1 ms/m x 150 m
    = 0.25 s, 3 steps of 0.1 s (a fixed graph: d_t d_g + 1 = 3 x 1 + 1)."""
    from dkfsim.config.plan import RunPlan
    from dkfsim.config.schema import Scenario
    sc = scenario(2, edges=[(0, 1)], protocol="flood", steps=10, latency=steps_latency(1))
    sc["mobility"] = {"vehicles": {"default": {"kind": "constant_velocity"}},
                      "range": {"model": "disk", "radius": 150.0}, "links": {"latency_per_m": 0.001}}
    plan = RunPlan(Scenario.model_validate(sc))
    assert plan.latency_bound == 3 and plan.buffer_length() == 4


@pytest.mark.parametrize("d_t", [None, 2])
def test_a_latency_per_metre_beyond_the_clock_is_refused_naming_it(d_t):
    """1e9 s per metre at 150 m: beyond the int64 nanosecond clock.  With ``links.d_t`` given, the
    bound was not worked out from it, and the run raised OverflowError or read outside an array."""
    import dkfsim
    sc = scenario(2, edges=[(0, 1)], protocol="flood", steps=10, latency=steps_latency(1))
    if d_t is not None:
        sc["links"]["d_t"] = d_t
    sc["mobility"] = {"vehicles": {"default": {"kind": "constant_velocity"}},
                      "range": {"model": "disk", "radius": 150.0}, "links": {"latency_per_m": 1e9}}
    with pytest.raises(ScenarioError) as e:
        dkfsim.load_scenario(sc)
    assert "latency" in str(e.value) and e.value.path in ("mobility.links.latency_per_m", "links.d_t", "links")


@pytest.mark.parametrize("links, what", [({"loss": [[5.0, 0.1], [5.0, 0.2]]}, "strictly increase"),
                                         ({"loss": [[5.0, 1.5]]}, "mobility.links.loss"),
                                         ({"rate": []}, "at least one"),
                                         ({"lattency_per_m": 1.0}, "lattency_per_m")])
def test_bad_distance_tables_are_errors_naming_the_key(links, what):
    import dkfsim
    sc = scenario(2, edges=[(0, 1)], protocol="flood", steps=10)
    sc["mobility"] = {"vehicles": {"default": {"kind": "constant_velocity"}},
                      "range": {"model": "disk", "radius": 150.0}, "links": links}
    with pytest.raises(ScenarioError) as e:
        dkfsim.load_scenario(sc)
    assert "mobility.links" in str(e.value) and what in str(e.value)


def test_speed_evaluates_every_trajectory_at_factor_times_t():
    """``speed: 2`` on waypoints equals the same waypoints at half the times, and on a
    constant velocity equals twice the velocity."""
    pts = [[0.0, 0.0, 0.0], [1.0, 10.0, 0.0], [3.0, 10.0, 40.0]]
    half = [[t / 2, x, y] for t, x, y in pts]
    fast = Mobility.model_validate({"vehicles": {"0": {"kind": "waypoints", "points": pts},
                                                 "1": {"kind": "constant_velocity", "velocity": [3.0, -1.0]}},
                                    "range": {"model": "disk", "radius": 1.0}, "speed": 2.0})
    ref = Mobility.model_validate({"vehicles": {"0": {"kind": "waypoints", "points": half},
                                                "1": {"kind": "constant_velocity", "velocity": [6.0, -2.0]}},
                                   "range": {"model": "disk", "radius": 1.0}})
    assert np.allclose(fast.positions(2, 40, 0.05), ref.positions(2, 40, 0.05), rtol=0, atol=1e-12)
    assert not np.allclose(fast.positions(2, 40, 0.05), Mobility.model_validate(
        {**ref.model_dump(), "vehicles": {"0": {"kind": "waypoints", "points": pts},
                                          "1": {"kind": "constant_velocity", "velocity": [3.0, -1.0]}}}
    ).positions(2, 40, 0.05))


# ================================================================= cellular_sinr with sinr: track

SINR_TRACK = "t x y sinr\n0 0 0 3\n1 0 0 12\n2 0 0 20\n"


@pytest.mark.parametrize("speed", [1.0, 2.0])
def test_cellular_sinr_track_draws_at_the_senders_recorded_sinr(tmp_path, speed):
    """Decision 181: a packet sent at run time t on a ``sinr: track`` link takes the latency the
    constant-SINR model draws (same link key, instant and seq) at the SINR the sender's track
    recorded at drive time speed x t: 3, 12 and 20 dB, one per bin of the fit."""
    from dkfsim.components.latency import CellularSinr
    path = tmp_path / "drive.txt"
    path.write_text(SINR_TRACK)
    track = {"kind": "track", "file": str(path), "time_column": "t", "time_unit": "s",
             "x_column": "x", "y_column": "y", "sinr_column": "sinr"}
    mob = Mobility.model_validate({"vehicles": {"default": track}, "range": {"model": "disk", "radius": 5.0},
                                   "speed": speed})
    T_ns = 100_000_000
    env = simpy.Environment()
    sched = LinkSchedule(np.ones((40, 1), dtype=bool), [(0, 1)])
    sched.sinr[0] = mob.sinr_at(0)
    model = CellularSinr(sinr="track", one_way=True)
    net = Network(env, [(0, 1)], lambda u, v: LinkSpec(latency=model), 7, T_ns, schedule=sched)
    got = []
    port = net.port("p", lambda link, payload: got.append((env.now, payload)), until=10**12)
    sends = [0, 500_000_000, 1_200_000_000, 2_500_000_000]
    for t in sends:
        if t > env.now:
            env.run(until=t)
        port.send(net.link(0, 1), t)
    env.run(until=10**12)
    recorded = {0: 3.0, 500_000_000: 3.0 if speed == 1 else 12.0, 1_200_000_000: 12.0 if speed == 1 else 20.0,
                2_500_000_000: 20.0}
    want = []
    for t in sends:
        fixed = CellularSinr(sinr=recorded[t], one_way=True).sampler(("link", 0, 1), 7, T_ns)
        want.append((t + fixed.draw(t, 0)[0], t))
    assert sorted(got) == sorted(want)
    assert len({lat - t for lat, t in want}) == 4


def test_cellular_sinr_track_needs_a_track_sender():
    import dkfsim
    sc = scenario(2, edges=[(0, 1)], protocol="flood", steps=10)
    sc["links"]["default"]["latency"] = {"model": "cellular_sinr", "sinr": "track"}
    with pytest.raises(ScenarioError) as e:
        dkfsim.load_scenario(sc)
    assert "links.default.latency.sinr" in str(e.value) and "mobility" in str(e.value)
    sc["mobility"] = {"vehicles": {"default": {"kind": "constant_velocity"}},
                      "range": {"model": "disk", "radius": 150.0}}
    with pytest.raises(ScenarioError) as e:
        dkfsim.load_scenario(sc)
    assert "node 0" in str(e.value) and "not a 'track' vehicle" in str(e.value)


def test_cellular_sinr_track_error_names_the_override_that_gives_it(tmp_path, capsys):
    """Link 0 - 1 takes its latency from its override (a link has one, issue 30 §7), written the
    other way round on an undirected topology: the refusal names it; an override that gives no
    latency leaves the default's in force."""
    import yaml

    import dkfsim
    from dkfsim.cli.main import main
    track = {"model": "cellular_sinr", "sinr": "track"}
    sc = scenario(3, edges=[(0, 1), (1, 2)], protocol="flood", steps=10)
    sc["links"]["overrides"] = [{"link": [1, 2], "loss": 0.1}, {"link": [1, 0], "latency": track}]
    path = tmp_path / "override.yaml"
    path.write_text(yaml.safe_dump(sc))
    assert main(["validate", str(path)]) == 2
    err = capsys.readouterr().err
    assert "override.yaml" in err and "links.overrides.1.latency.sinr" in err and "mobility" in err
    # an override without a latency: the default's (constant) is in force, nothing to refuse
    sc["links"]["overrides"][1] = {"link": [1, 0], "loss": 0.1}
    assert dkfsim.load_scenario(sc).link_spec(0, 1).latency.model == "constant"


def test_a_run_with_track_senders_draws_their_sinr(tmp_path):
    """The plan hands every ``track`` vehicle's SINR to its links: a run completes with every
    packet delivered, its delay bound from the slowest bin of the fit."""
    import dkfsim
    from dkfsim.config.plan import RunPlan
    path = tmp_path / "drive.txt"
    path.write_text(SINR_TRACK)
    track = {"kind": "track", "file": str(path), "time_column": "t", "time_unit": "s",
             "x_column": "x", "y_column": "y", "sinr_column": "sinr"}
    sc = scenario(2, edges=[(0, 1)], protocol="flood", steps=30)
    sc["links"]["default"]["latency"] = {"model": "cellular_sinr", "sinr": "track", "one_way": True}
    sc["mobility"] = {"vehicles": {"0": track, "1": {**track, "offset": [1.0, 0.0]}},
                      "range": {"model": "disk", "radius": 5.0}}
    loaded = dkfsim.load_scenario(sc)
    assert sorted(RunPlan(loaded).link_schedule.sinr) == [0, 1]
    run = run_scenario(sc)
    assert run.counts["delivered"] + run.counts["in_flight"] == run.counts["sent"] > 0

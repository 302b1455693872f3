"""Vehicles that move (issue 23): links from positions, flood on a changing graph, the
finite-time result on time-varying graphs (docs/design.md §3 "Links that come and go", §6).

Trajectories here are ``waypoints`` with one point per tick, so a test states which links
are up at which tick as a boolean pattern and the vehicles' positions follow from it.  The
independent truths: the centralized Kalman filter (final rows under the B-tick condition),
earliest arrivals along time-respecting paths computed here from the pattern (the flood's
arrival log), and hand-worked ticks.
"""

from __future__ import annotations

import copy

import numpy as np
import pytest
import reference as ref
from conftest import run_scenario, scenario
from test_exactness import check_against_window_reference, check_common, expected_late

T = 0.1                 # the conftest model's period
RADIUS = 10.0
NEAR, FAR = 1.0, 1000.0
ZERO = {"model": "constant", "value": 0.0}


def steps_latency(d):
    return {"model": "constant", "value": d * T}


def waypoints(xy):
    """A trajectory through ``xy[k]`` at ``t_k`` (one point per tick)."""
    return {"kind": "waypoints", "points": [[k * T, float(x), float(y)] for k, (x, y) in enumerate(xy)]}


def star_mobility(n, up_with_hub):
    """Node 0 is a hub at the origin; node ``i`` sits NEAR it at tick ``k`` while
    ``up_with_hub(i, k)``, else FAR, each on its own ray (so leaves never meet)."""
    def traj(i, K):
        ang = 2 * np.pi * i / n
        return waypoints([(np.cos(ang) * (NEAR if up_with_hub(i, k) else FAR),
                           np.sin(ang) * (NEAR if up_with_hub(i, k) else FAR)) for k in range(K + 1)])
    return traj


def with_mobility(sc, trajectories):
    sc = copy.deepcopy(sc)
    sc["mobility"] = {"vehicles": dict(enumerate(trajectories)),
                      "range": {"model": "disk", "radius": RADIUS}}
    return sc


def earliest_arrivals(n, K, L, arcs, up, d):
    """``hold[i, o, r]``: the tick at which ``i`` first holds ``(o, r)`` under flood with a
    constant latency of ``d`` steps, by the rule of docs/design.md §5: a node sends a
    contribution on an arc at the first tick at or after it holds it at which the arc is up
    (its relay, or the link-up resend), only while the row is live (ticks up to ``r + L``),
    and the packet arrives ``d`` ticks later whatever the arc does meanwhile.  ``inf``: never."""
    hold = np.full((n, n, K), np.inf)
    for o in range(n):
        for r in range(K):
            h = np.full(n, np.inf)
            h[o] = r + 1
            for k in range(r + 1, min(r + L, K) + 1):
                changed = True
                while changed:                      # zero latency: relays chain within a tick
                    changed = False
                    for a, (u, v) in enumerate(arcs):
                        if h[u] <= k and up(a, k) and k + d < h[v]:
                            h[v] = k + d
                            changed = changed or d == 0
            hold[:, o, r] = np.where(h <= K, h, np.inf)
    return hold


def arrival_ticks(a):
    return np.round(a["arrival"] / T)


# ================================================================= the link schedule itself

def test_schedule_from_positions_is_the_disk_rule_per_tick():
    from dkfsim.components.mobility import DiskRange, LinkSchedule
    # two vehicles 8 m apart, then 12, then exactly 10 (in range: at most R), on arcs both ways
    pos = np.array([[[0, 0], [8, 0]], [[0, 0], [0, 12]], [[3, 4], [9, 12]]], dtype=float)
    s = LinkSchedule.from_positions(pos, [(0, 1), (1, 0)], DiskRange(radius=10))
    assert s.up.tolist() == [[True, True], [False, False], [True, True]]
    assert s.changes and s.came_up(2) == [0, 1] and s.came_up(1) == []


def test_connect_window_matches_brute_force():
    """B from the two-pointer search equals the definition checked interval by interval."""
    import networkx as nx

    from dkfsim.components.mobility import LinkSchedule
    rng = np.random.default_rng(5)
    n, K = 4, 40
    arcs = [(u, v) for u in range(n) for v in range(n) if u != v]
    for trial in range(10):
        p = rng.uniform(0.05, 0.3)
        und = rng.random((K + 1, n, n)) < p
        if trial % 2:                   # sticky: each pair keeps its state ~10 ticks (long segments)
            keep = rng.random((K + 1, n, n)) < 0.9
            for k in range(1, K + 1):
                und[k] = np.where(keep[k], und[k - 1], und[k])
        up = np.array([[und[k, min(u, v), max(u, v)] for (u, v) in arcs] for k in range(K + 1)])
        s = LinkSchedule(up, arcs)

        def connected(lo, hi, up=up):
            g = nx.DiGraph()
            g.add_nodes_from(range(n))
            g.add_edges_from(arcs[a] for a in range(len(arcs)) if up[lo:hi + 1, a].any())
            return nx.is_strongly_connected(g)

        brute = next((B for B in range(1, K + 1)
                      if all(connected(s0, s0 + B - 1) for s0 in range(1, K - B + 2))), None)
        assert s.connect_window(n) == brute, (trial, s.connect_window(n), brute)


# ================================================================= item 1: far inside range

#: What a run with ``mobility:`` keeps beside the arrays of every run (decision 187).
MOBILITY_ARRAYS = {"positions", "links_up", "mobility_links"}


def _same_run(a, b):
    assert set(a.arrays) == set(b.arrays) | MOBILITY_ARRAYS
    for key in b.arrays:
        assert np.array_equal(a.arrays[key], b.arrays[key], equal_nan=True), key
    ca = {k: v for k, v in a.counts.items() if k != "range_lost"}
    cb = {k: v for k, v in b.counts.items()}
    ca["per_link"] = [{k: v for k, v in row.items() if k != "range_lost"} for row in ca["per_link"]]
    assert ca == cb


@pytest.mark.parametrize("protocol", ["tree", "flood"])
def test_formation_far_inside_range_is_bit_identical_to_the_fixed_graph(protocol):
    """Vehicles in a convoy 5 m apart with a 1 km range: every link is up at every tick, so
    the run equals the one without ``mobility:`` bit for bit (estimates and counts), with a
    random latency and loss so that every draw is exercised."""
    n = 5
    edges = [(0, 1), (1, 2), (1, 3), (3, 4)]
    sc = scenario(n, edges=edges, protocol=protocol, steps=40, seed=3, loss=0.2,
                  latency={"model": "uniform_steps", "d_t": 2})
    moving = copy.deepcopy(sc)
    moving["mobility"] = {"vehicles": {i: {"kind": "constant_velocity", "start": [5.0 * i, 0.0],
                                           "velocity": [20.0, 1.0]} for i in range(n)},
                          "range": {"model": "disk", "radius": 1000.0}}
    a, b = run_scenario(moving), run_scenario(sc)
    assert a.counts["range_lost"] == 0
    _same_run(a, b)


# ================================================================= the network

def test_a_packet_in_flight_when_the_link_goes_down_is_delivered():
    """Decision 171: the link's state at the send instant decides; a packet already in the
    air arrives.  Two vehicles in range for ticks 0..10, a constant latency of 3 steps:
    flood sends each tick's contribution both ways at ticks 1..10 (20 packets), all
    delivered, the last ones at ticks 11..13 after the link went down."""
    K = 30
    xs = [(0.0 if k <= 10 else 500.0, 0.0) for k in range(K + 1)]
    sc = with_mobility(scenario(2, edges=[(0, 1)], protocol="flood", steps=K, buffer_length=8,
                                latency=steps_latency(3)),
                       [{"kind": "constant_velocity", "start": [5.0, 0.0]}, waypoints(xs)])
    run = run_scenario(sc)
    c = run.counts
    assert (c["sent"], c["delivered"], c["lost"], c["range_lost"], c["in_flight"]) == (20, 20, 0, 0, 0), c
    ticks = arrival_ticks(run.arrays)
    assert ticks[1, 0, 9] == 13 and ticks[0, 1, 9] == 13      # sent at tick 10, the last up tick
    assert np.isinf(ticks[1, 0, 10:]).all()


def test_the_network_loses_what_is_handed_to_a_link_that_is_down():
    """Any protocol's packet on a down link is lost (range_lost, part of lost) and the
    identity sent + copies = delivered + lost + queue_dropped + crash_dropped + in_flight
    holds; the same packet on an up link is delivered."""
    import simpy

    from dkfsim.components.faults import LinkSpec
    from dkfsim.components.latency import Constant
    from dkfsim.components.mobility import LinkSchedule
    from dkfsim.network.network import Network
    env = simpy.Environment()
    up = np.array([[True, True], [True, False], [False, True]])     # ticks 0, 1, 2
    net = Network(env, [(0, 1), (1, 0)], lambda u, v: LinkSpec(latency=Constant(value=0.0)), 1, 100,
                  schedule=LinkSchedule(up, [(0, 1), (1, 0)]))
    got = []
    port = net.port("p", lambda link, payload: got.append((link.src, payload)))

    def at(t):
        env.run(until=t)
        port.send(net.link(0, 1), "a")
        port.send(net.link(1, 0), "b")
    at(150)              # tick 1: 0->1 up, 1->0 down
    at(250)              # tick 2: the other way round
    env.run(until=1000)
    c = port.counts()
    assert sorted(got) == [(0, "a"), (1, "b")]
    assert (c["sent"], c["delivered"], c["lost"], c["range_lost"], c["in_flight"]) == (4, 2, 2, 2, 0)
    assert c["sent"] + c["copies"] == (c["delivered"] + c["lost"] + c["queue_dropped"] + c["crash_dropped"]
                                       + c["in_flight"])


# ================================================================= item 2: flood

@pytest.mark.parametrize("protocol", ["flood", "tree"])
@pytest.mark.parametrize("L", [5, 15])
def test_a_vehicle_that_leaves_range_stops_receiving_and_catches_up_on_return(L, protocol):
    """Hand-worked: vehicle 1 is in range of vehicle 0 at ticks 0..9 and 20..30, away at
    ticks 10..19; zero latency.  Rows 0..8 arrive at their own tick; rows 9..18 (ticks
    10..19) arrive at tick 20 by the link-up resend (flood) or the rebuilt tree's first
    packets (tree) when still in the window there (r + L >= 20), else never; later rows at
    their own tick.  Nothing is sent while away."""
    K = 30
    xs = [(5.0 if (k < 10 or k >= 20) else 500.0, 0.0) for k in range(K + 1)]
    sc = with_mobility(scenario(2, edges=[(0, 1)], protocol=protocol, steps=K, buffer_length=L, latency=ZERO),
                       [{"kind": "constant_velocity"}, waypoints(xs)])
    run = run_scenario(sc)
    ticks = arrival_ticks(run.arrays)
    expect = np.array([r + 1 if r < 9 or r >= 19 else (20 if r + L >= 20 else np.inf) for r in range(K)])
    for i, o in ((1, 0), (0, 1)):
        assert np.array_equal(ticks[i, o], expect), (i, o, ticks[i, o], expect)
    assert run.counts["range_lost"] == 0
    assert run.counts["late"] == 0
    check_against_window_reference(run)


def path_positions(pattern):
    """x of the nodes of a path per tick, ``(n, K + 1)``: the gap between nodes ``e`` and
    ``e + 1`` is 5 m (in range) at the ticks where ``pattern[e]`` holds, else 1 km (only
    the path's pairs are links, so other pairs in range do not matter)."""
    gaps = np.where(pattern, 5.0, FAR)
    return np.concatenate([np.zeros((1, pattern.shape[1])), np.cumsum(gaps, axis=0)])


def path3_schedule(K, bc, ab):
    """A - B - C on a line, B fixed at the origin; C NEAR B at ticks with ``bc(k)``, A NEAR
    at ticks with ``ab(k)``, on opposite sides (A and C never within range of each other)."""
    a = [(-(NEAR if ab(k) else FAR), 0.0) for k in range(K + 1)]
    c = [((NEAR if bc(k) else FAR), 0.0) for k in range(K + 1)]
    return [waypoints(a), {"kind": "constant_velocity"}, waypoints(c)]


def test_union_connected_without_a_time_respecting_path_is_late():
    """The counterexample of docs/design.md §6: B-C up at ticks 0-5 of every 20, A-B at
    ticks 5-10.  The union over any 20 ticks is connected, yet a contribution from A reaches
    C only when B-C comes up again, up to 20 ticks later: with L = 12 and one step of latency
    some never reach C in time, and those sent at their row's last tick arrive late.  The
    arrival log equals the earliest time-respecting arrivals computed here, and ``late``
    equals the count of contributions that arrived after their row became final."""
    K, L = 80, 12
    bc = lambda k: k % 20 <= 5          # noqa: E731
    ab = lambda k: 5 <= k % 20 <= 10    # noqa: E731
    sc = with_mobility(scenario(3, edges=[(0, 1), (1, 2)], protocol="flood", steps=K, buffer_length=L,
                                latency=steps_latency(1)), path3_schedule(K, bc, ab))
    run = run_scenario(sc)
    arcs = [(0, 1), (1, 0), (1, 2), (2, 1)]
    up = lambda a, k: ab(k) if a < 2 else bc(k)     # noqa: E731
    expect = earliest_arrivals(3, K, L, arcs, up, 1)
    t_final = np.arange(K) + L
    assert (expect[2, 0] > t_final).sum() > 10          # A's rows that C does not hold when final
    ticks = arrival_ticks(run.arrays)
    assert np.array_equal(ticks, expect), np.argwhere(ticks != expect)[:5]
    late = expected_late(run.arrays)
    assert late > 0
    assert run.counts["late"] == late
    check_against_window_reference(run)


@pytest.mark.parametrize("d", [0, 2])
def test_flood_arrivals_follow_time_respecting_paths(d):
    """Random link patterns on a 5-node path (each edge up at a tick with probability 0.4),
    constant latency of d steps, L = 12: every entry of the arrival log (late ones included)
    is the earliest time-respecting arrival computed here."""
    n, K, L = 5, 50, 12
    edges = [(i, i + 1) for i in range(n - 1)]
    rng = np.random.default_rng(7 + d)
    pattern = rng.random((len(edges), K + 1)) < 0.4
    xs = path_positions(pattern)
    trajs = [waypoints([(xs[i, k], 0.0) for k in range(K + 1)]) for i in range(n)]
    sc = with_mobility(scenario(n, edges=edges, protocol="flood", steps=K, buffer_length=L,
                                latency=steps_latency(d)), trajs)
    run = run_scenario(sc)
    arcs = sorted([(u, v) for u, v in edges] + [(v, u) for u, v in edges])
    up = lambda a, k: pattern[min(arcs[a]), k]     # noqa: E731
    expect = earliest_arrivals(n, K, L, arcs, up, d)
    ticks = arrival_ticks(run.arrays)
    assert np.array_equal(ticks, expect), np.argwhere(ticks != expect)[:5]
    assert run.counts["late"] == expected_late(run.arrays)
    check_against_window_reference(run)


def _b_condition_trajectories(n, K, B):
    """A path of n nodes on a line whose edge ``e`` is up only at ticks ``k`` with
    ``(k + e) % B == 0``: every B consecutive ticks hold each edge once (the union is the
    path, connected), and no two edges are up at one tick when ``B >= n``."""
    pattern = np.array([[(k + e) % B == 0 for k in range(K + 1)] for e in range(n - 1)])
    xs = path_positions(pattern)
    return [waypoints([(xs[i, k], 0.0) for k in range(K + 1)]) for i in range(n)], pattern


@pytest.mark.parametrize("d_t", [0, 1, 2])
def test_finite_time_on_a_changing_graph_final_rows_are_centralized(d_t):
    """The restated theorem (docs/design.md §6, "Time-varying graphs"): every interval of B
    ticks has a connected union, per-hop latency at most d_t steps (random, uniform_steps),
    ``buffer_length: auto`` = (n - 1)(B + d_t) + 1 -> nothing late and every final row
    equals the centralized filter (1e-9)."""
    n, K, B = 4, 90, 5
    trajs, pattern = _b_condition_trajectories(n, K, B)
    latency = {"model": "uniform_steps", "d_t": d_t} if d_t else ZERO
    sc = with_mobility(scenario(n, edges=[(i, i + 1) for i in range(n - 1)], protocol="flood", steps=K,
                                seed=4 + d_t, latency=latency), trajs)
    run = run_scenario(sc)
    a = run.arrays
    L = int(a["buffer_length"])
    assert L == (n - 1) * (B + d_t) + 1
    xs, _ = check_common(run)
    assert run.counts["late"] == 0 and expected_late(a) == 0
    nfinal = K - L + 1
    assert nfinal >= 40
    for i in range(n):
        ref.assert_close(a["x_final"][:nfinal, i], xs[:nfinal], f"x_final node {i} vs centralized", 1e-9)
    # the links did come and go: most of the time a node misses something at its own tick
    assert not np.allclose(a["x_local"][:, 0], xs, rtol=0, atol=1e-6)
    check_against_window_reference(run)


# ================================================================= validation

def _error(sc):
    import dkfsim
    from dkfsim.core.errors import ScenarioError
    with pytest.raises(ScenarioError) as err:
        dkfsim.load_scenario(sc)
    return str(err.value)


def test_bad_mobility_is_an_error_naming_the_key():
    base = scenario(3, edges=[(0, 1), (1, 2)], protocol="flood", steps=20)
    sc = with_mobility(base, [{"kind": "constant_velocity"}] * 2)
    assert "mobility.vehicles" in (msg := _error(sc)) and "node 2 has no trajectory" in msg
    sc = copy.deepcopy(base)
    sc["mobility"] = {"vehicles": {"default": {"kind": "constant_velocity"}, 7: {"kind": "constant_velocity"}},
                      "range": {"model": "disk", "radius": 5}}
    assert "mobility.vehicles.7" in (msg := _error(sc)) and "out of range" in msg
    sc["mobility"] = {"vehicles": {"lead": {"kind": "constant_velocity"}}, "range": {"model": "disk", "radius": 5}}
    assert "node number or 'default'" in _error(sc)
    sc["mobility"] = {"vehicles": {"default": {"kind": "constant_velocity"}}, "range": {"model": "disk"}}
    assert "mobility.range.radius" in _error(sc)


def test_auto_without_a_window_b_is_refused():
    """Node 2 never comes within range: no interval of ticks has a connected union."""
    base = scenario(3, edges=[(0, 1), (1, 2)], protocol="flood", steps=20)
    sc = with_mobility(base, [{"kind": "constant_velocity"}, {"kind": "constant_velocity", "start": [1, 0]},
                              {"kind": "constant_velocity", "start": [0, 500]}])
    msg = _error(sc)
    assert "buffer_length" in msg and "no B exists" in msg
    sc["buffer_length"] = 4
    import dkfsim
    dkfsim.load_scenario(sc)      # an integer buffer is accepted


# ================================================================= item 3: the consensus filters

CONSENSUS = [{"kind": "ci_consensus", "rounds": 4}, {"kind": "kcf"}, {"kind": "icf", "rounds": 2},
             {"kind": "diffusion_kf"}, {"kind": "hcmci", "rounds": 2}]


def test_consensus_filters_use_the_current_neighbours():
    """A star (hub 0); vehicle 3 is out of range at ticks 20..39.  Hand-worked:

    - nothing is sent on its two arcs then (each filter sends 2 x slots x 20 packets fewer
      than on the fixed star, and loses none to range);
    - alone, ci_consensus's node 3 is its own information filter, continued from its row-18
      estimate (the rounds mix with nobody): equal to 1e-9 for rows 19..38;
    - after its return every filter's node 3 catches up: its distance to the fixed star's
      estimate shrinks by more than 1000x between the last isolated row and the last row;
    - before tick 20 every estimate is bit for bit the fixed star's;
    - the three others form a 3-node star meanwhile, with the weights of its degrees: the
      covariances of ci_consensus and hcmci (which do not depend on the data) approach those
      of a run on that fixed 3-node star (1e-3 relative after 19 ticks; the weights of the
      4-node star would leave them 25% and 0.7% away)."""
    K, n = 100, 4
    sc = scenario(n, edges=[(0, 1), (0, 2), (0, 3)], protocol="flood", steps=K, buffer_length=3)
    sc.pop("baselines")
    sc["estimators"] = copy.deepcopy(CONSENSUS)
    away = [20 <= k < 40 for k in range(K + 1)]
    trajs = [{"kind": "constant_velocity"}, {"kind": "constant_velocity", "start": [1, 0]},
             {"kind": "constant_velocity", "start": [0, 1]},
             waypoints([(500.0 if a else -1.0, 0.0) for a in away])]
    mob, fix = run_scenario(with_mobility(sc, trajs)), run_scenario(sc)
    for e in CONSENSUS:
        name = e["kind"]
        tm, tf = mob.res.traffic[name], fix.res.traffic[name]
        slots = mob.res.facts[name].get("slots", e.get("rounds"))
        assert tm["range_lost"] == 0 and tf["sent"] - tm["sent"] == 2 * slots * 20, (name, tm, tf)
        xm, xf = mob[f"x_{name}"], fix[f"x_{name}"]
        assert np.array_equal(xm[:19], xf[:19]), name
        gap = np.abs(xm[:, 3] - xf[:, 3]).max(axis=1)
        assert gap[38] > 1e-2 and gap[K - 1] < 1e-3 * gap[38], (name, gap[38], gap[K - 1])
    sc3 = scenario(3, edges=[(0, 1), (0, 2)], protocol="flood", steps=K, buffer_length=3)
    sc3.pop("baselines")
    sc3["estimators"] = copy.deepcopy(CONSENSUS)
    three = run_scenario(sc3)
    for name in ("ci_consensus", "hcmci"):
        P3 = three[f"P_{name}"][38]
        assert np.abs(mob[f"P_{name}"][38, :3] - P3).max() < 1e-3 * np.abs(P3).max(), name
    # ci_consensus alone: the local information filter of node 3
    a = mob.arrays
    Phi, Q, H, R, y = a["Phi"], a["Q"], a["H_3"], a["R_3"], a["y_3"]
    x, P = a["x_ci_consensus"][18, 3], a["P_ci_consensus"][18, 3]
    info = H.T @ np.linalg.solve(R, H)
    for r in range(19, 39):
        Pp, xp = Phi @ P @ Phi.T + Q, Phi @ x
        Om = np.linalg.inv(Pp) + info
        P = np.linalg.inv(Om)
        x = P @ (np.linalg.solve(Pp, xp) + H.T @ np.linalg.solve(R, y[r]))
        ref.assert_close(a["x_ci_consensus"][r, 3][None], x[None], f"ci_consensus node 3 row {r}", 1e-9)
        ref.assert_close(a["P_ci_consensus"][r, 3][None], P[None], f"ci_consensus P node 3 row {r}", 1e-9)


# ================================================================= item 4: tree

def _switch_trajectories(K, at):
    """Nodes 0, 1, 2 at x = 0, 8, 16 (radius 10: the path 0-1-2); node 3 at x = -8 (next to
    0) before tick ``at`` and at x = 24 (next to 2) from it: the graph is the path 3-0-1-2,
    then 0-1-2-3."""
    fixed = [{"kind": "constant_velocity", "start": [8.0 * i, 0.0]} for i in range(3)]
    return fixed + [waypoints([(-8.0 if k < at else 24.0, 0.0) for k in range(K + 1)])]


def test_a_rebuilt_tree_carries_its_first_packets_on_the_new_tree():
    """Hand-worked: every pair a link (complete topology, ``spanning_tree: true``), the
    graph of the links in range is a path, so each tick's tree is that path.  With one step
    of latency per hop: from tick 10 on nothing is sent between 0 and 3, the new arc 2-3
    carries packets from tick 10 on (the rebuild's resend), every arrival is the earliest
    along the tree of its tick (computed here), and the estimates follow the arrival log."""
    K, L, at = 40, 8, 10
    sc = scenario(4, edges=[(u, v) for u in range(4) for v in range(u + 1, 4)], protocol="tree", steps=K,
                  buffer_length=L, latency=steps_latency(1))
    sc["spanning_tree"] = True
    run = run_scenario(with_mobility(sc, _switch_trajectories(K, at)))
    per = {tuple(r["link"]): r for r in run.counts["per_link"]}
    # 0 <-> 3 only before tick 10 (one packet per tick with news: ticks 1..9 each way at most)
    assert 0 < per[(3, 0)]["sent"] <= at - 1 and 0 < per[(0, 3)]["sent"] <= at - 1
    assert per[(2, 3)]["sent"] >= K - at and per[(3, 2)]["sent"] >= K - at
    for arc in ((0, 2), (2, 0), (1, 3), (3, 1)):      # never in range: never used
        assert arc not in per or per[arc]["sent"] == 0
    assert run.counts["range_lost"] == 0
    path_before = {(3, 0), (0, 3), (0, 1), (1, 0), (1, 2), (2, 1)}
    path_after = {(0, 1), (1, 0), (1, 2), (2, 1), (2, 3), (3, 2)}
    arcs = sorted(path_before | path_after)
    up = lambda a, k: arcs[a] in (path_before if k < at else path_after)    # noqa: E731
    expect = earliest_arrivals(4, K, L, arcs, up, 1)
    ticks = arrival_ticks(run.arrays)
    assert np.array_equal(ticks, expect), np.argwhere(ticks != expect)[:5]
    assert ticks[2, 3, at] == at + 2 and ticks[0, 3, at] == at + 4     # row of tick 11: 1 and 3 hops
    assert ticks[0, 3, at - 3] == at - 1 and ticks[2, 3, at - 3] == at + 1   # tick 8's: the old tree
    check_against_window_reference(run)


def test_paper_weights_are_refused_on_a_changing_graph():
    sc = scenario(4, edges=[(u, v) for u in range(4) for v in range(u + 1, 4)], protocol="tree", steps=20,
                  weights="paper", buffer_length=4)
    sc["spanning_tree"] = True
    msg = _error(with_mobility(sc, _switch_trajectories(20, 10)))
    assert "weights" in msg and "changes" in msg


# ================================================================= a SUMO FCD file

FCD = """<?xml version="1.0" encoding="UTF-8"?>
<fcd-export>
  <timestep time="0.00">
    <vehicle id="a" x="0.00" y="0.00" speed="0.00" angle="90.00"/>
    <vehicle id="b" x="5.00" y="0.00" speed="0.00" angle="90.00"/>
    <vehicle id="c" x="100.00" y="0.00" speed="90.00" angle="270.00"/>
  </timestep>
  <timestep time="1.00">
    <vehicle id="a" x="0.00" y="0.00" speed="0.00" angle="90.00"/>
    <vehicle id="b" x="5.00" y="0.00" speed="20.00" angle="90.00"/>
    <vehicle id="c" x="10.00" y="0.00" speed="0.00" angle="270.00"/>
  </timestep>
  <timestep time="2.00">
    <vehicle id="a" x="0.00" y="0.00" speed="0.00" angle="90.00"/>
    <vehicle id="b" x="25.00" y="0.00" speed="0.00" angle="90.00"/>
    <vehicle id="c" x="10.00" y="0.00" speed="0.00" angle="270.00"/>
  </timestep>
</fcd-export>
"""


def test_a_sumo_fcd_file_gives_the_expected_positions_and_links(tmp_path):
    """Hand-worked from the file (radius 10 m, ticks of 0.1 s, every pair a link): c comes
    from x = 100 to 10 over the first second, b leaves from 5 to 25 over the next.  So a-b is
    up at ticks 0..12 (|x_b| <= 10 until t = 1.25), b-c at ticks 10..17 (from t = 0.944 to
    1.75), a-c from tick 10 on (x_c = 10 exactly at t = 1); flood's arrivals follow."""
    import dkfsim
    from dkfsim.config.plan import RunPlan
    fcd = tmp_path / "fcd.xml"
    fcd.write_text(FCD)
    K = 20
    sc = scenario(3, protocol="flood", steps=K, buffer_length=6, latency=steps_latency(1))
    del sc["topology"]                                   # mobility: every pair by default
    sc["mobility"] = {"vehicles": {i: {"kind": "sumo_fcd", "file": str(fcd), "vehicle": v}
                                   for i, v in enumerate("abc")},
                      "range": {"model": "disk", "radius": RADIUS}}
    plan = RunPlan(dkfsim.load_scenario(copy.deepcopy(sc)))
    pos = plan.scenario.mobility.positions(3, K, T)
    assert np.allclose(pos[10], [[0, 0], [5, 0], [10, 0]]) and np.allclose(pos[15], [[0, 0], [15, 0], [10, 0]])
    assert np.allclose(pos[5, 2], [55, 0])
    expect_pair = {(0, 1): lambda k: k <= 12, (1, 2): lambda k: 10 <= k <= 17, (0, 2): lambda k: k >= 10}
    arcs = plan.arcs
    assert arcs == [(0, 1), (0, 2), (1, 0), (1, 2), (2, 0), (2, 1)]
    up = lambda a, k: expect_pair[tuple(sorted(arcs[a]))](k)       # noqa: E731
    for a in range(len(arcs)):
        assert plan.link_schedule.up[:, a].tolist() == [up(a, k) for k in range(K + 1)], arcs[a]
    run = run_scenario(sc)
    ticks = arrival_ticks(run.arrays)
    assert np.array_equal(ticks, earliest_arrivals(3, K, 6, arcs, up, 1))


# ================================================================= the shipped scenarios

def _shipped(name, steps=200):
    """A shipped scenario at ``steps`` ticks, its plan, and its run with the arrival log."""
    from conftest import Run

    import dkfsim
    from dkfsim.config.plan import RunPlan
    sc = dkfsim.load_scenario(f"scenarios/{name}.yaml", overrides=[f"steps={steps}"])
    plan = RunPlan(sc)
    assert plan.graph_changes, f"{name}: no link changes in {steps} steps"
    return sc, plan, Run(dkfsim.run(sc, save="full"), {})


def test_shipped_convoy_meets_the_finite_time_bound_on_a_real_drive():
    """The convoy on the recorded arterial drive: the links come and go (cars two apart are
    in range only when the convoy is slow), each tick's graph is connected (B = 1), and with
    ``auto`` every final row equals the centralized filter and nothing is late."""
    sc, plan, run = _shipped("mobility_convoy")
    assert plan.connect_window == 1
    a = run.arrays
    L = int(a["buffer_length"])
    assert L == (sc.n - 1) * (1 + 2) + 1
    assert run.counts["late"] == 0 and run.counts["late_unit"] == "contributions"
    xs, _ = ref.centralized(a)
    for i in range(sc.n):
        ref.assert_close(a["x_final"][:200 - L + 1, i], xs[:200 - L + 1], f"x_final car {i}", 1e-9)
    check_against_window_reference(run)


@pytest.mark.parametrize("name, groups", [("mobility_crossing", ([0, 1, 2], [3, 4, 5])),
                                          ("mobility_platoon", ([0, 1, 2], [3, 4, 5]))])
def test_shipped_groups_share_nothing_while_apart(name, groups):
    """Crossing groups and a splitting platoon: no contribution of one group reaches the
    other before the first tick a link between them is up (from the schedule), yet some do
    afterwards; the estimates follow the arrival log (the oracle of docs/design.md §6)."""
    sc, plan, run = _shipped(name)
    a, b = groups
    arcs = plan.arcs
    cross = [i for i, (u, v) in enumerate(arcs) if (u in a) != (v in a)]
    up = plan.link_schedule.up
    meet = int(np.flatnonzero(up[:, cross].any(axis=1))[0])
    if name == "mobility_platoon":            # together at the start: find when they are apart
        apart = int(np.flatnonzero(~up[:, cross].any(axis=1))[0])
        back = apart + int(np.flatnonzero(up[apart:, cross].any(axis=1))[0])
        first, meet = apart, back
    else:
        first = 1
    ticks = arrival_ticks(run.arrays)
    for i in a:
        for o in b:
            for i_, o_ in ((i, o), (o, i)):
                rows = np.arange(first, meet - 1)          # rows whose tick is in [first + 1, meet)
                assert (ticks[i_, o_, rows] >= meet).all(), (name, i_, o_)
    assert np.isfinite(ticks[a[0], b[0], meet:]).any()
    check_against_window_reference(run)


def test_spanning_forest_is_the_bfs_spanning_tree_of_each_component():
    """The per-tick forest (plain Python) equals networkx's rule of ``spanning_tree`` (the
    lowest-index centre as root, neighbours in increasing order) on every component."""
    import networkx as nx

    from dkfsim.components.topology import bfs_spanning_forest, bfs_spanning_tree
    rng = np.random.default_rng(11)
    for trial in range(60):
        n = int(rng.integers(1, 14))
        g = nx.gnp_random_graph(n, float(rng.uniform(0.05, 0.6)), seed=int(rng.integers(1 << 30)))
        expect = set()
        for comp in nx.connected_components(g):
            if len(comp) > 1:
                sub = nx.relabel_nodes(g.subgraph(comp), {v: v for v in comp})
                expect |= {tuple(sorted(e)) for e in bfs_spanning_tree(sub).edges()}
        got = {tuple(sorted(e)) for e in bfs_spanning_forest(n, list(g.edges()))}
        assert got == expect, (trial, n, sorted(g.edges()))


@pytest.mark.parametrize("protocol", ["flood", "tree"])
def test_a_node_that_is_down_when_its_link_returns_resends_nothing(protocol):
    """Hand-worked: vehicle 1 is away at ticks 10..19 and down (crash window [1.5 s, 2.5 s),
    ticks 15..24) when its link returns at tick 20.  It resends nothing then, so its rows of
    ticks 10..14 never reach node 0; node 0's resend reaches a node that is down
    (crash_dropped); from tick 25 both exchange as before."""
    K, L = 40, 15
    xs = [(5.0 if (k < 10 or k >= 20) else 500.0, 0.0) for k in range(K + 1)]
    sc = with_mobility(scenario(2, edges=[(0, 1)], protocol=protocol, steps=K, buffer_length=L, latency=ZERO),
                       [{"kind": "constant_velocity"}, waypoints(xs)])
    sc["faults"] = {"crashes": [{"node": 1, "start": 1.5, "end": 2.5}]}
    run = run_scenario(sc)
    ticks = arrival_ticks(run.arrays)
    assert np.isinf(ticks[0, 1, 9:24]).all()          # ticks 10..14 held by 1, never sent; 15..24 down
    assert np.isinf(ticks[1, 0, 9:24]).all()
    assert run.counts["crash_dropped"] > 0
    assert np.array_equal(ticks[0, 1, 24:], np.arange(25, K + 1)) and np.array_equal(ticks[1, 0, 24:],
                                                                                     np.arange(25, K + 1))
    check_against_window_reference(run)


@pytest.mark.slow
def test_the_mobility_tables_of_the_docs_are_what_the_code_gives():
    """docs/mobility.md's two tables (tools/docs_numbers.py generator ``mobility``, decision
    205) equal a fresh run of every shipped mobility scenario and of the range sweep."""
    import importlib.util
    import sys
    from pathlib import Path
    dn = sys.modules.get("docs_numbers")            # (tests/test_docs_numbers.py loads it too)
    if dn is None:
        path = Path(__file__).resolve().parents[1] / "tools" / "docs_numbers.py"
        spec = importlib.util.spec_from_file_location("docs_numbers", path)
        dn = importlib.util.module_from_spec(spec)
        sys.modules["docs_numbers"] = dn            # dataclasses look their module up by name
        spec.loader.exec_module(dn)
    found = dn.page_blocks()
    for name, text in dn.render_mobility().items():
        assert found[name], name
        for page, body in found[name]:
            assert body.rstrip("\n") == text.rstrip("\n"), (page.name, name)

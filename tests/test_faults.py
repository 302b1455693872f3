"""Link faults and sensor crashes (issue 4): hand-worked tiny runs, counting
identities, common random numbers, the exactness oracle, scenario validation.

The hand-worked runs use the 2-state model with T = 0.1 s and constant
latencies, so every packet's fate is known in advance: on a path with the
tree protocol each node sends exactly one packet per tick to a leaf
neighbour (its own new row), and an inner node also relays at ``t + latency``.
"""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pytest
import reference as ref
import simpy
from conftest import run_scenario, scc_digraph_edges, scenario, tree_edges

from dkfsim.components.faults import CrashSchedule, Faults, LinkSpec, ScaleSchedule, Windows
from dkfsim.components.latency import parse_latency
from dkfsim.config.load import load_scenario, scenario_hash
from dkfsim.config.plan import RunPlan
from dkfsim.core.errors import ScenarioError
from dkfsim.network.links import Link
from dkfsim.network.network import Network

TOL = 1e-9
T_NS = 100_000_000           # T = 0.1 s (conftest's 2-state model)
REPO = Path(__file__).resolve().parents[1]
CONST = {"model": "constant", "value": 0.05}


def t_s(ns: int, K: int | None = None) -> float:
    """A time in ns as the arrival log stores it (ns / 1e9); ``inf`` after the
    last tick ``K`` (the run ends at ``t_K``: the packet is still in flight)."""
    return np.inf if K is not None and ns > K * T_NS else ns / 1e9


def identity(counts) -> None:
    """sent + copies = delivered + lost + crash_dropped + in_flight, per link and in total."""
    keys = ("sent", "copies", "delivered", "lost", "crash_dropped", "in_flight", "outage_lost")
    for c in [counts] + list(counts["per_link"]):
        assert all(c[k] >= 0 for k in keys), c
        assert c["sent"] + c["copies"] == (c["delivered"] + c["lost"] + c["crash_dropped"]
                                           + c["in_flight"]), c
        assert c["outage_lost"] <= c["lost"]
    for k in keys:
        assert sum(e[k] for e in counts["per_link"]) == counts[k], k


def per_link(counts, u, v):
    (e,) = [e for e in counts["per_link"] if tuple(e["link"]) == (u, v)]
    return e


def check_oracle(run) -> None:
    est = ref.node_estimates(run.arrays)
    for key in ("x_local", "P_local", "x_final"):
        ref.assert_close(run[key], est[key], f"{key} vs the arrival-log reference", TOL)


# =========================================================================== schedules
def test_scale_schedule_steps_and_ramps():
    from dkfsim.components.faults import ScheduleRamp, ScheduleStep
    s = ScaleSchedule([ScheduleRamp(**{"from": 1.0, "to": 3.0, "start_factor": 1.0,
                                       "end_factor": 3.0}),
                       ScheduleStep(at=5.0, factor=0.5)])
    ns = 1_000_000_000
    assert s.factor(0) == 1.0 and s.factor(ns) == 1.0
    assert s.factor(2 * ns) == pytest.approx(2.0)
    assert s.factor(3 * ns) == 3.0 and s.factor(4 * ns) == 3.0
    assert s.factor(5 * ns - 1) == 3.0 and s.factor(5 * ns) == 0.5
    assert s.max_factor() == 3.0
    assert ScaleSchedule([ScheduleStep(at=0.0, factor=0.5)]).max_factor() == 0.5


def test_windows_are_half_open_and_merged():
    w = Windows([(0.3, 0.5), (0.45, 0.6), (1.0, 1.1)])
    assert w.starts == [300_000_000, 1_000_000_000] and w.ends == [600_000_000, 1_100_000_000]
    assert 300_000_000 in w and 599_999_999 in w and 600_000_000 not in w
    assert 299_999_999 not in w and 1_050_000_000 in w


@pytest.mark.parametrize("schedule, expect", [
    # step at 0.35 s: sends at t >= 0.35 take 3 x 0.05 s
    ([{"kind": "step", "at": 0.35, "factor": 3.0}], {0: 0.05, 1: 0.05, 2: 0.05, 3: 0.15, 7: 0.15}),
    # ramp 1 -> 3 on [0.25, 0.45]: t = 0.3 -> 1.5, 0.4 -> 2.5, then 3
    ([{"kind": "ramp", "from": 0.25, "to": 0.45, "start_factor": 1.0, "end_factor": 3.0}],
     {0: 0.05, 1: 0.05, 2: 0.075, 3: 0.125, 4: 0.15, 7: 0.15}),
])
def test_schedule_scales_the_latency_at_the_send_time(schedule, expect):
    sc = scenario(2, edges=[[0, 1]], latency=CONST, steps=10)
    sc["links"]["default"]["schedule"] = schedule
    loaded = load_scenario(sc)
    # auto: d_t = ceil(0.05 * 3 / 0.1) = 2 over the whole schedule, L = 2 * 1 + 1
    assert RunPlan(loaded).d_t == 2 and RunPlan(loaded).buffer_length() == 3
    run = run_scenario(sc)
    arr = run["arrival"]
    for r, lat in expect.items():
        sent_ns = (r + 1) * T_NS
        want = t_s(sent_ns + round(lat * 1e9), 10)
        assert arr[1, 0, r] == want and arr[0, 1, r] == want, (r, arr[1, 0, r], want)
    check_oracle(run)


def test_jitter_is_added_and_not_scaled_and_counts_in_the_bound():
    sc = scenario(2, edges=[[0, 1]], latency=CONST, steps=8)
    sc["links"]["default"]["jitter"] = {"model": "constant", "value": 0.02}
    sc["links"]["default"]["schedule"] = {"kind": "step", "at": 0.35, "factor": 2.0}
    loaded = load_scenario(sc)
    assert RunPlan(loaded).d_t == 2          # ceil((0.05 * 2 + 0.02) / 0.1)
    arr = run_scenario(sc)["arrival"]
    assert arr[1, 0, 2] == t_s(3 * T_NS + 70_000_000)     # sent 0.3: 0.05 + 0.02
    assert arr[1, 0, 3] == t_s(4 * T_NS + 120_000_000)    # sent 0.4: 2 x 0.05 + 0.02
    # an unbounded jitter needs a stated bound
    sc["links"]["default"]["jitter"] = {"model": "exponential", "mean": 0.01}
    with pytest.raises(ScenarioError, match=r"exponential \(jitter\) is unbounded"):
        load_scenario(sc)
    sc["links"]["d_t"] = 3
    assert RunPlan(load_scenario(sc)).buffer_length() == 4


# =========================================================================== outages
def test_outage_drops_exactly_the_packets_sent_inside_it():
    sc = scenario(2, edges=[[0, 1]], latency=CONST, steps=10)
    base = run_scenario(sc)
    sc["links"]["overrides"] = [{"link": [0, 1], "outages": [[0.3, 0.5]]}]   # both directions
    run = run_scenario(sc)
    arr, arr0 = run["arrival"], base["arrival"]
    dropped = {2, 3}                       # sent at 0.3 and 0.4; 0.5 is outside [0.3, 0.5)
    for r in range(10):
        for i, o in ((1, 0), (0, 1)):
            want = np.inf if r in dropped else t_s((r + 1) * T_NS + 50_000_000, 10)
            assert arr[i, o, r] == want and (r in dropped or arr0[i, o, r] == want), (i, o, r)
    c = run.counts
    for u, v in ((0, 1), (1, 0)):
        e, e0 = per_link(c, u, v), per_link(base.counts, u, v)
        assert e["sent"] == e0["sent"] == 10                 # one packet per tick
        assert e["outage_lost"] == e["lost"] == 2
        assert e["delivered"] == e0["delivered"] - 2 == 7 and e["in_flight"] == 1
    identity(c)
    check_oracle(run)
    # no outage, no change anywhere else
    assert np.array_equal(run["truth"], base["truth"])


# =========================================================================== duplication
def test_duplicates_with_constant_latency_arrive_together_and_change_nothing():
    sc = scenario(2, edges=[[0, 1]], latency=CONST, steps=10)
    base = run_scenario(sc)
    sc["links"]["default"]["duplicate"] = 1.0
    run = run_scenario(sc)
    c, c0 = run.counts, base.counts
    for u, v in ((0, 1), (1, 0)):
        e = per_link(c, u, v)
        assert e["sent"] == 10 and e["copies"] == 10
        assert e["delivered"] == 18 and e["in_flight"] == 2   # the last packet and its copy
    identity(c)
    # every copy has the sequence number of its original: stale on arrival
    assert c["stale"] - c0["stale"] == 18
    for key in ("truth", "arrival", "x_local", "P_local", "x_final", "x_fused"):
        assert np.array_equal(run[key], base[key]), key


def _spec(**kw):
    return LinkSpec(latency=parse_latency(kw.pop("latency")), **kw)


def _draw_times(n=2000, seed=0):
    """Send instants (ns, some repeated) and each packet's number at its instant."""
    g = np.random.default_rng(seed)
    times, seqs = [], []
    t = 0
    for _ in range(n):
        if not times or g.random() > 0.3:
            t += int(g.integers(1, T_NS))
            seq = 0
        else:
            seq = seqs[-1] + 1                     # another packet at the same instant
        times.append(t)
        seqs.append(seq)
    return times, seqs


def test_faults_leave_the_other_draws_unchanged():
    """Common random numbers at the link: a packet's fate is a pure function of
    (link, send instant, seq); adding loss, duplication, jitter, an outage or a
    schedule changes no original packet's latency or loss draw."""
    lat = {"model": "uniform", "low": 0.0, "high": 0.3}
    plain = Link(0, 0, 1, _spec(latency=lat, loss=0.2), 5, T_NS)
    assert plain.spec.plain
    times, seqs = _draw_times()
    base = [plain.transmit(t, q) for t, q in zip(times, seqs)]
    assert all(why in (None, "lost") for _, why in base)
    assert all(len(lats) == (why is None) for lats, why in base)
    assert 0.15 < sum(why == "lost" for _, why in base) / len(base) < 0.25
    # pure: a fresh link queried backwards gives the same fates
    again = Link(0, 0, 1, _spec(latency=lat, loss=0.2), 5, T_NS)
    assert [again.transmit(t, q) for t, q in zip(times[::-1], seqs[::-1])][::-1] == base
    # loss does not touch the latency draws (a link without loss has the same latencies)
    lossless = Link(0, 0, 1, _spec(latency=lat), 5, T_NS)
    lat0 = [lossless.transmit(t, q) for t, q in zip(times, seqs)]
    assert all(why is None and len(lats) == 1 for lats, why in lat0)
    for b, l0 in zip(base, lat0):
        if b[1] is None:
            assert b[0] == l0[0]
    # more loss: the same uniforms, so every packet lost at 0.2 is lost at 0.5 as well
    lossier = Link(0, 0, 1, _spec(latency=lat, loss=0.5), 5, T_NS)
    for b, g in zip(base, (lossier.transmit(t, q) for t, q in zip(times, seqs))):
        assert g == b or (b[1] is None and g == ((), "lost"))
    variants = [
        Link(0, 0, 1, _spec(latency=lat, loss=0.2, duplicate=0.4), 5, T_NS),
        Link(0, 0, 1, _spec(latency=lat, loss=0.2, outages=((1.0, 2.0),)), 5, T_NS),
        Link(0, 0, 1, _spec(latency=lat, loss=0.2, duplicate=0.4, outages=((1.0, 2.0),)), 5, T_NS),
    ]
    copy_law = parse_latency(lat).sampler(("link", 0, 1, "duplicate"), 5, T_NS)
    for link in variants:
        assert not link.spec.plain
        got = [link.transmit(t, q) for t, q in zip(times, seqs)]
        for t, q, b, g in zip(times, seqs, base, got):
            in_outage = link.spec.outages and 1_000_000_000 <= t < 2_000_000_000
            if in_outage:
                assert g == ((), "outage")
            elif b[1] == "lost":
                assert g == ((), "lost")
            else:
                assert g[1] is None and g[0][0] == b[0][0]
                if len(g[0]) == 2:              # the copy: its own keyed latency draw
                    assert g[0][1] == copy_law.draw(t, q)[0]
        if link.duplicate:
            n_ok = sum(1 for g, _ in got if g)
            copies = sum(1 for g, _ in got if len(g) == 2)
            assert abs(copies / n_ok - 0.4) < 0.05
        if link.spec.outages:
            assert sum(why == "outage" for _, why in got) > 0
    # jitter adds its own keyed draw; a schedule scales the model's draw at the send time
    from dkfsim.components.faults import ScheduleStep
    jit = {"model": "uniform", "high": 0.02}
    jittered = Link(0, 0, 1, _spec(latency=lat, loss=0.2, jitter=parse_latency(jit)), 5, T_NS)
    jlaw = parse_latency(jit).sampler(("link", 0, 1, "jitter"), 5, T_NS)
    scheduled = Link(0, 0, 1, _spec(latency=lat, loss=0.2,
                                    schedule=(ScheduleStep(at=50.0, factor=2.0),)),
                     5, T_NS)
    n_jit = 0
    for t, q, b in zip(times, seqs, base):
        gj, gs = jittered.transmit(t, q), scheduled.transmit(t, q)
        if b[1] == "lost":
            assert gj == gs == ((), "lost")
            continue
        j = jlaw.draw(t, q)[0]
        n_jit += j > 0
        assert gj == ((b[0][0] + j,), None)
        assert gs == ((b[0][0] if t < 50 * 10**9 else round(b[0][0] * 2.0),), None)
    assert n_jit > len(times) // 2


def _network(spec, seed=5, arcs=((0, 1), (1, 0))):
    env = simpy.Environment()
    return env, Network(env, list(arcs), lambda u, v: spec, seed, T_NS)


def test_ports_sending_at_one_instant_share_the_link_draws():
    """Two estimators' ports that put a packet on one link at one instant (as the
    same number among their packets there) see the same latency and the same loss;
    a packet's fate does not depend on how many packets its port sent before."""
    spec = _spec(latency={"model": "exponential", "mean": 0.15}, loss=0.2, duplicate=0.2)
    env, net = _network(spec)
    got: dict[str, dict] = {"a": {}, "b": {}, "c": {}}

    def receiver(name):
        def receive(_link, payload):
            got[name].setdefault(payload, []).append(env.now)
        return receive

    ports = {name: net.port(name, receiver(name)) for name in got}
    link = net.link(0, 1)
    plan = {"a": lambda k: 3,                           # three packets every tick
            "b": lambda k: 2 if k % 2 == 0 else 0,      # two on even ticks
            "c": lambda k: 1 if k >= 150 else 0}        # one from tick 150 on: no history

    def sender():
        for k in range(300):
            for name, port in ports.items():
                for q in range(plan[name](k)):
                    port.send(link, (k, q), nbytes=10)
            yield env.timeout(T_NS)

    env.process(sender())
    env.run()
    fates = {}
    for k in range(300):
        for q in range(3):
            lats, why = link.transmit(k * T_NS, q)
            fates[(k, q)] = None if why else sorted(k * T_NS + x for x in lats)
    assert any(v is None for v in fates.values()) and any(v and len(v) == 2 for v in fates.values())
    for name, port in ports.items():
        sent = [(k, q) for k in range(300) for q in range(plan[name](k))]
        for key in sent:
            assert sorted(got[name].get(key, [])) == (fates[key] or []), (name, key)
        c = port.counts()
        assert c["sent"] == len(sent) and c["bytes"] == 10 * len(sent)
        assert c["lost"] == sum(fates[key] is None for key in sent)
        assert c["copies"] == sum(fates[key] is not None and len(fates[key]) == 2 for key in sent)
        assert c["in_flight"] == 0 and c["delivered"] == sum(len(v) for v in got[name].values())
    # b and c saw exactly a's fates for the packets they share, whatever their history
    for name in ("b", "c"):
        for key, arrivals in got[name].items():
            assert sorted(got["a"][key]) == sorted(arrivals)
    # and the other direction draws on its own keys
    back = net.link(1, 0)
    same = sum(back.transmit(k * T_NS, 0) == link.transmit(k * T_NS, 0) for k in range(300))
    assert same < 300 * 0.3


def test_loss_duplication_and_jitter_leave_a_runs_latency_draws_unchanged():
    """Run level: on one link each node sends one packet per tick (number 0 at its
    instant), so its delay is the same keyed draw whatever loss, duplication or
    jitter the link also has."""
    sc = scenario(2, edges=[[0, 1]], steps=60, latency={"model": "uniform", "low": 0.0,
                                                        "high": 0.25}, loss=0.0)
    base = run_scenario(sc)["arrival"]
    assert len(np.unique(base[1, 0] - base[0, 0])) > 20          # a real draw per packet
    lossy = copy.deepcopy(sc)
    lossy["links"]["default"]["loss"] = 0.3
    arr = run_scenario(lossy)["arrival"]
    lost = np.isinf(arr) & np.isfinite(base)
    assert lost.sum() > 10
    assert np.array_equal(arr[~lost], base[~lost])
    dup = copy.deepcopy(sc)
    dup["links"]["default"]["duplicate"] = 0.5
    arr = run_scenario(dup)["arrival"]
    assert np.all(arr <= base)                  # the original's arrival, or its earlier copy
    assert (arr < base).sum() > 5
    jit = copy.deepcopy(sc)
    jit["links"]["default"]["jitter"] = {"model": "uniform", "low": 0.01, "high": 0.02}
    jit["buffer_length"] = 4
    arr = run_scenario(jit)["arrival"]
    for i, o in ((1, 0), (0, 1)):               # the packets (own arrivals are the ticks)
        assert np.all(np.isinf(arr[i, o]) >= np.isinf(base[i, o]))
        fin = np.isfinite(arr[i, o])
        extra = arr[i, o, fin] - base[i, o, fin]
        assert extra.size > 50 and np.all(extra >= 0.01 - 1e-9) and np.all(extra <= 0.02 + 1e-9)


def test_duplication_keeps_truth_measurements_and_the_oracle():
    sc = scenario(5, edges=[[0, 1], [1, 2], [1, 3], [3, 4]], steps=60,
                  latency={"model": "uniform_steps", "d_t": 2}, loss=0.1)
    base = run_scenario(sc)
    sc["links"]["default"]["duplicate"] = 0.3
    run = run_scenario(sc)
    assert np.array_equal(run["truth"], base["truth"])
    for i in range(5):
        assert np.array_equal(run[f"y_{i}"], base[f"y_{i}"])
    c = run.counts
    assert c["copies"] > 0
    assert abs(c["copies"] / (c["sent"] - c["lost"]) - 0.3) < 0.06
    identity(c)
    check_oracle(run)


# =========================================================================== crashes
def _crash_path_run(**kw):
    sc = scenario(3, edges=[[0, 1], [1, 2]], latency=CONST, steps=12, **kw)
    sc["faults"] = {"crashes": [{"node": 1, "start": 0.35, "end": 0.65}]}
    return sc, run_scenario(sc)


@pytest.mark.parametrize("protocol", ["tree", "flood"])
def test_crash_on_a_path_hand_worked(protocol):
    sc, run = _crash_path_run(protocol=protocol)
    arr, K = run["arrival"], 12
    assert int(run["buffer_length"]) == 3                    # d_t = 1, d_g = 2
    crashed_rows = {3, 4, 5}            # ticks at 0.4, 0.5, 0.6 fall in [0.35, 0.65)
    assert np.array_equal(np.flatnonzero(run["crashed"][1]), sorted(crashed_rows))
    assert not run["crashed"][[0, 2]].any()
    for r in range(K):
        t = (r + 1) * T_NS
        # node 1's own contribution for a crashed row exists nowhere
        for i in range(3):
            if r in crashed_rows:
                assert arr[i, 1, r] == np.inf
        if r not in crashed_rows:
            assert arr[1, 1, r] == t_s(t)
            assert arr[0, 1, r] == arr[2, 1, r] == t_s(t + 50_000_000, K)
        # the ends' packets reach node 1 at t + 0.05: dropped at 0.35, 0.45, 0.55
        # (rows 2, 3, 4), received at 0.65 (the window is [start, end))
        lost_at_1 = r in (2, 3, 4)
        for o, far in ((0, 2), (2, 0)):
            assert arr[o, o, r] == t_s(t)
            assert arr[1, o, r] == (np.inf if lost_at_1 else t_s(t + 50_000_000, K)), (o, r)
            assert arr[far, o, r] == (np.inf if lost_at_1 else t_s(t + 100_000_000, K)), (o, r)
    c = run.counts
    assert c["crash_dropped"] == 6
    assert per_link(c, 0, 1)["crash_dropped"] == per_link(c, 2, 1)["crash_dropped"] == 3
    assert per_link(c, 1, 0)["crash_dropped"] == per_link(c, 1, 2)["crash_dropped"] == 0
    identity(c)
    # while down, node 1 only predicts: row 3 is the prediction of its row-2 estimate
    Phi, Q = run["Phi"], run["Q"]
    x2, P2 = run["x_local"][2, 1], run["P_local"][2, 1]
    ref.assert_close(run["x_local"][3, 1], Phi @ x2, "prediction while down", 1e-12)
    ref.assert_close(run["P_local"][3, 1], Phi @ P2 @ Phi.T + Q, "prediction while down", 1e-12)
    check_oracle(run)


def test_crash_mask_and_schedule():
    cs = CrashSchedule(Faults(crashes=[{"node": 0, "start": 0.1, "end": 0.3},
                                       {"node": 2, "start": 0.25, "end": 0.26}]), 3)
    assert cs.down(0, 100_000_000) and not cs.down(0, 300_000_000) and not cs.down(1, 0)
    assert cs.mask(4, T_NS).tolist() == [[True, True, False, False], [False] * 4, [False] * 4]
    assert not CrashSchedule(None, 3) and not CrashSchedule(Faults(), 3)


@pytest.mark.parametrize("protocol", ["tree", "flood"])
def test_every_fault_at_once_keeps_the_exactness_oracle(protocol):
    n = 7
    if protocol == "tree":
        edges, directed = tree_edges(n, 11), False
    else:
        edges, directed = scc_digraph_edges(n, 11), True
    sc = scenario(n, edges=edges, directed=directed, protocol=protocol, steps=80,
                  buffer_length=4, seed=3, latency={
                      "model": "gilbert_elliott", "p_good_to_bad": 0.1, "p_bad_to_good": 0.3,
                      "good": {"model": "uniform", "low": 0.0, "high": 0.15},
                      "bad": {"model": "uniform", "low": 0.1, "high": 0.4},
                      "loss_bad": 0.3})
    d = sc["links"]["default"]
    d.update(loss=0.05, duplicate=0.2, jitter={"model": "uniform", "high": 0.02},
             schedule=[{"kind": "ramp", "from": 2.0, "to": 4.0, "end_factor": 2.0}],
             outages=[[5.0, 5.6]])
    sc["links"]["overrides"] = [{"link": list(edges[0]), "outages": [[1.0, 1.5], [6.0, 6.3]]}]
    sc["faults"] = {"crashes": [{"node": 2, "start": 1.0, "end": 2.5},
                                {"node": 4, "start": 3.0, "end": 3.35}]}
    run = run_scenario(sc)
    c = run.counts
    for k in ("lost", "copies", "crash_dropped", "outage_lost", "late"):
        assert c[k] > 0, k
    identity(c)
    arr = run["arrival"]
    down = run["crashed"]
    assert down[2].sum() == 15 and down[4].sum() == 4        # ticks 1.0..2.4 and 3.0..3.3
    for node in (2, 4):
        rows = np.flatnonzero(down[node])
        assert np.all(np.isinf(arr[:, node, rows]))
        up = np.flatnonzero(~down[node])
        assert np.all(arr[node, node, up] == run["t"][up])
    check_oracle(run)


# =========================================================================== the schema
def test_scenarios_without_faults_keep_their_hash_and_keys():
    sc = load_scenario(REPO / "scenarios" / "paper_case1.yaml")
    d = sc.to_dict()
    assert "faults" not in d
    assert set(d["links"]["default"]) == {"latency", "loss"}
    # pinned: the restructure (issue 8) changed the canonical dict on purpose ("baselines" and
    # "consensus_rounds" became "estimators", "plugins" is new); no fault key ever enters it
    assert d["estimators"] == [{"kind": "centralized"}] and "baselines" not in d
    assert scenario_hash(sc) == "90e54d9ff50b6428197c58025028c9c5c1cb8071c331d343ea2b72155f1aeb46"


def test_fault_keys_round_trip_and_override():
    sc = scenario(3, edges=[[0, 1], [1, 2]], latency=CONST)
    sc["links"]["default"].update(
        duplicate=0.1, jitter={"model": "uniform", "high": 0.01},
        schedule=[{"kind": "ramp", "from": 0.5, "to": 1.0, "end_factor": 2.0},
                  {"kind": "step", "at": 2.0, "factor": 1.0}],
        outages=[[0.1, 0.2]])
    sc["links"]["overrides"] = [{"link": [1, 2], "duplicate": 0.0, "outages": [[1.0, 2.0]]}]
    sc["faults"] = {"crashes": [{"node": 0, "start": 1.0, "end": 2.0}]}
    loaded = load_scenario(sc)
    d = loaded.to_dict()
    assert d["links"]["default"]["schedule"][0]["from"] == 0.5
    assert load_scenario(d) == loaded
    s12, s01 = loaded.link_spec(2, 1), loaded.link_spec(0, 1)
    assert s12.duplicate == 0.0 and s12.outages == ((1.0, 2.0),) and s12.jitter is not None
    assert s01.duplicate == 0.1 and s01.outages == ((0.1, 0.2),)
    over = load_scenario(sc, overrides=["links.default.duplicate=0.5",
                                        "faults.crashes.0.node=2"])
    assert over.link_spec(0, 1).duplicate == 0.5 and over.faults.crashes[0].node == 2


@pytest.mark.parametrize("patch, where, what", [
    (lambda s: s.update(faults={"crashes": [{"node": 3, "start": 0.1, "end": 0.2}]}),
     "faults.crashes.0.node", "out of range 0..2"),
    (lambda s: s.update(faults={"crashes": [{"node": 1, "start": 0.3, "end": 0.2}]}),
     "faults.crashes.0.end", "must be > start"),
    (lambda s: s.update(faults={"crash": []}), "faults.crash", "did you mean 'crashes'"),
    (lambda s: s["links"]["default"].update(schedule=[{"kind": "stair", "at": 1, "factor": 2}]),
     "links.default.schedule.0", "unknown or missing schedule kind"),
    (lambda s: s["links"]["default"].update(schedule=[{"kind": "step", "at": 2, "factor": 2},
                                                      {"kind": "step", "at": 1, "factor": 1}]),
     "links.default.schedule.1", "time order"),
    (lambda s: s["links"]["default"].update(schedule=[{"kind": "ramp", "from": 2, "to": 1,
                                                       "end_factor": 2}]),
     "links.default.schedule.0.to", "must be > from"),
    (lambda s: s["links"]["default"].update(outages=[[0.5, 0.2]]),
     "links.default.outages.0", "0 <= start < end"),
    (lambda s: s["links"]["default"].update(duplicate=1.5),
     "links.default.duplicate", "must be <= 1"),
])
def test_bad_fault_settings_are_reported_with_their_key(patch, where, what):
    sc = scenario(3, edges=[[0, 1], [1, 2]], latency=CONST)
    patch(sc)
    with pytest.raises(ScenarioError) as info:
        load_scenario(sc)
    msg = str(info.value)
    assert where in msg and what in msg, msg


def test_empirical_file_resolves_against_the_scenario_folder(tmp_path):
    (tmp_path / "data").mkdir()
    (tmp_path / "data" / "lat.txt").write_text("delay(ms)\n10\n30\n20\n")
    sc = scenario(2, edges=[[0, 1]], steps=10, latency={
        "model": "empirical", "file": "data/lat.txt", "mode": "replay", "start": 0})
    import yaml
    (tmp_path / "s.yaml").write_text(yaml.safe_dump(sc))
    loaded = load_scenario(tmp_path / "s.yaml")
    assert RunPlan(loaded).d_t == 1                  # max 30 ms < T = 0.1 s
    from dkfsim import run
    res = run(loaded)
    a = res["arrival"]
    # replay from row 0 on each link, one row per tick: row r is sent at t_{r+1} = (r + 1) T,
    # during tick r + 1, so it takes row (0 + r + 1) mod 3 of [10, 30, 20] ms, cycling
    rows = [10, 30, 20]
    for i, o in ((1, 0), (0, 1)):
        assert [round((a[i, o, r] - (r + 1) * 0.1) * 1e3, 6) for r in range(9)] == \
            [rows[(r + 1) % 3] for r in range(9)]
    assert np.isinf(a[1, 0, 9])                        # sent at t_10: still in flight at the end
    with pytest.raises(ScenarioError, match="file not found"):
        load_scenario(sc)                              # a dict resolves against the cwd


# =========================================================================== stress scenarios
@pytest.mark.parametrize("name, L", [("stress_heavy_tail", 17), ("stress_5g_empirical", 57),
                                     ("stress_outage", 25), ("stress_ramp", 25)])
def test_stress_scenarios_validate_and_run(name, L):
    path = REPO / "scenarios" / f"{name}.yaml"
    sc = load_scenario(path, overrides=["steps=40"])
    assert RunPlan(sc).buffer_length() == L
    from dkfsim import run
    res = run(sc)
    identity(res.counts)


def test_baselines_do_without_the_measurements_a_crash_prevented():
    """A crashed sensor's rows exist nowhere: not for the centralized filter, not for its local one."""
    from conftest import scenario
    from reference import kalman_filter

    import dkfsim
    d = scenario(3, steps=30, generator="path")
    d["faults"] = {"crashes": [{"node": 1, "start": 0.45, "end": 1.05}]}   # T = 0.1: ticks 5..10
    d["baselines"] = ["centralized", "local"]
    res = dkfsim.run(dkfsim.load_scenario(d))
    a = res.arrays
    n = 3
    down = a["crashed"]
    assert down[1].sum() == 6 and not down[[0, 2]].any()
    Hs = [a[f"H_{i}"] for i in range(n)]
    Rs = [a[f"R_{i}"] for i in range(n)]
    ys = [a[f"y_{i}"] for i in range(n)]
    xc, _ = kalman_filter(a["Phi"], a["Q"], a["x0_mean"], a["P0"], Hs, Rs, ys,
                          lambda r: [(i, 1.0) for i in range(n) if not down[i, r]])
    np.testing.assert_allclose(a["x_centralized"], xc, rtol=1e-9, atol=1e-9)
    x1, _ = kalman_filter(a["Phi"], a["Q"], a["x0_mean"], a["P0"], Hs, Rs, ys,
                          lambda r: [] if down[1, r] else [(1, 1.0)])
    np.testing.assert_allclose(a["x_local_only"][:, 1], x1, rtol=1e-9, atol=1e-9)


def test_ci_consensus_respects_crash_windows():
    """A crashed node neither corrects, sends nor averages: with the whole run
    inside its window, it is a pure prediction and the others never hear from it."""
    from conftest import scenario

    import dkfsim
    d = scenario(3, steps=20, generator="path")
    d["baselines"] = ["ci_consensus"]
    d["consensus_rounds"] = 2
    base = dkfsim.run(dkfsim.load_scenario(d)).arrays
    d["faults"] = {"crashes": [{"node": 2, "start": 0.0, "end": 100.0}]}
    a = dkfsim.run(dkfsim.load_scenario(d)).arrays
    Phi, Q = a["Phi"], a["Q"]
    x, P = a["x0_mean"], a["P0"]
    for r in range(20):
        x, P = Phi @ x, Phi @ P @ Phi.T + Q
        np.testing.assert_allclose(a["x_ci_consensus"][r, 2], x, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(a["P_ci_consensus"][r, 2], P, rtol=1e-9, atol=1e-12)
    # Node 1 loses a neighbour: its estimate changes.
    assert not np.allclose(a["x_ci_consensus"][:, 1], base["x_ci_consensus"][:, 1])

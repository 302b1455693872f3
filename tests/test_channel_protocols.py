"""The protocols on a shared channel (issue 22 §1, decisions 227-228): what each hands the port.

Flood and the consensus family broadcast: one frame per sending node and instant, the same
content to each of its out-links, the frame the size of one message (flood: of the union of what
it relays).  The tree sends one combined frame per flush, each neighbour's own message behind one
header (``PACKET_HEADER + sum(PART_HEADER + rows)``), and the message to ``j`` leaves out what
came from ``j``.  The frames are recorded by wrapping :meth:`Port.send_frame`; the sizes and the
contents are recomputed here from the packets, not read from the protocols.
"""

from __future__ import annotations

from collections import defaultdict
from pathlib import Path

import numpy as np
import pytest
import reference as ref
from conftest import run_scenario, scenario, tree_edges
from test_exactness import check_against_window_reference, check_common, expected_late

import dkfsim
from dkfsim.network.port import Port, RecordPort
from dkfsim.protocols.base import PACKET_HEADER, PART_HEADER, row_bytes

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture
def frames(monkeypatch):
    """Every frame handed to a port: (port name, instant, frame bytes, parts), a part
    ``(link, payload, bytes)``; a record port's (the tree's) decoded into the payload its
    protocol means: ``(number, [(row, origin mask), ...])``."""
    log: list[tuple[str, int, int, list]] = []
    original = Port.send_frame
    original_records = RecordPort.send_records

    def spy(self, parts, frame_bytes):
        parts = list(parts)
        log.append((self.name, self.env.now, frame_bytes, parts))
        original(self, parts, frame_bytes)

    def spy_records(self, parts, records, frames_):
        p0 = 0
        for end, size in frames_.tolist():
            decoded = []
            for lid, tag, i0, i1, nbytes, _done in parts[p0:end, :6].tolist():
                items = [(int(r[0]), int.from_bytes(np.asarray(r[1:]).astype(np.uint64).tobytes(), "little"))
                         for r in records[i0:i1]]
                decoded.append((self.net.links[lid], (tag, items), nbytes))
            log.append((self.name, self.env.now, size, decoded))
            p0 = end
        original_records(self, parts, records, frames_)
    monkeypatch.setattr(Port, "send_frame", spy)
    monkeypatch.setattr(RecordPort, "send_records", spy_records)
    return log


def _out_links(sc):
    """Each node's out-neighbours on the scenario's (undirected) topology."""
    out = defaultdict(set)
    for u, v in sc["topology"]["edges"]:
        out[u].add(v)
        out[v].add(u)
    return out


@pytest.mark.parametrize("kind", ["ci_consensus", "kcf", "diffusion_kf"])
def test_consensus_broadcasts_one_frame_per_node_and_instant(kind, frames):
    """Every sub-slot instant, every node hands over exactly one frame: one part per out-link,
    all the same message, the frame that message's size; the parts are the port's packets."""
    sc = dict(scenario(6, edges=tree_edges(6, 51), steps=20), estimators=[{"kind": kind}])
    r = run_scenario(sc)
    out = _out_links(sc)
    mine = [f for f in frames if f[0] == kind]
    per_instant = defaultdict(list)
    for _, now, size, parts in mine:
        srcs = {link.src for link, _, _ in parts}
        assert len(srcs) == 1
        src = srcs.pop()
        per_instant[now].append(src)
        assert {link.dst for link, _, _ in parts} == out[src]
        assert len({id(p) for _, p, _ in parts}) == 1          # one message, broadcast
        assert {n for _, _, n in parts} == {size}
    instants = sorted(per_instant)
    assert len(instants) >= 20
    for now in instants:
        assert sorted(per_instant[now]) == list(range(6)), now      # once per node
    assert sum(len(f[3]) for f in mine) == r.res.traffic[kind]["sent"]


def test_without_a_channel_consensus_sends_per_link_in_the_links_order(monkeypatch):
    """No ``medium:``: the frames are the per-link sends, and at every instant they go in the
    network's link order (every arc, ascending ids), as the per-link loop sent them."""
    sent = defaultdict(list)
    original = Port.send_frames

    def spy(self, links, payloads, nbytes, ends, frame_bytes):
        if self.name == "ci_consensus":
            sent[self.env.now].extend(link.id for link in links)
        original(self, links, payloads, nbytes, ends, frame_bytes)
    monkeypatch.setattr(Port, "send_frames", spy)
    sc = dict(scenario(6, edges=tree_edges(6, 51), steps=10), estimators=[{"kind": "ci_consensus", "rounds": 2}])
    r = run_scenario(sc)
    ids = sorted(row["link"] for row in r.res.traffic["ci_consensus"]["per_link"])
    assert len(sent) == 20
    for now, order in sent.items():
        assert order == sorted(order) and len(order) == len(ids), (now, order)


def test_flood_broadcasts_the_union_once(frames):
    """Flood on a channel: one frame per flush; its size is one header and the union of the
    parts' rows; no part goes back to the neighbour its contributions came from (a leaf's relays
    are empty)."""
    sc = scenario(6, edges=tree_edges(6, 51), steps=20, protocol="flood",
                  latency={"model": "uniform_steps", "d_t": 2})
    sc["medium"] = {"rate": 1.0e6}
    run_scenario(sc)
    mine = [f for f in frames if f[0] == "anti_delay_dkf"]
    rb = row_bytes(2, 6)
    for _, _now, size, parts in mine:
        src = parts[0][0].src
        assert all(link.src == src for link, _, _ in parts)
        union: dict[int, int] = defaultdict(int)
        for _link, (_seq, items), n in parts:
            assert n == PACKET_HEADER + len(items) * rb
            for row, mask in items:
                union[row] |= mask
        assert size == PACKET_HEADER + len(union) * rb
    assert len(mine) > 0 and any(len(p) > 1 for _, _, _, p in mine)


def test_tree_combines_each_neighbours_message(frames):
    """Tree: one frame per flush of a node, its size one header plus each part's own header and
    rows; the message to ``j`` never carries ``j``'s own contribution, and the numbers of a
    link's parts increase by one per packet."""
    sc = scenario(6, edges=tree_edges(6, 51), steps=20, latency={"model": "uniform_steps", "d_t": 2})
    run_scenario(sc)
    mine = [f for f in frames if f[0] == "anti_delay_dkf"]
    rb = row_bytes(2, 6)
    last = defaultdict(int)
    for _, _now, size, parts in mine:
        src = parts[0][0].src
        assert all(link.src == src for link, _, _ in parts)
        assert len({link.dst for link, _, _ in parts}) == len(parts)
        assert size == PACKET_HEADER + sum(PART_HEADER + len(items) * rb for _, (_, items), _ in parts)
        for link, (seq, items), n in parts:
            assert n == PACKET_HEADER + len(items) * rb
            assert seq == last[link.id] + 1
            last[link.id] = seq
            for _row, mask in items:
                assert not mask >> link.dst & 1            # never j's own contribution back to j
    assert any(len(p) > 1 for _, _, _, p in mine)


# ------------------------------------------------------------------ on a channel
def _on_channel(n=6, steps=40, seed=1, medium=None, **kw):
    sc = scenario(n, edges=tree_edges(n, 51), steps=steps, seed=seed, **kw)
    sc["medium"] = {"rate": 6.0e6, "access": {"kind": "csma", "slot": 13.0e-6, "aifs": 110.0e-6, "cw": 15},
                    "preamble": 40.0e-6, **(medium or {})}
    return sc


def test_on_a_channel_frames_are_nodes_times_instants_not_links(frames):
    """With ``medium:``, the channel carries one frame per node and sub-slot for the consensus
    filters (``n K slots``, while their links carry ``arcs K slots`` packets), and one per node
    and flush for flood (the distinct (sender, instant) pairs of its packets)."""
    n, K = 6, 30
    sc = _on_channel(n, K, protocol="flood", latency={"model": "constant", "value": 5.0e-6})
    sc["estimators"] = [{"kind": "ci_consensus", "rounds": 2}, {"kind": "diffusion_kf"}]
    r = run_scenario(sc)
    arcs = 2 * (n - 1)
    ci, dif = r.res.traffic["ci_consensus"], r.res.traffic["diffusion_kf"]
    assert ci["sent"] == arcs * K * 2 and ci["channel"]["frames"] == n * K * 2
    assert dif["channel"]["frames"] == n * dif["sent"] // arcs          # two phases, each a broadcast
    flood = [f for f in frames if f[0] == "anti_delay_dkf"]
    flushes = {(parts[0][0].src, now) for _, now, _, parts in flood}
    dkf = r.res.traffic["fused"]
    assert len(flushes) == len(flood) < dkf["sent"]                     # one frame per flush
    # the channel counts the frames that ended by t_K: every frame handed over a tick before
    # the end (this light load never waits that long), at most every frame
    T_ns = 10**9 * sc["model"]["T"]
    early = sum(1 for _, now, _, _ in flood if now <= (K - 1) * T_ns)
    assert early <= dkf["channel"]["frames"] <= len(flood)


@pytest.mark.parametrize("protocol", ["tree", "flood"])
def test_the_dkf_is_exact_on_a_collision_free_slow_channel(protocol):
    """A slow channel (300 kbit/s: frames of milliseconds, queues) whose backoffs never coincide
    (this seed, asserted), a buffer longer than any wait: nothing lost or late, every final row
    of every node is the centralized filter, and the estimates follow the window rule on the
    arrival log.  The tree's combined frames deliver each neighbour's own message intact."""
    sc = _on_channel(5, 60, seed=3, latency={"model": "constant", "value": 5.0e-6}, buffer_length=12,
                     protocol=protocol, medium={"rate": 3.0e5, "access": {"kind": "csma", "slot": 1.0e-6, "aifs": 10.0e-6, "cw": 1023}})
    r = run_scenario(sc)
    ch = r.counts["channel"]
    assert ch["collisions"] == 0 and r.counts["lost"] == 0, ch
    assert ch["access_delay_mean"] > 1e-3, "the channel was meant to make frames wait"
    assert expected_late(r.arrays) == 0 and r.counts["late"] == 0
    xs, _ = check_common(r)
    nfinal = 60 - 12 + 1
    for i in range(5):
        ref.assert_close(r.arrays["x_final"][:nfinal, i], xs[:nfinal], f"x_final node {i} vs centralized", 1e-9)
    check_against_window_reference(r)


def test_with_collisions_the_dkf_is_exact_for_what_arrived():
    """ITS-G5 parameters, every node flushing at the tick: frames collide (both lost for every
    receiver).  The DKF still follows the window rule on what arrived, and ``late`` is the
    arrival log's count; the lost parts are ``collision_lost``, inside ``lost``."""
    sc = _on_channel(6, 60, latency={"model": "constant", "value": 5.0e-6}, buffer_length=3)
    r = run_scenario(sc)
    c = r.counts
    assert c["collision_lost"] > 0 and c["lost"] == c["collision_lost"]
    assert c["sent"] + c["copies"] == (c["delivered"] + c["lost"] + c["queue_dropped"] + c["crash_dropped"]
                                       + c["in_flight"])
    assert c["late"] == expected_late(r.arrays)
    check_common(r)
    check_against_window_reference(r)


# ------------------------------------------------------------------ the shipped scenario and sweep
def test_the_shipped_channel_scenario_validates_and_bad_overrides_name_the_key(capsys):
    """``dkfsim validate`` accepts the shipped scenario; a bad channel value given to it exits 2
    naming the file and the key, in one line."""
    from dkfsim.cli.main import main
    path = str(ROOT / "scenarios" / "channel_its_g5.yaml")
    assert main(["validate", path]) == 0
    for override, key in (("medium.rate=0", "medium.rate"), ("medium.access.cw=-1", "medium.access.cw"),
                          ("medium.access.slot=0", "medium.access.slot"),
                          ("medium.preamble=1e9", "medium.preamble")):
        capsys.readouterr()
        assert main(["validate", path, "--set", override]) == 2, override
        err = capsys.readouterr().err
        assert "channel_its_g5.yaml" in err and key in err and "Traceback" not in err, err
    # a link queue on the channel points to the radios' queue, not to a link rate it may not have
    for what in ("queue={packets: 3}", "background={packets_per_second: 5, size: 10}"):
        capsys.readouterr()
        assert main(["validate", path, "--set", f"links.default.{what}"]) == 2
        err = capsys.readouterr().err
        name = what.split("=")[0]
        assert f"links.default.{name}" in err and f"medium.{name}" in err and "give rate here" not in err, err


def test_the_channel_sweep_reaches_medium_rate_and_refuses_a_bad_rate(tmp_path, capsys):
    """The shipped sweep's grid key is the channel's rate (each grid point's run has it), and a
    sweep whose grid gives a rate of 0 stops with exit 2 naming the key, before any run."""
    import yaml

    from dkfsim.experiments.sweep.definition import load_sweep
    spec = yaml.safe_load((ROOT / "scenarios" / "sweep_channel.yaml").read_text())
    assert list(spec["grid"]) == ["medium.rate"]
    sweep = load_sweep(ROOT / "scenarios" / "sweep_channel.yaml")
    rates = sorted(p.scenario.medium.rate for p in sweep.parameter_sets)
    assert rates == sorted(spec["grid"]["medium.rate"])
    from dkfsim.cli.main import main
    bad = dict(spec, scenario=str(ROOT / "scenarios" / "channel_its_g5.yaml"), grid={"medium.rate": [1.0e6, 0.0]})
    (tmp_path / "s.yaml").write_text(yaml.safe_dump(bad))
    capsys.readouterr()
    assert main(["sweep", str(tmp_path / "s.yaml"), "--jobs", "1", "--quiet", "--db", str(tmp_path / "s.sqlite")]) == 2
    err = capsys.readouterr().err
    assert "medium.rate" in err and "Traceback" not in err, err


def test_centralized_delayed_sends_one_unicast_frame_per_sensor_and_tick():
    """On a channel the sensors' packets to the centre are frames on it, one part each: ``n K``
    handed over; every frame that left carried one packet (each delivered or collided packet is
    one frame; a collided frame loses one packet), those still waiting at ``t_K`` in flight;
    the counting identity holds per direct link."""
    n, K = 6, 40
    sc = _on_channel(n, K, latency={"model": "constant", "value": 5.0e-6},
                     medium={"background": {"arrivals": "periodic", "packets_per_second": 50, "size": 300}})
    sc["estimators"] = [{"kind": "centralized_delayed"}]
    t = run_scenario(sc).res.traffic["centralized_delayed"]
    ch = t["channel"]
    assert t["sent"] == n * K
    assert t["delivered"] + t["lost"] <= ch["frames"] <= t["sent"]
    assert t["lost"] == t["collision_lost"] == ch["frames_collided"] > 0
    for row in t["per_link"]:
        assert row["link"][1] == -1 and row["sent"] == K
        assert row["sent"] + row["copies"] == (row["delivered"] + row["lost"] + row["queue_dropped"]
                                               + row["crash_dropped"] + row["in_flight"])


def test_a_channel_background_too_heavy_to_simulate_is_refused_before_it_starts(tmp_path, capsys):
    """Every background frame is an event of the channel engine in each estimator's copy, so the
    run's estimate counts them: 1e9 frames per second and vehicle is refused (exit 2, the
    estimate and --yes named) at once instead of running for days; the shipped load adds little."""
    from dkfsim.cli.main import main
    from dkfsim.engine.estimate import estimate_run
    path = ROOT / "scenarios" / "channel_its_g5.yaml"
    shipped = estimate_run(dkfsim.load_scenario(path)).seconds
    quiet = estimate_run(dkfsim.load_scenario(path, overrides=["medium.background=null"])).seconds
    heavy = estimate_run(dkfsim.load_scenario(path, overrides=["medium.background.packets_per_second=1e9"])).seconds
    assert quiet < shipped < 1.05 * quiet and heavy > 1e6
    capsys.readouterr()
    code = main(["run", str(path), "--steps", "30", "--out", str(tmp_path / "out"),
                 "--set", "medium.background.packets_per_second=1e9"])
    err = capsys.readouterr().err
    assert code == 2 and "would take about" in err and "--yes" in err and "background" in err, err
    assert not (tmp_path / "out").exists()

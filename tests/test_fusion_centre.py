"""The fusion centre over the network (issue 22 §2; docs/design.md §7, "The fusion centre").

* at zero latency and no rate limit it is the idealised ``fused`` (1e-8 relative), on the
  tree (compiled and Python exchange), on flood, and with radars (whose ``omega`` it only
  knows from packets);
* its cross-covariances equal the pair-by-pair recursion of design §7 written here, fed with
  the held masks the centre logged (latency and loss);
* a lost packet: the centre fuses that node's older estimate predicted forward; a node silent
  for more than the margin leaves the fusion;
* with latency its NEES stays in the chi-square band over Monte Carlo runs;
* bad ``at`` is a validation error naming ``estimators.<i>.at``.
"""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pytest
import yaml
from scipy import stats

import dkfsim
from dkfsim.engine.driver import Run
from dkfsim.estimators.fusion import fuse_matrix
from dkfsim.estimators.fusion_centre import next_hops

ROOT = Path(__file__).resolve().parents[1]
ZERO = "links.default.latency={model: constant, value: 0}"
CENTRE = "estimators=[{kind: fusion_centre, at: %d}]"


def paper(overrides=(), at=0):
    return dkfsim.load_scenario(ROOT / "scenarios" / "paper_case1.yaml",
                                overrides=["steps=120", CENTRE % at, *overrides])


def radar(overrides=(), at=1):
    d = yaml.safe_load((ROOT / "scenarios" / "radar_experiment.yaml").read_text())
    return dkfsim.load_scenario(copy.deepcopy(d), overrides=["steps=60", CENTRE % at, *overrides])


def run(sc, log=False):
    sim = Run(sc)
    centre = sim.estimators[1]
    if log:
        centre.log = []
        # the DKF's holdings after each update: what each node held when it computed x_i[k-1]
        dkf, update = sim.dkf, sim.dkf.on_update
        centre.dkf_held = {}

        def hooked(k):
            update(k)
            centre.dkf_held[k] = dkf.holdings.held.copy()
        dkf.on_update = hooked
    return sim.run(), centre


def check_masks_are_the_nodes_holdings(centre):
    """The masks the centre holds for node i are what node i held when it computed its newest
    estimate (row r_i, tick r_i + 1): rows still in its window then as they were, final rows as
    they became final, nothing after r_i."""
    L, W, held = centre.L, centre.W, centre.dkf_held
    Sd = held[1].shape[0]
    checked = 0
    for k, newest, excluded, known, _Xi in centre.log:
        lo = max(k - W, 0)
        for i in np.flatnonzero(~excluded):
            ri = int(newest[i])
            for s in range(lo, k):
                if s > ri:
                    want = np.zeros_like(known[0, i])
                elif s >= ri + 1 - L:
                    want = held[ri + 1][s % Sd, i]
                else:
                    want = held[s + L][s % Sd, i]
                assert np.array_equal(known[s - lo, i], want), (k, i, s)
                checked += 1
    return checked


def rel(a, b):
    return float(np.max(np.abs(a - b)) / np.max(np.abs(b)))


# ------------------------------------------------------------------------------ = fused
@pytest.mark.parametrize("make, overrides", [
    (paper, [ZERO]),
    (paper, [ZERO, "protocol=flood"]),
    (paper, [ZERO, "fusion=diagonal"]),
    (paper, [ZERO, "weights=paper"]),
    (radar, [ZERO]),
])
def test_zero_latency_equals_fused(make, overrides):
    res, centre = run(make(overrides, at=1))
    a = res.arrays
    assert rel(a["x_fusion_centre"], a["x_fused"]) <= 1e-8
    assert rel(a["P_fusion_centre"], a["P_fused"]) <= 1e-8
    facts = res.facts["fusion_centre"]
    n, K = len(res.scenario.sensors), a["t"].shape[0]
    assert facts["packets_received"] == (n - 1) * K and facts["stale_rows_used"] == 0
    assert facts["nodes_excluded"] == 0
    # every packet reached the centre over the hops of the shortest paths (the only relays)
    hop, _ = next_hops(centre.ctx.plan.exchange_arcs, n, 1)
    hops = 0
    for i in range(n):
        j = i
        while j != 1:
            j, hops = int(hop[j]), hops + 1
    assert res.traffic["fusion_centre"]["delivered"] == hops * K


def test_radar_omega_only_from_packets():
    """The shadow knows a radar's ``omega[r]`` only where a packet carried it (zero elsewhere),
    and it carried every entry some node held by the end (zero latency)."""
    res, centre = run(radar(["links.default.latency={model: uniform_steps, d_t: 2}",
                             "links.default.loss=0.3"]))
    assert centre.varying.all()
    assert not centre.have_omega.all()                 # some were never carried to the centre
    assert np.all(centre.info.omega[~centre.have_omega] == 0.0)
    assert np.array_equal(centre.info.omega[centre.have_omega], centre.ctx.info.omega[centre.have_omega])


def test_next_hops_on_the_paper_tree():
    arcs = [(0, 1), (1, 0), (0, 2), (2, 0), (1, 4), (4, 1), (2, 5), (5, 2)]
    hop, dist = next_hops(arcs, 6, 4)
    assert hop.tolist() == [1, 4, 0, -1, -1, 2]        # 3 is not connected
    assert dist.tolist() == [2, 1, 3, -1, 0, 4]


# ------------------------------------------------------------------------ Xi by hand
def _step(Phi, Q, P, C, masks, A, omega):
    """One row of every node's information filter and of the pair-by-pair recursion of design
    §7, with node i holding origin o where ``masks[i, o]``."""
    n = P.shape[0]
    Pn, G = np.empty_like(P), np.empty_like(P)
    for i in range(n):
        Pp = Phi @ P[i] @ Phi.T + Q
        Om = sum(A[i, o] * omega[o] for o in range(len(omega)) if masks[i, o]) + 0 * Pp
        Pn[i] = np.linalg.inv(np.linalg.inv(Pp) + Om)
        G[i] = Pn[i] @ np.linalg.inv(Pp)
    Cn = np.empty_like(C)
    for i in range(n):
        for j in range(n):
            S = sum(A[i, o] * A[j, o] * omega[o] for o in range(len(omega)) if masks[i, o] and masks[j, o])
            Cn[i, j] = G[i] @ (Phi @ C[i, j] @ Phi.T + Q) @ G[j].T + Pn[i] @ (S + 0 * Q) @ Pn[j]
    return Pn, Cn


def independent_xi(log, Phi, Q, P0, A, omega_of, W):
    """Per fuse tick k, ``Xi`` of row k-1 from the masks the centre logged: rows below its
    window with the masks of the tick that made them final, the window's with this tick's."""
    n, nx = A.shape[0], Phi.shape[0]
    P = np.broadcast_to(P0, (n, nx, nx)).copy()
    C = np.broadcast_to(P0, (n, n, nx, nx)).copy()
    final, f, out = {}, -1, {}
    for k, _newest, _excluded, known, _Xi in log:
        lo = max(k - W, 0)
        while f < lo - 1:
            f += 1
            P, C = _step(Phi, Q, P, C, final[f], A, omega_of(f))
        Pt, Ct = P, C
        for s in range(lo, k):
            Pt, Ct = _step(Phi, Q, Pt, Ct, known[s - lo], A, omega_of(s))
        if k - W >= 0:
            final[k - W] = known[0]
        out[k] = Ct.transpose(0, 2, 1, 3).reshape(n * nx, n * nx)
    return out


@pytest.mark.parametrize("make, overrides", [
    (paper, ["links.default.latency={model: uniform_steps, d_t: 2}", "links.default.loss=0.15",
             "steps=60"]),
    (radar, ["links.default.latency={model: uniform_steps, d_t: 2}", "links.default.loss=0.15"]),
])
def test_cross_covariances_equal_the_recursion_from_the_held_masks(make, overrides):
    res, centre = run(make(overrides), log=True)
    ctx = centre.ctx
    s = ctx.system
    info = ctx.info
    omega_of = (lambda r: info.omega[r]) if info.varying else (lambda r: info.omega)
    want = independent_xi(centre.log, s.Phi, s.Q, s.P0, centre.dkf.weights, omega_of, centre.W)
    assert check_masks_are_the_nodes_holdings(centre) > 0
    stale = 0
    for k, newest, _excluded, _known, Xi in centre.log:
        assert rel(Xi, want[k]) <= 1e-8, k
        stale += int((newest < k - 1).sum())
    assert stale > 0                                  # the latency made some estimates stale
    assert res.traffic["fusion_centre"]["lost"] > 0


# ------------------------------------------------------------------- lost packets
def _path3(overrides=()):
    """Three sensors on a path 0 - 1 - 2, the centre at 0, buffer 4 (margin M = 4)."""
    d = yaml.safe_load((ROOT / "scenarios" / "paper_case1.yaml").read_text())
    d["sensors"] = d["sensors"][:3]
    d["topology"]["edges"] = [[0, 1], [1, 2]]
    d["steps"] = 30
    d["buffer_length"] = 4
    d["links"] = {"default": {"latency": {"model": "constant", "value": 0}},
                  "overrides": [{"link": [1, 0], "outages": [[0.055, 0.085]]}]}
    d["estimators"] = [{"kind": "fusion_centre", "at": 0}]
    return dkfsim.load_scenario(d, overrides=list(overrides))


def test_lost_packets_use_the_older_estimate_predicted_forward():
    """Sends on 1 -> 0 at ticks 6, 7, 8 are lost: at rows 5, 6, 7 the centre fuses node 0's
    estimate with nodes 1's and 2's of row 4 predicted forward, weighted by the recursion."""
    res, centre = run(_path3(), log=True)
    a = res.arrays
    s = centre.ctx.system
    want = independent_xi(centre.log, s.Phi, s.Q, s.P0, centre.dkf.weights, lambda r: centre.ctx.info.omega,
                          centre.W)
    facts = res.facts["fusion_centre"]
    assert facts["stale_rows_used"] == 6 and facts["nodes_excluded"] == 0
    xl = a["x_local"]
    for r in range(a["t"].shape[0]):
        age = r - 4 if r in (5, 6, 7) else 0
        F = np.linalg.matrix_power(s.Phi, age)
        xs = np.stack([xl[r, 0], F @ xl[r - age, 1], F @ xl[r - age, 2]])
        x, P = fuse_matrix(want[r + 1], xs)
        assert rel(a["x_fusion_centre"][r], x) <= 1e-8, r
        assert rel(a["P_fusion_centre"][r], P) <= 1e-8, r
    assert not np.allclose(a["x_fusion_centre"][5:8], a["x_fused"][5:8])


def test_a_node_silent_beyond_the_margin_leaves_the_fusion():
    """Sends on 1 -> 0 lost for 6 ticks (more than M = 4): nodes 1 and 2 (behind 1) leave the
    fusion for good, and the centre is then node 0's own estimate."""
    sc = _path3(["links.overrides.0.outages=[[0.055, 0.115]]"])
    res, _ = run(sc)
    a = res.arrays
    assert res.facts["fusion_centre"]["nodes_excluded"] == 2
    # the last packets of 1 and 2 before the outage are of row 4 (tick 5), final there up to row
    # 4 + 1 - L = 1; the shadow (W = 8) makes row 2 final at tick 10: from row 9 on, node 0 alone
    assert np.allclose(a["x_fusion_centre"][9:], a["x_local"][9:, 0], rtol=1e-10, atol=1e-12)
    assert np.allclose(a["P_fusion_centre"][9:], a["P_local"][9:, 0], rtol=1e-10, atol=0)
    assert not np.allclose(a["x_fusion_centre"][8], a["x_local"][8, 0], rtol=1e-6, atol=0)
    # a margin of 6 final rows covers the 6 silent ticks: nobody leaves
    res, _ = run(_path3(["links.overrides.0.outages=[[0.055, 0.115]]",
                         "estimators=[{kind: fusion_centre, at: 0, margin: 6}]"]))
    assert res.facts["fusion_centre"]["nodes_excluded"] == 0
    assert res.facts["fusion_centre"]["rows_carried"] == 4 + 6


# ---------------------------------------------------------------------------- NEES
def test_nees_in_the_chi_square_band_with_latency():
    """40 runs x 200 ticks, d_t = 4: the NEES averaged over runs stays in its 99 % chi-square
    band at (nearly) every tick, and its mean over ticks is in the band."""
    R, K = 40, 200
    sc = paper(["links.default.latency={model: uniform_steps, d_t: 4}", f"steps={K}"])
    nees = np.empty((R, K))
    for run_ in range(R):
        res = dkfsim.run(sc.model_copy(update={"seed": 1000 + run_}))
        e = res.arrays["x_fusion_centre"] - res.arrays["truth"]
        P = res.arrays["P_fusion_centre"]
        nees[run_] = np.einsum("ki,ki->k", e, np.linalg.solve(P, e[..., None])[..., 0])
    nx = 3
    lo, hi = stats.chi2.ppf([0.005, 0.995], R * nx) / R
    per_tick = nees[:, 20:].mean(axis=0)
    assert np.mean((per_tick >= lo) & (per_tick <= hi)) >= 0.95
    assert lo <= per_tick.mean() <= hi
    assert res.facts["fusion_centre"]["stale_rows_used"] > 0


# ------------------------------------------------------------------------ bad input
@pytest.mark.parametrize("entry, words", [
    ("{kind: fusion_centre, at: 12}", ["estimators.0.at", "node 12 does not exist"]),
    ("{kind: fusion_centre, at: one}", ["estimators.0.at"]),
    ("{kind: fusion_centre, at: -1}", ["estimators.0.at"]),
    ("{kind: fusion_centre}", ["estimators.0.at"]),
])
def test_bad_at_is_a_validation_error(entry, words, tmp_path, capsys):
    from dkfsim.cli.main import main
    f = tmp_path / "s.yaml"
    d = yaml.safe_load((ROOT / "scenarios" / "paper_case1.yaml").read_text())
    d["estimators"] = [yaml.safe_load(entry)]
    f.write_text(yaml.safe_dump(d))
    assert main(["validate", str(f)]) == 2
    err = capsys.readouterr().err
    assert str(f) in err and "Traceback" not in err
    for w in words:
        assert w in err, (w, err)


def test_bad_at_messages():
    for entry, words in [
        ({"kind": "fusion_centre", "at": 12}, ["estimators.0.at", "node 12 does not exist"]),
        ({"kind": "fusion_centre", "at": "one"}, ["estimators.0.at"]),
        ({"kind": "fusion_centre", "at": 1.5}, ["estimators.0.at"]),
        ({"kind": "fusion_centre", "at": 1, "margin": -1}, ["estimators.0.margin"]),
    ]:
        with pytest.raises(dkfsim.ScenarioError) as err:
            paper([f"estimators=[{yaml.safe_dump(entry, default_flow_style=True).strip()}]"])
        for w in words:
            assert w in str(err.value), (w, str(err.value))
    with pytest.raises(dkfsim.ScenarioError) as err:
        paper(["estimators=[{kind: fusion_centre, at: 0}, {kind: fusion_centre, at: 3}]"])
    assert "estimators.1" in str(err.value) and "taken" in str(err.value)
    with pytest.raises(dkfsim.ScenarioError) as err:        # links that come and go: refused
        dkfsim.load_scenario(ROOT / "scenarios" / "mobility_crossing.yaml", overrides=[CENTRE % 0])
    assert "estimators.0.kind" in str(err.value) and "does not change" in str(err.value)
    with pytest.raises(dkfsim.ScenarioError) as err:
        paper(["fusion=none"])
    assert "estimators.0" in str(err.value) and "fusion: none" in str(err.value)


# ------------------------------------------------------------- the DKF's queues and channel
@pytest.mark.parametrize("extra, shares", [
    ([], False),                                       # no rate, no channel: nothing to share
    (["links.default.rate=300000"], True),             # the DKF's transmitters
    (["medium={rate: 6e6}"], True),                    # the DKF's channel
])
def test_the_centre_waits_in_the_dkfs_queues(extra, shares):
    """Without a rate or a channel adding a centre changes none of the DKF's numbers (its draws
    are its own); with them its packets wait in the DKF's queues or contend on its channel, so
    the DKF's estimate changes: the centre's load is part of the DKF's cost."""
    base = [ZERO, "buffer_length=3", *extra, "estimators=[{kind: centralized}]"]
    alone = dkfsim.run(dkfsim.load_scenario(ROOT / "scenarios" / "paper_case1.yaml",
                                            overrides=["steps=120", *base]))
    res, _ = run(paper([ZERO, "buffer_length=3", *extra]))
    same = np.array_equal(res.arrays["x_fused"], alone.arrays["x_fused"])
    assert same is not shares
    t = res.traffic["fusion_centre"]
    assert t["sent"] == t["delivered"] + t["lost"] + t["queue_dropped"] + t["crash_dropped"] + t["in_flight"]
    if extra and extra[0].startswith("medium"):
        assert t["collision_lost"] > 0


def test_the_run_table_says_when_the_centre_lost_nodes():
    """``dkfsim run``'s table names a centre that left nodes out (only summary.json said so),
    and says nothing when it kept them all."""
    from dkfsim.report.tables import run_table
    base = ["steps=60", "estimators=[{kind: fusion_centre, at: 0, margin: 0}]"]
    lost = dkfsim.run(dkfsim.load_scenario(ROOT / "scenarios" / "paper_case1.yaml", overrides=base))
    n = lost.facts["fusion_centre"]["nodes_excluded"]
    assert n > 0
    assert f"fusion_centre: {n} of 11 nodes left its fusion" in run_table(lost)
    kept = dkfsim.run(dkfsim.load_scenario(ROOT / "scenarios" / "paper_case1.yaml",
                                           overrides=[*base[:1], "estimators=[{kind: fusion_centre, at: 0}]"]))
    assert kept.facts["fusion_centre"]["nodes_excluded"] == 0
    assert "left its fusion" not in run_table(kept)

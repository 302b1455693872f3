"""The ``ci_consensus`` estimator (dkfsim/estimators/ci_consensus.py, issue 3).

Oracles, each computed here independently of the engine's batched code:

* 0 rounds: every node is its own covariance-form (Joseph) Kalman filter;
* zero latency and many rounds on a well-mixing graph: the nodes agree, and
  (Metropolis weights being doubly stochastic) each equals the filter that
  adds the *average* information ``sum_o omega_o / n`` per row;
* any latency, loss and number of rounds: a slow per-node reference of the
  documented semantics (explicit inverses, step-by-step prediction of stale
  pairs, a packet's latency and loss are the keyed draws of its link at its
  send instant with seq 0: one packet per arc per round instant);
* CI is conservative: mean NEES <= nx (with margin), with and without delays.
"""

from __future__ import annotations

import copy

import numpy as np
import pytest
import reference as ref
from conftest import T2, scenario

from dkfsim.config.plan import RunPlan

TOL = 1e-9
T_NS = int(round(T2 * 1e9))

# K_{3,3}: every node has degree 3, Metropolis weights 1/4, second eigenvalue
# modulus 1/2, so 40 rounds shrink disagreement by 2^-40.
K33 = [[a, b] for a in (0, 1, 2) for b in (3, 4, 5)]


def ci_scenario(n=6, *, rounds=1, steps=60, latency=None, loss=0.0, edges=None, directed=False,
                protocol="tree", seed=1, nx=2, **kw):
    sc = scenario(n, nx=nx, steps=steps, latency=latency, loss=loss, edges=edges, directed=directed,
                  protocol=protocol, fusion="none", seed=seed, **kw)
    sc["estimators"] = [{"kind": "ci_consensus", "rounds": rounds}]
    return sc


def simulate(sc):
    """One run (the DKF and ci_consensus on the same draws): the run's context
    (model, truth, measurements) and the ci_consensus arrays and side facts
    (``_ci_consensus_<fact>``), the dict the old ``ci_consensus(sim)`` returned."""
    import dkfsim
    from dkfsim.engine.driver import Run
    run = Run(dkfsim.load_scenario(copy.deepcopy(sc)))
    res = run.run()
    name = "ci_consensus"
    out = {f"x_{name}": res.arrays[f"x_{name}"], f"P_{name}": res.arrays[f"P_{name}"]}
    for k in ("sent", "delivered", "lost", "in_flight"):
        out[f"_{name}_{k}"] = res.traffic[name][k]
    for k in ("rounds", "used", "stale"):
        out[f"_{name}_{k}"] = res.facts[name][k]
    return run.ctx, out


def model_of(sim):
    s = sim.system
    return (s.Phi, s.Q, s.x0_mean, s.P0, [np.atleast_2d(h) for h in s.H],
            [np.atleast_2d(r) for r in s.R], [np.asarray(y).reshape(sim.K, -1) for y in sim.ys])


def local_filters(sim):
    """(K, n, nx), (K, n, nx, nx): each node's own covariance-form Kalman filter."""
    Phi, Q, x0, P0, Hs, Rs, ys = model_of(sim)
    out = [ref.kalman_filter(Phi, Q, x0, P0, Hs, Rs, ys, lambda r, i=i: [(i, 1.0)])
           for i in range(len(Hs))]
    return np.stack([o[0] for o in out], axis=1), np.stack([o[1] for o in out], axis=1)


# ----------------------------------------------------------------------------
# the slow reference of the documented semantics
# ----------------------------------------------------------------------------

def link_draws(sim, u, v, times):
    """Latency (ns) and lost flag of the packets sent on link u -> v at the
    instants ``times`` (ns), each the only packet (seq 0) its sender put on
    the link at that instant: keyed draws, pure functions of (the link's named
    key, the send instant, seq), as every link of dkfsim draws them."""
    from dkfsim.core.streams import key64, keyed_uniform
    spec = sim.scenario.link_spec(u, v)
    lat_key = key64(sim.seed, "link", u, v, "latency")
    loss_key = key64(sim.seed, "link", u, v, "loss")
    u_lat = np.array([keyed_uniform(lat_key, t, 0) for t in times])
    lat = np.asarray(spec.latency.from_uniform(u_lat, T_NS), dtype=np.int64).reshape(len(times))
    if spec.loss > 0:
        lost = np.array([keyed_uniform(loss_key, t, 0) for t in times]) < spec.loss
    else:
        lost = np.zeros(len(times), dtype=bool)
    return lat, lost


def reference_ci(sim, rounds):
    """Per node, per instant, plain loops; returns x (K, n, nx), P (K, n, nx, nx)."""
    Phi, Q, x0, P0, Hs, Rs, ys = model_of(sim)
    inv = np.linalg.inv
    n, nx, K = len(Hs), Phi.shape[0], sim.K
    dt = T_NS // rounds
    arcs = list(RunPlan(sim.scenario).exchange.arcs)
    indeg = [sum(1 for _, v in arcs if v == i) for i in range(n)]
    n_instants = K * rounds                      # packets sent per arc
    time_of = lambda g: T_NS + g * dt            # noqa: E731
    draws = {a: link_draws(sim, a[0], a[1], [time_of(g) for g in range(n_instants)]) for a in arcs}
    packets = {a: [] for a in arcs}             # (stamp, arrival time, Om, q)
    Om = [None] * n
    q = [None] * n
    x = [np.array(x0, float) for _ in range(n)]
    P = [np.array(P0, float) for _ in range(n)]
    xs, Ps = np.zeros((K, n, nx)), np.zeros((K, n, nx, nx))

    def predict(Om_j, q_j, steps):
        Pj = inv(Om_j)
        xj = Pj @ q_j
        for _ in range(steps):
            xj = Phi @ xj
            Pj = Phi @ Pj @ Phi.T + Q
        Oj = inv(Pj)
        return Oj, Oj @ xj

    def average(g, tick):
        now = time_of(g)
        new = []
        for i in range(n):
            acc_O, acc_q, self_w = np.zeros((nx, nx)), np.zeros(nx), 1.0
            for a in arcs:
                if a[1] != i:
                    continue
                usable = [p for p in packets[a] if p[0] < g and p[1] <= now]
                if not usable:
                    continue
                stamp, _, O_j, q_j = max(usable, key=lambda p: p[0])
                age = tick - (stamp // rounds + 1)
                assert age >= 0
                if age > 0:
                    O_j, q_j = predict(O_j, q_j, age)
                w = 1.0 / (1 + max(indeg[a[0]], indeg[i]))
                acc_O += w * O_j
                acc_q += w * q_j
                self_w -= w
            new.append((self_w * Om[i] + acc_O, self_w * q[i] + acc_q))
        for i, (O_i, q_i) in enumerate(new):
            Om[i], q[i] = O_i, q_i
            P[i] = inv(O_i)
            x[i] = P[i] @ q_i

    for g in range(n_instants + 1):
        k, l = g // rounds + 1, g % rounds
        if l == 0 and k > 1:
            average(g, k - 1)
            for i in range(n):
                xs[k - 2, i], Ps[k - 2, i] = x[i], P[i]
        elif l > 0:
            average(g, k)
        if k > K:
            break
        if l == 0:
            for i in range(n):
                Pp = Phi @ P[i] @ Phi.T + Q
                Ppi = inv(Pp)
                RiH = np.linalg.solve(Rs[i], Hs[i])
                Om[i] = Ppi + Hs[i].T @ RiH
                q[i] = Ppi @ (Phi @ x[i]) + RiH.T @ ys[i][k - 1]
        for a in arcs:
            lat, lost = draws[a]
            if not lost[g]:
                packets[a].append((g, time_of(g) + int(lat[g]), Om[a[0]].copy(), q[a[0]].copy()))
    return xs, Ps


# ----------------------------------------------------------------------------
# tests
# ----------------------------------------------------------------------------

@pytest.mark.parametrize("nx,seed", [(2, 1), (3, 4)])
def test_zero_rounds_is_each_nodes_local_filter(nx, seed):
    sim, out = simulate(ci_scenario(6, rounds=0, steps=80, nx=nx, seed=seed,
                                    latency={"model": "uniform_steps", "d_t": 2}))
    xl, Pl = local_filters(sim)
    x, P = out["x_ci_consensus"], out["P_ci_consensus"]
    assert x.shape == (sim.K, 6, nx) and P.shape == (sim.K, 6, nx, nx)
    for i in range(6):
        ref.assert_close(x[:, i], xl[:, i], f"node {i} x vs its local KF", TOL)
        ref.assert_close(P[:, i], Pl[:, i], f"node {i} P vs its local KF", TOL)
    # also the package's own batched information filter
    from dkfsim.estimators.window import batched_filter
    s = sim.system
    xb, _ = batched_filter(s.Phi, s.Q, s.x0_mean, s.P0, sim.info.omega, sim.info.theta)
    ref.assert_close(x, xb, "x vs batched_filter", TOL)
    assert out["_ci_consensus_sent"] == 0


def test_many_rounds_zero_latency_agree_on_the_average_information_filter():
    n, rounds = 6, 40
    sim, out = simulate(ci_scenario(n, rounds=rounds, steps=40, edges=K33, protocol="flood"))
    x, P = out["x_ci_consensus"], out["P_ci_consensus"]
    # agreement
    scale = np.abs(x).max(axis=(1, 2), keepdims=True)
    assert (np.abs(x - x.mean(axis=1, keepdims=True)) / scale).max() < 1e-6
    assert (np.abs(P - P.mean(axis=1, keepdims=True)) / np.abs(P).max()).max() < 1e-6
    # the agreed value: every sensor's information with weight 1/n
    Phi, Q, x0, P0, Hs, Rs, ys = model_of(sim)
    xa, Pa = ref.kalman_filter(Phi, Q, x0, P0, Hs, Rs, ys, lambda r: [(o, 1.0 / n) for o in range(n)])
    for i in range(n):
        ref.assert_close(x[:, i], xa, f"node {i} x vs the 1/n-information filter", 1e-8)
        ref.assert_close(P[:, i], Pa, f"node {i} P vs the 1/n-information filter", 1e-8)
    # one packet per arc per round, all delivered at once
    sent = sim.K * rounds * 2 * len(K33)
    assert out["_ci_consensus_sent"] == sent == out["_ci_consensus_delivered"]
    assert out["_ci_consensus_stale"] == 0


def test_one_round_is_not_consensus():
    """The agreement above is the rounds' doing: one round leaves nodes apart."""
    _, out = simulate(ci_scenario(6, rounds=1, steps=40, edges=K33, protocol="flood"))
    x = out["x_ci_consensus"]
    assert np.abs(x - x.mean(axis=1, keepdims=True)).max() > 1e-3


CASES = {
    "zero latency, 1 round": dict(rounds=1),
    "latency = one round interval (boundary), 2 rounds": dict(
        rounds=2, latency={"model": "constant", "value": T2 / 2}),
    "1.5 ticks constant, 1 round": dict(rounds=1, latency={"model": "constant", "value": 1.5 * T2}),
    "uniform_steps d_t=3, loss 0.2, 2 rounds": dict(
        rounds=2, latency={"model": "uniform_steps", "d_t": 3}, loss=0.2),
    "continuous uniform, 4 rounds, override": dict(
        rounds=4, latency={"model": "uniform", "low": 0.0, "high": 0.23},
        overrides=[{"link": [0, 1], "latency": {"model": "constant", "value": 0.35}, "loss": 0.5}],
        edges=[[0, 1], [1, 2], [1, 3], [3, 4], [0, 5]]),
    "digraph flood, uniform_steps, 2 rounds": dict(
        rounds=2, latency={"model": "uniform_steps", "d_t": 2}, loss=0.1, directed=True,
        protocol="flood", edges=[[0, 1], [1, 2], [2, 3], [3, 4], [4, 5], [5, 0], [0, 3], [4, 1]]),
}


@pytest.mark.parametrize("case", list(CASES))
def test_against_the_slow_reference(case):
    kw = dict(CASES[case])
    rounds = kw["rounds"]
    sim, out = simulate(ci_scenario(6, steps=30, seed=3, **kw))
    xr, Pr = reference_ci(sim, rounds)
    ref.assert_close(out["x_ci_consensus"], xr, f"{case}: x", TOL)
    ref.assert_close(out["P_ci_consensus"], Pr, f"{case}: P", TOL)
    c = {k: out[f"_ci_consensus_{k}"] for k in ("sent", "delivered", "lost", "in_flight")}
    assert c["sent"] == sim.K * rounds * len(RunPlan(sim.scenario).exchange.arcs)
    assert c["sent"] == c["delivered"] + c["lost"] + c["in_flight"]
    if kw.get("loss"):
        assert c["lost"] > 0


def test_reference_detects_a_missing_prediction():
    """The reference test can fail: using a stale pair without predicting it
    forward gives a different answer (so predict-forward is exercised)."""
    from dkfsim.estimators import ci_consensus as consensus
    sc = ci_scenario(6, steps=30, seed=3, rounds=1, latency={"model": "constant", "value": 1.5 * T2})
    sim, out = simulate(sc)
    assert out["_ci_consensus_stale"] > 0
    orig = consensus._Powers.get

    def no_prediction(self, m):
        F, Qm = orig(self, m)
        return np.broadcast_to(np.eye(F.shape[-1]), F.shape), np.zeros_like(Qm)

    consensus._Powers.get = no_prediction
    try:
        _, bad = simulate(sc)
    finally:
        consensus._Powers.get = orig
    assert ref.rel_err(bad["x_ci_consensus"], out["x_ci_consensus"]) > 1e-6


def test_latency_longer_than_the_run_is_the_local_filter():
    steps = 25
    sim, out = simulate(ci_scenario(5, rounds=2, steps=steps,
                                    latency={"model": "constant", "value": (steps + 3) * T2}))
    xl, Pl = local_filters(sim)
    ref.assert_close(out["x_ci_consensus"], xl, "x vs local KFs", TOL)
    ref.assert_close(out["P_ci_consensus"], Pl, "P vs local KFs", TOL)
    assert out["_ci_consensus_delivered"] == 0
    assert out["_ci_consensus_in_flight"] == out["_ci_consensus_sent"] > 0
    assert out["_ci_consensus_used"] == 0


def test_same_seed_same_arrays_other_seed_other_arrays():
    sc = ci_scenario(6, rounds=2, steps=40, latency={"model": "uniform_steps", "d_t": 3}, loss=0.1)
    _, a = simulate(sc)
    _, b = simulate(sc)
    for key in ("x_ci_consensus", "P_ci_consensus"):
        assert np.array_equal(a[key], b[key])
    facts = lambda out: {k: v for k, v in out.items() if k.startswith("_")}  # noqa: E731
    assert facts(a) == facts(b)
    sc2 = copy.deepcopy(sc)
    sc2["links"]["default"]["loss"] = 0.3      # other loss draws, same measurements
    _, c = simulate(sc2)
    assert not np.array_equal(a["x_ci_consensus"], c["x_ci_consensus"])


def mean_nees(x, P, truth, burn_in):
    e = truth[burn_in:, None, :] - x[burn_in:]
    return float(np.einsum("...i,...i->...", e, np.linalg.solve(P[burn_in:], e[..., None])[..., 0]).mean())


@pytest.mark.parametrize("kw", [
    dict(rounds=20, edges=K33, protocol="flood"),
    dict(rounds=2, latency={"model": "uniform_steps", "d_t": 3}, loss=0.2),
], ids=["zero latency, 20 rounds", "delays and loss, 2 rounds"])
def test_ci_is_conservative(kw):
    """CI's covariance bounds the true error covariance: mean NEES <= nx, with a
    margin for sampling noise (several seeds, nodes and 300 rows)."""
    nees = []
    for seed in (11, 12, 13):
        sim, out = simulate(ci_scenario(6, steps=300, seed=seed, **kw))
        nees.append(mean_nees(out["x_ci_consensus"], out["P_ci_consensus"], sim.truth, 30))
    nx = 2
    assert np.mean(nees) <= nx * 1.15, nees
    # and it is not vacuous: an overconfident filter (P / 4) fails the bound
    assert 4 * np.mean(nees) > nx * 1.15


def test_rounds_must_divide_the_period():
    from dkfsim.core.errors import ScenarioError
    with pytest.raises(ScenarioError, match="consensus_rounds"):
        simulate(ci_scenario(4, rounds=3, steps=5))


def test_end_to_end_through_run():
    import dkfsim
    sc = ci_scenario(6, rounds=2, steps=50, latency={"model": "uniform_steps", "d_t": 2})
    old = {k: v for k, v in copy.deepcopy(sc).items() if k != "estimators"}
    old["baselines"] = ["ci_consensus"]          # the old spelling, converted
    old["consensus_rounds"] = sc["estimators"][0]["rounds"]
    res = dkfsim.run(dkfsim.load_scenario(old))
    _, direct = simulate(sc)
    assert np.array_equal(np.asarray(res["x_ci_consensus"]), direct["x_ci_consensus"])
    assert res.traffic["ci_consensus"]["sent"] == direct["_ci_consensus_sent"] > 0
    assert "ci_consensus" in res.metrics()

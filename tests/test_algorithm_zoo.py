"""The consensus-family estimators kcf, icf, diffusion_kf, hcmci (issue 12, docs/consensus.md).

Oracles, each computed here independently of the package's batched code:

* the centralized Kalman filter (tests/reference.py, covariance form) for the
  diffusion KF and the ICF on a complete graph;
* the papers' equations written out per node with explicit inverses and
  loops: Cattivelli & Sayed's sequential incremental update and diffusion
  step, Olfati-Saber's KCF update, neighbourhood Kalman filters;
* Monte Carlo intervals (ICF rounds; HCMCI's ANEES: the t-interval over runs);
* the links' keyed draws for the lost and late counts.
"""

from __future__ import annotations

import copy

import numpy as np
import pytest
import reference as ref
from conftest import T2, scenario
from scipy.stats import t as student_t
from test_consensus import link_draws, model_of

TOL = 1e-9
T_NS = int(round(T2 * 1e9))
ZOO = ("kcf", "icf", "diffusion_kf", "hcmci")


def complete(n):
    return [[a, b] for a in range(n) for b in range(a + 1, n)]


def path(n):
    return [[a, a + 1] for a in range(n - 1)]


def zoo_scenario(n, estimators, *, edges, steps=40, seed=2, **kw):
    sc = scenario(n, edges=edges, steps=steps, seed=seed, protocol="flood", fusion="none", **kw)
    sc["estimators"] = [dict(e) for e in estimators]
    del sc["baselines"]
    return sc


def simulate(sc):
    import dkfsim
    from dkfsim.engine.driver import Run
    run = Run(dkfsim.load_scenario(copy.deepcopy(sc)))
    return run.ctx, run.run()


def xP(res, name):
    return np.asarray(res.arrays[f"x_{name}"]), np.asarray(res.arrays[f"P_{name}"])


def neighbours(n, edges):
    nb = [set() for _ in range(n)]
    for a, b in edges:
        nb[a].add(b)
        nb[b].add(a)
    return [sorted(s) for s in nb]


def metropolis(n, edges):
    """C[i, j]: 1 / (1 + max(d_i, d_j)) for neighbours, the rest on the diagonal."""
    nb = neighbours(n, edges)
    C = np.zeros((n, n))
    for i in range(n):
        for j in nb[i]:
            C[i, j] = 1.0 / (1 + max(len(nb[i]), len(nb[j])))
        C[i, i] = 1.0 - C[i].sum()
    return C


def centralized(sim):
    Phi, Q, x0, P0, Hs, Rs, ys = model_of(sim)
    every = [(o, 1.0) for o in range(len(Hs))]
    return ref.kalman_filter(Phi, Q, x0, P0, Hs, Rs, ys, lambda r: every)


# ----------------------------------------------------------------------------
# diffusion KF
# ----------------------------------------------------------------------------

def test_diffusion_on_a_complete_graph_is_the_centralized_filter():
    n = 5
    sim, res = simulate(zoo_scenario(n, [{"kind": "diffusion_kf"}], edges=complete(n)))
    x, P = xP(res, "diffusion_kf")
    xc, Pc = centralized(sim)
    for i in range(n):
        ref.assert_close(x[:, i], xc, f"node {i} x vs centralized", TOL)
        ref.assert_close(P[:, i], Pc, f"node {i} P vs centralized", TOL)


def reference_diffusion(sim, edges, C):
    """Cattivelli & Sayed (TAC 2010) Algorithm 1, per node: sequential incremental
    update over the closed neighbourhood, then x_i = sum_l c_il psi_l."""
    Phi, Q, x0, P0, Hs, Rs, ys = model_of(sim)
    n, K, nx = len(Hs), sim.K, Phi.shape[0]
    nb = neighbours(n, edges)
    x = [np.array(x0, float) for _ in range(n)]
    P = [np.array(P0, float) for _ in range(n)]
    xs, Ps = np.zeros((K, n, nx)), np.zeros((K, n, nx, nx))
    for r in range(K):
        psi, Ppsi = [], []
        for i in range(n):
            xi, Pi = Phi @ x[i], Phi @ P[i] @ Phi.T + Q
            for l in [i] + nb[i]:
                H, R = Hs[l], Rs[l]
                G = Pi @ H.T @ np.linalg.inv(R + H @ Pi @ H.T)
                xi = xi + G @ (ys[l][r] - H @ xi)
                Pi = Pi - G @ H @ Pi
            psi.append(xi)
            Ppsi.append(Pi)
        for i in range(n):
            x[i] = sum(C[i, l] * psi[l] for l in range(n))
            P[i] = Ppsi[i]
            xs[r, i], Ps[r, i] = x[i], P[i]
    return xs, Ps


@pytest.mark.parametrize("weights", ["metropolis", "uniform"])
def test_diffusion_on_a_path_follows_the_papers_equations(weights):
    n, edges = 4, path(4)
    sim, res = simulate(zoo_scenario(n, [{"kind": "diffusion_kf", "weights": weights}], edges=edges))
    if weights == "metropolis":
        C = metropolis(n, edges)
    else:
        C = np.zeros((n, n))
        for i, nbi in enumerate(neighbours(n, edges)):
            C[i, [i] + nbi] = 1.0 / (len(nbi) + 1)
    xr, Pr = reference_diffusion(sim, edges, C)
    x, P = xP(res, "diffusion_kf")
    ref.assert_close(x, xr, "x vs the paper's equations", TOL)
    ref.assert_close(P, Pr, "P vs the paper's equations", TOL)
    # the diffusion step matters: without it (C = I) the answer differs
    xi, _ = reference_diffusion(sim, edges, np.eye(n))
    assert ref.rel_err(xi, xr) > 1e-4


# ----------------------------------------------------------------------------
# ICF
# ----------------------------------------------------------------------------

def test_icf_complete_graph_one_round_is_the_centralized_filter():
    n = 5
    assert np.allclose(metropolis(n, complete(n)), 1.0 / n)     # uniform weights 1/N
    sim, res = simulate(zoo_scenario(n, [{"kind": "icf", "rounds": 1}], edges=complete(n)))
    x, P = xP(res, "icf")
    xc, Pc = centralized(sim)
    for i in range(n):
        ref.assert_close(x[:, i], xc, f"node {i} x vs centralized", TOL)
        ref.assert_close(P[:, i], Pc, f"node {i} P vs centralized", TOL)


def test_icf_on_a_path_approaches_the_centralized_mse_with_more_rounds():
    """Paired over the same runs: excess MSE over the centralized filter per run; where
    the 95 % interval of the difference between two round counts excludes 0, more
    rounds must be the better one, and K = 1 vs 64 must separate."""
    n, steps, burn, runs = 5, 60, 15, 6
    Ks = (1, 4, 16, 64)
    est = [{"kind": "icf", "rounds": k, "name": f"icf{k}"} for k in Ks] + [{"kind": "centralized"}]
    excess = np.zeros((len(Ks), runs))
    for r in range(runs):
        sim, res = simulate(zoo_scenario(n, est, edges=path(n), steps=steps, seed=40 + r))
        truth = sim.truth[burn:]
        xc = np.asarray(res.arrays["x_centralized"])[burn:]
        mse_c = np.mean((xc - truth) ** 2)
        for a, k in enumerate(Ks):
            x = np.asarray(res.arrays[f"x_icf{k}"])[burn:]
            excess[a, r] = np.mean((x - truth[:, None, :]) ** 2) - mse_c
    tq = student_t.ppf(0.975, runs - 1)
    separated = 0
    for a in range(len(Ks)):
        for b in range(a + 1, len(Ks)):
            d = excess[a] - excess[b]
            half = tq * d.std(ddof=1) / np.sqrt(runs)
            if abs(d.mean()) > half:
                separated += 1
                assert d.mean() > 0, (Ks[a], Ks[b], d.mean(), half)
    assert separated >= 1
    d = excess[0] - excess[-1]
    assert d.mean() > tq * d.std(ddof=1) / np.sqrt(runs), "K = 1 vs 64 should separate"


# ----------------------------------------------------------------------------
# KCF
# ----------------------------------------------------------------------------

KCF_EDGES = [[0, 1], [1, 2], [1, 3], [3, 4], [4, 5], [2, 4]]


def test_kcf_eps_zero_is_each_nodes_neighbourhood_filter():
    n = 6
    sim, res = simulate(zoo_scenario(n, [{"kind": "kcf", "eps": 0}], edges=KCF_EDGES))
    Phi, Q, x0, P0, Hs, Rs, ys = model_of(sim)
    x, P = xP(res, "kcf")
    for i, nbi in enumerate(neighbours(n, KCF_EDGES)):
        use = [(o, 1.0) for o in [i] + nbi]
        xr, Pr = ref.kalman_filter(Phi, Q, x0, P0, Hs, Rs, ys, lambda _r, use=use: use)
        ref.assert_close(x[:, i], xr, f"node {i} x vs its neighbourhood KF", TOL)
        ref.assert_close(P[:, i], Pr, f"node {i} P vs its neighbourhood KF", TOL)


def reference_kcf(sim, edges, eps):
    """Olfati-Saber (CDC 2009) Algorithm 1 per node, explicit inverses."""
    Phi, Q, x0, P0, Hs, Rs, ys = model_of(sim)
    inv = np.linalg.inv
    n, K, nx = len(Hs), sim.K, Phi.shape[0]
    nb = neighbours(n, edges)
    xbar = [Phi @ np.array(x0, float) for _ in range(n)]
    Pbar = [Phi @ np.array(P0, float) @ Phi.T + Q for _ in range(n)]
    xs, Ps = np.zeros((K, n, nx)), np.zeros((K, n, nx, nx))
    for r in range(K):
        new = []
        for i in range(n):
            J = [i] + nb[i]
            y = sum(Hs[j].T @ inv(Rs[j]) @ ys[j][r] for j in J)
            S = sum(Hs[j].T @ inv(Rs[j]) @ Hs[j] for j in J)
            M = inv(inv(Pbar[i]) + S)
            gamma = eps / (1 + np.sqrt(np.trace(M.T @ M)))
            xh = xbar[i] + M @ (y - S @ xbar[i]) + gamma * M @ sum(xbar[j] - xbar[i] for j in nb[i])
            new.append((xh, M))
        for i, (xh, M) in enumerate(new):
            xs[r, i], Ps[r, i] = xh, M
            xbar[i], Pbar[i] = Phi @ xh, Phi @ M @ Phi.T + Q
    return xs, Ps


def test_kcf_follows_the_papers_update():
    n, eps = 6, 0.5
    sim, res = simulate(zoo_scenario(n, [{"kind": "kcf", "eps": eps}], edges=KCF_EDGES))
    xr, Pr = reference_kcf(sim, KCF_EDGES, eps)
    x, P = xP(res, "kcf")
    ref.assert_close(x, xr, "x vs the paper's KCF", TOL)
    ref.assert_close(P, Pr, "P vs the paper's KCF", TOL)
    x0r, _ = reference_kcf(sim, KCF_EDGES, 0.0)
    assert ref.rel_err(x0r, xr) > 1e-4          # the consensus term is exercised


# ----------------------------------------------------------------------------
# HCMCI
# ----------------------------------------------------------------------------

def nees(x, P, truth):
    e = truth[:, None, :] - x
    return np.einsum("...i,...i->...", e, np.linalg.solve(P, e[..., None])[..., 0])


def test_hcmci_omega_one_is_stable_and_conservative_where_a_node_alone_is_unobservable():
    """Node 1 measures velocity only (position unobservable alone); on a 6-node tree
    HCMCI with omega = 1 is stable (the last block's MSE within a factor 2 of the
    first block's after burn-in) and conservative: for each node, the whole 95 % Student-t
    interval over the runs of the per-run time-averaged NEES (the ANEES test of
    docs/statistics.md, `anees_ci95`) lies below nx.  (The per-tick chi-square band is for the
    mean NEES at one tick, not for a time average.)  omega = n is printed only."""
    n, nx, steps, burn, runs = 6, 2, 300, 50, 10
    edges = [[0, 1], [1, 2], [2, 3], [1, 4], [4, 5]]
    est = [{"kind": "hcmci", "omega": 1, "name": "h1"}, {"kind": "hcmci", "omega": "n", "name": "hn"}]
    per_run = {"h1": np.zeros((runs, n)), "hn": np.zeros((runs, n))}     # time-averaged NEES
    mse_blocks = []
    for r in range(runs):
        sim, res = simulate(zoo_scenario(n, est, edges=edges, steps=steps, seed=60 + r))
        assert np.allclose(np.atleast_2d(sim.system.H[1]), [[0.0, 1.0]])
        for name in per_run:
            x, P = xP(res, name)
            per_run[name][r] = nees(x[burn:], P[burn:], sim.truth[burn:]).mean(axis=0)
        x, _ = xP(res, "h1")
        e2 = ((x[burn:] - sim.truth[burn:, None, :]) ** 2).sum(axis=-1)
        mse_blocks.append(e2)
    e2 = np.mean(mse_blocks, axis=0)                 # (ticks, nodes)
    block = (steps - burn) // 5
    first, last = e2[:block].mean(axis=0), e2[-block:].mean(axis=0)
    assert np.all(last < 2.0 * first) and np.all(np.isfinite(last)), (first, last)
    # per node: Student-t interval over the runs of the per-run time averages
    half = student_t.ppf(0.975, runs - 1) * per_run["h1"].std(axis=0, ddof=1) / np.sqrt(runs)
    anees1 = per_run["h1"].mean(axis=0)
    assert np.all(anees1 + half < nx), (anees1 - half, anees1 + half)
    print("hcmci ANEES per node: omega=1", np.round(anees1, 3), "+-", np.round(half, 3),
          "omega=n", np.round(per_run["hn"].mean(axis=0), 3))


# ----------------------------------------------------------------------------
# all four: workers, traffic, latency and loss
# ----------------------------------------------------------------------------

ALL = [{"kind": "kcf"}, {"kind": "icf", "rounds": 2}, {"kind": "diffusion_kf"},
       {"kind": "hcmci", "rounds": 2}]
CYCLE = [[0, 1], [1, 2], [2, 3], [3, 4], [4, 0], [1, 3]]
SLOTS = {"kcf": 1, "icf": 2, "diffusion_kf": 2, "hcmci": 2}


def test_results_do_not_depend_on_worker_count():
    from dkfsim import load_scenario
    from dkfsim.experiments.montecarlo import montecarlo
    sc = load_scenario(zoo_scenario(5, ALL, edges=CYCLE, steps=30,
                                    latency={"model": "uniform_steps", "d_t": 2}, loss=0.1))
    a = montecarlo(sc, 3, jobs=1)
    b = montecarlo(sc, 3, jobs=2)
    assert len(a.rows) == len(b.rows) > 0
    for ra, rb in zip(a.rows, b.rows):
        assert {k: v for k, v in ra.items() if "time" not in k} == \
               {k: v for k, v in rb.items() if "time" not in k}
    np.testing.assert_array_equal(a.mse, b.mse)


def test_traffic_adds_up_per_link_over_the_full_topology():
    """Zero latency, no loss: one message per directed link of the full topology (not the
    spanning tree the tree protocol runs on) per sub-slot; per-link rows sum to the totals."""
    n, steps = 5, 20
    sc = zoo_scenario(n, ALL, edges=CYCLE, steps=steps)
    sc["protocol"], sc["spanning_tree"] = "tree", True
    sim, res = simulate(sc)
    arcs = sorted([(a, b) for a, b in CYCLE] + [(b, a) for a, b in CYCLE])
    for kind, slots in SLOTS.items():
        tr = res.traffic[kind]
        rows = tr["per_link"]
        assert sorted(tuple(r["link"]) for r in rows) == arcs
        for key in ("sent", "delivered", "lost", "bytes", "in_flight"):
            assert sum(r[key] for r in rows) == tr[key], (kind, key)
        assert all(r["sent"] == steps * slots for r in rows), kind
        assert tr["delivered"] == tr["sent"] and tr["late"] == 0
        assert tr["sent"] / steps == len(arcs) * slots          # messages per tick
        assert tr["bytes"] == sum(r["bytes"] for r in rows) > 0


def deadline_ns(kind, g):
    """Last usable instant of a message sent at round g (docs/consensus.md)."""
    slots = SLOTS[kind]
    dt = T_NS // slots
    if kind == "diffusion_kf":
        return T_NS + (g + 1) * dt           # the next sub-slot
    return (g // slots + 2) * T_NS           # the end of its tick, t_{k+1}


def test_under_latency_and_loss_lost_and_late_match_the_links_draws():
    n, steps = 5, 40
    sc = zoo_scenario(n, ALL, edges=CYCLE, steps=steps, seed=7,
                      latency={"model": "uniform", "low": 0.0, "high": 0.25}, loss=0.15)
    sim, res = simulate(sc)
    arcs = sorted([(a, b) for a, b in CYCLE] + [(b, a) for a, b in CYCLE])
    until = (steps + 1) * T_NS
    for kind, slots in SLOTS.items():
        dt = T_NS // slots
        times = [T_NS + g * dt for g in range(steps * slots)]
        lost = late = delivered = 0
        for u, v in arcs:
            lat, lo = link_draws(sim, u, v, times)
            for g, t in enumerate(times):
                if lo[g]:
                    lost += 1
                    continue
                arrive = t + int(lat[g])
                if arrive > until:
                    continue
                delivered += 1
                late += arrive > deadline_ns(kind, g)
        tr = res.traffic[kind]
        assert (tr["lost"], tr["delivered"], tr["late"]) == (lost, delivered, late), kind
        assert late > 0 and lost > 0
        x, P = xP(res, kind)
        assert np.all(np.isfinite(x)) and np.all(np.isfinite(P))


def test_rounds_not_dividing_the_period_are_rejected():
    from dkfsim.core.errors import ScenarioError
    for est in ({"kind": "icf", "rounds": 3}, {"kind": "hcmci", "rounds": 3}):
        with pytest.raises(ScenarioError, match="whole nanoseconds"):
            simulate(zoo_scenario(4, [est], edges=path(4), steps=5))
    with pytest.raises(ScenarioError, match="omega"):
        simulate(zoo_scenario(4, [{"kind": "hcmci", "omega": 5}], edges=path(4), steps=5))


def test_list_estimators_shows_them(capsys):
    from dkfsim.cli.main import main
    assert main(["list", "estimators"]) in (0, None)
    out = capsys.readouterr().out
    for kind in ZOO:
        assert f"  {kind} " in out, kind


def test_icf_is_hcmci_with_omega_n_even_under_delays_and_loss():
    """Algebra: N * avg(Jbar/N + U) = avg(Jbar) + N avg(U), so with the same weights and the
    same packets ICF equals HCMCI with omega = n (two separate implementations)."""
    sc = zoo_scenario(5, [{"kind": "icf", "rounds": 2}, {"kind": "hcmci", "rounds": 2, "omega": "n"}],
                      edges=CYCLE, steps=40, seed=9, latency={"model": "uniform_steps", "d_t": 1}, loss=0.1)
    _, res = simulate(sc)
    xi, Pi = xP(res, "icf")
    xh, Ph = xP(res, "hcmci")
    ref.assert_close(xi, xh, "icf vs hcmci(omega=n) x", 1e-8)
    ref.assert_close(Pi, Ph, "icf vs hcmci(omega=n) P", 1e-8)
    assert res.traffic["icf"]["late"] > 0

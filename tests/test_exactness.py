"""Exactness of the anti-delay DKF (docs/design.md §6).

The first group checks the reference implementations themselves (no engine
needed); the second runs dkfsim and compares every node's estimates with the
reference: the centralized Kalman filter where docs/design.md §6 promises equality
(zero latency; final rows under bounded latency with L = d_t d_g + 1), and
otherwise the window rule computed from the run's own ``arrival`` log.
"""

from __future__ import annotations

import numpy as np
import pytest
import reference as ref
from conftest import diameter, distances, run_scenario, scc_digraph_edges, scenario, tree_edges, tree_path

TOL = 1e-9


# ============================================================================
# self-tests of the references
# ============================================================================

@pytest.mark.parametrize("seed", [0, 1])
def test_ref_information_form_equals_covariance_form(seed):
    arrays, _ = ref.synthetic_arrays(seed, n=5, K=30, nx=2 + seed)
    m = ref.model_from_arrays(arrays)
    rng = np.random.default_rng(seed)
    subsets = [[(o, 1.0) for o in range(m.n) if rng.random() < 0.6] for _ in range(m.K)]
    use = lambda r: subsets[r]  # noqa: E731
    xa, Pa = ref.kalman_filter(m.Phi, m.Q, m.x0, m.P0, m.Hs, m.Rs, m.ys, use)
    xb, Pb = ref.kalman_filter(m.Phi, m.Q, m.x0, m.P0, m.Hs, m.Rs, m.ys, use, form="info")
    ref.assert_close(xb, xa, "info-form x vs Joseph x", 1e-11)
    ref.assert_close(Pb, Pa, "info-form P vs Joseph P", 1e-11)
    # a weight of 1 routed through the weighted branch changes nothing either;
    # a weight != 1 does change the estimate (the branch is live)
    xc, _ = ref.kalman_filter(m.Phi, m.Q, m.x0, m.P0, m.Hs, m.Rs, m.ys,
                              lambda r: [(o, 0.5) for o, _ in subsets[r]])
    assert ref.rel_err(xc, xa) > 1e-6


def test_ref_kalman_filter_is_optimal_against_monte_carlo():
    """The textbook KF's P is its true error covariance (checked by Monte
    Carlo on a small system: mean NEES close to nx)."""
    nees = []
    for rep in range(300):
        arrays, _ = ref.synthetic_arrays(1000 + rep, n=3, K=10, nx=2)
        xs, Ps = ref.centralized(arrays)
        e = xs[-1] - arrays["truth"][-1]
        nees.append(e @ np.linalg.solve(Ps[-1], e))
    # chi-square(2) mean 2, sd of the mean of 300 draws = 2/sqrt(300) ~ 0.115
    assert abs(np.mean(nees) - 2.0) < 0.5, np.mean(nees)


@pytest.mark.parametrize("L", [1, 2, 4])
def test_ref_node_estimates_zero_delay_is_centralized(L):
    arrays, _ = ref.synthetic_arrays(3, n=4, K=20, L=L, arrival="zero")
    est = ref.node_estimates(arrays)
    xs, Ps = ref.centralized(arrays)
    for i in range(4):
        ref.assert_close(est["x_local"][:, i], xs, f"x_local node {i}", 1e-11)
        ref.assert_close(est["P_local"][:, i], Ps, f"P_local node {i}", 1e-11)
        ref.assert_close(est["x_final"][:, i], xs, f"x_final node {i}", 1e-11)


def test_ref_node_estimates_own_only_is_local_kf():
    arrays, _ = ref.synthetic_arrays(4, n=4, K=20, L=3, arrival="own")
    m = ref.model_from_arrays(arrays)
    est = ref.node_estimates(arrays)
    for i in range(4):
        xs, Ps = ref.kalman_filter(m.Phi, m.Q, m.x0, m.P0, m.Hs, m.Rs, m.ys, lambda _r, i=i: [(i, 1.0)])
        ref.assert_close(est["x_local"][:, i], xs, f"x_local node {i}", 1e-11)
        ref.assert_close(est["P_local"][:, i], Ps, f"P_local node {i}", 1e-11)


def _brute_force(arrays, i, k):
    """Node i's estimates of rows 0..k-1 at tick k, from the prior, with the
    window rule (docs/design.md §4) written out directly (no chain of finals): O(K^2)."""
    m = ref.model_from_arrays(arrays)

    def use(r):
        cutoff = m.t[k - 1] if r >= k - m.L else m.t[r + m.L - 1]
        return [(o, m.A[i, o]) for o in range(m.n) if m.arrival[i, o, r] <= cutoff]

    ys = [y[:k] for y in m.ys]
    return ref.kalman_filter(m.Phi, m.Q, m.x0, m.P0, m.Hs, m.Rs, ys, use)


@pytest.mark.parametrize("weighted", [False, True])
def test_ref_node_estimates_matches_brute_force(weighted):
    n, K, L = 4, 18, 3
    W = None
    if weighted:
        W = np.random.default_rng(5).uniform(0.2, 1.0, size=(n, n))
        np.fill_diagonal(W, 1.0)
    arrays, _ = ref.synthetic_arrays(5, n=n, K=K, L=L, arrival="random", weights=W)
    est = ref.node_estimates(arrays)
    for i in range(n):
        for r in range(K):
            xs, Ps = _brute_force(arrays, i, r + 1)
            ref.assert_close(est["x_local"][r, i][None], xs[r][None], f"x_local[{r},{i}]", 1e-11)
            ref.assert_close(est["P_local"][r, i][None], Ps[r][None], f"P_local[{r},{i}]", 1e-11)
            xs, _ = _brute_force(arrays, i, min(r + L, K))
            ref.assert_close(est["x_final"][r, i][None], xs[r][None], f"x_final[{r},{i}]", 1e-11)
    # the random arrival pattern must make the nodes differ from each other
    assert ref.rel_err(est["x_local"][:, 0], est["x_local"][:, 1]) > 1e-6


@pytest.mark.parametrize("weighted", [False, True])
def test_ref_error_maps_reproduce_the_actual_errors(weighted):
    """error_maps is exact: x_local - truth == M @ xi for the realised noise."""
    n = 4
    W = None
    if weighted:
        W = np.random.default_rng(6).uniform(0.2, 1.0, size=(n, n))
        np.fill_diagonal(W, 1.0)
    arrays, xi = ref.synthetic_arrays(6, n=n, K=20, L=3, arrival="random", weights=W)
    est = ref.node_estimates(arrays)
    Ms, layout = ref.error_maps(arrays)
    assert layout.D == len(xi)
    for i in range(n):
        err = est["x_local"][:, i] - arrays["truth"]
        pred = np.einsum("rad,d->ra", Ms[:, i], xi)
        ref.assert_close(pred, err, f"error map node {i}", 1e-9)


def test_ref_cross_covariance_of_a_kalman_filter_is_its_P():
    arrays, _ = ref.synthetic_arrays(8, n=3, K=15, L=2, arrival="zero")
    Xi = ref.cross_covariances(arrays)
    est = ref.node_estimates(arrays)
    nx = 2
    for r in range(15):
        P = est["P_local"][r, 0]
        for i in range(3):
            for j in range(3):
                ref.assert_close(Xi[r, i * nx:(i + 1) * nx, j * nx:(j + 1) * nx][None], P[None],
                                 f"C_{i}{j} row {r}", 1e-10)


def test_ref_cross_covariance_of_local_filters_matches_the_known_recursion():
    """Two filters that never exchange data: their cross-covariance obeys
    C = (I-K1 H1)(Phi C Phi' + Q)(I-K2 H2)' (no common measurement)."""
    arrays, _ = ref.synthetic_arrays(9, n=2, K=12, L=1, arrival="own")
    m = ref.model_from_arrays(arrays)
    Xi = ref.cross_covariances(arrays)
    C = m.P0.copy()
    P = [m.P0.copy(), m.P0.copy()]
    for r in range(m.K):
        IKH = []
        for i in range(2):
            Pp = m.Phi @ P[i] @ m.Phi.T + m.Q
            H, R = m.Hs[i], m.Rs[i]
            G = Pp @ H.T @ np.linalg.inv(H @ Pp @ H.T + R)
            IKH.append(np.eye(2) - G @ H)
            P[i] = IKH[i] @ Pp @ IKH[i].T + G @ R @ G.T
        C = IKH[0] @ (m.Phi @ C @ m.Phi.T + m.Q) @ IKH[1].T
        ref.assert_close(Xi[r, 0:2, 2:4][None], C[None], f"C_01 row {r}", 1e-10)
        ref.assert_close(Xi[r, 0:2, 0:2][None], P[0][None], f"C_00 row {r}", 1e-10)


def test_ref_fuse_independent_estimates():
    rng = np.random.default_rng(1)
    nx = 3
    Ps = []
    for _ in range(3):
        B = rng.normal(size=(nx, nx))
        Ps.append(B @ B.T + 0.5 * np.eye(nx))
    Xi = ref._block_diag(Ps)
    xs = rng.normal(size=(3, nx))
    xf, Pf, G = ref.fuse(Xi, xs, nx)
    Pinv = sum(np.linalg.inv(P) for P in Ps)
    P_exp = np.linalg.inv(Pinv)
    x_exp = P_exp @ sum(np.linalg.solve(P, x) for P, x in zip(Ps, xs))
    ref.assert_close(Pf[None], P_exp[None], "fused P (independent)", 1e-6)
    ref.assert_close(xf[None], x_exp[None], "fused x (independent)", 1e-6)
    np.testing.assert_allclose(G.reshape(3, nx, nx).sum(axis=0), np.eye(nx), atol=1e-12)
    # diagonal variant: per-component scalar weights, block-diagonal Gamma
    xd, Pd, Gd = ref.fuse(Xi, xs, nx, "diagonal")
    for b in Gd.reshape(3, nx, nx):
        assert np.allclose(b, np.diag(np.diag(b)), atol=1e-14)
    assert np.trace(Pd) >= np.trace(Pf) - 1e-12
    # with diagonal covariances both variants coincide (up to the different
    # regularisation: delta vs per-component delta_c)
    Xd = ref._block_diag([np.diag(np.diag(P)) for P in Ps])
    a = ref.fuse(Xd, xs, nx)
    b = ref.fuse(Xd, xs, nx, "diagonal")
    ref.assert_close(a[0][None], b[0][None], "matrix vs diagonal on diagonal Xi", 1e-6)
    # ... and the diagonal variant is the closed form w_ic ~ 1/(P_i[c,c] + delta_c)
    v = np.array([np.diag(P) for P in Ps])           # (n, nx)
    dc = 1e-8 * v.sum(axis=0) / 3
    w = 1.0 / (v + dc)
    w /= w.sum(axis=0)
    ref.assert_close(b[0][None], (w * xs).sum(axis=0)[None], "diagonal fusion closed form", 1e-12)


def test_ref_fuse_identical_estimates():
    """All nodes hold the same estimate (singular Xi): equal weights, P_f = P."""
    nx = 2
    P = np.array([[2.0, 0.3], [0.3, 1.0]])
    Xi = np.kron(np.ones((4, 4)), P)
    x = np.array([1.5, -0.5])
    xf, Pf, G = ref.fuse(Xi, np.tile(x, 4), nx)
    ref.assert_close(xf[None], x[None], "x_f", 1e-12)
    ref.assert_close(Pf[None], P[None], "P_f", 1e-12)


# ============================================================================
# engine tests
# ============================================================================

def check_common(run, *, weights="unit", edges=None):
    """Invariants every run must satisfy, and x_centralized == reference KF."""
    a = run.arrays
    K = run.sc["steps"]
    n = len(run.sc["sensors"])
    t = a["t"]
    T = run.sc["model"]["T"]
    assert t.shape == (K,)
    np.testing.assert_allclose(t, np.arange(1, K + 1) * T, rtol=1e-12)
    arr = a["arrival"]
    assert arr.shape == (n, n, K)
    for i in range(n):
        assert np.array_equal(arr[i, i], t), f"own arrival of node {i} is not t"
    tt = np.broadcast_to(t, arr.shape)
    assert not np.any(arr < tt), "a contribution arrived before it was measured"
    assert not np.any(np.isnan(arr))
    A = a["weights_A"]
    assert A.shape == (n, n)
    if weights == "unit":
        assert np.array_equal(A, np.ones((n, n))), "unit weights: weights_A must be all ones"
    elif edges is not None:
        deg = np.zeros(n, dtype=int)
        for u, v in edges:
            deg[u] += 1
            deg[v] += 1
        for i in range(n):
            for o in range(n):
                path = tree_path(n, edges, o, i)
                expect = float(np.prod([1.0 / deg[v] for v in path[1:]]))
                assert abs(A[i, o] - expect) <= 1e-12 * expect, (
                    f"weights_A[{i},{o}] = {A[i, o]}, expected {expect} (path {path})")
    xs, Ps = ref.centralized(a)
    ref.assert_close(a["x_centralized"], xs, "x_centralized vs reference KF", TOL)
    if "P_centralized" in a:
        ref.assert_close(a["P_centralized"], Ps, "P_centralized vs reference KF", TOL)
    return xs, Ps


def check_counts(run):
    c = run.counts
    for key in ("sent", "delivered", "lost", "late", "in_flight"):
        assert key in c, f"counts lacks {key!r}"
        assert int(c[key]) >= 0
    assert c["sent"] == c["delivered"] + c["lost"] + c["in_flight"], c
    per = c["per_link"]
    assert len(per) > 0
    for e in per:
        inflight = e.get("in_flight", e["sent"] - e["delivered"] - e["lost"])
        assert inflight >= 0 and e["sent"] == e["delivered"] + e["lost"] + inflight, e
    for key in ("sent", "delivered", "lost"):
        assert sum(e[key] for e in per) == c[key], f"per-link {key} does not add up to the total"
    assert sum(e["sent"] - e["delivered"] - e["lost"] for e in per) == c["in_flight"]
    if "late_per_node" in c:
        assert sum(c["late_per_node"]) == c["late"]


def expected_late(a):
    arr, t = a["arrival"], a["t"]
    L = int(a["buffer_length"])
    K = len(t)
    late = 0
    for r in range(K - L + 1):
        if r + L > K:
            break
        col = arr[:, :, r]
        late += int(np.sum((col > t[r + L - 1]) & np.isfinite(col)))
    return late


def check_against_window_reference(run):
    a = run.arrays
    est = ref.node_estimates(a)
    ref.assert_close(a["x_local"], est["x_local"], "x_local vs window reference", TOL)
    ref.assert_close(a["P_local"], est["P_local"], "P_local vs window reference", TOL)
    ref.assert_close(a["x_final"], est["x_final"], "x_final vs window reference", TOL)
    return est


# ---------------------------------------------------------------- (a) zero latency

ZERO = {"model": "constant", "value": 0.0}


def _check_zero_latency(run):
    a = run.arrays
    xs, Ps = check_common(run)
    t = a["t"]
    assert np.array_equal(a["arrival"], np.broadcast_to(t, a["arrival"].shape)), \
        "zero latency: every contribution must be held at its own tick"
    assert int(a["buffer_length"]) == 1, "auto buffer with d_t = 0 must be L = 1"
    n = a["arrival"].shape[0]
    for i in range(n):
        ref.assert_close(a["x_local"][:, i], xs, f"zero latency: x_local node {i} vs centralized KF", TOL)
        ref.assert_close(a["P_local"][:, i], Ps, f"zero latency: P_local node {i} vs centralized KF", TOL)
        ref.assert_close(a["x_final"][:, i], xs, f"zero latency: x_final node {i} vs centralized KF", TOL)
    assert run.counts["late"] == 0 and run.counts["lost"] == 0
    check_counts(run)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_zero_latency_tree_random_tree_generator(seed):
    sc = scenario(7, generator="random_tree", params={"seed": seed}, steps=60, seed=seed,
                  latency=ZERO)
    _check_zero_latency(run_scenario(sc))


@pytest.mark.parametrize("seed", [4, 5])
def test_zero_latency_tree_explicit_tree_3_states(seed):
    sc = scenario(6, nx=3, edges=tree_edges(6, seed), steps=60, seed=seed, latency=ZERO)
    _check_zero_latency(run_scenario(sc))


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_zero_latency_flood_strongly_connected_digraph(seed):
    n = 6
    sc = scenario(n, edges=scc_digraph_edges(n, seed), directed=True, protocol="flood",
                  steps=60, seed=seed, latency=ZERO)
    _check_zero_latency(run_scenario(sc))


def test_zero_latency_flood_undirected_graph_and_packet_count():
    """Flood on an undirected graph with cycles.  Each (origin, row) is relayed
    once along every link, never back to the node it came from, duplicates
    dropped: a contribution crosses at most sum(deg) - (n - 1) = 2|E| - n + 1
    links.  A packet may bundle several contributions (bitmask payload), so
    this bounds the packet count from above only."""
    n = 6
    edges = [[i, (i + 1) % n] for i in range(n)] + [[0, 3], [1, 4]]
    K = 40
    run = run_scenario(scenario(n, edges=edges, protocol="flood", steps=K, seed=9, latency=ZERO))
    _check_zero_latency(run)
    per = 2 * len(edges) - n + 1
    assert 0 < run.counts["sent"] <= K * n * per, (
        f"flood sent {run.counts['sent']} packets, more than {K} rows x {n} origins x {per}")
    assert run.counts["in_flight"] == 0


# ---------------------------------------------------------------- (b) bounded latency

def _check_bounded(run, d_t, edges, directed):
    a = run.arrays
    n = len(run.sc["sensors"])
    K = run.sc["steps"]
    xs, _ = check_common(run)
    dg = diameter(n, edges, directed)
    L = int(a["buffer_length"])
    assert L == d_t * dg + 1, f"auto buffer: expected d_t*d_g+1 = {d_t * dg + 1}, got {L}"
    # every contribution arrives within dist(o -> i) * d_t steps of its tick
    dist = distances(n, edges, directed)
    t = a["t"]
    for i in range(n):
        for o in range(n):
            lag = dist[o, i] * d_t
            for r in range(K - lag):
                assert a["arrival"][i, o, r] <= t[r + lag], (
                    f"arrival[{i},{o},{r}] = {a['arrival'][i, o, r]} later than "
                    f"{dist[o, i]} hops x {d_t} steps (t = {t[r + lag]})")
    assert run.counts["late"] == 0
    assert expected_late(a) == 0
    # final rows equal the all-data centralized filter
    nfinal = K - L + 1
    assert nfinal > 10
    for i in range(n):
        ref.assert_close(a["x_final"][:nfinal, i], xs[:nfinal],
                         f"d_t={d_t}: x_final node {i} vs all-data centralized KF", TOL)
    check_against_window_reference(run)
    check_counts(run)


@pytest.mark.parametrize("d_t", [1, 2, 3])
def test_bounded_latency_tree_final_rows_are_centralized(d_t):
    n = 6
    edges = tree_edges(n, 10 + d_t)
    sc = scenario(n, edges=edges, steps=80, seed=d_t,
                  latency={"model": "uniform_steps", "d_t": d_t})
    _check_bounded(run_scenario(sc), d_t, edges, False)


@pytest.mark.parametrize("d_t", [1, 2])
def test_bounded_latency_flood_final_rows_are_centralized(d_t):
    n = 6
    edges = scc_digraph_edges(n, 20 + d_t, chords=2)
    sc = scenario(n, edges=edges, directed=True, protocol="flood", steps=80, seed=d_t,
                  latency={"model": "uniform_steps", "d_t": d_t})
    _check_bounded(run_scenario(sc), d_t, edges, True)


# ---------------------------------------------------------------- (c) random latencies

def _random_cases():
    e6 = tree_edges(6, 31)
    e7 = tree_edges(7, 32)
    dg = scc_digraph_edges(6, 33, chords=3)
    assert [1, 5] not in e6 and [5, 1] not in e6
    cases = {
        "tree-uniform_steps-short-buffer-loss": dict(
            n=6, edges=e6, latency={"model": "uniform_steps", "d_t": 3}, loss=0.2,
            buffer_length=3, steps=70, seed=11),
        "tree-continuous-uniform-loss-overrides": dict(
            n=7, edges=e7, latency={"model": "uniform", "low": 0.0, "high": 0.23}, loss=0.2,
            overrides=[{"link": e7[0], "latency": {"model": "constant", "value": 0.25}},
                       {"link": e7[1], "latency": {"model": "uniform_steps", "d_t": 4},
                        "loss": 0.0}],
            buffer_length="auto", steps=70, seed=12, expect_dt=4),
        "tree-exponential-links-d_t": dict(
            n=6, edges=e6, latency={"model": "exponential", "mean": 0.08, "offset": 0.01},
            links_d_t=1, loss=0.2, steps=70, seed=13, expect_dt=1),
        "tree-exponential-int-buffer-3-states": dict(
            n=5, nx=3, edges=tree_edges(5, 34),
            latency={"model": "exponential", "mean": 0.012, "offset": 0.0},
            buffer_length=2, loss=0.2, steps=70, seed=14),
        "flood-digraph-uniform_steps-loss": dict(
            n=6, edges=dg, directed=True, protocol="flood",
            latency={"model": "uniform_steps", "d_t": 2}, buffer_length=3, loss=0.2,
            steps=70, seed=15),
        "flood-undirected-exponential": dict(
            n=6, edges=e6 + [[1, 5]],   # the tree plus one chord: a cycle
            protocol="flood", latency={"model": "exponential", "mean": 0.1, "offset": 0.0},
            buffer_length=3, loss=0.2, steps=70, seed=16),
        "tree-paper-weights": dict(
            n=6, edges=e6, weights="paper", latency={"model": "uniform_steps", "d_t": 2},
            loss=0.2, buffer_length=4, steps=70, seed=17),
        "tree-paper-buffer-length": dict(
            n=6, edges=e6, latency={"model": "uniform_steps", "d_t": 3}, loss=0.1,
            buffer_length="paper", steps=60, seed=19, expect_L=3),
        "tree-paper-weights-zero-latency": dict(
            n=7, edges=e7, weights="paper", latency=ZERO, steps=50, seed=18),
    }
    return cases


RANDOM_CASES = _random_cases()


@pytest.mark.parametrize("case", list(RANDOM_CASES))
def test_random_latency_estimates_follow_the_window_rule(case):
    kw = dict(RANDOM_CASES[case])
    n = kw.pop("n")
    expect_dt = kw.pop("expect_dt", None)
    expect_L = kw.pop("expect_L", None)
    run = run_scenario(scenario(n, **kw))
    L = int(run["buffer_length"])
    if expect_dt is not None:   # auto: L = d_t * d_g + 1, d_t = max over links of ceil(sup / T)
        expect_L = expect_dt * diameter(n, kw["edges"], kw.get("directed", False)) + 1
    if expect_L is not None:
        assert L == expect_L, f"buffer_length {L}, expected {expect_L}"
    check_common(run, weights=kw.get("weights", "unit"),
                 edges=kw["edges"] if kw.get("weights") == "paper" else None)
    est = check_against_window_reference(run)
    check_counts(run)
    assert run.counts["late"] == expected_late(run.arrays), (
        f"counts['late'] = {run.counts['late']}, arrival log says {expected_late(run.arrays)}")
    if kw.get("weights") == "paper":
        # the weights matter: with paper weights the nodes are not the centralized KF
        xs, _ = ref.centralized(run.arrays)
        assert ref.rel_err(est["x_local"][:, 0], xs) > 1e-6
    if kw.get("loss", 0) > 0:
        assert run.counts["lost"] > 0


# ---------------------------------------------------------------- (d) late information

LATE_CASES = {
    "tree-uniform_steps": dict(n=6, edges=tree_edges(6, 41),
                               latency={"model": "uniform_steps", "d_t": 4},
                               buffer_length=2, loss=0.1, steps=80, seed=21),
    "tree-exponential": dict(n=6, edges=tree_edges(6, 42),
                             latency={"model": "exponential", "mean": 0.3, "offset": 0.0},
                             buffer_length=2, steps=80, seed=22),
    "flood-digraph": dict(n=6, edges=scc_digraph_edges(6, 43), directed=True, protocol="flood",
                          latency={"model": "uniform", "low": 0.0, "high": 0.5},
                          buffer_length=2, loss=0.1, steps=80, seed=23),
}


@pytest.mark.parametrize("case", list(LATE_CASES))
def test_late_information_is_counted_and_not_applied(case):
    kw = dict(LATE_CASES[case])
    n = kw.pop("n")
    run = run_scenario(scenario(n, **kw))
    a = run.arrays
    check_common(run)
    late = expected_late(a)
    assert late > 0, "scenario meant to produce late information produced none"
    assert run.counts["late"] > 0
    assert run.counts["late"] == late, (
        f"counts['late'] = {run.counts['late']}, but {late} (i, o, r) arrived after row r was final")
    check_against_window_reference(run)
    check_counts(run)

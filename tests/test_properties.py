"""Property tests: random small trees, latencies, buffers, losses, weights.

For every generated run: every P_local is symmetric positive definite,
P_fused is symmetric PSD and no larger than any node's true error covariance
C_ii (Loewner order, with the KKT regularisation slack), and the local
estimates follow the window rule of docs/design.md §4 (tests/reference.py).
"""

from __future__ import annotations

import numpy as np
import reference as ref
from conftest import run_scenario, scenario, tree_edges
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

K = 30


@st.composite
def tree_scenarios(draw):
    n = draw(st.integers(3, 6))
    tseed = draw(st.integers(0, 10_000))
    d_t = draw(st.integers(0, 3))
    kind = draw(st.sampled_from(["uniform_steps", "uniform", "constant", "exponential"]))
    links_d_t = None
    if kind == "exponential":   # unbounded: auto needs links.d_t
        latency = {"model": "exponential", "mean": round(0.05 * d_t + 0.01, 3), "offset": 0.0}
        links_d_t = d_t
    elif kind == "uniform_steps":
        latency = {"model": "uniform_steps", "d_t": d_t}
    elif kind == "uniform":
        latency = {"model": "uniform", "low": 0.0, "high": round(0.1 * d_t + 0.03, 3)}
    else:
        latency = {"model": "constant", "value": round(0.1 * d_t, 3)}
    buffer_length = draw(st.sampled_from(["auto", 1, 2, 3, 4]))
    loss = draw(st.sampled_from([0.0, 0.2]))
    weights = draw(st.sampled_from(["unit", "unit", "paper"]))
    seed = draw(st.integers(0, 2 ** 31 - 1))
    return scenario(n, edges=tree_edges(n, tseed), latency=latency, loss=loss,
                    buffer_length=buffer_length, weights=weights, steps=K, seed=seed,
                    links_d_t=links_d_t)


@settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(sc=tree_scenarios())
def test_random_tree_runs_satisfy_the_contract(sc):
    run = run_scenario(sc)
    a = run.arrays
    Kr, n, nx = a["x_local"].shape
    assert Kr == K

    # P_local symmetric positive definite
    P = a["P_local"]
    for r in range(Kr):
        for i in range(n):
            Pi = P[r, i]
            s = np.abs(Pi).max()
            assert np.abs(Pi - Pi.T).max() <= 1e-12 * s, f"P_local[{r},{i}] not symmetric"
            assert np.linalg.eigvalsh(Pi).min() > 0, f"P_local[{r},{i}] not positive definite"

    # local estimates follow the window rule
    est = ref.node_estimates(a)
    ref.assert_close(a["x_local"], est["x_local"], "x_local vs window reference")
    ref.assert_close(a["P_local"], est["P_local"], "P_local vs window reference")
    ref.assert_close(a["x_final"], est["x_final"], "x_final vs window reference")

    # fusion: symmetric PSD, no worse than any local estimate, equal to the reference
    Xi = ref.cross_covariances(a)
    for r in range(Kr):
        Pf = a["P_fused"][r]
        s = np.abs(Pf).max()
        assert np.abs(Pf - Pf.T).max() <= 1e-12 * s, f"P_fused[{r}] not symmetric"
        assert np.linalg.eigvalsh(Pf).min() >= -1e-12 * s, f"P_fused[{r}] not PSD"
        d = ref.fusion_delta(Xi[r], n, nx)
        for i in range(n):
            C = Xi[r, i * nx:(i + 1) * nx, i * nx:(i + 1) * nx]
            scale = np.linalg.eigvalsh(C).max()
            m = np.linalg.eigvalsh(0.5 * ((C - Pf) + (C - Pf).T)).min()
            assert m >= -(d + 1e-9 * scale), f"row {r}: P_fused not <= C_{i}{i} (min eig {m:.3e})"
    xf, Pf = ref.fuse_all(a, "matrix", Xi)
    ref.assert_close(a["x_fused"], xf, "x_fused vs reference fusion")
    ref.assert_close(a["P_fused"], Pf, "P_fused vs reference fusion")

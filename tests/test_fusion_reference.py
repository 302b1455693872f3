"""Fusion (docs/design.md §7) against the independent reference.

The reference cross-covariances are computed from explicit linear maps of the
stacked noise (tests/reference.py), not by the covariance recursion the
engine uses, and the KKT system is solved independently.
"""

from __future__ import annotations

import numpy as np
import pytest
import reference as ref
from conftest import run_scenario, scc_digraph_edges, scenario, tree_edges

TOL = 1e-9
K = 36

CASES = {
    "tree-unit-uniform_steps-loss": dict(
        n=6, edges=tree_edges(6, 51), latency={"model": "uniform_steps", "d_t": 2},
        buffer_length=3, loss=0.2, seed=31),
    "tree-paper-weights": dict(
        n=6, edges=tree_edges(6, 52), weights="paper",
        latency={"model": "uniform_steps", "d_t": 2}, buffer_length=4, loss=0.2, seed=32),
    "tree-continuous-uniform-3-states": dict(
        n=5, nx=3, edges=tree_edges(5, 53), latency={"model": "uniform", "low": 0.0, "high": 0.025},
        buffer_length="auto", seed=33),
    "flood-digraph-exponential": dict(
        n=6, edges=scc_digraph_edges(6, 54), directed=True, protocol="flood",
        latency={"model": "exponential", "mean": 0.1, "offset": 0.0}, buffer_length=2,
        loss=0.1, seed=34),
}

_cache = {}


def _run(case, fusion):
    key = (case, fusion)
    if key not in _cache:
        kw = dict(CASES[case])
        n = kw.pop("n")
        run = run_scenario(scenario(n, steps=K, fusion=fusion, **kw))
        _cache[key] = (run, ref.cross_covariances(run.arrays))
    return _cache[key]


def _delta(Xi_r, n, nx):
    return ref.fusion_delta(Xi_r, n, nx)


@pytest.mark.parametrize("fusion", ["matrix", "diagonal"])
@pytest.mark.parametrize("case", list(CASES))
def test_fused_estimate_equals_reference(case, fusion):
    run, Xi = _run(case, fusion)
    a = run.arrays
    xf, Pf = ref.fuse_all(a, fusion, Xi)
    ref.assert_close(a["x_fused"], xf, f"{case}/{fusion}: x_fused vs fuse(cross_covariances)", TOL)
    ref.assert_close(a["P_fused"], Pf, f"{case}/{fusion}: P_fused vs fuse(cross_covariances)", TOL)


@pytest.mark.parametrize("case", list(CASES))
def test_fused_covariance_is_no_worse_than_any_local(case):
    """P_fused <= C_ii in Loewner order for the matrix weights.  The KKT
    regularisation delta can cost at most delta*I (Gamma_delta minimises
    tr Gamma'(Xi + delta I)Gamma, so Gamma'(Xi+delta I)Gamma <= C_ii + delta I):
    that is the only slack allowed, plus 1e-9 of the scale."""
    run, Xi = _run(case, "matrix")
    a = run.arrays
    Kr, n, nx = a["x_local"].shape
    for r in range(Kr):
        d = _delta(Xi[r], n, nx)
        Pf = a["P_fused"][r]
        for i in range(n):
            C = Xi[r, i * nx:(i + 1) * nx, i * nx:(i + 1) * nx]
            scale = np.linalg.eigvalsh(C).max()
            m = np.linalg.eigvalsh(0.5 * ((C - Pf) + (C - Pf).T)).min()
            assert m >= -(d + 1e-9 * scale), (
                f"{case}: row {r}: P_fused not <= C_{i}{i}: min eig {m:.3e} (delta {d:.3e})")


@pytest.mark.parametrize("case", list(CASES))
def test_diagonal_fusion_is_no_better_than_matrix_fusion(case):
    (rm, Xi), (rd, _) = _run(case, "matrix"), _run(case, "diagonal")
    # fusion must not change anything upstream of it
    for key in ("truth", "arrival", "x_local", "P_local", "x_final"):
        assert np.array_equal(rm[key], rd[key]), f"{case}: {key} differs between fusion modes"
    Kr, n, nx = rm["x_local"].shape
    for r in range(Kr):
        _, _, Gd = ref.fuse(Xi[r], rd["x_local"][r], nx, "diagonal")
        slack = _delta(Xi[r], n, nx) * float(np.sum(Gd * Gd))
        tm, td = np.trace(rm["P_fused"][r]), np.trace(rd["P_fused"][r])
        assert td >= tm - slack - 1e-12 * tm, f"{case}: row {r}: tr diag {td} < tr matrix {tm}"
    # and the two are really different fusions
    assert ref.rel_err(rd["x_fused"], rm["x_fused"]) > 1e-9


@pytest.mark.parametrize("protocol", ["tree", "flood"])
def test_zero_latency_fused_is_centralized(protocol):
    n = 6
    if protocol == "tree":
        kw = dict(edges=tree_edges(n, 55))
    else:
        kw = dict(edges=scc_digraph_edges(n, 56), directed=True, protocol="flood")
    run = run_scenario(scenario(n, steps=K, latency={"model": "constant", "value": 0.0}, seed=35, **kw))
    a = run.arrays
    xs, Ps = ref.centralized(a)
    ref.assert_close(a["x_fused"], xs, "zero latency: x_fused vs centralized KF", TOL)
    ref.assert_close(a["P_fused"], Ps, "zero latency: P_fused vs centralized KF", TOL)
    ref.assert_close(a["x_centralized"], xs, "x_centralized vs reference KF", TOL)

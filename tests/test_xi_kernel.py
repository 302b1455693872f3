"""The cross-covariance recursion and the fusion weights against their dense definitions.

The compiled Xi kernel does not form ``Y Y'``: it sums the shared-measurement
term over the columns a node holds, or (unit weights) writes it as
``Omega_tot - MO_i - MO_j + sum over columns both miss``, and it keeps
symmetry by mirroring block rows (docs/design.md §7).  These tests check it,
and the numpy path, against the recursion written out pair by pair::

    C_ij = G_i (Phi C_ij Phi' + Q) G_j' + P_i (sum_m a_im a_jm h_im h_jm u_m u_m') P_j

on random held masks, weights, nodes that re-run and sensors with several
columns; and the fusion weights against the KKT system solved whole.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from dkfsim.estimators import kernels
from dkfsim.estimators.fusion import CrossCovariance, kkt_weights
from dkfsim.model.system import psd_factor


def _spd(rng, k, scale=1.0):
    B = rng.normal(size=(k, k))
    return scale * (B @ B.T + 0.5 * np.eye(k))


def _case(seed, n, nx, unit, p_held):
    """Random ring arrays of ``rows`` window rows and the matching dense ``Xi`` recursion."""
    rng = np.random.default_rng(seed)
    rows = 4
    n_o = n + 1                                       # one more origin than nodes (a source node)
    cols = rng.integers(1, 3, size=n_o)               # 1 or 2 measurement columns per origin
    column_sensor = np.repeat(np.arange(n_o), cols).astype(np.intp)
    M = len(column_sensor)
    U = rng.normal(size=(nx, M))
    U[:, rng.random(M) < 0.2] = 0.0                   # some sensors see nothing in some components
    Phi = np.eye(nx) + 0.1 * rng.normal(size=(nx, nx))
    Q = _spd(rng, nx, 0.1)
    Lq = psd_factor(Q)
    A = np.ones((n, n_o)) if unit else rng.uniform(0.0, 1.0, size=(n, n_o)) * (rng.random((n, n_o)) < 0.8)
    G = rng.normal(size=(rows, n, nx, nx)) * 0.5
    P = np.stack([np.stack([_spd(rng, nx) for _ in range(n)]) for _ in range(rows)])
    # held: per row a mix of nearly-full and nearly-empty nodes (both sums of the kernel)
    held = np.zeros((rows, n, n_o), dtype=bool)
    for r in range(rows):
        for i in range(n):
            p = rng.choice([p_held, 1.0 - p_held, 0.5, 1.0])
            held[r, i] = rng.random(n_o) < p
    Xi0 = np.kron(np.ones((n, n)), _spd(rng, nx))
    return dict(rng=rng, rows=rows, n=n, nx=nx, n_o=n_o, U=U, column_sensor=column_sensor, Phi=Phi, Q=Q,
                Lq=Lq, A=A, G=G, P=P, held=held, Xi0=Xi0)


def _dense(c):
    """The recursion pair by pair, every row and pair."""
    n, nx, rows = c["n"], c["nx"], c["rows"]
    out = np.zeros((rows, n * nx, n * nx))
    for r in range(rows):
        prev = c["Xi0"] if r == 0 else out[r - 1]
        for i in range(n):
            for j in range(n):
                bi, bj = slice(i * nx, (i + 1) * nx), slice(j * nx, (j + 1) * nx)
                S = np.zeros((nx, nx))
                for m, o in enumerate(c["column_sensor"]):
                    if c["held"][r, i, o] and c["held"][r, j, o]:
                        S += c["A"][i, o] * c["A"][j, o] * np.outer(c["U"][:, m], c["U"][:, m])
                Gi, Gj = c["G"][r, i], c["G"][r, j]
                out[r, bi, bj] = (Gi @ (c["Phi"] @ prev[bi, bj] @ c["Phi"].T + c["Q"]) @ Gj.T
                                  + c["P"][r, i] @ S @ c["P"][r, j])
        out[r] = 0.5 * (out[r] + out[r].T)          # the ring is kept exactly symmetric
    return out


def _stale(c, want, starts):
    """The ring as the previous tick left it: the blocks of pairs where a node re-runs row
    ``r`` (``starts[i] <= r``) hold stale values (symmetric noise), the others are current."""
    nx = c["nx"]
    old = want.copy()
    for r in range(c["rows"]):
        noise = c["rng"].normal(size=old[r].shape)
        stale = np.repeat(starts <= r, nx)
        mask = stale[:, None] | stale[None, :]
        old[r][mask] += (noise + noise.T)[mask]
    return old


def _compiled(c, starts):
    Xi = c["old"].copy()
    cross = kernels.Cross(Xi, c["Xi0"], c["A"], bool((c["A"] == 1.0).all()), c["column_sensor"], c["U"][None], False,
                          c["Phi"], c["Lq"])
    rows, n, nx = c["P"].shape[:3]
    ring = kernels.Ring(np.zeros((rows, n, nx)), c["P"], c["G"], np.zeros_like(c["P"]), np.zeros((rows, n, nx)),
                        c["held"])                   # x, Omega, Theta are not read
    kernels.compiled().xi_rows(cross, ring, starts, int(starts.min()), c["rows"] - 1, (0,) * c["nx"])
    return Xi


def _numpy(c, starts):
    n, nx = c["n"], c["nx"]
    info = SimpleNamespace(factor=c["U"], column_sensor=c["column_sensor"], varying=False,
                           factor_row=lambda row: c["U"])
    state = SimpleNamespace(G=c["G"], P=c["P"])
    w = SimpleNamespace(n=n, nx=nx, S=c["rows"], Q=c["Q"], info=info, A=c["A"], kernels=None,
                        state=state, holdings=SimpleNamespace(held=c["held"]), Phi=c["Phi"])
    xc = object.__new__(CrossCovariance)
    xc.w, xc.n, xc.nx, xc.N = w, n, nx, n * nx
    xc.Xi, xc.Xi0, xc.Lq, xc.info = c["old"].copy(), c["Xi0"], c["Lq"], info
    xc._F, xc._diag = np.zeros((n, nx, n, nx)), np.arange(n)
    xc.on_rows(int(starts.min()), c["rows"] - 1, starts)
    return xc.Xi


def _rel(a, b):
    return float(np.abs(a - b).max() / np.abs(b).max())


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 7), nx=st.sampled_from([1, 2, 3]),
       unit=st.booleans(), p_held=st.sampled_from([0.05, 0.3]))
def test_xi_kernel_matches_the_pairwise_recursion(seed, n, nx, unit, p_held):
    c = _case(seed, n, nx, unit, p_held)
    starts = c["rng"].integers(0, c["rows"], size=n).astype(np.intp)
    starts[c["rng"].integers(n)] = 0 if c["rng"].random() < 0.5 else starts.min()
    want = _dense(c)
    c["old"] = _stale(c, want, starts)
    for got in (_compiled(c, starts), _numpy(c, starts)):
        for r in range(c["rows"]):
            assert _rel(got[r], want[r]) < 1e-12, f"row {r}"
            assert np.array_equal(got[r], got[r].T), f"row {r} not exactly symmetric"


@pytest.mark.parametrize("p_held", [0.0, 1.0])
def test_xi_kernel_all_held_and_none_held(p_held):
    """The edges of the two sums: every node holds everything (the complement sum is empty,
    the zero-latency case) or nothing (only the process noise correlates the nodes)."""
    c = _case(5, 6, 3, True, 0.5)
    c["held"][:] = p_held == 1.0
    starts = np.zeros(6, dtype=np.intp)
    want = _dense(c)
    c["old"] = _stale(c, want, starts)
    got = _compiled(c, starts)
    for r in range(c["rows"]):
        assert _rel(got[r], want[r]) < 1e-12


def _kkt_dense(Xi, n, nx):
    N = n * nx
    E = np.tile(np.eye(nx), (n, 1))
    K = np.block([[Xi + 1e-8 * np.trace(Xi) / N * np.eye(N), E], [E.T, np.zeros((nx, nx))]])
    rhs = np.vstack([np.zeros((N, nx)), np.eye(nx)])
    return np.linalg.solve(K, rhs)[:N]


@pytest.mark.parametrize("rank", [None, 3, 6])
def test_kkt_weights_solve_the_regularised_kkt_system(rank):
    """Gamma from the Cholesky elimination is the KKT solution: full-rank and singular Xi."""
    rng = np.random.default_rng(rank or 0)
    n, nx = 8, 3
    N = n * nx
    B = rng.normal(size=(N, rank or N))
    Xi = B @ B.T
    G = kkt_weights(Xi, n, nx)
    assert np.allclose(G.reshape(n, nx, nx).sum(axis=0), np.eye(nx), atol=1e-10)
    # stationarity: (Xi + delta I) Gamma = -E Lambda, the same block for every node
    X = Xi + 1e-8 * np.trace(Xi) / N * np.eye(N)
    XG = (X @ G).reshape(n, nx, nx)
    scale = np.abs(X).max() * np.abs(G).max()
    assert np.abs(XG - XG[0]).max() <= 1e-8 * scale
    want = _kkt_dense(Xi, n, nx)
    Pf, Pw = G.T @ Xi @ G, want.T @ Xi @ want
    assert np.abs(Pf - Pw).max() <= 1e-10 * np.abs(Xi).max()
    if rank is None:
        assert np.abs(G - want).max() <= 1e-8 * np.abs(want).max()


def test_kkt_weights_fall_back_when_cholesky_refuses():
    """An indefinite Xi (beyond what delta fixes) goes to the symmetric indefinite KKT solve."""
    n, nx = 4, 2
    N = n * nx
    Xi = np.eye(N)
    Xi[0, 0] = -5.0
    G = kkt_weights(Xi, n, nx)
    want = _kkt_dense(Xi, n, nx)
    assert np.allclose(G, want, rtol=1e-10, atol=1e-12)

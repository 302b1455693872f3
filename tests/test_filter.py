"""The information-form step against independent truths.

* one step equals the textbook covariance-form Kalman update (Joseph form);
* the centralized filter converges to the closed-form steady state of the
  discrete algebraic Riccati equation (scipy's DARE solver);
* 100 000 ticks do not drift: covariances stay symmetric and on the DARE
  fixed point to machine precision.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg
from hypothesis import given, settings
from hypothesis import strategies as st

from dkfsim.estimators.window import centralized_filter, information_step


def ca_model(T=0.01):
    Phi = np.array([[1.0, T, T * T / 2], [0.0, 1.0, T], [0.0, 0.0, 1.0]])
    return Phi, np.eye(3)


def paper_sensors():
    R = [0.8, 1.0, 2.0, 1.0, 0.5, 1.5, 1.0, 1.0, 0.1, 1.0, 1.5, 1.0]
    H = [np.eye(3)[[i % 3]] for i in range(12)]
    return H, [np.array([[r]]) for r in R]


def joseph_update(x, P, H, R, y):
    S = H @ P @ H.T + R
    K = np.linalg.solve(S, H @ P).T
    IKH = np.eye(P.shape[0]) - K @ H
    return x + K @ (y - H @ x), IKH @ P @ IKH.T + K @ R @ K.T


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**32 - 1))
def test_information_step_equals_covariance_form(seed):
    rng = np.random.default_rng(seed)
    nx, m = 3, 2
    Phi = np.eye(nx) + 0.3 * rng.standard_normal((nx, nx))
    A = rng.standard_normal((nx, nx))
    Q = A @ A.T + 0.1 * np.eye(nx)
    B = rng.standard_normal((nx, nx))
    P = B @ B.T + 0.1 * np.eye(nx)
    x = rng.standard_normal(nx)
    H = rng.standard_normal((m, nx))
    C = rng.standard_normal((m, m))
    R = C @ C.T + 0.2 * np.eye(m)
    y = rng.standard_normal(m)
    Omega = H.T @ np.linalg.solve(R, H)
    Theta = H.T @ np.linalg.solve(R, y)
    xn, Pn, G = information_step(Phi, Q, x[None], P[None], Omega[None], Theta[None])
    xr, Pr = joseph_update(Phi @ x, Phi @ P @ Phi.T + Q, H, R, y)
    np.testing.assert_allclose(xn[0], xr, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(Pn[0], Pr, rtol=1e-9, atol=1e-10)
    # G = P Pp^-1 = I - K H.
    Pp = Phi @ P @ Phi.T + Q
    np.testing.assert_allclose(G[0] @ Pp, Pn[0], rtol=1e-9, atol=1e-10)
    assert np.array_equal(Pn[0], Pn[0].T)


def dare_filtered(Phi, Q, Omega):
    """Steady-state filtered covariance from the DARE of the predicted one."""
    # Predicted steady state Pp solves Pp = Phi (Pp^-1 + Omega)^-1 Phi' + Q;
    # with Omega = C' C this is the standard DARE with R = I.
    w, V = np.linalg.eigh(Omega)
    C = (V * np.sqrt(np.clip(w, 0, None))).T
    Pp = scipy.linalg.solve_discrete_are(Phi.T, C.T, Q, np.eye(C.shape[0]))
    return np.linalg.inv(np.linalg.inv(Pp) + Omega)


def test_centralized_filter_reaches_riccati_steady_state_without_drift():
    Phi, Q = ca_model()
    H, R = paper_sensors()
    Omega = sum(h.T @ np.linalg.solve(r, h) for h, r in zip(H, R))
    K = 100_000
    theta = np.zeros((K, 3))          # covariances do not depend on the data
    _, Ps = centralized_filter(Phi, Q, np.zeros(3), np.eye(3), Omega, theta)
    P_inf = dare_filtered(Phi, Q, Omega)
    # Converged long before the end, and still there after 100k ticks.
    for r in (K // 10, K // 2, K - 1):
        np.testing.assert_allclose(Ps[r], P_inf, rtol=1e-8, atol=1e-12)
    assert np.abs(Ps - np.swapaxes(Ps, 1, 2)).max() == 0.0
    assert np.all(np.linalg.eigvalsh(Ps[-1]) > 0)


def test_centralized_filter_is_unbiased_and_consistent_on_simulated_data():
    """NEES of the centralized KF over a long run lies in its chi-square band."""
    Phi, Q = ca_model()
    H, R = paper_sensors()
    rng = np.random.default_rng(4)
    K = 20_000
    x = np.zeros(3)
    truth = np.empty((K, 3))
    Lq = np.linalg.cholesky(Q)
    for k in range(K):
        x = Phi @ x + Lq @ rng.standard_normal(3)
        truth[k] = x
    theta = np.zeros((K, 3))
    for h, r in zip(H, R):
        y = truth @ h.T + np.sqrt(r[0, 0]) * rng.standard_normal((K, 1))
        theta += y @ (h / r[0, 0])
    Omega = sum(h.T @ np.linalg.solve(r, h) for h, r in zip(H, R))
    xs, Ps = centralized_filter(Phi, Q, np.zeros(3), np.eye(3), Omega, theta)
    e = truth - xs
    nees = np.einsum("ki,ki->k", e, np.linalg.solve(Ps, e[..., None])[..., 0])
    # Consecutive NEES values are correlated: batch means of 200 ticks are
    # nearly independent, so the mean of chi2(3) (= 3) must lie within four
    # standard errors of their average (batch-means method).
    blocks = nees[: K - K % 200].reshape(-1, 200).mean(axis=1)
    se = blocks.std(ddof=1) / np.sqrt(blocks.size)
    assert abs(blocks.mean() - 3.0) < 4 * se, (blocks.mean(), se)
    # ...and the spread is chi-square-like, not degenerate.
    assert 0.85 < nees.var() / 6.0 < 1.15

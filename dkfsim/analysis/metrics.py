"""Accuracy and cost metrics of one run, and pooling over independent runs.

Kept free of any simulation logic: everything here is a function of the
arrays a run writes (docs/design.md §8), so the same code scores a fresh
run and a ``run.npz`` read back from disk.  The second half serves
:mod:`dkfsim.experiments.montecarlo`: per-tick squared errors, NEES and node
disagreement of one run; Student-t intervals over runs; the chi-square band
of the mean NEES; the nominal packet size.
"""

from __future__ import annotations

import numpy as np

from dkfsim.core.linalg import solve


def default_burn_in(K: int) -> int:
    """Rows dropped before averaging: the first 10 % of the run."""
    return K // 10


def mse_per_component(x: np.ndarray, truth: np.ndarray, burn_in: int) -> np.ndarray:
    """Time-averaged squared error per state component after ``burn_in`` rows.

    ``x`` is (K, nx) or (K, n, nx); with nodes, the result averages over nodes too.
    """
    err = x[burn_in:] - (truth[burn_in:] if x.ndim == 2 else truth[burn_in:, None, :])
    axes = tuple(range(err.ndim - 1))
    return np.mean(err ** 2, axis=axes)


def nees(x: np.ndarray, P: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Normalised estimation error squared per row (uses a solve, not an inverse)."""
    e = truth - x
    return np.einsum("...i,...i->...", e, solve(P, e[..., None])[..., 0])


def run_metrics(arrays: dict, burn_in: int) -> dict:
    """MSE per component for the fused estimate, the mean of the local ones and baselines."""
    truth = arrays["truth"]
    out = {"burn_in": int(burn_in)}
    if "x_fused" in arrays:
        out["fused"] = mse_per_component(arrays["x_fused"], truth, burn_in).tolist()
    out["local_mean"] = mse_per_component(arrays["x_local"], truth, burn_in).tolist()
    for key in sorted(arrays):
        if key.startswith("x_") and key not in ("x_local", "x_final", "x_fused", "x0_mean"):
            out[key[2:]] = mse_per_component(arrays[key], truth, burn_in).tolist()
    return out


# =========================================================================== Monte Carlo
# Everything below scores one run (per-tick curves, per-run scalars) or pools
# independent runs (confidence intervals, the chi-square band of the mean NEES).

#: Bytes of a packet header in the nominal packet size (sequence number, link, row, time).
HEADER_BYTES = 16


def squared_error(x: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Squared error per tick and component, ``(K, nx)``.

    ``x`` is ``(K, nx)`` or per node ``(K, n, nx)``; per node, the squared
    errors are averaged over the nodes.
    """
    if x.ndim == 2:
        return (x - truth) ** 2
    return np.mean((x - truth[:, None, :]) ** 2, axis=1)


def nees_per_tick(x: np.ndarray, P: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """NEES per tick, ``(K,)``; per node (``x`` ``(K, n, nx)``), the mean over nodes.

    The nodes' errors are correlated, so the mean over nodes of n chi-square
    variables is not chi-square with ``n*nx`` degrees of freedom; its mean is
    still ``nx`` for consistent filters and its variance is at most that of
    one node's NEES, so the band of :func:`nees_band` (one term per run) is a
    conservative yardstick for it.
    """
    t = truth if x.ndim == 2 else truth[:, None, :]
    e = nees(x, P, np.broadcast_to(t, x.shape))
    return e if e.ndim == 1 else e.mean(axis=1)


def disagreement_per_tick(x: np.ndarray) -> np.ndarray:
    """Spread of per-node estimates ``x`` ``(K, n, nx)``: per tick, the mean
    over nodes of ``||x_i - mean_j x_j||^2``, ``(K,)``."""
    dev = x - x.mean(axis=1, keepdims=True)
    return np.mean(np.sum(dev ** 2, axis=2), axis=1)


def disagreement(x: np.ndarray, burn_in: int) -> float:
    """Time average after ``burn_in`` rows of :func:`disagreement_per_tick`."""
    return float(np.mean(disagreement_per_tick(x[burn_in:])))


def packet_bytes(nx: int, n: int, rows: int = 1) -> int:
    """Nominal size in bytes of one packet carrying ``rows`` window rows.

    ``HEADER_BYTES`` plus, per row, the information vector and the upper
    triangle of the information matrix as float64
    (``8 * (nx + nx (nx + 1) / 2)``) and the origin bitmask (``ceil(n / 8)``).
    """
    per_row = 8 * (nx + nx * (nx + 1) // 2) + -(-n // 8)
    return HEADER_BYTES + rows * per_row


def t_interval(samples, level: float = 0.95, axis: int = 0):
    """Mean and two-sided Student-t confidence interval over independent samples.

    Returns ``(mean, lo, hi)`` along ``axis``:
    ``mean -+ t_{(1+level)/2, N-1} * s / sqrt(N)`` with ``s`` the sample
    standard deviation (``ddof=1``).  With one sample the bounds are NaN.
    """
    from scipy.stats import t as student_t
    a = np.asarray(samples, dtype=float)
    N = a.shape[axis]
    mean = a.mean(axis=axis)
    if N < 2:
        nan = np.full_like(mean, np.nan)
        return mean, nan, nan.copy()
    half = student_t.ppf(0.5 + level / 2, N - 1) * a.std(axis=axis, ddof=1) / np.sqrt(N)
    return mean, mean - half, mean + half


def t_interval_from_moments(mean, m2, N: int, level: float = 0.95):
    """:func:`t_interval` from a running mean and sum of squared deviations
    ``m2`` (Welford) of ``N`` samples: ``(lo, hi)``."""
    from scipy.stats import t as student_t
    mean = np.asarray(mean, dtype=float)
    if N < 2:
        nan = np.full_like(mean, np.nan)
        return nan, nan.copy()
    half = student_t.ppf(0.5 + level / 2, N - 1) * np.sqrt(np.asarray(m2) / (N - 1) / N)
    return mean - half, mean + half


def paired_lower_bound(a, b, level: float = 0.95, axis: int = 0):
    """One-sided lower confidence bound of ``E[b - a]`` from paired samples
    (one pair per independent run): ``mean(d) - t_{level, N-1} s_d / sqrt(N)``.

    A positive bound supports ``E[a] < E[b]`` at that level.
    """
    from scipy.stats import t as student_t
    d = np.asarray(b, dtype=float) - np.asarray(a, dtype=float)
    N = d.shape[axis]
    if N < 2:
        return np.full_like(d.mean(axis=axis), np.nan)
    return d.mean(axis=axis) - student_t.ppf(level, N - 1) * d.std(axis=axis, ddof=1) / np.sqrt(N)


def nees_band(runs: int, nx: int, level: float = 0.95) -> np.ndarray:
    """Two-sided ``level`` band of the mean NEES over ``runs`` independent runs at one tick.

    For a consistent filter, the sum of the ``runs`` NEES values at one tick
    is chi-square with ``runs * nx`` degrees of freedom, so the mean lies in
    ``chi2.ppf([(1-level)/2, (1+level)/2], runs*nx) / runs`` with probability
    ``level``.  Returns ``array([lo, hi])``.

    Over time the NEES of one run is autocorrelated, so this per-tick band is
    not the band of the time-averaged ANEES; see :func:`anees_summary`.
    """
    from scipy.stats import chi2
    dof = runs * nx
    return chi2.ppf([0.5 - level / 2, 0.5 + level / 2], dof) / runs


def anees_summary(mean_nees: np.ndarray, runs: int, nx: int, burn_in: int,
                  level: float = 0.95) -> dict:
    """Time treatment of the ANEES.

    ``mean_nees`` is the mean NEES over ``runs`` runs per tick, ``(K,)``.
    After ``burn_in`` rows: ``anees`` is its time average, ``band`` the
    per-tick band of :func:`nees_band`, ``fraction_in_band`` the fraction of
    ticks whose mean NEES lies in that band (about ``level`` for a
    consistent filter).  NaN throughout when there is no covariance.
    """
    band = nees_band(runs, nx, level)
    m = np.asarray(mean_nees, dtype=float)[burn_in:]
    if m.size == 0 or np.all(np.isnan(m)):
        return {"anees": float("nan"), "band": band, "fraction_in_band": float("nan")}
    inside = (m >= band[0]) & (m <= band[1])
    return {"anees": float(np.mean(m)), "band": band, "fraction_in_band": float(np.mean(inside))}

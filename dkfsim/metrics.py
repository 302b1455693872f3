"""Accuracy metrics of one run.

Kept free of any simulation logic: everything here is a function of the
arrays a run writes (DESIGN.md section 5), so the same code scores a fresh
run and a ``run.npz`` read back from disk.
"""

from __future__ import annotations

import numpy as np


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
    return np.einsum("...i,...i->...", e, np.linalg.solve(P, e[..., None])[..., 0])


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

"""Metrics: how good and how costly each estimate of a run is, and pooling over runs.

Kept free of any simulation logic: everything here is a function of the
arrays a run writes (docs/design.md §8) and of the traffic it counted, so
the same code scores a fresh run and a ``run.npz`` read back from disk.

The named metrics (:data:`~dkfsim.core.registry.METRICS`) give the tidy rows
every output shares (:func:`score_scored`): one row per estimate and state
component with ``mse`` (per component; per-node estimates averaged over the
nodes), ``anees``, ``disagreement`` (per-node estimates only),
``messages_per_tick``, ``bytes_per_tick``, ``lost`` and ``late`` (``NaN``
where they do not apply: no covariance, a single estimate, no network
model).  ``run``, ``montecarlo`` and ``sweep`` write these rows with the
same columns (:data:`ROW_COLUMNS`).  Registering a metric adds a column
everywhere (docs/extending.md).  The rest: per-tick curves, Student-t
intervals over runs, the chi-square band of the mean NEES.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

from dkfsim.core.linalg import solve
from dkfsim.core.registry import METRICS


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


# =========================================================================== named metrics
@dataclass(frozen=True)
class Scored:
    """What a metric sees of one estimate of one run."""

    x: np.ndarray                 # (K, nx) or per node (K, n, nx)
    P: np.ndarray | None
    truth: np.ndarray             # (K, nx)
    traffic: dict | None          # the estimator's counts (None: no network model)
    burn_in: int

    @property
    def K(self) -> int:
        return self.truth.shape[0]

    @functools.cached_property
    def nees(self) -> np.ndarray | None:
        """:func:`nees_per_tick` of the whole run, ``(K,)`` (None without a covariance):
        computed once for the ANEES and the Monte Carlo curves (a batched solve per tick)."""
        if self.P is None:
            return None
        with np.errstate(all="ignore"):
            return nees_per_tick(self.x, self.P, self.truth)


@dataclass(frozen=True)
class Metric:
    """A named metric: ``value(s)`` is one number, or one per state component when
    ``per_component``."""

    value: Callable[[Scored], float | np.ndarray]
    per_component: bool = False
    unit: str = ""


def _traffic(key: str, scale: bool):
    def value(s: Scored) -> float:
        if s.traffic is None or key not in s.traffic:
            return math.nan
        v = float(s.traffic[key])
        return v / s.K if scale else v
    return value


def _anees(s: Scored) -> float:
    nees = s.nees                   # (None when s.P is None)
    if nees is None:
        return math.nan
    return float(np.mean(nees[s.burn_in:]))


for _name, _metric, _doc in (
        ("mse", Metric(lambda s: mse_per_component(s.x, s.truth, s.burn_in), True, "state unit^2"),
         "time-averaged squared error after the burn-in, per state component (per node: mean over nodes)"),
        ("anees", Metric(_anees),
         "time average after the burn-in of the NEES (per node: mean over nodes); nx when consistent"),
        ("disagreement", Metric(lambda s: disagreement(s.x, s.burn_in) if s.x.ndim == 3 else math.nan),
         "per-node estimates: time average of the mean squared distance to the nodes' mean"),
        ("messages_per_tick", Metric(_traffic("sent", True), unit="1/tick"),
         "packets the estimator sent, per tick"),
        ("bytes_per_tick", Metric(_traffic("bytes", True), unit="B/tick"),
         "nominal bytes of those packets (8-byte floats, headers, origin masks), per tick"),
        ("lost", Metric(_traffic("lost", False), unit="packets/run"), "packets the links lost, per run"),
        ("late", Metric(_traffic("late", False), unit="items/run"),
         "information that arrived too late to be used, per run (the DKF: late (packet, row) pairs, or "
         "late contributions when the run keeps the arrival log; docs/design.md §3; others: packets)")):
    METRICS.add(_name, implementation=_metric, description=_doc)

#: The columns of a tidy row, in order (metrics by their registration order).
KEY_COLUMNS = ("run", "seed", "estimate", "component")


def row_columns() -> tuple[str, ...]:
    """Every column of a tidy row: the keys, then every registered metric."""
    return KEY_COLUMNS + tuple(METRICS.names())


def scored(x, P, truth, traffic, burn_in: int) -> Scored:
    """What the metrics see of one estimate (:class:`Scored`), arrays as numpy arrays."""
    return Scored(np.asarray(x), None if P is None else np.asarray(P), truth, traffic, int(burn_in))


def score_scored(name: str, s: Scored, components) -> list[dict]:
    """The tidy rows of one estimate of one run, already wrapped by :func:`scored` (whose
    NEES a caller may reuse: :attr:`Scored.nees`): one per state component, every metric.

    ``run`` and ``seed`` are left to the caller.  Non-applicable metrics are NaN.
    """
    values = {}
    with np.errstate(all="ignore"):          # diverged estimates: inf / nan, reported as such
        for entry in METRICS.entries():
            values[entry.name] = (entry.implementation.per_component, entry.implementation.value(s))
    rows = []
    for c, comp in enumerate(components):
        row = {"estimate": name, "component": comp}
        for key, (per_comp, v) in values.items():
            row[key] = float(v[c]) if per_comp else float(v)
        rows.append(row)
    return rows


# =========================================================================== over runs
# The two quantile functions are scipy.stats' ``t.ppf`` and ``chi2.ppf`` without
# scipy.stats itself, whose import costs every dkfsim process (the CLI, a spawned
# worker) about half a second: the same special functions those call, so the same bits
# (tests/test_metrics.py compares them with scipy.stats).  scipy.special itself is imported
# at the first interval, not with this module (the metrics register for every command).
def t_quantile(q, df):
    """Quantile ``q`` of Student's t with ``df`` degrees of freedom (``scipy.stats.t.ppf``)."""
    from scipy.special import stdtrit
    return stdtrit(df, q)


def chi2_quantile(q, df):
    """Quantile ``q`` of the chi-square with ``df`` degrees of freedom (``scipy.stats.chi2.ppf``)."""
    from scipy.special import gammaincinv
    return 2 * gammaincinv(np.asarray(df) / 2, q)


def t_interval(samples, level: float = 0.95, axis: int = 0):
    """Mean and two-sided Student-t confidence interval over independent samples.

    Returns ``(mean, lo, hi)`` along ``axis``:
    ``mean -+ t_{(1+level)/2, N-1} * s / sqrt(N)`` with ``s`` the sample
    standard deviation (``ddof=1``).  With one sample the bounds are NaN.
    """
    a = np.asarray(samples, dtype=float)
    N = a.shape[axis]
    mean = a.mean(axis=axis)
    if N < 2:
        nan = np.full_like(mean, np.nan)
        return mean, nan, nan.copy()
    half = t_quantile(0.5 + level / 2, N - 1) * a.std(axis=axis, ddof=1) / np.sqrt(N)
    return mean, mean - half, mean + half


def t_interval_from_moments(mean, m2, N: int, level: float = 0.95):
    """:func:`t_interval` from a running mean and sum of squared deviations
    ``m2`` (Welford) of ``N`` samples: ``(lo, hi)``."""
    mean = np.asarray(mean, dtype=float)
    if N < 2:
        nan = np.full_like(mean, np.nan)
        return nan, nan.copy()
    half = t_quantile(0.5 + level / 2, N - 1) * np.sqrt(np.asarray(m2) / (N - 1) / N)
    return mean - half, mean + half


def paired_lower_bound(a, b, level: float = 0.95, axis: int = 0):
    """One-sided lower confidence bound of ``E[b - a]`` from paired samples
    (one pair per independent run): ``mean(d) - t_{level, N-1} s_d / sqrt(N)``.

    A positive bound supports ``E[a] < E[b]`` at that level.
    """
    d = np.asarray(b, dtype=float) - np.asarray(a, dtype=float)
    N = d.shape[axis]
    if N < 2:
        return np.full_like(d.mean(axis=axis), np.nan)
    return d.mean(axis=axis) - t_quantile(level, N - 1) * d.std(axis=axis, ddof=1) / np.sqrt(N)


def nees_band(runs: int, nx: int, level: float = 0.95) -> np.ndarray:
    """Two-sided ``level`` band of the mean NEES over ``runs`` independent runs at one tick.

    For a consistent filter, the sum of the ``runs`` NEES values at one tick
    is chi-square with ``runs * nx`` degrees of freedom, so the mean lies in
    ``chi2.ppf([(1-level)/2, (1+level)/2], runs*nx) / runs`` with probability
    ``level``.  Returns ``array([lo, hi])``.

    Over time the NEES of one run is autocorrelated, so this per-tick band is
    not the band of the time-averaged ANEES; see :func:`anees_summary`.
    """
    dof = runs * nx
    return chi2_quantile(np.array([0.5 - level / 2, 0.5 + level / 2]), dof) / runs


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


# =========================================================================== verdicts, pairs
def anees_consistent(ci95, nx: int) -> bool | None:
    """The consistency verdict of a time-averaged ANEES: ``ci95[0] <= nx <= ci95[1]``.

    ``ci95`` is the Student-t interval over runs of the per-run time averages (valid
    although NEES is correlated in time: the runs are independent).  ``None`` when there
    is no interval (a single run, no covariance).  A correct filter fails it in 5 % of
    seeds at 95 % (docs/statistics.md).
    """
    if ci95 is None:
        return None
    lo, hi = ci95
    if lo is None or hi is None or not (math.isfinite(lo) and math.isfinite(hi)):
        return None
    return bool(lo <= nx <= hi)


def paired_interval(values, reference, level: float = 0.95) -> dict:
    """Paired comparison of ``values`` with ``reference``, one pair per run (common random
    numbers: both computed on the same draws).

    ``diff``, ``diff_ci95``: mean of the per-run differences ``values - reference`` with
    its Student-t interval (``N - 1`` degrees of freedom); ``ratio``, ``ratio_ci95``: the
    exponentiated mean and t-interval of the per-run log-ratios ``log(values / reference)``
    (a geometric mean ratio; None unless every value of both is finite and > 0); ``runs``: N.
    Non-finite numbers are None (JSON); pairs with a NaN on either side are left out.
    """
    a = np.asarray(values, dtype=float)
    b = np.asarray(reference, dtype=float)
    if a.shape != b.shape:
        raise ValueError(f"paired samples of different lengths ({a.shape} vs {b.shape})")
    keep = ~(np.isnan(a) | np.isnan(b))
    a, b = a[keep], b[keep]
    out: dict = {"runs": int(a.size), "diff": None, "diff_ci95": [None, None],
                 "ratio": None, "ratio_ci95": [None, None]}
    if a.size == 0:
        return out
    with np.errstate(all="ignore"):
        mean, lo, hi = t_interval(a - b, level)
        out["diff"], out["diff_ci95"] = _finite(mean), [_finite(lo), _finite(hi)]
        if np.all(np.isfinite(a) & np.isfinite(b) & (a > 0) & (b > 0)):
            m, lo, hi = t_interval(np.log(a) - np.log(b), level)
            out["ratio"], out["ratio_ci95"] = _finite(np.exp(m)), [_finite(np.exp(lo)), _finite(np.exp(hi))]
    return out


def _finite(v) -> float | None:
    v = float(v)
    return v if math.isfinite(v) else None

"""Summaries of tidy tables with grid columns (sweeps): a mean and 95 % interval per grid point.

A sweep table (docs/design.md, "Sweeps") has the grid columns, then ``param_hash,
run, seed, estimate, component`` and the metrics.  :func:`summarize` folds the
runs of each (parameter set, estimate, component) into one row: ``runs``, ``mse``
with its 95 % Student-t interval, ``anees`` with its t-interval over runs and the
verdict ``anees_consistent`` (that interval covers the estimate's number of
components), the per-tick 95 % chi-square band ``anees_band95_*``
(:func:`dkfsim.analysis.metrics.nees_band`, kept for compatibility: it is a band for
the mean NEES at one tick, not for the time average; docs/statistics.md), the means of
``messages_per_tick``, ``bytes_per_tick`` and ``late``, and the paired comparison with
the reference estimate ``relative_to`` at the same grid point, run by run
(:mod:`dkfsim.analysis.paired`): ``mse_diff`` and ``mse_ratio`` with their 95 %
intervals.  ``None``: not applicable.  Pure functions of the rows, so a database and
its export summarize equally.
"""

from __future__ import annotations

import math

import numpy as np

from dkfsim.analysis.metrics import anees_consistent, nees_band, paired_interval, t_interval
from dkfsim.analysis.paired import number_or_nan, pair_values, reference_of

#: Columns of the summary after the grid columns.
SUMMARY_COLUMNS = ("param_hash", "estimate", "component", "runs", "mse", "mse_ci95_lo",
                   "mse_ci95_hi", "anees", "anees_ci95_lo", "anees_ci95_hi", "anees_consistent",
                   "anees_band95_lo", "anees_band95_hi", "messages_per_tick", "bytes_per_tick", "late",
                   "relative_to", "mse_diff", "mse_diff_ci95_lo", "mse_diff_ci95_hi", "mse_ratio",
                   "mse_ratio_ci95_lo", "mse_ratio_ci95_hi")


def grid_columns(columns) -> list[str]:
    """The grid columns of a sweep table: those before ``param_hash``."""
    return list(columns[:list(columns).index("param_hash")])


def groups(columns, rows) -> dict:
    """Rows grouped by (param_hash, estimate, component), in table order: each group
    ``{"grid": {key: value}, "param_hash", "estimate", "component", "rows": [row dicts]}``."""
    grid = grid_columns(columns)
    out: dict = {}
    for row in rows:
        d = dict(zip(columns, row))
        key = (d["param_hash"], d["estimate"], d["component"])
        g = out.get(key)
        if g is None:
            g = out[key] = {"grid": {k: d[k] for k in grid}, "param_hash": key[0],
                            "estimate": key[1], "component": key[2], "rows": []}
        g["rows"].append(d)
    return out


def interval(values) -> tuple[float, float, float]:
    """Mean and 95 % Student-t interval of per-run values (NaN when not applicable)."""
    a = np.array([number_or_nan(v) for v in values], dtype=float)
    if a.size == 0 or np.isnan(a).all():
        return math.nan, math.nan, math.nan
    mean, lo, hi = t_interval(a)
    return float(mean), float(lo), float(hi)


def _mean(values) -> float | None:
    a = np.array([number_or_nan(v) for v in values], dtype=float)
    return None if a.size == 0 or np.isnan(a).all() else float(np.mean(a))


def summarize(columns, rows, relative_to: str | None = None) -> tuple[list[str], list[list]]:
    """The summary table (see the module docstring) of a sweep table's ``(columns, rows)``;
    ``relative_to``: the reference estimate of the paired columns (default ``centralized``)."""
    grid = grid_columns(columns)
    found = groups(columns, rows)
    ref = reference_of((est for (_h, est, _c) in found), relative_to, "the sweep")
    n_comp: dict = {}
    for (h, est, _c) in found:
        n_comp[(h, est)] = n_comp.get((h, est), 0) + 1
    out = []
    for (h, est, comp), g in found.items():
        rs = g["rows"]
        runs = len(rs)
        mse = interval(r.get("mse") for r in rs)
        anees = interval(r.get("anees") for r in rs)
        nx = n_comp[(h, est)]
        band = nees_band(runs, nx) if not math.isnan(anees[0]) else (math.nan, math.nan)
        verdict = anees_consistent(anees[1:], nx)
        other = found.get((h, ref, comp))
        if other is None:
            paired: list = [None] * 7
        else:
            p = paired_interval(*pair_values(rs, other["rows"], "mse"))
            paired = [ref, p["diff"], *p["diff_ci95"], p["ratio"], *p["ratio_ci95"]]
        out.append([g["grid"][k] for k in grid] + [
            h, est, comp, runs, *mse, *anees, verdict, float(band[0]), float(band[1]),
            *(_mean(r.get(m) for r in rs) for m in ("messages_per_tick", "bytes_per_tick", "late")),
            *paired])
    cells = [[None if isinstance(v, float) and math.isnan(v) else v for v in row] for row in out]
    return grid + list(SUMMARY_COLUMNS), cells

"""Summaries of tidy tables with grid columns (sweeps): a mean and 95 % interval per grid point.

A sweep table (docs/design.md, "Sweeps") has the grid columns, then ``param_hash,
run, seed, estimate, component`` and the metrics.  :func:`summarize` folds the
runs of each (parameter set, estimate, component) into one row: ``runs``, ``mse``
with its 95 % Student-t interval, ``anees`` with its t-interval and the 95 %
chi-square band of a consistent filter (:func:`dkfsim.analysis.metrics.nees_band`
with ``runs`` and the estimate's number of components), and the means of
``messages_per_tick``, ``bytes_per_tick`` and ``late``.  ``None``: not applicable.
Pure functions of the rows, so a database and its export summarize equally.
"""

from __future__ import annotations

import math

import numpy as np

from dkfsim.analysis.metrics import nees_band, t_interval

#: Columns of the summary after the grid columns.
SUMMARY_COLUMNS = ("param_hash", "estimate", "component", "runs", "mse", "mse_ci95_lo",
                   "mse_ci95_hi", "anees", "anees_ci95_lo", "anees_ci95_hi", "anees_band95_lo",
                   "anees_band95_hi", "messages_per_tick", "bytes_per_tick", "late")


def grid_columns(columns) -> list[str]:
    """The grid columns of a sweep table: those before ``param_hash``."""
    return list(columns[:list(columns).index("param_hash")])


def _number(v) -> float:
    return math.nan if v is None else float(v)


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
    a = np.array([_number(v) for v in values], dtype=float)
    if a.size == 0 or np.isnan(a).all():
        return math.nan, math.nan, math.nan
    mean, lo, hi = t_interval(a)
    return float(mean), float(lo), float(hi)


def _mean(values) -> float | None:
    a = np.array([_number(v) for v in values], dtype=float)
    return None if a.size == 0 or np.isnan(a).all() else float(np.mean(a))


def summarize(columns, rows) -> tuple[list[str], list[list]]:
    """The summary table (see the module docstring) of a sweep table's ``(columns, rows)``."""
    grid = grid_columns(columns)
    found = groups(columns, rows)
    n_comp: dict = {}
    for (h, est, _c) in found:
        n_comp[(h, est)] = n_comp.get((h, est), 0) + 1
    out = []
    for (h, est, comp), g in found.items():
        rs = g["rows"]
        runs = len(rs)
        mse = interval(r.get("mse") for r in rs)
        anees = interval(r.get("anees") for r in rs)
        band = nees_band(runs, n_comp[(h, est)]) if not math.isnan(anees[0]) else (math.nan, math.nan)
        out.append([g["grid"][k] for k in grid] + [
            h, est, comp, runs, *mse, *anees, float(band[0]), float(band[1]),
            *(_mean(r.get(m) for r in rs) for m in ("messages_per_tick", "bytes_per_tick", "late"))])
    cells = [[None if isinstance(v, float) and math.isnan(v) else v for v in row] for row in out]
    return grid + list(SUMMARY_COLUMNS), cells

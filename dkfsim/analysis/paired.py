"""Paired comparisons on common random numbers: an estimate against a reference, run by run.

Every estimate of a run is computed on the same draws (truth, noises, delays), so the
difference of a metric between two estimates varies much less from run to run than the
metric itself.  :func:`pair_values` lines up two sets of tidy rows by ``run`` (the run
index: same index, same seed, same draws), and :func:`paired_block` gives an estimate's
``paired`` entry of a Monte Carlo ``summary.json`` (and the paired columns of a sweep's
summary): per state component, the mean difference of the MSE to the reference with its
Student-t interval over the paired runs, and the ratio as the exponentiated t-interval of
the per-run log-ratios (:func:`dkfsim.analysis.metrics.paired_interval`).  Pure functions
of the rows.  docs/statistics.md says what each interval answers.
"""

from __future__ import annotations

import math

import numpy as np

from dkfsim.analysis.metrics import paired_interval
from dkfsim.core.errors import DkfsimError
from dkfsim.core.params import suggest

#: The reference estimate when none is named (``--relative-to``).
DEFAULT_REFERENCE = "centralized"


def reference_of(names, relative_to: str | None, of: str = "these runs", *,
                 suggestion: bool = False, why: str = "") -> str | None:
    """The reference estimate of the paired comparisons: ``relative_to`` (refused when not among
    ``names``, the estimates ``of`` a result or scenario), else ``centralized`` when present, else
    None.  The one check of ``--relative-to`` (a scenario before its runs, a sweep's summary and
    plot); the refusal adds the closest name when ``suggestion``, and ``why`` at its end."""
    names = list(names)
    if relative_to is not None:
        if relative_to not in names:
            hint = suggest(relative_to, names) if suggestion else ""
            raise DkfsimError(f"--relative-to {relative_to}: not an estimate of {of}{hint} "
                              f"(estimates: {', '.join(dict.fromkeys(names))}){why}")
        return relative_to
    return DEFAULT_REFERENCE if DEFAULT_REFERENCE in names else None


def number_or_nan(v) -> float:
    """A metric cell as a float, ``None`` (not applicable) as NaN."""
    return math.nan if v is None else float(v)


def by_run(rows, metric: str) -> dict[int, float]:
    """``{run: value of metric}`` of tidy rows of one estimate and component."""
    return {int(r["run"]): number_or_nan(r.get(metric)) for r in rows}


def pair_values(rows, reference_rows, metric: str) -> tuple[np.ndarray, np.ndarray]:
    """The values of ``metric`` in ``rows`` and in ``reference_rows`` for the runs both have,
    in run order: two arrays of equal length."""
    a, b = by_run(rows, metric), by_run(reference_rows, metric)
    runs = sorted(set(a) & set(b))
    return np.array([a[r] for r in runs], dtype=float), np.array([b[r] for r in runs], dtype=float)


def paired_block(rows, estimate: str, reference: str, components, metric: str = "mse") -> dict:
    """An estimate's ``paired`` entry: ``reference``, ``runs`` (pairs), and per component
    ``<metric>_diff``, ``<metric>_diff_ci95``, ``<metric>_ratio``, ``<metric>_ratio_ci95``.

    ``rows``: tidy rows of several estimates (``run``, ``estimate``, ``component``,
    ``metric``) of one scenario (or one grid point of a sweep)."""
    mine: dict = {c: [] for c in components}
    ref: dict = {c: [] for c in components}
    for r in rows:
        if r["component"] in mine:
            if r["estimate"] == estimate:
                mine[r["component"]].append(r)
            if r["estimate"] == reference:
                ref[r["component"]].append(r)
    out: dict = {"reference": reference, "runs": 0, f"{metric}_diff": {}, f"{metric}_diff_ci95": {},
                 f"{metric}_ratio": {}, f"{metric}_ratio_ci95": {}}
    for c in components:
        p = paired_interval(*pair_values(mine[c], ref[c], metric))
        out["runs"] = max(out["runs"], p["runs"])
        out[f"{metric}_diff"][c] = p["diff"]
        out[f"{metric}_diff_ci95"][c] = p["diff_ci95"]
        out[f"{metric}_ratio"][c] = p["ratio"]
        out[f"{metric}_ratio_ci95"][c] = p["ratio_ci95"]
    return out

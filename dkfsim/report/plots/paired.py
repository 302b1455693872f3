"""The paired comparison of a Monte Carlo folder: each estimate's MSE relative to the reference.

Every estimate of a run is computed on the same draws, so the ratio of its MSE to the
reference's (``summary.json``'s ``paired`` block: the exponentiated 95 % t-interval of the
per-run log-ratios) is known far more precisely than either MSE's own interval suggests.
One panel per state component, one row per estimate, a point at the ratio and a bar for
its interval; 1 (the reference) is a dotted line.  See docs/statistics.md.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from dkfsim.analysis.paired import paired_block
from dkfsim.config.results import read_rows
from dkfsim.core.errors import DkfsimError
from dkfsim.core.extras import pyplot
from dkfsim.report.plots.folders import Folder
from dkfsim.report.plots.style import (
    DEFAULT_FORMATS,
    check_formats,
    color_of,
    estimate_order,
    label_of,
    plain,
    plain_log_ticks,
    save_figure,
    select_components,
)


def paired_reference(stats) -> str | None:
    """The reference estimate named by the paired blocks of ``stats`` (a folder's ``stats``, or
    the ``estimates`` of its summary.json), None without any."""
    for s in stats.values():
        p = (s or {}).get("paired")
        if p:
            return p["reference"]
    return None


def relative_to(folder: Folder, reference: str) -> Folder:
    """``folder`` with its paired blocks recomputed against ``reference`` from ``runs.csv``
    (``dkfsim plot --relative-to NAME``)."""
    if folder.kind != "montecarlo":
        raise DkfsimError(f"--relative-to: only for Monte Carlo folders and sweeps; {folder.path} "
                          "is a single run (nothing to pair)")
    if reference not in folder.mse:
        raise DkfsimError(f"--relative-to {reference}: not an estimate of {folder.path} "
                          f"(estimates: {', '.join(folder.mse)})")
    rows = read_rows(folder.path / "runs.csv")
    for a in folder.mse:
        folder.stats.setdefault(a, {})["paired"] = paired_block(rows, a, reference, folder.components)
    return folder


def plot_paired(folder: Folder, stem, formats=DEFAULT_FORMATS, components=None) -> list[Path]:
    """Draw the MSE ratios to the reference with their paired 95 % intervals into ``stem``."""
    formats = check_formats(formats)
    ref = paired_reference(folder.stats)
    if ref is None:
        raise DkfsimError(f"{folder.path}: summary.json has no paired comparison (no reference "
                          "estimate in these runs; dkfsim montecarlo --relative-to NAME)")
    names = [a for a in estimate_order(folder.stats) if a != ref and (folder.stats[a] or {}).get("paired")]
    idx = select_components(folder.components, components, folder.path)
    plt = pyplot()
    fig, axes = plt.subplots(1, len(idx), figsize=(3.2 * len(idx) + 1.6, 0.32 * len(names) + 1.5),
                             sharey=True, squeeze=False)
    for ax, i in zip(axes[0], idx):
        comp = folder.components[i]
        vals = []
        for y, a in enumerate(names):
            p = folder.stats[a]["paired"]
            r, (lo, hi) = p["mse_ratio"].get(comp), p["mse_ratio_ci95"].get(comp, (None, None))
            if r is None or not np.isfinite(r):
                continue
            vals.append(r)
            ok = lo is not None and hi is not None and np.isfinite(lo) and np.isfinite(hi)
            err = [[max(r - lo, 0.0)], [max(hi - r, 0.0)]] if ok else None     # (a file may lie)
            ax.errorbar([r], [y], xerr=err, fmt="o", ms=3.5, capsize=2.5, lw=1.1, color=color_of(a, folder.mse))
        ax.axvline(1.0, color="0.3", lw=0.8, ls=":")
        finite = np.array([v for v in vals if np.isfinite(v) and v > 0])
        if finite.size and finite.max() / min(finite.min(), 1.0) > 10:
            ax.set_xscale("log")
            plain_log_ticks(ax, "x")
        ax.set_title(plain(comp), fontsize=9)
        ax.set_xlabel(f"MSE / {plain(ref)} MSE", fontsize=8.5)
        ax.grid(True, which="both", axis="x", alpha=0.3)
    axes[0, 0].set_yticks(range(len(names)))
    axes[0, 0].set_yticklabels([label_of(a) for a in names], fontsize=8)
    axes[0, 0].invert_yaxis()
    runs = f"{folder.n_runs} runs" if folder.n_runs else "the runs"
    fig.suptitle(f"MSE relative to {plain(ref)}, paired over {runs} (same draws)\n"
                 "point: geometric mean of the per-run ratios; bar: 95 % t-interval of their logs",
                 fontsize=9.5)
    fig.tight_layout()
    return save_figure(fig, stem, formats)

"""The accuracy figures of one folder: MSE per tick (paper Fig. 4) and the average NEES.

See :mod:`dkfsim.report.plots`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from dkfsim.core.errors import DkfsimError
from dkfsim.core.extras import pyplot
from dkfsim.report.plots.folders import Folder
from dkfsim.report.plots.style import (DEFAULT_FORMATS, _averages, _avg_text, _band,
                                       _check_formats, color_of, default_smooth, label_of,
                                       _legend_below, _log_limits, moving_average, mse_note,
                                       _mse_ylabel, _order, _positive, _save, select_components)


def plot_mse(folder: Folder, stem, formats=DEFAULT_FORMATS, components=None, smooth=None,
             estimates=None, title=None) -> list[Path]:
    """MSE per tick and component for every estimate in the folder (paper Fig. 4)."""
    formats = _check_formats(formats)
    idx = select_components(folder, components)
    w = default_smooth(folder) if smooth is None else max(1, int(smooth))
    names = _order(folder.mse) if estimates is None else [a for a in estimates if a in folder.mse]
    if not names:
        raise DkfsimError(f"{folder.path}: none of the estimates {', '.join(estimates or [])} is in the folder")
    plt = pyplot()
    fig, axes = plt.subplots(len(idx), 1, figsize=(7.5, 2.3 * len(idx) + 0.9), sharex=True, squeeze=False)
    for ax, i in zip(axes[:, 0], idx):
        drawn, entries = [], []
        for j, a in enumerate(names):
            col = color_of(a, j)
            entries.append((_avg_text(folder, a, i), col))
            style = dict(color=col, lw=1.0, ls="--" if a == "centralized" else "-",
                         zorder={"fused": 5, "centralized": 6}.get(a, 3))
            y = _positive(moving_average(folder.mse[a][:, i], w))
            drawn.append(y)
            ax.plot(folder.t, y, label=label_of(a), **style)
            if a in folder.ci:
                lo, hi = folder.ci[a]
                ax.fill_between(folder.t, *_band(moving_average(lo[:, i], w), moving_average(hi[:, i], w)),
                                color=col, alpha=0.2, lw=0)
        ax.set_yscale("log")
        _log_limits(ax, drawn)
        _averages(ax, entries, folder)
        ax.set_ylabel(_mse_ylabel(folder, i, w))
        ax.grid(True, which="both", alpha=0.25)
        ax.margins(x=0)
    axes[-1, 0].set_xlabel("time [s]")
    fig.suptitle((title or f"MSE per tick: {folder.describe()}") + f"\n({mse_note(folder, w)})", fontsize=11)
    _legend_below(fig, axes[0, 0])
    return _save(fig, stem, formats)


def plot_nees(folder: Folder, stem, formats=DEFAULT_FORMATS, title=None) -> list[Path]:
    """Average NEES per tick with its 95 % consistency band (Monte Carlo folders)."""
    formats = _check_formats(formats)
    if not folder.nees:
        raise DkfsimError(f"{folder.path}: no NEES curves")
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7.5, 3.4))
    for j, a in enumerate(_order(folder.nees)):
        if np.all(~np.isfinite(folder.nees[a])):
            continue
        ax.plot(folder.t, folder.nees[a], color=color_of(a, j), lw=1.0, label=label_of(a),
                ls="--" if a == "centralized" else "-")
    if folder.nees_band is not None:
        ax.axhspan(*folder.nees_band, color="0.5", alpha=0.18, lw=0, label="95 % consistency band")
    ax.axhline(folder.nx, color="0.3", lw=0.8, ls=":")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("average NEES")
    ax.grid(True, alpha=0.3)
    ax.margins(x=0)
    n = f"{folder.n_runs} runs" if folder.n_runs else "Monte Carlo runs"
    ax.set_title(title or f"Consistency: {folder.describe()} (mean NEES over {n}; expected value {folder.nx})",
                 fontsize=10)
    _legend_below(fig, ax)
    return _save(fig, stem, formats)


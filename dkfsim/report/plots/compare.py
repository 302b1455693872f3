"""The comparison figure: the fused MSE of several folders overlaid (paper Figs. 5 and 6).

See :mod:`dkfsim.report.plots`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from dkfsim.core.errors import DkfsimError
from dkfsim.core.extras import pyplot
from dkfsim.report.plots.folders import Folder
from dkfsim.report.plots.style import (
    DEFAULT_FORMATS,
    average_text,
    check_formats,
    default_smooth,
    draw_averages,
    label_of,
    legend_below,
    log_band,
    log_limits,
    moving_average,
    mse_note,
    mse_ylabel,
    plain,
    positive_only,
    save_figure,
    select_components,
)


def check_comparable(folders: list[Folder]) -> None:
    first = folders[0]
    for f in folders[1:]:
        if f.K != first.K:
            raise DkfsimError(f"--compare: {f.path} has {f.K} ticks but {first.path} has {first.K}; "
                              f"compare folders run with the same number of steps")
        if not np.allclose(f.t, first.t, rtol=1e-9, atol=0):
            raise DkfsimError(f"--compare: {f.path} and {first.path} have different sample times "
                              f"(sampling periods {f.t[0]:g} s and {first.t[0]:g} s)")
        if f.components != first.components:
            raise DkfsimError(f"--compare: {f.path} has components {', '.join(f.components)} but "
                              f"{first.path} has {', '.join(first.components)}")


def plot_compare(folders: list[Folder], stem, labels=None, formats=DEFAULT_FORMATS, components=None,
                 smooth=None, title=None, estimate="fused", bands=None,
                 relative=False) -> list[Path]:
    """Fused MSE of several folders and the centralized filter of the first (paper Figs. 5, 6).

    ``relative`` adds a right-hand column with each folder's MSE divided by the
    first folder's centralized MSE (both moving-averaged over 5 % of the run):
    on the same draws the noise common to all curves cancels, so differences
    of a few per cent, invisible on the log scale, show.
    """
    formats = check_formats(formats)
    if len(folders) < 2:
        raise DkfsimError("--compare: give at least two folders")
    if labels is None:
        labels = [f.path.name or str(f.path) for f in folders]
    labels = [plain(lab) for lab in labels]
    if len(labels) != len(folders):
        raise DkfsimError(f"--labels: {len(labels)} labels for {len(folders)} folders; give one label per folder")
    check_comparable(folders)
    for f in folders:
        if estimate not in f.mse:
            raise DkfsimError(f"--compare: {f.path} has no {label_of(estimate)} estimate")
    first = folders[0]
    if relative and "centralized" not in first.mse:
        raise DkfsimError(f"--relative: the first folder ({first.path}) has no centralized estimate "
                          f"to divide by; run it with estimators including {{kind: centralized}}")
    idx = select_components(first.components, components, first.path)
    w = default_smooth(first) if smooth is None else max(1, int(smooth))
    if smooth is None and any(f.kind == "run" for f in folders):
        w = max(default_smooth(f) for f in folders)
    wr = max(w, first.K // 20)
    plt = pyplot()
    ncols = 2 if relative else 1
    height = 2.3 * len(idx) + 1.0 if len(idx) > 1 else 3.8
    fig, axes = plt.subplots(len(idx), ncols, figsize=(12.0 if relative else 7.5, height),
                             sharex=True, squeeze=False,
                             gridspec_kw={"width_ratios": [1.25, 1]} if relative else None)
    n = len(folders)
    cmap = plt.get_cmap("viridis")
    colors = [f"C{j}" for j in range(n)] if n <= 3 else [cmap(0.9 * j / (n - 1)) for j in range(n)]
    if bands is None:      # overlapping per-tick bands of many curves hide the curves
        bands = n <= 2
    for row, i in enumerate(idx):
        ax = axes[row, 0]
        drawn, entries = [], []
        for f, lab, col in zip(folders, labels, colors):
            y = positive_only(moving_average(f.mse[estimate][:, i], w))
            drawn.append(y)
            entries.append((f"{plain(lab, 16)}: {average_text(f, estimate, i)}", col))
            ax.plot(f.t, y, color=col, lw=1.1, label=lab)
            if bands and estimate in f.ci:
                lo, hi = f.ci[estimate]
                ax.fill_between(f.t, *log_band(moving_average(lo[:, i], w), moving_average(hi[:, i], w), y),
                                color=col, alpha=0.18, lw=0)
        if "centralized" in first.mse:
            y = positive_only(moving_average(first.mse["centralized"][:, i], w))
            drawn.append(y)
            entries.append((f"centralized: {average_text(first, 'centralized', i)}", "k"))
            ax.plot(first.t, y, color="k", lw=1.0, ls="--",
                    label="centralized KF (all data on time)" + (f", from {labels[0]}" if len(labels[0]) < 12 else ""))
        ax.set_yscale("log")
        log_limits(ax, drawn)
        ax.set_ylabel(mse_ylabel(first, i))
        ax.grid(True, which="both", alpha=0.25)
        ax.margins(x=0)
        if relative:
            ar = axes[row, 1]
            den = moving_average(first.mse["centralized"][:, i], wr)
            for f, col in zip(folders, colors):
                ar.plot(f.t, moving_average(f.mse[estimate][:, i], wr) / den, color=col, lw=1.2)
            ar.axhline(1.0, color="k", lw=1.0, ls="--")
            ar.set_ylabel(f"{plain(first.components[i])} MSE / centralized")
            ar.grid(True, alpha=0.3)
            ar.margins(x=0)
            if row == 0:
                ar.set_title(f"relative to the centralized KF ({wr}-tick moving averages)", fontsize=9)
        draw_averages(axes[row, -1], entries, first)
    for c in range(ncols):
        axes[-1, c].set_xlabel("time [s]")
    kinds = {f.kind for f in folders}
    ref = folders[0]
    note = mse_note(ref if kinds == {ref.kind} else next(f for f in folders if f.kind == "run"), w)
    if not bands and any(f.ci for f in folders):
        note = note.replace(", 95 % CI shaded", "")
    what = "fused anti-delay DKF" if estimate == "fused" else label_of(estimate)
    # (the labels are in the legend)
    fig.suptitle((plain(title) if title else f"MSE of the {what}") + f"\n({note})", fontsize=11)
    legend_below(fig, axes[0, 0], ncol=3 if n + 1 > 4 else 2)
    return save_figure(fig, stem, formats)


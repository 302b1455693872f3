"""The comparison figure: the fused MSE of several folders overlaid (paper Figs. 5 and 6).

See :mod:`dkfsim.report.plots`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from dkfsim.core.errors import DkfsimError
from dkfsim.core.extras import optional, pyplot
from dkfsim.report.plots.folders import Folder
from dkfsim.report.plots.style import (
    DEFAULT_FORMATS,
    average_text,
    check_formats,
    color_of,
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

#: Line styles of the folders, in order (``--compare``): the colour says which estimate a line is
#: (one vocabulary in every figure), the line style which folder.  Beyond six they repeat,
#: told apart by their shade.  None is ``--``, the centralized filter's style in every figure.
FOLDER_STYLES = ("-", (0, (5, 1.5, 1, 1.5)), (0, (1, 1.2)), (0, (8, 2, 1, 2, 1, 2)), (0, (10, 3)), (0, (2, 3)))
#: The per-tick bands of the first folders (drawn for two folders unless asked): filled, then hatched.
BAND_HATCHES = (None, "////", "\\\\\\\\", "xxxx")


def folder_looks(color, n: int) -> tuple[list, list]:
    """Colours and line styles of ``n`` folders drawn in the estimate's ``color``: folder 0 in
    that colour, the next ones lighter by steps (up to 55 % towards white), so that the hue still
    names the estimate; each with its own line style (:data:`FOLDER_STYLES`)."""
    base = np.array(optional("matplotlib.colors").to_rgb(color))
    mix = [0.55 * j / (n - 1) if n > 1 else 0.0 for j in range(n)]
    colors = [tuple(float(c) for c in base + m * (1.0 - base)) for m in mix]
    return colors, [FOLDER_STYLES[j % len(FOLDER_STYLES)] for j in range(n)]


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
    names = [str(lab) for lab in labels]           # as given: cut and escaped once where drawn
    labels = [plain(lab) for lab in names]
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
    colors, styles = folder_looks(color_of(estimate, first.mse), n)
    if bands is None:      # overlapping per-tick bands of many curves hide the curves
        bands = n <= 2
    for row, i in enumerate(idx):
        ax = axes[row, 0]
        drawn, entries = [], []
        for j, (f, lab, name, col, ls) in enumerate(zip(folders, labels, names, colors, styles)):
            y = positive_only(moving_average(f.mse[estimate][:, i], w))
            drawn.append(y)
            entries.append((f"{plain(name, 16)}: {average_text(f, estimate, i)}", col))
            ax.plot(f.t, y, color=col, lw=1.1, ls=ls, label=lab)
            if bands and estimate in f.ci:
                lo, hi = f.ci[estimate]
                ax.fill_between(f.t, *log_band(moving_average(lo[:, i], w), moving_average(hi[:, i], w), y),
                                facecolor=col if j == 0 else "none", edgecolor=col,
                                alpha=0.18 if j == 0 else 0.35, lw=0, hatch=BAND_HATCHES[j % len(BAND_HATCHES)])
        central = color_of("centralized")
        if "centralized" in first.mse:
            y = positive_only(moving_average(first.mse["centralized"][:, i], w))
            drawn.append(y)
            entries.append((f"centralized: {average_text(first, 'centralized', i)}", central))
            ax.plot(first.t, y, color=central, lw=1.0, ls="--",
                    label="centralized KF (all data on time)" + (f", from {labels[0]}" if len(labels[0]) < 12 else ""))
        ax.set_yscale("log")
        log_limits(ax, drawn)
        ax.set_ylabel(mse_ylabel(first, i))
        ax.grid(True, which="both", alpha=0.25)
        ax.margins(x=0)
        if relative:
            ar = axes[row, 1]
            den = moving_average(first.mse["centralized"][:, i], wr)
            for f, col, ls in zip(folders, colors, styles):
                ar.plot(f.t, moving_average(f.mse[estimate][:, i], wr) / den, color=col, lw=1.2, ls=ls)
            ar.axhline(1.0, color=central, lw=1.0, ls="--")
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
    legend_below(fig, axes[0, 0], ncol=3 if n + 1 > 4 else 2,
                 title=f"one line style per folder; colour: the estimate ({plain(estimate, 40)}, centralized)")
    return save_figure(fig, stem, formats)


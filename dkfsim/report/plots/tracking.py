"""The tracking figure: truth, fused, node 0 and the references per component (paper Fig. 3).

See :mod:`dkfsim.report.plots`.
"""

from __future__ import annotations

from pathlib import Path

from dkfsim.config.dynamics import state_text
from dkfsim.core.errors import DkfsimError
from dkfsim.core.extras import pyplot
from dkfsim.report.plots.folders import Folder
from dkfsim.report.plots.style import (
    DEFAULT_FORMATS,
    check_formats,
    color_of,
    label_of,
    legend_below,
    plain,
    save_figure,
    select_components,
    unit_label,
)

# ----------------------------------------------------------------------------
# figures
# ----------------------------------------------------------------------------

def zoom_window(K: int) -> tuple[int, int]:
    """Rows shown in the zoom column of the tracking figure: 8 % of the run, centred."""
    n = max(2, min(K, round(0.08 * K)))
    lo = max(0, K // 2 - n // 2)
    return lo, min(K, lo + n)


def plot_tracking(folder: Folder, stem, formats=DEFAULT_FORMATS, components=None, title=None,
                  zoom=True) -> list[Path]:
    """Truth, fused, node 0 and the references, one row per component (paper Fig. 3).

    The left column shows the whole run; at that scale every estimate lies on
    the truth, so the right column repeats a short window (shaded on the left)
    where the estimates can be told apart.
    """
    formats = check_formats(formats)
    if folder.truth is None:
        raise DkfsimError(f"{folder.path}: no example run (example_truth) to draw the tracking figure from")
    idx = select_components(folder.components, components, folder.path)
    plt = pyplot()
    ncols = 2 if zoom and folder.K >= 20 else 1
    fig, axes = plt.subplots(len(idx), ncols, figsize=(9.0 if ncols == 2 else 7.5, 2.3 * len(idx) + 0.6),
                             sharex="col", squeeze=False,
                             gridspec_kw={"width_ratios": [2.2, 1]} if ncols == 2 else None)
    t = folder.t
    lines = [("truth", folder.truth, dict(color="0.6", lw=3.0, zorder=1))]
    if "fused" in folder.examples:
        lines.append((label_of("fused"), folder.examples["fused"],
                      dict(color=color_of("fused"), lw=1.2, zorder=4)))
    if folder.node0 is not None:
        lines.append(("local: anti-delay DKF, node 0 (real time)", folder.node0,   # one of the local estimates
                      dict(color=color_of("local"), lw=1.0, ls=(0, (1.5, 1.2)), zorder=3)))
    if "centralized" in folder.examples:
        lines.append((label_of("centralized"), folder.examples["centralized"],
                      dict(color=color_of("centralized"), lw=0.9, ls="--", zorder=5)))
    if "ci_consensus" in folder.examples:
        lab = label_of("ci_consensus") + (", node 0" if folder.kind == "run" else "")
        lines.append((lab, folder.examples["ci_consensus"],
                      dict(color=color_of("ci_consensus"), lw=1.0, ls="-.", zorder=2)))
    lo, hi = zoom_window(folder.K)
    for row, i in enumerate(idx):
        ax = axes[row, 0]
        for lab, x, style in lines:
            ax.plot(t, x[:, i], label=lab, **style)
        ax.set_ylabel(plain(folder.components[i]) + unit_label(folder.units[i]))
        ax.grid(True, alpha=0.3)
        ax.margins(x=0)
        if ncols == 2:
            ax.axvspan(t[lo], t[hi - 1], color="0.5", alpha=0.15, lw=0)     # no estimate's colour
            az = axes[row, 1]
            for _lab, x, style in lines:
                az.plot(t[lo:hi], x[lo:hi, i], **style)
            az.grid(True, alpha=0.3)
            az.margins(x=0)
            az.set_facecolor((1.0, 0.97, 0.93))
    axes[-1, 0].set_xlabel("time [s]")
    if ncols == 2:
        axes[-1, 1].set_xlabel("time [s] (zoom)")
        axes[0, 1].set_title("zoom on the shaded window", fontsize=9)
    sub = "" if folder.kind == "run" else " (one example run)"
    cond = folder.condition()
    fig.suptitle(plain(title) if title else f"Tracking{', ' + cond if cond else ''}{sub}\n"
                 f"({plain(state_text(folder.components))})", fontsize=11)
    legend_below(fig, axes[0, 0], ncol=3 if len(lines) > 4 else 2)
    return save_figure(fig, stem, formats)


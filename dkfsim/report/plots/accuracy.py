"""The accuracy figures of one folder: MSE per tick (paper Fig. 4) and the average NEES.

See :mod:`dkfsim.report.plots`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from dkfsim.config.dynamics import state_text
from dkfsim.core.errors import DkfsimError
from dkfsim.core.extras import pyplot
from dkfsim.report.plots.folders import Folder
from dkfsim.report.plots.style import (
    DEFAULT_FORMATS,
    OPEN_BELOW,
    average_text,
    check_formats,
    color_of,
    default_smooth,
    draw_averages,
    estimate_order,
    label_of,
    legend_below,
    log_band,
    log_limits,
    moving_average,
    mse_note,
    mse_ylabel,
    opens_below,
    plain,
    positive_only,
    save_figure,
    select_components,
)

#: A ratio panel is added when the worst estimate's MSE exceeds the best one's by this factor.
RATIO_PANEL_ABOVE = 10.0
#: The ratio panel shows the estimates within this factor of the reference.
RATIO_SHOWN_WITHIN = 3.0
#: Above this many estimates with a NEES curve the NEES figure has one small panel per estimate.
NEES_SMALL_MULTIPLES_ABOVE = 4


def _ratio_reference(folder: Folder, names, idx) -> str | None:
    """The reference of the ratio panel: ``centralized`` when present, else the best estimate,
    when the MSEs of ``names`` span more than :data:`RATIO_PANEL_ABOVE` in some component."""
    if len(names) < 2:
        return None
    for i in idx:
        avg = [folder.time_average(a, i) for a in names]
        avg = [v for v in avg if np.isfinite(v) and v > 0]
        if avg and max(avg) / min(avg) > RATIO_PANEL_ABOVE:
            break
    else:
        return None
    if "centralized" in names:
        return "centralized"
    return min(names, key=lambda a: folder.time_average(a, idx[0]))


def plot_mse(folder: Folder, stem, formats=DEFAULT_FORMATS, components=None, smooth=None,
             estimates=None, title=None, ratio=None) -> list[Path]:
    """MSE per tick and component for every estimate in the folder (paper Fig. 4).

    When the estimates' MSEs differ by more than :data:`RATIO_PANEL_ABOVE` (``ratio``
    None; True / False force it), a right-hand column divides each estimate within
    :data:`RATIO_SHOWN_WITHIN` of the centralized filter (or of the best estimate) by
    it, on a linear axis, so the best estimates are not hidden under a far worse
    one on the log scale; the others are named in the panel with their factor.
    """
    formats = check_formats(formats)
    idx = select_components(folder.components, components, folder.path)
    w = default_smooth(folder) if smooth is None else max(1, int(smooth))
    names = estimate_order(folder.mse) if estimates is None else [a for a in estimates if a in folder.mse]
    if not names:
        raise DkfsimError(f"{folder.path}: none of the estimates {', '.join(estimates or [])} is in the folder")
    ref = _ratio_reference(folder, names, idx) if ratio is None else \
        (("centralized" if "centralized" in names else names[0]) if ratio else None)
    plt = pyplot()
    ncols = 2 if ref else 1
    fig, axes = plt.subplots(len(idx), ncols, figsize=(12.0 if ref else 7.5, 2.3 * len(idx) + 0.9),
                             sharex=True, squeeze=False,
                             gridspec_kw={"width_ratios": [1.25, 1]} if ref else None)
    wr = max(w, folder.K // 20)
    opened = False
    for row, i in enumerate(idx):
        ax = axes[row, 0]
        drawn, entries = [], []
        for a in names:
            col = color_of(a, folder.mse)
            entries.append((f"{plain(a, 16)}: {average_text(folder, a, i)}", col))
            style = dict(color=col, lw=1.0, ls="--" if a == "centralized" else "-",
                         zorder={"fused": 5, "centralized": 6}.get(a, 3))
            y = positive_only(moving_average(folder.mse[a][:, i], w))
            drawn.append(y)
            ax.plot(folder.t, y, label=label_of(a), **style)
            if a in folder.ci:
                lo, hi = (moving_average(b[:, i], w) for b in folder.ci[a])
                opened |= opens_below(lo)
                ax.fill_between(folder.t, *log_band(lo, hi, y), color=col, alpha=0.2, lw=0)
        ax.set_yscale("log")
        log_limits(ax, drawn)
        ax.set_ylabel(mse_ylabel(folder, i))
        ax.grid(True, which="both", alpha=0.25)
        ax.margins(x=0)
        if ref:
            _ratio_panel(axes[row, 1], folder, names, ref, i, wr, first=row == 0)
        draw_averages(axes[row, -1], entries, folder)
    for c in range(ncols):
        axes[-1, c].set_xlabel("time [s]")
    cond = folder.condition()
    open_note = f";\n{OPEN_BELOW}" if opened else ""
    fig.suptitle((plain(title) if title else f"MSE per tick{', ' + cond if cond else ''}")
                 + f"\n({mse_note(folder, w)}; {plain(state_text(folder.components))}{open_note})",
                 fontsize=11)
    legend_below(fig, axes[0, 0], ncol=3 if ref and len(names) > 4 else 2)
    return save_figure(fig, stem, formats)


def _ratio_panel(ar, folder: Folder, names, ref: str, i: int, wr: int, first: bool) -> None:
    """Each estimate within :data:`RATIO_SHOWN_WITHIN` of ``ref`` divided by it (linear axis)."""
    den = moving_average(folder.mse[ref][:, i], wr)
    base = folder.time_average(ref, i)
    off = []
    for a in names:
        factor = folder.time_average(a, i) / base if base > 0 else np.inf
        if a == ref:
            continue
        if not np.isfinite(factor) or factor > RATIO_SHOWN_WITHIN:
            off.append(f"{plain(a)} ×{factor:.3g}" if np.isfinite(factor) else plain(a))
            continue
        with np.errstate(divide="ignore", invalid="ignore"):
            ar.plot(folder.t, moving_average(folder.mse[a][:, i], wr) / den, color=color_of(a, folder.mse), lw=1.2)
    ar.axhline(1.0, color="k", lw=1.0, ls="--")
    ar.set_ylabel(f"{plain(folder.components[i])} MSE / {plain(ref)}")
    ar.grid(True, alpha=0.3)
    ar.margins(x=0)
    head = f"relative to {plain(ref)} (estimates within ×{RATIO_SHOWN_WITHIN:g}; {wr}-tick " \
        "moving averages)\n" if first else ""
    if off or first:                      # above the panel, never over a curve
        per_line = 4
        lines = [", ".join(off[k:k + per_line]) for k in range(0, len(off), per_line)]
        ar.set_title(head + ("off this scale: " + ",\n".join(lines) if off else ""), fontsize=7.5,
                     color="0.2")


def plot_nees(folder: Folder, stem, formats=DEFAULT_FORMATS, title=None) -> list[Path]:
    """Average NEES per tick with the per-tick 95 % chi-square band (Monte Carlo folders).

    The band is that of the mean NEES at one tick; each estimate's label gives the fraction
    of ticks inside it and, from ``summary.json``, the verdict on the time average: its
    ANEES with the 95 % t-interval over runs, consistent when the interval covers nx
    (docs/statistics.md).  Up to :data:`NEES_SMALL_MULTIPLES_ABOVE` estimates share one
    panel; more get one small panel each (same band, own y range).
    """
    formats = check_formats(formats)
    if not folder.nees:
        raise DkfsimError(f"{folder.path}: no NEES curves")
    names = [a for a in estimate_order(folder.nees) if not np.all(~np.isfinite(folder.nees[a]))]
    if not names:
        raise DkfsimError(f"{folder.path}: no finite NEES curve (no estimate has a covariance)")
    n = f"{folder.n_runs} runs" if folder.n_runs else "Monte Carlo runs"
    cond = folder.condition()
    head = plain(title) if title else \
        f"Consistency{', ' + cond if cond else ''}: mean NEES over {n} (expected {folder.nx})"
    if len(names) > NEES_SMALL_MULTIPLES_ABOVE:
        return _nees_small_multiples(folder, names, stem, formats, head)
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7.5, 3.4))
    for a in names:
        ax.plot(folder.t, folder.nees[a], color=color_of(a, folder.mse), lw=1.0,
                label=f"{label_of(a)}: {nees_verdict(folder, a)}", ls="--" if a == "centralized" else "-")
    if folder.nees_band is not None:
        ax.axhspan(*folder.nees_band, color="0.5", alpha=0.18, lw=0, label=band_label(folder))
    # (dotted grey: centralized is the black dashed curve, issue 34 §6)
    ax.axhline(folder.nx, color=EXPECTED_COLOUR, lw=1.6, ls=":", zorder=4, label=f"expected value nx = {folder.nx}")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("average NEES")
    ax.grid(True, alpha=0.3)
    ax.margins(x=0)
    ax.set_title(head, fontsize=10)
    legend_below(fig, ax, ncol=1)
    return save_figure(fig, stem, formats)


#: The expected value's line in the NEES figures: dotted dark grey, never a curve's style.
EXPECTED_COLOUR = "0.35"


def nees_verdict(folder: Folder, estimate: str) -> str:
    """``x % of ticks in band; ANEES a [lo, hi]: consistent`` for one estimate (what is known)."""
    parts = []
    frac = folder.fraction_in_band(estimate)
    if frac is not None:
        parts.append(f"{100 * frac:.0f} % of ticks in band")
    s = folder.stats.get(estimate) or {}
    anees, ci, ok = s.get("anees"), s.get("anees_ci95"), s.get("anees_consistent")
    if anees is not None and np.isfinite(anees):
        text = f"ANEES {anees:.3g}"
        if ci is not None and None not in ci and np.all(np.isfinite(ci)):
            text += f" [{ci[0]:.3g}, {ci[1]:.3g}]"
        if ok is not None:
            text += ": consistent" if ok else ": inconsistent"
        parts.append(text)
    return "; ".join(parts)


def band_label(folder: Folder) -> str:
    lo, hi = folder.nees_band or (np.nan, np.nan)
    return f"per-tick 95 % band of the mean NEES [{lo:.3g}, {hi:.3g}]"


def _nees_small_multiples(folder: Folder, names, stem, formats, head) -> list[Path]:
    plt = pyplot()
    ncols = 3 if len(names) > 4 else 2
    nrows = -(-len(names) // ncols)
    fig, axes = plt.subplots(nrows, ncols, figsize=(3.6 * ncols, 2.3 * nrows + 0.9), sharex=True,
                             sharey=True, squeeze=False)      # one scale: panels compare at a glance
    for k, ax in enumerate(axes.flat):
        if k >= len(names):
            ax.set_visible(False)
            continue
        a = names[k]
        if folder.nees_band is not None:
            ax.axhspan(*folder.nees_band, color="0.5", alpha=0.18, lw=0)
        ax.plot(folder.t, folder.nees[a], color=color_of(a, folder.mse), lw=0.9)
        ax.axhline(folder.nx, color=EXPECTED_COLOUR, lw=1.6, ls=":", zorder=4)       # over the trace
        verdict = nees_verdict(folder, a).replace("; ", "\n", 1)
        ax.set_title(f"{label_of(a)}\n{verdict}" if verdict else label_of(a), fontsize=7.5)
        ax.grid(True, alpha=0.3)
        ax.margins(x=0)
        ax.tick_params(labelsize=7.5)
        if k % ncols == 0:
            ax.set_ylabel("average NEES", fontsize=8)
        if k >= len(names) - ncols:         # the lowest panel of its column: its own time axis
            ax.set_xlabel("time [s]", fontsize=8)
            ax.xaxis.set_tick_params(labelbottom=True)
    band = f"\ndotted: the expected value nx = {folder.nx}" + \
        ("" if folder.nees_band is None else f"; grey: {band_label(folder)}")
    fig.suptitle(head + band, fontsize=10)
    fig.tight_layout()
    return save_figure(fig, stem, formats)

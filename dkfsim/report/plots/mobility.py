"""A run with ``mobility:`` (docs/mobility.md, "Seeing it"): the network over time and the
estimate errors beside the changes of the links.

Two figures, from the arrays ``dkfsim run`` keeps for such a run (``positions``, ``links_up``,
``mobility_links``; decision 187):

* ``network_over_time``: small multiples at chosen ticks (default: six evenly spaced, ``--at``),
  each the vehicles' positions, their paths over the whole run (grey) and the links up at that
  tick; every panel has the same scale, centred on the vehicles at that tick (decision 188);
* ``topology_errors``: the squared position error per tick (sum over the components in metres,
  centred moving average over 4 % of the ticks unless ``--smooth``) of ``fused``, ``local`` (mean over the nodes) and ``centralized``, with the
  ticks at which the set of links up changed marked, above a strip of the number of links up.
"""

from __future__ import annotations

import numpy as np

from dkfsim.core.errors import DkfsimError
from dkfsim.core.extras import pyplot
from dkfsim.report.plots.accuracy import EXPECTED_COLOUR
from dkfsim.report.plots.folders import Folder
from dkfsim.report.plots.style import (
    DEFAULT_FORMATS,
    check_formats,
    color_of,
    default_smooth,
    estimate_order,
    label_of,
    moving_average,
    plain,
    save_figure,
)

#: Panels of ``network_over_time`` without ``--at``.
DEFAULT_INSTANTS = 6
#: Most panels ``--at`` may ask for.
MAX_INSTANTS = 24
#: Estimates drawn in ``topology_errors`` when the run has them.
ERROR_ESTIMATES = ("fused", "local", "centralized")


def has_mobility(folder: Folder) -> bool:
    """True when the folder is a run with ``mobility:`` (its run.npz keeps positions and links),
    or a Monte Carlo folder of such a scenario (replayed from it: the same in every run)."""
    return bool(folder.mobility)


def _require(folder: Folder) -> None:
    if not has_mobility(folder):
        raise DkfsimError(f"{folder.path}: not a run or Monte Carlo folder of a scenario with mobility: "
                          "(no positions): no network-over-time figure")


def instants(folder: Folder, at=None) -> list[int]:
    """The ticks drawn (``1 .. K``): ``at`` checked, else :data:`DEFAULT_INSTANTS` evenly spaced."""
    K = folder.K
    if at is None:
        return sorted({int(round(x)) for x in np.linspace(1, K, min(DEFAULT_INSTANTS, K))})
    ticks = sorted({int(k) for k in at})
    if not ticks or len(ticks) > MAX_INSTANTS:
        raise DkfsimError(f"--at: give 1 to {MAX_INSTANTS} ticks, got {len(ticks)}")
    bad = [k for k in ticks if not 1 <= k <= K]
    if bad:
        raise DkfsimError(f"--at: tick {bad[0]} is outside the run's ticks 1..{K}")
    return ticks


def plot_network_over_time(folder: Folder, stem, formats=DEFAULT_FORMATS, at=None) -> list:
    """``stem.png`` (and the other formats): the vehicles and the links up at the ticks ``at``
    (default six evenly spaced), one panel each.  Raises DkfsimError without mobility."""
    formats = check_formats(formats)
    _require(folder)
    ticks = instants(folder, at)
    plt = pyplot()
    m = folder.mobility
    pos, up, pairs = m["positions"], m["links_up"], m["mobility_links"]
    rows = [k - 1 for k in ticks]                            # row r holds tick r + 1
    origin = np.zeros(2)
    if np.abs(pos).max() > 1e4:          # map coordinates (UTM): axes relative to a round origin
        origin = np.floor(pos.min(axis=(0, 1)) / 100) * 100
        pos = pos - origin
    centres = [(pos[r].min(axis=0) + pos[r].max(axis=0)) / 2 for r in rows]
    half = max(float(np.max(np.abs(pos[r] - c))) for r, c in zip(rows, centres))
    half = max(half * 1.15, 1.0)                             # one scale for every panel
    ncol = min(3, len(ticks))
    nrow = -(-len(ticks) // ncol)
    fig, axes = plt.subplots(nrow, ncol, figsize=(3.6 * ncol, 3.6 * nrow + 0.6), squeeze=False)
    for ax in axes.flat[len(ticks):]:
        ax.set_visible(False)
    for ax, k, r, c in zip(axes.flat, ticks, rows, centres):
        for i in range(pos.shape[1]):
            ax.plot(pos[:, i, 0], pos[:, i, 1], color="0.85", lw=0.8, zorder=0)
        for (u, v) in pairs[up[r]].tolist():
            ax.plot(pos[r, [u, v], 0], pos[r, [u, v], 1], color="C0", lw=1.2, zorder=1)
        ax.plot(pos[r, :, 0], pos[r, :, 1], "o", color="C3", ms=5, zorder=2)
        for (x, y), nodes in _stacks(pos[r], half / 40).items():      # vehicles on one spot: one label
            ax.annotate(",".join(map(str, nodes)), (x, y), textcoords="offset points", xytext=(4, 4),
                        fontsize=7)
        ax.set_xlim(c[0] - half, c[0] + half)
        ax.set_ylim(c[1] - half, c[1] + half)
        ax.set_aspect("equal")
        ax.set_title(f"t = {folder.t[r]:.4g} s (tick {k}): {int(up[r].sum())} links up", fontsize=9)
        ax.tick_params(labelsize=7)
        ax.grid(alpha=0.3)
    for ax in axes[-1]:
        ax.set_xlabel(_axis_label("x", origin[0]), fontsize=8)
    for ax in axes[:, 0]:
        ax.set_ylabel(_axis_label("y", origin[1]), fontsize=8)
    fig.suptitle(plain(f"{folder.scenario}: the vehicles and the links up") +
                 " (grey: the paths over the whole run)", fontsize=10)
    fig.tight_layout()
    return save_figure(fig, stem, formats)


def _axis_label(name: str, origin: float) -> str:
    return f"{name} − {origin:.0f} [m]" if origin else f"{name} [m]"


def _stacks(points: np.ndarray, tol: float) -> dict[tuple[float, float], list[int]]:
    """The vehicles that sit within ``tol`` of the first of them (their first point -> the nodes)."""
    out: dict[tuple[float, float], list[int]] = {}
    for i, (x, y) in enumerate(points.tolist()):
        for (px, py), nodes in out.items():
            if abs(px - x) <= tol and abs(py - y) <= tol:
                nodes.append(i)
                break
        else:
            out[(x, y)] = [i]
    return out


def _position_columns(folder: Folder) -> tuple[list[int], str]:
    """The position components (those in metres, e.g. ``x`` and ``y`` of the motion models),
    else every component; and what their summed squared error is called."""
    cols = [i for i, u in enumerate(folder.units) if u == "m"]
    if cols:
        names = " + ".join(folder.components[i] for i in cols)
        return cols, f"squared position error ({names}) [m²]"
    return list(range(folder.nx)), "squared error, sum over the components"


def change_ticks(folder: Folder) -> np.ndarray:
    """The ticks (``2 .. K``) at which the set of links up differs from the tick before."""
    up = folder.mobility["links_up"]
    return np.flatnonzero((up[1:] != up[:-1]).any(axis=1)) + 2


def plot_topology_errors(folder: Folder, stem, formats=DEFAULT_FORMATS, smooth=None) -> list:
    """``stem.png``: the squared position error of fused, local and centralized over time with
    the ticks where the links up changed marked, for a Monte Carlo folder their mean NEES below it
    (with its per-tick band and the expected value), above the number of links up per tick."""
    formats = check_formats(formats)
    _require(folder)
    plt = pyplot()
    w = smooth or max(default_smooth(folder), folder.K // 25)   # one run: 4 % of the ticks
    cols, ylabel = _position_columns(folder)
    t = folder.t
    up = folder.mobility["links_up"]
    changes = change_ticks(folder)
    nees = [e for e in estimate_order(folder.mse) if e in ERROR_ESTIMATES and e in folder.nees]
    if nees:      # a Monte Carlo: the mean NEES against the same changes (issue 34 §7)
        fig, (top, mid, bot) = plt.subplots(3, 1, figsize=(10, 8), sharex=True,
                                            gridspec_kw={"height_ratios": [3, 2, 1]})
    else:
        fig, (top, bot) = plt.subplots(2, 1, figsize=(10, 6), sharex=True,
                                       gridspec_kw={"height_ratios": [3, 1]})
    for k in changes:
        for ax in ((top, mid, bot) if nees else (top, bot)):
            ax.axvline(t[k - 1], color="0.6", lw=0.6, ls=":", zorder=0)
    names = [e for e in estimate_order(folder.mse) if e in ERROR_ESTIMATES]
    with np.errstate(all="ignore"):
        for name in names:
            err = moving_average(folder.mse[name][:, cols].sum(axis=1), w)
            top.plot(t, err, color=color_of(name, names), lw=1.0, label=label_of(name))
    top.set_yscale("log")
    top.set_ylabel(ylabel)
    top.plot([], [], color="0.6", lw=0.6, ls=":", label="the links up change")
    top.legend(fontsize=8, loc="upper right")
    over = f", mean over {folder.n_runs} runs" if folder.kind == "montecarlo" else ""
    top.set_title(plain(f"{folder.scenario}: estimate errors and the links up") +
                  (f" (moving average over {w} ticks{over})" if w > 1 else f" ({over[2:]})" if over else ""),
                  fontsize=10)
    top.grid(alpha=0.3)
    if nees:
        if folder.nees_band is not None:
            mid.axhspan(*folder.nees_band, color="0.5", alpha=0.15, lw=0)
        with np.errstate(all="ignore"):
            for name in nees:
                mid.plot(t, moving_average(folder.nees[name], w), color=color_of(name, names), lw=1.0)
        mid.axhline(folder.nx, color=EXPECTED_COLOUR, lw=1.6, ls=":", zorder=4)
        mid.set_ylabel(f"mean NEES\n(dotted: nx = {folder.nx})")
        mid.grid(alpha=0.3)
    bot.step(t, up.sum(axis=1), where="post", color="C0", lw=1.0)
    bot.set_ylabel("links up")
    bot.set_ylim(0, max(1, up.shape[1]) * 1.05)
    bot.set_xlabel("time [s]")
    bot.grid(alpha=0.3)
    fig.tight_layout()
    return save_figure(fig, stem, formats)

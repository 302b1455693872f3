"""The links of a rate-limited run (docs/traffic.md): queueing delay per link, utilisation and
queue length over time.

One figure, ``links.png``, from the arrays ``dkfsim run`` keeps for the scenario's DKF
(``rated_links``, ``queueing_delay_quantiles``, ``utilisation``, ``queue_length``):

* top: the distribution of the DKF's queueing delay on each link (a box from the 25th to the
  75th percentile, whiskers to the 5th and 95th, a dot at the largest), links in the order of
  their median;
* middle and bottom: utilisation and time-averaged queue length per tick, every link as a thin
  grey line, the three busiest (by mean utilisation) in colour, and the mean over the links.
"""

from __future__ import annotations

import numpy as np

from dkfsim.core.errors import DkfsimError
from dkfsim.core.extras import pyplot
from dkfsim.report.plots.folders import Folder
from dkfsim.report.plots.style import DEFAULT_FORMATS, check_formats, legend_below, plain, save_figure

#: Links drawn in colour over time (the busiest).
HIGHLIGHT = 3


def has_links(folder: Folder) -> bool:
    """True when the folder is a rate-limited run (its run.npz keeps the links' arrays)."""
    return bool(folder.links) and folder.links["rated_links"].shape[0] > 0


def plot_links(folder: Folder, stem, formats=DEFAULT_FORMATS) -> list:
    """``stem.png`` (and the other formats): queueing delay per link, utilisation and queue
    length over time.  Raises DkfsimError for a folder without rate-limited links."""
    formats = check_formats(formats)
    if not has_links(folder):
        raise DkfsimError(f"{folder.path}: not a rate-limited run (no rated_links in run.npz): "
                          "no link figure")
    plt = pyplot()
    links = folder.links
    arcs = [f"{u}→{v}" for u, v in links["rated_links"].tolist()]
    q = links["queueing_delay_quantiles"] * 1e3            # ms
    util, queue = links["utilisation"], links["queue_length"]
    t = folder.t
    fig, (top, mid, bot) = plt.subplots(3, 1, figsize=(11, 10), gridspec_kw={"height_ratios": [3, 2, 2]})
    # -- the delay distribution per link
    have = [e for e in range(len(arcs)) if np.isfinite(q[e]).all()]
    order = sorted(have, key=lambda e: (q[e, 50], q[e, 95]))
    stats = [{"med": q[e, 50], "q1": q[e, 25], "q3": q[e, 75], "whislo": q[e, 5], "whishi": q[e, 95],
              "fliers": [q[e, 100]], "label": arcs[e]} for e in order]
    if stats:
        top.bxp(stats, showfliers=True, flierprops={"marker": ".", "markersize": 4})
        top.tick_params(axis="x", labelrotation=90, labelsize=7)
    top.set_ylabel("queueing delay [ms]")
    top.set_title(plain(f"{folder.scenario}: the DKF's queueing delay per link") +
                  " (box: 25–75 %, whiskers: 5–95 %, dot: largest)", fontsize=10)
    top.grid(alpha=0.3, axis="y")
    # -- over time
    busiest = list(np.argsort(-util.mean(axis=0), kind="stable")[:HIGHLIGHT])
    for ax, data, label in ((mid, util, "utilisation"), (bot, queue, "packets waiting\n(time average per tick)")):
        for e in range(data.shape[1]):
            if e not in busiest:
                ax.plot(t, data[:, e], color="0.75", lw=0.5)
        for k, e in enumerate(busiest):
            ax.plot(t, data[:, e], color=f"C{k + 1}", lw=1.0, label=f"link {arcs[e]}")
        ax.plot(t, data.mean(axis=1), color="k", lw=1.5, label="mean over the links")
        ax.plot([], [], color="0.75", lw=0.5, label="every other link")
        ax.set_ylabel(label)
        ax.set_title(f"{label.splitlines()[0]} per tick, every rate-limited link (background included)",
                     fontsize=9)
        ax.grid(alpha=0.3)
    mid.set_ylim(0, 1.05)
    bot.set_xlabel("time [s]")
    legend_below(fig, [bot], ncol=5)
    return save_figure(fig, stem, formats)

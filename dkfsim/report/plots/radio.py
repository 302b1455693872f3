"""A run on a spatial radio (``medium.radio``, docs/radio.md): packet delivery against distance and
the channel busy ratio over time.

One figure, ``radio.png``, from what ``dkfsim run`` keeps for the scenario's DKF (its copy of the
channel, background included):

* top: the packet delivery ratio (PDR) of every (frame, receiver) pair per distance bin
  (summary.json ``packets.channel.pdr_by_distance``), with the number of pairs behind each bin on
  a second axis and, stacked, the share of each cause of a loss;
* bottom: each vehicle's channel busy ratio (CBR) per tick (run.npz ``cbr``) as thin grey lines,
  their mean in black.
"""

from __future__ import annotations

import numpy as np

from dkfsim.config.results import RADIO_CAUSES
from dkfsim.core.errors import DkfsimError
from dkfsim.core.extras import pyplot
from dkfsim.report.plots.folders import Folder
from dkfsim.report.plots.style import DEFAULT_FORMATS, check_formats, legend_below, plain, save_figure

#: Each cause's colour.
COLOURS = {"sensing": "#bdbdbd", "half_duplex": "#c7e9c0", "receiver_busy": "#fdae6b", "propagation": "#9ecae1",
           "reservation_collision": "#a63603", "collision": "#e6550d"}
#: The causes of a lost pair, in the order drawn (:data:`~dkfsim.config.results.RADIO_CAUSES`), with their colours.
CAUSES = tuple((cause, COLOURS[cause]) for cause in RADIO_CAUSES)


def has_radio(folder: Folder) -> bool:
    """True when the folder is a run on a spatial radio."""
    return bool(folder.radio)


def plot_radio(folder: Folder, stem, formats=DEFAULT_FORMATS) -> list:
    """``stem.png`` (and the other formats): PDR against distance, CBR over time.  Raises
    DkfsimError for a folder that is not a radio run."""
    formats = check_formats(formats)
    if not has_radio(folder):
        raise DkfsimError(f"{folder.path}: not a run on a spatial radio (no cbr in run.npz, no "
                          "pdr_by_distance in summary.json): no radio figure")
    plt = pyplot()
    radio = folder.radio
    fig, (top, bot) = plt.subplots(2, 1, figsize=(11, 8.5))
    block = radio.get("pdr_by_distance")
    if block is not None:
        edges = np.asarray(block["bins_m"], dtype=float)
        mid = (edges[:-1] + edges[1:]) / 2
        frames = np.asarray(block["frames"], dtype=float)
        width = np.diff(edges)
        bottom = np.zeros(len(mid))
        with np.errstate(invalid="ignore", divide="ignore"):
            for cause, colour in CAUSES:
                if block.get(cause) is None:
                    continue
                share = np.where(frames > 0, np.asarray(block[cause], dtype=float) / frames, 0.0)
                top.bar(mid, share, width=width, bottom=1 - bottom - share, color=colour, alpha=0.6,
                        label=f"lost: {cause.replace('_', ' ')}", linewidth=0)
                bottom += share
        pdr = np.array([np.nan if p is None else p for p in block["pdr"]], dtype=float)
        top.plot(mid, pdr, "o-", color="k", ms=3, lw=1.5, label="packet delivery ratio")
        filled = np.flatnonzero(frames > 0)
        top.set_xlim(edges[0], edges[filled[-1] + 1] if len(filled) else edges[-1])
        top.set_ylim(0, 1.02)
        top.set_xlabel("distance between sender and receiver [m]")
        top.set_ylabel("PDR (share of pairs)")
        counts = top.twinx()
        counts.step(mid, frames, where="mid", color="0.4", lw=0.8, ls=":")
        counts.set_ylabel("(frame, receiver) pairs per bin (dotted)", color="0.4")
        top.set_title(plain(f"{folder.scenario}: delivery against distance, every frame on the DKF's copy of "
                            "the channel (background included)"), fontsize=10)
        top.grid(alpha=0.3)
    if "cbr" in radio:
        cbr = np.asarray(radio["cbr"], dtype=float)
        t = folder.t
        for r in range(cbr.shape[1]):
            bot.plot(t, cbr[:, r], color="0.75", lw=0.5)
        bot.plot(t, cbr.mean(axis=1), color="k", lw=1.5, label="mean over the vehicles")
        bot.plot([], [], color="0.75", lw=0.5, label="each vehicle")
        bot.set_ylim(0, 1.02)
        bot.set_xlabel("time [s]")
        bot.set_ylabel("channel busy ratio per tick")
        bot.set_title("CBR: the share of each tick a vehicle senses the channel busy, its own frames included "
                      "(C-V2X: the share of its sub-channels found busy)",
                      fontsize=9)
        bot.grid(alpha=0.3)
    legend_below(fig, [top, bot], ncol=4)
    return save_figure(fig, stem, formats)

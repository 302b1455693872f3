"""Figures from the folders that ``dkfsim run`` and ``dkfsim montecarlo`` write.

``dkfsim plot DIR`` reads either layout and draws

* ``tracking``: truth, the fused estimate, node 0's estimate and the references
  (centralized Kalman filter; the consensus-on-information estimator when it
  ran), one panel per state component -- the paper's Fig. 3;
* ``mse``: mean squared error per tick and component for every estimate in the
  folder, log scale -- the paper's Fig. 4.  A Monte Carlo folder gives the mean
  over runs with its 95 % confidence band; a single run gives the squared error
  of that run, smoothed by a centred moving average (``--smooth``);
* ``nees`` (Monte Carlo folders only): the average NEES per tick with the per-tick 95 %
  chi-square band, the fraction of ticks inside it and the ANEES verdict of each estimate;
* ``paired`` (Monte Carlo folders with a reference estimate): each estimate's MSE relative
  to the reference, paired over the runs (:mod:`.paired`);
* ``links`` (a rate-limited run): the DKF's queueing delay per link, utilisation and queue
  length over time (:mod:`.links`);
* ``network_over_time`` and ``topology_errors`` (a run with ``mobility:``): the vehicles and
  links up at chosen ticks, and the errors beside the changes of the links (:mod:`.mobility`).

``dkfsim plot DIR1 DIR2 ... --compare --labels ...`` overlays the fused MSE of
several folders and the centralized filter of the first -- the paper's Fig. 5
(undirected vs directed graph) and, on folders run with ``d_t = 0..4`` and
``--component position``, its Fig. 6.

Everything here is a function of the files on disk.  Problems a user can cause
(missing folder, a folder of neither layout, folders that cannot be overlaid)
raise :class:`~dkfsim.core.errors.DkfsimError`.  matplotlib is imported lazily with
the Agg backend, so the module imports on a machine without a display or
without matplotlib.

The code, by figure family: :mod:`.folders` (reading either layout), :mod:`.style`
(labels, colours, axes, saving), :mod:`.tracking`, :mod:`.accuracy` (MSE and NEES) and
:mod:`.compare`; :func:`plot_folder` draws every figure one folder supports.
"""

from __future__ import annotations

from pathlib import Path

from dkfsim.core.errors import DkfsimError
from dkfsim.report.plots.accuracy import plot_mse, plot_nees
from dkfsim.report.plots.compare import check_comparable, plot_compare
from dkfsim.report.plots.folders import Folder, component_names, load_folder
from dkfsim.report.plots.links import has_links, plot_links
from dkfsim.report.plots.mobility import has_mobility, plot_network_over_time, plot_topology_errors
from dkfsim.report.plots.paired import paired_reference, plot_paired, relative_to
from dkfsim.report.plots.radio import has_radio, plot_radio
from dkfsim.report.plots.style import (
    DEFAULT_FORMATS,
    ESTIMATES,
    FORMATS,
    check_formats,
    color_of,
    default_smooth,
    label_of,
    moving_average,
    mse_note,
    select_components,
)
from dkfsim.report.plots.tracking import plot_tracking, zoom_window

__all__ = ["DEFAULT_FORMATS", "ESTIMATES", "FORMATS", "Folder", "check_comparable", "color_of",
           "component_names", "default_smooth", "has_links", "has_mobility", "has_radio", "label_of", "load_folder", "moving_average",
           "mse_note", "paired_reference", "plot_compare", "plot_folder", "plot_mse", "plot_nees",
           "plot_links", "plot_radio", "plot_network_over_time", "plot_paired", "plot_topology_errors", "plot_tracking", "relative_to",
           "select_components", "zoom_window", "check_formats"]


def plot_folder(folder: Folder, out_dir, formats=DEFAULT_FORMATS, components=None, smooth=None,
                at=None) -> list[Path]:
    """Every figure a single folder supports, into ``out_dir`` (``at``: the ticks of
    ``network_over_time``, a run with ``mobility:`` only)."""
    if at is not None and not has_mobility(folder):      # before any figure is written
        raise DkfsimError(f"--at: {folder.path} is not a run with mobility: (no positions in run.npz)")
    out = Path(out_dir)
    written = []
    if folder.truth is not None:
        written += plot_tracking(folder, out / "tracking", formats, components)
    written += plot_mse(folder, out / "mse", formats, components, smooth)
    if folder.nees:
        written += plot_nees(folder, out / "nees", formats)
    if paired_reference(folder.stats) is not None:
        written += plot_paired(folder, out / "paired", formats, components)
    if has_links(folder):
        written += plot_links(folder, out / "links", formats)
    if has_radio(folder):
        written += plot_radio(folder, out / "radio", formats)
    if has_mobility(folder):
        written += plot_network_over_time(folder, out / "network_over_time", formats, at)
        written += plot_topology_errors(folder, out / "topology_errors", formats, smooth)
    return written


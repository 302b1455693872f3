"""What a person reads of a sweep: its figures (:mod:`.plot`) and its report page (:mod:`.page`).

Everything that defines, runs, stores, reads and summarizes a sweep is in
:mod:`dkfsim.experiments.sweep`; everything that draws it is here (docs/decisions.md).
"""

from dkfsim.report.sweep.page import sweep_page
from dkfsim.report.sweep.plot import plot_sweep, sweep_curves

__all__ = ["plot_sweep", "sweep_curves", "sweep_page"]

"""``peak_error``: a metric for docs/extending.md -- the worst squared error after the burn-in.

A metric is a function of one estimate of one run (:class:`dkfsim.analysis.metrics.Scored`:
``x``, ``P``, ``truth``, the estimator's ``traffic``, ``burn_in``); registered, it becomes a
column of every tidy row (a run's rows.csv, Monte Carlo's runs.csv, sweeps) and of
``dkfsim list metrics``.
"""

from __future__ import annotations

import numpy as np

from dkfsim.analysis.metrics import Metric, squared_error
from dkfsim.core.registry import METRICS


def peak_error(s) -> np.ndarray:
    """Largest squared error per state component after the burn-in (per node: the mean over nodes)."""
    return squared_error(s.x, s.truth)[s.burn_in:].max(axis=0)


METRICS.add("peak_error", implementation=Metric(peak_error, per_component=True, unit="state unit^2"),
            description="largest squared error after the burn-in, per state component")

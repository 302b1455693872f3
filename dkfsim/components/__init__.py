"""The parameter models of every component family, registered where the schema finds them.

Latency models (with their distributions), link and sensor faults, graph
generators (and the graphs they build), sensor kinds, estimator parameters
and recorded tracks: everything a scenario key can name, validated here,
below the configuration stage that reads them.
"""

from dkfsim.components import estimators, faults, latency, sensors, topology, trajectories, truth  # noqa: F401

"""dkfsim: a discrete-event network simulator for distributed Kalman filtering
with time-varying transmission delays (the anti-delay DKF of Yu, Dai et al.).

Python API (mirrors the CLI; each call runs BLAS on one thread)::

    import dkfsim
    res = dkfsim.run("scenarios/paper_case1.yaml", steps=200)   # a path, a mapping or a Scenario
    res["x_fused"], res.counts, res.metrics(), res.save("out/case1")
    mc = dkfsim.montecarlo("scenarios/paper_case1.yaml", runs=20, jobs=2)
    sc = dkfsim.load_scenario("scenarios/paper_case1.yaml", overrides=["weights=paper"])
    old = dkfsim.load("out/case1")          # a run or Monte Carlo folder, or a sweep database
    old.to_frame()                           # its tidy rows as a pandas DataFrame
    dkfsim.sweep("scenarios/sweep_delay_bound.yaml", jobs=2)
    dkfsim.maxdelay("scenarios/paper_case1.yaml", relative=1.5, steps=300)

The package's folders are its stages, in the order data flows
(docs/architecture.md); importing it registers every built-in component, after
which the first registry read imports the installed entry-point plugins
(docs/extending.md).
"""

from dkfsim import components, estimators, model, protocols  # noqa: F401  (registration)
from dkfsim.config.load import load_scenario
from dkfsim.config.schema import Scenario
from dkfsim.core import registry as _registry
from dkfsim.core.errors import DkfsimError, ScenarioError
from dkfsim.core.version import __version__
from dkfsim.engine.driver import run
from dkfsim.engine.results import RunResult, load_run
from dkfsim.experiments.loading import SweepResult, load
from dkfsim.experiments.maxdelay import maxdelay
from dkfsim.experiments.montecarlo import montecarlo
from dkfsim.experiments.sweep import run_sweep as sweep

__all__ = ["DkfsimError", "RunResult", "Scenario", "ScenarioError", "SweepResult", "load", "load_run",
           "load_scenario", "maxdelay", "montecarlo", "run", "sweep", "__version__"]

_registry.builtins_registered()          # last: plugins may now import a complete dkfsim

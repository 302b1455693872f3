"""dkfsim: a discrete-event network simulator for distributed Kalman filtering
with time-varying transmission delays (the anti-delay DKF of Yu, Dai et al.).

Python API (mirrors the CLI; each call runs BLAS on one thread)::

    import dkfsim
    res = dkfsim.run("scenarios/paper_case1.yaml", steps=200)   # a path, a mapping or a Scenario
    res["x_fused"], res.counts, res.metrics(), res.save("out/case1")
    mc = dkfsim.montecarlo("scenarios/paper_case1.yaml", runs=20, jobs=2)
    sc = dkfsim.load_scenario("scenarios/paper_case1.yaml", overrides=["weights=paper"])
    old = dkfsim.load_run("out/case1")
    dkfsim.sweep("scenarios/sweep_delay_bound.yaml", jobs=2)
    dkfsim.maxdelay("scenarios/paper_case1.yaml", relative=1.5, steps=300)
"""

__version__ = "0.1.0"

from dkfsim.core.errors import DkfsimError, ScenarioError  # noqa: E402
from dkfsim.experiments.maxdelay import maxdelay  # noqa: E402
from dkfsim.experiments.montecarlo import montecarlo  # noqa: E402
from dkfsim.engine.results import RunResult, load_run  # noqa: E402
from dkfsim.config.schema import Scenario, load_scenario  # noqa: E402
from dkfsim.engine.driver import run  # noqa: E402
from dkfsim.experiments.sweep import run_sweep as sweep  # noqa: E402

__all__ = ["DkfsimError", "RunResult", "Scenario", "ScenarioError", "load_run", "load_scenario",
           "maxdelay", "montecarlo", "run", "sweep", "__version__"]

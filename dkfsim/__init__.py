"""dkfsim: a discrete-event network simulator for distributed Kalman filtering
with time-varying transmission delays (the anti-delay DKF of Yu, Dai et al.).

Python API (mirrors the CLI)::

    import dkfsim
    sc = dkfsim.load_scenario("scenarios/paper_case1.yaml", overrides=["steps=200"])
    res = dkfsim.run(sc)
    res["x_fused"], res.counts, res.save("out/")
"""

__version__ = "0.1.0"

from .errors import DkfsimError, ScenarioError  # noqa: E402
from .scenario import Scenario, load_scenario  # noqa: E402
from .simulation import run  # noqa: E402

__all__ = ["DkfsimError", "Scenario", "ScenarioError", "load_scenario", "run", "__version__"]

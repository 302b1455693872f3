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
(docs/architecture.md).  ``import dkfsim`` itself is cheap: each name above is
imported on its first use (PEP 562), and the built-in components register at
the first registry read (a scenario validated, ``dkfsim list``), after which
the installed entry-point plugins are imported (docs/extending.md); a command
pays only for the stages it uses (docs/decisions.md, "Start-up").
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from dkfsim.core.errors import DkfsimError, ScenarioError
from dkfsim.core.version import __version__

if TYPE_CHECKING:                        # what a type checker sees: the names themselves
    from dkfsim.config.load import load_scenario
    from dkfsim.config.schema import Scenario
    from dkfsim.engine.driver import run
    from dkfsim.engine.results import RunResult, load_run
    from dkfsim.experiments.loading import SweepResult, load
    from dkfsim.experiments.maxdelay import maxdelay
    from dkfsim.experiments.montecarlo import montecarlo
    from dkfsim.experiments.sweep import run_sweep as sweep

#: The API's names imported on first use: name -> (module, attribute).
_LAZY = {
    "load_scenario": ("dkfsim.config.load", "load_scenario"),
    "Scenario": ("dkfsim.config.schema", "Scenario"),
    "run": ("dkfsim.engine.driver", "run"),
    "RunResult": ("dkfsim.engine.results", "RunResult"),
    "load_run": ("dkfsim.engine.results", "load_run"),
    "SweepResult": ("dkfsim.experiments.loading", "SweepResult"),
    "load": ("dkfsim.experiments.loading", "load"),
    "maxdelay": ("dkfsim.experiments.maxdelay", "maxdelay"),
    "montecarlo": ("dkfsim.experiments.montecarlo", "montecarlo"),
    "sweep": ("dkfsim.experiments.sweep", "run_sweep"),
}

__all__ = ["DkfsimError", "RunResult", "Scenario", "ScenarioError", "SweepResult", "load", "load_run",
           "load_scenario", "maxdelay", "montecarlo", "run", "sweep", "__version__"]


def __getattr__(name: str) -> Any:
    """``dkfsim.run`` and the other API names, imported on their first use (PEP 562)."""
    if name not in _LAZY:
        raise AttributeError(f"module 'dkfsim' has no attribute {name!r}")
    module, attr = _LAZY[name]
    value = getattr(importlib.import_module(module), attr)
    globals()[name] = value              # (the next use is a plain attribute)
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))

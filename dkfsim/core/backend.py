"""How a run computes, chosen once: the filters' arithmetic and the way the exchange runs.

Two choices make a :class:`Backend`, and nothing else decides them:

* ``kernels``: ``"numba"`` (compiled kernels for the window filter, the contribution fold
  and the cross-covariance recursion) or ``"numpy"`` (the batched-numpy path) -- numba when
  it is installed, unless ``DKFSIM_KERNELS=numpy`` (:func:`dkfsim.core.jit.kernel_path`);
* ``exchange``: ``"compiled"`` (a protocol with a compiled twin runs it, the ``tree``
  protocol's kernels) or ``"python"`` (every protocol runs in Python, per packet) -- compiled
  on the numba path unless ``DKFSIM_EXCHANGE=python``.

:meth:`Backend.from_environment` reads the two variables; the engine builds a run's backend
from it once, narrowed to what the run can use (:func:`dkfsim.engine.driver.run_backend`: the
compiled exchange needs plain links and no crashes), hands it to every estimator in the
:class:`~dkfsim.estimators.base.RunContext` and records it in ``summary.json``
(:meth:`Backend.record`).  Code that computes asks the backend it was given
(:attr:`Backend.compiled`), never the environment.  docs/design.md §4 ("Kernel paths").
"""

from __future__ import annotations

import os
from dataclasses import dataclass, replace
from typing import Literal

from dkfsim.core.errors import DkfsimError
from dkfsim.core.files import clip
from dkfsim.core.jit import kernel_path

#: Environment variable: ``python`` runs the Python protocol where a compiled one would run.
EXCHANGE_ENV = "DKFSIM_EXCHANGE"

Kernels = Literal["numba", "numpy"]
ExchangeKind = Literal["compiled", "python"]


@dataclass(frozen=True)
class Backend:
    """The filters' arithmetic (``kernels``) and how the exchange runs (``exchange``)."""

    kernels: Kernels = "numpy"
    exchange: ExchangeKind = "python"

    @classmethod
    def from_environment(cls) -> Backend:
        """What the environment asks for: numba unless it is missing or ``DKFSIM_KERNELS=numpy``;
        the compiled exchange on the numba path unless ``DKFSIM_EXCHANGE=python``."""
        kernels: Kernels = "numba" if kernel_path() == "numba" else "numpy"
        raw = os.environ.get(EXCHANGE_ENV, "")
        want = raw.strip().lower()
        if want not in ("", "compiled", "python"):
            raise DkfsimError(f"{EXCHANGE_ENV}={clip(raw)}: not a known value; use compiled (the default "
                              "on the numba path) or python (every protocol in Python)")
        exchange: ExchangeKind = "compiled" if kernels == "numba" and want != "python" else "python"
        return cls(kernels, exchange)

    @property
    def compiled(self) -> bool:
        """True on the numba path: the filters run compiled kernels."""
        return self.kernels == "numba"

    @property
    def compiled_exchange(self) -> bool:
        """True when a protocol with a compiled twin runs it (the ``tree`` protocol's kernels)."""
        return self.exchange == "compiled"

    def python_exchange(self) -> Backend:
        """This backend with every protocol in Python (a run the compiled exchange cannot run)."""
        return replace(self, exchange="python")

    def record(self) -> dict[str, str]:
        """What ``summary.json`` keeps of it (its ``backend`` key)."""
        return {"kernels": self.kernels, "exchange": self.exchange}

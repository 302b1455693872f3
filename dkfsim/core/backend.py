"""How a run computes, chosen once: the filters' arithmetic.

``kernels``: ``"numba"`` (compiled kernels for the window filter, the contribution fold,
the cross-covariance recursion and the exchange protocols' bookkeeping) or ``"numpy"``
(the same steps without numba) -- numba when it is installed, unless
``DKFSIM_KERNELS=numpy`` (:func:`dkfsim.core.jit.kernel_path`).

:meth:`Backend.from_environment` reads it; the engine builds a run's backend once, hands it to
every estimator in the :class:`~dkfsim.estimators.base.RunContext` and records it in
``summary.json`` (:meth:`Backend.record`).  Code that computes asks the backend it was given
(:attr:`Backend.compiled`), never the environment.  How packets travel is not a backend
choice: every protocol runs the same code on every medium (docs/design.md §4, "Kernel paths").
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from dkfsim.core.jit import kernel_path

Kernels = Literal["numba", "numpy"]


@dataclass(frozen=True)
class Backend:
    """The filters' arithmetic (``kernels``)."""

    kernels: Kernels = "numpy"

    @classmethod
    def from_environment(cls) -> Backend:
        """What the environment asks for: numba unless it is missing or ``DKFSIM_KERNELS=numpy``."""
        return cls("numba" if kernel_path() == "numba" else "numpy")

    @property
    def compiled(self) -> bool:
        """True on the numba path: the filters run compiled kernels."""
        return self.kernels == "numba"

    def record(self) -> dict[str, str]:
        """What ``summary.json`` keeps of it (its ``backend`` key)."""
        return {"kernels": self.kernels}

"""The Estimator interface: one small class per algorithm, all run on the same draws.

A run (:mod:`dkfsim.engine`) simulates one truth, one set of measurements and
one network, and hands every estimator the same :class:`RunContext`.  An
estimator is configured by its parameter model (a pydantic class whose
fields are the keys of its ``estimators:`` entry), reacts to the run's clock
(:meth:`Estimator.on_measure` at every tick ``t_k`` before the deliveries of
that instant, :meth:`Estimator.on_update` after them) and to the packets of
its own :class:`~dkfsim.network.links.Port`, may schedule events of its own
on ``ctx.env`` (consensus rounds), and returns an :class:`EstimatorResult`:
named estimates (``x`` of shape ``(K, nx)``, or ``(K, n, nx)`` per node,
with covariances when it has them), extra arrays for ``run.npz`` and its
traffic.  Before a run, :meth:`Estimator.cost` says what it needs, so a
command can refuse work that cannot fit (:mod:`dkfsim.core.resources`).

Adding an algorithm is one file: a parameter model, an :class:`Estimator`
subclass, and ``ESTIMATORS.add(kind, params=..., implementation=...)``;
docs/extending.md walks through an example the tests run.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from dkfsim.components.estimators import EstimatorParams
from dkfsim.core.resources import Cost


@dataclass
class Estimate:
    """One named estimate of a run: ``x`` (K, nx) or per node (K, n, nx); ``P`` alike or None."""

    x: np.ndarray
    P: np.ndarray | None = None

    @property
    def per_node(self) -> bool:
        return self.x.ndim == 3


@dataclass
class EstimatorResult:
    """What an estimator returns (see the module docstring)."""

    estimates: dict[str, Estimate]
    arrays: dict[str, np.ndarray] = field(default_factory=dict)
    #: Port counts (``sent``, ``delivered``, ``lost``, ``bytes``, ... and ``late``); None when
    #: the algorithm has no network model (the idealised centralized filter).
    traffic: dict | None = None
    #: Side facts for summary.json (protocol counters, rounds, ...).
    facts: dict = field(default_factory=dict)


@dataclass
class RunContext:
    """What a run offers every estimator: the model, the draws, the network and the clock."""

    scenario: Any                 # dkfsim.config.schema.Scenario
    system: Any                   # dkfsim.model.system.LinearGaussianSystem
    truth: np.ndarray             # (K, nx)
    ys: list                      # y_i, (K, m_i) each
    info: Any                     # dkfsim.model.system.Information: every contribution
    crashes: Any                  # dkfsim.components.faults.CrashSchedule or None
    env: Any                      # simpy.Environment
    network: Any                  # dkfsim.network.links.Network
    save: str                     # "full" | "estimates" | "summary"

    @property
    def K(self) -> int:
        return self.truth.shape[0]

    @property
    def n(self) -> int:
        return self.system.n

    @property
    def nx(self) -> int:
        return self.system.nx

    @property
    def T_ns(self) -> int:
        return self.system.T_ns

    @property
    def seed(self) -> int:
        return int(self.scenario.seed)

    def measured(self) -> np.ndarray | None:
        """(K, n) bool: sensor i measured row r (False inside a crash window); None if no crashes."""
        if not self.crashes:
            return None
        return ~self.crashes.mask(self.K, self.T_ns).T

    def existing_information(self) -> tuple[np.ndarray, np.ndarray]:
        """``omega`` and ``theta`` of the measurements that exist (a crashed sensor measures
        nothing): ``omega`` (n, nx, nx) or per row (K, n, nx, nx), ``theta`` (K, n, nx)."""
        m = self.measured()
        if m is None:
            return self.info.omega, self.info.theta
        return self.info.omega_per_row() * m[:, :, None, None], self.info.theta * m[:, :, None]


class Estimator:
    """Base class of every algorithm (see the module docstring).

    Subclasses set :attr:`Params`, implement :meth:`finish`, and hook into the
    clock or the network as they need.  Constructors store; :meth:`start` is
    where an estimator opens its port and schedules its own events.
    """

    #: The parameter model of its ``estimators:`` entry.
    Params: ClassVar[type[EstimatorParams]] = EstimatorParams

    def __init__(self, params: EstimatorParams, ctx: RunContext):
        self.params = params
        self.ctx = ctx
        self.name = params.label

    @classmethod
    def cost(cls, params: EstimatorParams, scenario, *, L: int, arcs: int, save: str = "estimates") -> Cost:
        """Memory and CPU time of one run (default: next to nothing).  ``L`` and ``arcs``
        are the scenario's buffer length and exchange links, ``save`` the save mode."""
        return Cost(params.label)

    def start(self) -> None:
        """Called once before the first tick."""

    def on_measure(self, row: int) -> None:
        """Tick ``row + 1``: every sensor has just measured row ``row`` (before the deliveries
        of this instant)."""

    def on_update(self, k: int) -> None:
        """Tick ``k``: every packet due by ``t_k`` has been delivered."""

    def finish(self) -> EstimatorResult:
        """The estimates, once the run is over."""
        raise NotImplementedError

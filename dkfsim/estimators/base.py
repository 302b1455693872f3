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
with covariances when it has them), extra arrays for ``run.npz``, its
traffic and side facts.  Before a run, :meth:`Estimator.cost` says what it
needs, from the run's :class:`~dkfsim.config.plan.RunPlan` (buffer length, links,
save mode: what the run itself will follow), so a command can refuse work that cannot
fit (:mod:`dkfsim.core.resources`).

Adding an algorithm is one file: a parameter model that declares the kind
(``class MyParams(EstimatorParams, kind="my_kind")``) and an :class:`Estimator`
subclass that names it (``class Mine(Estimator, params=MyParams)``); both
register themselves.  docs/extending.md walks through an example the tests
run, and :func:`dkfsim.testing.check_estimator` checks one.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Callable, ClassVar

import numpy as np
import simpy

from dkfsim.components.estimators import EstimatorParams
from dkfsim.components.faults import CrashSchedule
from dkfsim.core.backend import Backend
from dkfsim.core.registry import ESTIMATORS
from dkfsim.core.resources import B_FLOAT, Cost, SaveMode
from dkfsim.model.system import Information, LinearGaussianSystem
from dkfsim.network.links import Link
from dkfsim.network.network import Network
from dkfsim.network.port import Port

if TYPE_CHECKING:                     # (annotations only: ``dkfsim list`` imports this module)
    from dkfsim.config.plan import RunPlan
    from dkfsim.config.schema import Scenario

__all__ = ["DKFView", "Estimate", "Estimator", "EstimatorResult", "RunContext", "SaveMode",
           "existing_information_bytes"]


@dataclass
class Estimate:
    """One named estimate of a run: ``x`` (K, nx) or per node (K, n, nx); ``P`` alike or None."""

    x: np.ndarray
    P: np.ndarray | None = None


@dataclass
class EstimatorResult:
    """What an estimator returns (see the module docstring)."""

    estimates: dict[str, Estimate]
    arrays: dict[str, np.ndarray] = field(default_factory=dict)
    #: Port counts (``sent``, ``delivered``, ``lost``, ``bytes``, ... and ``late``); None when
    #: the algorithm has no network model (the idealised centralized filter).
    traffic: dict[str, Any] | None = None
    #: Side facts for summary.json (protocol counters, rounds, ...).
    facts: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class DKFView:
    """What the run's own anti-delay DKF offers the estimators that build on it (the fusion
    centre): set by the DKF when it starts, before any listed estimator does.  The arrays are
    the DKF's own, written as the run goes: read them, never change them."""

    #: Its buffer length ``L`` and fusion (``matrix``, ``diagonal``, ``none``).
    L: int
    fusion: str
    #: ``(n, n)`` the origin weights ``a_io`` of its information sums.
    weights: np.ndarray
    #: ``(S, n, n)`` bool: the origins each node holds of the row in window slot ``row % S``.
    held: np.ndarray
    #: ``(K, n, nx)``: each node's real-time estimate of each row, once its tick's update ran.
    x_local: np.ndarray
    #: The DKF's port: open yours ``share_with`` it to send through its media.
    port: Port


@dataclass
class RunContext:
    """What a run offers every estimator: the model, the draws, the network and the clock.

    Read ``system`` (and its sensors), ``truth``, ``ys`` and ``info``; never change them:
    every estimator of the run, and the runs of a Monte Carlo, share them.
    """

    #: The validated scenario.
    scenario: Scenario
    #: What the scenario implies for this run, worked out once: the graphs, the buffer length of
    #: each anti-delay DKF, the save mode (:class:`~dkfsim.config.plan.RunPlan`).
    plan: RunPlan
    #: How the run computes, chosen once by the engine: numba or numpy, compiled or Python
    #: exchange (:class:`~dkfsim.core.backend.Backend`; pass it to the filters you call).
    backend: Backend
    #: The model as simulated: ``Phi``, ``Q``, ``x0_mean``, ``P0``, the sensors (``H``, ``R``).
    system: LinearGaussianSystem
    #: The true state, ``(K, nx)``.
    truth: np.ndarray
    #: Sensor ``i``'s measurements ``ys[i]``, ``(K, m_i)``.
    ys: list[np.ndarray]
    #: Every sensor's information contribution per row: ``theta`` (K, n, nx), ``omega``.
    info: Information
    #: The sensors' crash windows, or None when no sensor crashes.
    crashes: CrashSchedule | None
    #: The run's SimPy clock (integer nanoseconds).
    env: simpy.Environment
    #: The links of the run, shared by every estimator (open a port with ``network.port``).
    network: Network
    #: The scenario's own anti-delay DKF as the estimators that build on it see it (set when it
    #: starts, before any listed estimator does): what a fusion centre fuses.  None before.
    dkf: DKFView | None = None

    @property
    def save(self) -> SaveMode:
        """What the run keeps: ``"full"``, ``"estimates"`` or ``"summary"``."""
        return self.plan.save

    @property
    def K(self) -> int:
        return int(self.truth.shape[0])

    @property
    def n(self) -> int:
        return self.system.n

    @property
    def nx(self) -> int:
        return self.system.nx

    @property
    def T_ns(self) -> int:
        return int(self.system.T_ns)

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
        m = np.ascontiguousarray(m)         # (a transposed mask would make the products non-contiguous)
        return self.info.omega_per_row() * m[:, :, None, None], self.info.theta * m[:, :, None]

    def topology_links(self) -> list[Link]:
        """Every directed link of the scenario's topology, the full graph (an undirected edge
        both ways), in the network's order: what the consensus filters talk over."""
        return [self.network.link(u, v) for u, v in self.plan.arcs]

    def exchange_links(self) -> list[Link]:
        """The links of the graph the scenario's ``protocol`` runs on (``plan.exchange``: the
        tree, or a spanning tree of the topology, for ``tree``; every arc for ``flood``; every
        arc for a ``tree`` rebuilt on a graph that changes): what the anti-delay DKF and
        ``ci_consensus`` talk over."""
        return [self.network.link(u, v) for u, v in self.plan.exchange_arcs]


def existing_information_bytes(scenario: Scenario) -> int:
    """Memory :meth:`RunContext.existing_information` allocates, for an estimator's :meth:`~Estimator.cost`:
    with crash windows the masked copies, ``omega`` per row and ``theta`` (``K n nx (nx + 1)``
    floats); without, nothing (it returns the run's own arrays)."""
    if scenario.faults is None or not scenario.faults.crashes:
        return 0
    K, n, nx = int(scenario.steps), scenario.n, scenario.nx
    return K * n * nx * (nx + 1) * B_FLOAT


class Estimator:
    """Base class of every algorithm (see the module docstring).

    A subclass names its parameter model as a class keyword, ``class Mine(Estimator,
    params=MyParams)``, which registers it in :data:`~dkfsim.core.registry.ESTIMATORS`
    under the model's kind (and sets :attr:`Params`).  It hooks into the clock or the
    network as it needs and returns its estimate from :meth:`estimate` (or overrides
    :meth:`finish` when it returns more).  Constructors store; :meth:`start` is where an
    estimator opens its port and schedules its own events.
    """

    #: The parameter model of its ``estimators:`` entry (set by the ``params=`` class keyword).
    Params: ClassVar[type[EstimatorParams]] = EstimatorParams
    #: False for an idealised estimator with no network model (the centralized filter): its
    #: traffic is "not applicable" (None, ``null`` in summary.json), not zero.
    network_model: ClassVar[bool] = True
    #: False for one whose port is opened ``share_with`` the DKF's (its packets in the DKF's queues
    #: and channel): it adds no copy of the media, which resource estimates count.
    own_media: ClassVar[bool] = True
    #: What it sends and the nominal size of each packet kind (``dkfsim list estimators``,
    #: docs/estimators.md "Packet sizes"); a link's ``rate`` transmits these bytes.
    packets: ClassVar[str] = ""
    #: The estimator's port, when :meth:`start` opened one (:meth:`open_port`): the default
    #: :meth:`finish` reports its counts.
    port: Port | None = None

    def __init_subclass__(cls, params: type[EstimatorParams] | None = None, **kwargs: Any):
        super().__init_subclass__(**kwargs)
        if params is None:
            return
        kind = params.model_fields["kind"].default
        if not isinstance(kind, str) or not kind:
            raise TypeError(f"{cls.__name__}: params={params.__name__} declares no kind; declare it with "
                            f"class {params.__name__}(EstimatorParams, kind='...')")
        cls.Params = params
        ESTIMATORS.add(kind, implementation=cls)

    def __init__(self, params: EstimatorParams, ctx: RunContext):
        self.params = params
        self.ctx = ctx
        self.name = params.label

    @classmethod
    def cost(cls, params: EstimatorParams, plan: RunPlan) -> Cost:
        """Memory and CPU time of one run (default: next to nothing), from the run's ``plan``:
        ``plan.scenario``, the buffer length ``plan.L_estimate`` (exact, or a cheap bound on a
        large graph), the exchange links ``plan.n_exchange_links``, the save mode ``plan.save``."""
        return Cost(params.label)

    def start(self) -> None:
        """Called once before the first tick."""

    def on_measure(self, row: int) -> None:
        """Tick ``row + 1``: every sensor has just measured row ``row`` (before the deliveries
        of this instant)."""

    def on_update(self, k: int) -> None:
        """Tick ``k``: every packet due by ``t_k`` has been delivered."""

    # -- helpers ---------------------------------------------------------------------
    def open_port(self, receive: Callable[[Link, Any], None], links: list[Link],
                  until: int | None = None) -> Port:
        """Open this estimator's port (named after it) on ``links``: ``receive(link, payload)``
        gets its deliveries; deliveries after ``until`` ns (default: the run's last tick) stay
        in flight.  Sets :attr:`port`, whose counts the default :meth:`finish` reports."""
        self.port = self.ctx.network.port(self.name, receive, links, until=until)
        return self.port

    # -- the result --------------------------------------------------------------------
    def estimate(self) -> Estimate:
        """The run's estimate, named :attr:`name`, once the run is over (what the default
        :meth:`finish` reports)."""
        raise NotImplementedError(f"{type(self).__name__} implements neither estimate() nor finish()")

    def traffic(self) -> dict[str, Any] | None:
        """The port's counts (``late`` included: :meth:`~dkfsim.network.links.Port.count_late`);
        zero counts without a port; None without a network model (:attr:`network_model`)."""
        if not self.network_model:
            return None
        if self.port is None:
            return {"sent": 0, "delivered": 0, "lost": 0, "bytes": 0, "in_flight": 0, "late": 0}
        return self.port.counts()

    def facts(self) -> dict[str, Any]:
        """Side facts for summary.json (default: none)."""
        return {}

    def finish(self) -> EstimatorResult:
        """The result, once the run is over: :meth:`estimate` under :attr:`name`, :meth:`traffic`
        and :meth:`facts`.  Override it to return several estimates or extra arrays."""
        return EstimatorResult({self.name: self.estimate()}, traffic=self.traffic(), facts=self.facts())

"""The parameters of every built-in estimator (the keys of an ``estimators:`` entry).

An estimator's kind is declared once, by its parameter model:
``class KCFParams(EstimatorParams, kind="kcf")`` makes ``kind`` the literal
``"kcf"`` and registers the model in :data:`~dkfsim.core.registry.ESTIMATORS`
under it; the algorithm (:mod:`dkfsim.estimators`) names its model,
``class KCF(RoundBased, params=KCFParams)``, which registers it as the
implementation.  An estimator written as a plugin does both in its own file
(docs/extending.md).
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import BeforeValidator, Field

from dkfsim.components.topology import protocol_graph
from dkfsim.core.files import clip
from dkfsim.core.params import NAME_LIMIT, NonNegReal, StrictBool, StrictModel, custom_error, fix_kind, suggest
from dkfsim.core.registry import ESTIMATORS


class EstimatorParams(StrictModel):
    """The keys every ``estimators:`` entry has: ``kind`` (which algorithm) and ``name``
    (how its estimates are called in every output; default: the kind).

    A subclass declares its kind as a class keyword, ``class MyParams(EstimatorParams,
    kind="my_kind", aliases=("old_name",))``: the ``kind`` field becomes that literal (its
    default) and the model is registered under it, with the first line of its docstring
    as the description ``dkfsim list estimators`` prints.  A subclass without ``kind=``
    keeps its parent's kind and registers nothing.
    """

    kind: str = ""                       # (each subclass: its literal kind)
    name: Annotated[str, Field(strict=True, min_length=1, max_length=NAME_LIMIT,
                               pattern=r"^[A-Za-z][A-Za-z0-9_]*$")] | None = None

    def __init_subclass__(cls, kind: str | None = None, aliases: tuple[str, ...] = (), **kwargs: Any):
        if kind is not None:
            fix_kind(cls, kind)
        super().__init_subclass__(**kwargs)

    @classmethod
    def __pydantic_init_subclass__(cls, kind: str | None = None, aliases: tuple[str, ...] = (),
                                   **kwargs: Any) -> None:
        super().__pydantic_init_subclass__(**kwargs)
        if kind is not None:           # the model is complete: register it
            ESTIMATORS.add(kind, params=cls, aliases=aliases)

    @property
    def label(self) -> str:
        """The estimator's name: ``name`` if given, else ``kind``."""
        return self.name or self.kind

    def check(self, scenario) -> None:
        """Cross-checks against the whole scenario (raise ``custom_error``); none by default."""


class CentralizedParams(EstimatorParams, kind="centralized"):
    """Every measurement on time: the centralized Kalman filter (the lower bound)."""



class CentralizedDelayedParams(EstimatorParams, kind="centralized_delayed"):
    """A fusion centre fed over direct links with the default link settings, same buffer."""



class LocalOnlyParams(EstimatorParams, kind="local_only", aliases=("local",)):
    """Each node alone: a Kalman filter of its own measurements (no communication)."""



class NoBufferParams(EstimatorParams, kind="no_buffer"):
    """The anti-delay exchange with no buffer (L = 1): information for a past tick is dropped."""



class FusionCentreParams(EstimatorParams, kind="fusion_centre"):
    """The DKF's fusion at one node: every node's estimate reaches it hop by hop over the network."""

    #: The node (index, 0-based) where the centre runs; the nodes' packets are relayed to it
    #: over the scenario's DKF exchange graph, through the DKF's own queues.
    at: Annotated[int, Field(strict=True, ge=0)]
    #: ``M``: the final rows a node's packet repeats beyond its window, i.e. how many ticks in a
    #: row a node may go unheard before it leaves the fusion (default: the DKF's ``L``).
    margin: Annotated[int, Field(strict=True, ge=0, le=100_000)] | None = None

    def check(self, scenario) -> None:
        if self.at >= scenario.n:
            raise custom_error(f"node {self.at} does not exist: the scenario has {scenario.n} nodes "
                               f"(0 .. {scenario.n - 1})", "at")
        if scenario.fusion == "none":
            raise custom_error("a fusion centre fuses the scenario's DKF, which runs with 'fusion: none' "
                               "(set fusion: matrix or diagonal)", "kind")

    def check_plan(self, plan) -> None:
        """Cross-checks against what the scenario implies (the run's plan)."""
        if plan.graph_changes:
            raise custom_error("a fusion centre needs a graph that does not change (here mobility: takes "
                               "links down): its packets are routed over the exchange graph once "
                               "(docs/decisions.md #219)", "kind")


def buffer_length_value(value: Any) -> Any:
    """A ``buffer_length`` (the scenario's, or an anti-delay DKF instance's; None: unset):
    ``'auto'``, ``'paper'`` or an integer >= 1 (a ``BeforeValidator``)."""
    if value is None or (isinstance(value, str) and value in ("auto", "paper")):
        return value
    if isinstance(value, int) and not isinstance(value, bool) and value >= 1:
        return value
    hint = suggest(value, ("auto", "paper")) if isinstance(value, str) else ""
    raise custom_error(f"must be 'auto', 'paper' or an integer >= 1, got {clip(value)}{hint}")


#: A ``buffer_length`` key (docs/design.md §4, "Choosing L").
BufferLength = Annotated[Literal["auto", "paper"] | int, BeforeValidator(buffer_length_value)]


class AntiDelayParams(EstimatorParams, kind="anti_delay_dkf"):
    """Another instance of the anti-delay DKF; unset keys take the scenario's values."""

    buffer_length: BufferLength | None = None
    fusion: Literal["matrix", "diagonal", "none"] | None = None
    weights: Literal["unit", "paper"] | None = None

    def check(self, scenario) -> None:
        if self.weights == "paper" and protocol_graph(scenario.protocol) != "tree":
            raise custom_error("'paper' weights need protocol: tree", "weights")


def check_rounds(kind: str, rounds: int, scenario, key: str = "rounds", note: str = "") -> None:
    """``rounds`` sub-slots must divide ``T`` into whole nanoseconds (docs/consensus.md)."""
    if rounds > 0 and scenario.T_ns % rounds:
        raise custom_error(f"{rounds} rounds per tick{note} do not divide T = {scenario.model.T} s "
                           f"({scenario.T_ns} ns) into whole nanoseconds ({kind} runs a round every "
                           "T/rounds); choose a divisor of T in ns", key)


Rounds = Annotated[int, Field(strict=True, ge=1)]


class CIParams(EstimatorParams, kind="ci_consensus"):
    """Consensus on information (Battistelli & Chisci 2014) with Metropolis weights."""

    #: Consensus rounds per tick (0 = each node's local filter); T / rounds must be whole ns.
    rounds: Annotated[int, Field(strict=True, ge=0)] = 1

    def check(self, scenario) -> None:
        check_rounds(self.kind, self.rounds, scenario, note=" (consensus_rounds in older files)")


class KCFParams(EstimatorParams, kind="kcf"):
    """Kalman-consensus filter (Olfati-Saber, CDC 2009): one exchange per tick."""

    #: Consensus gain scale: gamma_i = eps / (1 + ||M_i||_F).  0 = neighbourhood filters only.
    #: Default 0.1: the paper leaves eps free; 0.1 keeps gamma_i ||M_i|| < 0.1, so the consensus
    #: term stays a contraction for up to 10 neighbours (docs/consensus.md).
    eps: NonNegReal = 0.1


class ICFParams(EstimatorParams, kind="icf"):
    """Information-weighted consensus filter (Kamal, Farrell, Roy-Chowdhury, TAC 2013)."""

    #: Consensus iterations per tick (>= 1); T / rounds must be whole ns.  Default 1: one
    #: message per link per tick, the budget of kcf and ci_consensus's default.
    rounds: Rounds = 1

    def check(self, scenario) -> None:
        check_rounds(self.kind, self.rounds, scenario)


class DiffusionParams(EstimatorParams, kind="diffusion_kf"):
    """Diffusion Kalman filter (Cattivelli & Sayed, TAC 2010): incremental update, then diffusion."""

    #: Diffusion (combination) weights c_ij: ``metropolis`` (doubly stochastic on an undirected
    #: graph) or ``uniform`` (1 / (|N_i| + 1) over the closed neighbourhood, as the paper's example).
    weights: Literal["metropolis", "uniform"] = "metropolis"
    #: False: the incremental (measurement) step only, C = I.
    diffusion: StrictBool = True

    def check(self, scenario) -> None:
        check_rounds(self.kind, 2, scenario, key="kind", note=" (its two exchanges)")


def _omega(value: Any) -> Any:
    if isinstance(value, str) and value == "n":
        return value
    if isinstance(value, (int, float)) and not isinstance(value, bool) and 1.0 <= float(value) < float("inf"):
        return float(value)
    raise custom_error(f"must be a number >= 1 or 'n' (the number of nodes), got {value!r}")


class HCMCIParams(EstimatorParams, kind="hcmci"):
    """Hybrid consensus on measurements and information (Battistelli et al., TAC 2015)."""

    #: Consensus rounds per tick (>= 1); T / rounds must be whole ns.
    rounds: Rounds = 1
    #: Scale of the averaged novel information: 1 (default; consistent whatever arrived) or up
    #: to ``n`` (``'n'``: the centralized filter at full consensus, overconfident before it).
    omega: Annotated[float | Literal["n"], BeforeValidator(_omega)] = 1.0

    def check(self, scenario) -> None:
        check_rounds(self.kind, self.rounds, scenario)
        if self.omega != "n" and self.omega > scenario.n:
            raise custom_error(f"omega = {self.omega} exceeds the number of nodes n = {scenario.n} "
                               "(the stability range of Battistelli et al. is 1 <= omega <= n)", "omega")


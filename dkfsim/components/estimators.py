"""The parameters of every built-in estimator (the keys of an ``estimators:`` entry).

Each model is registered in :data:`~dkfsim.core.registry.ESTIMATORS` under
its ``kind``; the algorithm itself (:mod:`dkfsim.estimators`) registers its
implementation under the same name.  An estimator written as a plugin
declares both in its own file (docs/extending.md).
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import BeforeValidator, Field

from dkfsim.core.params import NonNegReal, StrictBool, StrictModel, custom_error
from dkfsim.core.registry import ESTIMATORS


class EstimatorParams(StrictModel):
    """The keys every ``estimators:`` entry has: ``kind`` (which algorithm) and ``name``
    (how its estimates are called in every output; default: the kind)."""

    kind: str
    name: Annotated[str, Field(strict=True, min_length=1, pattern=r"^[A-Za-z][A-Za-z0-9_]*$")] | None = None

    @property
    def label(self) -> str:
        """The estimator's name: ``name`` if given, else ``kind``."""
        return self.name or self.kind

    def check(self, scenario) -> None:
        """Cross-checks against the whole scenario (raise ``custom_error``); none by default."""


class CentralizedParams(EstimatorParams):
    """Every measurement on time: the centralized Kalman filter (the lower bound)."""

    kind: Literal["centralized"] = "centralized"


class CentralizedDelayedParams(EstimatorParams):
    """A fusion centre fed over direct links with the default link settings, same buffer."""

    kind: Literal["centralized_delayed"] = "centralized_delayed"


class LocalOnlyParams(EstimatorParams):
    """Each node alone: a Kalman filter of its own measurements (no communication)."""

    kind: Literal["local_only"] = "local_only"


class NoBufferParams(EstimatorParams):
    """The anti-delay exchange with no buffer (L = 1): information for a past tick is dropped."""

    kind: Literal["no_buffer"] = "no_buffer"


def _buffer_length(value: Any) -> Any:
    if value is None or (isinstance(value, str) and value in ("auto", "paper")):
        return value
    if isinstance(value, int) and not isinstance(value, bool) and value >= 1:
        return value
    raise custom_error(f"must be 'auto', 'paper' or an integer >= 1, got {value!r}")


class AntiDelayParams(EstimatorParams):
    """Another instance of the anti-delay DKF; unset keys take the scenario's values."""

    kind: Literal["anti_delay_dkf"] = "anti_delay_dkf"
    buffer_length: Annotated[Literal["auto", "paper"] | int | None, BeforeValidator(_buffer_length)] = None
    fusion: Literal["matrix", "diagonal", "none"] | None = None
    weights: Literal["unit", "paper"] | None = None

    def check(self, scenario) -> None:
        if self.weights == "paper" and scenario.protocol_graph != "tree":
            raise custom_error("'paper' weights need protocol: tree", "weights")


def check_rounds(kind: str, rounds: int, scenario, key: str = "rounds", note: str = "") -> None:
    """``rounds`` sub-slots must divide ``T`` into whole nanoseconds (docs/consensus.md)."""
    if rounds > 0 and scenario.T_ns % rounds:
        raise custom_error(f"{rounds} rounds per tick{note} do not divide T = {scenario.model.T} s "
                           f"({scenario.T_ns} ns) into whole nanoseconds ({kind} runs a round every "
                           "T/rounds); choose a divisor of T in ns", key)


Rounds = Annotated[int, Field(strict=True, ge=1)]


class CIParams(EstimatorParams):
    """Consensus on information (Battistelli & Chisci 2014) with Metropolis weights."""

    kind: Literal["ci_consensus"] = "ci_consensus"
    #: Consensus rounds per tick (0 = each node's local filter); T / rounds must be whole ns.
    rounds: Annotated[int, Field(strict=True, ge=0)] = 1

    def check(self, scenario) -> None:
        check_rounds("ci_consensus", self.rounds, scenario, note=" (consensus_rounds in older files)")


class KCFParams(EstimatorParams):
    """Kalman-consensus filter (Olfati-Saber, CDC 2009): one exchange per tick."""

    kind: Literal["kcf"] = "kcf"
    #: Consensus gain scale: gamma_i = eps / (1 + ||M_i||_F).  0 = neighbourhood filters only.
    #: Default 0.1: the paper leaves eps free; 0.1 keeps gamma_i ||M_i|| < 0.1, so the consensus
    #: term stays a contraction for up to 10 neighbours (docs/consensus.md).
    eps: NonNegReal = 0.1


class ICFParams(EstimatorParams):
    """Information-weighted consensus filter (Kamal, Farrell, Roy-Chowdhury, TAC 2013)."""

    kind: Literal["icf"] = "icf"
    #: Consensus iterations per tick (>= 1); T / rounds must be whole ns.  Default 1: one
    #: message per link per tick, the budget of kcf and ci_consensus's default.
    rounds: Rounds = 1

    def check(self, scenario) -> None:
        check_rounds("icf", self.rounds, scenario)


class DiffusionParams(EstimatorParams):
    """Diffusion Kalman filter (Cattivelli & Sayed, TAC 2010): incremental update, then diffusion."""

    kind: Literal["diffusion_kf"] = "diffusion_kf"
    #: Diffusion (combination) weights c_ij: ``metropolis`` (doubly stochastic on an undirected
    #: graph) or ``uniform`` (1 / (|N_i| + 1) over the closed neighbourhood, as the paper's example).
    weights: Literal["metropolis", "uniform"] = "metropolis"
    #: False: the incremental (measurement) step only, C = I.
    diffusion: StrictBool = True

    def check(self, scenario) -> None:
        check_rounds("diffusion_kf", 2, scenario, key="kind", note=" (its two exchanges)")


def _omega(value: Any) -> Any:
    if isinstance(value, str) and value == "n":
        return value
    if isinstance(value, (int, float)) and not isinstance(value, bool) and 1.0 <= float(value) < float("inf"):
        return float(value)
    raise custom_error(f"must be a number >= 1 or 'n' (the number of nodes), got {value!r}")


class HCMCIParams(EstimatorParams):
    """Hybrid consensus on measurements and information (Battistelli et al., TAC 2015)."""

    kind: Literal["hcmci"] = "hcmci"
    #: Consensus rounds per tick (>= 1); T / rounds must be whole ns.
    rounds: Rounds = 1
    #: Scale of the averaged novel information: 1 (default; consistent whatever arrived) or up
    #: to ``n`` (``'n'``: the centralized filter at full consensus, overconfident before it).
    omega: Annotated[float | Literal["n"], BeforeValidator(_omega)] = 1.0

    def check(self, scenario) -> None:
        check_rounds("hcmci", self.rounds, scenario)
        if self.omega != "n" and self.omega > scenario.n:
            raise custom_error(f"omega = {self.omega} exceeds the number of nodes n = {scenario.n} "
                               "(the stability range of Battistelli et al. is 1 <= omega <= n)", "omega")


for _params in (CentralizedParams, CentralizedDelayedParams, LocalOnlyParams, NoBufferParams,
                AntiDelayParams, CIParams, KCFParams, ICFParams, DiffusionParams, HCMCIParams):
    ESTIMATORS.add(_params.model_fields["kind"].default, params=_params)
ESTIMATORS.add("local_only", aliases=("local",))

"""The parameters of every built-in estimator (the keys of an ``estimators:`` entry).

Each model is registered in :data:`~dkfsim.core.registry.ESTIMATORS` under
its ``kind``; the algorithm itself (:mod:`dkfsim.estimators`) registers its
implementation under the same name.  An estimator written as a plugin
declares both in its own file (docs/extending.md).
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import BeforeValidator, Field

from dkfsim.core.params import StrictModel, custom_error
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


class CIParams(EstimatorParams):
    """Consensus on information (Battistelli & Chisci 2014) with Metropolis weights."""

    kind: Literal["ci_consensus"] = "ci_consensus"
    #: Consensus rounds per tick (0 = each node's local filter); T / rounds must be whole ns.
    rounds: Annotated[int, Field(strict=True, ge=0)] = 1

    def check(self, scenario) -> None:
        if self.rounds > 0 and scenario.T_ns % self.rounds:
            raise custom_error(f"{self.rounds} rounds per tick (consensus_rounds in older files) do not "
                               f"divide T = {scenario.model.T} s into whole nanoseconds "
                               "(ci_consensus runs a round every T/rounds)", "rounds")


for _params in (CentralizedParams, CentralizedDelayedParams, LocalOnlyParams, NoBufferParams,
                AntiDelayParams, CIParams):
    ESTIMATORS.add(_params.model_fields["kind"].default, params=_params)
ESTIMATORS.add("local_only", aliases=("local",))

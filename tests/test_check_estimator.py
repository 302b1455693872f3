"""``dkfsim.testing.check_estimator`` (issue 18): every registered estimator and the docs'
example pass it; estimators broken on purpose, one promise each, fail it naming that promise.

The broken ones are small subclasses of ``local_only`` (a Kalman filter per node, no
communication) or of the docs' ``neighbour_mean`` (which sends over the links), each
declared in the test and unregistered afterwards (``isolated_registries``).
"""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from typing_extensions import override

import dkfsim  # noqa: F401  (registers the built-in estimators)
from dkfsim.components.estimators import EstimatorParams
from dkfsim.core.registry import ESTIMATORS, load_plugin
from dkfsim.core.resources import Cost
from dkfsim.estimators.base import Estimate, Estimator
from dkfsim.estimators.local_only import LocalOnly
from dkfsim.testing import check_estimator

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "docs" / "examples"
BUILT_IN = ["centralized", "centralized_delayed", "local_only", "no_buffer", "anti_delay_dkf",
            "ci_consensus", "kcf", "icf", "diffusion_kf", "hcmci", "fusion_centre"]
#: The keys a kind requires (none has a default): what check_estimator is given.
REQUIRED = {"fusion_centre": {"at": 0}}


def test_the_built_in_list_is_every_registered_estimator():
    assert sorted(ESTIMATORS.names()) == sorted(BUILT_IN)


@pytest.mark.parametrize("kind", BUILT_IN)
def test_every_built_in_estimator_passes(kind):
    assert check_estimator(kind, REQUIRED.get(kind)) is None


@pytest.mark.usefixtures("isolated_registries")
def snippet(doc: Path) -> str:
    """The ``python`` block of ``doc`` that calls ``check_estimator``, as a user copies it."""
    blocks = re.findall(r"```python\n(.*?)```", doc.read_text(), flags=re.S)
    found = [b for b in blocks if "check_estimator(" in b]
    assert len(found) == 1, f"{doc}: {len(found)} python blocks call check_estimator"
    return found[0]


@pytest.mark.parametrize("doc", ["README.md", "docs/extending.md"])
def test_the_docs_example_passes_as_the_docs_write_it(doc):
    """The README's and docs/extending.md's "check it" blocks, verbatim, from the repository's
    top (where the README's commands run): the plugin file loads and its estimator passes. (The
    README's block once called check_estimator without loading the plugin: an AssertionError.)"""
    p = subprocess.run([sys.executable, "-c", snippet(ROOT / doc)], cwd=ROOT, capture_output=True,
                       text=True, timeout=300)
    assert p.returncode == 0, p.stderr[-3000:]


def fails(kind: str, check: str) -> str:
    with pytest.raises(AssertionError) as err:
        check_estimator(kind)
    message = str(err.value)
    assert message.startswith(f"check_estimator({kind!r}): {check}"), message
    return message


@pytest.mark.usefixtures("isolated_registries")
def test_an_unknown_kind_or_a_model_without_implementation_fails_registration():
    fails("no_such_estimator", "registration: no such estimator")

    class OnlyParams(EstimatorParams, kind="only_params"):
        """Parameters, and no algorithm."""

    fails("only_params", "registration: no Estimator implementation")


@pytest.mark.usefixtures("isolated_registries")
def test_a_wrong_shape_fails():
    class WrongShapeParams(EstimatorParams, kind="wrong_shape"):
        """Per-node estimates with the node and state axes swapped."""

    class WrongShape(LocalOnly, params=WrongShapeParams):
        def estimate(self) -> Estimate:
            e = super().estimate()
            return Estimate(np.swapaxes(e.x, 1, 2).copy(), None)         # (K, nx, n), not (K, n, nx)

    message = fails("wrong_shape", "shapes: x of 'wrong_shape' has shape (100, 3, 6)")
    assert "(K, n, nx) = (100, 6, 3)" in message


@pytest.mark.usefixtures("isolated_registries")
def test_nondeterministic_draws_fail():
    class DiceParams(EstimatorParams, kind="dice"):
        """Adds noise from an unseeded generator: a different estimate every run."""

    class Dice(LocalOnly, params=DiceParams):
        def estimate(self) -> Estimate:
            e = super().estimate()
            return Estimate(e.x + 1e-3 * np.random.default_rng().standard_normal(e.x.shape), e.P)

    fails("dice", "determinism: a second run with the same seed gave a different x_dice")


@pytest.mark.usefixtures("isolated_registries")
def test_an_estimator_that_changes_the_shared_draws_fails():
    class ScribbleParams(EstimatorParams, kind="scribble"):
        """Writes into the run's measurements, which the DKF reads too."""

    class Scribble(LocalOnly, params=ScribbleParams):
        def start(self) -> None:
            self.ctx.info.theta[:] *= 2.0

    fails("scribble", "the same draws as the DKF: listing it changed")


@pytest.mark.usefixtures("isolated_registries")
def test_an_estimator_blind_to_the_run_fails():
    class PriorParams(EstimatorParams, kind="prior_only"):
        """Reports the prior mean, whatever the run measured."""

    class PriorOnly(Estimator, params=PriorParams):
        def estimate(self) -> Estimate:
            s = self.ctx.system
            return Estimate(np.tile(np.asarray(s.x0_mean, float), (self.ctx.K, 1)))

    fails("prior_only", "the same draws as the DKF: another seed gives the same estimates")


@pytest.mark.usefixtures("isolated_registries")
def test_a_miscounted_traffic_fails_the_counting_identity():
    load_plugin(str(EXAMPLES / "neighbour_mean.py"))
    NeighbourMean = ESTIMATORS.get("neighbour_mean").implementation

    class MiscountParams(NeighbourMean.Params, kind="miscount"):
        """Reports the packets it lost as delivered, and counts copies twice."""

    class Miscount(NeighbourMean, params=MiscountParams):
        def traffic(self):
            t = super().traffic()
            t["delivered"] += t["lost"] + t["copies"]
            return t

    fails("miscount", "counting identity: traffic of 'miscount': sent + copies != delivered")


@pytest.mark.usefixtures("isolated_registries")
def test_a_cost_below_what_the_run_allocates_fails():
    class CheapParams(EstimatorParams, kind="cheap"):
        """local_only with the default cost: next to nothing."""

    class Cheap(LocalOnly, params=CheapParams):
        @classmethod
        @override
        def cost(cls, params, plan) -> Cost:
            return Cost(params.label)

    fails("cheap", "cost >= measured allocation")


@pytest.mark.usefixtures("isolated_registries")
def test_a_cost_that_misses_one_array_per_node_fails():
    """The check's resolution: a covariance per node and tick left out of the cost is found."""
    class HoarderParams(EstimatorParams, kind="hoarder"):
        """local_only keeping one more (K, n, nx, nx) array than its cost says."""

    class Hoarder(LocalOnly, params=HoarderParams):
        def start(self) -> None:
            self.extra = np.ones((self.ctx.K, self.ctx.n, self.ctx.nx, self.ctx.nx))

    fails("hoarder", "cost >= measured allocation")


@pytest.mark.usefixtures("isolated_registries")
def test_an_estimator_that_raises_on_overflow_fails_nan_handling():
    class StrictParams(EstimatorParams, kind="strict"):
        """Refuses non-finite numbers instead of reporting them."""

    class Strict(LocalOnly, params=StrictParams):
        def estimate(self) -> Estimate:
            e = super().estimate()
            if not np.isfinite(e.x).all():
                raise FloatingPointError("the state overflowed")
            return e

    message = fails("strict", "NaN handling: on a model whose state overflows the run failed")
    assert "FloatingPointError: the state overflowed" in message

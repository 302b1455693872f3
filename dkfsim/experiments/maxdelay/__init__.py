"""The largest tolerable delay: ``dkfsim maxdelay FILE --tolerance X | --relative R``.

Three answers to "how much delay can this network take before the estimate
gets worse than a tolerance?", side by side:

1. **Empirical** (Monte Carlo, sequential).  The delay axis is ``d_t`` of a
   ``uniform_steps`` latency model (integers ``0, 1, 2, ...``) or, for
   continuous latency models, a scale ``s`` on a grid ``0, ds, 2 ds, ...``
   that multiplies every time parameter of every latency model (see
   :meth:`~dkfsim.components.latency.LatencyParams.scaled_keys`).  A candidate delay is evaluated with Monte Carlo runs
   in batches (run ``r`` uses seed ``derive_seed(seed, r)`` of
   :mod:`dkfsim.experiments.montecarlo`, the same ``r`` at every candidate: common
   random numbers) and stops as soon as the Student-t confidence interval of
   the metric's excess over the tolerance is entirely below 0 (*within*) or
   entirely above (*exceeds*), or when ``--max-runs`` is reached
   (*undecided*).  Candidates are chosen by galloping (0, 1, 2, 4, ...) and
   then bisection, which assumes the metric grows with the delay: few runs far
   from the boundary, more near it.
2. **Deterministic worst case.**  The covariance recursion does not depend on
   the data, only on when information arrives.  With every link at its
   maximum latency (constant ``d_t T``, or the scaled model's supremum) the
   arrival pattern is fixed, so ONE run gives the worst-case covariance
   metric: ``P_fused[c, c]`` (the expected squared error of component c) or
   ``trace(P_fused)``, time-averaged after burn-in.  Same search, one run per
   candidate.
3. **The paper's bound** (Remark ``bound_of_delay``, eq. ``delay_bound``),
   from :mod:`dkfsim.analysis.bounds`, for the covariance tolerance of (2).

Relative tolerance ``--relative R`` means metric(d) <= R * metric(0).  The
zero-delay value is estimated from the same runs (the same seeds, so the same
truth and measurements) and its uncertainty is carried by pairing: per run
``r`` the excess is ``m_d[r] - R * m_0[r]`` and the decision uses the
t-interval of those paired differences.  For the worst case the zero-delay
value is deterministic.

Runs hold the graph fixed (a random topology generator without
``params.seed`` gets the scenario seed, i.e. the graph of the base
scenario) and drop every listed estimator but the one measured (they do not change the anti-delay DKF's
estimates).  The buffer length follows the candidate delay when it is
``auto`` (``d_t d_g + 1``).

The code: :mod:`.axis` (the delay axis), :mod:`.search` (metrics, candidates, galloping,
bisection and the worst-case scan), :mod:`.run` (:class:`MaxDelay`, the three answers) and
:mod:`.report` (``maxdelay.json``, the table and the figure).  docs/design.md explains it.
"""

from __future__ import annotations

from dkfsim.experiments.maxdelay.axis import (
                                              RANDOM_GENERATORS,
                                              DelayAxis,
                                              latencies_deterministic,
                                              make_axis,
                                              scalable_models,
)
from dkfsim.experiments.maxdelay.report import MaxDelayResult
from dkfsim.experiments.maxdelay.run import MaxDelay, Settings, check_settings, maxdelay, resolve_component
from dkfsim.experiments.maxdelay.search import (
                                              COVARIANCE_METRICS,
                                              EXCEEDS,
                                              FUSED_METRICS,
                                              METRICS,
                                              UNDECIDED,
                                              WITHIN,
                                              Candidate,
                                              Runner,
                                              SearchResult,
                                              classify,
                                              covariance_value,
                                              empirical_search,
                                              gallop_bisect,
                                              interval,
                                              metric_value,
                                              summarise,
                                              worst_case_scan,
)

__all__ = ["COVARIANCE_METRICS", "EXCEEDS", "FUSED_METRICS", "METRICS", "RANDOM_GENERATORS",
           "UNDECIDED", "WITHIN", "Candidate", "DelayAxis", "MaxDelay", "MaxDelayResult", "Runner",
           "SearchResult", "Settings", "check_settings", "classify", "covariance_value",
           "empirical_search", "gallop_bisect", "interval", "latencies_deterministic", "make_axis",
           "maxdelay", "metric_value", "resolve_component", "scalable_models", "summarise",
           "worst_case_scan"]

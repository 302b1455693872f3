"""Every algorithm of a run: the anti-delay DKF and the field's other estimators.

Each is an :class:`~dkfsim.estimators.base.Estimator` in a module of its
own; importing this package registers the built-in ones.
"""

from dkfsim.estimators import (  # noqa: F401
                               anti_delay,
                               centralized,
                               centralized_delayed,
                               ci_consensus,
                               diffusion_kf,
                               fusion_centre,
                               hcmci,
                               icf,
                               kcf,
                               local_only,
)

"""``triangular``: a latency model for docs/extending.md -- triangular on [low, high] with a mode.

One class: its parameters (pydantic fields, validated like every scenario
key), its quantile function (``from_uniform``: every draw of a link is the
quantile of a keyed uniform, so the common-random-numbers rule holds with no
further work), its supremum (so ``buffer_length: auto`` can size the buffer)
and the keys a latency scale multiplies (so ``maxdelay`` can search it).
"""

from __future__ import annotations

from typing import ClassVar, Literal

import numpy as np
from pydantic import model_validator
from typing_extensions import override

from dkfsim.components.latency import LatencyParams
from dkfsim.core.params import NS_PER_S, NonNegSeconds, custom_error, seconds_to_ns
from dkfsim.core.registry import LATENCY_MODELS


@LATENCY_MODELS.register("triangular")
class Triangular(LatencyParams):
    """Triangular on [low, high] seconds with its peak at mode."""

    model: Literal["triangular"] = "triangular"
    low: NonNegSeconds = 0.0
    mode: NonNegSeconds
    high: NonNegSeconds
    scale_keys: ClassVar = ("low", "mode", "high")

    @model_validator(mode="after")
    def _ordered(self):
        if not self.low <= self.mode <= self.high:
            raise custom_error(f"must satisfy low <= mode <= high, got {self.low}, {self.mode}, {self.high}",
                               "mode")
        return self

    @override
    def from_uniform(self, u, T_ns):
        a, c, b = self.low, self.mode, self.high
        u = np.asarray(u, float)
        f = (c - a) / (b - a) if b > a else 0.5
        x = np.where(u < f, a + np.sqrt(u * (b - a) * (c - a)), b - np.sqrt((1 - u) * (b - a) * (b - c)))
        return np.rint(x * NS_PER_S).astype(np.int64)

    @override
    def sup_ns(self, T_ns):
        return seconds_to_ns(self.high)

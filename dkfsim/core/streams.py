"""Independent random streams keyed by stable names.

Every random quantity of a run (the truth, each sensor's noise, each link's
latency and loss) draws from its own :class:`numpy.random.Generator`, spawned
from the scenario seed with a key derived from a *name* such as
``("link", 0, 1)`` or ``("sensor", "s1")``.  Because the key depends on the
name only, adding a link or a sensor leaves every other stream unchanged, and
a run is bit-for-bit repeatable from its seed whatever the worker count.
"""

from __future__ import annotations

import hashlib

import numpy as np


def stream_key(name: tuple) -> tuple[int, ...]:
    """Map a name (a tuple of str/int) to a stable tuple of 32-bit words."""
    digest = hashlib.blake2b(repr(tuple(name)).encode(), digest_size=16).digest()
    return tuple(int.from_bytes(digest[i:i + 4], "little") for i in range(0, 16, 4))


def stream(seed: int, *name) -> np.random.Generator:
    """The generator for ``name`` under scenario ``seed``."""
    seq = np.random.SeedSequence(entropy=int(seed), spawn_key=stream_key(name))
    return np.random.Generator(np.random.PCG64(seq))

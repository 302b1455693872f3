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


# --------------------------------------------------------------------------- keyed draws
_M64 = (1 << 64) - 1
_GOLDEN = 0x9E3779B97F4A7C15
_SCALE = 1.0 / 9007199254740992.0          # 2^-53


def key64(seed: int, *name) -> int:
    """A 64-bit key for the draws named ``name`` under ``seed`` (e.g. a link's latency)."""
    digest = hashlib.blake2b(repr((int(seed),) + tuple(name)).encode(), digest_size=8).digest()
    return int.from_bytes(digest, "little")


def keyed_uniform(key: int, t: int, seq: int, _m64: int = _M64, _golden: int = _GOLDEN,
                  _scale: float = _SCALE) -> float:
    """A uniform draw in (0, 1) that is a pure function of ``(key, t, seq)``.

    Links draw a packet's latency and loss this way, keyed by the link and
    stream (``key``), the send instant in nanoseconds (``t``) and the
    packet's number among those its sender put on the link at that instant
    (``seq``): two estimators sending over one link at one instant see the
    same delay (common random numbers), and a draw never depends on how many
    packets came before.  Two rounds of SplitMix64 mixing; 53 bits.
    """
    # Two rounds of SplitMix64's output function (a bijection of 64-bit words with full
    # avalanche), written out: this runs once per packet (and once per frame's backoff on a
    # shared channel), so its constants are bound as defaults (local reads, not global:
    # about a fifth of its time; never pass them).
    z = (key + _golden * (t & _m64)) & _m64
    z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & _m64
    z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & _m64
    z = ((z ^ (z >> 31)) + _golden * (seq + 1)) & _m64
    z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & _m64
    z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & _m64
    return (((z ^ (z >> 31)) >> 11) + 0.5) * _scale


def keyed_uniforms(key, t, seq) -> np.ndarray:
    """:func:`keyed_uniform` for arrays of ``t`` and ``seq`` (and ``key``: one key, or one per
    entry, broadcast together; bit-identical values)."""
    t = np.asarray(t, dtype=np.int64).astype(np.uint64)
    seq = np.asarray(seq, dtype=np.int64).astype(np.uint64)
    key = np.uint64(key) if isinstance(key, int) else np.asarray(key, dtype=np.uint64)
    with np.errstate(over="ignore"):
        z = _mix_array(key + np.uint64(_GOLDEN) * t)
        z = _mix_array(z + np.uint64(_GOLDEN) * (seq + np.uint64(1)))
    return ((z >> np.uint64(11)).astype(np.float64) + 0.5) * _SCALE


def _mix_array(z: np.ndarray) -> np.ndarray:
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return z ^ (z >> np.uint64(31))

"""Kernels of :class:`dkfsim.network.media.slotted.SlottedAccess`: how the radios' views of the
medium change their counts (docs/radio.md, "The access rules").

The access rule's state is five arrays over the radios (``idle_at``, ``origin``, ``count``,
``due``, ``head_on``; their meaning is the class's).  A frame sensed by hundreds of radios
changes hundreds of them: one call does the loop, so the per-frame cost is one call, not a
dozen vector operations over a selection.

On the numba path these functions are compiled; on the numpy path they run as Python.
"""

from __future__ import annotations

from types import ModuleType

import numpy as np

from dkfsim.core.jit import LazyKernels

_KERNELS = ("busy", "clear", "start", "first_air")
_lazy = LazyKernels(__name__, _KERNELS)


def compiled() -> ModuleType:
    """This module with its kernels compiled by numba (loaded from the disk cache after the
    first time)."""
    return _lazy.get()


def busy(idle_at: np.ndarray, origin: np.ndarray, count: np.ndarray, due: np.ndarray, head_on: np.ndarray,
         nodes: np.ndarray, n: int, t: int, slot: int, never: int) -> int:
    """The radios ``nodes[:n]`` sense the medium busy from ``t``: each that sensed it idle keeps
    the boundaries of its count not passed before ``t`` (a head keeps at least 0 left; a
    post-backoff with nothing left and no frame to send is over: -1).  Returns how many
    changed (0: no ``due`` changed)."""
    changed = 0
    for j in range(n):
        r = nodes[j]
        if idle_at[r] < 0:
            continue
        changed += 1
        idle_at[r] = -1
        due[r] = never
        c = count[r]
        if c >= 0:
            o = origin[r]
            left = c if t <= o else c - (-((o - t) // slot))
            if head_on[r]:
                count[r] = left if left > 0 else 0
            else:
                count[r] = left if left > 0 else -1
    return changed


def clear(idle_at: np.ndarray, origin: np.ndarray, count: np.ndarray, due: np.ndarray, head_on: np.ndarray,
          nodes: np.ndarray, n: int, t: int, slot: int, aifs: int, eifs: int, error: np.ndarray) -> int:
    """The radios ``nodes[:n]`` sense the medium idle from ``t``: each counts from ``t + aifs``,
    or ``t + eifs`` when ``error[r]`` (its last frame received was in error; read and cleared
    here); a head is due at its count's boundary.  Returns how many heads were among them (0:
    no ``due`` changed)."""
    heads = 0
    for j in range(n):
        r = nodes[j]
        idle_at[r] = t
        o = t + (eifs if error[r] else aifs)
        error[r] = 0
        origin[r] = o
        if head_on[r]:
            heads += 1
            c = count[r]
            due[r] = o + c * slot if c >= 0 else o
    return heads


def start(due: np.ndarray, head_on: np.ndarray, count: np.ndarray, ts: int, never: int, out: np.ndarray) -> int:
    """The radios due at ``ts``, in order, written to ``out`` (their number returned): they are
    heads no more, due never, with no count."""
    n = 0
    for r in range(len(due)):
        if due[r] == ts:
            head_on[r] = False
            due[r] = never
            count[r] = -1
            out[n] = r
            n += 1
    return n


def first_air(due: np.ndarray, air: np.ndarray, ts: int) -> int:
    """The shortest airtime of the radios due at ``ts`` (-1: none)."""
    best = -1
    for r in range(len(due)):
        if due[r] == ts and (best < 0 or air[r] < best):
            best = air[r]
    return best

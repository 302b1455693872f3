"""Kernels of :mod:`dkfsim.model.holdings`: folding newly held contributions into the sums.

:func:`fold` adds the origins of one origin set (little-endian uint64 words) to one node's
information sums for one row, origins ascending, and notes the row as changed;
:func:`fold_masks` folds many, in order (what a Python protocol reported since the last
update).  The arrays come grouped in the module-level namedtuple :class:`Fold`, which numba's
disk cache keeps like plain arrays.

The compiled ``tree`` protocol folds what a packet brings straight into the holdings, with
:func:`fold` and :func:`bit_index` inlined into its own kernels
(:mod:`dkfsim.protocols.tree_compiled_kernels`).  numba's cache does not notice an edit of
this file in those kernels, so they pin its sha256 (``LazyKernels(..., borrows=...)``): after
an edit here they compile without the disk cache (correct, slower, one warning) until the pin
is updated, and ``tests/test_kernels.py`` fails until it is (docs/decisions.md 131).
"""

from __future__ import annotations

from collections import namedtuple

import numpy as np

from dkfsim.core.jit import LazyKernels

_KERNELS = ("bit_index", "fold", "fold_masks")
#: Steps inlined into the kernels that call them per contribution (here and in the tree's).
_INLINE = ("bit_index", "fold")
_lazy = LazyKernels(__name__, _KERNELS, inline=_INLINE)

#: What a fold reads and writes: the weights ``A`` (node x origin), the information ``omega``
#: (1 or K, origin, nx, nx; per row when ``varying``) and ``theta`` (K, origin, nx), and the
#: holdings: the sums ``Omega`` (slot, node, nx, nx) and ``Theta`` (slot, node, nx), the origins
#: held (``held``, slot x node x origin; no origin axis when nothing needs it) and ``starts``
#: (each node's earliest changed row).
Fold = namedtuple("Fold", "A omega varying theta Omega Theta held starts")

_ONE = np.uint64(1)
_ZERO = np.uint64(0)
#: De Bruijn multiplication: the index of a word's lowest set bit without scanning the others.
_DEBRUIJN = 0x03F79D71B4CB0A89
_BIT_INDEX = np.zeros(64, dtype=np.int64)
for _i in range(64):
    _BIT_INDEX[(((1 << _i) * _DEBRUIJN) & ((1 << 64) - 1)) >> 58] = _i
_DB = np.uint64(_DEBRUIJN)
_S58 = np.uint64(58)


def compiled():
    """This module with its kernels compiled by numba (loaded from the disk cache after the
    first time)."""
    return _lazy.get()


def bit_index(low):
    """The index of the one set bit of ``low`` (a word's lowest set bit, ``m & -m``)."""
    return _BIT_INDEX[(low * _DB) >> _S58]


def fold(node, row, bits, F):
    """Add the origins ``bits`` (words) of ``row`` to ``node``'s sums, origins ascending, mark
    them held and note ``row`` as changed for ``node``."""
    S = F.Omega.shape[0]
    nx = F.Omega.shape[2]
    slot = row % S
    r_om = row if F.varying else 0
    for w in range(bits.shape[0]):
        m = bits[w]
        while m != _ZERO:
            low = m & (~m + _ONE)
            m ^= low
            org = w * 64 + bit_index(low)
            a = F.A[node, org]
            if F.held.shape[2]:                    # only kept when the fusion needs it
                F.held[slot, node, org] = True
            for p in range(nx):
                for q in range(nx):
                    F.Omega[slot, node, p, q] += a * F.omega[r_om, org, p, q]
                F.Theta[slot, node, p] += a * F.theta[row, org, p]
    if row < F.starts[node]:
        F.starts[node] = row


def fold_masks(i, r, words, F):
    """:func:`fold` for many contributions, in order: ``words[k]`` holds the origins node
    ``i[k]`` gained for row ``r[k]``."""
    for k in range(i.shape[0]):
        fold(i[k], r[k], words[k], F)

"""Kernels of :mod:`dkfsim.model.holdings`: folding newly held contributions into the sums.

:func:`fold` adds the origins of one origin set (little-endian uint64 words) to one node's
information sums for one row, origins ascending, and notes the row as changed;
:func:`fold_masks` folds many, in order (what a Python protocol reported since the last
update).  The arrays come grouped in the module-level namedtuple :class:`Fold`, which numba's
disk cache keeps like plain arrays.

Every kernel that folds lives in this file: numba's disk cache keys a kernel by its own
file, so a kernel elsewhere calling :func:`fold` would keep stale code after an edit here.
:func:`fold_unknown` is a fusion centre's fold of what its packets taught it (decision 233).
"""

from __future__ import annotations

from collections import namedtuple

import numpy as np

from dkfsim.core.jit import LazyKernels

_KERNELS = ("bit_index", "fold", "fold_masks", "_fold_origins", "fold_unknown")
#: Steps inlined into the kernels that call them per contribution.
_INLINE = ("bit_index", "fold", "_fold_origins")
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


def _fold_origins(i, row, have, known, bits, F):
    """Fold the origins flagged in ``have`` that ``known`` (the caller's ring of what each node
    holds) lacks for node ``i`` and ``row`` into the sums (:func:`fold`, origins ascending),
    and mark them known."""
    slot = row % known.shape[0]
    new = False
    for o in range(have.shape[0]):
        if have[o] and not known[slot, i, o]:
            if not new:
                bits[:] = 0
                new = True
            known[slot, i, o] = True
            bits[o >> 6] |= np.uint64(1) << np.uint64(o & 63)
    if new:
        fold(i, row, bits, F)


def fold_unknown(stack, nodes, k0, known, F):
    """:meth:`Holdings.add_unknown <dkfsim.model.holdings.Holdings.add_unknown>`:
    ``stack[a, j]`` are the origins node ``nodes[j]`` holds of row ``k0 + a``; what ``known``
    lacks is folded (:func:`_fold_origins`; rows, then nodes)."""
    rows, m, no = stack.shape
    bits = np.zeros((no + 63) // 64, dtype=np.uint64)
    for a in range(rows):
        for j in range(m):
            _fold_origins(nodes[j], k0 + a, stack[a, j], known, bits, F)

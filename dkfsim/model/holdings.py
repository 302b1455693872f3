"""What every node holds for the rows of the window, and the information sums of it.

The seam between the anti-delay DKF's two halves: an exchange protocol
(:mod:`dkfsim.protocols`) decides *when* a node gains contributions, the window filter
(:class:`dkfsim.estimators.window.WindowFilter`) re-runs rows with *what* each node holds.
Neither touches the other; both use a :class:`Holdings`:

* a protocol reports what a node newly holds with :meth:`Holdings.add` (an origin bitmask for
  a row), or many at once with :meth:`Holdings.add_words`;
* the window clears a row's slot when the row opens (:meth:`Holdings.open_row`), takes each
  node's earliest changed row at its update (:meth:`Holdings.take_changes`, which folds what
  is pending first), and reads the sums ``Omega``, ``Theta`` and the flags ``held``.

Slot ``row % S`` holds row ``row``.  ``S = min(L, K) + 1``: the window of ``L`` rows and the
final row it starts from, never more than the run has rows (so a huge ``L`` costs no memory).
The sums are ``sum_o a_io omega_o`` and ``sum_o a_io theta_o[row]`` over the origins ``o`` held,
added in the order the contributions were reported (origins ascending within one report):
the numpy and numba folds add the same numbers in the same order.
"""

from __future__ import annotations

import numpy as np

from dkfsim.core.backend import Backend
from dkfsim.core.bits import mask_words, set_bits
from dkfsim.core.jit import bind
from dkfsim.model import holdings_kernels
from dkfsim.model.system import Information

#: ``starts`` of a node without news.
NO_ROW = np.iinfo(np.int64).max


class Holdings:
    """Each node's contributions held for the rows of the window, and their sums.

    :param info: every sensor's contributions (origins are its sensors).
    :param A: (nodes, origins) effective origin weights ``a_io`` (ones for unit weights).
    :param L: the buffer length (the ring has ``min(L, K) + 1`` slots).
    :param per_origin: keep which origins each node holds (``held``); only the fusion needs
        it (without, a 1000-node window would carry S x 10^6 flags).
    :param backend: the run's :class:`~dkfsim.core.backend.Backend` (numba or numpy fold).
    """

    def __init__(self, info: Information, A: np.ndarray, L: int, *, per_origin: bool = True,
                 backend: Backend):
        self.info = info
        self.A = np.asarray(A, float)
        self.L = int(L)
        K, n_origins, nx = info.theta.shape
        self.S = min(self.L, K) + 1
        n = self.A.shape[0]
        self.n, self.nx = n, nx
        S = self.S
        self.Omega = np.zeros((S, n, nx, nx))
        self.Theta = np.zeros((S, n, nx))
        self.held = np.zeros((S, n, n_origins if per_origin else 0), dtype=bool)
        #: each node's earliest row changed since the last :meth:`take_changes`
        self.starts = np.full(n, NO_ROW, dtype=np.int64)
        #: contributions reported since the last fold: node, origin bitmask, row (flat)
        self._pend: list[int] = []
        self._words = -(-n_origins // 64)
        self._compiled = backend.compiled
        omega = info.omega if info.varying else info.omega[None]
        #: the arrays a fold writes (:class:`dkfsim.model.holdings_kernels.Fold`), for kernels
        self.fold_target = holdings_kernels.Fold(self.A, omega, bool(info.varying), info.theta, self.Omega,
                                                 self.Theta, self.held, self.starts)
        #: the compiled fold of :meth:`add_words`, bound to its arguments' types (None: numpy)
        self._fold_words = None
        if self._compiled:
            i = np.zeros(1, np.int64)
            self._fold_words = bind(holdings_kernels.compiled().fold_masks, i, i,
                                    np.zeros((1, self._words), np.uint64), self.fold_target)

    # -- what protocols call -----------------------------------------------------
    def add(self, node: int, origins: int, row: int) -> None:
        """Node ``node`` now holds the contributions of the origins set in the bitmask
        ``origins`` (a non-negative int, bit ``o`` for origin ``o``) for ``row``; they must be
        new to it."""
        self._pend.extend((node, origins, row))

    def add_words(self, nodes: np.ndarray, rows: np.ndarray, words: np.ndarray) -> None:
        """:meth:`add` for many contributions, folded now, in order: node ``nodes[k]`` now holds
        the origins set in ``words[k]`` (little-endian uint64 words) for ``rows[k]``, new to it
        (int64 arrays and a C-ordered uint64 one: a protocol's kernel output, folded as it is)."""
        self._flush()
        if self._fold_words is not None:
            self._fold_words(nodes, rows, words, self.fold_target)
        else:
            self._fold(nodes, rows, words)

    def add_held(self, nodes: np.ndarray, rows: np.ndarray, held: np.ndarray) -> None:
        """:meth:`add` for many contributions at once, folded now: node ``nodes[k]`` now holds
        the origins flagged in ``held[k]`` (bool, one flag per origin) for ``rows[k]``, new to
        it.  The same sums, in the same order, as ``add`` of each then a fold (what is pending
        is folded first); no Python int per mask (the fusion centre's shadow, decision 233)."""
        self._flush()
        self._fold(np.asarray(nodes, dtype=np.intp), np.asarray(rows, dtype=np.intp),
                   np.asarray(held, dtype=bool))

    def add_unknown(self, stack: np.ndarray, nodes: np.ndarray, k0: int, known: np.ndarray) -> None:
        """:meth:`add_held` of what ``stack`` says that ``known`` lacks, folded now:
        ``stack[a, j]`` flags the origins node ``nodes[j]`` holds of row ``k0 + a``; those not
        yet set in ``known[row % len(known), node]`` (the caller's ring of what it knows each
        node holds) are folded -- rows, then nodes, origins ascending -- and set there (a
        fusion centre's shadow, decision 233)."""
        self._flush()
        if self._compiled:
            holdings_kernels.compiled().fold_unknown(stack, np.asarray(nodes, dtype=np.intp), int(k0), known,
                                                     self.fold_target)
            return
        slots = np.arange(k0, k0 + len(stack)) % known.shape[0]
        new = stack & ~known[slots[:, None], nodes]
        rr, jj = np.nonzero(new.any(axis=2))
        if not len(jj):
            return
        sel = new[rr, jj]
        known[slots[rr], nodes[jj]] |= sel
        self._fold(np.asarray(nodes, dtype=np.intp)[jj], k0 + rr, sel)

    # -- what the window calls -------------------------------------------------------
    def open_row(self, row: int) -> None:
        """Clear the slot that ``row`` (a new row) will use."""
        slot = row % self.S
        self.Omega[slot] = 0.0
        self.Theta[slot] = 0.0
        self.held[slot] = False

    def take_changes(self) -> np.ndarray | None:
        """Fold what is pending; each node's earliest row changed since the last call (``n``
        ints, :data:`NO_ROW` for a node without news), or None when no node changed."""
        self._flush()
        starts = self.starts.copy()
        self.starts.fill(NO_ROW)           # in place: a protocol's kernels hold a reference
        return None if starts.min() == NO_ROW else starts

    # -- folding -------------------------------------------------------------------------
    def _flush(self) -> None:
        """Fold what :meth:`add` reported since the last fold."""
        if self._pend:
            self._fold(*self._pending_arrays())

    def _pending_arrays(self):
        """The pending contributions as arrays: nodes, rows and the masks as little-endian
        64-bit words (one row of ``words`` per contribution)."""
        pend, self._pend = self._pend, []
        return (np.array(pend[0::3], dtype=np.intp), np.array(pend[2::3], dtype=np.intp),
                mask_words(pend[1::3], self._words))

    def _fold(self, i: np.ndarray, r: np.ndarray, words: np.ndarray) -> None:
        """Fold contributions in, in the order given (origins ascending within one mask): node
        ``i[k]`` gained the origins of ``words[k]`` for row ``r[k]``.  ``words``: each mask as
        little-endian 64-bit words, or (bool) one flag per origin.  Compiled:
        :func:`~dkfsim.model.holdings_kernels.fold_masks` (of words); else in numpy, which
        reads the flags as they are (no packing to unpack again)."""
        flags = words.dtype == np.bool_
        if self._compiled:
            if flags:
                packed = np.packbits(words, axis=1, bitorder="little")
                words = np.zeros((len(packed), 8 * self._words), dtype=np.uint8)
                words[:, :packed.shape[1]] = packed
                words = words.view(np.uint64)
            holdings_kernels.compiled().fold_masks(i, r, words, self.fold_target)
            return
        k, o = np.nonzero(words) if flags else set_bits(words)   # (rows, then origins, ascending)
        i, r = i[k], r[k]
        slot = r % self.S
        a = self.A[i, o]
        if self.held.shape[2]:
            self.held[slot, i, o] = True
        np.add.at(self.Omega, (slot, i), a[:, None, None] * self.info.omega_of(r, o))
        np.add.at(self.Theta, (slot, i), a[:, None] * self.info.theta[r, o])
        np.minimum.at(self.starts, i, r)

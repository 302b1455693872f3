"""Information-form Kalman filtering, batched over nodes.

Every filter in dkfsim -- each node's buffered window filter (docs/design.md
§4, the paper's Algorithms 1 and 2) and the centralized baseline --
is the same recursion: predict with ``Phi, Q``, then add the information
``Omega = sum omega_m``, ``Theta = sum theta_m`` of the contributions held::

    Pp = Phi P Phi' + Q                    # paper eq. (predict_delay_P)
    P  = (Pp^-1 + Omega)^-1                # paper eq. (COV_delay)
    x  = P (Pp^-1 Phi x + Theta)           # paper eq. (COV_state)

We never form ``Pp^-1``: with ``M = I + Pp Omega`` (eigenvalues >= 1, so well
conditioned whenever ``Pp`` is), ``G = M^-1 = P Pp^-1`` (the "I - K H" of the
covariance form), ``P = G Pp`` and ``x = M^-1 (xp + Pp Theta)``: one batched
linear solve per row for all nodes at once.  ``G`` is also what the fusion
cross-covariance recursion needs (:mod:`dkfsim.estimators.fusion`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dkfsim.core.bits import mask_words, set_bits
from dkfsim.core.linalg import solve
from dkfsim.estimators import kernels
from dkfsim.protocols import tree_compiled_kernels


def predict(Phi, Q, x, P):
    """The prediction of a batch of filters: ``(Phi x, Phi P Phi' + Q)`` for ``x`` (b, nx) and
    ``P`` (b, nx, nx), not symmetrized (the window, ``ci_consensus`` and the other round-based
    estimators predict with these exact operations; each symmetrizes or not as before)."""
    return x @ Phi.T, Phi @ P @ Phi.T + Q


def information_step(Phi, Q, x_prev, P_prev, Omega, Theta):
    """One predict/update for a batch of filters.

    :param x_prev: (b, nx) previous estimates; ``P_prev`` (b, nx, nx).
    :param Omega: (b, nx, nx) information matrices held for this row.
    :param Theta: (b, nx) information vectors held for this row.
    :returns: ``x, P, G`` with ``G = P Pp^-1``.
    """
    nx = Phi.shape[0]
    eye = _eye(nx)
    xp, Pp = predict(Phi, Q, x_prev, P_prev)
    M = Pp @ Omega
    M += eye
    rhs = np.empty(Pp.shape[:-1] + (nx + 1,))
    rhs[..., :nx] = eye
    rhs[..., nx:] = (Pp @ Theta[..., None])
    rhs[..., nx] += xp
    sol = solve(M, rhs)
    G = sol[..., :nx]
    x = sol[..., nx]
    P = G @ Pp
    P += np.swapaxes(P, -1, -2)
    P *= 0.5
    return x, P, G


_EYES: dict[int, np.ndarray] = {}
#: ``starts`` of a node without news.
NO_ROW = np.iinfo(np.int64).max


def _eye(nx: int) -> np.ndarray:
    """A cached identity: ``np.eye`` per row and node batch is measurable overhead."""
    eye = _EYES.get(nx)
    if eye is None:
        eye = _EYES[nx] = np.eye(nx)
        eye.setflags(write=False)
    return eye


def batched_filter(Phi, Q, x0, P0, Omega, Theta):
    """``b`` independent information filters.

    :param Omega: (b, nx, nx) information added at every row, or (K, b, nx, nx) per row.
    :param Theta: (K, b, nx) information vectors per row.
    :returns: ``x`` (K, b, nx) and ``P`` (K, b, nx, nx).
    """
    K, b, nx = Theta.shape
    xs = np.empty((K, b, nx))
    Ps = np.empty((K, b, nx, nx))
    x = np.broadcast_to(np.asarray(x0, float), (b, nx))
    P = np.broadcast_to(np.asarray(P0, float), (b, nx, nx))
    per_row = Omega.ndim == 4
    if kernels.kernel_path() == "numba":         # one compiled call instead of K numpy steps
        model = kernels.Model(np.asarray(Phi, float), np.asarray(Q, float), np.ascontiguousarray(x),
                              np.ascontiguousarray(P))
        kernels.compiled().filter_rows(model, np.ascontiguousarray(Omega if per_row else Omega[None], float),
                                       per_row, np.ascontiguousarray(Theta, float), xs, Ps)
        return xs, Ps
    for r in range(K):
        x, P, _ = information_step(Phi, Q, x, P, Omega[r] if per_row else Omega, Theta[r])
        xs[r] = x
        Ps[r] = P
    return xs, Ps


def centralized_filter(Phi, Q, x0, P0, omega_total, theta_total):
    """The centralized information filter that holds every contribution on time.

    :param omega_total: (nx, nx) sum of all sensors' ``omega``, or (K, nx, nx) per row.
    :param theta_total: (K, nx) sum over sensors of ``theta`` per row.
    :returns: ``x`` (K, nx) and ``P`` (K, nx, nx).
    """
    Om = omega_total[:, None] if omega_total.ndim == 3 else omega_total[None]
    xs, Ps = batched_filter(Phi, Q, x0, P0, Om, theta_total[:, None, :])
    return xs[:, 0], Ps[:, 0]


@dataclass
class WindowState:
    """Ring buffers of the last ``L + 1`` rows for all nodes.

    Slot ``r % (L + 1)`` holds row ``r``: its information sums (``Omega``,
    ``Theta``, accumulated as contributions arrive), which origins each node
    holds (``held``), and the estimates last computed for it (``x``, ``P``,
    ``G``).  ``L + 1`` slots because the window of rows ``k-L .. k-1`` starts
    from the final estimate of row ``k-L-1``.
    """

    x: np.ndarray       # (S, n, nx)
    P: np.ndarray       # (S, n, nx, nx)
    G: np.ndarray       # (S, n, nx, nx)
    Omega: np.ndarray   # (S, n, nx, nx)
    Theta: np.ndarray   # (S, n, nx)
    held: np.ndarray    # (S, n, n_origins) bool: held[slot, i, o]

    @classmethod
    def empty(cls, L: int, n: int, nx: int, n_origins: int | None = None) -> "WindowState":
        S = L + 1
        n_origins = n if n_origins is None else n_origins
        return cls(
            x=np.zeros((S, n, nx)),
            P=np.zeros((S, n, nx, nx)),
            G=np.zeros((S, n, nx, nx)),
            Omega=np.zeros((S, n, nx, nx)),
            Theta=np.zeros((S, n, nx)),
            held=np.zeros((S, n, n_origins), dtype=bool),
        )

    def reset_slot(self, slot: int) -> None:
        self.Omega[slot] = 0.0
        self.Theta[slot] = 0.0
        self.held[slot] = False


class WindowFilter:
    """All nodes' buffered window filters (the anti-delay DKF's Step 1).

    The filter itself holds no network logic: the exchange protocol reports
    each contribution a node newly holds through :meth:`add`, and the tick
    driver calls :meth:`update` once per tick after every delivery at that
    instant.  ``update`` re-runs each node from its own earliest row that
    changed since the last tick (an optimisation docs/design.md §4 allows
    because the result is identical), batched over nodes, with the compiled
    kernel of :mod:`dkfsim.estimators.kernels` or in numpy.

    :param info: the :class:`~dkfsim.model.system.Information` of all sensors.
    :param A: (nodes, origins) effective origin weights ``a_io`` (ones for
        unit weights).  Usually nodes and origins are the same sensors; a
        fusion centre without sensors of its own is one node with n origins.
    """

    def __init__(self, Phi, Q, x0, P0, info, A, L, per_origin: bool = True):
        self.Phi = np.asarray(Phi, float)
        self.Q = np.asarray(Q, float)
        self.info = info            # dkfsim.model.system.Information
        self.theta = info.theta     # (K, n, nx)
        omega = info.omega
        self.A = np.asarray(A, float)
        self.L = int(L)
        # L + 1 slots, but never more than the run has rows (+1): with L >= K no
        # row ever wraps, so a huge L (a huge delay bound) costs no memory.
        self.S = min(self.L, self.theta.shape[0]) + 1
        n, nx = self.A.shape[0], omega.shape[-1]
        self.n, self.nx = n, nx
        # Which origins each node holds is needed by the fusion only: without it ``held`` has
        # no origin axis (a 1000-node window would otherwise carry S x 10^6 flags).
        self.state = WindowState.empty(self.S - 1, n, nx, n_origins=self.theta.shape[1] if per_origin else 0)
        self.x0 = np.broadcast_to(np.asarray(x0, float), (n, nx)).copy()
        self.P0 = np.broadcast_to(np.asarray(P0, float), (n, nx, nx)).copy()
        #: contributions reported since the last update: node, origin bitmask, row (flat)
        self._pend: list[int] = []
        #: each node's earliest row changed since the last update, written by the folds: this
        #: filter's own and an exchange's that folds into the ring itself (:mod:`dkfsim.protocols.tree_compiled`)
        self.starts_in = np.full(n, NO_ROW, dtype=np.int64)
        self._mask_words = -(-self.theta.shape[1] // 64)
        #: ``"numba"`` or ``"numpy"`` (:func:`dkfsim.estimators.kernels.kernel_path`)
        self.kernels = kernels.kernel_path()
        self._k = kernels.compiled() if self.kernels == "numba" else None
        st = self.state
        #: the ring as the kernels take it (:class:`dkfsim.estimators.kernels.Ring`)
        self.ring = kernels.Ring(st.x, st.P, st.G, st.Omega, st.Theta, st.held)
        self._model = kernels.Model(self.Phi, self.Q, self.x0, self.P0)
        omega = info.omega if info.varying else info.omega[None]
        self._fold = tree_compiled_kernels.Fold(self.A, omega, bool(info.varying), self.theta, st.Omega, st.Theta,
                                                st.held, self.starts_in)
        #: node-rows recomputed so far (the filtering work; tools/bench.py fits its cost)
        self.node_rows = 0

    # -- contributions -----------------------------------------------------
    def add(self, node: int, origin: int, row: int) -> None:
        """Node ``node`` now holds ``origin``'s contribution for ``row``."""
        self.add_mask(node, 1 << origin, row)

    def add_mask(self, node: int, origins: int, row: int) -> None:
        """Node ``node`` now holds the contributions of the origins set in the bitmask
        ``origins`` (a non-negative int, bit ``o`` for origin ``o``) for ``row``."""
        self._pend.extend((node, origins, row))

    def _pending_arrays(self):
        """The pending contributions as arrays: nodes, rows and the masks as
        little-endian 64-bit words (one row of ``words`` per contribution)."""
        pend, self._pend = self._pend, []
        return (np.array(pend[0::3], dtype=np.intp), np.array(pend[2::3], dtype=np.intp),
                mask_words(pend[1::3], self._mask_words))

    def _unpack(self):
        """The pending contributions as arrays ``(node, origin, row)``, in the order added
        (origins ascending within one mask)."""
        i, r, words = self._pending_arrays()
        k, o = set_bits(words)
        return i[k], o, r[k]

    def _apply_pending(self) -> np.ndarray | None:
        """Fold pending contributions into the ring; each node's earliest changed row
        (``n`` ints, a huge number for nodes without news), or None."""
        if self._pend:
            if self.kernels == "numba":
                # The bit walk lives with the compiled tree protocol, which folds the same way.
                i, r, words = self._pending_arrays()
                tree_compiled_kernels.compiled().fold_masks(i, r, words, self._fold)
            else:
                self._fold_numpy()
        starts = self.starts_in.copy()
        self.starts_in.fill(NO_ROW)           # in place: an exchange may hold a reference
        return None if starts.min() == NO_ROW else starts

    def _fold_numpy(self) -> None:
        """The pending contributions added to the ring in numpy (the order of :meth:`_unpack`)."""
        st = self.state
        i, o, r = self._unpack()
        slot = r % self.S
        a = self.A[i, o]
        if st.held.shape[2]:
            st.held[slot, i, o] = True
        np.add.at(st.Omega, (slot, i), a[:, None, None] * self.info.omega_of(r, o))
        np.add.at(st.Theta, (slot, i), a[:, None] * self.theta[r, o])
        np.minimum.at(self.starts_in, i, r)

    # -- the tick ------------------------------------------------------------
    def begin_row(self, row: int) -> None:
        """Clear the ring slot that ``row`` (a new row) will use."""
        self.state.reset_slot(row % self.S)

    def update(self, k: int, on_rows=None) -> int:
        """Run the window at tick ``k`` (1-based) for rows ``k-L .. k-1``.

        Each node re-runs from its own earliest row that changed since the
        last tick (the newest row ``k-1`` for all): a node whose holdings did
        not change keeps its estimates, which are what a re-run would give
        (docs/design.md §4).

        :param on_rows: optional callback ``on_rows(first, last, starts)`` after
            the rows ``first .. last`` were recomputed, node ``i`` from row
            ``starts[i]`` on (the fusion recursion hooks in here).
        :returns: the first row recomputed.
        """
        starts = self._apply_pending()
        last = k - 1
        lo = max(k - self.L, 0)
        if starts is None:
            starts = np.full(self.n, last, dtype=np.intp)
        else:
            np.minimum(starts, last, out=starts)
            np.maximum(starts, lo, out=starts)
        first = int(starts.min())
        self.node_rows += int((last + 1 - starts).sum())
        if self.kernels == "numba":
            self._k.window_rows(self._model, self.ring, starts, first, last)
        else:
            for row in range(first, last + 1):
                self._row_numpy(row, np.flatnonzero(starts <= row))
        if on_rows is not None:
            on_rows(first, last, starts)
        return first

    def _row_numpy(self, row: int, nodes: np.ndarray) -> None:
        """Recompute ``row`` for ``nodes`` with :func:`information_step` (the numpy path)."""
        st = self.state
        slot = row % self.S
        src = (self.x0, self.P0) if row == 0 else (st.x[(row - 1) % self.S], st.P[(row - 1) % self.S])
        if 2 * len(nodes) > self.n:       # numpy's cost is per call: recompute all nodes
            x, P, G = information_step(self.Phi, self.Q, src[0], src[1], st.Omega[slot], st.Theta[slot])
            st.x[slot], st.P[slot], st.G[slot] = x, P, G
            return
        x, P, G = information_step(self.Phi, self.Q, src[0][nodes], src[1][nodes],
                                   st.Omega[slot, nodes], st.Theta[slot, nodes])
        st.x[slot, nodes], st.P[slot, nodes], st.G[slot, nodes] = x, P, G

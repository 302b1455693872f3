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

from dkfsim.core.backend import Backend
from dkfsim.core.linalg import solve
from dkfsim.estimators import kernels
from dkfsim.model.holdings import Holdings


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


def _eye(nx: int) -> np.ndarray:
    """A cached identity: ``np.eye`` per row and node batch is measurable overhead."""
    eye = _EYES.get(nx)
    if eye is None:
        eye = _EYES[nx] = np.eye(nx)
        eye.setflags(write=False)
    return eye


def batched_filter(Phi, Q, x0, P0, Omega, Theta, backend: Backend | None = None):
    """``b`` independent information filters.

    :param Omega: (b, nx, nx) information added at every row, or (K, b, nx, nx) per row.
    :param Theta: (K, b, nx) information vectors per row.
    :param backend: the run's (``ctx.backend``); outside a run, what the environment asks for.
    :returns: ``x`` (K, b, nx) and ``P`` (K, b, nx, nx).
    """
    K, b, nx = Theta.shape
    xs = np.empty((K, b, nx))
    Ps = np.empty((K, b, nx, nx))
    x = np.broadcast_to(np.asarray(x0, float), (b, nx))
    P = np.broadcast_to(np.asarray(P0, float), (b, nx, nx))
    per_row = Omega.ndim == 4
    if (backend or Backend.from_environment()).compiled:     # one compiled call instead of K numpy steps
        # (copies: a broadcast of one filter is a read-only view, another compiled signature)
        model = kernels.Model(np.asarray(Phi, float), np.asarray(Q, float), np.array(x, order="C"),
                              np.array(P, order="C"))
        kernels.compiled().filter_rows(model, np.ascontiguousarray(Omega if per_row else Omega[None], float),
                                       per_row, np.ascontiguousarray(Theta, float), xs, Ps)
        return xs, Ps
    for r in range(K):
        x, P, _ = information_step(Phi, Q, x, P, Omega[r] if per_row else Omega, Theta[r])
        xs[r] = x
        Ps[r] = P
    return xs, Ps


def centralized_filter(Phi, Q, x0, P0, omega_total, theta_total, backend: Backend | None = None):
    """The centralized information filter that holds every contribution on time.

    :param omega_total: (nx, nx) sum of all sensors' ``omega``, or (K, nx, nx) per row.
    :param theta_total: (K, nx) sum over sensors of ``theta`` per row.
    :returns: ``x`` (K, nx) and ``P`` (K, nx, nx).
    """
    Om = omega_total[:, None] if omega_total.ndim == 3 else omega_total[None]
    xs, Ps = batched_filter(Phi, Q, x0, P0, Om, theta_total[:, None, :], backend)
    return xs[:, 0], Ps[:, 0]


@dataclass
class WindowState:
    """The estimates of the last ``L + 1`` rows for all nodes, slot ``r % S`` for row ``r``
    (the slots of the :class:`~dkfsim.model.holdings.Holdings` the window reads): ``x``,
    ``P`` and the gain ``G = P Pp^-1`` last computed for each node.  ``L + 1`` slots because
    the window of rows ``k-L .. k-1`` starts from the final estimate of row ``k-L-1``.
    """

    x: np.ndarray       # (S, n, nx)
    P: np.ndarray       # (S, n, nx, nx)
    G: np.ndarray       # (S, n, nx, nx)

    @classmethod
    def empty(cls, S: int, n: int, nx: int) -> "WindowState":
        return cls(x=np.zeros((S, n, nx)), P=np.zeros((S, n, nx, nx)), G=np.zeros((S, n, nx, nx)))


class WindowFilter:
    """All nodes' buffered window filters (the anti-delay DKF's Step 1).

    The filter holds no network logic and no bookkeeping of who holds what: it reads the
    :class:`~dkfsim.model.holdings.Holdings` an exchange protocol fills, and the tick
    driver calls :meth:`update` once per tick after every delivery at that instant.
    ``update`` re-runs each node from its own earliest row that changed since the last tick
    (an optimisation docs/design.md §4 allows because the result is identical), batched over
    nodes, with the compiled kernel of :mod:`dkfsim.estimators.kernels` or in numpy, as the
    run's :class:`~dkfsim.core.backend.Backend` says.

    :param holdings: the contributions each node holds and their sums (its ``info``, weights
        ``A`` (nodes, origins) and ring of ``S`` slots are the filter's).  Usually nodes and
        origins are the same sensors; a fusion centre without sensors of its own is one node
        with n origins.
    """

    def __init__(self, Phi, Q, x0, P0, holdings: Holdings, backend: Backend):
        self.Phi = np.asarray(Phi, float)
        self.Q = np.asarray(Q, float)
        self.holdings = holdings
        self.info = holdings.info    # dkfsim.model.system.Information
        self.A = holdings.A
        self.L, self.S = holdings.L, holdings.S
        n, nx = holdings.n, holdings.nx
        self.n, self.nx = n, nx
        self.state = WindowState.empty(self.S, n, nx)
        self.x0 = np.broadcast_to(np.asarray(x0, float), (n, nx)).copy()
        self.P0 = np.broadcast_to(np.asarray(P0, float), (n, nx, nx)).copy()
        self.backend = backend
        #: the compiled kernels (:mod:`dkfsim.estimators.kernels`), None on the numpy path
        self.kernels = kernels.compiled() if backend.compiled else None
        st, h = self.state, holdings
        #: the ring as the kernels take it (:class:`dkfsim.estimators.kernels.Ring`)
        self.ring = kernels.Ring(st.x, st.P, st.G, h.Omega, h.Theta, h.held)
        self._model = kernels.Model(self.Phi, self.Q, self.x0, self.P0)
        #: node-rows recomputed so far (the filtering work; tools/bench.py fits its cost)
        self.node_rows = 0
        #: rows recomputed so far, for any node (what a fusion hooked in ``on_rows`` redoes)
        self.rows_run = 0

    # -- the tick ------------------------------------------------------------
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
        starts = self.holdings.take_changes()
        last = k - 1
        lo = max(k - self.L, 0)
        if starts is None:
            starts = np.full(self.n, last, dtype=np.intp)
        else:
            np.minimum(starts, last, out=starts)
            np.maximum(starts, lo, out=starts)
        first = int(starts.min())
        self.node_rows += int((last + 1 - starts).sum())
        self.rows_run += last + 1 - first
        if self.kernels is not None:
            self.kernels.window_rows(self._model, self.ring, starts, first, last)
        else:
            for row in range(first, last + 1):
                self._row_numpy(row, np.flatnonzero(starts <= row))
        if on_rows is not None:
            on_rows(first, last, starts)
        return first

    def _row_numpy(self, row: int, nodes: np.ndarray) -> None:
        """Recompute ``row`` for ``nodes`` with :func:`information_step` (the numpy path)."""
        st, h = self.state, self.holdings
        slot = row % self.S
        src = (self.x0, self.P0) if row == 0 else (st.x[(row - 1) % self.S], st.P[(row - 1) % self.S])
        if 2 * len(nodes) > self.n:       # numpy's cost is per call: recompute all nodes
            x, P, G = information_step(self.Phi, self.Q, src[0], src[1], h.Omega[slot], h.Theta[slot])
            st.x[slot], st.P[slot], st.G[slot] = x, P, G
            return
        x, P, G = information_step(self.Phi, self.Q, src[0][nodes], src[1][nodes],
                                   h.Omega[slot, nodes], h.Theta[slot, nodes])
        st.x[slot, nodes], st.P[slot, nodes], st.G[slot, nodes] = x, P, G

"""Optimal matrix-weighted fusion of the local estimates (paper Step 2).

Two pieces:

* :class:`CrossCovariance` keeps the true error cross-covariances
  ``Xi = [C_ij]`` of all nodes' estimates with the exact recursion of
  docs/design.md §7, written for all pairs at once::

      C_ij = G_i (Phi C_ij Phi' + Q) G_j' + P_i (sum_m a_im a_jm omega_m) P_j

  with ``G_i = P_i Pp_i^-1``.  As dense ``(n nx) x (n nx)`` matrices this is
  ``Xi = F Xi F' + Y Y'`` with ``F = blockdiag(G_i Phi)`` and
  ``Y = [G E Lq | P V]`` (``Lq Lq' = Q``, ``E`` stacks identities, ``V`` the
  held omega factors ``a_im U_m``), i.e. three BLAS products per row instead
  of n^2 small ones.  Only the block rows and columns of the nodes the
  window filter recomputed change (``F`` is block-diagonal): those are
  computed, with the compiled kernel of :mod:`dkfsim.estimators.kernels` or
  with batched numpy products.  The paper's ``(I - K_i H_i)(...)(I - K_j H_j)`` form is
  not used: it has no term for measurements both nodes hold.
* :func:`fuse_matrix` / :func:`fuse_diagonal` turn ``Xi`` and the local
  estimates into the fused estimate (Sun & Deng 2004; the paper's eq.
  (matrix_weighted) and its Remark's per-component variant).
"""

from __future__ import annotations

import numpy as np

from dkfsim.core.linalg import solve_posdef, solve_symmetric
from dkfsim.estimators import kernels
from dkfsim.model.system import psd_factor

#: The regularisation when ``tr(Xi) = 0`` (every estimate exact, e.g. ``Phi = 0, Q = 0``): the
#: relative ``delta`` would be 0 and ``X`` singular (NaN weights); any positive value gives the
#: mean of the estimates, exact here.
EXACT_DELTA = 1.0


def kkt_weights(Xi: np.ndarray, n: int, nx: int) -> np.ndarray:
    """Weights ``Gamma`` (n*nx, nx) minimising ``tr(Gamma' Xi Gamma)`` s.t. ``sum_i Gamma_i = I``.

    ``Xi`` is singular whenever two nodes hold the same information (always
    at zero latency), so we solve the KKT system with the reproducible
    regularisation ``X = Xi + delta I``, ``delta = 1e-8 tr(Xi) / (n nx)``
    (docs/design.md §7), or :data:`EXACT_DELTA` when that is 0 (``Xi = 0``: exact
    estimates).  ``X`` is positive definite, so the KKT system is solved by eliminating
    the constraint: ``Z = X^-1 E`` (Cholesky),
    ``Gamma = Z (E' Z)^-1``, the same solution at half the cost of a solve
    of the whole indefinite system; that solve (LAPACK ``dsysv``) remains
    for an ``X`` that Cholesky refuses (non-finite, or an ``Xi`` too
    indefinite for ``delta`` to fix).
    """
    N = n * nx
    X = np.array(Xi, dtype=float, order="C")
    diag = X.reshape(-1)[::N + 1]
    delta = 1e-8 * diag.sum() / N
    if delta == 0.0:
        # tr Xi = 0: every local estimate is exact (Phi = 0, Q = 0); any delta gives the
        # mean of them, and 1 keeps X = I well scaled.  Only here: other runs are unchanged.
        delta = EXACT_DELTA
    diag += delta
    E = _stacked_identities(n, nx)
    Z = solve_posdef(X.T, E, overwrite_a=True)       # X symmetric: X.T is its Fortran view
    if Z is not None:
        Sm = Z.reshape(n, nx, nx).sum(axis=0)          # E' X^-1 E, positive definite too
        Gt = solve_posdef(Sm, Z.T)
        if Gt is not None:
            return Gt.T
    K, rhs = _kkt_template(n, nx)
    K = K.copy()
    K[:N, :N] = Xi
    K.reshape(-1)[:N * (N + nx + 1):N + nx + 1] += delta
    sol = solve_symmetric(K, rhs)
    return sol[:N]


_E: dict[tuple[int, int], np.ndarray] = {}


def _stacked_identities(n: int, nx: int) -> np.ndarray:
    """``E``: n identities (nx, nx) stacked, Fortran-ordered for LAPACK, cached."""
    E = _E.get((n, nx))
    if E is None:
        E = _E[(n, nx)] = np.asfortranarray(np.tile(np.eye(nx), (n, 1)))
        E.setflags(write=False)
    return E


_KKT: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = {}


def _kkt_template(n: int, nx: int):
    """The constant parts of the KKT system (the constraint blocks and right-hand side), cached."""
    got = _KKT.get((n, nx))
    if got is None:
        N = n * nx
        K = np.zeros((N + nx, N + nx))
        E = _stacked_identities(n, nx)
        K[:N, N:] = E
        K[N:, :N] = E.T
        rhs = np.zeros((N + nx, nx))
        rhs[N:] = np.eye(nx)
        K.setflags(write=False)
        rhs.setflags(write=False)
        got = _KKT[(n, nx)] = (K, rhs)
    return got


def fuse_matrix(Xi: np.ndarray, x: np.ndarray):
    """Optimal matrix-weighted fusion.

    :param Xi: (n*nx, n*nx) cross-covariances; :param x: (n, nx) local estimates.
    :returns: ``x_f = Gamma' x_stack`` and ``P_f = Gamma' Xi Gamma`` (unregularised Xi).
    """
    n, nx = x.shape
    Gamma = kkt_weights(Xi, n, nx)
    xf = Gamma.T @ x.reshape(-1)
    Pf = Gamma.T @ Xi @ Gamma
    return xf, 0.5 * (Pf + Pf.T)


def fuse_diagonal(Xi: np.ndarray, x: np.ndarray):
    """Per-component scalar weights (the paper's cheaper variant).

    Component ``c`` is fused with the weights that are optimal for the
    ``n x n`` matrix of the ``(c, c)`` entries of all ``C_ij``; the returned
    ``P_f`` is the true covariance of that estimate, computed with the full
    ``Xi`` (the paper's Remark after Theorem 1).
    """
    n, nx = x.shape
    Gamma = np.zeros((n * nx, nx))
    for c in range(nx):
        idx = np.arange(n) * nx + c
        w = kkt_weights(Xi[np.ix_(idx, idx)], n, 1)[:, 0]
        Gamma[idx, c] = w
    xf = Gamma.T @ x.reshape(-1)
    Pf = Gamma.T @ Xi @ Gamma
    return xf, 0.5 * (Pf + Pf.T)


FUSERS = {"matrix": fuse_matrix, "diagonal": fuse_diagonal}


class CrossCovariance:
    """The ring of ``Xi`` matrices that follows a :class:`~dkfsim.estimators.window.WindowFilter`.

    Hook :meth:`on_row` into ``WindowFilter.update``; it recomputes ``Xi`` for
    exactly the rows the filter recomputed, from the same ring slots.
    """

    def __init__(self, window, P0):
        self.w = window
        n, nx = window.n, window.nx
        self.n, self.nx, self.N = n, nx, n * nx
        self.Xi = np.zeros((window.S, self.N, self.N))
        self.Xi0 = np.kron(np.ones((n, n)), np.asarray(P0, float))
        self.Lq = psd_factor(window.Q)
        self.info = window.info          # factor U per row and the sensor of each column
        self._F = np.zeros((n, nx, n, nx))
        self._diag = np.arange(n)
        self._column_sensor = np.ascontiguousarray(self.info.column_sensor, dtype=np.intp)
        #: all weights one: the compiled path may sum the shared-measurement term over
        #: the columns a node misses (kernels.xi_rows)
        self._unit = bool((window.A == 1.0).all())
        info = self.info
        self._cross = kernels.Cross(self.Xi, self.Xi0, window.A, self._unit, self._column_sensor,
                                    info.factor if info.varying else info.factor[None], bool(info.varying),
                                    window.Phi, self.Lq)

    def on_rows(self, first: int, last: int, starts: np.ndarray) -> None:
        """Recompute ``Xi`` of rows ``first .. last``; node ``i``'s blocks from row ``starts[i]``.

        The hook of :meth:`WindowFilter.update
        <dkfsim.estimators.window.WindowFilter.update>`, called after the
        filter recomputed those rows.
        """
        w = self.w
        if w.kernels is not None:
            w.kernels.xi_rows(self._cross, w.ring, starts, first, last, (0,) * self.nx)
            return
        order = np.sort(starts)
        for row in range(first, last + 1):
            # numpy's cost is per call: the dense product unless few nodes changed.
            many = 2 * int(np.searchsorted(order, row, side="right")) > self.n
            self.on_row(row, row % w.S, None if row == 0 else (row - 1) % w.S,
                        None if many else np.flatnonzero(starts <= row))

    def on_row(self, row: int, slot: int, prev: int | None, nodes: np.ndarray | None = None) -> None:
        """Recompute ``Xi`` of ``row`` for the blocks of ``nodes`` (all when None), in numpy."""
        st, n, nx, N = self.w.state, self.n, self.nx, self.N
        Xi_prev = self.Xi0 if prev is None else self.Xi[prev]
        G, P = st.G[slot], st.P[slot]
        F = G @ self.w.Phi                                   # (n, nx, nx): the blocks of F
        # Weights of each measurement column at each node: a_im if held, else 0.
        a_held = (self.w.A * self.w.holdings.held[slot])[:, self.info.column_sensor]   # (n, M)
        Z = P @ (self.info.factor_row(row)[None, :, :] * a_held[:, None, :])  # (n, nx, M)
        Y = np.concatenate([(G @ self.Lq).reshape(N, nx), Z.reshape(N, -1)], axis=1)
        Xi = self.Xi[slot]
        if nodes is None:
            Fd = self._F
            Fd[self._diag, :, self._diag, :] = F
            Fd = Fd.reshape(N, N)
            new = Fd @ Xi_prev @ Fd.T
            new += Y @ Y.T
            Xi[...] = new
            Xi += new.T
            Xi *= 0.5
            return
        na = len(nodes)
        Ya = Y.reshape(n, nx, -1)[nodes].reshape(na * nx, -1)
        YY = Ya @ Y.T                                        # block rows of Y Y' of ``nodes``
        # The block rows F_i C_i. F' of ``nodes``, then mirrored.
        R = F[nodes] @ Xi_prev.reshape(n, nx, N)[nodes]      # (na, nx, N)
        R = R.reshape(na * nx, n, nx).transpose(1, 0, 2) @ F.transpose(0, 2, 1)   # (n, na nx, nx)
        R = R.transpose(1, 0, 2).reshape(na * nx, N)
        R += YY
        sel = (nodes[:, None] * nx + np.arange(nx)).reshape(-1)
        Xi[sel, :] = R
        Xi[:, sel] = R.T
        sub = R[:, sel]
        Xi[np.ix_(sel, sel)] = 0.5 * (sub + sub.T)

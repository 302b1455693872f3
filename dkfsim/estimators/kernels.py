"""Compiled kernels (numba) for the window filter and the cross-covariance recursion.

The anti-delay DKF spends its time in small dense loops: a 3x3 predict/update
per node and window row, and ``F_i C_ij F_j'`` per pair of nodes.  Numpy pays
a call per row for those; these kernels run a whole tick's rows in one call.
They compute exactly what :func:`dkfsim.estimators.window.information_step`
and :class:`dkfsim.estimators.fusion.CrossCovariance` compute in numpy (the
same formulas, only the summation order differs), without ``fastmath`` and
single-threaded, so each path is bit-identical run to run.

Which path runs: numba when it is installed, unless the environment variable
``DKFSIM_KERNELS=numpy`` forces the pure-numpy path (the fallback on
platforms without numba, tested against the compiled one).  Compiled kernels
are cached on disk (``cache=True``): the first call on a machine compiles them
once (about 9 s of CPU); later processes load them (about 0.4 s).  See
docs/design.md §4 ("Kernel paths").
"""

from __future__ import annotations

import numpy as np

from dkfsim.core.jit import KERNELS_ENV, LazyKernels, kernel_path  # noqa: F401  (re-exported)

#: The kernels, callees before callers (numba resolves a callee by its module global).
_KERNELS = ("_step", "xi_blocks", "window_rows", "xi_rows", "filter_rows")
_lazy = LazyKernels(__name__, _KERNELS)


def compiled():
    """This module with its kernels compiled (``numba.njit(cache=True)``, no fastmath, no
    parallel): numba is imported, and the kernels loaded from the disk cache or compiled,
    on the first call (:class:`dkfsim.core.jit.LazyKernels`)."""
    return _lazy.get()


def _step(Phi, Q, xprev, Pprev, Om, Th, x_out, P_out, G_out, Pp, M, rhs):
    """One information-form predict/update of one node (see window.information_step)."""
    nx = Phi.shape[0]
    # Pp = Phi Pprev Phi' + Q  (M used as scratch for Phi Pprev)
    for a in range(nx):
        for b in range(nx):
            s = 0.0
            for c in range(nx):
                s += Phi[a, c] * Pprev[c, b]
            M[a, b] = s
    for a in range(nx):
        for b in range(nx):
            s = 0.0
            for c in range(nx):
                s += M[a, c] * Phi[b, c]
            Pp[a, b] = s + Q[a, b]
    # rhs = [I | Pp Theta + Phi xprev],  M = I + Pp Omega
    for a in range(nx):
        s = 0.0
        t = 0.0
        for c in range(nx):
            s += Pp[a, c] * Th[c]
            t += Phi[a, c] * xprev[c]
        for b in range(nx):
            rhs[a, b] = 1.0 if a == b else 0.0
        rhs[a, nx] = s + t
        for b in range(nx):
            u = 0.0
            for c in range(nx):
                u += Pp[a, c] * Om[c, b]
            M[a, b] = u + (1.0 if a == b else 0.0)
    # Gaussian elimination with partial pivoting (LAPACK getrf's pivot rule).
    ok = True
    for c in range(nx):
        p = c
        best = abs(M[c, c])
        for r in range(c + 1, nx):
            v = abs(M[r, c])
            if v > best:
                best = v
                p = r
        if not best > 0.0:             # singular (or NaN): this node's row is NaN
            ok = False
            break
        if p != c:
            for b in range(nx):
                M[c, b], M[p, b] = M[p, b], M[c, b]
            for b in range(nx + 1):
                rhs[c, b], rhs[p, b] = rhs[p, b], rhs[c, b]
        piv = M[c, c]
        for r in range(c + 1, nx):
            f = M[r, c] / piv
            if f != 0.0:
                for b in range(c + 1, nx):
                    M[r, b] -= f * M[c, b]
                for b in range(nx + 1):
                    rhs[r, b] -= f * rhs[c, b]
    if not ok:
        for a in range(nx):
            x_out[a] = np.nan
            for b in range(nx):
                P_out[a, b] = np.nan
                G_out[a, b] = np.nan
        return
    for c in range(nx - 1, -1, -1):
        piv = M[c, c]
        for b in range(nx + 1):
            s = rhs[c, b]
            for r in range(c + 1, nx):
                s -= M[c, r] * rhs[r, b]
            rhs[c, b] = s / piv
    for a in range(nx):
        x_out[a] = rhs[a, nx]
        for b in range(nx):
            G_out[a, b] = rhs[a, b]
    # P = G Pp, symmetrized
    for a in range(nx):
        for b in range(nx):
            s = 0.0
            for c in range(nx):
                s += rhs[a, c] * Pp[c, b]
            M[a, b] = s
    for a in range(nx):
        for b in range(nx):
            P_out[a, b] = 0.5 * (M[a, b] + M[b, a])


def window_rows(Phi, Q, x0, P0, X, P, G, Omega, Theta, starts, first, last):
    """Re-run rows ``first .. last`` of the ring; node ``i`` from row ``starts[i]`` on.

    ``X, P, G, Omega, Theta`` are the ring arrays of
    :class:`~dkfsim.estimators.window.WindowState` (slot ``row % S``); row 0
    starts from ``x0, P0`` (per node).
    """
    S, n, nx = X.shape
    Pp = np.empty((nx, nx))
    M = np.empty((nx, nx))
    rhs = np.empty((nx, nx + 1))
    for row in range(first, last + 1):
        slot = row % S
        prev = (row - 1) % S
        for i in range(n):
            if starts[i] > row:
                continue
            if row == 0:
                _step(Phi, Q, x0[i], P0[i], Omega[slot, i], Theta[slot, i],
                      X[slot, i], P[slot, i], G[slot, i], Pp, M, rhs)
            else:
                _step(Phi, Q, X[prev, i], P[prev, i], Omega[slot, i], Theta[slot, i],
                      X[slot, i], P[slot, i], G[slot, i], Pp, M, rhs)


def xi_blocks(Xi_prev, Xi, F, YY, nodes, active):
    """``C_ij = F_i C_ij(prev) F_j' + (Y Y')_ij`` for every block with ``i`` or ``j`` in ``nodes``.

    ``YY`` holds the block rows of ``Y Y'`` of ``nodes`` (in that order),
    ``active`` flags them; other blocks of ``Xi`` are left as they are (they did
    not change).  Each pair is computed once and mirrored; diagonal blocks are
    symmetrized.
    """
    n, nx = F.shape[0], F.shape[1]
    T = np.empty((nx, nx))
    for ai in range(nodes.shape[0]):
        i = nodes[ai]
        i0 = i * nx
        r0 = ai * nx
        for j in range(n):
            if active[j] and j < i:
                continue
            j0 = j * nx
            for a in range(nx):
                for b in range(nx):
                    s = 0.0
                    for c in range(nx):
                        s += F[i, a, c] * Xi_prev[i0 + c, j0 + b]
                    T[a, b] = s
            for a in range(nx):
                for b in range(nx):
                    s = 0.0
                    for c in range(nx):
                        s += T[a, c] * F[j, b, c]
                    Xi[i0 + a, j0 + b] = s + YY[r0 + a, j0 + b]
            if i == j:
                for a in range(nx):
                    for b in range(a + 1, nx):
                        v = 0.5 * (Xi[i0 + a, i0 + b] + Xi[i0 + b, i0 + a])
                        Xi[i0 + a, i0 + b] = v
                        Xi[i0 + b, i0 + a] = v
            else:
                for a in range(nx):
                    for b in range(nx):
                        Xi[j0 + b, i0 + a] = Xi[i0 + a, j0 + b]


def xi_rows(Xi, Xi0, G, P, held, A, column_sensor, factor, varying, Phi, Lq, starts, first, last):
    """The cross-covariance recursion for rows ``first .. last`` (see fusion.CrossCovariance).

    ``Xi`` is the ring (S, N, N), ``G, P, held`` the window filter's ring
    arrays, ``factor`` the measurement factor ``U`` (1, nx, M), or (K, nx, M)
    when ``varying``.  Node ``i``'s block row and column change from row
    ``starts[i]`` on; the rest of each row's ``Xi`` is left as it is.
    """
    S, n, nx = G.shape[0], G.shape[1], G.shape[2]
    N = n * nx
    M = factor.shape[2]
    W = nx + M
    F = np.empty((n, nx, nx))
    Y = np.empty((N, W))
    active = np.empty(n, dtype=np.bool_)
    nodes = np.empty(n, dtype=np.int64)
    wcol = np.empty(M)
    for row in range(first, last + 1):
        slot = row % S
        U = factor[row if varying else 0]
        na = 0
        for i in range(n):
            active[i] = starts[i] <= row
            if active[i]:
                nodes[na] = i
                na += 1
        for i in range(n):
            Gi = G[slot, i]
            Pi = P[slot, i]
            for a in range(nx):
                for b in range(nx):
                    s = 0.0
                    t = 0.0
                    for c in range(nx):
                        s += Gi[a, c] * Phi[c, b]
                        t += Gi[a, c] * Lq[c, b]
                    F[i, a, b] = s
                    Y[i * nx + a, b] = t
            for m in range(M):
                o = column_sensor[m]
                wcol[m] = A[i, o] if held[slot, i, o] else 0.0
            for a in range(nx):
                for m in range(M):
                    s = 0.0
                    if wcol[m] != 0.0:
                        for c in range(nx):
                            s += Pi[a, c] * U[c, m]
                        s *= wcol[m]
                    Y[i * nx + a, nx + m] = s
        Ya = np.empty((na * nx, W))
        for ai in range(na):
            i = nodes[ai]
            for a in range(nx):
                for b in range(W):
                    Ya[ai * nx + a, b] = Y[i * nx + a, b]
        YY = np.dot(Ya, Y.T)
        Xi_prev = Xi0 if row == 0 else Xi[(row - 1) % S]
        xi_blocks(Xi_prev, Xi[slot], F, YY, nodes[:na], active)


def filter_rows(Phi, Q, x0, P0, Omega, per_row, Theta, xs, Ps):
    """``b`` independent information filters over ``K`` rows (see window.batched_filter):
    ``Omega`` (1 or K, b, nx, nx), ``Theta`` (K, b, nx); results into ``xs``, ``Ps``."""
    K, b, nx = Theta.shape
    Pp = np.empty((nx, nx))
    M = np.empty((nx, nx))
    G = np.empty((nx, nx))
    rhs = np.empty((nx, nx + 1))
    for r in range(K):
        Om = Omega[r] if per_row else Omega[0]
        for i in range(b):
            if r == 0:
                _step(Phi, Q, x0[i], P0[i], Om[i], Theta[r, i], xs[r, i], Ps[r, i], G, Pp, M, rhs)
            else:
                _step(Phi, Q, xs[r - 1, i], Ps[r - 1, i], Om[i], Theta[r, i], xs[r, i], Ps[r, i], G, Pp, M, rhs)

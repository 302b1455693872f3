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
once (about 20 s of CPU with the compiled tree's); later processes load them.  See
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


def xi_blocks(Xi_prev, Xi, i, F_i, Ft, Y1, sel, E, Y2, R, Out, T):
    """Block row ``i`` of one row's ``Xi`` (node ``i`` re-ran the row).

    ``C_ij = F_i C_ij(prev) F_j' + sum_e Y1[e, a] Y2[sel[e], b n + j]`` for
    every ``j`` (``e < E``; the ``Q`` and shared-measurement terms, see
    :func:`xi_rows`), with ``Ft[b, d, j] = F_j[b, d]``.  Everything but the
    reading of ``C_i.(prev)`` and the writing of the block row runs over
    ``j`` innermost, contiguous and without reductions, so it vectorises
    without fastmath; ``R, Out`` (nx, nx, n) are scratch.  The diagonal block
    is symmetrized; :func:`xi_rows` makes the whole matrix symmetric once all
    active nodes are done.
    """
    nx, n = len(T), Ft.shape[2]
    i0 = i * nx
    # R[a, d, j] = (F_i C_ij(prev))[a, d]
    for j in range(n):
        j0 = j * nx
        for a in range(nx):
            for d in range(nx):
                s = 0.0
                for c in range(nx):
                    s += F_i[a, c] * Xi_prev[i0 + c, j0 + d]
                R[a, d, j] = s
    Outf = Out.reshape(nx, nx * n)
    for q in range(nx * n):
        for a in range(nx):
            Outf[a, q] = 0.0
    for e in range(E):
        y = Y2[sel[e]]
        for a in range(nx):
            g = Y1[e, a]
            if g != 0.0:
                o = Outf[a]
                for q in range(nx * n):
                    o[q] += g * y[q]
    for a in range(nx):
        for b in range(nx):
            for d in range(nx):
                for j in range(n):
                    Out[a, b, j] += R[a, d, j] * Ft[b, d, j]
    for a in range(nx):
        for b in range(nx):
            for j in range(n):
                Xi[i0 + a, j * nx + b] = Out[a, b, j]
    for a in range(nx):
        for b in range(nx):
            Xi[i0 + a, i0 + b] = 0.5 * (Out[a, b, i] + Out[b, a, i])


def xi_rows(Xi, Xi0, G, P, held, A, unit, column_sensor, factor, varying, Phi, Lq, starts, first, last, T):
    """The cross-covariance recursion for rows ``first .. last`` (see fusion.CrossCovariance).

    ``Xi`` is the ring (S, N, N), ``G, P, held`` the window filter's ring
    arrays, ``factor`` the measurement factor ``U`` (1, nx, M), or (K, nx, M)
    when ``varying``.  Node ``i``'s block row and column change from row
    ``starts[i]`` on; the rest of each row's ``Xi`` is left as it is.  ``T``
    is a tuple of ``nx`` zeros: its length is a compile-time constant, so the
    loops over the state's components unroll (each ``nx`` compiles once).

    The shared-measurement term ``P_i S_ij P_j``, ``S_ij = sum_m a_im a_jm
    h_im h_jm u_m u_m'`` (``h`` the held flags, ``u_m`` column ``m`` of ``U``),
    is summed over the columns node ``i`` holds (``direct``), or, when all
    weights are one (``unit``) and ``i`` misses fewer columns than it holds,
    over the columns it misses::

        S_ij = Omega_tot - MO_i - MO_j + sum_{m missed by i and j} u_m u_m',
        MO_i = sum_{m missed by i} u_m u_m',    Omega_tot = U U'

    (docs/design.md §7).  Late in the window most nodes hold almost
    everything, early in it almost nothing: either sum is short.  Each term
    is a coefficient (``Y1``, per node ``i``) times a row of ``Y2`` over
    ``(b, j)`` (index ``b n + j``): rows ``0..nx``: ``(G_j Lq)[b, d]``;
    ``nx..2nx``: ``P_j[d, b]``; ``2nx..3nx``: ``(MO_j P_j)[d, b]``; then
    ``(P_j u_m)[b]`` times ``missed_jm`` (``M`` rows) and times ``a_jm h_jm``
    (``M`` rows).
    """
    S, n, nx = G.shape[0], G.shape[1], len(T)
    N = n * nx
    M = factor.shape[2]
    Ft = np.empty((nx, nx, n))
    PU = np.empty((M, N))              # (P_j u_m)[b] at [m, b n + j]
    Y2 = np.empty((3 * nx + 2 * M, N))
    Y1 = np.empty((3 * nx + M, nx))
    sel = np.empty(3 * nx + M, dtype=np.int64)
    R = np.empty((nx, nx, n))
    Out = np.empty((nx, nx, n))
    F_i = np.empty((nx, nx))
    Ot = np.empty((nx, nx))
    active = np.empty(n, dtype=np.bool_)
    comp = np.empty(n, dtype=np.bool_)
    wj = np.empty(n)
    MO = np.empty((nx, nx, n))
    hc = np.empty((M, n))
    cnt = np.empty(n)
    need_c = np.empty(M, dtype=np.bool_)
    need_d = np.empty(M, dtype=np.bool_)
    act = np.empty(n, dtype=np.int64)
    P2, D2, ZC, ZD = nx, 2 * nx, 3 * nx, 3 * nx + M
    for row in range(first, last + 1):
        slot = row % S
        U = factor[row if varying else 0]
        hs = held[slot]
        na = 0
        for i in range(n):
            active[i] = starts[i] <= row
            if active[i]:
                act[na] = i
                na += 1
        if na == 0:
            continue
        # hc[m, j]: node j holds column m (its origin), as 0/1; its count per node
        for m in range(M):
            o = column_sensor[m]
            for j in range(n):
                hc[m, j] = 1.0 if hs[j, o] else 0.0
        for j in range(n):
            cnt[j] = 0.0
        for m in range(M):
            for j in range(n):
                cnt[j] += hc[m, j]
        n_direct = 0
        n_comp = 0
        for k in range(na):
            i = act[k]
            comp[i] = unit and M - cnt[i] + 2 * nx < cnt[i]
            if comp[i]:
                n_comp += 1
            else:
                n_direct += 1
        if na == 0:
            continue
        Gs = G[slot]
        Ps = P[slot]
        for j in range(n):
            for a in range(nx):
                for b in range(nx):
                    s = 0.0
                    t = 0.0
                    for c in range(nx):
                        s += Gs[j, a, c] * Phi[c, b]
                        t += Gs[j, a, c] * Lq[c, b]
                    Ft[a, b, j] = s
                    Y2[b, a * n + j] = t
                    Y2[P2 + a, b * n + j] = Ps[j, a, b]
        # Which columns m the active nodes' sums need: missed by a complement node
        # (rows ZC), held by a direct one (rows ZD).
        for m in range(M):
            need_c[m] = False
            need_d[m] = False
            for k in range(na):
                i = act[k]
                if comp[i]:
                    if hc[m, i] == 0.0:
                        need_c[m] = True
                elif hc[m, i] != 0.0:
                    need_d[m] = True
        # PU[m, b n + j] = sum_d P_j[d, b] U[d, m]
        for m in range(M):
            if not (need_c[m] or need_d[m]):
                continue
            u = U[0, m]
            for q in range(N):
                PU[m, q] = Y2[P2, q] * u
            for d in range(1, nx):
                u = U[d, m]
                for q in range(N):
                    PU[m, q] += Y2[P2 + d, q] * u
            o = column_sensor[m]
            if need_c[m]:
                for j in range(n):
                    wj[j] = 1.0 - hc[m, j]
                for b in range(nx):
                    for j in range(n):
                        Y2[ZC + m, b * n + j] = wj[j] * PU[m, b * n + j]
            if need_d[m]:
                for j in range(n):
                    wj[j] = A[j, o] * hc[m, j]
                for b in range(nx):
                    for j in range(n):
                        Y2[ZD + m, b * n + j] = wj[j] * PU[m, b * n + j]
        if n_comp > 0:
            # Ot = U U';  (MO_j P_j)[d, b] at Y2[D2 + d, b n + j]
            for a in range(nx):
                for b in range(nx):
                    s = 0.0
                    for m in range(M):
                        s += U[a, m] * U[b, m]
                    Ot[a, b] = s
            # MO[a, c, j] = sum over the columns j misses of U[a, m] U[c, m]
            for a in range(nx):
                for c in range(nx):
                    for j in range(n):
                        MO[a, c, j] = 0.0
            for m in range(M):
                for j in range(n):
                    wj[j] = 1.0 - hc[m, j]
                for a in range(nx):
                    for c in range(nx):
                        uu = U[a, m] * U[c, m]
                        if uu != 0.0:
                            for j in range(n):
                                MO[a, c, j] += uu * wj[j]
            for d in range(nx):
                for b in range(nx):
                    q = b * n
                    for j in range(n):
                        Y2[D2 + d, q + j] = MO[d, 0, j] * Y2[P2, q + j]
                    for c in range(1, nx):
                        for j in range(n):
                            Y2[D2 + d, q + j] += MO[d, c, j] * Y2[P2 + c, q + j]
        Xi_prev = Xi0 if row == 0 else Xi[(row - 1) % S]
        Xs = Xi[slot]
        for i in range(n):
            if not active[i]:
                continue
            for a in range(nx):
                for c in range(nx):
                    F_i[a, c] = Ft[a, c, i]
            # (G_i Lq)(G_j Lq)'
            E = 0
            for d in range(nx):
                for a in range(nx):
                    Y1[E, a] = Y2[d, a * n + i]
                sel[E] = d
                E += 1
            if comp[i]:
                # (P_i Omega_tot - (MO_i P_i)') P_j - P_i (MO_j P_j) + sum_{m missed by i} (P_i u_m) Z_m'
                for d in range(nx):
                    for a in range(nx):
                        s = 0.0
                        for c in range(nx):
                            s += Ps[i, a, c] * Ot[c, d]
                        Y1[E, a] = s - Y2[D2 + d, a * n + i]
                        Y1[E + 1, a] = -Ps[i, a, d]
                    sel[E] = P2 + d
                    sel[E + 1] = D2 + d
                    E += 2
                for m in range(M):
                    if hc[m, i] == 0.0:
                        for a in range(nx):
                            Y1[E, a] = PU[m, a * n + i]
                        sel[E] = ZC + m
                        E += 1
            else:
                for m in range(M):
                    w = A[i, column_sensor[m]] * hc[m, i]
                    if w != 0.0:
                        for a in range(nx):
                            Y1[E, a] = w * PU[m, a * n + i]
                        sel[E] = ZD + m
                        E += 1
            xi_blocks(Xi_prev, Xs, i, F_i, Ft, Y1, sel, E, Y2, R, Out, T)
        # Symmetry: block (j, i) := block (i, j)' for each active i, from the smaller index's
        # block row when both are active.  Row by row, so the writes stay within one row.
        for j in range(n):
            j0 = j * nx
            for b in range(nx):
                q = j0 + b
                for k in range(na):
                    i = act[k]
                    if i < j or not active[j]:
                        i0 = i * nx
                        for a in range(nx):
                            Xs[q, i0 + a] = Xs[i0 + a, q]


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

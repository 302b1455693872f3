"""Compiled kernels (numba) for the window filter and the cross-covariance recursion.

The anti-delay DKF spends its time in small dense loops: a 3x3 predict/update
per node and window row, and ``F_i C_ij F_j'`` per pair of nodes.  Numpy pays
a call per row for those; these kernels run a whole tick's rows in one call.
They compute exactly what :func:`dkfsim.estimators.window.information_step`
and :class:`dkfsim.estimators.fusion.CrossCovariance` compute in numpy (the
same formulas, only the summation order differs), without ``fastmath`` and
single-threaded, so each path is bit-identical run to run.  Their arrays come
grouped in the module-level namedtuples :class:`Model`, :class:`Ring` and
:class:`Cross` (numba loads kernels taking namedtuples from its disk cache
like any other; the types must be importable by name for that), and a kernel
is split into named steps in this module (numba's cache does not notice an
edit to a jitted function of another file), inlined into it (``_INLINE``).

Which path runs is the run's :class:`~dkfsim.core.backend.Backend`: numba when it is
installed, unless the environment variable ``DKFSIM_KERNELS=numpy`` forces the pure-numpy
path (the fallback on platforms without numba, tested against the compiled one).  Compiled kernels
are cached on disk (``cache=True``): the first call on a machine compiles them
once (about 20 s of CPU with the compiled tree's); later processes load them.  See
docs/design.md §4 ("Kernel paths").
"""

from __future__ import annotations

from collections import namedtuple

import numpy as np

from dkfsim.core.jit import KERNELS_ENV, LazyKernels  # noqa: F401  (KERNELS_ENV re-exported)

#: The kernels, callees before callers (numba resolves a callee by its module global).
_KERNELS = ("_predict", "_eliminate", "_back_substitute", "_posterior", "_nan", "_step", "window_rows", "filter_rows",
            "xi_blocks", "_xi_work", "_active", "_held_columns", "_node_terms", "_column_terms", "_missed_terms",
            "_row_terms", "_mirror", "xi_rows")
#: The steps, inlined into the kernels that call them (numba's ``inline="always"``): as calls,
#: one node's predict/update in five steps cost the window filter half again its time
#: (docs/decisions.md 120).  They bind a namedtuple's fields to locals once, at their top.
_INLINE = ("_predict", "_eliminate", "_back_substitute", "_posterior", "_nan", "_step", "xi_blocks", "_xi_work", "_active",
           "_held_columns", "_node_terms", "_column_terms", "_missed_terms", "_row_terms", "_mirror")
_lazy = LazyKernels(__name__, _KERNELS, inline=_INLINE)

#: The filters' model: ``Phi``, ``Q`` and the prior of each filter, ``x0`` (b, nx), ``P0`` (b, nx, nx).
Model = namedtuple("Model", "Phi Q x0 P0")
#: The window filter's ring, slot ``row % S``: per node the estimates ``x``, ``P``, the gain
#: ``G = P Pp^-1`` (:class:`~dkfsim.estimators.window.WindowState`), and from the
#: :class:`~dkfsim.model.holdings.Holdings` the information sums ``Omega``, ``Theta`` and the
#: origins held (``held``, no origin axis without the fusion).
Ring = namedtuple("Ring", "x P G Omega Theta held")
#: The cross-covariance recursion (:class:`~dkfsim.estimators.fusion.CrossCovariance`): its
#: ring ``Xi`` (S, N, N) and the prior's ``Xi0``, the weights ``A`` (node x origin; ``unit``:
#: all one), the origin of each measurement column, the measurement factor ``U`` (1, nx, M),
#: or (K, nx, M) when ``varying``, ``Phi``, and ``Lq`` with ``Lq Lq' = Q``.
Cross = namedtuple("Cross", "Xi Xi0 A unit column_sensor factor varying Phi Lq")
#: Scratch of one predict/update: ``Pp``, ``M`` (nx, nx) and the right-hand side (nx, nx + 1).
_Work = namedtuple("_Work", "Pp M rhs")
#: Scratch of :func:`xi_rows` (allocated by :func:`_xi_work`, which says what each holds).
_XiWork = namedtuple("_XiWork", "Ft PU Y2 Y1 sel R Out F_i Ot active comp wj MO hc cnt need_c need_d act")


def compiled():
    """This module with its kernels compiled (``numba.njit(cache=True)``, no fastmath, no
    parallel): numba is imported, and the kernels loaded from the disk cache or compiled,
    on the first call (:class:`dkfsim.core.jit.LazyKernels`)."""
    return _lazy.get()


def _predict(Phi, Q, xprev, Pprev, Om, Th, Pp, M, rhs):
    """``Pp = Phi Pprev Phi' + Q`` and the system ``M [G | x] = rhs = [I | Pp Theta + Phi xprev]``,
    ``M = I + Pp Omega`` (see window.information_step)."""
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


def _eliminate(M, rhs):
    """Gaussian elimination of ``M`` with partial pivoting (LAPACK getrf's pivot rule),
    applied to ``rhs``; False when ``M`` is singular (or NaN)."""
    nx = M.shape[0]
    for c in range(nx):
        p = c
        best = abs(M[c, c])
        for r in range(c + 1, nx):
            v = abs(M[r, c])
            if v > best:
                best = v
                p = r
        if not best > 0.0:
            return False
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
    return True


def _back_substitute(M, rhs):
    """``rhs := U^-1 rhs`` with ``U`` the eliminated ``M``: ``[G | x]``."""
    nx = M.shape[0]
    for c in range(nx - 1, -1, -1):
        piv = M[c, c]
        for b in range(nx + 1):
            s = rhs[c, b]
            for r in range(c + 1, nx):
                s -= M[c, r] * rhs[r, b]
            rhs[c, b] = s / piv


def _posterior(Pp, M, rhs, x_out, P_out, G_out):
    """``x``, ``G`` from the solved ``rhs`` and ``P = G Pp``, symmetrized (``M`` scratch)."""
    nx = Pp.shape[0]
    for a in range(nx):
        x_out[a] = rhs[a, nx]
        for b in range(nx):
            G_out[a, b] = rhs[a, b]
    for a in range(nx):
        for b in range(nx):
            s = 0.0
            for c in range(nx):
                s += rhs[a, c] * Pp[c, b]
            M[a, b] = s
    for a in range(nx):
        for b in range(nx):
            P_out[a, b] = 0.5 * (M[a, b] + M[b, a])


def _nan(x_out, P_out, G_out):
    """A node whose update is singular: its row is NaN."""
    nx = x_out.shape[0]
    for a in range(nx):
        x_out[a] = np.nan
        for b in range(nx):
            P_out[a, b] = np.nan
            G_out[a, b] = np.nan


def _step(Phi, Q, xprev, Pprev, Om, Th, x_out, P_out, G_out, w):
    """One information-form predict/update of one node (see window.information_step), with
    the scratch ``w`` (:class:`_Work`)."""
    Pp, M, rhs = w.Pp, w.M, w.rhs
    _predict(Phi, Q, xprev, Pprev, Om, Th, Pp, M, rhs)
    if not _eliminate(M, rhs):
        _nan(x_out, P_out, G_out)
        return
    _back_substitute(M, rhs)
    _posterior(Pp, M, rhs, x_out, P_out, G_out)


def window_rows(m, ring, starts, first, last):
    """Re-run rows ``first .. last`` of the :class:`Ring`; node ``i`` from row ``starts[i]`` on.

    Row 0 starts from the prior of :class:`Model` ``m`` (per node).
    """
    X, P, G, Omega, Theta = ring.x, ring.P, ring.G, ring.Omega, ring.Theta
    Phi, Q, x0, P0 = m.Phi, m.Q, m.x0, m.P0
    S, n, nx = X.shape
    w = _Work(np.empty((nx, nx)), np.empty((nx, nx)), np.empty((nx, nx + 1)))
    for row in range(first, last + 1):
        slot = row % S
        prev = (row - 1) % S
        for i in range(n):
            if starts[i] > row:
                continue
            if row == 0:
                _step(Phi, Q, x0[i], P0[i], Omega[slot, i], Theta[slot, i], X[slot, i], P[slot, i], G[slot, i], w)
            else:
                _step(Phi, Q, X[prev, i], P[prev, i], Omega[slot, i], Theta[slot, i], X[slot, i], P[slot, i],
                      G[slot, i], w)


def filter_rows(m, Omega, per_row, Theta, xs, Ps):
    """``b`` independent information filters of :class:`Model` ``m`` over ``K`` rows (see
    window.batched_filter): ``Omega`` (1 or K, b, nx, nx), ``Theta`` (K, b, nx); results into
    ``xs``, ``Ps``."""
    Phi, Q, x0, P0 = m.Phi, m.Q, m.x0, m.P0
    K, b, nx = Theta.shape
    w = _Work(np.empty((nx, nx)), np.empty((nx, nx)), np.empty((nx, nx + 1)))
    G = np.empty((nx, nx))
    for r in range(K):
        Om = Omega[r] if per_row else Omega[0]
        for i in range(b):
            if r == 0:
                _step(Phi, Q, x0[i], P0[i], Om[i], Theta[r, i], xs[r, i], Ps[r, i], G, w)
            else:
                _step(Phi, Q, xs[r - 1, i], Ps[r - 1, i], Om[i], Theta[r, i], xs[r, i], Ps[r, i], G, w)


def xi_blocks(Xi_prev, Xi, i, E, w, T):
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
    F_i, Ft, Y1, sel, Y2, R, Out = w.F_i, w.Ft, w.Y1, w.sel, w.Y2, w.R, w.Out
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


def _xi_work(n, M, T):
    """The scratch arrays of :func:`xi_rows` for ``n`` nodes and ``M`` measurement columns."""
    nx = len(T)
    N = n * nx
    return _XiWork(
        np.empty((nx, nx, n)),                 # Ft[a, b, j] = (G_j Phi)[a, b]
        np.empty((M, N)),                      # PU: (P_j u_m)[b] at [m, b n + j]
        np.empty((3 * nx + 2 * M, N)),         # Y2: the terms' rows over (b, j), see xi_rows
        np.empty((3 * nx + M, nx)),            # Y1: node i's coefficients of the Y2 rows ...
        np.empty(3 * nx + M, dtype=np.int64),  # sel: ... and which rows
        np.empty((nx, nx, n)),                 # R, Out: xi_blocks' scratch
        np.empty((nx, nx, n)),
        np.empty((nx, nx)),                    # F_i = G_i Phi
        np.empty((nx, nx)),                    # Ot = U U'
        np.empty(n, dtype=np.bool_),           # active: the node re-runs this row
        np.empty(n, dtype=np.bool_),           # comp: the node sums over the columns it misses
        np.empty(n),                           # wj: a per-node weight
        np.empty((nx, nx, n)),                 # MO[a, c, j]: the information node j misses
        np.empty((M, n)),                      # hc[m, j]: node j holds column m (0/1)
        np.empty(n),                           # cnt[j]: the columns node j holds
        np.empty(M, dtype=np.bool_),           # need_c: some complement node misses column m
        np.empty(M, dtype=np.bool_),           # need_d: some direct node holds column m
        np.empty(n, dtype=np.int64))           # act: the active nodes, ascending


def _active(starts, row, w):
    """Mark the nodes that re-run ``row`` (``w.active``, listed in ``w.act``); how many."""
    active, act = w.active, w.act
    na = 0
    for i in range(starts.shape[0]):
        active[i] = starts[i] <= row
        if active[i]:
            act[na] = i
            na += 1
    return na


def _held_columns(hs, column_sensor, unit, na, w, T):
    """Which columns each node holds (``w.hc``, ``w.cnt``) and which sum each active node
    takes (``w.comp``: the complement when weights are one and it is shorter); how many take
    the complement."""
    hc, cnt, comp, act = w.hc, w.cnt, w.comp, w.act
    nx = len(T)
    M, n = hc.shape
    for m in range(M):
        o = column_sensor[m]
        for j in range(n):
            hc[m, j] = 1.0 if hs[j, o] else 0.0
    for j in range(n):
        cnt[j] = 0.0
    for m in range(M):
        for j in range(n):
            cnt[j] += hc[m, j]
    n_comp = 0
    for k in range(na):
        i = act[k]
        comp[i] = unit and M - cnt[i] + 2 * nx < cnt[i]
        if comp[i]:
            n_comp += 1
    return n_comp


def _node_terms(Gs, Ps, Phi, Lq, w, T):
    """Per node ``j``: ``F_j = G_j Phi`` (``w.Ft``) and the ``Y2`` rows of ``G_j Lq``
    (rows ``0..nx``) and ``P_j`` (rows ``nx..2nx``)."""
    Ft, Y2 = w.Ft, w.Y2
    nx, n = len(T), Gs.shape[0]
    P2 = nx
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


def _column_terms(U, A, column_sensor, na, w, T):
    """The ``Y2`` rows of the columns the active nodes' sums need: ``(P_j u_m)`` (``w.PU``)
    times ``missed_jm`` for a column a complement node misses (rows ``ZC + m``), times
    ``a_jm h_jm`` for a column a direct node holds (rows ``ZD + m``)."""
    PU, Y2, hc, comp, act, wj, need_c, need_d = w.PU, w.Y2, w.hc, w.comp, w.act, w.wj, w.need_c, w.need_d
    nx = len(T)
    M, n = hc.shape
    N = n * nx
    P2, ZC, ZD = nx, 3 * nx, 3 * nx + M
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


def _missed_terms(U, w, T):
    """For the complement sums: ``Ot = U U'`` and the ``Y2`` rows ``2nx..3nx`` of
    ``(MO_j P_j)[d, b]``, ``MO_j`` the information of the columns node ``j`` misses."""
    Ot, MO, Y2, hc, wj = w.Ot, w.MO, w.Y2, w.hc, w.wj
    nx = len(T)
    M, n = hc.shape
    P2, D2 = nx, 2 * nx
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


def _row_terms(i, Ps, A, column_sensor, w, T):
    """Node ``i``'s block row as terms: ``w.F_i``, and coefficients ``w.Y1`` of the ``Y2``
    rows ``w.sel``; returns how many terms."""
    F_i, Ft, Y1, Y2, sel, PU, Ot, hc = w.F_i, w.Ft, w.Y1, w.Y2, w.sel, w.PU, w.Ot, w.hc
    nx = len(T)
    M, n = hc.shape
    P2, D2, ZC, ZD = nx, 2 * nx, 3 * nx, 3 * nx + M
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
    if w.comp[i]:
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
            wgt = A[i, column_sensor[m]] * hc[m, i]
            if wgt != 0.0:
                for a in range(nx):
                    Y1[E, a] = wgt * PU[m, a * n + i]
                sel[E] = ZD + m
                E += 1
    return E


def _mirror(Xs, na, w, T):
    """Symmetry: block ``(j, i)`` := block ``(i, j)'`` for each active ``i``, from the smaller
    index's block row when both are active.  Row by row, so the writes stay within one row."""
    active, act = w.active, w.act
    nx = len(T)
    n = active.shape[0]
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


def xi_rows(c, ring, starts, first, last, T):
    """The cross-covariance recursion for rows ``first .. last`` (see fusion.CrossCovariance).

    ``c`` is the :class:`Cross` (the ``Xi`` ring and the recursion's inputs), ``ring`` the
    window filter's :class:`Ring` (its ``G``, ``P`` and ``held``).  Node ``i``'s block row
    and column change from row ``starts[i]`` on; the rest of each row's ``Xi`` is left as it
    is.  ``T`` is a tuple of ``nx`` zeros: its length is a compile-time constant, so the loops
    over the state's components unroll (each ``nx`` compiles once).

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
    (``M`` rows).  Per row, in steps: the active nodes, the columns each holds
    and the sum it takes, the per-node and per-column ``Y2`` rows, the
    complement's, then each active node's block row and the mirror.
    """
    G, P, held, Xi = ring.G, ring.P, ring.held, c.Xi
    S, n = G.shape[0], G.shape[1]
    w = _xi_work(n, c.factor.shape[2], T)
    for row in range(first, last + 1):
        na = _active(starts, row, w)
        if na == 0:
            continue
        slot = row % S
        U = c.factor[row if c.varying else 0]
        n_comp = _held_columns(held[slot], c.column_sensor, c.unit, na, w, T)
        Ps = P[slot]
        _node_terms(G[slot], Ps, c.Phi, c.Lq, w, T)
        _column_terms(U, c.A, c.column_sensor, na, w, T)
        if n_comp > 0:
            _missed_terms(U, w, T)
        Xi_prev = c.Xi0 if row == 0 else Xi[(row - 1) % S]
        Xs = Xi[slot]
        for i in range(n):
            if w.active[i]:
                E = _row_terms(i, Ps, c.A, c.column_sensor, w, T)
                xi_blocks(Xi_prev, Xs, i, E, w, T)
        _mirror(Xs, na, w, T)

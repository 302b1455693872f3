"""Independent reference implementations for the dkfsim test-suite.

Nothing here imports :mod:`dkfsim`.  Everything is written the slow, obvious
way (plain loops, covariance form, explicit linear maps) so that a bug in the
engine's fast paths cannot be reproduced here by accident.

Conventions (docs/design.md §§1, 4-8):

* ``K`` ticks; row ``r = 0..K-1`` of every per-tick array holds tick ``k = r+1``
  at time ``t[r] = (r+1) T``.  The prior ``x0_mean, P0`` is at time 0, so row 0
  is "predict from the prior, then update".
* ``arrival[i, o, r]``: the time node ``i`` first held origin ``o``'s
  contribution for row ``r`` (``inf`` if never).
* Node ``i`` at tick ``k`` (1-based) re-runs rows ``k-L .. k-1`` (0-based)
  from its final estimate of row ``k-L-1`` (the prior if that is negative).
  A window row ``r`` uses the contributions held at ``t[k-1]``; a row is final
  when it leaves the window, i.e. the value computed at tick ``r+L`` with the
  contributions held at ``t[r+L-1]``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# ----------------------------------------------------------------------------
# comparison helpers
# ----------------------------------------------------------------------------

def rel_err(a, b) -> float:
    """Largest row-wise relative error of ``a`` against the reference ``b``.

    For every leading index ``r`` (a tick), ``max|a[r]-b[r]| / max|b[r]|``;
    the result is the maximum over rows.  Normalising per row keeps early rows
    (small values) as strict as late ones when the state grows with time.
    Non-finite entries must agree exactly (same position, same value).
    """
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    if a.shape != b.shape:
        raise AssertionError(f"shape mismatch: {a.shape} vs reference {b.shape}")
    fa, fb = np.isfinite(a), np.isfinite(b)
    if not np.array_equal(fa, fb) or not np.array_equal(a[~fa], b[~fb]):
        return float("inf")
    if a.ndim == 0:
        a, b = a.reshape(1), b.reshape(1)
        fa, fb = fa.reshape(1), fb.reshape(1)
    a = np.where(fa, a, 0.0)
    b = np.where(fb, b, 0.0)
    worst = 0.0
    for ar, br in zip(a, b):
        num = np.max(np.abs(ar - br)) if ar.size else 0.0
        den = np.max(np.abs(br)) if br.size else 0.0
        if num == 0.0:
            continue
        worst = max(worst, num / den if den > 0 else float("inf"))
    return worst


def first_mismatch(a, b, tol):
    """(row, max abs diff, value, reference) of the first row whose relative
    error exceeds ``tol``; ``None`` if none.  Used in assertion messages."""
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    for r, (ar, br) in enumerate(zip(a, b)):
        if rel_err(ar[None], br[None]) > tol:
            return r, float(np.nanmax(np.abs(ar - br))), ar, br
    return None


def assert_close(a, b, what: str, tol: float = 1e-9):
    err = rel_err(a, b)
    if not err < tol:
        mm = first_mismatch(a, b, tol)
        detail = ""
        if mm is not None:
            r, d, ar, br = mm
            detail = (f"; first bad row r={r} (tick {r + 1}), max|diff|={d:.3e}\n"
                      f"  got      = {np.array2string(np.asarray(ar), precision=12)}\n"
                      f"  expected = {np.array2string(np.asarray(br), precision=12)}")
        raise AssertionError(f"{what}: relative error {err:.3e} >= {tol:g}{detail}")


# ----------------------------------------------------------------------------
# the model as stored in a run (docs/design.md §8)
# ----------------------------------------------------------------------------

@dataclass
class Model:
    Phi: np.ndarray
    Q: np.ndarray
    x0: np.ndarray
    P0: np.ndarray
    Hs: list
    Rs: list
    ys: list
    t: np.ndarray
    L: int
    A: np.ndarray          # effective origin weights (n, n)
    arrival: np.ndarray    # (n, n, K)

    @property
    def n(self):
        return len(self.Hs)

    @property
    def nx(self):
        return self.Phi.shape[0]

    @property
    def K(self):
        return len(self.t)


def model_from_arrays(arrays) -> Model:
    n = 0
    while f"H_{n}" in arrays:
        n += 1
    if n == 0:
        raise KeyError("no H_0 in arrays")
    t = np.asarray(arrays["t"], dtype=float)
    K = len(t)
    A = np.asarray(arrays["weights_A"], dtype=float) if "weights_A" in arrays else np.ones((n, n))
    arrival = np.asarray(arrays["arrival"], dtype=float) if "arrival" in arrays else None
    ys = []
    for o in range(n):
        y = np.asarray(arrays[f"y_{o}"], dtype=float)
        ys.append(y.reshape(K, -1))
    return Model(
        Phi=np.asarray(arrays["Phi"], dtype=float),
        Q=np.asarray(arrays["Q"], dtype=float),
        x0=np.asarray(arrays["x0_mean"], dtype=float).reshape(-1),
        P0=np.asarray(arrays["P0"], dtype=float),
        Hs=[np.atleast_2d(np.asarray(arrays[f"H_{o}"], dtype=float)) for o in range(n)],
        Rs=[np.atleast_2d(np.asarray(arrays[f"R_{o}"], dtype=float)) for o in range(n)],
        ys=ys,
        t=t,
        L=int(np.asarray(arrays["buffer_length"])) if "buffer_length" in arrays else 1,
        A=A,
        arrival=arrival,
    )


# ----------------------------------------------------------------------------
# 1. textbook Kalman filter
# ----------------------------------------------------------------------------

class NoiseLayout:
    """Index layout of the stacked noise vector

    ``xi = [x(0) - x0_mean ; w_0 ; ... ; w_{K-1} ; v_0[0..K-1] ; ... ; v_{n-1}[0..K-1]]``

    where ``w_r`` drives row ``r`` (``x_row_r = Phi x_row_{r-1} + w_r``, with
    ``x_row_{-1} = x(0)``) and ``v_o[r]`` is sensor ``o``'s noise at row ``r``.
    """

    def __init__(self, nx, K, ms, P0, Q, Rs):
        self.nx, self.K, self.ms = nx, K, list(ms)
        self.w0 = nx
        self.v0 = nx + K * nx
        self.voff = []
        off = self.v0
        for m in self.ms:
            self.voff.append(off)
            off += K * m
        self.D = off
        blocks = [np.asarray(P0)] + [np.asarray(Q)] * K
        for o in range(len(self.ms)):
            blocks += [np.asarray(Rs[o])] * K
        self.Sigma = _block_diag(blocks)

    def x0_slot(self):
        return slice(0, self.nx)

    def w_slot(self, r):
        return slice(self.w0 + r * self.nx, self.w0 + (r + 1) * self.nx)

    def v_slot(self, o, r):
        m = self.ms[o]
        return slice(self.voff[o] + r * m, self.voff[o] + (r + 1) * m)

    def stack(self, x0dev, w, vs):
        """Stack realisations: x0dev (nx,), w (K, nx), vs[o] (K, m_o)."""
        xi = np.zeros(self.D)
        xi[self.x0_slot()] = x0dev
        for r in range(self.K):
            xi[self.w_slot(r)] = w[r]
            for o in range(len(self.ms)):
                xi[self.v_slot(o, r)] = vs[o][r]
        return xi


def _block_diag(blocks):
    size = sum(b.shape[0] for b in blocks)
    out = np.zeros((size, size))
    i = 0
    for b in blocks:
        m = b.shape[0]
        out[i:i + m, i:i + m] = b
        i += m
    return out


def kf_step(Phi, Q, x, P, Hs, Rs, yrow, used, *, form="auto", M=None, layout=None, r=None):
    """One predict/update of a Kalman filter.

    ``used`` is a list of ``(sensor, weight)``; ``yrow[o]`` is sensor o's
    measurement for this row.  With every weight equal to 1 (``form='auto'``)
    the update is the textbook covariance form: stack the used sensors'
    measurements, gain ``K = Pp H' (H Pp H' + R)^-1``, Joseph-form covariance
    ``(I-KH) Pp (I-KH)' + K R K'``.

    A weight != 1 makes the contribution ``(a H'R^-1 y, a H'R^-1 H)`` which is
    *not* the information of any measurement ``y = Hx + v`` with the sensor's
    real noise (it would be one with noise covariance ``R/a``, which is not the
    noise the data has), so there is no honest stacked-measurement gain for it:
    the update is then written in information form,
    ``P = (Pp^-1 + sum a_o H_o'R_o^-1 H_o)^-1``,
    ``x = P (Pp^-1 xp + sum a_o H_o'R_o^-1 y_o)``, exactly what the filter
    computes.  ``form='info'`` forces the information form (self-tests).

    If ``M`` (nx x D map of the estimation error onto the stacked noise, see
    :class:`NoiseLayout`) is given, the error map is propagated through the
    same equations and returned as a third value.
    """
    nx = Phi.shape[0]
    xp = Phi @ x
    Pp = Phi @ P @ Phi.T + Q
    Mp = None
    if M is not None:
        Mp = Phi @ M
        Mp[:, layout.w_slot(r)] -= np.eye(nx)   # e_p = Phi e - w_r
    if not used:
        return (xp, Pp, Mp) if M is not None else (xp, Pp)
    weights = [float(a) for _, a in used]
    if form == "auto" and all(a == 1.0 for a in weights):
        H = np.vstack([Hs[o] for o, _ in used])
        R = _block_diag([Rs[o] for o, _ in used])
        y = np.concatenate([np.atleast_1d(yrow[o]) for o, _ in used])
        S = H @ Pp @ H.T + R
        G = np.linalg.solve(S, H @ Pp).T            # Pp H' S^-1  (S, Pp symmetric)
        xn = xp + G @ (y - H @ xp)
        IKH = np.eye(nx) - G @ H
        Pn = IKH @ Pp @ IKH.T + G @ R @ G.T
        if M is not None:
            Mn = IKH @ Mp
            c = 0
            for o, _ in used:
                m = Hs[o].shape[0]
                Mn[:, layout.v_slot(o, r)] += G[:, c:c + m]   # e = (I-KH) e_p + K v
                c += m
            return xn, Pn, Mn
        return xn, Pn
    # information form
    Ppi = np.linalg.inv(Pp)
    Info = Ppi.copy()
    info_vec = Ppi @ xp
    for o, a in used:
        RiH = np.linalg.solve(Rs[o], Hs[o])         # R^-1 H
        Info += a * (Hs[o].T @ RiH)
        info_vec += a * (RiH.T @ np.atleast_1d(yrow[o]))
    Pn = np.linalg.inv(Info)
    Pn = 0.5 * (Pn + Pn.T)
    xn = Pn @ info_vec
    if M is not None:
        Mn = Pn @ (Ppi @ Mp)                         # e = P (Pp^-1 e_p + sum a H'R^-1 v)
        for o, a in used:
            RiH = np.linalg.solve(Rs[o], Hs[o])
            Mn[:, layout.v_slot(o, r)] += a * (Pn @ RiH.T)
        return xn, Pn, Mn
    return xn, Pn


def kalman_filter(Phi, Q, x0, P0, Hs, Rs, ys, use, *, form="auto"):
    """Run the filter over all rows.  ``ys[o]`` is (K, m_o); ``use(r)`` returns
    the list of ``(sensor, weight)`` pairs used for row ``r``.
    Returns ``xs`` (K, nx) and ``Ps`` (K, nx, nx)."""
    Phi = np.asarray(Phi, float)
    Q = np.asarray(Q, float)
    x = np.asarray(x0, float).reshape(-1)
    P = np.asarray(P0, float)
    Hs = [np.atleast_2d(np.asarray(h, float)) for h in Hs]
    Rs = [np.atleast_2d(np.asarray(rr, float)) for rr in Rs]
    K = len(ys[0])
    xs = np.zeros((K, len(x)))
    Ps = np.zeros((K, len(x), len(x)))
    for r in range(K):
        yrow = [np.atleast_1d(ys[o][r]) for o in range(len(Hs))]
        x, P = kf_step(Phi, Q, x, P, Hs, Rs, yrow, list(use(r)), form=form)
        xs[r], Ps[r] = x, P
    return xs, Ps


def centralized(arrays):
    """The centralized KF with every sensor at every row, all weights 1."""
    m = model_from_arrays(arrays)
    every = [(o, 1.0) for o in range(m.n)]
    return kalman_filter(m.Phi, m.Q, m.x0, m.P0, m.Hs, m.Rs, m.ys, lambda r: every)


# ----------------------------------------------------------------------------
# 2. the window rule of docs/design.md §4, from `arrival` alone
# ----------------------------------------------------------------------------

def held(m: Model, i: int, r: int, k: int):
    """Contributions node i uses for row r at tick k (1-based)."""
    if r >= k - m.L:          # window row: held at t_k
        cutoff = m.t[k - 1]
    else:                     # already final: held at tick r+L
        cutoff = m.t[r + m.L - 1]
    return [(o, m.A[i, o]) for o in range(m.n) if m.arrival[i, o, r] <= cutoff]


def _run_node(m: Model, i: int, layout: NoiseLayout | None = None):
    """Node i's estimates.  Keeps the chain of final estimates and re-runs the
    window at each tick: O(K*L) filter steps."""
    K, L, nx = m.K, m.L, m.nx
    yrows = [[m.ys[o][r] for o in range(m.n)] for r in range(K)]
    track = layout is not None
    x_local = np.zeros((K, nx))
    P_local = np.zeros((K, nx, nx))
    x_final = np.zeros((K, nx))
    M_local = np.zeros((K, nx, layout.D)) if track else None
    final = [None] * K            # (x, P, M) of each final row
    prior_M = None
    if track:
        prior_M = np.zeros((nx, layout.D))
        prior_M[:, layout.x0_slot()] = -np.eye(nx)   # e(0) = x0_mean - x(0)
    for k in range(1, K + 1):
        s0 = max(k - L, 0)
        if s0 == 0:
            x, P, M = m.x0.copy(), m.P0.copy(), prior_M
        else:
            x, P, M = final[s0 - 1]
        for r in range(s0, k):
            used = held(m, i, r, k)
            if track:
                x, P, M = kf_step(m.Phi, m.Q, x, P, m.Hs, m.Rs, yrows[r], used,
                                  M=M, layout=layout, r=r)
            else:
                x, P = kf_step(m.Phi, m.Q, x, P, m.Hs, m.Rs, yrows[r], used)
            if r == k - L or k == K:      # leaves the window now / last tick
                final[r] = (x, P, M)
                x_final[r] = x
            if r == k - 1:
                x_local[r], P_local[r] = x, P
                if track:
                    M_local[r] = M
    return x_local, P_local, x_final, M_local


def node_estimates(arrays):
    """Reference ``x_local`` (K, n, nx), ``P_local`` (K, n, nx, nx) and
    ``x_final`` (K, n, nx) from the model, the measurements, ``buffer_length``,
    ``weights_A`` and ``arrival`` of a run."""
    m = model_from_arrays(arrays)
    xl = np.zeros((m.K, m.n, m.nx))
    Pl = np.zeros((m.K, m.n, m.nx, m.nx))
    xf = np.zeros((m.K, m.n, m.nx))
    for i in range(m.n):
        a, b, c, _ = _run_node(m, i)
        xl[:, i], Pl[:, i], xf[:, i] = a, b, c
    return {"x_local": xl, "P_local": Pl, "x_final": xf}


# ----------------------------------------------------------------------------
# 3. true error cross-covariances by explicit linear maps
# ----------------------------------------------------------------------------

def layout_for(m: Model) -> NoiseLayout:
    return NoiseLayout(m.nx, m.K, [h.shape[0] for h in m.Hs], m.P0, m.Q, m.Rs)


def error_maps(arrays):
    """``M`` (K, n, nx, D): the error ``x_local[r, i] - x_true[r]`` of every
    local estimate as a linear map of the stacked noise (see
    :class:`NoiseLayout`), and the layout (whose ``Sigma`` is Cov(xi))."""
    m = model_from_arrays(arrays)
    layout = layout_for(m)
    Ms = np.zeros((m.K, m.n, m.nx, layout.D))
    for i in range(m.n):
        Ms[:, i] = _run_node(m, i, layout)[3]
    return Ms, layout


def cross_covariances(arrays):
    """Xi (K, n*nx, n*nx): the true error cross-covariances of the ``x_local``
    estimates of every row, ``C_ij = M_i Cov(xi) M_j'``, computed without any
    covariance recursion."""
    Ms, layout = error_maps(arrays)
    K, n, nx, D = Ms.shape
    # Cov(xi) is block diagonal and positive definite: use its Cholesky factor.
    S = np.linalg.cholesky(layout.Sigma)
    Xi = np.zeros((K, n * nx, n * nx))
    for r in range(K):
        B = Ms[r].reshape(n * nx, D) @ S
        X = B @ B.T
        Xi[r] = 0.5 * (X + X.T)
    return Xi


# ----------------------------------------------------------------------------
# 4. fusion (docs/design.md §7)
# ----------------------------------------------------------------------------

def fusion_delta(Xi, n, nx):
    delta = 1e-8 * np.trace(Xi) / (n * nx)
    return 1.0 if delta == 0.0 else delta          # tr(Xi) = 0: exact estimates (design §7)


def fuse(Xi, xs, nx, kind="matrix"):
    """Optimal linear fusion of the stacked estimates ``xs`` ((n, nx) or
    (n*nx,)) with error covariance ``Xi`` (n*nx, n*nx).

    ``kind='matrix'``: Gamma (n*nx, nx) solves
    ``[[Xi + delta I, E], [E', 0]] [Gamma; Lambda] = [0; I]``,
    ``delta = 1e-8 tr(Xi) / (n nx)``, E = n stacked identities.
    ``kind='diagonal'`` (the paper's per-component variant): every block
    ``P_ij`` of Xi is replaced by its diagonal, so the problem splits into nx
    independent scalar fusions, one per state component c, each with the
    n x n matrix ``Xi_c = [P_ij[c, c]]``.  docs/design.md §7 is silent on the
    regularisation here; we apply its formula to each scalar problem as it
    stands, ``delta_c = 1e-8 tr(Xi_c) / n`` (scale-invariant per component:
    a global delta would over-regularise a component whose variance is
    small next to the others').  Gamma's blocks are then diagonal.

    Returns ``x_f = Gamma' x_stack``, ``P_f = Gamma' Xi Gamma`` (with the full,
    unregularised Xi) and Gamma.
    """
    Xi = np.asarray(Xi, float)
    N = Xi.shape[0]
    n = N // nx
    xs = np.asarray(xs, float).reshape(N)
    if kind == "matrix":
        W = Xi
        reg = np.full(N, fusion_delta(Xi, n, nx))
    elif kind == "diagonal":
        W = Xi * np.kron(np.ones((n, n)), np.eye(nx))
        comp = np.diag(Xi).reshape(n, nx)               # [i, c] = P_ii[c, c]
        reg = np.tile(1e-8 * comp.sum(axis=0) / n, n)   # delta_c at index i*nx + c
    else:
        raise ValueError(kind)
    E = np.kron(np.ones((n, 1)), np.eye(nx))
    KKT = np.zeros((N + nx, N + nx))
    KKT[:N, :N] = W + np.diag(reg)
    KKT[:N, N:] = E
    KKT[N:, :N] = E.T
    rhs = np.zeros((N + nx, nx))
    rhs[N:] = np.eye(nx)
    sol = np.linalg.solve(KKT, rhs)
    Gamma = sol[:N]
    xf = Gamma.T @ xs
    Pf = Gamma.T @ Xi @ Gamma
    return xf, 0.5 * (Pf + Pf.T), Gamma


def fuse_all(arrays, kind="matrix", Xi=None):
    """Reference x_fused (K, nx), P_fused (K, nx, nx) from a run's x_local."""
    if Xi is None:
        Xi = cross_covariances(arrays)
    xl = np.asarray(arrays["x_local"], float)
    K, n, nx = xl.shape
    xf = np.zeros((K, nx))
    Pf = np.zeros((K, nx, nx))
    for r in range(K):
        xf[r], Pf[r], _ = fuse(Xi[r], xl[r].reshape(-1), nx, kind)
    return xf, Pf


# ----------------------------------------------------------------------------
# synthetic runs for the self-tests (no engine needed)
# ----------------------------------------------------------------------------

def synthetic_arrays(seed, n=4, K=25, L=3, nx=2, arrival="random", weights=None):
    """A run-shaped dict with known noise.  Returns (arrays, xi) where xi is
    the stacked noise realisation (NoiseLayout order).

    ``arrival``: 'zero' (every contribution held at its own time t[r]),
    'own' (only the node's own sensor, others never) or 'random' (random
    delays in whole ticks, some never)."""
    rng = np.random.default_rng(seed)
    T = 0.1
    if nx == 2:
        Phi = np.array([[1.0, T], [0.0, 1.0]])
        Q = 0.5 * np.array([[T ** 3 / 3, T ** 2 / 2], [T ** 2 / 2, T]])
    else:
        Phi = np.eye(nx) + T * np.diag(np.ones(nx - 1), 1)
        Q = 0.1 * np.eye(nx)
    x0 = rng.normal(size=nx)
    B = rng.normal(size=(nx, nx))
    P0 = B @ B.T + np.eye(nx)
    Hs, Rs = [], []
    for o in range(n):
        mo = 1 + (o % 2)
        H = rng.normal(size=(mo, nx))
        C = rng.normal(size=(mo, mo))
        Hs.append(H)
        Rs.append(C @ C.T + 0.3 * np.eye(mo))
    x0dev = np.linalg.cholesky(P0) @ rng.normal(size=nx)
    w = rng.multivariate_normal(np.zeros(nx), Q, size=K)
    vs = [rng.multivariate_normal(np.zeros(h.shape[0]), Rs[o], size=K) for o, h in enumerate(Hs)]
    truth = np.zeros((K, nx))
    x = x0 + x0dev
    for r in range(K):
        x = Phi @ x + w[r]
        truth[r] = x
    t = (np.arange(1, K + 1) * 100_000_000) / 1e9
    arr = np.full((n, n, K), np.inf)
    for i in range(n):
        for o in range(n):
            for r in range(K):
                if arrival == "zero" or i == o:
                    arr[i, o, r] = t[r]
                elif arrival == "random":
                    d = rng.integers(0, 2 * L + 1)
                    if rng.random() < 0.15 or r + d >= K:
                        continue
                    arr[i, o, r] = t[r + d]
    arrays = {
        "t": t, "truth": truth, "Phi": Phi, "Q": Q, "x0_mean": x0, "P0": P0,
        "buffer_length": np.array(L), "arrival": arr,
        "weights_A": np.ones((n, n)) if weights is None else np.asarray(weights, float),
    }
    for o in range(n):
        arrays[f"H_{o}"] = Hs[o]
        arrays[f"R_{o}"] = Rs[o]
        arrays[f"y_{o}"] = truth @ Hs[o].T + vs[o]
    layout = NoiseLayout(nx, K, [h.shape[0] for h in Hs], P0, Q, Rs)
    return arrays, layout.stack(x0dev, w, vs)

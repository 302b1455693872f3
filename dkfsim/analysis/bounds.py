"""The paper's theoretical delay bound (section IV, Remark ``bound_of_delay``).

Yu, Dai et al. bound the local information matrices from below (Theorem
``boundedness of error covariance``, eq. ``bounded_D_T(k)`` = ``cov_bound``)::

    [P_k^i(s)]^-1 >= omega_min * varpi^Z * alpha_bar * gamma_hat^(s-k+d_t)
                     * eta^(2 (Z d_t - 1) + 2 (s-k+d_t))                  (cov_bound)

with ``varpi = gamma_hat^d_t`` and ``Z = n + n_bar``, and "reverse" it into
a delay bound for a given covariance level ``P`` (eq. ``delay_bound``)::

    d_t <= log_{gamma_hat eta^(2(Z+1))} [ gamma_hat^(k-s) eta^(2(k-s+1))
                                           (P omega_min varpi^Z alpha_bar)^-1 ]

This module computes every term from the model and the graph and solves the
bound.  How each term is read (the paper leaves room; ``docs/maxdelay.md``
says the same):

* **Observability Gramian** (Assumption ``boundnessed``):
  ``M(N) = sum_{l=0}^{N} (Phi^l)' H' R^-1 H Phi^l`` with ``H`` stacking every
  sensor's measurement matrix and ``R`` block-diagonal (the paper writes
  ``Phi_l = col{Phi_{l,1}, ...}`` for the stacked measurement matrices).
  ``n_bar`` is the smallest positive integer with ``M(n_bar) > 0``;
  ``alpha = lambda_min(M(n_bar))`` and ``alpha_bar = lambda_min(M(n_bar + n -
  1))`` (``n`` = number of sensors).  The proof's step from ``bounded_kl`` to
  ``bounded_found_the_doundary`` applies this forward Gramian to a sum
  written with ``O^-1``; we follow the assumption as stated.  ``alpha_bar``
  enters on undirected graphs, ``alpha`` on directed ones (Remark
  ``directed_cov_boundess``).
* **eta** (Assumption ``varPhi_initial_cov_invertible``: ``Phi^-1 >= eta I``):
  the smallest singular value of ``Phi^-1`` (``= 1 / sigma_max(Phi)``), which is
  what the proof uses: ``O^-T O^-1 >= eta^2 I`` per factor.
* **gamma_hat** (Lemma ``lemma1_matrix_invert_beta``, after Battistelli &
  Chisci 2014): the largest ``gamma`` with
  ``(Phi Omega^-1 Phi' + Q)^-1 >= gamma Phi^-T Omega Phi^-1`` for every
  information matrix ``Omega`` that occurs.  For one ``Omega`` that is
  ``1 / (1 + lambda_max(Omega^1/2 Phi^-1 Q Phi^-T Omega^1/2))``; it decreases
  as ``Omega`` grows.  No node ever holds more information than the
  centralized filter with all data on time (same prior, Riccati monotone), so
  we take the minimum over the centralized filter's information matrices from
  ``P0`` until it has converged (and at least ``horizon`` rows).  (The lemma
  as printed writes ``(Phi Omega Phi' + Q)^-1``; the proof applies it with
  ``Omega = P^-1``, which is the form above.)
* **omega_min**: the smallest entry of ``W^sigma`` over the relevant
  ``sigma``, ``W`` the paper's weights: ``w_ii = 1`` (eq. ``commu_w_delay``)
  and ``w_ij = 1/|N_i|`` for each neighbour ``j`` (in-neighbour on a digraph).
  The proof claims ``W^sigma > 0`` for every ``sigma >= 1`` on an undirected
  graph; that is false for any graph that is not complete (``W^1`` is zero
  between non-neighbours), which makes the literal ``omega_min`` zero and the
  bound ``-inf``.  We report that literal value and use the smallest entry
  over ``sigma = sigma_0 .. Z``, ``sigma_0`` the first power with every entry
  positive (the diameter of the graph, since ``w_ii > 0``), or ``sigma >= n``
  on a digraph as the paper's Remark does, whichever is larger.
* **Z** ``= n + n_bar``.
* ``k - s = 0`` by default: the newest row, the one the fused estimate uses.

Solving: substituting ``varpi = gamma_hat^d_t`` into ``cov_bound`` gives
``c(d_t) = C0 * b^d_t`` with ``C0 = omega_min alpha_bar gamma_hat^(s-k)
eta^(2(s-k)-2)`` and ``b = (gamma_hat eta^2)^(Z+1)``.  Every local covariance
then satisfies ``lambda_max(P) <= 1 / c(d_t)``, and the fused one too
(``P_f <= P_i``).  A tolerance ``p`` on ``lambda_max(P)`` holds for every
``d_t <= d* = ln(p C0) / -ln(b)``; ``d*`` is exactly the fixed point of the
printed eq. ``delay_bound`` evaluated at ``varpi = gamma_hat^d*``
(:func:`delay_bound_formula`), so the printed formula and the solved one
agree.  A ``d*`` below 0 means the bound guarantees nothing even without
delay.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

import numpy as np

from dkfsim.config.plan import RunPlan
from dkfsim.model.system import LinearSensor

#: Relative eigenvalue threshold under which a Gramian counts as singular.
GRAMIAN_RTOL = 1e-10


# =========================================================================== terms
def information_sum(omegas) -> np.ndarray:
    """``sum_i H_i' R_i^-1 H_i`` from the per-sensor information matrices."""
    omegas = [np.asarray(o, float) for o in omegas]
    return np.sum(omegas, axis=0)


def observability_gramian(Phi: np.ndarray, Omega: np.ndarray, N: int) -> np.ndarray:
    """``M(N) = sum_{l=0}^{N} (Phi^l)' Omega Phi^l`` (``Omega = H' R^-1 H``)."""
    Phi = np.asarray(Phi, float)
    M = np.zeros_like(Phi)
    O = np.eye(Phi.shape[0])
    for _ in range(int(N) + 1):
        M += O.T @ Omega @ O
        O = Phi @ O
    return 0.5 * (M + M.T)


def gramian_terms(Phi: np.ndarray, Omega: np.ndarray, n: int, max_nbar: int = 1000) -> dict:
    """``n_bar, alpha, beta, alpha_bar, beta_bar`` of Assumption ``boundnessed``."""
    nx = np.asarray(Phi).shape[0]
    for nbar in range(1, max_nbar + 1):
        ev = np.linalg.eigvalsh(observability_gramian(Phi, Omega, nbar))
        if ev[0] > GRAMIAN_RTOL * max(ev[-1], 1e-300):
            break
    else:
        raise ValueError(f"the system is not observable from all sensors within {max_nbar} steps "
                         f"(state dimension {nx})")
    ev_bar = np.linalg.eigvalsh(observability_gramian(Phi, Omega, nbar + n - 1))
    return {"n_bar": nbar, "alpha": float(ev[0]), "beta": float(ev[-1]),
            "alpha_bar": float(ev_bar[0]), "beta_bar": float(ev_bar[-1])}


def eta_of(Phi: np.ndarray) -> float:
    """Smallest singular value of ``Phi^-1`` (``1 / sigma_max(Phi)``)."""
    s = np.linalg.svd(np.asarray(Phi, float), compute_uv=False)
    if s[-1] <= 0:
        raise ValueError("Phi is singular: the paper's analysis needs an invertible Phi")
    return float(1.0 / s[0])


def gamma_of(Phi: np.ndarray, Q: np.ndarray, Omega: np.ndarray) -> float:
    """The largest ``gamma`` with ``(Phi Omega^-1 Phi' + Q)^-1 >= gamma Phi^-T Omega Phi^-1``
    for this one information matrix: ``1 / (1 + lambda_max(Omega^1/2 Phi^-1 Q Phi^-T Omega^1/2))``.

    Exact: with ``S = Phi^-1 Q Phi^-T`` the inequality reads
    ``(Omega^-1 + S)^-1 >= gamma Omega``, i.e. ``S <= (1/gamma - 1) Omega^-1``.
    """
    Phi_inv = np.linalg.inv(np.asarray(Phi, float))
    S = Phi_inv @ np.asarray(Q, float) @ Phi_inv.T
    w, V = np.linalg.eigh(0.5 * (Omega + Omega.T))
    half = (V * np.sqrt(np.clip(w, 0.0, None))) @ V.T
    lam = float(np.linalg.eigvalsh(half @ S @ half)[-1])
    return 1.0 / (1.0 + max(lam, 0.0))


def centralized_informations(Phi, Q, Omega, P0, horizon: int, max_rows: int = 100_000,
                             rtol: float = 1e-12) -> tuple[np.ndarray, int]:
    """Filtered information matrices ``P_r^-1`` of the centralized Kalman filter
    (all sensors on time) from the prior ``P0``: at least ``horizon`` rows and
    until they stop changing.  Returns ``(stack, rows)``."""
    Phi, Q, Omega = (np.asarray(a, float) for a in (Phi, Q, Omega))
    P = np.asarray(P0, float)
    infos = []
    prev = None
    for r in range(max_rows):
        Pp = Phi @ P @ Phi.T + Q
        info = np.linalg.inv(Pp) + Omega
        info = 0.5 * (info + info.T)
        infos.append(info)
        P = np.linalg.inv(info)
        if prev is not None and r + 1 >= horizon and \
                np.max(np.abs(info - prev)) <= rtol * np.max(np.abs(info)):
            break
        prev = info
    return np.array(infos), len(infos)


def gamma_hat_of(Phi, Q, Omega, P0, horizon: int) -> dict:
    """``gamma_hat``: the minimum of :func:`gamma_of` over the centralized
    filter's information matrices (an upper bound of every node's)."""
    infos, rows = centralized_informations(Phi, Q, Omega, P0, horizon)
    gammas = np.array([gamma_of(Phi, Q, om) for om in infos])
    r = int(np.argmin(gammas))
    return {"gamma_hat": float(gammas[r]), "gamma_hat_row": r, "riccati_rows": rows,
            "omega_hat_lambda_max": float(np.linalg.eigvalsh(infos[r])[-1]),
            "gamma_steady_state": float(gammas[-1])}


def paper_weight_matrix(graph) -> np.ndarray:
    """``W`` with ``w_ii = 1`` and ``w_ij = 1/|N_i|`` for ``j`` in ``N_i`` (the
    in-neighbours on a digraph: the nodes ``i`` receives from)."""
    n = graph.number_of_nodes()
    W = np.eye(n)
    directed = graph.is_directed()
    for i in range(n):
        nbrs = list(graph.predecessors(i)) if directed else list(graph.neighbors(i))
        for j in nbrs:
            if j != i:
                W[i, j] = 1.0 / len(nbrs)
    return W


def omega_min_of(W: np.ndarray, Z: int, sigma_from: int = 1) -> dict:
    """Smallest entry of ``W^sigma`` over the relevant powers.

    ``omega_min_literal``: over ``sigma = sigma_from .. Z`` as the paper writes
    it (0 on any graph that is not complete); ``omega_min``: over ``sigma =
    sigma_0 .. max(Z, sigma_0)``, ``sigma_0`` the first power ``>= sigma_from``
    with every entry positive (0 if none is within ``sigma_from + n`` powers).
    """
    W = np.asarray(W, float)
    n = W.shape[0]
    last = max(int(Z), sigma_from + n)
    mins = {}
    Wp = np.linalg.matrix_power(W, sigma_from)
    for sigma in range(sigma_from, last + 1):
        mins[sigma] = float(Wp.min())
        Wp = Wp @ W
    literal = min(mins[s] for s in range(sigma_from, max(int(Z), sigma_from) + 1))
    sigma0 = next((s for s in sorted(mins) if mins[s] > 0), None)
    if sigma0 is None:
        positive = 0.0
    else:
        positive = min(mins[s] for s in range(sigma0, max(int(Z), sigma0) + 1))
    return {"omega_min_literal": literal, "omega_min": positive, "sigma_from": sigma_from,
            "sigma_0": sigma0, "sigma_to": max(int(Z), sigma0 or 0)}


# =========================================================================== the bound
def log_cov_bound(d_t: float, *, gamma_hat: float, eta: float, Z: int, omega_min: float,
                  alpha_bar: float, k_minus_s: int = 0) -> float:
    """``ln`` of the right side of eq. ``cov_bound`` with ``varpi = gamma_hat^d_t``
    (``-inf`` when ``omega_min`` is 0)."""
    if omega_min <= 0 or alpha_bar <= 0:
        return -math.inf
    e = d_t - k_minus_s                       # s - k + d_t
    return (math.log(omega_min) + Z * d_t * math.log(gamma_hat) + math.log(alpha_bar)
            + e * math.log(gamma_hat) + (2 * (Z * d_t - 1) + 2 * e) * math.log(eta))


def delay_bound_formula(P: float, *, gamma_hat: float, eta: float, Z: int, omega_min: float,
                        varpi: float, alpha_bar: float, k_minus_s: int = 0) -> float:
    """Eq. ``delay_bound`` exactly as printed, for a given ``varpi``:
    ``log_{gamma_hat eta^(2(Z+1))} [gamma_hat^(k-s) eta^(2(k-s+1)) (P omega_min varpi^Z alpha_bar)^-1]``."""
    ln_base = math.log(gamma_hat) + 2 * (Z + 1) * math.log(eta)
    ln_arg = (k_minus_s * math.log(gamma_hat) + 2 * (k_minus_s + 1) * math.log(eta)
              - math.log(P) - math.log(omega_min) - Z * math.log(varpi) - math.log(alpha_bar))
    return ln_arg / ln_base


@dataclass
class PaperBound:
    """Every term of the paper's delay bound and the bound itself.

    ``d_star`` is the real solution (``None`` when the bound does not shrink
    with the delay, see ``note``); ``d_t_bound`` = ``floor(d_star)`` when
    ``d_star >= 0``, else ``None`` (no delay is guaranteed, not even 0).
    ``lambda_max_bound(d)`` is the covariance level the paper guarantees at
    delay bound ``d``.
    """

    p_tol: float
    n: int
    n_bar: int
    Z: int
    alpha: float
    beta: float
    alpha_bar: float
    beta_bar: float
    alpha_used: float
    eta: float
    gamma_hat: float
    gamma_detail: dict
    omega_min: float
    omega_min_literal: float
    omega_detail: dict
    k_minus_s: int
    directed: bool
    ln_C0: float
    base: float                 # b = (gamma_hat eta^2)^(Z+1), per unit of d_t
    printed_base: float         # gamma_hat eta^(2(Z+1)), the base printed in eq. delay_bound
    d_star: float | None
    d_t_bound: int | None
    d_star_literal: float       # with the literal omega_min (0 -> -inf)
    meaningful: bool
    note: str
    guaranteed: list = field(default_factory=list)   # [(d, lambda_max bound), ...]

    def lambda_max_bound(self, d: float) -> float:
        """``1 / c(d)``: the paper's guaranteed bound on ``lambda_max(P)`` at delay ``d``."""
        lc = log_cov_bound(d, gamma_hat=self.gamma_hat, eta=self.eta, Z=self.Z,
                           omega_min=self.omega_min, alpha_bar=self.alpha_used,
                           k_minus_s=self.k_minus_s)
        return math.exp(-lc) if -lc < 700 else math.inf

    def log10_lambda_max_bound(self, d: float) -> float:
        lc = log_cov_bound(d, gamma_hat=self.gamma_hat, eta=self.eta, Z=self.Z,
                           omega_min=self.omega_min, alpha_bar=self.alpha_used,
                           k_minus_s=self.k_minus_s)
        return -lc / math.log(10)

    def terms(self) -> dict:
        return asdict(self)


def solve_delay_bound(p_tol: float, *, gamma_hat: float, eta: float, Z: int, omega_min: float,
                      alpha_bar: float, k_minus_s: int = 0) -> tuple[float | None, str]:
    """Real ``d*`` with ``c(d) >= 1/p_tol`` exactly for ``d <= d*`` (see the module docstring)."""
    if p_tol <= 0:
        raise ValueError("p_tol must be > 0")
    ln_b = (Z + 1) * (math.log(gamma_hat) + 2 * math.log(eta))
    ln_C0 = log_cov_bound(0.0, gamma_hat=gamma_hat, eta=eta, Z=Z, omega_min=omega_min,
                          alpha_bar=alpha_bar, k_minus_s=k_minus_s)
    if ln_C0 == -math.inf:
        return -math.inf, "omega_min = 0: the bound on the information is 0, nothing is guaranteed"
    if ln_b >= 0:
        return None, ("gamma_hat eta^2 >= 1: the paper's lower bound does not decrease with the "
                      "delay, so eq. delay_bound gives no upper limit on d_t")
    return (math.log(p_tol) + ln_C0) / (-ln_b), ""


def paper_bound(Phi, Q, omegas, P0, graph, p_tol: float, *, horizon: int = 1000,
                k_minus_s: int = 0) -> PaperBound:
    """The paper's delay bound for a covariance level ``p_tol`` on ``lambda_max(P)``.

    ``omegas``: each sensor's ``H' R^-1 H``; ``graph``: the exchange graph
    (networkx; a DiGraph selects the directed variant: ``alpha`` and
    ``sigma >= n``).
    """
    Phi, Q, P0 = (np.asarray(a, float) for a in (Phi, Q, P0))
    n = graph.number_of_nodes()
    directed = graph.is_directed()
    Omega = information_sum(omegas)
    g = gramian_terms(Phi, Omega, n)
    Z = n + g["n_bar"]
    eta = eta_of(Phi)
    gd = gamma_hat_of(Phi, Q, Omega, P0, horizon)
    gamma_hat = gd["gamma_hat"]
    od = omega_min_of(paper_weight_matrix(graph), Z, sigma_from=n if directed else 1)
    alpha_used = g["alpha"] if directed else g["alpha_bar"]
    kw = dict(gamma_hat=gamma_hat, eta=eta, Z=Z, alpha_bar=alpha_used, k_minus_s=k_minus_s)
    d_star, note = solve_delay_bound(p_tol, omega_min=od["omega_min"], **kw)
    d_lit, _ = solve_delay_bound(p_tol, omega_min=od["omega_min_literal"], **kw)
    ln_C0 = log_cov_bound(0.0, omega_min=od["omega_min"], **kw)
    meaningful = d_star is not None and d_star >= 0
    if d_star is not None and d_star < 0 and not note:
        note = (f"d* = {d_star:.4g} < 0: even without delay the paper's bound guarantees only "
                f"lambda_max(P) <= {math.exp(-ln_C0):.4g}, above the level p_tol = {p_tol:.4g} it is "
                "asked for")
    bound = PaperBound(
        p_tol=float(p_tol), n=n, n_bar=g["n_bar"], Z=Z, alpha=g["alpha"], beta=g["beta"],
        alpha_bar=g["alpha_bar"], beta_bar=g["beta_bar"], alpha_used=alpha_used, eta=eta,
        gamma_hat=gamma_hat, gamma_detail=gd, omega_min=od["omega_min"],
        omega_min_literal=od["omega_min_literal"], omega_detail=od, k_minus_s=k_minus_s,
        directed=directed, ln_C0=ln_C0,
        base=float(math.exp((Z + 1) * (math.log(gamma_hat) + 2 * math.log(eta)))),
        printed_base=float(gamma_hat * eta ** (2 * (Z + 1))),
        d_star=d_star, d_t_bound=int(math.floor(d_star)) if meaningful and d_star is not None else None,
        d_star_literal=d_lit if d_lit is not None else math.nan,
        meaningful=meaningful, note=note)
    bound.guaranteed = [(d, bound.lambda_max_bound(d)) for d in (0, 1, 2, 4, 8)]
    return bound


def paper_bound_for_scenario(scenario, p_tol: float, *, k_minus_s: int = 0) -> PaperBound:
    """:func:`paper_bound` for a scenario: its model, its sensors' information
    and the graph its protocol runs on."""
    omegas = []
    for spec in scenario.sensors:
        if spec.kind != "linear":
            raise ValueError(f"sensor {spec.name} is a {spec.kind} sensor, whose information "
                             "changes with its measurement; the paper's bound assumes linear sensors")
        omegas.append(LinearSensor(spec.H_matrix(), spec.R_matrix()).omega)
    return paper_bound(scenario.model.Phi_matrix(), scenario.model.Q_matrix(), omegas,
                       scenario.prior.cov_matrix(), RunPlan.of(scenario).exchange.graph, p_tol,
                       horizon=int(scenario.steps), k_minus_s=k_minus_s)

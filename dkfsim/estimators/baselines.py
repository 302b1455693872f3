"""Baselines, run on the same draws as the anti-delay DKF.

Every baseline sees the same truth and measurement noise (the same named
streams), and where it has links, the same latency models, so that a
difference in accuracy is the algorithm's alone.  Each is a function of the
finished :class:`~dkfsim.engine.driver.Simulation` returning arrays named
``x_<baseline>`` and ``P_<baseline>``: ``(K, nx)`` for one estimate,
``(K, n, nx)`` for per-node estimates (metrics then average over nodes).

``centralized``
    every measurement on time: the lower bound.  (Measurements that do not
    exist -- a sensor inside a crash window -- are missing from every baseline.)
``centralized_delayed``
    a fusion centre that receives each sensor's packet over a direct link
    with the scenario's default link settings (latency model, loss and link
    faults; streams ``("direct", sensor, ...)``), buffered with the same ``L``.
``local``
    each node filters its own measurements only.
``no_buffer``
    the same exchange with no anti-delay buffer (``L = 1``): information for
    a past tick is dropped.  Reported as its fused estimate (per-node
    estimates when ``fusion: none``).
``ci_consensus``
    consensus on information with Metropolis weights (Battistelli & Chisci
    2014), see :mod:`dkfsim.estimators.ci_consensus`.
"""

from __future__ import annotations

import numpy as np

from dkfsim.estimators.window import WindowFilter, batched_filter, centralized_filter


def measured(sim) -> np.ndarray | None:
    """(K, n) bool: sensor i measured row r (False while it was crashed); None if no crashes."""
    crashes = getattr(sim, "crashes", None)
    if not crashes:
        return None
    return ~crashes.mask(sim.K, sim.system.T_ns).T


def existing_information(sim):
    """``omega`` and ``theta`` of the measurements that exist (crashed sensors measure nothing)."""
    info, m = sim.info, measured(sim)
    if m is None:
        return info.omega, info.theta
    omega = info.omega_per_row() * m[:, :, None, None]
    return omega, info.theta * m[:, :, None]


def centralized(sim) -> dict:
    s = sim.system
    omega, theta = existing_information(sim)
    total = omega.sum(axis=-3)                 # (nx, nx), or (K, nx, nx) per row
    x, P = centralized_filter(s.Phi, s.Q, s.x0_mean, s.P0, total, theta.sum(axis=1))
    return {"x_centralized": x, "P_centralized": P}


def local(sim) -> dict:
    s = sim.system
    omega, theta = existing_information(sim)
    x, P = batched_filter(s.Phi, s.Q, s.x0_mean, s.P0, omega, theta)
    return {"x_local_only": x, "P_local_only": P}


def no_buffer(sim) -> dict:
    from dkfsim.config.schema import load_scenario
    from dkfsim.engine.driver import Simulation
    sc = load_scenario(sim.scenario, overrides=["buffer_length=1", "baselines=[]"])
    res = Simulation(sc, save="estimates").run()
    if "x_fused" in res.arrays:
        return {"x_no_buffer": res["x_fused"], "P_no_buffer": res["P_fused"],
                "_counts_no_buffer": res.counts}
    out = {"x_no_buffer": res["x_local"], "_counts_no_buffer": res.counts}
    if "P_local" in res.arrays:
        out["P_no_buffer"] = res["P_local"]
    return out


def direct_arrival_ticks(sim) -> np.ndarray:
    """Tick (1-based) at which the centre holds sensor i's row r; 0 if it never does.

    ``(n, K)`` int array: the first ``k`` with ``t_k >= t_{r+1} + latency``.
    Each direct link is a :class:`~dkfsim.network.links.Link` with the scenario's
    default link settings (latency model, loss, jitter, schedule, outages,
    duplication: the earlier copy counts) and streams ``("direct", sensor, ...)``.
    """
    from dkfsim.network.links import Link
    s, K = sim.system, sim.K
    T_ns = s.T_ns
    spec = sim.scenario.links.default
    ticks = np.zeros((s.n, K), dtype=np.int64)
    m = measured(sim)
    for i, name in enumerate(s.names):
        link = Link(i, i, -1, spec, sim.seed, T_ns, key=("direct", name))
        for r in range(K):
            sent = (r + 1) * T_ns
            arrivals = link.transmit(sent)
            if arrivals and (m is None or m[r, i]):   # a crashed sensor sends nothing
                ticks[i, r] = -(-(sent + min(arrivals)) // T_ns)
    return ticks


def centralized_delayed(sim) -> dict:
    s, K, L = sim.system, sim.K, sim.L
    w = WindowFilter(s.Phi, s.Q, s.x0_mean, s.P0, sim.info, np.ones((1, s.n)), L)
    ticks = direct_arrival_ticks(sim)
    rows = np.arange(K)
    usable = (ticks > 0) & (ticks <= rows + L) & (ticks <= K)
    order = np.argsort(ticks[usable], kind="stable")
    sensor_idx, row_idx = np.nonzero(usable)
    sensor_idx, row_idx, at = sensor_idx[order], row_idx[order], ticks[usable][order]
    bounds = np.searchsorted(at, np.arange(1, K + 2))
    x = np.empty((K, s.nx))
    P = np.empty((K, s.nx, s.nx))
    for k in range(1, K + 1):
        w.begin_row(k - 1)
        for j in range(bounds[k - 1], bounds[k]):
            w.add(0, int(sensor_idx[j]), int(row_idx[j]))
        w.update(k)
        slot = (k - 1) % w.S
        x[k - 1], P[k - 1] = w.state.x[slot, 0], w.state.P[slot, 0]
    late = int(((ticks > rows + L) & (ticks <= K)).sum())
    return {"x_centralized_delayed": x, "P_centralized_delayed": P, "_late_centralized_delayed": late}


def ci_consensus(sim) -> dict:
    from dkfsim.estimators.ci_consensus import ci_consensus as run_ci
    return run_ci(sim)


BASELINES = {
    "centralized": centralized,
    "centralized_delayed": centralized_delayed,
    "local": local,
    "no_buffer": no_buffer,
    "ci_consensus": ci_consensus,
}

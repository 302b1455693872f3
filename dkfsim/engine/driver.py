"""One run: scenario -> network -> protocol -> filter -> fusion -> results.

:func:`run` wires the pieces together inside one SimPy environment and drives
the ticks (docs/design.md §2): at ``t_k`` every sensor measures and
offers its contribution to the exchange; deliveries and relays at ``t_k``
follow; then, as an event of lower priority than all of them, every node's
window filter updates at once (batched), fusion runs, and the row that
leaves the window becomes final.
"""

from __future__ import annotations

import time

import numpy as np
import simpy
from simpy.events import NORMAL

from dkfsim.estimators.baselines import BASELINES
from dkfsim.components.faults import CrashSchedule
from dkfsim.core.errors import ScenarioError
from dkfsim.estimators.window import WindowFilter
from dkfsim.estimators.fusion import FUSERS, CrossCovariance
from dkfsim.network.links import PRIORITY_UPDATE, Network, Scheduled
from dkfsim.protocols.exchange import PROTOCOLS
from dkfsim.core.resources import check_run
from dkfsim.engine.results import RunResult, resolve_save_mode
from dkfsim.config.schema import Scenario, load_scenario
from dkfsim.model.system import LinearGaussianSystem, LinearSensor
from dkfsim.core.threads import single_thread
from dkfsim.model.trajectory import track_truth
from dkfsim.components.topology import paper_weights


def sensor_model(spec, nx: int | None = None):
    """The measurement model of one scenario sensor (``nx``: the state size,
    which a non-linear sensor needs to build its position selector)."""
    if getattr(spec, "kind", "linear") == "linear":
        return LinearSensor(spec.H_matrix(), spec.R_matrix())
    return spec.sensor_model(nx)


def build_system(scenario) -> LinearGaussianSystem:
    return LinearGaussianSystem(
        Phi=scenario.model.Phi_matrix(),
        Q=scenario.model.Q_matrix(),
        x0_mean=scenario.prior.mean_vector(),
        P0=scenario.prior.cov_matrix(),
        sensors=tuple(sensor_model(s, scenario.nx) for s in scenario.sensors),
        names=tuple(s.name for s in scenario.sensors),
        T_ns=scenario.T_ns,
    )


#: Largest ring of fusion cross-covariances we allocate (bytes).
FUSION_MEMORY_LIMIT = 2 << 30
#: Largest P_local (entries) we keep: 400 MB.
P_LOCAL_LIMIT = 50_000_000


def late_horizon(scenario, n: int, L: int) -> int:
    """How many final rows keep their holdings so that a late contribution counts once.

    Nothing is sent for a final row, so with a latency bound of ``d`` steps per
    hop a late packet arrives at most ``d + 1`` rows after its row became
    final: keep that many.  Unbounded latency: 4096 rows, fewer on large
    networks so that the holdings (n masks of n bits per row) stay near 64 MB.
    """
    bound = scenario.latency_bound_steps()
    if bound is not None:
        return bound + 2
    per_row = n * (n // 8 + 32)
    return int(max(L + 2, min(4096, (64 << 20) // per_row)))


class Simulation:
    """The runtime state of one run (configuration stays in the scenario)."""

    def __init__(self, scenario, *, save: str = "auto", progress=None):
        self.scenario = scenario
        self.K = K = int(scenario.steps)
        self.seed = int(scenario.seed)
        self.system = sys_ = build_system(scenario)
        self.exchange_graph = xg = scenario.exchange()
        self.L, self.d_t = scenario.resolved_buffer_length(), scenario.resolved_d_t()
        n, nx = sys_.n, sys_.nx
        self.save_mode = resolve_save_mode(save, n, K)
        self.progress = progress

        # Everything random but the network is drawn up front, from its own streams.
        if getattr(scenario, "truth", None) is not None:     # a recorded track (dkfsim.model.trajectory)
            self.truth = track_truth(scenario)
        else:
            self.truth = sys_.simulate_truth(K, self.seed)
        self.ys = sys_.simulate_measurements(self.truth, self.seed)
        self.info = sys_.information(self.ys)
        self.A = paper_weights(xg.graph) if scenario.weights == "paper" else np.ones((n, n))

        self.window = WindowFilter(sys_.Phi, sys_.Q, sys_.x0_mean, sys_.P0, self.info, self.A, self.L)
        self.fusion = scenario.fusion
        if self.fusion != "none":
            need = self.window.S * (n * nx) ** 2 * 8
            if need > FUSION_MEMORY_LIMIT:
                raise ScenarioError(
                    f"fusion: {self.fusion} keeps the cross-covariances of all {n} nodes for the "
                    f"{self.window.S} window rows, {need / 2**30:.1f} GiB; use fusion: none for a network "
                    f"this large (or a shorter buffer_length)",
                    source=scenario.source, path="fusion")
        self.xcov = CrossCovariance(self.window, sys_.P0) if self.fusion != "none" else None

        self.env = simpy.Environment()
        self.arrival = np.full((n, n, K), np.inf) if self.save_mode == "full" else None
        self.exchange = PROTOCOLS[scenario.protocol](self.env, n, self.window, arrival=self.arrival,
                                                     late_horizon=late_horizon(scenario, n, self.L))
        # Crash windows (dkfsim.components.faults): a node that is down neither measures nor receives.
        self.crashes = CrashSchedule(getattr(scenario, "faults", None), n) or None
        self.exchange.crashes = self.crashes
        self.network = Network(self.env, xg.arcs, scenario.link_spec, self.seed,
                               sys_.T_ns, self.exchange.receive, crashes=self.crashes)
        self.exchange.attach(self.network)

        self.x_local = np.empty((K, n, nx))
        # P_local is the one (K, n, nx, nx) array: skip it when nothing will save it
        # or when it alone would take more than a few hundred megabytes.
        keep_P = self.save_mode in ("full", "estimates") and K * n * nx * nx <= P_LOCAL_LIMIT
        self.P_local = np.empty((K, n, nx, nx)) if keep_P else None
        self.x_final = np.empty((K, n, nx))
        if self.xcov is not None:
            self.x_fused = np.empty((K, nx))
            self.P_fused = np.empty((K, nx, nx))
        self.k = 0

    # -- the tick driver ---------------------------------------------------------
    def _measure(self, _event) -> None:
        self.k += 1
        row = self.k - 1
        self.exchange.open_row(row)
        self.window.begin_row(row)
        self.exchange.measure(row)
        Scheduled(self.env, self._update, PRIORITY_UPDATE)

    def _update(self, _event) -> None:
        k, L, w = self.k, self.L, self.window
        w.update(k, on_row=self.xcov.on_row if self.xcov is not None else None)
        row = k - 1
        slot = row % w.S
        st = w.state
        self.x_local[row] = st.x[slot]
        if self.P_local is not None:
            self.P_local[row] = st.P[slot]
        if self.xcov is not None:
            self.x_fused[row], self.P_fused[row] = FUSERS[self.fusion](self.xcov.Xi[slot], st.x[slot])
        done = k - L                      # this row leaves the window: final
        if done >= 0:
            self.x_final[done] = st.x[done % w.S]
            self.exchange.close_row(done)
        if self.progress is not None and (k % max(1, self.K // 100) == 0 or k == self.K):
            self.progress(k, self.K)
        if k < self.K:
            Scheduled(self.env, self._measure, NORMAL, self.system.T_ns)

    def run(self) -> RunResult:
        t0 = time.perf_counter()
        # A diverging filter overflows; it is reported (RunResult.diverged), not warned about.
        with np.errstate(all="ignore"):
            Scheduled(self.env, self._measure, NORMAL, self.system.T_ns)
            self.env.run(until=self.K * self.system.T_ns + 1)
            # Rows still in the window at the end were never final: keep their last value.
            st = self.window.state
            for row in range(max(self.K - self.L + 1, 0), self.K):
                self.x_final[row] = st.x[row % self.window.S]
            wall = time.perf_counter() - t0
            return self._result(wall)

    def _result(self, wall: float) -> RunResult:
        sys_, K = self.system, self.K
        arrays = {
            "t": sys_.times(K),
            "truth": self.truth,
            "Phi": sys_.Phi, "Q": sys_.Q, "x0_mean": sys_.x0_mean, "P0": sys_.P0,
        }
        for i in range(sys_.n):
            arrays[f"H_{i}"] = sys_.H[i]
            arrays[f"R_{i}"] = sys_.R[i]
            arrays[f"y_{i}"] = self.ys[i]
            convert = getattr(sys_.sensors[i], "convert", None)
            if convert is not None:
                # A non-linear sensor enters the filters as a converted linear
                # measurement z = H x + noise(Rc[r]): keep both so run.npz alone
                # can recompute every estimate.
                arrays[f"z_{i}"], arrays[f"Rc_{i}"] = convert(self.ys[i])
        arrays["buffer_length"] = np.array(self.L)
        arrays["weights_A"] = self.A
        if self.crashes is not None:      # (n, K): node i was down at row r's tick
            arrays["crashed"] = self.crashes.mask(K, sys_.T_ns)
        if self.arrival is not None:
            arrays["arrival"] = self.arrival
        arrays["x_local"] = self.x_local
        if self.P_local is not None:
            arrays["P_local"] = self.P_local
        arrays["x_final"] = self.x_final
        if self.xcov is not None:
            arrays["x_fused"] = self.x_fused
            arrays["P_fused"] = self.P_fused
        counts = self.network.counts()
        counts.update(self.exchange.counts())
        for entry, late in zip(counts["per_link"], self.exchange.late_packets):
            entry["late_packets"] = late
        for name in self.scenario.baselines:
            for key, val in BASELINES[name](self).items():
                # Underscored keys are side facts (counts), not arrays.
                if key.startswith("_"):
                    counts[key[1:]] = val
                else:
                    arrays[key] = val
        info = {
            "buffer_length": self.L,
            "d_t": self.d_t,
            "d_g": self.exchange_graph.d_g,
            "n_links": len(self.network.links),
            "wall_time_s": wall,
            "save": self.save_mode,
        }
        return RunResult(self.scenario, arrays, counts, info)


@single_thread
def run(scenario, *, seed: int | None = None, steps: int | None = None,
        save: str = "auto", progress=None, yes: bool = False) -> RunResult:
    """Simulate one scenario and return its :class:`~dkfsim.engine.results.RunResult`.

    ``scenario`` is a :class:`~dkfsim.config.schema.Scenario`, a path to a
    scenario file or a mapping.  ``seed`` and ``steps`` override the
    scenario's (the same as ``--set``).  A run that cannot fit in memory
    raises :class:`~dkfsim.core.resources.ResourceError`; one estimated to take
    more than 10 minutes does too unless ``yes`` (:mod:`dkfsim.core.resources`).
    BLAS runs on one thread during the call (:mod:`dkfsim.core.threads`).
    """
    overrides = [f"{key}={int(val)}" for key, val in (("seed", seed), ("steps", steps)) if val is not None]
    if overrides or not isinstance(scenario, Scenario):   # validated exactly as --set would be
        scenario = load_scenario(scenario, overrides=overrides)
    check_run(scenario, save=save, yes=yes)
    with np.errstate(all="ignore"):      # an exploding truth is reported, not warned about
        sim = Simulation(scenario, save=save, progress=progress)
    return sim.run()

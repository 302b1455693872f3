"""The target and its sensors: the linear-Gaussian model of docs/design.md §1.

``x[k+1] = Phi x[k] + w[k]`` with ``w ~ N(0, Q)``, prior ``x[0] ~ N(x0_mean, P0)``
at time 0, and sensor ``i`` measuring ``y_i[k] = H_i x[k] + v_i[k]``,
``v_i ~ N(0, R_i)``, at ticks ``k = 1..K`` (row ``r = k-1``).

This module draws the truth and the measurements (each from its own named
stream, see :mod:`dkfsim.core.streams`) and turns measurements into the
information-form contributions every filter in the package consumes:
``omega_i = H_i' R_i^-1 H_i`` and ``theta_i[r] = H_i' R_i^-1 y_i[r]``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dkfsim.core.registry import SENSOR_KINDS
from dkfsim.core.streams import stream


def psd_factor(S: np.ndarray) -> np.ndarray:
    """A square factor ``F`` with ``F F' = S`` for a symmetric PSD ``S``.

    Cholesky when ``S`` is definite (the usual case, and the cheaper and more
    repeatable one); an eigendecomposition when it is only semidefinite
    (a process noise acting on some states only).
    """
    S = 0.5 * (S + S.T)
    try:
        return np.linalg.cholesky(S)
    except np.linalg.LinAlgError:
        w, V = np.linalg.eigh(S)
        return V * np.sqrt(np.clip(w, 0.0, None))


@SENSOR_KINDS.register("linear")
class LinearSensor:
    """``y = H x + v``, ``v ~ N(0, R)``: its information is the same every row."""

    kind = "linear"

    @classmethod
    def from_params(cls, params, nx: int) -> "LinearSensor":  # noqa: ARG003  (every sensor kind's signature)
        return cls(params.H_matrix(), params.R_matrix())

    def __init__(self, H: np.ndarray, R: np.ndarray):
        self.H = np.asarray(H, float)
        self.R = np.asarray(R, float)
        import scipy.linalg  # (lazy: a run's set-up, not every command, needs it)
        cR = scipy.linalg.cho_factor(self.R, lower=True)
        # H' R^-1 via a Cholesky solve rather than an explicit inverse.
        self.gain = scipy.linalg.cho_solve(cR, self.H).T
        om = self.gain @ self.H
        self.omega = 0.5 * (om + om.T)
        # U = H' L^-T with R = L L', so U U' = H' R^-1 H (used by the fusion recursion).
        self.factor = scipy.linalg.solve_triangular(np.linalg.cholesky(self.R), self.H, lower=True).T

    @property
    def m(self) -> int:
        return self.H.shape[0]

    def simulate(self, truth: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        v = rng.standard_normal((truth.shape[0], self.m)) @ psd_factor(self.R).T
        return truth @ self.H.T + v

    def information(self, y: np.ndarray):
        """``theta`` (K, nx), ``omega`` (nx, nx), factor (nx, m): static."""
        return y @ self.gain.T, self.omega, self.factor


@dataclass(frozen=True)
class Information:
    """The information-form contributions of all sensors for all rows.

    ``omega`` and ``factor`` (``U`` with ``U U' = sum omega``, columns by
    sensor) are static arrays when every sensor is linear, and per-row arrays
    (leading axis K) when some sensor's information changes with its
    measurement (a converted radar measurement).
    """

    theta: np.ndarray            # (K, n, nx)
    omega: np.ndarray            # (n, nx, nx) or (K, n, nx, nx)
    factor: np.ndarray           # (nx, M) or (K, nx, M)
    column_sensor: np.ndarray    # (M,)

    @property
    def varying(self) -> bool:
        return self.omega.ndim == 4

    def omega_of(self, rows: np.ndarray, origins: np.ndarray) -> np.ndarray:
        """``omega`` of each (row, origin) pair, shape (len, nx, nx)."""
        return self.omega[rows, origins] if self.varying else self.omega[origins]

    def factor_row(self, row: int) -> np.ndarray:
        return self.factor[row] if self.varying else self.factor

    def omega_per_row(self) -> np.ndarray:
        """(K, n, nx, nx), materialised (only for small problems and baselines)."""
        if self.varying:
            return self.omega
        return np.broadcast_to(self.omega, (self.theta.shape[0],) + self.omega.shape)


@dataclass(frozen=True)
class LinearGaussianSystem:
    """The model as simulated: the target's matrices and the sensor models."""

    Phi: np.ndarray
    Q: np.ndarray
    x0_mean: np.ndarray
    P0: np.ndarray
    sensors: tuple
    names: tuple[str, ...]
    T_ns: int

    @property
    def n(self) -> int:
        return len(self.sensors)

    @property
    def nx(self) -> int:
        return self.Phi.shape[0]

    @property
    def T(self) -> float:
        return self.T_ns / 1e9

    @property
    def H(self) -> tuple[np.ndarray, ...]:
        return tuple(s.H for s in self.sensors)

    @property
    def R(self) -> tuple[np.ndarray, ...]:
        return tuple(s.R for s in self.sensors)

    @property
    def omega(self) -> np.ndarray:
        """(n, nx, nx) static information matrices; only when every sensor is linear
        (otherwise use the per-row :class:`Information` of a run)."""
        if not all(isinstance(s, LinearSensor) for s in self.sensors):
            raise TypeError("sensor information varies per row: use Simulation.info")
        return np.array([s.omega for s in self.sensors])

    def times(self, K: int) -> np.ndarray:
        """Sample times ``t_k = k T`` of rows ``0..K-1``, exactly ``k*T_ns/1e9``."""
        return (np.arange(1, K + 1, dtype=np.int64) * self.T_ns) / 1e9

    def simulate_truth(self, K: int, seed: int) -> np.ndarray:
        """True states at ticks 1..K, shape (K, nx), from the ``("truth",)`` stream."""
        rng = stream(seed, "truth")
        z = rng.standard_normal((K + 1, self.nx))
        x = self.x0_mean + psd_factor(self.P0) @ z[0]
        w = z[1:] @ psd_factor(self.Q).T
        out = np.empty((K, self.nx))
        for k in range(K):
            x = self.Phi @ x + w[k]
            out[k] = x
        return out

    def simulate_measurements(self, truth: np.ndarray, seed: int) -> list[np.ndarray]:
        """``y_i`` for every sensor, each (K, m_i), from stream ``("sensor", name)``."""
        return [s.simulate(truth, stream(seed, "sensor", name)) for name, s in zip(self.names, self.sensors)]

    def information(self, ys: list[np.ndarray]) -> Information:
        """Every sensor's contribution for every row."""
        parts = [s.information(y) for s, y in zip(self.sensors, ys)]
        theta = np.stack([p[0] for p in parts], axis=1)
        owner = np.concatenate([[i] * p[2].shape[-1] for i, p in enumerate(parts)]).astype(np.intp)
        if all(p[1].ndim == 2 for p in parts):
            omega = np.array([p[1] for p in parts])
            factor = np.concatenate([p[2] for p in parts], axis=1)
        else:
            K = theta.shape[0]
            omega = np.stack([np.broadcast_to(p[1], (K,) + p[1].shape[-2:]) for p in parts], axis=1)
            factor = np.concatenate([np.broadcast_to(p[2], (K,) + p[2].shape[-2:]) for p in parts], axis=2)
        return Information(theta=theta, omega=np.ascontiguousarray(omega),
                           factor=np.ascontiguousarray(factor), column_sensor=owner)


def build_system(scenario) -> LinearGaussianSystem:
    """The model as simulated: matrices and each sensor's implementation (by its kind)."""
    return LinearGaussianSystem(
        Phi=scenario.model.Phi_matrix(),
        Q=scenario.model.Q_matrix(),
        x0_mean=scenario.prior.mean_vector(),
        P0=scenario.prior.cov_matrix(),
        sensors=tuple(SENSOR_KINDS.get(s.kind).implementation.from_params(s, scenario.nx)
                      for s in scenario.sensors),
        names=tuple(s.name for s in scenario.sensors),
        T_ns=scenario.T_ns,
    )

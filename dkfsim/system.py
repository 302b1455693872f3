"""The target and its sensors: the linear-Gaussian model of DESIGN.md section 1.

``x[k+1] = Phi x[k] + w[k]`` with ``w ~ N(0, Q)``, prior ``x[0] ~ N(x0_mean, P0)``
at time 0, and sensor ``i`` measuring ``y_i[k] = H_i x[k] + v_i[k]``,
``v_i ~ N(0, R_i)``, at ticks ``k = 1..K`` (row ``r = k-1``).

This module draws the truth and the measurements (each from its own named
stream, see :mod:`dkfsim.streams`) and turns measurements into the
information-form contributions every filter in the package consumes:
``omega_i = H_i' R_i^-1 H_i`` and ``theta_i[r] = H_i' R_i^-1 y_i[r]``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.linalg

from .streams import stream


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


@dataclass(frozen=True)
class LinearGaussianSystem:
    """The model as simulated: matrices only, no randomness."""

    Phi: np.ndarray
    Q: np.ndarray
    x0_mean: np.ndarray
    P0: np.ndarray
    H: tuple[np.ndarray, ...]
    R: tuple[np.ndarray, ...]
    names: tuple[str, ...]
    T_ns: int
    # Derived once: information contributions and a factor of each omega.
    omega: np.ndarray = field(init=False, repr=False)     # (n, nx, nx)
    gain: tuple[np.ndarray, ...] = field(init=False, repr=False)  # H_i' R_i^-1, (nx, m_i)
    omega_factor: np.ndarray = field(init=False, repr=False)  # (nx, M): U U' = sum of omegas, columns by sensor
    column_sensor: np.ndarray = field(init=False, repr=False)  # (M,) sensor of each column of omega_factor

    def __post_init__(self):
        gains, omegas, factors, owner = [], [], [], []
        for i, (H, R) in enumerate(zip(self.H, self.R)):
            # H' R^-1 via a Cholesky solve rather than an explicit inverse.
            cR = scipy.linalg.cho_factor(R, lower=True)
            HtRi = scipy.linalg.cho_solve(cR, H).T
            gains.append(HtRi)
            om = HtRi @ H
            omegas.append(0.5 * (om + om.T))
            # U_i = H' L^-T with R = L L', so U_i U_i' = H' R^-1 H.
            Lr = np.linalg.cholesky(R)
            factors.append(scipy.linalg.solve_triangular(Lr, H, lower=True).T)
            owner.extend([i] * H.shape[0])
        object.__setattr__(self, "gain", tuple(gains))
        object.__setattr__(self, "omega", np.array(omegas))
        object.__setattr__(self, "omega_factor", np.concatenate(factors, axis=1))
        object.__setattr__(self, "column_sensor", np.array(owner, dtype=np.intp))

    @property
    def n(self) -> int:
        return len(self.H)

    @property
    def nx(self) -> int:
        return self.Phi.shape[0]

    @property
    def T(self) -> float:
        return self.T_ns / 1e9

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
        ys = []
        for name, H, R in zip(self.names, self.H, self.R):
            rng = stream(seed, "sensor", name)
            v = rng.standard_normal((truth.shape[0], H.shape[0])) @ psd_factor(R).T
            ys.append(truth @ H.T + v)
        return ys

    def contributions(self, ys: list[np.ndarray]) -> np.ndarray:
        """``theta[r, i] = H_i' R_i^-1 y_i[r]``, shape (K, n, nx)."""
        return np.stack([y @ g.T for y, g in zip(ys, self.gain)], axis=1)

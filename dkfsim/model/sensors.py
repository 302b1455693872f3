"""Non-linear sensor models, used through converted measurements.

A radar measures the range and azimuth of the target relative to its own
position::

    y = [ hypot(x - px, y - py),  atan2(y - py, x - px) ] + v,   v ~ N(0, diag(sr^2, sa^2))

(azimuth in radians, counter-clockwise from the +x axis; ``state_index``
says which state components are the Cartesian position).

The filters of this package exchange *additive* information contributions
(docs/design.md §6).  An extended (linearised) information update would
linearise at each node's own estimate, so the same measurement would give a
different contribution at every node and the exact exchange (and its test
oracle) would no longer hold.  Instead the radar's measurement is *converted*
to a Cartesian position, which is a linear measurement of the state with a
covariance of its own per row (the "converted measurement Kalman filter")::

    z   = p + r [cos a, sin a]
    R_c = J diag(sr^2, sa^2) J',   J = d z / d(r, a) = [[cos a, -r sin a], [sin a, r cos a]]

evaluated at the *measured* ``r, a`` (so the contribution depends on the
measurement only, not on any estimate).  Written with the rotation
``G = [[cos a, -sin a], [sin a, cos a]]``, ``R_c = G diag(sr^2, (r sa)^2) G'``,
hence ``R_c^-1 = U2 U2'`` with ``U2 = G diag(1/sr, 1/(|r| sa))``: the
information and its factor have closed forms, no per-row Cholesky.

docs/radar.md explains why the plain (not debiased) conversion is used: the
conversion bias ``~ r sa^2 / 2`` is below a hundredth of ``sr`` for the
ranges and accuracies of the radar scenarios.
"""

from __future__ import annotations

import numpy as np

from dkfsim.core.registry import SENSOR_KINDS


@SENSOR_KINDS.register("radar")
class RadarSensor:
    """Range/azimuth radar at ``position``, handled as a converted measurement.

    :param position: (2,) the radar's Cartesian position (m).
    :param sigma_range: standard deviation of the range noise (m), > 0.
    :param sigma_azimuth: standard deviation of the azimuth noise (rad), > 0.
    :param nx: state dimension.
    :param state_index: the state components that are the Cartesian x and y.

    ``H`` (2, nx) selects the position and ``R = diag(sr^2, sa^2)`` is the
    covariance of the *polar* noise (what is written to ``run.npz`` as
    ``H_i``, ``R_i``; ``y_i`` holds the polar measurements).  The converted
    measurement and its covariance are :meth:`convert`.
    """

    kind = "radar"

    @classmethod
    def from_params(cls, params, nx: int) -> "RadarSensor":
        return cls(params.position, params.sigma_range, params.sigma_azimuth, nx, params.state_index)

    def __init__(self, position, sigma_range: float, sigma_azimuth: float, nx: int,
                 state_index=(0, 2)):
        self.position = np.asarray(position, float).reshape(2)
        self.sigma_range = float(sigma_range)
        self.sigma_azimuth = float(sigma_azimuth)
        if not (self.sigma_range > 0 and self.sigma_azimuth > 0):
            raise ValueError("sigma_range and sigma_azimuth must be > 0")
        self.nx = int(nx)
        self.state_index = tuple(int(i) for i in state_index)
        ix, iy = self.state_index
        if ix == iy or not (0 <= ix < self.nx and 0 <= iy < self.nx):
            raise ValueError(f"state_index {list(self.state_index)} must be two distinct "
                             f"indices in 0..{self.nx - 1}")
        self.H = np.zeros((2, self.nx))
        self.H[0, ix] = 1.0
        self.H[1, iy] = 1.0
        self.R = np.diag([self.sigma_range ** 2, self.sigma_azimuth ** 2])

    @property
    def m(self) -> int:
        return 2

    # -- the measurement --------------------------------------------------------
    def polar(self, truth: np.ndarray) -> np.ndarray:
        """Noise-free ``[range, azimuth]`` of each row of ``truth`` (K, nx)."""
        d = np.asarray(truth, float) @ self.H.T - self.position
        return np.column_stack([np.hypot(d[:, 0], d[:, 1]), np.arctan2(d[:, 1], d[:, 0])])

    def simulate(self, truth: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """``y`` (K, 2): range and azimuth plus noise, drawn as a linear sensor draws
        (``K x 2`` standard normals times the noise's Cholesky factor)."""
        v = rng.standard_normal((truth.shape[0], 2)) * np.array([self.sigma_range, self.sigma_azimuth])
        return self.polar(truth) + v

    # -- the conversion -----------------------------------------------------------
    def _rotation_and_scales(self, y: np.ndarray):
        y = np.atleast_2d(np.asarray(y, float))
        r, a = y[:, 0], y[:, 1]
        c, s = np.cos(a), np.sin(a)
        G = np.empty((len(r), 2, 2))
        G[:, 0, 0], G[:, 0, 1], G[:, 1, 0], G[:, 1, 1] = c, -s, s, c
        cross = np.abs(r) * self.sigma_azimuth          # cross-range standard deviation
        if np.any(cross == 0.0):
            k = int(np.argmax(cross == 0.0))
            raise ValueError(f"radar: measured range {r[k]!r} at row {k} is 0; a converted "
                             "measurement needs the target away from the radar")
        std = np.column_stack([np.full(len(r), self.sigma_range), cross])
        return r, c, s, G, std

    def convert(self, y: np.ndarray):
        """Converted measurements ``z`` (K, 2) and their covariances ``R_c`` (K, 2, 2)."""
        r, c, s, G, std = self._rotation_and_scales(y)
        z = self.position + r[:, None] * np.column_stack([c, s])
        Rc = (G * std[:, None, :] ** 2) @ np.swapaxes(G, 1, 2)
        return z, 0.5 * (Rc + np.swapaxes(Rc, 1, 2))

    def information(self, y: np.ndarray):
        """Per-row ``theta`` (K, nx), ``omega`` (K, nx, nx), ``factor`` (K, nx, 2).

        ``omega = H' R_c^-1 H``, ``theta = H' R_c^-1 z`` and ``U = H' G
        diag(1/sr, 1/(|r| sa))`` with ``U U' = omega``.
        """
        r, c, s, G, std = self._rotation_and_scales(y)
        z = self.position + r[:, None] * np.column_stack([c, s])
        U2 = G / std[:, None, :]                          # (K, 2, 2): R_c^-1 = U2 U2'
        W = U2 @ np.swapaxes(U2, 1, 2)                    # R_c^-1
        W = 0.5 * (W + np.swapaxes(W, 1, 2))
        K = len(r)
        idx = list(self.state_index)
        theta = np.zeros((K, self.nx))
        theta[:, idx] = np.einsum("kij,kj->ki", W, z)
        omega = np.zeros((K, self.nx, self.nx))
        omega[:, idx[0], idx] = W[:, 0]
        omega[:, idx[1], idx] = W[:, 1]
        factor = np.zeros((K, self.nx, 2))
        factor[:, idx, :] = U2
        return theta, omega, factor

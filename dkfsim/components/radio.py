"""A spatial radio (``medium.radio``, issue 32; docs/radio.md): what a frame sent at one place is
worth at another.

Without ``medium.radio`` the shared channel is one collision domain: every member hears every
other.  With it, every frame reaches every other member with a received power

``P_rx = power - path_loss(d) - X_shadowing + F_fading``  (dBm; ``d`` the pair's distance),

and each receiver decides for itself (:mod:`dkfsim.network.media.radio`): a frame below
``sensitivity`` is not detected, one above ``carrier_sense`` makes the receiver sense the channel
busy, and a frame it locks on is received by the ``reception`` rule from its SINR over the frame
(interference summed over every overlapping frame, or those at or above ``interference_floor``).
Each part below is a small declarative model, chosen by its ``model`` key; :func:`path_loss_db`
and :func:`fading_db` evaluate them, vectorised over receivers: the references the radio's
compiled forms are tested against (the reception rule is the radio's kernel's,
:func:`dkfsim.network.radio_kernels.error_rate`).

Units: powers in dBm, gains and losses in dB, distances in metres, frequencies in Hz.
"""

from __future__ import annotations

import functools
import math
from typing import Annotated, Literal, Union

import numpy as np
from pydantic import Field, field_validator, model_validator

from dkfsim.core.params import StrictModel, custom_error

#: The speed of light (m/s).
C_LIGHT = 299_792_458.0
#: Shortest distance a path-loss model is evaluated at (m): two antennas are not closer.
MIN_DISTANCE_M = 1.0

#: A power, a gain or a threshold in dB or dBm: far beyond any radio either way.
Decibel = Annotated[float, Field(strict=True, ge=-400.0, le=400.0, allow_inf_nan=False)]
#: A length of the radio's geometry (m).
Metres = Annotated[float, Field(strict=True, gt=0, le=1e7, allow_inf_nan=False)]


# ----------------------------------------------------------------------- path loss
class NoLoss(StrictModel):
    """No path loss: every receiver gets the transmit power (the one-collision-domain limit)."""

    model: Literal["none"] = "none"


class FreeSpace(StrictModel):
    """Friis free space: ``20 log10(4 pi d f / c)``."""

    model: Literal["free_space"] = "free_space"


class LogDistance(StrictModel):
    """``reference_loss + 10 exponent log10(d / reference_distance)`` (the reference loss: free
    space at the reference distance when not given)."""

    model: Literal["log_distance"] = "log_distance"
    exponent: Annotated[float, Field(strict=True, gt=0, le=10, allow_inf_nan=False)] = 3.0
    reference_distance: Metres = 1.0
    reference_loss: Decibel | None = None


class TwoRayInterference(StrictModel):
    """The two-ray ground-reflection model with interference of the two rays (Sommer et al.,
    "Using the Right Two-Ray Model?", IEEE VNC 2011; Veins' ``TwoRayInterferenceModel``): both
    antennas ``height`` m above a ground of relative permittivity ``permittivity``."""

    model: Literal["two_ray_interference"] = "two_ray_interference"
    height: Metres = 1.895
    permittivity: Annotated[float, Field(strict=True, ge=1, le=100, allow_inf_nan=False)] = 1.02


class WinnerB1(StrictModel):
    """WINNER+ B1 (urban micro), line of sight (IST-WINNER II D1.1.2, table 4-4), the model of
    the analytic 802.11p reference (Sepulcre et al. 2022): ``22.7 log10 d + 27 + 20 log10 f_GHz``
    up to the breakpoint ``4 h' h' f / c`` (``h' = height - environment_height``, both antennas at
    ``height``), ``40 log10 d + 7.56 - 34.6 log10 h' + 2.7 log10 f_GHz`` beyond it.  WINNER's
    environment height is 1 m; the analytic reference's vehicles, 1.5 m antennas over 0.5 m."""

    model: Literal["winner_b1"] = "winner_b1"
    height: Annotated[float, Field(strict=True, gt=0, le=1e3, allow_inf_nan=False)] = 1.5
    environment_height: Annotated[float, Field(strict=True, ge=0, le=1e3, allow_inf_nan=False)] = 1.0

    @model_validator(mode="after")
    def _above(self) -> WinnerB1:
        if self.height <= self.environment_height:
            raise custom_error(f"the antennas ({self.height} m) must be above the environment height "
                               f"({self.environment_height} m)", "height")
        return self


PathLoss = Annotated[Union[NoLoss, FreeSpace, LogDistance, TwoRayInterference, WinnerB1],
                     Field(discriminator="model")]


# ----------------------------------------------------------------------- shadowing, fading
class NoShadowing(StrictModel):
    """No shadowing."""

    model: Literal["none"] = "none"


class Lognormal(StrictModel):
    """Log-normal shadowing: a normal draw of ``sigma`` dB, per frame and receiver."""

    model: Literal["lognormal"] = "lognormal"
    sigma: Annotated[float, Field(strict=True, ge=0, le=50, allow_inf_nan=False)]


Shadowing = Annotated[Union[NoShadowing, Lognormal], Field(discriminator="model")]


class NoFading(StrictModel):
    """No fading."""

    model: Literal["none"] = "none"


class Nakagami(StrictModel):
    """Nakagami-m fading: the received power times a gamma draw of shape ``m`` and mean 1, per
    frame and receiver (``m = 1``: Rayleigh)."""

    model: Literal["nakagami"] = "nakagami"
    m: Annotated[float, Field(strict=True, ge=0.5, le=1e3, allow_inf_nan=False)] = 1.0


Fading = Annotated[Union[NoFading, Nakagami], Field(discriminator="model")]


# ----------------------------------------------------------------------- reception
class Threshold(StrictModel):
    """A frame is received when its SINR stays at or above ``sinr`` dB over the whole frame."""

    model: Literal["threshold"] = "threshold"
    sinr: Decibel = 8.0


class PerTable(StrictModel):
    """A frame's packet error rate against its SINR (dB): ``[[sinr_db, per], ...]``, SINR
    strictly increasing, linear in between, held beyond the ends.  Over a frame whose
    interference changes, the chunks multiply: success ``prod (1 - PER(sinr_i))^(len_i / len)``."""

    model: Literal["per_table"] = "per_table"
    table: list[tuple[Decibel, Annotated[float, Field(strict=True, ge=0, le=1, allow_inf_nan=False)]]]

    @field_validator("table")
    @classmethod
    def _increasing(cls, table: list) -> list:
        if not table:
            raise custom_error("give at least one [sinr_db, per] point")
        s = [p[0] for p in table]
        if any(b <= a for a, b in zip(s, s[1:])):
            raise custom_error(f"the SINR points must strictly increase, got {s[:8]}")
        return table


Reception = Annotated[Union[Threshold, PerTable], Field(discriminator="model")]


class DistanceBins(StrictModel):
    """The bins of ``pdr_by_distance``: ``[0, width), [width, 2 width), ...`` up to ``max`` m."""

    width: Metres = 25.0
    max: Metres = 1000.0

    @model_validator(mode="after")
    def _few(self) -> DistanceBins:
        if self.max / self.width > 10_000:
            raise custom_error(f"{self.max / self.width:.0f} bins of {self.width} m up to {self.max} m: "
                               "give at most 10000 (a wider bin or a shorter max)", "width")
        return self

    def edges(self) -> np.ndarray:
        n = max(1, int(math.ceil(self.max / self.width - 1e-9)))
        return np.arange(n + 1) * self.width


class RadioParams(StrictModel):
    """``medium.radio``: transmit power, carrier, noise, thresholds and the propagation models
    (defaults: ITS-G5 at 5.9 GHz, 10 MHz channel)."""

    #: dBm
    power: Decibel = 23.0
    #: Hz
    frequency: Annotated[float, Field(strict=True, gt=0, le=1e12, allow_inf_nan=False)] = 5.9e9
    #: the noise floor (dBm): thermal noise over 10 MHz (-104 dBm) plus a 9 dB noise figure
    noise: Decibel = -95.0
    #: below it a frame is not detected (dBm): the receiver neither locks on it nor senses it
    sensitivity: Decibel = -92.0
    #: at or above it a frame makes the receiver sense the channel busy (dBm)
    carrier_sense: Decibel = -85.0
    #: a frame received below it adds nothing to the interference (dBm; at most ``sensitivity``);
    #: None: every frame does.  ``sensitivity`` is ns-3's YansWifiChannel, which drops frames
    #: below the sensitivity before the PHY
    interference_floor: Decibel | None = None
    path_loss: PathLoss = Field(default_factory=LogDistance)
    shadowing: Shadowing = Field(default_factory=NoShadowing)
    fading: Fading = Field(default_factory=NoFading)
    reception: Reception = Field(default_factory=Threshold)
    #: a receiver locked on a frame switches to a later one at least this many dB stronger (the
    #: earlier is then lost); None: it stays on the first frame it locked on (ns-3's default)
    capture: Annotated[float, Field(strict=True, ge=0, le=400, allow_inf_nan=False)] | None = None
    #: with ``capture``: it switches only to a frame starting at most this many seconds after the
    #: one it locked on (ns-3's SimpleFrameCaptureModel: 20e-6, its 4 us preamble detection and
    #: 16 us CaptureWindow); None: at any time during that frame
    capture_window: Annotated[float, Field(strict=True, ge=0, le=1.0, allow_inf_nan=False)] | None = None
    bins: DistanceBins = Field(default_factory=DistanceBins)

    @model_validator(mode="after")
    def _consistent(self) -> RadioParams:
        if self.interference_floor is not None and self.interference_floor > self.sensitivity:
            raise custom_error(f"{self.interference_floor} dBm is above the sensitivity ({self.sensitivity} dBm): a "
                               "frame a receiver locks on would not count in its own sum of power on the air; give "
                               "at most the sensitivity", "interference_floor")
        if self.capture_window is not None and self.capture is None:
            raise custom_error("a capture window needs capture (the margin in dB a later frame must exceed)",
                               "capture_window")
        return self


# ----------------------------------------------------------------------- evaluation
def path_loss_db(model: object, d: np.ndarray, frequency: float) -> np.ndarray:
    """The path loss (dB) of ``model`` at distances ``d`` (m; at least :data:`MIN_DISTANCE_M`)."""
    d = np.maximum(np.asarray(d, dtype=np.float64), MIN_DISTANCE_M)
    if isinstance(model, NoLoss):
        return np.zeros_like(d)
    if isinstance(model, FreeSpace):
        return 20.0 * np.log10(4.0 * math.pi * d * frequency / C_LIGHT)
    if isinstance(model, LogDistance):
        d0 = model.reference_distance
        ref = model.reference_loss if model.reference_loss is not None else \
            20.0 * math.log10(4.0 * math.pi * d0 * frequency / C_LIGHT)
        return ref + 10.0 * model.exponent * np.log10(np.maximum(d, d0) / d0)
    if isinstance(model, TwoRayInterference):
        return _two_ray(d, frequency, model.height, model.permittivity)
    if isinstance(model, WinnerB1):
        return _winner_b1(d, frequency, model.height - model.environment_height)
    raise TypeError(f"no path-loss model {type(model).__name__}")


def _two_ray(d: np.ndarray, f: float, h: float, eps: float) -> np.ndarray:
    lam = C_LIGHT / f
    d_los = np.sqrt(d * d)                      # both antennas at one height
    d_ref = np.sqrt(d * d + (2.0 * h) ** 2)
    sin_t, cos_t = 2.0 * h / d_ref, d / d_ref
    root = np.sqrt(eps - cos_t * cos_t)
    gamma = (sin_t - root) / (sin_t + root)
    phi = 2.0 * math.pi * (d_los - d_ref) / lam
    amp = np.abs(1.0 / d_los + gamma * np.exp(1j * phi) / d_ref)
    gain = (lam / (4.0 * math.pi)) ** 2 * amp * amp
    return -10.0 * np.log10(np.maximum(gain, 1e-300))


def _winner_b1(d: np.ndarray, f: float, he: float) -> np.ndarray:
    f_ghz = f / 1e9
    d_bp = 4.0 * he * he * f / C_LIGHT
    log_d = np.log10(d)
    near = 22.7 * log_d + (27.0 + 20.0 * math.log10(f_ghz))
    far = 40.0 * log_d + (7.56 - 34.6 * math.log10(he) + 2.7 * math.log10(f_ghz))
    return np.where(d < d_bp, near, far)


def normal_quantiles(u: np.ndarray) -> np.ndarray:
    """``Phi^-1(u)``: the standard normal quantiles of uniform draws (what fading is drawn from;
    the radio's kernels compute the same bits, :func:`~dkfsim.network.radio_kernels.ndtri`)."""
    from scipy.special import ndtri  # (lazy: validating a scenario needs no scipy)
    return ndtri(u)


#: The grid of :func:`nakagami_table`: the standard normal quantile ``z = Phi^-1(u)`` from ``-Z_MAX``
#: to ``Z_MAX`` in steps of ``1 / Z_STEPS`` (a keyed uniform is at least 2^-53: ``|z| < 8.3``).
Z_MAX, Z_STEPS = 9.0, 128


@functools.lru_cache(maxsize=16)
def nakagami_table(m: float) -> np.ndarray:
    """The Nakagami-m power gain (gamma of shape ``m``, scale ``1/m``) in dB at the uniform grid of
    ``z`` (:data:`Z_MAX`, :data:`Z_STEPS`: 2,305 points, 18 kB), worked out once per ``m``.  In
    ``z`` the dB gain is smooth (near quadratic in the tails), so linear interpolation on a uniform
    grid is within 1e-4 dB of ``gammaincinv`` for m >= 0.5 (tests/test_radio.py holds it to 1e-3 dB),
    and the table stays in cache."""
    from scipy.special import gammainccinv, gammaincinv, ndtr  # (lazy: scipy.special only where fading draws)
    z = np.linspace(-Z_MAX, Z_MAX, int(2 * Z_MAX * Z_STEPS) + 1)
    # (the upper half from its tail probability: ndtr(z) rounds to 1 there)
    g = np.where(z <= 0, gammaincinv(m, ndtr(np.minimum(z, 0))), gammainccinv(m, ndtr(-np.maximum(z, 0)))) / m
    return 10.0 * np.log10(np.maximum(g, 1e-300))


def fading_table(model: object) -> np.ndarray:
    """``model``'s fading gain (dB) on :func:`nakagami_table`'s grid of normal quantiles (what the
    radio's kernel interpolates); no fading: an empty table."""
    if isinstance(model, Nakagami):
        return nakagami_table(float(model.m))
    return np.zeros(0)


def fading_db(model: object, u: np.ndarray, z: np.ndarray | None = None) -> np.ndarray:
    """The fading gain (dB) from uniform draws ``u`` in (0, 1) (or their normal quantiles ``z``,
    when the caller has them): the power gain of Nakagami-m is gamma of shape ``m`` and scale
    ``1/m``, drawn by its inverse CDF, tabulated against the normal quantile of ``u``
    (:func:`nakagami_table`): a point found by arithmetic, not a search."""
    if isinstance(model, Nakagami):
        if z is None:
            z = normal_quantiles(u)
        table = nakagami_table(float(model.m))
        x = (np.clip(z, -Z_MAX, Z_MAX) + Z_MAX) * Z_STEPS
        i = np.minimum(x.astype(np.int64), len(table) - 2)
        w = x - i
        lo = table[i]
        return lo + w * (table[i + 1] - lo)
    return np.zeros(len(u))

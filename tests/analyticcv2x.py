"""The analytic model of LTE-V2X (C-V2X) mode 4 sidelink broadcast of Gonzalez-Martin, Sepulcre,
Molina-Masegosa and Gozalvez, "Analytical Models of the Performance of C-V2X Mode 4 Vehicular
Communications", IEEE Trans. Veh. Technol. 68(2):1155-1166, 2019, doi 10.1109/TVT.2018.2888704
(post-print arXiv 1807.06508): the packet delivery ratio against the transmitter-receiver
distance and the probability of each of its four errors, on a straight road of equally spaced
vehicles each broadcasting ``lam`` packets per second of a fixed size with sensing-based
semi-persistent scheduling (SB-SPS).

An independent truth for a coming C-V2X radio access in dkfsim: nothing here imports
:mod:`dkfsim`.  Written from the paper's equations, as plain numpy/scipy.  The equation numbers
are those the authors' public implementation (github.com/msepulcre/C-V2X, GPL-3.0, commit
71d4c25) writes beside each equation it evaluates; the paper's text itself was not reachable
from here, so where the implementation is the only statement of an equation it is named as
the source.  No line of it is copied.  Our one numerical choice (as in tests/analytic80211p.py):
every expectation over log-normal shadowing is a sum over the exact probability masses of a
0.05 dB grid (differences of the normal CDF), where the authors correlate densities sampled
every 0.1 dB.

The model (a receiver ``r`` at 0, the transmitter ``t`` at distance ``d``, every other vehicle
``i`` on the lattice ``k / beta`` a potential interferer):

- a packet is lost for one of four reasons, in this order: ``half_duplex`` (``r`` transmits in
  the same subframe), ``sensing`` (the packet arrives below the sensing power threshold),
  ``propagation`` (it fails without interference) and ``collision`` (it fails only because
  another vehicle transmits on the same sub-channel(s) of the same subframe);
  eqs (6.1)-(6.5): ``HD = dHD``, ``SEN = dSEN (1 - dHD)``, ``PRO = dPRO (1 - dHD)(1 - dSEN)``,
  ``COL = dCOL (1 - dHD)(1 - dSEN)(1 - dPRO)``; eq. (6): ``PDR = 1 - HD - SEN - PRO - COL``,
  which is the product of the complements ``(1 - dHD)(1 - dSEN)(1 - dPRO)(1 - dCOL)``;
- every received power is ``P_t - PL(d) - X``, ``X`` a normal shadowing of ``sigma`` dB drawn
  independently per packet and link;
- a collision needs the interferer to hold the same resource as the transmitter (``p_sim``,
  from the resources each excludes after sensing) and its interference to break a packet that
  would otherwise be received (``p_int``); eqs (14), (15);
- the collisions are modelled twice: as if a vehicle picked at random among all the resources
  left after the exclusion of Step 2 (eq. (23)), and as if it picked among the 20 % of
  resources its Step 3 keeps (eq. (31)); the two are weighted by the channel load (eqs (21),
  (22)).

Parameters and their sources (the paper's equation numbers as the implementation labels them;
"impl." where only the implementation states the value):

==========================  ==========================================================  =========
quantity                    value                                                       source
==========================  ==========================================================  =========
path loss                   WINNER+ B1 LOS, f = 5.91 GHz, both antennas 1.5 m, no       impl.
                            environment height (effective heights 1.5 m, breakpoint     get_PL_SH
                            4 h h f / c = 177.3 m), floored at free space, d >= 3 m
shadowing sigma             3 dB, log-normal, the same for every link                   impl.
road, density beta          one line of vehicles 1 / beta m apart; 0.1, 0.2, 0.3        run_all
                            vehicles/m (100, 200, 300 per km)
packets                     190 bytes, lam = 10 or 20 Hz, periodic                      run_all
transmit power P_t          20 or 23 dBm                                                run_all
sensing threshold P_sen     -90.5 dBm (a packet below it is not received: eq. (10))     impl.
noise                       -95 dBm over the 50 RBs of 10 MHz (9 dB noise figure),      impl.
                            scaled to the RBs of the data: -95 - 10 log10(50 / RBs)
MCS / sub-channels S        190 B: S = 4 -> QPSK r = 0.7 in 10 data RBs (BLER table     impl.
                            ``QPSK_R07``); S = 2 -> QPSK r = 0.5, 12 RBs (``QPSK_R05``)  CV2XMode4
BLER(SINR)                  3GPP R1-160284 ("DMRS enhancement of V2V"), 190 B,          get_BLER
                            280 km/h relative speed, read off as the implementation
                            does: linear in between, 1 below the first point, 1e-4
                            above 20 dB
half duplex                 dHD = lam / 1000 (one subframe of the 1000 a second)        eq. (7)
sensing                     dSEN = 1 - PSR(d), PSR = Phi((P_t - PL - P_sen) / sigma)    (10),(11)
propagation                 dPRO = E[BLER(SNR) | received above P_sen]                  eq. (13)
packet collision            dCOL = 1 - prod_i (1 - p_sim(i) p_int(i))                   (14),(15)
interference                p_SINR(i) = E[BLER(SINR_i) | received above P_sen],         (17)
                            p_int = (p_SINR - dPRO) / (1 - dPRO)                        (18)
RRI                         1000 / lam ms (the packet interval: 100 ms at 10 Hz)        --
resources N                 S sub-channels x RRI subframes (400 at S = 4, 10 Hz)        eq. (28)
20 % rule                   N_c = 0.2 N candidate resources (3GPP's minimum)            impl.
sensed vehicles             S_PSR = beta sum_{x=-1500}^{1500} PSR(x) (1 m steps)        (29.1)
excluded resources          N_e = S/2 + sum_{k=1}^{floor(S/2)} max(1 - k/(N - S/2), 0), eq. (29)
                            S = S_PSR; available N_a = N - N_e
CBR                         N_e / N                                                     eq. (34)
common excluded             C_e(x) = R(x)/R(0) (beta N_e R(0)/S_PSR - N_e^2/N)          eq. (30)
                            + N_e^2/N, R the autocorrelation of PSR (30.2), R(0) (40)
common available            C_a = N - 2 N_e + C_e                                       eq. (27)
common candidates           C_c = C_a (N_c / N_a)^2                                     eq. (26)
same resource, Step 2       p_sim = p_s C_c(d_it) / N_c^2                               eq. (23)
unaware of each other       p_s = 1 - (1 - 1/tau) PSR(d_it)                             eq. (24)
reservation length tau      transmissions on one reservation: E[reselection counter] /  impl.:
                            (1 - p_keep); counter uniform in 5..15 at RRI >= 100 ms,    tau = lam
                            10..30 at 50 ms, 25..75 at 20 ms (3GPP); p_keep = 0 gives
                            tau = 10 at 10 Hz (and 20 at 20 Hz), the implementation's
                            tau = lam
sensing window              1000 ms (3GPP): not a parameter of the model; our reading:   ours
                            eq. (24) assumes it holds every current reservation of a
                            sensed vehicle
Step 3                      the threshold raised in 0.1 dB steps from P_sen until       (32),(33)
                            N_a >= N_c, with S = 2 beta sum PSR_n (eq. (32.1) as the    (31)
                            implementation evaluates it); p_sim as eq. (23) with that
                            N_e, N_a and PSR_n in p_s, C_e with R and S_PSR at P_sen
weight of Step 2            alpha = 0 below CBR 0.2, 2 CBR - 0.4 up to 0.7, 1 above     eq. (22)
                            dCOL = alpha dCOL_2 + (1 - alpha) dCOL_3 (after ordering)   eq. (21)
interferers                 every k / beta m from r, 0 < |k| <= round(1000 beta)        impl.
==========================  ==========================================================  =========

Assumptions of ours (the implementation's behaviour, not a statement of the paper we could
read): the interferers reach 1000 m; PSR and R are sums over -1500..1500 m in 1 m steps; C_c is
read at ``round(|d_it|)`` m; ``exclude_transmitter`` (off by default, as the implementation): when
``d`` is a multiple of ``1 / beta`` the transmitter stands on the interferers' lattice and the
implementation counts it as an interferer of itself (at 0.2 vehicles/m every distance
25, 50, ... m is on it; leaving it out raises the PDR by at most 1e-3 at the paper's
configurations).

Units: powers in dBm, losses in dB, distances in metres, rates in packets per second.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from analytic80211p import STEP_DB as STEP_DB  # (the grids' step, shared: re-exported)
from analytic80211p import interference_masses, received_masses, winner_b1_db
from scipy import special

#: The speed of light as the paper's propagation model takes it (m/s).
C = 3e8

#: BLER of a 190-byte transport block against the SINR (dB), QPSK code rate 0.7, 280 km/h
#: relative speed: 3GPP R1-160284, the curve the paper uses with 4 sub-channels (the points as
#: its implementation reads them off the figure; 1 below 0 dB, 1e-4 from just above 20 dB on).
QPSK_R07 = ((0.0, 1.0), (2.0, 0.9), (4.0, 0.7), (6.0, 0.4), (8.0, 0.13), (10.0, 0.045), (12.0, 0.017),
            (14.0, 0.007), (16.0, 1e-3), (18.0, 1e-3), (20.0, 1e-3), (20.0 + 1e-6, 1e-4))
#: The same for QPSK code rate 0.5 (the paper's 2 sub-channels); 1 below -2 dB.
QPSK_R05 = ((-2.0, 1.0), (0.0, 0.9), (2.0, 0.7), (4.0, 0.3), (6.0, 0.09), (8.0, 0.02), (10.0, 2e-3),
            (12.0, 1e-3), (14.0, 1e-3), (16.0, 1e-3), (18.0, 1e-3), (20.0, 1e-3), (20.0 + 1e-6, 1e-4))


@dataclass(frozen=True)
class Mcs:
    """How a 190-byte packet is sent with ``subchannels`` sub-channels in 10 MHz: the resource
    blocks its data field occupies (they set the noise) and its BLER(SINR) curve."""

    subchannels: int
    rbs: int
    bler: tuple[tuple[float, float], ...]


#: The paper's two configurations for 190-byte packets (its implementation's ``coding`` 1, 2).
MCS = {4: Mcs(subchannels=4, rbs=10, bler=QPSK_R07), 2: Mcs(subchannels=2, rbs=12, bler=QPSK_R05)}


@dataclass(frozen=True)
class Paper:
    """The paper's fixed parameters (module docstring)."""

    frequency: float = 5.91e9
    h_tx: float = 1.5
    h_rx: float = 1.5
    h_env: float = 0.0
    sigma: float = 3.0
    sensing: float = -90.5
    #: noise over the whole 10 MHz channel (dBm) and its resource blocks
    noise_channel: float = -95.0
    channel_rbs: int = 50
    #: subframes a second (1 ms each)
    subframes: int = 1000
    #: Step 2 keeps at least this share of the resources (3GPP's 20 %): N_c = fraction N
    candidate_fraction: float = 0.2
    #: the threshold step of the model of Step 3 (the implementation's 0.1 dB; 3GPP raises by 3 dB)
    threshold_step: float = 0.1
    #: the factor of eq. (32.1) as the implementation evaluates it
    step3_sensed_factor: float = 2.0
    #: reselection counter at an RRI of 100 ms or more (uniform, inclusive), and the probability
    #: of keeping the reservation when it runs out
    counter: tuple[int, int] = (5, 15)
    p_keep: float = 0.0
    #: eq. (22): alpha from 0 at CBR ``alpha_low`` to 1 at ``alpha_high``, linear in between
    alpha_low: float = 0.2
    alpha_high: float = 0.7
    free_space_floor: bool = True
    min_distance: float = 3.0
    #: interferers up to this far from the receiver
    reach: float = 1000.0
    #: PSR and its autocorrelation over ``-span .. span`` m in 1 m steps
    span: int = 1500


PAPER = Paper()


# ----------------------------------------------------------------------- propagation
def path_loss_db(d, p: Paper = PAPER) -> np.ndarray:
    """The paper's path loss (dB) at ``d`` m: WINNER+ B1 line of sight, effective heights 1.5 m
    (breakpoint 177.3 m), floored at free space (:func:`analytic80211p.winner_b1_db`, the same
    model as the 802.11p paper's)."""
    return winner_b1_db(d, p)


def mean_power_dbm(d, power: float, p: Paper = PAPER) -> np.ndarray:
    """The average received power at distance ``d``: ``P_t - PL(d)``."""
    return power - path_loss_db(d, p)


def psr(d, power: float, p: Paper = PAPER, threshold: float | None = None) -> np.ndarray:
    """Eq. (11), the packet sensing ratio: the probability that a packet sent ``d`` m away
    arrives at or above ``threshold`` (default the sensing threshold), ``1/2 (1 + erf((P_t -
    PL(d) - P_sen) / (sigma sqrt 2)))``."""
    level = p.sensing if threshold is None else threshold
    return 0.5 * (1.0 + special.erf((mean_power_dbm(d, power, p) - level) / (p.sigma * math.sqrt(2.0))))


def sensing_error(d, power: float, p: Paper = PAPER) -> np.ndarray:
    """Eq. (10), ``delta_SEN``: the probability that the packet's power at the receiver is below
    the sensing threshold, ``1 - PSR(d)``."""
    return 1.0 - psr(d, power, p)


def half_duplex_error(lam: float, p: Paper = PAPER) -> float:
    """Eq. (7), ``delta_HD = lam / 1000``: the receiver transmits its own packet in the
    transmitter's subframe (one of the ``p.subframes`` a second) and cannot receive."""
    return lam / p.subframes


# ----------------------------------------------------------------------- errors of a packet
def noise_dbm(subchannels: int, p: Paper = PAPER) -> float:
    """The noise over the data field of a packet: the channel's ``-95 dBm`` scaled from its 50
    resource blocks to the packet's (``MCS[subchannels].rbs``)."""
    return p.noise_channel - 10.0 * math.log10(p.channel_rbs / MCS[subchannels].rbs)


def bler_table(subchannels: int) -> list[list[float]]:
    """The paper's BLER against the SINR (dB) for ``subchannels``: ``[[sinr_db, bler], ...]``,
    linear in between and held beyond the ends (the form of dkfsim's ``per_table``)."""
    return [[s, b] for s, b in MCS[subchannels].bler]


def bler(sinr_db, subchannels: int) -> np.ndarray:
    """The block error rate at ``sinr_db``: :func:`bler_table`, linear in between, held beyond."""
    table = np.asarray(bler_table(subchannels))
    return np.interp(sinr_db, table[:, 0], table[:, 1])


def propagation_error(d, power: float, subchannels: int, p: Paper = PAPER) -> np.ndarray:
    """Eq. (13), ``delta_PRO`` before the ordering of eq. (6.3): the average BLER of a packet
    received above the sensing threshold without interference, ``E[BLER(P_t - PL(d) - X - N) |
    above P_sen]``."""
    s, masses = received_masses(mean_power_dbm(np.atleast_1d(d), power, p), power, p)
    return masses @ bler(s - noise_dbm(subchannels, p), subchannels)


def interference_error(d, d_int, power: float, subchannels: int, p: Paper = PAPER) -> np.ndarray:
    """Eq. (17), ``p_SINR``: the average BLER of a packet sent ``d`` m away and received above
    the sensing threshold while one vehicle ``d_int`` m from the receiver transmits on the same
    resource, the SINR ``(P_t - PL(d) - X) - 10 log10(N + 10^((P_t - PL(d_int) - X_i) / 10))``,
    ``X`` and ``X_i`` independent: ``(len(d), len(d_int))``."""
    noise = noise_dbm(subchannels, p)
    s, sig = received_masses(mean_power_dbm(np.atleast_1d(d), power, p), power, p)
    y, inter = interference_masses(mean_power_dbm(np.atleast_1d(d_int), power, p), power, noise, p)
    return sig @ bler(s[:, None] - y[None, :], subchannels) @ inter.T


# ----------------------------------------------------------------------- the resources
def resources(subchannels: int, lam: float, p: Paper = PAPER) -> float:
    """Eq. (28), ``N``: the resources of a selection window as long as the RRI, ``S`` sub-channels
    in each of its ``1000 / lam`` subframes (400 at 4 sub-channels and 10 Hz)."""
    return subchannels * p.subframes / lam


def reservation_length(lam: float, p: Paper = PAPER) -> float:
    """``tau`` of eq. (24): the mean number of packets a vehicle sends on one reservation, the
    mean of its reselection counter over ``1 - p_keep``.  The counter is uniform in 5..15 for an
    RRI of 100 ms or more and scaled by ``100 / RRI`` below (10..30 at 50 ms, 25..75 at 20 ms)."""
    rri_ms = p.subframes / lam
    scale = max(1.0, 100.0 / rri_ms)
    low, high = p.counter
    return 0.5 * (low + high) * scale / (1.0 - p.p_keep)


def _psr_grid(power: float, p: Paper, threshold: float | None = None) -> np.ndarray:
    """PSR over ``-span .. span`` m in 1 m steps (eqs (29.1), (30.2), (32.2))."""
    return psr(np.arange(-p.span, p.span + 1, dtype=np.float64), power, p, threshold)


def sensed_vehicles(beta: float, power: float, p: Paper = PAPER, threshold: float | None = None) -> float:
    """Eq. (29.1), ``S_PSR = beta sum_x PSR(x)``: the mean number of vehicles whose packets a
    vehicle senses (itself included, ``x = 0``)."""
    return beta * float(_psr_grid(power, p, threshold).sum())


def excluded_resources(sensed: float, n: float) -> float:
    """Eq. (29) (and (33)), ``N_e``: the resources a vehicle excludes when it senses ``sensed``
    vehicles, ``S/2 + sum_{k=1}^{floor(S/2)} max(1 - k / (N - S/2), 0)`` -- half of them on
    resources of their own, each of the other half on a resource not yet counted with the
    probability in the sum.  Below ``N`` for ``S < 2 N`` (where it grows with ``S``); beyond, the
    sum exceeds ``N``: kept as the implementation evaluates it (only Step 3 gets there, at its
    doubled ``S``, and its loop reads it as too few resources left and raises the threshold)."""
    half = sensed / 2.0
    k = np.arange(1, int(math.floor(half)) + 1, dtype=np.float64)
    with np.errstate(divide="ignore"):
        return half + float(np.maximum(1.0 - k / (n - half), 0.0).sum())


def cbr(beta: float, lam: float, power: float, subchannels: int, p: Paper = PAPER) -> float:
    """Eq. (34): the channel busy ratio, the share of the resources excluded, ``N_e / N``."""
    n = resources(subchannels, lam, p)
    return excluded_resources(sensed_vehicles(beta, power, p), n) / n


def alpha(load: float, p: Paper = PAPER) -> float:
    """Eq. (22): the weight of the Step-2 collisions, 0 below a CBR of 0.2, ``2 CBR - 0.4`` up to
    0.7, 1 above."""
    if load < p.alpha_low:
        return 0.0
    if load <= p.alpha_high:
        return (load - p.alpha_low) / (p.alpha_high - p.alpha_low)
    return 1.0


def psr_autocorrelation(power: float, p: Paper = PAPER) -> np.ndarray:
    """Eq. (30.2), ``R_PSR(x)`` for ``x = 0, 1, ... 2 span`` m, not normalised (``R(0)`` is eq.
    (40))."""
    grid = _psr_grid(power, p)
    return np.correlate(grid, grid, mode="full")[len(grid) - 1:]


def step3_threshold(beta: float, lam: float, power: float, subchannels: int, p: Paper = PAPER) -> tuple[float, float]:
    """Eqs (32)-(33): the threshold of the model of Step 3 and the resources it excludes there.
    From ``P_sen`` up in ``p.threshold_step`` dB steps, the first threshold at which ``N - N_e
    >= N_c``, with ``N_e`` of eq. (33) (eq. (29)'s form) at ``S = step3_sensed_factor beta sum
    PSR_n`` (eq. (32.1)): ``(threshold, N_e)``."""
    n = resources(subchannels, lam, p)
    nc = p.candidate_fraction * n
    k = 0
    while True:
        level = p.sensing + k * p.threshold_step
        ne = excluded_resources(p.step3_sensed_factor * sensed_vehicles(beta, power, p, level), n)
        if n - ne >= nc:
            return level, ne
        k += 1
        if k > 10_000:      # the PSR vanishes long before: excluded resources -> 0
            raise RuntimeError("Step 3 found no threshold leaving 20 % of the resources")


def same_resource(beta: float, lam: float, power: float, subchannels: int, d_it, excluded: float,
                  threshold: float, p: Paper = PAPER) -> np.ndarray:
    """Eq. (23) (Step 2) or eq. (31) (Step 3), ``p_sim``: the probability that a vehicle ``d_it``
    m from the transmitter holds the transmitter's resource, when each excludes ``excluded``
    resources and senses the other above ``threshold``:

    - eq. (30): ``C_e(x) = R(x)/R(0) (beta N_e R(0)/S_PSR - N_e^2/N) + N_e^2/N`` the resources both
      exclude (R, S_PSR at the sensing threshold), ``x = round(d_it)``;
    - eq. (27): ``C_a = N - 2 N_e + C_e`` those both may pick; eq. (26): ``C_c = C_a (N_c/N_a)^2``
      the common ones among their ``N_c`` candidates, ``N_a = N - N_e``;
    - eq. (24): ``p_s = 1 - (1 - 1/tau) PSR_threshold(d_it)``, that neither took the other's
      reservation into account (the other unsensed, or both reselecting in the same RRI);
    - ``p_sim = p_s C_c / N_c^2``."""
    n = resources(subchannels, lam, p)
    nc = p.candidate_fraction * n
    r = psr_autocorrelation(power, p)
    spsr = sensed_vehicles(beta, power, p)
    d_it = np.abs(np.asarray(d_it, dtype=np.float64))
    lag = np.minimum(np.rint(d_it).astype(np.int64), len(r) - 1)
    indep = excluded * excluded / n
    ce = (r[lag] / r[0]) * (beta * excluded * r[0] / spsr - indep) + indep       # eq. (30)
    ca = n - 2.0 * excluded + ce                                                  # eq. (27)
    cc = ca * (nc / (n - excluded)) ** 2                                          # eq. (26)
    tau = reservation_length(lam, p)
    p_s = 1.0 - (1.0 - 1.0 / tau) * psr(d_it, power, p, threshold)              # eq. (24)
    return p_s * cc / (nc * nc)                                                   # eqs (23), (31)


# ----------------------------------------------------------------------- the model
@dataclass
class Result:
    """The model at ``distances``: each error's probability in the order of eqs (6.1)-(6.5)
    (``collision`` weighted by eq. (21)), the PDR (eq. (6)), the CBR (eq. (34)) and alpha (eq.
    (22)); the errors before their ordering (eqs (7), (10), (13), (14) for Steps 2 and 3) in
    ``pre``, and the Step-3 threshold."""

    distances: np.ndarray
    half_duplex: np.ndarray
    sensing: np.ndarray
    propagation: np.ndarray
    collision: np.ndarray
    pdr: np.ndarray
    cbr: float
    alpha: float
    step3_threshold: float
    pre: dict[str, np.ndarray] = field(default_factory=dict)

    def errors(self) -> dict[str, np.ndarray]:
        return {"half_duplex": self.half_duplex, "sensing": self.sensing, "propagation": self.propagation,
                "collision": self.collision}


def _collision(p_int: np.ndarray, p_sim: np.ndarray) -> np.ndarray:
    """Eqs (14), (15): ``1 - prod_i (1 - p_sim(i) p_int(i))`` over the interferers (axis 1)."""
    return 1.0 - np.prod(1.0 - p_sim * p_int, axis=1)


def model(beta: float, lam: float, power: float, subchannels: int, size: int = 190, distances=None,
          p: Paper = PAPER, exclude_transmitter: bool = False) -> Result:
    """The PDR and the four errors at the transmitter-receiver ``distances`` (default: the
    paper's ``0, 25, ..., 500`` m) for ``beta`` vehicles per metre, ``lam`` packets per second
    each, ``power`` dBm, ``subchannels`` sub-channels (:data:`MCS`: 4 or 2) and packets of
    ``size`` bytes (the paper's MCS table is for 190 bytes only).

    The receiver at 0, the transmitter at ``-d``, the interferers at every ``k / beta``, ``0 <
    |k| <= round(reach beta)`` (``d_ir = |x|``, ``d_it = |x + d|``).  Eq. (18): ``p_int =
    (p_SINR - dPRO) / (1 - dPRO)`` (0 where ``dPRO = 1``); eqs (14)-(15) with ``p_sim`` of Step 2
    (eq. (23), ``N_e`` of eq. (29), threshold ``P_sen``) and of Step 3 (eq. (31),
    :func:`step3_threshold`); the errors ordered by eqs (6.1)-(6.5), the collisions weighted by
    eq. (21); ``PDR = 1 - HD - SEN - PRO - COL``.

    ``exclude_transmitter``: at a distance that is a multiple of ``1 / beta`` the transmitter
    stands on the interferers' lattice; True leaves it out of them (the implementation keeps it,
    so the default reproduces its numbers)."""
    if size != 190:
        raise ValueError("the paper's MCS / BLER tables are for 190-byte packets")
    if subchannels not in MCS:
        raise ValueError(f"subchannels: the paper's are {sorted(MCS)}")
    if beta <= 0 or lam <= 0:
        raise ValueError("beta and lam must be positive")
    d = np.asarray(np.arange(0.0, 501.0, 25.0) if distances is None else distances, dtype=np.float64)
    k_max = int(round(p.reach * beta))
    x = np.concatenate([-np.arange(k_max, 0, -1), np.arange(1, k_max + 1)]) / beta      # interferers
    d_it = np.abs(x[None, :] + d[:, None])                                              # (dist, interferer)

    hd = np.full(d.shape, half_duplex_error(lam, p))                                    # eq. (7)
    sen = sensing_error(d, power, p)                                                    # eq. (10)
    pro = propagation_error(d, power, subchannels, p)                                   # eq. (13)
    ks = np.arange(1, k_max + 1)
    p_sinr_side = interference_error(d, ks / beta, power, subchannels, p)               # eq. (17), by |k|
    p_sinr = p_sinr_side[:, np.abs(np.rint(x * beta)).astype(np.int64) - 1] if k_max else np.zeros((len(d), 0))
    with np.errstate(invalid="ignore", divide="ignore"):
        p_int = np.where(pro[:, None] < 1.0, (p_sinr - pro[:, None]) / (1.0 - pro[:, None]), 0.0)  # eq. (18)
    if exclude_transmitter:
        p_int = np.where(d_it < 1e-6 / beta, 0.0, p_int)

    n = resources(subchannels, lam, p)
    ne2 = excluded_resources(sensed_vehicles(beta, power, p), n)                        # eq. (29)
    load = ne2 / n                                                                      # eq. (34)
    col2 = _collision(p_int, same_resource(beta, lam, power, subchannels, d_it, ne2, p.sensing, p))  # eq. (23)
    a = alpha(load, p)                                                                  # eq. (22)
    level3, ne3 = step3_threshold(beta, lam, power, subchannels, p)                     # eqs (32)-(33)
    col3 = _collision(p_int, same_resource(beta, lam, power, subchannels, d_it, ne3, level3, p))  # eq. (31)

    HD = hd                                                                             # eq. (6.1)
    SEN = sen * (1.0 - hd)                                                              # eq. (6.2)
    PRO = pro * (1.0 - hd) * (1.0 - sen)                                                # eq. (6.3)
    survive = (1.0 - hd) * (1.0 - sen) * (1.0 - pro)
    COL = a * col2 * survive + (1.0 - a) * col3 * survive                               # eqs (6.4), (6.5), (21)
    return Result(distances=d, half_duplex=HD, sensing=SEN, propagation=PRO, collision=COL,
                  pdr=1.0 - HD - SEN - PRO - COL, cbr=load, alpha=a, step3_threshold=level3,  # eq. (6)
                  pre={"half_duplex": hd, "sensing": sen, "propagation": pro, "collision_step2": col2,
                       "collision_step3": col3})

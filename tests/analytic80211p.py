"""The analytic model of IEEE 802.11p broadcast of Sepulcre, Gonzalez-Martin, Gozalvez,
Molina-Masegosa and Coll-Perales, "Analytical Models of the Performance of IEEE 802.11p Vehicle
to Vehicle Communications", IEEE Trans. Veh. Technol. 71(1), 2022, doi 10.1109/TVT.2021.3124708
(post-print arXiv 2104.07923): the packet delivery ratio against the transmitter-receiver
distance, the probability of each of its four errors and the channel busy ratio, on a straight
road of equally spaced vehicles each broadcasting ``lam`` packets per second.

An independent truth for dkfsim's spatial radio (tests/test_radio_analytic.py): nothing here
imports :mod:`dkfsim`.  Written from the paper's equations (numbered as in the paper; the
numbering as the authors' public implementation, github.com/msepulcre/IEEE802.11p-model, labels
each equation it evaluates), as plain numpy/scipy.  The one numerical choice of our own: every
expectation over log-normal shadowing is a sum over the exact probability masses of a 0.05 dB
grid (differences of the normal CDF), where the authors convolve densities sampled every 0.1 dB.

The model (a receiver ``r``, the transmitter ``t`` at distance ``d``, every other vehicle ``i``
a potential interferer):

- a packet is lost for exactly one of four reasons, checked in this order: ``sensing`` (its
  power at ``r`` below the sensing threshold), ``receiver_busy`` (``r`` is receiving another
  packet), ``propagation`` (it fails without interference) and ``collision`` (it fails only
  because of interference); eqs (1), (3)-(6);
- every received power is ``P_t - PL(d) - X``, ``X`` a normal shadowing of ``sigma`` dB drawn
  independently per packet and link;
- a vehicle senses the channel busy while a packet above the sensing threshold is on the air
  (eq. 13, the packet sensing ratio ``PSR``), and the channel busy ratio is eqs (34)-(35).

Units: powers in dBm, losses in dB, distances in metres, times in seconds, rates in bit/s.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy import special

#: The speed of light as the paper's propagation model takes it (m/s).
C = 3e8

#: Frame error rate of the IEEE 802.11p receiver against Eb/N0 (dB): O. Goubet, G. Baudic, F.
#: Gabry, T. J. Abrahams, "Low-Complexity Scalable Iterative Algorithms for IEEE 802.11p
#: Receivers", IEEE Trans. Veh. Technol. 64(9):3944-3956, 2015, Fig. 14 (``L = 1``), the curve
#: Sepulcre et al. use (their section on propagation errors; the points as their implementation
#: reads them off the figure).  Linear in between, held beyond the ends (FER 1 below 5 dB,
#: 1e-3 above 35 dB).
GOUBET_FER_EBN0 = ((0.0, 1.0), (5.0, 1.0), (10.0, 0.4), (15.0, 1.5e-2), (20.0, 4e-3), (25.0, 3e-3),
                   (30.0, 2e-3), (35.0, 1e-3))


@dataclass(frozen=True)
class Paper:
    """The paper's fixed parameters (its table of simulation parameters): WINNER+ B1 LOS at
    5.89 GHz with both antennas at 1.5 m and an environment height of 0.5 m, 3 dB log-normal
    shadowing, a -85 dBm sensing threshold, -95 dBm noise over the 10 MHz channel, the 13 us
    slot, a 40 us preamble and 30 bytes of headers on every packet."""

    frequency: float = 5.89e9
    h_tx: float = 1.5
    h_rx: float = 1.5
    h_env: float = 0.5
    sigma: float = 3.0
    sensing: float = -85.0
    noise: float = -95.0
    bandwidth: float = 10e6
    slot: float = 13e-6
    preamble: float = 40e-6
    header: int = 30
    #: the path loss is never below free space (the authors' implementation)
    free_space_floor: bool = True
    #: distances below it are taken as it (the authors' implementation)
    min_distance: float = 3.0
    #: interferers up to this far from the receiver (the authors' implementation: 1000 m)
    reach: float = 1000.0
    #: the eq. (34) sum runs over ``-span .. span`` m in 1 m steps
    span: int = 1500
    #: the coefficients of the quadratic fit of eq. (35): ``a CBR_u^2 + b CBR_u + c``
    cbr_fit: tuple[float, float, float] = (-0.2481, 0.913, 0.003844)


PAPER = Paper()


# ----------------------------------------------------------------------- propagation
def winner_b1_db(d, p) -> np.ndarray:
    """WINNER+ B1 line of sight (IST-WINNER II D1.1.2 table 4-4; the propagation model of this
    paper and of tests/analyticcv2x.py's): with effective heights ``h' = h - h_env`` and breakpoint
    ``d_BP = 4 h'_t h'_r f / c``, ``22.7 log10 d + 27 + 20 log10 f_GHz`` below it, ``40 log10 d +
    7.56 - 17.3 log10 h'_t - 17.3 log10 h'_r + 2.7 log10 f_GHz`` beyond; never below free space
    (``20 log10 d + 46.4 + 20 log10(f_GHz / 5)``) when ``p.free_space_floor``; ``d`` at least
    ``p.min_distance`` (``p``: a paper's parameters with those fields)."""
    d = np.maximum(np.abs(np.asarray(d, dtype=np.float64)), p.min_distance)
    f_ghz = p.frequency / 1e9
    ht, hr = p.h_tx - p.h_env, p.h_rx - p.h_env
    d_bp = 4.0 * ht * hr * p.frequency / C
    near = 22.7 * np.log10(d) + 27.0 + 20.0 * math.log10(f_ghz)
    far = 40.0 * np.log10(d) + 7.56 - 17.3 * math.log10(ht) - 17.3 * math.log10(hr) + 2.7 * math.log10(f_ghz)
    pl = np.where(d < d_bp, near, far)
    if p.free_space_floor:
        pl = np.maximum(pl, 20.0 * np.log10(d) + 46.4 + 20.0 * math.log10(f_ghz / 5.0))
    return pl




def path_loss_db(d, p: Paper = PAPER) -> np.ndarray:
    """The paper's path loss (dB) at ``d`` m: :func:`winner_b1_db`."""
    return winner_b1_db(d, p)


def mean_power_dbm(d, power: float, p: Paper = PAPER) -> np.ndarray:
    """The average received power at distance ``d``: ``P_t - PL(d)``."""
    return power - path_loss_db(d, p)


def detection_probability(d, power: float, p: Paper = PAPER) -> np.ndarray:
    """Eq. (13), the packet sensing ratio ``PSR(d)``: the probability that a packet sent ``d`` m
    away arrives above the sensing threshold, ``P(P_t - PL(d) - X >= P_sen) = 1/2 (1 + erf((P_t
    - PL(d) - P_sen) / (sigma sqrt 2)))``."""
    return 0.5 * (1.0 + special.erf((mean_power_dbm(d, power, p) - p.sensing) / (p.sigma * math.sqrt(2.0))))


def sensing_error(d, power: float, p: Paper = PAPER) -> np.ndarray:
    """Eq. (12), ``delta_SEN``: the probability that the packet's power at the receiver (its
    shadowing drawn for this packet) is below the sensing threshold, ``1 - PSR(d)``."""
    return 1.0 - detection_probability(d, power, p)


# ----------------------------------------------------------------------- errors of a packet
def fer_table_sinr(data_rate: float, p: Paper = PAPER) -> list[list[float]]:
    """The paper's frame error rate against the SINR (dB) at ``data_rate``: Goubet et al.'s
    curve (:data:`GOUBET_FER_EBN0`) moved from Eb/N0 to SINR, ``Eb/N0 = SINR + 10 log10(B /
    R_d)`` (the paper's conversion; B the 10 MHz bandwidth): ``[[sinr_db, fer], ...]``, the form
    of dkfsim's ``reception: {model: per_table}``."""
    shift = 10.0 * math.log10(p.bandwidth / data_rate)
    return [[ebn0 - shift, fer] for ebn0, fer in GOUBET_FER_EBN0]


def fer(sinr_db, data_rate: float, p: Paper = PAPER) -> np.ndarray:
    """The frame error rate at ``sinr_db``: :func:`fer_table_sinr`, linear in between, held
    beyond the ends."""
    table = np.asarray(fer_table_sinr(data_rate, p))
    return np.interp(sinr_db, table[:, 0], table[:, 1])


#: The step (dB) of the grids of the expectations over shadowing.
STEP_DB = 0.05


def power_grid(low: float, power: float, p) -> np.ndarray:
    """Cell edges (dBm) from ``low`` to 8 sigma above the strongest mean power (at
    ``p.min_distance``), :data:`STEP_DB` apart (``p``: a paper's parameters; shared with
    tests/analyticcv2x.py)."""
    top = power - float(winner_b1_db(p.min_distance, p)) + 8.0 * p.sigma
    return low + np.arange(int(math.ceil((top - low) / STEP_DB)) + 1) * STEP_DB


def received_masses(mean_dbm, power: float, p) -> tuple[np.ndarray, np.ndarray]:
    """Per mean power, the probability of each grid cell of the received power *given that it
    is detected*, at or above ``p.sensing`` (the SNR and SINR of both papers are those of
    detected packets: here eqs (24), (30)): (cell centres, ``(len(mean), cells)``), each row
    summing to 1 (0 where detection is impossible)."""
    edges = power_grid(p.sensing, power, p)
    cdf = special.ndtr((edges[None, :] - np.asarray(mean_dbm, dtype=np.float64)[:, None]) / p.sigma)
    mass = np.diff(cdf, axis=1)
    total = mass.sum(axis=1, keepdims=True)
    return 0.5 * (edges[1:] + edges[:-1]), np.divide(mass, total, out=np.zeros_like(mass), where=total > 0)


def interference_masses(mean_dbm, power: float, noise: float, p) -> tuple[np.ndarray, np.ndarray]:
    """Per mean interference power, the probability of each grid cell of ``10 log10(N + I)``,
    ``N`` the ``noise`` (dBm), ``I`` log-normal and not truncated (an interferer below the
    threshold still interferes): ``P(10 log10(N + I) <= y) = Phi((10 log10(10^(y/10) - N) -
    mean) / sigma)`` for ``y`` above the noise: (cell centres, ``(len(mean), cells)``)."""
    edges = power_grid(noise, power, p)
    excess = 10.0 ** (edges / 10.0) - 10.0 ** (noise / 10.0)
    with np.errstate(divide="ignore"):
        level = np.where(excess > 0, 10.0 * np.log10(np.maximum(excess, 1e-300)), -np.inf)
    cdf = special.ndtr((level[None, :] - np.asarray(mean_dbm, dtype=np.float64)[:, None]) / p.sigma)
    cdf[:, -1] = 1.0
    return 0.5 * (edges[1:] + edges[:-1]), np.diff(cdf, axis=1)


def propagation_error(d, power: float, data_rate: float, p: Paper = PAPER) -> np.ndarray:
    """Eq. (24), the propagation error before the ordering of eq. (5): the average frame error
    rate of a detected packet without interference, ``E[FER(P_t - PL(d) - X - N) | detected]``,
    the SNR's distribution that of the shadowed power truncated at the sensing threshold."""
    s, masses = received_masses(mean_power_dbm(np.atleast_1d(d), power, p), power, p)
    return masses @ fer(s - p.noise, data_rate, p)


def interference_error(d, d_int, power: float, data_rate: float, p: Paper = PAPER) -> np.ndarray:
    """Eq. (30), ``p_SINR``: the average frame error rate of a detected packet sent ``d`` m
    away while one vehicle ``d_int`` m from the receiver transmits over all of it, the SINR
    ``(P_t - PL(d) - X) - 10 log10(N + 10^((P_t - PL(d_int) - X_i) / 10))``, ``X`` and ``X_i``
    independent: ``(len(d), len(d_int))``."""
    s, sig = received_masses(mean_power_dbm(np.atleast_1d(d), power, p), power, p)
    y, inter = interference_masses(mean_power_dbm(np.atleast_1d(d_int), power, p), power, p.noise, p)
    return sig @ fer(s[:, None] - y[None, :], data_rate, p) @ inter.T


# ----------------------------------------------------------------------- the channel
def airtime(size: int, data_rate: float, p: Paper = PAPER) -> float:
    """``T_tr``: the preamble and signal field (40 us) and ``(B + H) * 8 / R_d``, the paper's
    transmission time of a packet of ``size`` bytes with its ``H`` bytes of headers."""
    return p.preamble + (size + p.header) * 8.0 / data_rate


def _psr_grid(power: float, p: Paper) -> np.ndarray:
    """``PSR`` over ``-span .. span`` m in 1 m steps (eqs (20), (34))."""
    return detection_probability(np.arange(-p.span, p.span + 1, dtype=np.float64), power, p)


def cbr_uncorrected(beta: float, lam: float, power: float, size: int, data_rate: float,
                    p: Paper = PAPER) -> float:
    """Eq. (34), ``CBR_u = beta lam T_tr sum_d PSR(d)``: the busy time of every vehicle's
    packets a vehicle senses (its own included, ``d = 0``), as if none overlapped."""
    return beta * lam * airtime(size, data_rate, p) * float(_psr_grid(power, p).sum())


def cbr(beta: float, lam: float, power: float, size: int, data_rate: float, p: Paper = PAPER) -> float:
    """Eq. (35): the channel busy ratio, the paper's quadratic fit of its simulated CBR on
    ``CBR_u`` (overlapping packets count once): ``-0.2481 CBR_u^2 + 0.913 CBR_u + 0.003844``."""
    u = cbr_uncorrected(beta, lam, power, size, data_rate, p)
    a, b, c = p.cbr_fit
    return a * u * u + b * u + c


def psr_autocorrelation(power: float, p: Paper = PAPER) -> np.ndarray:
    """Eq. (20), ``R_PSR(x)`` for ``x = 0, 1, 2, ... m``: the autocorrelation of ``PSR`` normalised
    to 1 at 0 -- the part of one vehicle's busy time a vehicle ``x`` m away shares."""
    psr = _psr_grid(power, p)
    r = np.correlate(psr, psr, mode="full")[len(psr) - 1:]
    return r / r[0]


# ----------------------------------------------------------------------- the model
@dataclass
class Result:
    """The model at ``distances``: each error's probability (eqs (3)-(6)), the PDR (eq. (1))
    and the CBR (eq. (35)); the errors before their ordering (eqs (12), (14), (24), (26)) in
    ``pre``."""

    distances: np.ndarray
    sensing: np.ndarray
    receiver_busy: np.ndarray
    propagation: np.ndarray
    collision: np.ndarray
    pdr: np.ndarray
    cbr: float
    cbr_u: float
    pre: dict[str, np.ndarray] = field(default_factory=dict)

    def errors(self) -> dict[str, np.ndarray]:
        return {"sensing": self.sensing, "receiver_busy": self.receiver_busy,
                "propagation": self.propagation, "collision": self.collision}


def model(beta: float, lam: float, power: float, size: int, data_rate: float, distances=None,
          p: Paper = PAPER, exclude_transmitter: bool = False) -> Result:
    """The PDR and the four errors at the transmitter-receiver ``distances`` (default: the
    paper's ``0, 25, ..., 500`` m) for ``beta`` vehicles per metre, ``lam`` packets per second
    each, ``power`` dBm, packets of ``size`` bytes at ``data_rate`` bit/s.

    The receiver at 0, the transmitter at ``-d``, the interferers at every ``k / beta``,
    ``0 < |k| <= round(reach beta)``.  For each interferer ``i`` (``d_ir``, ``d_it`` its
    distances to the receiver and the transmitter, ``T = T_tr``, ``s`` the slot, ``CBR`` of eq.
    (35), ``R = R_PSR(d_it)`` of eq. (20)):

    - eq. (22): it starts in the transmitter's slot (carrier sensed) with ``p_sim_CT = s lam
      PSR(d_it) / (1 - CBR R)``;
    - eq. (18): it overlaps as a hidden terminal (not sensed) with ``p_sim_HT = T lam (1 -
      PSR(d_it)) / (1 - CBR R)``;
    - eq. (16): ``p_RXB_HT = T lam PSR(d_ir) (1 - PSR(d_it)) / (1 - CBR R)`` -- the receiver
      was already locked on its packet;
    - eq. (21): ``p_RXB_CT = p_sim_CT PSR(d_ir)`` when it is closer to the receiver than the
      transmitter (the receiver locks on it), else 0;
    - eq. (31): its packet alone makes the reception fail with ``p_int = (p_SINR - delta_PRO)
      / (1 - delta_PRO)`` (eq. (30) ``p_SINR``, eq. (24) ``delta_PRO``);
    - eq. (32): ``p_COL_CT = p_int p_sim_CT`` when it is not closer, else 0;
    - eq. (28): ``p_COL_HT = p_int p_sim_HT + p_int p_sim_HT (1 - PSR(d_ir))`` -- (as the
      paper writes it) one term for a hidden terminal that starts during the packet, one for
      one that started before it and that the receiver did not detect.

    Over the interferers, eq. (14) ``delta_RXB = 1 - prod(1 - p_RXB_CT - p_RXB_HT)`` and eq.
    (26) ``delta_COL = 1 - prod(1 - p_COL_CT - p_COL_HT)``; the errors in their order, eqs
    (3)-(6): ``SEN = delta_SEN``, ``RXB = delta_RXB (1 - delta_SEN)``, ``PRO = delta_PRO (1 -
    delta_SEN)(1 - delta_RXB)``, ``COL = delta_COL (1 - delta_SEN)(1 - delta_RXB)(1 -
    delta_PRO)``; eq. (1) ``PDR = 1 - SEN - RXB - PRO - COL``.

    ``exclude_transmitter``: at a distance that is a multiple of ``1 / beta`` the transmitter
    stands on the interferers' lattice; True leaves it out of them (the paper's grid of
    distances is not on the lattice, so it never meets this; the difference is below 1e-4)."""
    d = np.asarray(np.arange(0.0, 501.0, 25.0) if distances is None else distances, dtype=np.float64)
    T = airtime(size, data_rate, p)
    load = cbr(beta, lam, power, size, data_rate, p)
    R = psr_autocorrelation(power, p)
    k_max = int(round(p.reach * beta))
    x = np.concatenate([-np.arange(k_max, 0, -1), np.arange(1, k_max + 1)]) / beta     # interferers
    d_ir = np.abs(x)
    d_it = np.abs(x[None, :] + d[:, None])                                              # (dist, interferer)

    sen = sensing_error(d, power, p)
    pro = propagation_error(d, power, data_rate, p)
    psr_ir = detection_probability(d_ir, power, p)[None, :]
    psr_it = detection_probability(d_it, power, p)
    shared = 1.0 - load * R[np.minimum(np.rint(d_it).astype(np.int64), len(R) - 1)]
    p_sim_ct = p.slot * lam * psr_it / shared                                            # eq. (22)
    p_sim_ht = T * lam * (1.0 - psr_it) / shared                                         # eq. (18)
    closer = d_ir[None, :] < d[:, None]
    p_rxb_ht = T * lam * psr_ir * (1.0 - psr_it) / shared                                # eq. (16)
    p_rxb_ct = np.where(closer, p_sim_ct * psr_ir, 0.0)                                  # eq. (21)
    p_sinr = interference_error(d, d_ir, power, data_rate, p)                            # eq. (30)
    with np.errstate(invalid="ignore", divide="ignore"):
        p_int = np.where(pro[:, None] < 1.0, (p_sinr - pro[:, None]) / (1.0 - pro[:, None]), 0.0)  # eq. (31)
    p_col_ct = np.where(closer, 0.0, p_int * p_sim_ct)                                   # eq. (32)
    p_col_ht = p_int * p_sim_ht + p_int * p_sim_ht * (1.0 - psr_ir)                      # eq. (28)
    rxb_terms, col_terms = p_rxb_ct + p_rxb_ht, p_col_ct + p_col_ht
    if exclude_transmitter:
        itself = d_it < 1e-6 / beta
        rxb_terms, col_terms = np.where(itself, 0.0, rxb_terms), np.where(itself, 0.0, col_terms)
    rxb = 1.0 - np.prod(1.0 - rxb_terms, axis=1)                                         # eq. (14)
    col = 1.0 - np.prod(1.0 - col_terms, axis=1)                                         # eq. (26)

    SEN = sen                                                                            # eq. (3)
    RXB = rxb * (1.0 - sen)                                                              # eq. (4)
    PRO = pro * (1.0 - sen) * (1.0 - rxb)                                                # eq. (5)
    COL = col * (1.0 - sen) * (1.0 - rxb) * (1.0 - pro)                                  # eq. (6)
    return Result(distances=d, sensing=SEN, receiver_busy=RXB, propagation=PRO, collision=COL,
                  pdr=1.0 - SEN - RXB - PRO - COL, cbr=load,                             # eq. (1)
                  cbr_u=cbr_uncorrected(beta, lam, power, size, data_rate, p),
                  pre={"sensing": sen, "receiver_busy": rxb, "propagation": pro, "collision": col})


"""The C-V2X sidelink (``medium.access.kind: sps``, issue 33) against the analytic model of LTE-V2X
mode 4 of Gonzalez-Martin et al., IEEE TVT 68(2), 2019 (tests/analyticcv2x.py): the PDR against
distance, the probability of each of the model's four errors, and the channel busy ratio.

dkfsim is configured as the model is: vehicles equally spaced on a straight road, each
broadcasting 10 packets a second of 190 bytes with a random phase (``background: {arrivals:
periodic, offset: random}``), nothing else on the channel; 20 dBm; WINNER+ B1 at 5.91 GHz with
1.5 m antennas and no environment height; 3 dB log-normal shadowing per packet and receiver, no
fading; the model's BLER table (QPSK r = 0.7, 4 sub-channels) as ``per_table``; -95 dBm of noise
over the band, ``noise_share`` 10 / 50 resource blocks (one sub-channel's data: the model's
-102 dBm); its -90.5 dBm sensing power as both ``sensitivity`` and the sps ``rsrp_threshold``; 4
sub-channels of 190 bytes (a packet takes one), a 100 ms RRI and budget (N = 400 candidates),
``p_keep`` 0 (the model's tau = 10 packets a reservation), 20 % candidates.  Only packets sent by
the vehicles of a central kilometre are counted (``SpatialChannel.measure``), after a warm-up.

What the model leaves to dkfsim and how it is set here:

- the step of the RSRP threshold (3GPP's 3 dB): at both densities 20 % of the candidates are left
  at -90.5 dBm, so the threshold never rises (the model's Step 3 finds the same: -90.5 dBm);
- the CBR threshold: eq. (34)'s CBR is the share of the resources a vehicle excludes, those of the
  vehicles it senses above the sensing power; dkfsim's is the share of sub-channel-subframes whose
  RSSI reaches ``cbr_threshold``, set to the same -90.5 dBm (3GPP's -94 dBm counts more busy:
  0.29 and 0.52 at 0.1 and 0.2 vehicles/m against eq. (34)'s 0.23 and 0.44);
- the model's path loss is floored at free space below 102 m, dkfsim's WINNER+ B1 is not (at
  most 4.2 dB less loss there, where every packet is received above -70 dBm: no effect seen).

Known differences, each measured (16 runs at 0.1 and 8 at 0.2 vehicles/m, 4 s each after the
warm-up; the test's own runs agree with them within their noise):

- ``half_duplex``: the model takes the receiver's subframe independent of the transmitter's
  (eq. (7): lam / 1000 = 0.01).  Under SB-SPS a vehicle excludes the resources of the vehicles it
  senses, so a sensed neighbour's subframe has a sub-channel fewer to offer it: dkfsim loses
  0.0084 of the pairs within 500 m to half duplex at both densities (0.008-0.009 per bin), and
  0.009 (0.1 vehicles/m) and 0.0105 (0.2) of the pairs 600-1000 m apart, beyond each other's
  sensing.
- ``collision``: the model's probability that two vehicles hold the same resource (``p_sim``,
  eqs (23)-(31)) is not SB-SPS's.  Measured in dkfsim (every transmission of 10 runs of 5 s), two
  vehicles 0-300 m apart hold the same resource more often than the model says (``p_sim N`` =
  0.34-0.39 against 0.15-0.16 at 0.1 vehicles/m, 0.25-0.36 against 0.20-0.22 at 0.2): two
  neighbours that reselect unaware of each other pick among nearly the same 20 % least-loaded
  candidates, where eq. (26) draws the two candidate sets independently.  Two vehicles 400-1000 m
  apart hold it less often (0.32-0.74 against 0.59-1.18 at 0.1; 0.36-0.87 against 0.76-1.28 at
  400-600 m at 0.2): Step 3's ranking by RSSI steers clear of the vehicles heard below the sensing
  power too, which the model takes as unseen.  Hence dkfsim has more collisions than the model
  below 200 m and fewer beyond (0.1 vehicles/m: up to +0.021 at 100-150 m and -0.037 at 350-400
  m; 0.2: +0.018 and -0.014), and its PDR is up to 0.039 above the model's at 325-400 m at 0.1
  vehicles/m, within 0.019 everywhere at 0.2.  Fed dkfsim's own ``p_sim``, the model's collision
  equations (14)-(18) give dkfsim's collisions within 0.0041 in every bin at 0.1 vehicles/m (five
  sets of the test's runs; :func:`test_the_collision_difference_is_the_schedulings`): the radio's
  reception of a collided packet (SINR over its sub-channels, the BLER table) is the model's; the
  scheduling is what differs.  (At 0.2 vehicles/m the rebuilt model falls up to 0.024 short of
  dkfsim beyond 300 m; not pursued: a likely reason is that there dkfsim adds the interference of
  several vehicles on one resource, where eq. (17) judges each interferer alone.)
- ``sensing`` and ``propagation`` agree within 0.003 and 0.0005 in every bin: the path loss, the
  shadowing, the sensitivity, the noise share and the BLER table are the model's.
- CBR: 0.235 and 0.436 against eq. (34)'s 0.229 and 0.439.
"""

from __future__ import annotations

import functools
import math

import analyticcv2x as cv2x
import numpy as np
import pytest
import simpy
from test_radio_analytic import check_winner_b1_beyond_floor, table_rows

from dkfsim.components.faults import LinkSpec
from dkfsim.components.latency import Constant
from dkfsim.components.medium import Medium, Sps
from dkfsim.components.radio import RadioParams
from dkfsim.components.traffic import Background
from dkfsim.network import radio_kernels as rk
from dkfsim.network.network import Network

#: The paper's configuration (its run_all list): 10 Hz, 20 dBm, 190 bytes, 4 sub-channels.
LAM, POWER, SIZE, S = 10.0, 20.0, 190, 4
P = cv2x.PAPER
#: Packets sent by vehicles within this many metres of the road's middle are counted ...
CENTRAL_M = 500.0
#: ... and the road goes on this far beyond them: 500 m of receivers (the bins), the model's
#: interferers up to 1000 m from them and those vehicles' own neighbours.  With 1000, 1500 and
#: 2000 m every bin's PDR and collisions agreed within 0.005 (the runs' noise).
MARGIN_M = 1500.0
#: Seconds of warm-up (a sensing window of 1 s, and the first reservations, chosen blind, last up
#: to 1.5 s: from the third second on the PDR is steady within the noise), then per density
#: (runs, seconds measured in each).
WARM_S = 2.0
RUNS = {0.1: (4, 8.0), 0.2: (2, 6.0)}
#: The positions' tick (static vehicles: any), a subframe.
T_NS, SUBFRAME = 100_000_000, rk.SUBFRAME
#: Bins of pdr_by_distance (the paper evaluates 0, 25, ..., 500 m).
BIN_M, MAX_M = 25.0, 500.0
#: The model's errors, and the causes of dkfsim's that make each.
CAUSES = {"half_duplex": ("half_duplex",), "sensing": ("sensing",), "propagation": ("propagation",),
          "collision": ("reservation_collision", "collision")}

#: Tolerances.  PDR (issue 33): every bin within 0.05.
PDR_BIN = 0.05
#: CBR against eq. (34): dkfsim's measures the RSSI, eq. (34) counts the resources of the sensed
#: vehicles; 0.006 and 0.005 apart at most in the batches below, their noise 0.001.
CBR_TOL = 0.015
#: Each error, every bin.  The runs' noise: over 5 (0.1 vehicles/m) and 4 (0.2) independent sets
#: of ``RUNS`` a bin's standard deviation across the sets was at most 0.0023 and 0.0056
#: (collision), 0.0016 (sensing), 0.0017 (half_duplex), 0.0003 (propagation).  Beyond the noise,
#: the known differences (module docstring): half_duplex 0.0016 under the model's 0.01 on
#: average, collision up to 0.037 (the scheduling's; what it is made of is held by
#: :func:`test_the_collision_difference_is_the_schedulings`).  The worst of the 9 sets used at
#: most 0.0035 of half_duplex's tolerance, 0.0028 of sensing's, 0.0005 of propagation's, 0.0361
#: of collision's and 0.039 of the PDR's 0.05.
CAUSE_BIN = {"half_duplex": 0.006, "sensing": 0.008, "propagation": 0.002, "collision": 0.045}


def radio_params() -> RadioParams:
    """The model's radio (tests/analyticcv2x.py, :class:`~analyticcv2x.Paper`)."""
    return RadioParams(
        power=POWER, frequency=P.frequency, noise=P.noise_channel, sensitivity=P.sensing,
        path_loss={"model": "winner_b1", "height": P.h_tx, "environment_height": P.h_env},
        shadowing={"model": "lognormal", "sigma": P.sigma},
        reception={"model": "per_table", "table": cv2x.bler_table(S)},
        bins={"width": BIN_M, "max": MAX_M})


def medium() -> Medium:
    """10 Hz packets of 190 bytes with random phases on SB-SPS as the model assumes it (``rate``
    is the one-domain channel's, unused by the sidelink's 1 ms subframes)."""
    access = Sps(subchannels=S, subchannel_bytes=SIZE, noise_share=cv2x.MCS[S].rbs / P.channel_rbs, rri=0.1,
                 p_keep=P.p_keep, rsrp_threshold=P.sensing, candidates=P.candidate_fraction, budget=0.1,
                 misfit="reselect", cbr_threshold=P.sensing)
    return Medium(rate=6e6, access=access, radio=radio_params(),
                  background=Background(arrivals="periodic", packets_per_second=LAM, size=SIZE, offset="random"))


def road(beta: float, ticks: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Positions (``ticks`` ticks, static) of the vehicles ``1 / beta`` m apart on a road
    ``2 (CENTRAL_M + MARGIN_M)`` m long, and which of them are central."""
    half = int(math.ceil((CENTRAL_M + MARGIN_M) * beta))
    x = np.arange(-half, half + 1) / beta
    xy = np.stack([x, np.zeros_like(x)], axis=1)
    return np.repeat(xy[None], ticks, axis=0), np.abs(x) <= CENTRAL_M + 1e-9


#: Every how many ns the reservations are read (for :func:`test_the_collision_difference_is_the_schedulings`).
SNAP_NS = 20_000_000


@functools.lru_cache(maxsize=None)
def simulate(beta: float, first_seed: int = 0) -> dict:
    """``RUNS[beta]`` runs (seeds ``first_seed, ...``): the (packet, receiver) pairs of the central
    vehicles' packets per distance bin (``frames``) and per model error, the central vehicles'
    mean CBR over the measuring window, and how often a central vehicle and another ``k`` places
    along the road held the same resource (``same[k]`` of ``both[k]`` readings of the
    reservations while both held one)."""
    runs, seconds = RUNS[beta]
    start = int(WARM_S * 1e9)
    end = start + int(seconds * 1e9)
    positions, central = road(beta, end // T_NS + 2)
    n = positions.shape[1]
    senders = np.flatnonzero(central)
    lag = np.abs(np.arange(n)[None, :] - senders[:, None])
    out = {"frames": 0, **{name: 0 for name in CAUSES}, "cbr": 0.0, "same": np.zeros(n), "both": np.zeros(n)}
    for seed in range(first_seed, first_seed + runs):
        net = Network(simpy.Environment(), [(0, 1), (1, 0)], lambda u, v: LinkSpec(latency=Constant(value=1e-6)),
                      seed=seed, T_ns=T_NS, medium=medium(), positions=positions, n=n)
        channel = net.channel_of({})
        channel.measure(senders, start, end)              # the central vehicles' packets in the window
        for t in range(start, end, SNAP_NS):
            channel.advance(t)
            vs = channel.vrows
            on = vs[rk.V_ON] > 0
            resource = np.where(on, (vs[rk.V_SF] % channel.sps.rri_ms) * S + vs[rk.V_C], -1)
            pair = on[senders, None] & on[None, :] & (lag > 0)
            out["both"] += np.bincount(lag[pair], minlength=n)
            out["same"] += np.bincount(lag[pair & (resource[senders, None] == resource[None, :])], minlength=n)
        channel.advance(end + 2 * SUBFRAME)               # the window's last packets are decided
        block = channel.report(None, end)["pdr_by_distance"]
        out["frames"] = out["frames"] + np.array(block["frames"])
        for name, causes in CAUSES.items():
            out[name] = out[name] + sum(np.array(block[c]) for c in causes)
        busy = channel.busy_per_tick(T_NS, end // T_NS)[start // T_NS:]
        out["cbr"] += float((busy.sum(axis=0) / (channel.busy_unit(T_NS) * len(busy)))[central].mean()) / runs
    out["edges"] = np.array(block["bins_m"])
    return out


def measured(sim: dict) -> dict[str, np.ndarray]:
    """dkfsim's PDR and each error's share of the pairs, per bin."""
    frames = sim["frames"]
    errors = {name: sim[name] / frames for name in CAUSES}
    return {"pdr": 1.0 - sum(errors.values()), **errors}


def bin_weights(beta: float, edges: np.ndarray) -> np.ndarray:
    """(bins, k): how many of the central vehicles' (packet, receiver) pairs in each bin are ``k``
    places apart, bins filled as dkfsim fills them (``floor(d / width + 1e-9)``: a distance that is
    a multiple of 25 m, every 5th vehicle at both densities, lands in the bin above its edge)."""
    positions, central = road(beta)
    x = positions[0, :, 0]
    d = np.abs(x[None, :] - x[central, None])
    b = np.floor(d / (edges[1] - edges[0]) + 1e-9).astype(np.int64)
    k = np.rint(d * beta).astype(np.int64)
    keep = (k > 0) & (b < len(edges) - 1)
    weights = np.zeros((len(edges) - 1, int(k[keep].max()) + 1))
    np.add.at(weights, (b[keep], k[keep]), 1.0)
    return weights / weights.sum(axis=1, keepdims=True)


@functools.lru_cache(maxsize=None)
def model(beta: float) -> cv2x.Result:
    """The model at every lattice distance ``k / beta`` the bins hold (the transmitter not its
    own interferer: dkfsim's is not)."""
    edges = np.arange(int(MAX_M / BIN_M) + 1) * BIN_M
    k = bin_weights(beta, edges).shape[1]
    return cv2x.model(beta, LAM, POWER, S, SIZE, distances=np.arange(k) / beta, exclude_transmitter=True)


def analytic(beta: float, edges: np.ndarray) -> tuple[dict[str, np.ndarray], float]:
    """The model averaged over each bin's pairs (not read at points: the PDR falls fast across a
    bin), and its CBR (eq. (34))."""
    weights = bin_weights(beta, edges)
    result = model(beta)
    values = {"pdr": result.pdr, **result.errors()}
    return {name: weights @ v[:weights.shape[1]] for name, v in values.items()}, result.cbr


def failures(sim: dict, ref: dict, sim_cbr: float, ref_cbr: float) -> list[str]:
    """What exceeds its tolerance (empty: dkfsim agrees with the model)."""
    out = []
    worst = float(np.max(np.abs(sim["pdr"] - ref["pdr"])))
    if worst > PDR_BIN:
        out.append(f"PDR: worst bin {worst:.4f} (<= {PDR_BIN})")
    if abs(sim_cbr - ref_cbr) > CBR_TOL:
        out.append(f"CBR {sim_cbr:.4f} vs {ref_cbr:.4f} (+-{CBR_TOL})")
    for name, tol in CAUSE_BIN.items():
        worst = float(np.max(np.abs(sim[name] - ref[name])))
        if worst > tol:
            out.append(f"{name}: worst bin {worst:.4f} (<= {tol})")
    return out


@pytest.mark.slow
@pytest.mark.parametrize("beta", [0.1, 0.2])
def test_pdr_errors_and_cbr_match_the_analytic_model(beta):
    """At 0.1 and 0.2 vehicles/m: the PDR of every 25 m bin up to 500 m within 0.05 of the
    model's, each error within its tolerance, the CBR within 0.015 of eq. (34) (module
    docstring).  The same measurements against the model of the other density fail: the
    comparison tells the densities apart."""
    sim_raw = simulate(beta)
    edges = sim_raw["edges"]
    assert sim_raw["frames"].min() > 50_000             # (every bin well filled)
    sim = measured(sim_raw)
    ref, ref_cbr = analytic(beta, edges)
    gaps = {name: round(float(np.mean(np.abs(sim[name] - ref[name]))), 4) for name in ref}
    report = f"\n{table_rows(edges, sim, ref)}\nCBR {sim_raw['cbr']:.4f}|{ref_cbr:.4f}\nmean |diff| {gaps}"
    assert not failures(sim, ref, sim_raw["cbr"], ref_cbr), failures(sim, ref, sim_raw["cbr"], ref_cbr) + [report]
    other = {0.1: 0.2, 0.2: 0.1}[beta]
    wrong, wrong_cbr = analytic(other, edges)
    assert failures(sim, wrong, sim_raw["cbr"], wrong_cbr), "the comparison does not tell 0.1 from 0.2 vehicles/m"


def same_resource_measured(sim: dict, beta: float, width_m: float = 50.0) -> np.ndarray:
    """dkfsim's ``p_sim`` per lattice distance ``k`` (k = 0 .. ): the share of the readings in
    which two vehicles held the same resource, pooled over ``width_m`` windows of distance (the
    events are rare: p_sim is near 1 / 400)."""
    same, both = sim["same"], sim["both"]
    group = np.floor(np.arange(len(same)) / beta / width_m).astype(np.int64)
    pooled_same, pooled_both = np.bincount(group, same), np.bincount(group, both)
    return np.divide(pooled_same, pooled_both, out=np.zeros(len(pooled_same)), where=pooled_both > 0)[group]


def collision_with(beta: float, p_sim_of_k: np.ndarray, distances: np.ndarray) -> np.ndarray:
    """Eqs (14)-(18) and (6.4) at lattice ``distances`` with ``p_sim`` given per lattice distance
    between interferer and transmitter (beyond its end: 1 / N, unaware vehicles)."""
    n = cv2x.resources(S, LAM)
    kd = np.rint(distances * beta).astype(np.int64)
    reach = int(round(P.reach * beta))
    xs = np.concatenate([-np.arange(reach, 0, -1), np.arange(1, reach + 1)])     # interferers, from the receiver
    d_it = np.abs(xs[None, :] + kd[:, None])
    pro = cv2x.propagation_error(distances, POWER, S)
    p_sinr = cv2x.interference_error(distances, np.arange(1, reach + 1) / beta, POWER, S)[:, np.abs(xs) - 1]
    p_int = np.where(d_it == 0, 0.0, (p_sinr - pro[:, None]) / (1.0 - pro[:, None]))      # eq. (18)
    p_sim = np.where(d_it < len(p_sim_of_k), p_sim_of_k[np.minimum(d_it, len(p_sim_of_k) - 1)], 1.0 / n)
    col = 1.0 - np.prod(1.0 - p_sim * p_int, axis=1)                                     # eqs (14), (15)
    return col * (1 - cv2x.half_duplex_error(LAM)) * (1 - cv2x.sensing_error(distances, POWER)) * (1 - pro)


#: Rebuilt collisions against dkfsim's, every bin (0.1 vehicles/m; at most 0.0041 over five sets
#: of ``RUNS``).
REBUILT_BIN = 0.008


@pytest.mark.slow
def test_the_collision_difference_is_the_schedulings():
    """At 0.1 vehicles/m, where dkfsim and the model differ most: dkfsim holds the same resource
    more often than eqs (23)/(31) between vehicles up to 300 m apart and less often between
    vehicles 450-800 m apart; given dkfsim's own ``p_sim``, the model's collision equations give
    dkfsim's collisions in every bin within 0.008 (the reception of a collided packet agrees;
    the scheduling differs, module docstring)."""
    beta = 0.1
    sim_raw = simulate(beta)
    edges = sim_raw["edges"]
    n = cv2x.resources(S, LAM)
    p_sim = same_resource_measured(sim_raw, beta)
    k = np.arange(len(p_sim))
    level, excluded3 = cv2x.step3_threshold(beta, LAM, POWER, S)
    excluded2 = cv2x.excluded_resources(cv2x.sensed_vehicles(beta, POWER), n)
    a = cv2x.alpha(excluded2 / n)
    theirs = (a * cv2x.same_resource(beta, LAM, POWER, S, k / beta, excluded2, P.sensing)
              + (1 - a) * cv2x.same_resource(beta, LAM, POWER, S, k / beta, excluded3, level))
    near, far = (k > 0) & (k / beta < 300), (k / beta >= 450) & (k / beta < 800)
    assert p_sim[near].mean() > 1.5 * theirs[near].mean(), (p_sim[near].mean() * n, theirs[near].mean() * n)
    assert p_sim[far].mean() < 0.75 * theirs[far].mean(), (p_sim[far].mean() * n, theirs[far].mean() * n)
    weights = bin_weights(beta, edges)
    distances = np.arange(weights.shape[1]) / beta
    rebuilt = weights[:, 1:] @ collision_with(beta, p_sim, distances[1:])
    got = measured(sim_raw)["collision"]
    ref, _ = analytic(beta, edges)
    rows = "\n".join(f"{edges[j]:3.0f}-{edges[j + 1]:3.0f}  {got[j]:.4f} | {rebuilt[j]:.4f} | {ref['collision'][j]:.4f}"
                     for j in range(len(got)))
    assert np.max(np.abs(got - rebuilt)) < REBUILT_BIN, "bin: dkfsim | model with dkfsim's p_sim | model\n" + rows


# ---------------------------------------------------------------- the pieces, exactly
def test_dkfsims_winner_b1_is_the_models_beyond_the_free_space_floor():
    """With the model's heights (no environment height) dkfsim's WINNER+ B1 is the model's loss
    wherever the model's floor at free space does not bind (from 102 m on), and at most 4.2 dB
    below it nearer."""
    check_winner_b1_beyond_floor(radio_params(), cv2x.path_loss_db, P.frequency, 102.0)


def test_dkfsims_per_table_reads_the_bler_table_as_the_model_does():
    """``per_table`` interpolates the BLER table linearly in dB and holds its ends, as the model
    reads it: the same BLER at every SINR from -10 to 40 dB."""
    from dkfsim.network.media.radio import reception_rule
    sinr = np.linspace(-10.0, 40.0, 1001)
    rule = reception_rule(radio_params().reception)
    per = rk.compiled().error_rate
    got = np.array([per(*rule, s) for s in sinr])
    np.testing.assert_allclose(got, cv2x.bler(sinr, S), atol=1e-15)


def test_one_subchannels_noise_is_the_models():
    """``noise_share`` of the band's -95 dBm is the model's noise over a packet's 10 resource
    blocks, -101.99 dBm; a 190-byte packet takes one sub-channel of 190 bytes; the 100 ms budget
    and RRI give the model's N = 400 candidates."""
    access = medium().access
    assert isinstance(access, Sps)
    assert P.noise_channel + 10 * math.log10(access.noise_share) == pytest.approx(cv2x.noise_dbm(S), abs=1e-12)
    assert -(-SIZE // access.subchannel_bytes) == 1
    assert access.budget_ms * access.subchannels == cv2x.resources(S, LAM) == 400
    assert np.mean(access.counter_range) / (1 - access.p_keep) == cv2x.reservation_length(LAM)

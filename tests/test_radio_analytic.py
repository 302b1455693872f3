"""The spatial radio (``medium.radio``, issue 32) against the analytic model of IEEE 802.11p of
Sepulcre et al., IEEE TVT 71(1), 2022 (tests/analytic80211p.py): the PDR against distance, the
probability of each of the four causes of a loss, and the channel busy ratio.

dkfsim is configured as the paper's model is: vehicles equally spaced on a straight road
(``road``), each broadcasting 10 beacons a second of 190 bytes (+ 30 bytes of headers) at 6
Mbit/s and 23 dBm with a random phase (``background: {arrivals: periodic, offset: random}``),
nothing else on the channel; WINNER+ B1 with the paper's effective antenna heights, 3 dB
log-normal shadowing per frame and receiver, the paper's FER-vs-SINR table as ``per_table``,
-95 dBm noise, its -85 dBm sensing threshold as both ``sensitivity`` and ``carrier_sense``,
``edca`` with 802.11p's 13 us slot.  Only frames sent by the vehicles of a central stretch are
counted, their receivers and interferers all far from the road's ends.

Why many short runs rather than one long one: with strictly periodic beacons on a static road
a pair's relative phase is the same at every period, so whether a vehicle is a hidden terminal
for a pair is drawn once per run, not per period.  The model averages over the phases; so does
this test, over ``SEEDS`` runs of one beacon period each (each run draws new phases, shadowing
and backoffs).

The model judges a frame at the SINR of one interferer over all of it (eq. (30)); dkfsim's
``per_table`` multiplies ``(1 - PER)^(chunk / frame)`` over the frame's chunks of constant
interference, which forgives a partial overlap: dkfsim counts 15-20 % fewer collisions (up to
0.018 fewer between 150 and 300 m, at both densities; judging each frame at its worst chunk
instead, a patch tried outside the package, closes it at 0.06 vehicles/m).  The tolerances below
hold that difference and the sampling noise of these runs, measured over independent batches of
seeds.
"""

from __future__ import annotations

import math

import analytic80211p as sepulcre
import numpy as np
import pytest
import simpy

from dkfsim.components.faults import LinkSpec
from dkfsim.components.latency import Constant
from dkfsim.components.medium import Edca, Medium
from dkfsim.components.radio import PerTable, RadioParams
from dkfsim.components.traffic import Background
from dkfsim.components.trajectories import Road
from dkfsim.network.media.radio import CAUSES
from dkfsim.network.network import Network

#: The paper's configuration (its run_all list): 10 Hz, 23 dBm, 190 bytes, 6 Mbit/s.
LAM, POWER, SIZE, DATA_RATE = 10.0, 23.0, 190, 6e6
P = sepulcre.PAPER
#: Frames sent by vehicles within this many metres of the road's middle are counted ...
CENTRAL_M = 1000.0
#: ... and the road goes on this far beyond them: 500 m of receivers (the bins), then 800 m of
#: their hidden terminals and of those terminals' own neighbours (sensing reaches ~300 m, ~400 m
#: with shadowing); nearer ends lowered the hidden-terminal losses measurably, farther did not.
MARGIN_M = 1300.0
#: Runs (phase draws) per density, and the window of each: frames that start in [WARM, WARM +
#: one beacon period), each vehicle's beacon once.
SEEDS = {0.06: 60, 0.12: 30}
WARM_NS, PERIOD_NS = 10_000_000, 100_000_000
#: Bins of pdr_by_distance (the paper evaluates 0, 25, ..., 500 m).
BIN_M, MAX_M = 25.0, 500.0

#: Tolerances.  PDR (issue 32): mean absolute difference over the bins, and every bin.
PDR_MEAN, PDR_BIN = 0.03, 0.08
#: CBR against eq. (35) (the paper's fit to its simulations).
CBR_TOL = 0.03
#: Each cause, every bin and mean absolute difference over the bins.  Sampling noise: over 16
#: batches of ``SEEDS`` runs (8 per density) a bin's standard deviation across batches was at
#: most 0.0047 (sensing), 0.0018 (receiver_busy), 0.0012 (propagation), 0.0021 (collision),
#: 1.0-2.6 times the binomial one of its pairs; a bin is allowed about 4 of them.  Beyond noise,
#: two known differences (module docstring, the notes): dkfsim's chunk rule loses up to 0.018
#: fewer pairs to collisions (mean 0.006), and a receiver locks on a frame only if free at its
#: start, so up to 0.003 fewer are receiver_busy at 0.12 vehicles/m.  The worst of the 16
#: batches used at most 70 % of any of these tolerances (collision, worst bin: 0.020 of 0.03).
CAUSE_BIN = {"sensing": 0.02, "receiver_busy": 0.01, "propagation": 0.006, "collision": 0.03}
CAUSE_MEAN = {"sensing": 0.004, "receiver_busy": 0.004, "propagation": 0.002, "collision": 0.01}


def radio_params(table=None) -> RadioParams:
    """The paper's radio (tests/analytic80211p.py, :class:`~analytic80211p.Paper`)."""
    return RadioParams(
        power=POWER, frequency=P.frequency, noise=P.noise,
        sensitivity=P.sensing, carrier_sense=P.sensing,
        # the paper's 1.5 m antennas over a 0.5 m environment (WINNER's own is 1 m).  (The paper's
        # code also floors the loss at free space, which only binds below 81 m: <3e-4 on its PDR.)
        path_loss={"model": "winner_b1", "height": P.h_tx, "environment_height": P.h_env},
        shadowing={"model": "lognormal", "sigma": P.sigma},
        reception={"model": "per_table", "table": sepulcre.fer_table_sinr(DATA_RATE) if table is None else table},
        bins={"width": BIN_M, "max": MAX_M})


def medium(table=None) -> Medium:
    """10 Hz beacons of 190 + 30 bytes at 6 Mbit/s with random phases, 802.11p EDCA (13 us
    slot, AIFS 110 us, CW 15), a 40 us preamble: a frame is on the air the paper's T_tr."""
    return Medium(rate=DATA_RATE, access=Edca(slot=P.slot), preamble=P.preamble,
                  background=Background(arrivals="periodic", packets_per_second=LAM, size=SIZE + P.header,
                                        offset="random"),
                  radio=radio_params(table))


def road(beta: float) -> tuple[np.ndarray, np.ndarray]:
    """Positions (1 tick) of the vehicles ``1 / beta`` m apart on a road ``2 (CENTRAL_M +
    MARGIN_M)`` m long, and which of them are central."""
    spacing = 1.0 / beta
    half = int(math.ceil((CENTRAL_M + MARGIN_M) / spacing))
    n = 2 * half + 1
    lane = Road(spacing=spacing, start=(-half * spacing, 0.0))
    xy = np.array([lane.for_node(i).positions(np.zeros(1))[0] for i in range(n)])
    return xy[None, :, :], np.abs(xy[:, 0]) <= CENTRAL_M + 1e-9


def simulate(beta: float, seeds: int, table=None, first_seed: int = 0) -> tuple[np.ndarray, float, np.ndarray]:
    """``seeds`` runs of one beacon period (seeds ``first_seed, ...``): the (frame, receiver) pairs of the central vehicles'
    frames per distance bin and fate (received, then :data:`CAUSES`), the central vehicles'
    mean CBR over the window, and the bins' edges."""
    positions, central = road(beta)
    n = positions.shape[1]
    med = medium(table)
    start, end = WARM_NS, WARM_NS + PERIOD_NS
    pairs, cbr = 0, 0.0
    for seed in range(first_seed, first_seed + seeds):
        env = simpy.Environment()
        net = Network(env, [(0, 1), (1, 0)], lambda u, v: LinkSpec(latency=Constant(value=1e-6)), seed=seed,
                      T_ns=PERIOD_NS, medium=med, positions=positions, n=n)
        channel = net.channel_of({})
        channel.measure(np.flatnonzero(central), start, end)      # the central vehicles' frames in the window
        env.run(until=start)
        busy0 = channel.cbr(start) * start
        env.run(until=end)
        busy1 = channel.cbr(end) * end
        cbr += float(((busy1 - busy0) / (end - start))[central].mean())
        channel.advance(end + 2 * channel.airtime(SIZE + P.header))   # the window's last frames end
        pairs = pairs + channel.pairs
    return pairs, cbr / seeds, channel.edges


def analytic(beta: float, edges: np.ndarray) -> tuple[dict[str, np.ndarray], float]:
    """The model averaged over each bin as dkfsim fills it, and its CBR (eq. (35)).

    dkfsim puts a pair in bin ``d // width``, ``d`` computed from the positions: a distance
    between vehicles that is a multiple of 25 m (every third vehicle at both densities) lands
    on an edge, and rounding sends some such pairs to the bin below.  So each bin's model value
    is the mean over the pairs the central vehicles' frames make in it, distance by distance."""
    positions, central = road(beta)
    xy = positions[0]
    senders = np.flatnonzero(central)
    d = np.hypot(xy[None, :, 0] - xy[senders, None, 0], xy[None, :, 1] - xy[senders, None, 1])
    b = (d // (edges[1] - edges[0])).astype(np.int64)
    k = np.rint(d * beta).astype(np.int64)
    keep = (k > 0) & (b < len(edges) - 1)
    weights = np.zeros((len(edges) - 1, int(k[keep].max()) + 1))
    np.add.at(weights, (b[keep], k[keep]), 1.0)
    result = sepulcre.model(beta, LAM, POWER, SIZE, DATA_RATE, distances=np.arange(weights.shape[1]) / beta,
                            exclude_transmitter=True)
    values = {"pdr": result.pdr, **result.errors()}
    return {name: weights @ v / weights.sum(axis=1) for name, v in values.items()}, result.cbr


def measured(pairs: np.ndarray) -> dict[str, np.ndarray]:
    frames = pairs.sum(axis=1)
    out = {"pdr": pairs[:, 0] / frames}
    for c, name in enumerate(CAUSES, start=1):
        out[name] = pairs[:, c] / frames
    return out


def discrepancies(sim: dict, ref: dict) -> dict[str, tuple[float, float]]:
    """Per quantity: (mean absolute difference over the bins, largest bin difference)."""
    return {k: (float(np.mean(np.abs(sim[k] - ref[k]))), float(np.max(np.abs(sim[k] - ref[k])))) for k in ref}


def failures(sim: dict, ref: dict, sim_cbr: float, ref_cbr: float) -> list[str]:
    """What exceeds its tolerance (empty: dkfsim agrees with the model)."""
    out = []
    gap = discrepancies(sim, ref)
    mean, worst = gap["pdr"]
    if mean > PDR_MEAN or worst > PDR_BIN:
        out.append(f"PDR: mean |diff| {mean:.4f} (<= {PDR_MEAN}), worst bin {worst:.4f} (<= {PDR_BIN})")
    if abs(sim_cbr - ref_cbr) > CBR_TOL:
        out.append(f"CBR {sim_cbr:.4f} vs {ref_cbr:.4f} (+-{CBR_TOL})")
    for name in CAUSES:
        mean, worst = gap[name]
        if mean > CAUSE_MEAN[name] or worst > CAUSE_BIN[name]:
            out.append(f"{name}: mean |diff| {mean:.4f} (<= {CAUSE_MEAN[name]}), worst bin {worst:.4f} "
                       f"(<= {CAUSE_BIN[name]})")
    return out


def table_rows(edges, sim: dict, ref: dict) -> str:
    rows = ["bin (m)   " + "  ".join(f"{k:>17s}" for k in ref)]
    for j in range(len(edges) - 1):
        rows.append(f"{edges[j]:3.0f}-{edges[j + 1]:3.0f}  " +
                    "  ".join(f"{sim[k][j]:8.4f}|{ref[k][j]:<8.4f}" for k in ref))
    return "\n".join(rows)


@pytest.mark.slow
@pytest.mark.parametrize("beta", [0.06, 0.12])
def test_pdr_causes_and_cbr_match_the_analytic_model(beta):
    """At 0.06 and 0.12 vehicles/m: the PDR of every 25 m bin up to 500 m within 0.08 of the
    model's and within 0.03 on average; the CBR within 0.03 of eq. (35); each cause within its
    tolerance (module docstring).  The same measurements against the model of the other
    density fail: the comparison can tell the densities apart."""
    pairs, sim_cbr, edges = simulate(beta, SEEDS[beta])
    assert pairs.sum(axis=1).min() > 5000          # (every bin well filled)
    sim = measured(pairs)
    ref, ref_cbr = analytic(beta, edges)
    report = f"\n{table_rows(edges, sim, ref)}\nCBR {sim_cbr:.4f}|{ref_cbr:.4f}\n{discrepancies(sim, ref)}"
    assert not failures(sim, ref, sim_cbr, ref_cbr), failures(sim, ref, sim_cbr, ref_cbr) + [report]
    other = {0.06: 0.12, 0.12: 0.06}[beta]
    wrong, wrong_cbr = analytic(other, edges)
    assert failures(sim, wrong, sim_cbr, wrong_cbr), "the comparison does not tell 0.06 from 0.12 vehicles/m"
    from test_docs_numbers import assert_block, dn  # docs/radio.md quotes these very numbers
    assert_block(dn.analytic_name(beta), dn.analytic_block(beta, edges, sim, ref, sim_cbr, ref_cbr,
                                                             discrepancies(sim, ref), SEEDS[beta]))


# ---------------------------------------------------------------- the pieces, exactly
def test_dkfsims_per_table_reads_the_papers_error_table_as_the_paper_does():
    """``per_table`` interpolates the table linearly in dB and holds its ends, as the paper's
    FER curve is read (eq. (24)): the same PER at every SINR from -10 to 45 dB."""
    from dkfsim.network import radio_kernels
    from dkfsim.network.media.radio import reception_rule
    sinr = np.linspace(-10.0, 45.0, 1101)
    rule = reception_rule(PerTable(table=sepulcre.fer_table_sinr(DATA_RATE)))      # (what the receivers read)
    per = radio_kernels.compiled().error_rate
    got = np.array([per(*rule, s) for s in sinr])
    np.testing.assert_allclose(got, sepulcre.fer(sinr, DATA_RATE), atol=1e-15)


def check_winner_b1_beyond_floor(params: RadioParams, theirs, frequency: float, floor_m: float) -> None:
    """dkfsim's WINNER+ B1 (``params``' path loss) is a model's loss ``theirs(d)`` within 0.02 dB
    from ``floor_m`` on (where the model's floor at free space does not bind), and never more than
    0.02 dB above it and at most 4.2 dB below it nearer."""
    from dkfsim.components.radio import path_loss_db
    d = np.linspace(3.0, 1500.0, 3000)
    ours = path_loss_db(params.path_loss, d, frequency)
    model = theirs(d)
    far = d >= floor_m
    np.testing.assert_allclose(ours[far], model[far], atol=0.02)
    assert np.all(model[~far] - ours[~far] >= -0.02) and np.max(model - ours) < 4.2


def test_dkfsims_winner_b1_is_the_papers_beyond_the_free_space_floor():
    """With the paper's heights dkfsim's WINNER+ B1 is the paper's loss wherever the paper's floor
    at free space does not bind (from 81 m on), and at most 4.2 dB below it nearer."""
    check_winner_b1_beyond_floor(radio_params(), sepulcre.path_loss_db, P.frequency, 81.5)


#: The authors' implementation (github.com/msepulcre/IEEE802.11p-model, model80211p.m run in
#: GNU Octave 7.3 with its signal and statistics packages) at 0, 25, ..., 500 m, 10 Hz, 23 dBm,
#: 190 bytes, 6 Mbit/s: its printed PDR and CBR -- an independent check of our transcription of
#: the equations (theirs convolves densities on a 0.1 dB grid, ours sums exact masses on 0.05 dB).
AUTHORS = {
    0.06: (0.107123, [0.9870, 0.9853, 0.9824, 0.9781, 0.9701, 0.9560, 0.9359, 0.9076, 0.8598, 0.7714, 0.6318,
                      0.4611, 0.2980, 0.1717, 0.0893, 0.0425, 0.0188, 0.0078, 0.0031, 0.0012, 0.0004]),
    0.12: (0.203630, [0.9736, 0.9700, 0.9641, 0.9554, 0.9397, 0.9123, 0.8740, 0.8253, 0.7589, 0.6614, 0.5284,
                      0.3781, 0.2405, 0.1367, 0.0702, 0.0331, 0.0145, 0.0060, 0.0023, 0.0009, 0.0003]),
}


@pytest.mark.parametrize("beta", [0.06, 0.12])
def test_the_model_reproduces_the_authors_implementation(beta):
    cbr, pdr = AUTHORS[beta]
    result = sepulcre.model(beta, LAM, POWER, SIZE, DATA_RATE)
    assert result.cbr == pytest.approx(cbr, abs=1e-6)
    np.testing.assert_allclose(result.pdr, pdr, atol=1.5e-3)
    assert np.allclose(result.sensing + result.receiver_busy + result.propagation + result.collision + result.pdr, 1.0)

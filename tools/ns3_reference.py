"""The ns-3 reference of the spatial radio (issue 32; docs/radio.md): ns-3's IEEE 802.11p on the
configurations tests/test_ns3_reference.py runs dkfsim on, results stored under tests/data/ns3/.

Runs in a venv of its own with the PyPI package ``ns3`` (cppyy bindings), never in dkfsim's:
it imports neither dkfsim nor anything but the standard library, ``ns`` and numpy::

    python3.11 -m venv ../ns3env                                     # (a venv of its own, outside the repository)
    nice -n 10 ../ns3env/bin/pip install ns3==3.44.post0 numpy     # builds cppyy: minutes
    ../ns3env/bin/python tools/ns3_reference.py                       # every configuration
    ../ns3env/bin/python tools/ns3_reference.py --only sync_n12 --out out/ns3

What ns-3 runs (every attribute the dkfsim side must mirror is written into each JSON):
802.11p (``WIFI_STANDARD_80211p``, 10 MHz), ``AdhocWifiMac`` without QoS (so the DCF: AIFSN 2,
CWmin 15), ``ConstantRateWifiManager`` at ``OfdmRate6MbpsBW10MHz``, a ``YansWifiChannel`` with
``LogDistancePropagationLossModel`` (exponent 3, reference loss free space at 1 m at 5.9 GHz;
optionally ``NakagamiPropagationLossModel``) and ``ConstantSpeedPropagationDelayModel``,
``ConstantPositionMobilityModel``, 23 dBm, no preamble detection model (a PHY locks on any
frame at or above its sensitivity, as dkfsim's radio does), no frame capture model.  ns-3
scales ``RxSensitivity`` and ``CcaSensitivity`` (given for 20 MHz) by the channel width, so they
are set 3.01 dB higher to take effect at dkfsim's -92 and -85 dBm at 10 MHz.

A small C++ helper (``cppyy.cppdef``) schedules each frame as ``NetDevice::Send`` to the
broadcast address and records every transmission (PhyTxBegin/End), every reception (the
device's receive callback), every drop (PhyRxDrop with its reason), every payload in error
(the state helper's RxError) and each PHY's state periods (its ``State`` trace: TX, RX and
CCA_BUSY are the channel busy time).  Each (frame, receiver) pair gets one fate: received,
``receiver_busy`` (dropped because the receiver was transmitting or already receiving),
``error`` (PHY header or payload decoded in error) or ``not_detected`` (no trace: below
sensitivity, Yans drops it before the PHY).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shlex
import sys
import time
from importlib import metadata
from pathlib import Path

import numpy as np

C_LIGHT = 299_792_458.0
FREQ = 5.9e9
#: the configurations: name -> parameters (``kind`` sync: ``n`` vehicles within a few metres,
#: ``rounds`` rounds ``period`` apart, all handing a frame over at once or within ``jitter``;
#: ``kind`` highway: vehicles ``spacing`` m apart over ``length`` m, beacons at ``rate`` Hz with
#: a random phase each, for ``seconds``)
CONFIGS: dict[str, dict] = {
    **{f"sync_n{n}": dict(kind="sync", n=n, jitter=0.0) for n in (4, 12, 24)},
    **{f"sync_jitter_n{n}": dict(kind="sync", n=n, jitter=5e-3) for n in (4, 12, 24)},
    "highway_d0.06": dict(kind="highway", density=0.06, length=2000.0, seconds=0.5, runs=20),
    "highway_d0.12": dict(kind="highway", density=0.12, length=2000.0, seconds=0.5, runs=20),
    "highway_d0.06_interfere": dict(kind="highway", density=0.06, length=2000.0, seconds=0.5, runs=20,
                                     weak="interfere"),
    "highway_d0.12_interfere": dict(kind="highway", density=0.12, length=2000.0, seconds=0.5, runs=20,
                                     weak="interfere"),
    # issue 32's speed target compares dkfsim per frame with ns-3 on the highway of 300 vehicles
    # with 10 Hz beacons: the same 2000 m road at 0.15 vehicles/m
    "highway_n300_interfere": dict(kind="highway", density=0.15, length=2000.0, seconds=0.5, runs=20,
                                    weak="interfere"),
    # with Nakagami fading (m = 1.5 on every distance range), frames below the sensitivity after
    # fading dropped before the PHY (YansWifiChannel)
    **{f"highway_d{d}_nakagami": dict(kind="highway", density=d, length=2000.0, seconds=0.5, runs=20, nakagami=1.5)
       for d in (0.06, 0.12)},
    # with frame capture: a receiver switches to a frame 5 dB stronger arriving within 16 us of
    # the preamble it locked on (ns-3's SimpleFrameCaptureModel)
    "highway_d0.12_capture": dict(kind="highway", density=0.12, length=2000.0, seconds=0.5, runs=20, capture=5.0),
}
SYNC = dict(psdu=200, rounds=100, period=0.1, first=0.001, square=5.0)
HIGHWAY = dict(psdu=300, rate=10.0, tail=0.01)
#: the radio, as dkfsim's RadioParams defaults name it (dBm, dB)
RADIO = dict(power=23.0, sensitivity=-92.0, carrier_sense=-85.0, noise=-95.0, exponent=3.0)
BIN_WIDTH, BIN_MAX = 25.0, 500.0
#: the headers ns-3's WifiNetDevice and AdhocWifiMac add to a broadcast payload: LLC/SNAP 8,
#: non-QoS data MAC header 24, FCS 4 (bytes)
OVERHEAD = 36
#: SINR points of the exported error table (dB)
TABLE_DB = ([float(x) for x in range(-4, 3)] + [round(3.0 + 0.1 * i, 1) for i in range(71)]
            + [float(x) for x in range(11, 21)])

HELPER = r"""
#include <map>
#include <vector>
namespace dkfref {
using namespace ns3;
std::map<uint64_t, std::pair<uint32_t, uint32_t>> uid2;       // packet uid -> (sender, seq)
std::vector<uint32_t> rx_node, rx_src, rx_seq;               // receptions
std::vector<uint32_t> drop_node, drop_reason; std::vector<uint64_t> drop_uid;
std::vector<uint32_t> err_node; std::vector<uint64_t> err_uid;
std::vector<uint32_t> tx_node; std::vector<uint64_t> tx_uid; std::vector<int64_t> tx_t;
std::vector<uint64_t> txe_uid; std::vector<int64_t> txe_t;
std::vector<int64_t> busy_ns;                                 // per node: TX + RX + CCA_BUSY
std::vector<int64_t> st_ns;                                   // per node and state (8 states)
NetDeviceContainer devs;
void Clear() {
  uid2.clear(); rx_node.clear(); rx_src.clear(); rx_seq.clear(); drop_node.clear();
  drop_reason.clear(); drop_uid.clear(); err_node.clear(); err_uid.clear(); tx_node.clear();
  tx_uid.clear(); tx_t.clear(); txe_uid.clear(); txe_t.clear(); busy_ns.clear(); st_ns.clear();
}
bool Rx(uint32_t n, Ptr<NetDevice>, Ptr<const Packet> p, uint16_t, const Address&) {
  uint32_t b[2]; p->CopyData((uint8_t*)b, 8);
  rx_node.push_back(n); rx_src.push_back(b[0]); rx_seq.push_back(b[1]);
  return true;
}
void Drop(uint32_t n, Ptr<const Packet> p, WifiPhyRxfailureReason r) {
  drop_node.push_back(n); drop_reason.push_back((uint32_t)r); drop_uid.push_back(p->GetUid());
}
void Err(uint32_t n, Ptr<const Packet> p, double) { err_node.push_back(n); err_uid.push_back(p->GetUid()); }
void TxB(uint32_t n, Ptr<const Packet> p, double) {
  tx_node.push_back(n); tx_uid.push_back(p->GetUid()); tx_t.push_back(Simulator::Now().GetNanoSeconds());
}
void TxE(uint32_t n, Ptr<const Packet> p) { txe_uid.push_back(p->GetUid()); txe_t.push_back(Simulator::Now().GetNanoSeconds()); }
void State(uint32_t n, Time start, Time duration, WifiPhyState s) {
  st_ns[n * 8 + (uint32_t)s] += duration.GetNanoSeconds();
  if (s == WifiPhyState::TX || s == WifiPhyState::RX || s == WifiPhyState::CCA_BUSY)
    busy_ns[n] += duration.GetNanoSeconds();
}
void DoSend(uint32_t n, uint32_t seq, uint32_t size) {
  std::vector<uint8_t> buf(size, 0); uint32_t b[2] = {n, seq}; memcpy(buf.data(), b, 8);
  Ptr<Packet> p = Create<Packet>(buf.data(), size);
  uid2[p->GetUid()] = {n, seq};
  devs.Get(n)->Send(p, Mac48Address::GetBroadcast(), 0x88B5);
}
void Hook(NetDeviceContainer d) {
  devs = d;
  busy_ns.assign(d.GetN(), 0); st_ns.assign(8 * d.GetN(), 0);
  for (uint32_t i = 0; i < d.GetN(); ++i) {
    d.Get(i)->SetReceiveCallback(MakeBoundCallback(&Rx, i));
    Ptr<WifiPhy> phy = DynamicCast<WifiNetDevice>(d.Get(i))->GetPhy();
    phy->TraceConnectWithoutContext("PhyRxDrop", MakeBoundCallback(&Drop, i));
    phy->TraceConnectWithoutContext("PhyTxBegin", MakeBoundCallback(&TxB, i));
    phy->TraceConnectWithoutContext("PhyTxEnd", MakeBoundCallback(&TxE, i));
    phy->GetState()->TraceConnectWithoutContext("RxError", MakeBoundCallback(&Err, i));
    phy->GetState()->TraceConnectWithoutContext("State", MakeBoundCallback(&State, i));
  }
}
void At(int64_t t_ns, uint32_t n, uint32_t seq, uint32_t size) {
  Simulator::Schedule(NanoSeconds(t_ns), &DoSend, n, seq, size);
}
// the success rate of a frame: its L-SIG (24 bits at the header mode) and its data field
// (nbits at the data mode), both at SNR snr (linear), by the error rate model em
double FrameSuccess(Ptr<ErrorRateModel> em, double snr, uint64_t nbits) {
  WifiTxVector v;
  v.SetMode(WifiMode("OfdmRate6MbpsBW10MHz"));
  v.SetChannelWidth(MHz_u{10});
  v.SetPreambleType(WIFI_PREAMBLE_LONG);
  double h = em->GetChunkSuccessRate(WifiMode("OfdmRate3MbpsBW10MHz"), v, snr, 24, 1, WIFI_PPDU_FIELD_NON_HT_HEADER);
  double d = em->GetChunkSuccessRate(WifiMode("OfdmRate6MbpsBW10MHz"), v, snr, nbits, 1, WIFI_PPDU_FIELD_DATA);
  return h * d;
}
int64_t TxDuration(Ptr<NetDevice> dev, uint32_t psdu) {
  Ptr<WifiPhy> phy = DynamicCast<WifiNetDevice>(dev)->GetPhy();
  WifiTxVector v;
  v.SetMode(WifiMode("OfdmRate6MbpsBW10MHz"));
  v.SetChannelWidth(MHz_u{10});
  v.SetPreambleType(WIFI_PREAMBLE_LONG);
  return phy->CalculateTxDuration(psdu, v, phy->GetPhyBand()).GetNanoSeconds();
}
}
"""

ERROR_MODELS = {"nist": "ns3::NistErrorRateModel", "yans": "ns3::YansErrorRateModel",
                "table": "ns3::TableBasedErrorRateModel"}


def free_space_1m() -> float:
    return 20.0 * math.log10(4.0 * math.pi * FREQ / C_LIGHT)


def noise_figure() -> float:
    """The RxNoiseFigure (dB) that puts ns-3's noise floor over 10 MHz (Boltzmann's constant as
    ns-3 writes it, 290 K) at ``RADIO['noise']``."""
    thermal_dbm = 10.0 * math.log10(1.3803e-23 * 290.0 * 10e6) + 30.0
    return RADIO["noise"] - thermal_dbm


# ----------------------------------------------------------------------- geometry and traffic
def sync_plan(cfg: dict, rng: np.random.Generator) -> tuple[np.ndarray, list[tuple[int, int, int]]]:
    """Positions within a square of SYNC['square'] m, and (instant ns, node, seq) of every frame:
    round k at ``first + k period``, each node ``U[0, jitter)`` late."""
    n = cfg["n"]
    pos = np.round(rng.uniform(0.0, SYNC["square"], size=(n, 2)), 3)
    sends = []
    for k in range(SYNC["rounds"]):
        t0 = SYNC["first"] + k * SYNC["period"]
        delay = rng.uniform(0.0, cfg["jitter"], size=n) if cfg["jitter"] else np.zeros(n)
        sends += [(int(round((t0 + float(delay[i])) * 1e9)), i, k) for i in range(n)]
    return pos, sends


def highway_plan(cfg: dict, rng: np.random.Generator) -> tuple[np.ndarray, list[tuple[int, int, int]]]:
    """Vehicles equally spaced on one line, beacons at HIGHWAY['rate'] Hz from a uniform phase
    each over one period, for ``seconds`` plus a tail of HIGHWAY['tail'] s."""
    spacing = 1.0 / cfg["density"]
    n = int(round(cfg["length"] * cfg["density"]))
    pos = np.zeros((n, 2))
    pos[:, 0] = np.arange(n) * spacing
    period = 1.0 / HIGHWAY["rate"]
    phase = rng.uniform(0.0, period, size=n)
    end = cfg["seconds"] + HIGHWAY["tail"]
    sends = []
    for i in range(n):
        k = 0
        while phase[i] + k * period < end:
            sends.append((int(round((phase[i] + k * period) * 1e9)), i, k))
            k += 1
    return pos, sends


# ----------------------------------------------------------------------- ns-3
def build(ns, cppyy, pos: np.ndarray, error_model: str, nakagami_m: float | None, seed: int, weak: str = "ignore",
          capture: float | None = None):
    """The ns-3 nodes, devices and PHY attributes.  ``weak``: ``ignore``, ns-3's YansWifiChannel
    drops a frame below RxSensitivity before the PHY (it is no interference either);
    ``interfere``, every frame reaches the PHY (RxSensitivity -200 dBm, so it interferes) and
    a ThresholdPreambleDetectionModel (MinimumRssi = the sensitivity, Threshold -100 dB: no SNR
    condition) keeps the PHY from locking on one below the sensitivity -- dkfsim's semantics."""
    ns.RngSeedManager.SetSeed(seed)
    ns.RngSeedManager.SetRun(1)
    n = len(pos)
    nodes = ns.NodeContainer()
    nodes.Create(n)
    wifi = ns.WifiHelper()
    wifi.SetStandard(ns.WIFI_STANDARD_80211p)
    mode = ns.StringValue("OfdmRate6MbpsBW10MHz")
    wifi.SetRemoteStationManager("ns3::ConstantRateWifiManager", "DataMode", mode, "ControlMode", mode,
                                 "NonUnicastMode", mode)
    ch = ns.YansWifiChannelHelper()
    ch.SetPropagationDelay("ns3::ConstantSpeedPropagationDelayModel")
    ch.AddPropagationLoss("ns3::LogDistancePropagationLossModel", "Exponent", ns.DoubleValue(RADIO["exponent"]),
                          "ReferenceDistance", ns.DoubleValue(1.0), "ReferenceLoss", ns.DoubleValue(free_space_1m()))
    if nakagami_m is not None:
        m = ns.DoubleValue(nakagami_m)
        ch.AddPropagationLoss("ns3::NakagamiPropagationLossModel", "m0", m, "m1", m, "m2", m)
    phy = ns.YansWifiPhyHelper()
    phy.SetChannel(ch.Create())
    phy.SetErrorRateModel(ERROR_MODELS[error_model])
    width_db = 10.0 * math.log10(10.0 / 20.0)          # ns-3 scales these 20 MHz thresholds by width
    attrs = {"TxPowerStart": RADIO["power"], "TxPowerEnd": RADIO["power"],
             "RxSensitivity": RADIO["sensitivity"] - width_db, "CcaSensitivity": RADIO["carrier_sense"] - width_db,
             "CcaEdThreshold": RADIO["carrier_sense"], "RxNoiseFigure": noise_figure()}
    if weak == "ignore":
        phy.DisablePreambleDetectionModel()
    else:
        attrs["RxSensitivity"] = -200.0
        phy.SetPreambleDetectionModel("ns3::ThresholdPreambleDetectionModel", "MinimumRssi",
                                      ns.DoubleValue(RADIO["sensitivity"]), "Threshold", ns.DoubleValue(-100.0))
    if capture is not None:                 # (CaptureWindow: its default, 16 us after the first preamble)
        phy.SetFrameCaptureModel("ns3::SimpleFrameCaptureModel", "Margin", ns.DoubleValue(capture))
    for k, v in attrs.items():
        phy.Set(k, ns.DoubleValue(v))
    phy.Set("ChannelSettings", ns.StringValue("{0, 10, BAND_5GHZ, 0}"))
    mac = ns.WifiMacHelper()
    mac.SetType("ns3::AdhocWifiMac", "QosSupported", ns.BooleanValue(False))
    devs = wifi.Install(phy, mac, nodes)
    wifi.AssignStreams(devs, seed)
    mob = ns.MobilityHelper()
    alloc = ns.ListPositionAllocator()
    for x, y in pos:
        alloc.Add(ns.Vector(float(x), float(y), 0.0))
    mob.SetPositionAllocator(alloc)
    mob.SetMobilityModel("ns3::ConstantPositionMobilityModel")
    mob.Install(nodes)
    g = cppyy.gbl.dkfref
    g.Clear()
    g.Hook(devs)
    return nodes, devs, attrs


def mac_timing(ns, devs) -> dict:
    """The MAC timing ns-3 uses (seconds), read from the objects it built."""
    dev = ns.DynamicCast[ns.WifiNetDevice](devs.Get(0))
    phy, txop = dev.GetPhy(), dev.GetMac().GetTxop()
    sifs, slot, ack = (phy.GetSifs().GetNanoSeconds(), phy.GetSlot().GetNanoSeconds(),
                       phy.GetAckTxTime().GetNanoSeconds())
    aifsn = int(txop.GetAifsn())
    difs = sifs + aifsn * slot
    return {"slot": slot / 1e9, "sifs": sifs / 1e9, "aifsn": aifsn, "difs": difs / 1e9,
            "ack_tx_time": ack / 1e9, "eifs": (sifs + ack + difs) / 1e9,
            "cw_min": int(txop.GetMinCw()), "cw_max": int(txop.GetMaxCw()),
            "note": "non-QoS DCF (AdhocWifiMac, QosSupported false): EIFS = SIFS + AckTxTime + DIFS "
                    "(ChannelAccessManager::GetEifsNoDifs + DIFS); a frame that finds the medium idle with "
                    "no backoff pending goes DIFS after it was queued (NeedBackoffUponAccess: backoff "
                    "start = now + SIFS + AIFSN slot), or DIFS after the medium became idle if later"}


def error_table(ns, cppyy, error_model: str, data_bits: int) -> list[list[float]]:
    em = ns.CreateObject[getattr(ns, ERROR_MODELS[error_model].split("::")[1])]()
    out = []
    for s in TABLE_DB:
        ok = float(cppyy.gbl.dkfref.FrameSuccess(em, 10.0 ** (s / 10.0), data_bits))
        out.append([s, round(1.0 - ok, 6)])
    return out


def fates(ns, cppyy, pos: np.ndarray, t_end_ns: int, weak_reach_phy: bool = False) -> dict:
    """Every (frame, receiver) pair of the frames that ended by ``t_end_ns`` - 10 us, binned by
    distance: received, receiver_busy, error, not_detected.  ``weak_reach_phy``: frames below
    the sensitivity reach the PHY (and leave drop traces): a pair whose power by path loss is
    below it is ``not_detected`` whatever its trace (no fading then)."""
    g = cppyy.gbl.dkfref
    n = len(pos)
    uid_of = {}
    for uid, sq in g.uid2:
        uid_of[int(uid)] = (int(sq.first), int(sq.second))
    key_of_uid = {}
    tx_uids = [int(u) for u in g.tx_uid]
    for u in tx_uids:
        key_of_uid[u] = uid_of[u]
    ends = {int(u): int(t) for u, t in zip(g.txe_uid, g.txe_t)}
    done = [u for u in tx_uids if u in ends and ends[u] <= t_end_ns - 10_000]
    index = {key_of_uid[u]: f for f, u in enumerate(done)}
    F = len(done)
    RECEIVED, BUSY, ERROR, NOT_DETECTED = 0, 1, 2, 3
    fate = np.full((F, n), NOT_DETECTED, dtype=np.int8)
    sender = np.array([key_of_uid[u][0] for u in done], dtype=np.int64)
    frow = {u: f for f, u in enumerate(done)}
    busy_reasons = {int(getattr(ns, r)) for r in ("RXING", "TXING", "BUSY_DECODING_PREAMBLE", "RECEPTION_ABORTED_BY_TX",
                                                  "PREAMBLE_DETECTION_PACKET_SWITCH", "FRAME_CAPTURE_PACKET_SWITCH",
                                                  "SIGNAL_DETECTION_ABORTED_BY_TX")}
    reasons: dict[int, int] = {}
    for node, reason, uid in zip(g.drop_node, g.drop_reason, g.drop_uid):
        f = frow.get(int(uid))
        reasons[int(reason)] = reasons.get(int(reason), 0) + 1
        if f is not None:
            fate[f, int(node)] = BUSY if int(reason) in busy_reasons else ERROR
    for node, uid in zip(g.err_node, g.err_uid):
        f = frow.get(int(uid))
        if f is not None:
            fate[f, int(node)] = ERROR
    for node, src, seq in zip(g.rx_node, g.rx_src, g.rx_seq):
        f = index.get((int(src), int(seq)))
        if f is not None:
            fate[f, int(node)] = RECEIVED
    d = np.hypot(pos[:, None, 0] - pos[None, :, 0], pos[:, None, 1] - pos[None, :, 1])
    dist = d[sender]                                   # (F, n)
    if weak_reach_phy:
        rx_dbm = RADIO["power"] - free_space_1m() - 10.0 * RADIO["exponent"] * np.log10(np.maximum(dist, 1.0))
        fate[(rx_dbm < RADIO["sensitivity"]) & (fate != RECEIVED)] = NOT_DETECTED
    pair = np.ones((F, n), dtype=bool)
    pair[np.arange(F), sender] = False
    nb = int(round(BIN_MAX / BIN_WIDTH))
    # (dkfsim's count_pair: a distance of whole bins, 150 m computed as 149.99999999999997, counts in
    # the upper bin; plain floor division once moved such pairs a bin down and made a gap)
    b = np.floor(dist / BIN_WIDTH + 1e-9).astype(np.int64)
    inb = pair & (b < nb)
    counts = np.zeros((nb, 4), dtype=np.int64)
    np.add.at(counts, (b[inb], fate[inb]), 1)
    frames = counts.sum(axis=1)
    names = {int(getattr(ns, r)): r for r in ("RXING", "TXING", "BUSY_DECODING_PREAMBLE", "RECEPTION_ABORTED_BY_TX",
                                              "L_SIG_FAILURE", "PREAMBLE_DETECTION_PACKET_SWITCH",
                                              "FRAME_CAPTURE_PACKET_SWITCH", "PREAMBLE_DETECT_FAILURE",
                                              "SIGNAL_DETECTION_ABORTED_BY_TX")}
    total = counts.sum(axis=0)
    detected = int(total[:3].sum())
    return {
        "frames": F,
        "bins_m": [float(x) for x in np.arange(nb + 1) * BIN_WIDTH],
        "pairs": frames.tolist(),
        "received": counts[:, RECEIVED].tolist(),
        "receiver_busy": counts[:, BUSY].tolist(),
        "error": counts[:, ERROR].tolist(),
        "not_detected": counts[:, NOT_DETECTED].tolist(),
        "pdr": [None if f == 0 else round(float(r) / float(f), 6) for r, f in zip(counts[:, RECEIVED], frames)],
        "totals": {"pairs": int(total.sum()), "received": int(total[RECEIVED]), "receiver_busy": int(total[BUSY]),
                   "error": int(total[ERROR]), "not_detected": int(total[NOT_DETECTED])},
        "collided_fraction": round((int(total[BUSY]) + int(total[ERROR])) / detected, 6) if detected else 0.0,
        "drop_reasons": {names.get(k, str(k)): v for k, v in sorted(reasons.items())},
    }


def nakagami_of(cfg: dict, args) -> float | None:
    """The Nakagami m of a configuration: its own ``nakagami``, else ``--nakagami`` (None: no fading)."""
    return cfg.get("nakagami", args.nakagami)


def run_once(cfg: dict, args, ns, cppyy, seed: int) -> tuple[np.ndarray, dict, int, dict]:
    """One ns-3 run of ``cfg`` with its own draws (positions, send instants, ns-3's streams)."""
    rng = np.random.default_rng(seed)
    if cfg["kind"] == "sync":
        pos, sends = sync_plan(cfg, rng)
        psdu = SYNC["psdu"]
        t_end_ns = int(round(SYNC["rounds"] * SYNC["period"] * 1e9))
    else:
        pos, sends = highway_plan(cfg, rng)
        psdu = HIGHWAY["psdu"]
        t_end_ns = int(round((cfg["seconds"] + HIGHWAY["tail"]) * 1e9))
    weak = cfg.get("weak", "ignore")
    _, devs, attrs = build(ns, cppyy, pos, args.error_model, nakagami_of(cfg, args), seed, weak, cfg.get("capture"))
    g = cppyy.gbl.dkfref
    airtime_ns = int(g.TxDuration(devs.Get(0), psdu))
    payload = psdu - OVERHEAD
    t0 = time.process_time()
    for t, node, seq in sends:
        g.At(t, node, seq, payload)
    ns.Simulator.Stop(ns.NanoSeconds(t_end_ns))
    ns.Simulator.Run()
    cpu = time.process_time() - t0
    out = fates(ns, cppyy, pos, t_end_ns, weak == "interfere")
    busy = np.array([int(x) for x in g.busy_ns], dtype=np.float64)
    extra = {"mac": mac_timing(ns, devs), "attrs": attrs, "airtime_ns": airtime_ns, "payload": payload,
             "psdu": psdu, "cbr_mean": float((busy / t_end_ns).mean()), "cpu": cpu, "frames": int(len(g.tx_uid))}
    ns.Simulator.Destroy()
    return pos, out, t_end_ns, extra


def merge(outs: list[dict]) -> dict:
    """The pair counts of several runs added up, PDR and the lost fraction of the sums."""
    out = dict(outs[0])
    for key in ("pairs", "received", "receiver_busy", "error", "not_detected"):
        out[key] = np.sum([o[key] for o in outs], axis=0).tolist()
    out["frames"] = sum(o["frames"] for o in outs)
    out["pdr"] = [None if f == 0 else round(r / f, 6) for r, f in zip(out["received"], out["pairs"])]
    totals = {k: sum(o["totals"][k] for o in outs) for k in outs[0]["totals"]}
    out["totals"] = totals
    detected = totals["pairs"] - totals["not_detected"]
    out["collided_fraction"] = round((totals["receiver_busy"] + totals["error"]) / detected, 6) if detected else 0.0
    reasons: dict[str, int] = {}
    for o in outs:
        for k, v in o["drop_reasons"].items():
            reasons[k] = reasons.get(k, 0) + v
    out["drop_reasons"] = reasons
    return out


def run(name: str, cfg: dict, args, ns, cppyy) -> dict:
    """``cfg['runs']`` independent runs (seeds ``seed .. seed + runs - 1``), their pairs added up."""
    runs = [run_once(cfg, args, ns, cppyy, args.seed + r) for r in range(cfg.get("runs", 1))]
    pos, _, t_end_ns, ex = runs[0]
    out = merge([r[1] for r in runs])
    cbr = float(np.mean([r[3]["cbr_mean"] for r in runs]))
    cpu = sum(r[3]["cpu"] for r in runs)
    frames = sum(r[3]["frames"] for r in runs)
    timing, attrs, airtime_ns, payload, psdu = ex["mac"], ex["attrs"], ex["airtime_ns"], ex["payload"], ex["psdu"]
    if cfg["kind"] == "sync":
        assert cfg.get("runs", 1) == 1            # (the positions stored are run 0's)
    preamble_ns = 40_000
    data_bits = int(round((airtime_ns - preamble_ns) * 6e6 / 1e9))
    result = {
        "name": name,
        "ns3_version": metadata.version("ns3"),
        "command": " ".join(shlex.quote(a) for a in ["python", *sys.argv]),   # (python: the ns3 venv's)
        "config": {**{k: v for k, v in cfg.items() if k != "nakagami"}, **(SYNC if cfg["kind"] == "sync" else HIGHWAY),
                   "seed": args.seed, "runs": cfg.get("runs", 1),
                   "error_model": ERROR_MODELS[args.error_model], "nakagami_m": nakagami_of(cfg, args),
                   "duration_s": t_end_ns / 1e9, "payload_bytes": payload,
                   "bins": {"width": BIN_WIDTH, "max": BIN_MAX}},
        "positions": pos.tolist(),
        "radio": {**RADIO, "frequency": FREQ, "reference_loss_db": free_space_1m(), "ns3_attributes": attrs,
                  "propagation_delay": "ConstantSpeedPropagationDelayModel",
                  "weak_frames": cfg.get("weak", "ignore"),
                  "preamble_detection": "none" if cfg.get("weak", "ignore") == "ignore" else
                  f"ThresholdPreambleDetectionModel MinimumRssi {RADIO['sensitivity']} dBm, Threshold -100 dB",
                  "frame_capture": "none" if cfg.get("capture") is None else
                  f"SimpleFrameCaptureModel Margin {cfg['capture']} dB, CaptureWindow 16 us",
                  # (the window counts from the preamble's detection, 4 us into the frame)
                  "capture_margin_db": cfg.get("capture"),
                  "capture_window_s": None if cfg.get("capture") is None else 20e-6},
        "airtime": {"psdu_bytes": psdu, "ns3_tx_duration_s": airtime_ns / 1e9, "preamble_s": preamble_ns / 1e9,
                    "data_field_bits": data_bits,
                    "dkfsim_size_bytes": (airtime_ns - preamble_ns) * 6e6 / 8 / 1e9,
                    "note": "ns-3 (OfdmPhy::GetPayloadDuration) counts ceil((16 + 8 psdu + 6) / 24) symbols of "
                            "4 us at 6 Mbit/s and 10 MHz; dkfsim's size is the one whose airtime "
                            "preamble + size 8 / 6e6 is ns-3's"},
        "mac": timing,
        "per_table": error_table(ns, cppyy, args.error_model, data_bits),
        "per_table_note": "1 - (L-SIG success, 24 bits at OfdmRate3MbpsBW10MHz) x (data success, "
                          "data_field_bits at OfdmRate6MbpsBW10MHz) of the error rate model at that SINR",
        "results": {**out, "cbr_mean": round(cbr, 6),
                    "cbr_note": "per node: time in TX, RX or CCA_BUSY (WifiPhyStateHelper State trace) "
                                "over duration_s, averaged over the nodes and the runs"},
        "timing": {"cpu_seconds": round(cpu, 3), "frames": frames,
                   "cpu_per_frame_us": round(cpu / max(1, frames) * 1e6, 3),
                   "note": "process CPU time of scheduling and Simulator::Run, the import excluded"},
    }
    return result


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--only", nargs="*", choices=sorted(CONFIGS), help="configurations to run (default: all)")
    ap.add_argument("--out", default=str(Path(__file__).resolve().parent.parent / "tests" / "data" / "ns3"))
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--error-model", choices=sorted(ERROR_MODELS), default="nist")
    ap.add_argument("--nakagami", type=float, default=None, help="Nakagami m (default: no fading)")
    args = ap.parse_args(argv)
    if args.nakagami is not None and any(CONFIGS[c].get("weak") == "interfere" for c in args.only or CONFIGS):
        ap.error("--nakagami with a weak: interfere configuration: its pairs are told detected by path loss alone")
    t = time.time()
    import cppyy  # noqa: PLC0415
    from ns import ns  # noqa: PLC0415 (the bindings: seconds to minutes)
    cppyy.cppdef(HELPER)
    print(f"ns-3 imported in {time.time() - t:.0f} s", flush=True)
    os.makedirs(args.out, exist_ok=True)
    for name in args.only or list(CONFIGS):
        res = run(name, CONFIGS[name], args, ns, cppyy)
        path = Path(args.out) / f"{name}.json"
        path.write_text(json.dumps(res, indent=1) + "\n")
        r = res["results"]
        print(f"{name}: {res['timing']['frames']} frames, {res['timing']['cpu_seconds']} s CPU, "
              f"PDR bin0 {r['pdr'][0]}, collided {r['collided_fraction']}, CBR {r['cbr_mean']}, "
              f"drops {r['drop_reasons']} -> {path}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

#!/usr/bin/env python
"""Benchmarks of dkfsim, printed as ratios measured in one process.

1. ``paper_case1`` for 1000 ticks (fusion included): wall and CPU time, the
   number of packet events, the time bare SimPy needs for the same number of
   ``timeout`` events with a no-op callback, and their ratio; the same run on the pure-numpy
   path (``DKFSIM_KERNELS=numpy``) in the same process; the first call's cost (kernel compile,
   or loading them from the disk cache).
2. A scaling table for random trees of 12, 50 and 200 nodes: ticks per
   second and packets per tick, with per-tick cost normalised by the work
   (nodes x window rows for filtering, links for packets); then the fitted
   exponents of the per-tick cost against the node-rows actually re-run and
   against the links, over trees of 12 ... 1000 nodes (d_t = 1, no fusion).
3. Sweep throughput on 2 local workers: runs per minute of ``paper_case1`` at
   1000 ticks, through the whole sweep path (SQLite included), against one
   process in the same run.
4. The per-tick cost of a 1000-node random tree (no fusion) and the process's peak memory.
5. BLAS threads under load: a 50-node matrix-fusion run with the BLAS
   library's default threads and with one thread (what dkfsim uses), each
   while a CPU hog process spins beside it.
6. Monte Carlo on the one executor: this process, 2 local processes and a Dask
   LocalCluster of 2 worker processes (start-up included), runs per minute and
   whether the rows are identical.
7. A graph that changes (issue 23): ``paper_case1`` with ``mobility:`` whose links go down
   and come back every few ticks (each non-root vehicle out of range one tick in
   ``--mobility-period``, periodically, and then at random ticks with that probability, so
   that almost every tick has a new set of links), against the same run on the fixed graph,
   alternated (``--repeats`` times, min CPU of each); the ratio changing / fixed.
   ``--mobility-only`` runs this section alone.
8. Links that carry the traffic (issue 21): ``paper_case1`` with every link at 1 Mbit/s, a
   room of 20 packets and Poisson background (:data:`TRAFFIC`) against the same scenario
   without these keys, alternated in this process, min of ``--repeats``.
   ``--traffic-only`` runs this line alone.
9. A fusion centre over the network (issue 22): ``paper_case1`` with ``{kind: fusion_centre,
   at: 0}`` against the same scenario without it, alternated in this process, min CPU of
   ``--repeats``.
   ``--centre-only`` runs this line alone.
10. A shared channel (issue 22): ``scenarios/channel_its_g5.yaml`` (every estimator on one
    CSMA channel with background) against the same scenario without ``medium:``, alternated;
    min CPU of ``--repeats``.  ``--channel-only`` runs this line alone.

11. Start-up (issue 34): ``import dkfsim`` (CPU), ``dkfsim --help``, ``dkfsim list``, ``dkfsim
    validate scenarios/paper_case1.yaml`` and ``dkfsim run`` of it (wall and CPU; the run loads
    the compiled kernels from numba's cache, compiled in the warm-up round), each a fresh process, with Python's
    bytecode cache on (as a default Python has it: ``PYTHONDONTWRITEBYTECODE`` is removed from
    the probes' environment, every command run once before it is measured), min of ``--repeats``.
    ``--startup`` runs this section alone; with ``--base REF`` the commit ``REF`` (``git
    archive``) and this checkout are alternated in the same rounds and their ratios printed.
    The issue's targets on a quiet 2-core machine: ``import dkfsim`` below 0.4 s CPU, ``--help``
    and ``list`` below 0.5 s wall, ``validate`` below 1 s wall.

13. A spatial radio (issue 32): ``--radio-only`` runs vehicles on a two-lane road 8 m apart
    (50 ... 400) sending only 10 Hz beacons on the radio (:data:`RADIO`, EDCA) and prints the CPU
    per frame against the receivers in range (those that detect a frame), with the fitted
    exponent; then ``scenarios/highway_its_g5.yaml`` for ``--highway-seconds`` (the DKF group
    alone: the issue's target is 60 s of CPU for 60 s simulated).

12. Seconds per event (issue 34 §2): ``--calibrate`` runs a set of scenarios that exercise
    each kind of event (:data:`CALIBRATION_RUNS`: plain, rate-limited, channel, flood, the
    consensus family, a fusion centre, a changing graph, a 50-node tree), each warmed up once,
    alternated ``--repeats`` times in this process, and fits the CPU seconds of a run to its
    events (ticks, packets, node-rows, fused rows x (n nx)^3; non-negative least squares on the
    min CPU of each), prints the fit and each run's predicted / measured seconds, and writes the
    constants to ``dkfsim/data/calibration/seconds_per_event.json`` (the estimates' only
    machine-dependent input) with the machine and the load it was measured under.

Before/after (``--base REF``): the runs issue 31 holds to the commit before it -- paper_case1
(on the default path, with ``DKFSIM_EXCHANGE=python`` which a base commit may still read, and
on the numpy path), a 50-node tree with matrix fusion, a 200-node tree without, the 1000-node
tree, the shipped channel scenario, mobility_crossing, paper_case1 on rate-limited links, with a
fusion centre, and with a fusion centre on rate-limited links, paper_case1 on exponential latency
and stress_heavy_tail (latencies drawn one packet at a time) -- each in a fresh process,
alternating the commit ``REF``
(``git archive``, unpacked in a temporary folder) and this checkout ``--repeats`` times;
prints the CPU seconds of each (min over the repeats, each run after a short warm-up run of
the same kind) and the ratio this / base.  Nothing else runs in that mode.

Usage: ``python tools/bench.py [--ticks 1000] [--sizes 12 50 200] [--fit-sizes 12 50 200 1000]
[--skip-sweep] [--big-ticks 200] [--skip-threads] [--skip-executors] [--skip-traffic]``,
``python tools/bench.py --traffic-only [--ticks 1000] [--repeats 3]``,
``python tools/bench.py --centre-only [--ticks 1000] [--repeats 3]`` (``--channel-only`` likewise), or
``python tools/bench.py --base REF [--repeats 3]``,
``python tools/bench.py --startup [--base REF] [--repeats 5]``,
``python tools/bench.py --calibrate [--repeats 3] [--ticks 1000]``.
Timing lives here, never in the tests.
"""

from __future__ import annotations

import argparse
import json
import math
import multiprocessing
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import simpy

ROOT = Path(__file__).resolve().parents[1]
#: Which dkfsim the measurements import: this checkout, or (the probes of ``--base``) another tree.
TREE_ENV = "DKFSIM_BENCH_TREE"
sys.path.insert(0, os.environ.get(TREE_ENV) or str(ROOT))

import dkfsim  # noqa: E402
from dkfsim.core.jit import KERNELS_ENV  # noqa: E402

#: The environment variable of the Python exchange beside the compiled tree, before issue 31 (a
#: base commit of ``--base`` may still read it; this checkout ignores it: one exchange path).
EXCHANGE_ENV = "DKFSIM_EXCHANGE"

#: Issue 21's bench line: every link of ``paper_case1`` at 1 Mbit/s, a room of 20 packets and
#: Poisson background of 50 packets/s x 250 B (docs/traffic.md, "Cost").
TRAFFIC = ("links.default.rate=1.0e6", "links.default.queue={packets: 20}",
           "links.default.background={arrivals: poisson, packets_per_second: 50, size: 250}")


def bare_simpy(n_events: int, horizon: int) -> float:
    """Seconds for SimPy to schedule and fire ``n_events`` timeouts with a callback."""
    env = simpy.Environment()

    def noop(_ev):
        pass

    per_step = max(1, n_events // horizon)

    def source(env):
        made = 0
        while made < n_events:
            for j in range(min(per_step, n_events - made)):
                ev = env.timeout(j % 5)
                ev.callbacks.append(noop)
            made += per_step
            yield env.timeout(1)

    env.process(source(env))
    t0 = time.perf_counter()
    env.run()
    return time.perf_counter() - t0


def throughput(scenario: str | os.PathLike | None = None, *, steps: int = 1000, jobs: int = 2,
               runs: int | None = None, executor=None, overrides=()) -> dict:
    """Measured sweep throughput: ``runs`` Monte Carlo runs of ``scenario``
    (default ``scenarios/paper_case1.yaml``) at ``steps`` ticks through the
    whole sweep machinery (executor, scoring, SQLite writes), into a
    temporary database.

    ``executor`` defaults to ``jobs`` local processes; ``runs`` to ``4 *
    jobs``.  Worker start-up is included (it is part of what a sweep costs).
    Returns ``{"scenario", "steps", "runs", "executor", "wall_s",
    "runs_per_minute"}``.
    """
    from dkfsim.experiments.sweep import load_sweep, run_sweep
    if scenario is None:
        scenario = ROOT / "scenarios" / "paper_case1.yaml"
    runs = 4 * jobs if runs is None else runs
    with tempfile.TemporaryDirectory(prefix="dkfsim-throughput-") as tmp:
        sweep = load_sweep({"scenario": str(Path(scenario).resolve()),
                            "set": [f"steps={int(steps)}", *overrides], "runs": runs,
                            "output": str(Path(tmp) / "throughput.sqlite")})
        rep = run_sweep(sweep, executor=executor, jobs=jobs, progress=False)
    return {"scenario": str(scenario), "steps": int(steps), "runs": rep.computed,
            "executor": rep.executor, "wall_s": rep.wall_s,
            "runs_per_minute": rep.runs_per_minute}


def timed(sc, save: str = "estimates"):
    """Wall and CPU seconds of one run (the machine may be shared: CPU time is the steadier)."""
    t0, c0 = time.perf_counter(), time.process_time()
    r = dkfsim.run(sc, save=save)
    return time.perf_counter() - t0, time.process_time() - c0, r


def timed_with(sc, env: str, value: str):
    """:func:`timed` with the environment variable ``env`` set to ``value`` for the run."""
    os.environ[env] = value
    try:
        return timed(sc)
    finally:
        del os.environ[env]


def slope(x, y) -> float:
    """Least-squares slope of log y against log x."""
    lx, ly = [math.log(v) for v in x], [math.log(v) for v in y]
    mx, my = sum(lx) / len(lx), sum(ly) / len(ly)
    return sum((a - mx) * (b - my) for a, b in zip(lx, ly)) / sum((a - mx) ** 2 for a in lx)


def tree_scenario(n: int, ticks: int, fusion: str) -> dkfsim.Scenario:
    base = dkfsim.load_scenario(ROOT / "scenarios" / "paper_case1.yaml")
    d = base.to_dict()
    d["name"] = f"random_tree_{n}"
    d["steps"] = ticks
    d["sensors"] = [{"name": f"s{i}", "H": [[1.0 if c == i % 3 else 0.0 for c in range(3)]], "R": [[1.0]]}
                    for i in range(n)]
    d["topology"] = {"directed": False, "generator": "random_tree", "params": {"seed": 7}}
    d["fusion"] = fusion
    return dkfsim.load_scenario(d)


def _spin(stop) -> None:
    """A CPU hog: a busy loop until told to stop."""
    x = 0
    while not stop.is_set():
        x += 1


def threads_under_load(ticks: int) -> tuple[float, float, int]:
    """Seconds of a 50-node matrix-fusion run with the default BLAS threads and with one,
    each with a busy process beside it; and the default thread count."""
    from threadpoolctl import threadpool_info, threadpool_limits

    from dkfsim.engine.driver import Run  # the engine, below the API's thread pin
    sc = tree_scenario(50, ticks, "matrix")
    default = max((i["num_threads"] for i in threadpool_info()), default=1)
    times = []
    for limit in (default, 1):
        stop = multiprocessing.Event()
        hog = multiprocessing.Process(target=_spin, args=(stop,), daemon=True)
        hog.start()
        try:
            with threadpool_limits(limit):
                t0 = time.perf_counter()
                Run(sc, save="summary").run()
                times.append(time.perf_counter() - t0)
        finally:
            stop.set()
            hog.join()
    return times[0], times[1], default


def executors_compared(steps: int, runs: int) -> list[tuple[str, float, bool]]:
    """Monte Carlo of ``paper_case1`` on each backend: ``(label, runs per minute, same rows)``."""
    from dkfsim.experiments.executors import DaskExecutor, local
    sc = dkfsim.load_scenario(ROOT / "scenarios" / "paper_case1.yaml", overrides=[f"steps={steps}"])
    out, first = [], None
    for make in (lambda: local(1), lambda: local(2), lambda: DaskExecutor(n_workers=2)):
        t0 = time.perf_counter()
        with make() as ex:
            res = dkfsim.montecarlo(sc, runs, executor=ex, yes=True)
            label = ex.label
        wall = time.perf_counter() - t0
        first = repr(res.rows) if first is None else first
        out.append((label, 60.0 * runs / wall, repr(res.rows) == first))
    return out


def alternated(runs: dict, repeats: int) -> tuple[dict, dict]:
    """The min CPU seconds of each scenario of ``runs`` (name -> scenario), each warmed up once
    (kernels compiled or loaded: not counted), then alternated ``repeats`` times in this process;
    and each one's last result."""
    for sc in runs.values():
        dkfsim.run(dkfsim.load_scenario(sc, overrides=["steps=20"]), save="estimates")
    cpu: dict[str, list[float]] = {name: [] for name in runs}
    last = {}
    for _ in range(max(1, repeats)):
        for name, sc in runs.items():
            _, c, last[name] = timed(sc)
            cpu[name].append(c)
    return {name: min(v) for name, v in cpu.items()}, last


def traffic_cost(ticks: int, repeats: int) -> dict:
    """Section 8: CPU seconds of ``paper_case1`` with :data:`TRAFFIC` and without (``dkfsim.run``,
    ``save="estimates"``, the environment's backend), each warmed up once, then alternated
    ``repeats`` times in this process; the min of each, their ratio and the packets."""
    plain = dkfsim.load_scenario(ROOT / "scenarios" / "paper_case1.yaml", overrides=[f"steps={ticks}"])
    rated = dkfsim.load_scenario(plain, overrides=list(TRAFFIC))
    out, last = alternated({"plain": plain, "rated": rated}, repeats)
    out["ratio"] = out["rated"] / out["plain"]
    out.update({f"{name}_sent": r.counts["sent"] for name, r in last.items()})
    return out


def print_traffic_cost(ticks: int, repeats: int) -> None:
    t = traffic_cost(ticks, repeats)
    print(f"links that carry the traffic (issue 21): paper_case1, {ticks} ticks, 1 Mbit/s, room of 20, "
          f"Poisson background 50/s x 250 B, against the plain run; CPU s, min of {repeats} alternated")
    print(f"  plain {t['plain']:8.3f} s ({t['plain_sent']} packets)   rate-limited {t['rated']:8.3f} s "
          f"({t['rated_sent']} packets)   ratio {t['ratio']:.2f} x (issue: <= 2)")


def print_centre_cost(ticks: int, repeats: int) -> None:
    """Section 9: CPU seconds of ``paper_case1`` with a fusion centre at node 0 and without
    (``dkfsim.run``, ``save="estimates"``, :func:`alternated`) and their ratio."""
    plain = dkfsim.load_scenario(ROOT / "scenarios" / "paper_case1.yaml", overrides=[f"steps={ticks}"])
    centre = dkfsim.load_scenario(plain, overrides=["estimators=[{kind: centralized}, {kind: fusion_centre, at: 0}]"])
    cpu, last = alternated({"without": plain, "with": centre}, repeats)
    print(f"fusion centre (issue 22): paper_case1, {ticks} ticks, with {{kind: fusion_centre, at: 0}} against "
          f"without; CPU s, min of {repeats} alternated")
    print("  " + "   ".join(f"{name} {cpu[name]:8.3f} s" for name in cpu)
          + f"   {last['with'].traffic['fusion_centre']['sent']} centre packets   "
          f"ratio {cpu['with'] / cpu['without']:.2f} x (issue: <= 2)")


def channel_cost(ticks: int, repeats: int) -> dict:
    """Section 10: CPU seconds of ``scenarios/channel_its_g5.yaml`` and of the same scenario
    without ``medium:`` (:func:`alternated`); the min of each and the ratio."""
    import yaml
    path = ROOT / "scenarios" / "channel_its_g5.yaml"
    spec = yaml.safe_load(path.read_text())
    spec.pop("medium")
    runs = {"channel": dkfsim.load_scenario(path, overrides=[f"steps={ticks}"]),
            "plain": dkfsim.load_scenario(spec, overrides=[f"steps={ticks}"])}
    out, last = alternated(runs, repeats)
    out["ratio"] = out["channel"] / out["plain"]
    out["channel_sent"] = last["channel"].counts["sent"]
    return out


def print_channel_cost(ticks: int, repeats: int) -> None:
    t = channel_cost(ticks, repeats)
    print(f"a shared channel (issue 22): scenarios/channel_its_g5.yaml, {ticks} ticks, every estimator, "
          f"against the same scenario without medium:; CPU s, min of {repeats} alternated")
    print(f"  channel {t['channel']:8.3f} s ({t['channel_sent']} packets)   without medium {t['plain']:8.3f} s   "
          f"ratio {t['ratio']:.2f} x")


#: Section 13's radio: 802.11p's defaults on WINNER+ B1 with log-normal shadowing and Nakagami
#: fading, 10 Hz beacons of 300 bytes with random phases, EDCA.
RADIO = {"path_loss": {"model": "winner_b1"}, "shadowing": {"model": "lognormal", "sigma": 3.0},
         "fading": {"model": "nakagami", "m": 1.5}}


def radio_frames(vehicles: int, spacing: float, seconds: float) -> tuple[float, int, float]:
    """Section 13: ``vehicles`` on a two-lane road ``spacing`` m apart sending only 10 Hz beacons on
    the radio for ``seconds``: (CPU s, frames, mean receivers that detected a frame)."""
    import numpy as np
    import simpy

    from dkfsim.components.faults import LinkSpec
    from dkfsim.components.latency import Constant
    from dkfsim.components.medium import Edca, Medium
    from dkfsim.components.traffic import Background
    from dkfsim.network.network import Network
    T = 10_000_000
    K = int(seconds * 1e9 / T) + 1
    pos = np.zeros((K + 1, vehicles, 2))
    pos[:, :, 0] = (np.arange(vehicles) // 2) * spacing
    pos[:, :, 1] = (np.arange(vehicles) % 2) * 4.0
    med = Medium(rate=6e6, access=Edca(), radio=RADIO,
                 background=Background(arrivals="periodic", packets_per_second=10, size=300, offset="random"))
    env = simpy.Environment()
    net = Network(env, [(0, 1), (1, 0)], lambda *_: LinkSpec(latency=Constant(value=1e-6)), seed=1, T_ns=T,
                  medium=med, positions=pos, n=vehicles)
    port = net.port("bench", lambda *_: None)
    channel = port.channel
    c0 = time.process_time()
    channel.advance(int(seconds * 1e9))
    cpu = time.process_time() - c0
    r = channel.report(port, int(seconds * 1e9))
    frames = r["frames_on_air"]
    heard = (r["pairs"] - r["losses"]["sensing"]) / max(frames, 1)
    return cpu, frames, heard


def ns3_ratios() -> list[tuple[str, int, int, float, float]]:
    """Section 13, against ns-3: each stored ns-3 reference whose weak frames interfere (the
    same physics as dkfsim's radio; tests/test_ns3_reference.py) run on dkfsim as the test sets it
    up, every one of ns-3's runs: (name, vehicles, frames, dkfsim CPU per frame us, ns-3's stored
    CPU per frame us), both timing the frames scheduled and run, the set-up excluded."""
    sys.path.insert(0, str(ROOT / "tests"))
    from test_ns3_reference import NAMES, load, run_dkfsim
    out = []
    for name in NAMES:
        if not name.endswith("_interfere"):
            continue
        ref = load(name)
        run_dkfsim(ref, 1)                                  # warm-up
        cpu: list[float] = []
        frames = sum(run_dkfsim(ref, seed, cpu)["frames_on_air"] for seed in range(1, ref["config"]["runs"] + 1))
        out.append((name, len(ref["positions"]), frames, sum(cpu) / frames * 1e6, ref["timing"]["cpu_per_frame_us"]))
    return out


def print_radio_cost(seconds: float, vehicles: list[int], highway_seconds: float) -> None:
    """Section 13 (see the module)."""
    print(f"a spatial radio (issue 32): beacons only, EDCA, WINNER+ B1 + shadowing + fading, {seconds:g} s "
          "simulated; CPU per frame against the receivers in range (those that detect a frame)")
    print(f"{'vehicles':>9} {'frames':>8} {'in range':>9} {'CPU s':>7} {'us/frame':>9}")
    xs, ys = [], []
    for n in vehicles:
        cpu, frames, heard = radio_frames(n, 8.0, seconds)
        xs.append(heard)
        ys.append(cpu / frames * 1e6)
        print(f"{n:9d} {frames:8d} {heard:9.1f} {cpu:7.2f} {ys[-1]:9.1f}")
    if len(xs) > 1:
        print(f"  fitted exponent of CPU per frame against receivers in range: {slope(xs, ys):.2f}; against "
              f"the vehicles on the road: {slope([float(n) for n in vehicles], ys):.2f} (every member's power and "
              "draws are worked out, for the interference it adds)")
    if (ROOT / "tests" / "data" / "ns3").is_dir():
        print("  against ns-3 3.44 on its stored highways (weak frames interfere), CPU per frame, its scheduling "
              "and run:")
        for name, n, frames, ours, theirs in ns3_ratios():
            print(f"    {name:26s} {n:4d} vehicles {frames:7d} frames  dkfsim {ours:7.1f} us  ns-3 {theirs:7.1f} us  "
                  f"ns-3 / dkfsim {theirs / ours:6.1f}")
    path = ROOT / "scenarios" / "highway_its_g5.yaml"
    if path.is_file() and highway_seconds > 0:
        sc = dkfsim.load_scenario(path)
        steps = int(round(highway_seconds / sc.model.T))
        sc = dkfsim.load_scenario(path, overrides=[f"steps={steps}", "estimators=[]"])
        dkfsim.run(sc, steps=20, save="summary")           # warm-up
        wall, cpu, res = timed(sc, save="summary")
        ch = res.counts["channel"]
        members = len(ch["cbr"])
        print(f"  scenarios/highway_its_g5.yaml, {members} vehicles, the DKF group alone, {highway_seconds:g} s "
              f"simulated: {ch['frames_on_air']} frames, CPU {cpu:.1f} s ({cpu / ch['frames_on_air'] * 1e6:.0f} "
              f"us/frame; target: at most 60 s for 60 s)")
        sps = dkfsim.load_scenario(path, overrides=[f"steps={steps}", "estimators=[]", "medium.access.kind=sps"])
        dkfsim.run(sps, steps=20, save="summary")           # warm-up
        _, cpu_sps, res_sps = timed(sps, save="summary")
        print(f"  the same on C-V2X (--set medium.access.kind=sps, issue 33): "
              f"{res_sps.counts['channel']['frames_on_air']} frames, CPU {cpu_sps:.1f} s, sps / edca "
              f"{cpu_sps / cpu:.2f} (target: at most 1.5)")


def kernel_workloads(ticks: int, scale_ticks: int, big_nodes: int, big_ticks: int) -> dict:
    """The kernel-heavy runs of ``--base``: name -> (scenario, save, environment variable or None)."""
    case1 = dkfsim.load_scenario(ROOT / "scenarios" / "paper_case1.yaml", overrides=[f"steps={ticks}"])
    big = dkfsim.load_scenario(tree_scenario(big_nodes, big_ticks, "none"),
                               overrides=["links.default.latency.d_t=1", "estimators=[]"])
    centre = "estimators=[{kind: centralized}, {kind: fusion_centre, at: 0}]"
    channel = dkfsim.load_scenario(ROOT / "scenarios" / "channel_its_g5.yaml", overrides=[f"steps={min(ticks, 300)}"])
    crossing = dkfsim.load_scenario(ROOT / "scenarios" / "mobility_crossing.yaml")
    return {
        "paper_case1": (case1, "estimates", None),
        "paper_case1 (DKFSIM_EXCHANGE=python)": (case1, "estimates", (EXCHANGE_ENV, "python")),
        "paper_case1 (numpy kernels)": (case1, "estimates", (KERNELS_ENV, "numpy")),
        f"50-node tree, matrix fusion, {scale_ticks} ticks": (tree_scenario(50, scale_ticks, "matrix"), "summary", None),
        f"200-node tree, no fusion, {scale_ticks} ticks": (tree_scenario(200, scale_ticks, "none"), "summary", None),
        f"{big_nodes}-node tree, d_t = 1, {big_ticks} ticks": (big, "summary", None),
        f"channel_its_g5, {min(ticks, 300)} ticks": (channel, "estimates", None),
        "mobility_crossing": (crossing, "estimates", None),
        "paper_case1, rate-limited links": (dkfsim.load_scenario(case1, overrides=list(TRAFFIC)), "estimates", None),
        "paper_case1, fusion centre": (dkfsim.load_scenario(case1, overrides=[centre]), "estimates", None),
        "paper_case1, fusion centre, rate-limited links": (
            dkfsim.load_scenario(case1, overrides=list(TRAFFIC) + [centre]), "estimates", None),
        # (random latency drawn one packet at a time: the stress scenarios, maxdelay's scale axis)
        "paper_case1, exponential latency": (dkfsim.load_scenario(case1, overrides=[
            "links.default.latency={model: exponential, mean: 0.02}", "links.d_t=4"]), "estimates", None),
        "stress_heavy_tail": (dkfsim.load_scenario(ROOT / "scenarios" / "stress_heavy_tail.yaml",
                                                   overrides=[f"steps={ticks}"]), "estimates", None),
    }


def moving_paper_case1(ticks: int, period: int, random: bool = False) -> tuple[dkfsim.Scenario, dkfsim.Scenario]:
    """``paper_case1`` on its fixed tree, and the same with vehicles 1 m apart (radius 50 m)
    of which vehicle ``i >= 1`` is 1 km away at the ticks ``k`` with ``(k + i) % period == 0``
    (``random``: at each tick with probability ``1 / period``, seeded): every tick some links
    are down, each link comes back the tick after."""
    import numpy as np
    fixed = dkfsim.load_scenario(ROOT / "scenarios" / "paper_case1.yaml", overrides=[f"steps={ticks}"])
    T = fixed.model.T
    away = np.random.default_rng(0).random((fixed.n, ticks + 1)) < 1 / period if random else \
        np.array([[(k + i) % period == 0 for k in range(ticks + 1)] for i in range(fixed.n)])
    vehicles = {"0": {"kind": "constant_velocity"}}
    for i in range(1, fixed.n):
        vehicles[str(i)] = {"kind": "waypoints", "points": [
            [k * T, 1000.0 if away[i, k] else float(i), 0.0] for k in range(ticks + 1)]}
    data = fixed.to_dict()
    data["mobility"] = {"vehicles": vehicles, "range": {"model": "disk", "radius": 50.0}}
    data["buffer_length"] = fixed.buffer_length if isinstance(fixed.buffer_length, int) else \
        RunPlan_L(fixed)
    return fixed, dkfsim.load_scenario(data)


def RunPlan_L(sc) -> int:       # noqa: N802
    """The fixed run's buffer length, so that both runs filter the same window."""
    from dkfsim.config.plan import RunPlan
    return RunPlan(sc).buffer_length()


def changing_graph(ticks: int, period: int, repeats: int) -> None:
    """Section 7 (see the module): both patterns."""
    for random in (False, True):
        changing_graph_line(ticks, period, repeats, random)


def changing_graph_line(ticks: int, period: int, repeats: int, random: bool) -> None:
    """One pattern of section 7: changing graph against fixed, alternated, min CPU each."""
    fixed, moving = moving_paper_case1(ticks, period, random)
    dkfsim.run(fixed, steps=50, save="estimates")
    dkfsim.run(moving, steps=50, save="estimates")
    cpu = {"fixed": [], "changing": []}
    info = {}
    for _ in range(repeats):
        for label, sc in (("fixed", fixed), ("changing", moving)):
            _, c, r = timed(sc)
            cpu[label].append(c)
            info[label] = r
    f, m = min(cpu["fixed"]), min(cpu["changing"])
    rl = info["changing"].counts.get("range_lost", 0)
    how = f"with probability 1/{period} per tick" if random else f"one tick in {period}"
    print(f"paper_case1 on a changing graph, {ticks} ticks, each vehicle out of range {how} "
          f"(L = {info['changing'].info['buffer_length']} both):")
    print(f"  fixed graph     CPU {f:8.3f} s")
    print(f"  changing graph  CPU {m:8.3f} s  (packets lost to range {rl})")
    print(f"  ratio changing / fixed  {m / f:.2f} x  (min over {repeats} alternated runs each)")


def probe(args) -> int:
    """One pass over :func:`kernel_workloads` in this process; CPU seconds as JSON on stdout."""
    from dkfsim.core.threads import pin_process
    from dkfsim.engine.driver import Run  # the engine: the run without the API's result building
    pin_process()                         # one BLAS thread, as dkfsim.run (the engine alone does not pin)
    out = {"file": dkfsim.__file__}
    for name, (sc, save, env) in kernel_workloads(args.ticks, args.scale_ticks, args.big_nodes,
                                                  args.big_ticks).items():
        if env:
            os.environ[env[0]] = env[1]
        try:
            warm = dkfsim.load_scenario(sc, overrides=[f"steps={min(20, int(sc.steps))}"])
            Run(warm, save=save).run()              # kernels of this kind loaded (or compiled)
            c0 = time.process_time()
            Run(sc, save=save).run()
            out[name] = time.process_time() - c0
        finally:
            if env:
                del os.environ[env[0]]
    print(json.dumps(out))
    return 0


def before_after(args) -> int:
    """``--base``: :func:`probe` alternated between the commit ``args.base`` and this checkout."""
    from fingerprint import unpack  # (tools/, this script's folder): one git-archive rule

    with tempfile.TemporaryDirectory(prefix="dkfsim-bench-base-") as tmp:
        base = unpack(args.base, Path(tmp) / "base")
        trees = {"base": base, "this": ROOT}
        flags = ["--ticks", str(args.ticks), "--scale-ticks", str(args.scale_ticks), "--big-nodes",
                 str(args.big_nodes), "--big-ticks", str(args.big_ticks)]
        got: dict[str, list[dict]] = {name: [] for name in trees}
        for rep in range(args.repeats + 1):           # the first round compiles or loads: not counted
            for name, tree in trees.items():
                env = {**os.environ, TREE_ENV: str(tree)}
                env.pop(KERNELS_ENV, None)
                env.pop(EXCHANGE_ENV, None)
                done = subprocess.run([sys.executable, str(Path(__file__).resolve()), "--probe", *flags],
                                      env=env, check=True, capture_output=True, text=True)
                res = json.loads(done.stdout.strip().splitlines()[-1])
                if not res.pop("file").startswith(str(tree)):
                    raise SystemExit(f"the probe did not import the dkfsim of {tree}")
                if rep:
                    got[name].append(res)
    print(f"kernels before/after: {args.base} (base) against this checkout, CPU seconds of one run, "
          f"min of {args.repeats} runs alternated in fresh processes")
    print(f"  {'run':48s} {'base':>8s} {'this':>8s} {'this/base':>10s}")
    for key in got["this"][0]:
        b = min(r[key] for r in got["base"])
        t = min(r[key] for r in got["this"])
        print(f"  {key:48s} {b:8.3f} {t:8.3f} {t / b:10.3f}")
    return 0


#: Section 11's commands: label -> the arguments of ``python`` (run in this checkout's folder).
STARTUP = {
    "import dkfsim": ["-c", "import dkfsim"],
    "dkfsim --help": ["-m", "dkfsim", "--help"],
    "dkfsim list": ["-m", "dkfsim", "list"],
    "dkfsim validate paper_case1": ["-m", "dkfsim", "validate", "scenarios/paper_case1.yaml"],
    "dkfsim run paper_case1 (1000 ticks)": ["-m", "dkfsim", "run", "scenarios/paper_case1.yaml", "--quiet",
                                            "--out", "{tmp}/run"],
}


def startup_probe(tree: Path, args: list[str]) -> tuple[float, float]:
    """Wall and CPU seconds of ``python ARGS`` run in ``tree`` (so importing its dkfsim), with Python's
    bytecode cache on (the probe checks which dkfsim it imported)."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    env["PYTHONPATH"] = str(tree)
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    done = subprocess.run([sys.executable, *args], cwd=tree, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode != 0:
        raise SystemExit(f"{' '.join(args)} failed in {tree}: {done.stderr[-2000:]}")
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def startup(base: str | None, repeats: int) -> int:
    """Section 11 (see the module docstring)."""
    from fingerprint import unpack  # (tools/, this script's folder): one git-archive rule

    with tempfile.TemporaryDirectory(prefix="dkfsim-bench-startup-") as tmp:
        trees = {"this": ROOT} if base is None else {"base": unpack(base, Path(tmp) / "base"), "this": ROOT}
        for tree in trees.values():              # which dkfsim a probe imports; bytecode written
            env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
            got = subprocess.run([sys.executable, "-c", "import dkfsim; print(dkfsim.__file__)"], cwd=tree,
                                 env={**env, "PYTHONPATH": str(tree)}, capture_output=True, text=True,
                                 check=True).stdout.strip()
            if not got.startswith(str(tree)):
                raise SystemExit(f"the probe imported {got}, not the dkfsim of {tree}")
        times: dict = {(name, label): [] for name in trees for label in STARTUP}
        for rep in range(max(1, repeats) + 1):   # round 0 warms up (bytecode, file cache): not counted
            for label, cmd in STARTUP.items():
                for name, tree in trees.items():
                    wall, cpu = startup_probe(tree, [a.format(tmp=tmp) for a in cmd])
                    if rep:
                        times[name, label].append((wall, cpu))
    load = os.getloadavg()
    print(f"start-up, fresh processes, bytecode cache on, min of {repeats} "
          + ("" if base is None else f"alternated with {base} (base) ")
          + f"(load average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f} on {os.cpu_count()} CPUs)")
    head = f"  {'command':32s}" + "".join(f" {n + ' wall':>10s} {n + ' CPU':>10s}" for n in trees)
    print(head + ("" if base is None else f" {'wall this/base':>15s} {'CPU this/base':>14s}"))
    for label in STARTUP:
        best = {name: (min(w for w, _ in times[name, label]), min(c for _, c in times[name, label]))
                for name in trees}
        line = f"  {label:32s}" + "".join(f" {best[n][0]:10.3f} {best[n][1]:10.3f}" for n in trees)
        if base is not None:
            line += (f" {best['this'][0] / best['base'][0]:15.3f} {best['this'][1] / best['base'][1]:14.3f}")
        print(line)
    return 0


#: Section 12's runs: label -> ``--set`` overrides of ``scenarios/paper_case1.yaml`` (or
#: ``(file, overrides)``); ticks are ``--ticks`` (a third of them for the slower ones).
CALIBRATION_RUNS = {
    "paper_case1": [],
    "no fusion": ["fusion=none"],
    "rate-limited": list(TRAFFIC),
    "flood, heavy tail": ("stress_heavy_tail.yaml", []),
    "consensus family": ["estimators=[{kind: ci_consensus, rounds: 2}, {kind: kcf}, {kind: icf, rounds: 2}, "
                         "{kind: diffusion_kf}, {kind: hcmci, rounds: 2}]"],
    "fusion centre": ["estimators=[{kind: fusion_centre, at: 0}]"],
    "channel": ("channel_its_g5.yaml", []),
    "changing graph": ("mobility_convoy.yaml", []),
}


def calibrate(ticks: int, repeats: int) -> int:
    """Section 12 (see the module docstring)."""
    import numpy as np
    from scipy.optimize import nnls

    from dkfsim.core.resources import CALIBRATION
    runs = {}
    for label, spec in CALIBRATION_RUNS.items():
        file, ov = spec if isinstance(spec, tuple) else ("paper_case1.yaml", spec)
        k = ticks if file == "paper_case1.yaml" else max(50, ticks // 3)
        runs[label] = dkfsim.load_scenario(ROOT / "scenarios" / file, overrides=[*ov, f"steps={k}"])
    runs["50-node tree, matrix fusion"] = tree_scenario(50, max(50, ticks // 5), "matrix")
    cpu, last = alternated(runs, repeats)
    rows, y = [], []
    for label, res in last.items():
        ev, N = res.info["events"], res.scenario.n * res.scenario.nx
        rows.append([ev["ticks"], ev["packets"], ev["node_rows"], ev["fused_rows"] * float(N) ** 3])
        y.append(cpu[label])
    A, b = np.array(rows, dtype=float), np.array(y)
    scale = A.max(axis=0)
    scale[scale == 0] = 1.0
    x, _ = nnls(A / scale, b)
    x = x / scale
    pred = A @ x
    load = os.getloadavg()
    print(f"seconds per event, fitted on {len(runs)} runs (CPU s, min of {repeats} alternated; load average "
          f"{load[0]:.2f} on {os.cpu_count()} CPUs)")
    for name, value in zip(("ticks", "packets", "node_rows", "fusion_flops"), x):
        print(f"  {name:14s} {value:.3e} s")
    print(f"  {'run':32s} {'measured':>9s} {'predicted':>9s} {'ratio':>6s}")
    for (label, _res), m, p in zip(last.items(), b, pred):
        print(f"  {label:32s} {m:9.3f} {p:9.3f} {p / m:6.2f}")
    data = {"ticks": x[0], "packets": x[1], "node_rows": x[2], "fusion_flops": x[3],
            "measured": f"tools/bench.py --calibrate --ticks {ticks} --repeats {repeats}, "
                        f"{time.strftime('%Y-%m-%d')}, {os.cpu_count()} CPUs, load average {load[0]:.2f}"}
    CALIBRATION.write_text(json.dumps({k: (float(f"{v:.4g}") if isinstance(v, float) else v)
                                       for k, v in data.items()}, indent=2) + "\n")
    print(f"wrote {CALIBRATION.relative_to(ROOT)}")
    return 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--ticks", type=int, default=1000)
    ap.add_argument("--sizes", type=int, nargs="+", default=[12, 50, 200])
    ap.add_argument("--scale-ticks", type=int, default=200, help="ticks per scaling run")
    ap.add_argument("--skip-sweep", action="store_true", help="skip the sweep throughput measurement")
    ap.add_argument("--fit-sizes", type=int, nargs="*", default=[12, 50, 200, 1000],
                    help="tree sizes of the exponent fit (none skips it)")
    ap.add_argument("--big-nodes", type=int, default=1000, help="nodes of the large tree (0 skips it)")
    ap.add_argument("--big-ticks", type=int, default=200, help="ticks of the large-tree run")
    ap.add_argument("--skip-threads", action="store_true", help="skip the BLAS-threads measurement")
    ap.add_argument("--thread-ticks", type=int, default=100, help="ticks of the BLAS-threads runs")
    ap.add_argument("--skip-executors", action="store_true",
                    help="skip the Monte Carlo comparison of the executors")
    ap.add_argument("--base", metavar="REF", help="before/after: the kernel-heavy runs of this commit against "
                    "this checkout, alternated (see the module's docstring); nothing else runs")
    ap.add_argument("--repeats", type=int, default=3, help="alternations of --base, of section 7 and of the "
                    "traffic line (default 3)")
    ap.add_argument("--mobility-period", type=int, default=4,
                    help="section 7: each vehicle is out of range one tick in this many (default 4)")
    ap.add_argument("--mobility-only", action="store_true", help="run section 7 (a changing graph) alone")
    ap.add_argument("--skip-traffic", action="store_true", help="skip the rate-limited links' cost (section 8)")
    ap.add_argument("--traffic-only", action="store_true", help="only the rate-limited links' cost (section 8)")
    ap.add_argument("--skip-centre", action="store_true", help="skip the fusion centre's cost (section 9)")
    ap.add_argument("--centre-only", action="store_true", help="only the fusion centre's cost (section 9)")
    ap.add_argument("--skip-channel", action="store_true", help="skip the shared channel's cost (section 10)")
    ap.add_argument("--channel-only", action="store_true", help="only the shared channel's cost (section 10)")
    ap.add_argument("--radio-only", action="store_true", help="only the spatial radio's cost (section 13)")
    ap.add_argument("--radio-seconds", type=float, default=5.0, help="simulated seconds of each radio run")
    ap.add_argument("--radio-vehicles", type=int, nargs="+", default=[50, 100, 200, 300, 400])
    ap.add_argument("--highway-seconds", type=float, default=60.0,
                    help="simulated seconds of the shipped highway (0 skips it)")
    ap.add_argument("--startup", action="store_true",
                    help="only the start-up of import dkfsim, --help, list and validate (section 11); "
                         "with --base REF, against REF")
    ap.add_argument("--calibrate", action="store_true",
                    help="only fit the seconds per event of the estimates and store them (section 12)")
    ap.add_argument("--probe", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.calibrate:
        return calibrate(args.ticks, args.repeats)
    if args.probe:
        return probe(args)
    if args.startup:
        return startup(args.base, args.repeats)
    if args.base:
        return before_after(args)
    if args.mobility_only:
        changing_graph(args.ticks, args.mobility_period, args.repeats)
        return 0
    if args.traffic_only:
        print_traffic_cost(args.ticks, args.repeats)
        return 0
    if args.centre_only:
        print_centre_cost(args.ticks, args.repeats)
        return 0
    if args.channel_only:
        print_channel_cost(args.ticks, args.repeats)
        return 0
    if args.radio_only:
        print_radio_cost(args.radio_seconds, args.radio_vehicles, args.highway_seconds)
        return 0

    sc = dkfsim.load_scenario(ROOT / "scenarios" / "paper_case1.yaml", overrides=[f"steps={args.ticks}"])
    t0 = time.perf_counter()
    first = dkfsim.run(sc, steps=50, save="estimates")     # warm-up (imports, kernel compile or cache load)
    first_s = time.perf_counter() - t0
    wall, cpu, res = timed(sc)
    events = res.counts["delivered"]
    b0, c0 = time.perf_counter(), time.process_time()
    bare_simpy(events, args.ticks)
    bare, bare_cpu = time.perf_counter() - b0, time.process_time() - c0
    print(f"paper_case1, {args.ticks} ticks, L = {res.info['buffer_length']}, fusion {sc.fusion}, "
          f"kernels {res.info['kernels']}")
    print(f"  first call, 50 ticks (compile or cache load) {first_s:8.3f} s  ({first.info['kernels']})")
    print(f"  wall time of the run          {wall:8.3f} s   (CPU {cpu:.3f} s)")
    print(f"  packet events (deliveries)    {events:8d}  ({events / args.ticks:.1f} per tick)")
    print(f"  bare SimPy, same # timeouts   {bare:8.3f} s   (CPU {bare_cpu:.3f} s)")
    print(f"  ratio run / bare SimPy        {wall / bare:8.1f} x  (CPU {cpu / bare_cpu:.1f} x)")
    if res.info["kernels"] == "numba":
        wall_np, cpu_np, _ = timed_with(sc, KERNELS_ENV, "numpy")
        print(f"  pure-numpy path               {wall_np:8.3f} s   (CPU {cpu_np:.3f} s; numpy / numba "
              f"{cpu_np / cpu:.2f} x CPU)")
    print()
    print("scaling on random trees (uniform_steps d_t = 4, L = d_t * d_g + 1)")
    hdr = (f"{'nodes':>6} {'fusion':>7} {'L':>4} {'ticks/s':>9} {'(CPU)':>7} {'packets/tick':>13} "
           f"{'rows/tick':>9} {'us/(node*row)':>14} {'us/packet':>10}")
    print(hdr)
    for n in args.sizes:
        for fusion in (["matrix", "none"] if n <= 50 else ["none"]):
            w, c, r = timed(tree_scenario(n, args.scale_ticks, fusion), save="summary")
            L = r.info["buffer_length"]
            per_tick = w / args.scale_ticks
            pkts = r.counts["delivered"] / args.scale_ticks
            rows = r.info["node_rows"] / args.scale_ticks / n
            print(f"{n:6d} {fusion:>7} {L:4d} {args.scale_ticks / w:9.1f} {args.scale_ticks / c:7.1f} "
                  f"{pkts:13.1f} {rows:9.1f} {per_tick / (n * rows) * 1e6:14.2f} "
                  f"{per_tick / max(pkts, 1) * 1e6:10.2f}")

    if args.fit_sizes:
        print()
        print("per-tick cost against the work, random trees, uniform_steps d_t = 1, no fusion "
              "(CPU time of ticks K+1..2K: set-up excluded)")
        print(f"{'nodes':>6} {'links':>6} {'node-rows/tick':>15} {'ms/tick':>8}")
        pts = []
        for n in args.fit_sizes:
            # Per tick = the CPU of a run twice as long minus that of the run, over the extra
            # ticks: the set-up (a system of n sensors, the draws) cancels out.
            ticks = max(20, min(args.scale_ticks, 20_000 // n))
            runs = []
            for k in (ticks, 2 * ticks):
                s = dkfsim.load_scenario(tree_scenario(n, k, "none"),
                                         overrides=["links.default.latency.d_t=1", "estimators=[]"])
                runs.append(timed(s, save="summary"))
            (_, c1, r1), (_, c2, r) = runs
            c = c2 - c1
            nr = (r.info["node_rows"] - r1.info["node_rows"]) / ticks
            pts.append((n, r.info["n_links"], nr, c / ticks))
            print(f"{n:6d} {r.info['n_links']:6d} {nr:15.0f} {c / ticks * 1e3:8.2f}")
        print(f"  fitted exponent, cost ~ (node-rows re-run)^p: p = {slope([p[2] for p in pts], [p[3] for p in pts]):.2f}")
        print(f"  fitted exponent, cost ~ links^p:               p = {slope([p[1] for p in pts], [p[3] for p in pts]):.2f}")

    if args.big_nodes:
        s = tree_scenario(args.big_nodes, args.big_ticks, "none")
        s = dkfsim.load_scenario(s, overrides=["links.default.latency.d_t=1", "estimators=[]"])
        w, c, r = timed(s, save="summary")
        L = r.info["buffer_length"]
        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20       # KiB -> GiB
        print()
        loop = r.info["wall_time_s"]          # the simulation loop alone (no set-up)
        print(f"{args.big_nodes}-node random tree (d_g = {r.info['d_g']}, uniform_steps d_t = 1, L = {L}, "
              f"no fusion), {args.big_ticks} ticks: "
              f"{w / args.big_ticks * 1e3:.1f} ms per tick (CPU {c / args.big_ticks * 1e3:.1f} ms; "
              f"the loop alone {loop / args.big_ticks * 1e3:.1f} ms wall), "
              f"{r.counts['delivered'] / args.big_ticks:.0f} packets per tick, "
              f"{r.info['node_rows'] / args.big_ticks / args.big_nodes:.1f} rows re-run per node, "
              f"{c / r.info['node_rows'] * 1e6:.2f} us CPU per node x row re-run; "
              f"process peak memory {peak:.2f} GiB")

    if not args.skip_threads:
        many, one, default = threads_under_load(args.thread_ticks)
        print()
        print(f"BLAS threads under load (50-node tree, matrix fusion, {args.thread_ticks} ticks, a CPU hog "
              f"beside it on this {os.cpu_count()}-CPU machine):")
        print(f"  default BLAS threads ({default})   {many:8.2f} s")
        print(f"  one BLAS thread (dkfsim)  {one:8.2f} s   (ratio default / one {many / one:.2f} x)")

    if not args.skip_sweep:
        print()
        one = throughput(steps=args.ticks, jobs=1, runs=4)
        two = throughput(steps=args.ticks, jobs=2, runs=12)
        print(f"sweep throughput, paper_case1 at {args.ticks} ticks (SQLite included):")
        print(f"  1 process            {one['runs_per_minute']:7.1f} runs/min")
        print(f"  2 local workers      {two['runs_per_minute']:7.1f} runs/min  "
              f"(ratio {two['runs_per_minute'] / one['runs_per_minute']:.2f} x)")

    print()
    changing_graph(args.ticks, args.mobility_period, args.repeats)

    if not args.skip_executors:
        print()
        rows = executors_compared(args.ticks, 12)
        base = rows[0][1]
        print(f"Monte Carlo of paper_case1, 12 runs x {args.ticks} ticks, on each executor "
              "(start-up included):")
        for label, rate, same in rows:
            print(f"  {label:40s} {rate:7.1f} runs/min  (ratio {rate / base:.2f} x)  "
                  f"rows {'identical' if same else 'DIFFER'}")

    if not args.skip_traffic:
        print()
        print_traffic_cost(args.ticks, args.repeats)
    if not args.skip_centre:
        print()
        print_centre_cost(args.ticks, args.repeats)
    if not args.skip_channel:
        print()
        print_channel_cost(args.ticks, args.repeats)
    return 0


if __name__ == "__main__":
    sys.exit(main())

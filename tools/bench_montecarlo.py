#!/usr/bin/env python
"""Monte Carlo overhead benchmark: this tree against another commit, in one script.

What a Monte Carlo run costs beyond its simulation (``Run.run``: the event
loop, the estimators' start and finish): the scenario's validation, the set-up
of a run (system, draws, network), the scoring, what a worker sends back, the
executor and ``runs.csv``.  Two measurements, each alternating subprocesses
of the two trees (``git archive REF`` unpacked in a temporary folder, against
this working tree) so that a shared machine's load falls on both alike:

1. per-run overhead, in one process: CPU seconds of ``montecarlo(sc, N,
   jobs=1)`` minus the CPU seconds spent inside ``Run.run``, per run (min over
   the repeats), and the loop's CPU per run beside it;
2. the CLI, ``dkfsim montecarlo scenarios/paper_case1.yaml --runs R --jobs 2``:
   wall time, runs per minute, the start-up (the same command with ``--runs
   2``) and the 1000-run time extrapolated as ``start-up + 1000 x (per-run
   slope)``; the two ``runs.csv`` are compared byte for byte.

Usage: ``python tools/bench_montecarlo.py [--base REF] [--runs 40] [--probe-runs 20]
[--steps 1000] [--repeats 2]``.  Timing lives here, never in the tests.
"""

from __future__ import annotations

import argparse
import filecmp
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SCENARIO = "scenarios/paper_case1.yaml"

PROBE = r"""
import json, sys, time
from dkfsim.core.threads import pin_process
pin_process()
import dkfsim
import dkfsim.engine.driver as driver
from dkfsim.experiments.montecarlo import montecarlo
runs, steps = int(sys.argv[1]), int(sys.argv[2])
sc = dkfsim.load_scenario(sys.argv[3], overrides=[f"steps={steps}"])
montecarlo(sc, 1, jobs=1, yes=True)                 # warm-up: imports, kernels
loop = [0.0]
inner = driver.Run.run
def timed_run(self):
    c = time.process_time()
    try:
        return inner(self)
    finally:
        loop[0] += time.process_time() - c
driver.Run.run = timed_run
c0 = time.process_time()
montecarlo(sc, runs, jobs=1, yes=True)
total = time.process_time() - c0
print(json.dumps({"file": dkfsim.__file__, "total": total, "loop": loop[0], "runs": runs}))
"""


def unpack(ref: str, dest: Path) -> Path:
    """``git archive ref`` of this repository, unpacked into ``dest``."""
    archive = subprocess.run(["git", "-C", str(ROOT), "archive", ref], check=True,
                             capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", str(dest)], input=archive, check=True)
    return dest


def env_for(tree: Path) -> dict:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(tree)
    return env


def probe(tree: Path, runs: int, steps: int) -> dict:
    out = subprocess.run([sys.executable, "-c", PROBE, str(runs), str(steps), SCENARIO], cwd=tree,
                         env=env_for(tree), check=True, capture_output=True, text=True).stdout
    got = json.loads(out.strip().splitlines()[-1])
    if not got["file"].startswith(str(tree)):
        raise SystemExit(f"the probe imported {got['file']}, not the tree {tree}")
    return got


def cli(tree: Path, runs: int, steps: int, jobs: int, out: Path) -> float:
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "dkfsim", "montecarlo", SCENARIO, "--runs", str(runs),
                    "--jobs", str(jobs), "--steps", str(steps), "--out", str(out), "--quiet"],
                   cwd=tree, env=env_for(tree), check=True)
    return time.perf_counter() - t0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--base", default="main", help="the commit to compare against (default: main)")
    ap.add_argument("--runs", type=int, default=40, help="runs of the CLI measurement")
    ap.add_argument("--probe-runs", type=int, default=20, help="runs of the in-process measurement")
    ap.add_argument("--steps", type=int, default=1000)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--repeats", type=int, default=2)
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="dkfsim-bench-mc-") as tmp:
        tmp = Path(tmp)
        trees = {"base": unpack(args.base, tmp / "base"), "this": ROOT}
        for name, tree in trees.items():          # kernels compiled or loaded, files cached
            cli(tree, 1, 50, 1, tmp / f"warm-{name}")
        per = {name: [] for name in trees}
        for _ in range(args.repeats):
            for name, tree in trees.items():
                per[name].append(probe(tree, args.probe_runs, args.steps))
        print(f"paper_case1, {args.steps} ticks: per-run CPU in one process "
              f"(montecarlo, {args.probe_runs} runs, min of {args.repeats})")
        over = {}
        for name in trees:
            o = min((p["total"] - p["loop"]) / p["runs"] for p in per[name])
            lp = min(p["loop"] / p["runs"] for p in per[name])
            over[name] = o
            print(f"  {name:5s} overhead {o * 1e3:7.1f} ms/run   Run.run {lp * 1e3:7.1f} ms/run   "
                  f"overhead share {o / (o + lp) * 100:5.1f} %")
        print(f"  overhead ratio base / this {over['base'] / over['this']:.2f} x")

        walls = {name: [] for name in trees}
        starts = {name: [] for name in trees}
        for rep in range(args.repeats):
            for name, tree in trees.items():
                walls[name].append(cli(tree, args.runs, args.steps, args.jobs, tmp / f"{name}-{rep}"))
                starts[name].append(cli(tree, 2, args.steps, args.jobs, tmp / f"{name}-s{rep}"))
        same = filecmp.cmp(tmp / "base-0" / "runs.csv", tmp / "this-0" / "runs.csv", shallow=False)
        print(f"CLI montecarlo --runs {args.runs} --jobs {args.jobs} (min of {args.repeats}; "
              f"runs.csv {'byte-identical' if same else 'DIFFERS'})")
        rate = {}
        for name in trees:
            w, s = min(walls[name]), min(starts[name])
            slope = (w - s) / (args.runs - 2)
            rate[name] = 60 * args.runs / w
            print(f"  {name:5s} {w:7.1f} s  {rate[name]:6.1f} runs/min   --runs 2: {s:5.1f} s   "
                  f"1000 runs ~ {(s + 998 * slope) / 60:5.1f} min")
        print(f"  runs/min ratio this / base {rate['this'] / rate['base']:.2f} x")
    return 0


if __name__ == "__main__":
    sys.exit(main())

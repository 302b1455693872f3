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
   wall and CPU time (every process of the command), runs per minute, the
   same with ``--runs 2`` (start-up and one run per worker), and the 1000-run
   wall time on free cores extrapolated as ``wall(--runs 2) + 998 x (CPU per
   further run) / jobs``; the two ``runs.csv`` are compared byte for byte;
3. the start-up: CPU of ``import dkfsim.cli.main``.

Usage: ``python tools/bench_montecarlo.py [--base REF] [--runs 40] [--probe-runs 20]
[--steps 1000] [--repeats 2]``.  Timing lives here, never in the tests.
"""

from __future__ import annotations

import argparse
import filecmp
import json
import os
import resource
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
    dest.mkdir(parents=True)
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


def children_cpu() -> float:
    ru = resource.getrusage(resource.RUSAGE_CHILDREN)
    return ru.ru_utime + ru.ru_stime


def timed(cmd: list, tree: Path) -> tuple[float, float]:
    """Wall and CPU seconds (the process and every process it started) of ``cmd`` in ``tree``."""
    t0, c0 = time.perf_counter(), children_cpu()
    subprocess.run(cmd, cwd=tree, env=env_for(tree), check=True)
    return time.perf_counter() - t0, children_cpu() - c0


def cli(tree: Path, runs: int, steps: int, jobs: int, out: Path) -> tuple[float, float]:
    return timed([sys.executable, "-m", "dkfsim", "montecarlo", SCENARIO, "--runs", str(runs),
                  "--jobs", str(jobs), "--steps", str(steps), "--out", str(out), "--quiet"], tree)


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

        imports = {name: [] for name in trees}
        for _ in range(5):
            for name, tree in trees.items():
                imports[name].append(timed([sys.executable, "-c", "import dkfsim.cli.main"], tree)[1])
        print("start-up: CPU of 'import dkfsim.cli.main' (min of 5)")
        for name in trees:
            print(f"  {name:5s} {min(imports[name]):6.2f} s")
        print(f"  ratio base / this {min(imports['base']) / min(imports['this']):.2f} x")

        big = {name: [] for name in trees}
        small = {name: [] for name in trees}
        for rep in range(args.repeats):
            for name, tree in trees.items():
                big[name].append(cli(tree, args.runs, args.steps, args.jobs, tmp / f"{name}-{rep}"))
                small[name].append(cli(tree, 2, args.steps, args.jobs, tmp / f"{name}-s{rep}"))
        same = filecmp.cmp(tmp / "base-0" / "runs.csv", tmp / "this-0" / "runs.csv", shallow=False)
        print(f"CLI montecarlo --runs {args.runs} --jobs {args.jobs}, min of {args.repeats} "
              f"(runs.csv {'byte-identical' if same else 'DIFFERS'}); CPU = every process of the "
              "command; the wall time depends on the machine's load, the CPU much less")
        rate = {}
        for name in trees:
            w, c = min(b[0] for b in big[name]), min(b[1] for b in big[name])
            w2, c2 = min(b[0] for b in small[name]), min(b[1] for b in small[name])
            cpu_run = (c - c2) / (args.runs - 2)
            rate[name] = 60 * args.runs / w
            free = (w2 + 998 * cpu_run / args.jobs) / 60
            print(f"  {name:5s} wall {w:6.1f} s ({rate[name]:5.1f} runs/min), CPU {c:6.1f} s;  "
                  f"--runs 2: wall {w2:5.1f} s, CPU {c2:5.1f} s;  CPU per further run "
                  f"{cpu_run:5.3f} s;  1000 runs on {args.jobs} free cores ~ {free:5.1f} min")
        print(f"  runs/min ratio this / base {rate['this'] / rate['base']:.2f} x (wall)")
    return 0


if __name__ == "__main__":
    sys.exit(main())

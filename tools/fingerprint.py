#!/usr/bin/env python
"""Bit-identity check for refactors: fingerprint a fixed matrix of runs, compare two fingerprints.

A refactor that must not change behaviour (kernels, seams, protocols) runs this before and
after; ``--compare`` then says ``identical`` or names every run, array and count that differs.

The matrix: each scenario below (a scenario file of this repository with ``--set`` overrides),
``--steps`` ticks (default 300; the radar scenario too), on each kernel path, through the CLI
(``dkfsim run FILE --save full``) in a fresh process per run:

==============  =====================================================================
``numba``       the default: numba kernels
``numpy``       ``DKFSIM_KERNELS=numpy``: the pure-numpy path
==============  =====================================================================

(Before issue 31 a third path, ``python`` -- ``DKFSIM_EXCHANGE=python``, numba kernels with the
Python exchange beside the compiled tree -- was in the matrix; fingerprints of those commits
still hold it: compare them with ``--paths numba numpy``.)

A run's fingerprint is the sha256 (with dtype and shape) of every array of ``run.npz`` and
the numbers of ``summary.json`` (packets, per-link and per-estimate traffic, facts, rows
re-run, metrics, the resolved buffer length ...); wall time and versions are left out, and
the path a run took (``kernels``, ``exchange``) is recorded but not compared.  Paths are
compared with themselves only: numba and numpy sum in different orders.

Usage::

    python tools/fingerprint.py -o before.json                 # this checkout
    python tools/fingerprint.py --ref main -o main.json        # another commit (git archive)
    python tools/fingerprint.py --compare before.json after.json

Options: ``--only NAME ...`` (scenarios), ``--paths numba numpy`` (also restricts ``--compare``), ``--steps``,
``--jobs`` (parallel runs; the machine may be shared), ``--keep DIR`` (keep every run's
folder, to look at an array that differs), ``--list``.  ``--compare`` exits 0 when the two
are identical, 1 when something differs or is missing.  The ``--ref`` tree compiles its own
numba kernels once (about 20 s of CPU).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]

CASE1 = "scenarios/paper_case1.yaml"
CASE2 = "scenarios/paper_case2.yaml"
RADAR = "scenarios/radar_experiment.yaml"
CHANNEL = "scenarios/channel_its_g5.yaml"
#: The shipped scenarios not covered above, each run as it is (mobility: changing graphs).
SHIPPED = ("scenarios/mobility_crossing.yaml", "scenarios/mobility_platoon.yaml", "scenarios/mobility_convoy.yaml",
           "scenarios/cicv5g_track.yaml", "scenarios/stress_5g_empirical.yaml", "scenarios/stress_heavy_tail.yaml",
           "scenarios/stress_outage.yaml", "scenarios/stress_ramp.yaml")
#: 70 sensors, H cycling over the 3 states: origin bitmasks wider than one 64-bit word.
SENSORS_70 = "[" + ", ".join(f"{{name: s{i}, H: [[{int(i % 3 == 0)}, {int(i % 3 == 1)}, {int(i % 3 == 2)}]], "
                             f"R: [[{1.0 + 0.1 * (i % 7):.1f}]]}}" for i in range(70)) + "]"
CONSENSUS = ("estimators=[{kind: centralized}, {kind: centralized_delayed}, {kind: local_only}, "
             "{kind: no_buffer}, {kind: anti_delay_dkf, name: dkf_paper, weights: paper, fusion: diagonal}, "
             "{kind: ci_consensus, rounds: 2}, {kind: kcf}, {kind: icf, rounds: 2}, {kind: diffusion_kf}, "
             "{kind: hcmci, rounds: 2}]")

#: name -> (scenario file, overrides).  Changing this list changes every fingerprint: compare
#: fingerprints made by the same list (``--compare`` checks the commands match).
SCENARIOS: dict[str, tuple[str, list[str]]] = {
    # tree, matrix fusion, uniform_steps d_t = 4, unit weights (the complement sums of the fusion)
    "paper_case1": (CASE1, []),
    # flood on a digraph, matrix fusion
    "paper_case2": (CASE2, []),
    # flood on a digraph, diagonal fusion, d_t = 2
    "flood_digraph": (CASE2, ["fusion=diagonal", "links.default.latency.d_t=2"]),
    # the tree with the paper's weights (the fusion's direct sums)
    "paper_weights": (CASE1, ["weights=paper"]),
    # a buffer far shorter than the delays: late packets (counted per contribution with --save full)
    "short_buffer": (CASE1, ["buffer_length=3"]),
    # lost packets and a crash window (the Python exchange on every path)
    "loss_crash": (CASE1, ["links.default.loss=0.2", "faults={crashes: [{node: 2, start: 0.5, end: 1.2}]}"]),
    # zero latency: every node holds every contribution on time
    "zero_latency": (CASE1, ["links.default.latency={model: constant, value: 0.0}"]),
    # radars: information that varies per row; every estimator kind of the experiment
    "radar": (RADAR, []),
    # the consensus family and the other baselines beside the anti-delay DKF
    "consensus": (CASE1, [CONSENSUS]),
    # 70 nodes on a random tree, d_t = 1, matrix fusion
    "nodes70": (CASE1, [f"sensors={SENSORS_70}",
                        "topology={directed: false, generator: random_tree, params: {seed: 3}}",
                        "links.default.latency.d_t=1"]),
    # links that carry the traffic (issue 21): 1 Mbit/s, a room of 20, Poisson background
    "traffic": (CASE1, ["links.default.rate=1.0e6", "links.default.queue={packets: 20}",
                        "links.default.background={arrivals: poisson, packets_per_second: 50, size: 250}"]),
    # transmitters between ticks: constant latency off the grid, a room of 2 that overflows,
    # exponential background sizes
    "traffic_off_grid": (CASE1, ["links.default.latency={model: constant, value: 0.013}",
                                 "links.default.rate=2.0e5", "links.default.queue={packets: 2}",
                                 "links.default.background={packets_per_second: 40, size: 200, "
                                 "sizes: exponential}"]),
    # the fusion centre relayed hop by hop: on plain links, and on rate-limited links with background
    "centre": (CASE1, ["estimators=[{kind: fusion_centre, at: 0}, {kind: centralized_delayed}]"]),
    "centre_traffic": (CASE1, ["links.default.rate=1.0e6", "links.default.queue={packets: 20}",
                               "links.default.background={arrivals: poisson, packets_per_second: 50, size: 250}",
                               "estimators=[{kind: fusion_centre, at: 0}, {kind: centralized_delayed}]"]),
    # the shared channel (tree; flood; one queue per node shared by every estimator)
    "channel_its_g5": (CHANNEL, []),
    "channel_flood": (CHANNEL, ["protocol=flood"]),
    "channel_shared_queues": (CHANNEL, ["links.shared_queues=true"]),
    # every other shipped scenario as it is
    **{Path(f).stem: (f, []) for f in SHIPPED},
}

#: Kernel paths: name -> environment variables of the run (DKFSIM_* not listed are unset).
PATHS: dict[str, dict[str, str]] = {
    "numba": {},
    "numpy": {"DKFSIM_KERNELS": "numpy"},
}

#: summary.json keys left out of the fingerprint (they change with the machine or the clock) ...
UNCOMPARED = {"wall_time_s", "versions", "source"}
#: ... and recorded but not compared: which path the run took.
PATH_KEYS = ("kernels", "exchange", "backend")


def array_digest(a: np.ndarray) -> dict:
    """sha256 of an array's bytes (C order), with its dtype and shape."""
    a = np.ascontiguousarray(a)
    return {"sha256": hashlib.sha256(a.tobytes()).hexdigest(), "dtype": a.dtype.str, "shape": list(a.shape)}


def fingerprint_folder(folder: Path) -> dict:
    """The fingerprint of one run's output folder (run.npz and summary.json)."""
    summary = json.loads((folder / "summary.json").read_text())
    with np.load(folder / "run.npz", allow_pickle=False) as z:
        arrays = {name: array_digest(z[name]) for name in sorted(z.files)}
    return {"arrays": arrays,
            "summary": {k: v for k, v in sorted(summary.items()) if k not in UNCOMPARED and k not in PATH_KEYS},
            "path": {k: summary.get(k) for k in PATH_KEYS}}


def command(name: str, steps: int, out: Path) -> list[str]:
    path, overrides = SCENARIOS[name]
    cmd = [sys.executable, "-m", "dkfsim", "run", path, "--steps", str(steps), "--save", "full",
           "--out", str(out), "--quiet", "--yes"]
    for o in overrides:
        cmd += ["--set", o]
    return cmd


def run_one(tree: Path, name: str, path: str, steps: int, work: Path) -> dict:
    """Run scenario ``name`` on kernel path ``path`` with the dkfsim of ``tree``; its fingerprint."""
    out = work / f"{name}-{path}"
    env = {k: v for k, v in os.environ.items() if not k.startswith("DKFSIM_")}
    env.update(PATHS[path])
    env["PYTHONPATH"] = str(tree)
    cmd = command(name, steps, out)
    t0 = time.perf_counter()
    done = subprocess.run(cmd, cwd=tree, env=env, capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise SystemExit(f"{name}/{path} failed (exit {done.returncode}):\n{done.stderr[-2000:]}")
    fp = fingerprint_folder(out)
    k = cmd.index("--out")
    fp["command"] = ["python"] + cmd[1:k] + cmd[k + 2:]          # without the folder
    fp["env"] = PATHS[path]
    fp["seconds"] = round(time.perf_counter() - t0, 1)
    return fp


def unpack(ref: str, dest: Path) -> Path:
    """``git archive ref`` of this repository, unpacked into ``dest``."""
    dest.mkdir(parents=True)
    archive = subprocess.run(["git", "-C", str(ROOT), "archive", ref], check=True, capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", str(dest)], input=archive, check=True)
    return dest


def describe(tree: Path, ref: str | None) -> str:
    try:
        head = subprocess.run(["git", "-C", str(ROOT), "rev-parse", ref or "HEAD"], capture_output=True,
                              text=True, check=True).stdout.strip()
        dirty = "" if ref else subprocess.run(["git", "-C", str(tree), "status", "--porcelain", "--", "dkfsim"],
                                              capture_output=True, text=True, check=False).stdout.strip()
        return head + (" + uncommitted changes in dkfsim/" if dirty else "")
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def make(args) -> int:
    names = args.only or list(SCENARIOS)
    for path in args.paths:
        if path not in PATHS:
            raise SystemExit(f"the {path} path is gone (issue 31: one exchange path); use {', '.join(PATHS)}")
    for name in names:
        if name not in SCENARIOS:
            raise SystemExit(f"unknown scenario {name!r}; known: {', '.join(SCENARIOS)}")
    with tempfile.TemporaryDirectory(prefix="dkfsim-fingerprint-") as tmp:
        tmp = Path(tmp)
        tree = unpack(args.ref, tmp / "tree") if args.ref else ROOT
        work = Path(args.keep) if args.keep else tmp / "runs"
        work.mkdir(parents=True, exist_ok=True)
        jobs = [(name, path) for name in names for path in args.paths]
        # The first run compiles (or loads) the tree's kernels alone: parallel runs would all compile.
        runs = {}
        first, rest = jobs[0], jobs[1:]
        runs[first] = run_one(tree, *first, args.steps, work)
        with ThreadPoolExecutor(max(1, args.jobs)) as pool:
            futures = {job: pool.submit(run_one, tree, *job, args.steps, work) for job in rest}
            for job, fut in futures.items():
                runs[job] = fut.result()
                print(f"  {job[0]}/{job[1]}: {runs[job]['seconds']} s", file=sys.stderr)
        doc = {"tool": "tools/fingerprint.py", "commit": describe(tree, args.ref), "steps": args.steps,
               "runs": {f"{n}/{p}": runs[(n, p)] for n, p in jobs}}
    text = json.dumps(doc, indent=1, sort_keys=True) + "\n"
    if args.output:
        Path(args.output).write_text(text)
        print(f"{len(jobs)} runs fingerprinted ({doc['commit']}) -> {args.output}")
    else:
        sys.stdout.write(text)
    return 0


def first_difference(a, b, where: str = "") -> str | None:
    """Where two JSON values first differ, and how (None if equal)."""
    if type(a) is not type(b):
        return f"{where}: {a!r} vs {b!r}"
    if isinstance(a, dict):
        for k in sorted(set(a) | set(b), key=str):
            if k not in a or k not in b:
                return f"{where}.{k}: only in {'B' if k not in a else 'A'}"
            d = first_difference(a[k], b[k], f"{where}.{k}")
            if d:
                return d
        return None
    if isinstance(a, list):
        if len(a) != len(b):
            return f"{where}: length {len(a)} vs {len(b)}"
        for i, (x, y) in enumerate(zip(a, b)):
            d = first_difference(x, y, f"{where}[{i}]")
            if d:
                return d
        return None
    return None if a == b else f"{where}: {a!r} vs {b!r}"


def compare(a: dict, b: dict) -> list[str]:
    """Every difference between fingerprints ``a`` and ``b`` (empty: identical)."""
    out = []
    if a.get("steps") != b.get("steps"):
        out.append(f"steps: {a.get('steps')} vs {b.get('steps')}")
    ra, rb = a["runs"], b["runs"]
    for side, mine, other in (("A", ra, rb), ("B", rb, ra)):
        alone = sorted(set(mine) - set(other))
        if alone:
            out.append(f"{len(alone)} run(s) only in {side}: {', '.join(alone)}")
    for run in sorted(set(ra) & set(rb)):
        x, y = ra[run], rb[run]
        if x["command"] != y["command"] or x["env"] != y["env"]:
            out.append(f"{run}: not the same command (fingerprints of different matrices)")
        if x["path"] != y["path"]:
            out.append(f"{run}: note: the run took path {x['path']} vs {y['path']}")
        for name in sorted(set(x["arrays"]) | set(y["arrays"])):
            if name not in x["arrays"] or name not in y["arrays"]:
                out.append(f"{run}: array {name} only in {'B' if name not in x['arrays'] else 'A'}")
            elif x["arrays"][name] != y["arrays"][name]:
                da, db = x["arrays"][name], y["arrays"][name]
                how = ("values" if da["shape"] == db["shape"] and da["dtype"] == db["dtype"]
                       else f"{da['dtype']}{da['shape']} vs {db['dtype']}{db['shape']}")
                out.append(f"{run}: array {name} differs ({how})")
        for key in sorted(set(x["summary"]) | set(y["summary"])):
            d = first_difference(x["summary"].get(key), y["summary"].get(key), f"summary.{key}")
            if d:
                out.append(f"{run}: {d}")
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--compare", nargs=2, metavar=("A", "B"), help="compare two fingerprint files")
    ap.add_argument("-o", "--output", help="write the fingerprint here (default: stdout)")
    ap.add_argument("--ref", help="fingerprint this commit of the repository instead of the checkout")
    ap.add_argument("--only", nargs="+", metavar="NAME", help="these scenarios only")
    ap.add_argument("--paths", nargs="+", choices=list(PATHS) + ["python"], default=list(PATHS))
    ap.add_argument("--steps", type=int, default=300)
    ap.add_argument("--jobs", type=int, default=1, help="runs at once (default 1)")
    ap.add_argument("--keep", metavar="DIR", help="keep every run's output folder in DIR")
    ap.add_argument("--list", action="store_true", help="print the matrix's commands and exit")
    args = ap.parse_args(argv)
    if args.list:
        for name in SCENARIOS:
            cmd = command(name, args.steps, Path("OUT"))
            print(f"{name}: {' '.join(cmd[1:])[:200]}")
        return 0
    if args.compare:
        a, b = (json.loads(Path(p).read_text()) for p in args.compare)
        for doc in (a, b):               # (the runs of the paths asked for only)
            doc["runs"] = {run: fp for run, fp in doc["runs"].items() if run.rsplit("/", 1)[1] in args.paths}
        diffs = compare(a, b)
        notes = [d for d in diffs if ": note: " in d]
        real = [d for d in diffs if ": note: " not in d]
        for d in notes + real:
            print(d)
        n = len(set(a["runs"]) | set(b["runs"]))
        if real:
            print(f"DIFFERENT: {len(real)} difference(s) over {n} runs ({a.get('commit')} vs {b.get('commit')})")
            return 1
        print(f"identical: {n} runs, every array and count ({a.get('commit')} vs {b.get('commit')})")
        return 0
    return make(args)


if __name__ == "__main__":
    sys.exit(main())

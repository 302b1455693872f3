#!/usr/bin/env python
"""Regenerate the simulation figures of the paper (its Figs. 3-6) in one command.

Runs ``scenarios/paper_case1.yaml`` (undirected tree, protocol ``tree``) and
``scenarios/paper_case2.yaml`` (directed graph, protocol ``flood``) through the
``dkfsim`` command line, then draws with :mod:`dkfsim.report.plots`:

========================  ==================================================================
file                      what (paper figure)
========================  ==================================================================
fig3_tracking.png         case 1, d_t = 3: truth, fused estimate, node 0, centralized KF and
                          the consensus-on-information reference (Fig. 3, ``fig_alg2_delay``)
fig4_mse.png              case 1, d_t = 3: MSE per tick of the same algorithms (Fig. 4)
fig5_case1_vs_case2.png   fused MSE of case 1 vs case 2 (d_t = 4, the paper's default) and
                          the centralized KF (Fig. 5)
fig6_delay_bounds.png     case 1: fused position MSE for d_t = 0, 1, 2, 3, 4 (Fig. 6)
========================  ==================================================================

Each case is a Monte Carlo of ``--runs`` runs (``dkfsim montecarlo``).  The
reference of the paper's Figs. 3/4 ([2020Distributed], a consensus filter) is
represented by the ``ci_consensus`` estimator.

Everything goes to one output folder, ``--out`` (default ``out/reproduce_paper``,
ignored by git): the figures (PNG and PDF) and, unless ``--work`` names another
folder, one simulation folder per case.  It never writes over tracked files unless
asked to: refreshing the figures the docs show is ``--out docs/figures --work
out/reproduce_paper``.  ``--plot-only`` redraws from existing simulation folders.

Usage::

    .venv/bin/python tools/reproduce_paper.py                  # 20 runs per case, 1000 ticks
    .venv/bin/python tools/reproduce_paper.py --runs 100 --jobs 8 --out out/figs
    .venv/bin/python tools/reproduce_paper.py --runs 1 --steps 10 --format png   # a smoke test
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from dkfsim.core.errors import DkfsimError  # noqa: E402
from dkfsim.report import plots  # noqa: E402

CASE1 = ROOT / "scenarios" / "paper_case1.yaml"
CASE2 = ROOT / "scenarios" / "paper_case2.yaml"
DKFSIM = [sys.executable, "-m", "dkfsim"]
REFERENCE = ["centralized", "ci_consensus"]      # estimators beside the DKF in Figs. 3/4
DELAY_BOUNDS = (0, 1, 2, 3, 4)


@dataclass
class Job:
    name: str
    scenario: Path
    d_t: int
    estimators: list[str]

    def overrides(self) -> list[str]:
        entries = ", ".join("{kind: %s}" % kind for kind in self.estimators)
        return ["--set", f"links.default.latency.d_t={self.d_t}",
                "--set", f"estimators=[{entries}]"]


def quiet_run(argv) -> subprocess.CompletedProcess:
    return subprocess.run(DKFSIM + argv, capture_output=True, text=True, cwd=ROOT)


def simulate(job: Job, folder: Path, args) -> float:
    argv = ["montecarlo", str(job.scenario), "--runs", str(args.runs), "--jobs", str(args.jobs),
            "--out", str(folder), "--quiet", *job.overrides()]
    if args.steps is not None:
        argv += ["--steps", str(args.steps)]
    print("  $ dkfsim " + " ".join(a if " " not in a else repr(a) for a in argv), flush=True)
    t0 = time.perf_counter()
    p = quiet_run(argv)
    if p.returncode != 0:
        raise SystemExit(f"reproduce_paper: dkfsim {argv[0]} failed for {job.name} "
                         f"(exit {p.returncode}):\n{p.stderr.strip()}")
    return time.perf_counter() - t0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 epilog="See the module docstring for the figures and what each shows.")
    ap.add_argument("--runs", type=int, default=20, metavar="N",
                    help="Monte Carlo runs per case (default: 20)")
    ap.add_argument("--steps", type=int, default=None, metavar="K",
                    help="ticks per run (default: the scenarios' 1000, i.e. 10 s)")
    ap.add_argument("--jobs", type=int, default=min(2, os.cpu_count() or 1), metavar="J",
                    help="worker processes (default: min(2, CPUs))")
    ap.add_argument("--out", type=Path, default=ROOT / "out" / "reproduce_paper", metavar="DIR",
                    help="output folder: the figures and, unless --work says otherwise, the "
                         "simulation folders (default: out/reproduce_paper, ignored by git)")
    ap.add_argument("--work", type=Path, default=None, metavar="DIR",
                    help="folder for the simulation outputs (default: the --out folder)")
    ap.add_argument("--format", dest="formats", nargs="+", default=["png", "pdf"], choices=plots.FORMATS,
                    help="figure formats (default: png pdf)")
    ap.add_argument("--smooth", type=int, default=None, metavar="TICKS",
                    help="moving average of the MSE curves, in ticks (default: none)")
    ap.add_argument("--plot-only", action="store_true",
                    help="do not simulate; redraw from the folders in --work")
    args = ap.parse_args(argv)
    if args.runs < 1 or args.jobs < 1 or (args.steps is not None and args.steps < 10):
        ap.error("--runs and --jobs must be >= 1 and --steps >= 10")

    out = args.out
    work = out if args.work is None else args.work
    t_start = time.perf_counter()
    jobs = [Job("case1_d3", CASE1, 3, REFERENCE)]
    jobs += [Job(f"case1_d{d}", CASE1, d, ["centralized"]) for d in DELAY_BOUNDS if d != 3]
    jobs += [Job("case2_d4", CASE2, 4, ["centralized"])]

    if not args.plot_only:
        print(f"simulating {len(jobs)} cases into {work} (Monte Carlo, {args.runs} runs each, "
              f"{args.jobs} job(s))", flush=True)
        for job in jobs:          # each Monte Carlo uses every worker itself
            dt = simulate(job, work / job.name, args)
            print(f"    {job.name}: {dt:.1f} s", flush=True)

    try:
        f = {job.name: plots.load_folder(work / job.name) for job in jobs}
    except DkfsimError as exc:
        raise SystemExit(f"reproduce_paper: {exc}") from None
    c1 = f["case1_d3"]
    what = f"{c1.n_runs} Monte Carlo runs"
    written = []
    written += plots.plot_tracking(
        c1, out / "fig3_tracking", args.formats,
        title="Fig. 3: tracking with delay bound d_t = 3, case 1 (undirected tree); "
              "run 0 of the Monte Carlo")
    fig4_estimates = ["fused", "local", "ci_consensus", "centralized"]
    written += plots.plot_mse(
        c1, out / "fig4_mse", args.formats, smooth=args.smooth, estimates=fig4_estimates,
        title="Fig. 4: MSE with delay bound d_t = 3, case 1 (undirected tree)")
    pair = [f["case1_d4"], f["case2_d4"]]
    written += plots.plot_compare(
        pair, out / "fig5_case1_vs_case2", formats=args.formats, smooth=args.smooth, relative=True,
        labels=["case 1: undirected tree (protocol tree)",
                "case 2: directed graph (protocol flood)"],
        title="Fig. 5: fused MSE, undirected (case 1) vs directed (case 2) graph, d_t = 4")
    sweep = [f[f"case1_d{d}"] for d in DELAY_BOUNDS]
    written += plots.plot_compare(
        sweep, out / "fig6_delay_bounds", formats=args.formats, smooth=args.smooth, relative=True,
        labels=[f"d_t = {d}" for d in DELAY_BOUNDS], components=["position"],
        title="Fig. 6: fused position MSE for delay bounds d_t = 0..4, case 1")
    print(f"figures from {what} per case, {time.perf_counter() - t_start:.0f} s in all:")
    for p in written:
        print(f"  {p}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

#!/usr/bin/env python
"""The tables and the figure of docs/mobility.md: the shipped mobility scenarios.

``scenario_table()``: one run of each shipped mobility scenario (its own steps and seed): the
buffer length and the window ``B`` of the finite-time result (docs/design.md §6), the share of
(tick, link) pairs that are up, how many ticks change the set of links, the position MSE (x + y,
m^2, after the burn-in) of the fused, local (mean over nodes), centralized and ci_consensus
estimates, and ``late`` counted per contribution (the run keeps the arrival log).
``range_table()``: ``scenarios/sweep_mobility_range.yaml`` run through ``dkfsim sweep`` (in a
temporary folder), the position MSE per range and estimate from its ``summary.csv``.  Both are
Markdown tables; tools/docs_numbers.py writes them into docs/mobility.md (generator
``mobility``, decision 205), and this script prints them.

With ``--figure STEM`` it also draws the convoy (``STEM.png``): the cars' paths with the
links up at three instants, and over time the number of links up beside car 5's position
error (fused, its own window estimate, centralized; 1 s moving average).

Usage: ``python tools/mobility_table.py [--figure docs/figures/mobility_convoy]``.
"""

from __future__ import annotations

import argparse
import csv
import tempfile
from collections import defaultdict
from pathlib import Path

import numpy as np

import dkfsim
from dkfsim.config.plan import RunPlan
from dkfsim.report.plots.style import color_of, moving_average, save_figure

ROOT = Path(__file__).resolve().parents[1]
SCENARIOS = ("mobility_convoy", "mobility_crossing", "mobility_platoon")
ESTIMATES = ("fused", "local", "centralized", "ci_consensus")


def row(name: str) -> str:
    """The table row of scenario ``name`` (see the module)."""
    sc = dkfsim.load_scenario(ROOT / "scenarios" / f"{name}.yaml")
    plan = RunPlan(sc)
    up = plan.link_schedule.up[1:]
    changes = int((up[1:] != up[:-1]).any(axis=1).sum())
    res = dkfsim.run(sc, save="full")
    m = res.metrics()
    mse = [f"{m[e][0] + m[e][2]:.3f}" if e in m else "–" for e in ESTIMATES]
    B = plan.connect_window
    return (f"| `{name}` | {sc.steps} | {res.info['buffer_length']} ({'B = ' + str(B) if B else 'no B'}) | "
            f"{up.mean():.2f} | {changes} | " + " | ".join(mse) + f" | {res.counts['late']} |")


def convoy_figure(stem: Path) -> list[Path]:
    """The convoy figure (see the module)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    sc = dkfsim.load_scenario(ROOT / "scenarios" / "mobility_convoy.yaml")
    plan = RunPlan(sc)
    K, T = sc.steps, sc.model.T
    pos = sc.mobility.positions(sc.n, K, T)
    pos = pos - pos[0, 0]
    up = plan.link_schedule.up
    res = dkfsim.run(sc, save="estimates")
    a = res.arrays
    t = np.arange(K + 1) * T
    fig, (ax0, ax1) = plt.subplots(1, 2, figsize=(11, 4.2))
    ax0.plot(pos[:, 0, 0], pos[:, 0, 1], color="0.8", lw=4, zorder=0)
    for k, c in zip((240, 600, 900), ("C0", "C1", "C2")):
        for i, (u, v) in enumerate(plan.arcs):
            if u < v and up[k, i]:
                ax0.plot(*pos[k, [u, v]].T, color=c, lw=1.5)
        ax0.plot(*pos[k].T, "o", color=c, ms=4, label=f"t = {k * T:.0f} s")
    ax0.set_aspect("equal")
    ax0.set_xlabel("east (m)")
    ax0.set_ylabel("north (m)")
    ax0.set_title("the convoy and its links at three instants")
    ax0.legend(fontsize=8)
    n_up = up[1:].sum(axis=1) // 2
    ax1.fill_between(t[1:], 0, n_up, step="pre", color="0.85", label="links up (right axis)")
    ax1.set_ylabel("links up")
    ax2 = ax1.twinx()
    truth = a["truth"][:, [0, 2]]
    for name, x in (("fused", a["x_fused"]), ("local", a["x_local"][:, 5]),
                    ("centralized", a["x_centralized"])):
        err = moving_average(np.hypot(*(x[:, [0, 2]] - truth).T), 20)     # 1 s moving average
        ax2.plot(t[1:], err, lw=0.8, color=color_of(name), label=f"{name}{' (car 5)' if name == 'local' else ''}")
    ax2.set_ylabel("position error (m), 1 s moving average")
    ax1.set_xlabel("t (s)")
    ax1.set_title("links up and position errors")
    ax2.legend(fontsize=8, loc="upper right")
    fig.tight_layout()
    return save_figure(fig, stem, ("png",))


def scenario_table() -> str:
    """One run of each shipped mobility scenario, as a Markdown table (see the module)."""
    lines = ["| scenario | ticks | L | links up | ticks that change links | " + " | ".join(ESTIMATES)
             + " | late |", "|---|---|---|---|---|" + "---|" * len(ESTIMATES) + "---|"]
    return "\n".join(lines + [row(name) for name in SCENARIOS])


def _sweep_rows(name: str) -> list[dict[str, str]]:
    """The ``summary.csv`` rows of ``scenarios/<name>`` run through ``dkfsim sweep``."""
    from dkfsim.cli.main import main as cli
    with tempfile.TemporaryDirectory() as tmp:
        db = Path(tmp) / "sweep.sqlite"
        cli(["sweep", str(ROOT / "scenarios" / name), "--db", str(db), "--jobs", "1", "--quiet", "--yes"])
        with open(db.with_suffix(".summary.csv"), newline="") as f:
            return list(csv.DictReader(f))


def range_table() -> str:
    """``scenarios/sweep_mobility_range.yaml`` through ``dkfsim sweep``, as a Markdown table."""
    rows = _sweep_rows("sweep_mobility_range.yaml")
    mse: dict[tuple[float, str], float] = defaultdict(float)
    for r in rows:
        if r["component"] in ("x", "y"):
            mse[(float(r["mobility.range.radius"]), r["estimate"])] += float(r["mse"])
    cols = ("local", "ci_consensus", "fused", "centralized")
    lines = ["| range (m) | local (mean over nodes) | ci_consensus | fused | centralized |", "|---|---|---|---|---|"]
    for radius in sorted({k[0] for k in mse}):
        lines.append(f"| {radius:g} | " + " | ".join(f"{mse[(radius, e)]:.3f}" for e in cols) + " |")
    return "\n".join(lines)


def speed_table() -> str:
    """``scenarios/sweep_mobility_speed.yaml`` (range x ``mobility.speed``) through ``dkfsim
    sweep``, as a Markdown table."""
    rows = _sweep_rows("sweep_mobility_speed.yaml")
    mse: dict[tuple[float, float, str], float] = defaultdict(float)
    for r in rows:
        if r["component"] in ("x", "y"):
            mse[(float(r["mobility.range.radius"]), float(r["mobility.speed"]), r["estimate"])] += float(r["mse"])
    cols = ("local", "ci_consensus", "fused", "centralized")
    lines = ["| range (m) | speed | local (mean over nodes) | ci_consensus | fused | centralized |",
             "|---|---|---|---|---|---|"]
    for radius, speed in sorted({k[:2] for k in mse}):
        lines.append(f"| {radius:g} | {speed:g} | " + " | ".join(f"{mse[(radius, speed, e)]:.3f}" for e in cols) + " |")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--figure", type=Path, default=None, help="draw the convoy figure to this stem")
    args = ap.parse_args(argv)
    if args.figure is not None:
        for path in convoy_figure(args.figure):
            print(f"wrote {path}")
    print(scenario_table())
    print()
    print(range_table())
    print()
    print(speed_table())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

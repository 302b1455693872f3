#!/usr/bin/env python
"""The paper's radar experiment (section V-D) as a Monte Carlo study.

Runs ``scenarios/radar_experiment.yaml`` (three range/azimuth radars, a car
starting at (0, 6.123) m, T = 0.01 s, 21 ticks, a 3-node tree with delays of
0-2 ticks per hop) over many independent seeds -- run ``r`` uses
``dkfsim.experiments.montecarlo.derive_seed(seed, r)``, the same run ``r`` as
``dkfsim montecarlo`` -- and writes

* ``docs/figures/radar_track.png``: one run in the x-y plane: the radars, the
  truth, the anti-delay DKF's fused estimate, the centralized filter and each
  radar's local-only filter (overview and zoom on the track);
* ``docs/figures/radar_mse.png``: the position MSE per tick (mean over runs of
  ``(x - x_true)^2 + (y - y_true)^2``, shaded 95 % Student-t intervals) of the
  fused estimate, the centralized filters, the other estimators and each radar alone;

and prints the table of time-averaged position MSEs with 95 % intervals.
See docs/radar.md for the assumptions and the reading of the results.

Usage: ``python tools/radar_experiment.py [--runs 200] [--out docs/figures]
[--scenario scenarios/radar_experiment.yaml] [--no-plots]``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import dkfsim  # noqa: E402
from dkfsim.analysis.metrics import t_interval  # noqa: E402
from dkfsim.experiments.montecarlo import derive_seed  # noqa: E402

#: (label, array, per node?) of every estimate scored; radars alone are added per sensor.
ESTIMATES = (
    ("anti-delay DKF (fused)", "x_fused", False),
    ("anti-delay DKF (per node, mean)", "x_local", True),
    ("centralized (all data on time)", "x_centralized", False),
    ("centralized, delayed links", "x_centralized_delayed", False),
    ("no buffer (L = 1), fused", "x_no_buffer", False),
    ("CI consensus (per node, mean)", "x_ci_consensus", True),
)


def position_sq_error(x: np.ndarray, truth: np.ndarray, ix: int, iy: int) -> np.ndarray:
    """(K,) squared position error; per-node estimates (K, n, nx) averaged over nodes."""
    if x.ndim == 3:
        e = (x[..., ix] - truth[:, None, ix]) ** 2 + (x[..., iy] - truth[:, None, iy]) ** 2
        return e.mean(axis=1)
    return (x[:, ix] - truth[:, ix]) ** 2 + (x[:, iy] - truth[:, iy]) ** 2


def monte_carlo(sc, runs: int):
    """Squared position errors per (estimate, run, tick) and run 0's arrays."""
    ix, iy = sc.sensors[0].state_index if sc.sensors[0].kind == "radar" else (0, 2)
    labels = [lab for lab, key, _ in ESTIMATES]
    radar_labels = [f"{s.name} alone" for s in sc.sensors]
    err = {lab: np.empty((runs, sc.steps)) for lab in labels + radar_labels}
    first = None
    present = set()
    for r in range(runs):
        res = dkfsim.run(sc, seed=derive_seed(sc.seed, r), save="estimates")
        truth = res["truth"]
        if first is None:
            first = {k: np.asarray(v) for k, v in res.arrays.items()}
        for lab, key, _ in ESTIMATES:
            if key in res.arrays:
                err[lab][r] = position_sq_error(res[key], truth, ix, iy)
                present.add(lab)
        for i, lab in enumerate(radar_labels):
            err[lab][r] = position_sq_error(res["x_local_only"][:, i], truth, ix, iy)
            present.add(lab)
    return {lab: e for lab, e in err.items() if lab in present}, first, (ix, iy)


def table(err: dict, sc) -> str:
    K, T = sc.steps, sc.model.T
    half = K // 2
    rows = [("estimate", f"all {K} ticks", f"ticks {half + 1}-{K}", f"tick {K}",
             "minus fused, all ticks (paired)")]
    fused = err[ESTIMATES[0][0]].mean(axis=1)
    for lab, e in err.items():
        cells = [lab]
        for block in (e.mean(axis=1), e[:, half:].mean(axis=1), e[:, -1], e.mean(axis=1) - fused):
            m, lo, hi = t_interval(block)
            cells.append(f"{m * 1e4:7.2f} [{lo * 1e4:6.2f}, {hi * 1e4:6.2f}]")
        if lab == ESTIMATES[0][0]:
            cells[-1] = "-"
        rows.append(tuple(cells))
    w = [max(len(r[c]) for r in rows) for c in range(len(rows[0]))]
    lines = [f"position MSE (x^2 + y^2 error, in cm^2 = 1e-4 m^2), mean [95 % CI] over "
             f"{len(next(iter(err.values())))} runs; T = {T} s"]
    for j, r in enumerate(rows):
        lines.append("  ".join(c.ljust(w[i]) if i == 0 else c.rjust(w[i]) for i, c in enumerate(r)))
        if j == 0:
            lines.append("  ".join("-" * x for x in w))
    return "\n".join(lines)


def plot_track(first: dict, sc, ixy, path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    ix, iy = ixy
    truth = first["truth"]
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.6), gridspec_kw={"width_ratios": [1, 1.3]})
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for ax, zoom in zip(axes, (False, True)):
        for i, s in enumerate(sc.sensors):
            c = colours[(i + 3) % len(colours)]
            if not zoom:
                ax.plot(*s.position, marker="^", ms=10, color=c, ls="none", label=f"{s.name}")
                ax.plot([s.position[0], truth[0, ix]], [s.position[1], truth[0, iy]], color=c,
                        lw=0.6, ls=":")
            xl = first["x_local_only"][:, i]
            ax.plot(xl[:, ix], xl[:, iy], color=c, lw=1, ls="--", marker=".", ms=3,
                    label=f"{s.name} alone" if zoom else None)
        ax.plot(truth[:, ix], truth[:, iy], color="k", lw=2, label="truth")
        ax.plot(first["x_centralized"][:, ix], first["x_centralized"][:, iy], color=colours[1],
                lw=1.2, marker="s", ms=3, label="centralized")
        ax.plot(first["x_fused"][:, ix], first["x_fused"][:, iy], color=colours[0], lw=1.5,
                marker="o", ms=3, label="anti-delay DKF (fused)")
        ax.plot(truth[0, ix], truth[0, iy], marker="*", ms=12, color="k", ls="none")
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
        ax.grid(alpha=0.3)
        if zoom:
            ax.set_title(f"zoom on the track ({sc.steps} ticks of {sc.model.T} s; star: tick 1)")
            ax.legend(fontsize=8, loc="best")
        else:
            ax.set_title("radars and car (one run)")
            ax.set_aspect("equal", adjustable="datalim")
            ax.legend(fontsize=8, loc="center left")
    fig.suptitle("Radar experiment (paper section V-D): tracking, seed "
                 f"{derive_seed(sc.seed, 0)} (run 0)", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)


def plot_mse(err: dict, sc, path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    t = np.arange(1, sc.steps + 1) * sc.model.T
    fig, ax = plt.subplots(figsize=(8.5, 5))
    styles = {"anti-delay DKF (fused)": dict(lw=2.2, color="C0"),
              "centralized (all data on time)": dict(lw=1.6, color="C1", ls="--")}
    for j, (lab, e) in enumerate(err.items()):
        m, lo, hi = t_interval(e)
        st = styles.get(lab, dict(lw=1.1, color=f"C{(j + 2) % 10}",
                                  ls=":" if lab.endswith("alone") else "-"))
        ax.plot(t, m, label=lab, **st)
        ax.fill_between(t, lo, hi, color=st["color"], alpha=0.12, lw=0)
    ax.set_yscale("log")
    ax.set_xlabel("time t_k = k T (s)")
    ax.set_ylabel("position MSE (m^2)")
    ax.grid(alpha=0.3, which="both")
    ax.set_title(f"Radar experiment: position MSE per tick over {len(e)} runs "
                 "(shaded: 95 % CI)", fontsize=10)
    ax.legend(fontsize=8, ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--runs", type=int, default=200, help="independent runs (default 200)")
    p.add_argument("--scenario", default=str(ROOT / "scenarios" / "radar_experiment.yaml"))
    p.add_argument("--out", default=str(ROOT / "docs" / "figures"), help="folder for the PNGs")
    p.add_argument("--no-plots", action="store_true", help="print the table only")
    args = p.parse_args(argv)
    if args.runs < 2:
        p.error("--runs must be at least 2 (confidence intervals)")
    sc = dkfsim.load_scenario(args.scenario)
    t0 = time.perf_counter()
    err, first, ixy = monte_carlo(sc, args.runs)
    print(table(err, sc))
    print(f"({args.runs} runs in {time.perf_counter() - t0:.1f} s)")
    if not args.no_plots:
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        plot_track(first, sc, ixy, out / "radar_track.png")
        plot_mse(err, sc, out / "radar_mse.png")
        print(f"wrote {out / 'radar_track.png'} and {out / 'radar_mse.png'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

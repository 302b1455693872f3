#!/usr/bin/env python
"""Regenerate the numbers the docs quote, from the code (issue 24 §3, decision 205).

Every number README.md and docs/*.md quote from a simulation sits in a marked block::

    <!-- numbers:NAME -->
    ... text this tool writes ...
    <!-- /numbers -->

and every NAME belongs to one generator below, which runs a fixed command with fixed seeds
(the scenario's ``seed``; Monte Carlo run r uses ``derive_seed(seed, r)``) and renders the
block.  The text between the markers is the tool's: edit the template here, not the page.

Two kinds of generator:

* **cheap** (one run, a few seconds): ``quickstart``.  The drift test
  (tests/test_docs_numbers.py) recomputes it in the normal suite.
* **Monte Carlo studies** (minutes of CPU): ``paper`` (Figs. 4-6 of docs/figures.md),
  ``consensus`` (docs/consensus.md, docs/estimators.md, docs/statistics.md) and ``sweep``
  (``scenarios/sweep_algorithms.yaml``: docs/consensus.md, docs/figures.md), ``centre``
  (docs/fusion_centre.md: paper case 1 at d_t = 0, 2, 4 with a fusion centre).  The per-run rows
  a study's blocks are computed from are kept in ``docs/numbers/<study>.csv``; the drift test
  renders the blocks from those rows (normal suite) and, in its slow tier, re-runs runs 0 and 1
  of each study and checks they equal the stored rows.
* ``buffer`` (docs/performance.md): paper case 1 at L = 5, 9, 17, 33, 65, ten runs each: bytes
  and MSE from the stored rows, the memory and the CPU estimated from a trial's events (at the
  stored seconds per event: regenerate after ``tools/bench.py --calibrate``).
* ``channel`` (docs/channel.md): ``scenarios/sweep_channel.yaml``, one study per channel rate
  (its stored rows keep ``lost`` and ``bytes_per_tick`` too), like ``sweep``.
* ``radar`` (docs/radar.md, docs/figures.md): 200 runs of 21 ticks, recomputed whole by the
  slow tier (``--check`` recomputes it only when named in ``--only``); ``mobility``
  (docs/mobility.md: the shipped mobility scenarios, the range sweep and the range x speed
  sweep, about 60 runs of 300-1080 ticks) likewise.
* ``sidelink`` (docs/radio.md, "C-V2X sidelink", issue 33): ``scenarios/sweep_sidelink_*ms.yaml``
  and the sidelink tuned to the 20 ms tick (``sweep_sidelink_20ms_tuned.yaml``), one study per
  radio, density and DKF tick (about 15 minutes of CPU in all), whose stored rows
  keep the DKF's packet and frame counts beside the radio's; it also draws
  docs/figures/sidelink_highway.png.

Timings are never generated: they depend on the machine (decision 205).

Usage::

    .venv/bin/python tools/docs_numbers.py                 # recompute everything, rewrite blocks
    .venv/bin/python tools/docs_numbers.py --only quickstart
    .venv/bin/python tools/docs_numbers.py --render        # rewrite blocks from the stored rows
    .venv/bin/python tools/docs_numbers.py --check         # exit 1 naming blocks that differ
                                                           # (cheap generators and stored rows)
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import re
import sys
import textwrap
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml
from scipy.stats import t as student_t

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import dkfsim  # noqa: E402
from dkfsim.analysis.metrics import anees_consistent, nees_band, t_interval  # noqa: E402
from dkfsim.analysis.paired import paired_block  # noqa: E402
from dkfsim.core.folders import write_csv  # noqa: E402
from dkfsim.experiments.montecarlo import Template, derive_seed, run_rows  # noqa: E402
from dkfsim.report.tables import run_table  # noqa: E402

PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
DATA = ROOT / "docs" / "numbers"
#: A block: its opening and closing markers each a line of their own.
BLOCK = re.compile(r"^(<!-- numbers:(?P<name>[\w-]+) -->\n)(?P<body>.*?)^(<!-- /numbers -->)$", re.S | re.M)
#: The columns of the stored per-run rows (a subset of ``runs.csv``'s).
COLUMNS = ("run", "estimate", "component", "mse", "anees", "messages_per_tick", "late")
SPOT_RUNS = (0, 1)


# =========================================================================== the blocks
def blocks(text: str) -> list[tuple[str, str]]:
    """``(name, body)`` of every marked block of a page, in page order."""
    return [(m["name"], m["body"]) for m in BLOCK.finditer(text)]


def rewrite(text: str, rendered: dict[str, str]) -> str:
    """``text`` with the body of every block named in ``rendered`` replaced."""
    def sub(m):
        name = m["name"]
        return m.group(1) + rendered[name].rstrip("\n") + "\n" + m.group(4) if name in rendered else m.group(0)
    return BLOCK.sub(sub, text)


def page_blocks() -> dict[str, list[tuple[Path, str]]]:
    """Every block of README.md and docs/*.md: name -> [(page, body)]."""
    out: dict[str, list[tuple[Path, str]]] = {}
    for page in PAGES:
        for name, body in blocks(page.read_text()):
            out.setdefault(name, []).append((page, body))
    return out


def write_blocks(rendered: dict[str, str]) -> list[Path]:
    """Rewrite the pages holding the blocks in ``rendered``; the pages changed."""
    changed = []
    for page in PAGES:
        old = page.read_text()
        new = rewrite(old, rendered)
        if new != old:
            page.write_text(new)
            changed.append(page)
    return changed


# =========================================================================== formatting
def g4(v: float) -> str:
    return "—" if v is None or math.isnan(v) else f"{v:.4g}"


def sig2(v: float) -> str:
    """Two significant digits, trailing zero kept (2.0, 0.65, 1.1)."""
    return f"{v:#.2g}".rstrip(".")


def interval(samples, spec: str = ".4g") -> str:
    mean, lo, hi = t_interval(np.asarray(samples, dtype=float))
    return f"{mean:{spec}} [{lo:{spec}}, {hi:{spec}}]"


def para(text: str, bullet: bool = False) -> str:
    """Prose wrapped at 100 columns (as a ``- `` list item when ``bullet``)."""
    glued = text.replace(" %", "\0%").replace(" cm²", "\0cm²")       # never a unit alone on a line
    return textwrap.fill(glued, 100, break_long_words=False, break_on_hyphens=False,
                         initial_indent="- " if bullet else "",
                         subsequent_indent="  " if bullet else "").replace("\0", " ")


def pct_above(ratio: float) -> str:
    return sig2(100 * (ratio - 1))


def span(values, fmt: Callable[[float], str]) -> str:
    """``lo–hi`` of ``values`` as ``fmt`` writes them; one value when both read the same."""
    lo, hi = fmt(min(values)), fmt(max(values))
    return lo if lo == hi else f"{lo}–{hi}"


# =========================================================================== stored rows
class Rows:
    """The per-run rows of one Monte Carlo study, looked up by estimate, component, column."""

    def __init__(self, rows: list[dict]):
        self.rows = rows
        self.components = list(dict.fromkeys(r["component"] for r in rows))
        self.estimates = list(dict.fromkeys(r["estimate"] for r in rows))
        self.runs = len({r["run"] for r in rows})

    def col(self, estimate: str, key: str, component: str | None = None) -> np.ndarray:
        comp = self.components[0] if component is None else component
        return np.array([r[key] for r in sorted(self.rows, key=lambda r: r["run"])
                         if r["estimate"] == estimate and r["component"] == comp], dtype=float)

    def mean(self, estimate: str, key: str, component: str | None = None) -> float:
        return float(np.mean(self.col(estimate, key, component)))

    def consistent(self, estimate: str) -> str:
        _, lo, hi = t_interval(self.col(estimate, "anees"))
        return {True: "yes", False: "no", None: "—"}[anees_consistent([float(lo), float(hi)],
                                                                      len(self.components))]

    def ratio(self, estimate: str, reference: str, component: str) -> tuple[float, float, float]:
        """Paired MSE ratio (geometric mean over runs) with its 95 % interval."""
        p = paired_block(self.rows, estimate, reference, self.components)
        lo, hi = p["mse_ratio_ci95"][component]
        return p["mse_ratio"][component], lo, hi


def save_rows(path: Path, rows: Iterable[dict], columns: tuple[str, ...] = COLUMNS) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    write_csv(path, columns, ([r[c] if c in ("run", "estimate", "component") else float(r[c])
                               for c in columns] for r in rows))


def read_rows(path: Path) -> list[dict]:
    with path.open(newline="") as f:
        return [{c: (int(v) if c == "run" else v if c in ("estimate", "component") else float(v))
                 for c, v in row.items()} for row in csv.DictReader(f)]


@dataclass(frozen=True)
class Study:
    """One Monte Carlo configuration: a scenario, ``--set`` overrides, a number of runs."""

    name: str
    scenario: str
    overrides: tuple[str, ...]
    runs: int
    #: the columns of ``runs.csv`` it stores (a study may keep more than :data:`COLUMNS`)
    columns: tuple[str, ...] = COLUMNS

    def load(self):
        return dkfsim.load_scenario(ROOT / self.scenario, overrides=list(self.overrides))

    def command(self, out: str) -> str:
        sets = "".join(f" \\\n  --set {s!r}" if " " in s else f" \\\n  --set {s}" for s in self.overrides)
        return (f".venv/bin/dkfsim montecarlo {self.scenario} --runs {self.runs} --jobs 2 --yes "
                f"--out {out}{sets}")

    def compute(self, jobs: int) -> list[dict]:
        res = dkfsim.montecarlo(self.load(), self.runs, jobs=jobs, yes=True)
        return [{c: r[c] for c in self.columns} for r in res.rows]

    def spot(self, runs: Iterable[int] = SPOT_RUNS) -> list[dict]:
        """Runs ``runs`` alone (run r is the same run whatever ``--runs``), as stored."""
        sc = self.load()
        tpl = Template(sc)
        out = []
        for r in runs:
            rows, _ = run_rows(tpl, derive_seed(sc.seed, r), curves=False)
            out += [{**{c: row[c] for c in self.columns}, "run": r} for row in rows]
        return out

    @property
    def path(self) -> Path:
        return DATA / f"{self.name}.csv"


# =========================================================================== generators
@dataclass
class Generator:
    """Renders named blocks.  ``studies``: the Monte Carlo configurations whose stored rows
    ``render`` reads (empty: ``render`` computes from scratch, cheaply)."""

    name: str
    blocks: tuple[str, ...]
    render: Callable[..., dict[str, str]]
    studies: tuple[Study, ...] = field(default_factory=tuple)
    cheap: bool = False


# --------------------------------------------------------------------------- quick start
def render_quickstart() -> dict[str, str]:
    """``make run``: ``dkfsim run scenarios/paper_case1.yaml``, its table without the wall time."""
    res = dkfsim.run(ROOT / "scenarios" / "paper_case1.yaml")
    table = "\n".join(line for line in run_table(res).splitlines() if not line.startswith("wall time"))
    m = res.metrics()
    comps = res.components
    above = [m["fused"][i] / m["centralized"][i] for i in range(len(comps))]
    local = m["local"][0] / m["fused"][0]
    reading = (f"The fused estimate's MSE is {span(above, pct_above)} % above "
               "the centralized Kalman filter's although every hop delays packets by 0–4 ticks; a "
               "single node's real-time estimate (which still misses most of the newest rows' "
               f"information) has {local:.1f} times the fused position MSE.")
    return {"quickstart": f"```\n{table}\n```", "quickstart-reading": para(reading)}


# --------------------------------------------------------------------------- the paper's figures
PAPER_ESTIMATORS = {3: "[{kind: centralized}, {kind: ci_consensus}]"}
PAPER = tuple(Study(f"paper_case1_d{d}", "scenarios/paper_case1.yaml",
                    (f"links.default.latency.d_t={d}",
                     f"estimators={PAPER_ESTIMATORS.get(d, '[{kind: centralized}]')}"), 20)
              for d in range(5)) + (
    Study("paper_case2_d4", "scenarios/paper_case2.yaml",
          ("links.default.latency.d_t=4", "estimators=[{kind: centralized}]"), 20),)


def render_paper(rows: dict[str, Rows]) -> dict[str, str]:
    """Figs. 4-6 of tools/reproduce_paper.py (the same Monte Carlo runs)."""
    d3 = rows["paper_case1_d3"]
    comps = d3.components
    above = [d3.ratio("fused", "centralized", c)[0] for c in comps]
    below = [d3.mean("ci_consensus", "mse", c) / d3.mean("fused", "mse", c) for c in comps]
    fig4 = (f"**Fig. 4** — The same case: MSE per tick over {d3.runs} runs (95 % confidence band "
            "shaded; the number beside each panel is the MSE averaged over t ≥ 1.01 s with its 95 % "
            f"interval): the fused estimate's MSE is {span(above, pct_above)} % above the "
            f"centralized filter's (paired ratios), {span(below, lambda v: f'{v:.0f}')} times below the "
            "consensus reference and well below the nodes' own real-time estimates.")
    pair = []
    for name, label in (("paper_case1_d4", "case 1"), ("paper_case2_d4", "case 2")):
        r, lo, hi = rows[name].ratio("fused", "centralized", "position")
        pair.append(f"{r:.3f} [{lo:.3f}, {hi:.3f}] ({label})")
    fig5 = ("**Fig. 5** — Fused MSE on the undirected tree (case 1, protocol `tree`, `L = 17`) and on "
            "the directed graph (case 2, protocol `flood`, `L = 21`) at the paper's `d_t = 4`, with the "
            "centralized filter; the right column divides each by the centralized MSE (50-tick moving "
            "averages). Averaged over t ≥ 1.01 s, the fused position MSE is "
            f"{' and '.join(pair)} times the centralized one (paired ratios over the {d3.runs} runs).")
    grow = [rows[f"paper_case1_d{d}"].ratio("fused", "centralized", "position")[0] for d in range(1, 5)]
    d0 = rows["paper_case1_d0"]
    per_run = d0.col("fused", "mse", "position") / d0.col("centralized", "mse", "position")
    exact = 1.0 if np.allclose(per_run, 1.0, rtol=0, atol=1e-9) else float(np.mean(per_run))
    fig6 = ("**Fig. 6** — Fused position MSE on case 1 for delay bounds `d_t = 0, 1, 2, 3, 4` (one "
            "Monte Carlo per bound, `--set links.default.latency.d_t=…`, buffer `L = 4 d_t + 1`): at "
            f"`d_t = 0` it equals the centralized filter {'exactly' if exact == 1 else f'× {exact:.6f}'}, "
            f"and it grows moderately with the bound (by {', '.join(pct_above(v) + ' %' for v in grow[:-1])} "
            f"and {pct_above(grow[-1])} % at `d_t = 1, 2, 3, 4`: paired ratios to the centralized "
            "filter, `mse_ratio` in `summary.json`), as the paper's Fig. 6 reports.")
    return {"fig4": para(fig4), "fig5": para(fig5), "fig6": para(fig6)}


# --------------------------------------------------------------------------- the consensus family
CONSENSUS = Study(
    "consensus_case1_d4", "scenarios/paper_case1.yaml",
    ("links.default.latency.d_t=4",
     "estimators=[{kind: centralized}, {kind: local_only}, {kind: ci_consensus}, {kind: kcf}, "
     "{kind: icf}, {kind: diffusion_kf}, {kind: hcmci}, {kind: hcmci, omega: n, name: hcmci_n}, "
     "{kind: no_buffer}]"),
    100)
ONE_SLOT = ("ci_consensus", "kcf", "icf", "hcmci", "hcmci_n")      # one message per link and tick
LABELS = {"fused": "`fused` (anti-delay DKF)", "no_buffer": "`no_buffer` (the DKF with `L = 1`)",
          "hcmci": "`hcmci` (`omega = 1`)",
          "hcmci_n": "`hcmci` (`omega = n`)"}
ESTIMATORS_ORDER = ("fused", "centralized", "no_buffer", "ci_consensus", "kcf", "icf", "diffusion_kf",
                    "hcmci", "hcmci_n", "local_only")


def render_consensus(rows: dict[str, Rows]) -> dict[str, str]:
    """docs/consensus.md's results table and docs/estimators.md's summary of it."""
    s = rows[CONSENSUS.name]
    comps, nx = s.components, len(s.components)
    sc = CONSENSUS.load()
    K = int(sc.steps)
    lo, hi = nees_band(s.runs, nx)
    head = ("| estimate | " + " | ".join(f"MSE {c} (95% CI)" for c in comps)
            + " | ANEES (95% CI over runs) | consistent | messages/tick | late (per run) |")
    lines = ["```", CONSENSUS.command("out/case1_dt4"), "```", "",
             f"{s.runs} runs, {K} ticks, burn-in {K // 10}, d_t = 4", "", head,
             "|" + "---|" * (len(comps) + 5)]
    for name in s.estimates:
        msgs = s.mean(name, "messages_per_tick")
        lines.append(f"| {name} | " + " | ".join(interval(s.col(name, "mse", c)) for c in comps)
                     + f" | {interval(s.col(name, 'anees'), '#.4g')} | {s.consistent(name)} | {g4(msgs)} | "
                     f"{g4(s.mean(name, 'late'))} |")
    lines += ["", para("MSE after the burn-in (95 % t-intervals over runs); ANEES with the 95 % "
                       "t-interval over runs of the per-run time averages, consistent when it covers "
                       f"nx = 3 ([statistics.md](statistics.md); the per-tick chi-square band of {s.runs} "
                       f"runs, [{lo:.2f}, {hi:.2f}], is for the mean NEES at one tick).")]
    consensus = "\n".join(lines)

    est = ["| estimate | MSE pos | MSE vel | MSE acc | ANEES [95 % CI over runs] | consistent "
           f"(CI covers {nx}) | messages/tick |", "|---|---|---|---|---|---|---|"]
    for name in ESTIMATORS_ORDER:
        msgs = s.mean(name, "messages_per_tick")
        est.append(f"| {LABELS.get(name, f'`{name}`')} | "
                   + " | ".join(g4(s.mean(name, "mse", c)) for c in comps)
                   + f" | {interval(s.col(name, 'anees'), '#.4g')} | {s.consistent(name)} | "
                   + ("—" if math.isnan(msgs) else f"{msgs:.3g}") + " |")
    r, rlo, rhi = s.ratio("fused", "centralized", "position")
    est += ["", para(f"The MSE of `fused` (position) is {r:.3f} [{rlo:.3f}, {rhi:.3f}] times the "
                     f"centralized filter's, paired over the same {s.runs} runs; the per-tick "
                     f"chi-square band is [{lo:.2f}, {hi:.2f}] for {s.runs} runs.")]

    late = [s.mean(n, "late") / (s.mean(n, "messages_per_tick") * K) for n in ONE_SLOT]
    worse = [s.mean(n, "mse", "position") / s.mean("fused", "mse", "position")
             for n in ("ci_consensus", "kcf", "icf", "diffusion_kf", "hcmci", "hcmci_n")]
    above = s.mean("fused", "mse", "position") / s.mean("centralized", "mse", "position")
    headline = (f"On paper case 1 at `d_t = 4` ({s.runs} Monte Carlo runs × {K} ticks, every "
                f"estimator on the same draws) {span(late, lambda v: f'{100 * v:.0f}')} % of the "
                "one-tick consensus messages arrive after their tick, and the textbook filters, "
                f"built for networks without delay, have {span(worse, lambda v: f'{v:.0f}')} times the "
                f"fused anti-delay DKF's position MSE, which is {pct_above(above)} % above the "
                "centralized filter's.")
    return {"consensus-table": consensus, "estimators-table": "\n".join(est),
            "consensus-headline": para(headline), **render_statistics(s)}


def minus(v: float, spec: str) -> str:
    return f"{v:{spec}}".replace("-", "−")


def welch_half(a: np.ndarray, b: np.ndarray) -> float:
    """Half-width of the 95 % Welch interval of mean(a) - mean(b), the runs taken as unpaired."""
    va, vb = a.var(ddof=1) / a.size, b.var(ddof=1) / b.size
    df = (va + vb) ** 2 / (va ** 2 / (a.size - 1) + vb ** 2 / (b.size - 1))
    return float(student_t.ppf(0.975, df) * math.sqrt(va + vb))


def render_statistics(s: Rows) -> dict[str, str]:
    """docs/statistics.md: the paired table of fused and no_buffer against centralized."""
    comps = s.components
    lines = [f"| paired over {s.runs} runs | " + " | ".join(comps) + " |", "|---" * (len(comps) + 1) + "|"]
    pairs = (("fused", "centralized"), ("no_buffer", "centralized"), ("fused", "no_buffer"))
    blocks = {pair: paired_block(s.rows, *pair, comps) for pair in pairs}
    for (a, b), p in blocks.items():
        for kind, sign, spec in (("diff", "−", ".4g"), ("ratio", "/", ".4f")):
            cells = [f"{minus(p[f'mse_{kind}'][c], spec)} [{minus(p[f'mse_{kind}_ci95'][c][0], spec)}, "
                     f"{minus(p[f'mse_{kind}_ci95'][c][1], spec)}]" for c in comps]
            lines.append(f"| `{a}` {sign} `{b}` | " + " | ".join(cells) + " |")
    above = [blocks[("fused", "centralized")]["mse_ratio"][c] for c in comps]
    below = [1 - blocks[("fused", "no_buffer")]["mse_ratio"][c] for c in comps]
    outside = all(lo > 0 or hi < 0 for p in blocks.values() for lo, hi in p["mse_diff_ci95"].values())
    f, c0 = s.col("fused", "mse", comps[0]), s.col("centralized", "mse", comps[0])
    _, flo, fhi = t_interval(f)
    _, clo, chi = t_interval(c0)
    wider = []
    for c in comps:
        lo, hi = blocks[("fused", "centralized")]["mse_diff_ci95"][c]
        wider.append(welch_half(s.col("fused", "mse", c), s.col("centralized", "mse", c)) / ((hi - lo) / 2))
    plo, phi = blocks[("fused", "centralized")]["mse_diff_ci95"][comps[0]]
    overlap = "overlap" if flo <= chi and clo <= fhi else "do not overlap"
    reading = (f"The anti-delay DKF is {span(above, pct_above)} % above the centralized filter and "
               f"{span(below, lambda v: sig2(100 * v))} % below the same DKF without its buffer "
               f"(`no_buffer`, L = 1){', each difference far outside its interval' if outside else ''}. "
               f"Unpaired, the two MSE intervals of `fused` and `centralized` {overlap} "
               f"([{flo:.4g}, {fhi:.4g}] and [{clo:.4g}, {chi:.4g}] for {comps[0]}) and the Welch "
               f"interval of the difference is {span(wider, lambda v: f'{v:.0f}')} times wider than the "
               f"paired one ({comps[0]}: half-width "
               f"{welch_half(f, c0):.2g} against {(phi - plo) / 2:.2g}); `tests/test_statistics.py` "
               "recomputes every paired number from `runs.csv` with `scipy.stats` and checks it is "
               "narrower than Welch's.")
    return {"statistics-paired": "\n".join(lines), "statistics-reading": para(reading)}


# --------------------------------------------------------------------------- the delay-bound sweep
SWEEP_FILE = "scenarios/sweep_algorithms.yaml"


def grid_studies(file: str, name_of, columns: tuple[str, ...] = COLUMNS) -> tuple[Study, ...]:
    """One study per grid value of the one-key sweep ``file`` (a sweep's run r of a grid point
    uses ``derive_seed(seed, r)``, as a Monte Carlo of that point does), named ``name_of(value)``."""
    spec = yaml.safe_load((ROOT / file).read_text())
    (key, values), = spec["grid"].items()
    scenario = str((Path(file).parent / spec["scenario"]).as_posix())
    return tuple(Study(name_of(v), scenario, (*spec.get("set", []), f"{key}={v}"), int(spec["runs"]), columns)
                 for v in values)


def sweep_studies() -> tuple[Study, ...]:
    """One study per grid value of ``scenarios/sweep_algorithms.yaml``."""
    return grid_studies(SWEEP_FILE, lambda v: f"sweep_algorithms_d{v}")


SWEEP = sweep_studies()
CONSENSUS_FAMILY = ("ci_consensus", "kcf", "icf", "diffusion_kf", "hcmci", "hcmci_n")


def render_sweep(rows: dict[str, Rows]) -> dict[str, str]:
    """docs/consensus.md's sweep table and docs/figures.md's reading of its figures."""
    points = [rows[s.name] for s in SWEEP]
    bounds = [s.overrides[-1].split("=")[1] for s in SWEEP]
    first, last = points[0], points[-1]
    lines = ["```", f".venv/bin/dkfsim sweep {SWEEP_FILE} --jobs 2 --export out/algorithms.csv", "```", "",
             f"Position MSE (mean ± 95 % half-width over {first.runs} runs of "
             f"{SWEEP[0].load().steps} ticks); [messages/tick]", "",
             "| estimate | " + " | ".join(f"d_t={b}" for b in bounds) + " |",
             "|---" * (len(bounds) + 1) + "|"]
    for name in first.estimates:
        if name in ("local", "local_only"):
            continue
        cells = []
        for r in points:
            mean, lo, hi = t_interval(r.col(name, "mse", "position"))
            msgs = r.mean(name, "messages_per_tick")
            cells.append(f"{mean:.3g} ± {(hi - lo) / 2:.2g}" + ("" if math.isnan(msgs) else f" [{msgs:.0f}]"))
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    pos = lambda r, n: r.mean(n, "mse", "position")  # noqa: E731
    same = np.allclose(first.col("fused", "mse", "position"), first.col("centralized", "mse", "position"),
                       rtol=1e-9, atol=0)
    growth = [pos(last, n) / pos(first, n) for n in CONSENSUS_FAMILY if n != "hcmci_n"]
    above0 = [pos(first, n) / pos(first, "centralized") for n in CONSENSUS_FAMILY]
    one_slot = {first.mean(n, "messages_per_tick") for n in CONSENSUS_FAMILY if n != "diffusion_kf"}
    arrows = ", ".join(f"`{n}` {pos(first, n):.3g} → {pos(last, n):.3g}"
                       for n in sorted(CONSENSUS_FAMILY[:-1], key=lambda n: pos(last, n)))
    reading = (
        f"How to read them: at `d_t = {bounds[0]}` the fused anti-delay DKF "
        f"{'equals' if same else 'is close to'} the centralized filter (position MSE "
        f"{pos(first, 'fused'):.4g} {'for both' if same else 'and ' + format(pos(first, 'centralized'), '.4g')}); "
        f"as the bound grows to {bounds[-1]} ticks its MSE rises by "
        f"{pct_above(pos(last, 'fused') / pos(first, 'fused'))} % ({pos(last, 'fused'):.4g}) while every "
        f"consensus filter's grows {min(growth):.1f}- to {max(growth):.1f}-fold — {arrows} — because "
        "their messages must arrive within the tick they belong to. Even without delay, one round per "
        "tick on case 1's tree (diameter 4) leaves them "
        f"{span(above0, lambda v: f'{v:.2g}')}× above the centralized filter: they spend a fixed "
        f"{', '.join(f'{m:.0f}' for m in sorted(one_slot))} messages per tick "
        f"({first.mean('diffusion_kf', 'messages_per_tick'):.0f} for `diffusion_kf`), the DKF "
        f"{first.mean('fused', 'messages_per_tick'):.0f} at `d_t = {bounds[0]}` falling to "
        f"{last.mean('fused', 'messages_per_tick'):.0f} at `d_t = {bounds[-1]}` as more information "
        "shares each packet.")
    return {"sweep-table": "\n".join(lines), "sweep-reading": para(reading)}


# --------------------------------------------------------------------------- the radar experiment
def radar_rows() -> tuple[dict, object]:
    sys.path.insert(0, str(ROOT / "tools"))
    import radar_experiment
    sc = dkfsim.load_scenario(ROOT / "scenarios" / "radar_experiment.yaml")
    err, _, _ = radar_experiment.monte_carlo(sc, 200)
    return err, radar_experiment.table(err, sc)


def render_radar() -> dict[str, str]:
    """tools/radar_experiment.py --runs 200: its table and the figures page's summary."""
    err, table = radar_rows()
    cm2 = {lab: e.mean(axis=1) * 1e4 for lab, e in err.items()}          # per-run averages, cm²
    fused, cen = cm2["anti-delay DKF (fused)"], cm2["centralized (all data on time)"]
    alone = [v for lab, v in cm2.items() if lab.endswith(" alone")]
    nobuf, ci = cm2["no buffer (L = 1), fused"], cm2["CI consensus (per node, mean)"]
    local = cm2["anti-delay DKF (per node, mean)"]
    best_alone = min(float(np.mean(v)) for v in alone)
    summary = (f"Position MSE over the {err['anti-delay DKF (fused)'].shape[1]} ticks (cm², 95 % "
               f"interval over {len(fused)} runs): fused anti-delay DKF {interval(fused, '.1f')}, "
               f"centralized {interval(cen, '.1f')}, no buffer {np.mean(nobuf):.1f}, consensus on "
               f"information {np.mean(ci):.1f}, each radar alone "
               f"{min(np.mean(v) for v in alone):.1f}–{max(np.mean(v) for v in alone):.1f}: the fused "
               f"estimate is {best_alone / np.mean(fused):.1f}x better than any single radar.")
    gap = np.mean(fused) - np.mean(cen)
    _, clo, _ = t_interval(fused - cen)
    radars_worse = all(t_interval(a - fused)[1] > 0 for a in alone)
    excl = " The paired intervals exclude zero on both sides." if clo > 0 and radars_worse else ""
    _, blo, bhi = t_interval(nobuf - fused)
    reading = "\n".join(para(b, bullet=True) for b in (
        "**Close to centralized, far better than any single radar.** This is the paper's "
        f"qualitative claim. The fused anti-delay DKF is {gap:.1f} cm² ({100 * gap / np.mean(cen):.0f} %) "
        "above the centralized filter that has every measurement on time. It has "
        f"{best_alone / np.mean(fused):.1f} times less error than any radar's own filter.{excl}",
        "**The buffer's gain is small.** Without the buffer (`no_buffer`, L = 1, same exchange) the "
        f"error grows by {np.mean(nobuf - fused):.1f} cm² [{blo:.1f}, {bhi:.1f}] (paired). With delays "
        "of at most 2 ticks per hop and 21 ticks there is little late information to recover.",
        "**Fusion beats each node's own estimate.** The fused estimate beats the mean of the "
        f"per-node estimates by {np.mean(local - fused):.1f} cm². A node's real-time estimate still "
        "lacks the newest rows of the other radars."))
    return {"radar-table": f"```\n{table}\n```", "radar-summary": para(summary), "radar-reading": reading}


def render_mobility() -> dict[str, str]:
    """tools/mobility_table.py: the shipped mobility scenarios (one run each), the range sweep
    (5 runs x 5 ranges) and the range x speed sweep (2 runs x 9 points), through ``dkfsim
    sweep``: docs/mobility.md."""
    sys.path.insert(0, str(ROOT / "tools"))
    import mobility_table
    return {"mobility-scenarios": mobility_table.scenario_table(), "mobility-range": mobility_table.range_table(),
            "mobility-speed": mobility_table.speed_table()}


# --------------------------------------------------------------------------- the channel sweep
CHANNEL_FILE = "scenarios/sweep_channel.yaml"
#: the channel sweep's estimates, in the table's order (those a run has)
CHANNEL_ESTIMATES = ("fused", "fusion_centre", "centralized", "centralized_delayed", *CONSENSUS_FAMILY[:-1])


def channel_studies() -> tuple[Study, ...]:
    """One study per channel rate of ``scenarios/sweep_channel.yaml``, keeping ``lost``
    (collisions: the scenario loses nothing else in the air) and ``bytes_per_tick`` beside the
    usual columns."""
    return grid_studies(CHANNEL_FILE, lambda v: f"sweep_channel_{float(v):g}", (*COLUMNS, "lost", "bytes_per_tick"))


CHANNEL = channel_studies()


def rate_label(bits: float) -> str:
    return f"{bits / 1e6:g} Mbit/s" if bits >= 1e6 else f"{bits / 1e3:g} kbit/s"


def render_channel(rows: dict[str, Rows]) -> dict[str, str]:
    """docs/channel.md's table: position MSE per channel rate and estimate, and per run the
    collisions and late items of the DKF and the fusion centres."""
    points = [rows[s.name] for s in CHANNEL]
    rates = [float(s.overrides[-1].split("=")[1]) for s in CHANNEL]
    first = points[0]
    K = CHANNEL[0].load().steps
    names = [n for n in CHANNEL_ESTIMATES if n in first.estimates]
    lines = ["```", f".venv/bin/dkfsim sweep {CHANNEL_FILE} --jobs 1 --db out/channel.sqlite", "```", "",
             f"Position MSE, mean and 95 % t-interval over {first.runs} runs of "
             f"{K} ticks per channel rate:", "",
             "| estimate | " + " | ".join(rate_label(r) for r in rates) + " |",
             "|---" * (len(rates) + 1) + "|"]
    for name in names:
        lines.append(f"| `{name}` | " + " | ".join(interval(r.col(name, "mse", "position"), ".3g")
                                                    for r in points) + " |")
    counted = [n for n in ("fused", "fusion_centre", "centralized_delayed", "ci_consensus") if n in names]
    for label, key in (("packets lost in collisions per run", "lost"), ("late items per run", "late"),
                       ("messages per tick", "messages_per_tick")):
        for name in counted:
            lines.append(f"| `{name}`: {label} | " + " | ".join(f"{r.mean(name, key):.4g}" for r in points) + " |")
    pos = lambda r, n: r.mean(n, "mse", "position")  # noqa: E731
    share = lambda r, n: r.mean(n, "lost") / (r.mean(n, "messages_per_tick") * K)  # noqa: E731
    last = points[-1]
    i6 = rates.index(6.0e6) if 6.0e6 in rates else len(rates) - 1
    family = [n for n in CONSENSUS_FAMILY[:-1] if n in names]
    worst = max(family, key=lambda n: pos(first, n))
    near = [r for r, p in zip(rates, points) if all(pos(p, n) <= 1.5 * pos(last, n) for n in family)]
    on_time = [r for r, p in zip(rates, points) if p.mean("centralized_delayed", "late") == 0]
    reading = (
        f"How to read it: the fused anti-delay DKF stays within "
        f"{max(pos(p, 'fused') / pos(p, 'centralized') for p in points):.2f}× of the centralized filter at "
        f"every rate ({pos(first, 'fused'):.3g} at {rate_label(rates[0])}, {pos(last, 'fused'):.3g} at "
        f"{rate_label(rates[-1])}), although the channel loses {100 * share(points[i6], 'fused'):.0f} % of its "
        f"packets to collisions at {rate_label(rates[i6])} (every node flushes at the tick, so up to 12 radios "
        "contend for 16 backoff slots at once): what a collision loses is either carried by a later "
        "message or arrives late, and the fusion uses exactly what each node holds. The consensus filters "
        "must have their messages within the tick they belong to: below a few Mbit/s their frames wait "
        "longer than that, almost nothing is on time, and the nodes without a position sensor drift "
        f"(`{worst}` {pos(first, worst):.3g} at {rate_label(rates[0])}); every one of them is within 1.5× "
        f"of its own error at {rate_label(rates[-1])} only from {rate_label(min(near))} up. `fusion_centre` "
        "fuses at each tick "
        "the newest estimate it has received from every node, which with any propagation delay is the "
        f"tick before's, predicted ({pos(points[i6], 'fusion_centre'):.3g} at {rate_label(rates[i6])}). "
        "`centralized_delayed` likewise holds each measurement a tick after it was taken "
        f"({pos(points[i6], 'centralized_delayed'):.3g} at {rate_label(rates[i6])}); its twelve frames per "
        f"tick reach the centre in time from {rate_label(min(on_time))} up; below that the channel cannot "
        "carry them: they are dropped when a radio's two-frame queue is full, or wait and arrive after "
        "their rows became final (late), and its error grows with them "
        f"({pos(first, 'centralized_delayed'):.3g} at {rate_label(rates[0])}).")
    return {"channel-table": "\n".join(lines), "channel-reading": para(reading)}


# --------------------------------------------------------------------------- the fusion centre
CENTRE = tuple(Study(f"centre_case1_d{d}", "scenarios/paper_case1.yaml",
                     (f"links.default.latency.d_t={d}",
                      "estimators=[{kind: centralized_delayed}, {kind: fusion_centre, at: 0}]"), 10)
               for d in (0, 2, 4))
CENTRE_ORDER = ("fused", "fusion_centre", "centralized_delayed")


def render_centre(rows: dict[str, Rows]) -> dict[str, str]:
    """docs/fusion_centre.md: the fusion centre against ``fused`` and ``centralized_delayed``."""
    first = rows[CENTRE[0].name]
    comps, nx, runs = first.components, len(first.components), first.runs
    K = int(CENTRE[0].load().steps)
    lines = ["```"] + [st.command(f"out/centre_d{st.name[-1]}") for st in CENTRE] + ["```", "",
             f"{runs} runs of {K} ticks per `d_t`, burn-in {K // 10}; MSE per component (mean over runs), "
             "ANEES with its 95 % t-interval over runs", "",
             "| d_t | estimate | " + " | ".join(f"MSE {c}" for c in comps)
             + f" | ANEES [95 % CI] | consistent (covers {nx}) | messages/tick |",
             "|---|---|" + "---|" * (len(comps) + 3)]
    for st in CENTRE:
        s = rows[st.name]
        for name in CENTRE_ORDER:
            msgs = s.mean(name, "messages_per_tick")
            lines.append(f"| {st.name[-1]} | `{name}` | " + " | ".join(g4(s.mean(name, "mse", c)) for c in comps)
                         + f" | {interval(s.col(name, 'anees'), '#.4g')} | {s.consistent(name)} | "
                         + ("—" if math.isnan(msgs) else f"{msgs:.3g}") + " |")
    d0 = rows[CENTRE[0].name]
    same = max(abs(d0.mean("fusion_centre", "mse", c) / d0.mean("fused", "mse", c) - 1) for c in comps)
    worse = [rows[st.name].mean("fusion_centre", "mse", "position") / rows[st.name].mean("fused", "mse", "position")
             for st in CENTRE[1:]]
    reading = ("At `d_t = 0` the centre's MSE is `fused`'s ("
               + ("identical in every run" if same == 0 else f"largest relative difference {same:.1e}")
               + "). With latency the centre fuses estimates that are up to "
               "`d_t` times the hop count ticks old, predicted forward: its position MSE is "
               + " and ".join(f"{w:.2f}" for w in worse) + " times `fused`'s at `d_t = 2` and 4, while "
               "its ANEES stays consistent (it is exact for what it holds). `messages/tick` counts "
               "every hop of a relayed packet.")
    return {"centre-table": "\n".join(lines), "centre-reading": para(reading)}


# --------------------------------------------------------------------------- the buffer's cost
#: Buffer lengths of docs/performance.md's table (paper case 1 needs L = d_t d_g + 1 = 17).
BUFFER_LENGTHS = (5, 9, 17, 33, 65)
BUFFER = tuple(Study(f"buffer_case1_L{L}", "scenarios/paper_case1.yaml",
                     (f"buffer_length={L}", "estimators=[{kind: centralized}]"), 10,
                     (*COLUMNS, "bytes_per_tick"))
               for L in BUFFER_LENGTHS)


def render_buffer(rows: dict[str, Rows]) -> dict[str, str]:
    """docs/performance.md: what a larger buffer costs on paper case 1 (Monte Carlo rows:
    bytes and MSE; the memory the estimate counts exactly; the events of a trial, and the CPU they
    cost at the stored seconds per event -- an estimate, never a timing)."""
    from dkfsim.config.plan import RunPlan
    from dkfsim.core.resources import event_seconds
    from dkfsim.engine.driver import trial_events
    from dkfsim.engine.estimate import estimate_run
    head = ("| L | bytes per tick (DKF) | node-rows re-run per tick | CPU per 1000 ticks (estimated) "
            "| memory of a run | fused position MSE | fused / centralized |")
    lines = [head, "|---:|---:|---:|---:|---:|---:|---:|"]
    for study, L in zip(BUFFER, BUFFER_LENGTHS):
        r = rows[study.name]
        plan = RunPlan(study.load(), "estimates")
        events, _ = trial_events(plan)
        K, N = int(plan.scenario.steps), plan.scenario.n * plan.scenario.nx
        cpu = event_seconds(events, N) * 1000 / K
        memory = estimate_run(plan).bytes / 2**20
        ratio, lo, hi = r.ratio("fused", "centralized", r.components[0])
        lines.append(f"| {L}{' (auto)' if L == 17 else ''} | {r.mean('fused', 'bytes_per_tick'):.0f} | "
                     f"{events['node_rows'] / K:.0f} | {cpu:.2f} s | {memory:.2f} MiB | "
                     f"{g4(r.mean('fused', 'mse'))} | {ratio:.3f} [{lo:.3f}, {hi:.3f}] |")
    mse = {L: rows[st.name].mean("fused", "mse") for st, L in zip(BUFFER, BUFFER_LENGTHS)}
    bytes_ = {L: rows[st.name].mean("fused", "bytes_per_tick") for st, L in zip(BUFFER, BUFFER_LENGTHS)}
    lo_L, top_L = BUFFER_LENGTHS[0], BUFFER_LENGTHS[-1]
    reading = (f"Below the bound a short buffer drops what arrives late and sends less: L = {lo_L} carries "
               f"{bytes_[lo_L] / bytes_[17]:.2f} times the bytes of L = 17 and has "
               f"{mse[lo_L] / mse[17]:.3f} times its fused position MSE (here the late rows matter little: "
               "the paired ratio to the centralized filter barely moves). Above the bound nothing older "
               f"arrives, so the bytes and the rows re-run stay as at 17 (L = {top_L}: "
               f"{bytes_[top_L] / bytes_[17]:.2f} and {mse[top_L] / mse[17]:.3f} times); only the memory "
               "of the window grows with L.")
    return {"buffer-table": "\n".join(lines), "buffer-reading": para(reading)}


# --------------------------------------------------------------------------- the radio's highway
HIGHWAY_FILE = "scenarios/sweep_highway.yaml"
#: the columns of a highway run's rows: the usual, then each estimator's copy of the radio -- the
#: mean CBR of the group's vehicles (the nodes), and the PDR of its (frame, receiver) pairs within
#: 300 m, background included (NaN without a radio copy)
RADIO_COLUMNS = (*COLUMNS, "cbr", "pdr_300")
#: the highway sweep's estimates, in the table's order
HIGHWAY_ESTIMATES = ("fused", "fusion_centre", "centralized", *CONSENSUS_FAMILY[:-1])


#: the further columns a study of the sidelink keeps (:func:`radio_rows`): the PDR within 100 m,
#: and the estimator's own packets (per link: ``sent``, ``delivered``, ``queue_dropped`` -- refused
#: by a full waiting room, or on the sidelink too big or past its budget --, ``lost_parts``: the
#: port's ``lost``, in the air)
#: and frames (``frames`` that went on the air, ``frames_dropped``, ``access_delay`` in seconds)
TRAFFIC_COLUMNS = ("pdr_100", "sent", "delivered", "queue_dropped", "lost_parts", "frames", "frames_dropped",
                   "access_delay")


def pdr_within(block: dict, causes: Iterable[str], metres: float) -> float:
    """The PDR of the (frame, receiver) pairs of a ``pdr_by_distance`` block in the bins that end
    within ``metres`` (NaN without a pair); ``causes``: the radio's causes of loss."""
    near = [i for i, edge in enumerate(block["bins_m"][1:]) if edge <= metres]
    frames = sum(block["frames"][i] for i in near)
    lost = sum(block[c][i] for c in causes for i in near)
    return (frames - lost) / frames if frames else math.nan


def radio_rows(scenario: str, overrides: tuple[str, ...], r: int,
               columns: tuple[str, ...] = RADIO_COLUMNS) -> list[dict]:
    """Run ``r`` of a radio study (run r's seed, as a Monte Carlo's): its tidy rows with the
    radio's numbers of each estimator's copy of the channel (``columns``: :data:`RADIO_COLUMNS`,
    and any of :data:`TRAFFIC_COLUMNS`; NaN for an estimator without a copy)."""
    from dkfsim.engine.driver import Run
    sc = dkfsim.load_scenario(ROOT / scenario, overrides=list(overrides))
    tpl = Template(sc)
    run_sc = tpl.scenario_for(derive_seed(sc.seed, r))
    burn = max(1, int(run_sc.steps) // 10)
    with np.errstate(all="ignore"):
        res = Run(run_sc, save="summary", system=tpl.system, plan=tpl.plan_for(run_sc)).run()
        rows = res.rows(burn, res.scored(burn))
    out = []
    for row in rows:
        traffic = res.traffic.get(row["estimate"]) or {}
        ch = traffic.get("channel") or {}
        block = ch.get("pdr_by_distance")
        got = dict.fromkeys(("cbr", "pdr_300", *TRAFFIC_COLUMNS), math.nan)
        if block is not None:
            causes = list(ch["losses"])                      # (the radio's own: edca's or the sidelink's)
            group = ch["cbr"][:len(run_sc.sensors)]          # (the channel's first members are the nodes)
            got.update(cbr=float(np.mean(group)), pdr_300=pdr_within(block, causes, 300.0),
                       pdr_100=pdr_within(block, causes, 100.0))
        if ch:
            got.update(sent=traffic["sent"], delivered=traffic["delivered"], queue_dropped=traffic["queue_dropped"],
                       lost_parts=traffic["lost"], frames=ch["frames"], frames_dropped=ch["frames_dropped"],
                       access_delay=ch["access_delay_mean"])
        out.append({**{c: row[c] for c in COLUMNS if c != "run"}, "run": r,
                    **{c: float(got[c]) for c in columns if c not in COLUMNS}})
    return out


def _radio_job(args: tuple) -> list[dict]:
    return radio_rows(*args)


@dataclass(frozen=True)
class RadioStudy(Study):
    """A study of runs on a spatial radio: each run's rows keep its copies' CBR and PDR
    (:func:`radio_rows`); ``spot_runs``: the runs the slow tier recomputes."""

    spot_runs: tuple[int, ...] = (0,)

    def compute(self, jobs: int) -> list[dict]:
        from concurrent.futures import ProcessPoolExecutor
        args = [(self.scenario, self.overrides, r, self.columns) for r in range(self.runs)]
        with ProcessPoolExecutor(max_workers=max(1, jobs)) as pool:
            return [row for rows in pool.map(_radio_job, args) for row in rows]

    def spot(self, runs: Iterable[int] = SPOT_RUNS) -> list[dict]:
        return [row for r in runs for row in radio_rows(self.scenario, self.overrides, r, self.columns)]


def highway_studies() -> tuple[RadioStudy, ...]:
    """One study per density of ``scenarios/sweep_highway.yaml``; the slow tier spot-checks run 0
    of the lightest (a full-density run costs about 17 s)."""
    studies = grid_studies(HIGHWAY_FILE, lambda v: f"sweep_highway_{float(v):g}", RADIO_COLUMNS)
    return tuple(RadioStudy(s.name, s.scenario, s.overrides, s.runs, s.columns, (0,) if i == 0 else ())
                 for i, s in enumerate(studies))


HIGHWAY = highway_studies()


def highway_per_km() -> float:
    """Vehicles per km on the shipped highway's SUMO run, both directions (scenarios/data/highway.json)."""
    meta = json.loads((ROOT / "scenarios" / "data" / "highway.json").read_text())
    dense = meta["files"]["highway_dense.fcd.xml"]["density_veh_per_km_per_direction"]
    return dense["eastbound"]["mean"] + dense["westbound"]["mean"]


def render_radio(rows: dict[str, Rows]) -> dict[str, str]:
    """docs/radio.md's highway table: per density, each estimate's position MSE and each copy's
    PDR within 300 m and CBR (means over the runs, 95 % intervals for the DKF)."""
    spec = yaml.safe_load((ROOT / HIGHWAY_FILE).read_text())
    per_km = highway_per_km()
    points = [(s, rows[s.name]) for s in HIGHWAY]
    first = points[0][1]
    names = [e for e in HIGHWAY_ESTIMATES if e in first.estimates]
    K = int(spec["set"][0].split("=")[1])
    head = ["share of the traffic", "vehicles per km", *(f"MSE {e}" for e in names), "PDR ≤ 300 m (DKF)",
            "group's CBR (DKF)", "PDR ≤ 300 m (ci_consensus)", "group's CBR (ci_consensus)"]
    lines = ["```", f".venv/bin/dkfsim sweep {HIGHWAY_FILE} --jobs 2 --db out/highway.sqlite", "```", "",
             f"{first.runs} runs of {K} ticks per density; position MSE after the burn-in (mean over the runs; the "
             "DKF's with its 95 % interval); each estimator's copy of the radio (the same traffic in each, its "
             "own frames besides): the PDR of every (frame, receiver) pair within 300 m and the mean CBR of the "
             "twelve vehicles of the group:", "",
             "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for study, r in points:
        share = float(study.overrides[-1].split("=")[1])
        cells = [f"{share:g}", f"{share * per_km:.0f}", interval(r.col("fused", "mse"))]
        cells += [g4(r.mean(e, "mse")) for e in names[1:]]
        cells += [f"{r.mean('fused', 'pdr_300'):.3f}", f"{r.mean('fused', 'cbr'):.3f}",
                  f"{r.mean('ci_consensus', 'pdr_300'):.3f}", f"{r.mean('ci_consensus', 'cbr'):.3f}"]
        lines.append("| " + " | ".join(cells) + " |")
    rs = [r for _, r in points]
    dkf_cbr = [r.mean("fused", "cbr") for r in rs]
    ci_cbr = [r.mean("ci_consensus", "cbr") for r in rs]
    dkf_pdr = [r.mean("fused", "pdr_300") for r in rs]
    grow = [r.mean(e, "mse") for r in (rs[0], rs[-1]) for e in ("fused", "ci_consensus")]
    reading = (f"From a quarter of the traffic to all of it, the fused DKF's position MSE moves from "
               f"{g4(grow[0])} to {g4(grow[2])} while ci_consensus's grows from {g4(grow[1])} to {g4(grow[3])}. "
               f"The radio shows what the DKF's buffer absorbs: its own traffic (twelve nodes flushing every "
               f"10 ms) keeps the group's channel {min(dkf_cbr):.0%}–{max(dkf_cbr):.0%} busy at every density "
               f"(ci_consensus's traffic: {min(ci_cbr):.0%}–{max(ci_cbr):.0%}), and only "
               f"{min(dkf_pdr):.0%}–{max(dkf_pdr):.0%} of the pairs within 300 m are received on its copy. "
               "Issue 33 asks whether C-V2X carries it better.")
    return {"radio-highway": "\n".join(lines), "radio-highway-reading": para(reading)}


def draw_radio_figure(path: Path) -> Path:
    """docs/figures/radio_highway.png from the highway study's stored rows (what docs/radio.md's
    table quotes): each estimate's position MSE against the density, and each copy's PDR within
    300 m and the group's CBR.  Written by ``--only radio`` (never by the tests)."""
    from dkfsim.core.extras import pyplot
    from dkfsim.report.plots.style import color_of, label_of, legend_below, save_figure
    plt = pyplot()
    per_km = highway_per_km()
    points = [(float(s.overrides[-1].split("=")[1]) * per_km, Rows(read_rows(s.path))) for s in HIGHWAY]
    x = [p for p, _ in points]
    fig, (left, right) = plt.subplots(1, 2, figsize=(11, 4.6))
    for e in HIGHWAY_ESTIMATES:
        if e in points[0][1].estimates:
            left.plot(x, [r.mean(e, "mse") for _, r in points], "o-", color=color_of(e, HIGHWAY_ESTIMATES),
                      label=label_of(e), ms=4)
    left.set_yscale("log")
    left.set_xlabel("vehicles per km (both directions)")
    left.set_ylabel("position MSE (mean over runs)")
    left.set_title("the estimates against the traffic density", fontsize=10)
    left.grid(alpha=0.3, which="both")
    for e, style in (("fused", "-"), ("ci_consensus", "--")):
        right.plot(x, [r.mean(e, "pdr_300") for _, r in points], "o" + style, color="k", ms=4,
                   label=f"PDR within 300 m, {label_of(e)}'s copy")
        right.plot(x, [r.mean(e, "cbr") for _, r in points], "s" + style, color="#e6550d", ms=4,
                   label=f"group's CBR, {label_of(e)}'s copy")
    right.set_ylim(0, 1)
    right.set_xlabel("vehicles per km (both directions)")
    right.set_title("the radio around the group (each estimator's copy)", fontsize=10)
    right.grid(alpha=0.3)
    legend_below(fig, [left, right], ncol=3)
    return save_figure(fig, path, ("png",))[0]


# --------------------------------------------------------------------------- the C-V2X sidelink
#: issue 33's study: one sweep file per DKF tick (a grid is a cartesian product, and ``steps``
#: follows ``model.T`` to keep the simulated time), each over the radio and the density
SIDELINK_FILES = (*(f"scenarios/sweep_sidelink_{ms}ms.yaml" for ms in (10, 20, 100)),
                  "scenarios/sweep_sidelink_20ms_tuned.yaml")
#: the keys that make a sidelink study the tuned one (its own file: ``sps_tuned`` in the table)
SIDELINK_TUNED = ("medium.access.rri", "medium.access.misfit", "medium.access.budget")
SIDELINK_COLUMNS = (*RADIO_COLUMNS, *TRAFFIC_COLUMNS)
#: the points whose run 0 the slow tier recomputes: the sidelink at the lighter density, at the
#: shortest and the longest tick (about 5 and 3 s each)
SIDELINK_SPOT = (("sps", 0.25, 0.01), ("sps", 0.25, 0.1))
#: the radios in the table's order, and what the table calls them
SIDELINK_RADIOS = {"edca": "802.11p (`edca`)", "sps": "C-V2X (`sps`)",
                   "sps_tuned": "C-V2X tuned (`sps`, `rri` 20 ms, `misfit: one_shot`, `budget` 20 ms)"}


def setting(study: Study, key: str) -> str:
    """The value a study's overrides give ``key`` (the last one that sets it), as written."""
    return next(o.partition("=")[2] for o in reversed(study.overrides) if o.partition("=")[0] == key)


def sidelink_point(study: Study) -> tuple[str, float, float]:
    """(radio, share of the traffic, tick in seconds) of one sidelink study (the radio ``sps_tuned``
    when it sets any of :data:`SIDELINK_TUNED`)."""
    tuned = any(o.partition("=")[0] in SIDELINK_TUNED for o in study.overrides)
    return (setting(study, "medium.access.kind") + ("_tuned" if tuned else ""),
            float(setting(study, "medium.bystanders.sumo_fcd.fraction")), float(setting(study, "model.T")))


def sidelink_studies() -> tuple[RadioStudy, ...]:
    """One study per point of each ``scenarios/sweep_sidelink_*ms.yaml`` (every combination of
    its grid, in the sweep's order; its overrides as the sweep writes them: ``set``, then the grid
    values), named ``sidelink_<tick>_<radio>_<share>``."""
    import itertools
    out = []
    for file in SIDELINK_FILES:
        spec = yaml.safe_load((ROOT / file).read_text())
        scenario = str((Path(file).parent / spec["scenario"]).as_posix())
        keys = list(spec["grid"])
        for values in itertools.product(*spec["grid"].values()):
            cells = dict(zip(keys, values))
            study = RadioStudy("", scenario, (*spec.get("set", []), *(f"{k}={v}" for k, v in cells.items())),
                               int(spec["runs"]), SIDELINK_COLUMNS)
            radio, share, tick = sidelink_point(study)
            study = RadioStudy(f"sidelink_{1000 * tick:g}ms_{radio}_{share:g}", scenario, study.overrides,
                               study.runs, SIDELINK_COLUMNS)
            spot = (0,) if sidelink_point(study) in SIDELINK_SPOT else ()
            out.append(RadioStudy(study.name, scenario, study.overrides, study.runs, SIDELINK_COLUMNS, spot))
    return tuple(out)


SIDELINK = sidelink_studies()


def sidelink_points(rows: dict[str, Rows]) -> list[tuple[str, float, float, Rows]]:
    """(radio, share, tick, rows) of every sidelink study, in the table's order: radio, share, tick."""
    pts = [(*sidelink_point(s), rows[s.name]) for s in SIDELINK]
    order = list(SIDELINK_RADIOS)
    return sorted(pts, key=lambda p: (order.index(p[0]), p[1], p[2]))


def share_of(r: Rows, estimate: str, key: str) -> float:
    """The share of ``estimate``'s packets (per link, summed over the runs) counted in ``key``."""
    return r.mean(estimate, key) / r.mean(estimate, "sent")


def best_consensus(r: Rows) -> tuple[str, float]:
    """The consensus filter with the lowest mean position MSE, and that MSE."""
    name = min((e for e in CONSENSUS_FAMILY[:-1] if e in r.estimates), key=lambda e: r.mean(e, "mse"))
    return name, r.mean(name, "mse")


def render_sidelink(rows: dict[str, Rows]) -> dict[str, str]:
    """docs/radio.md's C-V2X table: per radio, density and DKF tick, the position MSE of the
    fused DKF (95 % interval), the fusion centre, the centralized filter and the best of the
    consensus family; the DKF's packets delivered and refused before the air, its frames' access
    delay; the PDR within 100 m and the group's CBR on the DKF's copy of the radio."""
    per_km = highway_per_km()
    pts = sidelink_points(rows)
    first = pts[0][3]
    steps = {p[2]: int(setting(s, "steps")) for s, p in zip(SIDELINK, map(sidelink_point, SIDELINK))}
    seconds = {round(T * k, 9) for T, k in steps.items()}
    (duration,) = seconds
    medium = next(s for s in SIDELINK if sidelink_point(s)[0] == "sps").load().medium
    tuned = next(s for s in SIDELINK if sidelink_point(s)[0] == "sps_tuned").load().medium
    head = ["radio", "share of the traffic (vehicles per km)", "tick", "MSE fused", "MSE fusion_centre",
            "MSE centralized", "best consensus: MSE (filter)", "DKF packets delivered", "DKF packets refused",
            "DKF access delay", "PDR ≤ 100 m", "group's CBR"]
    lines = ["```", *(f".venv/bin/dkfsim sweep {f} --jobs 2 --db out/{Path(f).stem.removeprefix('sweep_')}.sqlite"
                      for f in SIDELINK_FILES), "```", "",
             f"{first.runs} runs of {duration:g} s per point ({', '.join(f'{k} ticks of {T * 1000:g} ms' for T, k in steps.items())}); "
             "position MSE after the burn-in (10 % of the ticks; mean over the runs, the DKF's with its 95 % "
             "interval); the best consensus filter is the one of "
             f"{', '.join(f'`{e}`' for e in CONSENSUS_FAMILY[:-1])} with the lowest mean. The DKF's packets "
             "(one per link and message; the fusion centre's relayed packets share its radios and are not "
             "counted here) delivered, and refused before the air (a full waiting room of "
             f"{medium.queue.packets} packets; on the sidelink also a packet past its {1000 * medium.access.budget:g} ms "
             f"budget, {1000 * tuned.access.budget:g} ms tuned); the mean access delay of its frames (hand-over "
             "to the start of transmission); on the DKF's copy of the radio, the PDR of every (frame, "
             "receiver) pair within 100 m, background included, and the mean CBR of the twelve vehicles "
             "of the group (802.11p: the share of time they sense the medium busy; the sidelink: the share "
             f"of sub-channels whose power reaches {minus(medium.access.cbr_threshold, 'g')} dBm):", "",
             "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for radio, share, T, r in pts:
        name, best = best_consensus(r)
        cells = [SIDELINK_RADIOS[radio], f"{share:g} ({share * per_km:.0f})", f"{T * 1000:g} ms",
                 interval(r.col("fused", "mse")), g4(r.mean("fusion_centre", "mse")), g4(r.mean("centralized", "mse")),
                 f"{g4(best)} ({name})", f"{share_of(r, 'fused', 'delivered'):.0%}",
                 f"{share_of(r, 'fused', 'queue_dropped'):.0%}", f"{1000 * r.mean('fused', 'access_delay'):.1f} ms",
                 f"{r.mean('fused', 'pdr_100'):.3f}", f"{r.mean('fused', 'cbr'):.3f}"]
        lines.append("| " + " | ".join(cells) + " |")
    return {"sidelink-table": "\n".join(lines),
            "sidelink-reading": para(sidelink_reading(pts) + " " + sidelink_tuned_reading(pts))}


NUMBER_WORDS = {2: "two", 3: "three", 4: "four"}


def listed(items: list[str]) -> str:
    """``a``, ``a and b``, ``a, b and c``."""
    return items[0] if len(items) == 1 else ", ".join(items[:-1]) + " and " + items[-1]


def sidelink_reading(pts: list[tuple[str, float, float, Rows]]) -> str:
    """The answer to issue 33 from the stored rows: per tick, what the sidelink refuses of the
    DKF's packets and how long its frames wait, against 802.11p, and what that does to the fused
    DKF and to the consensus family (each comparison worded from the numbers it quotes)."""
    ticks = sorted({p[2] for p in pts})
    at = lambda radio, T: [r for rad, _, t, r in pts if rad == radio and t == T]  # noqa: E731
    pct = lambda v: f"{100 * v:.0f}"  # noqa: E731
    ms = lambda T: f"{1000 * T:g} ms"  # noqa: E731
    radios = ["edca", "sps"]
    pts = [p for p in pts if p[0] in radios]
    per_tick = lambda f: {(radio, T): [f(r) for r in at(radio, T)] for radio in radios for T in ticks}  # noqa: E731
    every = lambda f: {radio: [f(r) for T in ticks for r in at(radio, T)] for radio in radios}  # noqa: E731
    refused = per_tick(lambda r: share_of(r, "fused", "queue_dropped"))
    n = len(SIDELINK[0].load().sensors)
    seconds = {T: T * int(setting(next(s for s in SIDELINK if sidelink_point(s)[2] == T), "steps")) for T in ticks}
    on_air = {radio: [r.mean("fused", "frames") / (n * seconds[T]) for T in ticks for r in at(radio, T)]
              for radio in radios}
    handed = {radio: [(r.mean("fused", "frames") + r.mean("fused", "frames_dropped")) / (n * seconds[T])
                      for T in ticks for r in at(radio, T)] for radio in radios}
    delay = every(lambda r: 1000 * r.mean("fused", "access_delay"))
    pdr = every(lambda r: r.mean("fused", "pdr_100"))
    ratio = per_tick(lambda r: r.mean("fused", "mse") / r.mean("centralized", "mse"))
    best = per_tick(lambda r: best_consensus(r)[1])
    late = {T: [r.mean("fused", "late") for r in at("sps", T)] for T in ticks}
    fits = [T for T in ticks if max(refused[("sps", T)]) <= max(refused[("edca", T)])]
    flat = all(max(refused[("sps", T)]) - min(refused[("sps", T)]) < 0.05 for T in ticks)
    sps = next(s for s in SIDELINK if sidelink_point(s)[0] == "sps").load()
    d_t = sps.links.d_t
    waits = per_tick(lambda r: r.mean("fused", "access_delay"))
    late_ticks = [T for T in ticks if min(late[T]) > 0 and min(waits[("sps", T)]) > d_t * T]
    worse = [T for T in ticks if min(best[("sps", T)]) > 2 * max(best[("edca", T)])]
    same = [T for T in ticks if T not in worse]
    sps_edca = lambda d, f, T: f"{span(d[('sps', T)], f)} against {span(d[('edca', T)], f)}"  # noqa: E731
    two = lambda v: f"{v:.2f}"  # noqa: E731
    verdict = (f"at none of the {NUMBER_WORDS.get(len(ticks), len(ticks))} ticks does it carry the DKF's traffic as 802.11p does"
               if not fits else f"it carries the DKF's traffic as 802.11p does at {listed([ms(T) for T in fits])}")
    text = (
        f"On the sidelink with its defaults (a reservation every {1000 * sps.medium.access.rri:g} ms, a "
        f"{1000 * sps.medium.access.budget:g} ms budget), {verdict}: it refuses "
        + listed([f"{span(refused[('sps', T)], pct)} %" + (" of the DKF's packets" if i == 0 else "") + f" at {ms(T)}"
                  for i, T in enumerate(ticks)])
        + " (802.11p: " + listed([f"{span(refused[('edca', T)], pct)} %" for T in ticks]) + ")"
        + (", whatever the density" if flat else "")
        + f", and its frames wait {span(delay['sps'], lambda v: f'{v:.0f}')} ms for their subframe "
        f"({span(delay['edca'], lambda v: f'{v:.1f}')} ms on 802.11p). Each of the twelve vehicles puts "
        f"{span(on_air['sps'], lambda v: f'{v:.0f}')} of the DKF's frames per second on the air "
        f"(802.11p: {span(on_air['edca'], lambda v: f'{v:.0f}')}) while its DKF hands over "
        f"{span(handed['sps'], lambda v: f'{v:.0f}')} (802.11p: {span(handed['edca'], lambda v: f'{v:.0f}')}): "
        "a frame at every tick and another whenever a packet brings it something new, into a waiting room "
        f"of {sps.medium.queue.packets} packets that its beacons and the fusion centre's relays share. "
        + (f"What goes on the air (background included) is received more often: PDR within 100 m "
           f"{span(pdr['sps'], two)} against "
           f"{span(pdr['edca'], two)}. " if min(pdr["sps"]) > max(pdr["edca"]) else
           f"PDR within 100 m: {span(pdr['sps'], two)} against {span(pdr['edca'], two)}. ")
        + "What it costs: the fused DKF's position MSE is "
        + listed([f"{span(ratio[('sps', T)], two)}" + (" times the centralized filter's" if i == 0 else "")
                  + f" at {ms(T)}" for i, T in enumerate(ticks)])
        + " (802.11p: " + listed([span(ratio[("edca", T)], two) for T in ticks]) + ")"
        + (f"; at {listed([ms(T) for T in late_ticks])} the wait exceeds the d_t = {d_t} ticks per hop its buffer is "
           "sized for, and " + listed([span(late[T], lambda v: f"{v:.0f}") for T in late_ticks])
           + " rows per run arrive late" if late_ticks else "")
        + ". The consensus family, whose messages must arrive within their tick, ")
    parts = []
    if worse:
        parts.append(f"has more than twice 802.11p's error at {listed([ms(T) for T in worse])} (its best filter "
                     + listed([sps_edca(best, g4, T) for T in worse]) + ")")
    if same:
        parts.append(f"is within a factor of two of it at {listed([ms(T) for T in same])} ("
                     + listed([sps_edca(best, g4, T) for T in same]) + ")")
    return (text + " and ".join(parts) + ". The two CBRs are not one measure (802.11p: the time sensed busy; "
            f"the sidelink: the sub-channels at {minus(sps.medium.access.cbr_threshold, 'g')} dBm or above).")


def sidelink_tuned_reading(pts: list[tuple[str, float, float, Rows]]) -> str:
    """What the sidelink tuned to the tick does at that tick, against its defaults and 802.11p
    (the table's ``sps_tuned`` rows), worded from the numbers it quotes."""
    (T,) = {t for radio, _, t, _ in pts if radio == "sps_tuned"}
    at = lambda radio: [r for rad, _, t, r in pts if rad == radio and t == T]  # noqa: E731
    pct = lambda v: f"{100 * v:.0f}"  # noqa: E731
    two = lambda v: f"{v:.2f}"  # noqa: E731
    tuned = next(s for s in SIDELINK if sidelink_point(s)[0] == "sps_tuned").load().medium.access
    col = lambda radio, f: span([f(r) for r in at(radio)], pct if f is not mse else two)  # noqa: E731

    def refused(r: Rows) -> float:
        return share_of(r, "fused", "queue_dropped")

    def delivered(r: Rows) -> float:
        return share_of(r, "fused", "delivered")

    def mse(r: Rows) -> float:
        return r.mean("fused", "mse") / r.mean("centralized", "mse")
    wait = span([1000 * r.mean("fused", "access_delay") for r in at("sps_tuned")], lambda v: f"{v:.0f}")
    return (f"Tuned to the {1000 * T:g} ms tick (a reservation every {1000 * tuned.rri:g} ms, a one-shot resource "
            f"for a packet that does not fit it, a {1000 * tuned.budget:g} ms budget), the sidelink refuses "
            f"{col('sps_tuned', refused)} % of the DKF's packets ({col('sps', refused)} % with its defaults, "
            f"802.11p {col('edca', refused)} %) and delivers "
            f"{col('sps_tuned', delivered)} % ({col('sps', delivered)} %, 802.11p {col('edca', delivered)} %), its "
            f"frames waiting {wait} ms; the fused DKF's MSE is {col('sps_tuned', mse)} times the centralized "
            f"filter's ({col('sps', mse)} with the defaults, 802.11p {col('edca', mse)}).")


def draw_sidelink_figure(path: Path) -> Path:
    """docs/figures/sidelink_highway.png from the sidelink study's stored rows (what docs/radio.md's
    table quotes): the fused DKF's position MSE over the centralized filter's, and the share of the
    DKF's packets delivered, against the tick, one line per radio and density.  Written by
    ``--only sidelink`` (never by the tests)."""
    from dkfsim.core.extras import pyplot
    from dkfsim.report.plots.style import legend_below, save_figure
    plt = pyplot()
    per_km = highway_per_km()
    pts = sidelink_points({s.name: Rows(read_rows(s.path)) for s in SIDELINK})
    colors = {"edca": "#3182bd", "sps": "#e6550d", "sps_tuned": "#31a354"}
    shares = sorted({p[1] for p in pts})
    styles = dict(zip(shares, ("--", "-", ":", "-.")))
    fig, (left, right) = plt.subplots(1, 2, figsize=(11, 4.6))
    for radio in SIDELINK_RADIOS:
        for share in shares:
            line = [(T * 1000, r) for rad, s, T, r in pts if rad == radio and s == share]
            x = [t for t, _ in line]
            label = f"{SIDELINK_RADIOS[radio].replace('`', '')}, {share * per_km:.0f} vehicles per km"
            style = dict(color=colors[radio], ls=styles[share], marker="o", ms=4, label=label)
            left.plot(x, [r.mean("fused", "mse") / r.mean("centralized", "mse") for _, r in line], **style)
            right.plot(x, [share_of(r, "fused", "delivered") for _, r in line], **style)
    for ax in (left, right):
        ax.set_xscale("log")
        ax.set_xticks([p[2] * 1000 for p in pts[:3]])
        ax.set_xticklabels([f"{p[2] * 1000:g}" for p in pts[:3]])
        ax.minorticks_off()
        ax.set_xlabel("DKF tick (ms)")
        ax.grid(alpha=0.3)
    left.set_ylabel("fused position MSE / centralized")
    left.set_title("the fused DKF against the centralized filter", fontsize=10)
    right.set_ylim(0, 1)
    right.set_ylabel("share of the DKF's packets delivered")
    right.set_title("the DKF's packets (per link) that reach their neighbour", fontsize=10)
    legend_below(fig, [left], ncol=2)
    return save_figure(fig, path, ("png",))[0]


def _tests_module(name: str):
    """A module of tests/ (the validation's own code: the analytic model and the ns-3 comparison)."""
    import importlib
    if str(ROOT / "tests") not in sys.path:
        sys.path.insert(0, str(ROOT / "tests"))
    return importlib.import_module(name)


def analytic_name(beta: float) -> str:
    """The docs block of one density's analytic comparison (block names hold no dot)."""
    return f"radio-analytic-{beta:g}".replace(".", "")


def analytic_block(beta: float, edges, sim: dict, ref: dict, sim_cbr: float, ref_cbr: float, gap: dict,
                   seeds: int) -> str:
    """docs/radio.md's table of one density against the analytic model: PDR and the collision
    share per 25 m bin (every other bin), dkfsim | model, and the worst differences and CBR --
    from the numbers tests/test_radio_analytic.py computes (it checks this block with them)."""
    lines = [f"{beta} vehicles/m ({seeds} one-period runs): PDR mean |difference| {gap['pdr'][0]:.4f}, "
             f"worst bin {gap['pdr'][1]:.4f}; worst bin per cause: "
             + ", ".join(f"{k.replace('_', ' ')} {gap[k][1]:.3f}" for k in ("sensing", "receiver_busy",
                                                                               "propagation", "collision"))
             + f"; CBR {sim_cbr:.3f} against eq. (35)'s {ref_cbr:.3f}.", "",
             "| bin (m) | PDR: dkfsim \\| model | collision: dkfsim \\| model |", "|---|---|---|"]
    for k in range(0, len(edges) - 1, 2):
        lines.append(f"| {edges[k]:.0f}–{edges[k + 1]:.0f} | {sim['pdr'][k]:.3f} \\| {ref['pdr'][k]:.3f} | "
                     f"{sim['collision'][k]:.3f} \\| {ref['collision'][k]:.3f} |")
    return "\n".join(lines)


def ns3_sync_block(results: dict[str, tuple[dict, dict]]) -> str:
    """docs/radio.md's synchronized senders against ns-3: per configuration (name -> (ns-3's
    results, dkfsim's :func:`test_ns3_reference.run_all`)) the PDR, the detected pairs lost and CBR."""
    rows = ["| configuration | PDR: dkfsim \\| ns-3 | detected pairs lost | CBR |", "|---|---|---|---|"]
    for name, (r, ours) in results.items():
        pdr_o = sum(ours["received"]) / max(1, sum(ours["pairs"]))
        pdr_r = sum(p * n for p, n in zip(r["pdr"], r["pairs"]) if p is not None) / max(1, sum(r["pairs"]))
        rows.append(f"| {name} | {pdr_o:.3f} \\| {pdr_r:.3f} | {ours['lost_fraction']:.3f} \\| "
                    f"{r['collided_fraction']:.3f} | {ours['cbr_mean']:.4f} \\| {r['cbr_mean']:.4f} |")
    return "\n".join(rows)


def ns3_highway_block(r: dict, ours: dict, min_pairs: int) -> str:
    """docs/radio.md's table of one ns-3 highway: PDR per 25 m bin with enough pairs, and CBR."""
    rows = [f"CBR: dkfsim {ours['cbr_mean']:.3f}, ns-3 {r['cbr_mean']:.3f}.", "",
            "| bin (m) | PDR: dkfsim \\| ns-3 |", "|---|---|"]
    edges = r["bins_m"]
    for k in range(len(edges) - 1):
        if min(r["pairs"][k], ours["pairs"][k]) >= min_pairs:
            rows.append(f"| {edges[k]:.0f}–{edges[k + 1]:.0f} | {ours['pdr'][k]:.3f} \\| {r['pdr'][k]:.3f} |")
            if max(ours["pdr"][k], r["pdr"][k]) == 0.0:
                rows[-1] = rows[-1][:-1] + "(and every bin beyond) |"
                break
    return "\n".join(rows)


#: the ns-3 references docs/radio.md quotes
NS3_SYNC = ("sync_n4", "sync_n12", "sync_n24", "sync_jitter_n4", "sync_jitter_n12", "sync_jitter_n24")
NS3_HIGHWAYS = {"highway_d0.06_interfere": "radio-ns3-highway-006", "highway_d0.12_interfere": "radio-ns3-highway-012",
                "highway_n300_interfere": "radio-ns3-highway-n300",
                "highway_d0.12_nakagami": "radio-ns3-highway-012-nakagami"}


def render_radio_validation() -> dict[str, str]:
    """docs/radio.md's validation tables: dkfsim against the analytic 802.11p model of Sepulcre et
    al. and against the stored ns-3 references -- the validation tests' own computations, each of
    which checks its block with the numbers it computed."""
    ta = _tests_module("test_radio_analytic")
    out = {}
    for beta in (0.06, 0.12):
        pairs, sim_cbr, edges = ta.simulate(beta, ta.SEEDS[beta])
        sim = ta.measured(pairs)
        ref, ref_cbr = ta.analytic(beta, edges)
        out[analytic_name(beta)] = analytic_block(beta, edges, sim, ref, sim_cbr, ref_cbr,
                                                      ta.discrepancies(sim, ref), ta.SEEDS[beta])
    tn = _tests_module("test_ns3_reference")
    out["radio-ns3-sync"] = ns3_sync_block({n: (tn.load(n)["results"], tn.run_all(tn.load(n))) for n in NS3_SYNC})
    for name, block in NS3_HIGHWAYS.items():
        ref = tn.load(name)
        out[block] = ns3_highway_block(ref["results"], tn.run_all(ref), tn.MIN_PAIRS)
    return out


GENERATORS = (
    Generator("quickstart", ("quickstart", "quickstart-reading"), render_quickstart, cheap=True),
    Generator("paper", ("fig4", "fig5", "fig6"), render_paper, PAPER),
    Generator("consensus", ("consensus-table", "estimators-table", "consensus-headline",
                            "statistics-paired", "statistics-reading"),
              render_consensus, (CONSENSUS,)),
    Generator("sweep", ("sweep-table", "sweep-reading"), render_sweep, SWEEP),
    Generator("radar", ("radar-table", "radar-summary", "radar-reading"), render_radar),
    Generator("mobility", ("mobility-scenarios", "mobility-range", "mobility-speed"), render_mobility),
    Generator("centre", ("centre-table", "centre-reading"), render_centre, CENTRE),
    Generator("channel", ("channel-table", "channel-reading"), render_channel, CHANNEL),
    Generator("buffer", ("buffer-table", "buffer-reading"), render_buffer, BUFFER),
    Generator("radio", ("radio-highway", "radio-highway-reading"), render_radio, HIGHWAY),
    Generator("sidelink", ("sidelink-table", "sidelink-reading"), render_sidelink, SIDELINK),
    Generator("radio_validation", ("radio-analytic-006", "radio-analytic-012", "radio-ns3-sync",
                                   *NS3_HIGHWAYS.values()), render_radio_validation),
)


def stored(gen: Generator) -> dict[str, str]:
    """``gen``'s blocks rendered from its studies' stored rows (``gen.studies`` not empty)."""
    return gen.render({s.name: Rows(read_rows(s.path)) for s in gen.studies})


def compute(gen: Generator, jobs: int) -> dict[str, str]:
    """``gen``'s blocks from scratch (its studies' rows recomputed and stored first)."""
    if not gen.studies:
        return gen.render()
    for study in gen.studies:
        print(f"  {study.name}: {study.runs} runs", flush=True)
        save_rows(study.path, study.compute(jobs), study.columns)
    return stored(gen)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--only", nargs="+", choices=[g.name for g in GENERATORS], metavar="GEN",
                    help="generators to run: " + ", ".join(g.name for g in GENERATORS))
    mode = ap.add_mutually_exclusive_group()
    mode.add_argument("--render", action="store_true",
                      help="render the Monte Carlo studies' blocks from docs/numbers/*.csv")
    mode.add_argument("--check", action="store_true",
                      help="rewrite nothing; exit 1 naming every block that differs (cheap "
                           "generators recomputed, studies rendered from their stored rows)")
    ap.add_argument("--jobs", type=int, default=2, help="worker processes (default 2)")
    args = ap.parse_args(argv)
    gens = [g for g in GENERATORS if args.only is None or g.name in args.only]
    rendered: dict[str, str] = {}
    for gen in gens:
        if args.render or args.check:
            if gen.studies:
                rendered.update(stored(gen))
            elif gen.cheap or (args.check and args.only):      # radar: only when named
                rendered.update(gen.render())
        else:
            print(f"{gen.name} ...", flush=True)
            rendered.update(compute(gen, args.jobs))
    if args.check:
        found = page_blocks()
        bad = [f"{page.relative_to(ROOT)}: {name}" for name, text in rendered.items()
               for page, body in found.get(name, []) if body.rstrip("\n") != text.rstrip("\n")]
        bad += [f"no block {name} in any page" for name in rendered if name not in found]
        print("\n".join(bad) or "every block matches")
        return 1 if bad else 0
    for page in write_blocks(rendered):
        print(f"rewrote {page.relative_to(ROOT)}")
    if any(g.name == "radio" for g in gens):
        print(f"drew {draw_radio_figure(ROOT / 'docs' / 'figures' / 'radio_highway').relative_to(ROOT)}")
    if any(g.name == "sidelink" for g in gens):
        print(f"drew {draw_sidelink_figure(ROOT / 'docs' / 'figures' / 'sidelink_highway').relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

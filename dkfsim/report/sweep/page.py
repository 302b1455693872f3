"""The sweep's page of ``dkfsim report``: a sweep database as one self-contained HTML page.

The scenario (as resolved for the first parameter set), its network, the figures of
``dkfsim plot SWEEP`` (:mod:`dkfsim.report.sweep.plot`) and, per grid point, the MSE,
NEES and traffic of the sweep summary (:func:`dkfsim.experiments.sweep.grid.summarize`),
built from the blocks of :mod:`dkfsim.report.html`.
"""

from __future__ import annotations

import html
import tempfile
from pathlib import Path

from dkfsim.core.errors import DkfsimError
from dkfsim.experiments.sweep import SweepDB, read_results
from dkfsim.experiments.sweep.grid import grid_columns, summarize
from dkfsim.report import html as blocks
from dkfsim.report.plots.style import png_resolution
from dkfsim.report.sweep.plot import axis_label, plot_sweep


def sweep_page(db: Path) -> str:
    columns, rows = read_results(db)
    scols, srows = summarize(columns, rows)
    grid = grid_columns(columns)
    store = SweepDB(db, readonly=True)
    try:
        meta, params, definition = store.meta(), store.params(), store.definition or {}
    finally:
        store.close()
    cfg = params[0]["scenario"] if params else {}
    sc = blocks.stored_or_unvalidated(cfg, definition.get("scenario_file"), f"{db} (params.scenario_json)")
    ix = {c: i for i, c in enumerate(scols)}
    comps = []
    for r in srows:
        if r[ix["component"]] not in comps:
            comps.append(r[ix["component"]])
    wide: dict = {}                 # one row per grid point and estimate, 3 cells per component
    for r in srows:
        key = (r[ix["param_hash"]], r[ix["estimate"]])
        if key not in wide:
            wide[key] = [*(r[ix[k]] for k in grid), r[ix["estimate"]], r[ix["runs"]]]
        wide[key].append(blocks.Interval((r[ix["mse"]], r[ix["mse_ci95_lo"]], r[ix["mse_ci95_hi"]])))
    mse_rows = list(wide.values())
    first: dict = {}
    for r in srows:
        first.setdefault((r[ix["param_hash"]], r[ix["estimate"]]), r)
    nees_rows = [(*(r[ix[k]] for k in grid), r[ix["estimate"]],
                  blocks.Interval((r[ix["anees"]], r[ix["anees_ci95_lo"]], r[ix["anees_ci95_hi"]])),
                  blocks.verdict(r[ix["anees_consistent"]]))
                 for r in first.values()]
    pk = [(*(r[ix[k]] for k in grid), r[ix["estimate"]], r[ix["messages_per_tick"]],
           r[ix["bytes_per_tick"]], r[ix["late"]]) for r in first.values()]
    figs = []
    with tempfile.TemporaryDirectory(prefix="dkfsim-report-") as tmp, png_resolution(blocks.SCREEN_DPI):
        if grid:
            x = grid[0]
            hue = grid[1] if len(grid) > 1 else None
            values: dict[str, list] = {k: [] for k in grid[2:]}
            for r in srows:
                for k in grid[2:]:
                    if r[ix[k]] not in values[k]:
                        values[k].append(r[ix[k]])
            where = [f"{k}={v[0]}" for k, v in values.items()]
            try:
                for metric in ("mse", "anees"):
                    plot_sweep(db, Path(tmp) / metric, x=x, hue=hue, metric=metric, where=where,
                               formats=("png",))
                    figs.append(blocks.figure(blocks.png_b64(Path(tmp) / f"{metric}.png"),
                                       f"{metric} against the {axis_label(x)} ({x})"
                                       + (f", one line per {hue}" if hue else "")
                                       + (f" ({', '.join(where)})" if where else "")
                                       + "; bands: 95 % intervals over runs.", metric))
            except DkfsimError as exc:
                figs.append(f"<p class='note'>No figure: {html.escape(str(exc))}</p>")
    facts = [("kind", "sweep"), ("database", db.name), ("parameter sets", len(params)),
             ("runs per set", definition.get("runs")),
             ("grid", "; ".join(f"{k} ∈ {v}" for k, v in definition.get("grid", []))),
             ("fixed settings", ", ".join(definition.get("set", [])) or "none"),
             ("rows below", "the scenario as resolved for the first parameter set")]
    short = [k.removeprefix("param:").rsplit(".", 1)[-1] for k in grid]
    gh = tuple(sh if short.count(sh) == 1 else k.removeprefix("param:") for sh, k in zip(short, grid))
    sections = [
        ("Scenario", blocks.facts_table(sc, facts) + blocks.scenario_text(cfg)),
        ("Network", blocks.network_section(sc, "Drawn for the first parameter set" + (
            f" ({', '.join(f'{k} = {v}' for k, v in zip(gh, _first_values(srows, ix, grid)))})"
            if grid else ""))),
        ("Figures", "\n".join(figs)),
        ("MSE", blocks.table("mse", (*gh, "estimate", "runs",
                              *(f"{c} MSE [95 % CI]" for c in comps)),
                      mse_rows, "per grid point: mean over runs of the time-averaged MSE and its 95 % "
                      "Student-t interval (the sweep summary file <db>.summary.csv)")),
        ("NEES", blocks.table("nees", (*gh, "estimate", "ANEES [95 % CI over runs]", "consistent"),
                              nees_rows, "mean over runs of each run's time-averaged NEES and its 95 % "
                              "t-interval; consistent: the interval covers the number of state "
                              "components (docs/statistics.md)")),
        ("Packets", blocks.table("packets", (*gh, "estimate", *blocks.RATE_HEADS, blocks.LATE_HEAD),
                          pk, f"means over runs; {blocks.PACKETS_NOTE}")),
        ("Versions and seeds", blocks.versions_table({"dkfsim (database)": meta.get("dkfsim_version")},
                                         [("created", meta.get("created", ""))])
         + blocks.table("seeds", ("parameter set", "param_hash", "base seed"),
                 [(p["idx"], p["param_hash"], p["base_seed"]) for p in params],
                 "run r of a parameter set uses derive_seed(base seed, r)")),
    ]
    return blocks.html_page(f"dkfsim report: {Path(meta.get('sweep_file', db.stem)).stem}",
                 f"sweep: {len(params)} parameter sets x {definition.get('runs')} runs", sections)


def _first_values(srows, ix, grid) -> list:
    return [srows[0][ix[k]] for k in grid] if srows else []

"""``dkfsim report DIR``: one self-contained HTML page for a run, Monte Carlo or sweep.

The page is a lab-note attachment: the scenario (its key facts, and the whole
file in a fold), the network drawing (:mod:`dkfsim.report.network`), the MSE and
NEES tables, the figures of ``dkfsim plot``, packet and late counts, versions and
seeds.  Figures are inline base64 PNG, styles inline: the one file opens anywhere
and can be mailed.  Every number in a table is read from the folder's files
(``summary.json``, ``rows.csv``, ``runs.csv``, a sweep database and its summary,
:mod:`dkfsim.analysis.grid`), printed with 6 significant digits; tables carry
``id`` attributes (``facts``, ``mse``, ``nees``, ``packets``, ``versions``,
``seeds``) so that tests and scripts can read them back with any HTML parser.
"""

from __future__ import annotations

import base64
import html
import io
import math
import tempfile
import time
from pathlib import Path

import networkx as nx
import yaml

from dkfsim.config.dynamics import component_names
from dkfsim.config.load import stored_scenario
from dkfsim.config.plan import RunPlan
from dkfsim.config.results import (
    MonteCarloSummary,
    RunSummary,
    components_of,
    read_record,
    read_run_seeds,
)
from dkfsim.core.errors import DkfsimError
from dkfsim.core.extras import pyplot
from dkfsim.core.folders import write_text
from dkfsim.core.version import __version__
from dkfsim.experiments.sweep import SweepDB, is_database, read_results
from dkfsim.experiments.sweep.grid import grid_columns, summarize
from dkfsim.report.network import draw_network
from dkfsim.report.plots import load_folder, plot_mse, plot_nees, plot_tracking
from dkfsim.report.plots.folders import NothingToPlot
from dkfsim.report.plots.style import png_resolution
from dkfsim.report.sweep.plot import plot_sweep

#: Resolution of the inline figures (a screen, not print: the page stays small).
SCREEN_DPI = 110

CSS = """
body{font-family:system-ui,-apple-system,"Segoe UI",Helvetica,Arial,sans-serif;max-width:1100px;
margin:1.5em auto;padding:0 1em;color:#222;line-height:1.4}
h1{font-size:1.6em;margin-bottom:.1em}h2{font-size:1.2em;border-bottom:1px solid #ccc;margin-top:1.6em}
.sub{color:#666;margin-top:0}table{border-collapse:collapse;margin:.6em 0;font-size:.9em}
th,td{border:1px solid #ddd;padding:.2em .5em}th{background:#f3f5f8;text-align:left}
td.num{text-align:right;font-variant-numeric:tabular-nums;white-space:nowrap}tr:nth-child(even) td{background:#fafbfc}
figure{margin:.8em 0}figure img{max-width:100%;border:1px solid #eee}
figcaption{color:#555;font-size:.88em}caption{caption-side:top;text-align:left;padding:.2em 0}
table.facts td:first-child{color:#555}pre{background:#f6f8fa;padding:.8em;overflow:auto;font-size:.8em}
.note{color:#555;font-size:.88em}.wrap{overflow-x:auto;max-width:100%}
"""


# =========================================================================== building blocks
class Interval(tuple):
    """A table cell ``mean [low, high]`` (a 95 % interval), 5 significant digits."""


def _num(v) -> str:
    if isinstance(v, Interval):
        return " ".join(("–" if x is None or math.isnan(x) else f"{x:.5g}") for x in v[:1]) + \
            " [" + ", ".join(("–" if x is None or math.isnan(x) else f"{x:.5g}") for x in v[1:]) + "]"
    if v is None:
        return "–"
    if isinstance(v, bool):
        return str(v)
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return "–" if math.isnan(v) else f"{v:.6g}"      # NaN: not applicable (docs/design.md §8)
    return html.escape(str(v))


def table(table_id: str, head, rows, caption: str = "") -> str:
    """An HTML table; numbers right-aligned with 6 significant digits ("–": not applicable).
    ``head`` None: no header row (a two-column list of facts)."""
    out = [f'<div class="wrap"><table id="{table_id}" class="{table_id}">']
    if caption:
        out.append(f"<caption class='note'>{html.escape(caption)}</caption>")
    if head is not None:
        out.append("<tr>" + "".join(f"<th>{html.escape(str(h))}</th>" for h in head) + "</tr>")
    for row in rows:
        cells = []
        for v in row:
            cls = ' class="num"' if (v is None or isinstance(v, (int, float, Interval))) and not isinstance(v, bool) else ""
            cells.append(f"<td{cls}>{_num(v)}</td>")
        out.append("<tr>" + "".join(cells) + "</tr>")
    out.append("</table></div>")
    return "\n".join(out)


def _png(path: Path) -> str:
    return base64.b64encode(Path(path).read_bytes()).decode("ascii")


def figure(png_b64: str, caption: str, alt: str) -> str:
    return (f'<figure><img alt="{html.escape(alt)}" src="data:image/png;base64,{png_b64}">'
            f"<figcaption>{html.escape(caption)}</figcaption></figure>")


def _fig_b64(fig) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110, bbox_inches="tight")
    pyplot().close(fig)
    return base64.b64encode(buf.getvalue()).decode("ascii")


# =========================================================================== sections
class Unvalidated:
    """A stored scenario that could not be validated here (its kinds unknown in this process, a
    data file moved): the page shows its stored values only, and says why."""

    def __init__(self, reason: str):
        self.reason = reason


def _scenario(config, source, label: str):
    """The stored scenario validated as data (never importing its plugins), or :class:`Unvalidated`."""
    try:
        return stored_scenario(config, source=source, label=label)
    except DkfsimError as exc:
        return Unvalidated(str(exc))


def _facts(sc, extra: list) -> str:
    rows = list(extra)
    if not isinstance(sc, Unvalidated):
        lat = sc.links.default.latency
        rows += [("nodes", sc.n), ("state", ", ".join(component_names(sc.model.kind, sc.nx))),
                 ("model", f"{sc.model.kind}, T = {sc.model.T:g} s"), ("steps", sc.steps),
                 ("topology", f"{sc.topology.generator}{' (directed)' if sc.topology.directed else ''}"),
                 ("protocol", sc.protocol), ("weights", sc.weights), ("fusion", sc.fusion),
                 ("default latency", getattr(lat, "model", "?") + "".join(
                     f", {k} = {v}" for k, v in lat.model_dump().items() if k != "model")),
                 ("loss", sc.links.default.loss),
                 ("estimators", ", ".join(e.name or e.kind for e in sc.estimators) or "none")]
    return table("facts", None, [(k, str(v)) for k, v in rows])


def _network(sc, note: str = "") -> str:
    if isinstance(sc, Unvalidated):
        return (f"<p class='note'>No drawing: the stored scenario is shown as stored, not validated "
                f"({html.escape(sc.reason)}).</p>")
    try:
        plan = RunPlan(sc)
        graph, xg = plan.graph, plan.exchange
    except DkfsimError as exc:
        return f"<p class='note'>No drawing: {html.escape(str(exc))}</p>"
    is_tree = not xg.graph.is_directed() and nx_is_tree(xg.graph)
    labels = [s.name or f"s{i + 1}" for i, s in enumerate(sc.sensors)]
    fig, caption = draw_network(graph, xg.graph, is_tree, labels)
    return figure(_fig_b64(fig), caption + (f". {note}" if note else ""), "network")


def nx_is_tree(g) -> bool:
    return g.number_of_nodes() > 0 and g.number_of_edges() == g.number_of_nodes() - 1 and \
        nx.is_connected(g)


def _versions(versions: dict, extra: list = ()) -> str:
    rows = [(k, str(v)) for k, v in (versions or {}).items()] + list(extra)
    return table("versions", ("package", "version"), rows)


def _scenario_text(config: dict) -> str:
    text = yaml.safe_dump(config, sort_keys=False, default_flow_style=None, width=100)
    return (f"<details><summary>The scenario as run (YAML)</summary><pre>{html.escape(text)}</pre>"
            "</details>")


def _figures(folder_path: Path, kinds) -> list[str]:
    """The figures of ``dkfsim plot`` for a run or Monte Carlo folder, inline."""
    out = []
    try:
        folder = load_folder(folder_path)
    except NothingToPlot as exc:         # a damaged or hostile file is an error of the report
        return [f"<p class='note'>No figures: {html.escape(str(exc))}</p>"]
    with tempfile.TemporaryDirectory(prefix="dkfsim-report-") as tmp, png_resolution(SCREEN_DPI):
        tmp = Path(tmp)
        if folder.truth is not None and "tracking" in kinds:
            plot_tracking(folder, tmp / "tracking", ("png",))
            out.append(figure(_png(tmp / "tracking.png"), "Truth and estimates (left: the whole run; "
                              "right: the shaded window).", "tracking"))
        plot_mse(folder, tmp / "mse", ("png",))
        out.append(figure(_png(tmp / "mse.png"), "MSE per tick and state component.", "mse"))
        if folder.nees:
            plot_nees(folder, tmp / "nees", ("png",))
            out.append(figure(_png(tmp / "nees.png"), "Mean NEES per tick with the 95 % chi-square "
                              "band of a consistent filter.", "nees"))
    return out


def _page(title: str, subtitle: str, sections: list[tuple[str, str]]) -> str:
    body = "\n".join(f"<h2>{html.escape(h)}</h2>\n{content}" for h, content in sections)
    return (f"<!DOCTYPE html>\n<html lang='en'><head><meta charset='utf-8'>"
            f"<meta name='viewport' content='width=device-width, initial-scale=1'>"
            f"<title>{html.escape(title)}</title><style>{CSS}</style></head><body>\n"
            f"<h1>{html.escape(title)}</h1><p class='sub'>{html.escape(subtitle)}</p>\n{body}\n"
            f"<p class='note'>Written by dkfsim {__version__} on "
            f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}.</p></body></html>\n")


# =========================================================================== per kind
def run_page(folder: Path) -> str:
    s = read_record(folder / "summary.json", RunSummary, "summary.json")
    cfg = s["scenario_config"]
    sc = _scenario(cfg, s.get("source"), str(folder / "summary.json"))
    burn = s["metrics"]["burn_in"]
    rows = s["rows"]
    comps = components_of(rows)
    by = {(r["estimate"], r["component"]): r for r in rows}
    mse_rows = [(e, *(by[(e, c)]["mse"] for c in comps)) for e in s.get("estimates", [])]
    nees_rows = [(e, by[(e, comps[0])]["anees"], by[(e, comps[0])]["disagreement"])
                 for e in s.get("estimates", [])]
    p = s.get("packets") or {}
    pk = [("DKF (anti-delay)", p.get("sent"), p.get("delivered"), p.get("lost"),
           p.get("in_flight"), p.get("late"))]
    for name, t in (s.get("traffic") or {}).items():
        if t is not None and name not in ("fused", "local"):
            pk.append((name, t.get("sent"), t.get("delivered"), t.get("lost"), t.get("in_flight"),
                       t.get("late")))
    facts = [("kind", "single run"), ("seed", s.get("seed")), ("buffer length L", s.get("buffer_length")),
             ("d_t, d_g", f"{s.get('d_t')}, {s.get('d_g')}"), ("burn-in rows", burn)]
    sections = [
        ("Scenario", _facts(sc, facts) + _scenario_text(cfg)),
        ("Network", _network(sc)),
        ("MSE", table("mse", ("estimate", *comps), mse_rows,
                      f"time-averaged squared error after {burn} burn-in rows (rows.csv)")),
        ("NEES", table("nees", ("estimate", "ANEES", "disagreement"), nees_rows,
                       f"time-averaged NEES after the burn-in; expected {len(comps)} when consistent")),
        ("Packets", table("packets", ("estimator", "sent", "delivered", "lost", "in flight at end",
                                      "late"), pk, "late: contributions (the DKF) or stale packets")),
        ("Figures", "\n".join(_figures(folder, ("tracking",)))),
        ("Versions and seeds", _versions(s.get("versions"), [("seed", str(s.get("seed")))])),
    ]
    if s.get("diverged"):
        sections.insert(2, ("Diverged", f"<p>{html.escape(', '.join(s['diverged']))}</p>"))
    return _page(f"dkfsim report: {s.get('scenario')}", f"a single run of {s.get('steps')} ticks",
                 sections)


def montecarlo_page(folder: Path) -> str:
    s = read_record(folder / "summary.json", MonteCarloSummary, "summary.json")
    cfg = s["scenario_config"]
    sc = _scenario(cfg, s.get("source"), str(folder / "summary.json"))
    comps = s.get("components") or []
    est = s.get("estimates") or {}
    mse_rows = [(name, *(Interval((e["mse"][c], *e["mse_ci95"][c])) for c in comps))
                 for name, e in est.items()]
    nees_rows = [(name, e.get("anees"), *(e.get("anees_band95") or (None, None)),
                  e.get("anees_fraction_in_band")) for name, e in est.items()]
    pk = [(name, e.get("messages_per_tick"), e.get("bytes_per_tick"), e.get("lost"), e.get("late"))
          for name, e in est.items()]
    seeds = _runs_seeds(folder / "runs.csv")
    facts = [("kind", "Monte Carlo"), ("runs", s.get("runs")), ("base seed", s.get("base_seed")),
             ("buffer length L", s.get("buffer_length")), ("d_t, d_g", f"{s.get('d_t')}, {s.get('d_g')}"),
             ("burn-in rows", s.get("burn_in"))]
    sections = [
        ("Scenario", _facts(sc, facts) + _scenario_text(cfg)),
        ("Network", _network(sc)),
        ("MSE", table("mse", ("estimate", *(f"{c} MSE [95 % CI]" for c in comps)), mse_rows,
                      "mean over runs of the time-averaged MSE and its 95 % Student-t interval over runs")),
        ("NEES", table("nees", ("estimate", "ANEES", "band low", "band high", "fraction in band"),
                       nees_rows, f"expected {len(comps)} when consistent; band: per-tick 95 % "
                       "chi-square band of the mean NEES over runs")),
        ("Packets", table("packets", ("estimate", "messages per tick", "bytes per tick", "lost", "late"),
                          pk, "means over runs; – : not modelled for that estimate")),
        ("Figures", "\n".join(_figures(folder, ("tracking",)))),
        ("Versions and seeds", _versions(s.get("versions"), [("seed rule", s.get("seed_rule", ""))])
         + table("seeds", ("run", "seed"), seeds[:50],
                 f"{len(seeds)} runs" + (", the first 50 shown" if len(seeds) > 50 else ""))),
    ]
    return _page(f"dkfsim report: {s.get('scenario')}",
                 f"Monte Carlo: {s.get('runs')} runs x {s.get('steps')} ticks", sections)


def _runs_seeds(path: Path) -> list[tuple[int, int]]:
    return sorted(read_run_seeds(path).items()) if path.is_file() else []


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
    sc = _scenario(cfg, definition.get("scenario_file"), f"{db} (params.scenario_json)")
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
        wide[key].append(Interval((r[ix["mse"]], r[ix["mse_ci95_lo"]], r[ix["mse_ci95_hi"]])))
    mse_rows = list(wide.values())
    first = {}
    for r in srows:
        first.setdefault((r[ix["param_hash"]], r[ix["estimate"]]), r)
    nees_rows = [(*(r[ix[k]] for k in grid), r[ix["estimate"]], r[ix["anees"]], r[ix["anees_band95_lo"]],
                  r[ix["anees_band95_hi"]]) for r in first.values()]
    pk = [(*(r[ix[k]] for k in grid), r[ix["estimate"]], r[ix["messages_per_tick"]],
           r[ix["bytes_per_tick"]], r[ix["late"]]) for r in first.values()]
    figs = []
    with tempfile.TemporaryDirectory(prefix="dkfsim-report-") as tmp, png_resolution(SCREEN_DPI):
        if grid:
            x = grid[0]
            hue = grid[1] if len(grid) > 1 else None
            values = {k: [] for k in grid[2:]}
            for r in srows:
                for k in grid[2:]:
                    if r[ix[k]] not in values[k]:
                        values[k].append(r[ix[k]])
            where = [f"{k}={v[0]}" for k, v in values.items()]
            try:
                for metric in ("mse", "anees"):
                    plot_sweep(db, Path(tmp) / metric, x=x, hue=hue, metric=metric, where=where,
                               formats=("png",))
                    figs.append(figure(_png(Path(tmp) / f"{metric}.png"),
                                       f"{metric} against {x}" + (f", one line per {hue}" if hue else "")
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
        ("Scenario", _facts(sc, facts) + _scenario_text(cfg)),
        ("Network", _network(sc, "Drawn for the first parameter set" + (
            f" ({', '.join(f'{k} = {v}' for k, v in zip(gh, _first_values(srows, ix, grid)))})"
            if grid else ""))),
        ("Figures", "\n".join(figs)),
        ("MSE", table("mse", (*gh, "estimate", "runs",
                              *(f"{c} MSE [95 % CI]" for c in comps)),
                      mse_rows, "per grid point: mean over runs of the time-averaged MSE and its 95 % "
                      "Student-t interval (the sweep summary file <db>.summary.csv)")),
        ("NEES", table("nees", (*gh, "estimate", "ANEES", "band low", "band high"), nees_rows,
                       "mean over runs of each run's time-averaged NEES; 95 % chi-square band")),
        ("Packets", table("packets", (*gh, "estimate", "messages per tick", "bytes per tick", "late"),
                          pk, "means over runs; – : not modelled for that estimate")),
        ("Versions and seeds", _versions({"dkfsim (database)": meta.get("dkfsim_version")},
                                         [("created", meta.get("created", ""))])
         + table("seeds", ("parameter set", "param_hash", "base seed"),
                 [(p["idx"], p["param_hash"], p["base_seed"]) for p in params],
                 "run r of a parameter set uses derive_seed(base seed, r)")),
    ]
    return _page(f"dkfsim report: {Path(meta.get('sweep_file', db.stem)).stem}",
                 f"sweep: {len(params)} parameter sets x {definition.get('runs')} runs", sections)


def _first_values(srows, ix, grid) -> list:
    return [srows[0][ix[k]] for k in grid] if srows else []


# =========================================================================== entry
def find_kind(path) -> tuple[str, Path]:
    """``("run" | "montecarlo" | "sweep", path)`` of what ``path`` holds."""
    p = Path(path)
    if not p.exists():
        raise DkfsimError(f"{path}: no such file or folder")
    if p.is_file():
        if is_database(p):
            return "sweep", p
        raise DkfsimError(f"{path}: not a folder of dkfsim run / montecarlo, nor a sweep database")
    if (p / "curves.npz").is_file() and (p / "summary.json").is_file():
        return "montecarlo", p
    if (p / "summary.json").is_file() and (p / "rows.csv").is_file():
        return "run", p
    dbs = sorted(f for f in p.glob("*.sqlite") if is_database(f))
    if len(dbs) == 1:
        return "sweep", dbs[0]
    if len(dbs) > 1:
        raise DkfsimError(f"{path}: holds {len(dbs)} sweep databases ({', '.join(d.name for d in dbs)}); "
                          "give the one to report on")
    raise DkfsimError(f"{path}: neither a run folder (summary.json + rows.csv), a Monte Carlo folder "
                      "(summary.json + curves.npz) nor a folder with a sweep database (.sqlite)")


def default_output(kind: str, path: Path) -> Path:
    return path.with_name(path.stem + ".report.html") if kind == "sweep" else path / "report.html"


def write_report(path, out=None) -> Path:
    """Write the report of ``path`` (a run or Monte Carlo folder, a sweep database or a folder
    holding one) to ``out`` (default: ``DIR/report.html``, ``<db stem>.report.html``)."""
    kind, p = find_kind(path)
    page = {"run": run_page, "montecarlo": montecarlo_page, "sweep": sweep_page}[kind](p)
    target = Path(out) if out is not None else default_output(kind, p)
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        write_text(target, page)
    except OSError as exc:
        raise DkfsimError(f"{target}: cannot write the report ({exc.strerror})") from None
    return target

"""The building blocks of an HTML report page: tables, inline figures, the scenario's sections.

Every page of ``dkfsim report`` (:mod:`dkfsim.report.html_report` for runs and Monte Carlo,
:mod:`dkfsim.report.sweep.page` for sweeps) is made of these: one inline style sheet, tables
with 6 significant digits ("–": not applicable) and ``id`` attributes, base64 PNG figures,
the scenario's facts, its network drawing and its YAML in a fold.
"""

from __future__ import annotations

import base64
import html
import io
import math
import time
from pathlib import Path
from typing import Sequence

import yaml

from dkfsim.components.mobility import link_pairs, link_uptime
from dkfsim.components.topology import is_tree as topology_is_tree
from dkfsim.config.dynamics import component_names
from dkfsim.config.load import stored_scenario
from dkfsim.config.plan import RunPlan
from dkfsim.core.errors import DkfsimError
from dkfsim.core.extras import pyplot
from dkfsim.core.files import open_regular
from dkfsim.core.version import __version__
from dkfsim.report.network import draw_network

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


#: Column heads of the packets tables: rates per tick and totals per run said apart, with units
#: (``late`` counts items: the DKF's (packet, row) pairs or contributions, others' packets).
RATE_HEADS = ("messages per tick [1/tick]", "bytes per tick [B/tick]")
LOST_HEAD, LATE_HEAD = "lost [packets/run]", "late [items/run]"
PACKETS_NOTE = ("per tick: rates; per run: totals over one whole run; late items: (packet, row) "
                "pairs or contributions for the DKF, packets for the others; – : not modelled")


def folded(summary: str, body: str) -> str:
    """``body`` in a fold that opens on a click (long lists: seeds), ``summary`` always shown."""
    return f"<details><summary>{html.escape(summary)}</summary>{body}</details>"


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


def verdict(ok) -> str | None:
    """``anees_consistent`` as a table cell: yes / no / – (a single run)."""
    return None if ok is None else ("yes" if ok else "no")


#: Largest figure inlined (bytes): a page of screen-resolution PNGs is a few hundred kB each.
MAX_FIGURE_BYTES = 64 << 20


def png_b64(path: Path) -> str:
    """A figure the report drew into its own temporary folder, inline."""
    with open_regular(path, limit=MAX_FIGURE_BYTES, what="figure") as fh:
        return base64.b64encode(fh.read()).decode("ascii")


def figure(png: str, caption: str, alt: str) -> str:
    return (f'<figure><img alt="{html.escape(alt)}" src="data:image/png;base64,{png}">'
            f"<figcaption>{html.escape(caption)}</figcaption></figure>")


def fig_b64(fig) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=SCREEN_DPI, bbox_inches="tight")
    pyplot().close(fig)
    return base64.b64encode(buf.getvalue()).decode("ascii")


# =========================================================================== sections
class Unvalidated:
    """A stored scenario that could not be validated here (its kinds unknown in this process, a
    data file moved): the page shows its stored values only, and says why."""

    def __init__(self, reason: str):
        self.reason = reason


def stored_or_unvalidated(config, source, label: str):
    """The stored scenario validated as data (never importing its plugins), or :class:`Unvalidated`."""
    try:
        return stored_scenario(config, source=source, label=label)
    except DkfsimError as exc:
        return Unvalidated(str(exc))


def facts_table(sc, extra: list) -> str:
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


def network_section(sc, note: str = "") -> str:
    if isinstance(sc, Unvalidated):
        return (f"<p class='note'>No drawing: the stored scenario is shown as stored, not validated "
                f"({html.escape(sc.reason)}).</p>")
    try:
        plan = RunPlan.of(sc)
        graph, xg = plan.graph, plan.exchange
    except DkfsimError as exc:
        return f"<p class='note'>No drawing: {html.escape(str(exc))}</p>"
    is_tree = topology_is_tree(xg.graph)
    labels = [s.name or f"s{i + 1}" for i, s in enumerate(sc.sensors)]
    uptime = None
    if plan.graph_changes and plan.link_schedule is not None:   # vehicles that move: the links that were up
        pairs, up = link_pairs(plan.link_schedule)
        uptime = {(int(u), int(v)): f for u, v, f in link_uptime(pairs, up[1:])}
    fig, caption = draw_network(graph, xg.graph, is_tree, labels, uptime=uptime)
    return figure(fig_b64(fig), caption + (f". {note}" if note else ""), "network")


def versions_table(versions: dict | None, extra: Sequence = ()) -> str:
    rows = [(k, str(v)) for k, v in (versions or {}).items()] + list(extra)
    return table("versions", ("package", "version"), rows)


def scenario_text(config: dict) -> str:
    text = yaml.safe_dump(config, sort_keys=False, default_flow_style=None, width=100)
    return (f"<details><summary>The scenario as run (YAML)</summary><pre>{html.escape(text)}</pre>"
            "</details>")


def html_page(title: str, subtitle: str, sections: list[tuple[str, str]]) -> str:
    body = "\n".join(f"<h2>{html.escape(h)}</h2>\n{content}" for h, content in sections)
    return (f"<!DOCTYPE html>\n<html lang='en'><head><meta charset='utf-8'>"
            f"<meta name='viewport' content='width=device-width, initial-scale=1'>"
            f"<title>{html.escape(title)}</title><style>{CSS}</style></head><body>\n"
            f"<h1>{html.escape(title)}</h1><p class='sub'>{html.escape(subtitle)}</p>\n{body}\n"
            f"<p class='note'>Written by dkfsim {__version__} on "
            f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}.</p></body></html>\n")

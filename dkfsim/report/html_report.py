"""``dkfsim report DIR``: one self-contained HTML page for a run, Monte Carlo or sweep.

This module writes the run and Monte Carlo pages and chooses the page of a path; the sweep's
page is :mod:`dkfsim.report.sweep.page`, the blocks every page is made of :mod:`dkfsim.report.html`.

The page is a lab-note attachment: the scenario (its key facts, and the whole
file in a fold), the network drawing (:mod:`dkfsim.report.network`), the MSE and
NEES tables, the figures of ``dkfsim plot``, packet and late counts, versions and
seeds.  Figures are inline base64 PNG, styles inline: the one file opens anywhere
and can be mailed.  Every number in a table is read from the folder's files
(``summary.json``, ``rows.csv``, ``runs.csv``, a sweep database and its summary,
:mod:`dkfsim.experiments.sweep.grid`), printed with 6 significant digits; tables carry
``id`` attributes (``facts``, ``mse``, ``nees``, ``packets``, ``channel``, ``versions``,
``seeds``) so that tests and scripts can read them back with any HTML parser.
"""

from __future__ import annotations

import html
import tempfile
from pathlib import Path
from typing import Any

from dkfsim.config.results import (
    RADIO_CAUSES,
    MonteCarloSummary,
    RunSummary,
    components_of,
    read_record,
    read_run_seeds,
)
from dkfsim.core.errors import DkfsimError
from dkfsim.core.folders import write_text
from dkfsim.experiments.sweep import is_database
from dkfsim.report.html import (
    LATE_HEAD,
    LOST_HEAD,
    PACKETS_NOTE,
    RATE_HEADS,
    SCREEN_DPI,
    Interval,
    facts_table,
    figure,
    folded,
    html_page,
    network_section,
    png_b64,
    scenario_text,
    stored_or_unvalidated,
    table,
    verdict,
    versions_table,
)
from dkfsim.report.plots import (
    load_folder,
    paired_reference,
    plot_folder,
)
from dkfsim.report.plots.folders import NothingToPlot
from dkfsim.report.plots.style import png_resolution
from dkfsim.report.sweep.page import sweep_page
from dkfsim.report.tables import PACKET_HEADS, background_on_air, collided_percent, count, packet_columns, packet_row

# =========================================================================== sections
#: Captions of the figures of ``dkfsim plot`` in a report, by file stem.
CAPTIONS = {
    "tracking": "Truth and estimates (left: the whole run; right: the shaded window).",
    "mse": "MSE per tick and state component.",
    "nees": "Mean NEES per tick with the per-tick 95 % chi-square band of the mean NEES (labels: the "
            "fraction of ticks in it and the ANEES verdict).",
    "paired": "MSE relative to the reference estimate, paired over the runs (95 % t-interval of the "
              "per-run log-ratios).",
    "links": "The rate-limited links: the DKF's queueing delay per link, utilisation and "
             "time-averaged queue length per tick (run.npz).",
    "network_over_time": "The vehicles and the links up at six evenly spaced ticks; grey: their "
                         "paths over the whole run (run.npz; for Monte Carlo runs, replayed from "
                         "the scenario: every run moves alike).",
    "topology_errors": "Squared position error over time; dotted: the ticks at which the links up "
                       "change; below: the number of links up per tick.",
    "radio": "The spatial radio as the DKF's copy of the channel saw it: packet delivery ratio of every "
             "(frame, receiver) pair against their distance, the causes of the losses stacked above it "
             "and the pairs per bin (dotted); below, each vehicle's channel busy ratio per tick.",
}


def _figures(folder_path: Path) -> list[str]:
    """The figures of ``dkfsim plot`` (:func:`~dkfsim.report.plots.plot_folder`) for a run or
    Monte Carlo folder, inline, each with its caption."""
    try:
        folder = load_folder(folder_path)
    except NothingToPlot as exc:         # a damaged or hostile file is an error of the report
        return [f"<p class='note'>No figures: {html.escape(str(exc))}</p>"]
    with tempfile.TemporaryDirectory(prefix="dkfsim-report-") as where, png_resolution(SCREEN_DPI):
        return [figure(png_b64(path), CAPTIONS[path.stem], path.stem)
                for path in plot_folder(folder, Path(where), ("png",))]


def _links_section(per_link: list[dict]) -> list[tuple[str, str]]:
    """A rate-limited run's per-link table (summary.json ``per_link``), none otherwise."""
    rated = [r for r in per_link if "utilisation" in r]
    if not rated:
        return []
    rows = [(f"{r['link'][0]}→{r['link'][1]}", r["utilisation"], r.get("queue_length_mean"),
             1e3 * r["queueing_delay_mean"], 1e3 * r["queueing_delay_p95"], r.get("sent"),
             r.get("queue_dropped"), r.get("lost"), r.get("background_sent"), r.get("background_dropped"))
            for r in rated]
    return [("Links", table("links", ("link", "utilisation", "mean waiting", "queueing delay mean [ms]",
                                       "queueing delay p95 [ms]", "sent", "queue dropped", "lost",
                                       "background sent", "background dropped"), rows,
                            "the DKF's packets on each rate-limited link (summary.json per_link): utilisation "
                            "and mean number waiting over the run, background included; queueing delay "
                            "from hand-over to the start of transmission"))]


#: The shared channel's keys a report lists, with their units (``medium:``, docs/channel.md):
#: dotted key -> (label, factor to the unit shown).
CHANNEL_KEYS = {
    "rate": ("rate [bit/s]", 1.0), "access.kind": ("access", None), "access.cw": ("contention window [slots]", 1.0),
    "access.slot": ("slot [µs]", 1e6), "access.aifs": ("AIFS [µs]", 1e6), "preamble": ("preamble [µs]", 1e6),
    "queue.packets": ("radio queue [packets]", 1.0), "queue.bytes": ("radio queue [B]", 1.0),
    "background.arrivals": ("background arrivals", None),
    "background.packets_per_second": ("background per node [frames/s]", 1.0),
    "background.size": ("background frame [B]", 1.0), "background.sizes": ("background sizes", None),
    "background.offset": ("background offset [s]", 1.0), "nodes": ("nodes on the channel", None),
    "access.eifs": ("EIFS [µs]", 1e6), "generation_jitter": ("generation jitter [ms]", 1e3),
    "radio.power": ("transmit power [dBm]", 1.0), "radio.frequency": ("carrier [GHz]", 1e-9),
    "radio.noise": ("noise floor [dBm]", 1.0), "radio.sensitivity": ("sensitivity [dBm]", 1.0),
    "radio.carrier_sense": ("carrier sense threshold [dBm]", 1.0), "radio.path_loss.model": ("path loss", None),
    "radio.shadowing.model": ("shadowing", None), "radio.shadowing.sigma": ("shadowing σ [dB]", 1.0),
    "radio.fading.model": ("fading", None), "radio.fading.m": ("Nakagami m", 1.0),
    "radio.reception.model": ("reception", None), "radio.reception.sinr": ("SINR threshold [dB]", 1.0),
    "radio.capture": ("capture margin [dB]", 1.0),
}


def _channel_parameters(medium) -> list[tuple[str, object]]:
    """The ``medium:`` block of a stored scenario as (label with unit, value) rows: the keys of
    :data:`CHANNEL_KEYS` it has (numbers converted to the unit shown, anything else as text)."""
    rows: list[tuple[str, object]] = []
    if not isinstance(medium, dict):
        return rows
    for key, (label, factor) in CHANNEL_KEYS.items():
        value: Any = medium
        for part in key.split("."):
            value = value.get(part) if isinstance(value, dict) else None
        if value is None:
            continue
        if factor is not None and isinstance(value, (int, float)) and not isinstance(value, bool):
            value = value * factor if factor != 1.0 else value
        elif not isinstance(value, str):
            value = ", ".join(str(v) for v in value) if isinstance(value, (list, tuple)) else str(value)
        rows.append((label, value))
    return rows


def _channel_section(packets: dict, traffic: dict, medium=None) -> list[tuple[str, str]]:
    """A run with ``medium:``: one row per estimator whose traffic has a ``channel`` block
    (summary.json ``packets.channel`` for the DKF, ``traffic.<estimate>.channel`` for the others;
    ``fused`` and ``local`` are the DKF's), none otherwise."""
    blocks = [("DKF (anti-delay)", packets.get("channel"))]
    blocks += [(name, t.get("channel")) for name, t in traffic.items()
               if t is not None and name not in ("fused", "local")]
    rows = [(name, ch["utilisation"], ch["frames"], collided_percent(ch), ch["frames_dropped"],
             background_on_air(ch), ch["background_collided"], 1e3 * ch["access_delay_mean"])
            for name, ch in blocks if ch]
    if not rows:
        return []
    params = table("channel_parameters", ("parameter", "value"), _channel_parameters(medium),
                   "the channel of the scenario (medium:, docs/channel.md), in the units shown")
    params += _radio_table(blocks)
    return [("Shared channel", params + table("channel", (
        "estimator", "utilisation", "frames", "collided [%]", "dropped [frames]", "background on air",
        "background collided", "mean access delay [ms]"), rows,
        "the shared radio channel (summary.json traffic.<estimate>.channel): utilisation of the "
        "channel over the run, background included; the estimator's own frames, the percentage of "
        "them that collided and those its full radio queues refused; the background frames that "
        "went on the air and how many of them collided; the mean access delay of its frames, from hand-over to the start of "
        "transmission. Each estimator has its own copy of the channel unless links.shared_queues "
        "(the fusion centre shares the DKF's)"))]


def _radio_table(blocks: list) -> str:
    """A spatial radio's numbers per estimator's copy (``cbr_mean``, ``pairs``, ``losses`` by
    each cause any copy reports: :data:`~dkfsim.config.results.RADIO_CAUSES`), or nothing for
    one collision domain."""
    radio = [(name, ch) for name, ch in blocks if ch and ch.get("losses") is not None]
    if not radio:
        return ""
    causes = [c for c in RADIO_CAUSES if any(ch["losses"].get(c) is not None for _, ch in radio)]
    rows = []
    for name, ch in radio:
        pairs, losses = ch.get("pairs") or 0, ch["losses"]
        rows.append((name, ch.get("cbr_mean"), pairs,
                     100.0 * ch.get("pairs_received", 0) / pairs if pairs else None,
                     *(losses.get(c) for c in causes)))
    return table("radio", ("estimator", "CBR (mean over vehicles)", "(frame, receiver) pairs", "received [%]",
                           *(f"lost: {c.replace('_', ' ')}" for c in causes)), rows,
                 "the spatial radio (medium.radio, docs/radio.md): every (frame, receiver) pair of every frame on "
                 "the estimator's copy of the channel, background included, received or lost by cause: below "
                 "sensitivity, the receiver transmitting (half duplex) or locked on another frame, noise and "
                 "fading alone, interference (on a C-V2X reservation, or not); CBR: the share of the run each "
                 "vehicle sensed the channel busy (802.11p), or of its sub-channels found busy (C-V2X)")


def _uptime_section(record: dict | None) -> list[tuple[str, str]]:
    """A run with ``mobility:``: the fraction of the ticks each pair's link was up (summary.json
    ``mobility.link_uptime``), none otherwise."""
    if not record:
        return []
    rows = [(f"{int(u)}–{int(v)}", float(f)) for u, v, f in record["link_uptime"]]
    return [("Link up-time", table("link_uptime", ("pair", "up-time [fraction of ticks]"), rows,
                                   "the fraction of the run's ticks at which each pair's link was up "
                                   "(in the topology and in range; summary.json mobility.link_uptime)"))]


# =========================================================================== per kind
def run_page(folder: Path) -> str:
    s = read_record(folder / "summary.json", RunSummary, "summary.json")
    cfg = s["scenario_config"]
    sc = stored_or_unvalidated(cfg, s.get("source"), str(folder / "summary.json"))
    burn = s["metrics"]["burn_in"]
    rows = s["rows"]
    comps = components_of(rows)
    by = {(r["estimate"], r["component"]): r for r in rows}
    mse_rows = [(e, *(by[(e, c)]["mse"] for c in comps)) for e in s.get("estimates", [])]
    nees_rows = [(e, by[(e, comps[0])]["anees"], by[(e, comps[0])]["disagreement"])
                 for e in s.get("estimates", [])]
    p = s.get("packets") or {}
    blocks = [("DKF (anti-delay)", p)] + [(name, t) for name, t in (s.get("traffic") or {}).items()
                                         if isinstance(t, dict) and name not in ("fused", "local")]
    columns = packet_columns([t for _, t in blocks])
    pk = [(name, *packet_row(t, columns), count(t.get("late"))) for name, t in blocks]
    facts = [("kind", "single run"), ("seed", s.get("seed")), ("buffer length L", s.get("buffer_length")),
             ("d_t, d_g", f"{s.get('d_t')}, {s.get('d_g')}"), ("burn-in rows", burn)]
    sections = [
        ("Scenario", facts_table(sc, facts) + scenario_text(cfg)),
        ("Network", network_section(sc)),
        ("MSE", table("mse", ("estimate", *comps), mse_rows,
                      f"time-averaged squared error after {burn} burn-in rows (rows.csv)")),
        ("NEES", table("nees", ("estimate", "ANEES", "disagreement"), nees_rows,
                       f"time-averaged NEES after the burn-in; expected {len(comps)} when consistent")),
        ("Packets", table("packets", ("estimator", *(f"{PACKET_HEADS[c]} [packets]" for c in columns),
                                      "late [items]"),
                          pk, f"totals over the whole run ({s.get('steps')} ticks): sent + duplicate copies = "
                              "delivered + lost + dropped + in flight at end, for every estimator; lost "
                              "split by cause where the run has one; late items: contributions or "
                              "(packet, row) pairs for the DKF, stale packets for the others")),
        *_links_section(s.get("per_link") or []),
        *_channel_section(p, s.get("traffic") or {}, cfg.get("medium") if isinstance(cfg, dict) else None),
        *_uptime_section(s.get("mobility")),
        ("Figures", "\n".join(_figures(folder))),
        ("Versions and seeds", versions_table(s.get("versions"), [("seed", str(s.get("seed")))])),
    ]
    if s.get("diverged"):
        sections.insert(2, ("Diverged", f"<p>{html.escape(', '.join(s['diverged']))}</p>"))
    return html_page(f"dkfsim report: {s.get('scenario')}", f"a single run of {s.get('steps')} ticks",
                 sections)


def montecarlo_page(folder: Path) -> str:
    s = read_record(folder / "summary.json", MonteCarloSummary, "summary.json")
    cfg = s["scenario_config"]
    sc = stored_or_unvalidated(cfg, s.get("source"), str(folder / "summary.json"))
    comps = s.get("components") or []
    est = s.get("estimates") or {}
    mse_rows = [(name, *(Interval((e["mse"][c], *e["mse_ci95"][c])) for c in comps))
                 for name, e in est.items()]
    nees_rows = [(name, Interval((e.get("anees"), *(e.get("anees_ci95") or (None, None)))),
                  verdict(e.get("anees_consistent")), percent(e.get("anees_fraction_in_band")))
                 for name, e in est.items()]
    ref = paired_reference(est)
    paired_rows = [(name, *(Interval((e["paired"]["mse_ratio"].get(c),
                                      *e["paired"]["mse_ratio_ci95"].get(c, (None, None)))) for c in comps),
                    *(Interval((e["paired"]["mse_diff"].get(c),
                                *e["paired"]["mse_diff_ci95"].get(c, (None, None)))) for c in comps))
                   for name, e in est.items() if e.get("paired") and name != ref]
    counts = {name: e.get("packets") if isinstance(e.get("packets"), dict) else None for name, e in est.items()}
    columns = packet_columns(list(counts.values())) if any(counts.values()) else []
    pk = [(name, count(e.get("messages_per_tick")), count(e.get("bytes_per_tick")),
           *(packet_row(counts[name], columns) if columns else [count(e.get("lost"))]), count(e.get("late")))
          for name, e in est.items()]
    pk_head = ("estimate", *RATE_HEADS, *((f"{PACKET_HEADS[c]} [packets/run]" for c in columns) if columns
                                         else (LOST_HEAD,)), LATE_HEAD)
    seeds = _runs_seeds(folder / "runs.csv")
    facts = [("kind", "Monte Carlo"), ("runs", s.get("runs")), ("base seed", s.get("base_seed")),
             ("buffer length L", s.get("buffer_length")), ("d_t, d_g", f"{s.get('d_t')}, {s.get('d_g')}"),
             ("burn-in rows", s.get("burn_in"))]
    sections = [
        ("Scenario", facts_table(sc, facts) + scenario_text(cfg)),
        ("Network", network_section(sc)),
        ("MSE", table("mse", ("estimate", *(f"{c} MSE [95 % CI]" for c in comps)), mse_rows,
                      "mean over runs of the time-averaged MSE and its 95 % Student-t interval over runs")),
        ("NEES", table("nees", ("estimate", "ANEES [95 % CI over runs]", "consistent",
                                "ticks in per-tick band"),
                       nees_rows, f"consistent: the 95 % t-interval over runs of the time-averaged "
                       f"NEES covers nx = {len(comps)} (a correct filter fails it in 5 % of seeds); "
                       "ticks in per-tick band: fraction of ticks whose mean NEES lies in the "
                       "per-tick 95 % chi-square band (docs/statistics.md)")),
        ("Paired", table("paired", ("estimate", *(f"{c} MSE / {ref} [95 % CI]" for c in comps),
                                    *(f"{c} MSE − {ref} [95 % CI]" for c in comps)), paired_rows,
                         f"run by run against {ref} on the same draws: ratio = exponentiated mean "
                         "and t-interval of the per-run log-ratios; difference: t-interval of the "
                         "per-run differences")
         if paired_rows else "<p class='note'>No paired comparison (no reference estimate in "
                             "these runs).</p>"),
        ("Packets", table("packets", pk_head, pk,
                          "means over runs" + ("; per run: sent + duplicate copies = delivered + lost + "
                                               "dropped + in flight at end, lost split by cause where the "
                                               "runs have one" if columns else "") + f"; {PACKETS_NOTE}")),
        ("Figures", "\n".join(_figures(folder))),
        ("Versions and seeds", versions_table(s.get("versions"), [("seed rule", s.get("seed_rule", ""))])
         + folded(f"Seeds of the {len(seeds)} runs" + (", the first 50" if len(seeds) > 50 else "")
                  + " (the seed rule above)", table("seeds", ("run", "seed"), seeds[:50]))),
    ]
    return html_page(f"dkfsim report: {s.get('scenario')}",
                 f"Monte Carlo: {s.get('runs')} runs x {s.get('steps')} ticks", sections)


def percent(fraction) -> str | None:
    """A fraction as the figures write it (``93 %``), None when it is not a number."""
    value = count(fraction)
    return None if value is None else f"{100 * value:.0f} %"


def _runs_seeds(path: Path) -> list[tuple[int, int]]:
    return sorted(read_run_seeds(path).items()) if path.is_file() else []


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

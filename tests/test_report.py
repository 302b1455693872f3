"""dkfsim report: the page is one self-contained HTML file whose tables hold the
folder's numbers (read back with html.parser and compared with rows.csv,
summary.json and the sweep's stored rows)."""

from __future__ import annotations

import csv
import json
import math
import statistics
from html.parser import HTMLParser
from pathlib import Path

import pytest
import yaml
from scipy.stats import t as student_t

import dkfsim
from dkfsim.cli.main import main

ROOT = Path(__file__).resolve().parents[1]
CASE1 = ROOT / "scenarios" / "paper_case1.yaml"


class Page(HTMLParser):
    """Tables by id (rows of cell texts), image sources, captions and links."""

    def __init__(self, text: str):
        super().__init__()
        self.tables: dict[str, list[list[str]]] = {}
        self.images: list[str] = []
        self.external: list[str] = []
        self.captions: list[str] = []
        self._table = self._row = self._cell = None
        self._in_caption = False
        self.feed(text)

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        if tag == "table":
            self._table = self.tables.setdefault(a.get("id", f"t{len(self.tables)}"), [])
        elif tag == "tr" and self._table is not None:
            self._row = []
            self._table.append(self._row)
        elif tag in ("td", "th") and self._row is not None:
            self._cell = ""
        elif tag == "img":
            self.images.append(a.get("src", ""))
        elif tag == "figcaption":
            self._in_caption = True
            self.captions.append("")
        if tag in ("link", "script") and (a.get("href") or a.get("src")):
            self.external.append(a.get("href") or a.get("src"))

    def handle_endtag(self, tag):
        if tag in ("td", "th") and self._cell is not None:
            self._row.append(self._cell.strip())
            self._cell = None
        elif tag == "table":
            self._table = None
        elif tag == "figcaption":
            self._in_caption = False

    def handle_data(self, data):
        if self._cell is not None:
            self._cell += data
        if self._in_caption:
            self.captions[-1] += data


def close(cell: str, value, rel=6e-6) -> bool:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return cell in ("–", "nan")
    return float(cell) == pytest.approx(float(value), rel=rel, abs=1e-300)


def self_contained(page: Page):
    assert page.images and all(src.startswith("data:image/png;base64,") for src in page.images)
    assert not page.external


@pytest.fixture(scope="module")
def folders(tmp_path_factory):
    d = tmp_path_factory.mktemp("report")
    sc = dkfsim.load_scenario(CASE1, overrides=["steps=40", "estimators=[{kind: centralized}, "
                                                "{kind: ci_consensus, rounds: 2}]"])
    dkfsim.run(sc).save(d / "run")
    dkfsim.montecarlo(sc, runs=3).save(d / "mc")
    return d


def test_run_report_tables_hold_rows_csv(folders):
    assert main(["report", str(folders / "run")]) == 0
    page = Page((folders / "run" / "report.html").read_text())
    self_contained(page)
    with open(folders / "run" / "rows.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    head, *body = page.tables["mse"]
    comps = head[1:]
    assert comps == ["position", "velocity", "acceleration"]
    assert [r[0] for r in body] == ["fused", "local", "centralized", "ci_consensus"]
    for r in body:
        for comp, cell in zip(comps, r[1:]):
            want = next(x for x in rows if x["estimate"] == r[0] and x["component"] == comp)
            assert close(cell, float(want["mse"]))
    for r in page.tables["nees"][1:]:
        want = next(x for x in rows if x["estimate"] == r[0])
        assert close(r[1], float(want["anees"]))
    summary = json.loads((folders / "run" / "summary.json").read_text())
    dkf = page.tables["packets"][1]
    p = summary["packets"]
    assert [int(c) for c in dkf[1:]] == [p["sent"], p["copies"], p["delivered"], p["lost"], p["queue_dropped"],
                                         p["crash_dropped"], p["in_flight"], p["late"]]
    versions = dict((r[0], r[1]) for r in page.tables["versions"][1:])
    assert versions["numpy"] == summary["versions"]["numpy"] and versions["seed"] == str(summary["seed"])
    assert any("12 nodes" in c and "tree" in c for c in page.captions)


def test_montecarlo_report_tables_hold_summary_json(folders, tmp_path):
    out = tmp_path / "mc.html"
    assert main(["report", str(folders / "mc"), "--out", str(out)]) == 0
    page = Page(out.read_text())
    self_contained(page)
    s = json.loads((folders / "mc" / "summary.json").read_text())
    head, *body = page.tables["mse"]
    assert head == ["estimate"] + [f"{c} MSE [95 % CI]" for c in s["components"]]
    assert [r[0] for r in body] == list(s["estimates"])
    for name, *cells in body:
        e = s["estimates"][name]
        for comp, cell in zip(s["components"], cells):     # "MSE [low, high]", 5 significant digits
            mse, lo, hi = cell.replace("[", " ").replace(",", " ").replace("]", " ").split()
            assert close(mse, e["mse"][comp], 6e-5)
            assert close(lo, e["mse_ci95"][comp][0], 6e-5) and close(hi, e["mse_ci95"][comp][1], 6e-5)
    for name, anees, verdict, frac in page.tables["nees"][1:]:
        e = s["estimates"][name]
        mean, lo, hi = anees.replace("[", " ").replace(",", " ").replace("]", " ").split()
        assert close(mean, e["anees"], 6e-5) and close(lo, e["anees_ci95"][0], 6e-5) \
            and close(hi, e["anees_ci95"][1], 6e-5)
        nx = len(s["components"])          # the verdict, recomputed from the interval
        assert verdict == ("yes" if e["anees_ci95"][0] <= nx <= e["anees_ci95"][1] else "no")
        assert frac == f"{100 * e['anees_fraction_in_band']:.0f} %"      # as the NEES figure writes it
    with open(folders / "mc" / "runs.csv", newline="") as fh:
        seeds = {int(r["run"]): int(r["seed"]) for r in csv.DictReader(fh)}
    assert {int(r): int(sd) for r, sd in page.tables["seeds"][1:]} == seeds


def test_sweep_report_intervals_are_those_of_the_stored_rows(tmp_path):
    (tmp_path / "s.yaml").write_text(yaml.safe_dump({
        "scenario": str(CASE1), "grid": {"links.default.latency.d_t": [0, 3]},
        "set": ["steps=30", "estimators=[{kind: centralized}]"], "runs": 3}))
    assert main(["sweep", str(tmp_path / "s.yaml"), "--jobs", "1", "--quiet",
                 "--export", str(tmp_path / "s.csv")]) == 0
    assert main(["report", str(tmp_path)]) == 0          # the folder holding the database
    page = Page((tmp_path / "s.report.html").read_text())
    self_contained(page)
    with open(tmp_path / "s.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    head, *body = page.tables["mse"]
    assert head[:3] == ["d_t", "estimate", "runs"]        # the grid key's last part (in the facts in full)
    assert len(body) == 2 * 3                               # grid points x estimates
    for d_t, est, runs, *cells in body:
        assert int(runs) == 3 and len(cells) == 3           # "MSE [CI low, CI high]" per component
        for c, comp in enumerate(["position", "velocity", "acceleration"]):
            vals = [float(r["mse"]) for r in rows if r["links.default.latency.d_t"] == d_t
                    and r["estimate"] == est and r["component"] == comp]
            assert len(vals) == 3
            mean = statistics.fmean(vals)
            half = student_t.ppf(0.975, len(vals) - 1) * statistics.stdev(vals) / math.sqrt(len(vals))
            mse, lo, hi = cells[c].replace("[", " ").replace(",", " ").replace("]", " ").split()
            # printed with 5 significant digits
            assert close(mse, mean, 6e-5) and close(lo, mean - half, 6e-5) and close(hi, mean + half, 6e-5)


def test_big_networks_are_drawn_capped_and_say_so(tmp_path):
    d = yaml.safe_load(CASE1.read_text())
    d.pop("baselines", None)
    d.update(steps=12, fusion="none", estimators=[],
             topology={"generator": "random_tree", "directed": False, "params": {"seed": 3}},
             sensors=[{"name": f"s{i}", "H": [[1.0, 0.0, 0.0]], "R": [[1.0]]} for i in range(90)])
    dkfsim.run(d).save(tmp_path / "big")
    assert main(["report", str(tmp_path / "big")]) == 0
    page = Page((tmp_path / "big" / "report.html").read_text())
    assert any("Only 60 of the 90 nodes are drawn" in c for c in page.captions)


def test_report_of_a_wrong_path_is_one_paragraph(tmp_path, capsys):
    (tmp_path / "x.txt").write_text("hello")
    assert main(["report", str(tmp_path / "x.txt")]) == 2
    assert main(["report", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 2 and "neither a run folder" in err

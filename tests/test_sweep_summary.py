"""Sweep summaries and sweep plots: the summary's numbers are recomputed here from the
stored rows (Student-t interval by hand, chi-square band from scipy), a database and
its export give the same summary, and dkfsim plot draws either."""

from __future__ import annotations

import csv
import math
import statistics
from pathlib import Path

import pytest
import yaml
from scipy.stats import chi2
from scipy.stats import t as student_t

from dkfsim.cli.main import main

ROOT = Path(__file__).resolve().parents[1]
CASE1 = ROOT / "scenarios" / "paper_case1.yaml"
RUNS = 3


def read(path):
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


@pytest.fixture(scope="module")
def swept(tmp_path_factory):
    d = tmp_path_factory.mktemp("sweep")
    (d / "s.yaml").write_text(yaml.safe_dump({
        "scenario": str(CASE1), "grid": {"links.default.latency.d_t": [0, 3], "protocol": ["tree", "flood"]},
        "set": ["steps=30", "estimators=[{kind: centralized}, {kind: local_only}]"], "runs": RUNS}))
    assert main(["sweep", str(d / "s.yaml"), "--jobs", "1", "--export", str(d / "s.csv")]) == 0
    assert (d / "s.summary.csv").is_file()
    return d


def test_summary_interval_and_band_equal_those_computed_from_the_rows(swept):
    rows = read(swept / "s.csv")
    summary = read(swept / "s.summary.csv")
    assert len(summary) == len(rows) // RUNS
    t975 = student_t.ppf(0.975, RUNS - 1)
    for s in summary:
        mine = [r for r in rows if (r["param_hash"], r["estimate"], r["component"])
                == (s["param_hash"], s["estimate"], s["component"])]
        assert len(mine) == RUNS == int(s["runs"])
        assert s["links.default.latency.d_t"] == mine[0]["links.default.latency.d_t"]
        mse = [float(r["mse"]) for r in mine]
        mean, half = statistics.fmean(mse), t975 * statistics.stdev(mse) / math.sqrt(RUNS)
        assert float(s["mse"]) == pytest.approx(mean, rel=1e-12)
        assert float(s["mse_ci95_lo"]) == pytest.approx(mean - half, rel=1e-9, abs=1e-15)
        assert float(s["mse_ci95_hi"]) == pytest.approx(mean + half, rel=1e-9)
        anees = [float(r["anees"]) for r in mine if r["anees"] not in ("", "nan")]
        if not anees:                            # no covariance: no ANEES, no band
            assert s["anees"] == "" and s["anees_band95_lo"] == ""
        else:
            assert float(s["anees"]) == pytest.approx(statistics.fmean(anees), rel=1e-12)
            lo, hi = chi2.ppf([0.025, 0.975], RUNS * 3) / RUNS
            assert (float(s["anees_band95_lo"]), float(s["anees_band95_hi"])) == pytest.approx((lo, hi))
        msgs = [float(r["messages_per_tick"]) for r in mine if r["messages_per_tick"]]
        if msgs:
            assert float(s["messages_per_tick"]) == pytest.approx(statistics.fmean(msgs))
        else:                                    # centralized: no network model
            assert s["messages_per_tick"] == ""


def test_summary_of_the_export_equals_that_of_the_database(swept):
    from dkfsim.experiments.sweep.summary import write_summary
    path, n = write_summary(swept / "s.csv", swept / "from_export.csv")
    assert n > 0 and read(path) == read(swept / "s.summary.csv")


def test_plot_a_sweep_database_and_its_export(swept):
    assert main(["plot", str(swept / "s.sqlite"), "--x", "d_t", "--hue", "protocol",
                 "--out", str(swept / "figs")]) == 0
    assert (swept / "figs" / "mse_vs_d_t_by_protocol.png").stat().st_size > 1000
    assert (swept / "figs" / "mse_vs_d_t_by_protocol.pdf").read_bytes()[:4] == b"%PDF"
    assert main(["plot", str(swept / "s.csv"), "--x", "links.default.latency.d_t", "--where",
                 "protocol=tree", "--metric", "anees", "--format", "png", "--out", str(swept / "figs")]) == 0
    assert (swept / "figs" / "anees_vs_links_default_latency_d_t.png").is_file()


@pytest.mark.parametrize("args, message", [
    (["--x", "protocl"], "did you mean 'protocol'"),
    (["--x", "d_t"], "grid key protocol takes 2 values"),
    (["--x", "d_t", "--hue", "protocol", "--metric", "msee"], "not a column"),
    (["--x", "d_t", "--hue", "protocol", "--estimate", "fusd"], "did you mean 'fused'"),
    (["--x", "d_t", "--where", "protocol=ring"], "no rows"),
])
def test_bad_sweep_plot_flags_exit_2_with_one_paragraph(swept, args, message, capsys):
    assert main(["plot", str(swept / "s.sqlite"), *args, "--out", str(swept / "bad")]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1


def test_python_api_frames_equal_the_files(swept):
    import dkfsim
    rep = dkfsim.sweep(swept / "s.yaml", jobs=1)          # complete: resumes with nothing to do
    assert rep.computed == 0
    frame, summary = rep.to_frame(), rep.summary()
    rows, srows = read(swept / "s.csv"), read(swept / "s.summary.csv")
    assert list(frame.columns) == list(rows[0]) and len(frame) == len(rows)
    assert list(summary.columns) == list(srows[0]) and len(summary) == len(srows)
    for got, want in ((frame, rows), (summary, srows)):
        for i in (0, len(want) // 2, len(want) - 1):
            for c, cell in want[i].items():
                v = got.iloc[i][c]
                if cell == "" or cell == "nan":
                    assert v is None or v != v
                elif isinstance(v, str):
                    assert v == cell
                else:
                    assert float(v) == float(cell)

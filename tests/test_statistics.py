"""The consistency verdict and the paired comparisons, each recomputed here from the rows.

Monte Carlo on the shipped example (paper case 1 with the centralized filter and
``no_buffer``, fewer runs and ticks than the README so the suite stays quick): every number
of ``summary.json``'s ``anees_consistent`` and ``paired`` blocks is recomputed from
``runs.csv`` with scipy.stats by hand; the paired interval is narrower than the unpaired
(Welch) one; a sweep's summary columns likewise; ``dkfsim.load`` reads each kind of result.
"""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import numpy as np
import pytest
import yaml
from scipy import stats

import dkfsim
from dkfsim.cli.main import main
from dkfsim.core.errors import DkfsimError

ROOT = Path(__file__).resolve().parents[1]
CASE1 = ROOT / "scenarios" / "paper_case1.yaml"
RUNS = 12
ESTIMATORS = "estimators=[{kind: centralized}, {kind: no_buffer}]"


def read(path):
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def column(rows, estimate, component, key="mse"):
    """Per-run values in run order, from the CSV rows."""
    got = sorted((int(r["run"]), float(r[key])) for r in rows
                 if r["estimate"] == estimate and r["component"] == component)
    return np.array([v for _, v in got])


def t_by_hand(d):
    """Mean and 95 % Student-t interval of samples ``d``, with scipy.stats."""
    n = len(d)
    half = stats.t.ppf(0.975, n - 1) * np.std(d, ddof=1) / math.sqrt(n)
    return d.mean(), d.mean() - half, d.mean() + half


def welch_half_width(a, b):
    """Half-width of the 95 % Welch interval of mean(a) - mean(b) (unpaired)."""
    va, vb = np.var(a, ddof=1) / len(a), np.var(b, ddof=1) / len(b)
    df = (va + vb) ** 2 / (va ** 2 / (len(a) - 1) + vb ** 2 / (len(b) - 1))
    return stats.t.ppf(0.975, df) * math.sqrt(va + vb)


@pytest.fixture(scope="module")
def mc(tmp_path_factory):
    out = tmp_path_factory.mktemp("stats") / "mc"
    assert main(["montecarlo", str(CASE1), "--runs", str(RUNS), "--steps", "300", "--jobs", "1",
                 "--quiet", "--out", str(out), "--set", ESTIMATORS[:-1] + ", {kind: ci_consensus}]"]) == 0
    return out


def test_anees_consistent_is_the_t_interval_over_runs_covering_nx(mc):
    s = json.loads((mc / "summary.json").read_text())
    rows = read(mc / "runs.csv")
    nx = len(s["components"])
    verdicts = {}
    for name, e in s["estimates"].items():
        anees = column(rows, name, s["components"][0], "anees")
        mean, lo, hi = t_by_hand(anees)
        assert e["anees_ci95"] == pytest.approx([lo, hi], rel=1e-9)
        assert e["anees_consistent"] is bool(lo <= nx <= hi)
        verdicts[name] = e["anees_consistent"]
    # the exact filters are consistent here; ci_consensus over-states its covariance (ANEES ~ 2)
    assert verdicts["centralized"] is True and verdicts["fused"] is True
    assert verdicts["ci_consensus"] is False


def test_paired_interval_equals_the_one_computed_from_the_rows(mc):
    s = json.loads((mc / "summary.json").read_text())
    rows = read(mc / "runs.csv")
    assert s["relative_to"] == "centralized"
    for name in ("fused", "no_buffer", "local", "centralized"):
        p = s["estimates"][name]["paired"]
        assert p["reference"] == "centralized" and p["runs"] == RUNS
        for comp in s["components"]:
            a, b = column(rows, name, comp), column(rows, "centralized", comp)
            mean, lo, hi = t_by_hand(a - b)
            assert p["mse_diff"][comp] == pytest.approx(mean, rel=1e-9, abs=1e-15)
            assert p["mse_diff_ci95"][comp] == pytest.approx([lo, hi], rel=1e-9, abs=1e-15)
            m, lo, hi = t_by_hand(np.log(a) - np.log(b))
            assert p["mse_ratio"][comp] == pytest.approx(math.exp(m), rel=1e-9)
            assert p["mse_ratio_ci95"][comp] == pytest.approx([math.exp(lo), math.exp(hi)], rel=1e-9)


def test_paired_interval_is_narrower_than_the_unpaired_welch_interval(mc):
    """Common random numbers: the paired interval of fused - centralized (and no_buffer -
    centralized) is more than twice narrower than Welch's, which ignores the pairing."""
    s = json.loads((mc / "summary.json").read_text())
    rows = read(mc / "runs.csv")
    for name in ("fused", "no_buffer"):
        for comp in s["components"]:
            lo, hi = s["estimates"][name]["paired"]["mse_diff_ci95"][comp]
            welch = welch_half_width(column(rows, name, comp), column(rows, "centralized", comp))
            assert (hi - lo) / 2 < welch / 2, (name, comp, (hi - lo) / 2, welch)


def test_relative_to_names_the_reference_and_is_checked_before_any_run(tmp_path, capsys):
    out = tmp_path / "mc"
    assert main(["montecarlo", str(CASE1), "--runs", "3", "--steps", "60", "--jobs", "1", "--quiet",
                 "--out", str(out), "--set", ESTIMATORS, "--relative-to", "no_buffer"]) == 0
    s = json.loads((out / "summary.json").read_text())
    assert s["relative_to"] == "no_buffer"
    assert all(e["paired"]["reference"] == "no_buffer" for e in s["estimates"].values())
    zero = s["estimates"]["no_buffer"]["paired"]
    assert all(v == 0 for v in zero["mse_diff"].values()) and all(v == 1 for v in zero["mse_ratio"].values())
    assert main(["montecarlo", str(CASE1), "--runs", "3", "--steps", "60", "--jobs", "1",
                 "--out", str(tmp_path / "bad"), "--relative-to", "nobuffer"]) == 2
    assert "--relative-to nobuffer: not an estimate" in capsys.readouterr().err
    assert not (tmp_path / "bad").exists()


def test_a_single_run_has_no_verdict_and_no_interval():
    res = dkfsim.montecarlo(dkfsim.load_scenario(str(CASE1), overrides=["steps=60"]), runs=1, jobs=1)
    e = res.summary()["estimates"]["fused"]
    assert e["anees_consistent"] is None
    assert e["paired"]["mse_diff_ci95"]["position"] == [None, None]


def test_a_montecarlo_folder_loads_back_with_the_same_summary_and_rows(mc):
    res = dkfsim.load(mc)
    assert type(res).__name__ == "MonteCarloResult"
    saved = json.loads((mc / "summary.json").read_text())
    again = json.loads(json.dumps(res.summary()["estimates"]))
    assert again == saved["estimates"]
    frame, rows = res.to_frame(), read(mc / "runs.csv")
    assert list(frame.columns) == list(rows[0]) and len(frame) == len(rows)
    assert frame["mse"].to_numpy() == pytest.approx([float(r["mse"]) for r in rows], rel=0, abs=0)


def test_load_tells_the_kinds_apart(tmp_path):
    dkfsim.run(str(CASE1), steps=40).save(tmp_path / "run")
    assert type(dkfsim.load(tmp_path / "run")).__name__ == "RunResult"
    assert len(dkfsim.load(tmp_path / "run").to_frame()) == len(read(tmp_path / "run" / "rows.csv"))
    with pytest.raises(DkfsimError, match="not a result dkfsim wrote"):
        dkfsim.load(tmp_path)
    with pytest.raises(DkfsimError, match="no such file"):
        dkfsim.load(tmp_path / "missing")


@pytest.fixture(scope="module")
def swept(tmp_path_factory):
    d = tmp_path_factory.mktemp("sweep")
    (d / "s.yaml").write_text(yaml.safe_dump({
        "scenario": str(CASE1), "grid": {"links.default.latency.d_t": [0, 3], "protocol": ["tree", "flood"]},
        "set": ["steps=60", ESTIMATORS], "runs": 4}))
    assert main(["sweep", str(d / "s.yaml"), "--jobs", "1", "--quiet", "--export", str(d / "s.csv")]) == 0
    return d


def test_sweep_summary_paired_columns_equal_those_computed_from_the_rows(swept):
    rows, summary = read(swept / "s.csv"), read(swept / "s.summary.csv")
    checked = 0
    for s in summary:
        mine = [r for r in rows if r["param_hash"] == s["param_hash"] and r["component"] == s["component"]]
        a, b = column(mine, s["estimate"], s["component"]), column(mine, "centralized", s["component"])
        assert s["relative_to"] == "centralized"
        mean, lo, hi = t_by_hand(a - b)
        assert float(s["mse_diff"]) == pytest.approx(mean, rel=1e-9, abs=1e-15)
        if s["estimate"] != "centralized":
            assert (float(s["mse_diff_ci95_lo"]), float(s["mse_diff_ci95_hi"])) == pytest.approx((lo, hi), rel=1e-9)
            m, lo, hi = t_by_hand(np.log(a) - np.log(b))
            assert float(s["mse_ratio"]) == pytest.approx(math.exp(m), rel=1e-9)
            assert float(s["mse_ratio_ci95_hi"]) == pytest.approx(math.exp(hi), rel=1e-9)
            checked += 1
        anees = column(mine, s["estimate"], s["component"], "anees")
        _, lo, hi = t_by_hand(anees)
        assert s["anees_consistent"] == str(bool(lo <= 3 <= hi))
    assert checked == 4 * 3 * 3          # 4 grid points x (fused, local, no_buffer) x 3 components


def test_sweep_loads_and_plots_paired_ratios(swept):
    res = dkfsim.load(swept / "s.sqlite")
    assert type(res).__name__ == "SweepResult"
    assert len(res.to_frame()) == len(read(swept / "s.csv"))
    assert set(res.summary(relative_to="no_buffer")["relative_to"]) == {"no_buffer"}
    assert main(["plot", str(swept / "s.sqlite"), "--x", "d_t", "--where", "protocol=tree",
                 "--relative-to", "centralized", "--format", "png", "--out", str(swept / "f")]) == 0
    assert (swept / "f" / "mse_vs_d_t_relative_to_centralized.png").stat().st_size > 1000
    assert main(["plot", str(swept / "s.sqlite"), "--x", "d_t", "--hue", "protocol",
                 "--relative-to", "tree", "--format", "png", "--out", str(swept / "f")]) == 0
    assert main(["plot", str(swept / "s.sqlite"), "--x", "d_t", "--hue", "protocol",
                 "--relative-to", "star", "--format", "png", "--out", str(swept / "f")]) == 2


def test_hue_pairing_is_refused_when_seed_is_a_grid_key(tmp_path, capsys):
    (tmp_path / "s.yaml").write_text(yaml.safe_dump({
        "scenario": str(CASE1), "grid": {"seed": [1, 2], "protocol": ["tree", "flood"]},
        "set": ["steps=30", "estimators=[{kind: centralized}]"], "runs": 2}))
    assert main(["sweep", str(tmp_path / "s.yaml"), "--jobs", "1", "--quiet"]) == 0
    assert main(["plot", str(tmp_path / "s.sqlite"), "--x", "seed", "--hue", "protocol",
                 "--relative-to", "tree", "--format", "png"]) == 2
    assert "seed is a grid key" in capsys.readouterr().err


def test_an_unknown_reference_is_refused_with_the_same_words_everywhere(tmp_path):
    """``--relative-to`` is checked in one place (analysis.paired.reference_of) for a scenario,
    a sweep's summary and a sweep's plot; each message names what was searched and its estimates."""
    from dkfsim.experiments.montecarlo import check_reference
    from dkfsim.experiments.sweep.grid import summarize
    from dkfsim.report.sweep.plot import sweep_curves

    case1 = dkfsim.load_scenario(CASE1)
    with pytest.raises(DkfsimError) as e:
        check_reference(case1, "nobuffer")
    assert str(e.value) == ("--relative-to nobuffer: not an estimate of paper_case1 "
                            "(estimates: fused, local, centralized)")
    alone = dkfsim.load_scenario(CASE1, overrides=["fusion=none"])
    with pytest.raises(DkfsimError) as e:
        check_reference(alone, "fused")
    assert str(e.value) == ("--relative-to fused: not an estimate of paper_case1 (estimates: local, "
                            "centralized); the scenario has fusion: none, so there is no fused estimate")
    check_reference(case1, "local")                      # an estimate of the scenario: accepted
    columns = ["d_t", "param_hash", "run", "seed", "estimate", "component", "mse"]
    rows = [[d, f"h{d}", r, 7 + r, est, "position", 1.0 + r + d] for d in (0, 2) for r in (0, 1)
            for est in ("fused", "local")]
    with pytest.raises(DkfsimError) as e:
        summarize(columns, rows, relative_to="fuse")
    assert str(e.value) == "--relative-to fuse: not an estimate of the sweep (estimates: fused, local)"
    table = tmp_path / "s.csv"
    table.write_text("\n".join(",".join(map(str, r)) for r in [columns, *rows]) + "\n")
    with pytest.raises(DkfsimError) as e:
        sweep_curves(table, x="d_t", relative_to="fuse")
    assert str(e.value) == ("--relative-to fuse: not an estimate of the sweep (did you mean 'fused'?) "
                            "(estimates: fused, local)")
    assert sweep_curves(table, x="d_t", relative_to="local")["lines"]

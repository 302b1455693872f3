"""Monte Carlo: seeds, worker-count independence, the output contract, statistics that must hold.

* ``--jobs 1`` and ``--jobs 2`` write the same ``runs.csv`` (bytes) and ``curves.npz`` (arrays);
* run r does not depend on N (its seed is ``derive_seed(seed, r)``);
* the centralized Kalman filter's Monte Carlo MSE matches the steady-state Riccati covariance
  (solved independently with scipy), and the exact filters' ANEES lies in its chi-square band;
* with delays on paper case 1: centralized < anti-delay DKF (fused) < no buffer, and < local_only, each
  asserted per component with a one-sided paired t bound over independent runs.
"""

from __future__ import annotations

import csv
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import scipy.linalg
import yaml
from conftest import scenario
from scipy.stats import chi2

from dkfsim import load_scenario
from dkfsim.analysis.metrics import nees_band, paired_lower_bound, row_columns
from dkfsim.cli import main as cli
from dkfsim.config.plan import RunPlan
from dkfsim.core.errors import DkfsimError
from dkfsim.experiments.montecarlo import derive_seed, montecarlo, run_rows

ROOT = Path(__file__).resolve().parents[1]
CASE1 = ROOT / "scenarios" / "paper_case1.yaml"
ALL_BASELINES = "baselines=[centralized,centralized_delayed,no_buffer,local,ci_consensus]"


def dkfsim(*args):
    return subprocess.run([sys.executable, "-m", "dkfsim", *map(str, args)],
                          capture_output=True, text=True, cwd=ROOT, timeout=300)


def _npz(path):
    with np.load(path, allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


# --------------------------------------------------------------------------- seeds
def test_derive_seed_is_a_fixed_function_of_base_seed_and_run():
    # pinned: changing the rule silently would change every published Monte Carlo result
    assert derive_seed(1, 0) == 8431846347943309920
    seeds = [derive_seed(1, r) for r in range(200)]
    assert len(set(seeds)) == 200 and all(0 <= s < 2 ** 63 for s in seeds)
    assert derive_seed(2, 0) != derive_seed(1, 0)
    with pytest.raises(ValueError):
        derive_seed(1, -1)


def test_run_r_is_the_same_whatever_the_number_of_runs():
    sc = load_scenario(CASE1, overrides=["steps=30", "fusion=diagonal"])
    two, three = montecarlo(sc, 2), montecarlo(sc, 3)
    assert repr(two.rows) == repr(three.rows[:len(two.rows)])       # repr: nan == nan
    rows, curves = run_rows(sc, derive_seed(sc.seed, 2))
    assert repr([{**r, "run": 2} for r in rows]) == repr([r for r in three.rows if r["run"] == 2])
    assert rows[0]["seed"] == derive_seed(sc.seed, 2)
    np.testing.assert_array_equal(three.example["example_truth"], run_rows(sc, three.seeds[0])[1]["example_truth"])


# --------------------------------------------------------------------------- CLI
@pytest.mark.slow
def test_help_explains_every_option():
    p = dkfsim("montecarlo", "--help")
    assert p.returncode == 0
    for opt in ("FILE", "--runs", "--jobs", "--out", "--set", "--burn-in", "--steps", "--seed", "--quiet"):
        assert opt in p.stdout, opt
    assert "montecarlo" in dkfsim("--help").stdout


@pytest.mark.parametrize("flag, value", [("--runs", "0"), ("--jobs", "0"), ("--runs", "-3"),
                                         ("--burn-in", "20")])
def test_bad_flags_exit_2_naming_the_flag(flag, value, tmp_path, capsys):
    opts = {"--runs": "2", "--jobs": "1", "--steps": "20", "--burn-in": "2", flag: value}
    args = ["montecarlo", str(CASE1), "--out", str(tmp_path / "o"), "--quiet"]
    for k, v in opts.items():
        args += [k, v]
    assert cli.main(args) == 2
    err = capsys.readouterr().err
    assert flag in err and "Traceback" not in err
    assert not (tmp_path / "o").exists()


def test_api_rejects_bad_runs_and_jobs():
    sc = load_scenario(CASE1, overrides=["steps=10"])
    with pytest.raises(DkfsimError, match="--runs"):
        montecarlo(sc, 0)
    with pytest.raises(DkfsimError, match="--jobs"):
        montecarlo(sc, 1, jobs=0)


def test_a_failing_run_is_reported_by_run_and_seed_whatever_the_jobs(tmp_path, capsys, monkeypatch):
    # Runs 2 and 4 fail (a seed-dependent failure; the worker processes are
    # forked, so they inherit the patch): the lowest failing run is reported.
    import dkfsim.engine.driver
    from dkfsim.core.errors import ScenarioError
    bad = {derive_seed(0, 2), derive_seed(0, 4)}
    original = dkfsim.engine.driver.Run.run

    def flaky(self):
        if int(self.scenario.seed) in bad:
            raise ScenarioError("simulated failure", source=self.scenario.source)
        return original(self)

    monkeypatch.setattr(dkfsim.engine.driver.Run, "run", flaky)
    spec = tmp_path / "s.yaml"
    spec.write_text(yaml.safe_dump(scenario(4, steps=10, seed=0)))
    errs = []
    for jobs in ("1", "2"):
        assert cli.main(["montecarlo", str(spec), "--runs", "6", "--jobs", jobs, "--out",
                         str(tmp_path / "o"), "--quiet"]) == 2
        errs.append(capsys.readouterr().err)
    assert errs[0] == errs[1]
    assert f"run 2 (seed {derive_seed(0, 2)})" in errs[0] and "simulated failure" in errs[0]
    assert str(spec) in errs[0]


@pytest.mark.slow
def test_jobs_1_and_2_write_identical_results(tmp_path):
    outs = {}
    for jobs in (1, 2):
        out = tmp_path / f"j{jobs}"
        p = dkfsim("montecarlo", CASE1, "--runs", 5, "--jobs", jobs, "--steps", 40, "--seed", 11,
                   "--set", ALL_BASELINES, "--out", out)
        assert p.returncode == 0, p.stderr
        assert "fused" in p.stdout and "95% CI" in p.stdout
        outs[jobs] = out
    a, b = outs[1], outs[2]
    assert (a / "runs.csv").read_bytes() == (b / "runs.csv").read_bytes()
    za, zb = _npz(a / "curves.npz"), _npz(b / "curves.npz")
    assert sorted(za) == sorted(zb)
    for k in za:
        assert za[k].dtype == zb[k].dtype and np.array_equal(za[k], zb[k], equal_nan=za[k].dtype.kind == "f"), k
    sa, sb = (json.loads((d / "summary.json").read_text()) for d in (a, b))
    for s in (sa, sb):
        del s["wall_time_s"], s["jobs"]
    assert sa == sb


def test_output_contract(tmp_path):
    out = tmp_path / "mc"
    assert cli.main(["montecarlo", str(CASE1), "--runs", "3", "--steps", "40", "--burn-in", "5",
                     "--set", ALL_BASELINES, "--out", str(out), "--quiet"]) == 0
    algs = ["fused", "local", "centralized", "centralized_delayed", "no_buffer", "local_only",
            "ci_consensus"]
    comps = ["position", "velocity", "acceleration"]
    with open(out / "runs.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert tuple(rows[0]) == row_columns()
    assert len(rows) == 3 * len(algs) * len(comps)
    assert [(r["run"], r["estimate"], r["component"]) for r in rows] == \
        [(str(r), a, c) for r in range(3) for a in algs for c in comps]
    z = _npz(out / "curves.npz")
    K, A = 40, len(algs)
    assert list(z["estimates"]) == algs and list(z["components"]) == comps
    assert z["t"].shape == (K,) and z["nees_band"].shape == (2,)
    for key in ("mse", "mse_ci_lo", "mse_ci_hi", "example_x"):
        assert z[key].shape == (A, K, 3), key
    assert z["nees"].shape == (A, K)
    assert z["example_truth"].shape == (K, 3) and z["example_node0"].shape == (K, 3)
    assert np.all(z["mse_ci_lo"] <= z["mse"]) and np.all(z["mse"] <= z["mse_ci_hi"])
    np.testing.assert_allclose(z["nees_band"], chi2.ppf([0.025, 0.975], 3 * 3) / 3)
    s = json.loads((out / "summary.json").read_text())
    assert s["runs"] == 3 and s["burn_in"] == 5 and s["base_seed"] == 1 and s["scenario"] == "paper_case1"
    assert len(s["scenario_hash"]) == 64 and s["scenario_config"]["steps"] == 40
    assert list(s["estimates"]) == algs
    for name, a in s["estimates"].items():
        i = algs.index(name)
        for c, comp in enumerate(comps):
            per_run = [float(r["mse"]) for r in rows if r["estimate"] == name and r["component"] == comp]
            assert a["mse"][comp] == pytest.approx(np.mean(per_run))
            # the per-run time average after burn-in, pooled, is the time average of the pooled curve
            assert a["mse"][comp] == pytest.approx(z["mse"][i, 5:, c].mean())
            lo, hi = a["mse_ci95"][comp]
            assert lo < a["mse"][comp] < hi
        assert a["anees"] == pytest.approx(np.nanmean(z["nees"][i, 5:]))
        assert a["anees_band95"] == pytest.approx(list(z["nees_band"]))
    # example run = run 0: the per-node estimates show node 0, which for the DKF is x_local
    np.testing.assert_array_equal(z["example_x"][algs.index("local")], z["example_node0"])
    # traffic
    A_ = s["estimates"]
    assert A_["local_only"]["messages_per_tick"] == 0 and A_["local_only"]["bytes_per_tick"] == 0
    assert A_["centralized"]["messages_per_tick"] is None
    assert A_["centralized_delayed"]["messages_per_tick"] == 12 and A_["centralized_delayed"]["lost"] == 0
    dkf = A_["fused"]
    # bytes are measured per packet: header 16 B + per window row 8 + 8*(nx + nx(nx+1)/2) + ceil(n/8)
    # B; every packet holds at least one row (rows per packet are not in the summary)
    n, nx = load_scenario(CASE1).n, len(comps)
    pair = 8 * (nx + nx * (nx + 1) // 2)
    assert dkf["messages_per_tick"] > 11 and dkf["bytes_per_tick"] >= dkf["messages_per_tick"] * (16 + 8 + pair + -(-n // 8))
    assert A_["no_buffer"]["late"] > 0 and dkf["late"] == 0
    assert dkf["disagreement"] is None and A_["local"]["disagreement"] > 0
    assert A_["ci_consensus"]["messages_per_tick"] == 22          # one round per tick on 22 arcs
    # one (x, P) pair per ci_consensus packet: exactly 16 + 8*(nx + nx(nx+1)/2) bytes each
    assert A_["ci_consensus"]["bytes_per_tick"] == pytest.approx(A_["ci_consensus"]["messages_per_tick"] * (16 + pair),
                                                               rel=1e-12)
    assert A_["ci_consensus"]["disagreement"] > 0


def test_cli_pools_each_estimate_once_for_the_file_and_the_table(tmp_path, monkeypatch, capsys):
    """summary.json and the printed table come from one pooling per estimate (it walks every
    runs.csv row per component; doing it twice doubled the cost), and show the same numbers."""
    from dkfsim.experiments.montecarlo import MonteCarloResult
    calls: list[str] = []
    pool = MonteCarloResult.estimate_summary
    monkeypatch.setattr(MonteCarloResult, "estimate_summary",
                        lambda self, name: calls.append(name) or pool(self, name))
    out = tmp_path / "mc"
    assert cli.main(["montecarlo", str(CASE1), "--runs", "2", "--steps", "20", "--burn-in", "2",
                     "--jobs", "1", "--out", str(out)]) == 0
    s = json.loads((out / "summary.json").read_text())
    assert sorted(calls) == sorted(s["estimates"])
    fused = s["estimates"]["fused"]
    assert f"{fused['mse']['position']:.4g}" in capsys.readouterr().out


def test_without_fusion_and_with_a_generic_model():
    res = montecarlo(load_scenario(scenario(3, steps=20, fusion="none")), 2, burn_in=0)
    assert res.estimates == ["local", "centralized"]
    assert res.components == ["x0", "x1"]
    assert res.mse.shape == (2, 20, 2) and np.isfinite(res.nees).all()


# --------------------------------------------------------------------------- statistics
def _steady_state(sc):
    """Filtered steady-state covariance of the centralized KF, from the DARE (independent of dkfsim)."""
    Phi = np.array(sc["model"]["Phi"], dtype=float)
    Q = np.array(sc["model"]["Q"], dtype=float)
    H = np.vstack([np.array(s["H"], dtype=float) for s in sc["sensors"]])
    R = scipy.linalg.block_diag(*[np.array(s["R"], dtype=float) for s in sc["sensors"]])
    Pp = scipy.linalg.solve_discrete_are(Phi.T, H.T, Q, R)        # predicted
    Omega = H.T @ np.linalg.solve(R, H)
    return np.linalg.inv(np.linalg.inv(Pp) + Omega)


def test_centralized_mse_matches_riccati_and_exact_filters_are_consistent():
    # 2-state model, 4 nodes, zero latency, 40 ticks (converged after ~20), 240 independent runs
    spec = scenario(4, steps=40, seed=3)
    P = _steady_state(spec)
    N, nx = 240, 2
    res = montecarlo(load_scenario(spec), N, jobs=2, burn_in=20)
    algs = res.estimates
    c = algs.index("centralized")

    # last tick of each run (independent across runs): mean of e^2 / P_cc ~ chi2(N) / N per component
    lo99, hi99 = chi2.ppf([0.005, 0.995], N) / N
    for comp in range(nx):
        ratio = res.mse[c, -1, comp] / P[comp, comp]
        assert lo99 < ratio < hi99, (comp, ratio, (lo99, hi99))
    # time average after burn-in: the t-interval over runs covers the Riccati variance
    s = res.estimate_summary("centralized")
    for comp, name in enumerate(res.components):
        lo, hi = s["mse_ci95"][name]
        assert lo < P[comp, comp] < hi, (name, lo, P[comp, comp], hi)

    band = nees_band(N, nx)
    np.testing.assert_allclose(res.nees_band, band)
    for name in ("centralized", "fused", "local"):
        a = algs.index(name)
        s = res.estimate_summary(name)
        assert band[0] < res.nees[a, -1] < band[1], (name, res.nees[a, -1], band)
        assert band[0] < s["anees"] < band[1], (name, s["anees"])
        assert s["anees_ci95"][0] < nx < s["anees_ci95"][1], (name, s["anees_ci95"])
        assert s["anees_fraction_in_band"] >= 0.8, (name, s["anees_fraction_in_band"])
    # the band has power: a covariance 1.5 times too large would be caught
    assert not band[0] < res.nees[c, -1] / 1.5 < band[1]
    # zero latency: the fused DKF is the centralized filter (to rounding)
    np.testing.assert_allclose(res.mse[algs.index("fused")], res.mse[c], rtol=1e-8)


def test_with_delays_centralized_beats_dkf_beats_no_buffer_and_local():
    sc = load_scenario(CASE1, overrides=["steps=300", "baselines=[centralized,no_buffer,local]"])
    res = montecarlo(sc, 30, jobs=2)
    for comp in res.components:
        cen, dkf, nob, loc = (res.column(a, "mse", comp)
                              for a in ("centralized", "fused", "no_buffer", "local_only"))
        # one-sided 95 % lower bounds of the paired mean differences over independent runs
        assert paired_lower_bound(cen, dkf) > 0, comp
        assert paired_lower_bound(dkf, nob) > 0, comp
        assert paired_lower_bound(dkf, loc) > 0, comp


def test_random_topology_is_the_same_graph_in_every_run():
    """Runs redraw noise and latency, not the network (seed pinned to the base seed)."""
    import dkfsim
    from dkfsim.experiments.montecarlo import pinned_topology
    d = dkfsim.load_scenario(ROOT / "scenarios" / "paper_case1.yaml").to_dict()
    d["topology"] = {"directed": False, "generator": "random_tree"}
    d["seed"] = 11
    assert pinned_topology(d) == ["topology.params.seed=11"]
    g1 = RunPlan(dkfsim.load_scenario(d, overrides=pinned_topology(d) + ["seed=5"])).graph
    g2 = RunPlan(dkfsim.load_scenario(d, overrides=pinned_topology(d) + ["seed=6"])).graph
    assert sorted(g1.edges()) == sorted(g2.edges())
    # An explicit seed or a deterministic generator is left alone.
    d["topology"]["params"] = {"seed": 3}
    assert pinned_topology(d) == []

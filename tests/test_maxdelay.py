"""``dkfsim maxdelay``: the sequential search finds answers known by construction,
the worst case dominates random delays, the paper's bound matches a hand
computation, and the command line reports bad input in one paragraph."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

import dkfsim
from dkfsim.analysis.bounds import (
    delay_bound_formula,
    omega_min_of,
    paper_bound,
    paper_bound_for_scenario,
    paper_weight_matrix,
)
from dkfsim.config.plan import RunPlan
from dkfsim.core.errors import DkfsimError
from dkfsim.experiments.maxdelay import EXCEEDS, UNDECIDED, WITHIN, MaxDelay, Settings, make_axis, metric_value
from dkfsim.experiments.maxdelay.report import pow10_text
from dkfsim.experiments.montecarlo import derive_seed
from dkfsim.report.maxdelay import plot_maxdelay

ROOT = Path(__file__).resolve().parents[1]
SEED = 3


def rw_scenario(latency, *, n=5, q=1.0, R=4.0, steps=60, fusion="matrix"):
    """A scalar random walk seen by n equal sensors on a path, T = 1 s."""
    return {"name": "rw", "seed": SEED, "steps": steps,
            "model": {"kind": "linear", "T": 1.0, "Phi": [[1.0]], "Q": [[q]]},
            "prior": {"mean": [0.0], "cov": [[1.0]]},
            "sensors": [{"name": f"s{i}", "H": [[1.0]], "R": [[R]]} for i in range(n)],
            "topology": {"generator": "path"},
            "links": {"default": {"latency": latency}},
            "fusion": fusion, "baselines": []}


def steps_latency(d):
    return {"model": "uniform_steps", "d_t": d}


def const_latency(seconds):
    return {"model": "constant", "value": float(seconds)}


def run_metric(data, metric, r=None, burn=None):
    sc = dkfsim.load_scenario(data, overrides=[] if r is None else [f"seed={derive_seed(SEED, r)}"])
    res = dkfsim.run(sc, save="estimates")
    return metric_value(res.arrays, metric, 0, sc.steps // 10 if burn is None else burn)


def search(data, **kw):
    return MaxDelay(dkfsim.load_scenario(data), Settings(**kw)).run()


# =========================================================================== answers known by construction
def test_trace_P_answer_2_by_construction_decided_at_first_look():
    """Tolerance halfway between the mean trace(P_fused) at d_t = 2 and 3 over the
    runs the search will use (same derived seeds) -> answer 2, 5 runs each."""
    v = {d: np.mean([run_metric(rw_scenario(steps_latency(d)), "trace_P", r) for r in range(5)])
         for d in (2, 3)}
    assert v[3] > v[2] * 1.03
    tol = 0.5 * (v[2] + v[3])
    res = search(rw_scenario(steps_latency(1)), metric="trace_P", tolerance=tol, batch=5,
                 max_runs=20, max_delay=8)
    assert res.emp.status == "decided"
    assert res.answer == 2
    cands = res.md.cands
    assert set(cands) <= {0, 1, 2, 3, 4}                      # gallop 0,1,2,4 then bisect 3
    assert cands[0].deterministic and cands[0].runs == 1      # no latency: nothing random in P
    assert all(c.runs == 5 for j, c in cands.items() if j > 0)  # decided at the first look
    assert cands[2].decision == WITHIN and cands[2].ci[1] < tol
    assert cands[3].decision == EXCEEDS and cands[3].ci[0] > tol
    assert cands[2].mean == pytest.approx(v[2], rel=1e-12)    # the same runs as above
    d = res.to_dict()["empirical"]
    assert d["at_answer"]["delay"] == 2 and d["at_answer_plus_1"]["delay"] == 3

    # The same boundary with a cap of 5 runs and the tolerance exactly at the mean of
    # d_t = 2: its interval straddles the tolerance -> undecided; the answer falls back
    # to the largest delay decided within (1).
    res = search(rw_scenario(steps_latency(1)), metric="trace_P", tolerance=v[2], batch=5,
                 max_runs=5, max_delay=8)
    assert res.md.cands[2].decision == UNDECIDED
    assert res.emp.status == "undecided"
    assert res.answer == 1


def _monotone_constant_values(delays):
    data = {d: rw_scenario(const_latency(d), q=0.05) for d in delays}
    return {d: run_metric(data[d], "trace_P") for d in delays}


def test_constant_latency_is_deterministic_one_run_per_candidate():
    """Constant latencies: trace(P_fused) depends on nothing random, so each
    candidate of the scale axis takes ONE run, and the empirical curve IS the
    worst-case curve."""
    v = _monotone_constant_values(range(0, 5))
    assert all(v[d + 1] > v[d] for d in range(4))              # monotone on this scenario
    tol = 0.5 * (v[2] + v[3])
    res = search(rw_scenario(const_latency(1.0), q=0.05), metric="trace_P", tolerance=tol,
                 scale_step=1.0, max_scale=8.0)
    assert res.md.axis.mode == "scale"
    assert res.emp.status == "decided" and res.answer == 2.0
    assert all(c.deterministic and c.runs == 1 for c in res.md.cands.values())
    assert res.wc.status == "decided" and res.md.axis.value(res.wc.answer) == 2.0
    common = set(res.md.cands) & set(res.md.wc)
    assert {0, 1, 2, 3} <= common                              # the scan stops at 3 (exceeds)
    for j in common:
        assert res.md.wc[j].mean == pytest.approx(res.md.cands[j].mean, rel=1e-12)

    # Relative: R between v3/v0 and v2/v0 -> answer 2; the zero-delay reference is exact.
    rho = 0.5 * (v[2] + v[3]) / v[0]
    res = search(rw_scenario(const_latency(1.0), q=0.05), metric="trace_P", relative=rho,
                 scale_step=1.0, max_scale=8.0)
    assert res.answer == 2.0 and res.emp.status == "decided"
    assert res.reference["mean"] == pytest.approx(v[0], rel=1e-12)
    assert res.to_dict()["tolerance"]["reference"]["tolerance"] == pytest.approx(rho * v[0])


def test_monte_carlo_metric_spends_runs_near_the_boundary():
    """local_mse (random through the data) on a 4-node path: its means are about
    0.61, 0.92, 1.09, 1.17, 1.24 at d_t = 0..4 (keyed link draws; 200 runs at d_t = 1, 2,
    40 at the others; sd of one run about 0.08 at d_t = 0, 0.12 at d_t >= 2, so 40 runs
    give +- 0.04), so a tolerance of 1.13, midway between d_t = 2 and 3, has the answer 2.
    Candidates far from the boundary are decided at the first look; the runs go
    to d_t = 2 and 3."""
    data = rw_scenario(steps_latency(1), n=4, steps=200)
    res = search(data, metric="local_mse", tolerance=1.13, batch=5, max_runs=40, max_delay=8)
    runs = {j: c.runs for j, c in res.md.cands.items()}
    assert res.emp.status == "decided" and res.answer == 2, runs
    assert runs[0] == 5 and runs[1] == 5
    near = runs[2] + runs[3]
    assert near > 0.5 * sum(runs.values()), runs
    assert max(runs[2], runs[3]) > 5
    assert all(runs[j] <= max(runs[2], runs[3]) for j in runs)
    assert sum(runs.values()) < 0.5 * len(runs) * 40


class FakeEvaluator:
    """Decisions given per candidate; counts what the search asks for."""

    def __init__(self, decisions, excess):
        self.decisions, self.excess, self.cands, self.asked = decisions, excess, {}, []

    def __call__(self, j):
        from dkfsim.experiments.maxdelay import Candidate
        self.asked.append(j)
        c = Candidate(index=j, delay=j, deterministic=False, decision=self.decisions(j),
                      excess_mean=self.excess(j))
        self.cands[j] = c
        return c


def test_search_logic_gallop_bisect_and_undecided_boundary():
    from dkfsim.experiments.maxdelay import empirical_search, worst_case_scan
    # monotone, boundary between 11 and 12: gallop 0,1,2,4,8,16 then bisect 12, 10, 11
    ev = FakeEvaluator(lambda j: WITHIN if j <= 11 else EXCEEDS, lambda j: j - 11.5)
    res = empirical_search(ev, 32)
    assert (res.status, res.answer, res.first_exceeding) == ("decided", 11, 12)
    assert ev.asked == [0, 1, 2, 4, 8, 16, 12, 10, 11]
    # undecided plateau 9..14 (means on both sides of the tolerance): the answer is the
    # largest delay decided within (8); 9 is evaluated for the CI at answer + 1
    ev = FakeEvaluator(lambda j: WITHIN if j <= 8 else (UNDECIDED if j <= 14 else EXCEEDS),
                       lambda j: j - 13.5)
    res = empirical_search(ev, 32)
    assert (res.status, res.answer) == ("undecided", 8) and 9 in ev.cands
    # nothing exceeds up to the cap; zero delay already exceeds
    assert empirical_search(FakeEvaluator(lambda j: WITHIN, lambda j: -1), 8).status == "capped"
    res = empirical_search(FakeEvaluator(lambda j: EXCEEDS, lambda j: 1), 8)
    assert (res.status, res.answer) == ("none", None)
    # the worst case scans and stops at the first exceeding delay, even if a later one is within
    ev = FakeEvaluator(lambda j: EXCEEDS if j == 3 else WITHIN, lambda j: 0)
    res = worst_case_scan(ev, 8)
    assert (res.status, res.answer, ev.asked) == ("decided", 2, [0, 1, 2, 3])


# =========================================================================== worst case
def test_worst_case_dominates_random_delays_trace_P():
    md = MaxDelay(dkfsim.load_scenario(rw_scenario(steps_latency(1))),
                  Settings(metric="trace_P", tolerance=1.0))
    ax = md.axis
    for d in (1, 2, 3):
        wc = run_metric(ax.scenario(d, ax.worst_overrides(d)), "trace_P")
        rnd = [run_metric(ax.scenario(d), "trace_P", r) for r in range(4)]
        assert wc >= max(rnd), (d, wc, rnd)
    # and the worst case is what the constant latency d*T gives
    assert run_metric(ax.scenario(2, ax.worst_overrides(2)), "trace_P") == \
        pytest.approx(run_metric(rw_scenario(const_latency(2.0)), "trace_P"), rel=1e-12)


def test_the_worst_case_and_the_bound_follow_the_estimate_searched():
    """``--metric mse --estimate local`` has the worst case of ``--metric local_mse``: the DKF
    nodes' own covariance, ``P_local`` (it used ``P_fused``: on paper case 1 "d_t >= 32" where the
    nodes' own estimates exceed at 1). For another estimator than the DKF, whose covariance neither
    follows, no worst case or paper's bound is computed, and the table says why."""
    data = rw_scenario(steps_latency(1))
    kw = dict(relative=1.2, max_delay=3, batch=2, max_runs=2)
    local, twin, fused = (search(data, metric="mse", estimate="local", **kw), search(data, metric="local_mse", **kw),
                          search(data, metric="fused_mse", **kw))
    assert (local.wc_tol, local.limit) == (twin.wc_tol, twin.limit)
    assert [c.values for c in local.wc.candidates.values()] == [c.values for c in twin.wc.candidates.values()]
    assert local.limit != fused.limit
    assert local.to_dict()["worst_case"]["metric"].endswith("of the node estimates, mean over nodes")
    other = search({**data, "estimators": [{"kind": "local_only"}]}, metric="mse", estimate="local_only", **kw)
    assert other.wc is None and other.runs_total == other.runs_empirical
    assert "local_only" in other.paper["error"]
    assert "(2) worst case:  not computed (it follows the anti-delay DKF's covariance, not local_only's)" \
        in other.table()


# =========================================================================== the delay axis
def test_axis_scales_every_time_parameter_and_links_d_t():
    data = rw_scenario({"model": "uniform", "low": 0.5, "high": 1.5})
    data["links"]["overrides"] = [{"link": [1, 2], "latency": {"model": "exponential", "mean": 0.2,
                                                               "offset": 0.1}}]
    data["links"]["d_t"] = 3
    sc = dkfsim.load_scenario(data)
    ax = make_axis(sc, max_delay=8, scale_step=0.5, max_scale=4.0)
    assert ax.mode == "scale" and ax.max_index == 8
    assert set(ax.describe()["keys"]) >= {"links.default.latency.low", "links.default.latency.high",
                                          "links.overrides.0.latency.mean",
                                          "links.overrides.0.latency.offset"}
    s2 = ax.scenario(4)                                        # s = 2
    assert s2.links.default.latency.low == pytest.approx(1.0)
    assert s2.links.default.latency.high == pytest.approx(3.0)
    ov = s2.links.overrides[0].latency
    assert (ov.mean, ov.offset) == (pytest.approx(0.4), pytest.approx(0.2))
    assert s2.links.d_t == 6
    s0 = ax.scenario(0)                                        # s = 0: no latency at all
    assert s0.links.default.latency.model == "constant" and s0.links.default.latency.value == 0
    w = ax.scenario(4, ax.worst_overrides(4))                  # every link at its largest latency
    assert w.links.default.latency.model == "constant"
    assert w.links.default.latency.value == pytest.approx(3.0)              # high * s
    assert w.links.overrides[0].latency.value == pytest.approx(6.0)         # links.d_t(s) * T
    # d_t axis: every uniform_steps model and links.d_t follow the candidate
    data = rw_scenario(steps_latency(4))
    data["links"]["overrides"] = [{"link": [0, 1], "latency": steps_latency(1)}]
    ax = make_axis(dkfsim.load_scenario(data), max_delay=8, scale_step=1, max_scale=1)
    s3 = ax.scenario(3)
    assert ax.mode == "d_t" and s3.links.default.latency.d_t == 3
    assert s3.links.overrides[0].latency.d_t == 3
    assert RunPlan(s3).buffer_length() == 3 * 4 + 1            # buffer follows d_t (d_g = 4)


def test_axis_rejects_mixed_models():
    data = rw_scenario(steps_latency(2))
    data["links"]["overrides"] = [{"link": [0, 1], "latency": const_latency(0.5)}]
    with pytest.raises(DkfsimError, match="mix uniform_steps"):
        make_axis(dkfsim.load_scenario(data), max_delay=8, scale_step=1, max_scale=2)


# =========================================================================== the paper's bound
def test_paper_bound_matches_hand_computation_on_one_state():
    a, q, Rs, p0, p_tol = 1.2, 0.5, (2.0, 1.0, 4.0), 10.0, 1.0
    import networkx as nx
    g = nx.path_graph(3)
    b = paper_bound([[a]], [[q]], [[[1 / r]] for r in Rs], [[p0]], g, p_tol)
    om = sum(1 / r for r in Rs)                                # H' R^-1 H summed: 1.75
    n, nbar = 3, 1                                             # observable at once; n_bar >= 1
    assert (b.n, b.n_bar, b.Z) == (n, nbar, n + nbar)
    assert b.alpha == pytest.approx(om * (1 + a ** 2))
    assert b.alpha_bar == pytest.approx(om * sum(a ** (2 * l) for l in range(nbar + n)))
    assert b.eta == pytest.approx(1 / a)
    # steady state of the centralized Riccati (P0 = 10 above it: information grows to it)
    r_e = 1 / om
    B = q + r_e * (1 - a ** 2)
    p_ss = (-B + math.sqrt(B ** 2 + 4 * a ** 2 * q * r_e)) / (2 * a ** 2)
    gamma = 1 / (1 + q * (1 / p_ss) / a ** 2)
    assert b.gamma_hat == pytest.approx(gamma, rel=1e-9)
    # W = [[1, 1, 0], [1/2, 1, 1/2], [0, 1, 1]]: W^1 has zeros, W^2 = [[1.5, 2, .5], ...]
    assert paper_weight_matrix(g) == pytest.approx(np.array([[1, 1, 0], [.5, 1, .5], [0, 1, 1]]))
    assert (b.omega_min_literal, b.omega_min) == (0.0, pytest.approx(0.5))
    assert b.omega_detail["sigma_0"] == 2
    Z = n + nbar
    d_star = math.log(p_tol * 0.5 * b.alpha_bar * a ** 2) / (-(Z + 1) * math.log(gamma / a ** 2))
    assert b.d_star == pytest.approx(d_star, rel=1e-9)
    assert 0 < d_star < 1 and b.d_t_bound == 0 and b.meaningful
    assert b.d_star_literal == -math.inf
    # d* is the fixed point of eq. (delay_bound) as printed, with varpi = gamma_hat^d*
    printed = delay_bound_formula(p_tol, gamma_hat=b.gamma_hat, eta=b.eta, Z=Z, omega_min=0.5,
                                  varpi=b.gamma_hat ** d_star, alpha_bar=b.alpha_bar)
    assert printed == pytest.approx(d_star, rel=1e-9)
    # the guaranteed covariance at d* is exactly the tolerance
    assert b.lambda_max_bound(d_star) == pytest.approx(p_tol, rel=1e-9)


def test_omega_min_directed_starts_at_n():
    import networkx as nx
    ring = nx.DiGraph([(0, 1), (1, 2), (2, 0)])
    W = paper_weight_matrix(ring)
    assert W == pytest.approx(np.array([[1, 0, 1], [1, 1, 0], [0, 1, 1]]))
    d = omega_min_of(W, 5, sigma_from=3)
    assert d["sigma_0"] == 3 and d["omega_min"] == pytest.approx(2.0)   # (I + P)^3 = 2I + 3P + 3P^2


def test_paper_bound_on_paper_case1_is_meaningless():
    sc = dkfsim.load_scenario(ROOT / "scenarios" / "paper_case1.yaml", overrides=["steps=300"])
    b = paper_bound_for_scenario(sc, 0.3)
    assert (b.n, b.n_bar, b.Z) == (12, 1, 13)
    assert b.omega_min_literal == 0.0 and b.d_star < 0 and not b.meaningful
    assert b.lambda_max_bound(1) > 1e10                        # one step of delay: nothing left


# =========================================================================== command line
def dkfsim_cli(*args):
    return subprocess.run([sys.executable, "-m", "dkfsim", *map(str, args)], capture_output=True,
                          text=True, cwd=ROOT)


@pytest.mark.slow
def test_cli_end_to_end_writes_json_and_plots(tmp_path):
    f = tmp_path / "rw.yaml"
    f.write_text(yaml.safe_dump(rw_scenario(const_latency(1.0), q=0.05)))
    out = tmp_path / "out"
    p = dkfsim_cli("maxdelay", f, "--metric", "trace_P", "--relative", 1.3, "--scale-step", 1,
                   "--max-scale", 6, "--out", out)
    assert p.returncode == 0, p.stderr
    for key in ("(1) empirical", "(2) worst case", "(3) paper bound", "gamma_hat", "omega_min"):
        assert key in p.stdout
    d = json.loads((out / "maxdelay.json").read_text())
    assert d["axis"]["mode"] == "scale" and d["axis"]["keys"] == ["links.default.latency.value"]
    assert d["tolerance"]["kind"] == "relative" and d["tolerance"]["reference"]["runs"] >= 1
    cands = d["empirical"]["candidates"]
    assert cands and all({"delay", "runs", "ci", "decision", "values"} <= set(c) for c in cands)
    assert d["empirical"]["status"] in ("decided", "capped")
    for key in ("alpha_bar", "eta", "gamma_hat", "omega_min", "Z", "d_star", "p_tol"):
        assert key in d["paper_bound"]
    assert d["worst_case"]["no_exchange_limit"] is not None
    assert (out / "maxdelay.png").stat().st_size > 0 and (out / "maxdelay.pdf").stat().st_size > 0
    assert "maxdelay" in dkfsim_cli("--help").stdout
    h = dkfsim_cli("maxdelay", "--help").stdout
    for opt in ("--metric", "--component", "--tolerance", "--relative", "--max-runs", "--batch",
                "--max-delay", "--scale-step", "--steps", "--jobs", "--out"):
        assert opt in h


@pytest.mark.parametrize("args, data_change, expected", [
    (["--tolerance", "0"], None, "--tolerance: must be a finite number > 0"),
    (["--relative", "0.8"], None, "--relative: must be a finite factor > 1"),
    (["--tolerance", "1", "--component", "speed"], None, "--component: unknown component"),
    (["--tolerance", "1", "--max-runs", "3"], None, "--max-runs: must be >= --batch"),
    (["--tolerance", "1"], "mixed", "mix uniform_steps"),
    (["--tolerance", "1"], "nofusion", "fusion: none"),
])
@pytest.mark.slow
def test_cli_bad_input_is_one_paragraph(tmp_path, args, data_change, expected):
    data = rw_scenario(steps_latency(1), steps=20)
    if data_change == "mixed":
        data["links"]["overrides"] = [{"link": [0, 1], "latency": const_latency(0.5)}]
    if data_change == "nofusion":
        data["fusion"] = "none"
    f = tmp_path / "s.yaml"
    f.write_text(yaml.safe_dump(data))
    p = dkfsim_cli("maxdelay", f, "--out", tmp_path / "o", *args)
    assert p.returncode == 2
    assert expected in p.stderr
    assert p.stderr.startswith("dkfsim maxdelay: error:") and "Traceback" not in p.stderr
    assert len(p.stderr.strip().splitlines()) == 1


def test_capped_answer_names_the_option_and_the_figure_has_units_and_only_what_occurred(tmp_path):
    # Constant 1 s latencies on a random walk: with a 100x relative tolerance every scale up
    # to --max-scale 2 is within, so the search is capped.
    res = search(rw_scenario(const_latency(1.0), q=0.05), metric="trace_P", relative=100.0,
                 scale_step=1.0, max_scale=2.0)
    assert res.emp.status == "capped"
    table = res.table()
    assert "capped" in table and "raise it with --max-scale" in table
    drawn = plot_maxdelay(res, tmp_path / "maxdelay")
    assert "[" in drawn["xlabel"] and "latency scale" in drawn["xlabel"]
    assert drawn["ylabel"].startswith("trace of P_fused")
    assert "decided within" in drawn["legend"]
    assert "decided exceeds" not in drawn["legend"] and "undecided (run cap)" not in drawn["legend"]
    assert not any("10^" in t for t in drawn["texts"] + drawn["legend"])
    assert (tmp_path / "maxdelay.png").stat().st_size > 0


def test_powers_of_ten_print_as_plain_numbers():
    assert pow10_text(-0.0549) == "0.8813"          # 10^-0.0549 = exp(-0.12641) = 0.88125
    assert pow10_text(5.5) == "3.162e+05" and pow10_text(400) == "10^400"


def test_a_relative_search_says_its_decisions_are_on_the_paired_runs():
    """Issue 34 §7: "mean 0.2254 ... within" under "tolerance 0.225" read as a contradiction; the
    decision is on the runs paired with zero delay, and the lines say so (absolute: not)."""
    import dkfsim
    from dkfsim.cli.maxdelay import _done_line
    from dkfsim.experiments.maxdelay import Candidate, classify
    case1 = Path(__file__).resolve().parents[1] / "scenarios" / "paper_case1.yaml"
    rel = dkfsim.maxdelay(case1, steps=40, relative=1.5, jobs=1, max_delay=2, batch=2, max_runs=2).table()
    assert "paired with the same runs at zero delay" in rel, rel
    absolute = dkfsim.maxdelay(case1, steps=40, tolerance=1.0, jobs=1, max_delay=2, batch=2, max_runs=2).table()
    assert "paired" not in absolute, absolute
    c = Candidate(index=1, delay=1.0, deterministic=False, values=[0.2254, 0.2255], excess=[-0.01, -0.012])
    classify(c, 0.95)
    assert "paired excess over R x the same run at zero delay" in _done_line("d_t = 1", c, paired=True)
    assert "decided on the paired excess" in _done_line("d_t = 1", c, paired=True)
    assert "paired" not in _done_line("d_t = 1", c, paired=False)

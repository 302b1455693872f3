"""Estimates count events, and the events a command predicts are within 2x of those it records
(issue 34 §2): on every shipped scenario, every shipped sweep and the README's and docs'
``montecarlo`` and ``maxdelay`` commands, steps scaled down so that the tier stays cheap.

A run records its events (``RunResult.info["events"]``: estimator ticks, packets sent, node-rows
re-run, fused rows); an estimate predicts them (:func:`dkfsim.engine.driver.measured_estimate`:
a trial of the first ticks on the numpy path, scaled; a Monte Carlo, a sweep and a search add
them up over the runs they expect).  ``force_trial`` makes each estimate measure what a long
command would (a short one keeps the analytic guess, which only says it is short).
"""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

import dkfsim
from dkfsim.config.plan import RunPlan
from dkfsim.core.errors import ResourceError
from dkfsim.core.resources import EVENT_KINDS
from dkfsim.engine.driver import measured_estimate
from dkfsim.experiments.maxdelay.run import MaxDelay, Settings
from dkfsim.experiments.montecarlo import estimate_montecarlo
from dkfsim.experiments.sweep import load_sweep, run_sweep
from dkfsim.experiments.sweep.run import estimate_tasks

ROOT = Path(__file__).resolve().parents[1]
SCENARIOS = sorted(p.name for p in (ROOT / "scenarios").glob("*.yaml") if not p.name.startswith("sweep_"))
SWEEPS = sorted(p.name for p in (ROOT / "scenarios").glob("sweep_*.yaml"))
#: Sweeps too long for the slow tier: the sidelink's 20 and 100 ms files are the 10 ms file's
#: scenario and grid with a longer tick, so their 60 ticks are 1.2 and 6 s of the 509-vehicle
#: highway at each of four points for eight estimators (13 and 40 s; the 10 ms file, 11 s, runs);
#: the tuned 20 ms file is the 20 ms file's sidelink half with three more keys.
TOO_LONG = {"sweep_sidelink_20ms.yaml", "sweep_sidelink_100ms.yaml", "sweep_sidelink_20ms_tuned.yaml"}
#: What the issue allows between the predicted and the recorded count of each kind.
FACTOR = 2.0


def within(predicted: dict, recorded: dict, what: str) -> None:
    """Every kind of event within :data:`FACTOR` (both zero counts as agreeing)."""
    assert set(recorded) == set(EVENT_KINDS), recorded
    bad = {}
    for kind in EVENT_KINDS:
        p, r = float(predicted.get(kind, 0.0)), float(recorded[kind])
        if (p == 0) != (r == 0) or (r and not 1 / FACTOR <= p / r <= FACTOR):
            bad[kind] = (round(p), r)
    assert not bad, f"{what}: predicted vs recorded events outside {FACTOR}x: {bad}"


def test_the_check_sees_a_prediction_off_by_more_than_twice():
    recorded = {"ticks": 100, "packets": 1000, "node_rows": 500, "fused_rows": 0}
    within({**recorded, "packets": 1999}, recorded, "ok")
    for wrong in ({**recorded, "packets": 2001}, {**recorded, "node_rows": 240}, {**recorded, "fused_rows": 1}):
        with pytest.raises(AssertionError):
            within(wrong, recorded, "off")


@pytest.mark.parametrize("name", SCENARIOS)
def test_a_runs_events_are_predicted_within_twice(name):
    sc = dkfsim.load_scenario(ROOT / "scenarios" / name)
    sc = dkfsim.load_scenario(sc, overrides=[f"steps={min(int(sc.steps), 150)}"])
    est = measured_estimate(RunPlan(sc, "estimates"), force=True)
    res = dkfsim.run(sc, save="estimates", yes=True)
    within(est.events, res.info["events"], name)


@pytest.mark.slow
@pytest.mark.parametrize("name", [pytest.param(n, marks=pytest.mark.skip(
    reason="the 10 ms file's grid, longer or with three more keys: 6 to 40 s (TOO_LONG)"))
    if n in TOO_LONG else n for n in SWEEPS])
def test_a_sweeps_events_are_predicted_within_twice(name, tmp_path):
    path = ROOT / "scenarios" / name
    spec = yaml.safe_load(path.read_text())
    spec.update(scenario=str(path.parent / spec["scenario"]), runs=1, output=str(tmp_path / "s.sqlite"),
                set=[*spec.get("set", []), "steps=60"])
    sweep = load_sweep(spec)
    est = estimate_tasks(sweep, set(), 1, force_trial=True)
    rep = run_sweep(sweep, jobs=1, progress=False, yes=True)
    within(est.events, rep.events, name)


@pytest.mark.slow
def test_the_readme_montecarlo_predicts_its_events_within_twice():
    # README: dkfsim montecarlo scenarios/paper_case1.yaml --runs 100 --set 'estimators=[...]'
    sc = dkfsim.load_scenario(ROOT / "scenarios" / "paper_case1.yaml", overrides=[
        "estimators=[{kind: centralized}, {kind: local_only}, {kind: ci_consensus, rounds: 4}]", "steps=120"])
    est = estimate_montecarlo(sc, 4, 1, force_trial=True)
    mc = dkfsim.montecarlo(sc, runs=4, jobs=1, yes=True)
    within(est.events, mc.events, "README montecarlo")


#: The docs' maxdelay commands (README.md, docs/maxdelay.md, docs/traffic.md), steps scaled.
MAXDELAY = {
    "README: --metric trace_P --relative 1.05": {"metric": "trace_P", "relative": 1.05},
    "maxdelay.md: --relative 1.5": {"relative": 1.5},
    "traffic.md: --axis rate --relative 1.1": {"axis": "rate", "relative": 1.1},
}


@pytest.mark.slow
@pytest.mark.parametrize("what", MAXDELAY)
def test_the_docs_maxdelay_commands_predict_their_events_within_twice(what):
    sc = dkfsim.load_scenario(ROOT / "scenarios" / "paper_case1.yaml", overrides=["steps=100"])
    md = MaxDelay(sc, Settings(jobs=1, **MAXDELAY[what]), yes=True)
    est = md.estimate(force_trial=True)
    res = md.run()
    within(est.events, res.events, what)


def test_the_readme_maxdelay_command_is_not_refused():
    """The README's ``maxdelay`` at its 1000 ticks: about 50 runs of a few tenths of a second each,
    not the "about 14.9 min" of the analytic worst case (every candidate at --max-runs)."""
    sc = dkfsim.load_scenario(ROOT / "scenarios" / "paper_case1.yaml")
    md = MaxDelay(sc, Settings(metric="trace_P", relative=1.05, jobs=1), yes=False)   # raises when refused
    assert md.estimate().wall_seconds < 600


@pytest.mark.parametrize("overrides, settings, named, not_named", [
    ([], {}, ["--max-delay"], ["--scale-step", "--max-scale", "--rate-step"]),
    (["links.default.latency={model: exponential, mean: 0.02}", "links.d_t=4"], {},
     ["--scale-step", "--max-scale"], ["--max-delay", "--rate-step"]),
    ([], {"axis": "rate"}, ["--rate-step", "--max-rate"], ["--max-delay", "--scale-step"]),
])
def test_a_refused_search_suggests_only_options_of_its_axis(overrides, settings, named, not_named):
    sc = dkfsim.load_scenario(ROOT / "scenarios" / "paper_case1.yaml", overrides=["steps=100000", *overrides])
    with pytest.raises(ResourceError) as err:
        MaxDelay(sc, Settings(relative=1.5, jobs=1, **settings), yes_flag="--yes")
    text = str(err.value)
    assert "add --yes" in text and "events" in text, text
    assert all(flag in text for flag in named), text
    assert not any(flag in text for flag in not_named), text


def test_a_refused_montecarlo_from_python_names_keywords_not_flags():
    sc = dkfsim.load_scenario(ROOT / "scenarios" / "paper_case1.yaml", overrides=["steps=100000"])
    with pytest.raises(ResourceError) as err:
        dkfsim.montecarlo(sc, runs=1000, jobs=1)
    text = str(err.value)
    assert "yes=True" in text and "--" not in text, text


@pytest.mark.parametrize("path, overrides", [
    ("channel_its_g5.yaml", ["estimators=[{kind: centralized}, {kind: diffusion_kf}, {kind: kcf}]"]),
    ("channel_its_g5.yaml", ["links.shared_queues=true"]),
    ("paper_case1.yaml", ["links.default.rate=1e6", "estimators=[{kind: centralized}]",
                          "links.default.background={arrivals: poisson, packets_per_second: 50, size: 250}"]),
    # (the fusion centre sends through the DKF's media: no copy of its own)
    ("channel_its_g5.yaml", ["estimators=[{kind: fusion_centre, at: 0}, {kind: kcf}]"]),
    ("highway_its_g5.yaml", []),
])
def test_the_estimates_copies_of_the_media_are_those_the_run_makes(monkeypatch, path, overrides):
    """What the time estimate (background packets) and the memory estimate (a radio's positions)
    multiply by: the copies of each medium the run builds, counted as they are built (a channel
    per copy; a FIFO medium per link and copy)."""
    from dkfsim.engine.estimate import channel_copies
    from dkfsim.network.media.channel import Channel
    from dkfsim.network.media.fifo import Fifo
    made = {Channel: 0, Fifo: 0}
    for cls in made:
        def counting(self, *args, _cls=cls, _init=cls.__init__, **kw):
            made[_cls] += 1
            _init(self, *args, **kw)
        monkeypatch.setattr(cls, "__init__", counting)
    sc = dkfsim.load_scenario(ROOT / "scenarios" / path, overrides=["steps=3", *overrides])
    dkfsim.run(sc)
    copies = made[Channel] if sc.medium is not None else made[Fifo] / len(RunPlan.of(sc).arcs)
    assert copies == channel_copies(sc) >= 1


def test_a_spatial_radio_costs_time_at_every_vehicle_each_frame_visits():
    """Every frame on a spatial radio visits every vehicle on the air: with the background of
    each, the radio's time grows with the square of the vehicles (10 frames per second each),
    plus one estimators' frame per node and tick; none without a radio."""
    from dkfsim.core.resources import C_RADIO_MEMBER
    from dkfsim.engine.estimate import channel_copies, estimate_run, radio_seconds
    highway = ROOT / "scenarios" / "highway_its_g5.yaml"

    def plan(*overrides):
        return RunPlan.of(dkfsim.load_scenario(highway, overrides=["steps=100", *overrides]))
    one = plan("medium.bystanders=null", "estimators=[{kind: centralized}]")
    sc = one.scenario
    assert sc.medium.background.packets_per_second == 10 and len(sc.medium.members(sc.n)) == sc.n == 12
    frames = 12 * 100 + 10 * 12 * 100 * sc.model.T
    assert channel_copies(sc) == 1 and radio_seconds(one) == pytest.approx(frames * 12 * C_RADIO_MEMBER)
    two = plan("medium.bystanders=null", "estimators=[{kind: centralized}, {kind: kcf}]")
    assert radio_seconds(two) == pytest.approx(2 * radio_seconds(one))
    assert estimate_run(two).seconds - estimate_run(one).seconds > radio_seconds(one)
    channel = RunPlan.of(dkfsim.load_scenario(ROOT / "scenarios" / "channel_its_g5.yaml"))
    assert radio_seconds(channel) == 0.0

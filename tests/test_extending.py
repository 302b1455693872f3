"""docs/extending.md's examples run: one file (plus its registration) is all a component needs.

Each example in docs/examples/ is loaded as a plugin (a scenario's ``plugins:``
key, or the ``dkfsim.plugins`` entry point) and checked against an
independent truth: the estimator against the mean it promises, computed here
from the run's own local filters; the latency model against scipy's
triangular law; the protocol against the arrival-log oracle; the metric
against the squared errors.  The estimator then runs through ``montecarlo``,
``sweep``, ``plot`` and ``maxdelay``'s Monte Carlo search with no other edit.
Registrations are undone after each test, so the rest of the suite never
sees them.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from conftest import scenario
from reference import node_estimates
from scipy import stats

import dkfsim
from dkfsim.config.plan import RunPlan

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "docs" / "examples"
CASE1 = ROOT / "scenarios" / "paper_case1.yaml"


@pytest.fixture(autouse=True)
def _isolated(isolated_registries):
    """Every test here registers components: undo it afterwards (conftest.isolated_registries)."""


def case1_with(tmp_path, steps=40, **keys) -> Path:
    d = yaml.safe_load(CASE1.read_text())
    d.pop("baselines", None)
    d.update(steps=steps, **keys)
    path = tmp_path / "s.yaml"
    path.write_text(yaml.safe_dump(d))
    return path


def test_the_example_estimator_is_the_mean_it_promises(tmp_path):
    path = case1_with(tmp_path, plugins=[str(EXAMPLES / "neighbour_mean.py")],
                      links={"default": {"latency": {"model": "constant", "value": 0.0}}},
                      estimators=[{"kind": "neighbour_mean"}, {"kind": "local_only"},
                                  {"kind": "neighbour_mean", "name": "nm_half", "weight_self": 0.5}])
    res = dkfsim.run(path)
    own = res["x_local_only"]                          # each node's own Kalman filter
    x, half = res["x_neighbour_mean"], res["x_nm_half"]
    graph = RunPlan(res.scenario).exchange
    for i in range(res.scenario.n):
        nbrs = [u for u, v in graph.arcs if v == i]
        # zero latency: every neighbour's estimate of row r has arrived by the update at t_{r+1}
        np.testing.assert_allclose(x[:, i], np.mean([own[:, i]] + [own[:, j] for j in nbrs], axis=0),
                                   rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(half[:, i], 0.5 * own[:, i] + 0.5 * np.mean([own[:, j] for j in nbrs], axis=0),
                                   rtol=1e-12, atol=1e-12)
    t = res.traffic["neighbour_mean"]
    assert t["sent"] == 40 * len(graph.arcs) == t["delivered"] and t["bytes"] == t["sent"] * (16 + 8 * 3)
    assert "neighbour_mean" in res.estimates and "neighbour_mean" in res.metrics()


def test_two_estimators_sending_together_see_the_same_delays():
    """Common random numbers on the shared network: the n-th packet two ports put on one link at
    one instant takes the same latency (and fate), whatever else either port sent before."""
    import simpy

    from dkfsim.components.faults import LinkSpec
    from dkfsim.components.latency import Exponential
    from dkfsim.network.network import Network
    env = simpy.Environment()
    spec = LinkSpec(latency=Exponential(mean=0.05), loss=0.2)
    net = Network(env, [(0, 1), (1, 0)], lambda u, v: spec, seed=7, T_ns=10_000_000)
    got = {"a": [], "b": []}
    ports = {name: net.port(name, lambda link, payload, name=name: got[name].append((payload, env.now)))
             for name in got}
    link = net.link(0, 1)

    def sender(env):
        for k in range(200):
            extra = k % 3 == 0                   # port a sends two packets at some instants
            for seq in range(2 if extra else 1):
                ports["a"].send(link, (k, seq))
            ports["b"].send(link, (k, 0))
            yield env.timeout(10_000_000)
    env.process(sender(env))
    env.run()
    a, b = dict(got["a"]), dict(got["b"])
    assert len(b) > 100 and len(a) > len(b)                     # 20 % loss, two ports
    assert all(a[key] == t for key, t in b.items())            # b's packets: a's first ones exactly
    lost_b = {(k, 0) for k in range(200)} - set(b)
    assert lost_b and not lost_b & set(a)                      # the same packets are lost too
    second = [a[(k, 1)] - (k * 10_000_000) for k in range(0, 200, 3) if (k, 1) in a]
    first = [a[(k, 0)] - (k * 10_000_000) for k in range(0, 200, 3) if (k, 0) in a]
    assert second != first[:len(second)]                       # a second packet draws anew


@pytest.mark.usefixtures("isolated_registries")
def test_every_estimator_listed_has_a_packets_line():
    """``dkfsim list estimators``: a ``packets:`` line under every estimator, the plugins' too --
    theirs says "not described" when the class has no ``packets`` (issue 34 §8)."""
    from dkfsim.cli.list import describe
    from dkfsim.components.estimators import EstimatorParams
    from dkfsim.core.registry import load_plugin
    from dkfsim.estimators.base import Estimator

    load_plugin(str(EXAMPLES / "neighbour_mean.py"))

    class SilentParams(EstimatorParams, kind="silent_test_estimator"):
        """A plugin that says nothing of its packets."""

    class Silent(Estimator, params=SilentParams):
        """It sends nothing it describes."""

    entries: dict[str, list[str]] = {}
    for line in describe("estimators")[1:]:
        if line.startswith("  also accepted"):
            break
        if not line.startswith("   "):                     # "  name   description"
            entries[line.split()[0]] = []
        else:
            entries[list(entries)[-1]].append(line.strip())
    assert {"neighbour_mean", "silent_test_estimator", "centralized"} <= set(entries)
    assert all(any(text.startswith("packets: ") for text in v) for v in entries.values()), entries
    assert any(t.startswith("packets: one per exchange link and tick") for t in entries["neighbour_mean"])
    assert any(t.startswith("packets: not described") for t in entries["silent_test_estimator"])


@pytest.mark.slow
def test_the_example_estimator_runs_everywhere(tmp_path):
    path = case1_with(tmp_path, steps=30, plugins=[str(EXAMPLES / "neighbour_mean.py")],
                      estimators=[{"kind": "neighbour_mean"}, {"kind": "centralized"}])
    mc = dkfsim.montecarlo(str(path), 3, jobs=2)
    assert "neighbour_mean" in mc.estimates and mc.estimate_summary("neighbour_mean")["mse"]["position"] > 0
    out = tmp_path / "mc"
    mc.save(out)
    from dkfsim.report.plots import load_folder, plot_folder
    folder = load_folder(out)
    assert "neighbour_mean" in folder.mse
    assert plot_folder(folder, tmp_path / "figs", ("png",))
    sweep = tmp_path / "sweep.yaml"
    sweep.write_text(yaml.safe_dump({"scenario": str(path), "grid": {"links.default.latency.d_t": [0, 2]},
                                     "runs": 2}))
    rep = dkfsim.sweep(sweep, jobs=1)
    from dkfsim.experiments.sweep import read_results
    cols, rows = read_results(rep.db)
    est = cols.index("estimate")
    assert sum(r[est] == "neighbour_mean" for r in rows) == 2 * 2 * 3          # sets x runs x components
    md = dkfsim.maxdelay(str(path), metric="mse", estimate="neighbour_mean", relative=3.0, max_runs=4,
                         batch=2, max_delay=2)
    assert md.to_dict()["empirical"]["candidates"]


def test_the_example_latency_model_draws_its_law(tmp_path):
    from dkfsim.core.registry import load_plugin
    load_plugin(str(EXAMPLES / "triangular_latency.py"))
    from dkfsim.components.latency import parse_latency
    m = parse_latency({"model": "triangular", "low": 0.001, "mode": 0.004, "high": 0.01})
    x = m.sample_ns(np.random.default_rng(3), 20_000, 10_000_000) / 1e9
    law = stats.triang(c=(0.004 - 0.001) / 0.009, loc=0.001, scale=0.009)
    assert stats.kstest(x, law.cdf).pvalue > 0.01
    assert stats.kstest(x, stats.triang(c=0.5, loc=0.001, scale=0.009).cdf).pvalue < 1e-6
    path = case1_with(tmp_path, plugins=[str(EXAMPLES / "triangular_latency.py")],
                      links={"default": {"latency": {"model": "triangular", "low": 0.0, "mode": 0.01,
                                                     "high": 0.025}}})
    sc = dkfsim.load_scenario(path)
    assert RunPlan(sc).d_t == 3 and RunPlan(sc).buffer_length() == 3 * 4 + 1
    res = dkfsim.run(sc)
    assert res.counts["late"] == 0 and res.counts["delivered"] > 0
    with pytest.raises(dkfsim.ScenarioError, match="low <= mode <= high"):
        dkfsim.load_scenario(path, ["links.default.latency.mode=0.5"])


def test_the_example_protocol_keeps_the_dkf_exact():
    from dkfsim.core.registry import load_plugin
    load_plugin(str(EXAMPLES / "tick_flood.py"))
    d = scenario(6, steps=30, protocol="tick_flood", latency={"model": "uniform", "low": 0.0, "high": 0.25},
                 fusion="none")
    res = dkfsim.run(d, save="full")
    ref = node_estimates(res.arrays)
    np.testing.assert_allclose(res["x_local"], ref["x_local"], rtol=1e-9, atol=1e-11)
    np.testing.assert_allclose(res["x_final"], ref["x_final"], rtol=1e-9, atol=1e-11)
    # it is not flood: relays wait for ticks, so information reaches nodes later
    flood = dkfsim.run({**d, "protocol": "flood"}, save="full")
    assert np.sum(res["arrival"] > flood["arrival"]) > 0


def test_the_example_metric_is_a_column_everywhere(tmp_path):
    from dkfsim.core.registry import load_plugin
    load_plugin(str(EXAMPLES / "peak_error.py"))
    res = dkfsim.run(case1_with(tmp_path))
    burn = res.metrics()["burn_in"]
    for row in res.rows():
        c = res.components.index(row["component"])
        x = res[f"x_{row['estimate']}"]
        err = (x - (res["truth"] if x.ndim == 2 else res["truth"][:, None, :])) ** 2
        expected = (err if x.ndim == 2 else err.mean(axis=1))[burn:, c].max()
        assert row["peak_error"] == pytest.approx(expected)
    from dkfsim.analysis.metrics import row_columns
    assert row_columns()[-1] == "peak_error"


def throwaway_package(site: Path, group: str, module: str = "neighbour_mean") -> None:
    """An installed package as pip leaves one: the module in ``nm_plugin/`` and a ``.dist-info``
    whose ``entry_points.txt`` declares it in ``group``."""
    (site / "nm_plugin").mkdir(parents=True)
    (site / "nm_plugin" / "__init__.py").write_text("")
    shutil.copy(EXAMPLES / "neighbour_mean.py", site / "nm_plugin" / f"{module}.py")
    dist = site / "nm_plugin-1.0.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: nm-plugin\nVersion: 1.0\n")
    (dist / "entry_points.txt").write_text(f"[{group}]\nneighbour_mean = nm_plugin.{module}\n")


def dkfsim_command(*args: str, site: Path) -> subprocess.CompletedProcess:
    """``dkfsim ARGS`` in a fresh process whose sys.path holds ``site``, as a user's shell runs it."""
    script = Path(sys.executable).with_name("dkfsim")
    cmd = [str(script)] if script.exists() else [sys.executable, "-m", "dkfsim"]
    env = {**os.environ, "PYTHONPATH": str(site)}
    return subprocess.run(cmd + list(args), env=env, capture_output=True, text=True, timeout=300)


@pytest.mark.slow
def test_an_installed_estimator_plugin_runs_in_a_fresh_process(tmp_path):
    """Issue 18: the ``dkfsim.plugins`` entry point of an installed package declaring
    docs/examples/neighbour_mean.py.  A fresh process lists it and runs a scenario that names
    its kind (no ``plugins:`` key), with the estimates the same file gives as a ``plugins:``
    file; nothing on stderr says a plugin failed (before the fix: a circular import, because a
    registry read during ``import dkfsim`` loaded the plugin while dkfsim was half imported)."""
    site = tmp_path / "site"
    throwaway_package(site, "dkfsim.plugins")
    listed = dkfsim_command("list", "estimators", site=site)
    assert listed.returncode == 0 and "failed" not in listed.stderr, listed.stderr
    assert "neighbour_mean" in listed.stdout and "neighbours' latest estimates" in listed.stdout
    assert "packets: one per exchange link and tick: 16-byte header + 8 nx" in listed.stdout   # (issue 34 §8)
    path = case1_with(tmp_path, steps=20, estimators=[{"kind": "neighbour_mean"}])
    ran = dkfsim_command("run", str(path), "--out", str(tmp_path / "out"), "--save", "estimates", site=site)
    assert ran.returncode == 0 and "failed" not in ran.stderr, ran.stderr
    assert "neighbour_mean" in ran.stdout
    with np.load(tmp_path / "out" / "run.npz") as npz:
        installed = npz["x_neighbour_mean"]
    as_file = dkfsim.run(case1_with(tmp_path, steps=20, estimators=[{"kind": "neighbour_mean"}],
                                    plugins=[str(EXAMPLES / "neighbour_mean.py")]), save="estimates")
    assert installed.shape == (20, 12, 3)
    np.testing.assert_array_equal(installed, as_file["x_neighbour_mean"])


def test_dkfsim_list_shows_a_plugin_file_it_is_given(tmp_path):
    """``dkfsim list --plugin FILE`` loads the file as a scenario's ``plugins:`` entry does and
    lists what it registers (without it a plugin file could never be listed); a missing one is a
    one-line error, exit 2."""
    listed = dkfsim_command("list", "estimators", "--plugin", str(EXAMPLES / "neighbour_mean.py"), site=tmp_path)
    assert listed.returncode == 0, listed.stderr
    assert "neighbour_mean" in listed.stdout and "neighbours' latest estimates" in listed.stdout
    assert "neighbour_mean" not in dkfsim_command("list", "estimators", site=tmp_path).stdout
    missing = dkfsim_command("list", "--plugin", str(tmp_path / "nope.py"), site=tmp_path)
    assert missing.returncode == 2 and missing.stdout == ""
    assert missing.stderr.strip() == f"dkfsim list: error: plugin file not found: {tmp_path / 'nope.py'}"


@pytest.mark.slow
def test_the_estimators_entry_point_group_is_the_same_mechanism(tmp_path):
    site = tmp_path / "site"
    throwaway_package(site, "dkfsim.estimators")
    listed = dkfsim_command("list", "estimators", site=site)
    assert listed.returncode == 0 and "failed" not in listed.stderr, listed.stderr
    assert "neighbour_mean" in listed.stdout


@pytest.mark.slow
def test_a_broken_plugin_is_reported_once_and_dkfsim_works_on(tmp_path):
    site = tmp_path / "site"
    throwaway_package(site, "dkfsim.plugins", module="broken")
    (site / "nm_plugin" / "broken.py").write_text("raise RuntimeError('the plugin is broken')\n")
    listed = dkfsim_command("list", "estimators", site=site)
    assert listed.returncode == 0 and "centralized" in listed.stdout
    assert listed.stderr.count("plugin 'neighbour_mean' (nm_plugin.broken) failed to load: the plugin is broken") == 1


def test_a_one_domain_rule_on_a_spatial_radio_is_refused_at_validation():
    """``persistent`` decides for one collision domain: on a spatial radio (``medium.radio``) the
    scenario is refused when validated, naming ``medium.access.kind`` (it used to validate, then
    raise a ValueError with a traceback when the run built the radio); edca and csma, which each
    radio runs on its own view, are taken."""
    from dkfsim.core.errors import ScenarioError
    from dkfsim.core.registry import load_plugin
    load_plugin(str(EXAMPLES / "persistent_access.py"))
    highway = ROOT / "scenarios" / "highway_its_g5.yaml"
    with pytest.raises(ScenarioError, match="one collision domain") as info:
        dkfsim.load_scenario(highway, overrides=["medium.access={kind: persistent}"])
    assert info.value.path == "medium.access.kind"
    for kind in ("edca", "csma"):
        assert dkfsim.load_scenario(highway, overrides=[f"medium.access.kind={kind}"]).medium.access.kind == kind


def test_the_example_access_rule_sends_at_once_and_collides(tmp_path):
    """docs/examples/persistent_access.py, a researcher's MAC in one file: it is listed as a
    medium, ``medium.access.kind: persistent`` names it, and its rule holds on a hand-worked
    timeline -- frames handed over to an idle channel start that instant (no backoff), frames
    that become ready while it is busy all start when it becomes idle, and frames starting
    together collide (1 Mbit/s, no preamble: 100 bytes are 800 us on the air)."""
    import simpy

    from dkfsim.cli.list import describe
    from dkfsim.core.registry import load_plugin
    from dkfsim.network.media.base import Frame
    from dkfsim.network.media.channel import Channel
    load_plugin(str(EXAMPLES / "persistent_access.py"))
    assert any(line.split()[0] == "persistent" for line in describe("media")[1:] if line.strip())
    spec = dkfsim.load_scenario(case1_with(tmp_path, medium={"rate": 1.0e6, "preamble": 0.0,
                                                             "access": {"kind": "persistent"}})).medium
    assert spec is not None and spec.access.kind == "persistent"
    env = simpy.Environment()
    ch = Channel(env, spec, (0, 1, 2, 3), seed=1, record=True)
    us = 1000

    def offer(node, t):
        def go(env):
            yield env.timeout(t)
            assert ch.offer(Frame(node, 100, env.now, node, lambda f, ok: None))
        env.process(go(env))
    offer(0, 0)                       # alone, idle: 0 .. 800 us, delivered
    offer(1, 100 * us)                # busy: waits for 800 us
    offer(2, 300 * us)                # busy: waits for 800 us too -> collides with 1
    offer(3, 2000 * us)               # idle again: 2000 .. 2800 us, alone
    env.run()
    got = sorted(ch.ended or [], key=lambda e: (e[1], e[0]))
    assert [(node, start // us, end // us, ok) for node, start, end, ok, _ in got] == [
        (0, 0, 800, True), (1, 800, 1600, False), (2, 800, 1600, False), (3, 2000, 2800, True)]
    # the DKF on it, through every layer: packets lost to collisions, the counts add up
    res = dkfsim.run(case1_with(tmp_path, steps=30, plugins=[str(EXAMPLES / "persistent_access.py")],
                                medium={"rate": 1.0e6, "access": {"kind": "persistent"}}))
    c = res.counts
    assert c["collision_lost"] > 0
    assert c["sent"] + c["copies"] == c["delivered"] + c["lost"] + c["queue_dropped"] + c["crash_dropped"] + c["in_flight"]

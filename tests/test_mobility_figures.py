"""Issue 23 §5, "Seeing it": what a run with ``mobility:`` keeps for its figures (run.npz
``positions``, ``links_up``, ``mobility_links``; summary.json ``mobility.link_uptime``), the
figures ``dkfsim plot`` draws from them, the report's up-time table, and a folder whose
arrays do not fit its summary.json refused cleanly."""

from __future__ import annotations

import copy
import json

import numpy as np
import pytest

pytest.importorskip("matplotlib")        # the `plots` extra
from conftest import import_dkfsim, scenario  # noqa: E402

from dkfsim.cli.main import main  # noqa: E402
from dkfsim.config.plan import RunPlan  # noqa: E402
from dkfsim.core.errors import DkfsimError  # noqa: E402
from dkfsim.report.plots import load_folder  # noqa: E402

T = 0.1                  # the conftest model's period
K = 60
RADIUS = 10.0


def ab_up(k):            # pair 0-1 in range at these ticks (hand-made pattern)
    return k % 20 < 7


def bc_up(k):            # pair 1-2
    return 4 <= k % 15 < 12


def moving_scenario():
    """A path 0 - 1 - 2: node 1 fixed, nodes 0 and 2 on waypoints NEAR (5 m) or FAR (1 km)
    by the patterns above; node 3 drives at a constant velocity (only its own links, none)."""
    base = scenario(4, edges=[(0, 1), (1, 2), (2, 3)], protocol="flood", steps=K, buffer_length=10,
                    latency={"model": "constant", "value": 0.0})
    a = [[k * T, -(5.0 if ab_up(k) else 1000.0), 0.0] for k in range(K + 1)]
    c = [[k * T, 5.0 if bc_up(k) else 1000.0, 0.0] for k in range(K + 1)]
    sc = copy.deepcopy(base)
    sc["mobility"] = {"vehicles": {0: {"kind": "waypoints", "points": a},
                                   1: {"kind": "constant_velocity", "start": [0.0, 0.0]},
                                   2: {"kind": "waypoints", "points": c},
                                   3: {"kind": "constant_velocity", "start": [3.0, -500.0],
                                       "velocity": [2.0, 7.0]}},
                      "range": {"model": "disk", "radius": RADIUS}}
    return sc


@pytest.fixture(scope="module")
def folders(tmp_path_factory):
    """One run with mobility and the same scenario without, saved as dkfsim run saves them."""
    dk = import_dkfsim()
    root = tmp_path_factory.mktemp("mobviz")
    sc = moving_scenario()
    plain = copy.deepcopy(sc)
    del plain["mobility"]
    out = {}
    for name, s in (("moving", sc), ("plain", plain)):
        loaded = dk.load_scenario(copy.deepcopy(s))
        res = dk.run(loaded, save="full")
        res.save(root / name)
        out[name] = (root / name, loaded, res)
    return out


def test_link_uptime_is_the_fraction_of_ticks_each_pair_was_up(folders):
    """summary.json's up-time per pair equals this test's count over ticks 1..K, from the
    plan's link schedule and from the hand-made pattern; run.npz's links_up is the schedule."""
    path, sc, _ = folders["moving"]
    summary = json.loads((path / "summary.json").read_text())
    got = {(u, v): f for u, v, f in summary["mobility"]["link_uptime"]}
    schedule = RunPlan(sc).link_schedule
    arcs = schedule.arcs
    own = {}
    for u, v in [(0, 1), (1, 2), (2, 3)]:
        cols = [arcs.index((u, v)), arcs.index((v, u))]
        own[(u, v)] = sum(bool(schedule.up[k, cols].any()) for k in range(1, K + 1)) / K
    assert got.keys() == own.keys()
    for pair in own:
        assert got[pair] == pytest.approx(own[pair], abs=1e-15), pair
    assert got[(0, 1)] == pytest.approx(sum(ab_up(k) for k in range(1, K + 1)) / K)
    assert got[(1, 2)] == pytest.approx(sum(bc_up(k) for k in range(1, K + 1)) / K)
    assert got[(2, 3)] == 0.0
    with np.load(path / "run.npz") as z:
        assert z["mobility_links"].tolist() == [[0, 1], [1, 2], [2, 3]]
        assert z["links_up"].shape == (K, 3)
        assert z["links_up"][:, 0].tolist() == [int(ab_up(k)) for k in range(1, K + 1)]
        assert z["links_up"][:, 1].tolist() == [int(bc_up(k)) for k in range(1, K + 1)]


def test_stored_positions_are_the_trajectories_at_the_ticks(folders):
    """run.npz's positions row r is every vehicle at the run's t[r] = (r + 1) T: node 3 by
    its closed form start + velocity t, nodes 0 and 2 at their waypoints."""
    path, _, _ = folders["moving"]
    with np.load(path / "run.npz") as z:
        pos, t = z["positions"], z["t"]
    assert pos.shape == (K, 4, 2)
    assert np.allclose(t, np.arange(1, K + 1) * T, rtol=0, atol=1e-12)
    np.testing.assert_allclose(pos[:, 3], np.array([3.0, -500.0]) + np.outer(t, [2.0, 7.0]), rtol=0, atol=1e-9)
    np.testing.assert_allclose(pos[:, 0, 0], [-(5.0 if ab_up(k) else 1000.0) for k in range(1, K + 1)],
                               rtol=0, atol=1e-9)
    np.testing.assert_allclose(pos[:, 2, 0], [5.0 if bc_up(k) else 1000.0 for k in range(1, K + 1)],
                               rtol=0, atol=1e-9)
    assert (pos[:, 1] == 0).all()


def test_plot_and_report_draw_the_mobility_figures_only_for_a_moving_run(folders, tmp_path):
    figures = ("network_over_time.png", "topology_errors.png")
    moving, plain = folders["moving"][0], folders["plain"][0]
    assert main(["plot", str(moving), "--format", "png", "--at", "1", "30", str(K)]) == 0
    assert main(["plot", str(plain), "--format", "png"]) == 0
    for f in figures:
        assert (moving / "figures" / f).stat().st_size > 1000
        assert not (plain / "figures" / f).exists()
    assert main(["plot", str(plain), "--format", "png", "--at", "3", "--out", str(tmp_path / "f")]) == 2
    assert not (tmp_path / "f").exists()           # no mobility: refused before any figure
    assert main(["plot", str(moving), "--format", "png", "--at", str(K + 1)]) == 2
    assert main(["report", str(moving)]) == 0
    assert main(["report", str(plain)]) == 0
    page = (moving / "report.html").read_text()
    assert 'id="link_uptime"' in page and "topology_errors" in page and "network_over_time" in page
    assert "<td>0–1</td>" in page
    other = (plain / "report.html").read_text()
    assert "link_uptime" not in other and "topology_errors" not in other
    # a run without mobility keeps nothing new
    with np.load(plain / "run.npz") as z:
        assert not {"positions", "links_up", "mobility_links"} & set(z.files)
    assert "mobility" not in json.loads((plain / "summary.json").read_text())


def test_a_montecarlo_folder_draws_the_network_its_runs_moved_on(folders, tmp_path):
    """A Monte Carlo folder keeps no positions, but every run moves the same (no draw moves a
    vehicle): the folder read back holds the single run's positions and links up, equal to
    that run's run.npz, and `dkfsim plot` draws both mobility figures from it (decision 231)."""
    import yaml
    spec = tmp_path / "moving.yaml"
    spec.write_text(yaml.safe_dump(moving_scenario()))
    mc = tmp_path / "mc"
    assert main(["montecarlo", str(spec), "--runs", "2", "--jobs", "1", "--quiet", "--out", str(mc)]) == 0
    run = load_folder(folders["moving"][0]).mobility
    replayed = load_folder(mc).mobility
    assert replayed.keys() == run.keys()
    for key in run:
        np.testing.assert_array_equal(replayed[key], run[key], err_msg=key)
    assert main(["plot", str(mc), "--format", "png", "--at", "1", "30"]) == 0
    for f in ("network_over_time.png", "topology_errors.png"):
        assert (mc / "figures" / f).stat().st_size > 1000
    # a stored scenario of other runs is refused before it is replayed
    summary = json.loads((mc / "summary.json").read_text())
    summary["scenario_config"]["steps"] = 10**9
    (mc / "summary.json").write_text(json.dumps(summary))
    with pytest.raises(DkfsimError, match="scenario_config has steps 1000000000 but curves.npz has 60 ticks"):
        load_folder(mc)
    # a Monte Carlo folder of a scenario without mobility: none
    plain = copy.deepcopy(moving_scenario())
    del plain["mobility"]
    spec.write_text(yaml.safe_dump(plain))
    assert main(["montecarlo", str(spec), "--runs", "2", "--jobs", "1", "--quiet", "--out", str(tmp_path / "p")]) == 0
    assert load_folder(tmp_path / "p").mobility == {}
    assert main(["plot", str(tmp_path / "p"), "--format", "png", "--at", "3"]) == 2


def _tampered(src, tmp_path, name, change_arrays=None, change_summary=None):
    dst = tmp_path / name
    dst.mkdir()
    with np.load(src / "run.npz") as z:
        arrays = {k: z[k] for k in z.files}
    summary = json.loads((src / "summary.json").read_text())
    if change_arrays:
        change_arrays(arrays)
    if change_summary:
        change_summary(summary)
    np.savez(dst / "run.npz", **arrays)
    (dst / "summary.json").write_text(json.dumps(summary))
    return dst


@pytest.mark.parametrize("arrays, summary, words", [
    (lambda a: a.update(links_up=a["links_up"][:, :2]), None, "links_up"),
    (lambda a: a.update(positions=a["positions"][1:]), None, "positions"),
    (lambda a: a.update(positions=a["positions"][:, :3]), None, "positions"),
    (lambda a: a.update(mobility_links=a["mobility_links"][::-1].copy()), None, "pairs"),
    (lambda a: a["mobility_links"].__setitem__((2, 1), 9), None, "mobility_links"),
    (lambda a: a["links_up"].__setitem__((0, 0), 7), None, "links_up"),
    (None, lambda s: s.pop("mobility"), "mobility"),
    (None, lambda s: s["mobility"]["link_uptime"].pop(), "link_uptime"),
    (lambda a: [a.pop(k) for k in ("positions", "links_up", "mobility_links")], None,
                 "mobility_links"),
], ids=["short_links_up", "rows_of_positions", "nodes_of_positions", "other_pairs", "pair_out_of_range",
        "not_a_bit", "no_mobility_summary", "uptime_rows", "no_arrays"])
def test_a_mismatched_mobility_array_is_a_clean_error(folders, tmp_path, capsys, arrays, summary, words):
    bad = _tampered(folders["moving"][0], tmp_path, "case", arrays, summary)
    with pytest.raises(DkfsimError) as exc:
        load_folder(bad)
    assert words in str(exc.value).replace(str(bad), ""), exc.value      # the message, not the path
    assert main(["plot", str(bad), "--format", "png"]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and words in err.replace(str(bad), "")


def test_a_folder_read_back_and_saved_again_keeps_mobility_only_where_it_was(folders, tmp_path):
    """dkfsim.load then save: the moving run's up-time table and arrays survive; the plain run
    gains no ``mobility`` key (a None field of the record is not written back)."""
    dk = import_dkfsim()
    for name in ("moving", "plain"):
        path = folders[name][0]
        dk.load(path).save(tmp_path / name)
        before = json.loads((path / "summary.json").read_text())
        after = json.loads((tmp_path / name / "summary.json").read_text())
        assert ("mobility" in after) == (name == "moving")
        assert after.get("mobility") == before.get("mobility")
    with np.load(folders["moving"][0] / "run.npz") as a, np.load(tmp_path / "moving" / "run.npz") as b:
        for key in ("positions", "links_up", "mobility_links"):
            assert np.array_equal(a[key], b[key]), key

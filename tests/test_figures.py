"""Issue 24 §2, figures that show the result: what can be asserted of a figure (markers,
labels with units, legend width, what is refused), and the two bugs found in review."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

matplotlib = pytest.importorskip("matplotlib")

from dkfsim.cli.main import main  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
CASE1 = ROOT / "scenarios" / "paper_case1.yaml"


def test_relative_to_fused_with_fusion_none_is_refused_before_any_run(tmp_path, capsys, monkeypatch):
    import dkfsim.experiments.montecarlo as mc

    def no_run(*_a, **_k):
        raise AssertionError("a run started before --relative-to was checked")
    monkeypatch.setattr(mc, "_montecarlo", no_run)
    out = tmp_path / "mc"
    assert main(["montecarlo", str(CASE1), "--runs", "2", "--steps", "20", "--jobs", "1", "--quiet",
                 "--set", "fusion=none", "--relative-to", "fused", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "--relative-to fused" in err and "fusion: none" in err and err.count("\n") == 1
    assert not out.exists()


# ----------------------------------------------------------------------------
# sweep figures
# ----------------------------------------------------------------------------

@pytest.fixture(scope="module")
def swept(tmp_path_factory):
    d = tmp_path_factory.mktemp("sweep")
    (d / "s.yaml").write_text(yaml.safe_dump({
        "scenario": str(CASE1), "grid": {"links.default.latency.d_t": [0, 2], "protocol": ["tree", "flood"]},
        "set": ["steps=40", "estimators=[{kind: centralized}, {kind: kcf}, {kind: icf}, {kind: hcmci}]"],
        "runs": 2}))
    assert main(["sweep", str(d / "s.yaml"), "--jobs", "1", "--quiet", "--export", str(d / "s.csv")]) == 0
    return d


def keep_figures(monkeypatch, *modules) -> list:
    """The figures the drawing ``modules`` would save, kept open (in order) instead of written."""
    kept: list = []
    for mod in modules:
        monkeypatch.setattr(mod, "save_figure", lambda fig, stem, formats: kept.append(fig) or [])
    return kept


@pytest.fixture
def figures(monkeypatch):
    """The figures plot_sweep would save."""
    import dkfsim.report.sweep.plot as sp
    return keep_figures(monkeypatch, sp)


def data_lines(ax):
    """The lines of a panel that draw data (not the reference lines at 1 or nx)."""
    return [ln for ln in ax.get_lines() if ln.get_marker() not in (None, "None", "")]


def style(line):
    return (line.get_marker(), str(line.get_linestyle()), str(line.get_markerfacecolor()))


def test_sweep_x_label_is_the_key_in_words_with_its_unit_or_xlabel(swept, figures):
    from dkfsim.report.sweep.plot import plot_sweep
    plot_sweep(swept / "s.sqlite", swept / "f", x="d_t", where=["protocol=tree"])
    fig = figures.pop()
    assert fig.axes[-1].get_xlabel() == "per-hop delay bound d_t [ticks]"
    assert "links.default.latency.d_t" in fig._suptitle.get_text()          # the exact key stays findable
    plot_sweep(swept / "s.sqlite", swept / "f", x="d_t", where=["protocol=tree"], xlabel="d_t (ticks of 0.1 s)")
    assert figures.pop().axes[-1].get_xlabel() == "d_t (ticks of 0.1 s)"


def test_component_and_xlabel_are_accepted_for_a_sweep(swept, figures):
    assert main(["plot", str(swept / "s.sqlite"), "--x", "d_t", "--where", "protocol=tree", "--component",
                 "velocity", "--xlabel", "bound", "--format", "png", "--out", str(swept / "c")]) == 0
    fig = figures.pop()
    labels = [ax.get_ylabel() for ax in fig.axes if ax.get_ylabel()]
    assert labels and all(lab.startswith("velocity MSE") or lab.startswith("velocity MSE /") for lab in labels)
    assert all(ax.get_xlabel() in ("", "bound") for ax in fig.axes)


def test_component_of_a_scalar_metric_or_unknown_is_refused(swept, capsys):
    for extra, words in ((["--component", "veloctiy"], "did you mean 'velocity'"),
                         (["--metric", "messages_per_tick", "--component", "position"], "one value per run")):
        assert main(["plot", str(swept / "s.sqlite"), "--x", "d_t", "--where", "protocol=tree", *extra,
                     "--out", str(swept / "bad")]) == 2
        err = capsys.readouterr().err
        assert words in err and err.count("\n") == 1
    assert not (swept / "bad").exists()


def test_coinciding_sweep_lines_get_distinct_markers_and_styles(swept, figures):
    """fused lies on centralized, and kcf, icf and hcmci send the same messages: every line of
    a panel has its own marker, and a line drawn over an equal one is hollow and dashed."""
    from dkfsim.report.sweep.plot import plot_sweep
    for metric in ("mse", "messages_per_tick"):
        plot_sweep(swept / "s.sqlite", swept / "f", x="d_t", where=["protocol=tree"], metric=metric)
        for ax in figures.pop().axes:
            lines = data_lines(ax)
            assert len({ln.get_marker() for ln in lines}) == len(lines)
            for k, ln in enumerate(lines):
                same = [o for o in lines[:k] if list(o.get_ydata()) == pytest.approx(list(ln.get_ydata()), rel=1e-3)]
                if same:                                # drawn over an equal line: hollow, not solid
                    assert str(ln.get_markerfacecolor()) == "none" and ln.get_linestyle() != "-"
                    assert all(style(o) != style(ln) for o in same)
        if metric == "messages_per_tick":              # the three consensus filters are equal here
            equal = [ln for ln in lines if str(ln.get_markerfacecolor()) == "none"]
            assert len(equal) >= 2


def test_hue_lines_never_take_a_built_in_estimate_colour(swept, figures):
    from matplotlib.colors import to_rgb

    from dkfsim.report.plots.style import ESTIMATES
    from dkfsim.report.sweep.plot import plot_sweep
    plot_sweep(swept / "s.sqlite", swept / "f", x="d_t", hue="protocol")
    builtin = {to_rgb(c) for _, c in ESTIMATES.values()}
    colours = {to_rgb(ln.get_color()) for ax in figures.pop().axes for ln in data_lines(ax)}
    assert len(colours) == 2 and not colours & builtin


def test_sweep_mse_has_a_paired_relative_panel_and_labelled_log_ticks(swept, figures):
    from dkfsim.report.sweep.plot import plot_sweep
    plot_sweep(swept / "s.sqlite", swept / "f", x="d_t", where=["protocol=tree"])
    fig = figures.pop()
    right = [ax for ax in fig.axes if "/ centralized" in ax.get_ylabel()]
    assert len(right) == 3                                # one ratio panel per component
    assert all(1.0 in list(ln.get_ydata()) for ax in right for ln in ax.get_lines()
               if ln.get_marker() in (None, "None", ""))  # the reference line at 1
    logs = [ax for ax in fig.axes if ax.get_yscale() == "log"]
    assert logs
    for ax in logs:
        fig.canvas.draw()
        lo, hi = ax.get_ylim()
        shown = [t.get_text() for t, v in zip(ax.get_yticklabels(), ax.get_yticks()) if lo <= v <= hi and t.get_text()]
        assert len(shown) >= 3, (ax.get_ylabel(), shown)   # not only 1 and 10


def test_an_empty_anees_or_relative_figure_is_refused_not_saved(swept, figures, capsys, tmp_path):
    """Review bug (a): the reference line (nx, or 1) counted as something drawn."""
    import csv
    rows = list(csv.DictReader(open(swept / "s.csv", newline="")))
    for r in rows:
        r["anees"] = ""
    with open(tmp_path / "empty.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    for path, extra in ((tmp_path / "empty.csv", ["--metric", "anees"]),
                        (swept / "s.sqlite", ["--metric", "messages_per_tick", "--estimate", "fused",
                                              "--relative-to", "centralized"])):
        assert main(["plot", str(path), "--x", "d_t", "--where", "protocol=tree", *extra,
                     "--format", "png", "--out", str(tmp_path / "figs")]) == 2
        err = capsys.readouterr().err
        assert "nothing to draw" in err and err.count("\n") == 1
    assert not figures and not (tmp_path / "figs").exists()


# ----------------------------------------------------------------------------
# maxdelay figure
# ----------------------------------------------------------------------------

def rgb_distance(a, b) -> float:
    from matplotlib.colors import to_rgb
    return sum((x - y) ** 2 for x, y in zip(to_rgb(a), to_rgb(b))) ** 0.5


def test_maxdelay_figure_legend_labels_and_colours(tmp_path, monkeypatch, capsys):
    import dkfsim.report.maxdelay as rm
    from dkfsim.report.plots.style import ESTIMATES, OTHER_COLORS
    kept = keep_figures(monkeypatch, rm)
    assert main(["maxdelay", str(CASE1), "--metric", "trace_P", "--relative", "1.05", "--steps", "60",
                 "--jobs", "1", "--batch", "2", "--max-runs", "4", "--max-delay", "4",
                 "--out", str(tmp_path / "md")]) == 0
    text = capsys.readouterr().out
    import re
    n = re.search(r"\((\d+) Monte Carlo runs\)", text).group(1)        # one count, said the same way twice
    assert re.search(rf"runs in [\d.]+ s: {n} Monte Carlo \(1\)", text)
    if "p_tol = " in text:                     # the level the paper bound is solved for, explained
        assert "p_tol = tol / nx = " in text
    fig = kept.pop()
    fig.canvas.draw()
    r = fig.canvas.get_renderer()
    top, bot = fig.axes[:2]
    legend = fig.legends[0].get_window_extent(r)
    width = fig.bbox.width
    assert legend.x0 >= -0.05 * width and legend.x1 <= 1.05 * width     # not wider than the figure
    assert legend.y1 <= bot.get_window_extent(r).y0                       # below the panels
    label = top.yaxis.label.get_window_extent(r)
    ticks = [t.get_window_extent(r) for t in bot.get_yticklabels() if t.get_text()]
    assert not any(label.overlaps(t) for t in ticks)                      # y label clear of the lower ticks
    # the data fill the upper panel: the no-exchange limit far above is named, not drawn
    lo, hi = top.get_ylim()
    means = [y for ln in top.get_lines() if ln.get_marker() in ("o", "s") for y in ln.get_ydata()]
    assert (max(means) - min(means)) / (hi - lo) > 0.6
    # run counts drawn over the vertical answer lines
    counts = [t for t in top.texts if t.get_text().isdigit()]
    assert counts and all(t.get_zorder() > max(ln.get_zorder() for ln in top.get_lines()) for t in counts)
    for c in rm.COLORS.values():
        assert min(rgb_distance(c, b) for b in [v[1] for v in ESTIMATES.values()] + list(OTHER_COLORS)) >= 0.18


# ----------------------------------------------------------------------------
# Monte Carlo figures
# ----------------------------------------------------------------------------

ZOO = "estimators=[{kind: centralized}, {kind: local_only}, {kind: kcf}, {kind: icf}, {kind: diffusion_kf}]"


@pytest.fixture(scope="module")
def mc_folder(tmp_path_factory):
    out = tmp_path_factory.mktemp("mc") / "mc"
    assert main(["montecarlo", str(CASE1), "--runs", "3", "--steps", "80", "--jobs", "1", "--quiet",
                 "--set", ZOO, "--out", str(out)]) == 0
    return out


@pytest.fixture
def mc_figures(monkeypatch):
    import dkfsim.report.plots.accuracy as acc
    return keep_figures(monkeypatch, acc)


def test_mse_margin_names_each_value_and_nothing_covers_the_ratio_curves(mc_folder, mc_figures):
    from dkfsim.report.plots import load_folder
    from dkfsim.report.plots.accuracy import plot_mse
    folder = load_folder(mc_folder)
    plot_mse(folder, mc_folder / "f", ratio=True)
    fig = mc_figures.pop()
    left, right = fig.axes[0::2], fig.axes[1::2]
    for ax in right:
        values = [t.get_text() for t in ax.texts if "±" in t.get_text() or t.get_text()[:1].isalpha()]
        named = [v for v in values if ":" in v and not v.startswith("MSE")]
        assert sorted(v.split(":")[0] for v in named) == sorted(folder.mse)      # every value has its name
        inside = [t for t in ax.texts if 0 <= t.get_position()[0] <= 1]
        assert not inside                                 # no box over the curves
    assert "off this scale" in right[0].get_title()
    # a band whose lower end is <= 0 starts at the mean, not at 1e-300 (the bottom of the axis)
    for ax in left:
        for band in ax.collections:
            ys = np.concatenate([p.vertices[:, 1] for p in band.get_paths()])
            assert np.nanmin(ys) > 1e-100


def test_nees_small_multiples_share_one_y_axis_with_the_expected_line_on_top(mc_folder, mc_figures):
    from dkfsim.report.plots import load_folder
    from dkfsim.report.plots.accuracy import plot_nees
    folder = load_folder(mc_folder)
    plot_nees(folder, mc_folder / "n")
    axes = [ax for ax in mc_figures.pop().axes if ax.get_visible()]
    assert len(axes) == len(folder.nees) > 4
    assert len({ax.get_ylim() for ax in axes}) == 1       # one scale for all panels
    for ax in axes:
        trace, expected = [ln for ln in ax.get_lines() if len(ln.get_xdata()) > 2], \
            [ln for ln in ax.get_lines() if list(ln.get_ydata()) == [folder.nx, folder.nx]]
        assert expected and expected[0].get_zorder() > max(ln.get_zorder() for ln in trace)


# ----------------------------------------------------------------------------
# units and the state order
# ----------------------------------------------------------------------------

def test_kinematic_components_have_units_and_others_none():
    from dkfsim.config.dynamics import component_names, component_units
    assert component_units(component_names("constant_velocity", 4), "constant_velocity") == ["m", "m/s", "m", "m/s"]
    assert component_units(["position", "velocity"], "constant_velocity") == ["m", "m/s"]
    assert component_units(["position", "velocity", "acceleration"], None) == ["m", "m/s", "m/s$^2$"]
    assert component_units(["x", "vx", "y", "vy"], None) == ["m", "m/s", "m", "m/s"]       # a sweep: names only
    assert component_units(["x0", "x1"], "linear") == ["", ""]
    assert component_units(["x", "vx"], "linear") == ["", ""]                               # not its names


def test_constant_velocity_figures_have_units_the_state_order_and_node_0_in_local_colour(tmp_path, monkeypatch):
    import dkfsim.report.plots.accuracy as acc
    import dkfsim.report.plots.tracking as tr
    from dkfsim.report.plots.style import color_of
    kept = keep_figures(monkeypatch, acc, tr)
    out = tmp_path / "radar"
    assert main(["run", str(ROOT / "scenarios" / "radar_experiment.yaml"), "--steps", "40", "--quiet",
                 "--out", str(out)]) == 0
    assert main(["plot", str(out), "--format", "png"]) == 0
    tracking, mse = kept[:2]
    labels = [ax.get_ylabel() for ax in tracking.axes if ax.get_ylabel()]
    assert labels == ["x [m]", "vx [m/s]", "y [m]", "vy [m/s]"]
    assert "state [x, vx, y, vy]" in tracking._suptitle.get_text()
    assert "state [x, vx, y, vy]" in mse._suptitle.get_text()
    assert [ax.get_ylabel() for ax in mse.axes if "MSE" in ax.get_ylabel()][:2] == \
        ["x MSE [m$^2$]", "vx MSE [(m/s)$^2$]"]
    node0 = [ln for ln in tracking.axes[0].get_lines() if "anti-delay DKF, node 0" in ln.get_label()]
    assert node0 and all(ln.get_color() == color_of("local") for ln in node0)


def test_late_and_lost_are_labelled_per_run():
    from dkfsim.core.registry import METRICS
    from dkfsim.report.sweep.plot import METRIC_LABELS
    assert "per run" in METRIC_LABELS["late"] and "per run" in METRIC_LABELS["lost"]
    assert METRICS.get("late").implementation.unit and METRICS.get("lost").implementation.unit


# ----------------------------------------------------------------------------
# the HTML report
# ----------------------------------------------------------------------------

def test_report_packets_have_units_and_the_seeds_are_folded(mc_folder, tmp_path):
    import re
    assert main(["report", str(mc_folder), "--out", str(tmp_path / "r.html")]) == 0
    page = (tmp_path / "r.html").read_text()
    packets = page[page.index('id="packets"'):]
    packets = packets[:packets.index("</table>")]
    for head in ("messages per tick [1/tick]", "bytes per tick [B/tick]", "lost [packets/run]", "late [items/run]"):
        assert head in packets
    fold = re.search(r"<details><summary>Seeds of the 3 runs[^<]*</summary>(.*?)</details>", page, re.S)
    assert fold and fold.group(1).count("<tr>") >= 3        # every seed, behind a click


def test_sensor_names_are_drawn_under_the_node_circles_not_in_them():
    import networkx as nx

    from dkfsim.report.network import draw_network
    g = nx.path_graph(3)
    fig, _ = draw_network(g, g, is_tree=True, labels=["front_radar", "s2", "a_long_sensor_name"])
    ax = fig.axes[0]
    inside = [t.get_text() for t in ax.texts if not hasattr(t, "xyann")]
    below = [t for t in ax.texts if hasattr(t, "xyann")]
    assert sorted(inside) == ["0", "1", "2"]
    assert sorted(t.get_text() for t in below) == ["a_long_sensor_name", "front_radar", "s2"]
    assert all(t.xyann[1] < 0 and t.get_va() == "top" for t in below)


def test_rate_ticks_are_in_one_notation():
    """Issue 34 §6: a rate axis read 500000 beside 1e+06."""
    from dkfsim.report.sweep.plot import tick_texts
    assert tick_texts([1e5, 2e5, 5e5, 1e6, 6e6, 1.2e7]) == ["100k", "200k", "500k", "1M", "6M", "12M"]
    assert tick_texts([0, 1, 2, 4]) == ["0", "1", "2", "4"] and tick_texts([0.5, 1.25]) == ["0.5", "1.25"]

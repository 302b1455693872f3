"""`dkfsim plot`: figures from run folders, Monte Carlo folders and --compare, and its errors."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("matplotlib")        # the `plots` extra; Pillow comes with matplotlib
import matplotlib.image as mpimg  # noqa: E402
from PIL import Image  # noqa: E402

from dkfsim.cli.main import main  # noqa: E402
from dkfsim.core.errors import DkfsimError  # noqa: E402
from dkfsim.report import plots  # noqa: E402
from dkfsim.report.plots.style import png_resolution  # noqa: E402

#: The one test that draws at the default (print) resolution; the others draw at 100 dpi
#: to keep the suite fast (the figures are the same, only the pixel count differs).
PRINT_DPI_TEST = "test_run_folder_default_png_and_pdf"


@pytest.fixture(autouse=True)
def screen_dpi(request):
    if request.node.name == PRINT_DPI_TEST:
        yield 150
        return
    with png_resolution(100):
        yield 100

ROOT = Path(__file__).resolve().parents[1]
K_RUN = 60
T = 0.01


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("plots") / "run"
    rc = main(["run", str(ROOT / "scenarios" / "paper_case1.yaml"), "--out", str(out),
               "--steps", str(K_RUN), "--quiet"])
    assert rc == 0
    return out


def write_montecarlo(path: Path, K: int = K_RUN, runs: int = 4, T: float = T,
                     estimates=("fused", "centralized", "ci_consensus")) -> Path:
    """A Monte Carlo folder with the layout of the montecarlo contract."""
    path.mkdir(parents=True)
    rng = np.random.default_rng(0)
    A, nx = len(estimates), 3
    t = T * np.arange(1, K + 1)
    mse = np.exp(rng.normal(size=(A, K, nx))) * (1 + np.arange(A))[:, None, None]
    truth = np.cumsum(rng.normal(size=(K, nx)), axis=0)
    np.savez(path / "curves.npz", t=t, components=np.array(["position", "velocity", "acceleration"]),
             estimates=np.array(list(estimates)), mse=mse, mse_ci_lo=0.8 * mse, mse_ci_hi=1.25 * mse,
             nees=3 + rng.normal(size=(A, K)), nees_band=np.array([2.2, 3.9]),
             example_truth=truth, example_x=truth[None] + 0.3 * rng.normal(size=(A, K, nx)),
             example_node0=truth + rng.normal(size=(K, nx)))
    with open(path / "runs.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["run", "seed", "estimate", "component", "mse", "anees", "disagreement",
                    "messages_per_tick", "bytes_per_tick", "lost", "late"])
        for r in range(runs):
            for a in estimates:
                for c in ("position", "velocity", "acceleration"):
                    w.writerow([r, 100 + r, a, c, 0.2, 3.0, 0.0, 20.0, 960.0, 0, 0])
    summary = {"scenario": "fake_mc", "d_t": 3,
               "scenario_config": {"name": "fake_mc", "model": {"kind": "constant_acceleration", "T": T}},
               "runs": runs, "burn_in": K // 5,
               "estimates": {a: {"mse": {"position": 0.2, "velocity": 0.2, "acceleration": 0.1},
                                  "mse_ci95": {"position": [0.1, 0.3], "velocity": [0.15, 0.25],
                                               "acceleration": [None, None]},
                                  "anees": 3.0, "anees_band95": [2.2, 3.9]} for a in estimates}}
    (path / "summary.json").write_text(json.dumps(summary))
    return path


def assert_figures(folder: Path, stems, formats=("png", "pdf"), dpi=100):
    for stem in stems:
        for fmt in formats:
            f = folder / f"{stem}.{fmt}"
            assert f.is_file(), f"missing {f}"
            assert f.stat().st_size > 1000, f"{f} is (nearly) empty"
            if fmt == "png":
                img = mpimg.imread(f)
                assert img.ndim == 3 and img.shape[0] > 200 and img.shape[1] > 300
                assert img[..., :3].std() > 0.05, f"{f} looks blank"
                assert f.stat().st_size < (1_500_000 if dpi >= 300 else 400_000)   # (64-colour palette)
                with Image.open(f) as im:                      # 150: screens (issue 34); --dpi 300: print
                    assert round(im.info["dpi"][0]) == dpi
            if fmt == "pdf":
                assert f.read_bytes()[:5] == b"%PDF-"


def test_run_folder_default_png_and_pdf(run_dir, capsys, tmp_path):
    assert main(["plot", str(run_dir)]) == 0
    assert_figures(run_dir / "figures", ["tracking", "mse"], dpi=150)     # the default
    assert main(["plot", str(run_dir), "--dpi", "300", "--format", "png", "--out", str(tmp_path / "print")]) == 0
    assert_figures(tmp_path / "print", ["tracking", "mse"], formats=("png",), dpi=300)
    out = capsys.readouterr().out
    assert str(run_dir / "figures" / "mse.png") in out


def test_run_folder_curves_are_the_squared_errors(run_dir):
    f = plots.load_folder(run_dir)
    d = np.load(run_dir / "run.npz")
    assert f.kind == "run" and f.K == K_RUN
    assert f.components == ["position", "velocity", "acceleration"]
    assert f.units == ["m", "m/s", "m/s$^2$"]
    np.testing.assert_allclose(f.mse["fused"], (d["x_fused"] - d["truth"]) ** 2)
    np.testing.assert_allclose(f.mse["local"],
                               np.mean((d["x_local"] - d["truth"][:, None]) ** 2, axis=1))
    np.testing.assert_allclose(f.mse["centralized"], (d["x_centralized"] - d["truth"]) ** 2)
    np.testing.assert_allclose(f.node0, d["x_local"][:, 0])
    assert f.d_t == 4 and f.scenario == "paper_case1"


def test_out_and_format(run_dir, tmp_path):
    figs = tmp_path / "figs"
    assert main(["plot", str(run_dir), "--out", str(figs), "--format", "png", "--component", "position"]) == 0
    assert_figures(figs, ["tracking", "mse"], formats=("png",))
    assert not list(figs.glob("*.pdf"))


def test_montecarlo_folder(tmp_path):
    mc = write_montecarlo(tmp_path / "mc")
    f = plots.load_folder(mc)
    assert f.kind == "montecarlo" and f.n_runs == 4 and f.d_t == 3
    assert set(f.ci) == {"fused", "centralized", "ci_consensus"}
    assert f.nees_band == (2.2, 3.9)
    assert f.ci95("centralized", 1) == (0.15, 0.25) and f.ci95("centralized", 2) is None
    z = np.load(mc / "curves.npz")
    assert f.time_average("ci_consensus", 2) == pytest.approx(z["mse"][2, K_RUN // 5:, 2].mean())
    assert main(["plot", str(mc)]) == 0
    assert_figures(mc / "figures", ["tracking", "mse", "nees"])


def test_montecarlo_folder_of_an_older_version_reads_in_todays_names(tmp_path):
    """Folders written before the one vocabulary said ``algorithms`` and
    ``anti_delay_dkf`` / ``anti_delay_dkf_local`` / ``local``."""
    old_names = ("anti_delay_dkf", "anti_delay_dkf_local", "local", "centralized")
    mc = write_montecarlo(tmp_path / "old", estimates=old_names)
    z = dict(np.load(mc / "curves.npz"))
    z["algorithms"] = z.pop("estimates")
    np.savez(mc / "curves.npz", **z)
    summary = json.loads((mc / "summary.json").read_text())
    summary["algorithms"] = summary.pop("estimates")
    (mc / "summary.json").write_text(json.dumps(summary))
    f = plots.load_folder(mc)
    assert list(f.mse) == ["fused", "local", "local_only", "centralized"]
    np.testing.assert_array_equal(f.mse["local_only"], z["mse"][2])
    assert f.ci95("fused", 0) == (0.1, 0.3)
    assert main(["plot", str(mc), "--format", "png"]) == 0
    assert_figures(mc / "figures", ["mse"], formats=("png",))


def test_montecarlo_folder_without_examples_or_nees(tmp_path):
    mc = tmp_path / "mc"
    write_montecarlo(mc)
    z = dict(np.load(mc / "curves.npz"))
    for k in ("example_truth", "example_x", "example_node0", "nees", "nees_band", "mse_ci_lo", "mse_ci_hi"):
        z.pop(k)
    np.savez(mc / "curves.npz", **z)
    assert main(["plot", str(mc), "--format", "png"]) == 0
    assert_figures(mc / "figures", ["mse"], formats=("png",))
    assert not (mc / "figures" / "tracking.png").exists()
    assert not (mc / "figures" / "nees.png").exists()


def test_compare_two_folders(run_dir, tmp_path):
    mc = write_montecarlo(tmp_path / "mc")
    figs = tmp_path / "cmp"
    rc = main(["plot", str(run_dir), str(mc), "--compare", "--labels", "case 1", "case 2",
               "--out", str(figs), "--name", "fig5"])
    assert rc == 0
    assert_figures(figs, ["fig5"])
    rc = main(["plot", str(run_dir), str(mc), "--compare", "--relative", "--out", str(figs),
               "--name", "fig5_relative", "--format", "png"])
    assert rc == 0
    assert_figures(figs, ["fig5_relative"], formats=("png",))
    # the ratio column makes the figure wider than the plain one
    assert mpimg.imread(figs / "fig5_relative.png").shape[1] > mpimg.imread(figs / "fig5.png").shape[1] * 1.3


def test_compare_default_output_and_one_component(run_dir, tmp_path):
    mc = write_montecarlo(tmp_path / "mc")
    assert main(["plot", str(mc), str(run_dir), "--compare", "--component", "position", "--format", "png"]) == 0
    assert_figures(mc / "figures", ["compare_mse"], formats=("png",))


def test_compare_tells_folders_apart_by_line_style_never_by_another_estimate_colour(tmp_path, monkeypatch):
    """Colours mean estimates in every figure: the folders of --compare are the compared
    estimate's colour (lighter for later folders) in one line style each, and no folder line
    takes another built-in estimate's colour (they were C0, C1, C2: fused, no_buffer,
    centralized_delayed)."""
    from matplotlib.axes import Axes
    from matplotlib.colors import to_rgb

    from dkfsim.report.plots import compare, style
    drawn: list = []                       # (label, rgb, ls as asked) of every line, in order
    real_plot = Axes.plot

    def plot(ax, *a, **kw):
        drawn.append((kw.get("label", ""), to_rgb(kw["color"]), str(kw.get("ls", "-"))))
        return real_plot(ax, *a, **kw)
    monkeypatch.setattr(Axes, "plot", plot)
    titles: list = []
    monkeypatch.setattr(compare, "save_figure",
                        lambda fig, _s, _f: titles.append(fig.legends[0].get_title().get_text()) or [])
    folders = [write_montecarlo(tmp_path / f"mc{j}") for j in range(4)]
    labels = ["a", "b", "c", "d"]
    compare.plot_compare([plots.load_folder(f) for f in folders], tmp_path / "c", labels=labels,
                         components=["position"], relative=True)
    lines = {lab: (rgb, ls) for lab, rgb, ls in drawn if lab in labels}
    assert list(lines) == labels
    fused = to_rgb(style.color_of("fused"))
    assert lines["a"] == (pytest.approx(fused), "-")
    assert len({ls for _rgb, ls in lines.values()}) == 4              # one line style per folder
    others = [to_rgb(style.color_of(a)) for a in style.ESTIMATES if a != "fused"]
    for lab, (rgb, _ls) in lines.items():
        assert min(rgb_distance(rgb, o) for o in others) >= DISTINCT, (lab, rgb)
        # a shade of fused's blue: on the segment from it to white
        t = (np.array(rgb) - fused) / (1 - np.array(fused))
        assert np.allclose(t, t[0]) and 0 <= t[0] <= 0.6, (lab, rgb)
    centre = [(rgb, ls) for lab, rgb, ls in drawn if lab.startswith("centralized")]
    assert centre == [(to_rgb(style.color_of("centralized")), "--")]      # as in every figure
    assert all(ls != "--" for _rgb, ls in lines.values())
    ratios = [(rgb, ls) for lab, rgb, ls in drawn if not lab]          # the ratio column, same looks
    assert ratios == list(lines.values())
    assert "line style per folder" in titles[0]


def test_compare_escapes_a_label_once(tmp_path, monkeypatch):
    """A --labels value is plain text: its "$" is escaped once, in the legend and in the column
    of averages (that column escaped the escaped label again and drew its backslashes)."""
    from dkfsim.report.plots import compare
    texts: list = []

    def capture(fig, _stem, _formats):
        texts.extend(t.get_text() for ax in fig.axes for t in ax.texts)
        texts.extend(t.get_text() for t in fig.legends[0].get_texts())
        return []
    monkeypatch.setattr(compare, "save_figure", capture)
    folders = [plots.load_folder(write_montecarlo(tmp_path / f"mc{j}")) for j in range(2)]
    compare.plot_compare(folders, tmp_path / "c", labels=["$d_t$ = 1", "two"], components=["position"])
    assert "\\$d_t\\$ = 1" in texts                                   # the legend entry
    assert any(t.startswith("\\$d_t\\$ = 1: ") for t in texts), texts     # the averages column
    assert not any("\\\\" in t for t in texts), texts


def test_every_compared_folder_has_its_own_look():
    """(colour, line style) pairs of --compare's folders are all different, the line styles
    too up to six folders (then the shade tells them apart)."""
    from dkfsim.report.plots.compare import folder_looks
    for n in range(1, 13):
        colors, styles = folder_looks("C0", n)
        assert len(colors) == len(styles) == n
        assert len({(c, str(s)) for c, s in zip(colors, styles)}) == n
        assert len({str(s) for s in styles}) == min(n, 6)


def fails(capsys, argv, *words):
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("dkfsim plot: error: ")
    for w in words:
        assert w in err, err
    return err


def test_errors(run_dir, tmp_path, capsys):
    fails(capsys, ["plot", str(tmp_path / "nope")], "no such folder")
    empty = tmp_path / "empty"
    empty.mkdir()
    fails(capsys, ["plot", str(empty)], "neither a run folder", "Monte Carlo")
    fails(capsys, ["plot", str(run_dir / "run.npz")], "not a folder")
    short = write_montecarlo(tmp_path / "short", K=K_RUN - 20)
    fails(capsys, ["plot", str(run_dir), str(short), "--compare"], "40 ticks", "60")
    slow = write_montecarlo(tmp_path / "slow", T=0.1)
    fails(capsys, ["plot", str(run_dir), str(slow), "--compare"], "different sample times")
    fails(capsys, ["plot", str(run_dir), str(run_dir), "--compare", "--labels", "a"], "1 labels for 2 folders")
    fails(capsys, ["plot", str(run_dir), "--compare"], "at least two folders")
    fails(capsys, ["plot", str(run_dir), "--labels", "a"], "--labels", "--compare")
    fails(capsys, ["plot", str(run_dir), "--component", "jerk"], "'jerk'", "position")
    # one --component rule for a folder and a sweep (report.plots.style.select_components)
    fails(capsys, ["plot", str(run_dir), "--component", "veloctiy"],
          f"is not a component of {run_dir} (did you mean 'velocity'?) (components: position, "
          "velocity, acceleration, or 0..2)")
    fails(capsys, ["plot", str(run_dir), "--smooth", "0"], "--smooth")
    fails(capsys, ["plot", str(run_dir), "--relative"], "--relative", "--compare")
    no_central = write_montecarlo(tmp_path / "nocentral", estimates=("fused", "ci_consensus"))
    fails(capsys, ["plot", str(no_central), str(run_dir), "--compare", "--relative"], "no centralized")


def test_errors_in_the_files(tmp_path, capsys):
    summ_only = tmp_path / "summ"
    summ_only.mkdir()
    (summ_only / "summary.json").write_text("{}")
    fails(capsys, ["plot", str(summ_only)], "no run.npz", "--save")
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "run.npz").write_bytes(b"not a zip file")
    fails(capsys, ["plot", str(bad)], "run.npz", "not a readable")
    mc = write_montecarlo(tmp_path / "mc")
    z = dict(np.load(mc / "curves.npz"))
    z["mse"] = z["mse"][:, :10]
    np.savez(mc / "curves.npz", **z)
    with pytest.raises(DkfsimError, match="'mse' has shape"):
        plots.load_folder(mc)


def test_component_names_and_smoothing():
    assert plots.component_names(3, "constant_acceleration") == ["position", "velocity", "acceleration"]
    assert plots.component_names(3, "linear") == ["x0", "x1", "x2"]
    assert plots.component_names(2, "constant_acceleration") == ["x0", "x1"]
    assert plots.component_names(4, "constant_velocity") == ["x", "vx", "y", "vy"]
    a = np.array([0.0, 3.0, 0.0, 0.0, 6.0])
    np.testing.assert_allclose(plots.moving_average(a, 3), [1.5, 1.0, 1.0, 2.0, 3.0])
    np.testing.assert_allclose(plots.moving_average(a, 1), a)
    np.testing.assert_allclose(plots.moving_average(np.ones((7, 2)), 4), np.ones((7, 2)))


def test_a_figure_file_gets_the_mode_of_the_umask_like_every_other_output(tmp_path):
    """save_figure writes through a mkstemp file (mode 0o600): it must get 0o666 & ~umask before
    the rename, as the JSON and CSV files of the same folder do (a maxdelay folder holds both)."""
    import os

    from dkfsim.core.extras import pyplot
    from dkfsim.report.plots.style import save_figure
    old = os.umask(0o022)
    try:
        fig = pyplot().figure()
        paths = save_figure(fig, tmp_path / "f", ("png", "pdf"))
    finally:
        os.umask(old)
    assert [p.name for p in paths] == ["f.png", "f.pdf"]
    assert all((p.stat().st_mode & 0o777) == 0o644 for p in paths)


def test_a_figure_that_fails_midway_leaves_the_previous_file_and_no_temporary(tmp_path):
    """Figures are replaced like every other output (core.folders.replacing): a format that
    fails while writing keeps the previous file whole and leaves nothing beside it."""
    from dkfsim.core.extras import pyplot
    from dkfsim.report.plots.style import save_figure
    (tmp_path / "f.pdf").write_bytes(b"the previous figure")
    fig = pyplot().figure()
    real = fig.savefig

    def half_then_fail(fh, **kw):
        if kw.get("format") == "pdf":
            fh.write(b"%PDF- half")
            raise OSError(28, "No space left on device")
        return real(fh, **kw)
    fig.savefig = half_then_fail
    with pytest.raises(DkfsimError, match=r"f\.pdf: cannot write the figure \(No space left on device\)"):
        save_figure(fig, tmp_path / "f", ("png", "pdf"))
    assert (tmp_path / "f.pdf").read_bytes() == b"the previous figure"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f.pdf", "f.png"]


# ----------------------------------------------------------------------------
# colours: built-in names fixed, other names from a palette without those colours
# (issue 24 §2, decision 197)
# ----------------------------------------------------------------------------

#: Smallest RGB distance (0..sqrt 3) counted as "another colour": "C0" and "#1f77b4" are
#: one colour, and so are the near copies the old palette held ("#3182bd" beside "C0").
DISTINCT = 0.18


def rgb_distance(a, b) -> float:
    from matplotlib.colors import to_rgb
    return float(np.linalg.norm(np.subtract(to_rgb(a), to_rgb(b))))


def built_in_names() -> list[str]:
    """``fused``, ``local`` and the default name (= kind) of every estimator kind shipped in
    dkfsim.components.estimators, read from the registry (not from the colour table)."""
    import dkfsim.components.estimators  # noqa: F401  (registers the built-in kinds)
    from dkfsim.core.registry import ESTIMATORS
    kinds = [e.name for e in ESTIMATORS.entries()
             if e.params is not None and e.params.__module__ == "dkfsim.components.estimators"]
    assert {"centralized", "ci_consensus", "anti_delay_dkf", "hcmci"} <= set(kinds)
    return ["fused", "local", *kinds]


def test_every_built_in_name_has_its_own_fixed_colour():
    from dkfsim.report.plots.style import color_of
    names = built_in_names()
    others = ["aa", "zz", "neighbour_mean", "dkf_b"]
    colours = {a: color_of(a) for a in names}
    for a in names:                       # the same whatever else the result holds
        assert color_of(a, names + others) == color_of(a, others[:1]) == colours[a], a
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            assert rgb_distance(colours[a], colours[b]) >= DISTINCT, (a, b, colours[a], colours[b])


def test_an_unknown_name_never_gets_a_built_in_colour():
    from dkfsim.report.plots.style import color_of
    fixed = [color_of(a) for a in built_in_names()]
    unknown = [f"plugin_{k:02d}" for k in range(25)]
    for k in range(1, len(unknown) + 1):
        result = built_in_names() + unknown[:k]
        for a in unknown[:k]:
            c = color_of(a, result)
            near = [f for f in fixed if rgb_distance(c, f) < DISTINCT]
            assert not near, (a, k, c, near)


def test_unknown_names_get_distinct_colours_whatever_their_order():
    import itertools

    from dkfsim.report.plots.style import color_of
    names = ["zeta", "fused", "neighbour_mean", "centralized", "dkf_b", "nm_self"]
    first = {a: color_of(a, names) for a in names}
    for perm in itertools.permutations(names):
        assert {a: color_of(a, list(perm)) for a in perm} == first
    unknown = [f"u{k}" for k in range(10)]
    cols = [color_of(a, unknown) for a in unknown]
    for i in range(len(cols)):
        for j in range(i + 1, len(cols)):
            assert rgb_distance(cols[i], cols[j]) >= DISTINCT, (unknown[i], unknown[j])


def line_colours(monkeypatch, folder: Path, tmp_path: Path) -> dict:
    """Legend label -> RGB of the MSE figure drawn from ``folder`` (captured before saving)."""
    from matplotlib.colors import to_rgb

    from dkfsim.report.plots import accuracy, style
    seen: dict = {}
    real = style.save_figure            # (not accuracy's: a second call would find the first capture)

    def capture(fig, stem, formats):
        for ax in fig.axes:
            for line in ax.get_lines():
                if not line.get_label().startswith("_"):
                    seen[line.get_label()] = to_rgb(line.get_color())
        return real(fig, stem, formats)

    monkeypatch.setattr(accuracy, "save_figure", capture)
    accuracy.plot_mse(plots.load_folder(folder), tmp_path / "mse", formats=("png",), ratio=False)
    return seen


def test_a_name_has_the_same_colour_in_a_run_and_a_montecarlo_figure(monkeypatch, tmp_path):
    # a run with a second DKF and a renamed no_buffer (names the colour table does not know)
    run = tmp_path / "run"
    assert main(["run", str(ROOT / "scenarios" / "paper_case1.yaml"), "--out", str(run), "--steps", "40",
                 "--quiet", "--set", "estimators=[{kind: centralized}, {kind: anti_delay_dkf, name: dkf_b, "
                 "buffer_length: 1}, {kind: no_buffer, name: aa_nb}]"]) == 0
    # a Monte Carlo folder of the same estimates, listed in another order
    mc = write_montecarlo(tmp_path / "mc", estimates=("aa_nb", "centralized", "local", "dkf_b", "fused"))
    in_run = line_colours(monkeypatch, run, tmp_path / "f1")
    in_mc = line_colours(monkeypatch, mc, tmp_path / "f2")
    from dkfsim.report.plots.style import label_of
    labels = [label_of(a) for a in ("fused", "local", "centralized", "dkf_b", "aa_nb")]
    assert set(labels) <= set(in_run) and set(labels) <= set(in_mc)
    for lab in labels:
        assert in_run[lab] == in_mc[lab], lab
    assert rgb_distance(in_run["dkf_b"], in_run["aa_nb"]) >= DISTINCT
    for a in ("fused", "local", "centralized"):          # not the colour of a built-in
        assert rgb_distance(in_run["dkf_b"], in_run[label_of(a)]) >= DISTINCT
        assert rgb_distance(in_run["aa_nb"], in_run[label_of(a)]) >= DISTINCT

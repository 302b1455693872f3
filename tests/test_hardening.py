"""Bad input of every kind ends in a clear error, quickly; nothing computed is lost.

One test (or a parametrised family) per class of hostile input: YAML that
nests too deep or expands without end, special files, numbers that fit a
float but not the int64 clock or float64 products, requests that cannot fit
in memory or would take hours, output folders that cannot take a result,
and runs killed while they write.  Each asserts the message names the file
and key and says what is wrong, and that the command ends in seconds.
"""

from __future__ import annotations

import csv
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml
from conftest import scenario

import dkfsim
from dkfsim.core.errors import DkfsimError, ScenarioError
from dkfsim.core.resources import ResourceError

ROOT = Path(__file__).resolve().parents[1]
CASE1 = ROOT / "scenarios" / "paper_case1.yaml"


def cli(*args, timeout=60, **kw):
    """``dkfsim ARGS`` as a user runs it: a real process."""
    return subprocess.run([sys.executable, "-m", "dkfsim", *map(str, args)], capture_output=True,
                          text=True, timeout=timeout, **kw)


class cpu_clock:
    """CPU seconds spent by child processes inside the block: what "answered in seconds" means,
    measured so that a loaded machine (other jobs, a parallel test worker) cannot fail it."""

    def __enter__(self):
        t = os.times()
        self.start = t.children_user + t.children_system
        return self

    def __exit__(self, *exc):
        t = os.times()
        self.seconds = t.children_user + t.children_system - self.start


def one_paragraph(p, *words):
    """Exit 2, no traceback, one line naming every word."""
    assert p.returncode == 2, (p.returncode, p.stdout, p.stderr)
    err = p.stderr.strip()
    assert "Traceback" not in p.stderr and "\n" not in err, p.stderr
    for w in words:
        assert w in err, (w, err)
    return err


# =========================================================================== YAML
@pytest.mark.parametrize("text, words", [
    ("a: " + "[" * 5000 + "]" * 5000, ["nested deeper than 64 levels", "line 1"]),
    ("".join(" " * i + f"k{i}:\n" for i in range(3000)) + " " * 3000 + "x: 1\n",
     ["nested deeper than 64 levels"]),
    ("a: &a [x, x, x, x, x, x, x, x, x]\n" + "".join(
        f"{c}: &{c} [{', '.join(['*' + p] * 9)}]\n" for p, c in zip("abcdefghi", "bcdefghij")),
     ["alias bomb", "line 7"]),
    ("seed: &s [*s]\n", ["refers to a node that contains it"]),
])
@pytest.mark.slow
def test_hostile_yaml_is_refused_quickly(tmp_path, text, words):
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with cpu_clock() as c:
        p = cli("validate", path)
    assert c.seconds < 20
    one_paragraph(p, str(path), *words)
    assert len(p.stderr) < 2000


@pytest.mark.slow
def test_alias_bomb_in_a_field_gives_a_short_message(tmp_path):
    """A value that expands to megabytes is not echoed back whole."""
    d = yaml.safe_load(CASE1.read_text())
    text = yaml.safe_dump(d) + "".join(f"x{i}: &x{i} [{', '.join(['*x' + str(i - 1)] * 4) if i else '1'}]\n"
                                       for i in range(9)) + "name: *x8\n"
    path = tmp_path / "bomb.yaml"
    path.write_text(text.replace("name: paper_case1\n", ""))
    p = cli("validate", path)
    err = one_paragraph(p, str(path))
    assert len(err) < 1000


def test_merge_keys_are_not_duplicates(tmp_path):
    """``<<: *base`` then a key of its own: the own key overrides the merged one."""
    d = yaml.safe_load(CASE1.read_text())
    text = yaml.safe_dump({k: v for k, v in d.items() if k != "links"}) + \
        "links:\n  default:\n    latency: &lat {model: uniform_steps, d_t: 4}\n" \
        "  overrides:\n    - link: [0, 1]\n      latency:\n        <<: *lat\n        d_t: 2\n"
    path = tmp_path / "merge.yaml"
    path.write_text(text)
    sc = dkfsim.load_scenario(path)
    assert sc.link_spec(0, 1).latency.d_t == 2 and sc.link_spec(1, 4).latency.d_t == 4
    path.write_text(text + "seed: 3\n")
    with pytest.raises(ScenarioError, match="duplicate key 'seed'"):      # a real duplicate still is one
        dkfsim.load_scenario(path)


def test_deep_mapping_from_python_is_a_clean_error():
    d = yaml.safe_load(CASE1.read_text())
    deep = []
    for _ in range(2000):
        deep = [deep]
    d["model"]["Q"] = deep
    with pytest.raises(ScenarioError, match="nested deeper than 64 levels"):
        dkfsim.load_scenario(d)


# =========================================================================== special files
@pytest.mark.slow
@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs on this platform")
def test_a_fifo_does_not_block(tmp_path):
    fifo = tmp_path / "pipe.yaml"
    os.mkfifo(fifo)
    with cpu_clock() as c:
        one_paragraph(cli("validate", fifo, timeout=20), str(fifo), "not a regular file")
    assert c.seconds < 20


@pytest.mark.slow
def test_special_files_are_refused(tmp_path):
    zero = tmp_path / "zero.yaml"
    zero.symlink_to("/dev/zero")
    one_paragraph(cli("validate", zero), str(zero), "not a regular file")
    one_paragraph(cli("validate", tmp_path), str(tmp_path), "is a directory")
    one_paragraph(cli("validate", ""), "empty path")
    huge = tmp_path / "huge.yaml"
    with open(huge, "wb") as fh:
        fh.truncate(9 << 20)                   # sparse: costs no disk
    one_paragraph(cli("validate", huge), str(huge), "bytes, more than")
    (tmp_path / "trace.csv").symlink_to("/dev/zero")
    d = scenario(3, latency={"model": "empirical", "file": "trace.csv"}, buffer_length=2)
    with pytest.raises(ScenarioError, match="not a regular file"):
        dkfsim.load_scenario(d, base_dir=tmp_path)


@pytest.mark.slow
def test_a_sweep_file_that_is_a_fifo_does_not_block(tmp_path):
    fifo = tmp_path / "sweep.yaml"
    os.mkfifo(fifo)
    one_paragraph(cli("sweep", fifo, "--dry-run", timeout=20), str(fifo), "not a regular file")


# =========================================================================== numbers
@pytest.mark.parametrize("override, key, words", [
    ("model.T=1e10", "model.T", ["2^62 ns"]),
    ("model.T=1e300", "model.T", ["2^62 ns"]),
    ("steps=1000000000000", "steps", ["int64 nanosecond clock", "use at most"]),
    ("links.default.latency.d_t=4611686018427387000", "links.default", ["int64 nanosecond clock"]),
    ("links.d_t=4611686018427387000", "links.d_t", ["int64 nanosecond clock"]),
    ("buffer_length=4611686018427387000", "buffer_length", ["int64 nanosecond clock"]),
    ("links.default.schedule={kind: step, at: 0.1, factor: 1e300}", "links.default.schedule.0.factor",
     ["float64"]),
    ("links.default.schedule={kind: step, at: 0.1, factor: 1e90}", "links.default", ["int64"]),
    ("links.default.latency={model: constant, value: 1e300}", "links.default.latency.value", ["2^62 ns"]),
    ("sensors.0.R=[[1e300]]", "sensors.0.R", ["at most 1e+100"]),
    ("prior.mean=[1e300, 0, 0]", "prior.mean", ["at most 1e+100"]),
    ("model.Q=[[1e300,0,0],[0,1,0],[0,0,1]]", "model.Q", ["at most 1e+100"]),
])
def test_numbers_the_representation_cannot_hold(override, key, words):
    with pytest.raises(ScenarioError) as info:
        dkfsim.load_scenario(CASE1, [override])
    assert info.value.path == key, str(info.value)
    for w in words:
        assert w in str(info.value), str(info.value)


def test_radar_position_beyond_float64_headroom():
    radar = ROOT / "scenarios" / "radar_experiment.yaml"
    with pytest.raises(ScenarioError, match="at most 1e\\+100") as info:
        dkfsim.load_scenario(radar, ["sensors.0.position=[1e300, 0]"])
    assert info.value.path == "sensors.0.position"


def test_unbounded_latency_scaled_without_end_still_runs():
    """A factor that pushes draws past 2^62 ns clamps them: those packets never arrive."""
    res = dkfsim.run(dkfsim.load_scenario(CASE1, [
        "links.default.latency={model: pareto, alpha: 0.5, scale: 1e9}", "links.d_t=4",
        "links.default.schedule={kind: step, at: 0.05, factor: 1e90}", "steps=30"]))
    assert res.counts["delivered"] < res.counts["sent"]
    assert np.isfinite(res["x_fused"]).all() and res.diverged == []


@pytest.mark.slow
def test_an_exploding_model_finishes_and_says_it_diverged(tmp_path):
    sc = dkfsim.load_scenario(CASE1, ["model.kind=linear", "model.Phi=[[1e50,0,0],[0,1,0],[0,0,1]]",
                                      "steps=20", "baselines=[centralized,local,ci_consensus]"])
    res = dkfsim.run(sc)
    assert "x_fused" in res.diverged and "x_centralized" in res.diverged
    res.save(tmp_path / "out")
    s = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert "x_fused" in s["diverged"]
    assert all(v in ("nan", "inf", "-inf") or isinstance(v, float) for v in s["metrics"]["fused"])
    assert "nan" in s["metrics"]["fused"] or "inf" in s["metrics"]["fused"]
    with np.load(tmp_path / "out" / "run.npz", allow_pickle=False) as z:
        assert all(z[k].dtype != object for k in z.files)
    p = cli("run", CASE1, "--out", tmp_path / "cli", "--set", "model.kind=linear", "--set",
            "model.Phi=[[1e50,0,0],[0,1,0],[0,0,1]]", "--steps", 20)
    assert p.returncode == 0 and "DIVERGED" in p.stdout and "Warning" not in p.stderr, p.stderr


# =========================================================================== resources
@pytest.mark.slow
def test_a_run_that_cannot_fit_is_refused_before_it_starts(tmp_path):
    with cpu_clock() as c:
        p = cli("run", CASE1, "--out", tmp_path / "o", "--set", "model.T=1e-6", "--steps", 10**12)
    err = one_paragraph(p, "memory", "more than the")
    assert c.seconds < 20 and not (tmp_path / "o").exists(), err
    with pytest.raises(ResourceError, match="memory"):
        dkfsim.run(dkfsim.load_scenario(CASE1, ["model.T=1e-6", "steps=1000000000000"]))


@pytest.mark.slow
def test_hours_of_consensus_rounds_ask_for_yes(tmp_path):
    p = cli("run", CASE1, "--out", tmp_path / "o", "--set", "consensus_rounds=10000000",
            "--set", "baselines=[ci_consensus]")
    one_paragraph(p, "would take about", "--yes")
    with pytest.raises(ResourceError, match="yes"):
        dkfsim.run(dkfsim.load_scenario(CASE1, ["consensus_rounds=10000000", "baselines=[ci_consensus]"]))


@pytest.mark.slow
def test_a_20000_node_graph_is_answered_in_seconds(tmp_path):
    d = yaml.safe_load(CASE1.read_text())
    d["sensors"] = [{"name": f"s{i}", "H": [[1, 0, 0]], "R": [[1.0]]} for i in range(20000)]
    for topology, protocol in (({"generator": "random_tree"}, "tree"),
                               ({"generator": "random_regular", "params": {"d": 3}}, "flood")):
        d["topology"], d["protocol"] = topology, protocol
        path = tmp_path / f"{protocol}.yaml"
        path.write_text(yaml.safe_dump(d))
        # Refused at validation (fusion's cross-covariances): the size in GiB names the memory.
        with cpu_clock() as c:
            p = cli("run", path, "--out", tmp_path / "o", timeout=300)
        one_paragraph(p, "20000 nodes", "GiB")
        assert c.seconds < 60
    d["topology"] = {"generator": "erdos_renyi", "params": {"p": 0.5}}
    with pytest.raises(ScenarioError, match="edges, more than") as info:
        dkfsim.load_scenario(d)
    assert info.value.path == "topology.params.p"


def write_sweep(tmp_path, **kw):
    data = {"scenario": str(CASE1), "runs": 1, **kw}
    path = tmp_path / "s.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


@pytest.mark.slow
def test_huge_sweeps_are_refused_or_need_yes(tmp_path):
    p = cli("sweep", write_sweep(tmp_path, runs=10**9), timeout=60)
    one_paragraph(p, "tasks left", "memory")
    grid = {"seed": list(range(1000)), "steps": list(range(1, 1001))}
    with cpu_clock() as c:
        p = cli("sweep", write_sweep(tmp_path, grid=grid), "--dry-run", timeout=120)
    one_paragraph(p, "1,000,000 parameter sets")
    assert c.seconds < 30
    p = cli("sweep", write_sweep(tmp_path, runs=2000), "--jobs", 1, timeout=60)
    one_paragraph(p, "would take about", "--yes")


@pytest.mark.parametrize("flags, words", [
    (["--max-scale", "inf"], ["--max-scale", "finite"]),
    (["--scale-step", "1e-12"], ["candidates", "memory"]),
])
@pytest.mark.slow
def test_maxdelay_settings_that_never_end(tmp_path, flags, words):
    d = yaml.safe_load(CASE1.read_text())
    d["links"]["default"]["latency"] = {"model": "constant", "value": 0.02}
    path = tmp_path / "c.yaml"
    path.write_text(yaml.safe_dump(d))
    one_paragraph(cli("maxdelay", path, "--relative", 1.5, "--out", tmp_path / "o", *flags), *words)


# =========================================================================== output
@pytest.mark.slow
def test_out_problems_are_found_before_the_run(tmp_path):
    (tmp_path / "file").write_text("x")
    (tmp_path / "theirs").mkdir()
    (tmp_path / "theirs" / "notes.txt").write_text("mine")
    (tmp_path / "npzdir" / "run.npz").mkdir(parents=True)
    # A run this long would need minutes of CPU: far over the bound below if it ever started.
    slow = ["--set", "consensus_rounds=10", "--set", "baselines=[ci_consensus]", "--steps", 5000]
    for out, words in ((tmp_path / "file", ["not a folder"]),
                       (tmp_path / "theirs", ["did not write", "notes.txt"]),
                       (tmp_path / "npzdir", ["run.npz inside it is a folder"]),
                       (tmp_path / "file" / "sub", ["cannot write"])):
        with cpu_clock() as c:
            p = cli("run", CASE1, "--out", out, *slow, timeout=600)
        one_paragraph(p, "--out", *words)
        assert c.seconds < 10          # the 5000-tick run never started
    assert (tmp_path / "theirs" / "notes.txt").read_text() == "mine"
    for cmd in (["montecarlo", CASE1, "--runs", 2], ["maxdelay", CASE1, "--relative", 1.5]):
        one_paragraph(cli(*cmd, "--out", tmp_path / "theirs"), "did not write")


@pytest.mark.slow
def test_plot_name_cannot_leave_the_figures_folder(tmp_path):
    dkfsim.run(CASE1, steps=20).save(tmp_path / "r")
    one_paragraph(cli("plot", tmp_path / "r", tmp_path / "r", "--compare", "--name", "../../x"),
                  "--name", "without folders")
    assert not (tmp_path.parent / "x.png").exists()


def _summary_steps(folder: Path) -> int:
    return json.loads((folder / "summary.json").read_text())["steps"]


def test_a_failed_save_leaves_the_previous_output(tmp_path, monkeypatch):
    out = tmp_path / "out"
    dkfsim.run(CASE1, steps=10).save(out)
    before = {p.name: p.read_bytes() for p in out.iterdir()}

    def boom(*_, **__):
        raise OSError(28, "No space left on device")
    monkeypatch.setattr(np, "savez", boom)
    with pytest.raises(DkfsimError, match="No space left on device.*holds what it held before"):
        dkfsim.run(CASE1, steps=12).save(out)
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    assert [p.name for p in tmp_path.iterdir()] == ["out"]          # no staging folder left


@pytest.mark.slow
def test_a_run_killed_at_any_moment_leaves_old_or_new_output(tmp_path):
    """kill -9 at several moments of a second run into the same folder: the folder
    holds either the first run's complete output or the second's, never a mix."""
    out = tmp_path / "out"
    assert cli("run", CASE1, "--out", out, "--steps", 50, "--quiet").returncode == 0
    first = _summary_steps(out)
    seen = set()
    for delay in (0.3, 0.8, 1.2, 1.6, 2.0, 2.5, 3.5):
        p = subprocess.Popen([sys.executable, "-m", "dkfsim", "run", str(CASE1), "--out", str(out),
                              "--steps", "400", "--quiet"])
        time.sleep(delay)
        p.send_signal(signal.SIGKILL)
        p.wait()
        steps = _summary_steps(out)
        seen.add(steps)
        with np.load(out / "run.npz", allow_pickle=False) as z:
            assert z["truth"].shape[0] == steps          # run.npz and summary.json of one run
        with open(out / "rows.csv", newline="") as f:    # rows.csv too
            rows = list(csv.DictReader(f))
        summary_rows = json.loads((out / "summary.json").read_text())["rows"]
        assert rows and [float(r["mse"]) for r in rows] == [float(r["mse"]) for r in summary_rows]
        assert {p.name for p in out.iterdir()} == {".dkfsim-output", "run.npz", "summary.json", "rows.csv"}
    assert seen <= {first, 400}


@pytest.mark.slow
def test_make_run_twice_replaces_the_folder(tmp_path):
    out = tmp_path / "case1"
    for steps in (30, 40):
        p = cli("run", CASE1, "--out", out, "--steps", steps, "--quiet")
        assert p.returncode == 0, p.stderr
    assert _summary_steps(out) == 40


# =========================================================================== API and pipes
def test_run_takes_a_path_and_the_package_exports_the_entry_points(tmp_path):
    res = dkfsim.run(str(CASE1), steps=20)
    assert res["x_fused"].shape == (20, 3)
    for name in ("run", "montecarlo", "sweep", "maxdelay", "load_scenario", "load_run"):
        assert callable(getattr(dkfsim, name)) and name in dkfsim.__all__
    res.save(tmp_path / "r")
    back = dkfsim.load_run(tmp_path / "r")
    np.testing.assert_array_equal(back["x_fused"], res["x_fused"])
    assert back.counts["sent"] == res.counts["sent"] and back.scenario == res.scenario
    mc = dkfsim.montecarlo({**yaml.safe_load(CASE1.read_text()), "steps": 20}, 2)
    assert mc.runs == 2 and "fused" in mc.estimates


@pytest.mark.slow
def test_a_closed_pipe_ends_quietly():
    p = subprocess.run(f"{sys.executable} -m dkfsim sweep {ROOT / 'scenarios' / 'sweep_delay_bound.yaml'} "
                       "--dry-run | head -1", shell=True, capture_output=True, text=True, timeout=60)
    assert p.stdout.count("\n") == 1 and "Traceback" not in p.stderr and "Error" not in p.stderr


def test_blas_runs_on_one_thread_inside_api_calls_only(monkeypatch):
    from threadpoolctl import threadpool_info
    seen = []
    import dkfsim.engine.driver as driver
    real = driver.Run.run

    def spy(self):
        seen.append([i["num_threads"] for i in threadpool_info()])
        return real(self)
    monkeypatch.setattr(driver.Run, "run", spy)
    before = [i["num_threads"] for i in threadpool_info()]
    dkfsim.run(CASE1, steps=5)
    assert seen and all(n == 1 for n in seen[0])
    assert [i["num_threads"] for i in threadpool_info()] == before


@pytest.mark.slow
def test_cli_workers_run_one_blas_thread():
    code = ("import sys; from dkfsim.core.threads import pin_process; pin_process(); "
            "from threadpoolctl import threadpool_info; import os; "
            "print(all(i['num_threads'] == 1 for i in threadpool_info()), os.environ['OPENBLAS_NUM_THREADS'])")
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert p.stdout.split() == ["True", "1"], p.stderr


@pytest.mark.slow
def test_a_regular_install_runs_copies_of_the_data_scenarios_anywhere(tmp_path):
    """`pip install .` (a wheel, not editable): the CICV5G traces ship inside the package, so
    copies of the two data scenarios run from an unrelated folder."""
    import shutil
    src = tmp_path / "src"                       # a copy: building leaves build/ in the source
    shutil.copytree(ROOT / "dkfsim", src / "dkfsim", ignore=shutil.ignore_patterns("__pycache__"))
    for name in ("pyproject.toml", "README.md"):
        shutil.copy(ROOT / name, src / name)
    wheel = tmp_path / "wheel"
    p = subprocess.run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "-w", str(wheel),
                        str(src)], capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert p.returncode == 0, p.stderr
    site = tmp_path / "site"
    p = subprocess.run([sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--target", str(site),
                        *map(str, wheel.glob("*.whl"))], capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    # (the numpy kernels: compiling the installed copy's numba kernels cold is 35 s, and the
    # point here is the data files in the package)
    env = {**os.environ, "PYTHONPATH": str(site), "DKFSIM_KERNELS": "numpy"}
    for name in ("stress_5g_empirical", "cicv5g_track"):
        (elsewhere / f"{name}.yaml").write_text((ROOT / "scenarios" / f"{name}.yaml").read_text())
        code = ("import dkfsim, sys; assert dkfsim.__file__.startswith(sys.argv[1]), dkfsim.__file__; "
                "r = dkfsim.run(sys.argv[2], steps=30); print(r.counts['delivered'])")
        p = subprocess.run([sys.executable, "-c", code, str(site), f"{name}.yaml"], cwd=elsewhere, env=env,
                           capture_output=True, text=True, timeout=300)
        assert p.returncode == 0 and int(p.stdout) > 0, p.stderr
    meta = next(site.glob("dkfsim-*.dist-info")) / "METADATA"
    assert "License-Expression: MIT AND CC-BY-4.0" in meta.read_text()
    # the version from its one place, and the type information for the installing project's checker
    from dkfsim.core.version import __version__
    assert f"\nVersion: {__version__}\n" in meta.read_text()
    assert (site / "dkfsim" / "py.typed").is_file()


def test_a_number_too_long_to_read_is_refused_in_a_file_and_an_override(tmp_path):
    """Python refuses to convert an integer of more than 4300 digits (a ValueError inside the
    YAML loader, which was a traceback): the event check refuses it first, with its place."""
    path = tmp_path / "huge.yaml"
    path.write_text(CASE1.read_text().replace("seed: 1\n", "seed: 1" + "0" * 5000 + "\n"))
    err = one_paragraph(cli("validate", path), str(path), "5,001 characters")
    assert "line" in err and len(err) < 1000
    with pytest.raises(ScenarioError, match="characters"):
        dkfsim.load_scenario(CASE1, overrides=["steps=1" + "0" * 5000])

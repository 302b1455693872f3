"""The command line as a new user meets it: help, run, validate, bad input."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

#: The slow tier (`make test-fast` leaves it out): every test here runs dkfsim as a process (end-to-end).
pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[1]
CASE1 = ROOT / "scenarios" / "paper_case1.yaml"
CASE2 = ROOT / "scenarios" / "paper_case2.yaml"

CONTRACT_KEYS = ["t", "truth", "Phi", "Q", "x0_mean", "P0", "buffer_length", "arrival",
               "x_local", "P_local", "x_final", "x_fused", "P_fused", "x_centralized"]


def dkfsim(*args, cwd=ROOT):
    return subprocess.run([sys.executable, "-m", "dkfsim", *map(str, args)],
                          capture_output=True, text=True, cwd=cwd)


def test_help_explains_every_subcommand_and_option():
    top = dkfsim("--help")
    assert top.returncode == 0
    for cmd in ("run", "validate"):
        assert cmd in top.stdout
    run = dkfsim("run", "--help")
    for name in ("summary.json", "rows.csv", "run.npz"):
        assert name in run.stdout, name
    for opt in ("--out", "--seed", "--steps", "--set", "--save", "--burn-in", "--quiet"):
        assert opt in run.stdout


def test_run_writes_summary_and_every_design_array(tmp_path):
    out = tmp_path / "case1"
    p = dkfsim("run", CASE1, "--out", out, "--steps", 120, "--seed", 5)
    assert p.returncode == 0, p.stderr
    assert "fused (matrix)" in p.stdout and "centralized" in p.stdout and "packets: sent" in p.stdout
    wrote = next(line for line in p.stdout.splitlines() if line.startswith("wrote "))
    written = sorted(f.name for f in out.iterdir() if not f.name.startswith("."))   # (.dkfsim-output: the owner mark)
    assert written == ["rows.csv", "run.npz", "summary.json"]
    assert all(str(out / name) in wrote for name in written), wrote   # the line names every file
    summary = json.loads((out / "summary.json").read_text())
    assert summary["seed"] == 5 and summary["steps"] == 120
    assert summary["scenario"] == "paper_case1" and len(summary["scenario_hash"]) == 64
    pk = summary["packets"]
    assert pk["sent"] == pk["delivered"] + pk["lost"] + pk["in_flight"]
    with np.load(out / "run.npz") as z:
        for key in CONTRACT_KEYS:
            assert key in z.files, key
        n = 12
        for i in range(n):
            assert f"H_{i}" in z.files and f"R_{i}" in z.files and f"y_{i}" in z.files
        assert z["arrival"].shape == (n, n, 120)
        assert z["x_local"].shape == (120, n, 3)
        assert z["P_fused"].shape == (120, 3, 3)
        assert int(z["buffer_length"]) == 17


def test_set_overrides_reach_the_run(tmp_path):
    p = dkfsim("run", CASE1, "--out", tmp_path, "--steps", 30, "--quiet",
               "--set", "links.default.latency.d_t=0", "--set", "fusion=diagonal")
    assert p.returncode == 0, p.stderr
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["buffer_length"] == 1 and summary["fusion"] == "diagonal"


def test_validate_reports_what_would_run():
    p = dkfsim("validate", CASE2)
    assert p.returncode == 0, p.stderr
    assert "ok" in p.stdout and "flood" in p.stdout and "L = " in p.stdout


@pytest.mark.parametrize("content, key, words", [
    ("name: x\nbuffer_lenght: 3\n", "buffer_lenght", "did you mean 'buffer_length'"),
    ("name: x\nsensors:\n  - {name: a, H: [[1, 0, 0]], R: [[-1]]}\n", "sensors.0.R", "positive"),
    ("name: x\nprotocol: gossip\n", "protocol", "tree"),
])
def test_bad_scenarios_exit_2_with_one_paragraph_and_no_traceback(tmp_path, content, key, words):
    base = CASE1.read_text()
    bad = tmp_path / "bad.yaml"
    # Start from the real file and break one key, as a user would.
    import yaml
    d = yaml.safe_load(base)
    d.update(yaml.safe_load(content))
    bad.write_text(yaml.safe_dump(d))
    for cmd in (["validate", bad], ["run", bad, "--out", tmp_path / "o"]):
        p = dkfsim(*cmd)
        assert p.returncode == 2
        assert "Traceback" not in p.stderr
        assert str(bad) in p.stderr and key in p.stderr and words in p.stderr, p.stderr
        assert len(p.stderr.strip().splitlines()) <= 3


def test_missing_file_and_bad_override_are_clear(tmp_path):
    p = dkfsim("run", tmp_path / "nope.yaml", "--out", tmp_path)
    assert p.returncode == 2 and "nope.yaml" in p.stderr and "Traceback" not in p.stderr
    p = dkfsim("validate", CASE1, "--set", "links.default.latency.d_t")
    assert p.returncode == 2 and "links.default.latency.d_t" in p.stderr and "Traceback" not in p.stderr
    p = dkfsim("run", CASE1, "--out", tmp_path, "--burn-in", 5000, "--steps", 10)
    assert p.returncode == 2 and "--burn-in" in p.stderr


def test_sweep_and_scenario_files_mixed_up_get_a_pointer_to_the_right_command(tmp_path):
    p = dkfsim("run", ROOT / "scenarios" / "sweep_delay_bound.yaml", "--out", tmp_path)
    assert p.returncode == 2 and "this is a sweep file" in p.stderr and "dkfsim sweep" in p.stderr
    p = dkfsim("sweep", CASE1, "--db", tmp_path / "x.sqlite")
    assert p.returncode == 2 and "this is a scenario file" in p.stderr

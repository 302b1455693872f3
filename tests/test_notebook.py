"""The notebook API: conversions to pandas / xarray hold the files' numbers, and the
example notebook (docs/examples/notebook.py, a jupytext percent script) executes."""

from __future__ import annotations

import csv
import math
import os
import re
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest

import dkfsim

ROOT = Path(__file__).resolve().parents[1]
CASE1 = ROOT / "scenarios" / "paper_case1.yaml"


def _read_csv(path):
    with open(path, newline="") as fh:
        reader = csv.reader(fh)
        return next(reader), list(reader)


def _same(cell: str, value) -> bool:
    if cell == "":
        return value is None or (isinstance(value, float) and math.isnan(value))
    try:
        f = float(cell)
    except ValueError:
        return cell == str(value)
    return (math.isnan(f) and math.isnan(float(value))) or f == float(value)


def _frame_equals_file(frame, path):
    columns, rows = _read_csv(path)
    assert list(frame.columns) == columns
    assert len(frame) == len(rows)
    for (_, got), want in zip(frame.iterrows(), rows):
        for c, cell in zip(columns, want):
            assert _same(cell, got[c]), (c, cell, got[c])


@pytest.fixture(scope="module")
def run_and_mc(tmp_path_factory):
    sc = dkfsim.load_scenario(CASE1, overrides=["steps=40", "estimators=[{kind: centralized}]"])
    res = dkfsim.run(sc)
    mc = dkfsim.montecarlo(sc, runs=3)
    out = tmp_path_factory.mktemp("nb")
    res.save(out / "run")
    mc.save(out / "mc")
    return res, mc, out


def test_run_frame_is_rows_csv_and_dataset_has_named_dimensions(run_and_mc):
    res, _, out = run_and_mc
    frame = res.to_frame()
    _frame_equals_file(frame, out / "run" / "rows.csv")
    ds = res.to_xarray()
    assert ds.x_local.dims == ("tick", "node", "state")
    assert ds.P_fused.dims == ("tick", "state", "state_j")
    assert list(ds.state.values) == ["position", "velocity", "acceleration"]
    np.testing.assert_array_equal(ds.time.values, res["t"])
    np.testing.assert_array_equal(ds.x_local.sel(node=3, state="velocity").values, res["x_local"][:, 3, 1])
    np.testing.assert_array_equal(ds.y.sel(sensor=5).values, res["y_5"])
    # The frame's MSE is the time average of the dataset's squared error after the burn-in.
    burn = res.metrics()["burn_in"]
    err = (ds.x_fused - ds.truth).sel(state="acceleration").values[burn:]
    row = frame[(frame.estimate == "fused") & (frame.component == "acceleration")]
    assert row.mse.item() == pytest.approx(float(np.mean(err ** 2)), rel=1e-12)
    text = repr(res)
    assert "paper_case1" in text and "fused" in text and "centralized" in text


def test_montecarlo_frame_is_runs_csv_and_curves_are_curves_npz(run_and_mc):
    _, mc, out = run_and_mc
    _frame_equals_file(mc.to_frame(), out / "mc" / "runs.csv")
    ds = mc.to_xarray()
    with np.load(out / "mc" / "curves.npz") as z:
        np.testing.assert_array_equal(ds.mse.values, z["mse"])
        np.testing.assert_array_equal(ds.mse_ci_hi.sel(estimate="centralized").values,
                                      z["mse_ci_hi"][list(z["estimates"]).index("centralized")])
        np.testing.assert_array_equal(ds.nees.values, z["nees"])
    assert ds.mse.dims == ("estimate", "tick", "state")
    assert "± is the 95 % half-width" in repr(mc)


def test_a_callable_progress_sees_every_run():
    seen = []
    dkfsim.montecarlo(dkfsim.load_scenario(CASE1, overrides=["steps=20"]), runs=2,
                      progress=lambda done, total: seen.append((done, total)))
    assert seen == [(1, 2), (2, 2)]


@pytest.mark.slow
def test_the_example_notebook_executes_from_another_directory(tmp_path):
    """Started outside the repository (cwd = tmp_path), it finds the scenarios beside itself."""
    out = tmp_path / "out"
    env = {**os.environ, "MPLBACKEND": "Agg", "DKFSIM_EXAMPLE_OUT": str(out),
           "DKFSIM_EXAMPLE_STEPS": "30", "DKFSIM_EXAMPLE_RUNS": "2"}
    p = subprocess.run([sys.executable, str(ROOT / "docs" / "examples" / "notebook.py")],
                       cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr[-3000:]
    assert (out / "delay.sqlite").is_file()
    assert sorted(x.name for x in tmp_path.iterdir()) == ["out"]
    text = (ROOT / "docs" / "examples" / "notebook.py").read_text()
    assert text.count("# %%") >= 8 and "format_name: percent" in text


def test_the_example_notebook_says_which_file_it_cannot_find(tmp_path):
    """Copied out of the repository with a dkfsim that is no checkout, it stops at once with an
    error naming the scenario it needs, not a bare StopIteration."""
    shutil.copy2(ROOT / "docs" / "examples" / "notebook.py", tmp_path / "notebook.py")
    shutil.copytree(ROOT / "dkfsim", tmp_path / "site" / "dkfsim",
                    ignore=shutil.ignore_patterns("__pycache__"))
    env = {**os.environ, "MPLBACKEND": "Agg", "PYTHONPATH": str(tmp_path / "site")}
    p = subprocess.run([sys.executable, "notebook.py"], cwd=tmp_path, env=env,
                       capture_output=True, text=True, timeout=120)
    assert p.returncode != 0
    last = p.stderr.strip().splitlines()[-1]
    assert last.startswith("FileNotFoundError:") and "scenarios/paper_case1.yaml" in last, last
    here = tmp_path.resolve()
    assert str(here / "site" / "dkfsim") in last and str(here) in last


def test_the_notebook_extra_brings_the_progress_bar_widget():
    """tqdm.auto draws a widget in Jupyter only with ipywidgets installed."""
    extras = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["optional-dependencies"]
    names = {re.split(r"[<>=!~\[; ]", req, maxsplit=1)[0].lower() for req in extras["notebook"]}
    assert {"pandas", "xarray", "ipywidgets"} <= names

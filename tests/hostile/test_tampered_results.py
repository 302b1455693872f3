"""Tampered or hostile result files get clean errors (issue 20 §1).

Each case tampers with a copy of a legitimate run folder, Monte Carlo folder or sweep database and
runs ``dkfsim plot`` and ``dkfsim report`` on it as a user would (a child process): exit 2, one
paragraph, no traceback, within a CPU-time and memory bound, and the output an earlier command
wrote (``report.html``, ``figures/``) is intact.  ``dkfsim.load_run`` raises a DkfsimError for
every damaged run folder.  Names that reach matplotlib (``$\\nosuch$``) are drawn as plain text, and
``plot`` never writes outside ``--out`` or through a link in a folder it reads.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml
from hostile_kit import CASE1, copy_of, dkfsim_cli, legit  # noqa: F401  (legit: a fixture)
from tampering import (
    deep,
    deep_json_text,
    edit_json,
    flip_npz_member_byte,
    npz_arrays,
    npz_claiming,
    npz_replace,
    set_values_json,
    sql,
    truncate,
)

import dkfsim
from dkfsim.core.errors import DkfsimError

MATH = "$\\nosuch$"          # mathtext that matplotlib cannot parse


def earlier_output(folder: Path) -> dict[Path, bytes]:
    """The report and figures of the untouched folder (made by the fixture): their bytes."""
    files = [folder / "report.html", *sorted((folder / "figures").iterdir())]
    assert len(files) >= 3
    return {f: f.read_bytes() for f in files}


def refused(folder: Path, *words, load_run: bool = False, **bounds) -> None:
    """plot and report end in a clean error naming ``words``; load_run and dkfsim.load raise
    DkfsimError."""
    for cmd in (("plot", folder, "--format", "png"), ("report", folder)):
        dkfsim_cli(*cmd, fresh="memory_mb" in bounds).clean_error(*words, **bounds)
    if load_run:
        with pytest.raises(DkfsimError):
            dkfsim.load_run(folder)
    with pytest.raises(DkfsimError):
        dkfsim.load(folder)


# =========================================================================== run folders
def _string_truth(f):
    npz_replace(f / "run.npz", truth=np.array([["a", "b", "c"]] * 40))


def _empty_rows(f):
    a = npz_arrays(f / "run.npz")
    npz_replace(f / "run.npz", **{k: v[:0] for k, v in a.items() if k in ("t", "truth") or k.startswith("x_")})


def _deflated_and_flipped(npz):
    """run.npz recompressed, then bytes of truth's deflate stream flipped (a zlib error inside)."""
    npz_replace(npz)
    np.savez_compressed(npz, **npz_arrays(npz))
    data = bytearray(npz.read_bytes())
    start = data.index(b"truth.npy") + len(b"truth.npy") + 40
    for i in range(start, start + 200, 7):
        data[i] ^= 0x5A
    npz.write_bytes(bytes(data))


def _no_state(f):
    npz_replace(f / "run.npz", truth=np.zeros((40, 0)))


RUN_CASES = {
    "truncated npz": (lambda f: truncate(f / "run.npz"), ["run.npz"]),
    "empty npz": (lambda f: (f / "run.npz").write_bytes(b""), ["run.npz"]),
    "bad CRC": (lambda f: flip_npz_member_byte(f / "run.npz", "truth"), ["run.npz", "truth"]),
    "garbage npz": (lambda f: (f / "run.npz").write_bytes(os.urandom(5000)), ["run.npz"]),
    "corrupt deflate": (lambda f: _deflated_and_flipped(f / "run.npz"), ["run.npz", "truth"]),
    "string dtype": (_string_truth, ["truth", "expected numbers"]),
    "K = 0": (_empty_rows, ["run.npz"]),
    "nx = 0": (_no_state, ["truth"]),
    "summary nested 1000 levels": (lambda f: (f / "summary.json").write_text(
        '{"facts": ' + deep_json_text(1000) + "}"), ["summary.json", "nested deeper"]),
    "rows not a list": (lambda f: edit_json(f / "summary.json", lambda s: s.update(rows=5)),
                        ["summary.json", "rows"]),
    "mse is text": (lambda f: edit_json(f / "summary.json", lambda s: s["rows"][0].update(mse="abc")),
                    ["summary.json", "rows.0.mse", "number"]),
    "scenario_config a list": (lambda f: edit_json(f / "summary.json", lambda s: s.update(scenario_config=[])),
                               ["summary.json", "scenario_config"]),
    "no rows key": (lambda f: edit_json(f / "summary.json", lambda s: s.pop("rows")),
                    ["summary.json", "rows", "missing"]),
    "estimates without rows": (lambda f: edit_json(f / "summary.json", lambda s: s["estimates"].append("x")),
                               ["summary.json", "no row for estimate"]),
    "binary summary": (lambda f: (f / "summary.json").write_bytes(os.urandom(3000)), ["summary.json"]),
    "deep list in facts": (lambda f: edit_json(f / "summary.json", lambda s: s.update(facts=deep(200))),
                           ["summary.json", "nested deeper"]),
}


BOMB_ROWS = 60_000_000


@pytest.fixture(scope="module")
def bomb(tmp_path_factory) -> Path:
    """A run.npz of 3.3 MB whose t, truth and x_fused claim 60 M rows of zeros (3.4 GB)."""
    path = tmp_path_factory.mktemp("bomb") / "run.npz"
    K = BOMB_ROWS
    assert npz_claiming(path, {"t": (K,), "truth": (K, 3), "x_fused": (K, 3)}) < 8 << 20
    return path


@pytest.mark.slow
@pytest.mark.parametrize("steps", ["summary says 40", "summary says 60 M too"])
def test_a_small_file_claiming_60_million_rows_is_refused_without_reading_it(legit, bomb, tmp_path,  # noqa: F811
                                                                            steps):
    """3 MB compressed holding 60 M rows of zeros: refused from the headers, in seconds and within
    a few hundred MB (it used to reach 3.8 GB, then MemoryError)."""
    folder = copy_of(legit["run"], tmp_path)
    copy_of(bomb, folder)
    K = BOMB_ROWS
    if steps != "summary says 40":
        edit_json(folder / "summary.json", lambda s: (s.update(steps=K), s["scenario_config"].update(steps=K)))
    words = ["60000000"] if steps == "summary says 40" else ["zip bomb"]
    # Reading the arrays would take 3.4 GB (truth alone 60 M x 3 x 8 B = 1.44 GB); the child's own peak
    # when it refuses from the headers is ~125 MB (Python, numpy, dkfsim), so 400 MB separates the two.
    refused(folder, *words, cpu=15, memory_mb=400)
    with pytest.raises(DkfsimError, match="60000000|zip bomb"):
        dkfsim.load_run(folder)


# =========================================================================== Monte Carlo folders
MC_CASES = {
    "a 5 MB component name": (lambda f: npz_replace(f / "curves.npz", components=np.array(
        ["x" * 5_000_000, "v", "a"])), ["components", "names"]),
    "mse of the wrong shape": (lambda f: npz_replace(f / "curves.npz", mse=np.zeros((3, 2, 3))), ["mse", "shape"]),
    "an estimate that is a number": (lambda f: edit_json(f / "summary.json",
                                                         lambda s: s["estimates"].update(fused=3)),
                                     ["summary.json", "estimates.fused"]),
    "runs.csv of binary bytes": (lambda f: (f / "runs.csv").write_bytes(b"run,seed\n" + os.urandom(4000)),
                                 ["runs.csv"]),
    "runs.csv with a text seed": (lambda f: (f / "runs.csv").write_text("run,seed,estimate\n0,abc,fused\n"),
                                  ["runs.csv", "line 2"]),
    "components not a list": (lambda f: edit_json(f / "summary.json", lambda s: s.update(components=5)),
                              ["summary.json", "components"]),
    "curves.npz names as numbers": (lambda f: npz_replace(f / "curves.npz", estimates=np.arange(3)),
                                    ["estimates", "names"]),
}


FOLDER_CASES = [("run", c) for c in RUN_CASES] + [("mc", c) for c in MC_CASES]


@pytest.mark.parametrize("kind, case", FOLDER_CASES)
def test_a_tampered_folder_is_refused_cleanly(legit, tmp_path, kind, case):  # noqa: F811
    """plot and report (and load_run for a run folder) refuse cleanly; the report and figures
    made from the untouched folder are intact."""
    folder = copy_of(legit[kind], tmp_path)
    before = earlier_output(folder)
    tamper, words = (RUN_CASES if kind == "run" else MC_CASES)[case]
    tamper(folder)
    refused(folder, *words, load_run=kind == "run")
    for f, data in before.items():
        assert f.read_bytes() == data, f"{f} changed"


LOAD_CASES = {
    "text in an mse cell": (lambda f: _edit_runs_csv(f, 4, "abc"), ["runs.csv", "line 2", "mse", "number"]),
    "a negative run": (lambda f: _edit_runs_csv(f, 0, "-1"), ["runs.csv", "run"]),
    "a 500-character estimate name": (lambda f: _edit_runs_csv(f, 2, "e" * 500), ["runs.csv", "estimate",
                                                                                 "at most 200 characters"]),
    "a row short of a cell": (lambda f: _edit_runs_csv(f, None, None), ["runs.csv", "cells"]),
}


def _edit_runs_csv(folder: Path, column, value) -> None:
    lines = (folder / "runs.csv").read_text().splitlines()
    cells = lines[1].split(",")
    if column is None:
        cells = cells[:-1]
    else:
        cells[column] = value
    lines[1] = ",".join(cells)
    (folder / "runs.csv").write_text("\n".join(lines) + "\n")


@pytest.mark.parametrize("case", list(LOAD_CASES))
def test_a_tampered_runs_csv_is_refused_by_load(legit, tmp_path, case):  # noqa: F811
    """dkfsim.load reads every row of runs.csv (plot and report read only its seeds): each cell
    is checked, and a bad one is an error naming the file, the line and the column."""
    folder = copy_of(legit["mc"], tmp_path)
    tamper, words = LOAD_CASES[case]
    tamper(folder)
    with pytest.raises(DkfsimError) as err:
        dkfsim.load(folder)
    text = str(err.value)
    assert all(w in text for w in words), text
    assert len(text) < 2000


def test_a_paired_block_that_lies_is_drawn_or_refused_never_a_traceback(legit, tmp_path):  # noqa: F811
    """summary.json's paired blocks feed the paired figure: an interval that excludes its ratio is
    drawn (bars clipped at the point); a ratio that is text is refused naming the key."""
    folder = copy_of(legit["mc"], tmp_path)
    edit_json(folder / "summary.json", lambda s: s["estimates"]["fused"]["paired"].update(
        mse_ratio_ci95={c: [5.0, 0.1] for c in s["components"]}))
    dkfsim_cli("plot", folder, "--format", "png").ok()
    assert (folder / "figures" / "paired.png").stat().st_size > 1000
    edit_json(folder / "summary.json", lambda s: s["estimates"]["fused"]["paired"].update(
        mse_ratio={c: "big" for c in s["components"]}))
    dkfsim_cli("plot", folder, "--format", "png").clean_error("summary.json", "paired", "mse_ratio")


# =========================================================================== sweep databases
def _huge_estimate(db):
    sql(db, "UPDATE results SET estimate=? WHERE rowid=1", params=("e" * 5_000_000,))


SWEEP_CASES = {
    "a 5 MB estimate name": (_huge_estimate, ["results", "estimate", "at most 200 characters"]),
    "definition not JSON": (lambda db: sql(db, "UPDATE meta SET value='{not json' WHERE key='definition'"),
                            ["meta.definition", "JSON"]),
    "definition of the wrong type": (lambda db: sql(db, "UPDATE meta SET value='[1, 2]' WHERE key='definition'"),
                                     ["meta.definition"]),
    "text in mse": (lambda db: sql(db, "UPDATE results SET mse='abc' WHERE rowid=2"), ["mse", "number"]),
    "text in run": (lambda db: sql(db, "UPDATE results SET run='r' WHERE rowid=3"), ["run", "integer"]),
    "params dropped": (lambda db: sql(db, "DROP TABLE params"), ["params"]),
    "results dropped": (lambda db: sql(db, "DROP TABLE results"), ["results"]),
    "meta dropped": (lambda db: sql(db, "DROP TABLE meta"), ["not a dkfsim sweep database"]),
    "scenario_json not JSON": (lambda db: sql(db, "UPDATE params SET scenario_json='[[[' WHERE idx=0"),
                               ["scenario_json"]),
    "values_json nested 1000 levels": (lambda db: sql(db, "UPDATE params SET values_json=? WHERE idx=0",
                                                      params=(deep_json_text(1000),)), ["values_json"]),
}


@pytest.mark.parametrize("case", list(SWEEP_CASES))
def test_a_tampered_sweep_database_is_refused_cleanly(legit, tmp_path, case):  # noqa: F811
    db = copy_of(legit["sweep"], tmp_path)
    page = copy_of(legit["sweep"].with_name("s.report.html"), tmp_path).read_bytes()
    tamper, words = SWEEP_CASES[case]
    tamper(db)
    for cmd in (("plot", db, "--format", "png", "--x", "d_t"), ("report", db)):
        dkfsim_cli(*cmd).clean_error(*words)
    with pytest.raises(DkfsimError):
        dkfsim.load(db)
    assert db.with_name("s.report.html").read_bytes() == page


def test_null_metrics_are_not_applicable_not_an_error(legit, tmp_path):  # noqa: F811
    """NULL in a metric column is "not applicable" (how NaN is stored): drawn as a gap, no crash;
    where every value is NULL there is nothing to draw, which is said cleanly (issue 24 §2: an
    empty figure was saved) and the report page says it in place of that figure."""
    db = copy_of(legit["sweep"], tmp_path)
    sql(db, "UPDATE results SET anees=NULL WHERE estimate='fused'")
    dkfsim_cli("plot", db, "--format", "png", "--x", "d_t", "--metric", "anees").ok()
    sql(db, "UPDATE results SET anees=NULL")
    dkfsim_cli("report", db).ok()
    dkfsim_cli("plot", db, "--format", "png", "--x", "d_t", "--metric", "anees").clean_error("nothing to draw")


# =========================================================================== names matplotlib sees
@pytest.mark.slow
def test_names_are_drawn_as_plain_text(legit, tmp_path):  # noqa: F811
    """Sensor, scenario, estimate and component names, grid values, --labels and --title holding
    mathtext matplotlib cannot parse: every figure is drawn (they were ParseException tracebacks)."""
    data = yaml.safe_load(CASE1.read_text())
    data.update(name=MATH, steps=40)
    data["sensors"][0]["name"] = MATH
    (tmp_path / "s.yaml").write_text(yaml.safe_dump(data))
    run = tmp_path / "run"
    dkfsim_cli("run", tmp_path / "s.yaml", "--out", run, "--quiet").ok()
    npz_replace(run / "run.npz", **{f"x_{MATH}": npz_arrays(run / "run.npz")["x_fused"]})
    dkfsim_cli("report", run).ok()
    assert MATH in (run / "report.html").read_text()
    mc = copy_of(legit["mc"], tmp_path)
    names = [MATH, *npz_arrays(mc / "curves.npz")["estimates"][1:]]
    npz_replace(mc / "curves.npz", estimates=np.array(names), components=np.array([MATH, "v", "a"]))
    edit_json(mc / "summary.json", lambda s: s.update(components=[MATH, "v", "a"], estimates={
        n: {**e, "mse": dict(zip([MATH, "v", "a"], e["mse"].values())),
            "mse_ci95": dict(zip([MATH, "v", "a"], e["mse_ci95"].values()))}
        for n, e in zip(names, s["estimates"].values())}))
    for folder in (run, mc):
        out = dkfsim_cli("plot", folder, "--format", "png").ok()
        assert "mse.png" in out
    twin = copy_of(run, tmp_path, "twin")
    dkfsim_cli("plot", run, twin, "--compare", "--labels", MATH, "$\\frac$", "--title", MATH, "--format", "png",
               "--out", tmp_path / "cmp").ok()
    db = copy_of(legit["sweep"], tmp_path / "sw")
    set_values_json(db, lambda v: {k: f"{MATH}{x}" for k, x in v.items()})
    dkfsim_cli("plot", db, "--format", "png", "--x", "d_t").ok()
    dkfsim_cli("report", db).ok()


# =========================================================================== where plot writes
@pytest.mark.parametrize("name", ["../../x", "ABSOLUTE", "a" * 300])
def test_plot_name_is_a_file_name_for_sweeps_too(legit, tmp_path, name):  # noqa: F811
    db = copy_of(legit["sweep"], tmp_path / "a" / "b")
    if name == "ABSOLUTE":
        name = str(tmp_path / "x")
    before = sorted(p for p in tmp_path.rglob("*"))
    dkfsim_cli("plot", db, "--name", name, "--format", "png").clean_error("--name")
    assert sorted(p for p in tmp_path.rglob("*")) == before


def test_plot_never_writes_through_a_figures_link(legit, tmp_path):  # noqa: F811
    target = tmp_path / "elsewhere"
    target.mkdir()
    (target / "mse.png").write_text("precious")
    folder = copy_of(legit["run"], tmp_path)
    shutil.rmtree(folder / "figures")
    (folder / "figures").symlink_to(target)
    dkfsim_cli("plot", folder, "--format", "png").clean_error("symbolic link", "--out")
    db = copy_of(legit["sweep"], tmp_path / "sw")
    (db.parent / "s_figures").symlink_to(target)
    dkfsim_cli("plot", db, "--format", "png").clean_error("symbolic link")
    assert sorted(p.name for p in target.iterdir()) == ["mse.png"]
    assert (target / "mse.png").read_text() == "precious"
    dkfsim_cli("plot", folder, "--format", "png", "--out", tmp_path / "figs").ok()   # --out: the user's choice


# =========================================================================== a sweep's dry run
def test_a_dry_run_of_a_billion_runs_answers_at_once(tmp_path):
    (tmp_path / "s.yaml").write_text(yaml.safe_dump({"scenario": str(CASE1), "runs": 10**9}))
    out = dkfsim_cli("sweep", tmp_path / "s.yaml", "--dry-run").ok(cpu=10)
    assert "0/1000000000 done" in out


def test_load_run_of_a_missing_or_odd_folder_is_a_dkfsim_error(tmp_path):
    for path in (tmp_path / "none", tmp_path):
        with pytest.raises(DkfsimError):
            dkfsim.load_run(path)
    (tmp_path / "summary.json").write_text(json.dumps({"scenario_config": {}, "packets": {}}))
    with pytest.raises(DkfsimError, match="summary.json"):
        dkfsim.load_run(tmp_path)

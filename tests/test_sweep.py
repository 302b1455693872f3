"""dkfsim sweep: tidy rows (one per task, estimate and state component), crash-safe
resume, identical results on every executor, and clear errors for bad sweeps."""

from __future__ import annotations

import os
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from dkfsim.core.errors import DkfsimError, ScenarioError

ROOT = Path(__file__).resolve().parents[1]
CASE1 = ROOT / "scenarios" / "paper_case1.yaml"
COMPONENTS = ["position", "velocity", "acceleration"]      # paper_case1's state
NC = len(COMPONENTS)                                       # tidy rows per estimate and task


def dkfsim(*args, cwd=ROOT, **kw):
    return subprocess.run([sys.executable, "-m", "dkfsim", *map(str, args)],
                          capture_output=True, text=True, cwd=cwd, **kw)


def write_sweep(folder: Path, *, name="s", scenario=CASE1, grid=None, runs=2, steps=40,
                extra_set=(), **keys) -> Path:
    data = {"scenario": str(scenario),
            "grid": {"links.default.latency.d_t": [0, 2], "protocol": ["tree", "flood"]}
            if grid is None else grid,
            "set": [f"steps={steps}", *extra_set],
            "runs": runs, **keys}
    path = folder / f"{name}.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def table(db: Path, sql: str):
    with sqlite3.connect(db) as conn:
        return conn.execute(sql).fetchall()


# --------------------------------------------------------------------------- one row per task
def test_small_sweep_writes_one_row_per_parameter_set_seed_estimate_and_component(tmp_path):
    from dkfsim.experiments.montecarlo import derive_seed
    from dkfsim.experiments.sweep import load_sweep, read_results, run_sweep
    path = write_sweep(tmp_path, grid={"links.default.latency.d_t": [0, 1, 3]}, runs=2,
                       extra_set=["baselines=[centralized, local]"])
    sweep = load_sweep(path)
    assert sweep.output == tmp_path / "s.sqlite"          # default: <stem>.sqlite beside it
    rep = run_sweep(sweep, jobs=1, progress=False)
    assert (rep.total, rep.skipped, rep.computed) == (6, 0, 6)

    db = sweep.output
    # a rollback journal: a full disk leaves nothing beside the database (decision 252)
    assert table(db, "PRAGMA journal_mode")[0][0] == "delete"
    tasks = table(db, "SELECT param_hash, run, seed FROM tasks")
    assert len(tasks) == 6 == len(set((h, r) for h, r, _ in tasks))
    base = {p.param_hash: p.base_seed for p in sweep.parameter_sets}
    for h, r, seed in tasks:
        assert seed == derive_seed(base[h], r)

    rows = table(db, "SELECT param_hash, run, seed, estimate, component FROM results")
    estimates = {e for *_, e, _ in rows}
    assert estimates == {"fused", "local", "centralized", "local_only"}
    assert {c for *_, c in rows} == set(COMPONENTS)
    keys = [(h, r, e, c) for h, r, _, e, c in rows]
    assert len(keys) == len(set(keys)) == 6 * len(estimates) * NC
    assert {(h, r) for h, r, *_ in rows} == {(h, r) for h, r, _ in tasks}

    columns, exported = read_results(db)
    assert columns[:6] == ["links.default.latency.d_t", "param_hash", "run", "seed", "estimate", "component"]
    for c in ("mse", "anees", "disagreement",
              "messages_per_tick", "bytes_per_tick", "lost", "late"):
        assert c in columns
    assert [row[0] for row in exported] == sorted(row[0] for row in exported)
    comp, mse = columns.index("component"), columns.index("mse")
    for name in COMPONENTS:            # every component's MSE (was mse_position, ... columns)
        assert sum(row[comp] == name for row in exported) == 6 * len(estimates)
    assert all(row[mse] > 0 for row in exported)
    # d_t = 0 is the zero-latency case: the fused estimate equals the centralized filter.
    at0 = {(r[2], r[4]): r for r in exported if r[0] == 0 and r[comp] == "position"}
    for run in (0, 1):
        f, c = at0[(run, "fused")][mse], at0[(run, "centralized")][mse]
        assert f == pytest.approx(c, rel=1e-9)


def test_tidy_rows_keep_per_component_values_of_any_metric(tmp_path):
    """Rows are stored tidy (one per component): a metric that differs per component
    (here ``late``) keeps each component's value, a per-run one (``anees``) repeats."""
    from dkfsim.experiments.sweep import SweepDB, load_sweep, read_results
    sweep = load_sweep(write_sweep(tmp_path, grid={}, runs=1))
    rows = [{"seed": 5, "estimate": "a", "component": c, "mse": m, "anees": 3.0, "late": late}
            for c, m, late in (("x0", 0.1, 1), ("x1", 0.2, 2))]
    h = sweep.parameter_sets[0].param_hash
    with SweepDB(sweep.output, sweep) as store:
        store.write_task(h, 0, 5, rows, 0.1)
    columns, exported = read_results(sweep.output)
    got = [dict(zip(columns, row)) for row in exported]
    assert [(g["estimate"], g["seed"], g["component"], g["mse"], g["anees"], g["late"]) for g in got] == \
        [("a", 5, "x0", 0.1, 3.0, 1), ("a", 5, "x1", 0.2, 3.0, 2)]


def test_a_task_is_written_entirely_or_not_at_all(tmp_path):
    from dkfsim.experiments.sweep import SweepDB, load_sweep
    sweep = load_sweep(write_sweep(tmp_path, grid={}, runs=1))
    good = [{"seed": 7, "estimate": a, "component": "x0", "mse": 1.0} for a in ("a", "b")]
    bad = good[:1] + [{"seed": 8, "estimate": "b", "component": "x0", "mse": 1.0}]
    h = sweep.parameter_sets[0].param_hash
    with SweepDB(sweep.output, sweep) as store:
        with pytest.raises(RuntimeError):
            store.write_task(h, 0, 7, bad, 0.1)   # fails on its second row
        assert store.done() == set()
        store.write_task(h, 0, 7, good, 0.1)
        assert store.done() == {(h, 0)}
        with pytest.raises(sqlite3.IntegrityError):
            store.write_task(h, 0, 7, good, 0.1)  # (param_hash, run) is unique
    assert table(sweep.output, "SELECT COUNT(*) FROM results") == [(2,)]


# --------------------------------------------------------------------------- kill -9 and resume
@pytest.mark.slow
def test_killed_sweep_resumes_without_losing_or_repeating_a_task(tmp_path):
    psutil = pytest.importorskip("psutil")
    grid = {"links.default.latency.d_t": [0, 1, 2]}
    # Long enough tasks (about 0.3 s each) that the kill lands while most are still to do.
    killed = write_sweep(tmp_path, name="killed", grid=grid, runs=4, steps=1000)
    fresh = write_sweep(tmp_path, name="fresh", grid=grid, runs=4, steps=1000)
    db = tmp_path / "killed.sqlite"
    total = 12

    proc = subprocess.Popen([sys.executable, "-m", "dkfsim", "sweep", killed, "--jobs", "2",
                             "--quiet"], cwd=ROOT, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    workers = []
    deadline = time.monotonic() + 60
    done = 0
    try:
        while time.monotonic() < deadline and proc.poll() is None:
            if not workers:
                workers = psutil.Process(proc.pid).children()
            if db.exists():
                try:
                    done = table(db, "SELECT COUNT(*) FROM tasks")[0][0]
                except sqlite3.OperationalError:  # schema not there yet, or a write under way
                    pass
                if done >= 3:
                    break
            time.sleep(0.01)
        assert proc.poll() is None, f"the sweep ended before it could be killed: {proc.stderr.read()}"
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=10)
    finally:
        if proc.poll() is None:
            proc.kill()
    saved = table(db, "SELECT COUNT(*) FROM tasks")[0][0]
    assert 3 <= saved < total, saved
    # Every saved task has all its rows (3 estimates: fused, local, centralized; 3 components each).
    assert table(db, "SELECT COUNT(*) FROM results")[0][0] == 3 * NC * saved
    # The pool's workers notice that their parent is gone and exit.
    assert workers, "no worker processes seen"
    gone, alive = psutil.wait_procs(workers, timeout=10)
    assert not alive, alive

    again = dkfsim("sweep", killed, "--jobs", "2", "--export", tmp_path / "killed.csv")
    assert again.returncode == 0, again.stderr
    assert f"done: {saved} already in the database, {total - saved} computed" in again.stdout
    assert table(db, "SELECT COUNT(*) FROM tasks")[0][0] == total
    assert table(db, "SELECT COUNT(*) FROM results")[0][0] == 3 * NC * total

    clean = dkfsim("sweep", fresh, "--jobs", "1", "--quiet", "--export", tmp_path / "fresh.csv")
    assert clean.returncode == 0, clean.stderr
    a = (tmp_path / "killed.csv").read_text()
    b = (tmp_path / "fresh.csv").read_text()
    assert len(a.splitlines()) == 1 + 3 * NC * total
    assert a == b


# --------------------------------------------------------------------------- executors agree
@pytest.mark.slow
def test_dask_local_cluster_and_local_pool_give_identical_rows(tmp_path):
    pytest.importorskip("distributed")
    from dkfsim.experiments.executors import DaskExecutor
    from dkfsim.experiments.sweep import export, load_sweep, run_sweep
    path = write_sweep(tmp_path, runs=2, grid={"links.default.latency.d_t": [0, 3],
                                               "protocol": ["tree", "flood"]})
    with DaskExecutor(n_workers=2, processes=False) as ex:
        rep = run_sweep(load_sweep(path, output=tmp_path / "dask.sqlite"), executor=ex,
                        progress=False)
    assert rep.computed == 8 and "Dask" in rep.executor
    export(tmp_path / "dask.sqlite", tmp_path / "dask.csv")

    p = dkfsim("sweep", path, "--jobs", "2", "--db", tmp_path / "pool.sqlite", "--quiet",
               "--export", tmp_path / "pool.csv")
    assert p.returncode == 0, p.stderr
    a, b = (tmp_path / "dask.csv").read_text(), (tmp_path / "pool.csv").read_text()
    assert len(a.splitlines()) == 1 + 8 * 3 * NC
    assert a == b

    pq = pytest.importorskip("pyarrow.parquet")
    out, n = export(tmp_path / "pool.sqlite", tmp_path / "pool.parquet")
    t = pq.read_table(out)
    assert t.num_rows == n == 24 * NC
    assert t.column("estimate").to_pylist()[:3 * NC] == [e for e in ("fused", "local", "centralized")
                                                         for _ in range(NC)]
    assert t.column("component").to_pylist()[:NC] == COMPONENTS


@pytest.mark.slow
def test_cli_dask_local_processes(tmp_path):
    pytest.importorskip("distributed")
    path = write_sweep(tmp_path, runs=1, steps=20, grid={"protocol": ["tree", "flood"]})
    p = dkfsim("sweep", path, "--dask-local", "2", "--export", tmp_path / "d.csv")
    assert p.returncode == 0, p.stderr
    assert "on Dask LocalCluster (2 worker processes)" in p.stdout
    q = dkfsim("sweep", path, "--jobs", "1", "--db", tmp_path / "i.sqlite", "--quiet",
               "--export", tmp_path / "i.csv")
    assert q.returncode == 0, q.stderr
    assert (tmp_path / "d.csv").read_text() == (tmp_path / "i.csv").read_text()


# --------------------------------------------------------------------------- sweeps that grow
def _count_tasks(monkeypatch) -> list:
    """Record (seed, estimates asked for) of every task this process computes (jobs=1)."""
    import dkfsim.experiments.sweep.run as sweep_run
    seen, real = [], sweep_run.run_task

    def counting(scenario, seed, burn_in, base_dir=None, only=None):
        seen.append((seed, None if only is None else tuple(only)))
        return real(scenario, seed, burn_in, base_dir, only)
    monkeypatch.setattr(sweep_run, "run_task", counting)
    return seen


def test_a_sweep_grown_from_2_to_3_runs_equals_one_run_with_3_and_computes_only_the_third(
        tmp_path, monkeypatch):
    from dkfsim.experiments.montecarlo import derive_seed
    from dkfsim.experiments.sweep import load_sweep, read_results, run_sweep
    grid = {"protocol": ["tree", "flood"]}
    grown = write_sweep(tmp_path, name="grown", grid=grid, runs=2, steps=20)
    assert run_sweep(grown, jobs=1, progress=False).computed == 4
    write_sweep(tmp_path, name="grown", grid=grid, runs=3, steps=20)
    seen = _count_tasks(monkeypatch)
    rep = run_sweep(grown, jobs=1, progress=False)
    base = load_sweep(grown).parameter_sets[0].base_seed
    assert (rep.total, rep.skipped, rep.computed) == (6, 4, 2)
    assert seen == [(derive_seed(base, 2), None)] * 2         # run 2 of each parameter set, only

    fresh = write_sweep(tmp_path, name="fresh", grid=grid, runs=3, steps=20)
    assert run_sweep(fresh, jobs=1, progress=False).computed == 6
    assert read_results(tmp_path / "grown.sqlite") == read_results(tmp_path / "fresh.sqlite")


def test_added_grid_values_and_estimators_compute_only_what_is_new(tmp_path, monkeypatch):
    from dkfsim.experiments.sweep import read_results, run_sweep
    one = ["estimators=[{kind: centralized}]"]
    two = ["estimators=[{kind: centralized}, {kind: local_only}]"]
    grown = write_sweep(tmp_path, name="grown", grid={"links.default.latency.d_t": [2]}, runs=2,
                        steps=20, extra_set=one)
    assert run_sweep(grown, jobs=1, progress=False).computed == 2
    new_grid = {"links.default.latency.d_t": [0, 2]}           # a value before the old one
    write_sweep(tmp_path, name="grown", grid=new_grid, runs=3, steps=20, extra_set=two)
    seen = _count_tasks(monkeypatch)
    rep = run_sweep(grown, jobs=1, progress=False)
    # d_t=0: 3 new runs; d_t=2: run 2 new, runs 0 and 1 only gain local_only
    assert rep.computed == 6 and sorted(o for _, o in seen if o) == [("local_only",)] * 2
    fresh = write_sweep(tmp_path, name="fresh", grid=new_grid, runs=3, steps=20, extra_set=two)
    assert run_sweep(fresh, jobs=1, progress=False).computed == 6
    a, b = read_results(tmp_path / "grown.sqlite"), read_results(tmp_path / "fresh.sqlite")
    assert a == b and len(b[1]) == 2 * 3 * 4 * NC               # fused, local, centralized, local_only
    assert run_sweep(grown, jobs=1, progress=False).computed == 0


# --------------------------------------------------------------------------- definition checks
@pytest.mark.slow
def test_changes_that_alter_stored_tasks_are_refused(tmp_path):
    from dkfsim.experiments.sweep import run_sweep
    scen = tmp_path / "case.yaml"
    scen.write_text(CASE1.read_text())
    est = ["estimators=[{kind: centralized}, {kind: local_only}]"]
    keep = dict(scenario="case.yaml", steps=20, output="res.sqlite")
    path = write_sweep(tmp_path, runs=2, grid={"protocol": ["tree", "flood"]}, extra_set=est, **keep)
    assert run_sweep(path, jobs=1, progress=False).computed == 4

    # Same definition (comments): resumes, computes nothing.
    path.write_text("# a comment\n" + path.read_text())
    assert run_sweep(path, jobs=1, progress=False).computed == 0

    refused = [
        (dict(runs=1, grid={"protocol": ["tree", "flood"]}, extra_set=est),
         r"runs: 2 in the file, 1 now \(runs can be raised, not lowered\)"),
        (dict(runs=2, grid={"protocol": ["tree"]}, extra_set=est),
         r"parameter set protocol=\"flood\" has results in the file but is no longer in the grid"),
        (dict(runs=2, grid={"protocol": ["tree", "flood"], "fusion": ["matrix"]}, extra_set=est),
         r"grid keys: .*not by keys"),
        (dict(runs=2, grid={"protocol": ["tree", "flood"]},
              extra_set=["estimators=[{kind: local_only}, {kind: centralized}]"]),
         r"estimators: .*not removed, changed or reordered"),
        (dict(runs=2, grid={"protocol": ["tree", "flood"]}, extra_set=["estimators=[]"]),
         r"estimators: .*not removed"),
        (dict(runs=2, grid={"protocol": ["tree", "flood"]}, extra_set=est + ["fusion=diagonal"]),
         r"resolves differently \(the scenario file or set changed\)"),
        (dict(runs=2, grid={"protocol": ["tree", "flood"]}, extra_set=est, burn_in=3),
         r"burn_in: null in the file, 3 now"),
    ]
    for change, message in refused:
        write_sweep(tmp_path, **change, **keep)
        with pytest.raises(DkfsimError, match=r"different sweep definition \(.*" + message):
            run_sweep(path, jobs=1, progress=False)

    write_sweep(tmp_path, runs=2, grid={"protocol": ["tree", "flood"]}, extra_set=est, **keep)
    scen.write_text(CASE1.read_text().replace("R: [[0.8]]", "R: [[0.9]]"))
    p = dkfsim("sweep", path)
    assert p.returncode == 2
    assert "different sweep definition" in p.stderr and "scenario file or set changed" in p.stderr
    assert "Traceback" not in p.stderr and len(p.stderr.strip().splitlines()) == 1


@pytest.mark.slow
def test_a_database_of_an_earlier_format_is_refused_by_name(tmp_path):
    """A database written by an earlier dkfsim (format 1: wide rows, old names)
    is not resumed into: the message names the format and the way out."""
    import json as _json
    import sqlite3

    from dkfsim.experiments.sweep import run_sweep
    path = write_sweep(tmp_path, grid={}, runs=1, steps=20, output="res.sqlite")
    assert run_sweep(path, jobs=1, progress=False).computed == 1
    db = tmp_path / "res.sqlite"
    con = sqlite3.connect(db)
    definition = _json.loads(con.execute("SELECT value FROM meta WHERE key='definition'").fetchone()[0])
    definition["format"] = 1                      # what the earlier version stored
    con.execute("UPDATE meta SET value=? WHERE key='definition'", (_json.dumps(definition),))
    con.commit()
    con.close()
    p = dkfsim("sweep", path)
    assert p.returncode == 2
    assert "database format 1 of an earlier dkfsim" in p.stderr and "--db" in p.stderr
    assert "Traceback" not in p.stderr


def test_a_second_writer_is_refused(tmp_path):
    from dkfsim.experiments.sweep import SweepDB, load_sweep, run_sweep
    sweep = load_sweep(write_sweep(tmp_path, grid={}, runs=1, steps=20))
    with SweepDB(sweep.output, sweep):
        with pytest.raises(DkfsimError, match="another dkfsim sweep is writing"):
            run_sweep(sweep, jobs=1, progress=False)


BAD = [
    ({"grid": {"links.default.latencyy.d_t": [0, 1]}}, "links.default.latencyy"),
    ({"grid": {"protocol": []}}, "grid.protocol: empty list"),
    ({"grid": {"protocol": "tree"}}, "grid.protocol: must be a list"),
    ({"grid": {"protocol": ["tree", "tree"]}}, "listed twice"),
    ({"grid": {"protocol": ["tree", "gossip"]}}, "unknown protocol 'gossip'"),
    ({"runs": 0}, "runs: must be >= 1"),
    ({"runs": 1.5}, "runs: must be an integer"),
    ({"scenario": "missing.yaml"}, "scenario: file not found"),
    ({"burn_in": 1000}, "burn_in: must be less than steps"),
    ({"rnus": 3}, "rnus: unknown key (did you mean 'runs'?)"),
    ({"set": ["steps"]}, "bad override 'steps'"),
    ({"set": ["protocol=flood"]}, "set: protocol is both in set and in grid"),
    ({"output": ""}, "output: must be a file name"),
]


@pytest.mark.parametrize("change, message", BAD, ids=[m for _, m in BAD])
def test_bad_sweep_files_give_one_clear_paragraph(tmp_path, change, message):
    from dkfsim.experiments.sweep import load_sweep
    data = {"scenario": str(CASE1), "grid": {"protocol": ["tree"]}, "set": ["steps=20"],
            "runs": 1}
    data.update(change)
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(DkfsimError, match=None) as info:
        load_sweep(path)
    assert message in str(info.value)
    assert str(path) in str(info.value)
    assert not (tmp_path / "bad.sqlite").exists()


def test_a_sweep_file_is_checked_by_its_schema_every_problem_at_once(tmp_path):
    """The schema (dkfsim.config.sweep.SweepFile) names every bad key of the file in one message,
    each with its key path, and a typo first with the valid keys."""
    from dkfsim.experiments.sweep import load_sweep
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump({"scenario": str(CASE1), "grid": {"protocol": []}, "runs": 0,
                                    "burn_in": -1}))
    with pytest.raises(ScenarioError) as info:
        load_sweep(path)
    assert str(info.value) == (f"{path}: grid.protocol: empty list: give at least one value; "
                               "runs: must be >= 1, got 0; burn_in: must be null or an integer >= 0 "
                               "(rows), got -1")
    assert info.value.path == "grid.protocol"
    path.write_text(yaml.safe_dump({"scenario": str(CASE1), "rnus": 2, "runs": 0}))
    with pytest.raises(ScenarioError, match=r"rnus: unknown key \(did you mean 'runs'\?\) \(valid: "
                                            r"scenario, grid, set, runs, burn_in, output\)$"):
        load_sweep(path)


def cli(capsys, *args):
    """``dkfsim ARGS`` in this process: (exit status, stdout, stderr)."""
    from dkfsim.cli.main import main
    try:
        rc = main([str(a) for a in args])
    except SystemExit as exc:          # argparse usage errors
        rc = exc.code
    out, err = capsys.readouterr()
    return rc, out, err


@pytest.mark.slow
def test_cli_bad_input_exits_2_with_one_paragraph(tmp_path, capsys):
    rc, _, err = cli(capsys, "sweep", tmp_path / "nope.yaml")
    assert rc == 2 and "sweep file not found" in err

    path = write_sweep(tmp_path, grid={"links.default.latency.dt": [0, 1]}, runs=1)
    p = dkfsim("sweep", path)                     # as a user meets it: a real process
    assert p.returncode == 2
    assert "links.default.latency.dt" in p.stderr and "parameter set 0" in p.stderr
    assert "Traceback" not in p.stderr and len(p.stderr.strip().splitlines()) == 1

    good = write_sweep(tmp_path, name="good", grid={}, runs=1, steps=20)
    rc, _, err = cli(capsys, "sweep", good, "--export", tmp_path / "out.xlsx")
    assert rc == 2 and "use a .csv or .parquet" in err
    assert not (tmp_path / "good.sqlite").exists()      # checked before anything runs
    rc, _, err = cli(capsys, "sweep", good, "--jobs", "2", "--dask-local", "2")
    assert rc == 2 and "not allowed with" in err

    not_db = tmp_path / "plain.sqlite"
    not_db.write_text("hello")
    rc, _, err = cli(capsys, "sweep", good, "--db", not_db)
    assert rc == 2 and err.count("not an SQLite file") == 1
    assert not_db.read_text() == "hello"


@pytest.mark.slow
def test_export_only_from_a_database_and_help(tmp_path, capsys):
    path = write_sweep(tmp_path, grid={"protocol": ["tree"]}, runs=1, steps=20)
    assert cli(capsys, "sweep", path, "--jobs", "1", "--quiet")[0] == 0
    db = tmp_path / "s.sqlite"
    rc, out, err = cli(capsys, "sweep", db, "--export", tmp_path / "x.csv")
    assert rc == 0, err
    assert "wrote" in out and len((tmp_path / "x.csv").read_text().splitlines()) == 1 + 3 * NC
    rc, _, err = cli(capsys, "sweep", db)
    assert rc == 2 and "--export" in err
    rc, out, _ = cli(capsys, "sweep", "--help")
    assert rc == 0
    for opt in ("--jobs", "--scheduler", "--dask-local", "--db", "--export", "--dry-run",
                "--quiet", "scenario", "grid", "runs", "burn_in", "output"):
        assert opt in out, opt
    rc, out, _ = cli(capsys, "sweep", path, "--dry-run")
    assert rc == 0 and "1/1 done" in out


def test_throughput_reports_runs_per_minute():
    # a benchmark helper: it lives in tools/bench.py, not in the package
    import importlib.util
    spec = importlib.util.spec_from_file_location("dkfsim_bench", ROOT / "tools" / "bench.py")
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    out = bench.throughput(steps=20, jobs=1, runs=2)
    assert out["runs"] == 2 and out["steps"] == 20
    assert out["runs_per_minute"] > 0 and out["wall_s"] > 0


def test_the_last_line_gives_the_whole_time_when_start_up_was_long(tmp_path, capsys, monkeypatch):
    """The progress lines count from the command's start, the "computed in" from the first task:
    with a long start-up (the sidelink sweep's trials and first compile: 34 s) the two disagreed
    with no word on why. The last line now gives both, above a threshold (here 5 s, then -1)."""
    from dkfsim.cli import sweep as cli_sweep
    from dkfsim.cli.main import main
    path = write_sweep(tmp_path, runs=1, steps=10)
    assert main(["sweep", str(path), "--jobs", "1"]) == 0
    out = capsys.readouterr().out
    assert "computed in" in out and "in all" not in out
    monkeypatch.setattr(cli_sweep, "STARTUP_SAID_ABOVE_S", -1.0)
    path = write_sweep(tmp_path, name="t", runs=1, steps=10)
    assert main(["sweep", str(path), "--jobs", "1"]) == 0
    assert "in all, with the time estimate and start-up" in capsys.readouterr().out


"""One executor for montecarlo, sweep and maxdelay: the same results on a local process
pool and on a Dask LocalCluster, and a worker killed mid-task loses and duplicates
nothing (its tasks run again; a task that always kills its worker is reported)."""

from __future__ import annotations

import os
import struct
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
import pytest
import yaml

import dkfsim
from dkfsim.core.errors import DkfsimError
from dkfsim.experiments import executors
from dkfsim.experiments.executors import DaskExecutor, LocalExecutor, in_order

ROOT = Path(__file__).resolve().parents[1]
CASE1 = ROOT / "scenarios" / "paper_case1.yaml"
PARENT = os.getpid()


# --------------------------------------------------------------------------- helpers
def _square_or_die(x: int, marker: str, victim: int) -> int:
    """x * x; the first time task ``victim`` runs in a worker process, that process dies."""
    if x == victim and os.getpid() != PARENT and not os.path.exists(marker):
        Path(marker).write_text("died once")
        os._exit(1)
    return x * x


def _always_die(x: int) -> int:
    if os.getpid() != PARENT:
        os._exit(1)
    return x


def _kill_first_run_in_a_worker(monkeypatch, marker: Path) -> None:
    """The first simulation run by a worker process (forked: it inherits the patch) kills it."""
    import dkfsim.engine.driver as driver
    real = driver.Run.run

    def run(self):
        if os.getpid() != PARENT and not marker.exists():
            marker.write_text("died once")
            os._exit(1)
        return real(self)
    monkeypatch.setattr(driver.Run, "run", run)


def _same_montecarlo(a, b) -> None:
    assert repr(a.rows) == repr(b.rows)                       # repr: nan == nan
    for name in ("mse", "mse_ci_lo", "mse_ci_hi", "nees"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    for k in a.example:
        np.testing.assert_array_equal(a.example[k], b.example[k])


def _maxdelay_dict(res) -> dict:
    d = res.to_dict()
    del d["wall_time_s"], d["versions"]
    return d


def _rw(steps=30):
    """A scalar random walk seen by 4 sensors on a path, uniform_steps latency."""
    return {"name": "rw", "seed": 3, "steps": steps,
            "model": {"kind": "linear", "T": 1.0, "Phi": [[1.0]], "Q": [[1.0]]},
            "prior": {"mean": [0.0], "cov": [[1.0]]},
            "sensors": [{"name": f"s{i}", "H": [[1.0]], "R": [[4.0]]} for i in range(4)],
            "topology": {"generator": "path"},
            "links": {"default": {"latency": {"model": "uniform_steps", "d_t": 1}}},
            "fusion": "matrix", "baselines": []}


MAXDELAY = dict(metric="fused_mse", relative=1.5, batch=2, max_runs=4, max_delay=3)


# --------------------------------------------------------------------------- the executor itself
@pytest.mark.slow
def test_a_killed_worker_loses_and_duplicates_no_task(tmp_path):
    marker = tmp_path / "died"
    with LocalExecutor(2) as ex:
        got = list(ex.imap_unordered(_square_or_die, ((x, (x, str(marker), 5)) for x in range(12))))
    assert marker.exists()                                    # a worker did die
    assert sorted(k for k, _ in got) == list(range(12))       # each task exactly once
    assert dict(got) == {x: x * x for x in range(12)}


@pytest.mark.slow
def test_a_task_that_always_kills_its_worker_is_reported_after_bounded_retries():
    with LocalExecutor(2) as ex, pytest.raises(DkfsimError, match=r"died 3 times while running task 7"):
        list(ex.imap_unordered(_always_die, [(7, (7,))]))
    assert executors.MAX_RETRIES == 2


def test_a_pool_whose_worker_died_sending_a_result_stops_without_a_thread_left_waiting():
    """A worker stopped in the middle of sending its result (``kill PID`` under load) left half a
    message in the result pipe; the pool's manager thread then waited for the rest for ever, and
    the interpreter, which joins that thread at exit, with it: an interrupted ``dkfsim montecarlo``
    hung. Here the half message is written by hand (the pool's own pipe: standard-library
    internals), then :func:`kill_pool` must leave no manager thread behind, in seconds."""
    pool = ProcessPoolExecutor(2)
    assert pool.submit(pow, 2, 3).result() == 8              # the workers and the manager run
    manager = pool._executor_manager_thread
    writer = pool._result_queue._writer
    os.write(writer.fileno(), struct.pack("!i", 1000) + b"x" * 10)   # 10 of 1000 bytes
    time.sleep(0.3)                                          # the manager is reading the rest
    try:
        t0 = time.monotonic()
        executors.kill_pool(pool)
        elapsed = time.monotonic() - t0
        assert not manager.is_alive()
        assert elapsed < 4.0, elapsed
    finally:                                                 # never leave this test's process hung
        if not writer.closed:
            writer.close()
        manager.join(5)


def test_in_order_gives_task_order_and_the_first_error_in_that_order():
    with LocalExecutor(2) as ex:
        assert ex.map(pow, [(x, 2) for x in range(9)]) == [x * x for x in range(9)]
        # pow(0, -1) and pow(0, -2) both fail; the first in task order is the one raised
        tasks = [("a", (2, 1)), ("b", (0, -1)), ("c", (0, -2)), ("d", (3, 1))]
        with pytest.raises(ZeroDivisionError, match="negative power"):
            list(in_order(ex, pow, tasks))


# --------------------------------------------------------------------------- the three commands
@pytest.mark.slow
def test_montecarlo_survives_a_killed_worker_with_the_same_result(tmp_path, monkeypatch):
    sc = dkfsim.load_scenario(CASE1, overrides=["steps=20"])
    clean = dkfsim.montecarlo(sc, 4, jobs=1)
    marker = tmp_path / "died"
    _kill_first_run_in_a_worker(monkeypatch, marker)
    crashed = dkfsim.montecarlo(sc, 4, jobs=2)
    assert marker.exists()
    assert [r["run"] for r in crashed.rows[::len(crashed.rows) // 4]] == [0, 1, 2, 3]
    _same_montecarlo(clean, crashed)


@pytest.mark.slow
def test_sweep_survives_a_killed_worker_with_every_task_once(tmp_path, monkeypatch):
    from dkfsim.experiments.sweep import load_sweep, read_results, run_sweep
    spec = {"scenario": str(CASE1), "grid": {"protocol": ["tree", "flood"]},
            "set": ["steps=20"], "runs": 2}
    (tmp_path / "s.yaml").write_text(yaml.safe_dump(spec))
    clean = run_sweep(load_sweep(tmp_path / "s.yaml", output=tmp_path / "clean.sqlite"), jobs=1,
                      progress=False)
    marker = tmp_path / "died"
    _kill_first_run_in_a_worker(monkeypatch, marker)
    crashed = run_sweep(load_sweep(tmp_path / "s.yaml", output=tmp_path / "crash.sqlite"), jobs=2,
                        progress=False)
    assert marker.exists()
    assert clean.computed == crashed.computed == 4
    assert read_results(tmp_path / "clean.sqlite") == read_results(tmp_path / "crash.sqlite")


@pytest.mark.slow
def test_maxdelay_survives_a_killed_worker_with_the_same_answer(tmp_path, monkeypatch):
    sc = dkfsim.load_scenario(_rw())
    clean = dkfsim.maxdelay(sc, jobs=1, **MAXDELAY)
    marker = tmp_path / "died"
    _kill_first_run_in_a_worker(monkeypatch, marker)
    crashed = dkfsim.maxdelay(sc, jobs=2, **MAXDELAY)
    assert marker.exists()
    assert _maxdelay_dict(clean) == _maxdelay_dict(crashed)


@pytest.mark.slow
def test_montecarlo_and_maxdelay_agree_on_a_local_pool_and_a_dask_local_cluster():
    pytest.importorskip("distributed")
    mc_sc = dkfsim.load_scenario(CASE1, overrides=["steps=20"])
    md_sc = dkfsim.load_scenario(_rw())
    pool_mc = dkfsim.montecarlo(mc_sc, 4, jobs=2)
    pool_md = dkfsim.maxdelay(md_sc, jobs=2, **MAXDELAY)
    with DaskExecutor(n_workers=2, processes=False) as ex:
        dask_mc = dkfsim.montecarlo(mc_sc, 4, executor=ex)
        dask_md = dkfsim.maxdelay(md_sc, executor=ex, **MAXDELAY)
        assert "Dask" in dask_mc.executor
    _same_montecarlo(pool_mc, dask_mc)
    assert _maxdelay_dict(pool_md) == _maxdelay_dict(dask_md)
    assert pool_md.runs_total == dask_md.runs_total > 4


@pytest.mark.slow
def test_the_three_commands_share_the_executor_flags():
    from dkfsim.cli.main import build_parser
    parser = build_parser()
    sub = next(a for a in parser._actions if a.choices and "sweep" in a.choices).choices
    for cmd in ("montecarlo", "sweep", "maxdelay"):
        flags = {o: a for a in sub[cmd]._actions for o in a.option_strings}
        assert {"--jobs", "--scheduler", "--dask-local", "--quiet"} <= set(flags), cmd
        assert flags["--jobs"].default is None, cmd           # one default: every CPU

"""With ``links.shared_queues: true`` a sweep may not grow by estimators (docs/traffic.md): the
added estimators would run alone on stored runs whose queues they should have shared."""

from __future__ import annotations

import sqlite3

from test_sweep import dkfsim, write_sweep

SHARED = ["links.default.rate=2.0e+5", "links.shared_queues=true"]


def _rows(db):
    with sqlite3.connect(db) as conn:
        return conn.execute("SELECT COUNT(*) FROM results").fetchone()[0]


def test_growing_by_estimators_with_shared_queues_is_refused(tmp_path):
    from dkfsim.experiments.sweep import run_sweep
    one = SHARED + ["estimators=[{kind: centralized}]"]
    two = SHARED + ["estimators=[{kind: centralized}, {kind: kcf}]"]
    path = write_sweep(tmp_path, grid={"links.default.latency.d_t": [1]}, runs=1, steps=15, extra_set=one)
    assert run_sweep(path, jobs=1, progress=False).computed == 1
    db = tmp_path / "s.sqlite"
    before = _rows(db)
    # more runs with the same estimators: every new run has all of them, allowed
    write_sweep(tmp_path, grid={"links.default.latency.d_t": [1]}, runs=2, steps=15, extra_set=one)
    assert run_sweep(path, jobs=1, progress=False).computed == 1
    grown = _rows(db)
    assert grown > before
    write_sweep(tmp_path, grid={"links.default.latency.d_t": [1]}, runs=2, steps=15, extra_set=two)
    p = dkfsim("sweep", path, "--jobs", "1")
    assert p.returncode == 2, p.stderr
    err = p.stderr
    assert str(path) in err and "estimators" in err and "links.shared_queues" in err and "kcf" in err
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert _rows(db) == grown                                  # nothing written


def test_without_shared_queues_the_same_growth_runs(tmp_path):
    from dkfsim.experiments.sweep import run_sweep
    rate = ["links.default.rate=2.0e+5"]
    path = write_sweep(tmp_path, grid={"links.default.latency.d_t": [1]}, runs=1, steps=15,
                       extra_set=rate + ["estimators=[{kind: centralized}]"])
    assert run_sweep(path, jobs=1, progress=False).computed == 1
    write_sweep(tmp_path, grid={"links.default.latency.d_t": [1]}, runs=1, steps=15,
                extra_set=rate + ["estimators=[{kind: centralized}, {kind: kcf}]"])
    assert run_sweep(path, jobs=1, progress=False).computed == 1

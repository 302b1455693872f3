"""Faults leave nothing behind (issue 20 §2).

A file-size limit (EFBIG: what a full disk does to a write, reproducible without one), SIGTERM and
kill -9 while a run stages its output, a sweep database being created or locked, standard output
that is ASCII-only, full or closed, numba's cache that cannot be written and bad kernel settings.
Every command ends in a clean error (or succeeds), within CPU-time and memory bounds, and the
output an earlier command wrote is intact; the next command removes what a killed one left.
"""

from __future__ import annotations

import csv
import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from conftest import numba_cache_but
from hostile_kit import CASE1, dkfsim_cli, file_size_limit

import dkfsim
from dkfsim.core.folders import OWNER, remove_dead_staging
from dkfsim.experiments.sweep import SweepDB, is_database, load_sweep

SMALL = ["--steps", "30"]


def snapshot(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir())}


def staging_left(parent: Path) -> list[str]:
    return sorted(p.name for p in parent.iterdir() if ".new-" in p.name or ".old-" in p.name)


# =========================================================================== a full disk
@pytest.mark.parametrize("command", [
    ["run", CASE1, *SMALL, "--save", "full"],
    ["montecarlo", CASE1, *SMALL, "--runs", "2", "--jobs", "1"],
    ["maxdelay", CASE1, *SMALL, "--relative", "1.5", "--jobs", "1"],
])
def test_a_full_disk_is_a_clean_error_and_the_earlier_output_survives(tmp_path, command):
    out = tmp_path / "out"
    dkfsim_cli(*command, "--out", out, "--quiet").ok(cpu=120)
    before = snapshot(out)
    child = dkfsim_cli(*command, "--out", out, "--quiet", preexec=file_size_limit(2_000))
    child.clean_error("--out", "File too large", "holds what it held before", cpu=120)
    assert snapshot(out) == before
    assert staging_left(tmp_path) == []


def _export(db: Path, to: Path) -> list[dict]:
    dkfsim_cli("sweep", db, "--export", to, "--quiet").ok()
    with open(to, newline="") as fh:
        return list(csv.DictReader(fh))


def test_a_sweep_on_a_full_disk_leaves_a_database_the_next_sweep_resumes(tmp_path):
    """At every size limit the sweep stops cleanly, leaves no database or a whole one (never a
    header-only file every later sweep refused), and a sweep without the limit completes it with
    the rows of an uninterrupted sweep."""
    spec = {"scenario": str(CASE1), "grid": {"links.default.latency.d_t": [0, 2]},
            "set": ["steps=30", "estimators=[{kind: centralized}]"], "runs": 3}
    (tmp_path / "ref.yaml").write_text(yaml.safe_dump(spec))
    dkfsim_cli("sweep", tmp_path / "ref.yaml", "--jobs", "1", "--quiet").ok(cpu=120)
    reference = _export(tmp_path / "ref.sqlite", tmp_path / "ref.csv")
    for limit in (4_000, 20_000, 60_000):
        d = tmp_path / f"limit{limit}"
        d.mkdir()
        (d / "s.yaml").write_text(yaml.safe_dump(spec))
        child = dkfsim_cli("sweep", d / "s.yaml", "--jobs", "1", "--quiet", preexec=file_size_limit(limit))
        if child.returncode != 0:
            child.clean_error("s.sqlite", cpu=120)
        db = d / "s.sqlite"
        assert not db.exists() or (is_database(db) and SweepDB(db, readonly=True).close() is None)
        assert staging_left(d) == []
        dkfsim_cli("sweep", d / "s.yaml", "--jobs", "1", "--quiet").ok(cpu=120)
        rows = _export(db, d / "s.csv")
        assert [{k: v for k, v in r.items()} for r in rows] == reference


def test_a_healthy_database_reads_on_a_full_disk(tmp_path):
    (tmp_path / "s.yaml").write_text(yaml.safe_dump({"scenario": str(CASE1), "runs": 2,
                                                     "set": ["steps=20", "estimators=[]"]}))
    dkfsim_cli("sweep", tmp_path / "s.yaml", "--jobs", "1", "--quiet").ok(cpu=60)
    out = dkfsim_cli("sweep", tmp_path / "s.yaml", "--dry-run", preexec=file_size_limit(0)).ok()
    assert "2/2 done" in out


@pytest.mark.slow
def test_a_kernel_cache_that_cannot_be_written_compiles_in_memory(tmp_path):
    """numba's cache in a fresh folder, cold for one kernel module (every module cold: 35 s more,
    the same path), with a 100 kB file-size limit: the run completes with one warning and the
    numbers of a normal run (it crashed every run)."""
    out, ref = tmp_path / "out", tmp_path / "ref"
    cache = numba_cache_but(tmp_path, "port_kernels")          # (its largest file is over 100 kB)
    child = dkfsim_cli("run", CASE1, *SMALL, "--save", "summary", "--out", out, "--quiet",
                       env={"NUMBA_CACHE_DIR": str(cache)}, preexec=file_size_limit(100_000))
    child.ok(cpu=300, memory_mb=1500)
    assert child.stderr.count("cannot write numba's kernel cache") == 1
    dkfsim_cli("run", CASE1, *SMALL, "--save", "summary", "--out", ref, "--quiet").ok(cpu=300, memory_mb=1500)
    rows = [json.loads((f / "summary.json").read_text())["rows"] for f in (out, ref)]
    assert rows[0] == rows[1]


# =========================================================================== signals while staging
#: Runs ``dkfsim`` (argv) with a signal sent to itself right after run.npz is written into the
#: staging folder: the moment a SIGTERM or kill -9 used to leave a 30 MB hidden folder behind.
SIGNAL_WHILE_STAGING = """
import os, signal, sys
import numpy as np
savez, sig = np.savez, getattr(signal, os.environ["SIGNAL"])
def savez_then_signal(*a, **k):
    savez(*a, **k)
    os.kill(os.getpid(), sig)
np.savez = savez_then_signal
from dkfsim.cli.main import main
sys.exit(main(sys.argv[1:]))
"""


def test_sigterm_while_staging_cleans_up_like_ctrl_c(tmp_path):
    out = tmp_path / "out"
    dkfsim_cli("run", CASE1, *SMALL, "--out", out, "--quiet").ok()
    before = snapshot(out)
    child = dkfsim_cli("run", CASE1, "--steps", "40", "--out", out, "--quiet", env={"SIGNAL": "SIGTERM"},
                       python=SIGNAL_WHILE_STAGING)
    assert child.returncode == 143 and "terminated" in child.stderr and "Traceback" not in child.stderr
    assert staging_left(tmp_path) == [] and snapshot(out) == before


def test_the_next_command_removes_what_a_killed_run_left(tmp_path):
    out = tmp_path / "out"
    dkfsim_cli("run", CASE1, *SMALL, "--out", out, "--quiet").ok()
    child = dkfsim_cli("run", CASE1, "--steps", "40", "--out", out, "--quiet", env={"SIGNAL": "SIGKILL"},
                       python=SIGNAL_WHILE_STAGING)
    assert child.returncode == -signal.SIGKILL
    left = staging_left(tmp_path)
    assert len(left) == 1 and (tmp_path / left[0] / "run.npz").is_file()      # what kill -9 leaves
    # Two folders that are not provably dead stay: one of a live process (this one), one without owner.
    alive = tmp_path / ".out.new-1-alive"
    alive.mkdir()
    me = json.loads((tmp_path / left[0] / OWNER).read_text())
    (alive / OWNER).write_text(json.dumps({**me, "pid": os.getpid(),
                                           "start": _start_time(os.getpid())}))
    (tmp_path / ".out.new-2-unknown").mkdir()
    dkfsim_cli("run", CASE1, "--steps", "20", "--out", out, "--quiet").ok()
    assert staging_left(tmp_path) == [".out.new-1-alive", ".out.new-2-unknown"]
    assert json.loads((out / "summary.json").read_text())["steps"] == 20


def _start_time(pid: int) -> int:
    with open(f"/proc/{pid}/stat", "rb") as fh:
        return int(fh.read().rsplit(b")", 1)[1].split()[19])


def test_a_dead_swap_puts_the_previous_output_back(tmp_path):
    """The two-rename swap (no renameat2) killed between its renames: the previous output, kept as
    .NAME.old-*, is put back by the next command."""
    out = tmp_path / "out"
    dkfsim.run(CASE1, steps=10).save(out)
    before = snapshot(out)
    old = tmp_path / ".out.old-99999999-x"
    out.rename(old)
    dead = {"pid": 99999999, "start": 1, "host": os.uname().nodename,
            "boot": Path("/proc/sys/kernel/random/boot_id").read_text().strip()}
    (old / OWNER).write_text(json.dumps(dead))
    assert remove_dead_staging(out) == [old]
    assert snapshot(out) == before


# =========================================================================== the sweep's lock
def test_a_sweep_database_is_whole_before_anyone_can_see_it(tmp_path, monkeypatch):
    (tmp_path / "s.yaml").write_text(yaml.safe_dump({"scenario": str(CASE1), "runs": 1,
                                                     "set": ["steps=10", "estimators=[]"]}))
    sweep = load_sweep(tmp_path / "s.yaml")
    seen = []
    lock = SweepDB._lock

    def checked_lock(self):
        seen.append(SweepDB(self.path, readonly=True).definition)     # a whole database already
        lock(self)
    monkeypatch.setattr(SweepDB, "_lock", checked_lock)
    with SweepDB(sweep.output, sweep):
        assert seen and seen[0]["runs"] == 1
        second = dkfsim_cli("sweep", tmp_path / "s.yaml", "--jobs", "1")
        second.clean_error("another dkfsim sweep is writing")
        assert "0/1 done" in dkfsim_cli("sweep", tmp_path / "s.yaml", "--dry-run").ok()
        dkfsim_cli("report", sweep.output).ok()


def test_a_filesystem_without_hard_links_still_gets_a_database(tmp_path, monkeypatch):
    """The whole database is linked into place; where links are not supported it is renamed."""
    (tmp_path / "s.yaml").write_text(yaml.safe_dump({"scenario": str(CASE1), "runs": 1,
                                                     "set": ["steps=10", "estimators=[]"]}))
    sweep = load_sweep(tmp_path / "s.yaml")

    def no_link(*_):
        raise PermissionError(1, "Operation not permitted")
    monkeypatch.setattr(os, "link", no_link)
    with SweepDB(sweep.output, sweep) as store:
        assert store.definition["runs"] == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.sqlite", "s.yaml"]


# =========================================================================== standard output
def test_an_ascii_only_stdout_gets_escapes():
    out = dkfsim_cli("validate", CASE1, env={"PYTHONIOENCODING": "ascii"}).ok()
    assert ": ok \\u2014 paper_case1" in out


def test_a_full_stdout_is_a_clean_error_after_the_files_are_written(tmp_path):
    with open("/dev/full", "w") as full:
        dkfsim_cli("run", CASE1, *SMALL, "--out", tmp_path / "out", stdout=full).clean_error(
            "cannot write to standard output", "No space left on device")
    assert json.loads((tmp_path / "out" / "summary.json").read_text())["steps"] == 30


@pytest.mark.parametrize("closed", [(1,), (1, 2)])
def test_a_closed_stdout_is_not_an_error(closed):
    def close():
        for fd in closed:
            os.close(fd)
    p = subprocess.run([sys.executable, "-m", "dkfsim", "validate", str(CASE1)], preexec_fn=close,
                       stdin=subprocess.DEVNULL, stderr=subprocess.PIPE if 2 not in closed else None,
                       timeout=120)
    assert p.returncode == 0, p.stderr


# =========================================================================== kernel settings
def test_numba_num_threads_zero_is_a_clean_error(tmp_path):
    dkfsim_cli("run", CASE1, *SMALL, "--out", tmp_path / "o", env={"NUMBA_NUM_THREADS": "0"}).clean_error(
        "NUMBA_NUM_THREADS", "DKFSIM_KERNELS=numpy")
    dkfsim_cli("run", CASE1, *SMALL, "--out", tmp_path / "o", "--quiet",
               env={"NUMBA_NUM_THREADS": "0", "DKFSIM_KERNELS": "numpy"}).ok()


def test_an_unknown_kernels_value_is_named(tmp_path):
    dkfsim_cli("run", CASE1, *SMALL, "--out", tmp_path / "o", env={"DKFSIM_KERNELS": "garbage"}).clean_error(
        "DKFSIM_KERNELS", "garbage", "not a known value")

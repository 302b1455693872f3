"""Long commands say how far they are when stderr is not a terminal (issue 34 §4): ``montecarlo``,
``sweep`` and ``run`` write one line about every 10 s (``DKFSIM_PROGRESS_EVERY``: here a
hundredth of a second, so that a short command writes several), nothing with ``--quiet``; and
the first run on a machine says that it compiles dkfsim's kernels, once."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import numba_cache_but

ROOT = Path(__file__).resolve().parents[1]
CASE1 = ROOT / "scenarios" / "paper_case1.yaml"


def dkfsim(*args, env=None, timeout=600) -> subprocess.CompletedProcess:
    """``dkfsim ARGS`` with stderr a pipe (not a terminal), as in a log or a batch job."""
    return subprocess.run([sys.executable, "-m", "dkfsim", *map(str, args)], cwd=ROOT, capture_output=True,
                          text=True, timeout=timeout, env={**os.environ, **(env or {})})


FAST = {"DKFSIM_PROGRESS_EVERY": "0.01"}


@pytest.mark.slow
def test_a_montecarlo_writes_progress_lines_to_a_log(tmp_path):
    p = dkfsim("montecarlo", CASE1, "--runs", 4, "--steps", 40, "--jobs", 1, "--out", tmp_path / "mc", env=FAST)
    assert p.returncode == 0, p.stderr
    lines = re.findall(r"^dkfsim montecarlo paper_case1: (\d+)/4 runs, .*$", p.stderr, re.M)
    assert len(lines) >= 2 and lines[-1] == "4", p.stderr
    assert "left" in p.stderr                          # a rate, once a run is done
    quiet = dkfsim("montecarlo", CASE1, "--runs", 2, "--steps", 40, "--jobs", 1, "--quiet", "--out",
                   tmp_path / "q", env=FAST)
    assert quiet.returncode == 0 and "runs," not in quiet.stderr, quiet.stderr


@pytest.mark.slow
def test_a_sweep_writes_progress_lines_to_a_log(tmp_path):
    (tmp_path / "s.yaml").write_text(f"scenario: {CASE1}\ngrid: {{fusion: [matrix, diagonal]}}\nruns: 2\n"
                                     f"set: ['steps=40', 'estimators=[]']\noutput: {tmp_path / 's.sqlite'}\n")
    p = dkfsim("sweep", tmp_path / "s.yaml", "--jobs", 1, env=FAST)
    assert p.returncode == 0, p.stderr
    lines = re.findall(r"^dkfsim sweep s: (\d+)/4 runs, .*$", p.stderr, re.M)
    assert len(lines) >= 2 and lines[-1] == "4", p.stderr


@pytest.mark.slow
def test_the_first_run_says_it_compiles_the_kernels_once(tmp_path):
    # a machine whose cache is cold for one kernel module (every module cold: 35 s more, same path)
    env = {"NUMBA_CACHE_DIR": str(numba_cache_but(tmp_path, "holdings_kernels"))}
    first = dkfsim("run", CASE1, "--steps", 10, "--out", tmp_path / "a", "--quiet", env=env, timeout=1200)
    assert first.returncode == 0, first.stderr
    said = re.findall(r"^dkfsim: compiling dkfsim's kernels once \(about (\d+) s of CPU", first.stderr, re.M)
    assert len(said) == 1 and int(said[0]) > 0, first.stderr
    again = dkfsim("run", CASE1, "--steps", 10, "--out", tmp_path / "b", "--quiet", env=env)
    assert again.returncode == 0 and "compiling" not in again.stderr, again.stderr


def test_the_compile_estimate_counts_each_kernel_not_yet_cached(tmp_path):
    """A module counts by the share of its kernels numba's cache lacks, not only when it lacks
    them all: after paper case 1 had compiled 3 of the estimators' kernels, the sidelink sweep's
    other estimators were counted as cached ("about 8 s" before 36 s of compiling)."""
    from types import SimpleNamespace

    from dkfsim.core.jit import cache_is_cold, uncached_share

    def kernel(name: str, cached: bool):
        path = tmp_path / f"{name}.nbi"
        if cached:
            path.write_text("")
        return SimpleNamespace(_cache=SimpleNamespace(_cache_file=SimpleNamespace(_index_path=str(path))))
    some = [kernel("a", True), kernel("b", False), kernel("c", False), kernel("d", True)]
    assert uncached_share(some) == 0.5 and not cache_is_cold(some)
    cold = [kernel("e", False), kernel("f", False)]
    assert uncached_share(cold) == 1.0 and cache_is_cold(cold)
    silent = [SimpleNamespace()]                 # a numba that does not say where its index is
    assert uncached_share(silent) == 0.0 and not cache_is_cold(silent)


#!/usr/bin/env python
"""Measure every test and write the ones above the fast tier's budget to tests/slow_tests.txt.

The fast tier (``make test-fast``) is the suite without the tests marked ``slow``.  Besides the
tests marked by what they are (docs/development.md, "Two tiers"), a test whose call takes more
than :data:`BUDGET_S` seconds on the project's 2-core machine, under ``pytest -n 2``, is in the
slow tier by this measurement: tests/conftest.py marks every node id listed in
tests/slow_tests.txt.  Rerun this when the fast tier drifts over its 90 s::

    python tools/slow_tier.py              # runs the whole suite once (about 9 min), rewrites the list

The list keeps the measured seconds beside each id, and says which ids it dropped (gone, or
now within the budget).  As a pytest plugin (``-p slow_tier``, with this folder on the path) the
module records each test's call time to the file named by ``DKFSIM_TEST_TIMES``.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
LIST = ROOT / "tests" / "slow_tests.txt"
#: The fast tier's per-test budget (seconds of one test's setup and call under ``-n 2``).
BUDGET_S = 1.5
HEADER = f"""\
# Tests in the slow tier because they take more than {BUDGET_S} s on the project's 2-core machine
# (setup and call under pytest -n 2), beside those marked slow in their files.
# Written by tools/slow_tier.py (measured seconds, then the node id); tests/conftest.py reads it.
"""


#: Whether this pytest process records (the one that runs the tests: an xdist worker, or pytest
#: without xdist; an xdist controller sees every report again).
_RECORDS = False


def pytest_configure(config) -> None:
    global _RECORDS
    _RECORDS = hasattr(config, "workerinput") or not getattr(config.option, "numprocesses", None)


def pytest_runtest_logreport(report) -> None:
    """Record the setup and call time of each test (in the process that ran it)."""
    out = os.environ.get("DKFSIM_TEST_TIMES")
    measured = "slow" not in report.keywords or "slow_by_time" in report.keywords   # (not slow by what it is)
    if out and _RECORDS and measured and report.when in ("setup", "call"):
        with open(out, "a", encoding="utf-8") as f:
            f.write(f"{report.duration:.3f}\t{report.nodeid}\n")


def read_list(path: Path = LIST) -> dict[str, float]:
    """The listed node ids and their measured seconds."""
    if not path.is_file():
        return {}
    rows = (line.split(None, 1) for line in path.read_text(encoding="utf-8").splitlines()
            if line.strip() and not line.startswith("#"))
    return {nodeid.strip(): float(seconds) for seconds, nodeid in rows}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--jobs", default="2", help="pytest-xdist workers (default 2, as measured)")
    ap.add_argument("--times", help="use this file of recorded times instead of running the suite")
    args = ap.parse_args(argv)
    if args.times:
        times_file = Path(args.times)
    else:
        times_file = Path(tempfile.mkdtemp()) / "times.tsv"
        env = {**os.environ, "DKFSIM_TEST_TIMES": str(times_file),
               "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT / "tools"), os.environ.get("PYTHONPATH")]))}
        code = subprocess.call([sys.executable, "-m", "pytest", "-n", args.jobs, "-p", "slow_tier",
                                "-p", "no:cacheprovider"], cwd=ROOT, env=env)
        if code != 0:
            print(f"the suite failed (exit {code}): the list is not rewritten", file=sys.stderr)
            return code
    seconds: dict[str, float] = {}
    for line in times_file.read_text(encoding="utf-8").splitlines():
        t, nodeid = line.split("\t", 1)
        seconds[nodeid] = seconds.get(nodeid, 0.0) + float(t)
    old = read_list()
    slow = {n: t for n, t in seconds.items() if t > BUDGET_S}
    dropped = sorted(set(old) - set(slow))
    tmp = LIST.with_suffix(".new")
    tmp.write_text(HEADER + "".join(f"{t:6.1f}  {n}\n" for n, t in sorted(slow.items())), encoding="utf-8")
    tmp.replace(LIST)
    print(f"{len(slow)} tests over {BUDGET_S} s written to {LIST.relative_to(ROOT)}"
          + (f"; dropped {len(dropped)}: {', '.join(dropped)}" if dropped else ""))
    return 0


if __name__ == "__main__":
    sys.exit(main())

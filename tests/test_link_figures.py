"""``dkfsim plot`` and ``dkfsim report`` on a rate-limited run: the link figure and the per-link
table, from run.npz and summary.json; nothing of the kind for a run without a rate."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import yaml
from test_maxdelay import const_latency, rw_scenario

ROOT = Path(__file__).resolve().parents[1]


def _cli(*args):
    return subprocess.run([sys.executable, "-m", "dkfsim", *map(str, args)], capture_output=True,
                          text=True, cwd=ROOT)


def _run(tmp_path, rate):
    data = rw_scenario(const_latency(0.2), steps=40)
    if rate is not None:
        data["links"]["default"].update(rate=rate, queue={"packets": 3},
                                        background={"packets_per_second": 3.0, "size": 30})
    f = tmp_path / "s.yaml"
    f.write_text(yaml.safe_dump(data))
    out = tmp_path / "run"
    p = _cli("run", f, "--out", out, "--quiet")
    assert p.returncode == 0, p.stderr
    return out


def test_rate_limited_run_gets_the_link_figure_and_table(tmp_path):
    out = _run(tmp_path, 1500.0)
    p = _cli("plot", out, "--format", "png")
    assert p.returncode == 0, p.stderr
    assert "links.png" in p.stdout and (out / "figures" / "links.png").stat().st_size > 10_000
    p = _cli("report", out)
    assert p.returncode == 0, p.stderr
    page = (out / "report.html").read_text()
    assert 'alt="links"' in page
    table = re.search(r'<table id="links".*?</table>', page, re.S)
    assert table is not None and table.group(0).count("<tr") == 1 + 8     # a path of 5 nodes: 8 directed links


def test_run_without_a_rate_has_neither(tmp_path):
    out = _run(tmp_path, None)
    assert _cli("plot", out, "--format", "png").returncode == 0
    assert not (out / "figures" / "links.png").exists()
    assert _cli("report", out).returncode == 0
    page = (out / "report.html").read_text()
    assert 'alt="links"' not in page and 'id="links"' not in page


def test_a_rate_sweep_is_drawn_on_a_log_axis():
    """Link rates span decades: a positive grid over more than a factor 100 gets a log x axis
    (the rate sweep's figure), a delay bound 0..6 does not."""
    from dkfsim.report.sweep.plot import log_x
    assert log_x([1e15, 1e8, 3e5])
    assert not log_x([0.0, 1.0, 6.0]) and not log_x([1.0, 50.0]) and not log_x([])

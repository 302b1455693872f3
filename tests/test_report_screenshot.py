"""The report page as a browser shows it: ``tools/screenshot_report.py`` renders a report in
headless Chromium (issue 24 §2).  Skipped, saying how to install it, where Chromium is absent."""

from __future__ import annotations

import importlib.util
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from dkfsim.cli.main import main

ROOT = Path(__file__).resolve().parents[1]
TOOL = ROOT / "tools" / "screenshot_report.py"


def tool():
    spec = importlib.util.spec_from_file_location("screenshot_report", TOOL)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_without_chromium_the_tool_says_how_to_install_it(tmp_path):
    page = tmp_path / "p.html"
    page.write_text("<html><body>x</body></html>")
    env = {**os.environ, "PATH": str(tmp_path)}            # nothing to find there
    done = subprocess.run([sys.executable, str(TOOL), str(page), str(tmp_path / "p.png")],
                          capture_output=True, text=True, env=env, timeout=60)
    assert done.returncode != 0 and "apt-get install chromium" in done.stderr
    assert not (tmp_path / "p.png").exists()


def test_a_report_page_renders_in_chromium(tmp_path):
    if tool().find_chromium() is None:
        pytest.skip(tool().INSTALL + " to run this test")
    from PIL import Image
    out = tmp_path / "run"
    assert main(["run", str(ROOT / "scenarios" / "paper_case1.yaml"), "--steps", "60", "--quiet",
                 "--out", str(out)]) == 0
    assert main(["report", str(out)]) == 0
    png = tmp_path / "shot.png"
    done = subprocess.run([sys.executable, str(TOOL), str(out / "report.html"), str(png), "--width", "1000",
                           "--height", "1400"], capture_output=True, text=True, timeout=180)
    assert done.returncode == 0, done.stderr[-1000:]
    img = np.asarray(Image.open(png).convert("L"), dtype=float)
    assert img.shape == (1400, 1000)
    ink = img < 128
    assert ink.mean() > 0.005                              # text and figures, not a blank page
    assert ink[:80].any() and ink[-400:].any()             # the title on top, content far down

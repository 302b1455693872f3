"""Render a ``dkfsim report`` page in headless Chromium and save a PNG screenshot.

    .venv/bin/python tools/screenshot_report.py out/case1/report.html docs/figures/report_run.png

Chromium comes from the system packages (Debian: ``apt-get install chromium``).
The page is self-contained, so Chromium needs no network; ``--height`` sets how
much of the page is captured (default: the first 2400 CSS pixels).  Used to look
at the page as a person would before it ships (issue 11).
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

#: What to do when no Chromium is found (the tool and its test say it).
INSTALL = "no Chromium found: install it (Debian: apt-get install chromium)"


def find_chromium() -> str | None:
    """The path of a Chromium (or Chrome) on PATH, None without one."""
    for name in ("chromium", "chromium-browser", "google-chrome", "chrome"):
        path = shutil.which(name)
        if path:
            return path
    return None


def chromium() -> str:
    return find_chromium() or sys.exit(INSTALL)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("page", type=Path, help="the report.html to render")
    p.add_argument("png", type=Path, help="where to write the screenshot")
    p.add_argument("--width", type=int, default=1200)
    p.add_argument("--height", type=int, default=2400)
    args = p.parse_args(argv)
    if not args.page.is_file():
        sys.exit(f"{args.page}: no such file")
    args.png.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="dkfsim-chromium-") as profile:
        cmd = [chromium(), "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
               f"--user-data-dir={profile}", f"--window-size={args.width},{args.height}",
               f"--screenshot={args.png.resolve()}", args.page.resolve().as_uri()]
        done = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    if done.returncode != 0 or not args.png.is_file():
        sys.exit(f"chromium failed ({done.returncode}): {done.stderr[-2000:]}")
    print(f"wrote {args.png}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

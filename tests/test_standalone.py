"""The repository stands alone: no file points at a folder beside it or at an absolute path
of the machine it was written on."""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TEXT = {".py", ".md", ".yaml", ".yml", ".toml", ".txt", ".cfg", ".ini", ".sh", ""}
#: The folder of reference material beside a developer's clone, and the top folders of developer
#: machines' absolute paths. Both are spelled in pieces so that this file passes its own check.
SHELF = ".." + "/" + "shared"
MACHINE_ROOTS = ("work", "home", "root", "tmp" + "/ci_clone", "Users")
OUTSIDE = re.compile(re.escape(SHELF) + r"\b|(?<![\w.])/(?:" + "|".join(map(re.escape, MACHINE_ROOTS)) + r")/")


def tracked_text_files() -> list[Path]:
    try:
        out = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True, check=True).stdout
        files = [ROOT / line for line in out.splitlines()]
    except (OSError, subprocess.CalledProcessError):         # an unpacked archive, not a clone
        files = [p for p in ROOT.rglob("*") if ".venv" not in p.parts and ".git" not in p.parts]
    return [p for p in files if p.is_file() and p.suffix in TEXT and p.stat().st_size < 2_000_000]


def test_no_file_points_outside_the_repository():
    files = tracked_text_files()
    assert len(files) > 50
    hits = []
    for path in files:
        if path == Path(__file__).resolve():
            continue
        for i, line in enumerate(path.read_text(errors="replace").splitlines(), 1):
            if OUTSIDE.search(line):
                hits.append(f"{path.relative_to(ROOT)}:{i}: {line.strip()[:100]}")
    assert not hits, "\n".join(hits)


def test_the_pattern_catches_what_it_is_for():
    for bad in (f"see {SHELF}/DESIGN.md", "data: /" + "work/project/data/x.txt", "open('/" + "home/me/x')"):
        assert OUTSIDE.search(bad), bad
    for fine in ("dataset: cicv5g/urban", "https://example.org/" + "work/", "docs/design.md", "a/" + "work/b"):
        assert not OUTSIDE.search(fine), fine

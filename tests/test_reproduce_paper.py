"""tools/reproduce_paper.py writes into its output folder, never over the repository's tracked
files (issue 24 §3): run on a copy of the repository, `git status` stays as it was."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
FIGURES = ("fig3_tracking", "fig4_mse", "fig5_case1_vs_case2", "fig6_delay_bounds")


def git(repo: Path, *argv: str) -> str:
    p = subprocess.run(["git", "-c", "user.name=t", "-c", "user.email=t@t", *argv], cwd=repo,
                       capture_output=True, text=True, check=True)
    return p.stdout


def copy_of_the_repository(dest: Path) -> Path:
    """The working tree's files (tracked and new, not ignored) in a fresh git repository, so the
    tool runs on this branch's code and its writes show in the copy's `git status`."""
    files = git(ROOT, "ls-files", "-z", "--cached", "--others", "--exclude-standard").split("\0")
    for name in filter(None, files):
        src = ROOT / name
        if src.is_file():
            (dest / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, dest / name)
    git(dest, "init", "-q")
    git(dest, "add", "-A")
    git(dest, "commit", "-q", "-m", "copy")
    return dest


@pytest.mark.slow
def test_reproduce_paper_leaves_git_status_clean(tmp_path):
    repo = copy_of_the_repository(tmp_path / "repo")
    before = git(repo, "status", "--porcelain", "--untracked-files=all")
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    env = {**os.environ, "MPLBACKEND": "Agg", "DKFSIM_KERNELS": "numpy"}
    p = subprocess.run([sys.executable, str(repo / "tools" / "reproduce_paper.py"), "--runs", "1",
                        "--steps", "10", "--jobs", "1", "--format", "png"],
                       cwd=elsewhere, env=env, capture_output=True, text=True, timeout=240)
    assert p.returncode == 0, p.stderr[-3000:]
    assert git(repo, "status", "--porcelain", "--untracked-files=all") == before
    out = repo / "out" / "reproduce_paper"
    for stem in FIGURES:
        assert (out / f"{stem}.png").stat().st_size > 0, stem
    assert (out / "case1_d3" / "summary.json").is_file()
    assert not any(elsewhere.iterdir()), "the tool wrote into the working directory"

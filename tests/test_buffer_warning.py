"""``validate`` and ``run`` warn when an integer ``buffer_length`` is below the bound they compute
(issue 34 §7): on a changing graph ``late = 0`` does not mean the final rows are exact (in the
issue's run, 184 of 189 final rows differed from the centralized filter with late 0), so a silent
run could not be told from an exact one."""

from __future__ import annotations

from pathlib import Path

import pytest

from dkfsim.cli.main import main

ROOT = Path(__file__).resolve().parents[1]
CONVOY = ROOT / "scenarios" / "mobility_convoy.yaml"       # (n - 1)(B + d_t) + 1 = 16
CASE1 = ROOT / "scenarios" / "paper_case1.yaml"            # d_t d_g + 1 = 17


@pytest.mark.parametrize("path, L, bound", [(CONVOY, 6, 16), (CASE1, 10, 17)])
def test_validate_and_run_warn_below_the_bound(tmp_path, capsys, path, L, bound):
    assert main(["validate", str(path), "--set", f"buffer_length={L}"]) == 0
    err = capsys.readouterr().err
    assert f"dkfsim validate: warning: buffer_length {L} is below" in err and f"= {bound}" in err, err
    assert main(["run", str(path), "--set", f"buffer_length={L}", "--steps", "200", "--quiet", "--out",
                 str(tmp_path / "r")]) == 0
    err = capsys.readouterr().err
    assert f"dkfsim run: warning: buffer_length {L} is below" in err, err


@pytest.mark.parametrize("path, L", [(CONVOY, "auto"), (CONVOY, 16), (CASE1, "auto"), (CASE1, 17), (CASE1, 40)])
def test_no_warning_at_or_above_the_bound(capsys, path, L):
    assert main(["validate", str(path), "--set", f"buffer_length={L}"]) == 0
    assert "warning" not in capsys.readouterr().err

"""Issue 24 §2, figures that show the result: what can be asserted of a figure (markers,
labels with units, legend width, what is refused), and the two bugs found in review."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

matplotlib = pytest.importorskip("matplotlib")

from dkfsim.cli.main import main  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
CASE1 = ROOT / "scenarios" / "paper_case1.yaml"


def test_relative_to_fused_with_fusion_none_is_refused_before_any_run(tmp_path, capsys, monkeypatch):
    import dkfsim.experiments.montecarlo as mc

    def no_run(*a, **k):
        raise AssertionError("a run started before --relative-to was checked")
    monkeypatch.setattr(mc, "_montecarlo", no_run)
    out = tmp_path / "mc"
    assert main(["montecarlo", str(CASE1), "--runs", "2", "--steps", "20", "--jobs", "1", "--quiet",
                 "--set", "fusion=none", "--relative-to", "fused", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "--relative-to fused" in err and "fusion: none" in err and err.count("\n") == 1
    assert not out.exists()

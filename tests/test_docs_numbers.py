"""Docs that cannot drift (issue 24 §3, decision 205).

Every number README.md and docs/*.md quote from a simulation sits in a block that
tools/docs_numbers.py writes.  These tests fail when a quoted number no longer matches what the
code produces: the cheap generator (the quick start) is recomputed here; the Monte Carlo studies'
blocks are rendered from their stored per-run rows (docs/numbers/*.csv), and the slow tier
re-runs runs 0 and 1 of every study (and the whole short radar experiment) against those rows.
Timings are never quoted as checked facts.
"""

from __future__ import annotations

import importlib.util
import math
import re
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.stats import t as student_t

ROOT = Path(__file__).resolve().parents[1]


def _tool():
    spec = importlib.util.spec_from_file_location("docs_numbers", ROOT / "tools" / "docs_numbers.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules["docs_numbers"] = module
    spec.loader.exec_module(module)
    return module


dn = _tool()
STUDIES = [s for g in dn.GENERATORS for s in g.studies]


def assert_quoted(rendered: dict[str, str], generator: str) -> None:
    """Each rendered block equals every copy of it in the pages."""
    found = dn.page_blocks()
    stale = [f"{page.relative_to(ROOT)}: block {name}" for name, text in rendered.items()
             for page, body in found[name] if body.rstrip("\n") != text.rstrip("\n")]
    assert not stale, (f"quoted numbers differ from what the code gives: {stale}; run "
                       f".venv/bin/python tools/docs_numbers.py --only {generator} and commit")


def test_every_block_belongs_to_a_generator_and_every_generated_block_is_quoted():
    found = dn.page_blocks()
    generated = {b for g in dn.GENERATORS for b in g.blocks}
    assert set(found) == generated, (set(found) ^ generated)
    for page in dn.PAGES:               # markers come in pairs: nothing half-marked
        text = page.read_text()
        opening = re.findall(r"^<!-- numbers:[\w-]+ -->$", text, re.M)
        closing = re.findall(r"^<!-- /numbers -->$", text, re.M)
        assert len(opening) == len(closing) == len(dn.blocks(text)), page.name


def test_the_quick_start_numbers_are_what_make_run_prints():
    assert_quoted(dn.render_quickstart(), "quickstart")


@pytest.mark.parametrize("gen", [g for g in dn.GENERATORS if g.studies], ids=lambda g: g.name)
def test_the_monte_carlo_numbers_are_rendered_from_the_stored_rows(gen):
    assert_quoted(dn.stored(gen), gen.name)


def test_a_quoted_interval_is_the_t_interval_of_the_stored_rows():
    """The fused row of docs/consensus.md's table, recomputed here with scipy from the CSV."""
    rows = dn.read_rows(dn.CONSENSUS.path)
    mse = np.array([r["mse"] for r in rows if r["estimate"] == "fused" and r["component"] == "position"])
    assert mse.size == dn.CONSENSUS.runs
    half = student_t.ppf(0.975, mse.size - 1) * mse.std(ddof=1) / math.sqrt(mse.size)
    expected = f"| fused | {mse.mean():.4g} [{mse.mean() - half:.4g}, {mse.mean() + half:.4g}] |"
    assert expected in (ROOT / "docs" / "consensus.md").read_text()


@pytest.mark.slow
@pytest.mark.parametrize("study", STUDIES, ids=lambda s: s.name)
def test_the_stored_rows_are_what_the_code_computes(study):
    """Runs 0 and 1 of each study, computed alone (run r is the same run whatever --runs),
    equal the stored rows; the store holds every run of the study."""
    stored = dn.read_rows(study.path)
    assert sorted({r["run"] for r in stored}) == list(range(study.runs))
    runs = getattr(study, "spot_runs", dn.SPOT_RUNS)       # (a radio study: run 0 of one or two points)
    key = lambda r: (r["run"], r["estimate"], r["component"])  # noqa: E731
    old = {key(r): r for r in stored if r["run"] in runs}
    new = {key(r): r for r in study.spot(runs)}
    assert set(old) == set(new)
    for k, row in new.items():
        radio = [c for c in ("cbr", "pdr_300", *dn.TRAFFIC_COLUMNS) if c in study.columns]
        for col in ("mse", "anees", "messages_per_tick", "late", *radio):
            assert np.isclose(row[col], old[k][col], rtol=1e-9, atol=0, equal_nan=True), (k, col)


@pytest.mark.slow
def test_the_radar_numbers_are_what_the_experiment_gives():
    assert_quoted(dn.render_radar(), "radar")


def assert_block(name: str, text: str) -> None:
    """The block ``name`` of the docs is ``text`` (for a test that computed its numbers itself)."""
    found = dn.page_blocks()[name]
    assert found and all(body.rstrip("\n") == text.rstrip("\n") for _, body in found), (
        f"docs block {name} differs from what this test computed; run .venv/bin/python "
        "tools/docs_numbers.py --only radio_validation and commit")

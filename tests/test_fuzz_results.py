"""Every mutant of a result folder or sweep database is read cleanly: plot, report, load_run.

Hypothesis draws mutants from the enumeration of tools/fuzz_results.py (the one place it is
defined; the tool is loaded by path) and asserts its contract: each reading command succeeds
or ends in a DkfsimError with a one-paragraph message, within the time limit and the memory
cap of a worker process.  ``python tools/fuzz_results.py`` checks a larger sample at once.
"""

from __future__ import annotations

import importlib.util
import sys
from datetime import timedelta
from pathlib import Path

import pytest
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st

TOOLS = Path(__file__).resolve().parents[1] / "tools"


def _load(name: str):
    loaded = sys.modules.get(name)     # (tests/test_fuzz_scenarios.py may have loaded it)
    if loaded is not None and Path(loaded.__file__).resolve() == TOOLS / f"{name}.py":
        return loaded
    spec = importlib.util.spec_from_file_location(name, TOOLS / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


sys.path.insert(0, str(TOOLS))
fuzz = _load("fuzz_results")

COMMON = dict(deadline=timedelta(seconds=60), derandomize=True, database=None,
              phases=(Phase.explicit, Phase.generate), suppress_health_check=[HealthCheck.too_slow])
#: Drawn from the whole enumeration, made at the first draw (building the bases takes seconds,
#: which collecting the suite should not pay).
MUTANTS = st.deferred(lambda: st.sampled_from(fuzz.enumerate_mutants()))


@pytest.fixture(scope="module")
def checker():
    with fuzz.ResultChecker(jobs=1, timeout=120) as checker:      # (wall time: a shared machine)
        yield checker


def assert_contract(checker, spec) -> None:
    outcome = checker.check(spec)
    if not outcome.acceptable:
        pytest.fail(outcome.report(), pytrace=False)


@pytest.mark.parametrize("base", fuzz.BASES)
def test_the_bases_read_cleanly(checker, base):
    """Each base, unmutated, is plotted, reported and loaded (else every mutant would fail), opening
    nothing outside itself and its output (one test per base: the workers share them)."""
    outcome = checker.check(fuzz.ResultMutant(base, (fuzz.base_files(base)[0],), "none"))
    assert outcome.cls == "ran" and outcome.acceptable, outcome.report()


@pytest.mark.parametrize("spec", [
    fuzz.ResultMutant("run", ("run.npz", "truth"), "as_object"),
    fuzz.ResultMutant("run", ("summary.json", "rows"), "deep_list_1000"),
    fuzz.ResultMutant("mc", ("curves.npz", "components"), "rename_mathtext"),
    fuzz.ResultMutant("sweep", ("s.sqlite", "results", "estimate"), "set_5MB_text"),
    fuzz.ResultMutant("sweep", ("s.sqlite", "definition"), "json_nested_1000"),
    fuzz.ResultMutant("mobility", ("summary.json",), "stored_track_canary"),
    fuzz.ResultMutant("sweep_channel", ("s.sqlite", "scenario_json"), "stored_fcd_fifo"),
    fuzz.ResultMutant("channel", ("rows.csv",), "names_escape"),
    fuzz.ResultMutant("centre", ("summary.json", "traffic", "fusion_centre", "per_link"), "'x'"),
], ids=lambda s: s.label)
def test_known_hostile_mutants(checker, spec):
    assert spec in fuzz.enumerate_mutants((spec.scenario,))
    assert_contract(checker, spec)


@settings(max_examples=6, **COMMON)
@given(spec=MUTANTS)
def test_a_mutant_is_read_cleanly(checker, spec):
    assert_contract(checker, spec)


@pytest.mark.slow
@settings(max_examples=16, **COMMON)     # (tools/fuzz_results.py checks a larger sample at once)
@given(spec=MUTANTS)
def test_many_mutants_are_read_cleanly(checker, spec):
    assert_contract(checker, spec)

"""Every mutant of a shipped scenario fails with a clean error or runs.

Hypothesis draws a shipped scenario, a key path in it and a mutation from
the vocabulary of tools/fuzz_scenarios.py (the one place it is defined; the
tool is loaded by path) and asserts the contract stated there: validation
raises a DkfsimError with a one-paragraph message, or a short run
(tools/fuzz_scenarios.RUN_STEPS steps) ends normally or with such an error,
within the time limit.  Each mutant runs in a worker process with a time
limit and a memory cap, so a hang or a huge allocation fails one example
instead of stalling or exhausting the test run.

A failure reports the mutant and the traceback; ``python
tools/fuzz_scenarios.py`` lists every finding of the whole vocabulary at once.

Settings: deterministic (``derandomize``, no example database); no shrink
phase, as a mutant drawn from finite lists has nothing smaller worth the
time (a timed-out example costs the whole time limit per shrink step).
"""

from __future__ import annotations

import importlib.util
import sys
from datetime import timedelta
from pathlib import Path

import pytest
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st

import dkfsim

#: The slow tier (`make test-fast` leaves it out): fuzzing.
pytestmark = pytest.mark.slow


def _load_fuzzer():
    """tools/fuzz_scenarios.py, imported by path (tools/ is not a package)."""
    path = Path(__file__).resolve().parents[1] / "tools" / "fuzz_scenarios.py"
    loaded = sys.modules.get("fuzz_scenarios")     # (tools/fuzz_results.py imports it too)
    if loaded is not None and Path(loaded.__file__).resolve() == path:
        return loaded      # one module object: its classes must pickle by name across workers
    spec = importlib.util.spec_from_file_location("fuzz_scenarios", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module    # dataclasses and unpickling look the module up by name
    spec.loader.exec_module(module)
    return module


fuzz = _load_fuzzer()

COMMON = dict(deadline=timedelta(seconds=20), derandomize=True, database=None,
              phases=(Phase.explicit, Phase.generate), suppress_health_check=[HealthCheck.too_slow])


@st.composite
def mutants(draw):
    """A shipped scenario, a key path in its base, and a mutation that applies there."""
    name = draw(st.sampled_from(fuzz.base_names()))
    path = draw(st.sampled_from(fuzz.mutation_paths(name)))
    mutation = draw(st.sampled_from(fuzz.mutations_at(name, path)))
    return fuzz.MutantSpec(name, path, mutation.name)


@pytest.fixture(scope="module")
def checker():
    with fuzz.MutantChecker(jobs=1, timeout=fuzz.DEFAULT_TIMEOUT) as checker:
        yield checker


def assert_contract(checker, spec) -> None:
    outcome = checker.check(spec)
    if not outcome.acceptable:
        pytest.fail(outcome.report(), pytrace=False)


@pytest.mark.parametrize("name", fuzz.base_names())
def test_every_base_scenario_runs(name):
    """The bases the mutants start from are valid and run (else every mutant would be an error)."""
    base = fuzz.base(name)
    assert base["steps"] == fuzz.RUN_STEPS
    dkfsim.run(dkfsim.load_scenario(base), save="summary")


@pytest.mark.parametrize("spec", [
    fuzz.MutantSpec("rate_links", (), "traffic_background_1e9"),
    fuzz.MutantSpec("rate_links", (), "traffic_override_twice"),
    fuzz.MutantSpec("channel_its_g5", (), "medium_queue_bytes_1"),
    fuzz.MutantSpec("mobility_crossing", (), "mobility_vehicle_key_twice"),
    fuzz.MutantSpec("fcd_mobility", ("mobility", "vehicles", "default", "file"), "fcd_coords_1e308"),
    fuzz.MutantSpec("fcd_mobility", ("mobility", "vehicles", "default", "file"), "file_fifo"),
    fuzz.MutantSpec("fcd_mobility", ("mobility", "vehicles", "1", "file"), "file_canary"),
    fuzz.MutantSpec("centre_links", (), "centre_name_10000"),
], ids=lambda s: s.label)
def test_known_hostile_mutants_of_the_new_surfaces(checker, spec):
    """One mutant per surface of issue 30 (each a finding before it): clean, in seconds, opening
    nothing but its inputs."""
    assert spec in fuzz.enumerate_mutants([spec.scenario])
    assert_contract(checker, spec)


@settings(max_examples=60, **COMMON)
@given(spec=mutants())
def test_a_mutant_fails_cleanly_or_runs(checker, spec):
    assert_contract(checker, spec)


@pytest.mark.slow
@settings(max_examples=400, **COMMON)
@given(spec=mutants())
def test_many_mutants_fail_cleanly_or_run(checker, spec):
    assert_contract(checker, spec)

"""The hostile tests' resource bounds measure the child, not the process that started it: a
memory bound that counted the pytest worker's resident size would pass or fail with the worker."""

from __future__ import annotations

import pytest
from hostile_kit import dkfsim_cli

ALLOCATE_300_MB = """
import sys
block = bytearray(300 * 2**20)
block[::4096] = b"x" * len(block[::4096])
sys.exit(0)
"""


def test_the_childs_own_peak_is_measured():
    assert dkfsim_cli(python=ALLOCATE_300_MB).ok(memory_mb=1000) == ""
    assert dkfsim_cli(python=ALLOCATE_300_MB).maxrss_mb >= 300


def test_the_parents_memory_is_not_counted():
    held = bytearray(600 * 2**20)
    held[::4096] = b"x" * len(held[::4096])      # resident, not only reserved
    child = dkfsim_cli("validate", "no-such-file.yaml")
    assert child.returncode == 2
    assert child.maxrss_mb < 300, f"{child.maxrss_mb:.0f} MB: the parent's {len(held) >> 20} MB counted"


def _allocate_300_mb() -> None:
    block = bytearray(300 * 2**20)
    block[::4096] = b"x" * len(block[::4096])
    _KEPT.append(block)                          # (alive until the child exits)


_KEPT: list[bytearray] = []


def test_a_forked_childs_growth_is_measured(monkeypatch):
    """A forked child (the default) counts what it allocates, not the test process it copies."""
    monkeypatch.delenv("DKFSIM_TEST_FORK", raising=False)       # (forked, whatever the run chose)
    child = dkfsim_cli("validate", "no-such-file.yaml", preexec=_allocate_300_mb)
    assert not child.fresh and child.returncode == 2 and "Traceback" not in child.stderr, child
    assert child.maxrss_mb >= 300, child.maxrss_mb
    assert dkfsim_cli("validate", "no-such-file.yaml").maxrss_mb < 300


def test_a_forked_child_refuses_a_memory_bound_tighter_than_the_default(monkeypatch):
    monkeypatch.delenv("DKFSIM_TEST_FORK", raising=False)
    child = dkfsim_cli("validate", "no-such-file.yaml")
    with pytest.raises(AssertionError, match="fresh=True"):
        child.clean_error("no-such-file.yaml", memory_mb=400)
    dkfsim_cli("validate", "no-such-file.yaml", fresh=True).clean_error("no-such-file.yaml", memory_mb=400)

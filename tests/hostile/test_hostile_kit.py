"""The hostile tests' resource bounds measure the child, not the process that started it: a
memory bound that counted the pytest worker's resident size would pass or fail with the worker."""

from __future__ import annotations

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

"""The holdings: what each node holds for the rows of the window, and the sums of it.

The independent truth is the definition, evaluated with plain Python floats in the order the
contributions were reported: ``Omega_i[r] = sum a_io omega_o`` and ``Theta_i[r] = sum a_io
theta_o[r]`` over the origins ``o`` node ``i`` gained for row ``r``.  Both folds (numpy, and
numba's, which the compiled tree's kernels also run) must give exactly those numbers: the
order of the additions is the order of the reports, origins ascending within one.
"""

from __future__ import annotations

import numpy as np
import pytest

from dkfsim.core.backend import Backend
from dkfsim.model.holdings import NO_ROW, Holdings
from dkfsim.model.system import Information


def _info(rng, K, n, nx, varying):
    omega = rng.normal(size=(K, n, nx, nx) if varying else (n, nx, nx))
    return Information(theta=rng.normal(size=(K, n, nx)), omega=omega, factor=np.zeros((nx, 1)),
                       column_sensor=np.zeros(1, dtype=np.intp))


def _reports(rng, n_nodes, n_origins, rows, count):
    """``count`` reports (node, origin mask, row), each mask new to its node and row."""
    held: dict[tuple[int, int], int] = {}
    out = []
    while len(out) < count:
        node, row = int(rng.integers(n_nodes)), int(rng.choice(rows))
        free = [o for o in range(n_origins) if not (held.get((node, row), 0) >> o) & 1]
        if not free:
            continue
        mask = 0
        for o in rng.choice(free, size=int(rng.integers(1, min(3, len(free)) + 1)), replace=False):
            mask |= 1 << int(o)
        held[(node, row)] = held.get((node, row), 0) | mask
        out.append((node, mask, row))
    return out


@pytest.mark.parametrize("kernels", ["numpy", "numba"])
@pytest.mark.parametrize("varying", [False, True])
@pytest.mark.parametrize("bulk", [False, True])
def test_the_folds_add_the_definition_in_the_reported_order(kernels, varying, bulk):
    """``bulk``: the reports alternate, in runs of 7, between :meth:`Holdings.add` and
    :meth:`Holdings.add_held` (flags, folded at once after what ``add`` left pending)."""
    rng = np.random.default_rng(4)
    K, n, nx, L = 12, 70, 2, 4                          # 70 origins: masks of two words
    info = _info(rng, K, n, nx, varying)
    A = rng.uniform(0.5, 1.5, size=(5, n))              # 5 nodes, weights per origin
    h = Holdings(info, A, L, backend=Backend(kernels))
    assert h.S == L + 1
    rows = [6, 7, 8, 9]
    for r in rows:
        h.open_row(r)
    reports = _reports(rng, 5, n, rows, 60)
    for start in range(0, len(reports), 7):
        run = reports[start:start + 7]
        if bulk and start % 14:
            flags = np.array([[(mask >> o) & 1 for o in range(n)] for _, mask, _ in run], dtype=bool)
            h.add_held(np.array([r[0] for r in run]), np.array([r[2] for r in run]), flags)
        else:
            for node, mask, row in run:
                h.add(node, mask, row)
    Omega = np.zeros_like(h.Omega)
    Theta = np.zeros_like(h.Theta)
    held = np.zeros_like(h.held)
    first = np.full(5, NO_ROW)
    for node, mask, row in reports:
        s = row % h.S
        for o in range(n):
            if (mask >> o) & 1:
                om = info.omega[row, o] if varying else info.omega[o]
                for p in range(nx):
                    for q in range(nx):
                        Omega[s, node, p, q] = float(Omega[s, node, p, q]) + float(A[node, o]) * float(om[p, q])
                    Theta[s, node, p] = float(Theta[s, node, p]) + float(A[node, o]) * float(info.theta[row, o, p])
                held[s, node, o] = True
        first[node] = min(first[node], row)
    starts = h.take_changes()
    assert np.array_equal(starts, first)
    assert np.array_equal(h.Omega, Omega) and np.array_equal(h.Theta, Theta)      # bit for bit
    assert np.array_equal(h.held, held)
    assert h.take_changes() is None                      # nothing new since


def test_opening_a_row_clears_its_slot_only():
    rng = np.random.default_rng(1)
    info = _info(rng, 10, 3, 2, False)
    h = Holdings(info, np.ones((3, 3)), 2, backend=Backend("numpy"))
    h.add(0, 0b011, 4)
    h.add(1, 0b100, 5)
    h.take_changes()
    h.open_row(7)                                        # slot 7 % 3 = 1: row 4's
    assert not h.held[1].any() and not h.Omega[1].any() and not h.Theta[1].any()
    assert h.held[2, 1, 2] and h.Theta[2].any()          # row 5 kept


def test_without_origin_flags_the_sums_are_the_same():
    rng = np.random.default_rng(2)
    info = _info(rng, 8, 4, 2, False)
    a, b = (Holdings(info, np.ones((4, 4)), 3, per_origin=flags, backend=Backend("numba")) for flags in (True, False))
    for h in (a, b):
        h.add(2, 0b1011, 5)
        h.add(0, 0b0100, 6)
        h.take_changes()
    assert b.held.shape == (4, 4, 0)
    assert np.array_equal(a.Omega, b.Omega) and np.array_equal(a.Theta, b.Theta)

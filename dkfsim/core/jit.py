"""The generic part of dkfsim's compiled kernels: which path runs, and compiling a module's
kernels lazily, once, under a lock.

Kernels live in the layer that uses them (:mod:`dkfsim.estimators.kernels` for the window
filter, the contribution fold and the cross-covariance recursion,
:mod:`dkfsim.protocols.tree_compiled_kernels` for the compiled ``tree`` protocol's instants:
deliveries, flushes and keyed latency draws); this module only holds what they share, low enough in the layers
for both.  See docs/design.md §4 ("Kernel paths").
"""

from __future__ import annotations

import importlib.util
import os
import sys
import threading

from dkfsim.core.extras import optional

#: Environment variable that selects the kernel path: ``numba`` (default) or ``numpy``.
KERNELS_ENV = "DKFSIM_KERNELS"


def kernel_path() -> str:
    """``"numba"`` or ``"numpy"``: the path the filters of a run started now will use.

    Checks that numba is installed without importing it: commands that never
    filter (validation, ``list``, ``--help``) do not pay numba's import.
    """
    want = os.environ.get(KERNELS_ENV, "").strip().lower()
    if want == "numpy" or importlib.util.find_spec("numba") is None:
        return "numpy"
    return "numba"


class LazyKernels:
    """The functions ``names`` of module ``module``, replaced by their ``numba.njit(cache=True)``
    versions (no fastmath, no parallel, nogil) on the first :meth:`get`.

    ``names`` lists callees before callers: numba resolves a callee by its module global; those
    also in ``inline`` are inlined into their callers by numba (``inline="always"``: a small
    step a kernel calls per node or packet costs no call).  Runs in threads (a Dask worker
    with threads, a notebook) may call :meth:`get` together: one compiles, under a lock, and
    none jits an already jitted function.
    """

    def __init__(self, module: str, names: tuple[str, ...], inline: tuple[str, ...] = ()):
        self.module = module
        self.names = tuple(names)
        self.inline = frozenset(inline)
        self._done = False
        self._lock = threading.Lock()

    def get(self):
        """The module, its kernels compiled (loaded from numba's disk cache or compiled)."""
        if not self._done:
            with self._lock:
                if not self._done:
                    numba = optional("numba")
                    mod = sys.modules[self.module]
                    for name in self.names:
                        inline = "always" if name in self.inline else "never"
                        setattr(mod, name, numba.njit(cache=True, fastmath=False, nogil=True,
                                                      inline=inline)(getattr(mod, name)))
                    self._done = True
        return sys.modules[self.module]


def entry_point(kernel, *args):
    """``kernel`` (a numba dispatcher) called once with ``args``, then the compiled function of
    exactly those argument types: calling it skips numba's per-call type dispatch (about half
    of a small kernel's call cost).  Only for arguments of the same types (array dtype, rank and
    layout) on every call; any other function is returned as it is."""
    kernel(*args)
    overloads = getattr(kernel, "overloads", None)
    if overloads is None:
        return kernel
    sig = tuple(kernel.typeof_pyval(a) for a in args)
    compiled = overloads.get(sig)
    return kernel if compiled is None else compiled.entry_point

"""The generic part of dkfsim's compiled kernels: which path the environment asks for, and
compiling a module's kernels lazily, once, under a lock.

Kernels live in the layer that uses them (:mod:`dkfsim.estimators.kernels` for the window
filter and the cross-covariance recursion, :mod:`dkfsim.model.holdings_kernels` for the
contribution fold, :mod:`dkfsim.network.port_kernels` for a record port's batches,
:mod:`dkfsim.protocols.tree_kernels` for the ``tree`` protocol's bookkeeping); this module only
holds what they share, low enough in the layers for all.  A run's path is decided once, by its
:class:`~dkfsim.core.backend.Backend` (which reads :func:`kernel_path`).  See docs/design.md §4
("Kernel paths").
"""

from __future__ import annotations

import importlib.util
import os
import sys
import threading
from typing import Any

from dkfsim.core.errors import DkfsimError
from dkfsim.core.extras import optional
from dkfsim.core.files import clip

#: Environment variable that selects the kernel path: ``numba`` (default) or ``numpy``.
KERNELS_ENV = "DKFSIM_KERNELS"


def kernel_path() -> str:
    """``"numba"`` or ``"numpy"``: the path the filters of a run started now will use.

    Checks that numba is installed without importing it: commands that never
    filter (validation, ``list``, ``--help``) do not pay numba's import.
    """
    want = os.environ.get(KERNELS_ENV, "").strip().lower()
    if want not in ("", "numba", "numpy"):
        raise DkfsimError(f"{KERNELS_ENV}={clip(os.environ[KERNELS_ENV])}: not a known value; use numba "
                          "(the default: compiled kernels) or numpy (the pure-numpy path)")
    if want == "numpy" or importlib.util.find_spec("numba") is None:
        return "numpy"
    return "numba"


def import_numba():
    """numba, imported; a :class:`DkfsimError` (not a traceback) when its import fails on a bad
    setting of its own (``NUMBA_NUM_THREADS=0``, a malformed ``NUMBA_*`` variable)."""
    try:
        numba = optional("numba")
    except DkfsimError:
        raise
    except Exception as exc:  # noqa: BLE001  (numba validates its environment at import)
        bad = ", ".join(f"{k}={clip(v, 20)}" for k, v in sorted(os.environ.items()) if k.startswith("NUMBA_"))
        raise DkfsimError(f"numba cannot start ({type(exc).__name__}: {clip(str(exc), 120)})"
                          + (f"; check {bad}" if bad else "") + f", or set {KERNELS_ENV}=numpy") from None
    _tolerate_cache_write_errors(optional("numba.core.caching"))
    _listen_for_compiles(numba)
    return numba


class _CacheGuard:
    """Whether numba's cache writes are guarded yet, and whether the warning was printed."""

    installed = False
    warned = False


def _tolerate_cache_write_errors(caching) -> None:
    """A kernel cache that cannot be written (a full disk, a file-size limit, a read-only
    folder found late) is not an error: the kernel was compiled in memory and is used as it
    is; one warning on stderr says the next process compiles again."""
    cls = getattr(caching, "Cache", None)
    save = getattr(cls, "save_overload", None)
    if _CacheGuard.installed or cls is None or save is None:
        return

    def save_overload(self, sig, data):
        try:
            return save(self, sig, data)
        except OSError as exc:
            if not _CacheGuard.warned:
                _CacheGuard.warned = True
                print(f"dkfsim: warning: cannot write numba's kernel cache ({exc.strerror or exc}); "
                      "the kernels are compiled in memory, and compiled again by the next process",
                      file=sys.stderr)
            return None

    cls.save_overload = save_overload
    _CacheGuard.installed = True


#: CPU seconds numba takes to compile each kernel module's kernels (measured on this project's
#: 2-core machine; the first run on a machine pays them once, later ones load the disk cache).
COMPILE_SECONDS = {"dkfsim.estimators.kernels": 15, "dkfsim.model.holdings_kernels": 3,
                   "dkfsim.protocols.tree_kernels": 8, "dkfsim.network.port_kernels": 6,
                   "dkfsim.network.radio_kernels": 8}


class _Compiling:
    """Whether this process said yet that it compiles dkfsim's kernels (once), and the kernel
    modules imported so far (their :class:`LazyKernels`)."""

    said = False
    listening = False
    lazy: list = []


def _index_paths(dispatchers) -> list[str]:
    """Where numba's disk cache keeps the index of each of ``dispatchers`` (njit with
    ``cache=True``); none from a numba that does not say."""
    found = [getattr(getattr(getattr(d, "_cache", None), "_cache_file", None), "_index_path", None)
             for d in dispatchers]
    return [p for p in found if isinstance(p, str)]


def cache_is_cold(dispatchers) -> bool:
    """True when numba's disk cache holds no index for any of ``dispatchers``: a module never
    compiled on this machine, whose first calls compile.  (One kernel a short run never called
    has no index either: that alone is not a cold cache.  A numba that does not say where its
    index is says nothing: False.)"""
    paths = _index_paths(dispatchers)
    return bool(paths) and not any(os.path.exists(p) for p in paths)


def uncached_share(dispatchers) -> float:
    """The share of ``dispatchers`` numba's disk cache holds no index for: what a process calling
    every one would still compile (0 from a numba that does not say)."""
    paths = _index_paths(dispatchers)
    return sum(not os.path.exists(p) for p in paths) / len(paths) if paths else 0.0


def _listen_for_compiles(numba) -> None:
    """Say :func:`say_compiling` at numba's first compile of one of dkfsim's kernels in this
    process (the ``numba:compile`` event: a real compile, not a load from the disk cache)."""
    event = optional("numba.core.event")
    if _Compiling.listening or not hasattr(event, "Listener") or not hasattr(event, "register"):
        return
    listener: Any = event.Listener      # numba's base class: mypy cannot check it (no type information)

    class _OnCompile(listener):
        def on_start(self, ev):
            func = getattr(getattr(ev, "data", {}).get("dispatcher"), "py_func", None)
            if str(getattr(func, "__module__", "")).startswith("dkfsim."):
                say_compiling(numba)

        def on_end(self, ev):
            pass

    event.register("numba:compile", _OnCompile())
    _Compiling.listening = True


def say_compiling(numba) -> None:
    """Once per process, one line on stderr: dkfsim's kernels are compiled now, once, and about
    how long that takes (the kernel modules imported so far that were never compiled here)."""
    if _Compiling.said:
        return
    _Compiling.said = True
    # (each module's share of kernels not compiled yet: a short run compiles only those it calls,
    # and a run of other estimators after it compiles the rest, which counting cold modules only
    # left out: "about 8 s" before 36 s of compiling)
    seconds = sum(COMPILE_SECONDS.get(lazy.module, 5) * lazy.uncached(numba) for lazy in _Compiling.lazy)
    try:
        print(f"dkfsim: compiling dkfsim's kernels once (about {max(round(seconds), 1)} s of CPU; later runs "
              "load them from numba's disk cache)", file=sys.stderr, flush=True)
    except (OSError, ValueError):
        pass


class LazyKernels:
    """The functions ``names`` of module ``module``, replaced by their ``numba.njit(cache=True)``
    versions (no fastmath, no parallel, nogil) on the first :meth:`get`.

    ``names`` lists callees before callers: numba resolves a callee by its module global; those
    also in ``inline`` are inlined into their callers by numba (``inline="always"``: a small
    step a kernel calls per node or packet costs no call).  Runs in threads (a Dask worker
    with threads, a notebook) may call :meth:`get` together: one compiles, under a lock, and
    none jits an already jitted function.  numba's disk cache keys a kernel by its own file,
    so a kernel module calls no other file's kernels (``tests/test_kernels.py`` checks it):
    what two of them share goes through Python.
    """

    def __init__(self, module: str, names: tuple[str, ...], inline: tuple[str, ...] = ()):
        self.module = module
        self.names = tuple(names)
        self.inline = frozenset(inline)
        self._done = False
        self._lock = threading.Lock()
        _Compiling.lazy.append(self)

    def get(self):
        """The module, its kernels compiled (loaded from numba's disk cache or compiled)."""
        if not self._done:
            with self._lock:
                if not self._done:
                    numba = import_numba()
                    mod = sys.modules[self.module]
                    for name in self.names:
                        inline = "always" if name in self.inline else "never"
                        setattr(mod, name, numba.njit(cache=True, fastmath=False, nogil=True,
                                                      inline=inline)(getattr(mod, name)))
                    self._done = True
        return sys.modules[self.module]

    def _probes(self, numba) -> list:
        """This module's kernels as dispatchers (probes made without compiling; none when the
        module is not imported)."""
        mod = sys.modules.get(self.module)
        funcs = [getattr(mod, name, None) for name in self.names if name not in self.inline] \
            if mod is not None else []
        return [f if hasattr(f, "py_func") else numba.njit(cache=True)(f) for f in funcs if callable(f)]

    def cold(self, numba) -> bool:
        """Whether numba's disk cache holds none of this module's kernels (:func:`cache_is_cold`;
        False when the module is not imported)."""
        return cache_is_cold(self._probes(numba))

    def uncached(self, numba) -> float:
        """The share of this module's kernels numba's disk cache does not hold
        (:func:`uncached_share`; 0 when the module is not imported)."""
        return uncached_share(self._probes(numba))


def kernels_cached(modules: tuple[str, ...]) -> bool:
    """Whether numba's disk cache holds the kernels of every kernel module of ``modules``
    (their :class:`LazyKernels`; each imported now): the first calls of a process load them
    in well under a second instead of compiling them (:func:`cache_is_cold`).  Imports numba."""
    numba = import_numba()
    for name in modules:
        importlib.import_module(name)
        lazy = next((k for k in _Compiling.lazy if k.module == name), None)
        if lazy is None or lazy.cold(numba):
            return False
    return True


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


def bind(kernel, *args):
    """The compiled function of ``kernel`` (a numba dispatcher) for the types of ``args``,
    compiled (or loaded from the disk cache) now without calling it: calling it skips numba's
    per-call type dispatch, which for a kernel taking namedtuples of arrays costs more than
    the work of a small call.  Only for arguments of the same types (array dtype, rank and
    layout) on every call; a function that is not a dispatcher (the numpy path) is returned as
    it is."""
    typeof = getattr(kernel, "typeof_pyval", None)
    if typeof is None:
        return kernel
    sig = tuple(typeof(a) for a in args)
    kernel.compile(sig)
    return kernel.overloads[sig].entry_point

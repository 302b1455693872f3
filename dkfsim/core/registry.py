"""Registries: the named components a scenario can ask for, declared once.

Each family (graph generators, latency models, protocols, estimators,
sensor kinds, metrics) is a :class:`Registry` that implementations register
into.  An entry carries the name a scenario uses, a one-line description,
its parameter model (a pydantic class: the schema of its keys, with
defaults) and its implementation.  The scenario schema looks components up
here when it validates a file, so ``dkfsim.config`` never imports the
stages that implement them, and a component added by a plugin is valid in
every scenario key, every command and ``dkfsim list`` at once.

The built-in components register when the modules of :data:`BUILTIN_MODULES` are imported:
at the first registry read, so that a command that reads no registry (``dkfsim --help``)
never imports the stages that implement them (docs/decisions.md, "Start-up").

Plugins: the entry-point groups ``dkfsim.plugins`` and ``dkfsim.estimators``
(modules imported at the first registry read, after the built-ins) and a scenario's
``plugins:`` key (modules or ``.py`` files imported before the scenario is validated).
Importing a plugin runs its code: that is what a plugin is for.
"""

from __future__ import annotations

import hashlib
import importlib
import importlib.util
import re
import sys
import threading
from dataclasses import dataclass
from importlib.metadata import entry_points
from os import PathLike
from pathlib import Path
from typing import Any, Callable, Iterator

from dkfsim.core.errors import DkfsimError
from dkfsim.core.files import clip
from dkfsim.core.params import suggest


@dataclass
class Entry:
    """One registered component."""

    name: str
    description: str = ""
    params: type | None = None          # pydantic model of its scenario keys
    implementation: Any = None          # class or function that does the work


def _first_line(obj: Any) -> str:
    """The first sentence of ``obj``'s docstring, on one line (a sentence may wrap: cutting at the
    line's end left ``dkfsim list`` saying "a frame that finds the medium idle and no")."""
    doc = (getattr(obj, "__doc__", None) or "").strip()
    paragraph = " ".join(line.strip() for line in doc.split("\n\n")[0].splitlines())
    end = re.search(r"(?<!e\.g)(?<!i\.e)\.(\s|$)", paragraph)
    return (paragraph[:end.start()] if end else paragraph).replace("``", "")


class Registry:
    """Named components of one family, in registration order."""

    def __init__(self, family: str, key: str, where: str | None = None):
        #: What a member is called in messages ("latency model").
        self.family = family
        #: The scenario key that names a member (``model``, ``kind``, ``generator``).
        self.key = key
        #: Where a scenario names one (``dkfsim list``; default: its key).
        self.where = where or f"scenario key {key}:"
        self._entries: dict[str, Entry] = {}
        self._aliases: dict[str, str] = {}

    # -- registering ---------------------------------------------------------
    def add(self, name: str, *, params: type | None = None, implementation: Any = None,
            description: str | None = None, aliases: tuple[str, ...] = ()) -> Entry:
        """Add (or complete) entry ``name``: the parameter model and the implementation may
        be registered by different modules (the first at the bottom layer, the second
        in the stage that runs it)."""
        entry = self._entries.get(name)
        if entry is None:
            entry = self._entries[name] = Entry(name)
        if params is not None:
            if entry.params is not None and entry.params is not params:
                raise ValueError(f"{self.family} {name!r}: parameters registered twice")
            entry.params = params
        if implementation is not None:
            if entry.implementation is not None and entry.implementation is not implementation:
                raise ValueError(f"{self.family} {name!r}: implementation registered twice")
            entry.implementation = implementation
        if description is not None:
            entry.description = description
        elif not entry.description:
            entry.description = _first_line(implementation) or _first_line(params)
        for alias in aliases:
            self._aliases[alias] = name
        return entry

    def register(self, name: str | None = None, **kw: Any) -> Callable[[type], type]:
        """Class decorator: ``@REGISTRY.register("name", params=...)`` registers the
        decorated class as the implementation (and as the parameter model when it is
        one: a class with ``model_fields``)."""
        def deco(cls: type) -> type:
            key = name or cls.__name__
            if hasattr(cls, "model_fields") and "params" not in kw:
                self.add(key, params=cls, implementation=kw.get("implementation", cls),
                         description=kw.get("description"), aliases=kw.get("aliases", ()))
            else:
                self.add(key, implementation=cls, **kw)
            return cls
        return deco

    # -- reading ---------------------------------------------------------------
    def canonical(self, name: str) -> str:
        """The registered name of ``name`` (itself, or what it is an alias of)."""
        ensure_registered()
        return self._aliases.get(name, name)

    def get(self, name: Any) -> Entry:
        """The entry named ``name`` (or an alias); :class:`KeyError` with the message
        "unknown <family> 'x' (did you mean 'y'?); valid: ..." when there is none."""
        ensure_registered()
        key = self.canonical(name) if isinstance(name, str) else name
        entry = self._entries.get(key) if isinstance(key, str) else None
        if entry is None:
            raise KeyError(self.unknown(name))
        return entry

    def unknown(self, name: Any) -> str:
        """The message for a name that is not registered, with the closest one."""
        names = self.names()
        return f"unknown {self.family} {clip(name)}{suggest(name, names)}; valid: " + ", ".join(names)

    def __contains__(self, name: object) -> bool:
        ensure_registered()
        return isinstance(name, str) and self.canonical(name) in self._entries

    def names(self) -> list[str]:
        ensure_registered()
        return list(self._entries)

    def entries(self) -> Iterator[Entry]:
        ensure_registered()
        return iter(list(self._entries.values()))

    def aliases(self) -> dict[str, str]:
        ensure_registered()
        return dict(self._aliases)


#: Every family, by the word ``dkfsim list`` uses.
GENERATORS = Registry("graph generator", "generator")
LATENCY_MODELS = Registry("latency model", "model")
PROTOCOLS = Registry("protocol", "protocol")
ESTIMATORS = Registry("estimator", "kind")
SENSOR_KINDS = Registry("sensor kind", "kind")
METRICS = Registry("metric", "metric")
#: How a vehicle moves (issue 23): ``components/trajectories.py``.
TRAJECTORIES = Registry("trajectory kind", "kind")
#: How a frame leaves its sender (issue 31): ``network/media/`` -- a link without a rate
#: (``direct``), with one (``fifo``), and the shared channel's access rules (``csma``; a
#: scenario names one as ``medium.access.kind``).
MEDIA = Registry("medium", "kind", where="a link without a rate is direct, with one fifo; a shared channel's "
                 "access rule is medium.access.kind:")
REGISTRIES: dict[str, Registry] = {
    "generators": GENERATORS, "latency": LATENCY_MODELS, "protocols": PROTOCOLS,
    "estimators": ESTIMATORS, "sensors": SENSOR_KINDS, "metrics": METRICS,
    "trajectories": TRAJECTORIES, "media": MEDIA,
}

#: Entry-point groups whose modules are imported as plugins: ``dkfsim.plugins``
#: (any component) and ``dkfsim.estimators`` (the name an estimator package may
#: expect); both are the same mechanism.
PLUGIN_GROUPS = ("dkfsim.plugins", "dkfsim.estimators")

#: The modules whose import registers the built-in components, imported by name at the first
#: registry read (:func:`ensure_registered`).  Names, not imports: the stages above ``core``
#: register into it, it never depends on them (tests/test_layers.py checks the names).
BUILTIN_MODULES = ("dkfsim.components", "dkfsim.model", "dkfsim.protocols", "dkfsim.estimators",
                   "dkfsim.analysis.metrics")
#: "no" until the first registry read, "loading" while the built-ins and plugins are imported
#: (a read then sees what is registered so far: a module reading a registry as it registers
#: does not recurse), "done" after.
_STATE = "no"
_LOCK = threading.RLock()


def ensure_registered() -> None:
    """Register every built-in component (import the modules of :data:`BUILTIN_MODULES`), then
    import the entry-point plugins (:func:`load_entry_point_plugins`): once per process, at the
    first registry read.  Threads that read together wait for the one that loads."""
    global _STATE
    if _STATE == "done":
        return
    with _LOCK:
        if _STATE != "no":           # done meanwhile, or this thread is loading (a read while registering)
            return
        _STATE = "loading"
        try:
            for module in BUILTIN_MODULES:
                importlib.import_module(module)
            load_entry_point_plugins()
        except BaseException:
            _STATE = "no"
            raise
        _STATE = "done"


def load_entry_point_plugins() -> None:
    """Import the modules of the :data:`PLUGIN_GROUPS` entry-point groups (what
    :func:`ensure_registered` does once the built-ins are registered).  A plugin that fails to
    import is reported on stderr (once) and left out; dkfsim itself keeps working."""
    for ep in (ep for group in PLUGIN_GROUPS for ep in entry_points(group=group)):
        try:
            ep.load()
        except Exception as exc:  # noqa: BLE001  (a broken plugin must not break dkfsim)
            print(f"dkfsim: plugin {ep.name!r} ({ep.value}) failed to load: {exc}", file=sys.stderr)


def load_plugin(spec: str, base_dir: str | PathLike | None = None) -> None:
    """Import a plugin: a module name (``my_pkg.my_estimator``) or a ``.py`` file
    (relative paths resolve against ``base_dir``).  Raises :class:`DkfsimError`."""
    if spec.endswith(".py"):
        path = Path(spec)
        if not path.is_absolute() and base_dir is not None:
            path = Path(base_dir) / path
        if not path.is_file():
            raise DkfsimError(f"plugin file not found: {path}")
        name = "dkfsim_plugin_" + hashlib.sha1(str(path.resolve()).encode()).hexdigest()[:16]
        if name in sys.modules:
            return
        module_spec = importlib.util.spec_from_file_location(name, path)
        if module_spec is None or module_spec.loader is None:
            raise DkfsimError(f"plugin {path} cannot be imported (not a Python file?)")
        module = importlib.util.module_from_spec(module_spec)
        sys.modules[name] = module
        try:
            module_spec.loader.exec_module(module)
        except Exception as exc:
            del sys.modules[name]
            raise DkfsimError(f"plugin {path} failed to load: {type(exc).__name__}: {exc}") from None
        return
    try:
        importlib.import_module(spec)
    except ImportError as exc:
        raise DkfsimError(f"plugin module {spec!r} cannot be imported: {exc}") from None

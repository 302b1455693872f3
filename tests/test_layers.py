"""The package's architecture is enforced, not just described.

* the layering contract of pyproject.toml (import-linter): a stage imports
  only from the stages before it (core, components, config, model, network,
  protocols, estimators, analysis, engine, experiments, report, cli);
* no import cycles between modules, inside a stage or across;
* no import statement inside a function, but the heavy third-party modules listed in
  :data:`LAZY_IMPORTS` where they are listed (start-up: docs/decisions.md, "Start-up");
  optional heavy packages go through the one seam, :mod:`dkfsim.core.extras`;
* what ``dkfsim --help``, ``dkfsim list`` and ``import dkfsim`` import: none of the heavy
  packages (:func:`test_start_up_imports_only_what_the_command_needs`);
* no module reads or writes another module's private attributes (``obj._name`` where
  ``_name`` is not the module's own, or ``from m import _name``; ``self._x``/``cls._x``
  inside a class, namedtuple's ``_replace``/``_asdict``/``_fields`` and ``os._exit`` are
  fine);
* every stage is in docs/architecture.md's table and every module says what it is for.
"""

from __future__ import annotations

import ast
import re
import subprocess
import sys
from pathlib import Path

import grimp
import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "dkfsim"
STAGES = ["core", "components", "config", "model", "network", "protocols", "estimators", "analysis",
          "engine", "experiments", "report", "cli"]


def test_the_layering_contract_holds():
    lint = Path(sys.executable).parent / "lint-imports"
    p = subprocess.run([str(lint)], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stdout[-3000:] + p.stderr[-2000:]
    assert "1 kept, 0 broken" in p.stdout


def test_the_contract_lists_every_stage_and_the_stages_are_the_folders():
    text = (ROOT / "pyproject.toml").read_text()
    layers = [line.strip().strip('",') for line in text.split("layers = [", 1)[1].split("]", 1)[0].splitlines()
              if line.strip()]
    assert layers == [f"dkfsim.{s}" for s in reversed(STAGES)]
    folders = sorted(p.name for p in PACKAGE.iterdir() if (p / "__init__.py").exists())
    assert folders == sorted(STAGES)


def test_no_import_cycles():
    graph = grimp.build_graph("dkfsim")
    modules = sorted(m for m in graph.modules if m != "dkfsim")
    for m in modules:
        for imported in graph.find_modules_directly_imported_by(m):
            if imported == "dkfsim" or imported == m:
                continue
            chain = graph.find_shortest_chain(importer=imported, imported=m)
            assert chain is None, f"import cycle: {m} -> {' -> '.join(chain)}"


#: The only imports inside functions: (module, imported module) -> why it is not at the top.  Each
#: defers a heavy third-party package (scipy's submodules, networkx: 0.1-0.2 s each) from the
#: modules every command imports -- the registered components, read by ``dkfsim list`` and the
#: schema -- to the functions that compute with it (docs/decisions.md, "Start-up").  dkfsim's own
#: modules are never imported lazily: the layering contract sees every import at the top.
LAZY_IMPORTS = {
    ("dkfsim/analysis/metrics.py", "scipy.special"): "t and chi-square quantiles: intervals over runs",
    ("dkfsim/components/latency.py", "scipy.special"): "lognormal and gamma quantiles: their draws",
    ("dkfsim/components/radio.py", "scipy.special"): "normal and gamma quantiles: shadowing and fading draws",
    ("dkfsim/components/mobility.py", "scipy.sparse.csgraph"): "a changing graph's connectivity",
    ("dkfsim/components/topology.py", "networkx"): "building and measuring a scenario's graph",
    ("dkfsim/core/linalg.py", "scipy.linalg.lapack"): "the fusion's LAPACK solves",
    ("dkfsim/estimators/fusion_centre.py", "networkx"): "a fusion centre's routes",
    ("dkfsim/estimators/rounds.py", "scipy.sparse"): "the consensus family's combination matrices",
    ("dkfsim/model/system.py", "scipy.linalg"): "a sensor's Cholesky factors at a run's set-up",
}


def function_imports(source: str) -> list[tuple[int, str]]:
    """``(line, imported module)`` of every import statement inside a function of ``source``."""
    found: set[tuple[int, str]] = set()
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            for sub in ast.walk(node):
                if isinstance(sub, ast.Import):
                    found |= {(sub.lineno, a.name) for a in sub.names}
                elif isinstance(sub, ast.ImportFrom):
                    found.add((sub.lineno, "." * sub.level + (sub.module or "")))
    return sorted(found)


def test_the_function_import_check_finds_what_it_must():
    planted = """
import os
def f():
    import networkx as nx
    from scipy.special import ndtri
    def g():
        from . import sibling
    return nx, ndtri
"""
    assert function_imports(planted) == [(4, "networkx"), (5, "scipy.special"), (7, ".")]


def test_no_import_inside_a_function_but_the_listed_lazy_ones():
    found, used = [], set()
    for path in sorted(PACKAGE.rglob("*.py")):
        rel = str(path.relative_to(ROOT))
        for line, module in function_imports(path.read_text()):
            if (rel, module) in LAZY_IMPORTS:
                used.add((rel, module))
            else:
                found.append(f"{rel}:{line} ({module})")
    assert not found, ("imports inside functions (use dkfsim.core.extras for optional packages; a heavy "
                       "core dependency deferred for start-up belongs in LAZY_IMPORTS): " + ", ".join(found))
    assert not set(LAZY_IMPORTS) - used, f"LAZY_IMPORTS lists imports that are gone: {set(LAZY_IMPORTS) - used}"


#: Heavy packages a command that computes nothing must not import: what made ``dkfsim --help``
#: take seconds (issue 34).  matplotlib, numba, dask, pandas are extras or compile-time only.
HEAVY = ("scipy", "networkx", "numba", "matplotlib", "distributed", "pandas", "xarray", "tqdm")


#: ``dkfsim ARGV`` in this interpreter, its output swallowed.
COMMAND = """import contextlib, io
from dkfsim.cli.main import main
with contextlib.redirect_stdout(io.StringIO()), contextlib.suppress(SystemExit):
    assert main({argv!r}) == 0
"""


def _imported_by(code: str) -> set[str]:
    """The top-level packages of :data:`HEAVY` a fresh interpreter has imported after ``code``."""
    probe = code + "\nimport sys\nprint(' '.join(sorted({m.split('.')[0] for m in sys.modules})))"
    p = subprocess.run([sys.executable, "-c", probe], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr[-2000:]
    return set(p.stdout.split()) & set(HEAVY)


@pytest.mark.parametrize("what, code, allowed", [
    ("import dkfsim", "import dkfsim", ()),
    ("dkfsim --help", COMMAND.format(argv=["--help"]), ()),
    ("dkfsim list", COMMAND.format(argv=["list"]), ()),
    ("dkfsim validate", COMMAND.format(argv=["validate", "scenarios/paper_case1.yaml"]), ("networkx",)),
])
def test_start_up_imports_only_what_the_command_needs(what, code, allowed):
    """Start-up (issue 34): a command imports only the packages its work needs -- none of the
    heavy ones for ``import dkfsim``, ``--help`` and ``list``; the graph library for ``validate``.
    (Seconds are measured by ``tools/bench.py --startup``, never here.)"""
    assert _imported_by(code) == set(allowed), what


@pytest.mark.parametrize("stage", STAGES)
def test_every_stage_is_in_the_architecture_table(stage):
    assert f"| `{stage}/`" in (ROOT / "docs" / "architecture.md").read_text()


def _listed_modules(cell: str) -> set[str]:
    """The modules a row of the architecture table lists: ``name`` for a module of the stage,
    ``sub/`` then ``(a, b)`` for a subpackage and its modules (``sub/a``, ``sub/b``); a
    parenthesis after a module is a remark."""
    out: set[str] = set()
    sub = None
    depth = 0
    for m in re.finditer(r"\(|\)|`([^`]+)`", cell):
        token = m.group(0)
        if token == "(":
            depth += 1
        elif token == ")":
            depth -= 1
            if depth == 0:
                sub = None
        elif depth == 0:
            name = m.group(1)
            if name.endswith("/"):
                sub = name.rstrip("/")
                out.add(name)
            else:
                sub = None
                out.add(name)
        elif sub is not None and depth == 1:
            out.add(f"{sub}/{m.group(1)}")
    return out


@pytest.mark.parametrize("stage", STAGES)
def test_the_architecture_table_lists_each_stages_modules(stage):
    """docs/architecture.md's module list of each stage is the stage's folder: every module (and
    every subpackage with its modules), nothing more."""
    rows = [line for line in (ROOT / "docs" / "architecture.md").read_text().splitlines()
            if line.startswith(f"| `{stage}/`")]
    assert len(rows) == 1, rows
    listed = _listed_modules(rows[0].split("|")[3])
    folder = PACKAGE / stage
    actual = {p.stem for p in folder.glob("*.py") if p.stem != "__init__"}
    for sub in (d for d in folder.iterdir() if (d / "__init__.py").exists()):
        actual.add(sub.name + "/")
        actual |= {f"{sub.name}/{p.stem}" for p in sub.glob("*.py") if p.stem != "__init__"}
    assert listed == actual, f"listed only: {sorted(listed - actual)}; in the folder only: {sorted(actual - listed)}"


def test_every_module_says_what_it_is_for():
    missing = [str(p.relative_to(ROOT)) for p in sorted(PACKAGE.rglob("*.py"))
               if not ast.get_docstring(ast.parse(p.read_text()))]
    assert not missing, missing


#: Private names any module may use on another module's objects: namedtuple's API.
NAMEDTUPLE_API = {"_replace", "_asdict", "_fields"}


def _private(name: str) -> bool:
    return name.startswith("_") and not (name.startswith("__") and name.endswith("__"))


def _own_names(tree: ast.AST) -> set[str]:
    """The names a module defines itself: functions, classes, assigned names (module, class or
    local), and attributes it assigns on ``self`` or ``cls``."""
    own = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            own.add(node.name)
        elif isinstance(node, ast.Name) and isinstance(node.ctx, ast.Store):
            own.add(node.id)
        elif isinstance(node, ast.alias):
            own.add((node.asname or node.name).split(".")[0])
        elif (isinstance(node, ast.Attribute) and isinstance(node.ctx, ast.Store)
              and isinstance(node.value, ast.Name) and node.value.id in ("self", "cls")):
            own.add(node.attr)
    return own


def private_uses(source: str) -> list[str]:
    """``line: code`` of each use, in ``source``, of another module's private attribute:
    ``obj._name`` (read or written) whose ``_name`` the module does not define itself, unless
    ``obj`` is ``self`` or ``cls`` (a class's own), ``_name`` is namedtuple API or it is
    ``os._exit``; and ``from m import _name``.  (That a name the module defines is its own is
    the test's reading of "another module's": an attribute this module never defines can only
    be another module's.)"""
    tree = ast.parse(source)
    own = _own_names(tree)
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.level == 0:
            found += [f"{node.lineno}: from {node.module} import {a.name}" for a in node.names if _private(a.name)]
        elif isinstance(node, ast.Attribute) and _private(node.attr) and node.attr not in NAMEDTUPLE_API:
            base = node.value
            if isinstance(base, ast.Name) and (base.id in ("self", "cls") or (base.id, node.attr) == ("os", "_exit")):
                continue
            if node.attr not in own:
                found.append(f"{node.lineno}: {ast.unparse(node)}")
    return found


def test_the_private_attribute_check_finds_what_it_must():
    """The check on planted uses: each violation found, each allowed use left alone."""
    planted = """
import os
from dkfsim.report.plots.style import _save
from dkfsim.estimators import window
class Mine:
    def __init__(self, port, w):
        self._own = 1
        port._count["sent"] = 3
        w._k.xi_rows()
        self._log = None
    def f(self, other, row):
        other._own += 1
        window._EYES.clear()
        os._exit(0)
        return row._replace(a=1), row._asdict(), row._fields, self._missing, cls_call(Mine._own)
"""
    found = private_uses(planted)
    assert found == ["3: from dkfsim.report.plots.style import _save", "8: port._count", "9: w._k",
                     "13: window._EYES"], found


def test_no_module_touches_another_modules_private_attributes():
    found = []
    for path in sorted(PACKAGE.rglob("*.py")):
        found += [f"{path.relative_to(ROOT)}:{use}" for use in private_uses(path.read_text())]
    assert not found, "private attributes of other modules used (make them public, or add an interface):\n" + \
        "\n".join(found)


def test_the_first_registry_read_registers_every_built_in_component():
    """The registries load :data:`~dkfsim.core.registry.BUILTIN_MODULES` at their first read: what
    they then hold is what importing every module of the package registers (a module that
    registers a component but is missing from the list would be seen by some commands only)."""
    probe = """
import importlib, pkgutil
import dkfsim
from dkfsim.core import registry
def snapshot():
    return {f: sorted(r.names()) for f, r in registry.REGISTRIES.items()}
first = snapshot()
for m in pkgutil.walk_packages(dkfsim.__path__, "dkfsim."):
    if m.name != "dkfsim.__main__":
        importlib.import_module(m.name)
assert snapshot() == first, (first, snapshot())
assert all(first.values()), first
print("ok")
"""
    p = subprocess.run([sys.executable, "-c", probe], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert p.returncode == 0 and p.stdout.strip() == "ok", p.stderr[-3000:]

"""The package's architecture is enforced, not just described.

* the layering contract of pyproject.toml (import-linter): a stage imports
  only from the stages before it (core, components, config, model, network,
  protocols, estimators, analysis, engine, experiments, report, cli);
* no import cycles between modules, inside a stage or across;
* no import statement inside a function anywhere in the package: optional
  heavy packages go through the one seam, :mod:`dkfsim.core.extras`;
* every stage is in docs/architecture.md's table and every module says what it is for.
"""

from __future__ import annotations

import ast
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


def test_no_import_inside_a_function():
    found = []
    for path in sorted(PACKAGE.rglob("*.py")):
        tree = ast.parse(path.read_text())
        for node in ast.walk(tree):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                found += [f"{path.relative_to(ROOT)}:{sub.lineno}" for sub in ast.walk(node)
                          if isinstance(sub, (ast.Import, ast.ImportFrom))]
    assert not found, "imports inside functions (use dkfsim.core.extras for optional packages): " + ", ".join(found)


@pytest.mark.parametrize("stage", STAGES)
def test_every_stage_is_in_the_architecture_table(stage):
    assert f"| `{stage}/`" in (ROOT / "docs" / "architecture.md").read_text()


def test_every_module_says_what_it_is_for():
    missing = [str(p.relative_to(ROOT)) for p in sorted(PACKAGE.rglob("*.py"))
               if not ast.get_docstring(ast.parse(p.read_text()))]
    assert not missing, missing

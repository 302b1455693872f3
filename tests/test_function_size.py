"""No function in ``dkfsim/`` is longer than 120 lines (issue 19, "kernels a reader can follow").

Lines from the first decorator to the last line of the body, docstring and comments included,
found by walking each module's syntax tree (nested functions count on their own and inside
their parent).
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
LIMIT = 120
#: Functions allowed to be longer (none since the sweep file became a schema, issue 19).
EXEMPT: set[tuple[str, str]] = set()


def function_lengths() -> list[tuple[int, str, str]]:
    """``(lines, file, name)`` of every function and method in the package."""
    out = []
    for path in sorted((ROOT / "dkfsim").rglob("*.py")):
        rel = path.relative_to(ROOT).as_posix()
        for node in ast.walk(ast.parse(path.read_text(), filename=rel)):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                start = min([node.lineno] + [d.lineno for d in node.decorator_list])
                out.append((node.end_lineno - start + 1, rel, node.name))
    return out


def test_no_function_is_longer_than_120_lines():
    lengths = function_lengths()
    assert len(lengths) > 500                  # the walk found the package
    long = [f"{rel}: {name} ({n} lines)" for n, rel, name in lengths if n > LIMIT and (rel, name) not in EXEMPT]
    assert not long, "functions over 120 lines:\n" + "\n".join(long)

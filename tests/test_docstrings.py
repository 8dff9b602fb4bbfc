"""Every public definition is documented: module-level functions and classes, and the public
methods of public classes, in facegeom/, baselines/ and viewer/ (array shapes go in the docstrings)."""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
FILES = sorted(p for pkg in ("facegeom", "baselines", "viewer") for p in (ROOT / pkg).rglob("*.py"))


def undocumented(tree: ast.Module) -> list[str]:
    """Names of public definitions without a docstring (``Class.method`` for methods)."""
    out = []

    def visit(body, prefix):
        for node in body:
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)) and not node.name.startswith("_"):
                if ast.get_docstring(node) is None:
                    out.append(f"{prefix}{node.name} (line {node.lineno})")
                if isinstance(node, ast.ClassDef):
                    visit(node.body, f"{node.name}.")

    visit(tree.body, "")
    return out


@pytest.mark.parametrize("path", FILES, ids=lambda p: str(p.relative_to(ROOT)))
def test_public_definitions_have_docstrings(path):
    tree = ast.parse(path.read_text(encoding="utf-8"))
    if path.name != "__main__.py":
        assert ast.get_docstring(tree), "module docstring missing"
    assert not undocumented(tree), undocumented(tree)


def test_the_check_finds_a_missing_docstring():
    tree = ast.parse('"""m"""\ndef f():\n    pass\nclass C:\n    """c"""\n    def g(self):\n        pass\n'
                     "    def _h(self):\n        pass\n")
    assert undocumented(tree) == ["f (line 2)", "C.g (line 6)"]

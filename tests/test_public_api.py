"""Tests, benchmarks and examples use the project through its public API only.

Every ``.py`` file under ``tests/``, ``benchmarks/`` and ``examples/`` is
parsed; an attribute access ``obj._name`` (not a dunder) is a private member
unless ``_name`` is the file's own: a function or class it defines, an
attribute it assigns on ``self``, or a module-level name. Importing a private
name from ``sqpmpc`` or ``services``, and naming one in ``getattr``,
``setattr``, ``hasattr`` or ``monkeypatch.setattr``, count too.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
FOLDERS = ("tests", "benchmarks", "examples")
PROJECT = ("sqpmpc", "services")
BY_NAME = {"getattr", "setattr", "hasattr", "delattr"}


def _private(name: str) -> bool:
    return name.startswith("_") and not (name.startswith("__") and name.endswith("__"))


def _own_names(tree: ast.Module) -> set[str]:
    """Names the file defines itself (its helpers may be private)."""
    own: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
            own.add(node.name)
        elif isinstance(node, ast.Attribute) and isinstance(node.ctx, ast.Store) and (
                isinstance(node.value, ast.Name) and node.value.id in ("self", "cls")):
            own.add(node.attr)
    for node in tree.body:
        targets = node.targets if isinstance(node, ast.Assign) else (
            [node.target] if isinstance(node, ast.AnnAssign) else [])
        own.update(t.id for t in targets if isinstance(t, ast.Name))
    return own


def private_uses(path: Path) -> list[str]:
    """``file:line: what`` for every private member of another module ``path`` reaches."""
    tree = ast.parse(path.read_text(), str(path))
    own = _own_names(tree)
    where = path.relative_to(ROOT)
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and _private(node.attr) and node.attr not in own:
            found.append(f"{where}:{node.lineno}: .{node.attr}")
        elif isinstance(node, ast.ImportFrom) and (node.module or "").split(".")[0] in PROJECT:
            found += [f"{where}:{node.lineno}: import {a.name}" for a in node.names
                      if _private(a.name)]
        elif isinstance(node, ast.Call) and len(node.args) >= 2:  # getattr(obj, "_x")
            fn = node.func
            name = fn.id if isinstance(fn, ast.Name) else (
                fn.attr if isinstance(fn, ast.Attribute) else "")
            arg = node.args[1]
            if name in BY_NAME and isinstance(arg, ast.Constant) and isinstance(
                    arg.value, str) and _private(arg.value) and arg.value not in own:
                found.append(f"{where}:{node.lineno}: {name}(..., {arg.value!r})")
    return found


def _files() -> list[Path]:
    return sorted(p for folder in FOLDERS for p in (ROOT / folder).rglob("*.py"))


@pytest.mark.parametrize("path", _files(), ids=lambda p: str(p.relative_to(ROOT)))
def test_no_private_member_is_reached(path: Path) -> None:
    assert private_uses(path) == []


def test_the_check_finds_what_it_looks_for() -> None:
    """A private member of another object, a private import and a private name by string
    are found; the file's own helpers and dunders are not."""
    probe = ROOT / "tests" / "_probe_private_use.py"
    probe.write_text(
        "from sqpmpc.control import _hidden\n"
        "def _helper(ctrl, monkeypatch):\n"
        "    ctrl._predict_neighbours(0)\n"
        "    monkeypatch.setattr(ctrl, '_flag', 1)\n"
        "    return ctrl.__class__, _helper\n"
        "class Mine:\n"
        "    def __init__(self):\n"
        "        self._own = 1\n"
        "    def use(self):\n"
        "        return self._own\n")
    try:
        found = private_uses(probe)
    finally:
        probe.unlink()
    assert sorted(f.split(": ", 1)[1] for f in found) == sorted(
        ["import _hidden", "._predict_neighbours", "setattr(..., '_flag')"])

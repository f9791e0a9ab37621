"""The package's architecture: layered subpackages, imports only downwards, no cycle.

Every import counts: module level, inside functions, under ``TYPE_CHECKING``,
relative or absolute. The layers, bottom to top (``docs/engine.md``):

====  ============  ========================================================
0     base          :mod:`sqpmpc.errors`, :mod:`sqpmpc.version`, the built-in scenario files
1     kernels       compiled kernels (numba)
2     models        robot models (state, input, dynamics, Jacobians, footprint)
3     problem       scenarios, references, obstacles, plant specification, fleets
4     coordination  the roadmap, conflict-free plans (LaCAM), their delay-tolerant schedule
5     qp            layout, sparse QP, backends
6     ocp           the RTI/SQP iteration and the rows it linearizes
7     rules         the plug-ins of the pipeline (coordination, liveness) and their registry
8     control       settings, pipeline, controllers, plans
9     sim           run buffer, in-process closed loop
10    io            metrics, files, recording, plots, animation, run log
11    cli           the ``sqpmpc`` command and its options
12    facade        ``sqpmpc`` itself (the public names, loaded lazily)
13    services      the distributed processes
====  ============  ========================================================

A module imports from its own package and from lower layers only.
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
LAYERS = ("base", "kernels", "models", "problem", "coordination", "qp", "ocp", "rules",
          "control", "sim", "io", "cli", "facade", "services")
BASE_MODULES = ("sqpmpc.errors", "sqpmpc.version", "sqpmpc.scenarios")


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def _modules() -> dict[str, Path]:
    found = {}
    for top in ("sqpmpc", "services"):
        for path in sorted((ROOT / top).rglob("*.py")):
            found[_module_name(path)] = path
    return found


MODULES = _modules()


def _is_package(name: str) -> bool:
    return MODULES[name].name == "__init__.py"


def _resolve(name: str) -> str | None:
    """The project module ``name`` refers to (a name inside a module: that module)."""
    while name:
        if name in MODULES:
            return name
        name = name.rpartition(".")[0]
    return None


def imports_of(name: str) -> set[str]:
    """Every project module ``name`` imports, in any way."""
    tree = ast.parse(MODULES[name].read_text())
    package = name if _is_package(name) else name.rpartition(".")[0]
    found: set[str] = set()
    for node in ast.walk(tree):
        targets: list[str] = []
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[:len(base) - (node.level - 1)]
                prefix = ".".join(base + ([node.module] if node.module else []))
            else:
                prefix = node.module or ""
            # "from pkg import name": the submodule pkg.name if there is one, else pkg
            targets = [f"{prefix}.{a.name}" if f"{prefix}.{a.name}" in MODULES else prefix
                       for a in node.names]
        for target in targets:
            resolved = _resolve(target)
            if resolved is not None and resolved != name:
                found.add(resolved)
    return found


def layer_of(name: str) -> int:
    if name in BASE_MODULES or name.startswith("sqpmpc.scenarios"):
        return LAYERS.index("base")
    if name.startswith("services"):
        return LAYERS.index("services")
    parts = name.split(".")
    if len(parts) == 1 or parts[1] == "__main__":
        return LAYERS.index("facade")
    if parts[1] not in LAYERS:
        raise AssertionError(f"module {name} is in no layer: add its package to LAYERS")
    return LAYERS.index(parts[1])


def _package_of(name: str) -> str:
    return ".".join(name.split(".")[:2])


def test_every_import_goes_down_or_stays_in_its_package() -> None:
    bad = []
    for name in MODULES:
        mine = layer_of(name)
        for other in sorted(imports_of(name)):
            theirs = layer_of(other)
            same_package = _package_of(other) == _package_of(name)
            if theirs > mine or (theirs == mine and not same_package
                                 and LAYERS[mine] not in ("base", "services")):
                bad.append(f"{name} ({LAYERS[mine]}) imports {other} ({LAYERS[theirs]})")
    assert not bad, "imports against the layers:\n" + "\n".join(bad)


def _cycles() -> list[list[str]]:
    graph = {name: sorted(imports_of(name)) for name in MODULES}
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    components: list[list[str]] = []
    counter = [0]

    def visit(v: str) -> None:  # Tarjan's strongly connected components
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on_stack.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                components.append(sorted(component))

    for v in graph:
        if v not in index:
            visit(v)
    return components


def test_no_import_cycle() -> None:
    assert _cycles() == []


def test_layers_are_packages() -> None:
    packages = {name.split(".")[1] for name in MODULES
                if name.startswith("sqpmpc.") and _is_package(name)} - {"scenarios"}
    assert len(packages) >= 5
    assert packages <= set(LAYERS), packages - set(LAYERS)


def test_the_checker_sees_every_kind_of_import(tmp_path: Path) -> None:
    """The walker counts imports inside functions and under TYPE_CHECKING too."""
    assert "sqpmpc.control.settings" in imports_of("sqpmpc.control.pipeline")
    source = MODULES["sqpmpc"].read_text()
    assert "TYPE_CHECKING" in source
    assert "sqpmpc.control.centralized" in imports_of("sqpmpc")

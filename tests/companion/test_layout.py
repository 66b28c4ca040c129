"""The import graph of ``vehicle/`` and ``companion/``, read with ``ast`` (imports inside functions included):
no cycle between modules, and no package importing one of a higher layer (docs/code-layout.md).

A layer may import its own package and the layers below it, never a sibling on its own level or one above.
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

LAYERS: dict[str, int] = {
    # vehicle: the MAVLink side, usable without the app
    "vehicle": 0, "vehicle.errors": 0, "vehicle.settings": 0,
    "vehicle.protocol": 1, "vehicle.link": 2, "vehicle.autopilot": 3, "vehicle.camera": 4, "vehicle.sim": 5,
    # companion: the app, above the whole of vehicle
    "companion": 10, "companion.errors": 11, "companion.packaged": 11, "companion.atomic_write": 11,
    "companion.config": 12, "companion.output_path": 12,
    "companion.sources": 20,
    "companion.vision": 30,
    "companion.storage": 40,
    "companion.evaluation": 50,
    "companion.export": 55,
    "companion.live": 60, "companion.topside": 60, "companion.archive": 60,
    "companion.extension": 65,
    "companion.bench": 70,
    "companion.commands": 80,
    "companion.cli": 90, "companion.__main__": 91,
}


def module_files() -> dict[str, Path]:
    found = {}
    for package in ("vehicle", "companion"):
        for path in (ROOT / package).rglob("*.py"):
            parts = list(path.relative_to(ROOT).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts.pop()
            found[".".join(parts)] = path
    return found


def imports_of(name: str, path: Path, known: dict[str, Path]) -> set[str]:
    """The project modules ``name`` imports anywhere in its file (``from x import y`` counts x.y when a module)."""
    is_package = path.name == "__init__.py"
    out: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            targets = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = name.split(".")[: len(name.split(".")) - node.level + (1 if is_package else 0)]
                prefix = ".".join(base + ([node.module] if node.module else []))
            else:
                prefix = node.module or ""
            targets = [prefix] + [f"{prefix}.{alias.name}" for alias in node.names]
        else:
            continue
        out.update(t for t in targets if t in known and t != name)
    return out


def graph() -> dict[str, set[str]]:
    known = module_files()
    return {name: imports_of(name, path, known) for name, path in known.items()}


def area(module: str) -> str:
    """The layer a module belongs to: its own entry when it has one (companion.config), else its package."""
    parts = module.split(".")
    for n in range(min(len(parts), 2), 0, -1):
        if ".".join(parts[:n]) in LAYERS:
            return ".".join(parts[:n])
    raise AssertionError(f"{module}: not in any layer of tests/companion/test_layout.py (add its package)")


def cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan's algorithm, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []
    counter = 0
    for root in sorted(edges):
        if root in index:
            continue
        work = [(root, iter(sorted(edges[root])))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on_stack.add(root)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = counter
                    counter += 1
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(edges[child]))))
                elif child in on_stack:
                    low[node] = min(low[node], index[child])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                component = []
                while True:
                    top = stack.pop()
                    on_stack.discard(top)
                    component.append(top)
                    if top == node:
                        break
                if len(component) > 1:
                    found.append(sorted(component))
    return found


def test_the_graph_is_read_whole() -> None:
    edges = graph()
    assert len(edges) > 150
    # an import inside a function counts: a command imports what it runs only when it runs
    assert "companion.live.runner" in edges["companion.commands.run"]
    assert "companion.live.control.params" in edges["companion.live.companion"]


def test_no_import_cycle() -> None:
    assert cycles(graph()) == []


def test_the_cycle_finder_finds_one() -> None:
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]


def test_no_module_imports_a_higher_or_sibling_layer() -> None:
    upward = sorted(f"{module} -> {target}" for module, targets in graph().items() for target in targets
                    if area(module) != area(target) and LAYERS[area(target)] >= LAYERS[area(module)])
    assert upward == []


def test_every_package_has_a_layer() -> None:
    assert {area(module) for module in graph()} <= set(LAYERS)

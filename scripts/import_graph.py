#!/usr/bin/env python3
"""Print the import graph between the project's packages, or its layers, and any cycles.

Standard library only, so anyone can run it:

    python3 scripts/import_graph.py            # packages (backend.api, worker.pipeline ...)
    python3 scripts/import_graph.py --layers   # the layers of docs/architecture.md + rules
    python3 scripts/import_graph.py --modules  # cycles between single modules

A package is a directory with an __init__.py three levels deep at most; every import, also
one inside a function or under TYPE_CHECKING, counts. `--layers` maps every module to its
layer (LAYERS below), prints the graph between layers, and each import that breaks a rule
(ALLOWED); it exits 1 on a cycle between layers or a broken rule (tests/test_architecture.py
runs it).
"""

from __future__ import annotations

import argparse
import ast
import sys
from collections import defaultdict
from pathlib import Path

ROOTS = ("backend", "worker")

# Module prefix -> layer; the longest matching prefix wins (see docs/architecture.md).
LAYERS = {
    "worker.pipeline": "library",
    "worker.reports": "library",
    "worker.simulator": "simulation",
    "worker.pairgen": "simulation",
    "worker.training": "training",
    "worker.detection_bench": "training",
    "worker.commands": "cli",
    "backend.cli": "composition",
    "backend.wiring": "composition",
    "worker.tasks": "composition",
    "worker.tasks_monitoring": "composition",
    "worker.tasks_tiles": "composition",
    "backend": "domain",
    "backend.db": "domain",
    "worker.jobs": "jobs",
    "worker.celery_app": "jobs",
    "worker.dispatch": "jobs",
    "backend.services": "services",
    "backend.api": "api",
    "backend.api.app": "composition",
}
# Which layers each layer may import (besides itself). Composition roots may import all.
ALLOWED = {
    "library": set(),
    "simulation": {"library"},
    "training": {"library", "simulation"},
    "cli": {"library", "simulation", "training"},
    "domain": {"library"},
    "jobs": {"domain", "library", "training"},
    "services": {"domain", "library", "jobs", "simulation"},
    "api": {"services", "domain", "library", "jobs"},
    "composition": {
        "library",
        "simulation",
        "training",
        "cli",
        "domain",
        "jobs",
        "services",
        "api",
    },
}
# Modules of the job layer that other layers may import: its one narrow interface.
JOBS_INTERFACE = ("worker.jobs.control", "worker.celery_app")


def packages(root: Path) -> list[str]:
    """Dotted names of the packages (depth <= 3) under the project roots."""
    found = []
    for top in ROOTS:
        for init in sorted((root / top).rglob("__init__.py")):
            parts = init.parent.relative_to(root).parts
            if len(parts) <= 3:
                found.append(".".join(parts))
    return found


def owner(module: str, known: list[str]) -> str | None:
    """The deepest known package that holds `module`."""
    roots = [p for p, layer in LAYERS.items() if layer == "composition"]
    root = next((p for p in roots if module == p or module.startswith(p + ".")), None)
    if root:
        return root  # a composition root imports everything: its own node
    inside = [p for p in known if module == p or module.startswith(p + ".")]
    return max(inside, key=len, default=None)


def module_name(root: Path, path: Path) -> str:
    parts = list(path.relative_to(root).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def imported_modules(path: Path, module: str) -> list[tuple[str, int]]:
    tree = ast.parse(path.read_text(), filename=str(path))
    is_package = path.name == "__init__.py"
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found += [(alias.name, node.lineno) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = module.split(".")
                base = base[: len(base) - node.level + (1 if is_package else 0)]
                name = ".".join(base + ([node.module] if node.module else []))
            else:
                name = node.module or ""
            found.append((name, node.lineno))
            found += [(f"{name}.{alias.name}", node.lineno) for alias in node.names]
    return found


def package_graph(root: Path) -> dict[str, dict[str, list[str]]]:
    """{package: {imported package: ["file:line", ...]}} over packages of the project."""
    known = packages(root)
    graph: dict[str, dict[str, list[str]]] = defaultdict(lambda: defaultdict(list))
    for top in ROOTS:
        for path in sorted((root / top).rglob("*.py")):
            module = module_name(root, path)
            source = owner(module, known)
            if source is None:
                continue
            seen = set()
            for name, line in imported_modules(path, module):
                target = owner(name, known) if name.split(".")[0] in ROOTS else None
                if target is None or target == source or (target, path) in seen:
                    continue
                seen.add((target, path))
                graph[source][target].append(f"{path.relative_to(root)}:{line}")
    return graph


def cycles(graph: dict[str, dict[str, list[str]]]) -> list[list[str]]:
    """Strongly connected components with more than one package (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for nxt in graph.get(node, {}):
            if nxt not in index:
                visit(nxt)
                low[node] = min(low[node], low[nxt])
            elif nxt in on_stack:
                low[node] = min(low[node], index[nxt])
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

    for node in sorted(set(graph) | {t for edges in graph.values() for t in edges}):
        if node not in index:
            visit(node)
    return found


def layer_of(module: str) -> str | None:
    inside = [p for p in LAYERS if module == p or module.startswith(p + ".")]
    best = max(inside, key=len, default=None)
    return LAYERS[best] if best else None


def layer_graph(root: Path) -> tuple[dict[str, set[str]], list[str]]:
    """({layer: layers it imports}, ["file:line: rule broken", ...])."""
    graph: dict[str, set[str]] = defaultdict(set)
    broken: dict[str, str] = {}  # one per importing line
    for top in ROOTS:
        for path in sorted((root / top).rglob("*.py")):
            module = module_name(root, path)
            source = layer_of(module)
            for name, line in imported_modules(path, module):
                target = layer_of(name)
                if source is None or target is None or target == source:
                    continue
                graph[source].add(target)
                where = f"{path.relative_to(root)}:{line}"
                if where in broken:
                    continue
                if target not in ALLOWED[source]:
                    broken[where] = f"{where}: {source} imports {target} ({name})"
                elif (
                    target == "jobs"
                    and source in ("services", "api")
                    and name not in ("worker.jobs", "worker")
                    and not any(name == m or name.startswith(m + ".") for m in JOBS_INTERFACE)
                ):
                    broken[where] = (
                        f"{where}: {source} imports {name}, not the job layer's "
                        f"interface ({', '.join(JOBS_INTERFACE)})"
                    )
    return graph, sorted(broken.values())


def module_graph(root: Path) -> dict[str, dict[str, list[str]]]:
    """{module: {imported module of the project: ["file:line", ...]}}."""
    modules = {
        module_name(root, path): path for top in ROOTS for path in (root / top).rglob("*.py")
    }
    graph: dict[str, dict[str, list[str]]] = defaultdict(lambda: defaultdict(list))
    for module, path in modules.items():
        for name, line in imported_modules(path, module):
            inside = [m for m in modules if name == m or name.startswith(m + ".")]
            target = max(inside, key=len, default=None)
            if target is not None and target != module:
                graph[module][target].append(f"{path.relative_to(root)}:{line}")
    return graph


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--root", type=Path, default=Path(__file__).resolve().parents[1])
    parser.add_argument("--where", action="store_true", help="list the importing lines")
    parser.add_argument("--layers", action="store_true", help="layers and their rules")
    parser.add_argument("--modules", action="store_true", help="cycles between modules")
    args = parser.parse_args()
    sys.setrecursionlimit(10000)
    if args.modules:
        found = cycles(module_graph(args.root))
        print(f"module cycles: {len(found)}")
        for component in found:
            print("  " + " <-> ".join(component))
        return 1 if found else 0
    if args.layers:
        layers, broken = layer_graph(args.root)
        for source in sorted(layers):
            print(f"{source} -> {', '.join(sorted(layers[source]))}")
        found = cycles({k: dict.fromkeys(v) for k, v in layers.items()})
        print(f"\ncycles: {len(found)}")
        for component in found:
            print("  " + " <-> ".join(component))
        print(f"imports that break a rule: {len(broken)}")
        for line in broken:
            print("  " + line)
        return 1 if found or broken else 0
    graph = package_graph(args.root)
    for source in sorted(graph):
        targets = graph[source]
        print(f"{source} -> {', '.join(sorted(targets))}")
        if args.where:
            for target in sorted(targets):
                print(f"    {target}: {' '.join(targets[target])}")
    found = cycles(graph)
    print(f"\ncycles: {len(found)}")
    for component in found:
        print("  " + " <-> ".join(component))
    return 1 if found else 0


if __name__ == "__main__":
    sys.exit(main())

"""The project's modules import only downward: no import cycle among ``pneumatic_env``,
``agents`` and ``studies``.

The graph is built statically with ``ast`` from every import statement, including imports
inside functions (a function-local import does not break a cycle, it hides it); imports
under ``if TYPE_CHECKING:`` are left out, as they never run. ``pneumatic_env.agents`` and
``pneumatic_env.studies`` (the installed names) are the same modules as ``agents`` and
``studies``.
"""

from __future__ import annotations

import ast
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[1]
TOP_PACKAGES = ("pneumatic_env", "agents", "studies")
#: installed name prefix -> the name the graph uses
ALIASES = {"pneumatic_env.agents": "agents", "pneumatic_env.studies": "studies"}


def module_files() -> dict[str, Path]:
    """Dotted module name -> its file, for every module of the three packages."""
    modules: dict[str, Path] = {}
    for package in TOP_PACKAGES:
        for path in sorted((REPO_ROOT / package).rglob("*.py")):
            parts = list(path.relative_to(REPO_ROOT).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            modules[".".join(parts)] = path
    return modules


def canonical(name: str) -> str:
    """``name`` with the installed prefixes replaced by the graph's names."""
    for prefix, alias in ALIASES.items():
        if name == prefix or name.startswith(prefix + "."):
            return alias + name[len(prefix) :]
    return name


def is_type_checking_block(node: ast.AST) -> bool:
    if not isinstance(node, ast.If):
        return False
    test = node.test
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"
    )


def longest_module(name: str, modules: set[str]) -> str | None:
    """The longest prefix of dotted ``name`` that is one of ``modules``, if any."""
    parts = name.split(".")
    for stop in range(len(parts), 0, -1):
        prefix = ".".join(parts[:stop])
        if prefix in modules:
            return prefix
    return None


def import_targets(tree: ast.Module, module: str, is_package: bool, modules: set[str]) -> set[str]:
    """The project's modules that the import statements of ``tree`` import.

    ``from X import y`` imports module ``X.y`` when that is a module, else module ``X``; the
    parent packages a dotted import runs are no edge (every module of a package runs them).
    """
    targets: set[str] = set()
    package = module if is_package else module.rpartition(".")[0]

    def add(name: str) -> None:
        found = longest_module(canonical(name), modules)
        if found is not None and found != module:
            targets.add(found)

    def visit(node: ast.AST) -> None:
        if is_type_checking_block(node):
            assert isinstance(node, ast.If)
            for child in node.orelse:
                visit(child)
            return
        if isinstance(node, ast.Import):
            for alias in node.names:
                add(alias.name)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base_parts = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                base = ".".join(base_parts + ([node.module] if node.module else []))
            else:
                base = node.module or ""
            for alias in node.names:
                add(f"{base}.{alias.name}")
        for child in ast.iter_child_nodes(node):
            visit(child)

    visit(tree)
    return targets


def import_graph() -> dict[str, set[str]]:
    """Module -> the project's modules it imports."""
    files = module_files()
    modules = set(files)
    return {
        module: import_targets(
            ast.parse(path.read_text(encoding="utf-8"), filename=str(path)),
            module,
            path.name == "__init__.py",
            modules,
        )
        for module, path in files.items()
    }


def strongly_connected_components(graph: dict[str, set[str]]) -> list[list[str]]:
    """Tarjan's algorithm, iterative; components in discovery order."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    on_stack: set[str] = set()
    stack: list[str] = []
    components: list[list[str]] = []
    counter = 0
    for root in sorted(graph):
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on_stack.add(root)
        while work:
            node, children = work[-1]
            advanced = False
            for child in children:
                if child not in index:
                    index[child] = low[child] = counter
                    counter += 1
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(graph.get(child, ())))))
                    advanced = True
                    break
                if child in on_stack:
                    low[node] = min(low[node], index[child])
            if advanced:
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                component = []
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    component.append(member)
                    if member == node:
                        break
                components.append(sorted(component))
    return components


def cycle_path(graph: dict[str, set[str]], component: list[str]) -> list[str]:
    """One cycle through the component's first module, as a list of modules."""
    members = set(component)
    start = component[0]
    paths = {start: [start]}
    frontier = [start]
    while frontier:
        node = frontier.pop(0)
        for child in sorted(graph[node] & members):
            if child == start:
                return [*paths[node], start]
            if child not in paths:
                paths[child] = [*paths[node], child]
                frontier.append(child)
    return component


def test_the_graph_sees_function_local_and_relative_imports() -> None:
    tree = ast.parse(
        "from . import sibling\n"
        "from ..other import thing\n"
        "def f():\n"
        "    from pneumatic_env.agents.base import Controller\n"
        "from typing import TYPE_CHECKING\n"
        "if TYPE_CHECKING:\n"
        "    import hidden\n"
    )
    modules = {"pkg.sub.sibling", "pkg.other", "agents.base", "hidden"}
    assert import_targets(tree, "pkg.sub.mod", False, modules) == {
        "pkg.sub.sibling",
        "pkg.other",
        "agents.base",
    }


def test_a_cycle_is_found() -> None:
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}
    cycles = [c for c in strongly_connected_components(graph) if len(c) > 1]
    assert cycles == [["a", "b", "c"]]
    assert cycle_path(graph, cycles[0]) == ["a", "b", "c", "a"]


def test_no_import_cycle() -> None:
    graph = import_graph()
    assert "agents.base" in graph and "studies.paper" in graph and "pneumatic_env" in graph
    cycles = [c for c in strongly_connected_components(graph) if len(c) > 1]
    report = "\n".join(
        f"{' -> '.join(cycle_path(graph, c))}   (component: {', '.join(c)})" for c in cycles
    )
    assert not cycles, f"import cycles:\n{report}"

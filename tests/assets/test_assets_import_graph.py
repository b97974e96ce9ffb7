"""The modules of data_gen.assets import each other without a cycle (every import counts: module level,
inside functions and under TYPE_CHECKING)."""

from __future__ import annotations

import ast
from pathlib import Path

import data_gen.assets

PACKAGE = "data_gen.assets"
ROOT = Path(data_gen.assets.__file__).parent
MODULES = {f"{PACKAGE}.{p.stem}" for p in ROOT.glob("*.py")}


def imported_modules(path: Path) -> set[str]:
    """Every module of ``PACKAGE`` that ``path`` imports anywhere in its source (absolute or relative)."""
    out: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:  # relative: resolve against this package
                parts = PACKAGE.split(".")
                base = ".".join(parts[: len(parts) - node.level + 1] + ([base] if base else []))
            # `from pkg import mod` imports the module pkg.mod; `from pkg.mod import name` imports pkg.mod
            names = [base] + [f"{base}.{a.name}" for a in node.names]
        else:
            continue
        out |= {n for n in names if n in MODULES}
    return out


def import_graph() -> dict[str, set[str]]:
    graph = {f"{PACKAGE}.{p.stem}": imported_modules(p) for p in sorted(ROOT.glob("*.py"))}
    return {module: deps - {module} for module, deps in graph.items()}


def find_cycle(graph: dict[str, set[str]]) -> list[str]:
    """One cycle as a path [a, b, ..., a], or [] when the graph is acyclic (depth-first search)."""
    state: dict[str, int] = {}  # 1 = on the current path, 2 = done
    path: list[str] = []

    def visit(node: str) -> list[str]:
        state[node] = 1
        path.append(node)
        for nxt in sorted(graph.get(node, ())):
            if state.get(nxt) == 1:
                return path[path.index(nxt) :] + [nxt]
            if nxt not in state and (cycle := visit(nxt)):
                return cycle
        state[node] = 2
        path.pop()
        return []

    for node in sorted(graph):
        if node not in state and (cycle := visit(node)):
            return cycle
    return []


def test_cycle_finder_on_hand_made_graphs() -> None:
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": set()}) == []
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert find_cycle({"a": {"b", "c"}, "b": {"c"}, "c": set(), "d": {"d"}}) == ["d", "d"]


def test_parser_sees_function_level_and_type_checking_imports(tmp_path: Path) -> None:
    src = tmp_path / "m.py"
    src.write_text(
        "from typing import TYPE_CHECKING\n"
        "if TYPE_CHECKING:\n    from data_gen.assets.library import ObjectAsset\n"
        "def f():\n    from data_gen.assets import captured\n    import data_gen.assets.layouts\n"
        "from . import materials\n"
    )
    assert imported_modules(src) == {
        "data_gen.assets.library",
        "data_gen.assets.captured",
        "data_gen.assets.layouts",
        "data_gen.assets.materials",
    }


def test_assets_import_graph_is_acyclic() -> None:
    graph = import_graph()
    assert len(graph) >= 15 and "data_gen.assets.registry" in graph
    assert find_cycle(graph) == [], f"import cycle: {' -> '.join(find_cycle(graph))}"
    # the types are leaves of the asset catalogues and loaders; only the registry sees every loader
    importers = {m for m, deps in graph.items() if "data_gen.assets.registry" in deps}
    assert importers == set()
    assert {"data_gen.assets.captured", "data_gen.assets.imported"} <= graph["data_gen.assets.registry"]

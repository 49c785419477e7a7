"""The house's shape: tools/ is rooms only, imports are at module level and point one way.

The layers themselves (bus < world < agents < tools, and the rooms of tools/) are import-linter
contracts in pyproject.toml, checked by ``make check``; what a contract cannot say is checked here.
"""

from __future__ import annotations

import ast
from pathlib import Path

import grimp
import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components

ROOT = Path(__file__).resolve().parent.parent
PACKAGE_FOLDERS = ("agents", "bus", "world", "tools", "scenarios")


def package_files() -> list[Path]:
    return [ROOT / "__main__.py", *(path for folder in PACKAGE_FOLDERS for path in sorted((ROOT / folder).rglob("*.py")))]


def function_level_imports(path: Path, root: Path = ROOT) -> list[str]:
    """``file:line module`` of every import of a project module inside a function or method."""
    found = []

    def visit(node: ast.AST, in_function: bool) -> None:
        for child in ast.iter_child_nodes(node):
            if in_function and isinstance(child, ast.ImportFrom):
                if child.level or (child.module or "").startswith("ringtrack"):
                    found.append(f"{path.relative_to(root)}:{child.lineno} {child.module}")
            elif in_function and isinstance(child, ast.Import):
                found.extend(f"{path.relative_to(root)}:{child.lineno} {alias.name}" for alias in child.names
                             if alias.name.startswith("ringtrack"))
            visit(child, in_function or isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)))

    visit(ast.parse(path.read_text()), False)
    return found


def test_tools_holds_rooms_only() -> None:
    """Every module of tools/ lies in a subpackage (a room) whose name says what it holds."""
    loose = [path.name for path in (ROOT / "tools").glob("*.py") if path.name != "__init__.py"]
    assert loose == []
    rooms = sorted(path.name for path in (ROOT / "tools").iterdir() if (path / "__init__.py").is_file())
    assert rooms == ["bench", "cli", "dashboard", "introspect", "monitor", "output", "runlog", "studies", "team", "viz"]


def test_no_function_level_imports_of_project_modules() -> None:
    """A module says at its top what it needs. The command dispatch (tools/cli/__init__.py) loads a
    command's module by name with importlib, so a robot process never imports the dashboard."""
    found = [entry for path in package_files() for entry in function_level_imports(path)]
    assert found == []


def test_the_checker_sees_a_function_level_import(tmp_path: Path) -> None:
    path = tmp_path / "module.py"
    path.write_text("import os\n\ndef f():\n    from ringtrack.world import geometry\n    import json\n")
    assert function_level_imports(path, tmp_path) == ["module.py:4 ringtrack.world"]


def import_cycles(graph: grimp.ImportGraph) -> list[list[str]]:
    """The strongly connected sets of more than one module (imports under TYPE_CHECKING count)."""
    modules = sorted(graph.modules)
    index = {module: number for number, module in enumerate(modules)}
    rows, columns = [], []
    for module in modules:
        for imported in graph.find_modules_directly_imported_by(module):
            if imported in index:
                rows.append(index[module])
                columns.append(index[imported])
    adjacency = csr_matrix((np.ones(len(rows)), (rows, columns)), shape=(len(modules), len(modules)))
    count, labels = connected_components(adjacency, directed=True, connection="strong")
    groups = [[modules[i] for i in np.flatnonzero(labels == label)] for label in range(count)]
    return [group for group in groups if len(group) > 1]


def test_no_import_cycles_between_modules() -> None:
    graph = grimp.build_graph("ringtrack", cache_dir=None)
    # A package's __init__ importing its own modules is not a cycle between modules.
    for module in sorted(graph.modules):
        for imported in graph.find_modules_directly_imported_by(module):
            if imported.startswith(module + "."):
                graph.remove_import(importer=module, imported=imported)
    assert import_cycles(graph) == []

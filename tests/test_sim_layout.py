"""The simulator package's shape: its modules import each other one way only.

Every import statement counts, wherever it sits (module level, inside a
function, under ``TYPE_CHECKING``): a circle hidden in a function is still a
circle for a reader.
"""

from __future__ import annotations

import ast
from pathlib import Path

import ics35_async.sim

SIM_DIR = Path(ics35_async.sim.__file__).parent
PACKAGE = "ics35_async.sim"


def sim_imports(path: Path) -> set[str]:
    """The sibling modules of ``path`` (names within ics35_async.sim) that it imports."""
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.ImportFrom):
            if node.level == 1:
                if node.module:
                    found.add(node.module.split(".")[0])
                else:
                    found.update(alias.name for alias in node.names)
            elif node.level == 0 and node.module and node.module.startswith(PACKAGE + "."):
                found.add(node.module[len(PACKAGE) + 1 :].split(".")[0])
        elif isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name.startswith(PACKAGE + "."):
                    found.add(alias.name[len(PACKAGE) + 1 :].split(".")[0])
    return found


def import_graph() -> dict[str, set[str]]:
    modules = {p.stem: p for p in SIM_DIR.glob("*.py")}
    return {name: sim_imports(path) & set(modules) - {name} for name, path in modules.items()}


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    state: dict[str, int] = {}  # 1: on the current path, 2: done
    path: list[str] = []

    def visit(node: str) -> list[str] | None:
        state[node] = 1
        path.append(node)
        for nxt in sorted(graph[node]):
            if state.get(nxt) == 1:
                return [*path[path.index(nxt) :], nxt]
            if nxt not in state and (cycle := visit(nxt)) is not None:
                return cycle
        path.pop()
        state[node] = 2
        return None

    for node in sorted(graph):
        if node not in state and (cycle := visit(node)) is not None:
            return cycle
    return None


def test_sim_modules_import_each_other_one_way() -> None:
    graph = import_graph()
    assert graph, "no modules found"
    # __init__ and __main__ sit on top of everything; nothing below may import them.
    for name, deps in graph.items():
        assert "__init__" not in deps and "__main__" not in deps, f"{name} imports the package itself"
    cycle = find_cycle(graph)
    assert cycle is None, "import circle: " + " -> ".join(cycle or [])


def test_only_the_pty_plumbing_imports_posix_tty_modules() -> None:
    posix = {"termios", "fcntl", "tty", "pty"}
    users = set()
    for path in SIM_DIR.glob("*.py"):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else []
            if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names = [node.module]
            if posix & {n.split(".")[0] for n in names}:
                users.add(path.stem)
    assert users == {"pty_port"}

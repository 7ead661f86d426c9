"""The house rules, checked on the source: arrows only go down, no circles, small modules, a cheap import.

Imports are read with ``ast`` (module level, inside functions and under
``TYPE_CHECKING`` alike: a lazy import is still an arrow).
"""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "ics35_async"

# Layer of each top-level part of the package (docs/development/architecture.md); a module may import
# its own layer or lower ones only.  The package root (__init__) re-exports from everywhere.
LAYERS = {
    "errors": 1, "units": 1, "eeprom": 1, "protocol": 1, "stats": 1, "running": 1, "tasks": 1, "user_files": 1,
    "terminal": 1, "extras": 1,
    "engine": 2, "compiled": 2,
    "drivers": 3, "transports": 3,
    "line": 4, "frames": 4,
    "servo": 5, "stream": 5, "policies": 5,
    "bus": 6,
    "group": 7, "diagnose": 7,
    "blocking": 8, "robot": 8,
    "sim": 9, "cli": 10, "web": 10,
}  # fmt: skip


def test_the_layer_table_in_the_docs_is_the_one_checked_here() -> None:
    """Every part of the package in the layer table of docs/development/architecture.md, in the row of its
    layer here (a part the page left out, or put in another row, fails)."""
    page = (PACKAGE.parent / "docs" / "development" / "architecture.md").read_text(encoding="utf-8")
    placed: dict[str, range] = {}
    for row in page.splitlines():
        cells = row.split("|")
        if len(cells) < 4 or not cells[1].strip()[:1].isdigit():
            continue
        low, _, high = cells[1].split()[0].partition("-")
        for name in cells[2].replace("`", "").split(","):
            placed[name.strip().removesuffix(".py").removesuffix("/")] = range(int(low), int(high or low) + 1)
    assert set(placed) == set(LAYERS), set(placed) ^ set(LAYERS)
    assert {part for part, layer in LAYERS.items() if layer not in placed[part]} == set()


def test_every_part_of_the_package_has_a_layer() -> None:
    """A module or subpackage at the package's top level outside the table would be outside the arrow check
    too (its imports, and those of it, are not looked at): each has a row on the page and a layer here."""
    parts = {
        path.stem if path.suffix == ".py" else path.name
        for path in PACKAGE.iterdir()
        if (path.suffix == ".py" or (path.is_dir() and any(path.glob("*.py"))))
        and path.stem not in ("__init__", "__main__")
    }
    assert parts == set(LAYERS), (parts - set(LAYERS), set(LAYERS) - parts)


def module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imports_of(path: Path) -> set[str]:
    """Package modules ``path`` imports (resolved; ``from . import x`` counts as ``pkg.x`` if a module)."""
    here = module_name(path)
    package = here if path.name == "__init__.py" else here.rpartition(".")[0]
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found.update(a.name for a in node.names if a.name.startswith("ics35_async"))
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - node.level + 1]
                target = ".".join([*base, *([node.module] if node.module else [])])
            else:
                target = node.module or ""
            if not target.startswith("ics35_async"):
                continue
            if target != "ics35_async":  # the root only re-exports (lazily): not an arrow
                found.add(target)
            for alias in node.names:
                candidate = f"{target}.{alias.name}"
                if (PACKAGE.parent / Path(*candidate.split("."))).with_suffix(".py").exists() or (
                    PACKAGE.parent / Path(*candidate.split(".")) / "__init__.py"
                ).exists():
                    found.add(candidate)
    found.discard(here)
    return found


def graph() -> dict[str, set[str]]:
    return {module_name(p): imports_of(p) for p in PACKAGE.rglob("*.py")}


def part(module: str) -> str:
    return module.split(".")[1] if "." in module else ""


def test_no_import_circles() -> None:
    g = graph()
    # Tarjan's strongly connected components: any with more than one module is a circle.
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    circles: list[list[str]] = []
    counter = [0]

    def visit(v: str) -> None:
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on_stack.add(v)
        for w in g.get(v, ()):
            if w not in g:
                continue
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
                circles.append(sorted(component))

    sys.setrecursionlimit(10_000)
    for v in g:
        if v not in index:
            visit(v)
    assert circles == [], f"import circles: {circles}"


def test_arrows_only_go_down() -> None:
    wrong = []
    for module, targets in graph().items():
        if module == "ics35_async" or part(module) not in LAYERS:
            continue
        for target in targets:
            if target == "ics35_async" or part(target) not in LAYERS:
                continue
            if LAYERS[part(target)] > LAYERS[part(module)]:
                wrong.append(f"{module} -> {target}")
    assert wrong == []


def test_importing_the_package_loads_no_simulator_and_no_event_loop() -> None:
    code = (
        "import sys, ics35_async\n"
        "from ics35_async import open_bus, Servo, Stream, BusGroup\n"
        "heavy = ('ics35_async.sim', 'ics35_async.drivers.a', 'asyncio', 'trio')\n"
        "print(sorted(m for m in sys.modules if m.startswith(heavy)))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]", out.stdout


def test_the_package_and_the_cli_start_up_without_the_web_configurator() -> None:
    """``ics35 web``'s server (and Starlette, uvicorn) load only when that command runs."""
    code = (
        "import sys, ics35_async\n"
        "from ics35_async.cli import cli\n"
        "cli.list_commands(None)\n"
        "heavy = ('ics35_async.web', 'starlette', 'uvicorn')\n"
        "print(sorted(m for m in sys.modules if m.startswith(heavy)))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]", out.stdout


def test_the_drivers_do_not_ask_the_program_runner() -> None:
    """Whether a run says a lost port itself is a registry below the drivers (``terminal``), which ``running``
    fills: the drivers' core reads it there, not from the runner of programs, which uses lines."""
    asking = sorted(m for m, targets in graph().items() if part(m) == "drivers" and "ics35_async.running" in targets)
    assert asking == []

"""The project's import graph, read from the source (every import, in functions too, and
the string imports: ``importlib.import_module("pkg.mod")``, ``__import__("pkg.mod")`` and a
dotted name given to another loader such as ``importlib.util.find_spec`` or
``pkgutil.resolve_name``).

The floors: the model (toggle) at the bottom; planning (controllers) and the FMU (fmu_src)
on it; the clamp synthesis (design) and the rig (hil) above; the ``toggle`` command line
(toggle_cli) on top. Every import runs down a floor or stays in its package; packages on
one floor import nothing of each other; no two modules import each other in a circle.
The packages are the folders of the repository that hold an ``__init__.py``: a new one must
be given a floor here. ``python tests/import_graph.py`` prints the graph between packages
and every finding (tests/test_layers.py asserts there is none).
"""

from __future__ import annotations

import ast
import sys
from collections import defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
FLOORS = {"toggle": 0, "controllers": 1, "fmu_src": 1, "design": 2, "hil": 2, "toggle_cli": 3}
#: The rooms of a package, on floors of their own: hil's wire (link) under the host side of a
#: run (host), under the rigs without hardware (emulators), under the front panel (panel),
#: under the command line (cli), under the public API over the command's run (api). A module
#: of a room imports its own room or rooms below; a package's own modules (its __init__)
#: import none of its rooms.
ROOMS = {"hil": {"link": 0, "host": 1, "emulators": 2, "panel": 3, "cli": 4, "api": 5}}


def packages(root: Path = ROOT) -> list[str]:
    """The top-level packages: the repository's folders with an ``__init__.py``."""
    return sorted(p.parent.name for p in root.glob("*/__init__.py"))


def module_name(path: Path, root: Path = ROOT) -> str:
    parts = path.relative_to(root).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


#: Functions (by their last name) whose first argument, a string, names a module they load.
LOADERS = frozenset({"import_module", "__import__", "find_spec", "resolve_name",
                     "import_string", "spec_from_loader"})


def string_import(node: ast.AST) -> str | None:
    """The module a call such as ``importlib.import_module("fmu_src.description")`` loads:
    its first argument where that is a string constant (an f-string's constant head up to
    its last dot, e.g. ``f"toggle_cli.{name}"``: the package); None for any other node."""
    if not (isinstance(node, ast.Call) and node.args):
        return None
    func = node.func
    name = func.attr if isinstance(func, ast.Attribute) else getattr(func, "id", None)
    if name not in LOADERS:
        return None
    arg = node.args[0]
    if isinstance(arg, ast.Constant) and isinstance(arg.value, str):
        return arg.value.split(":")[0]  # resolve_name's "pkg.mod:attr"
    if isinstance(arg, ast.JoinedStr) and arg.values and isinstance(arg.values[0], ast.Constant):
        head = str(arg.values[0].value).rpartition(".")[0]
        return head or None
    return None


def imports(path: Path, root: Path = ROOT) -> set[str]:
    """The modules of the project that ``path`` imports (absolute and relative imports, and
    the string imports :func:`string_import` reads)."""
    name = module_name(path, root)
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - node.level + 1]
                module = ".".join([*base, *([node.module] if node.module else [])])
            else:
                module = node.module or ""
            found.add(module)
            # ``from pkg import mod``: the submodule, where it is one
            found.update(f"{module}.{alias.name}" for alias in node.names)
        elif (loaded := string_import(node)) is not None:
            found.add(loaded)
    own = set(packages(root))
    return {m for m in found if m.split(".")[0] in own}


def module_graph(root: Path = ROOT) -> dict[str, set[str]]:
    """Each module of every package and the project modules it imports (names resolved to
    modules that exist)."""
    files = {module_name(p, root): p for pkg in packages(root)
             for p in (root / pkg).rglob("*.py")}
    graph = {}
    for name, path in files.items():
        targets = set()
        for target in imports(path, root):
            while target and target not in files:  # an attribute: its module
                target = target.rpartition(".")[0]
            if target and target != name:
                targets.add(target)
        graph[name] = targets
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for nxt in sorted(graph.get(node, ())):
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

    sys.setrecursionlimit(max(sys.getrecursionlimit(), 10_000))
    for node in sorted(graph):
        if node not in index:
            visit(node)
    return found


def findings(root: Path = ROOT) -> list[str]:
    """Every import that breaks the floors, every package without a floor, every circle."""
    problems = [f"package {pkg}/ has no floor in tests/import_graph.py FLOORS"
                for pkg in packages(root) if pkg not in FLOORS]
    graph = module_graph(root)
    for module, targets in sorted(graph.items()):
        here = module.split(".")[0]
        for target in sorted(targets):
            there = target.split(".")[0]
            if there == here or here not in FLOORS or there not in FLOORS:
                continue
            if FLOORS[there] > FLOORS[here]:
                problems.append(f"{module} (floor {FLOORS[here]}) imports {target} "
                                f"(floor {FLOORS[there]}): up")
            elif FLOORS[there] == FLOORS[here]:
                problems.append(f"{module} imports {target}: across floor {FLOORS[here]}")
    problems += room_findings(graph)
    problems += [f"circle: {' <-> '.join(c)}" for c in cycles(graph)]
    return problems


def room_of(module: str) -> tuple[str, str | None]:
    """The package and the room of a module (None: the package's own module, or no rooms)."""
    package, _, rest = module.partition(".")
    room = rest.split(".")[0] if rest else None
    return package, room if room in ROOMS.get(package, {}) else None


def room_findings(graph: dict[str, set[str]]) -> list[str]:
    """Every import inside a package with rooms that runs up a room, or into a room from the
    package's own modules (which every room's import loads first)."""
    problems = []
    for module, targets in sorted(graph.items()):
        package, room = room_of(module)
        if package not in ROOMS:
            continue
        floors = ROOMS[package]
        for target in sorted(targets):
            there_package, there = room_of(target)
            if there_package != package or there is None or there == room:
                continue
            if room is None:
                problems.append(f"{module} (the package's own) imports {target} (room {there})")
            elif room not in floors:
                problems.append(f"{module}: {room!r} is not a room of {package} in ROOMS")
            elif floors[there] > floors[room]:
                problems.append(f"{module} (room {room}) imports {target} (room {there}): up")
    unplaced = sorted({room_of(m)[0] + "." + m.split(".")[1] for m in graph
                       if m.split(".")[0] in ROOMS and len(m.split(".")) > 1
                       and room_of(m)[1] is None})
    problems += [f"{m}: not in a room of ROOMS" for m in unplaced]
    return problems


def package_edges(root: Path = ROOT) -> dict[str, set[str]]:
    edges: dict[str, set[str]] = defaultdict(set)
    for module, targets in module_graph(root).items():
        for target in targets:
            if target.split(".")[0] != module.split(".")[0]:
                edges[module.split(".")[0]].add(target.split(".")[0])
    return edges


def main() -> int:
    edges = package_edges()
    for pkg in sorted(packages(), key=lambda p: (-FLOORS.get(p, 99), p)):
        below = ", ".join(sorted(edges.get(pkg, ()), key=lambda p: (-FLOORS.get(p, 99), p)))
        print(f"floor {FLOORS.get(pkg, '?')}  {pkg:<12} -> {below or '(nothing of the project)'}")
    problems = findings()
    print("\n".join(problems) if problems else "every import runs down; no circle")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())

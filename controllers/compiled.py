"""Machine code for the planner's CasADi functions, cached on disk.

Building the planner's functions symbolically (the plant's jets at every node, the
objective and constraints with their derivatives) takes a quarter of a second, and
CasADi's virtual machine evaluates them several times per IPOPT iteration.
:func:`compiled` generates C for them once, compiles it with the system C compiler
(``CC``, default ``gcc``) and keeps the shared library in the cache directory
(``TOGGLE_CACHE_DIR``, default ``~/.cache/toggle-clamp``) under a key computed from
everything that determines the functions, so a later process loads them in
milliseconds without building them. The caller's key covers the code
(:func:`code_digest`) and its parameters; the compiler, the link flags, CasADi's
version and the platform are added here. A changed input is a new key, never a stale
library.

Each translation unit has the optimisation level its caller chose: small code doing
heavy arithmetic is worth ``-O1``, large straight-line code compiles in seconds at
``-O0`` but in half a minute at ``-O1``. The units compile in parallel. A library is
moved into the cache complete, named with the checksum of its content; one whose
content does not match (truncated, damaged: loading it could crash the process) is
deleted and rebuilt, as is one that does not load. Where no compiler works or the
cache is not writable, the functions as built are used, interpreted: same results,
slower. The generic part (compile, cache, load) is :mod:`toggle.c_library`.
"""

from __future__ import annotations

import ast
import hashlib
import importlib.util
from collections.abc import Callable, Sequence
from pathlib import Path
from types import ModuleType

import casadi as ca

from toggle.c_library import Sources, casadi_source, shared_library

#: One translation unit: its optimisation flags and the functions it holds.
Unit = tuple[tuple[str, ...], list[ca.Function]]


def source_digest(*packages: ModuleType) -> str:
    """Hash of the source text of the modules directly in the packages' directories."""
    digest = hashlib.sha256()
    for package in packages:
        roots = sorted({Path(entry) for entry in package.__path__ if Path(entry).is_dir()})
        for path in sorted(p for root in roots for p in root.glob("*.py")):
            digest.update(f"{package.__name__}.{path.stem}\0".encode())
            digest.update(path.read_bytes())
    return digest.hexdigest()


def _imported(path: Path, roots: tuple[str, ...]) -> set[str]:
    """Names of the modules of the packages ``roots`` that the source file imports at
    module level (imports inside functions, such as plotting, are not the model's)."""
    names = set()
    for node in ast.parse(path.read_text(encoding="utf-8")).body:
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module)
            names.update(f"{node.module}.{alias.name}" for alias in node.names)
    return {n for n in names if n.split(".")[0] in roots}


#: The project's packages whose code a compiled problem can use.
PROJECT_PACKAGES = ("controllers", "toggle")


def code_modules(*modules: str, roots: tuple[str, ...] = PROJECT_PACKAGES) -> dict[str, Path]:
    """The modules given and every module of the packages ``roots`` they import at module
    level, directly or not, with their source files: the code a compiled problem uses."""
    seen: dict[str, Path] = {}
    todo = list(modules)
    while todo:
        name = todo.pop()
        if name in seen:
            continue
        try:
            spec = importlib.util.find_spec(name)
        except ModuleNotFoundError:  # an attribute imported from a module
            continue
        if spec is None or not spec.origin or not spec.origin.endswith(".py"):
            continue  # an attribute imported from a module, not a module
        seen[name] = Path(spec.origin)
        todo.extend(_imported(seen[name], roots))
    return seen


def code_digest(*modules: str, roots: tuple[str, ...] = PROJECT_PACKAGES) -> str:
    """Hash of the source text of :func:`code_modules`, so that editing the plant
    recompiles and editing another module (plots, the CLI) keeps the cache."""
    digest = hashlib.sha256()
    for name, path in sorted(code_modules(*modules, roots=roots).items()):
        digest.update(f"{name}\0".encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()


def _load(library: Path, names: Sequence[str]) -> list[ca.Function] | None:
    """The functions from ``library``, or None if it does not load."""
    try:
        return [ca.external(name, str(library)) for name in names]
    except RuntimeError:
        return None


def compiled(name: str, key: str, names: Sequence[str], build: Callable[[], list[Unit]],
             machine_code: bool = True) -> list[ca.Function]:
    """The functions ``names`` as machine code: from the library cached under ``key``, or
    else built by ``build``, compiled, cached and loaded; as built (interpreted) where
    compiling or loading fails, or without ``machine_code`` (a problem solved once, for
    which a compile would cost more than it saves)."""
    if not machine_code:
        built = {fn.name(): fn for _, functions in build() for fn in functions}
        return [built[n] for n in names]
    units: list[Unit] = []

    def sources(tmp: Path) -> Sources:
        units.extend(build())
        return [(flags, casadi_source(tmp / f"unit{k}.c", functions))
                for k, (flags, functions) in enumerate(units)]

    loaded = shared_library(name, key, sources, lambda library: _load(library, names))
    if loaded is not None:
        return loaded
    built = {fn.name(): fn for _, functions in units or build() for fn in functions}
    return [built[n] for n in names]

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
slower. The newest :data:`KEEP` libraries of a name are kept.
"""

from __future__ import annotations

import ast
import hashlib
import importlib.util
import os
import platform
import subprocess
import tempfile
import zlib
from collections.abc import Callable, Sequence
from pathlib import Path
from types import ModuleType

import casadi as ca

#: One translation unit: its optimisation flags and the functions it holds.
Unit = tuple[tuple[str, ...], list[ca.Function]]
_COMPILE = ("-fPIC", "-c")
_LINK = ("-shared", "-s")
_TIMEOUT = 300  # s, per compiler run
#: Libraries of one name kept (0.7 to 2 MB each); older ones (of changed code or plants,
#: other N, robust variants) are deleted.
KEEP = 48


def cache_dir() -> Path:
    """Directory of the compiled libraries."""
    default = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "toggle-clamp"
    return Path(os.environ.get("TOGGLE_CACHE_DIR", default))


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


def _compiler() -> str:
    return os.environ.get("CC", "gcc")


def _stem(name: str, key: str) -> str:
    """File-name stem of the library for ``key``, also keyed by the toolchain and platform."""
    salt = (key, _compiler(), *_COMPILE, *_LINK, ca.__version__, platform.machine(),
            platform.system())
    digest = hashlib.sha256("\0".join(salt).encode()).hexdigest()[:24]
    return f"{name}_{digest}"


def _checksum(data: bytes) -> str:
    """CRC-32 of a library's content (it catches truncation and damage), 8 hex digits."""
    return f"{zlib.crc32(data):08x}"


def _run_all(commands: list[list[str]]) -> None:
    """Run the commands in parallel; raise if any fails."""
    jobs = [subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            for cmd in commands]
    try:
        codes = [job.wait(timeout=_TIMEOUT) for job in jobs]
    finally:
        for job in jobs:
            if job.poll() is None:
                job.kill()
                job.wait()
    if any(codes):
        raise subprocess.CalledProcessError(max(codes), commands[codes.index(max(codes))])


def _compile(units: list[Unit], stem: str) -> Path | None:
    """Generate, compile and link the units into a library named by ``stem`` and its
    checksum, moved into the cache in one step; None on failure."""
    try:
        cache_dir().mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryDirectory(dir=cache_dir()) as tmp:
            objects = [Path(tmp) / f"unit{k}.o" for k in range(len(units))]
            for (_, functions), obj in zip(units, objects):
                generator = ca.CodeGenerator(obj.with_suffix(".c").name)
                for fn in functions:
                    generator.add(fn)
                obj.with_suffix(".c").write_text(generator.dump(), encoding="utf-8")
            _run_all([[_compiler(), *flags, *_COMPILE, "-o", str(obj), str(obj.with_suffix(".c"))]
                      for (flags, _), obj in zip(units, objects)])
            shared = Path(tmp) / "library.so"
            _run_all([[_compiler(), *_LINK, "-o", str(shared), *map(str, objects)]])
            library = cache_dir() / f"{stem}_{_checksum(shared.read_bytes())}.so"
            os.replace(shared, library)
        return library
    except (OSError, subprocess.SubprocessError):
        return None


def _prune(name: str) -> None:
    """Delete all but the :data:`KEEP` newest libraries of ``name``."""
    try:
        libraries = sorted(cache_dir().glob(f"{name}_*.so"), key=lambda p: p.stat().st_mtime)
        for old in libraries[:-KEEP]:
            old.unlink(missing_ok=True)
    except OSError:  # another process pruning at the same time
        pass


def _intact(library: Path) -> bool:
    """Whether the library's content matches the checksum in its name; a damaged one (a
    truncated file can crash the process that loads it) is deleted."""
    try:
        if library.stem.rsplit("_", 1)[1] == _checksum(library.read_bytes()):
            return True
        library.unlink()
    except OSError:
        pass
    return False


def _load(library: Path, names: Sequence[str]) -> list[ca.Function] | None:
    """The functions from ``library``, or None if it does not load."""
    try:
        return [ca.external(name, str(library)) for name in names]
    except RuntimeError:
        return None


def compiled(name: str, key: str, names: Sequence[str], build: Callable[[], list[Unit]]
             ) -> list[ca.Function]:
    """The functions ``names`` as machine code: from the library cached under ``key``, or
    else built by ``build``, compiled, cached and loaded; as built (interpreted) where
    compiling or loading fails."""
    stem = _stem(name, key)
    for library in cache_dir().glob(f"{stem}_*.so"):
        loaded = _load(library, names) if _intact(library) else None
        if loaded is not None:
            return loaded
    units = build()
    built = {fn.name(): fn for _, functions in units for fn in functions}
    library = _compile(units, stem)
    loaded = _load(library, names) if library else None
    _prune(name)
    return loaded if loaded is not None else [built[n] for n in names]

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

The first process of a plant does not wait for the compile (a minute or more for a
200-interval problem, against seconds for the whole plan interpreted): with
``TOGGLE_COMPILE`` unset or ``background`` it plans with the functions interpreted (the
same functions, the same answers to the printed digits) and hands them to a detached
compile (:func:`toggle.c_library.compile_later`: ``python -m controllers.compiled JOB``,
nice 19, under the cache's lock and size cap), one per library at a time, so that the next
process loads them. ``TOGGLE_COMPILE=wait`` compiles before the answer, as before (the
test suite, and benchmarks that time the compiled code).
"""

from __future__ import annotations

import ast
import fcntl
import hashlib
import importlib.util
import json
import os
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from types import ModuleType

import casadi as ca

from controllers import progress
from toggle.c_library import (
    DETACHED_TIMEOUT,
    JOB_PREFIX,
    Sources,
    cache_dir,
    cached_library,
    casadi_source,
    compile_later,
    have_compiler,
    shared_library,
)
from toggle.params import ParameterError

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


#: How a process gets functions no library holds yet (``TOGGLE_COMPILE``): interpreted,
#: compiled meanwhile in the background for the next process; or compiled first.
MODES = ("background", "wait")


def compile_mode() -> str:
    """``TOGGLE_COMPILE``: ``background`` (the default) or ``wait``."""
    mode = os.environ.get("TOGGLE_COMPILE", "").strip().lower() or MODES[0]
    if mode not in MODES:
        raise ParameterError(f"TOGGLE_COMPILE={mode!r}: use one of {', '.join(MODES)}")
    return mode


def _interpreted(units: list[Unit], names: Sequence[str]) -> list[ca.Function]:
    built = {fn.name(): fn for _, functions in units for fn in functions}
    return [built[n] for n in names]


def _sources(units: Callable[[], list[Unit]],
             choose: Callable[[tuple[str, ...], Path], tuple[str, ...]] = lambda f, _: f
             ) -> Callable[[Path], Sources]:
    """The C sources of the units (built when first asked for) in a scratch directory,
    each with its flags (or those ``choose`` makes of them and the source)."""
    def sources(tmp: Path) -> Sources:
        written = [(flags, casadi_source(tmp / f"unit{k}.c", functions))
                   for k, (flags, functions) in enumerate(units())]
        return [(choose(flags, source), source) for flags, source in written]
    return sources


def _names_in(units: list[Unit]) -> list[str]:
    return [fn.name() for _, functions in units for fn in functions]


def compiled(name: str, key: str, names: Sequence[str], build: Callable[[], list[Unit]],
             machine_code: bool = True, first: Sequence[str] = ()) -> list[ca.Function]:
    """The functions ``names`` as machine code from the library cached under ``key``;
    else (:func:`compile_mode` ``background``) built by ``build``, its first units (one
    per key in ``first``) compiled now (small code that carries the arithmetic: seconds;
    each cached as a library ``NAME-first`` under its own key, so that another problem
    with the same unit, as a robust plan's nominal clamp, loads it), the others
    interpreted, while a detached process compiles them all for the next time; or
    (``wait``) all compiled, cached and loaded now. As built (interpreted) where compiling
    or loading fails, or without ``machine_code`` (a problem solved once, for which a
    compile would cost more than it saves)."""
    if not machine_code:
        return _interpreted(build(), names)
    loaded = cached_library(name, key, lambda library: _load(library, names))
    if loaded is not None:
        return loaded
    if not have_compiler():  # nothing to compile with: no job written, no scratch made
        return _interpreted(build(), names)
    if compile_mode() == "background":
        return _first_answer(name, key, names, build, first)
    kept: list[Unit] = []

    def units_once() -> list[Unit]:
        if not kept:
            kept.extend(build())
        return kept

    with progress.doing("compiling the problem, once per plant and code"):
        loaded = shared_library(name, key, _sources(units_once),
                                lambda library: _load(library, names))
    return loaded if loaded is not None else _interpreted(units_once(), names)


#: The largest unit of C (bytes) compiled for a first answer with its own flags; a larger
#: one is compiled at -O0. gcc -O1's register allocation grows faster than the code: a
#: symmetric clamp's jets (0.44 MB) take 2.1 s of CPU at -O1 and run 2-5 times faster than
#: at -O0 (worth it), a robust plan's erroneous clamp (unequal halves: 1.4 MB) took about
#: 10 s at -O1 against 1.7 s at -O0. The detached compile for the next process keeps each
#: unit's own flags. The same arithmetic either way (no fast-math): the same answers.
FIRST_ANSWER_MAX_BYTES = 1_000_000


def first_answer_flags(flags: tuple[str, ...], source: Path) -> tuple[str, ...]:
    """A unit's flags for a first answer: its own, or -O0 for a unit of C too large to
    optimise in seconds (:data:`FIRST_ANSWER_MAX_BYTES`)."""
    if source.stat().st_size <= FIRST_ANSWER_MAX_BYTES:
        return flags
    return (*(f for f in flags if not f.startswith("-O")), "-O0")


def _first_answer(name: str, key: str, names: Sequence[str], build: Callable[[], list[Unit]],
                  first: Sequence[str]) -> list[ca.Function]:
    """:func:`compiled`'s functions on a cache miss, ``background``: the ``first`` units
    compiled now (without the cache's lock: a detached compile may hold it for a minute),
    the rest interpreted, all of them handed to a detached compile."""
    with progress.doing("building the problem; compiled in the background for the next "
                        "run"):
        units = build()
        compile_in_background(name, key, names, units)
    functions = dict(zip(_names_in(units), _interpreted(units, _names_in(units))))
    for unit, unit_key in zip(units, first):
        quick = _names_in([unit])
        with progress.doing("compiling the plant's jets"):
            loaded = shared_library(f"{name}-first", unit_key,
                                    _sources(lambda u=unit: [u], first_answer_flags),
                                    lambda library, q=quick: _load(library, q), lock=False)
        functions.update(zip(quick, loaded or ()))
    return [functions[n] for n in names]


def _job_path(name: str, key: str) -> Path:
    return cache_dir() / f"{JOB_PREFIX}{name}-{hashlib.sha256(key.encode()).hexdigest()[:24]}.json"


def compile_in_background(name: str, key: str, names: Sequence[str], units: list[Unit]
                          ) -> int | None:
    """Write the units (CasADi's serialisation) to a job file in the cache and start a
    detached compile of it (:func:`main`); its process id, or None where none started: one
    of the same library queued or running already (it holds the job file's lock), or no
    writable cache."""
    job = _job_path(name, key)
    try:
        job.parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(job, os.O_RDWR | os.O_CREAT, 0o600)
    except OSError:
        return None
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        text = json.dumps({"name": name, "key": key, "names": list(names), "units": [
            [list(flags), [fn.serialize() for fn in functions]] for flags, functions in units]})
        os.ftruncate(fd, 0)
        with os.fdopen(os.dup(fd), "w", encoding="utf-8") as out:
            out.write(text)
        return compile_later(["-m", "controllers.compiled", str(job)])
    except OSError:  # locked: a compile of this library is on its way
        return None
    finally:
        os.close(fd)  # unlocked: the job's process takes the lock for the compile


def main(argv: Sequence[str]) -> int:
    """The detached compile of a job file (:func:`compile_in_background`): hold its lock
    (marking the compile as on its way), compile under the cache's lock (where the library
    is found, by another's compile, nothing is done), delete the job; exit status 0 if
    the library is in the cache."""
    job = Path(argv[0])
    try:
        fd = os.open(job, os.O_RDWR)
    except OSError:
        return 1
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)  # after the writer's
        try:
            with os.fdopen(os.dup(fd), encoding="utf-8") as text:
                spec = json.loads(text.read())
        except ValueError:  # empty or cut short: its writer was killed
            job.unlink(missing_ok=True)
            return 1
        units: list[Unit] = [(tuple(flags), [ca.Function.deserialize(f) for f in functions])
                             for flags, functions in spec["units"]]
        loaded = shared_library(spec["name"], spec["key"], _sources(lambda: units),
                                lambda library: _load(library, spec["names"]),
                                timeout=DETACHED_TIMEOUT)
        job.unlink(missing_ok=True)
        return 0 if loaded is not None else 1
    finally:
        os.close(fd)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

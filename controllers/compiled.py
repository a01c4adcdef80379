"""Machine code for the planner's per-node plant functions.

CasADi's virtual machine evaluates the plant's jets (value, gradient,
Hessian at every node) several times per IPOPT iteration; compiled C is
about ten times faster. The C source CasADi generates is compiled once by
the system C compiler (``CC``, default ``gcc``) and kept on disk under the
hash of its source (``TOGGLE_CACHE_DIR``, default ``~/.cache/toggle-clamp``),
so a later process loads it in milliseconds. Where no compiler works or the
cache is not writable the functions stay interpreted: same results, slower.
"""

from __future__ import annotations

import hashlib
import os
import subprocess
import tempfile
from pathlib import Path

import casadi as ca

CFLAGS = ("-O1", "-shared", "-fPIC")


def cache_dir() -> Path:
    """Directory of the compiled libraries."""
    default = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "toggle-clamp"
    return Path(os.environ.get("TOGGLE_CACHE_DIR", default))


def _build(source: str, library: Path) -> bool:
    """Compile ``source`` into ``library`` (atomically); False if that fails."""
    try:
        library.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryDirectory(dir=library.parent) as tmp:
            c_file, so_file = Path(tmp) / "jets.c", Path(tmp) / library.name
            c_file.write_text(source, encoding="utf-8")
            subprocess.run([os.environ.get("CC", "gcc"), *CFLAGS, "-o", str(so_file),
                            str(c_file)], check=True, capture_output=True, timeout=120)
            os.replace(so_file, library)
        return True
    except (OSError, subprocess.SubprocessError):
        return False


def compiled(functions: list[ca.Function], name: str) -> list[ca.Function]:
    """The functions, compiled and loaded from the cache (built on first use), or
    themselves where that is not possible."""
    generator = ca.CodeGenerator(f"{name}.c")
    for fn in functions:
        generator.add(fn)
    source = generator.dump()
    digest = hashlib.sha256(" ".join((*CFLAGS, source)).encode()).hexdigest()[:20]
    library = cache_dir() / f"{name}_{digest}.so"
    if not (library.exists() or _build(source, library)):
        return functions
    try:
        return [ca.external(fn.name(), str(library)) for fn in functions]
    except RuntimeError:  # an unloadable library (another platform's cache): interpret
        return functions

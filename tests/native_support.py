"""Builds of the native FMU shared by the tests/test_native_*.py modules: each variant
(FMI version, interface) is built once per test session, into a folder removed at exit."""

from __future__ import annotations

import atexit
import functools
import shutil
import subprocess
import tempfile
import zipfile
from pathlib import Path

from fmu_src.c_code import fmi_headers
from fmu_src.native_build import build_native_fmu

_ROOT = Path(tempfile.mkdtemp(prefix="toggle_native_tests_"))
atexit.register(shutil.rmtree, _ROOT, ignore_errors=True)


@functools.cache
def native_build(fmi_version: int = 2, interface: str = "cs") -> Path:
    """The native FMU of chang2021 for this FMI version and interface, built once."""
    return build_native_fmu(_ROOT / f"fmi{fmi_version}_{interface}", "chang2021", fmi_version,
                            interface)


@functools.cache
def native_sources(fmi_version: int = 2, interface: str = "cs") -> Path:
    """The sources/ folder of that build, extracted once."""
    folder = _ROOT / f"sources{fmi_version}_{interface}"
    with zipfile.ZipFile(native_build(fmi_version, interface)) as zf:
        for name in zf.namelist():
            if name.startswith("sources/"):
                zf.extract(name, folder)
    return folder / "sources"


def compile_harness(harness: Path, out: Path, *flags: str, fmi_version: int = 2,
                    interface: str = "cs") -> Path:
    """gcc a C test harness with the FMU's own sources (C11, every warning an error)."""
    src = native_sources(fmi_version, interface)
    sources = [p for p in sorted(src.glob("*.c"))]
    subprocess.run(["gcc", "-std=c11", "-Wall", "-Wextra", "-Werror", "-Wno-unused-parameter",
                    *flags, "-I", str(src), "-I", str(fmi_headers(fmi_version)), str(harness),
                    *map(str, sources), "-o", str(out), "-lm"],
                   check=True, capture_output=True, text=True)
    return out

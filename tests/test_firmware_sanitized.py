"""The firmware's host build under AddressSanitizer and UBSan, driven by the Python tests.

The conformance suite (tests/test_mcu_conformance.py) runs in a child process against
librigfw.so built with RIGFW_SANITIZE=1 (given as RIGFW_LIBRARY), the sanitizers' runtimes
preloaded into Python: any report aborts the child (-fno-sanitize-recover=all). The C unit
tests and the fuzz harness run under both sanitizers too (tests/test_firmware_core.py).
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


def _runtime(name: str) -> str | None:
    path = subprocess.run(["gcc", f"-print-file-name={name}"], capture_output=True,
                          text=True).stdout.strip()
    return path if os.path.isabs(path) and os.path.exists(path) else None


def test_the_host_build_is_clean_under_asan_and_ubsan() -> None:
    if shutil.which("gcc") is None:
        pytest.skip("needs gcc (Debian package gcc)")
    runtimes = [_runtime("libasan.so"), _runtime("libubsan.so")]
    if None in runtimes:
        pytest.skip("needs gcc's sanitizer runtimes (Debian packages libasan8, libubsan1)")
    # built here, without the runtimes: CasADi's code generation dlopens its plugins with
    # RTLD_DEEPBIND, which the sanitizer runtime refuses
    built = subprocess.run(
        [sys.executable, "-c",
         "from hil.emulators.firmware import build_host_firmware as b; print(b())"],
        cwd=ROOT, env={**os.environ, "RIGFW_SANITIZE": "1"}, capture_output=True, text=True,
        check=True).stdout.strip()
    env = {**os.environ, "RIGFW_LIBRARY": built, "LD_PRELOAD": ":".join(runtimes),
           "ASAN_OPTIONS": "detect_leaks=0:abort_on_error=1",
           "UBSAN_OPTIONS": "print_stacktrace=1:halt_on_error=1"}
    result = subprocess.run(
        [sys.executable, "-m", "pytest", "-p", "no:cacheprovider",
         "tests/test_mcu_conformance.py", "-k", "firmware or whole"],
        cwd=ROOT, env=env, capture_output=True, text=True, timeout=600)
    report = result.stdout[-3000:] + result.stderr[-3000:]
    assert result.returncode == 0, report
    assert "ERROR: AddressSanitizer" not in report and "runtime error" not in report, report
    passed = re.search(r"(\d+) passed", result.stdout)
    assert passed and int(passed.group(1)) >= 20 and "skipped" not in result.stdout, report

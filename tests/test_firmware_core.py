"""The rig firmware's portable core (firmware/core/) checked by its own C programs.

Runs ``make -C firmware test sanitize fuzz analyze`` once: the unit tests on the fake HAL
(built normally, then under AddressSanitizer + UBSan), the receive-path fuzzer (1e6 frames
under both sanitizers) and the static analysis (gcc -fanalyzer -Werror, cppcheck). Each
program's closing line is asserted, not only make's exit status. About 15 s here.
"""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
MISSING = [tool for tool in ("gcc", "make", "cppcheck") if shutil.which(tool) is None]

pytestmark = pytest.mark.skipif(
    bool(MISSING),
    reason=f"{', '.join(MISSING)} missing: install the Debian packages gcc, make and cppcheck",
)


@pytest.fixture(scope="module")
def make_output() -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        ["make", "-C", str(ROOT / "firmware"), "test", "sanitize", "fuzz", "analyze"],
        # about 40 s idle; the fuzz runs a fixed count of executions, so a loaded machine
        # takes longer (over 300 s at load 7-14): the timeout only catches a hang
        capture_output=True, text=True, timeout=1200,
    )


def test_make_succeeds(make_output: subprocess.CompletedProcess[str]) -> None:
    assert make_output.returncode == 0, make_output.stdout[-3000:] + make_output.stderr[-3000:]


def test_unit_tests_pass_normal_and_sanitized(
        make_output: subprocess.CompletedProcess[str]) -> None:
    results = re.findall(r"^core tests: (\d+) passed, (\d+) failed$", make_output.stdout,
                         re.MULTILINE)
    assert len(results) == 2, make_output.stdout[-3000:]  # test, then sanitize
    for passed, failed in results:
        assert int(passed) >= 20 and int(failed) == 0


def test_fuzzer_finds_nothing(make_output: subprocess.CompletedProcess[str]) -> None:
    match = re.search(r"^fuzz: (\d+) frames, (\d+) failures$", make_output.stdout, re.MULTILINE)
    assert match, make_output.stdout[-3000:] + make_output.stderr[-3000:]
    assert int(match.group(1)) >= 1_000_000 and int(match.group(2)) == 0


def test_static_analysis_is_clean(make_output: subprocess.CompletedProcess[str]) -> None:
    assert "analyze: gcc -fanalyzer and cppcheck found nothing" in make_output.stdout
    assert "warning:" not in make_output.stderr and "error:" not in make_output.stderr

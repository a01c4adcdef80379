"""Every ``hil`` command answers generated bad input with a clear line (tests/cli_fuzz.py).

Runs stay cheap: ``hil run`` gets a tiny --max-duration (every valid run is refused after
all its settings are checked, before anything moves), the default plan is a canned
profile, the emulators (the Python model, QEMU, the rehosted board) stop serving once their
port is printed, and rig ports fail at once.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import pytest
from cli_fuzz import EXAMPLES, cheap_commands, check_answer, invocations, path_values
from hypothesis import HealthCheck, given, settings

from hil.cli.main import build_parser, main

ROOT = Path(tempfile.mkdtemp(prefix="hil_fuzz_"))
PATHS = path_values(ROOT)
OUT = ROOT / "out"


def caps(words: tuple[str, ...]) -> list[str]:
    if words == ("run",):
        return ["--max-duration", "1e-9", "--out", str(OUT)]
    return []


@pytest.fixture(autouse=True, scope="module")
def cheap(monkeypatch_module) -> None:
    cheap_commands(monkeypatch_module, ROOT)  # the emulators serve for no time


@pytest.fixture(scope="module")
def monkeypatch_module():
    with pytest.MonkeyPatch.context() as mp:
        yield mp


@settings(max_examples=EXAMPLES, derandomize=True, deadline=None,
          suppress_health_check=[HealthCheck.too_slow])
@given(argv=invocations(build_parser(), PATHS, caps))
def test_every_hil_command_answers_bad_input_with_one_clear_line(argv: list[str]) -> None:
    check_answer(main, argv, [OUT], watch=ROOT, in_words=True)

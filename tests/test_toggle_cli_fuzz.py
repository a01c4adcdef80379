"""Every ``toggle`` command answers generated bad input with one clear line (tests/cli_fuzz.py).

2000 invocations of every sub-command (``toggle plot <kind>`` included) with values from
the edge pools. Runs stay cheap without stubbing the checks: the expensive counts are
capped after the drawn options (argparse still judges every drawn value; the last one
wins), and the FMU builds and matplotlib's rendering are replaced by fakes that write a
few bytes where the real ones write the file (:func:`cli_fuzz.cheap_commands`).
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import pytest
from cli_fuzz import EXAMPLES, cheap_commands, check_answer, invocations, path_values
from hypothesis import HealthCheck, given, settings

from toggle_cli import build_parser, main

ROOT = Path(tempfile.mkdtemp(prefix="toggle_fuzz_"))
PATHS = path_values(ROOT)
(ROOT / "latin1.toml").write_bytes("# Größe\nname = 'x'\n".encode("latin-1"))  # not UTF-8
PATHS.append(str(ROOT / "latin1.toml"))

#: Options appended to keep one run in milliseconds (a count, a sample size).
CAPS: dict[tuple[str, ...], list[str]] = {
    ("synthesize",): ["--samples", "20"],
    ("tolerance",): ["--samples", "0"],
    ("kinematics",): ["--points", "3"],
    ("study",): ["--points", "3"],
    ("sweep",): ["--points", "3"],
    ("plot", "study"): ["--points", "3"],
    ("plot", "sweep"): ["--points", "3"],
    ("plot", "clamp"): ["--mu", "0.1"],
    ("plan",): ["--intervals", "4"],
    ("plot", "trade-off"): ["--intervals", "4", "--points", "2"],
    ("calibrate",): ["--fit", "free_play", "--speeds", "5e-3"],
    ("plot", "linkage"): ["--frames", "2"],
}


def caps(words: tuple[str, ...]) -> list[str]:
    return CAPS.get(words, [])


@pytest.fixture(scope="module")
def monkeypatch_module():
    with pytest.MonkeyPatch.context() as mp:
        yield mp


@pytest.fixture(autouse=True, scope="module")
def cheap(monkeypatch_module) -> None:
    cheap_commands(monkeypatch_module, ROOT)


@settings(max_examples=EXAMPLES, derandomize=True, deadline=None,
          suppress_health_check=[HealthCheck.too_slow])
@given(argv=invocations(build_parser(), PATHS, caps))
def test_every_toggle_command_answers_bad_input_with_one_clear_line(argv: list[str]) -> None:
    check_answer(main, argv, [], watch=ROOT, in_words=True)

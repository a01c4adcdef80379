"""Saved states of the native FMU are input to validate: a state fuzzer.

tests/native_state_fuzz.c forges 100 000 states with valid checksums from genuine states of
every phase, of Co-Simulation and Model Exchange instances (the CS+ME build), and asserts,
for each, fmi2Error with the instance unchanged, or a restore whose next 100 steps return
fmi2OK or fmi2Error with finite outputs (its header states the criterion). It is compiled
from the FMU's own sources with ASan and UBSan, so a read out of bounds or an undefined
operation on forged data fails the test.
"""

from __future__ import annotations

import os
import re
import subprocess
from pathlib import Path

from native_support import compile_harness

ITERATIONS = 100_000


def test_forged_states_are_refused_or_restore_to_a_working_instance(tmp_path: Path):
    fuzz = compile_harness(Path(__file__).with_name("native_state_fuzz.c"), tmp_path / "fuzz",
                           "-O2", "-g", "-fsanitize=address,undefined",
                           "-fno-sanitize-recover=all", interface="both")
    env = {**os.environ, "ASAN_OPTIONS": "detect_leaks=1:abort_on_error=0",
           "UBSAN_OPTIONS": "halt_on_error=1:print_stacktrace=1"}
    run = subprocess.run([str(fuzz), str(ITERATIONS), "28"], capture_output=True, text=True,
                         env=env, timeout=300)
    assert run.returncode == 0, run.stdout + run.stderr
    counts = dict((k, int(v)) for k, v in re.findall(r"(\w+) (\d+)", run.stdout))
    assert counts["refused"] + counts["restored"] == ITERATIONS
    # both outcomes occur in bulk, and restored states do step (not only refuse)
    assert counts["refused"] > ITERATIONS // 4 and counts["restored"] > ITERATIONS // 10
    assert counts["stepped"] > ITERATIONS // 20
    assert counts["steps_ok"] > 100 * counts["stepped"] // 2

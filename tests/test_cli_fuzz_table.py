"""A few dozen lines of the tabulated CLI fuzz (tests/cli_fuzz_table.py; the full 749-line
run prints the table): every kind of mistake, against both command lines, answered by the
convention."""

from __future__ import annotations

from pathlib import Path

from cli_fuzz_table import KINDS, fuzz, generate, make_fixture

from hil.cli.main import build_parser as hil_parser
from toggle_cli import build_parser as toggle_parser


def test_the_generated_lines_cover_both_commands_and_every_kind_of_mistake(
        tmp_path: Path) -> None:
    fixture = make_fixture(tmp_path)
    parsers = {"toggle": toggle_parser(), "hil": hil_parser()}
    lines = generate(60, 40, fixture, parsers)
    assert {line.cli for line in lines} == {"toggle", "hil"}
    labels = {line.kind.split(":")[0] for line in lines}
    assert {"input", "output", "unknown option", "not a number", "an option without value",
            "a choice not offered", "run failure", "port"} == labels and len(KINDS) == len(labels)
    assert generate(60, 40, fixture, parsers) == lines  # a seed replays


def test_sixty_fuzzed_lines_keep_the_convention(tmp_path: Path) -> None:
    rows, findings = fuzz(60, 7, root=tmp_path)
    assert sum(r.lines for r in rows.values()) == 60
    assert sum(r.tracebacks for r in rows.values()) == 0, findings
    assert sum(r.internals for r in rows.values()) == 0, findings
    assert sum(r.clobbered for r in rows.values()) == 0, findings
    assert findings == []  # every mistake: exit 2, one error line, before the work; a failed
    # run (no rig answers): exit 1

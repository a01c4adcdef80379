"""The README (issue 48): under 150 lines, and every command in it run by the suite. Each
part of each command in its ``bash`` blocks (and each ``examples/`` script it names) must
match a rule below that points at what runs it, which this test checks; its Python blocks
run here (mark ``examples``); its links to docs/ resolve."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text(encoding="utf-8")


def _blocks(language: str) -> list[str]:
    return re.findall(rf"```{language}\n(.*?)```", README, flags=re.S)


def _text(path: str) -> str:
    return (ROOT / path).read_text(encoding="utf-8")


#: What runs each command: CI's script installs and tests exactly as the README says; the
#: soak test runs `hil run` with default options; tests/test_docs.py builds the site.
RUN_BY = {
    "python3 -m venv .venv": lambda: "python3 -m venv .venv" in _text(".ci/run"),
    ".venv/bin/pip install -e .": lambda: "\n.venv/bin/pip install -e .\n" in _text(".ci/run"),
    ".venv/bin/pip install -e '.[test]'":
        lambda: "\n.venv/bin/pip install -e '.[test]'\n" in _text(".ci/run"),
    ".venv/bin/python -m pytest": lambda: "\n.venv/bin/python -m pytest\n" in _text(".ci/run"),
    ".venv/bin/hil run": lambda: 'hil("run", timeout=300)' in _text("tests/test_hil_soak.py"),
    ".venv/bin/mkdocs build --strict":
        lambda: '"mkdocs", "build", "--strict"' in _text("tests/test_docs.py"),
}


def test_the_readme_is_short() -> None:
    assert len(README.splitlines()) < 150


def test_every_command_in_the_readme_is_run_by_the_suite() -> None:
    commands = [part.strip() for block in _blocks("bash") for line in block.splitlines()
                if line.strip() for part in line.split("&&")]
    assert commands, "the README lost its commands"
    for command in commands:
        assert command in RUN_BY, f"README command {command!r}: no test runs it"
        assert RUN_BY[command](), f"README command {command!r}: its test no longer runs it"
    sys.path.insert(0, str(ROOT / "examples"))
    from make_figures import EXAMPLES  # tests/test_examples.py runs each

    named = re.findall(r"examples/(\w+)\.py", README)
    assert named and set(named) <= set(EXAMPLES)


@pytest.mark.examples  # it plans and runs a stroke, as the examples do (half a minute)
def test_the_readmes_python_runs(tmp_path: Path) -> None:
    code = "\n".join(_blocks("python"))
    done = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True,
                          text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "stroke 55.0047 mm" in done.stdout
    assert (tmp_path / "plan.csv").is_file() and list((tmp_path / "runs").glob("*/samples.csv"))


def test_the_readmes_links_resolve() -> None:
    for target in re.findall(r"\]\(([^)#]+)\)", README):
        assert (ROOT / target).exists(), target

"""The examples (examples/, issue 48): each runs end to end in its own process and writes
its figure; the site shows the committed copies (docs/examples/, ``python
examples/make_figures.py``). Marked ``examples``: ``-m "not examples"`` leaves them out
(about two minutes in one process on a loaded two-core machine, most of it planning)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "examples"))
from make_figures import EXAMPLES  # noqa: E402

pytestmark = pytest.mark.examples


def test_every_example_script_is_run_here_and_shown_on_the_site() -> None:
    scripts = {p.stem for p in (ROOT / "examples").glob("*.py")} - {"_common", "make_figures"}
    assert scripts == set(EXAMPLES)
    page = (ROOT / "docs" / "examples.md").read_text(encoding="utf-8")
    for name in EXAMPLES:
        assert (ROOT / "docs" / "examples" / f"{name}.png").stat().st_size > 5000
        assert f"examples/{name}.png" in page and f"examples/{name}.py" in page


@pytest.mark.parametrize("name", EXAMPLES)
def test_the_example_runs_and_draws_its_figure(name: str, tmp_path: Path) -> None:
    done = subprocess.run([sys.executable, str(ROOT / "examples" / f"{name}.py"), str(tmp_path)],
                          cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    figure = tmp_path / f"{name}.png"
    assert figure.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and figure.stat().st_size > 5000
    assert f"results in {tmp_path}" in done.stdout

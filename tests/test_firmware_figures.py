"""docs/firmware_figures.py: the measured figures of docs/firmware.md and
docs/firmware-emulated.md are the script's output.

The cheap blocks (the NUCLEO image's memory, its step pulses on the rehosted TIM1) are
measured again and compared with the document; the QEMU block takes a build of the
generated model and is left to a full run of the script.
"""

from __future__ import annotations

import importlib.util
import shutil
from pathlib import Path
from types import ModuleType

import pytest

from hil.emulators.firmware_qemu import qemu_available

ROOT = Path(__file__).resolve().parents[1]
pytest.importorskip("unicorn", reason="needs the unicorn package (pip install unicorn)")


@pytest.fixture(scope="module")
def figures() -> ModuleType:
    missing = qemu_available(need_qemu=False)
    if missing:
        pytest.skip(f"needs the Debian packages: {' '.join(missing)}")
    spec = importlib.util.spec_from_file_location("firmware_figures",
                                                  ROOT / "docs" / "firmware_figures.py")
    assert spec and spec.loader
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_documents_cheap_figures_are_current(figures: ModuleType,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    code = figures.main(["--check", "--cheap"])
    assert code == 0, capsys.readouterr().out


def test_a_stale_figure_is_named_and_regenerated(figures: ModuleType, tmp_path: Path,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    doc = tmp_path / "firmware-emulated.md"  # the page that holds nucleo-memory
    shutil.copyfile(figures.DOCS / doc.name, doc)
    text = doc.read_text()
    start = text.index("<!-- figures:nucleo-memory -->")
    end = text.index("<!-- /figures:nucleo-memory -->")
    doc.write_text(text[:start] + "<!-- figures:nucleo-memory -->\n| typed | 15 052 B |\n"
                   + text[end:])
    assert figures.main(["--check", "--cheap", "--doc", str(doc)]) == 1
    assert "block nucleo-memory is stale" in capsys.readouterr().out
    assert figures.main(["--cheap", "--doc", str(doc)]) == 0
    assert doc.read_text() == text  # written back as the document has it


def test_a_document_without_the_blocks_is_refused(figures: ModuleType, tmp_path: Path,
                                                  capsys: pytest.CaptureFixture[str]) -> None:
    doc = tmp_path / "firmware-emulated.md"
    doc.write_text("# no figures here\n")
    assert figures.main(["--check", "--cheap", "--doc", str(doc)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: firmware-emulated.md has no block nucleo-memory, nucleo-tick")
    other = tmp_path / "notes.md"  # named like no page: it must hold every block
    other.write_text("# no figures here\n")
    assert figures.main(["--check", "--cheap", "--doc", str(other)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: notes.md has no block nucleo-memory, nucleo-pulses, nucleo-tick")


def test_each_block_is_on_the_page_the_script_names(figures: ModuleType) -> None:
    """Each block sits on the page BLOCKS names, and only there (the page was split)."""
    for name, (_, _, page) in figures.BLOCKS.items():
        holders = [p.name for p in (ROOT / "docs").glob("*.md")
                   if f"<!-- figures:{name} -->" in p.read_text(encoding="utf-8")]
        assert holders == [page], (name, holders)

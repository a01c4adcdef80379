"""The documentation site (mkdocs.yml, issue 48) builds strictly and offline: a broken link,
anchor or API reference fails the build; the pages load no fonts or scripts from the
network; the API reference is generated from the docstrings of the public API."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def site(tmp_path_factory: pytest.TempPathFactory) -> Path:
    mkdocs = Path(sys.executable).with_name("mkdocs")
    if not mkdocs.exists() and shutil.which("mkdocs") is None:
        pytest.fail("mkdocs is not installed: pip install -e '.[docs]' (the test extra has it)")
    out = tmp_path_factory.mktemp("site")
    done = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir",
                           str(out)], cwd=ROOT, capture_output=True, text=True, timeout=300,
                          env={"NO_MKDOCS_2_WARNING": "1", "PATH": "/usr/bin:/bin"})
    assert done.returncode == 0, done.stderr[-3000:]
    assert "WARNING" not in done.stderr
    return out


def test_the_site_builds_strictly_with_every_page(site: Path) -> None:
    for page in ("index", "getting-started", "guide/planning", "api/controllers", "seeds",
                 "examples", "rig", "rig-protocol", "rig-protocol-behaviour", "firmware",
                 "firmware-emulated", "fmu", "design", "design-runs", "design-throughput",
                 "planning", "planning-drive", "unequal-halves", "unequal-halves-results"):
        assert (site / f"{page}.html").is_file(), page


def test_the_pages_load_nothing_from_the_network(site: Path) -> None:
    for page in site.rglob("*.html"):
        html = page.read_text(encoding="utf-8")
        remote = re.findall(r'<(?:script|link|img)[^>]*(?:src|href)="(https?://[^"]+)"', html)
        assert not remote, f"{page.name} loads {remote}"
        assert "fonts.googleapis" not in html


def test_the_api_reference_is_generated_from_the_docstrings(site: Path) -> None:
    html = (site / "api" / "controllers.html").read_text(encoding="utf-8")
    from controllers.api import plan_stroke

    assert "plan_stroke" in html and "export" in html
    first = plan_stroke.__doc__.splitlines()[0]
    assert first.split("(")[0].strip() in html  # the docstring's first line, rendered


def test_the_broken_link_check_is_on(tmp_path: Path) -> None:
    """A page with a broken link fails the strict build (the check above could pass by
    checking nothing)."""
    docs = tmp_path / "docs"
    docs.mkdir()
    (docs / "index.md").write_text("# x\n\n[broken](nowhere.md)\n", encoding="utf-8")
    config = (ROOT / "mkdocs.yml").read_text(encoding="utf-8")
    config = config.split("\nnav:")[0].replace("paths: [.]", f"paths: [{ROOT}]")
    (tmp_path / "mkdocs.yml").write_text(config, encoding="utf-8")
    done = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict"], cwd=tmp_path,
                          capture_output=True, text=True, timeout=300,
                          env={"NO_MKDOCS_2_WARNING": "1", "PATH": "/usr/bin:/bin"})
    assert done.returncode != 0 and "nowhere.md" in done.stderr

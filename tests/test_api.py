"""The public API (issue 48): its names and signatures are the committed list
(tests/api_names.txt, written by ``python tests/api_names.py --write``), every function of it
has a Google-style docstring, and importing the packages stays cheap (the names load their
modules on first use; ``hil --version`` answers before the command's imports)."""

from __future__ import annotations

import importlib
import inspect
import subprocess
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))
from api_names import LIST, PACKAGES, api_lines  # noqa: E402


def test_the_api_is_the_committed_list() -> None:
    """A name or signature changed without the list: deliberate changes rewrite the list."""
    committed = LIST.read_text(encoding="utf-8").splitlines()
    now = api_lines()
    added, removed = sorted(set(now) - set(committed)), sorted(set(committed) - set(now))
    assert not added and not removed, (
        f"the public API changed: added {added}, removed {removed}; if deliberate, run "
        "`python tests/api_names.py --write` and commit tests/api_names.txt")


@pytest.mark.parametrize("package", PACKAGES)
def test_every_public_function_has_a_google_style_docstring(package: str) -> None:
    module = importlib.import_module(package)
    assert module.__all__ and len(set(module.__all__)) == len(module.__all__)
    for name in module.__all__:
        obj = getattr(module, name)
        doc = inspect.getdoc(obj) or ""
        assert doc, f"{package}.{name} has no docstring"
        if inspect.isfunction(obj):
            params = [p for p in inspect.signature(obj).parameters if p != "self"]
            assert not params or "\nArgs:\n" in doc, f"{package}.{name}: no Args: section"
            assert "\nReturns:\n" in doc, f"{package}.{name}: no Returns: section"
            for param in params:
                assert f"\n    {param}: " in doc, f"{package}.{name}: {param} undocumented"


def test_importing_the_packages_loads_nothing_heavy() -> None:
    """The names load their modules on first use: ``import toggle`` etc. stay cheap (the
    commands' ``--version`` and signal handlers rely on it)."""
    code = ("import sys, toggle, controllers, fmu_src, design, hil; "
            "print(sorted(m for m in ('numpy', 'casadi', 'scipy', 'fmpy', 'matplotlib') "
            "if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout
    assert out.strip() == "[]"


def test_hil_version_answers_before_the_commands_imports() -> None:
    """``hil --version`` prints what argparse's version action prints, without importing
    numpy (the fast path in hil/__init__.py)."""
    hil = Path(sys.executable).with_name("hil")
    if not hil.exists():
        pytest.skip("the hil script is not installed beside this Python")
    fast = subprocess.run([str(hil), "--version"], capture_output=True, text=True, check=True)
    from toggle import __version__

    assert fast.stdout == f"hil {__version__}\n" and fast.stderr == ""
    slow = subprocess.run([sys.executable, "-m", "hil.cli", "--version"], capture_output=True,
                          text=True, check=True)
    assert slow.stdout.split()[-1] == __version__  # argparse's answer, the same version

"""The floors of the project (tests/import_graph.py): every import of every module runs down
a floor or stays in its package, packages on one floor import nothing of each other, every
package has a floor, and no modules import each other in a circle."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from import_graph import FLOORS, ROOT, cycles, findings, module_graph, packages


def test_every_import_runs_down_and_nothing_is_circular() -> None:
    assert findings() == []


def test_every_package_folder_has_a_floor() -> None:
    assert set(packages()) == set(FLOORS)


def test_the_model_imports_nothing_above_it_at_run_time() -> None:
    """Beyond the source: importing the model's modules loads no other package."""
    modules = sorted(m for m in module_graph() if m.split(".")[0] == "toggle")
    code = ("import importlib, sys\n"
            f"for m in {modules!r}: importlib.import_module(m)\n"
            "print(sorted({m.split('.')[0] for m in sys.modules}))")
    loaded = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                            check=True, cwd=ROOT).stdout
    assert not [pkg for pkg in FLOORS if pkg != "toggle" and f"'{pkg}'" in loaded], loaded


def test_the_checks_find_an_import_up_a_circle_and_an_unplaced_package(tmp_path: Path) -> None:
    """The checker itself: a tree with each fault is reported."""
    for pkg, text in {"toggle": "from controllers import plan\n",
                      "controllers": "", "extra": ""}.items():
        (tmp_path / pkg).mkdir()
        (tmp_path / pkg / "__init__.py").write_text(text)
    (tmp_path / "controllers" / "plan.py").write_text("from controllers import other\n")
    (tmp_path / "controllers" / "other.py").write_text("from controllers.plan import x\n")
    found = findings(tmp_path)
    assert "package extra/ has no floor in tests/import_graph.py FLOORS" in found
    assert any("toggle (floor 0) imports controllers.plan (floor 1): up" in f for f in found)
    assert cycles(module_graph(tmp_path)) == [["controllers.other", "controllers.plan"]]


def test_the_room_check_finds_an_import_up_a_room(tmp_path: Path) -> None:
    """hil's rooms (import_graph.ROOMS): the host side importing the command line is reported,
    as is the package's own module importing a room and a module outside every room."""
    for room in ("", "link", "host", "cli"):
        (tmp_path / "hil" / room).mkdir(parents=True, exist_ok=True)
        (tmp_path / "hil" / room / "__init__.py").write_text("")
    (tmp_path / "hil" / "__init__.py").write_text("from hil.host import run\n")
    (tmp_path / "hil" / "host" / "run.py").write_text("from hil.cli import main\n")
    (tmp_path / "hil" / "cli" / "main.py").write_text("from hil.link import wire\n")
    (tmp_path / "hil" / "link" / "wire.py").write_text("")
    (tmp_path / "hil" / "loose.py").write_text("")
    found = findings(tmp_path)
    assert "hil.host.run (room host) imports hil.cli.main (room cli): up" in found
    assert "hil (the package's own) imports hil.host.run (room host)" in found
    assert "hil.loose: not in a room of ROOMS" in found
    assert not any("hil.cli.main" in f and "link" in f for f in found)


def test_string_imports_are_read_and_make_a_circle(tmp_path: Path) -> None:
    """``importlib.import_module("...")``, ``__import__`` and a dotted name given to another
    loader count as imports (fmu_src.slave loaded fmu_src.build so, which imported it back:
    a circle the checker did not see, issue 47)."""
    (tmp_path / "fmu_src").mkdir()
    (tmp_path / "fmu_src" / "__init__.py").write_text("")
    (tmp_path / "fmu_src" / "build.py").write_text("from fmu_src.slave import Var\n")
    (tmp_path / "fmu_src" / "slave.py").write_text(
        "import importlib\n"
        "def to_xml():\n"
        "    return importlib.import_module('fmu_src.build')\n")
    (tmp_path / "fmu_src" / "host.py").write_text(
        "import pkgutil\nx = __import__('fmu_src.state')\n"
        "y = pkgutil.resolve_name('fmu_src.guard:CODE')\n")
    (tmp_path / "fmu_src" / "state.py").write_text("")
    (tmp_path / "fmu_src" / "guard.py").write_text("")
    graph = module_graph(tmp_path)
    assert graph["fmu_src.slave"] == {"fmu_src.build"}
    assert graph["fmu_src.host"] == {"fmu_src.state", "fmu_src.guard"}
    assert cycles(graph) == [["fmu_src.build", "fmu_src.slave"]]
    assert "circle: fmu_src.build <-> fmu_src.slave" in findings(tmp_path)

"""Any unpack path (issues 28, 39): the pythonfmu FMU extracted under a folder whose path
holds a space, ``%``, ``#``, ``é`` and the text ``%20`` runs in fmpy (a fresh process), in
the C host and in the FMI Compliance Checker (when FMUCHECK names it). Masters pass the
resource folder as a percent-encoded file: URI; the guard decodes it and hands pythonfmu
(which decodes only %20 itself) the plain path, or /proc/self/fd/N for a path holding
"%20"."""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

import pytest
from fmpy import extract
from fmu_support import BARE_ENV, built_fmu, compile_c_host, run_c_host, run_fresh

from toggle.kinematics import stroke_limits
from toggle.plant import configure

ODD = "unpacked here 100% #1 é %20 a%20b"  # pythonfmu alone read %20 as a space
X_OPEN, X_TOGGLE = stroke_limits(configure("chang2021").mechanism.lower)


@pytest.fixture(scope="module")
def odd_folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("paths") / ODD
    folder.mkdir()
    return folder


def test_fmpy_runs_the_fmu_unpacked_under_an_odd_path(odd_folder: Path):
    signal = ("x_cmd", [0.0, 1.0], [X_OPEN, X_OPEN + 2e-3])
    result = run_fresh(built_fmu("clamp"), odd_folder, signal, ["x"], stop_time=0.05,
                       step_size=1e-3, start_values={"x_cmd": X_OPEN, "drive_bandwidth": 0.0})
    assert ODD in result["unzip"] and "%" in (Path(result["unzip"]) / "resources").as_uri()
    assert result["last"]["x"] == pytest.approx(X_OPEN + 2e-3 * 0.049, abs=1e-12)  # 1 step late


def test_the_c_host_runs_the_fmu_unpacked_under_an_odd_path(odd_folder: Path):
    unzipped = Path(extract(str(built_fmu("clamp")), str(odd_folder / "for the C host")))
    run = run_c_host(compile_c_host(odd_folder), unzipped, 2.5, loads=1)
    assert run.returncode == 0, run.stderr
    status, force = run.stdout.split()
    assert status == "0" and float(force) != 0.0


def test_the_compliance_checker_runs_the_fmu_unpacked_under_an_odd_path(odd_folder: Path):
    checker = os.environ.get("FMUCHECK")
    if not checker:
        pytest.skip("set FMUCHECK to an fmuCheck.linux64 (see docs/fmu.md)")
    work = odd_folder / "checker"
    work.mkdir()
    log, out = work / "check.log", work / "out.csv"
    run = subprocess.run([checker, "-t", str(work), "-l", "3", "-e", str(log), "-o", str(out),
                          str(built_fmu("clamp"))], capture_output=True, text=True, timeout=300,
                         env=BARE_ENV)
    text = log.read_text()
    assert run.returncode == 0, text
    assert "0 warning(s) and error(s)" in text, text


def test_the_fmu_holds_no_path_of_the_build_machine():
    """No file of the FMU names this checkout, this venv or its base Python (issue 39)."""
    import sys
    import zipfile

    from fmu_src.build import ROOT

    machine = {str(ROOT), sys.prefix, sys.base_prefix, str(Path.home())} - {"/", ""}
    with zipfile.ZipFile(built_fmu("clamp")) as zf:
        for name in zf.namelist():
            data = zf.read(name)
            found = [m for m in machine if m.encode() in data]
            assert not found, (name, found)


def test_a_master_without_python_runs_the_fmu_in_another_venv(tmp_path: Path):
    """The C host with VIRTUAL_ENV naming a second venv (its packages reached through a .pth
    file, as a fresh venv with the project installed has them) runs; without VIRTUAL_ENV, a
    Python lacking the packages refuses the instance with one line naming what is missing,
    and the host gets NULL, not a crash."""
    import sys
    import sysconfig

    venv = tmp_path / "second venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True)
    site = venv / "lib" / f"python{sys.version_info.major}.{sys.version_info.minor}"
    (site / "site-packages" / "reach.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    unzipped = Path(extract(str(built_fmu("clamp")), str(tmp_path / "fmu")))
    host = compile_c_host(tmp_path)
    run = run_c_host(host, unzipped, 2.5, 1, {"PATH": "/usr/bin:/bin", "VIRTUAL_ENV": str(venv)})
    assert run.returncode == 0, run.stderr
    bare = run_c_host(host, unzipped, 2.5, 1, {"PATH": "/usr/bin:/bin", "HOME": str(tmp_path)})
    assert bare.returncode > 0  # a failed instantiation, not a signal
    lines = [line for line in bare.stderr.splitlines() if "ToggleClamp.fmu:" in line
             or "cannot load Python" in line]
    assert len(lines) == 1 and ("No module named" in lines[0] or "VIRTUAL_ENV" in lines[0])

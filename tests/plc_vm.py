"""pyplcopen's Structured Text VM and axis model, built from its sdist for the tests.

pyplcopen's source distribution ships a header-only C++ ST compiler, bytecode VM and axis
model (``core/``) whose MC_CamTableSelect/MC_CamIn couple a slave to a master through a
table of at most 64 points, interpolated linearly. :func:`cam_vm` fetches the sdist with
pip (the version installed by the test extra), compiles ``tests/plc/cam_vm.cpp`` against
its ``core/`` with g++, and caches the executable under the checkout's ``build/`` keyed by
the version and the driver's digest, so a suite builds it once. No source of pyplcopen is
kept: the sdist is unpacked in a temporary directory and removed.
"""

from __future__ import annotations

import hashlib
import importlib.metadata
import shutil
import subprocess
import sys
import tarfile
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DRIVER = Path(__file__).with_name("plc") / "cam_vm.cpp"


def cam_vm() -> Path:
    """The built driver (``tests/plc/cam_vm.cpp`` on pyplcopen's VM); built on first use."""
    version = importlib.metadata.version("pyplcopen")
    digest = hashlib.sha256(DRIVER.read_bytes()).hexdigest()[:12]
    target = ROOT / "build" / "pyplcopen-vm" / f"cam_vm-{version}-{digest}"
    if target.is_file():
        return target
    compiler = shutil.which("g++")
    if compiler is None:
        raise RuntimeError("g++ is needed to build pyplcopen's ST VM")
    with tempfile.TemporaryDirectory() as tmp:
        subprocess.run([sys.executable, "-m", "pip", "download", "-q", "--no-deps",
                        "--no-binary", ":all:", "-d", tmp, f"pyplcopen=={version}"],
                       check=True)
        with tarfile.open(next(Path(tmp).glob("pyplcopen-*.tar.gz"))) as sdist:
            core = [m for m in sdist.getmembers() if m.name.split("/")[1:2] == ["core"]]
            sdist.extractall(tmp, members=core, filter="data")
        include = next(Path(tmp).glob("pyplcopen-*/core"))
        target.parent.mkdir(parents=True, exist_ok=True)
        scratch = target.with_suffix(".tmp")
        # -O0: the driver runs a few thousand scans; optimising costs more than it saves
        subprocess.run([compiler, "-std=c++17", "-O0", "-I", str(include), "-o",
                        str(scratch), str(DRIVER)], check=True)
        scratch.replace(target)
    return target

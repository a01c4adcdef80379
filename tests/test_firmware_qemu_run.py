"""``hil run --real`` against the firmware's Cortex-M build in QEMU and its host build.

The recipe of docs/rig.md with ``hil emulate --firmware --qemu`` and with ``hil emulate
--firmware``, each in its own process as a user starts them, and the same run on both: one
cycle at 40 mm/s. The two builds run the same core on the same plant (the native FMU's
C, compiled for the Cortex-M4 and for this machine), so the platen reads the same
encoder count in every sample; forces carry each run's own load-cell noise. (The default
job, 3 cycles: 18602 samples on both, stroke 44.9870 mm on both; docs/firmware-emulated.md.)
"""

from __future__ import annotations

import csv
import os
import subprocess
import sys
from pathlib import Path

import pytest
from hil_host import SHORT_RUN, hil

from hil.emulators.firmware_qemu import qemu_available

pytestmark = pytest.mark.alone

#: The plain run: no --ack-ms, --watchdog-ms or --heartbeat-ms; the host measures the link
#: (issue 35: the QEMU run needed --ack-ms 100 --heartbeat-ms 1000 by hand).
RUN = SHORT_RUN
#: Jobs in the CPU-hog test: one in the suite (each is about a minute of the suite's ten,
#: alone on the machine); HIL_QEMU_JOBS=3 is issue 35's acceptance, 3 of 3.
JOBS = int(os.environ.get("HIL_QEMU_JOBS", "1"))


def _run_on(emulate: list[str], out: Path, run: tuple[str, ...] = RUN,
            cycles: int = 1) -> tuple[list[dict[str, str]], str]:
    """``hil run --real`` against a fresh ``hil emulate`` (so unreferenced: it homes);
    the samples and the run's stderr."""
    proc = subprocess.Popen([sys.executable, "-m", "hil.cli", "emulate", *emulate],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        port = proc.stdout.readline().strip()
        assert port.startswith("/dev/"), proc.stderr.read()
        code, stdout, stderr = hil("run", "--real", "--port", port, "--out", str(out), *run,
                                   timeout=600.0)
        assert code == 0 and f"{cycles} of {cycles} cycles complete" in stdout, stderr
    finally:
        proc.terminate()
        proc.wait(timeout=20)
    assert proc.returncode == 143  # SIGTERM ends the emulator cleanly (QEMU with it): 128 + 15
    with (out / "samples.csv").open(newline="") as fh:
        return list(csv.DictReader(fh)), stderr


def test_the_qemu_build_runs_the_job_as_the_host_build(tmp_path: Path) -> None:
    missing = qemu_available()
    if missing:
        pytest.skip(f"needs the Debian packages: {' '.join(missing)}")
    qemu, _ = _run_on(["--firmware", "--qemu"], tmp_path / "qemu")
    host, _ = _run_on(["--firmware"], tmp_path / "host")
    assert len(qemu) == len(host) > 2000
    assert [r["platen [m]"] for r in qemu] == [r["platen [m]"] for r in host]
    assert [r["x_cmd [m]"] for r in qemu] == [r["x_cmd [m]"] for r in host]
    rms = [sum(float(r["force [N]"]) ** 2 for r in rows) / len(rows) for rows in (qemu, host)]
    assert rms[0] == pytest.approx(rms[1], rel=0.01)
    assert not subprocess.run(["pgrep", "-f", "qemu-system-arm -M netduinoplus2"],
                              capture_output=True).stdout  # no QEMU left behind


def test_the_default_job_on_qemu_beside_a_cpu_hog(tmp_path: Path) -> None:
    """Issue 35's acceptance: the plain ``hil run --real --port PTY`` (the default job: the
    planned profile, 3 cycles) on ``hil emulate --firmware --qemu`` with one CPU hog
    running, homing included (each job a freshly booted, unreferenced rig), JOBS of JOBS.
    It failed in homing (chunk ACKs of 67-408 ms, HEARTBEAT_LOST at 251 ms)."""
    missing = qemu_available()
    if missing:
        pytest.skip(f"needs the Debian packages: {' '.join(missing)}")
    hog = subprocess.Popen([sys.executable, "-c", "while 1: pass"])
    try:
        for job in range(JOBS):
            rows, stderr = _run_on(["--firmware", "--qemu"], tmp_path / f"job{job}",
                                   run=("--quiet",), cycles=3)
            assert "homing at its home switch" in stderr, stderr
            assert len(rows) > 18000, len(rows)
    finally:
        hog.kill()
        hog.wait()

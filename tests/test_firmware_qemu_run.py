"""``hil run --real`` against the firmware's Cortex-M build in QEMU and its host build.

The README's recipe with ``hil emulate --firmware --qemu`` and with ``hil emulate
--firmware``, each in its own process as a user starts them, and the same run on both: one
cycle at 40 mm/s. The two builds run the same core on the same plant (the native FMU's
C, compiled for the Cortex-M4 and for this machine), so the platen reads the same
encoder count in every sample; forces carry each run's own load-cell noise. (The default
job, 3 cycles: 18602 samples on both, stroke 44.9870 mm on both; docs/firmware.md.)
"""

from __future__ import annotations

import csv
import subprocess
import sys
from pathlib import Path

import pytest
from hil_host import SHORT_RUN, hil

from hil.firmware_qemu import qemu_available

pytestmark = pytest.mark.alone

# QEMU's UART takes a byte about every 50 us; QEMU's clock runs on while a loaded machine
# (the suite's other worker, QEMU's own thread) holds back the relay: 1 s of heartbeat
# watchdog, where a gap of 251 ms once stopped the run at the default 250 ms
RUN = (*SHORT_RUN, "--ack-ms", "100", "--heartbeat-ms", "1000")


def _run_on(emulate: list[str], out: Path) -> list[dict[str, str]]:
    proc = subprocess.Popen([sys.executable, "-m", "hil.cli", "emulate", *emulate],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        port = proc.stdout.readline().strip()
        assert port.startswith("/dev/"), proc.stderr.read()
        code, stdout, stderr = hil("run", "--real", "--port", port, "--out", str(out), *RUN)
        assert code == 0 and "1 of 1 cycles complete" in stdout, stderr
    finally:
        proc.terminate()
        proc.wait(timeout=20)
    assert proc.returncode == 0  # SIGTERM ends the emulator cleanly (QEMU with it)
    with (out / "samples.csv").open(newline="") as fh:
        return list(csv.DictReader(fh))


def test_the_qemu_build_runs_the_job_as_the_host_build(tmp_path: Path) -> None:
    missing = qemu_available()
    if missing:
        pytest.skip(f"needs the Debian packages: {' '.join(missing)}")
    qemu = _run_on(["--firmware", "--qemu"], tmp_path / "qemu")
    host = _run_on(["--firmware"], tmp_path / "host")
    assert len(qemu) == len(host) > 2000
    assert [r["platen [m]"] for r in qemu] == [r["platen [m]"] for r in host]
    assert [r["x_cmd [m]"] for r in qemu] == [r["x_cmd [m]"] for r in host]
    rms = [sum(float(r["force [N]"]) ** 2 for r in rows) / len(rows) for rows in (qemu, host)]
    assert rms[0] == pytest.approx(rms[1], rel=0.01)
    assert not subprocess.run(["pgrep", "-f", "qemu-system-arm -M netduinoplus2"],
                              capture_output=True).stdout  # no QEMU left behind

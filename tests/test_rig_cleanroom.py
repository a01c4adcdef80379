"""The project's host against a clean-room MCU written from docs/rig-protocol.md
and docs/rig-protocol-behaviour.md alone.

The rig (tests/cleanroom_rig.py and the cleanroom_* modules it names) runs in a spawned
process on a pseudo-terminal; the host (`hil.cli.main`) runs in this process, exactly as
against a real rig.
"""

from __future__ import annotations

import csv
import json
import os
import time
import tty
from collections.abc import Iterator
from pathlib import Path

import pytest
from cleanroom_commands import Run
from cleanroom_rig import CleanroomRig
from cleanroom_wire import (
    ACK,
    ACK_FMT,
    ACK_REQ,
    HELLO,
    HELLO_FMT,
    TELEMETRY,
    TELEMETRY_FMT,
    cobs_decode,
    crc16,
    frame,
)

from hil.cli.main import main

pytestmark = [pytest.mark.real_time,
              pytest.mark.skipif(not hasattr(os, "openpty"), reason="needs a pty")]


@pytest.fixture
def rig() -> Iterator[CleanroomRig]:
    """A freshly booted clean-room rig (its own process and pty)."""
    r = CleanroomRig()
    try:
        yield r
    finally:
        r.close()


def _run(rig: CleanroomRig, out: Path, *extra: str) -> int:
    return main(["run", "--real", "--port", rig.port, "--speed", "25e-3", "--cycles", "1",
                 "--out", str(out), "--quiet", *extra])


def _rows(path: Path) -> list[dict[str, str]]:
    with path.open(newline="") as f:
        return list(csv.DictReader(f))


def _last_run(rig: CleanroomRig, before: int) -> Run:
    runs = rig.runs()
    assert len(runs) > before, f"the rig saw no new START: {runs}"
    return runs[-1]


def _check_complete_run(rig: CleanroomRig, out: Path, runs_before: int) -> Run:
    summary = json.loads((out / "summary.json").read_text())
    assert summary["cycles_complete"] == 1, summary
    run = _last_run(rig, runs_before)
    rows = _rows(out / "samples.csv")
    assert len(rows) == run.samples, (len(rows), run, rig.stats())
    assert run.end_state == 1 and run.exec_index == run.points  # IDLE, run complete
    return run


def test_codec_matches_the_worked_examples() -> None:
    """COBS, CRC and layouts reproduce section 12 byte for byte."""
    assert crc16(b"123456789") == 0x29B1
    hello = frame(HELLO, 1, 1, HELLO_FMT.pack(1, 0, 0x12345678))
    assert hello.hex(" ") == "04 01 01 01 02 01 07 78 56 34 12 d6 b7 00"
    ack = frame(ACK, 0, 0, ACK_FMT.pack(1, 0, 1, 12, 0, 2048))
    assert ack.hex(" ") == "02 80 01 01 02 01 01 03 01 0c 01 01 01 01 01 04 08 92 1a 00"
    tel = frame(TELEMETRY, 0, 0x0203, TELEMETRY_FMT.pack(
        0x5EED0001, 1500, 1_500_250, 30_000, 12_004, 121_500, 1499, 548, 0, 2, 0x1B))
    assert tel.hex(" ") == (
        "02 82 04 03 02 01 05 ed 5e dc 05 01 04 5a e4 16 03 30 75 01 03 e4 2e 01 04 "
        "9c da 01 03 db 05 01 03 24 02 01 05 02 1b 04 07 00")
    assert cobs_decode(tel[:-1]) is not None


def test_host_runs_twice_against_the_cleanroom_rig(rig: CleanroomRig, tmp_path: Path) -> None:
    """A run records exactly the rig's samples from START to standstill; a second follows."""
    n = len(rig.runs())
    assert _run(rig, tmp_path / "run") == 0
    first = _check_complete_run(rig, tmp_path / "run", n)
    stats = rig.stats()
    assert stats["state"] == "BOOT" and not stats["session"], stats  # BYE ended the session
    assert stats["referenced"] and stats["faults"] == 0, stats
    assert not stats.get("tx_dropped_in_session"), stats

    n = len(rig.runs())
    assert _run(rig, tmp_path / "run2") == 0
    second = _check_complete_run(rig, tmp_path / "run2", n)
    assert second.start_sample > first.end_sample
    assert rig.stats()["state"] == "BOOT"


def test_status_force_limit_stop_and_recovery(rig: CleanroomRig, tmp_path: Path,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    """`rig status` works; a 5 N force limit stops the run (exit 1); a normal run follows."""
    assert main(["rig", "status", "--port", rig.port]) == 0
    assert rig.stats()["state"] == "BOOT"

    capsys.readouterr()
    n = len(rig.runs())
    assert _run(rig, tmp_path / "limited", "--force-limit", "5") == 1
    captured = capsys.readouterr()
    text = (captured.out + captured.err).lower()
    assert "force" in text and "limit" in text, text
    run = _last_run(rig, n)
    assert run.faults & 0x0001 and run.end_state == 4, run  # FORCE_LIMIT, FAULT
    summary = json.loads((tmp_path / "limited" / "summary.json").read_text())
    assert summary["cycles_complete"] == 0
    assert "FORCE_LIMIT" in str(summary.get("abort_reason")), summary
    assert len(_rows(tmp_path / "limited" / "samples.csv")) == run.samples
    stats = rig.stats()
    assert stats["faults"] == 0 and stats["state"] == "BOOT", stats  # cleared, then BYE

    n = len(rig.runs())
    assert _run(rig, tmp_path / "after") == 0
    _check_complete_run(rig, tmp_path / "after", n)


def test_host_works_with_a_later_minor_version(tmp_path: Path) -> None:
    """Section 10: a 1.1 host ignores appended fields, new flag bits and new MCU types."""
    with CleanroomRig(future=True) as rig:
        assert main(["rig", "status", "--port", rig.port]) == 0
        n = len(rig.runs())
        assert _run(rig, tmp_path / "run") == 0
        _check_complete_run(rig, tmp_path / "run", n)
        meta = json.loads((tmp_path / "run" / "meta.json").read_text())
        assert meta["plant"]["protocol"] == "1.4"


def test_fault_left_by_a_dead_host_needs_rig_clear(rig: CleanroomRig, tmp_path: Path,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    """Section 8, "Who clears": HEARTBEAT_LOST from a vanished host blocks `hil run`."""
    fd = os.open(rig.port, os.O_RDWR | os.O_NOCTTY)
    try:
        tty.setraw(fd)
        os.write(fd, frame(HELLO, ACK_REQ, 100, HELLO_FMT.pack(1, 1, 42)))
        time.sleep(0.45)  # no heartbeats: the MCU's 250 ms watchdog trips
    finally:
        os.close(fd)
    stats = rig.stats()
    assert stats["state"] == "FAULT" and stats["faults"] == 0x0040, stats
    capsys.readouterr()
    assert _run(rig, tmp_path / "refused") == 1
    captured = capsys.readouterr()
    assert "HEARTBEAT_LOST" in captured.out + captured.err
    assert rig.stats()["faults"] == 0x0040  # not cleared by `hil run`
    assert main(["rig", "clear", "--port", rig.port]) == 0
    stats = rig.stats()
    assert stats["faults"] == 0 and stats["state"] == "BOOT", stats


def test_bringup_store_and_tare_against_the_cleanroom_rig(
        rig: CleanroomRig, capsys: pytest.CaptureFixture[str]) -> None:
    """Protocol 1.3 from the document alone: the host reads the stored calibration (none:
    the default), tares, stores a calibration and reads it back in a new session."""
    def run(*args: str) -> dict[str, object]:
        capsys.readouterr()
        assert main(["rig", *args, "--port", rig.port, "--json"]) == 0
        return json.loads(capsys.readouterr().out)

    assert run("store") == {"cal_seq": 0, "offset": 1500, "gain": pytest.approx(1e-4)}
    tare = run("tare", "--samples", "200")
    # the rig's cell reads 1500 at zero force, 0.2 N (2000 counts) of noise, one sigma
    assert abs(tare["offset"] - 1500) < 2000 and 0.1 < tare["noise"] < 0.3, tare
    stored = run("store", "--offset", str(tare["offset"]), "--gain", "1.1e-4")
    assert stored == {"cal_seq": 1, "offset": tare["offset"], "gain": pytest.approx(1.1e-4)}
    assert run("store") == stored  # a new session reads the same record
    stats = rig.stats()
    assert stats["state"] == "BOOT" and not stats["faults"], stats

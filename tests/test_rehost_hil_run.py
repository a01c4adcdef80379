"""`hil emulate --firmware --board nucleo` from the command line: whole `hil run` jobs on
the rehosted NUCLEO image (docs/firmware-emulated.md, "The rehosted image"), its options, and the
host build they are compared with. Minutes each: marked ``alone`` or ``real_time``."""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest

from hil.emulators.mcu_model import RigHardware
from hil.host.backends import RigSetup
from hil.link import protocol as p

unicorn = pytest.importorskip("unicorn", reason="needs the unicorn package (pip install unicorn)")

from hil.emulators.rehost.nucleo import NucleoBoard, NucleoRig  # noqa: E402


@pytest.mark.alone
def test_hil_run_on_the_rehosted_image_agrees_with_the_host_build(elf: Path,
                                                                  tmp_path: Path) -> None:
    """`hil emulate --firmware --board nucleo` and `hil emulate --firmware` (each in its own
    process, as a user starts them) run the same short job: the same samples and commanded
    positions, the same stroke to a few encoder counts (the rehosted plant follows the
    pulses as TIM1 emits them, about 1.7 periods behind the host build's sim, which `hil
    emulate --firmware` runs with its steps at once), forces alike in their statistics
    (each run draws its own noise). The plain command: the host measures the link when the
    session opens (the rehost runs slower than the wall clock)."""
    import csv
    import json
    import signal
    import sys

    from hil_host import SHORT_RUN, hil

    def run_on(emulate: list[str], out: Path) -> tuple[list[dict[str, str]], dict]:
        proc = subprocess.Popen([sys.executable, "-m", "hil.cli", "emulate", *emulate],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            port = proc.stdout.readline().strip()
            assert port.startswith("/dev/"), proc.stderr.read()
            code, stdout, stderr = hil("run", "--real", "--port", port, "--out", str(out),
                                       *SHORT_RUN, timeout=300.0)
            assert code == 0 and "1 of 1 cycles complete" in stdout, stderr
        finally:
            proc.send_signal(signal.SIGINT)
            _, err = proc.communicate(timeout=30)
        assert proc.returncode == 130, err  # SIGINT: 128 + 2, as every command
        print(" ".join(emulate), "|", err.strip().splitlines()[-1:])
        with (out / "samples.csv").open(newline="") as fh:
            return list(csv.DictReader(fh)), json.loads((out / "summary.json").read_text())

    rehost, r_summary = run_on(["--firmware", "--board", "nucleo"], tmp_path / "rehost")
    host, h_summary = run_on(["--firmware"], tmp_path / "host")
    assert len(rehost) == len(host) > 2000
    assert [r["x_cmd [m]"] for r in rehost] == [r["x_cmd [m]"] for r in host]
    strokes = [max(float(r["platen [m]"]) for r in rows) - min(float(r["platen [m]"])
                                                                for r in rows)
               for rows in (rehost, host)]
    assert abs(strokes[0] - strokes[1]) <= 5e-6, strokes  # 5 encoder counts
    rms = [sum(float(r["force [N]"]) ** 2 for r in rows) / len(rows) for rows in (rehost, host)]
    assert rms[0] == pytest.approx(rms[1], rel=0.01)
    print(f"strokes {strokes[0] * 1e3:.4f} / {strokes[1] * 1e3:.4f} mm; samples {len(host)}; "
          f"cycles {r_summary.get('cycles_complete')} / {h_summary.get('cycles_complete')}")


@pytest.mark.parametrize(("args", "message"), [
    (["--board", "nucleo"], "--board nucleo runs the firmware: give --firmware too"),
    (["--firmware", "--board", "nucleo", "--qemu"], "two ways to run the firmware: give one"),
    (["--firmware", "--board", "nucleo", "--junk", "0.1"], "injects no faults: drop junk"),
    (["--step-timing", "nucleo"], "--step-timing chooses the host build's table timing"),
    (["--firmware", "--board", "nucleo", "--step-timing", "nucleo"], "without --board"),
    (["--load-noise", "-1"], "must be an rms force in N"),
])
def test_hil_emulate_board_refuses_what_it_cannot_do(args: list[str], message: str) -> None:
    import sys

    result = subprocess.run([sys.executable, "-m", "hil.cli", "emulate", *args],
                            capture_output=True, text=True, timeout=60)
    assert result.returncode == 2 and message in result.stderr, result.stderr  # usage
    assert result.stdout == "" and "Traceback" not in result.stderr


@pytest.mark.real_time
def test_hil_run_pulses_on_the_timer_equal_the_commanded_steps(elf: Path, tmp_path: Path) -> None:
    """`hil run --real --port PTY` (homing, the move to the start, one cycle at 40 mm/s:
    tests/hil_host.py SHORT_RUN, the shortest job that homes and runs a whole cycle; the
    default 3 cycles take three times as long) on the paced rehosted image. Counted on the
    emulator's side: the rising edges TIM1's model put on PA8 (and TIM3's model counted)
    equal the steps the firmware commanded, period by period, in every telemetry sample it
    sent (homing included); over the recorded cycle they equal the host's commanded
    positions; the table stands where the firmware's and the host's last position says."""
    import csv

    from hil_host import SHORT_RUN, X_OPEN, hil

    board = NucleoBoard(elf, seed=9, rng_seed=13)
    decoder, telemetry = p.FrameDecoder(), []
    take = board.take_output

    def tap() -> bytes:  # every byte the image sent, decoded beside the pty
        data = take()
        telemetry.extend(m for m in map(p.parse_message, decoder.feed(data))
                         if isinstance(m, p.Telemetry))
        return data

    board.take_output = tap  # type: ignore[method-assign]
    out = tmp_path / "run"
    with NucleoRig(board) as rig:
        code, stdout, stderr = hil("run", "--real", "--port", rig.port, "--out", str(out),
                                   *SHORT_RUN, timeout=120.0)
        with rig.paused():
            rig.check()
            pulses_pa8 = sum(b.rises(b.end) for b in board.tim1.bursts if b.output)
            tim3_count = board.tim3.read(0x24, 4)  # CNT, as the firmware reads it
    assert code == 0 and "1 of 1 cycles complete" in stdout, stderr
    assert [reason for _, reason in board.log.resets] == ["power-on"]
    # telemetry flows in sessions only (the probe's, the host's): none lost within one,
    # and the table does not move between them
    pairs = list(zip(telemetry, telemetry[1:]))
    gaps = [(a, b) for a, b in pairs if b.sample != a.sample + 1]
    assert all(b.sample > a.sample and b.steps == a.steps for a, b in gaps), gaps
    assert all(t.flags & p.TelemetryFlag.SESSION for t in telemetry)
    moves = [(t.steps - prev.steps) for prev, t in pairs
             if t.sample == prev.sample + 1 and t.flags & p.TelemetryFlag.MOVING]
    # (a SET_POSITION is no move)
    commanded = sum(abs(d) for d in moves)
    assert pulses_pa8 == commanded > 0
    assert tim3_count == commanded & 0xFFFF  # TIM3 (16 bits) counted TIM1's TRGO from boot
    assert board.log.pulses_ignored == 0
    assert board.log.pulses == board.plant.steps == sum(moves)  # signed: the table's place
    # the recorded cycle: the host's commanded positions, step by step
    with (out / "samples.csv").open(newline="") as fh:
        rows = list(csv.DictReader(fh))
    step_m = 200e-9
    x_cmd = [float(r["x_cmd [m]"]) for r in rows]
    host_steps = sum(abs(round((b - a) / step_m)) for a, b in zip(x_cmd, x_cmd[1:]))
    first, last = int(rows[0]["sample"]), int(rows[-1]["sample"])
    by_sample = {t.sample: t for t in telemetry}
    in_run = sum(abs(by_sample[s].steps - by_sample[s - 1].steps)
                 for s in range(first + 1, last + 1)
                 if by_sample[s].flags & p.TelemetryFlag.MOVING)
    assert host_steps == in_run > 0
    homing = commanded - in_run
    assert homing > 0  # the homing and the approach moved too
    # the final position: the firmware's last count is the host's last x_cmd, and the table
    # stands where the pulses put it, shifted only by homing's SET_POSITION (no pulses)
    final = telemetry[-1]
    assert round((x_cmd[-1] - X_OPEN) / step_m) == final.steps
    reference = board.plant.steps - final.steps  # table steps at the host's step 0
    status = board.plant.status()
    assert status.x == pytest.approx(X_OPEN + board.plant.steps * step_m, abs=1e-12)
    print(f"{len(board.tim1.bursts)} bursts: {pulses_pa8} pulses on PA8, TIM3 "
          f"{tim3_count}; commanded {commanded} steps ({in_run} in the recorded cycle, "
          f"{homing} homing and approach); table at {status.x * 1e3:.4f} mm, host's last "
          f"x_cmd {x_cmd[-1] * 1e3:.4f} mm; the host's step 0 is the table's step {reference} "
          f"(the home switch opens at step 1); {rig.summary()}")


def _pulses_and_moves(board: NucleoBoard, telemetry: list[p.Telemetry]) -> tuple[int, int]:
    """(rising edges TIM1's model put on PA8, steps the firmware's telemetry commanded)."""
    pulses = sum(b.rises(b.end) for b in board.tim1.bursts if b.output)
    pairs = zip(telemetry, telemetry[1:])
    return pulses, sum(abs(t.steps - prev.steps) for prev, t in pairs
                       if t.sample == prev.sample + 1 and t.flags & p.TelemetryFlag.MOVING)


@pytest.mark.alone
def test_the_default_job_agrees_with_the_host_build_at_the_boards_step_timing(
        elf: Path, tmp_path: Path) -> None:
    """`hil run --real --port PTY --cycles 1` (the default job's plan, homing and the first
    of its 3 cycles: the whole job, measured in docs/firmware-emulated.md, took the suite a
    minute alone and checks nothing more) on the rehosted
    image as `hil emulate --firmware --board nucleo --load-noise 0` serves it, and on `hil
    emulate --firmware --step-timing nucleo --load-noise 0` from the command line: the same
    samples and commanded positions; from the cycles' first move on the same encoder
    counts, and the forces to the ADC's resolution once the start's transient has gone
    (the plant's state at START depends on the dwell before it, wall-clock time that the
    rehost emulates slower: docs/firmware-emulated.md). On the rehosted image every step pulse of
    the whole job (homing included) is a rising edge on PA8: their count equals the steps
    the firmware's telemetry commanded. Minutes: the rehosted image runs below real time."""
    import csv
    import signal
    import sys

    from hil_host import hil

    from hil.emulators.rig_physics import ClampPhysics

    def rows(out: Path) -> list[dict[str, str]]:
        with (out / "samples.csv").open(newline="") as fh:
            return list(csv.DictReader(fh))

    setup = RigSetup()
    hw = RigHardware(x_origin=setup.stroke[0], load_noise_n=0.0)
    physics = ClampPhysics(setup.preset, setup.delta_r8, setup.mu, setup.x_contact)
    board = NucleoBoard(elf, physics, hw, seed=1)  # as hil emulate --seed 1 (its default)
    decoder, telemetry = p.FrameDecoder(), []
    take = board.take_output

    def tap() -> bytes:
        data = take()
        telemetry.extend(m for m in map(p.parse_message, decoder.feed(data))
                         if isinstance(m, p.Telemetry))
        return data

    board.take_output = tap  # type: ignore[method-assign]
    with NucleoRig(board) as rig:
        code, stdout, stderr = hil("run", "--real", "--port", rig.port, "--quiet", "--out",
                                   str(tmp_path / "rehost"), "--cycles", "1", timeout=900.0)
        with rig.paused():
            rig.check()
            pulses, commanded = _pulses_and_moves(board, telemetry)
    assert code == 0 and "1 of 1 cycles complete" in stdout, stderr
    print(f"the default job's first cycle on the rehosted image: {pulses} rising edges on PA8, "
          f"{commanded} steps commanded in its telemetry; {rig.summary()}")
    assert pulses == commanded > 0 and board.log.pulses_ignored == 0
    proc = subprocess.Popen([sys.executable, "-m", "hil.cli", "emulate", "--firmware",
                             "--step-timing", "nucleo", "--load-noise", "0"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        port = proc.stdout.readline().strip()
        assert port.startswith("/dev/"), proc.stderr.read()
        code, stdout, stderr = hil("run", "--real", "--port", port, "--quiet", "--out",
                                   str(tmp_path / "host"), "--cycles", "1", "--watchdog-ms", "1000",
                                   "--heartbeat-ms", "1000", "--ack-ms", "500",
                                   timeout=300.0)  # bounds a loaded machine keeps
        assert code == 0 and "1 of 1 cycles complete" in stdout, stderr
    finally:
        proc.send_signal(signal.SIGINT)
        proc.communicate(timeout=30)
    rehost, host = rows(tmp_path / "rehost"), rows(tmp_path / "host")
    assert len(rehost) == len(host) > 5_000
    assert [r["x_cmd [m]"] for r in rehost] == [r["x_cmd [m]"] for r in host]
    counts = [abs(round((float(a["platen [m]"]) - float(b["platen [m]"])) / 1e-6))
              for a, b in zip(rehost, host)]
    forces = [abs(float(a["force [N]"]) - float(b["force [N]"])) for a, b in zip(rehost, host)]
    moved = next(i for i, r in enumerate(host) if r["x_cmd [m]"] != host[0]["x_cmd [m]"])
    lsb = hw.load_gain_n
    settled = next(i for i in range(len(forces)) if max(forces[i:]) <= lsb * 1.01)
    print(f"{len(host)} samples; platen apart by at most {max(counts)} counts "
          f"({max(counts[moved:])} from the first move, sample {moved}), force by "
          f"{max(forces):.3g} N ({max(forces[moved:]):.3g} N from the first move; within "
          f"1 LSB = {lsb:g} N from sample {settled})")
    assert max(counts[moved:]) == 0
    assert settled < 1000  # the start's transient gone within a second of the cycle

"""The NUCLEO-F446RE image rehosted (hil/emulators/rehost/,
docs/firmware-emulated.md "The rehosted image").

The ELF `make -C firmware/board nucleo` writes, bytes unchanged, runs on the unicorn CPU
emulator with models of the STM32F446 peripherals and the ADS131M02, joined to the
simulated rig. Most tests drive the board in-process (protocol frames into its USART, its
emulated time run without pacing); one serves it on a pty as `hil emulate --firmware
--board nucleo` does.
"""

from __future__ import annotations

import subprocess
import time
from collections.abc import Callable
from pathlib import Path

import pytest

from hil.emulators.mcu_model import RigHardware
from hil.host.backends import RigSetup
from hil.link import protocol as p

unicorn = pytest.importorskip("unicorn", reason="needs the unicorn package (pip install unicorn)")

from hil.emulators.rehost.machine import UNITS_PER_S, UnsupportedAccessError  # noqa: E402
from hil.emulators.rehost.nucleo import NucleoBoard, NucleoRig  # noqa: E402
from hil.emulators.rehost.pulses import TMC5160, full_rate_reversal  # noqa: E402
from hil.emulators.rehost.stm32f446.flash import PowerCutError  # noqa: E402

NO_CHECK = -(2**31)


class Session:
    """A host in-process: frames into the board's USART, its replies decoded."""

    def __init__(self, board: NucleoBoard) -> None:
        self.board = board
        self.decoder = p.FrameDecoder()
        self.seq = 0
        self.messages: list[p.Message] = []

    def run(self, seconds: float, heartbeat: float = 0.05) -> None:
        """Run the board, a heartbeat every ``heartbeat`` s (the MCU's watchdog is 250 ms)."""
        left = seconds
        while left > 1e-9:
            step = min(left, heartbeat)
            self.board.run(step)
            left -= step
            self.messages += [p.parse_message(f)
                              for f in self.decoder.feed(self.board.take_output())]
            self.board.receive(p.encode_message(p.Heartbeat(0), self._next(), 0))

    def _next(self) -> int:
        self.seq = (self.seq + 1) & 0xFFFF
        return self.seq

    def command(self, msg: p.Message, wait: float = 0.01) -> p.Message:
        """Send ``msg`` and return its reply (ACK or HELLO_REPLY)."""
        seq = self._next()
        self.board.receive(p.encode_message(msg, seq, p.FLAG_ACK_REQ))
        for _ in range(20):
            self.run(wait)
            for m in self.messages:
                if getattr(m, "acked_seq", None) == seq:
                    return m
        raise AssertionError(f"no reply to {msg}")

    def hello(self) -> p.HelloReply:
        """HELLO, sent again every 50 ms as a host does (bytes sent before the firmware
        turns its USART on are lost, as on the chip)."""
        for _ in range(20):
            seq = self._next()
            self.board.receive(b"\x00" + p.encode_message(p.Hello(host_nonce=0x5EED), seq,
                                                          p.FLAG_ACK_REQ))
            self.run(0.05)
            for m in self.messages:
                if isinstance(m, p.HelloReply) and m.acked_seq == seq:
                    assert m.result == p.Result.OK
                    return m
        raise AssertionError("no HELLO_REPLY in 1 s")

    def upload(self, points: list[tuple[int, int]]) -> None:
        for first in range(0, len(points), p.MAX_CHUNK_POINTS):
            chunk = tuple(points[first:first + p.MAX_CHUNK_POINTS])
            final = p.TrajChunk.FINAL if first + len(chunk) == len(points) else 0
            ack = self.command(p.TrajChunk(first_index=first, flags=final, points=chunk))
            assert ack.result == p.Result.OK, ack

    def faults(self) -> list[p.FaultReport]:
        return [m for m in self.messages if isinstance(m, p.FaultReport)]

    def telemetry(self) -> list[p.Telemetry]:
        return [m for m in self.messages if isinstance(m, p.Telemetry)]


def _board(elf: Path, hw: RigHardware | None = None,
           **inject: object) -> tuple[NucleoBoard, Session]:
    """A board powered on with the given faults injected (attribute paths: 'adc__present')."""
    board = NucleoBoard(elf, hw=hw, seed=3, rng_seed=11)
    for path, value in inject.items():
        obj, _, name = path.rpartition("__")
        setattr(getattr(board, obj) if obj else board, name, value)
    if inject:
        board.machine.reset("power-on")
    board.run(0.02)
    return board, Session(board)


def _profile(full: int, periods: int) -> list[tuple[int, int]]:
    """Out at ``full`` steps per period, a full-rate reversal, back to 0, then a hold."""
    steps, pos = [], 0
    for delta in [full] * periods + [-full] * periods + [0] * 5:
        pos += delta
        steps.append((pos, NO_CHECK))
    return steps


def test_the_image_is_the_flashed_elf_and_answers_hello_on_a_pty(elf: Path) -> None:
    serial = pytest.importorskip("serial")
    board = NucleoBoard(elf)
    assert board.elf_sha256 == __import__("hashlib").sha256(elf.read_bytes()).hexdigest()
    flashed = elf.with_suffix(".bin").read_bytes()  # what a programmer writes at 0x08000000
    assert board.machine.read_bytes(0x08000000, len(flashed)) == flashed
    print(f"rehosted {elf}: sha256 {board.elf_sha256}")
    with NucleoRig(board) as rig:
        port = serial.Serial(rig.port, 921600, timeout=0.05)
        decoder = p.FrameDecoder()
        reply = None
        deadline = time.monotonic() + 20.0
        while reply is None and time.monotonic() < deadline:
            port.write(b"\x00" + p.encode_message(p.Hello(host_nonce=77), 5, p.FLAG_ACK_REQ))
            end = time.monotonic() + 0.5
            while reply is None and time.monotonic() < end:
                for f in decoder.feed(port.read(4096)):
                    m = p.parse_message(f)
                    if isinstance(m, p.HelloReply) and m.acked_seq == 5:
                        reply = m
        port.close()
        rig.check()
        ratio = rig.time_ratio
    assert reply is not None and reply.result == p.Result.OK and reply.host_nonce == 77
    assert reply.boot_id != 0 and reply.state == p.State.IDLE
    assert 0 < ratio <= 1.0 + 1e-3  # paced: never ahead of the wall clock
    print(f"emulated/wall time {ratio:.3f}")


def test_the_plain_host_runs_a_trajectory_on_the_paced_pty(elf: Path) -> None:
    """The host with no timeouts given (as `hil run --real --port PTY`: measured when the
    session opens, docs/rig-protocol-behaviour.md section 7) on the pty NucleoRig publishes once the
    image answered HELLO and BYE: 300 ms of trajectory out and back, every sample received,
    the image's clock never faster than the wall clock. (The default job takes minutes on
    the rehost: docs/firmware-emulated.md "The rehosted image".)"""
    pytest.importorskip("serial")
    from hil.link.serial_link import SerialLink

    board = NucleoBoard(elf, seed=5, rng_seed=7)
    with NucleoRig(board) as rig:
        assert rig.port.startswith("/dev/")
        answered_at = board.now_s  # the probe's HELLO and BYE were answered by then
        wall0, emu0 = time.monotonic(), board.now_s
        with SerialLink(rig.port) as link:
            assert link.open().state == p.State.IDLE  # measures the link
            link.configure(link.config_for(force_limit_n=50e3))  # as measured
            points = _profile(5, 145)  # 5 steps per ms out for 145 ms, back, a 5 ms hold
            for first in range(0, len(points), p.MAX_CHUNK_POINTS):
                chunk = points[first:first + p.MAX_CHUNK_POINTS]
                link.send_chunk(first, chunk, final=first + len(chunk) == len(points))
            start = link.start().sample
            samples = []
            while not samples or samples[-1].sample < start + len(points) + 5:
                samples.append(link.next_sample(timeout=2 * link.telemetry_timeout))
            timing, stats = link.timing, link.stats
        wall, emu = time.monotonic() - wall0, board.now_s - emu0
        rig.check()
    assert answered_at > 0
    assert timing is not None and timing.clock_rate <= 1.05, timing  # never faster
    assert emu <= wall + NucleoRig.SLICE_S
    assert stats.lost_samples == 0 and stats.duplicates == 0 and stats.queue_dropped == 0
    assert [s.sample for s in samples] == list(range(samples[0].sample,
                                                     samples[-1].sample + 1))
    assert samples[-1].state == p.State.IDLE and samples[-1].steps == points[-1][0] == 0
    assert max(s.steps for s in samples) == 5 * 145
    assert board.log.pulses == 0 and board.log.pulses_ignored == 0
    print(f"{timing.text()}; ACK timeout {link.ack_timeout * 1e3:.0f} ms, watchdog "
          f"{link.telemetry_timeout * 1e3:.0f} ms, heartbeat {link.heartbeat_timeout_ms} ms; "
          f"{emu:.3f} s emulated in {wall:.3f} s; {stats.retransmissions} retransmissions")


def test_step_pulses_equal_the_commanded_steps_and_meet_the_drivers_timing(elf: Path) -> None:
    """256 steps per period (TIM1's longest burst) out, back at once: every commanded step
    is a rising edge on PA8, and STEP high and low, DIR setup and hold meet the TMC5160's
    minimums (hil.emulators.rehost.pulses.TMC5160, from its datasheet)."""
    board, timing, telemetry = full_rate_reversal(elf, periods=12, steps=256)
    last = telemetry[-1]
    assert not [m for m in telemetry if m.faults] and last.state == p.State.IDLE
    assert last.steps == 0  # out and back
    assert timing.pulses == 2 * 12 * 256  # every pulse on PA8
    assert board.log.pulses == board.plant.steps == last.steps  # signed: out and back
    assert board.log.pulses_ignored == 0
    assert timing.dir_setup_s is not None and timing.dir_hold_s is not None
    assert timing.step_high_s >= TMC5160.step_high_s and timing.step_low_s >= TMC5160.step_low_s
    assert timing.dir_setup_s >= TMC5160.dir_setup_s and timing.dir_hold_s >= TMC5160.dir_hold_s
    assert timing.meets(TMC5160)
    print(f"{timing.bursts} bursts, {timing.pulses} pulses; STEP high >= "
          f"{timing.step_high_s * 1e6:.2f} us, low >= {timing.step_low_s * 1e6:.2f} us; at a "
          f"full-rate reversal DIR hold {timing.dir_hold_s * 1e6:.2f} us, setup "
          f"{timing.dir_setup_s * 1e6:.2f} us ({TMC5160.source})")


def test_a_step_delta_over_the_boards_limit_is_refused(elf: Path) -> None:
    """1.3: the image states its 256-step limit and refuses a larger max_step_delta as
    BAD_VALUE, as the model and the host build do (it took 300, then latched INTERNAL at
    START: the burst over 256 steps is still not emitted, now unreachable by the wire)."""
    board, s = _board(elf)
    assert s.hello().max_step_delta_limit == p.MAX_STEP_DELTA == 256
    assert s.command(p.Config(max_step_delta=257)).result == p.Result.BAD_VALUE
    assert s.command(p.Config(max_step_delta=256)).result == p.Result.OK
    assert not s.faults() and board.log.pulses == 0


def test_a_config_over_a_full_buffer_never_makes_a_tick_late(elf: Path) -> None:
    """A CONFIG re-checking 2048 buffered points took 56 105 instructions in one rig_rx
    (a tick due in it armed its burst after the 290 us deadline even at CPI 1); with the
    block summaries it reads one block. Counted exactly by the image's DWT."""
    from hil.emulators.rehost.tick_cost import measure

    cost = measure(elf)
    assert cost.late_ticks == 0 and cost.step_errors == 0
    assert 0 < cost.config_rx < 8_000  # 31 summaries and one 64-point block
    assert cost.deadline_cpi() >= 3.0, cost
    print(f"CONFIG over 2048 points: {cost.config_rx} instructions; worst rig_rx "
          f"{cost.rx_max}, worst tick {cost.tick_max}: the arming deadline holds to CPI "
          f"{cost.deadline_cpi():.1f}")


def _enable_at(board: NucleoBoard, t: int) -> bool:
    level = False
    for when, value in board.log.enable:
        if when <= t:
            level = value
    return level


def test_a_hardfault_takes_the_enable_low_before_the_watchdog_resets(elf: Path) -> None:
    board, s = _board(elf)
    first = s.hello()
    s.upload(_profile(100, 100))
    assert s.command(p.Start()).result == p.Result.OK
    s.run(0.03)
    t_fault = board.machine.now
    assert _enable_at(board, t_fault) and board.tim1.burst is not None  # moving
    board.force_hardfault()
    board.run(0.1)
    lows = [t for t, level in board.log.enable if not level and t >= t_fault]
    resets = [t for t, reason in board.log.resets if reason == "IWDG"]
    assert lows and resets and lows[0] < resets[0]
    assert (lows[0] - t_fault) / UNITS_PER_S < 20e-6  # the handler's first instructions
    assert not [b for b in board.tim1.bursts if b.start > lows[0]]  # no burst after it
    assert 0.03 < (resets[0] - t_fault) / UNITS_PER_S < 0.06  # IWDG: 50 ms
    assert s.hello().boot_id != first.boot_id  # it boots again
    print(f"enable low {(lows[0] - t_fault) / UNITS_PER_S * 1e6:.1f} us after the "
          f"HardFault, IWDG reset after {(resets[0] - t_fault) / UNITS_PER_S * 1e3:.1f} ms")


def test_a_debugger_halt_freezes_the_watchdog_and_the_tick(elf: Path) -> None:
    board, s = _board(elf)
    s.hello()
    ticks = board.tim5.updates
    board.debug_halt(0.2)  # four times the watchdog's 50 ms
    assert board.dbg.frozen("IWDG") and board.dbg.frozen("TIM5") and board.dbg.frozen("TIM1")
    assert board.tim5.updates == ticks
    s.run(0.02)
    assert [reason for _, reason in board.log.resets] == ["power-on"]


@pytest.mark.parametrize(("inject", "fault", "value"), [
    ({"rcc__pll_locks": False}, p.Fault.CLOCK, 2),
    ({"rcc__hse_present": False}, p.Fault.CLOCK, 1),
    ({"adc__present": False}, p.Fault.LOAD_ADC, 1),
], ids=["pll-never-locks", "no-hse", "adc-missing"])
def test_a_board_fault_at_boot_is_named_and_nothing_moves(elf: Path, inject: dict,
                                                           fault: p.Fault, value: int) -> None:
    board, s = _board(elf, **inject)
    s.hello()  # the link works (on the HSI when the PLL failed)
    s.run(0.01)
    assert [(f.fault, f.value) for f in s.faults()] == [(fault, value)]
    assert s.telemetry()[-1].state == p.State.FAULT
    assert s.command(p.ClearFault()).result == p.Result.FAULT_ACTIVE
    assert s.command(p.TrajChunk(first_index=0, flags=1, points=((10, NO_CHECK),))
                     ).result != p.Result.OK or s.command(p.Start()).result != p.Result.OK
    s.run(0.02)
    assert board.log.pulses == 0 and not board.tim1.bursts


def _moving(elf: Path) -> tuple[NucleoBoard, Session]:
    board, s = _board(elf)
    s.hello()
    s.upload(_profile(50, 200))
    assert s.command(p.Start()).result == p.Result.OK
    s.run(0.02)
    assert board.tim1.burst is not None and not s.faults()
    return board, s


@pytest.mark.parametrize(("poke", "fault", "value", "within"), [
    ("limit_open", p.Fault.OVERTRAVEL, 1, 1e-3),
    ("limit_closed", p.Fault.OVERTRAVEL, 2, 1e-3),
    ("chain_broken", p.Fault.STOP_CHAIN, 1, 21e-3),
], ids=["overtravel-open-end", "overtravel-closed-end", "stop-chain-open"])
def test_an_input_fault_while_moving_stops_the_steps(elf: Path, poke: str, fault: p.Fault,
                                                     value: int, within: float) -> None:
    board, s = _moving(elf)
    t0 = board.machine.now
    setattr(board, poke, True)
    s.run(0.04)
    assert [(f.fault, f.value) for f in s.faults()] == [(fault, value)]
    assert s.telemetry()[-1].state == p.State.FAULT
    limit = t0 + round((within + 1e-3) * UNITS_PER_S)  # the tick that reads it, + 1 period
    late = [b for b in board.tim1.bursts if b.start > limit]
    assert not late
    cut = [b for b in board.tim1.bursts if b.cut is not None]
    assert all(b.cut <= limit for b in cut)
    assert board.log.pulses == board.plant.steps == s.telemetry()[-1].steps
    # a board's fault de-energises the driver in the tick that latched it (section 8)
    lows = [t for t, level in board.log.enable if not level and t >= t0]
    assert lows and lows[0] <= limit and not board.enable_level()
    assert not s.telemetry()[-1].flags & p.TelemetryFlag.DRIVER_ENABLED


def test_start_into_an_open_stop_chain_emits_no_step(elf: Path) -> None:
    """At rest the enable is low, so an open chain looks normal; START enables the driver
    and the run's first point waits for the chain's feedback: 20 periods later STOP_CHAIN,
    with not one pulse on PA8 and the enable low again."""
    board, s = _board(elf)
    s.hello()
    s.upload(_profile(50, 20))
    board.chain_broken = True
    s.run(0.01)
    assert not s.faults()
    t0 = board.machine.now
    assert s.command(p.Start()).result == p.Result.OK
    s.run(0.04)
    assert [(f.fault, f.value) for f in s.faults()] == [(p.Fault.STOP_CHAIN, 1)]
    last = s.telemetry()[-1]
    assert last.state == p.State.FAULT and last.steps == 0 and last.exec_index == 0
    assert board.log.pulses == 0 and not [b for b in board.tim1.bursts if b.n]
    highs = [t for t, level in board.log.enable if level and t >= t0]
    assert highs and not board.enable_level()


@pytest.mark.parametrize(("inject", "value"), [("crc_errors", 1), ("drdy_stuck", True),
                                               ("status_set", 0x0400)],
                         ids=["bad-crc", "drdy-timeout", "status-reset"])
def test_adc_health_faults_are_named(elf: Path, inject: str, value: object) -> None:
    board, s = _moving(elf)
    setattr(board.adc, inject, value)
    s.run(0.02)
    code = {"crc_errors": 3, "drdy_stuck": 2, "status_set": 4}[inject]
    assert [(f.fault, f.value) for f in s.faults()] == [(p.Fault.LOAD_ADC, code)]
    assert s.telemetry()[-1].state == p.State.FAULT
    assert board.log.pulses == board.plant.steps == s.telemetry()[-1].steps
    assert not board.enable_level()  # de-energised (section 8)


def test_an_access_no_model_implements_is_an_error(elf: Path) -> None:
    board, _ = _board(elf)
    with pytest.raises(UnsupportedAccessError, match="TIM1"):
        board.tim1.write(0x48, 4, 0)  # DCR: DMA bursts are not modelled
    with pytest.raises(UnsupportedAccessError, match="no peripheral"):
        board.machine._mmio_read(board.machine.uc, 0x400, 4, 0x40010000)  # TIM8


def test_the_objdump_finds_the_images_wfi(elf: Path) -> None:
    board = NucleoBoard(elf)
    out = subprocess.run(["arm-none-eabi-objdump", "-d", str(elf)], capture_output=True,
                         text=True, check=True).stdout
    assert len(board.machine.wfi_returns) == out.count("\twfi")


def _chunks(points: list[tuple[int, int]]) -> list[p.TrajChunk]:
    return [p.TrajChunk(first_index=first, points=tuple(points[first:first + p.MAX_CHUNK_POINTS]),
                        flags=p.TrajChunk.FINAL if first + p.MAX_CHUNK_POINTS >= len(points)
                        else 0)
            for first in range(0, len(points), p.MAX_CHUNK_POINTS)]


PREFILL_CHUNKS = 50  # 1500 points before START (the MCU buffers 2048)


def _stream(command: Callable[[p.Message], p.Message], wait: Callable[[], None],
            points: list[tuple[int, int]]) -> None:
    """Prefill, START, the rest of the chunks as the buffer takes them (no underrun)."""
    chunks = _chunks(points)
    for chunk in chunks[:PREFILL_CHUNKS]:
        assert command(chunk).result == p.Result.OK
    assert command(p.Start()).result == p.Result.OK
    for chunk in chunks[PREFILL_CHUNKS:]:
        while (ack := command(chunk)).result == p.Result.NO_SPACE:
            wait()
        assert ack.result == p.Result.OK, ack


def _host_build_run(hw: RigHardware, config: p.Config, points: list[tuple[int, int]],
                    seconds_: float) -> list[p.Telemetry]:
    """The host build with the NUCLEO's step timing, the same session as the board's (HELLO,
    CONFIG, the trajectory streamed, START, heartbeats), one tick per millisecond."""
    from hil.emulators.firmware import FirmwareMcu
    from hil.emulators.rig_physics import ClampPhysics

    fw = FirmwareMcu(ClampPhysics(), hw, seed=3, step_timing="nucleo")
    now, seq = 0.0, 0
    decoded: list[p.Message] = []

    def take(frames: list[bytes]) -> None:
        decoded.extend(p.parse_message(p.decode_frame(f[:-1])) for f in frames)

    def tick() -> None:
        nonlocal now
        take(fw.tick(now))
        now += 1e-3

    def command(msg: p.Message) -> p.Message:
        nonlocal seq
        seq += 1
        take(fw.receive(p.encode_message(msg, seq, p.FLAG_ACK_REQ), now))
        for _ in range(10):  # as the board's session: 10 ms per command
            tick()
        return next(m for m in decoded if getattr(m, "acked_seq", None) == seq)

    for _ in range(3):
        tick()
    assert command(p.Hello(host_nonce=0x5EED)).result == p.Result.OK
    assert command(config).result == p.Result.OK
    _stream(command, lambda: [tick() for _ in range(50)], points)
    while now < seconds_:
        seq += 1
        take(fw.receive(p.encode_message(p.Heartbeat(0), seq, 0), now))
        for _ in range(50):
            tick()
    return [m for m in decoded if isinstance(m, p.Telemetry)]


def _the_run(telemetry: list[p.Telemetry]) -> list[p.Telemetry]:
    """From the START's first RUNNING sample to 20 samples after the first IDLE after it."""
    start = next(i for i, t in enumerate(telemetry) if t.state == p.State.RUNNING)
    end = next(i for i in range(start, len(telemetry))
               if telemetry[i].state == p.State.IDLE)
    assert len(telemetry) >= end + 20, "the run did not end in time"
    return telemetry[start:end + 20]


def test_the_host_build_with_the_boards_step_timing_agrees_sample_by_sample(elf: Path) -> None:
    """The plant of the rehosted image (stepped at its ticks, fed the pulses TIM1's model
    emitted) and the host build's with step_timing "nucleo" (sim_rig.c emitting a period's
    steps as step_burst.h says the board does) see the same table positions at the same
    instants: a stroke to the toggle and back at 40 mm/s (200 steps per period, the whole
    force range) gives the same encoder count in every sample and load-cell codes within
    1 LSB (the load cell's noise off: each draws it from its own sequence)."""
    from hil.host.experiment import stroke_positions

    setup = RigSetup()
    hw = RigHardware(x_origin=setup.stroke[0], load_noise_n=0.0)
    x_open, x_toggle = setup.stroke
    forward = list(stroke_positions(x_open, x_toggle, 40e-3, setup.period, setup.limits))
    points = [(round((x - x_open) / 200e-9), NO_CHECK) for x in forward + forward[-2::-1]]
    config = p.Config(force_limit_n=400.0, steps_min=-50_000, steps_max=400_000,
                      enc_min=-500_000, enc_max=500_000, max_step_delta=p.MAX_STEP_DELTA)
    board, s = _board(elf, hw=hw)
    s.hello()
    assert s.command(config).result == p.Result.OK
    _stream(s.command, lambda: s.run(0.05), points)
    for _ in range(50):
        s.run(0.1)
        if s.telemetry()[-1].exec_index == len(points):
            break
    s.run(0.05)
    assert not s.faults()
    rehost = _the_run(s.telemetry())
    host = _the_run(_host_build_run(hw, config, points, len(points) * 1e-3 + 1.0))
    assert len(rehost) == len(host) > 2000
    assert [t.steps for t in rehost] == [t.steps for t in host]
    assert max(t.steps for t in host) == max(pt[0] for pt in points)
    enc_r, enc_h = [t.enc for t in rehost], [t.enc for t in host]
    assert max(enc_h) - min(enc_h) > 40_000  # the platen travelled its 45 mm
    differ = [i for i, (a, b) in enumerate(zip(enc_r, enc_h)) if a != b]
    assert not differ, (differ[:5], [(enc_r[i], enc_h[i]) for i in differ[:5]])
    raw = [abs(a.load_raw - b.load_raw) for a, b in zip(rehost, host)]
    assert max(raw) <= 1, max(raw)
    loads = [t.load_raw for t in host]
    print(f"{len(host)} samples: enc equal in all, load_raw differs by at most {max(raw)} "
          f"LSB over {min(loads)}..{max(loads)}; table (TIM1 pulses) {board.plant.steps}")


# --- 1.3: the calibration in flash (firmware/board/cal_flash.c) ---------------------------


def _rebooted(board: NucleoBoard) -> Session:
    """Power the board off and on (flash and the plant kept): a fresh session on it."""
    board.flash.cut_after = None
    board.machine.reset("power-on")
    board.run(0.02)
    session = Session(board)
    session.hello()
    return session


def test_the_rehosted_image_answers_the_calibration_script_as_the_model(elf: Path) -> None:
    """tests/calibration_script.py: the same answers as the model and the host build
    (tests/test_mcu_config.py), its reboot a power cycle of the board."""
    from calibration_script import EXPECTED, calibration_script

    board, s = _board(elf)
    s.hello()
    sessions = [s]

    def reboot() -> p.HelloReply:
        board.flash.cut_after = None
        board.machine.reset("power-on")
        board.run(0.02)
        sessions.append(Session(board))
        return sessions[-1].hello()

    answers = calibration_script(lambda msg: sessions[-1].command(msg), reboot)
    assert answers == EXPECTED


def _record(seq: int, offset: int, gain: float) -> bytes:
    """A calibration record of cal_flash.c, as its 32-byte slot."""
    import struct
    import zlib

    words = struct.pack("<Iif", seq, offset, gain)
    return words + struct.pack("<II", zlib.crc32(words), 0x3250414C) + b"\xff" * 12


def test_a_power_cut_at_any_flash_write_keeps_a_valid_calibration(elf: Path) -> None:
    """The power fails before each of a record's five words in turn: after the reboot the
    previous record is in force, and a new store works (it skips the torn slot)."""
    board, s = _board(elf)
    s.hello()
    assert s.command(p.StoreCalibration(-20_000, 1.25e-4)).cal_seq == 1
    for k in range(5):
        board.flash.cut_after = board.flash.writes + k
        with pytest.raises(PowerCutError):
            s.command(p.StoreCalibration(1000 + k, 2e-4))
        s = _rebooted(board)
        back = s.command(p.ReadCalibration())
        assert (back.cal_seq, back.load_offset) == (1, -20_000), (k, back)
    stored = s.command(p.StoreCalibration(4242, 2e-4))
    assert (stored.result, stored.cal_seq) == (p.Result.OK, 2)
    assert _rebooted(board).hello().load_offset == 4242


def test_a_full_sector_goes_on_in_the_other_and_a_cut_there_keeps_the_last(elf: Path) -> None:
    """Sector 5 full of records (4096): the next store goes to sector 6, which the boot
    erased; a power cut in that write keeps sector 5's newest, and the boot after erases the
    torn sector 6 again; once sector 6 holds the newest, the next boot erases sector 5."""
    from hil.emulators.rehost.stm32f446.flash import Flash

    board, _ = _board(elf)
    sector = Flash.SECTOR_SIZE
    board.flash.memory[:sector] = b"".join(_record(i + 1, -i, 1e-4) for i in range(4096))
    board.flash.memory[sector:sector + 32] = b"\x00" * 32  # junk in sector 6
    s = _rebooted(board)
    assert s.command(p.ReadCalibration()).cal_seq == 4096
    assert board.flash.memory[sector:2 * sector] == b"\xff" * sector  # erased at boot
    board.flash.cut_after = board.flash.writes + 3
    with pytest.raises(PowerCutError):
        s.command(p.StoreCalibration(9, 2e-4))
    s = _rebooted(board)
    assert (s.command(p.ReadCalibration()).cal_seq, s.hello().load_offset) == (4096, -4095)
    assert s.command(p.StoreCalibration(9, 2e-4)).cal_seq == 4097
    s = _rebooted(board)
    assert s.hello().load_offset == 9
    assert board.flash.memory[:sector] == b"\xff" * sector  # the older sector, erased


def test_hsebyp_changes_only_while_hse_is_off(elf: Path) -> None:
    """RM0390 6.3.1: HSEBYP may be written only with HSEON clear. The RCC model refuses a
    write that changes it with HSE on (the image cleared both in one write when HSE was
    missing); the image sets HSEBYP before HSEON and, without HSE, clears it after."""
    board, _ = _board(elf)
    cr = board.rcc.read(0x00, 4)
    assert cr >> 16 & 1 and cr >> 18 & 1  # booted on the ST-LINK's 8 MHz, bypassed
    with pytest.raises(UnsupportedAccessError, match="HSEBYP"):
        board.rcc.write(0x00, 4, cr & ~((1 << 16) | (1 << 18)))  # both in one write
    board, s = _board(elf, rcc__hse_present=False)
    s.hello()
    assert not board.rcc.read(0x00, 4) >> 16 & 7  # HSEON, HSERDY, HSEBYP all clear

"""The step pulses of the rehosted image, measured on TIM1's model, against the named stepper
driver's STEP/DIR minimums (docs/firmware.md "Stepper driver").

:data:`TMC5160` holds the driver's minimums with their source; :func:`burst_timing`
measures a run's bursts (:class:`hil.emulators.rehost.stm32f446.timers.Burst`);
:func:`full_rate_reversal` runs the image through the hardest case, 256 steps per period out
and back with an instant reversal, and returns what it measured (tests/test_firmware_rehost.py and
docs/firmware_figures.py use it).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from hil.emulators.mcu_model import RigHardware
from hil.emulators.rehost.machine import UNITS_PER_S
from hil.emulators.rehost.nucleo import NucleoBoard
from hil.emulators.rehost.stm32f446.timers import Burst
from hil.link import protocol as p


@dataclass(frozen=True)
class DriverTiming:
    """A stepper driver's STEP/DIR input minimums (s) and where they come from."""

    name: str
    step_high_s: float
    step_low_s: float
    dir_setup_s: float
    dir_hold_s: float
    source: str


#: TMC5160/TMC5160A datasheet Rev. 1.14 (Trinamic, 2020-05-19), section 15.1 "Timing", table
#: "STEP and DIR interface timing" (p. 94): tSH, tSL >= max(tFILTSD, tCLK + 20 ns), tDSU and
#: tDSH >= 20 ns, tFILTSD at most 30 ns; tCLK at the internal oscillator's slowest, 11.5 MHz
#: (chapter 28, table "Clock oscillator and input", p. 122).
_T_FILTSD_MAX_S, _F_CLK_MIN_HZ = 30e-9, 11.5e6
_T_STEP_MIN_S = max(_T_FILTSD_MAX_S, 1 / _F_CLK_MIN_HZ + 20e-9)
TMC5160 = DriverTiming("TMC5160", _T_STEP_MIN_S, _T_STEP_MIN_S, 20e-9, 20e-9,
                       "TMC5160/TMC5160A datasheet Rev. 1.14, section 15.1, p. 94")


@dataclass(frozen=True)
class PulseTiming:
    """What TIM1's model put out: bursts with output, rising edges on PA8, and the shortest
    STEP high and low times, DIR setup and hold at the reversals (s; None without one)."""

    bursts: int
    pulses: int
    step_high_s: float
    step_low_s: float
    dir_setup_s: float | None
    dir_hold_s: float | None

    def meets(self, driver: DriverTiming) -> bool:
        """Every minimum of ``driver`` met (a run without a reversal meets the DIR ones)."""
        return (self.step_high_s >= driver.step_high_s and self.step_low_s >= driver.step_low_s
                and (self.dir_setup_s is None or self.dir_setup_s >= driver.dir_setup_s)
                and (self.dir_hold_s is None or self.dir_hold_s >= driver.dir_hold_s))


def burst_timing(bursts: list[Burst]) -> PulseTiming:
    """Measure ``bursts`` (those with the output on): DIR changes at the update ending the
    burst before a reversal (hold: after that burst's last rising edge) and must be set
    before the first rising edge of the burst after it (setup)."""
    out = [b for b in bursts if b.output]
    if not out:
        raise ValueError("no burst reached the STEP pin")
    setups, holds = [], []
    for prev, b in zip(out, out[1:]):
        if b.dir_high != prev.dir_high:
            last_edge = prev.start + ((prev.n - 1) * prev.period + prev.ccr1) * prev.tick
            first_edge = b.start + b.ccr1 * b.tick
            holds.append((b.dir_since - last_edge) / UNITS_PER_S)
            setups.append((first_edge - b.dir_since) / UNITS_PER_S)
    return PulseTiming(len(out), sum(b.rises(b.end) for b in out),
                       min(b.high_units for b in out) / UNITS_PER_S,
                       min(b.low_units for b in out) / UNITS_PER_S,
                       min(setups) if setups else None, min(holds) if holds else None)


def command_answered(board: NucleoBoard, decoder: p.FrameDecoder, msg: p.Message, seq: int,
             tries: int = 20, prefix: bytes = b"") -> tuple[p.Message, list[p.Message]]:
    """Send ``msg`` (again every 10 ms, as bytes sent before the USART is on are lost) until
    its reply comes; the reply and every message seen."""
    seen: list[p.Message] = []
    for _ in range(tries):
        board.receive(prefix + p.encode_message(msg, seq, p.FLAG_ACK_REQ))
        board.run(0.01)
        seen += [p.parse_message(f) for f in decoder.feed(board.take_output())]
        for m in seen:
            if getattr(m, "acked_seq", None) == seq:
                return m, seen
    raise RuntimeError(f"the rehosted image did not answer {type(msg).__name__}")


def full_rate_reversal(elf: Path, periods: int = 12,
                       steps: int = 256) -> tuple[NucleoBoard, PulseTiming, list[p.Telemetry]]:
    """``steps`` per period (256: TIM1's longest burst) out for ``periods`` periods, the
    same back at once, a 5-period hold; the board, what TIM1's model emitted and the
    telemetry. An instant reversal at 51 mm/s takes more than the load cell's 838 N: the
    board has a load cell 100 times coarser and the CONFIG a force limit to match."""
    from hil.host.backends import RigSetup

    board = NucleoBoard(elf, hw=RigHardware(x_origin=RigSetup().stroke[0], load_gain_n=1e-2),
                        seed=3, rng_seed=11)
    board.run(0.02)
    decoder, seq, messages = p.FrameDecoder(), 0, []

    def command(msg: p.Message, prefix: bytes = b"") -> None:
        nonlocal seq
        seq += 1
        reply, seen = command_answered(board, decoder, msg, seq, prefix=prefix)
        messages.extend(seen)
        if reply.result != p.Result.OK:
            raise RuntimeError(f"{type(msg).__name__} refused: {reply}")

    command(p.Hello(host_nonce=0x5EED), prefix=b"\x00")
    command(p.Config(max_step_delta=steps, force_limit_n=50e3))
    pos, points = 0, []
    for delta in [steps] * periods + [-steps] * periods + [0] * 5:
        pos += delta
        points.append((pos, p.NO_CHECK))
    for first in range(0, len(points), p.MAX_CHUNK_POINTS):
        chunk = tuple(points[first:first + p.MAX_CHUNK_POINTS])
        final = p.TrajChunk.FINAL if first + len(chunk) == len(points) else 0
        command(p.TrajChunk(first_index=first, flags=final, points=chunk))
    command(p.Start())
    for _ in range(len(points) // 10 + 3):
        board.run(0.01)
        messages += [p.parse_message(f) for f in decoder.feed(board.take_output())]
        seq += 1
        board.receive(p.encode_message(p.Heartbeat(0), seq, 0))
    telemetry = [m for m in messages if isinstance(m, p.Telemetry)]
    return board, burst_timing(board.tim1.bursts), telemetry


__all__ = ["TMC5160", "DriverTiming", "PulseTiming", "burst_timing", "full_rate_reversal"]

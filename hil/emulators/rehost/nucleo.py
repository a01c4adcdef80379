"""The NUCLEO-F446RE image rehosted: the ELF `make -C firmware/board nucleo` writes, run
unchanged on :mod:`hil.emulators.rehost.machine` with the peripheral models of
:mod:`hil.emulators.rehost.stm32f446` and :mod:`hil.emulators.rehost.ads131m02`, wired as the
board is
(docs/firmware.md) to the simulated rig.

The rig is the host build's plant (firmware/sim/sim_rig.c on the native FMU, built by
:func:`hil.emulators.firmware.build_host_firmware` with ``plant_only``), stepped once per
millisecond
of emulated time, at the firmware's tick instants (TIM5's update events) while the tick
runs, so the image reads the plant as it stands at its tick (a free 1 ms grid would put a
boot-dependent phase of up to a period between the two): its input is the table position
the step pulses have driven (rising edges on PA8 in TIM1's bursts, direction PA9, counted
only while the driver is enabled on PA10), its platen position is the encoder TIM2 counts,
its force (as load-cell counts with the sim's noise) is what the ADS131M02 converts, and its
home switch is PC0. The host build with ``step_timing="nucleo"`` feeds the same plant the
same positions at the same instants (docs/firmware-emulated.md "Host build and rehost,
sample by sample").

:class:`NucleoBoard` is the board (run it to a time, poke its inputs, read what it did);
:class:`NucleoRig` serves it on a pseudo-terminal, paced so emulated time never runs
faster than the wall clock, and publishes the port once the image answered a HELLO.
"""

from __future__ import annotations

import contextlib
import ctypes
import hashlib
import os
import secrets
import select
import subprocess
import termios
import threading
import time
import tty
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType

from hil.emulators.firmware import (
    BOARD_DIR,
    BUILD_DIR,
    SimRigHw,
    SimRigStatus,
    build_host_firmware,
    check_hardware,
    fmu_start_values,
    make_board,
)
from hil.emulators.firmware_qemu import await_firmware
from hil.emulators.mcu_model import RigHardware
from hil.emulators.rehost.ads131m02 import Ads131m02
from hil.emulators.rehost.cortex import DbgMcu, Dwt, SystemControl
from hil.emulators.rehost.machine import (
    UNITS_PER_S,
    Machine,
    UnsupportedAccessError,
    find_wfi,
    load_elf,
    seconds,
)
from hil.emulators.rehost.stm32f446.clocks import HSE_HZ, Pwr, Rcc
from hil.emulators.rehost.stm32f446.flash import Flash, FlashMemory
from hil.emulators.rehost.stm32f446.gpio import Gpio
from hil.emulators.rehost.stm32f446.iwdg import Iwdg
from hil.emulators.rehost.stm32f446.rng import Rng
from hil.emulators.rehost.stm32f446.spi import Spi
from hil.emulators.rehost.stm32f446.timers import EncoderTimer, PulseCounter, StepTimer, TickTimer
from hil.emulators.rehost.stm32f446.usart_dma import Dma1, Usart
from hil.emulators.rig_physics import ClampPhysics

NUCLEO_ELF = BUILD_DIR / "board-nucleo" / "rig.elf"
PLANT_PERIOD_S = 1e-3

# pins (docs/firmware.md, board_nucleo.h)
PA_STEP, PA_DIR, PA_ENABLE, PA_ENC_A, PA_ENC_B = 8, 9, 10, 0, 1
PB_STOP, PB_DRDY, PB_ADC_RST, PB_ALARM, PB_CHAIN, PB_CS = 0, 1, 2, 4, 5, 12
PC_HOME, PC_LIMIT_OPEN, PC_LIMIT_CLOSED, PC_CLKIN, PC_B1 = 0, 2, 3, 9, 13


def build_nucleo_image() -> Path:
    """``make -C firmware/board nucleo`` (arm-none-eabi-gcc); the ELF it writes.
    RuntimeError with make's output when it fails."""
    result = make_board("nucleo")
    if result.returncode or not NUCLEO_ELF.is_file():
        raise RuntimeError(f"make -C {BOARD_DIR} nucleo failed:\n{result.stdout.strip()}\n"
                           f"{result.stderr.strip()}")
    return NUCLEO_ELF


def sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


class RigInputs(ctypes.Structure):
    """rig_hal.h's rig_inputs, as far as the plant fills it (the rest is padding here)."""

    _fields_ = [("enc", ctypes.c_int32), ("load_raw", ctypes.c_int32),
                ("home_switch", ctypes.c_bool), ("stop_input", ctypes.c_bool),
                ("driver_alarm", ctypes.c_bool), ("spare", ctypes.c_uint8 * 29)]


class Plant:
    """The simulated rig of the host build (sim_rig.c on the FMU), driven by step counts."""

    def __init__(self, physics: ClampPhysics, hw: RigHardware, seed: int) -> None:
        check_hardware(hw, physics.period)
        lib = ctypes.CDLL(str(build_host_firmware(physics.preset, plant_only=True)))
        lib.sim_rig_init.argtypes = [ctypes.POINTER(SimRigHw),
                                     ctypes.POINTER(ctypes.c_char_p),
                                     ctypes.POINTER(ctypes.c_double), ctypes.c_int,
                                     ctypes.c_char_p, ctypes.c_size_t]
        lib.hal_step.argtypes = [ctypes.c_int32]
        lib.hal_read.argtypes = [ctypes.POINTER(RigInputs)]
        lib.sim_rig_get_status.argtypes = [ctypes.POINTER(SimRigStatus)]
        self.lib = lib
        params = fmu_start_values(physics, hw.x_origin)
        names = (ctypes.c_char_p * len(params))(*(n.encode() for n in params))
        values = (ctypes.c_double * len(params))(*params.values())
        cell_offset, cell_gain = hw.cell  # the rig's true cell (bring-up options)
        self._hw = SimRigHw(x_origin=hw.x_origin,
                            home_x=hw.x_origin if hw.home_x is None else hw.home_x,
                            load_gain_n=cell_gain, load_noise_n=hw.load_noise_n,
                            period_s=physics.period, noise_seed=seed & (2**64 - 1),
                            load_offset=cell_offset, enc_sign=hw.encoder_sign,
                            drop_n=hw.drop_steps[0], drop_d=hw.drop_steps[1])
        err = ctypes.create_string_buffer(512)
        if lib.sim_rig_init(ctypes.byref(self._hw), names, values, len(params), err,
                            len(err)) != 0:
            raise ValueError(f"the simulated rig refused its setup: {err.value.decode()}")
        self.inputs = RigInputs()
        self.steps = 0
        self.step(0)

    def step(self, delta: int) -> None:
        """``delta`` steps output during the last period, then one period of the plant."""
        self.steps += delta
        self.lib.hal_step(delta)
        self.lib.hal_read(ctypes.byref(self.inputs))

    def status(self) -> SimRigStatus:
        st = SimRigStatus()
        self.lib.sim_rig_get_status(ctypes.byref(st))
        return st


class PlantClock:
    """The plant's 1 ms steps as an event of the machine (physics runs on its own): a period
    after the last step, unless a tick (TIM5's update) stepped it first."""

    def __init__(self, board: NucleoBoard) -> None:
        self.board = board
        self.next = seconds(PLANT_PERIOD_S)

    def advance(self, now: int) -> None:
        while now >= self.next:
            self.board.plant_period(self.next)
            self.next += seconds(PLANT_PERIOD_S)

    def next_event(self) -> int | None:
        return self.next

    def reset(self) -> None:
        """A chip reset does not touch the mechanics."""

    def freeze(self, duration: int) -> None:
        """Physics does not stop for a debugger."""


@dataclass
class BoardLog:
    """What the board did, in time units (:data:`hil.emulators.rehost.machine.UNITS_PER_S`)."""

    enable: list[tuple[int, bool]] = field(default_factory=list)  # PA10 changes
    pulses: int = 0  # signed step pulses the driver took (enabled)
    pulses_ignored: int = 0  # pulses while the driver was disabled
    resets: list[tuple[int, str]] = field(default_factory=list)


class NucleoBoard:
    """The rehosted NUCLEO-F446RE on the simulated rig; see the module's docstring.

    Fault injection: :attr:`rcc` (``hse_present``, ``pll_locks``), :attr:`pwr`
    (``od_ready``), :attr:`adc` (``present``, ``crc_errors``, ``drdy_stuck``,
    ``status_set``), and the inputs :attr:`stop_pressed`, :attr:`limit_open`,
    :attr:`limit_closed` (overtravel switch open), :attr:`driver_alarm`,
    :attr:`chain_broken` (the stop chain's feedback stuck low); :meth:`force_hardfault`,
    :meth:`debug_halt`.
    """

    def __init__(self, elf: Path, physics: ClampPhysics | None = None,
                 hw: RigHardware | None = None, seed: int = 0,
                 rng_seed: int | None = None) -> None:
        self.elf = Path(elf)
        self.elf_sha256 = sha256(self.elf)
        from hil.host.backends import RigSetup

        physics = physics or ClampPhysics("chang2021")
        self.hw = hw or RigHardware(x_origin=RigSetup(preset=physics.preset).stroke[0])
        self.plant = Plant(physics, self.hw, seed)
        self.log = BoardLog()
        self.stop_pressed = self.limit_open = self.limit_closed = False
        self.driver_alarm = self.chain_broken = self.b1_pressed = False
        self.output = bytearray()  # what the MCU sent on USART2, not yet taken
        m = self.machine = Machine()
        m.map_memory(0x08000000, 0x20000)  # sectors 0-4: the image
        m.map_memory(0x20000000, 0x20000)  # SRAM1 + SRAM2
        for page in (0x40000000, 0x40003000, 0x40004000, 0x40007000, 0x40010000,
                     0x40020000, 0x40023000, 0x40026000, 0x50060000, 0xE0001000,
                     0xE000E000, 0xE0042000):
            m.map_mmio(page, 0x1000)
        m.map_mmio(0x08020000, 0x60000)  # sectors 5-7: calibration, boot counter
        self.segments = load_elf(m, self.elf)
        find_wfi(m, self.elf)
        self.scs = m.add(SystemControl(m))
        m.add(Dwt(m, self.scs))
        self.dbg = m.add(DbgMcu(m))
        self.pwr = m.add(Pwr(m))
        self.rcc = m.add(Rcc(m, self.pwr))
        self.flash = m.add(Flash(m))
        self.rcc.flash_latency = lambda: self.flash.regs[0] & 0xF
        m.add(FlashMemory(m, self.flash))
        self.gpio = {p: m.add(Gpio(m, p, self.rcc)) for p in "ABC"}
        self.usart = m.add(Usart(m, self.rcc))
        self.dma = m.add(Dma1(m, self.rcc, self.usart, self.output.extend))
        self.tim1 = m.add(StepTimer(m, self.rcc, self.dbg))
        self.tim3 = m.add(PulseCounter(m, self.rcc, self.dbg, self.tim1))
        self.tim2 = m.add(EncoderTimer(m, self.rcc, self.dbg, self._encoder))
        self.tim5 = m.add(TickTimer(m, self.rcc, self.dbg))
        self.tim5.on_trgo = self.tim1.trigger
        self.tim5.on_update = self.plant_period  # the plant steps at the image's ticks
        self.adc = Ads131m02(lambda: m.now, self._clkin)
        self.spi = m.add(Spi(m, self.rcc, self.adc.exchange))
        self.iwdg = m.add(Iwdg(m, self.rcc))
        self.rng = m.add(Rng(m, self.rcc, secrets.randbits(32) if rng_seed is None
                             else rng_seed))
        self.plant_clock = PlantClock(self)
        m.peripherals.append(self.plant_clock)  # type: ignore[arg-type]
        m.timed.append(self.plant_clock)  # type: ignore[arg-type]
        self._wire()
        self._first_open = 0
        self._last_period = 0
        m.on_reset.append(lambda reason: self.log.resets.append((m.now, reason)))
        m.reset("power-on")

    # --- wiring ---------------------------------------------------------------------------

    def _wire(self) -> None:
        a, b, c = self.gpio["A"], self.gpio["B"], self.gpio["C"]
        b.levels = lambda: {
            PB_STOP: self.stop_pressed, PB_DRDY: not self.adc.drdy_low(),
            PB_ALARM: self.driver_alarm, PB_CHAIN: self._chain_feedback()}
        c.levels = lambda: {
            PC_HOME: not self.plant.inputs.home_switch, PC_LIMIT_OPEN: self.limit_open,
            PC_LIMIT_CLOSED: self.limit_closed, PC_B1: not self.b1_pressed}
        a.on_output = self._porta_output
        b.on_output = self._portb_output

    def _porta_output(self, pin: int, high: bool) -> None:
        if pin == PA_ENABLE:
            level = self.enable_level()
            if not self.log.enable or self.log.enable[-1][1] != level:
                self.log.enable.append((self.machine.now, level))

    def _portb_output(self, pin: int, high: bool) -> None:
        if pin == PB_CS and self.gpio["B"].mode(PB_CS) == 1:
            self.adc.select(not high)
        elif pin == PB_ADC_RST and self.gpio["B"].mode(PB_ADC_RST) == 1:
            self.adc.set_sync(high)

    def enable_level(self) -> bool:
        """PA10 drives the driver's enable (high: energised) when it is an output."""
        a = self.gpio["A"]
        return a.mode(PA_ENABLE) == 1 and a.output(PA_ENABLE)

    def _chain_feedback(self) -> bool:
        """The stop chain's end (PB5): the enable after the stop button's contact."""
        return self.enable_level() and not self.stop_pressed and not self.chain_broken

    def _clkin(self) -> int:
        c = self.gpio["C"]
        if self.rcc.mco2_hse and c.mode(PC_CLKIN) == 2 and c.af(PC_CLKIN) == 0:
            return HSE_HZ
        return 0

    def _encoder(self) -> int | None:
        a = self.gpio["A"]
        for pin in (PA_ENC_A, PA_ENC_B):
            if a.mode(pin) != 2 or a.af(pin) != 1:
                return None
        return self.plant.inputs.enc

    def step_pin_connected(self) -> bool:
        a = self.gpio["A"]
        return all(a.mode(p) == 2 and a.af(p) == 1 for p in (PA_STEP, PA_DIR))

    # --- the plant's period ---------------------------------------------------------------

    def pulses_between(self, t0: int, t1: int) -> int:
        """Signed step pulses on PA8 (direction from PA9) in (t0, t1]."""
        total = 0
        bursts = self.tim1.bursts
        while self._first_open < len(bursts):
            b = bursts[self._first_open]
            if (b.end if b.cut is None else b.cut) <= t0 and self._first_open < len(bursts) - 1:
                self._first_open += 1
            else:
                break
        for b in bursts[self._first_open:]:
            if b.output:
                total += (b.rises(t1) - b.rises(t0)) * (1 if b.dir_high else -1)
        return total

    def plant_period(self, t: int) -> None:
        """One step of the plant at ``t`` with the pulses since its last (once per instant)."""
        if t <= self._last_period:
            return
        delta = self.pulses_between(self._last_period, t)
        self._last_period = t
        self.plant_clock.next = t + seconds(PLANT_PERIOD_S)
        if delta and not (self.enable_level() and self.step_pin_connected()):
            self.log.pulses_ignored += abs(delta)
            delta = 0
        self.log.pulses += delta
        self.plant.step(delta)
        self.adc.load_counts = self.plant.inputs.load_raw

    # --- running, injecting -------------------------------------------------------------

    @property
    def now_s(self) -> float:
        return self.machine.now / UNITS_PER_S

    def run(self, seconds_: float) -> None:
        """Run the board for ``seconds_`` of emulated time."""
        self.machine.run_until(self.machine.now + seconds(seconds_))

    def receive(self, data: bytes) -> None:
        """Bytes from the host on USART2's RX."""
        self.usart.receive(data)

    def take_output(self) -> bytes:
        data = bytes(self.output)
        self.output.clear()
        return data

    def force_hardfault(self) -> None:
        """A HardFault now (what a bus error or a corrupted pointer would raise)."""
        self.machine.pend(3)

    def debug_halt(self, seconds_: float) -> None:
        """A debugger halts the core for ``seconds_``: the peripherals whose DBGMCU bit is
        set freeze, the others (and the rig) run on."""
        d = seconds(seconds_)
        for name, p in (("TIM1", self.tim1), ("TIM5", self.tim5), ("IWDG", self.iwdg)):
            if self.dbg.frozen(name):
                p.freeze(d)
        self.machine.debug_halted = True
        try:
            self.machine.run_until(self.machine.now + d)
        finally:
            self.machine.debug_halted = False

    def symbol(self, name: str) -> int:
        out = subprocess.run(["arm-none-eabi-nm", str(self.elf)], capture_output=True,
                             text=True, check=True).stdout
        for line in out.splitlines():
            parts = line.split()
            if len(parts) == 3 and parts[2] == name:
                return int(parts[0], 16)
        raise KeyError(f"no symbol {name!r} in {self.elf}")


class NucleoRig:
    """:class:`NucleoBoard` served on a pseudo-terminal (:attr:`port`) by a thread that
    paces it, as docs/rig-protocol-behaviour.md (section 7, "Emulated MCUs") asks of an emulator:
    emulated time never runs faster than the wall clock (a slice that took longer than its
    emulated millisecond is not made up later: that time is lost, and the image's own
    clock, its ``t_us``, shows it), and :attr:`port` is published only once the image
    answered a HELLO and then a BYE on it (:func:`hil.emulators.firmware_qemu.await_firmware`).
    ``answer_timeout`` bounds that wait (s). :attr:`time_ratio`: emulated per wall time.
    ``with NucleoRig(...) as rig``; :meth:`close` stops it. :attr:`error`: what stopped
    the board (an :class:`~hil.emulators.rehost.machine.UnsupportedAccessError` access), re-raised
    by :meth:`check`."""

    SLICE_S = 1e-3
    #: What the USB link of the ST-LINK's virtual COM port holds while the host is slow to
    #: read (beyond it the oldest bytes are lost, as a full buffer would lose them).
    BACKLOG_BYTES = 64 * 1024

    def __init__(self, board: NucleoBoard, answer_timeout: float = 60.0) -> None:
        self.board = board
        self.error: BaseException | None = None
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)
        os.set_blocking(self._master, False)
        self.port = ""
        self.dropped = 0
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._wall0 = time.monotonic()
        self._emu0 = board.machine.now
        self._thread = threading.Thread(target=self._serve, name="nucleo-rehost",
                                        daemon=True)
        self._thread.start()
        try:
            self._await_image(answer_timeout)
        except BaseException:
            self.close()
            raise
        self.port = os.ttyname(self._slave)

    def _await_image(self, timeout: float) -> None:
        """HELLO and BYE through the pty's own slave end, so the whole path is tried."""
        slave = self._slave

        def receive(wait: float) -> bytes:
            if not select.select([slave], [], [], wait)[0]:
                return b""
            return os.read(slave, 65536)

        await_firmware(lambda data: os.write(slave, data) and None, receive, timeout,
                       lambda: self.error is not None or not self._thread.is_alive(),
                       lambda: f"board stopped: {self.error}" if self.error
                       else f"{self.board.now_s:.3f} s emulated", "the rehosted image")
        termios.tcflush(slave, termios.TCIFLUSH)  # nothing of the probe's for the host

    @property
    def time_ratio(self) -> float:
        """Emulated seconds per wall-clock second since the start (at most 1)."""
        wall = time.monotonic() - self._wall0
        emu = (self.board.machine.now - self._emu0) / UNITS_PER_S
        return emu / wall if wall > 0 else 0.0

    def _serve(self) -> None:
        board, master = self.board, self._master
        backlog = bytearray()
        # the pacing's origin: emulated time may lead the wall clock since it by a slice at
        # most; when it lags, the origin moves up (the lost time is never run faster)
        wall_base, emu_base = self._wall0, self._emu0
        try:
            while not self._stop.is_set():
                writers = [master] if backlog else []
                ahead = ((board.machine.now - emu_base) / UNITS_PER_S
                         - (time.monotonic() - wall_base))
                if ahead < 0:
                    wall_base, emu_base = time.monotonic(), board.machine.now
                    ahead = 0.0
                readable, writable, _ = select.select([master], writers, [], ahead)
                if readable:
                    with contextlib.suppress(BlockingIOError, OSError):
                        board.receive(os.read(master, 4096))
                if writable:
                    with contextlib.suppress(BlockingIOError, OSError):
                        del backlog[:os.write(master, backlog)]
                if ahead > 0 and (board.machine.now - emu_base) / UNITS_PER_S > (
                        time.monotonic() - wall_base):
                    continue
                with self._lock:
                    board.run(self.SLICE_S)
                backlog += board.take_output()
                if len(backlog) > self.BACKLOG_BYTES:  # the host stopped reading: the
                    self.dropped += len(backlog) - self.BACKLOG_BYTES  # oldest bytes go
                    del backlog[:len(backlog) - self.BACKLOG_BYTES]
        except BaseException as exc:  # the board stopped: keep it for check()
            self.error = exc

    def summary(self) -> str:
        """One line of counts: bytes in and out, lost ones, resets."""
        b = self.board
        return (f"{b.machine.now / UNITS_PER_S:.3f} s emulated, {b.dma.sent} bytes sent "
                f"({self.dropped} dropped, the host not reading), RX overruns {b.usart.overruns}, "
                f"bytes lost before the USART was on {b.usart.lost}, step pulses to the "
                f"driver {b.log.pulses:+d} ({b.log.pulses_ignored} while it was disabled), "
                f"resets {[reason for _, reason in b.log.resets]}")

    def check(self) -> None:
        """Raise what stopped the board, if anything did."""
        if self.error is not None:
            raise self.error

    @contextlib.contextmanager
    def paused(self):  # type: ignore[no-untyped-def]
        """Hold the board between two slices (to inspect or poke it)."""
        with self._lock:
            yield self.board

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5.0)
        for fd in (self._master, self._slave):
            with contextlib.suppress(OSError):
                os.close(fd)

    def __enter__(self) -> NucleoRig:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()


__all__ = ["NucleoBoard", "NucleoRig", "Plant", "UnsupportedAccessError", "build_nucleo_image",
           "sha256"]

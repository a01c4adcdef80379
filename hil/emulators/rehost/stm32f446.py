"""Models of the STM32F446 peripherals the NUCLEO-F446RE firmware touches (RM0390 rev 6).

Each model implements the registers and the fields the board's C (board_nucleo.c,
nucleo_*.c) uses and raises :class:`hil.emulators.rehost.machine.UnsupportedAccessError` for
anything else (another register, a mode it does not model, an access with the peripheral's
clock off). What each one does not model is listed in docs/firmware.md ("The rehosted
image").
"""

from __future__ import annotations

import random
from collections.abc import Callable
from dataclasses import dataclass

from hil.emulators.rehost.cortex import DbgMcu
from hil.emulators.rehost.machine import (
    UNITS_PER_S,
    Machine,
    Peripheral,
    UnsupportedAccessError,
    seconds,
)

HSI_HZ = 16_000_000
HSE_HZ = 8_000_000  # the ST-LINK's MCO into OSC_IN (HSE bypass)
LSI_HZ = 32_000
IWDG_UPDATE_LSI_CYCLES = 5  # RM0390 19.4.4: PR/RLR updates take up to 5 LSI cycles


# ---- RCC, PWR, FLASH interface ------------------------------------------------------------

class Pwr(Peripheral):
    """PWR_CR's VOS, ODEN, ODSWEN; PWR_CSR's ODRDY, ODSWRDY (RM0390 5.4). ``od_ready``
    False: the over-drive never becomes ready."""

    NAME = "PWR"
    BASE = 0x40007000
    REGS = {0x0: "CR", 0x4: "CSR"}
    RESET = {0x0: 0x0000C000}
    CR_MODELLED = (3 << 14) | (1 << 16) | (1 << 17)

    def __init__(self, machine: Machine) -> None:
        self.od_ready = True
        super().__init__(machine)

    def read(self, off: int, size: int) -> int:
        self._check(off, size, "read")
        if off == 0x4:
            cr = self.regs[0]
            ok = self.od_ready
            return (1 << 14) | ((cr >> 16 & 1 and ok) << 16) | ((cr >> 17 & 1 and ok) << 17)
        return self.regs[0]

    def write(self, off: int, size: int, value: int) -> None:
        self._check(off, size, "write")
        if off == 0x4 or value & ~self.CR_MODELLED:
            raise self.fail(f"write {value:#x} at {off:#x}: only VOS, ODEN, ODSWEN modelled")
        self.regs[0] = value

    @property
    def overdrive(self) -> bool:
        return bool(self.od_ready and self.regs[0] >> 17 & 1)


class Rcc(Peripheral):
    """The clock tree as the firmware sets it (RM0390 6.3): HSE bypass and HSI, the main
    PLL (M, N, P, Q; lock only with a valid VCO), the system clock switch (SWS follows SW
    once the source is ready), the APB prescalers, MCO2, the enable registers and the reset
    flags. ``hse_present`` False: no 8 MHz on OSC_IN (HSERDY never sets); ``pll_locks``
    False: PLLRDY never sets. The core's speed follows the switch."""

    NAME = "RCC"
    BASE = 0x40023800
    REGS = {0x00: "CR", 0x04: "PLLCFGR", 0x08: "CFGR", 0x0C: "CIR", 0x30: "AHB1ENR",
            0x34: "AHB2ENR", 0x40: "APB1ENR", 0x44: "APB2ENR", 0x74: "CSR"}
    RESET = {0x00: 0x00000083, 0x04: 0x24003010, 0x30: 0x00100000, 0x74: 0x0E000000}
    CR_WRITABLE = (1 << 0) | (1 << 16) | (1 << 18) | (1 << 24)
    CR_READ_ONLY = (1 << 1) | (1 << 17) | (1 << 25) | (1 << 27) | (1 << 29) | 0xFF00
    CFGR_MODELLED = 0x3 | (0xF << 4) | (0x7 << 10) | (0x7 << 13) | (0x1F << 27) | (0x3 << 30)
    HPRE = {0: 1, 8: 2, 9: 4, 10: 8, 11: 16, 12: 64, 13: 128, 14: 256, 15: 512}
    PPRE = {0: 1, 4: 2, 5: 4, 6: 8, 7: 16}
    MAX_HCLK_NO_OD = 168_000_000
    FLASH_WS_MHZ = 30  # RM0390 table 5: one wait state per 30 MHz at 2.7-3.6 V

    def __init__(self, machine: Machine, pwr: Pwr) -> None:
        self.pwr = pwr
        self.hse_present = True
        self.pll_locks = True
        self.flash_latency: Callable[[], int] = lambda: 0
        self.reset_flags = 0x0E000000  # PORRSTF, PINRSTF, BORRSTF at power-on
        self._hclk_key: tuple[int, int, int, bool, bool] | None = None
        self._hclk = HSI_HZ
        super().__init__(machine)

    def reset(self) -> None:
        super().reset()
        self.regs[0x74] = self.reset_flags
        self.m.cpu_hz = HSI_HZ

    def note_reset(self, flag_bit: int) -> None:
        self.reset_flags |= 1 << flag_bit

    # clocks ------------------------------------------------------------------------------

    @property
    def hse_ready(self) -> bool:
        return bool(self.regs[0] >> 16 & 1 and self.hse_present)

    def _pll_input(self) -> int:
        cfg = self.regs[4]
        return HSE_HZ if cfg >> 22 & 1 else HSI_HZ

    def pll_vco(self) -> int | None:
        """The PLL's VCO frequency, or None while it is not locked."""
        cfg, cr = self.regs[4], self.regs[0]
        if not (cr >> 24 & 1 and self.pll_locks):
            return None
        if cfg >> 22 & 1 and not self.hse_ready:
            return None
        m, n = cfg & 0x3F, cfg >> 6 & 0x1FF
        if not 2 <= m <= 63 or not 50 <= n <= 432:
            return None
        vin = self._pll_input() / m
        vco = vin * n
        if not (0.95e6 <= vin <= 2.1e6 and 100e6 <= vco <= 432e6):
            return None
        return int(vco)

    def pll_q_hz(self) -> int | None:
        vco, q = self.pll_vco(), self.regs[4] >> 24 & 0xF
        return None if vco is None or q < 2 else vco // q

    def _sysclk(self, sw: int) -> int | None:
        if sw == 0:
            return HSI_HZ
        if sw == 1:
            return HSE_HZ if self.hse_ready else None
        vco = self.pll_vco()
        if sw == 2 and vco is not None:
            return vco // (2 * ((self.regs[4] >> 16 & 3) + 1))
        return None

    @property
    def hclk(self) -> int:
        key = (self.regs[0], self.regs[4], self.regs[8], self.hse_present, self.pll_locks)
        if key != self._hclk_key:
            self._hclk_key, self._hclk = key, self._compute_hclk()
        return self._hclk

    def _compute_hclk(self) -> int:
        sws = self.regs[8] >> 2 & 3
        return (self._sysclk(sws) or HSI_HZ) // self.HPRE.get(self.regs[8] >> 4 & 0xF, 1)

    def apb_hz(self, bus: int) -> int:
        return self.hclk // self.PPRE[self.regs[8] >> (10 if bus == 1 else 13) & 7]

    def timer_hz(self, bus: int) -> int:
        div = self.PPRE[self.regs[8] >> (10 if bus == 1 else 13) & 7]
        return self.hclk * (1 if div == 1 else 2) // div

    @property
    def mco2_hse(self) -> bool:
        """MCO2 (PC9) outputs HSE undivided: the ADC's CLKIN."""
        return self.regs[8] >> 30 == 2 and self.regs[8] >> 27 & 7 == 0 and self.hse_ready

    def enabled(self, reg: int, bit: int) -> bool:
        return bool(self.regs[reg] >> bit & 1)

    # registers -----------------------------------------------------------------------------

    def read(self, off: int, size: int) -> int:
        self._check(off, size, "read")
        if off == 0x00:
            cr = self.regs[0]
            return (cr & ~self.CR_READ_ONLY) | 0x2 | (self.hse_ready << 17) | \
                ((self.pll_vco() is not None) << 25) | (cr & 0xFF00)
        return self.regs[off]

    def write(self, off: int, size: int, value: int) -> None:
        name = self._check(off, size, "write")
        if name == "CR":
            changed = (value ^ self.regs[0]) & ~self.CR_READ_ONLY
            if changed & ~self.CR_WRITABLE or not value & 1:
                raise self.fail(f"RCC_CR {value:#x}: HSEON, HSEBYP, PLLON are modelled "
                                f"(HSI stays on; no CSS, trimming, PLLI2S, PLLSAI)")
            if changed >> 18 & 1 and (self.regs[0] >> 16 & 1 or value >> 16 & 1):
                raise self.fail(f"RCC_CR {value:#x}: HSEBYP changed with HSEON set (RM0390 "
                                f"6.3.1: HSEBYP may be written only while HSE is off)")
            self.regs[0] = (self.regs[0] & self.CR_READ_ONLY) | (value & ~self.CR_READ_ONLY)
            return
        if name == "PLLCFGR":
            if self.regs[0] >> 24 & 1:
                raise self.fail("PLLCFGR written with the PLL on (RM0390: only while off)")
            self.regs[4] = value
            return
        if name == "CFGR":
            self._switch(value)
            return
        if name == "CIR" and value:
            raise self.fail("clock interrupts are not modelled")
        if name == "CSR":
            if value & (1 << 24):  # RMVF
                self.reset_flags = 0
                self.regs[0x74] = 0
            if value & ~(1 << 24):
                raise self.fail("RCC_CSR: LSI control is the IWDG's (not modelled here)")
            return
        self.regs[off] = value

    def _switch(self, value: int) -> None:
        if value & ~self.CFGR_MODELLED & ~0xC:
            raise self.fail(f"RCC_CFGR {value:#x}: fields beyond SW, HPRE, PPRE1/2, MCO2")
        sw = value & 3
        clk = self._sysclk(sw)
        sws = sw if clk is not None else self.regs[8] >> 2 & 3
        new = (value & ~0xC) | (sws << 2)
        old = self.regs[8]
        self.regs[8] = new
        hclk = self.hclk
        if hclk > self.MAX_HCLK_NO_OD and not self.pwr.overdrive:
            self.regs[8] = old
            raise self.fail(f"HCLK {hclk / 1e6:g} MHz without over-drive (RM0390 5.1.4)")
        ws_needed = -(-hclk // (self.FLASH_WS_MHZ * 1_000_000)) - 1
        if self.flash_latency() < ws_needed:
            self.regs[8] = old
            raise self.fail(f"HCLK {hclk / 1e6:g} MHz with {self.flash_latency()} flash "
                            f"wait states (needs {ws_needed})")
        if self.apb_hz(1) > 45_000_000 or self.apb_hz(2) > 90_000_000:
            self.regs[8] = old
            raise self.fail("APB clock above its maximum (45/90 MHz)")
        self.m.cpu_hz = hclk


class PowerCutError(RuntimeError):
    """The test hook of :class:`Flash`: the power failed before a flash write took effect."""


class Flash(Peripheral):
    """The flash interface (RM0390 3.8): ACR, the KEYR unlock sequence and LOCK, SR's BSY
    and error flags (write 1 to clear), CR's PG, SER/SNB/STRT, PSIZE. Sectors 5-7 (the
    calibration log and the boot counter, :class:`FlashMemory`) can be erased (to 0xFF)
    and programmed a word at a time (bits only clear: 1 -> 0); sectors 0-4 hold the image
    and cannot be written. An operation completes at once but reads BSY once, so the
    firmware's wait loop runs.

    Test hook: with :attr:`cut_after` = N, the (N+1)-th write (a word programmed or a
    sector erased) raises :class:`PowerCutError` before it takes effect, which stops the
    machine as a power cut would; :attr:`writes` counts the writes done."""

    NAME = "FLASH"
    BASE = 0x40023C00
    REGS = {0x00: "ACR", 0x04: "KEYR", 0x0C: "SR", 0x10: "CR"}
    RESET = {0x10: 0x80000000}
    KEYS = (0x45670123, 0xCDEF89AB)
    PGSERR, WRPERR, BSY = 1 << 7, 1 << 4, 1 << 16
    FIRST_SECTOR = 5  # sectors 5-7 are writable here
    SECTOR_BASE = 0x08020000
    SECTOR_SIZE = 0x20000

    def __init__(self, machine: Machine) -> None:
        self.memory = bytearray(b"\xff" * (3 * self.SECTOR_SIZE))  # survives resets
        self.cut_after: int | None = None
        self.writes = 0
        super().__init__(machine)

    def reset(self) -> None:
        super().reset()
        self.key_step = 0
        self.busy = False

    @property
    def locked(self) -> bool:
        return bool(self.regs[0x10] >> 31)

    def _write_done(self) -> None:
        """Count one write, or cut the power before it (the test hook)."""
        if self.cut_after is not None and self.writes >= self.cut_after:
            raise PowerCutError(f"power cut before flash write {self.writes + 1}")
        self.writes += 1
        self.busy = True

    def read(self, off: int, size: int) -> int:
        value = super().read(off, size)
        if self._check(off, size, "read") == "SR" and self.busy:
            self.busy = False
            value |= self.BSY
        return value

    def write(self, off: int, size: int, value: int) -> None:
        name = self._check(off, size, "write")
        if name == "ACR":
            if value & ~(0xF | 0x7 << 8 | 0x3 << 11):
                raise self.fail(f"FLASH_ACR {value:#x}")
            self.regs[0] = value & ~(0x3 << 11)
        elif name == "KEYR":
            if self.locked and value == self.KEYS[self.key_step]:
                self.key_step += 1
                if self.key_step == 2:
                    self.regs[0x10] &= ~(1 << 31)
                    self.key_step = 0  # after the next LOCK the sequence starts again
            else:
                self.key_step = 0  # a wrong key: locked until reset (a bus error there)
        elif name == "SR":
            self.regs[0x0C] &= ~(value & 0xF3)
        else:  # CR
            if self.locked:
                return
            if value & ~((1 << 31) | (1 << 16) | (3 << 8) | (0xF << 3) | 0x3):
                raise self.fail(f"FLASH_CR {value:#x}: mass erase, interrupts not modelled")
            self.regs[0x10] = value & ~(1 << 16)
            if value & (1 << 16) and value & 2:  # STRT with SER
                sector = value >> 3 & 0xF
                if not self.FIRST_SECTOR <= sector <= 7:
                    raise self.fail(f"erase of sector {sector}: the image's")
                self._write_done()
                start = (sector - self.FIRST_SECTOR) * self.SECTOR_SIZE
                self.memory[start:start + self.SECTOR_SIZE] = b"\xff" * self.SECTOR_SIZE

    def program(self, offset: int, size: int, value: int) -> None:
        """A write of ``size`` bytes at ``offset`` into sectors 5-7: programs (ANDs) it."""
        cr = self.regs[0x10]
        if self.locked or not cr & 1 or size != 4 or cr >> 8 & 3 != 2:
            self.regs[0x0C] |= self.PGSERR
            return
        self._write_done()
        old = int.from_bytes(self.memory[offset:offset + 4], "little")
        self.memory[offset:offset + 4] = (old & value).to_bytes(4, "little")


class FlashMemory(Peripheral):
    """Sectors 5-7 of the flash memory (0x08020000, 3 x 128 KiB): reads of any size; a word
    write programs it through :class:`Flash` (erased bits only clear, as flash does)."""

    NAME = "flash sectors 5-7"
    BASE = Flash.SECTOR_BASE
    SIZE = 3 * Flash.SECTOR_SIZE

    def __init__(self, machine: Machine, flash: Flash) -> None:
        self.flash = flash
        super().__init__(machine)

    def read(self, off: int, size: int) -> int:
        return int.from_bytes(self.flash.memory[off:off + size], "little")

    def write(self, off: int, size: int, value: int) -> None:
        self.flash.program(off, size, value)


# ---- GPIO -------------------------------------------------------------------------------

class Gpio(Peripheral):
    """One GPIO port (RM0390 7.4): MODER, OTYPER, OSPEEDR, PUPDR, IDR, ODR, BSRR, AFR.
    Inputs come from ``levels()`` (the board's wiring: pin -> level of the connected pins;
    the others read their pull-up or pull-down, or 0 floating); output changes go to
    ``on_output(pin, level)``."""

    REGS = {0x00: "MODER", 0x04: "OTYPER", 0x08: "OSPEEDR", 0x0C: "PUPDR", 0x10: "IDR",
            0x14: "ODR", 0x18: "BSRR", 0x20: "AFRL", 0x24: "AFRH"}
    PORT_RESET = {"A": {0x00: 0xA8000000, 0x0C: 0x64000000},
                  "B": {0x00: 0x00000280, 0x08: 0x000000C0, 0x0C: 0x00000100}, "C": {}}

    def __init__(self, machine: Machine, port: str, rcc: Rcc) -> None:
        self.NAME = f"GPIO{port}"
        self.BASE = 0x40020000 + 0x400 * "ABC".index(port)
        self.RESET = self.PORT_RESET[port]
        self.port, self.rcc = port, rcc
        self.levels: Callable[[], dict[int, bool]] = dict
        self.on_output: Callable[[int, bool], None] = lambda pin, high: None
        super().__init__(machine)

    def mode(self, pin: int) -> int:
        return self.regs[0] >> (2 * pin) & 3

    def af(self, pin: int) -> int:
        return (self.regs[0x20 if pin < 8 else 0x24] >> (4 * (pin & 7))) & 0xF

    def output(self, pin: int) -> bool:
        return bool(self.regs[0x14] >> pin & 1)

    def idr(self) -> int:
        moder, pupdr = self.regs[0], self.regs[0x0C]
        value = 0
        wired = self.levels()
        for pin in range(16):
            mode = moder >> (2 * pin) & 3
            if mode == 1:
                level = self.regs[0x14] >> pin & 1
            elif pin in wired:
                level = wired[pin]
            else:
                level = (pupdr >> (2 * pin) & 3) == 1
            value |= level << pin
        return value

    def _clock(self) -> None:
        if not self.rcc.enabled(0x30, "ABC".index(self.port)):
            raise self.fail("accessed with its clock off (RCC_AHB1ENR)")

    def read(self, off: int, size: int) -> int:
        self._check(off, size, "read")
        self._clock()
        if off == 0x10:
            return self.idr()
        if off == 0x18:
            return 0
        return self.regs[off]

    def write(self, off: int, size: int, value: int) -> None:
        name = self._check(off, size, "write")
        self._clock()
        if name == "IDR":
            raise self.fail("write to IDR")
        before = self.regs[0x14]
        if name == "BSRR":
            self.regs[0x14] = (before | (value & 0xFFFF)) & ~(value >> 16)
        elif name == "OTYPER" and value:
            raise self.fail("open-drain outputs are not modelled")
        else:
            self.regs[off] = value
        changed = before ^ self.regs[0x14]
        for pin in range(16):
            if changed >> pin & 1 or (name == "MODER" and self.mode(pin) == 1):
                self.on_output(pin, self.output(pin))


# ---- USART2 and DMA1 stream 6 ------------------------------------------------------------

class Usart(Peripheral):
    """USART2 (RM0390 25.6): 8N1 at BRR's rate from PCLK1 (OVER8 0), RXNE with its
    interrupt, ORE when a byte arrives before the last was read, TX by DMA (CR3.DMAT).
    Bytes from the host are queued by :meth:`receive` and arrive one frame time apart."""

    NAME = "USART2"
    BASE = 0x40004400
    IRQ = 38
    REGS = {0x00: "SR", 0x04: "DR", 0x08: "BRR", 0x0C: "CR1", 0x10: "CR2", 0x14: "CR3",
            0x18: "GTPR"}
    RESET = {0x00: 0xC0}
    SR_ORE, SR_RXNE = 1 << 3, 1 << 5
    CR1_MODELLED = (1 << 13) | (1 << 3) | (1 << 2) | (1 << 5)

    def __init__(self, machine: Machine, rcc: Rcc) -> None:
        self.rcc = rcc
        self.inbox = bytearray()
        self.lost = 0
        self.overruns = 0
        super().__init__(machine)

    def reset(self) -> None:
        super().reset()
        self.rx_byte = 0
        self.next_rx: int | None = None

    def frame_units(self) -> int:
        """Time of one 10-bit frame at the programmed rate."""
        brr = self.regs[0x08]
        if brr < 16:
            return 0
        return 10 * UNITS_PER_S * brr // self.rcc.apb_hz(1)

    def baud(self) -> float:
        brr = self.regs[0x08]
        return self.rcc.apb_hz(1) * 16 / (16 * brr) if brr else 0.0

    def receiving(self) -> bool:
        cr1 = self.regs[0x0C]
        return bool(cr1 >> 13 & 1 and cr1 >> 2 & 1 and self.frame_units())

    def receive(self, data: bytes) -> None:
        """Bytes the host sent (arriving after those queued before)."""
        self.inbox += data
        if self.next_rx is None and self.inbox and self.receiving():
            self.next_rx = self.m.now + self.frame_units()

    def advance(self, now: int) -> None:
        if self.inbox and self.next_rx is None:
            if not self.receiving():
                self.lost += len(self.inbox)
                self.inbox.clear()
                return
            self.next_rx = now + self.frame_units()
        while self.next_rx is not None and self.next_rx <= now:
            byte = self.inbox.pop(0)
            if self.regs[0] & self.SR_RXNE:
                self.regs[0] |= self.SR_ORE
                self.overruns += 1
            else:
                self.rx_byte = byte
                self.regs[0] |= self.SR_RXNE
            if self.regs[0x0C] & (1 << 5):
                self.m.pend(16 + self.IRQ)
            self.next_rx = self.next_rx + self.frame_units() if self.inbox else None

    def next_event(self) -> int | None:
        return self.next_rx

    def read(self, off: int, size: int) -> int:
        name = self._check(off, size, "read")
        if not self.rcc.enabled(0x40, 17):
            raise self.fail("accessed with its clock off")
        if name == "DR":
            self.regs[0] &= ~(self.SR_RXNE | self.SR_ORE)
            return self.rx_byte
        return self.regs[off]

    def write(self, off: int, size: int, value: int) -> None:
        name = self._check(off, size, "write")
        if not self.rcc.enabled(0x40, 17):
            raise self.fail("accessed with its clock off")
        if name == "CR1" and value & ~self.CR1_MODELLED:
            raise self.fail(f"USART_CR1 {value:#x}: parity, 9 bits, OVER8, other interrupts")
        if name == "CR3" and value & ~(1 << 7):
            raise self.fail(f"USART_CR3 {value:#x}: only DMAT is modelled")
        if name in ("CR2", "GTPR") and value:
            raise self.fail(f"{name} {value:#x}: stop bits, clock, smartcard not modelled")
        if name in ("SR", "DR"):
            raise self.fail(f"{name} written: TX is by DMA here; flags clear by reading")
        self.regs[off] = value


class Dma1(Peripheral):
    """DMA1 (RM0390 9.5) with stream 6 only: channel 4 (USART2_TX), memory to peripheral,
    memory increment, direct mode, transfer-complete interrupt. The bytes are read when the
    stream is enabled and leave the USART one frame time apart; EN clears and TCIF6 sets
    after the last."""

    NAME = "DMA1"
    BASE = 0x40026000
    IRQ = 17
    S6 = 0x10 + 0x18 * 6
    REGS = {0x00: "LISR", 0x04: "HISR", 0x08: "LIFCR", 0x0C: "HIFCR", S6: "S6CR",
            S6 + 4: "S6NDTR", S6 + 8: "S6PAR", S6 + 12: "S6M0AR", S6 + 16: "S6M1AR",
            S6 + 20: "S6FCR"}
    RESET = {S6 + 20: 0x21}
    CR_EXPECTED = (4 << 25) | (1 << 10) | (1 << 6) | (1 << 4) | 1
    TCIF6 = 1 << 21

    def __init__(self, machine: Machine, rcc: Rcc, usart: Usart,
                 send: Callable[[bytes], None]) -> None:
        self.rcc, self.usart, self.send = rcc, usart, send
        self.sent = 0
        super().__init__(machine)

    def reset(self) -> None:
        super().reset()
        self.queue = b""
        self.emitted = 0
        self.t_start: int | None = None

    def advance(self, now: int) -> None:
        if self.t_start is None:
            return
        frame = self.usart.frame_units()
        due = min(len(self.queue), (now - self.t_start) // frame - self.emitted)
        if due > 0:
            out = bytes(self.queue[self.emitted:self.emitted + due])
            self.emitted += due
            self.sent += due
            self.regs[self.S6 + 4] = len(self.queue) - self.emitted
            self.send(out)
        if self.emitted == len(self.queue):
            self.t_start = None
            self.regs[self.S6] &= ~1
            self.regs[0x04] |= self.TCIF6
            if self.regs[self.S6] & (1 << 4):
                self.m.pend(16 + self.IRQ)

    def next_event(self) -> int | None:
        """The transfer's end (the bytes before it leave at the chunk boundaries)."""
        if self.t_start is None:
            return None
        return self.t_start + len(self.queue) * self.usart.frame_units()

    def write(self, off: int, size: int, value: int) -> None:
        name = self._check(off, size, "write")
        if not self.rcc.enabled(0x30, 21):
            raise self.fail("accessed with its clock off")
        if name in ("LISR", "HISR"):
            raise self.fail(f"{name} is read-only")
        if name in ("LIFCR", "HIFCR"):
            reg = 0x00 if name == "LIFCR" else 0x04
            self.regs[reg] &= ~value
            return
        if name == "S6CR":
            if self.regs[self.S6] & 1 and value & 1:
                raise self.fail("S6CR written while the stream is enabled")
            if value & 1:
                self._start(value)
            self.regs[off] = value if value & 1 else value & ~1
            return
        if self.regs[self.S6] & 1:
            raise self.fail(f"{name} written while the stream is enabled (RM0390 9.3.18)")
        if name == "S6FCR" and value & 0x4:
            raise self.fail("FIFO mode is not modelled")
        self.regs[off] = value

    def _start(self, cr: int) -> None:
        if cr != self.CR_EXPECTED:
            raise self.fail(f"S6CR {cr:#x}: only channel 4, M2P, MINC, TCIE, bytes modelled")
        if self.regs[0x04] & (0x3D << 16):
            raise self.fail("stream 6 enabled with its flags set (RM0390 9.3.18)")
        if self.regs[self.S6 + 8] != Usart.BASE + 4:
            raise self.fail(f"S6PAR {self.regs[self.S6 + 8]:#x} is not USART2_DR")
        usart = self.usart
        if not (usart.regs[0x14] & (1 << 7) and usart.regs[0x0C] >> 13 & 1
                and usart.regs[0x0C] >> 3 & 1 and usart.frame_units()):
            raise self.fail("USART2 not enabled for DMA transmission (UE, TE, DMAT, BRR)")
        n = self.regs[self.S6 + 4]
        if not 1 <= n <= 0xFFFF:
            raise self.fail(f"NDTR {n}")
        self.queue = self.m.read_bytes(self.regs[self.S6 + 12], n)
        self.emitted = 0
        self.t_start = self.m.now


# ---- timers ------------------------------------------------------------------------------

TIM_REGS = {0x00: "CR1", 0x04: "CR2", 0x08: "SMCR", 0x0C: "DIER", 0x10: "SR", 0x14: "EGR",
            0x18: "CCMR1", 0x1C: "CCMR2", 0x20: "CCER", 0x24: "CNT", 0x28: "PSC",
            0x2C: "ARR", 0x30: "RCR", 0x34: "CCR1", 0x38: "CCR2", 0x3C: "CCR3",
            0x40: "CCR4", 0x44: "BDTR"}
CR1, CR2, SMCR, DIER, SR, EGR, CCMR1, CCER, CNT, PSC, ARR, RCR, CCR1, CCR2, BDTR = (
    0x00, 0x04, 0x08, 0x0C, 0x10, 0x14, 0x18, 0x20, 0x24, 0x28, 0x2C, 0x30, 0x34, 0x38, 0x44)


class _Timer(Peripheral):
    """What the four timer models share: the clock check and the register check of
    ``ALLOWED`` (register -> the bits a write may set)."""

    CLOCK: tuple[int, int] = (0x40, 0)
    ALLOWED: dict[int, int] = {}
    BUS = 1

    def __init__(self, machine: Machine, rcc: Rcc, dbg: DbgMcu) -> None:
        self.rcc, self.dbg = rcc, dbg
        self.REGS = {off: TIM_REGS[off] for off in self.ALLOWED}
        super().__init__(machine)

    def _clock(self) -> None:
        if not self.rcc.enabled(*self.CLOCK):
            raise self.fail("accessed with its clock off")

    def check_write(self, off: int, size: int, value: int) -> None:
        self._check(off, size, "write")
        self._clock()
        if off != SR and value & ~self.ALLOWED[off]:  # SR: rc_w0, writing 1 is no change
            raise self.fail(f"{TIM_REGS[off]} = {value:#x}: bits "
                            f"{value & ~self.ALLOWED[off]:#x} are not modelled")

    def tick_units(self) -> int:
        """Time of one counter clock (timer clock / (PSC + 1))."""
        return UNITS_PER_S * (self.regs[PSC] + 1) // self.rcc.timer_hz(self.BUS)


class TickTimer(_Timer):
    """TIM5 as the tick (RM0390 17.4): upcounting from the prescaled APB1 timer clock,
    update at ARR with UIF and its interrupt (URS), OC1REF in PWM mode 2 as TRGO, whose
    rising edge (CNT reaching CCR1) triggers TIM1 (TIM1's ITR0). ``on_trgo(t)`` and
    ``on_update(t)`` are called at those instants (the board's wiring)."""

    NAME = "TIM5"
    BASE = 0x40000C00
    IRQ = 50
    CLOCK = (0x40, 3)
    ALLOWED = {CR1: 0x5, CR2: 0x70, DIER: 0x1, SR: 0x1F, EGR: 0x1, CCMR1: 0x70, CNT: 0,
               PSC: 0xFFFF, ARR: 0xFFFFFFFF, CCR1: 0xFFFFFFFF}

    def reset(self) -> None:
        super().reset()
        self.t_zero = 0  # the time at which CNT was (or would have been) 0
        self.next_update: int | None = None
        self.next_edge: int | None = None
        self.on_trgo: Callable[[int], None] = getattr(self, "on_trgo", lambda t: None)
        self.on_update: Callable[[int], None] = getattr(self, "on_update", lambda t: None)
        self.updates = 0

    def _schedule(self, now: int) -> None:
        period = (self.regs[ARR] + 1) * self.tick_units()
        k = (now - self.t_zero) // period
        self.next_update = self.t_zero + (k + 1) * period
        edge = self.t_zero + k * period + self.regs[CCR1] * self.tick_units()
        self.next_edge = edge if edge > now else edge + period

    def advance(self, now: int) -> None:
        if not self.regs[CR1] & 1:
            return
        period = (self.regs[ARR] + 1) * self.tick_units()
        while True:
            t = min(self.next_update, self.next_edge)
            if t > now:
                break
            if t == self.next_edge:
                self.next_edge += period
                if (self.regs[CCMR1] >> 4 & 7) == 7 and (self.regs[CR2] >> 4 & 7) == 4 and \
                        0 < self.regs[CCR1] <= self.regs[ARR]:
                    self.on_trgo(t)
            else:
                self.next_update += period
                self.updates += 1
                self.regs[SR] |= 1
                if self.regs[DIER] & 1:
                    self.m.pend(16 + self.IRQ)
                self.on_update(t)

    def next_event(self) -> int | None:
        if not self.regs[CR1] & 1:
            return None
        return min(self.next_update, self.next_edge)

    def freeze(self, duration: int) -> None:
        if self.regs[CR1] & 1:
            self.t_zero += duration
            self.next_update += duration
            self.next_edge += duration

    def count(self, now: int) -> int:
        if not self.regs[CR1] & 1:
            return self.regs[CNT]
        return (now - self.t_zero) // self.tick_units() % (self.regs[ARR] + 1)

    def read(self, off: int, size: int) -> int:
        self._check(off, size, "read")
        self._clock()
        return self.count(self.m.now) if off == CNT else self.regs[off]

    def write(self, off: int, size: int, value: int) -> None:
        self.check_write(off, size, value)
        running = self.regs[CR1] & 1
        if off == SR:
            self.regs[SR] &= value
        elif off == EGR:
            if running:
                raise self.fail("UG while counting is not modelled")
            self.regs[CNT] = 0
            if not self.regs[CR1] & 0x4:
                self.regs[SR] |= 1
        elif off == CR1:
            if value & 1 and not running:
                self.t_zero = self.m.now - self.regs[CNT] * self.tick_units()
                self.regs[CR1] = value
                self._schedule(self.m.now)
            elif running and not value & 1:
                self.regs[CNT] = self.count(self.m.now)
            self.regs[CR1] = value
        elif off == CNT:
            raise self.fail("CNT written: not modelled")
        else:
            if running and value != self.regs[off]:
                raise self.fail(f"{TIM_REGS[off]} changed while counting: not modelled")
            self.regs[off] = value


@dataclass
class Burst:
    """One run of TIM1 from its trigger to its last update: ``n`` periods of ``period``
    counter ticks (``tick`` time units each), OC1REF high from CCR1 to the period's end
    (PWM mode 2), DIR (OC2REF) at ``dir_high``; ``cut``: the time it was forced low."""

    start: int
    n: int
    period: int
    ccr1: int
    tick: int
    dir_high: bool
    dir_since: int
    output: bool  # CC1E and MOE: the pulses reach the pin
    cut: int | None = None

    @property
    def end(self) -> int:
        return self.start + self.n * self.period * self.tick

    def rises(self, t: int) -> int:
        """Rising edges of OC1REF at or before ``t``."""
        if self.ccr1 > self.period - 1 or self.ccr1 == 0:
            return 0
        t = min(t, self.end if self.cut is None else self.cut)
        first = self.start + self.ccr1 * self.tick
        if t < first:
            return 0
        return min(self.n, (t - first) // (self.period * self.tick) + 1)

    @property
    def high_units(self) -> int:
        return (self.period - self.ccr1) * self.tick

    @property
    def low_units(self) -> int:
        return self.ccr1 * self.tick


class StepTimer(_Timer):
    """TIM1 as the step generator (RM0390 12.3): one-pulse mode with the repetition counter
    (``RCR + 1`` periods per trigger), started by its trigger in trigger mode (ITR0 = TIM5's
    TRGO), OC1 in PWM mode 2 (STEP) and forced low, OC2 in PWM mode 1 as DIR, ARR/CCR1/CCR2
    preloaded and taken at the update that ends a burst (or UG), TRGO = OC1REF (TIM3
    counts it), CC1E/CC2E and MOE. Every burst is kept in :attr:`bursts`."""

    NAME = "TIM1"
    BASE = 0x40010000
    CLOCK = (0x44, 0)
    BUS = 2
    ALLOWED = {CR1: 0x8D, CR2: 0x70, SMCR: 0x77, DIER: 0, SR: 0x1FFF, EGR: 0x1,
               CCMR1: 0x7878, CCER: 0x11, CNT: 0, PSC: 0xFFFF, ARR: 0xFFFF, RCR: 0xFF,
               CCR1: 0xFFFF, CCR2: 0xFFFF, BDTR: 0x8000}

    def reset(self) -> None:
        super().reset()
        self.shadow = {ARR: 0xFFFF, CCR1: 0, CCR2: 0, RCR: 0}
        self.burst: Burst | None = None
        self.bursts: list[Burst] = getattr(self, "bursts", [])
        self.dir_high, self.dir_since = False, self.m.now
        self.triggers_while_running = 0

    def _load(self, t: int) -> None:
        """An update event at ``t``: the preloaded registers become active."""
        before = self.dir_high
        self.shadow = {ARR: self.regs[ARR], CCR1: self.regs[CCR1], CCR2: self.regs[CCR2],
                       RCR: self.regs[RCR]}
        self.dir_high = self.shadow[CCR2] > 0  # OC2REF PWM1: high while CNT < CCR2
        if self.dir_high != before:
            self.dir_since = t

    def trigger(self, t: int) -> None:
        """TIM5's TRGO rising edge at ``t``."""
        self.advance(t)
        smcr = self.regs[SMCR]
        if smcr & 0x70 or smcr & 7 != 6:
            return  # not armed: ITR0 in trigger mode only
        if self.regs[CR1] & 1:
            self.triggers_while_running += 1
            return
        if not self.regs[CR1] & 0x8:
            raise UnsupportedAccessError("TIM1: trigger without one-pulse mode is not modelled")
        self.regs[CR1] |= 1
        self.burst = Burst(t, self.shadow[RCR] + 1, self.shadow[ARR] + 1, self.shadow[CCR1],
                           self.tick_units(), self.dir_high, self.dir_since, self.output_on())
        self.bursts.append(self.burst)

    def output_on(self) -> bool:
        return bool(self.regs[CCER] & 1 and self.regs[BDTR] & 0x8000)

    def advance(self, now: int) -> None:
        b = self.burst
        if b is not None and b.end <= now:
            self.burst = None
            self.regs[CR1] &= ~1
            self.regs[SR] |= 1
            self._load(b.end)

    def next_event(self) -> int | None:
        return None if self.burst is None else self.burst.end

    def freeze(self, duration: int) -> None:
        if self.burst is not None:
            self.burst.start += duration

    def read(self, off: int, size: int) -> int:
        self._check(off, size, "read")
        self._clock()
        if off == CNT:
            b = self.burst
            if b is None:
                return 0
            return (self.m.now - b.start) // b.tick % b.period
        return self.regs[off]

    def write(self, off: int, size: int, value: int) -> None:
        self.check_write(off, size, value)
        now = self.m.now
        self.advance(now)
        if off == SR:
            self.regs[SR] &= value
        elif off == EGR:
            if self.burst is not None:
                raise self.fail("UG during a burst is not modelled")
            self._load(now)
        elif off == CCMR1:
            oc1m = value >> 4 & 7
            if oc1m not in (4, 7) or value >> 12 & 7 != 6 or value & 0x303:
                raise self.fail(f"CCMR1 {value:#x}: OC1 PWM2/force low, OC2 PWM1 modelled")
            if oc1m == 4 and self.burst is not None and self.burst.cut is None:
                self.burst.cut = now
            self.regs[CCMR1] = value
        elif off == CR1:
            if self.burst is not None and not value & 1:
                if self.burst.cut is None:
                    self.burst.cut = now
                self.burst = None
            if value & 1 and self.burst is None:
                raise self.fail("CEN set by software: bursts start by trigger only here")
            self.regs[CR1] = value
        elif off == CNT:
            if value:
                raise self.fail("CNT written with a value other than 0")
        elif off == BDTR:
            self.regs[BDTR] = value
            if self.burst is not None and not value & 0x8000 and self.burst.cut is None:
                self.burst.cut = now  # outputs off: no more pulses reach the pin
        elif off == CCER:
            self.regs[CCER] = value
            if self.burst is not None and not value & 1 and self.burst.cut is None:
                self.burst.cut = now
        else:
            self.regs[off] = value

    def rises(self, t: int) -> int:
        """OC1REF rising edges (TRGO) of every burst up to ``t``."""
        return sum(b.rises(t) for b in self.bursts)


class PulseCounter(_Timer):
    """TIM3 counting TIM1's TRGO (external clock mode 1 on ITR0, RM0390 17.3.14), 16 bits
    (ARR 0xFFFF)."""

    NAME = "TIM3"
    BASE = 0x40000400
    CLOCK = (0x40, 1)
    ALLOWED = {CR1: 0x1, SMCR: 0x77, CNT: 0, ARR: 0xFFFF}

    def __init__(self, machine: Machine, rcc: Rcc, dbg: DbgMcu, source: StepTimer) -> None:
        self.source = source
        super().__init__(machine, rcc, dbg)

    def reset(self) -> None:
        super().reset()
        self.base, self.base_rises = 0, 0

    def read(self, off: int, size: int) -> int:
        self._check(off, size, "read")
        self._clock()
        if off != CNT:
            return self.regs[off]
        if not self.regs[CR1] & 1:
            return self.base
        return (self.base + self.source.rises(self.m.now) - self.base_rises) & 0xFFFF

    def write(self, off: int, size: int, value: int) -> None:
        self.check_write(off, size, value)
        if off == SMCR and value != 0x07:
            raise self.fail(f"SMCR {value:#x}: only external clock 1 on ITR0 is modelled")
        if off == ARR and value != 0xFFFF:
            raise self.fail("ARR other than 0xFFFF is not modelled")
        if off == CNT:
            raise self.fail("CNT written: not modelled")
        if off == CR1 and value & 1 and not self.regs[CR1] & 1:
            if self.regs[SMCR] != 0x07:
                raise self.fail("enabled before its slave mode")
            self.base_rises = self.source.rises(self.m.now)
        self.regs[off] = value


class EncoderTimer(_Timer):
    """TIM2 in encoder mode 3 (RM0390 18.3.16): CNT follows the quadrature position of the
    encoder on PA0/PA1 (both edges of both channels: one count per encoder count), 32 bits;
    the input filter is accepted and not modelled (the encoder model has no bounce)."""

    NAME = "TIM2"
    BASE = 0x40000000
    CLOCK = (0x40, 0)
    ALLOWED = {CR1: 0x1, SMCR: 0x7, CCMR1: 0xF3F3, CCER: 0, CNT: 0xFFFFFFFF,
               ARR: 0xFFFFFFFF}

    def __init__(self, machine: Machine, rcc: Rcc, dbg: DbgMcu,
                 position: Callable[[], int | None]) -> None:
        self.position = position  # counts, or None while the pins are not connected
        super().__init__(machine, rcc, dbg)

    def reset(self) -> None:
        super().reset()
        self.regs[ARR] = 0xFFFFFFFF
        self.offset = 0

    def _pos(self) -> int:
        p = self.position()
        if p is None:
            raise self.fail("encoder read with PA0/PA1 not in AF1 (TIM2_CH1/CH2)")
        return p

    def read(self, off: int, size: int) -> int:
        self._check(off, size, "read")
        self._clock()
        if off != CNT:
            return self.regs[off]
        if not self.regs[CR1] & 1:
            return self.regs[CNT]
        return (self._pos() + self.offset) & 0xFFFFFFFF

    def write(self, off: int, size: int, value: int) -> None:
        self.check_write(off, size, value)
        if off == SMCR and value != 3:
            raise self.fail(f"SMCR {value:#x}: only encoder mode 3 is modelled")
        if off == ARR and value != 0xFFFFFFFF:
            raise self.fail("ARR other than 0xFFFFFFFF is not modelled")
        if off == CCMR1 and (value & 0x3 != 1 or value >> 8 & 3 != 1):
                raise self.fail(f"CCMR1 {value:#x}: CC1S = TI1, CC2S = TI2 needed")
        if off == CR1 and value & 1 and not self.regs[CR1] & 1:
            if self.regs[SMCR] != 3:
                raise self.fail("enabled before encoder mode was set")
            self.offset = self.regs[CNT] - self._pos()
        if off == CNT and self.regs[CR1] & 1:
            self.offset = value - self._pos()
        self.regs[off] = value


# ---- SPI2, IWDG, RNG -----------------------------------------------------------------------

class Spi(Peripheral):
    """SPI2 as a master (RM0390 26.3.5): 8-bit frames, software NSS, full duplex; each DR
    write exchanges one byte with the device whose chip select is low (``exchange``), and
    RXNE/TXE are set at once (the 0.7 us a byte takes at 11.25 MHz is not modelled)."""

    NAME = "SPI2"
    BASE = 0x40003800
    REGS = {0x00: "CR1", 0x04: "CR2", 0x08: "SR", 0x0C: "DR"}
    RESET = {0x08: 0x2}
    CR1_MODELLED = 0x1 | 0x2 | 0x4 | 0x38 | 0x40 | 0x100 | 0x200
    MAX_SCK_HZ = 25_000_000  # the ADS131M02's fSCLK maximum

    def __init__(self, machine: Machine, rcc: Rcc,
                 exchange: Callable[[int], int | None]) -> None:
        self.rcc, self.exchange = rcc, exchange
        super().__init__(machine)

    def reset(self) -> None:
        super().reset()
        self.rx = 0

    def _clock(self) -> None:
        if not self.rcc.enabled(0x40, 14):
            raise self.fail("accessed with its clock off")

    def read(self, off: int, size: int) -> int:
        self._check(off, size, "read")
        self._clock()
        if off == 0x0C:
            self.regs[0x08] &= ~1
            return self.rx
        return self.regs[off]

    def write(self, off: int, size: int, value: int) -> None:
        name = self._check(off, size, "write")
        self._clock()
        if name == "CR1":
            if value & ~self.CR1_MODELLED:
                raise self.fail(f"SPI_CR1 {value:#x}: 16-bit frames, CRC, LSB first, "
                                f"bidirectional modes are not modelled")
            self.regs[0] = value
        elif name == "CR2":
            if value:
                raise self.fail("SPI_CR2: interrupts and DMA are not modelled")
        elif name == "SR":
            raise self.fail("SPI_SR written")
        else:
            self._transfer(value & 0xFF)

    def _transfer(self, byte: int) -> None:
        cr1 = self.regs[0]
        if not cr1 & 0x40:
            raise self.fail("DR written with SPE off")
        if cr1 & 0x304 != 0x304:
            raise self.fail("only master mode with software NSS (SSM, SSI) is modelled")
        sck = self.rcc.apb_hz(1) >> ((cr1 >> 3 & 7) + 1)
        if sck > self.MAX_SCK_HZ:
            raise self.fail(f"SCLK {sck / 1e6:g} MHz above the ADS131M02's 25 MHz")
        if cr1 & 3 != 1:
            raise self.fail(f"CPOL/CPHA {cr1 & 3}: the ADS131M02 needs mode 1 (CPOL 0, CPHA 1)")
        if self.regs[0x08] & 1:
            self.regs[0x08] |= 1 << 6  # OVR: the last byte was not read
        answer = self.exchange(byte)
        self.rx = 0x00 if answer is None else answer
        self.regs[0x08] |= 0x3


class Iwdg(Peripheral):
    """The independent watchdog (RM0390 19): started by 0xCCCC, reloaded by 0xAAAA,
    PR/RLR writable after 0x5555 and busy (PVU/RVU in SR) for 5 LSI cycles, counting down
    at LSI / (4 << PR); at 0 it resets the chip (RCC_CSR.IWDGRSTF). LSI at 32 kHz."""

    NAME = "IWDG"
    BASE = 0x40003000
    REGS = {0x0: "KR", 0x4: "PR", 0x8: "RLR", 0xC: "SR"}
    RESET = {0x8: 0xFFF}

    def __init__(self, machine: Machine, rcc: Rcc) -> None:
        self.rcc = rcc
        self.fired = 0
        self.running = False
        super().__init__(machine)

    def reset(self) -> None:
        super().reset()
        self.running = False  # a system reset stops it here (option byte WDG_SW = 1)
        self.unlocked = False
        self.expiry: int | None = None
        self.busy_until = 0

    def timeout_units(self) -> int:
        return (self.regs[0x8] + 1) * (4 << self.regs[0x4]) * UNITS_PER_S // LSI_HZ

    def read(self, off: int, size: int) -> int:
        self._check(off, size, "read")
        if off == 0xC:
            return 0x3 if self.m.now < self.busy_until else 0
        if off == 0x0:
            return 0
        return self.regs[off]

    def write(self, off: int, size: int, value: int) -> None:
        name = self._check(off, size, "write")
        if name == "KR":
            value &= 0xFFFF
            self.unlocked = value == 0x5555
            if value == 0xCCCC:
                self.running = True
                self.expiry = self.m.now + self.timeout_units()
            elif value == 0xAAAA and self.running:
                self.expiry = self.m.now + self.timeout_units()
        elif name == "SR":
            raise self.fail("IWDG_SR written")
        elif not self.unlocked:
            return  # write-protected
        else:
            self.regs[off] = value & (0x7 if off == 0x4 else 0xFFF)
            self.busy_until = self.m.now + IWDG_UPDATE_LSI_CYCLES * UNITS_PER_S // LSI_HZ

    def advance(self, now: int) -> None:
        if self.expiry is not None and now >= self.expiry:
            self.fired += 1
            self.rcc.note_reset(29)
            self.expiry = None
            self.m.request_reset("IWDG")

    def next_event(self) -> int | None:
        return self.expiry

    def freeze(self, duration: int) -> None:
        if self.expiry is not None:
            self.expiry += duration


class Rng(Peripheral):
    """The RNG (RM0390 20): RNGEN, DRDY and DR from a seeded generator while the PLL's Q
    output clocks it; without it CECS (clock error) is set."""

    NAME = "RNG"
    BASE = 0x50060800
    REGS = {0x0: "CR", 0x4: "SR", 0x8: "DR"}

    def __init__(self, machine: Machine, rcc: Rcc, seed: int) -> None:
        self.rcc, self.random = rcc, random.Random(seed)
        super().__init__(machine)

    def _clocked(self) -> bool:
        q = self.rcc.pll_q_hz()
        return q is not None and q <= 48_000_000 and q >= self.rcc.hclk // 16

    def read(self, off: int, size: int) -> int:
        self._check(off, size, "read")
        if not self.rcc.enabled(0x34, 6):
            raise self.fail("accessed with its clock off")
        if off == 0x4:
            if not self.regs[0] & 4:
                return 0
            return 0x1 if self._clocked() else 0x22  # DRDY, or CECS | CEIS
        if off == 0x8:
            return self.random.getrandbits(32) if self._clocked() else 0
        return self.regs[0]

    def write(self, off: int, size: int, value: int) -> None:
        self._check(off, size, "write")
        if off != 0 or value & ~4:
            raise self.fail(f"write {value:#x} at {off:#x}: only CR.RNGEN is modelled")
        self.regs[0] = value


__all__ = ["Dma1", "EncoderTimer", "Flash", "FlashMemory", "Gpio", "Iwdg", "PowerCutError",
           "PulseCounter", "Pwr", "Rcc", "Rng", "Spi", "StepTimer", "TickTimer", "Usart", "seconds"]

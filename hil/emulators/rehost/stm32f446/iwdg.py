"""The STM32F446's independent watchdog (RM0390 section 19), clocked by the 32 kHz LSI:
at its timeout it resets the chip through RCC's reset flags."""

from __future__ import annotations

from hil.emulators.rehost.machine import UNITS_PER_S, Machine, Peripheral
from hil.emulators.rehost.stm32f446.clocks import Rcc

LSI_HZ = 32_000
IWDG_UPDATE_LSI_CYCLES = 5  # RM0390 19.4.4: PR/RLR updates take up to 5 LSI cycles


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

"""The STM32F446's random number generator (RM0390 section 20), clocked by the PLL's Q
output: seeded, so a rehosted run repeats."""

from __future__ import annotations

import random

from hil.emulators.rehost.machine import Machine, Peripheral
from hil.emulators.rehost.stm32f446.clocks import Rcc


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

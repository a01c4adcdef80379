"""The STM32F446's GPIO ports A-C (RM0390 section 7): modes, alternate functions, pulls,
inputs from the board's wiring and outputs to it."""

from __future__ import annotations

from collections.abc import Callable

from hil.emulators.rehost.machine import Machine, Peripheral
from hil.emulators.rehost.stm32f446.clocks import Rcc


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

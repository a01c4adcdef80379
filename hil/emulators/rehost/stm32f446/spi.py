"""The STM32F446's SPI2 as the master of the ADS131M02 load-cell ADC (RM0390 section 26)."""

from __future__ import annotations

from collections.abc import Callable

from hil.emulators.rehost.machine import Machine, Peripheral
from hil.emulators.rehost.stm32f446.clocks import Rcc


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

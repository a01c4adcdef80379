"""The host link's serial port on the STM32F446 (RM0390 sections 9 and 25): USART2
receiving byte by byte at its baud rate with its interrupt, and DMA1 stream 6 sending the
firmware's frames through it."""

from __future__ import annotations

from collections.abc import Callable

from hil.emulators.rehost.machine import UNITS_PER_S, Machine, Peripheral
from hil.emulators.rehost.stm32f446.clocks import Rcc


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

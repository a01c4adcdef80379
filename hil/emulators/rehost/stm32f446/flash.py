"""The STM32F446's flash interface and the flash sectors the firmware writes (RM0390
section 3): the unlock sequence, sector erase and word programming of sectors 5-7 (the
calibration log and the boot counter), with a power-cut hook for the tests of the
firmware's log."""

from __future__ import annotations

from hil.emulators.rehost.machine import Machine, Peripheral


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

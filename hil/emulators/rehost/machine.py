"""A Cortex-M4 on the `unicorn` CPU emulator, with the parts of the core the firmware uses.

:class:`Machine` runs an unchanged ARM image: flash and RAM are plain memory, every
peripheral page is a memory-mapped IO region whose reads and writes go to a Python model
(:class:`Peripheral`), and nothing else calls Python (no per-instruction hook), so the CPU
runs in unicorn's translated code between peripheral accesses. Time is a count of
:data:`UNITS_PER_S` units per second; the CPU runs in chunks of at most :data:`MAX_CHUNK_S`
between the peripherals' events, one instruction per core clock cycle (what a Cortex-M4
running from zero-wait-state flash comes close to; caches and pipeline stalls are not
modelled). Interrupts (NVIC: enable, pending, 4-bit priorities, nesting, PRIMASK) are taken
between chunks; exception entry pushes the hardware's 8-word frame and exception return
(a branch to EXC_RETURN) pops it. WFI sleeps until an enabled interrupt is pending.

An access the models do not implement raises :class:`UnsupportedAccessError`: the run stops with it
(a test failure, never silence).
"""

from __future__ import annotations

import struct
import subprocess
from collections.abc import Callable
from pathlib import Path

from unicorn import (
    UC_ARCH_ARM,
    UC_HOOK_INTR,
    UC_MODE_MCLASS,
    UC_MODE_THUMB,
    Uc,
    UcError,
)
from unicorn.arm_const import (
    UC_ARM_REG_LR,
    UC_ARM_REG_PC,
    UC_ARM_REG_PRIMASK,
    UC_ARM_REG_R0,
    UC_ARM_REG_R1,
    UC_ARM_REG_R2,
    UC_ARM_REG_R3,
    UC_ARM_REG_R12,
    UC_ARM_REG_SP,
    UC_ARM_REG_XPSR,
    UC_CPU_ARM_CORTEX_M4,
)

#: Time unit: 1/1.44 GHz, the least common multiple of the clocks modelled (180 MHz HCLK,
#: 90 and 60 MHz timer clocks, 16 MHz HSI, 1 MHz tick, the 4 kHz watchdog clock).
UNITS_PER_S = 1_440_000_000
#: The longest run of instructions between two looks at the peripherals and interrupts:
#: also the worst interrupt latency, and the most a WFI's time can be over-counted.
MAX_CHUNK_S = 50e-6
EXC_RETURN_THREAD = 0xFFFFFFF9  # return to thread mode, main stack, basic frame
EXCP_EXCEPTION_EXIT = 8  # unicorn's interrupt number for a branch to EXC_RETURN
HARDFAULT = 3


def seconds(t: float) -> int:
    """Seconds -> time units (rounded)."""
    return round(t * UNITS_PER_S)


class UnsupportedAccessError(RuntimeError):
    """The firmware used a register or a configuration a model does not implement."""


class Peripheral:
    """A memory-mapped peripheral: ``read``/``write`` of an offset in its block.

    Subclasses list their registers in ``REGS`` (offset -> name); an access to any other
    offset, or of a size other than 4 bytes unless ``BYTE_OK`` names the offset, raises
    :class:`UnsupportedAccessError`. Plain registers keep what was written in :attr:`regs`.
    """

    NAME = "peripheral"
    BASE = 0
    SIZE = 0x400
    REGS: dict[int, str] = {}
    RESET: dict[int, int] = {}

    def __init__(self, machine: Machine) -> None:
        self.m = machine
        self.regs: dict[int, int] = {}
        self.reset()

    def reset(self) -> None:
        """Power-on reset values."""
        self.regs = {off: self.RESET.get(off, 0) for off in self.REGS}

    def fail(self, what: str) -> UnsupportedAccessError:
        return UnsupportedAccessError(f"{self.NAME}: {what} (pc {self.m.pc:#010x})")

    def _check(self, off: int, size: int, kind: str) -> str:
        name = self.REGS.get(off)
        if name is None or size != 4:
            raise self.fail(f"{kind} of {size} bytes at offset {off:#x}: not modelled")
        return name

    def read(self, off: int, size: int) -> int:
        self._check(off, size, "read")
        return self.regs[off]

    def write(self, off: int, size: int, value: int) -> None:
        self._check(off, size, "write")
        self.regs[off] = value

    def advance(self, now: int) -> None:
        """Bring the model's state to time ``now`` (flags, pending interrupts)."""

    def next_event(self) -> int | None:
        """The time of the model's next state change that can matter to the CPU."""
        return None

    def freeze(self, duration: int) -> None:
        """A debugger halted the core for ``duration`` and this peripheral's DBGMCU stop
        bit was set: it did not count (default: nothing to freeze)."""


class Machine:
    """The CPU, its memory, the NVIC and the peripheral map; see the module's docstring."""

    def __init__(self, cpu_hz: int = 16_000_000) -> None:
        self.uc = Uc(UC_ARCH_ARM, UC_MODE_THUMB | UC_MODE_MCLASS)
        self.uc.ctl_set_cpu_model(UC_CPU_ARM_CORTEX_M4)
        self.uc.hook_add(UC_HOOK_INTR, self._on_interrupt)
        self.now = 0
        self.cpu_hz = cpu_hz
        self.sleeping = False
        self.debug_halted = False  # a debugger holds the core: peripherals run on
        self.peripherals: list[Peripheral] = []
        self.timed: list[Peripheral] = []  # those with events: advance() and next_event()
        self._blocks: dict[int, Peripheral] = {}
        # NVIC: enabled, pending, priority byte per interrupt; active exceptions (nesting)
        self.enabled: set[int] = set()
        self.pending: set[int] = set()  # exception numbers (16 + IRQ), HardFault = 3
        self.priority: dict[int, int] = {}
        self.active: list[tuple[int, object]] = []  # (exception, the context it interrupted)
        self.vtor = 0
        self.instructions = 0
        # one instruction per emulator call: DWT's CYCCNT exact to the instruction (else it
        # moves by whole chunks, up to MAX_CHUNK_S of instructions); about 50 times slower
        self.exact_counts = False
        self.exceptions_taken: dict[int, int] = {}
        self.on_reset: list[Callable[[str], None]] = []
        self.reset_reasons: list[tuple[int, str]] = []
        self._fault_pending = False
        self._reset_request: str | None = None
        #: addresses after each WFI instruction of the image (:meth:`find_wfi`)
        self.wfi_returns: set[int] = set()

    # --- memory ---------------------------------------------------------------------------

    def map_memory(self, base: int, size: int, data: bytes = b"") -> None:
        self.uc.mem_map(base, size)
        if data:
            self.uc.mem_write(base, data)

    def map_mmio(self, base: int, size: int) -> None:
        """One IO page: its accesses are dispatched to the peripherals by 1 KiB block."""
        self.uc.mmio_map(base, size, self._mmio_read, base, self._mmio_write, base)

    def add(self, peripheral: Peripheral) -> Peripheral:
        for block in range(peripheral.BASE, peripheral.BASE + peripheral.SIZE, 0x400):
            self._blocks[block] = peripheral
        self.peripherals.append(peripheral)
        if type(peripheral).next_event is not Peripheral.next_event:
            self.timed.append(peripheral)
        return peripheral

    def _nothing(self, address: int) -> UnsupportedAccessError:
        return UnsupportedAccessError(f"access to {address:#010x}: no peripheral modelled there "
                           f"(pc {self.pc:#010x})")

    def _mmio_read(self, uc: Uc, offset: int, size: int, page: int) -> int:
        address = page + offset
        p = self._blocks.get(address & ~0x3FF)
        if p is None:
            raise self._nothing(address)
        return p.read(address - p.BASE, size) & ((1 << (8 * size)) - 1)

    def _mmio_write(self, uc: Uc, offset: int, size: int, value: int, page: int) -> None:
        address = page + offset
        p = self._blocks.get(address & ~0x3FF)
        if p is None:
            raise self._nothing(address)
        p.write(address - p.BASE, size, value)

    def read32(self, address: int) -> int:
        return int.from_bytes(self.uc.mem_read(address, 4), "little")

    def read_bytes(self, address: int, n: int) -> bytes:
        return bytes(self.uc.mem_read(address, n))

    def write32(self, address: int, value: int) -> None:
        self.uc.mem_write(address, (value & 0xFFFFFFFF).to_bytes(4, "little"))

    @property
    def pc(self) -> int:
        return self.uc.reg_read(UC_ARM_REG_PC)

    # --- NVIC -------------------------------------------------------------------------------

    def pend(self, exception: int) -> None:
        """Mark an exception (16 + IRQ number, or a system exception) pending."""
        self.pending.add(exception)

    def _takeable(self, masked: bool | None = None) -> int | None:
        """The pending exception the core would take now, if any (``masked``: PRIMASK as
        given instead of the core's)."""
        if not self.pending:
            return None
        current = self.priority.get(self.active[-1][0], -1) if self.active else 256
        if self.active and self.active[-1][0] == HARDFAULT:
            current = -1
        if masked is None:
            masked = bool(self.uc.reg_read(UC_ARM_REG_PRIMASK) & 1)
        best = None
        for exc in self.pending:
            if exc >= 16 and (exc - 16 not in self.enabled or masked):
                continue
            prio = -1 if exc == HARDFAULT else self.priority.get(exc, 0)
            if prio < current and (best is None or (prio, exc) < best[0]):
                best = ((prio, exc), exc)
        return None if best is None else best[1]

    def wake_pending(self) -> bool:
        """WFI wakes on any enabled pending interrupt, even with PRIMASK set."""
        return any(exc < 16 or exc - 16 in self.enabled for exc in self.pending)

    def _enter(self, exc: int) -> None:
        """Exception entry: the 8-word frame pushed as the hardware does (for the stack's
        depth); the whole register context is kept aside and comes back at the return
        (what the frame, the lazily stacked FP registers and an AAPCS handler's own
        saves give back on the chip)."""
        uc = self.uc
        context = uc.context_save()
        r0, r1, r2, r3, r12, lr, pc, xpsr, sp = uc.reg_read_batch(
            (UC_ARM_REG_R0, UC_ARM_REG_R1, UC_ARM_REG_R2, UC_ARM_REG_R3, UC_ARM_REG_R12,
             UC_ARM_REG_LR, UC_ARM_REG_PC, UC_ARM_REG_XPSR, UC_ARM_REG_SP))
        aligned = sp & 4
        sp = (sp - 32) & ~7
        frame_xpsr = (xpsr & ~(1 << 9)) | (1 << 24) | ((1 << 9) if aligned else 0)
        uc.mem_write(sp, struct.pack("<8I", r0, r1, r2, r3, r12, lr, pc & ~1, frame_xpsr))
        handler = self.read32(self.vtor + 4 * exc)
        uc.reg_write_batch(((UC_ARM_REG_SP, sp), (UC_ARM_REG_LR, EXC_RETURN_THREAD),
                            (UC_ARM_REG_PC, handler | 1)))
        self.pending.discard(exc)
        self.active.append((exc, context))
        self.exceptions_taken[exc] = self.exceptions_taken.get(exc, 0) + 1
        self.sleeping = False

    def _on_interrupt(self, uc: Uc, intno: int, data: object) -> None:
        if intno != EXCP_EXCEPTION_EXIT or not self.active:
            # any other CPU exception (undefined instruction, ...): a HardFault
            self._fault_pending = True
            uc.emu_stop()
            return
        _, context = self.active.pop()
        primask = uc.reg_read(UC_ARM_REG_PRIMASK)  # not restored by an exception return
        uc.context_restore(context)
        uc.reg_write(UC_ARM_REG_PRIMASK, primask)

    # --- reset, running ---------------------------------------------------------------------

    def reset(self, reason: str = "power-on") -> None:
        """Core reset: registers from the vector table, NVIC cleared, peripherals reset
        (RAM is kept, as on the chip); ``on_reset`` callbacks see the reason."""
        self.reset_reasons.append((self.now, reason))
        self._reset_request = None
        self.enabled.clear()
        self.pending.clear()
        self.priority.clear()
        self.active.clear()
        self.vtor = 0x08000000
        self.sleeping = False
        self._fault_pending = False
        self.uc.reg_write(UC_ARM_REG_PRIMASK, 0)
        for p in self.peripherals:
            p.reset()
        for callback in self.on_reset:
            callback(reason)
        self.uc.reg_write(UC_ARM_REG_SP, self.read32(self.vtor))
        self.uc.reg_write(UC_ARM_REG_PC, self.read32(self.vtor + 4) | 1)
        self.uc.reg_write(UC_ARM_REG_LR, 0xFFFFFFFF)

    def request_reset(self, reason: str) -> None:
        """A system reset (watchdog, SYSRESETREQ) at the end of the present instruction."""
        self._reset_request = reason
        self.uc.emu_stop()

    @property
    def insn_units(self) -> int:
        return UNITS_PER_S // self.cpu_hz

    def _next_event(self, limit: int) -> int:
        t = limit
        for p in self.timed:
            e = p.next_event()
            if e is not None and e < t:
                t = e
        return t

    def _advance(self) -> None:
        for p in self.timed:
            p.advance(self.now)

    def run_until(self, end: int) -> None:
        """Run the CPU and the peripherals to time ``end`` (units); raises what stopped
        the machine (:class:`UnsupportedAccessError`, an emulator error)."""
        while self.now < end:
            chunk = self.insn_units if self.exact_counts else seconds(MAX_CHUNK_S)
            self._advance()
            if self._reset_request is not None:
                reason, self._reset_request = self._reset_request, None
                self.reset(reason)
            if self._fault_pending:
                self._fault_pending = False
                self.pend(HARDFAULT)
            if self.debug_halted:
                self.now = max(self.now, self._next_event(end))
                continue
            exc = self._takeable()
            if exc is not None:
                self._enter(exc)
            if self.sleeping:
                if self.wake_pending():
                    self.sleeping = False
                    continue
                self.now = max(self.now, self._next_event(end))
                continue
            t = self._next_event(min(end, self.now + chunk))
            n = max(1, (t - self.now) // self.insn_units)
            if self.pending and self._takeable(masked=False) is not None:
                n = 1  # held back by PRIMASK only: one instruction at a time until the
                # CPSIE lets it in (a lower priority waits for the exception return)
            self._execute(n)
            self.now += n * self.insn_units

    def _execute(self, n: int) -> None:
        pc = self.uc.reg_read(UC_ARM_REG_PC)
        try:
            self.uc.emu_start(pc | 1, 0xFFFFFFFF, count=n)
        except UnsupportedAccessError:
            raise
        except UcError:
            # a bus error (unmapped address), an instruction the core refuses: HardFault
            self._fault_pending = True
            return
        self.instructions += n
        here = self.uc.reg_read(UC_ARM_REG_PC)
        if here in self.wfi_returns:  # stopped by a WFI (or its count ended there)
            self.sleeping = True


def find_wfi(machine: Machine, elf: Path) -> None:
    """Note where the image's WFI instructions are (arm-none-eabi-objdump's disassembly):
    an emulation that stops just after one has gone to sleep."""
    out = subprocess.run(["arm-none-eabi-objdump", "-d", str(elf)], capture_output=True,
                         text=True, check=True).stdout
    for line in out.splitlines():
        parts = line.split("\t")
        if len(parts) >= 3 and parts[2].strip() == "wfi":
            machine.wfi_returns.add(int(parts[0].strip().rstrip(":"), 16) + 2)


def load_elf(machine: Machine, elf: Path) -> list[tuple[int, bytes]]:
    """The PT_LOAD segments of a 32-bit little-endian ARM ELF, written at their physical
    (load) addresses; returns (address, bytes) of each, unchanged from the file."""
    data = elf.read_bytes()
    if data[:4] != b"\x7fELF" or data[4] != 1 or data[5] != 1:
        raise ValueError(f"{elf} is not a 32-bit little-endian ELF file")
    phoff, = struct.unpack_from("<I", data, 28)
    phentsize, phnum = struct.unpack_from("<HH", data, 42)
    segments = []
    for i in range(phnum):
        p_type, offset, _vaddr, paddr, filesz, _memsz, _flags, _align = struct.unpack_from(
            "<8I", data, phoff + i * phentsize)
        if p_type == 1 and filesz:
            chunk = data[offset:offset + filesz]
            machine.uc.mem_write(paddr, chunk)
            segments.append((paddr, chunk))
    return segments

"""The Cortex-M4's own memory-mapped parts (ARMv7-M architecture reference manual, Cortex-M4
generic user guide) and the STM32F446's DBGMCU (RM0390 section 33.16): the NVIC, the SCB,
SysTick, the DWT cycle counter, the debug freeze bits. Registers the firmware does not
touch are not modelled (:class:`hil.emulators.rehost.machine.UnsupportedAccessError`)."""

from __future__ import annotations

from hil.emulators.rehost.machine import Machine, Peripheral

CPUID_M4_R0P1 = 0x410FC241
AIRCR_VECTKEY = 0x05FA
AIRCR_SYSRESETREQ = 1 << 2
DEMCR_TRCENA = 1 << 24
DWT_CYCCNTENA = 1


class SystemControl(Peripheral):
    """0xE000E000: SysTick, the NVIC (ISER/ICER/ISPR/ICPR, 4-bit priority bytes) and the
    SCB (CPUID, VTOR, AIRCR's SYSRESETREQ, SHPR, fault status, CPACR, DEMCR)."""

    NAME = "SCS"
    BASE = 0xE000E000
    SIZE = 0x1000
    REGS = {0x10: "SYST_CSR", 0x14: "SYST_RVR", 0x18: "SYST_CVR", 0x1C: "SYST_CALIB",
            0xD00: "CPUID", 0xD04: "ICSR", 0xD08: "VTOR", 0xD0C: "AIRCR", 0xD10: "SCR",
            0xD14: "CCR", 0xD18: "SHPR1", 0xD1C: "SHPR2", 0xD20: "SHPR3", 0xD24: "SHCSR",
            0xD28: "CFSR", 0xD2C: "HFSR", 0xD88: "CPACR", 0xDFC: "DEMCR"}
    RESET = {0xD00: CPUID_M4_R0P1, 0xD08: 0x08000000, 0xD0C: 0xFA050000, 0xD14: 0x200}

    def read(self, off: int, size: int) -> int:
        m = self.m
        if 0x100 <= off < 0x380 and size == 4:  # ISER, ICER, ISPR, ICPR
            word = (off & 0x7F) // 4
            if word > 2:
                raise self.fail(f"NVIC word {word}: the F446 has 97 interrupts")
            group = (off - 0x100) // 0x80
            bits = m.enabled if group in (0, 1) else {e - 16 for e in m.pending if e >= 16}
            return sum(1 << (i - 32 * word) for i in bits if 32 * word <= i < 32 * word + 32)
        if 0x400 <= off < 0x461:
            return sum((m.priority.get(16 + off - 0x400 + k, 0) << 4) << (8 * k)
                       for k in range(size))
        name = self._check(off, size, "read")
        if name == "VTOR":
            return m.vtor
        return self.regs[off]

    def write(self, off: int, size: int, value: int) -> None:
        m = self.m
        if 0x100 <= off < 0x380 and size == 4:
            word = (off & 0x7F) // 4
            if word > 2:
                raise self.fail(f"NVIC word {word}: the F446 has 97 interrupts")
            irqs = {32 * word + b for b in range(32) if value >> b & 1}
            group = (off - 0x100) // 0x80
            if group == 0:
                m.enabled |= irqs
            elif group == 1:
                m.enabled -= irqs
            elif group == 2:
                m.pending |= {16 + i for i in irqs}
            else:
                m.pending -= {16 + i for i in irqs}
            return
        if 0x400 <= off < 0x461:
            for k in range(size):
                m.priority[16 + off - 0x400 + k] = ((value >> (8 * k)) & 0xFF) >> 4
            return
        name = self._check(off, size, "write")
        if name == "SYST_CSR" and value & 1:
            raise self.fail("SysTick enabled: its counting is not modelled (unused so far)")
        if name == "AIRCR":
            if value >> 16 != AIRCR_VECTKEY:
                return  # ignored without the key, as on the core
            if value & AIRCR_SYSRESETREQ:
                m.request_reset("SYSRESETREQ")
            return
        if name in ("CPUID", "CFSR", "HFSR"):
            if name == "CPUID":
                raise self.fail("write to CPUID")
            self.regs[off] &= ~value  # write 1 to clear
            return
        if name == "VTOR":
            m.vtor = value & ~0x7F
            return
        if name == "SHPR3":
            m.priority[14] = (value >> 16 & 0xFF) >> 4
            m.priority[15] = (value >> 24 & 0xFF) >> 4
        if name == "SCR" and value & 0x4:
            raise self.fail("SLEEPDEEP: stop and standby modes are not modelled")
        self.regs[off] = value


class Dwt(Peripheral):
    """0xE0001000: DWT_CTRL's CYCCNTENA and the cycle counter, counting the core's cycles
    (one per instruction here) while DEMCR.TRCENA and CYCCNTENA are set. The count moves
    when a chunk of instructions ends: a read inside a chunk gives its start's count, so the
    difference of two reads is exact only with ``Machine.exact_counts``."""

    NAME = "DWT"
    BASE = 0xE0001000
    REGS = {0x0: "CTRL", 0x4: "CYCCNT"}
    RESET = {0x0: 0x40000000}  # NUMCOMP = 4

    def __init__(self, machine: Machine, scs: SystemControl) -> None:
        self.scs = scs
        super().__init__(machine)

    def reset(self) -> None:
        super().reset()
        self.base_count, self.base_insn = 0, 0

    def _running(self) -> bool:
        return bool(self.scs.regs[0xDFC] & DEMCR_TRCENA and self.regs[0] & DWT_CYCCNTENA)

    def _count(self) -> int:
        extra = self.m.instructions - self.base_insn if self._running() else 0
        return (self.base_count + extra) & 0xFFFFFFFF

    def read(self, off: int, size: int) -> int:
        self._check(off, size, "read")
        return self._count() if off == 4 else self.regs[0]

    def write(self, off: int, size: int, value: int) -> None:
        self._check(off, size, "write")
        count = self._count()
        if off == 4:
            count = value
        else:
            if value & ~1 & 0xFFFF:
                raise self.fail(f"DWT_CTRL {value:#x}: only CYCCNTENA is modelled")
            self.regs[0] = (self.regs[0] & ~1) | (value & 1)
        self.base_count, self.base_insn = count, self.m.instructions


class DbgMcu(Peripheral):
    """0xE0042000: the debug freeze bits (RM0390 33.16.4, 33.16.5). A debugger halt
    (:meth:`hil.emulators.rehost.nucleo.NucleoBoard.debug_halt`) freezes the peripherals whose
    bit is set."""

    NAME = "DBGMCU"
    BASE = 0xE0042000
    REGS = {0x0: "IDCODE", 0x4: "CR", 0x8: "APB1_FZ", 0xC: "APB2_FZ"}
    RESET = {0x0: 0x10006421}  # DEV_ID 0x421: STM32F446
    APB1_BITS = {"TIM2": 0, "TIM3": 1, "TIM4": 2, "TIM5": 3, "WWDG": 11, "IWDG": 12}
    APB2_BITS = {"TIM1": 0}

    def write(self, off: int, size: int, value: int) -> None:
        name = self._check(off, size, "write")
        if name == "IDCODE":
            raise self.fail("write to IDCODE")
        if name == "CR" and value:
            raise self.fail("DBGMCU_CR (debug in low-power modes) is not modelled")
        self.regs[off] = value

    def frozen(self, peripheral: str) -> bool:
        """Whether ``peripheral`` (TIM1, TIM2, TIM3, TIM5, IWDG) stops in a debug halt."""
        if peripheral in self.APB2_BITS:
            return bool(self.regs[0xC] >> self.APB2_BITS[peripheral] & 1)
        return bool(self.regs[0x8] >> self.APB1_BITS[peripheral] & 1)

"""The STM32F446's clock tree and power control (RM0390 sections 5 and 6): PWR's voltage
scaling and over-drive, RCC's oscillators, main PLL, system clock switch, bus prescalers,
MCO2, peripheral clock enables and reset flags. The other models ask :class:`Rcc` for
their bus clocks and whether their clock is on."""

from __future__ import annotations

from collections.abc import Callable

from hil.emulators.rehost.machine import Machine, Peripheral

HSI_HZ = 16_000_000
HSE_HZ = 8_000_000  # the ST-LINK's MCO into OSC_IN (HSE bypass)


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

"""The STM32F446's timers as the firmware uses them (RM0390 sections 12, 17 and 18): TIM5
the tick, TIM1 the step-pulse generator (its bursts kept as :class:`Burst`), TIM3 counting
TIM1's pulses, TIM2 the encoder interface. One module: they trigger and count each other
and share the register map and checks of ``_Timer``."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from hil.emulators.rehost.cortex import DbgMcu
from hil.emulators.rehost.machine import UNITS_PER_S, Machine, Peripheral, UnsupportedAccessError
from hil.emulators.rehost.stm32f446.clocks import Rcc

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

/* The step bursts of the NUCLEO-F446RE's step generator (firmware/board/nucleo_step.c,
 * docs/firmware.md "Step generator"): a period's |delta| steps leave as one burst of TIM1
 * counting at STEP_BURST_CLOCK_HZ, started by hardware STEP_PHASE_US after the period's
 * tick and spread over one period less a guard; each pulse period is low, then high for its
 * last `high` ticks (PWM mode 2), so a step takes effect at its rising edge.
 *
 * Shared with the simulated rig (firmware/sim/sim_rig.c, sim_rig_hw.step_timing), which can
 * emit a period's steps with this timing, so that the host build's table moves at the
 * instants the rehosted board's does (docs/firmware-emulated.md "Host build and rehost,
 * sample by sample"). Header only, no state.
 */
#ifndef STEP_BURST_H
#define STEP_BURST_H

#include <stdint.h>

#define STEP_BURST_CLOCK_HZ 60000000u    /* TIM1: 180 MHz / 3 */
#define STEP_BURST_PERIOD_TICKS 60000u   /* one 1 ms telemetry period of TIM1 ticks */
#define STEP_GUARD_TICKS 60u             /* a burst ends >= 1 us before the next may start */
#define STEP_PULSE_TICKS 150u            /* 2.5 us high (shorter when the period is < 5 us) */
#define STEP_MAX_PER_PERIOD 256u         /* TIM1's 8-bit repetition counter: one burst */
#define STEP_PHASE_US 300u               /* a burst starts this long after its tick */
/* TIM1 ticks from a burst's start to the next period's tick */
#define STEP_BURST_TICKS_TO_TICK (STEP_BURST_PERIOD_TICKS - STEP_PHASE_US * 60u)

/* Timer ticks of one pulse period in an n-step burst (n >= 1). */
static inline uint32_t step_burst_period(uint32_t n) {
    return (STEP_BURST_PERIOD_TICKS - STEP_GUARD_TICKS) / n;
}

/* Ticks STEP is high in a pulse period of `period` ticks. */
static inline uint32_t step_burst_high(uint32_t period) {
    return period / 2u < STEP_PULSE_TICKS ? period / 2u : STEP_PULSE_TICKS;
}

/* Rising edges of an n-step burst within `ticks` timer ticks of its start (inclusive). */
static inline uint32_t step_burst_rises(uint32_t n, uint32_t ticks) {
    if (n == 0u || n > STEP_BURST_PERIOD_TICKS - STEP_GUARD_TICKS) return 0u;
    uint32_t period = step_burst_period(n), first = period - step_burst_high(period);
    if (ticks < first) return 0u;
    uint32_t k = (ticks - first) / period + 1u;
    return k < n ? k : n;
}

#endif

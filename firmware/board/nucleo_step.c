/* The NUCLEO-F446RE's motor outputs (board_nucleo.h): the step generator (TIM1 one-pulse
 * bursts of |delta| pulses on PA8, started by TIM5's OC1REF STEP_PHASE_US into the period,
 * DIR on PA9; TIM3 counts the pulses emitted), the driver's enable (PA10) and its stop
 * chain's feedback, and the fault handlers' safe state. */
#include "board_nucleo.h"
#include "step_burst.h"

#define STEP_TIMER_PSC 3u                         /* TIM1 at 60 MHz */
#define STEP_TICKS_PER_PERIOD (APB2_TIMER_HZ / STEP_TIMER_PSC / RIG_TELEMETRY_HZ) /* 60000 */
_Static_assert(STEP_TICKS_PER_PERIOD == STEP_BURST_PERIOD_TICKS &&
                   APB2_TIMER_HZ / STEP_TIMER_PSC == STEP_BURST_CLOCK_HZ,
               "step_burst.h describes TIM1 at these clocks");
/* STEP_GUARD_TICKS, STEP_PULSE_TICKS, STEP_MAX_PER_PERIOD, STEP_PHASE_US: step_burst.h */
#define STEP_ARM_DEADLINE_US (STEP_PHASE_US - 10u) /* hal_step later than this: an error */

/* the step generator's bookkeeping: the burst before the last armed one (a), the last one
 * armed (b); pulses emitted since base (TIM3's count, mod 2^16) fill a first, then b */
typedef struct {
    uint16_t n;
    int8_t sign;
} burst;
static burst burst_a, burst_b;
static uint16_t pulse_base;
bool step_error; /* a burst that could not be armed in time or was too long */
bool driver_on;  /* what hal_driver_enable last set */

/* ---- step generator: TIM1 bursts, TIM3 counts them ----------------------------------------- */

void step_init(void) {
    TIM1->CR1 = TIM_CR1_OPM | TIM_CR1_ARPE | TIM_CR1_URS;
    TIM1->PSC = STEP_TIMER_PSC - 1u;
    TIM1->ARR = STEP_TICKS_PER_PERIOD - 1u;
    TIM1->CCR1 = STEP_TICKS_PER_PERIOD; /* no pulse until armed */
    TIM1->CCR2 = 0;                     /* DIR low */
    TIM1->CCMR1 = TIM_CCMR_OC1M_PWM2 | TIM_CCMR_OC1PE | TIM_CCMR_OC2M_PWM1 | TIM_CCMR_OC2PE;
    TIM1->CCER = TIM_CCER_CC1E | TIM_CCER_CC2E;
    TIM1->CR2 = TIM_CR2_MMS_OC1REF; /* every step's rising edge clocks TIM3 */
    TIM1->SMCR = TIM_SMCR_TS_ITR0;  /* ITR0 = TIM5's TRGO; slave mode set when armed */
    TIM1->EGR = TIM_EGR_UG;
    TIM1->BDTR = TIM_BDTR_MOE;
    TIM3->ARR = 0xFFFFu;
    TIM3->SMCR = TIM_SMCR_TS_ITR0 | TIM_SMCR_SMS_EXTCLK1; /* TIM3's ITR0 = TIM1's TRGO */
    TIM3->CR1 = TIM_CR1_CEN;
    pulse_base = (uint16_t)TIM3->CNT;
}

void hal_step(int32_t delta) {
    uint32_t n = (uint32_t)(delta < 0 ? -(int64_t)delta : delta);
    /* the burst armed two calls ago has ended (before the last one started) */
    pulse_base = (uint16_t)(pulse_base + burst_a.n);
    burst_a = burst_b;
    burst_b.n = 0;
    burst_b.sign = 0;
    if (n == 0) {
        TIM1->SMCR = TIM_SMCR_TS_ITR0; /* no trigger: the timer stays stopped */
        return;
    }
    if (n > STEP_MAX_PER_PERIOD || tick_count != tick_now ||
        TIM5->CNT >= STEP_ARM_DEADLINE_US) {
        /* a burst this long, or armed so late that the last one may be ending while its
         * registers are written: not emitted; the core halts (hal_read reports it) and
         * hal_step_halt() gives these pulses back */
        TIM1->SMCR = TIM_SMCR_TS_ITR0;
        burst_b.n = (uint16_t)(n > 0xFFFFu ? 0xFFFFu : n);
        burst_b.sign = delta < 0 ? -1 : 1;
        step_error = true;
        board_tick_stats.step_errors++;
        return;
    }
    uint32_t period = step_burst_period(n); /* timer ticks */
    uint32_t high = step_burst_high(period);
    /* no interrupt between the deadline check above and the last write: the running burst
     * (the last period's) ends >= 4.8 us after the deadline and takes these at its end */
    irq_disable();
    if (TIM5->CNT >= STEP_ARM_DEADLINE_US) { /* an interrupt came between: too late now */
        irq_enable();
        burst_b.n = (uint16_t)n;
        burst_b.sign = delta < 0 ? -1 : 1;
        step_error = true;
        board_tick_stats.step_errors++;
        return;
    }
    bool running = (TIM1->CR1 & TIM_CR1_CEN) != 0;
    TIM1->ARR = period - 1u;
    TIM1->CCR1 = period - high; /* PWM mode 2: low, then high for `high` ticks */
    TIM1->CCR2 = delta < 0 ? 0u : 0xFFFFu; /* DIR: always low / always high */
    TIM1->RCR = n - 1u;
    if (!running) TIM1->EGR = TIM_EGR_UG; /* stopped: load them now */
    TIM1->SMCR = TIM_SMCR_TS_ITR0 | TIM_SMCR_SMS_TRIGGER;
    irq_enable();
    burst_b.n = (uint16_t)n;
    burst_b.sign = delta < 0 ? -1 : 1;
}

int32_t hal_step_halt(void) {
    uint32_t ccmr = TIM1->CCMR1;
    TIM1->CCMR1 = (ccmr & ~(7u << 4)) | TIM_CCMR_OC1M_FORCE_LOW; /* at once */
    TIM1->SMCR = TIM_SMCR_TS_ITR0;
    TIM1->CR1 &= ~TIM_CR1_CEN;
    uint16_t emitted = (uint16_t)((uint16_t)TIM3->CNT - pulse_base);
    uint32_t done_a = emitted < burst_a.n ? emitted : burst_a.n;
    uint32_t done_b = emitted > burst_a.n ? (uint32_t)(emitted - burst_a.n) : 0u;
    if (done_b > burst_b.n) done_b = burst_b.n;
    int32_t left = burst_a.sign * (int32_t)(burst_a.n - done_a) +
                   burst_b.sign * (int32_t)(burst_b.n - done_b);
    TIM1->CNT = 0;
    TIM1->EGR = TIM_EGR_UG;
    TIM1->CCMR1 = ccmr;
    pulse_base = (uint16_t)TIM3->CNT;
    burst_a.n = burst_b.n = 0;
    burst_a.sign = burst_b.sign = 0;
    step_error = false;
    return left;
}

void hal_driver_enable(bool on) {
    driver_on = on;
    pin_write(GPIOA, PIN_ENABLE, on);
}

/* The chain's feedback (PB5) high with the enable on: the contacts pass the enable. */
bool hal_driver_powered(void) { return driver_on && pin_read(GPIOB, PIN_CHAIN); }

/* The first thing every fault handler does (startup.c's Default_Handler): the driver's
 * enable low and the step timer stopped, touching only what is clocked. */
void board_fault_stop(void) {
    if (RCC->AHB1ENR & RCC_AHB1_GPIOA) GPIOA->BSRR = 1u << (PIN_ENABLE + 16u);
    if (RCC->APB2ENR & RCC_APB2_TIM1) {
        TIM1->BDTR = 0;                /* outputs off: STEP and DIR idle low */
        TIM1->SMCR = TIM_SMCR_TS_ITR0; /* no trigger */
        TIM1->CR1 = 0;                 /* counter stopped */
    }
}


/* The rig firmware on the NUCLEO-F446RE (STM32F446RE): rig_hal.h on the real hardware and
 * the main loop around the portable core. Pins, clocks and the reasoning are in
 * docs/firmware.md; in short:
 *
 *   clock   8 MHz from the ST-LINK's MCO (HSE bypass) -> PLL M 4, N 180, P 2 -> 180 MHz;
 *           AHB 180, APB1 45 (timers 90), APB2 90 (timers 180); PLLQ 8 -> 45 MHz for the
 *           RNG; flash 5 wait states, over-drive on. HSI 16 MHz (M 8) if the MCO is absent.
 *   serial  USART2 PA2/PA3 (ST-LINK virtual COM port), 921 600 baud 8N1; RX by the RXNE
 *           interrupt into a ring; TX by DMA1 stream 6 from rig_tx_take()
 *   tick    TIM5 at 1 MHz, update every 1000 us: the interrupt counts; the main loop runs
 *           rig_rx() on the received bytes and rig_tick() for each counted period
 *   steps   TIM1 one-pulse mode with the repetition counter: |delta| pulses of PA8 per
 *           burst, started by hardware (TIM5's OC1REF, STEP_PHASE_US after the tick) and
 *           spread over one period; DIR on PA9 is TIM1 channel 2, whose preloaded level
 *           changes at a burst's end; TIM3 counts the emitted pulses (TIM1 TRGO = OC1REF)
 *   encoder TIM2 (32 bits) in encoder mode 3 on PA0/PA1
 *   load    ADS131M02 on SPI2 (PB13/14/15, CS PB12), CLKIN 8 MHz from MCO2 (PC9, HSE):
 *           3.9 kSPS, the latest conversion read in the tick
 *   inputs  home PC0, stop PB0 (normally-closed button) or the Nucleo's B1 (PC13), driver
 *           alarm PB4, overtravel limits PC2 (open end) and PC3 (closed end, both normally
 *           closed to GND), the stop chain's feedback PB5 (the driver's enable after the
 *           stop contacts), the ADC's DRDY PB1; driver enable PA10
 *   safety  IWDG about 50 ms, kicked from the tick (rig_tick calls hal_watchdog_kick); IWDG
 *           and the timers frozen while a debugger halts the core (DBGMCU); every fault
 *           handler first takes the enable low and stops TIM1 (board_fault_stop); bounded
 *           clock waits (HSI and the CLOCK fault when the PLL does not lock); the ADC's
 *           presence, DRDY, CRC and STATUS checked (LOAD_ADC); overtravel (OVERTRAVEL) and
 *           the stop chain (STOP_CHAIN) read every tick; a late tick or a burst over 256
 *           steps is INTERNAL
 *   flash   sectors 5 and 6: the load-cell calibration log, sector 7 the boot counter
 *           (cal_flash.c)
 *   boot id the RNG mixed with the boot counter, never 0 nor the previous boot's
 */
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>
#include <string.h>

#include "cal_flash.h"
#include "rig_core.h"
#include "rx_ring.h"
#include "step_burst.h"
#include "stm32f4_regs.h"

/* ---- constants ----------------------------------------------------------------------------- */

#define HCLK_HZ 180000000u
#define APB1_HZ 45000000u
#define APB1_TIMER_HZ 90000000u
#define APB2_TIMER_HZ 180000000u
#define HSI_HZ 16000000u /* the fallback: every bus at 16 MHz, no motion (CLOCK fault) */
#define CLOCK_WAIT_TRIES 100000u /* each wait: well over the datasheet's lock/ready times */
#define STEP_TIMER_PSC 3u                         /* TIM1 at 60 MHz */
#define STEP_TICKS_PER_PERIOD (APB2_TIMER_HZ / STEP_TIMER_PSC / RIG_TELEMETRY_HZ) /* 60000 */
_Static_assert(STEP_TICKS_PER_PERIOD == STEP_BURST_PERIOD_TICKS &&
                   APB2_TIMER_HZ / STEP_TIMER_PSC == STEP_BURST_CLOCK_HZ,
               "step_burst.h describes TIM1 at these clocks");
/* STEP_GUARD_TICKS, STEP_PULSE_TICKS, STEP_MAX_PER_PERIOD, STEP_PHASE_US: step_burst.h */
#define STEP_ARM_DEADLINE_US (STEP_PHASE_US - 10u) /* hal_step later than this: an error */
#define TX_DMA_BYTES 128u
#define IWDG_PRESCALER_DIV8 1u /* LSI 32 kHz / 8 = 4 kHz */
#define IWDG_RELOAD 200u       /* 200 / 4 kHz = 50 ms */

/* USART2 at 45 MHz: USARTDIV = 45e6 / (16 * 921600) = 3.05 -> 3 + 1/16 = 3.0625:
 * 918 367 baud, -0.35 % (a receiver tolerates about +-3 %). On the HSI fallback (16 MHz):
 * 1 + 1/16 = 1.0625: 941 176 baud, +2.1 % (enough to report the CLOCK fault). */
#define USART2_BRR ((3u << 4) | 1u)
#define USART2_BRR_HSI ((1u << 4) | 1u)

/* pins: port, number */
#define PIN_STEP 8u    /* PA8  TIM1_CH1 AF1 */
#define PIN_DIR 9u     /* PA9  TIM1_CH2 AF1 */
#define PIN_ENABLE 10u /* PA10 GPIO out: high energises the driver */
#define PIN_ENC_A 0u   /* PA0  TIM2_CH1 AF1 */
#define PIN_ENC_B 1u   /* PA1  TIM2_CH2 AF1 */
#define PIN_TX 2u      /* PA2  USART2_TX AF7 */
#define PIN_RX 3u      /* PA3  USART2_RX AF7 */
#define PIN_STOP 0u    /* PB0  stop button (normally closed to GND: high = pressed/open) */
#define PIN_ALARM 4u   /* PB4  driver alarm (photocoupler on in normal: high = alarm) */
#define PIN_CS 12u     /* PB12 ADC chip select, GPIO out */
#define PIN_SCK 13u    /* PB13 SPI2_SCK AF5 */
#define PIN_MISO 14u   /* PB14 SPI2_MISO AF5 */
#define PIN_MOSI 15u   /* PB15 SPI2_MOSI AF5 */
#define PIN_ADC_RST 2u /* PB2  ADC SYNC/RESET, GPIO out (high = run) */
#define PIN_DRDY 1u    /* PB1  ADC DRDY (low: a conversion waits to be read) */
#define PIN_CHAIN 5u   /* PB5  stop chain feedback: high while the driver's enable is live */
#define PIN_HOME 0u    /* PC0  home switch (closes to GND when active) */
#define PIN_LIMIT_OPEN 2u   /* PC2  overtravel beyond the open end (NC to GND: high = hit) */
#define PIN_LIMIT_CLOSED 3u /* PC3  overtravel beyond the closed end (NC to GND: high = hit) */
#define PIN_CLKIN 9u   /* PC9  MCO2 AF0: 8 MHz to the ADC's CLKIN */
#define PIN_B1 13u     /* PC13 the Nucleo's user button B1 (low when pressed) */

/* the firmware's calibration while none is stored (cal_flash.c) */
#define CAL_DEFAULT_OFFSET 1500
#define CAL_DEFAULT_GAIN 1e-4f
#define NOINIT_MAGIC 0xB007B007u

/* FAULT values of the board's faults (docs/rig-protocol.md section 8) */
#define INTERNAL_STEP_BURST 1 /* a burst over 256 steps or armed too late: not emitted */
#define INTERNAL_LATE_TICK 2  /* a tick ran more than one period late */
#define ADC_MISSING 1         /* no ADS131M02 answered at boot (ID register, CRC) */
#define ADC_DRDY_TIMEOUT 2    /* no conversion for ADC_DRDY_TICKS ticks */
#define ADC_BAD_CRC 3         /* a frame's output CRC did not match */
#define ADC_BAD_STATUS 4      /* STATUS: reset, resync, register map or word length */
#define ADC_SPI_TIMEOUT 5     /* SPI2 did not finish a byte */
#define CLOCK_NO_HSE 1        /* HSE missing: the PLL runs from HSI, the ADC has no CLKIN */
#define CLOCK_NO_PLL 2        /* the PLL did not lock: running on HSI, no motion */
#define CLOCK_NO_OVERDRIVE 3  /* over-drive not ready: HSI, no motion */
#define CLOCK_NO_SWITCH 4     /* the switch to the PLL did not take: HSI, no motion */
#define ADC_DRDY_TICKS 3u     /* ticks without a conversion (one every 256 us) */
#define STOP_CHAIN_TICKS 20u  /* feedback may lag the enable this long (relays) */

/* ---- state ---------------------------------------------------------------------------------- */

static rig_mcu mcu;
static volatile uint32_t tick_count;      /* TIM5 updates */
static uint32_t tick_now;                 /* tick_count at which the running rig_tick is due */
static rx_ring rx;
static volatile uint32_t rx_overruns;
static uint8_t tx_dma_buf[TX_DMA_BYTES];

/* the step generator's bookkeeping: the burst before the last armed one (a), the last one
 * armed (b); pulses emitted since base (TIM3's count, mod 2^16) fill a first, then b */
typedef struct {
    uint16_t n;
    int8_t sign;
} burst;
static burst burst_a, burst_b;
static uint16_t pulse_base;
static bool step_error; /* a burst that could not be armed in time or was too long */
static bool late_tick;  /* the main loop found more than one period due */
static bool driver_on;  /* what hal_driver_enable last set */
static uint32_t clock_fault, adc_fault; /* CLOCK_*, ADC_* codes (0: none) */
static uint32_t drdy_missed, chain_mismatch;
static int32_t adc_last;
static uint32_t apb1_hz = APB1_HZ, apb1_timer_hz = APB1_TIMER_HZ;

/* what a debugger reads (docs/firmware.md): the tick's cost in CPU cycles (DWT) */
typedef struct {
    uint32_t ticks, late_ticks, tick_max_cycles, rx_max_cycles, step_errors, rx_overruns;
    uint32_t boots, clock_from_hsi, rng_failed;
} board_stats;
volatile board_stats board_tick_stats;

static struct {
    uint32_t magic, last_id;
} persist __attribute__((section(".noinit")));

/* ---- GPIO ------------------------------------------------------------------------------------ */

static void pin_mode(gpio_regs *port, uint32_t pin, uint32_t mode, uint32_t af, uint32_t pull) {
    uint32_t shift2 = pin * 2u, shift4 = (pin & 7u) * 4u;
    port->AFR[pin >> 3] = (port->AFR[pin >> 3] & ~(0xFu << shift4)) | (af << shift4);
    port->OSPEEDR |= 3u << shift2; /* very high speed: clean 250 kHz edges, 11 MHz SPI */
    port->PUPDR = (port->PUPDR & ~(3u << shift2)) | (pull << shift2);
    port->MODER = (port->MODER & ~(3u << shift2)) | (mode << shift2);
}

static void pin_write(gpio_regs *port, uint32_t pin, bool high) {
    port->BSRR = high ? (1u << pin) : (1u << (pin + 16u));
}

static bool pin_read(const gpio_regs *port, uint32_t pin) { return (port->IDR >> pin) & 1u; }

/* ---- clocks ---------------------------------------------------------------------------------- */

static bool wait_set(volatile uint32_t *reg, uint32_t mask, uint32_t tries) {
    while (tries--) {
        if ((*reg & mask) == mask) return true;
    }
    return false;
}

static bool wait_clear(volatile uint32_t *reg, uint32_t mask, uint32_t tries) {
    while (tries--) {
        if (!(*reg & mask)) return true;
    }
    return false;
}

/* The PLL at 180 MHz, or the HSI at 16 MHz with clock_fault set: every wait is bounded.
 * Returns true on the PLL. */
static bool clock_to_pll(void) {
    RCC->APB1ENR |= RCC_APB1_PWR;
    PWR->CR |= PWR_CR_VOS_SCALE1;
    /* 8 MHz from the ST-LINK's MCO into OSC_IN (HSE bypass, Nucleo default SB16/SB50);
     * RM0390 6.3.1: HSEBYP may change only while HSE is off, so it is set before HSEON and
     * cleared after HSEON is off and HSERDY has fallen, each in a write of its own */
    RCC->CR |= RCC_CR_HSEBYP;
    RCC->CR |= RCC_CR_HSEON;
    if (wait_set(&RCC->CR, RCC_CR_HSERDY, 200000u)) {
        RCC->PLLCFGR = RCC_PLLCFGR(4u, 180u, 2u, 8u, 2u) | RCC_PLLCFGR_SRC_HSE;
    } else { /* no MCO: the internal 16 MHz RC (1 % accurate: the UART still works), but the
              * ADC's CLKIN is HSE through MCO2: no conversions, so a named CLOCK fault */
        RCC->CR &= ~RCC_CR_HSEON;
        if (wait_clear(&RCC->CR, RCC_CR_HSERDY, CLOCK_WAIT_TRIES)) RCC->CR &= ~RCC_CR_HSEBYP;
        RCC->PLLCFGR = RCC_PLLCFGR(8u, 180u, 2u, 8u, 2u);
        board_tick_stats.clock_from_hsi = 1u;
        clock_fault = CLOCK_NO_HSE;
    }
    RCC->CR |= RCC_CR_PLLON;
    if (!wait_set(&RCC->CR, RCC_CR_PLLRDY, CLOCK_WAIT_TRIES)) {
        clock_fault = CLOCK_NO_PLL;
        return false;
    }
    PWR->CR |= PWR_CR_ODEN; /* over-drive: 180 MHz needs it */
    if (!wait_set(&PWR->CSR, PWR_CSR_ODRDY, CLOCK_WAIT_TRIES)) {
        clock_fault = CLOCK_NO_OVERDRIVE;
        return false;
    }
    PWR->CR |= PWR_CR_ODSWEN;
    if (!wait_set(&PWR->CSR, PWR_CSR_ODSWRDY, CLOCK_WAIT_TRIES)) {
        clock_fault = CLOCK_NO_OVERDRIVE;
        return false;
    }
    FLASH->ACR = FLASH_ACR_LATENCY(5) | FLASH_ACR_PRFTEN | FLASH_ACR_ICEN | FLASH_ACR_DCEN;
    RCC->CFGR = RCC_CFGR_MCO2_HSE | RCC_CFGR_PPRE2_DIV2 | RCC_CFGR_PPRE1_DIV4 | RCC_CFGR_SW_PLL;
    if (!wait_set(&RCC->CFGR, RCC_CFGR_SWS_PLL, CLOCK_WAIT_TRIES) ||
        (RCC->CFGR & RCC_CFGR_SWS_MASK) != RCC_CFGR_SWS_PLL) {
        RCC->CFGR = RCC_CFGR_MCO2_HSE | RCC_CFGR_SW_HSI;
        clock_fault = CLOCK_NO_SWITCH;
        return false;
    }
    return true;
}

static void clock_init(void) {
    if (!clock_to_pll()) { /* HSI, every bus at 16 MHz: the link works, nothing moves */
        RCC->CR &= ~RCC_CR_PLLON;
        RCC->CFGR = RCC_CFGR_MCO2_HSE | RCC_CFGR_SW_HSI;
        apb1_hz = HSI_HZ;
        apb1_timer_hz = HSI_HZ;
    }
    RCC->AHB1ENR |= RCC_AHB1_GPIOA | RCC_AHB1_GPIOB | RCC_AHB1_GPIOC | RCC_AHB1_DMA1;
    RCC->AHB2ENR |= RCC_AHB2_RNG;
    RCC->APB1ENR |= RCC_APB1_TIM2 | RCC_APB1_TIM3 | RCC_APB1_TIM5 | RCC_APB1_SPI2 |
                    RCC_APB1_USART2;
    RCC->APB2ENR |= RCC_APB2_TIM1;
    (void)RCC->APB2ENR; /* the enables take effect before the first register access */
    DEMCR |= DEMCR_TRCENA;
    DWT_CYCCNT = 0;
    DWT_CTRL |= DWT_CTRL_CYCCNTENA;
    /* a debugger's breakpoint stops the watchdog and the timers (no reset, no steps) */
    DBGMCU_APB1_FZ |= DBGMCU_APB1_TIM2 | DBGMCU_APB1_TIM3 | DBGMCU_APB1_TIM5 | DBGMCU_APB1_IWDG;
    DBGMCU_APB2_FZ |= DBGMCU_APB2_TIM1;
}

/* ---- pins ------------------------------------------------------------------------------------ */

static void pins_init(void) {
    pin_write(GPIOA, PIN_ENABLE, false); /* driver off until START */
    pin_mode(GPIOA, PIN_ENABLE, GPIO_MODE_OUTPUT, 0, GPIO_PULL_NONE);
    pin_mode(GPIOA, PIN_STEP, GPIO_MODE_AF, 1, GPIO_PULL_DOWN);
    pin_mode(GPIOA, PIN_DIR, GPIO_MODE_AF, 1, GPIO_PULL_NONE);
    pin_mode(GPIOA, PIN_ENC_A, GPIO_MODE_AF, 1, GPIO_PULL_UP);
    pin_mode(GPIOA, PIN_ENC_B, GPIO_MODE_AF, 1, GPIO_PULL_UP);
    pin_mode(GPIOA, PIN_TX, GPIO_MODE_AF, 7, GPIO_PULL_UP);
    pin_mode(GPIOA, PIN_RX, GPIO_MODE_AF, 7, GPIO_PULL_UP);
    pin_mode(GPIOB, PIN_STOP, GPIO_MODE_INPUT, 0, GPIO_PULL_UP);
    pin_mode(GPIOB, PIN_ALARM, GPIO_MODE_INPUT, 0, GPIO_PULL_UP);
    pin_mode(GPIOB, PIN_DRDY, GPIO_MODE_INPUT, 0, GPIO_PULL_UP);
    pin_mode(GPIOB, PIN_CHAIN, GPIO_MODE_INPUT, 0, GPIO_PULL_DOWN);
    pin_mode(GPIOC, PIN_LIMIT_OPEN, GPIO_MODE_INPUT, 0, GPIO_PULL_UP);
    pin_mode(GPIOC, PIN_LIMIT_CLOSED, GPIO_MODE_INPUT, 0, GPIO_PULL_UP);
    pin_write(GPIOB, PIN_CS, true);
    pin_mode(GPIOB, PIN_CS, GPIO_MODE_OUTPUT, 0, GPIO_PULL_NONE);
    pin_mode(GPIOB, PIN_SCK, GPIO_MODE_AF, 5, GPIO_PULL_NONE);
    pin_mode(GPIOB, PIN_MISO, GPIO_MODE_AF, 5, GPIO_PULL_NONE);
    pin_mode(GPIOB, PIN_MOSI, GPIO_MODE_AF, 5, GPIO_PULL_NONE);
    pin_write(GPIOB, PIN_ADC_RST, true);
    pin_mode(GPIOB, PIN_ADC_RST, GPIO_MODE_OUTPUT, 0, GPIO_PULL_NONE);
    pin_mode(GPIOC, PIN_HOME, GPIO_MODE_INPUT, 0, GPIO_PULL_UP);
    pin_mode(GPIOC, PIN_CLKIN, GPIO_MODE_AF, 0, GPIO_PULL_NONE);
    pin_mode(GPIOC, PIN_B1, GPIO_MODE_INPUT, 0, GPIO_PULL_NONE); /* external pull-up R30 */
}

/* ---- serial: USART2, RX interrupt, TX DMA ---------------------------------------------------- */

void USART2_IRQHandler(void) {
    uint32_t sr = USART2->SR;
    if (sr & (USART_SR_RXNE | USART_SR_ORE)) {
        uint8_t byte = (uint8_t)(USART2->DR & 0xFFu); /* also clears ORE */
        if (sr & USART_SR_ORE) rx_overruns = rx_overruns + 1u;
        if (!rx_ring_push(&rx, byte)) rx_overruns = rx_overruns + 1u;
    }
}

/* Transfer complete: nothing to do but wake the main loop to refill. */
void DMA1_Stream6_IRQHandler(void) { DMA1->HIFCR = DMA_HIFCR_S6_ALL; }

static void uart_init(void) {
    USART2->BRR = apb1_hz == APB1_HZ ? USART2_BRR : USART2_BRR_HSI;
    USART2->CR3 = USART_CR3_DMAT;
    USART2->CR1 = USART_CR1_UE | USART_CR1_TE | USART_CR1_RE | USART_CR1_RXNEIE;
    DMA1->S[6].CR = 0;
    DMA1->S[6].PAR = (uint32_t)(uintptr_t)&USART2->DR;
    DMA1->S[6].FCR = 0; /* direct mode */
    nvic_enable(IRQ_USART2, 1);
    nvic_enable(IRQ_DMA1_STREAM6, 3);
}

/* Start the next DMA transfer when the last one is done. */
static void uart_pump(void) {
    if (DMA1->S[6].CR & DMA_CR_EN) return;
    size_t n = rig_tx_take(&mcu, tx_dma_buf, sizeof tx_dma_buf);
    if (n == 0) return;
    DMA1->HIFCR = DMA_HIFCR_S6_ALL;
    DMA1->S[6].M0AR = (uint32_t)(uintptr_t)tx_dma_buf;
    DMA1->S[6].NDTR = (uint32_t)n;
    DMA1->S[6].CR = DMA_CR_CHSEL(4) | DMA_CR_MINC | DMA_CR_DIR_M2P | DMA_CR_TCIE | DMA_CR_EN;
}

/* ---- tick: TIM5 ------------------------------------------------------------------------------ */

void TIM5_IRQHandler(void) {
    TIM5->SR = ~TIM_SR_UIF;
    /* disarm: the burst armed for the last period has started; only this period's
     * hal_step may arm the next (a late or missing one must not repeat the last burst) */
    TIM1->SMCR = TIM_SMCR_TS_ITR0;
    tick_count = tick_count + 1u;
}

static void tick_init(void) {
    TIM5->PSC = apb1_timer_hz / 1000000u - 1u; /* 1 MHz */
    TIM5->ARR = 1000u - 1u;
    /* OC1REF (PWM mode 2: high from CCR1 to the period's end) is TRGO: its rising edge
     * STEP_PHASE_US into each period starts that period's step burst (TIM1 ITR0) */
    TIM5->CCR1 = STEP_PHASE_US;
    TIM5->CCMR1 = TIM_CCMR_OC1M_PWM2;
    TIM5->CR2 = TIM_CR2_MMS_OC1REF;
    TIM5->EGR = TIM_EGR_UG;
    TIM5->SR = 0;
    TIM5->DIER = TIM_DIER_UIE;
    nvic_enable(IRQ_TIM5, 2);
    TIM5->CR1 = TIM_CR1_URS | TIM_CR1_CEN;
}

/* ---- step generator: TIM1 bursts, TIM3 counts them ----------------------------------------- */

static void step_init(void) {
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

/* ---- encoder: TIM2 -------------------------------------------------------------------------- */

static void encoder_init(void) {
    TIM2->ARR = 0xFFFFFFFFu;
    /* TI1, TI2 filtered over 8 samples of 90 MHz (89 ns): far above the encoder's edges */
    TIM2->CCMR1 = TIM_CCMR_CC1S_TI1 | TIM_CCMR_IC1F(3) | TIM_CCMR_CC2S_TI2 | TIM_CCMR_IC2F(3);
    TIM2->CCER = 0; /* both inputs non-inverted */
    TIM2->SMCR = TIM_SMCR_SMS_ENCODER3;
    TIM2->CNT = 0;
    TIM2->CR1 = TIM_CR1_CEN;
}

/* ---- load cell: ADS131M02 on SPI2 -------------------------------------------------------- */

#define ADC_WORD 3u                 /* 24-bit words (the ADS131M02's default) */
#define ADC_FRAME (4u * ADC_WORD)   /* STATUS/response, CH0, CH1, CRC */
#define ADC_CMD_NULL 0x0000u
#define ADC_CMD_RREG(addr) (0xA000u | ((uint32_t)(addr) << 7)) /* one register */
#define ADC_CMD_WREG(addr) (0x6000u | ((uint32_t)(addr) << 7)) /* one register */
#define ADC_REG_ID 0x00u
#define ADC_REG_MODE 0x02u
#define ADC_REG_GAIN 0x04u
#define ADC_ID_M02 0x22u            /* ID[15:8]: 0x2 and CHANCNT = 2 */
#define ADC_MODE_24BIT 0x0110u      /* WLENGTH 24 bits, SPI timeout on, RESET flag cleared */
#define ADC_GAIN_CH0_128 0x0007u
#define ADC_STATUS_FAULTS 0x7400u   /* F_RESYNC, REG_MAP, CRC_ERR, RESET */
#define ADC_STATUS_WLENGTH 0x0300u
#define ADC_STATUS_WLENGTH_24 0x0100u
#define SPI_WAIT_TRIES 1000u        /* a byte takes 0.7 us: about 128 CPU cycles */

static bool spi_wait(uint32_t flag, bool set) {
    for (uint32_t tries = 0; tries < SPI_WAIT_TRIES; tries++)
        if (((SPI2->SR & flag) != 0u) == set) return true;
    return false;
}

/* One frame; false when SPI2 did not finish a byte (the chip select is released). */
static bool spi_frame(const uint8_t *out, uint8_t *in) {
    bool ok = true;
    pin_write(GPIOB, PIN_CS, false);
    for (unsigned i = 0; i < ADC_FRAME && ok; i++) {
        ok = spi_wait(SPI_SR_TXE, true);
        if (ok) SPI2->DR = out[i];
        ok = ok && spi_wait(SPI_SR_RXNE, true);
        in[i] = ok ? (uint8_t)SPI2->DR : 0u;
    }
    ok = spi_wait(SPI_SR_BSY, false) && ok;
    pin_write(GPIOB, PIN_CS, true);
    return ok;
}

/* CRC-16-CCITT (0x1021, initial 0xFFFF), the ADS131M02's output CRC over the words before it */
static uint16_t adc_crc(const uint8_t *data, unsigned n) {
    uint16_t crc = 0xFFFFu;
    for (unsigned i = 0; i < n; i++) {
        crc = (uint16_t)(crc ^ ((uint16_t)data[i] << 8));
        for (int b = 0; b < 8; b++)
            crc = (uint16_t)((crc & 0x8000u) ? ((uint32_t)crc << 1) ^ 0x1021u : (uint32_t)crc << 1);
    }
    return crc;
}

static uint16_t word16(const uint8_t *w) { return (uint16_t)((w[0] << 8) | w[1]); }

/* A frame with a command (and one data word); its CRC checked. 0 or an ADC_* code. */
static uint32_t adc_command(uint32_t cmd, uint32_t data, uint8_t in[ADC_FRAME]) {
    uint8_t out[ADC_FRAME] = {0};
    out[0] = (uint8_t)(cmd >> 8);
    out[1] = (uint8_t)cmd;
    out[ADC_WORD] = (uint8_t)(data >> 8);
    out[ADC_WORD + 1u] = (uint8_t)data;
    if (!spi_frame(out, in)) return ADC_SPI_TIMEOUT;
    if (adc_crc(in, 3u * ADC_WORD) != word16(&in[3u * ADC_WORD])) return ADC_BAD_CRC;
    return 0;
}

/* Configure the converter and check that it is there: the ID register's answer (in the
 * frame after the RREG) names an ADS131M02 and every frame's CRC holds. */
static void adc_init(void) {
    /* mode 1 (CPOL 0, CPHA 1), 45 MHz / 4 = 11.25 MHz (the ADC takes up to 25 MHz) */
    SPI2->CR1 = SPI_CR1_MSTR | SPI_CR1_BR_DIV4 | SPI_CR1_CPHA | SPI_CR1_SSM | SPI_CR1_SSI;
    SPI2->CR1 |= SPI_CR1_SPE;
    uint8_t in[ADC_FRAME];
    /* the first frame after power-on answers the reset; its CRC is checked like any */
    uint32_t err = adc_command(ADC_CMD_WREG(ADC_REG_MODE), ADC_MODE_24BIT, in);
    if (!err) err = adc_command(ADC_CMD_WREG(ADC_REG_GAIN), ADC_GAIN_CH0_128, in);
    if (!err) err = adc_command(ADC_CMD_RREG(ADC_REG_ID), 0u, in);
    if (!err) err = adc_command(ADC_CMD_NULL, 0u, in);
    if (err || in[0] != ADC_ID_M02) adc_fault = ADC_MISSING;
    /* CLOCK keeps its default: both channels, OSR 1024, high resolution */
}

/* The latest conversion when DRDY says there is one; the health checks set adc_fault. */
static int32_t adc_read(void) {
    /* no CLKIN (CLOCK_NO_HSE) means no conversions: CLOCK names the cause, not LOAD_ADC */
    if (adc_fault == ADC_MISSING || clock_fault == CLOCK_NO_HSE) return adc_last;
    if (pin_read(GPIOB, PIN_DRDY)) { /* high: nothing new since the last read */
        if (++drdy_missed >= ADC_DRDY_TICKS && !adc_fault) adc_fault = ADC_DRDY_TIMEOUT;
        return adc_last;
    }
    drdy_missed = 0;
    uint8_t in[ADC_FRAME];
    uint32_t err = adc_command(ADC_CMD_NULL, 0u, in);
    uint16_t status = word16(in);
    if (!err && ((status & ADC_STATUS_FAULTS) ||
                 (status & ADC_STATUS_WLENGTH) != ADC_STATUS_WLENGTH_24)) {
        err = ADC_BAD_STATUS;
    }
    if (err) {
        if (!adc_fault) adc_fault = err;
        return adc_last;
    }
    uint32_t raw = ((uint32_t)in[ADC_WORD] << 16) | ((uint32_t)in[ADC_WORD + 1u] << 8) |
                   in[ADC_WORD + 2u];
    adc_last = (int32_t)(raw ^ 0x800000u) - 0x800000; /* sign-extend 24 bits */
    return adc_last;
}

/* ---- hal_read, watchdog ------------------------------------------------------------------ */

/* The board's faults of this period, each with its FAULT value (the first found). */
static void board_faults(rig_inputs *in) {
    uint16_t bits = 0;
    int32_t detail = 0;
    if (step_error || late_tick) {
        bits |= RIG_F_INTERNAL;
        detail = step_error ? INTERNAL_STEP_BURST : INTERNAL_LATE_TICK;
        late_tick = false;
    }
    bool open_end = pin_read(GPIOC, PIN_LIMIT_OPEN), closed_end = pin_read(GPIOC, PIN_LIMIT_CLOSED);
    if (open_end || closed_end) {
        if (!bits) detail = (open_end ? 1 : 0) | (closed_end ? 2 : 0);
        bits |= RIG_F_OVERTRAVEL;
    }
    if (adc_fault) {
        if (!bits) detail = (int32_t)adc_fault;
        bits |= RIG_F_LOAD_ADC;
    }
    if (clock_fault) {
        if (!bits) detail = (int32_t)clock_fault;
        bits |= RIG_F_CLOCK;
    }
    /* the stop chain: its feedback follows the enable unless the stop button opened it */
    bool feedback = pin_read(GPIOB, PIN_CHAIN);
    if (feedback != driver_on && !in->stop_input) {
        if (chain_mismatch < STOP_CHAIN_TICKS) chain_mismatch++;
    } else {
        chain_mismatch = 0;
    }
    if (chain_mismatch >= STOP_CHAIN_TICKS) {
        if (!bits) detail = driver_on ? 1 : 2; /* 1: chain open, 2: enable stuck live */
        bits |= RIG_F_STOP_CHAIN;
    }
    in->board_faults = bits;
    in->board_detail = detail;
}

void hal_read(rig_inputs *in) {
    in->enc = (int32_t)TIM2->CNT;
    in->load_raw = adc_read();
    in->home_switch = !pin_read(GPIOC, PIN_HOME);
    in->stop_input = pin_read(GPIOB, PIN_STOP) || !pin_read(GPIOC, PIN_B1);
    in->driver_alarm = pin_read(GPIOB, PIN_ALARM);
    board_faults(in);
}

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

void hal_watchdog_kick(void) { IWDG->KR = IWDG_KEY_RELOAD; }

static void watchdog_init(void) {
    IWDG->KR = IWDG_KEY_START; /* starts the LSI too */
    IWDG->KR = IWDG_KEY_UNLOCK;
    IWDG->PR = IWDG_PRESCALER_DIV8;
    IWDG->RLR = IWDG_RELOAD;
    /* the update takes up to 5 LSI cycles (156 us); bounded: the watchdog runs anyway */
    for (uint32_t tries = 0; tries < 200000u && IWDG->SR != 0u; tries++) {
    }
    IWDG->KR = IWDG_KEY_RELOAD;
}

/* ---- boot id --------------------------------------------------------------------------- */

static uint32_t mix32(uint32_t h) { /* a 32-bit avalanche (xor-shift-multiply) */
    h ^= h >> 16;
    h *= 0x7FEB352Du;
    h ^= h >> 15;
    h *= 0x846CA68Bu;
    h ^= h >> 16;
    return h;
}

/* 32 bits from the RNG (PLLQ's 45 MHz), 0 if it reports a seed or clock error. */
static uint32_t rng_word(void) {
    RNG->CR = RNG_CR_RNGEN;
    for (uint32_t tries = 0; tries < 100000u; tries++) {
        uint32_t sr = RNG->SR;
        if (sr & (RNG_SR_SECS | RNG_SR_CECS)) break;
        if (sr & RNG_SR_DRDY) return RNG->DR;
    }
    board_tick_stats.rng_failed = 1u;
    return 0;
}

static uint32_t new_boot_id(uint32_t boots) {
    uint32_t id = mix32(rng_word() ^ mix32(boots * 0x9E3779B9u) ^ DWT_CYCCNT);
    if (persist.magic != NOINIT_MAGIC) {
        persist.magic = NOINIT_MAGIC;
        persist.last_id = 0;
    }
    for (uint32_t k = 1; id == 0 || id == persist.last_id; k++) id = mix32(id + k);
    persist.last_id = id;
    return id;
}

/* ---- main loop -------------------------------------------------------------------------- */

int main(void) {
    clock_init();
    pins_init();
    uint32_t boots = cal_flash_count_boot();
    board_tick_stats.boots = boots;
    rig_calibration defaults = {CAL_DEFAULT_OFFSET, CAL_DEFAULT_GAIN, 0u};
    rig_calibration stored = cal_flash_boot(defaults);
    rig_boot(&mcu, new_boot_id(boots), stored);
    encoder_init();
    adc_init();
    step_init();
    uart_init();
    watchdog_init();
    tick_init();

    uint32_t ticks_done = 0;
    for (;;) {
        uint8_t buf[RX_SLICE];
        size_t n = rx_ring_take(&rx, buf);
        if (n != 0) {
            uint32_t c0 = DWT_CYCCNT;
            rig_rx(&mcu, buf, n);
            uint32_t dc = DWT_CYCCNT - c0;
            if (dc > board_tick_stats.rx_max_cycles) board_tick_stats.rx_max_cycles = dc;
        }
        uint32_t due = tick_count;
        if (due != ticks_done) {
            if (due - ticks_done > 1u) {
                board_tick_stats.late_ticks++;
                late_tick = true; /* INTERNAL in this tick's reading */
            }
            tick_now = ticks_done + 1u;
            uint32_t c0 = DWT_CYCCNT;
            rig_tick(&mcu, ticks_done * RIG_POINT_PERIOD_US);
            uint32_t dc = DWT_CYCCNT - c0;
            if (dc > board_tick_stats.tick_max_cycles) board_tick_stats.tick_max_cycles = dc;
            board_tick_stats.ticks++;
            board_tick_stats.rx_overruns = rx_overruns;
            ticks_done++;
        }
        uart_pump();
        irq_disable();
        if (rx_ring_empty(&rx) && tick_count == ticks_done) wait_for_interrupt();
        irq_enable();
    }
}

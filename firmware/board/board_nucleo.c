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
 *           alarm PB4; driver enable PA10
 *   safety  IWDG about 50 ms, kicked from the tick (rig_tick calls hal_watchdog_kick)
 *   flash   sector 7 (0x08060000): the load-cell calibration record and a boot counter
 *   boot id the RNG mixed with the boot counter, never 0 nor the previous boot's
 */
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>
#include <string.h>

#include "rig_core.h"
#include "rx_ring.h"
#include "stm32f4_regs.h"

/* ---- constants ----------------------------------------------------------------------------- */

#define HCLK_HZ 180000000u
#define APB1_TIMER_HZ 90000000u
#define APB2_TIMER_HZ 180000000u
#define TICK_PRESCALER (APB1_TIMER_HZ / 1000000u) /* TIM5 at 1 MHz */
#define STEP_TIMER_PSC 3u                         /* TIM1 at 60 MHz */
#define STEP_TICKS_PER_PERIOD (APB2_TIMER_HZ / STEP_TIMER_PSC / RIG_TELEMETRY_HZ) /* 60000 */
#define STEP_GUARD_TICKS 60u     /* a burst ends >= 1 us before the next one may start */
#define STEP_PULSE_TICKS 150u    /* 2.5 us high (shorter when the period is under 5 us) */
#define STEP_MAX_PER_PERIOD 256u /* TIM1's 8-bit repetition counter: one burst */
#define STEP_PHASE_US 300u       /* a burst starts this long after its tick */
#define STEP_ARM_DEADLINE_US (STEP_PHASE_US - 10u) /* hal_step later than this: an error */
#define TX_DMA_BYTES 128u
#define IWDG_PRESCALER_DIV8 1u /* LSI 32 kHz / 8 = 4 kHz */
#define IWDG_RELOAD 200u       /* 200 / 4 kHz = 50 ms */

/* USART2 at 45 MHz: USARTDIV = 45e6 / (16 * 921600) = 3.05 -> 3 + 1/16 = 3.0625:
 * 918 367 baud, -0.35 % (a receiver tolerates about +-3 %). */
#define USART2_BRR ((3u << 4) | 1u)

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
#define PIN_HOME 0u    /* PC0  home switch (closes to GND when active) */
#define PIN_CLKIN 9u   /* PC9  MCO2 AF0: 8 MHz to the ADC's CLKIN */
#define PIN_B1 13u     /* PC13 the Nucleo's user button B1 (low when pressed) */

/* flash sector 7 (0x08060000, 128 KiB): calibration record, then the boot counter log */
#define CAL_SECTOR 7u
#define CAL_MAGIC 0x314C4143u /* "CAL1" */
#define CAL_DEFAULT_OFFSET 1500
#define CAL_DEFAULT_GAIN 1e-4f
#define NOINIT_MAGIC 0xB007B007u

extern uint32_t __calib_start[], __calib_size[];

typedef struct {
    uint32_t magic;
    int32_t load_offset;
    uint32_t gain_bits; /* f32 N per count */
    uint32_t check;     /* cal_check() of the three words */
} cal_record;

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

static void clock_init(void) {
    RCC->APB1ENR |= RCC_APB1_PWR;
    PWR->CR |= PWR_CR_VOS_SCALE1;
    /* 8 MHz from the ST-LINK's MCO into OSC_IN (HSE bypass, Nucleo default SB16/SB50) */
    RCC->CR |= RCC_CR_HSEBYP | RCC_CR_HSEON;
    if (wait_set(&RCC->CR, RCC_CR_HSERDY, 200000u)) {
        RCC->PLLCFGR = RCC_PLLCFGR(4u, 180u, 2u, 8u, 2u) | RCC_PLLCFGR_SRC_HSE;
    } else { /* no MCO: the internal 16 MHz RC (1 % accurate: the UART still works) */
        RCC->CR &= ~(RCC_CR_HSEON | RCC_CR_HSEBYP);
        RCC->PLLCFGR = RCC_PLLCFGR(8u, 180u, 2u, 8u, 2u);
        board_tick_stats.clock_from_hsi = 1u;
    }
    RCC->CR |= RCC_CR_PLLON;
    (void)wait_set(&RCC->CR, RCC_CR_PLLRDY, 1000000u);
    PWR->CR |= PWR_CR_ODEN; /* over-drive: 180 MHz needs it */
    (void)wait_set(&PWR->CSR, PWR_CSR_ODRDY, 1000000u);
    PWR->CR |= PWR_CR_ODSWEN;
    (void)wait_set(&PWR->CSR, PWR_CSR_ODSWRDY, 1000000u);
    FLASH->ACR = FLASH_ACR_LATENCY(5) | FLASH_ACR_PRFTEN | FLASH_ACR_ICEN | FLASH_ACR_DCEN;
    RCC->CFGR = RCC_CFGR_MCO2_HSE | RCC_CFGR_PPRE2_DIV2 | RCC_CFGR_PPRE1_DIV4 | RCC_CFGR_SW_PLL;
    while ((RCC->CFGR & RCC_CFGR_SWS_MASK) != RCC_CFGR_SWS_PLL) {
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
    USART2->BRR = USART2_BRR;
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
    TIM5->PSC = TICK_PRESCALER - 1u;
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
    uint32_t period = (STEP_TICKS_PER_PERIOD - STEP_GUARD_TICKS) / n; /* timer ticks */
    uint32_t high = period / 2u < STEP_PULSE_TICKS ? period / 2u : STEP_PULSE_TICKS;
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

void hal_driver_enable(bool on) { pin_write(GPIOA, PIN_ENABLE, on); }

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
#define ADC_CMD_WREG(addr) (0x6000u | ((uint32_t)(addr) << 7)) /* one register */
#define ADC_REG_GAIN 0x04u
#define ADC_GAIN_CH0_128 0x0007u

static void spi_frame(const uint8_t *out, uint8_t *in) {
    pin_write(GPIOB, PIN_CS, false);
    for (unsigned i = 0; i < ADC_FRAME; i++) {
        while (!(SPI2->SR & SPI_SR_TXE)) {
        }
        SPI2->DR = out[i];
        while (!(SPI2->SR & SPI_SR_RXNE)) {
        }
        in[i] = (uint8_t)SPI2->DR;
    }
    while (SPI2->SR & SPI_SR_BSY) {
    }
    pin_write(GPIOB, PIN_CS, true);
}

static void adc_init(void) {
    /* mode 1 (CPOL 0, CPHA 1), 45 MHz / 4 = 11.25 MHz (the ADC takes up to 25 MHz) */
    SPI2->CR1 = SPI_CR1_MSTR | SPI_CR1_BR_DIV4 | SPI_CR1_CPHA | SPI_CR1_SSM | SPI_CR1_SSI;
    SPI2->CR1 |= SPI_CR1_SPE;
    uint8_t out[ADC_FRAME] = {0}, in[ADC_FRAME];
    uint32_t cmd = ADC_CMD_WREG(ADC_REG_GAIN);
    out[0] = (uint8_t)(cmd >> 8);
    out[1] = (uint8_t)cmd;
    out[ADC_WORD] = (uint8_t)(ADC_GAIN_CH0_128 >> 8);
    out[ADC_WORD + 1u] = (uint8_t)ADC_GAIN_CH0_128;
    spi_frame(out, in); /* CLOCK keeps its default: both channels, OSR 1024, high resolution */
}

static int32_t adc_read(void) {
    static const uint8_t null_frame[ADC_FRAME] = {(uint8_t)(ADC_CMD_NULL >> 8), 0};
    uint8_t in[ADC_FRAME];
    spi_frame(null_frame, in);
    uint32_t raw = ((uint32_t)in[ADC_WORD] << 16) | ((uint32_t)in[ADC_WORD + 1u] << 8) |
                   in[ADC_WORD + 2u];
    return (int32_t)(raw ^ 0x800000u) - 0x800000; /* sign-extend 24 bits */
}

/* ---- hal_read, watchdog ------------------------------------------------------------------ */

void hal_read(rig_inputs *in) {
    in->enc = (int32_t)TIM2->CNT;
    in->load_raw = adc_read();
    in->home_switch = !pin_read(GPIOC, PIN_HOME);
    in->stop_input = pin_read(GPIOB, PIN_STOP) || !pin_read(GPIOC, PIN_B1);
    /* a step burst that could not be emitted is reported as the driver's alarm (a halt)
     * until rig_hal.h carries the core's INTERNAL fault (docs/firmware.md) */
    in->driver_alarm = pin_read(GPIOB, PIN_ALARM) || step_error;
}

void hal_watchdog_kick(void) { IWDG->KR = IWDG_KEY_RELOAD; }

static void watchdog_init(void) {
    IWDG->KR = IWDG_KEY_START; /* starts the LSI too */
    IWDG->KR = IWDG_KEY_UNLOCK;
    IWDG->PR = IWDG_PRESCALER_DIV8;
    IWDG->RLR = IWDG_RELOAD;
    while (IWDG->SR != 0u) {
    }
    IWDG->KR = IWDG_KEY_RELOAD;
}

/* ---- flash: calibration and boot counter ----------------------------------------------- */

static uint32_t mix32(uint32_t h) { /* a 32-bit avalanche (xor-shift-multiply) */
    h ^= h >> 16;
    h *= 0x7FEB352Du;
    h ^= h >> 15;
    h *= 0x846CA68Bu;
    h ^= h >> 16;
    return h;
}

static uint32_t cal_check(const cal_record *r) {
    return mix32(r->magic ^ mix32((uint32_t)r->load_offset ^ mix32(r->gain_bits)));
}

static rig_calibration load_calibration(const cal_record *r) {
    rig_calibration cal = {CAL_DEFAULT_OFFSET, CAL_DEFAULT_GAIN};
    if (r->magic == CAL_MAGIC && r->check == cal_check(r)) {
        float gain;
        memcpy(&gain, &r->gain_bits, sizeof gain);
        if (gain > 0.0f && gain < 1.0f) {
            cal.load_offset = r->load_offset;
            cal.load_gain_n = gain;
        }
    }
    return cal;
}

static bool flash_wait(void) {
    while (FLASH->SR & FLASH_SR_BSY) {
    }
    bool ok = (FLASH->SR & FLASH_SR_ERRORS) == 0u;
    FLASH->SR = FLASH_SR_ERRORS;
    return ok;
}

static bool flash_program(volatile uint32_t *addr, uint32_t value) {
    FLASH->CR = FLASH_CR_PSIZE_X32 | FLASH_CR_PG;
    *addr = value;
    bool ok = flash_wait();
    FLASH->CR = 0;
    return ok && *addr == value;
}

/* The boot counter: after the 16-byte calibration record, one word per boot holding the
 * count; the sector is erased (and the record written back) when the log is full, about
 * every 32 000 boots. Runs before the watchdog starts (an erase stalls the CPU ~1 s). */
static uint32_t count_boot(void) {
    volatile uint32_t *sector = (volatile uint32_t *)(uintptr_t)__calib_start;
    uint32_t words = (uint32_t)(uintptr_t)__calib_size / 4u;
    uint32_t first = sizeof(cal_record) / 4u, slot = first, count = 0;
    while (slot < words && sector[slot] != 0xFFFFFFFFu) count = sector[slot++];
    count++;
    FLASH->KEYR = FLASH_KEY1;
    FLASH->KEYR = FLASH_KEY2;
    FLASH->SR = FLASH_SR_ERRORS;
    if (slot == words) {
        cal_record keep;
        memcpy(&keep, (const void *)(uintptr_t)__calib_start, sizeof keep);
        FLASH->CR = FLASH_CR_PSIZE_X32 | FLASH_CR_SER | FLASH_CR_SNB(CAL_SECTOR);
        FLASH->CR |= FLASH_CR_STRT;
        (void)flash_wait();
        FLASH->CR = 0;
        if (keep.magic == CAL_MAGIC) {
            const uint32_t *w = (const uint32_t *)&keep;
            for (uint32_t i = 0; i < first; i++) (void)flash_program(&sector[i], w[i]);
        }
        slot = first;
    }
    (void)flash_program(&sector[slot], count);
    FLASH->CR = FLASH_CR_LOCK;
    return count;
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
    uint32_t boots = count_boot();
    board_tick_stats.boots = boots;
    rig_calibration stored =
        load_calibration((const cal_record *)(uintptr_t)__calib_start);
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
            if (due - ticks_done > 1u) board_tick_stats.late_ticks++;
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

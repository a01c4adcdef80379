/* The NUCLEO-F446RE's system (board_nucleo.h): the clock tree (PLL at 180 MHz from the
 * ST-LINK's 8 MHz, or the HSI with a CLOCK fault), the pins, the independent watchdog and the
 * boot id (the RNG mixed with the boot counter, never 0 nor the previous boot's). */
#include "board_nucleo.h"
#include "boot_mix.h"

#define CLOCK_WAIT_TRIES 100000u /* each wait: well over the datasheet's lock/ready times */
#define IWDG_PRESCALER_DIV8 1u /* LSI 32 kHz / 8 = 4 kHz */
#define IWDG_RELOAD 200u       /* 200 / 4 kHz = 50 ms */
#define NOINIT_MAGIC 0xB007B007u

uint32_t clock_fault; /* CLOCK_* */
uint32_t apb1_hz = APB1_HZ, apb1_timer_hz = APB1_TIMER_HZ;

static struct {
    uint32_t magic, last_id;
} persist __attribute__((section(".noinit")));

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

void clock_init(void) {
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

static void pin_mode(gpio_regs *port, uint32_t pin, uint32_t mode, uint32_t af, uint32_t pull) {
    uint32_t shift2 = pin * 2u, shift4 = (pin & 7u) * 4u;
    port->AFR[pin >> 3] = (port->AFR[pin >> 3] & ~(0xFu << shift4)) | (af << shift4);
    port->OSPEEDR |= 3u << shift2; /* very high speed: clean 250 kHz edges, 11 MHz SPI */
    port->PUPDR = (port->PUPDR & ~(3u << shift2)) | (pull << shift2);
    port->MODER = (port->MODER & ~(3u << shift2)) | (mode << shift2);
}

void pins_init(void) {
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

void hal_watchdog_kick(void) { IWDG->KR = IWDG_KEY_RELOAD; }

void watchdog_init(void) {
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

uint32_t new_boot_id(uint32_t boots) {
    uint32_t id = mix32(rng_word() ^ mix32(boots * 0x9E3779B9u) ^ DWT_CYCCNT);
    if (persist.magic != NOINIT_MAGIC) {
        persist.magic = NOINIT_MAGIC;
        persist.last_id = 0;
    }
    for (uint32_t k = 1; id == 0 || id == persist.last_id; k++) id = mix32(id + k);
    persist.last_id = id;
    return id;
}


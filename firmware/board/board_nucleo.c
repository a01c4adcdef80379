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
 *
 * This file holds the main loop, the serial link and the tick; board_nucleo.h names the
 * files of the rest.
 */
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "board_nucleo.h"
#include "cal_flash.h"
#include "rx_ring.h"
#include "step_burst.h"

/* ---- constants ----------------------------------------------------------------------------- */

#define TX_DMA_BYTES 128u

/* USART2 at 45 MHz: USARTDIV = 45e6 / (16 * 921600) = 3.05 -> 3 + 1/16 = 3.0625:
 * 918 367 baud, -0.35 % (a receiver tolerates about +-3 %). On the HSI fallback (16 MHz):
 * 1 + 1/16 = 1.0625: 941 176 baud, +2.1 % (enough to report the CLOCK fault). */
#define USART2_BRR ((3u << 4) | 1u)
#define USART2_BRR_HSI ((1u << 4) | 1u)

/* the firmware's calibration while none is stored (cal_flash.c) */
#define CAL_DEFAULT_OFFSET 1500
#define CAL_DEFAULT_GAIN 1e-4f

/* ---- state ---------------------------------------------------------------------------------- */

static rig_mcu mcu;
static rx_ring rx;
static volatile uint32_t rx_overruns;
static uint8_t tx_dma_buf[TX_DMA_BYTES];
/* shared with the other files (board_nucleo.h) */
volatile uint32_t tick_count;
uint32_t tick_now;
bool late_tick;
volatile board_stats board_tick_stats;

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

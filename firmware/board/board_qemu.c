/* The rig firmware on QEMU's netduinoplus2 (STM32F405): the portable core (firmware/core/)
 * on the simulated rig (firmware/sim/: rig_hal.h on the clamp's native FMU), with the
 * simulation's parameters baked in at build time (rig_setup.h, written by
 * hil/emulators/firmware_qemu.py). What QEMU 7.2 emulates of the F405 decides the peripherals:
 *
 *   - USART1 is QEMU's serial0 (-serial pty): RX by the RXNE interrupt into a ring, TX by
 *     polling TXE from the main loop (QEMU's USART transmits a written byte at once);
 *   - SysTick at 1 kHz of the 168 MHz processor clock is the tick; t_us is the tick count
 *     times 1000 (the period's scheduled time, as the protocol asks);
 *   - no RCC (reads 0: the clock tree is QEMU's fixed one), no RNG (reads 0), no IWDG, no
 *     TIM1, no DWT cycle counter: the boot id mixes a seed word that the launcher writes
 *     into RAM (-device loader, QEMU_SEED_ADDR) with a boot counter kept across resets.
 *
 * The main loop is the Nucleo's: received bytes go to rig_rx(), a pending tick runs
 * rig_tick(), the transmit FIFO drains; nothing preempts rig_tick() but the two ISRs,
 * which touch only the ring and the tick counter.
 *
 * Measurement (docs/firmware-emulated.md): the link wraps the core's calls of hal_read and hal_step
 * (-Wl,--wrap) to time, in SysTick counts, the whole tick, the simulated rig's part (the
 * FMU step in hal_read, which the real board replaces by an SPI read) and the delay from
 * the tick's start to hal_step. SysTick->VAL is only readable under -icount (QEMU 7.2
 * reads 0 without it); the maxima are in board_tick_stats, read through QEMU's monitor.
 */
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>
#include <string.h>

#include "rig_core.h"
#include "rx_ring.h"
#include "rig_setup.h"
#include "sim_rig.h"
#include "stm32f4_regs.h"
#include "boot_mix.h"

#define SYSCLK_HZ 168000000u /* QEMU netduinoplus2's fixed processor clock */
#define SYSTICK_RELOAD (SYSCLK_HZ / RIG_TELEMETRY_HZ)
#define TX_SLICE 64u
#define QEMU_SEED_ADDR 0x2001FFF0u /* above the stack (qemu_f405.ld): the launcher's seed */
#define NOINIT_MAGIC 0x51E3B007u

/* ---- what the monitor reads --------------------------------------------------------- */

typedef struct {
    uint32_t magic;          /* 0x71C5A75 once running */
    uint32_t counts_per_ms;  /* SysTick counts per period (SYSTICK_RELOAD) */
    uint32_t ticks;          /* rig_tick calls */
    uint32_t late_ticks;     /* ticks that found the previous period still pending */
    uint32_t tick_max;       /* longest rig_tick, SysTick counts */
    uint32_t sim_max;        /* longest simulated hal_read (FMU step and sensor model) */
    uint32_t core_max;       /* longest rig_tick minus its hal_read: the core's own work */
    uint32_t step_at_max;    /* latest hal_step after the tick's start */
    uint32_t rx_max;         /* longest rig_rx call (one slice of <= RX_SLICE bytes) */
    uint32_t rx_bytes;       /* bytes received */
    uint32_t tx_bytes;       /* bytes sent */
    uint32_t tick_max_state; /* core state during the longest tick */
} board_stats;

volatile board_stats board_tick_stats;

/* ---- state --------------------------------------------------------------------------- */

static rig_mcu mcu;
static volatile uint32_t systick_count;
static rx_ring rx;

/* Kept across a reset (the loader writes the same seed again at every reset). */
static struct {
    uint32_t magic, boots, last_id;
} persist __attribute__((section(".noinit")));

/* ---- time ------------------------------------------------------------------------------ */

void SysTick_Handler(void) { systick_count++; }

/* SysTick counts since boot (valid under -icount; VAL reads 0 otherwise). */
static uint64_t now_counts(void) {
    uint32_t t1, t2, v;
    do {
        t1 = systick_count;
        v = SYSTICK->VAL;
        t2 = systick_count;
    } while (t1 != t2);
    return (uint64_t)t1 * SYSTICK_RELOAD + (SYSTICK_RELOAD - 1u - v);
}

static uint32_t clip32(uint64_t v) { return v > UINT32_MAX ? UINT32_MAX : (uint32_t)v; }

static uint64_t tick_start, sim_this_tick;

void __real_hal_read(rig_inputs *in);
void __wrap_hal_read(rig_inputs *in);
void __wrap_hal_read(rig_inputs *in) {
    uint64_t t0 = now_counts();
    __real_hal_read(in);
    uint64_t dt = now_counts() - t0;
    sim_this_tick += dt;
    if (dt > board_tick_stats.sim_max) board_tick_stats.sim_max = clip32(dt);
}

void __real_hal_step(int32_t delta);
void __wrap_hal_step(int32_t delta);
void __wrap_hal_step(int32_t delta) {
    uint64_t dt = now_counts() - tick_start;
    if (dt > board_tick_stats.step_at_max) board_tick_stats.step_at_max = clip32(dt);
    __real_hal_step(delta);
}

/* ---- serial: USART1 = QEMU's serial0 ----------------------------------------------------- */

void USART1_IRQHandler(void) {
    uint32_t sr = USART1->SR;
    if (sr & (USART_SR_RXNE | USART_SR_ORE)) {
        uint8_t byte = (uint8_t)(USART1->DR & 0xFFu); /* reading DR also clears ORE */
        (void)rx_ring_push(&rx, byte); /* a full ring loses the byte */
    }
}

static void uart_init(void) {
    USART1->CR1 = USART_CR1_UE | USART_CR1_TE | USART_CR1_RE | USART_CR1_RXNEIE;
    nvic_enable(IRQ_USART1, 1);
}

static void uart_puts(const char *s) {
    while (*s) {
        while (!(USART1->SR & USART_SR_TXE)) {
        }
        USART1->DR = (uint8_t)*s++;
    }
}

/* Send what the core queued (QEMU transmits each byte as it is written). */
static void uart_drain(void) {
    uint8_t buf[TX_SLICE];
    size_t n;
    while ((n = rig_tx_take(&mcu, buf, sizeof buf)) != 0) {
        for (size_t i = 0; i < n; i++) {
            while (!(USART1->SR & USART_SR_TXE)) {
            }
            USART1->DR = buf[i];
        }
        board_tick_stats.tx_bytes += (uint32_t)n;
    }
}

/* ---- boot id ------------------------------------------------------------------------------ */

static uint32_t boot_id(void) {
    if (persist.magic != NOINIT_MAGIC) {
        persist.magic = NOINIT_MAGIC;
        persist.boots = 0;
        persist.last_id = 0;
    }
    persist.boots++;
    uint32_t seed = *(volatile uint32_t *)QEMU_SEED_ADDR;
    uint32_t id = mix32(seed ^ mix32(persist.boots * 0x9E3779B9u));
    for (uint32_t k = 1; id == 0 || id == persist.last_id; k++) id = mix32(id + k);
    persist.last_id = id;
    return id;
}

/* ---- main loop ---------------------------------------------------------------------------- */

static void run_tick(uint32_t t_us) {
    sim_this_tick = 0;
    tick_start = now_counts();
    rig_tick(&mcu, t_us);
    uint64_t dt = now_counts() - tick_start;
    board_tick_stats.ticks++;
    if (dt > board_tick_stats.tick_max) {
        board_tick_stats.tick_max = clip32(dt);
        board_tick_stats.tick_max_state = mcu.state;
    }
    uint64_t core = dt > sim_this_tick ? dt - sim_this_tick : 0;
    if (core > board_tick_stats.core_max) board_tick_stats.core_max = clip32(core);
}

/* QEMU's netduinoplus2 has no writable flash: the calibration is kept in RAM (rig_mcu's
 * copy), in use until the next reset; the NUCLEO board stores it in flash. */
bool hal_nvm_store(const rig_calibration *cal) {
    (void)cal;
    return true;
}

int main(void) {
    static char err[160];
    board_tick_stats.counts_per_ms = SYSTICK_RELOAD;
    uart_init();
    if (sim_rig_init(&rig_setup_hw, rig_setup_names, rig_setup_values, RIG_SETUP_COUNT, err,
                     sizeof err) != 0) {
        /* junk between frames to a host (the protocol drops it); readable on a terminal */
        uart_puts("\r\nrig: the simulated rig refused its setup: ");
        uart_puts(err);
        uart_puts("\r\n");
        for (;;) wait_for_interrupt();
    }
    rig_boot(&mcu, boot_id(), rig_setup_default);
    board_tick_stats.magic = 0x71C5A75u;

    SCB_SHPR3 = (SCB_SHPR3 & 0x00FFFFFFu) | (2u << 28); /* SysTick below the UART */
    SYSTICK->LOAD = SYSTICK_RELOAD - 1u;
    SYSTICK->VAL = 0;
    SYSTICK->CTRL = SYSTICK_CTRL_ENABLE | SYSTICK_CTRL_TICKINT | SYSTICK_CTRL_CLKSOURCE;

    uint32_t ticks_done = 0;
    for (;;) {
        /* received bytes, a slice at a time so that a pending tick waits little */
        uint8_t buf[RX_SLICE];
        size_t n = rx_ring_take(&rx, buf);
        if (n != 0) {
            uint64_t t0 = now_counts();
            rig_rx(&mcu, buf, n);
            uint64_t dt = now_counts() - t0;
            if (dt > board_tick_stats.rx_max) board_tick_stats.rx_max = clip32(dt);
            board_tick_stats.rx_bytes += (uint32_t)n;
        }
        /* the period's tick: each missed one too, at its scheduled time */
        uint32_t due = systick_count;
        if (due != ticks_done) {
            if (due - ticks_done > 1u) board_tick_stats.late_ticks++;
            run_tick(ticks_done * RIG_POINT_PERIOD_US);
            ticks_done++;
        }
        uart_drain();
        irq_disable();
        if (rx_ring_empty(&rx) && systick_count == ticks_done) wait_for_interrupt();
        irq_enable();
    }
}

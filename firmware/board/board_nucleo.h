/* What the NUCLEO-F446RE board's files share (board_nucleo.c has the overview: pins,
 * clocks and the reasoning are in docs/firmware.md):
 *
 *   board_nucleo.c   the main loop, serial (USART2, TX by DMA), the tick (TIM5), the stats
 *   nucleo_system.c  the clock tree, the pins, the independent watchdog, the boot id
 *   nucleo_step.c    the step generator (TIM1 bursts, TIM3 counts them), the driver's enable
 *   nucleo_inputs.c  hal_read: encoder (TIM2), load cell (ADS131M02 on SPI2), switches and
 *                    the board's own faults
 */
#ifndef BOARD_NUCLEO_H
#define BOARD_NUCLEO_H

#include <stdbool.h>
#include <stdint.h>

#include "rig_core.h"
#include "stm32f4_regs.h"

/* ---- clocks, pins, the board's FAULT values ------------------------------------------------- */

/* the clock tree of nucleo_system.c's clock_init */
#define HCLK_HZ 180000000u
#define APB1_HZ 45000000u
#define APB1_TIMER_HZ 90000000u
#define APB2_TIMER_HZ 180000000u
#define HSI_HZ 16000000u /* the fallback: every bus at 16 MHz, no motion (CLOCK fault) */

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

/* FAULT values of the board's faults (docs/rig-protocol-behaviour.md section 8) */
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

/* ---- state shared between the files (each defined in the file named) ------------------------ */

/* what a debugger reads (docs/firmware.md): the tick's cost in CPU cycles (DWT) */
typedef struct {
    uint32_t ticks, late_ticks, tick_max_cycles, rx_max_cycles, step_errors, rx_overruns;
    uint32_t boots, clock_from_hsi, rng_failed;
} board_stats;
extern volatile board_stats board_tick_stats; /* board_nucleo.c */

/* board_nucleo.c */
extern volatile uint32_t tick_count; /* TIM5 updates */
extern uint32_t tick_now;            /* tick_count at which the running rig_tick is due */
extern bool late_tick;               /* the main loop found more than one period due */
/* nucleo_step.c */
extern bool step_error; /* a burst that could not be armed in time or was too long */
extern bool driver_on;  /* what hal_driver_enable last set */
/* nucleo_system.c */
extern uint32_t clock_fault;            /* a CLOCK_* code (0: none) */
extern uint32_t apb1_hz, apb1_timer_hz; /* APB1_HZ, APB1_TIMER_HZ, or HSI_HZ on the fallback */

/* ---- GPIO ----------------------------------------------------------------------------------- */

static inline void pin_write(gpio_regs *port, uint32_t pin, bool high) {
    port->BSRR = high ? (1u << pin) : (1u << (pin + 16u));
}

static inline bool pin_read(const gpio_regs *port, uint32_t pin) {
    return (port->IDR >> pin) & 1u;
}

/* ---- the files' entry points ---------------------------------------------------------------- */

/* nucleo_system.c */
void clock_init(void);
void pins_init(void);
void watchdog_init(void);
uint32_t new_boot_id(uint32_t boots);
/* nucleo_step.c */
void step_init(void);
/* nucleo_inputs.c */
void encoder_init(void);
void adc_init(void);

#endif

/* The hardware interface of the rig firmware: what the portable core (rig_core.h) needs
 * from a board, and nothing more. Each board (firmware/board/, the STM32F4 Nucleo) and the
 * simulated rig (firmware/sim/, the clamp plant) implements these functions; the core
 * calls them only from rig_boot() and rig_tick(), never from rig_rx(), but for
 * hal_nvm_store().
 *
 * Units are the protocol's (docs/rig-protocol.md section 3): steps (0.2 um of table
 * travel), encoder counts (1 um of platen travel), raw load-cell ADC counts. Counts here
 * are the hardware's own, since power-on; the core applies SET_POSITION's offsets.
 */
#ifndef RIG_HAL_H
#define RIG_HAL_H

#include <stdbool.h>
#include <stdint.h>

/* Inputs latched together at the start of a period, after that period's step output. */
typedef struct {
    int32_t enc;       /* encoder counts since power-on (quadrature timer, 32-bit extended) */
    int32_t load_raw;  /* load-cell ADC counts, sign-extended 24-bit */
    bool home_switch;  /* reference switch at the open position active */
    bool stop_input;   /* operator's stop button pressed (latches ESTOP) */
    bool driver_alarm; /* stepper driver's alarm output active (latches DRIVER) */
    /* faults the board itself found this period (RIG_F_INTERNAL, RIG_F_OVERTRAVEL,
     * RIG_F_LOAD_ADC, RIG_F_CLOCK, RIG_F_STOP_CHAIN of rig_core.h): each latches as a
     * halting fault with board_detail as its FAULT frame's value (which input, which
     * check: docs/rig-protocol-behaviour.md section 8); 0 on a board without such checks */
    uint16_t board_faults;
    int32_t board_detail;
} rig_inputs;

/* The load-cell calibration stored in non-volatile memory (protocol section 3). */
typedef struct {
    int32_t load_offset; /* ADC counts at zero force */
    float load_gain_n;   /* N per ADC count */
    uint32_t seq;        /* 1.3: record number, +1 per STORE_CALIBRATION; 0 = defaults */
} rig_calibration;

/* Emit |delta| step pulses (direction by sign) spread evenly over the coming period;
 * 0 holds the position. Called once per tick while the table moves. */
void hal_step(int32_t delta);

/* Stop the step pulses of the present period at once (a halting fault). Returns the
 * pulses of the last hal_step() that were not emitted (0 when it had finished), with the
 * sign of that step, so the core's step count stays the count actually output. */
int32_t hal_step_halt(void);

/* Energise (true) or disable (false) the stepper driver. */
void hal_driver_enable(bool on);

/* Whether power reaching the driver is confirmed now (the stop chain's feedback follows
 * the enable). A run's first point waits for it after START; a board without such
 * feedback returns true. The board reports a chain that never confirms (STOP_CHAIN). */
bool hal_driver_powered(void);

/* Latch every input of the period. */
void hal_read(rig_inputs *in);

/* 1.3: write the calibration (its seq already the new record's) to non-volatile memory and
 * read it back; true when it verified. The previous record must stay readable until the
 * new one verifies (a power cut mid-write keeps it). The one HAL call from rig_rx(): for
 * STORE_CALIBRATION in IDLE, while the table holds still; it must take well under a
 * period (program a few words; erase only at boot). */
bool hal_nvm_store(const rig_calibration *cal);

/* Kick the independent hardware watchdog (once per tick, from the main loop's tick). */
void hal_watchdog_kick(void);

#endif

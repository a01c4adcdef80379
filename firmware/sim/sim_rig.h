/* The simulated rig: a board whose "hardware" is the clamp plant. It implements every
 * function of rig_hal.h (firmware/core/) on the native FMU's C code (fmu_src/native/
 * fmi2_clamp.c and the generated clamp_model.c, compiled in): the sim is an FMI 2.0 master
 * of that FMU, one fmi2DoStep per sensor reading, so the rig's mechanics are the FMU's
 * equations and nothing else. On top of the plant it adds the sensors exactly as
 * hil/emulators/rig_hardware.py's Sensors.read does: encoder quantisation, load-cell noise
 * (own seeded PRNG), amplifier offset and gain, the 24-bit ADC rails, and the injected sensor
 * faults of hil/emulators/rig_emulator.py's FaultPlan (force spike, stuck load cell, stuck encoder, the
 * operator's stop button).
 *
 * One rig per program, static state, no heap in this file (the FMU itself allocates its
 * instance with calloc at fmi2Instantiate: see sim_rig.c). No POSIX: builds for the host
 * and for Cortex-M4 with arm-none-eabi-gcc and newlib.
 */
#ifndef SIM_RIG_H
#define SIM_RIG_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "rig_hal.h"

/* The rig's constants (hil.emulators.rig_hardware.RigHardware). */
typedef struct {
    double x_origin;     /* input (table) position at hardware step 0, power-on, m */
    double home_x;       /* reference switch active while x <= home_x + 1e-12 m */
    double load_gain_n;  /* load-cell amplifier and ADC: N per count (> 0) */
    double load_noise_n; /* rms noise of the load cell and amplifier, N (>= 0) */
    double period_s;     /* one hal_read() is one FMU step of this length, s (> 0) */
    uint64_t noise_seed; /* seed of the noise generator: the same seed, the same noise */
    int32_t load_offset; /* ADC counts at zero force */
    int32_t step_timing; /* SIM_RIG_STEPS_AT_ONCE or SIM_RIG_STEPS_NUCLEO (below) */
    /* bring-up faults (hil.emulators.rig_hardware.RigHardware): -1 the encoder counts against
     * the steps (0 or 1: with them); the drive loses drop_n of every drop_d step pulses (0: none) */
    int32_t enc_sign;
    uint32_t drop_n, drop_d;
} sim_rig_hw;

/* When the table takes a period's steps (sim_rig_hw.step_timing):
 * AT_ONCE  all of them before the period's reading (hil.emulators.mcu_model's idealised board: the
 *          reading of a tick shows that tick's steps; hal_step_halt() has nothing left);
 * NUCLEO   as the NUCLEO-F446RE's TIM1 emits them (step_burst.h): a tick's steps leave in
 *          a burst that starts STEP_PHASE_US after it and lasts the period, and the reading
 *          at a tick shows the pulses whose rising edge came by that tick; the board calls
 *          sim_rig_tick() at each tick's instant, before the core's rig_tick, and
 *          hal_step_halt() gives back the pulses not yet emitted at that instant. */
#define SIM_RIG_STEPS_AT_ONCE 0
#define SIM_RIG_STEPS_NUCLEO 1

#define SIM_RIG_STEP_M 200e-9 /* table travel of one step (RIG_STEP_NM) */
#define SIM_RIG_ENC_M 1e-6    /* platen travel of one encoder count (RIG_ENC_NM) */

/* (Re)start the rig: instantiate and initialise the FMU with the parameters given by name
 * (the variables of the generated CLAMP_NAMES table; any not given keeps the FMU's start
 * value). x_cmd, if given, must equal hw->x_origin (the table is there at power-on); it
 * defaults to it. Returns 0, or -1 with a message naming the refused parameter in err
 * (err may be NULL). Counts, faults and time restart at zero. */
int sim_rig_init(const sim_rig_hw *hw, const char *const *names, const double *values, int n,
                 char *err, size_t err_len);

/* The board's tick instant (SIM_RIG_STEPS_NUCLEO): the bursts in flight age by a period. */
void sim_rig_tick(void);

/* Sensor faults (hil.emulators.rig_emulator.FaultPlan). */
void sim_rig_force_spike(double newtons, uint32_t samples); /* add to the next readings */
void sim_rig_stick_load(bool on);    /* the load-cell reading freezes (true) / recovers */
void sim_rig_stick_encoder(bool on); /* the encoder reading freezes (true) / recovers */
void sim_rig_press_stop(bool pressed); /* the operator's stop button (stop_input) */
void sim_rig_board_fault(uint16_t bits, int32_t detail); /* a board's own faults, held */

/* What the rig is doing (for tests and the board's diagnostics). */
typedef struct {
    int32_t hw_steps;         /* steps output since power-on (hal_step's sum) */
    int32_t table_steps;      /* of them, those the table took by the last reading */
    bool driver_enabled;      /* last hal_driver_enable() */
    uint32_t reads;           /* hal_read() calls = FMU steps attempted */
    uint32_t watchdog_kicks;  /* hal_watchdog_kick() calls */
    uint32_t fmu_failures;    /* FMU steps refused (the platen then stays where it was) */
    double time_s;            /* simulated time: reads * period_s */
    double x;                 /* present input position, m */
    double platen_position;   /* true platen position of the last reading, m */
    double input_force;       /* true input force of the last reading (no spike, noise), N */
    size_t arena_used;        /* bytes the FMU took through fmi2CallbackFunctions */
} sim_rig_status;

void sim_rig_get_status(sim_rig_status *out);

/* The last message the FMU logged (an init refusal, a refused step); "" if none. */
const char *sim_rig_last_message(void);

#endif

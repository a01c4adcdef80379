/* A fake rig_hal.h for the core's tests and fuzzer: a table that moves at once, an encoder
 * that follows it (enc = enc_base + hw_steps / enc_div when enc_div != 0), a load cell that
 * reads load_base plus a toggling noise bit (or load_base exactly when load_stuck), and
 * switches the test sets. It counts every call and checks the per-tick order (hal_step
 * once, before hal_read). */
#ifndef FAKE_HAL_H
#define FAKE_HAL_H

#include <stdbool.h>
#include <stdint.h>

#include "rig_core.h"
#include "rig_hal.h"

typedef struct {
    int32_t hw_steps;
    int32_t enc_base, enc_div;
    int32_t load_base;
    bool load_stuck, home_switch, stop_input, driver_alarm;
    int32_t halt_return; /* what hal_step_halt reports as not emitted */
    bool driver_on;
    bool chain_open;       /* hal_driver_powered() false */
    uint16_t board_faults; /* reported by hal_read */
    uint32_t steps_calls, read_calls, kicks, halts, driver_calls;
    uint32_t order_errors; /* hal_read without a hal_step since the last read, or two steps */
    int32_t last_delta;
    bool stepped;
    /* non-volatile memory (1.3): the last record written; nvm_fail makes writes fail */
    bool nvm_fail;
    uint32_t nvm_writes;
    rig_calibration nvm;
} fake_hal_state;

extern fake_hal_state fake;

void fake_hal_reset(void);

#endif

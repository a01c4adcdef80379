/* The fake HAL (fake_hal.h). */
#include "fake_hal.h"

#include <string.h>

fake_hal_state fake;

void fake_hal_reset(void) {
    memset(&fake, 0, sizeof fake);
    fake.enc_base = 1234; /* not 0: the core zeroes the first reading */
    fake.load_base = 1500;
}

void hal_step(int32_t delta) {
    if (fake.stepped) fake.order_errors++;
    fake.stepped = true;
    fake.steps_calls++;
    fake.last_delta = delta;
    fake.hw_steps = (int32_t)((uint32_t)fake.hw_steps + (uint32_t)delta);
}

/* Reports min(halt_return, |last delta|) pulses of the last hal_step as not emitted, with
 * that step's sign (a real step generator cannot have more left than it was given). */
int32_t hal_step_halt(void) {
    fake.halts++;
    int32_t left = fake.halt_return < 0 ? 0 : fake.halt_return;
    int32_t mag = fake.last_delta < 0 ? -fake.last_delta : fake.last_delta;
    if (left > mag) left = mag;
    int32_t r = fake.last_delta < 0 ? -left : left;
    fake.hw_steps = (int32_t)((uint32_t)fake.hw_steps - (uint32_t)r);
    fake.halt_return = 0;
    fake.last_delta = 0; /* what is left of that period's output is gone */
    return r;
}

void hal_driver_enable(bool on) {
    fake.driver_calls++;
    fake.driver_on = on;
}

bool hal_driver_powered(void) { return fake.driver_on && !fake.chain_open; }

void hal_read(rig_inputs *in) {
    if (!fake.stepped) fake.order_errors++;
    fake.stepped = false;
    fake.read_calls++;
    in->enc = fake.enc_base + (fake.enc_div ? fake.hw_steps / fake.enc_div : 0);
    in->load_raw = fake.load_base + (fake.load_stuck ? 0 : (int32_t)(fake.read_calls & 1u));
    in->home_switch = fake.home_switch;
    in->stop_input = fake.stop_input;
    in->driver_alarm = fake.driver_alarm;
    in->board_faults = fake.board_faults;
}

void hal_watchdog_kick(void) { fake.kicks++; }

bool hal_nvm_store(const rig_calibration *cal) {
    fake.nvm_writes++;
    if (fake.nvm_fail) return false;
    fake.nvm = *cal;
    return true;
}

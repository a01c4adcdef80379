/* The host build of the rig firmware: the portable core (firmware/core/) on the simulated
 * rig (firmware/sim/), one MCU per process, exported as a plain C API for Python's ctypes
 * (hil/emulators/firmware.py). The caller is the board's main loop: it feeds received bytes
 * (rigfw_rx), calls rigfw_tick once per period with its clock, and sends what
 * rigfw_tx_take hands it. Only the rigfw_* functions are exported from librigfw.so.
 */
#define _DEFAULT_SOURCE /* getrandom() */

#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>
#include <sys/random.h>
#include <unistd.h>

#include "rig_core.h"
#include "sim_rig.h"

#define EXPORT __attribute__((visibility("default")))

static rig_mcu mcu;
static rig_calibration stored;
static bool opened, have_boot_time;
static double boot_s;

/* 32 bits from the OS's entropy: getrandom(), else /dev/urandom, else a mix of what is
 * at hand (a board's hardware RNG in the firmware proper). */
static uint32_t entropy32(void) {
    uint32_t v = 0;
    ssize_t got;
    do {
        got = getrandom(&v, sizeof v, 0);
    } while (got < 0 && errno == EINTR);
    if (got == (ssize_t)sizeof v) return v;
    int fd = open("/dev/urandom", O_RDONLY | O_CLOEXEC);
    if (fd >= 0) {
        got = read(fd, &v, sizeof v);
        close(fd);
        if (got == (ssize_t)sizeof v) return v;
    }
    static uint32_t fallback = 0x9E3779B9u;
    fallback = fallback * 1664525u + 1013904223u + (uint32_t)(uintptr_t)&v;
    return fallback;
}

/* A boot id: non-zero and different from the previous one (rig_core.h, rig_boot). */
static uint32_t new_boot_id(uint32_t previous) {
    uint32_t id;
    do {
        id = entropy32();
    } while (id == 0 || id == previous);
    return id;
}

static void boot(void) {
    rig_boot(&mcu, new_boot_id(mcu.boot_id), stored);
    have_boot_time = false; /* the next tick is the boot's time, t_us = 0 */
}

/* Start the rig (the sim's FMU with these parameters) and power the MCU on. Returns 0, or
 * -1 with the reason in err (a refused parameter is named). */
EXPORT int rigfw_open(const sim_rig_hw *hw, const char *const *names, const double *values,
                      int n, char *err, size_t err_len) {
    opened = false;
    if (sim_rig_init(hw, names, values, n, err, err_len) != 0) return -1;
    stored.load_offset = hw->load_offset;
    stored.load_gain_n = (float)hw->load_gain_n;
    mcu.boot_id = 0;
    boot();
    opened = true;
    return 0;
}

/* Bytes from the host, received at now_s (the core times frames by its own ticks). */
EXPORT void rigfw_rx(const uint8_t *data, size_t n, double now_s) {
    (void)now_s;
    if (opened && n) rig_rx(&mcu, data, n);
}

/* One period at now_s (s, any monotonic clock): t_us counts from the first tick after
 * boot, rounded to whole us, modulo 2^32. */
EXPORT void rigfw_tick(double now_s) {
    if (!opened) return;
    if (!have_boot_time) {
        boot_s = now_s;
        have_boot_time = true;
    }
    double us = nearbyint((now_s - boot_s) * 1e6);
    uint32_t t_us = (uint32_t)(int64_t)fmod(us, 4294967296.0);
    sim_rig_tick(); /* the tick's instant: the board's step bursts in flight age */
    rig_tick(&mcu, t_us);
}

/* Up to max bytes the MCU sends (whole frames or parts), in order; returns how many. */
EXPORT size_t rigfw_tx_take(uint8_t *out, size_t max) {
    return opened ? rig_tx_take(&mcu, out, max) : 0;
}

/* MCU reset: new boot id, no session, counts at 0; the rig's physics is untouched, but the
 * step pulses not yet emitted are (the reset stops the step timer). */
EXPORT void rigfw_reset(void) {
    if (!opened) return;
    (void)hal_step_halt();
    boot();
}

EXPORT void rigfw_link_lost(void) {
    if (opened) rig_link_lost(&mcu);
}

EXPORT uint32_t rigfw_boot_id(void) { return mcu.boot_id; }
EXPORT int rigfw_state(void) { return mcu.state; }

/* Counts as the core reports them (after SET_POSITION's offsets), and the hardware's. */
EXPORT void rigfw_counts(int32_t *steps, int32_t *enc, int32_t *load_raw, int32_t *hw_steps) {
    sim_rig_status st;
    sim_rig_get_status(&st);
    if (steps) *steps = mcu.steps;
    if (enc) *enc = mcu.enc;
    if (load_raw) *load_raw = mcu.load_raw;
    if (hw_steps) *hw_steps = st.hw_steps;
}

EXPORT void rigfw_sim_status(sim_rig_status *out) { sim_rig_get_status(out); }
EXPORT const char *rigfw_sim_message(void) { return sim_rig_last_message(); }
EXPORT size_t rigfw_sizeof_status(void) { return sizeof(sim_rig_status); }
EXPORT size_t rigfw_sizeof_hw(void) { return sizeof(sim_rig_hw); }

/* The sim's fault injection. */
EXPORT void rigfw_force_spike(double newtons, uint32_t samples) {
    sim_rig_force_spike(newtons, samples);
}
EXPORT void rigfw_stick_load(bool on) { sim_rig_stick_load(on); }
EXPORT void rigfw_stick_encoder(bool on) { sim_rig_stick_encoder(on); }
EXPORT void rigfw_press_stop(bool pressed) { sim_rig_press_stop(pressed); }
EXPORT void rigfw_board_fault(uint16_t bits, int32_t detail) {
    sim_rig_board_fault(bits, detail);
}

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
#include <stdio.h>
#include <string.h>
#include <sys/random.h>
#include <unistd.h>

#include "rig_core.h"
#include "sim_rig.h"

#define EXPORT __attribute__((visibility("default")))

static rig_mcu mcu;
static rig_calibration stored;
static bool opened, have_boot_time;
/* the MCU's non-volatile memory: a file (survives the process), or this memory only when
 * no path was given (survives rigfw_reset, an MCU reset) */
static char nvm_path[512];
static bool nvm_defaults_set;
static rig_calibration nvm_defaults;
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

/* ---- non-volatile memory: one 20-byte record, replaced atomically (write, fsync, rename) */

#define NVM_MAGIC 0x314C4143u /* "CAL1" */

static uint32_t nvm_check(const uint32_t w[4]) { /* FNV-1a over the record's 16 bytes */
    uint32_t h = 2166136261u;
    for (int i = 0; i < 4; i++)
        for (int b = 0; b < 4; b++) h = (h ^ ((w[i] >> (8 * b)) & 0xFFu)) * 16777619u;
    return h;
}

static void nvm_words(const rig_calibration *cal, uint32_t w[5]) {
    w[0] = NVM_MAGIC;
    w[1] = cal->seq;
    w[2] = (uint32_t)cal->load_offset;
    memcpy(&w[3], &cal->load_gain_n, sizeof w[3]);
    w[4] = nvm_check(w);
}

/* The record in the file, or false when there is none or it does not verify. */
static bool nvm_load(rig_calibration *cal) {
    uint32_t w[5];
    FILE *f = fopen(nvm_path, "rb");
    if (!f) return false;
    size_t got = fread(w, sizeof w[0], 5, f);
    fclose(f);
    if (got != 5 || w[0] != NVM_MAGIC || w[4] != nvm_check(w)) return false;
    cal->seq = w[1];
    cal->load_offset = (int32_t)w[2];
    memcpy(&cal->load_gain_n, &w[3], sizeof cal->load_gain_n);
    return true;
}

bool hal_nvm_store(const rig_calibration *cal) {
    if (nvm_path[0] == '\0') return true; /* memory only: rig_mcu keeps it, boot() reuses it */
    char tmp[sizeof nvm_path + 8];
    snprintf(tmp, sizeof tmp, "%s.new", nvm_path);
    uint32_t w[5];
    nvm_words(cal, w);
    int fd = open(tmp, O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
    if (fd < 0) return false;
    bool ok = write(fd, w, sizeof w) == (ssize_t)sizeof w && fsync(fd) == 0;
    ok = close(fd) == 0 && ok;
    ok = ok && rename(tmp, nvm_path) == 0;
    rig_calibration back;
    return ok && nvm_load(&back) && back.seq == cal->seq;
}

/* Where the MCU's non-volatile memory lives ("" or NULL: memory only) and the firmware's
 * default calibration (used while nothing is stored); call before rigfw_open. */
EXPORT void rigfw_set_nvm(const char *path, int32_t default_offset, double default_gain) {
    nvm_path[0] = '\0';
    if (path) snprintf(nvm_path, sizeof nvm_path, "%s", path);
    nvm_defaults.load_offset = default_offset;
    nvm_defaults.load_gain_n = (float)default_gain;
    nvm_defaults.seq = 0;
    nvm_defaults_set = true;
}

/* The stored calibration cal_seq (0: the defaults), for tests. */
EXPORT uint32_t rigfw_stored_seq(void) { return mcu.stored.seq; }

static void boot(void) {
    if (mcu.stored.seq != 0) stored = mcu.stored; /* a store of this power-on survives */
    rig_boot(&mcu, new_boot_id(mcu.boot_id), stored);
    have_boot_time = false; /* the next tick is the boot's time, t_us = 0 */
}

/* Start the rig (the sim's FMU with these parameters) and power the MCU on. Returns 0, or
 * -1 with the reason in err (a refused parameter is named). */
EXPORT int rigfw_open(const sim_rig_hw *hw, const char *const *names, const double *values,
                      int n, char *err, size_t err_len) {
    opened = false;
    if (sim_rig_init(hw, names, values, n, err, err_len) != 0) return -1;
    if (nvm_defaults_set) {
        stored = nvm_defaults;
    } else {
        stored.load_offset = hw->load_offset;
        stored.load_gain_n = (float)hw->load_gain_n;
        stored.seq = 0;
    }
    if (nvm_path[0] != '\0') (void)nvm_load(&stored);
    mcu.boot_id = 0;
    mcu.stored.seq = 0;
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

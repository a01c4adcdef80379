/* The simulated rig (sim_rig.h): rig_hal.h on the native FMU of the clamp.
 *
 * Memory: this file has no heap. It hands the FMU fmi2CallbackFunctions whose
 * allocateMemory/freeMemory come from a static arena (SIM_RIG_ARENA_BYTES), but the native
 * FMU's wrapper (fmu_src/native/fmi2_clamp.c, canNotUseMemoryManagementFunctions="true")
 * does not call them: fmi2Instantiate takes its instance with calloc() and
 * fmi2FreeInstance frees it (and fmi2GetFMUstate/fmi2DeSerializeFMUstate would malloc,
 * which the sim never calls). An image with the sim therefore links newlib's malloc for
 * that one instance (about 2 KiB), allocated at sim_rig_init. sim_rig_get_status() reports
 * the bytes taken from the arena (0 with this FMU).
 *
 * Logging: the FMU's messages (vsnprintf, as newlib has it) land in one static buffer,
 * read by sim_rig_init's refusal and sim_rig_last_message(). Numbers in them are printed
 * with %g: a newlib-nano image needs -u _printf_float to see them.
 */
#include "sim_rig.h"

#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <string.h>

#include "fmi2Functions.h"
#include "clamp_model_data.h"
#include "step_burst.h"

#ifndef SIM_RIG_ARENA_BYTES
#define SIM_RIG_ARENA_BYTES 4096u
#endif

#define ADC_MIN (-8388608.0)
#define ADC_MAX 8388607.0
#define HOME_TOLERANCE_M 1e-12
#define TWO_PI 6.283185307179586

/* ---- state: one rig per program -------------------------------------------------------- */

static struct {
    sim_rig_hw hw;
    fmi2Component fmu;
    fmi2ValueReference vr_x, vr_platen, vr_force;
    bool ready;
    /* actuators and counters */
    int32_t hw_steps;
    /* the table: steps taken (all of hw_steps but the bursts in flight, NUCLEO timing);
     * the bursts armed at the last tick (running) and at this one (starting later) */
    int32_t table_steps, burst_running, burst_armed;
    bool driver_enabled, stop_pressed;
    uint16_t board_faults; /* injected: what a board's own checks would report */
    int32_t board_detail;
    uint32_t reads, kicks, fmu_failures;
    double time_s, platen, force;
    /* sensors */
    bool have_zero, have_last, load_stuck, enc_stuck;
    double platen_zero, spike_n;
    uint32_t spike_samples;
    int32_t last_enc, last_raw;
    uint64_t drop_acc; /* lost pulses: hil.emulators.rig_hardware.Sensors._lose_steps */
    /* noise: xoshiro256** and Box-Muller with the second deviate kept */
    uint64_t rng[4];
    bool have_spare;
    double spare;
} sim;

static char log_text[256];

/* ---- the FMU's memory and logger ------------------------------------------------------- */

#if SIM_RIG_ARENA_BYTES > 0
static union {
    long double align_ld;
    uint64_t align_u64;
    unsigned char bytes[SIM_RIG_ARENA_BYTES];
} arena;
#endif
static size_t arena_used;

static void *arena_alloc(size_t nobj, size_t size) {
#if SIM_RIG_ARENA_BYTES > 0
    size_t need, start = (arena_used + 15u) & ~(size_t)15u;
    if (size != 0 && nobj > ((size_t)-1) / size) return NULL;
    need = nobj * size;
    if (start > sizeof arena.bytes || need > sizeof arena.bytes - start) return NULL;
    arena_used = start + need;
    memset(arena.bytes + start, 0, need);
    return arena.bytes + start;
#else
    (void)nobj; (void)size;
    return NULL;
#endif
}

static void arena_free(void *p) {
    (void)p; /* a bump arena: everything returns at the next sim_rig_init */
}

static void fmu_logger(fmi2ComponentEnvironment env, fmi2String instance, fmi2Status status,
                       fmi2String category, fmi2String message, ...) {
    va_list ap;
    (void)env; (void)instance; (void)status; (void)category;
    if (!message) return;
    va_start(ap, message);
    vsnprintf(log_text, sizeof log_text, message, ap);
    va_end(ap);
}

static const fmi2CallbackFunctions CALLBACKS = {fmu_logger, arena_alloc, arena_free, NULL, NULL};

/* ---- noise: splitmix64 seeding, xoshiro256**, Box-Muller ------------------------------- */

static uint64_t splitmix64(uint64_t *s) {
    uint64_t z = (*s += 0x9E3779B97F4A7C15ull);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
    return z ^ (z >> 31);
}

static uint64_t rotl(uint64_t x, int k) { return (x << k) | (x >> (64 - k)); }

static uint64_t xoshiro(void) {
    uint64_t *s = sim.rng, result = rotl(s[1] * 5u, 7) * 9u, t = s[1] << 17;
    s[2] ^= s[0]; s[3] ^= s[1]; s[1] ^= s[2]; s[0] ^= s[3];
    s[2] ^= t;
    s[3] = rotl(s[3], 45);
    return result;
}

static double uniform01(void) { return (double)(xoshiro() >> 11) * 0x1.0p-53; } /* [0, 1) */

static double gauss(void) {
    if (sim.have_spare) {
        sim.have_spare = false;
        return sim.spare;
    }
    double u1 = 1.0 - uniform01(), u2 = uniform01(); /* u1 in (0, 1]: log finite */
    double r = sqrt(-2.0 * log(u1));
    sim.spare = r * sin(TWO_PI * u2);
    sim.have_spare = true;
    return r * cos(TWO_PI * u2);
}

/* ---- helpers --------------------------------------------------------------------------- */

static void fail(char *err, size_t len, const char *fmt, ...) {
    va_list ap;
    if (!err || !len) return;
    va_start(ap, fmt);
    vsnprintf(err, len, fmt, ap);
    va_end(ap);
}

static int variable(const char *name) {
    for (int i = 0; i < CLAMP_N_REAL; i++)
        if (strcmp(CLAMP_NAMES[i], name) == 0) return i;
    return -1;
}

/* Input position of a step count: as hil.emulators.rig_hardware.Sensors.x
 * (steps * step_nm / 1e9). */
static double table_x(int32_t steps) {
    return sim.hw.x_origin + (double)((int64_t)steps * 200) / 1e9;
}

/* Round half to even (Python's round()) to an int32 within [lo, hi]. */
static int32_t round_clamped(double v, double lo, double hi) {
    double r = nearbyint(v);
    if (!(r >= lo)) return isnan(r) ? 0 : (int32_t)lo;
    if (r > hi) return (int32_t)hi;
    return (int32_t)r;
}

static void release(void) {
    if (sim.fmu) fmi2FreeInstance(sim.fmu);
    sim.fmu = NULL;
    sim.ready = false;
    arena_used = 0;
}

/* Pulses of a signed burst whose rising edge came by the tick after its start. */
static int32_t emitted_by_tick(int32_t burst) {
    uint32_t n = (uint32_t)(burst < 0 ? -(int64_t)burst : burst);
    int32_t done = (int32_t)step_burst_rises(n, STEP_BURST_TICKS_TO_TICK);
    return burst < 0 ? -done : done;
}

/* ---- sim_rig.h ------------------------------------------------------------------------- */

int sim_rig_init(const sim_rig_hw *hw, const char *const *names, const double *values, int n,
                 char *err, size_t err_len) {
    fmi2ValueReference vr;
    double x0;
    if (err && err_len) err[0] = '\0';
    release();
    memset(&sim, 0, sizeof sim);
    log_text[0] = '\0';
    if (!hw) {
        fail(err, err_len, "no rig hardware given");
        return -1;
    }
    if (!(isfinite(hw->period_s) && hw->period_s > 0)) {
        fail(err, err_len, "hardware: period_s must be > 0 s, got %g", hw->period_s);
        return -1;
    }
    if (!(isfinite(hw->load_gain_n) && hw->load_gain_n > 0)) {
        fail(err, err_len, "hardware: load_gain_n must be > 0 N/count, got %g", hw->load_gain_n);
        return -1;
    }
    if (!(isfinite(hw->load_noise_n) && hw->load_noise_n >= 0)) {
        fail(err, err_len, "hardware: load_noise_n must be >= 0 N, got %g", hw->load_noise_n);
        return -1;
    }
    if (!(isfinite(hw->x_origin) && isfinite(hw->home_x))) {
        fail(err, err_len, "hardware: x_origin and home_x must be finite");
        return -1;
    }
    if (hw->step_timing != SIM_RIG_STEPS_AT_ONCE && hw->step_timing != SIM_RIG_STEPS_NUCLEO) {
        fail(err, err_len, "hardware: step_timing must be %d (at once) or %d (NUCLEO), got %ld",
             SIM_RIG_STEPS_AT_ONCE, SIM_RIG_STEPS_NUCLEO, (long)hw->step_timing);
        return -1;
    }
    if (hw->load_offset < (int32_t)ADC_MIN || hw->load_offset > (int32_t)ADC_MAX) {
        fail(err, err_len, "hardware: load_offset %ld is outside the 24-bit ADC",
             (long)hw->load_offset);
        return -1;
    }
    if (n < 0 || (n > 0 && (!names || !values))) {
        fail(err, err_len, "parameters: %d names", n);
        return -1;
    }
    sim.hw = *hw;
    for (int i = 0; i < n; i++) {
        int k = names[i] ? variable(names[i]) : -1;
        if (k < 0) {
            fail(err, err_len, "unknown parameter '%s': not a variable of the %s FMU",
                 names[i] ? names[i] : "(null)", CLAMP_PRESET);
            return -1;
        }
        if (k >= VR_OUT0 && k < VR_OUT0 + CLAMP_N_OUT) {
            fail(err, err_len, "parameter '%s' is an output of the FMU, not settable", names[i]);
            return -1;
        }
        for (int j = 0; j < i; j++)
            if (strcmp(names[j], names[i]) == 0) {
                fail(err, err_len, "parameter '%s' given twice", names[i]);
                return -1;
            }
        if (!isfinite(values[i])) {
            fail(err, err_len, "parameter '%s' = %g is not a finite number", names[i], values[i]);
            return -1;
        }
        if (k == VR_X_CMD) {
            if (values[i] != hw->x_origin) {
                fail(err, err_len, "parameter 'x_cmd' = %.17g m is not the table's power-on "
                     "position x_origin = %.17g m", values[i], hw->x_origin);
                return -1;
            }
        }
    }
    sim.fmu = fmi2Instantiate("sim_rig", fmi2CoSimulation, CLAMP_GUID, "", &CALLBACKS,
                              fmi2False, fmi2False);
    if (!sim.fmu) {
        fail(err, err_len, "the FMU could not be instantiated%s%s", log_text[0] ? ": " : "",
             log_text);
        return -1;
    }
    for (int i = 0; i < n; i++) {
        vr = (fmi2ValueReference)variable(names[i]);
        if (fmi2SetReal(sim.fmu, &vr, 1, &values[i]) != fmi2OK) {
            fail(err, err_len, "parameter '%s' = %g refused: %s", names[i], values[i], log_text);
            release();
            return -1;
        }
    }
    vr = VR_X_CMD;
    x0 = hw->x_origin;
    if (fmi2SetReal(sim.fmu, &vr, 1, &x0) != fmi2OK ||
        fmi2SetupExperiment(sim.fmu, fmi2False, 0.0, 0.0, fmi2False, 0.0) != fmi2OK ||
        fmi2EnterInitializationMode(sim.fmu) != fmi2OK ||
        fmi2ExitInitializationMode(sim.fmu) != fmi2OK) {
        /* the FMU's message names the parameter: "initialisation failed: parameter
         * delta_r8 = 0.01 is outside [-0.005, 0.005]" */
        fail(err, err_len, "%s", log_text[0] ? log_text : "the FMU refused to initialise");
        release();
        return -1;
    }
    sim.vr_x = VR_X_CMD;
    sim.vr_platen = (fmi2ValueReference)variable("platen_position");
    sim.vr_force = (fmi2ValueReference)variable("input_force");
    {
        fmi2ValueReference out[2] = {sim.vr_platen, sim.vr_force};
        double y[2];
        if (fmi2GetReal(sim.fmu, out, 2, y) != fmi2OK) {
            fail(err, err_len, "the FMU's outputs cannot be read: %s", log_text);
            release();
            return -1;
        }
        sim.platen = y[0];
        sim.force = y[1];
    }
    {
        uint64_t seed = hw->noise_seed;
        for (int i = 0; i < 4; i++) sim.rng[i] = splitmix64(&seed);
    }
    sim.ready = true;
    return 0;
}

void sim_rig_force_spike(double newtons, uint32_t samples) {
    sim.spike_n = newtons;
    sim.spike_samples = samples;
}

void sim_rig_stick_load(bool on) { sim.load_stuck = on; }
void sim_rig_stick_encoder(bool on) { sim.enc_stuck = on; }
void sim_rig_press_stop(bool pressed) { sim.stop_pressed = pressed; }
void sim_rig_board_fault(uint16_t bits, int32_t detail) {
    sim.board_faults = bits;
    sim.board_detail = detail;
}

void sim_rig_get_status(sim_rig_status *out) {
    out->hw_steps = sim.hw_steps;
    out->table_steps = sim.table_steps + emitted_by_tick(sim.burst_running);
    out->driver_enabled = sim.driver_enabled;
    out->reads = sim.reads;
    out->watchdog_kicks = sim.kicks;
    out->fmu_failures = sim.fmu_failures;
    out->time_s = sim.time_s;
    out->x = table_x(out->table_steps);
    out->platen_position = sim.platen;
    out->input_force = sim.force;
    out->arena_used = arena_used;
}

const char *sim_rig_last_message(void) { return log_text; }

/* ---- rig_hal.h ------------------------------------------------------------------------- */

void sim_rig_tick(void) {
    if (sim.hw.step_timing != SIM_RIG_STEPS_NUCLEO) return;
    sim.table_steps += sim.burst_running; /* it ended STEP_PHASE_US after the last tick */
    sim.burst_running = sim.burst_armed;
    sim.burst_armed = 0;
}

/* The pulses of a step command the table takes: drop_n of every drop_d are lost. */
static int32_t taken(int32_t delta) {
    if (sim.hw.drop_d == 0u || sim.hw.drop_n == 0u) return delta;
    uint32_t size = delta < 0 ? (uint32_t)0 - (uint32_t)delta : (uint32_t)delta;
    sim.drop_acc += (uint64_t)size * sim.hw.drop_n;
    int32_t lost = (int32_t)(sim.drop_acc / sim.hw.drop_d);
    sim.drop_acc %= sim.hw.drop_d;
    return delta < 0 ? delta + lost : delta - lost;
}

void hal_step(int32_t delta) {
    sim.hw_steps += delta;
    delta = taken(delta);
    if (sim.hw.step_timing == SIM_RIG_STEPS_NUCLEO) {
        sim.burst_armed += delta; /* one hal_step per tick: the burst of this period */
    } else {
        sim.table_steps += delta; /* no pulses: the move is at once */
    }
}

int32_t hal_step_halt(void) {
    /* the pulses not emitted at this tick's instant: the rest of the running burst and the
     * armed one (at once: none) */
    int32_t done = emitted_by_tick(sim.burst_running);
    int32_t left = sim.burst_running - done + sim.burst_armed;
    sim.table_steps += done;
    sim.hw_steps -= left;
    sim.burst_running = sim.burst_armed = 0;
    return left;
}

void hal_driver_enable(bool on) { sim.driver_enabled = on; }

bool hal_driver_powered(void) { return true; } /* no stop chain simulated */

void hal_watchdog_kick(void) { sim.kicks++; }

void hal_read(rig_inputs *in) {
    double x = table_x(sim.table_steps + emitted_by_tick(sim.burst_running));
    memset(in, 0, sizeof *in);
    if (!sim.ready) return;
    /* the plant: one FMU step of the period toward the table's position */
    {
        fmi2ValueReference out[2] = {sim.vr_platen, sim.vr_force};
        double y[2];
        if (fmi2SetReal(sim.fmu, &sim.vr_x, 1, &x) == fmi2OK &&
            fmi2DoStep(sim.fmu, sim.time_s, sim.hw.period_s, fmi2True) == fmi2OK &&
            fmi2GetReal(sim.fmu, out, 2, y) == fmi2OK) {
            sim.platen = y[0];
            sim.force = y[1];
        } else {
            sim.fmu_failures++; /* the mechanism does not follow: it stays as it was */
        }
    }
    sim.reads++;
    sim.time_s = sim.reads * sim.hw.period_s;
    if (!sim.have_zero) {
        sim.platen_zero = sim.platen;
        sim.have_zero = true;
    }
    /* the sensors: hil.emulators.rig_hardware.Sensors.read */
    double force = sim.force;
    if (sim.spike_samples > 0) {
        force += sim.spike_n;
        sim.spike_samples--;
    }
    double sign = sim.hw.enc_sign < 0 ? -1.0 : 1.0;
    int32_t enc = round_clamped(sign * nearbyint((sim.platen - sim.platen_zero) / SIM_RIG_ENC_M),
                                (double)INT32_MIN, (double)INT32_MAX);
    double noisy = force + gauss() * sim.hw.load_noise_n;
    int32_t raw = round_clamped((double)sim.hw.load_offset + noisy / sim.hw.load_gain_n,
                                ADC_MIN, ADC_MAX);
    if (sim.have_last) {
        if (sim.enc_stuck) enc = sim.last_enc;
        if (sim.load_stuck) raw = sim.last_raw;
    }
    sim.last_enc = enc;
    sim.last_raw = raw;
    sim.have_last = true;
    in->enc = enc;
    in->load_raw = raw;
    in->home_switch = x <= sim.hw.home_x + HOME_TOLERANCE_M;
    in->stop_input = sim.stop_pressed;
    in->driver_alarm = false;
    in->board_faults = sim.board_faults;
    in->board_detail = sim.board_detail;
}

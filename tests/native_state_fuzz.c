/* State fuzzer of the native FMU (tests/test_native_state_fuzz.py), built with ASan and
 * UBSan from the FMU's own sources/ (fmi2_clamp.c, clamp_core.c, ...).
 *
 * usage: native_state_fuzz ITERATIONS SEED
 *
 * It takes genuine serialised states of Co-Simulation instances in every phase
 * (instantiated, initialising, failed initialisation, stepping with and without motion,
 * mold and unequal halves, a 20 Hz lag and the ideal drive, input derivatives pending,
 * terminated) and of a Model Exchange instance (built from the CS+ME sources), then forges ITERATIONS states from them: random field values (NaN, inf,
 * huge, negative, nearby), enums out of range, wrong phases, bit flips, truncated or
 * extended buffers, all with the checksum recomputed (but for a few), and feeds each to
 * fmi2DeSerializeFMUstate and fmi2SetFMUstate. The criterion, checked for each:
 *   - refused: fmi2Error, and the instance is unchanged (its outputs bit for bit);
 *   - restored: every output finite; then, in Step Mode (after exitInitializationMode
 *     for a state before initialisation, which may fail with fmi2Error), 100 steps:
 *     Co-Simulation steps of 1 ms holding x_cmd where the state left it, Model Exchange
 *     explicit Euler steps of 20 us with x_cmd where the drive stands; each returns
 *     fmi2OK or fmi2Error (a command the restored motion cannot follow is rejected, as
 *     for any instance), and every output stays finite after each;
 *   - the unmodified states restore and step 100 times without an error.
 * Prints "refused R restored S stepped K steps_ok N steps_rejected E" and exits 0, or
 * prints the violation and exits 1. Crashes and sanitizer reports fail the test.
 */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"
#include "clamp_core.h"

static void quiet(fmi2ComponentEnvironment env, fmi2String name, fmi2Status status,
                  fmi2String category, fmi2String message, ...) {
    (void)env; (void)name; (void)status; (void)category; (void)message;
}

static uint64_t rng_state;
static uint64_t next_u64(void) { /* xorshift64* */
    rng_state ^= rng_state >> 12; rng_state ^= rng_state << 25; rng_state ^= rng_state >> 27;
    return rng_state * 2685821657736338717ull;
}
static unsigned below(unsigned n) { return (unsigned)(next_u64() % n); }
static double uniform(void) { return (next_u64() >> 11) * (1.0 / 9007199254740992.0); }

static uint64_t fnv(const unsigned char *p) {
    uint64_t h = 1469598103934665603ull;
    for (size_t i = 0; i < offsetof(CoreState, checksum); i++) h = (h ^ p[i]) * 1099511628211ull;
    return h;
}

#define FAIL(...) do { printf(__VA_ARGS__); printf("\n"); exit(1); } while (0)
#define MAX_BASES 32
#define ME_H 2e-5 /* s: explicit Euler step of the Model Exchange runs (the slip law is stiff) */
static unsigned char bases[MAX_BASES][sizeof(CoreState)];
static int base_me[MAX_BASES], n_bases;

static void keep(fmi2Component c) {
    fmi2FMUstate st = NULL;
    size_t size = 0;
    if (fmi2GetFMUstate(c, &st) != fmi2OK || fmi2SerializedFMUstateSize(c, st, &size) != fmi2OK ||
        size != sizeof(CoreState) ||
        fmi2SerializeFMUstate(c, st, (fmi2Byte *)bases[n_bases], size) != fmi2OK)
        FAIL("could not save a base state");
    base_me[n_bases] = ((CoreState *)bases[n_bases])->me;
    n_bases++;
    fmi2FreeFMUstate(c, &st);
}

static fmi2ValueReference out_vr[CLAMP_N_OUT];
static void outputs(fmi2Component c, double y[CLAMP_N_OUT]) {
    if (fmi2GetReal(c, out_vr, CLAMP_N_OUT, y) != fmi2OK) FAIL("getReal of the outputs failed");
    for (int i = 0; i < CLAMP_N_OUT; i++)
        if (!isfinite(y[i])) FAIL("output %s = %g", CLAMP_NAMES[VR_OUT0 + i], y[i]);
}

static void set(fmi2Component c, fmi2ValueReference vr, double v) {
    if (fmi2SetReal(c, &vr, 1, &v) != fmi2OK) FAIL("setReal %s failed", CLAMP_NAMES[vr]);
}

static double x_cmd_now(fmi2Component c) {
    fmi2ValueReference vr = VR_X_CMD;
    double v;
    if (fmi2GetReal(c, &vr, 1, &v) != fmi2OK) FAIL("getReal x_cmd failed");
    return v;
}

/* Genuine states of an instance with these parameters, in every phase. */
static void collect(const fmi2CallbackFunctions *cb, double x_contact, double delta_r8,
                    double bandwidth, int with_derivatives) {
    fmi2Component c = fmi2Instantiate("base", fmi2CoSimulation, CLAMP_GUID, "", cb, 0, 0);
    double x0 = CLAMP_START[VR_X_CMD], y[CLAMP_N_OUT];
    if (!c) FAIL("instantiate failed");
    keep(c);                                                    /* instantiated */
    fmi2SetupExperiment(c, 0, 0, 0, 0, 0);
    fmi2EnterInitializationMode(c);
    set(c, VR_X_CONTACT, x_contact);
    set(c, VR_DELTA0 + CLAMP_N_DIMS + 6, delta_r8);             /* delta_r8: link 8 (r5 of upper) */
    set(c, VR_BANDWIDTH, bandwidth);
    keep(c);                                                    /* initialising, stale */
    outputs(c, y);
    keep(c);                                                    /* initialising, outputs */
    if (fmi2ExitInitializationMode(c) != fmi2OK) FAIL("base initialisation failed");
    keep(c);                                                    /* stepping, at rest */
    double x_top = x_contact + 1e-3 < CLAMP_MAX[VR_X_CONTACT] ? x_contact + 5e-4
                                                               : CLAMP_MAX[VR_X_CONTACT] - 1e-3;
    for (int k = 1; k <= 400; k++) {
        double s = k / 400.0, x = x0 + (x_top - x0) * s * s * s * (10 - 15 * s + 6 * s * s);
        set(c, VR_X_CMD, x);
        if (with_derivatives) {
            fmi2ValueReference vr[2] = {VR_X_CMD, VR_X_CMD};
            fmi2Integer order[2] = {1, 2};
            double ds = 1 / 0.4, d[2] = {(x_top - x0) * 30 * s * s * (1 - s) * (1 - s) * ds,
                                         (x_top - x0) * 60 * s * (1 - s) * (1 - 2 * s) * ds * ds};
            if (fmi2SetRealInputDerivatives(c, vr, 2, order, d) != fmi2OK) FAIL("derivatives");
        }
        if (fmi2DoStep(c, (k - 1) * 1e-3, 1e-3, 1) != fmi2OK) FAIL("base step %d failed", k);
        if (k == 150 || k == 399) keep(c);                      /* stepping, moving / at mold */
    }
    if (with_derivatives) {
        fmi2ValueReference vr = VR_X_CMD;
        fmi2Integer order = 1;
        double d = 0.0;
        fmi2SetRealInputDerivatives(c, &vr, 1, &order, &d);
        keep(c);                                                /* derivatives pending */
    }
    set(c, VR_X_CMD, 0.5);
    if (fmi2DoStep(c, 0.4, 1e-3, 1) != fmi2Error) FAIL("a step to 0.5 m was accepted");
    keep(c);                                                    /* x_cmd outside the range */
    fmi2Terminate(c);
    keep(c);                                                    /* terminated */
    fmi2FreeInstance(c);
}

static void failed_base(const fmi2CallbackFunctions *cb) {
    fmi2Component c = fmi2Instantiate("failed", fmi2CoSimulation, CLAMP_GUID, "", cb, 0, 0);
    fmi2EnterInitializationMode(c);
    set(c, VR_MASS0 + 2, -3.0);                                 /* m_platen */
    if (fmi2ExitInitializationMode(c) != fmi2Error) FAIL("m_platen = -3 was accepted");
    keep(c);                                                    /* failed initialisation */
    fmi2FreeInstance(c);
}

/* One explicit Euler step of a Model Exchange instance with x_cmd set to u. */
static fmi2Status euler(fmi2Component c, double t, double u) {
    fmi2ValueReference vr = VR_X_CMD;
    double x[CORE_N_STATES], dx[CORE_N_STATES];
    fmi2Status st = fmi2SetTime(c, t);
    if (st == fmi2OK) st = fmi2SetReal(c, &vr, 1, &u);
    if (st == fmi2OK) st = fmi2GetContinuousStates(c, x, CORE_N_STATES);
    if (st == fmi2OK) st = fmi2GetDerivatives(c, dx, CORE_N_STATES);
    for (int i = 0; st == fmi2OK && i < CORE_N_STATES; i++) x[i] += ME_H * dx[i];
    if (st == fmi2OK) st = fmi2SetContinuousStates(c, x, CORE_N_STATES);
    return st;
}

/* Genuine states of a Model Exchange instance, in every phase. */
static void collect_me(const fmi2CallbackFunctions *cb, double x_contact) {
    fmi2Component c = fmi2Instantiate("me", fmi2ModelExchange, CLAMP_GUID, "", cb, 0, 0);
    double x0 = CLAMP_START[VR_X_CMD], y[CLAMP_N_OUT];
    if (!c) FAIL("instantiate (Model Exchange) failed");
    keep(c);
    fmi2SetupExperiment(c, 0, 0, 0, 0, 0);
    fmi2EnterInitializationMode(c);
    set(c, VR_X_CONTACT, x_contact);
    set(c, VR_DELTA0 + CLAMP_N_DIMS + 6, 0.5e-3);
    set(c, VR_BANDWIDTH, 20.0);
    keep(c);
    outputs(c, y);
    keep(c);
    if (fmi2ExitInitializationMode(c) != fmi2OK) FAIL("ME base initialisation failed");
    keep(c);
    for (int k = 1; k <= 20000; k++) {
        double s = k / 20000.0, u = x0 + (x_contact + 5e-4 - x0) * s * s * (3 - 2 * s);
        if (euler(c, k * ME_H, u) != fmi2OK) FAIL("ME base step %d failed", k);
        if (k == 8000 || k == 20000) { outputs(c, y); keep(c); }
    }
    fmi2Terminate(c);
    keep(c);
    fmi2FreeInstance(c);
}

static const double SPECIAL[] = {NAN, INFINITY, -INFINITY, 1e308, -1e308, -3.0, 0.0, -0.0,
                                 1e-300, 5e-3, -5e-3, 0.09, 1.0, 11.0, 2e4};

static void mutate_double(unsigned char *b) {
    size_t first = offsetof(CoreState, time), n = (offsetof(CoreState, checksum) - first) / 8;
    double *slot = (double *)(b + first) + below((unsigned)n), v = *slot;
    switch (below(4)) {
    case 0: *slot = SPECIAL[below(sizeof SPECIAL / sizeof SPECIAL[0])]; break;
    case 1: *slot = v * (1 + (uniform() - 0.5) * 1e-6) + (below(2) ? 0 : 1e-12); break;
    case 2: *slot = -v; break;
    default: *slot = (uniform() - 0.5) * pow(10, below(12) - 6.0); break;
    }
}

static void mutate_int(unsigned char *b) {
    static const int32_t values[] = {-1, 0, 1, 2, 3, 4, 5, 6, 7, INT32_MAX, INT32_MIN, 255};
    int32_t *slot = (int32_t *)b + below(offsetof(CoreState, time) / 4);
    *slot = below(4) ? values[below(sizeof values / sizeof values[0])] : (int32_t)next_u64();
}

int main(int argc, char **argv) {
    if (argc != 3) return 2;
    long iterations = atol(argv[1]);
    rng_state = strtoull(argv[2], NULL, 10) * 2654435761u + 1;
    fmi2CallbackFunctions cb = {quiet, calloc, free, NULL, NULL};
    for (int i = 0; i < CLAMP_N_OUT; i++) out_vr[i] = VR_OUT0 + i;
    double toggle = CLAMP_MAX[VR_X_CONTACT];
    collect(&cb, toggle - 1e-3, 0.5e-3, 20.0, 0);   /* mold, unequal halves, 20 Hz lag */
    collect(&cb, toggle, 0.0, 0.0, 1);              /* no mold, equal, ideal, derivatives */
    failed_base(&cb);
    int first_me = n_bases;
    collect_me(&cb, toggle - 1e-3);                 /* mold, unequal halves, 20 Hz lag */
    int n_genuine = n_bases;

    fmi2Component inst[2] = {
        fmi2Instantiate("fuzz", fmi2CoSimulation, CLAMP_GUID, "", &cb, 0, 0),
        fmi2Instantiate("fuzz-me", fmi2ModelExchange, CLAMP_GUID, "", &cb, 0, 0)};
    fmi2FMUstate home[2] = {NULL, NULL};
    for (int me = 0; me < 2; me++)  /* a stepping state of each interface */
        if (!inst[me] || fmi2DeSerializeFMUstate(inst[me], (fmi2Byte *)bases[me ? first_me + 4 : 4],
                                                 sizeof(CoreState), &home[me]) != fmi2OK)
            FAIL("a genuine stepping state was refused");
    long refused = 0, restored = 0, stepped = 0, steps_ok = 0, steps_rejected = 0;
    unsigned char forged[sizeof(CoreState) + 16];
    for (long it = 0; it < iterations; it++) {
        int base = (int)below((unsigned)n_genuine), kind = (int)below(16);
        size_t size = sizeof(CoreState);
        memcpy(forged, bases[base], sizeof(CoreState));
        if (kind <= 6) mutate_double(forged);
        else if (kind <= 8) mutate_int(forged);
        else if (kind == 9) ((int32_t *)forged)[2] = (int32_t)below(PHASE_COUNT);  /* phase */
        else if (kind == 10) {
            int bits = 1 + (int)below(8);
            for (int k = 0; k < bits; k++) {
                size_t at = below(offsetof(CoreState, checksum));
                forged[at] ^= (unsigned char)(1u << below(8));
            }
        } else if (kind == 11) size = below(sizeof forged);           /* truncated / extended */
        else if (kind <= 13)
            for (int k = 0, n = 2 + (int)below(4); k < n; k++)
                (below(3) ? mutate_double : mutate_int)(forged);
        /* kind 14, 15: unmodified */
        if (below(50)) {  /* the checksum recomputed (but for a few) */
            uint64_t sum = fnv(forged);
            memcpy(forged + offsetof(CoreState, checksum), &sum, sizeof sum);
        }
        int genuine = kind >= 14, me = base_me[base];
        fmi2Component c = inst[me];
        if (fmi2SetFMUstate(c, home[me]) != fmi2OK) FAIL("the home state was refused");
        double before[CLAMP_N_OUT], after[CLAMP_N_OUT];
        outputs(c, before);
        fmi2FMUstate st = NULL;
        fmi2Status status = fmi2DeSerializeFMUstate(c, (fmi2Byte *)forged, size, &st);
        if (status == fmi2OK) status = fmi2SetFMUstate(c, st);
        if (status != fmi2OK) {
            if (status != fmi2Error) FAIL("iteration %ld: status %d", it, status);
            if (genuine) FAIL("iteration %ld: genuine base %d refused", it, base);
            outputs(c, after);
            if (memcmp(before, after, sizeof before)) FAIL("iteration %ld: refused but changed", it);
            refused++;
            fmi2FreeFMUstate(c, &st);
            continue;
        }
        restored++;
        fmi2FreeFMUstate(c, &st);
        CoreState s;
        memcpy(&s, forged, sizeof s);
        double hold = 0.0;
        if (me && s.initialised) {  /* a master sets the input before it reads outputs */
            double x[CORE_N_STATES];
            fmi2ValueReference vr = VR_X_CMD;
            if (fmi2GetContinuousStates(c, x, CORE_N_STATES) != fmi2OK) FAIL("getStates");
            hold = x[0];
            fmi2SetReal(c, &vr, 1, &hold);
        }
        if (s.phase == PHASE_STEPPING || s.phase == PHASE_TERMINATED) outputs(c, after);
        if (s.phase == PHASE_INSTANTIATED) fmi2EnterInitializationMode(c);
        if (s.phase <= PHASE_FAILED) {
            fmi2Status init = fmi2ExitInitializationMode(c);
            if (init != fmi2OK && init != fmi2Error) FAIL("iteration %ld: init status %d", it, init);
            if (init == fmi2Error) {
                if (genuine && base != first_me - 1) FAIL("genuine base %d did not initialise", base);
                continue;
            }
        }
        if (me && !s.initialised) {  /* initialised just now: x_cmd where the drive stands */
            fmi2ValueReference x_vr = VR_OUT0;
            if (fmi2GetReal(c, &x_vr, 1, &hold) != fmi2OK) FAIL("getReal x");
        }
        outputs(c, after);
        if (!me) hold = x_cmd_now(c);  /* Co-Simulation: x_cmd where the state left it */
        int all_ok = 1;
        for (int k = 0; k < 100; k++) {
            fmi2Status st_step;
            if (me) st_step = euler(c, k * ME_H, hold);
            else {
                fmi2ValueReference vr = VR_X_CMD;
                fmi2SetReal(c, &vr, 1, &hold);
                st_step = fmi2DoStep(c, k * 1e-3, 1e-3, 1);
            }
            if (st_step == fmi2OK) steps_ok++;
            else if (st_step == fmi2Error) { steps_rejected++; all_ok = 0; }
            else FAIL("iteration %ld: step status %d", it, st_step);
            outputs(c, after);
        }
        if (genuine && !all_ok && s.phase != PHASE_TERMINATED &&
            !(s.r[VR_X_CMD] > s.x_hi && s.initialised))
            FAIL("iteration %ld: genuine base %d rejected a step", it, base);
        stepped += all_ok;
    }
    for (int me = 0; me < 2; me++) {
        fmi2FreeFMUstate(inst[me], &home[me]);
        fmi2FreeInstance(inst[me]);
    }
    printf("refused %ld restored %ld stepped %ld steps_ok %ld steps_rejected %ld\n", refused,
           restored, stepped, steps_ok, steps_rejected);
    return 0;
}

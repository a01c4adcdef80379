/* The toggle clamp's native core (see clamp_core.h): messages, the instance's life
 * (instantiation, initialisation, termination) and its variables. The initialisation's
 * work is clamp_init.c, the motion clamp_motion.c, saved states clamp_state.c. */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <string.h>

#include "clamp_core_internal.h"

const char *const CORE_CATEGORIES[] = {"logStatusError", "logAll"};
#define N_CATEGORIES 2

void core_say(Core *c, int error, const char *fmt, ...) {
    char msg[1024];
    va_list ap;
    if (!c->log || (!error && !c->logging)) return;
    va_start(ap, fmt);
    vsnprintf(msg, sizeof msg, fmt, ap);
    va_end(ap);
    c->log(c->log_env, error, msg);
}

void core_init(Core *c, int me, CoreLog log, void *log_env, int logging) {
    memset(c, 0, sizeof *c);
    c->log = log; c->log_env = log_env; c->logging = logging;
    c->s.me = me;
    core_reset(c);
}

void core_reset(Core *c) {
    int me = c->s.me;
    memset(&c->s, 0, sizeof c->s);
    c->s.version = CORE_STATE_VERSION;
    c->s.size = sizeof(CoreState);
    c->s.me = me;
    memcpy(c->s.r, CLAMP_START, sizeof c->s.r);
    c->s.phase = PHASE_INSTANTIATED;
    c->stale = 1;
    c->failure[0] = '\0';
}

int core_enter_initialisation(Core *c) {
    if (c->s.phase != PHASE_INSTANTIATED) {
        core_say(c, 1, "enterInitializationMode: only after instantiation or reset");
        return CORE_ERROR;
    }
    c->s.phase = PHASE_INITIALISING;
    return CORE_OK;
}

int core_exit_initialisation(Core *c) {
    if (c->s.phase != PHASE_INITIALISING && c->s.phase != PHASE_FAILED) {
        core_say(c, 1, "exitInitializationMode: not in Initialization Mode");
        return CORE_ERROR;
    }
    CoreState n = c->s;
    if (!core_initial_state(c, &n)) {
        c->s.phase = PHASE_FAILED;  /* set valid values and exit again, or reset */
        core_say(c, 1, "initialisation failed: %s", c->failure);
        return CORE_ERROR;
    }
    c->s = n;
    c->s.phase = PHASE_STEPPING;
    c->stale = 0;
    return CORE_OK;
}

int core_terminate(Core *c) {
    c->s.phase = PHASE_TERMINATED;
    return CORE_OK;
}

int core_set_debug_logging(Core *c, int on, size_t n, const char *const categories[]) {
    for (size_t i = 0; i < n; i++) {
        int known = 0;
        for (int k = 0; k < N_CATEGORIES; k++)
            known |= categories[i] && strcmp(categories[i], CORE_CATEGORIES[k]) == 0;
        if (!known) {
            core_say(c, 1, "setDebugLogging: unknown log category \"%s\"; this FMU has "
                     "logStatusError and logAll", categories[i] ? categories[i] : "(null)");
            return CORE_ERROR;
        }
    }
    c->logging = on;
    return CORE_OK;
}

int core_set_input_derivative(Core *c, unsigned vr, int order, double value) {
    if (vr != VR_X_CMD || order < 1 || order > 2 || !isfinite(value)) {
        core_say(c, 1, "setRealInputDerivatives: only x_cmd (value reference %d) has "
                 "derivatives, of order 1 or 2 and finite; got value reference %u, order %d, "
                 "value %.6g", VR_X_CMD, vr, order, value);
        return CORE_ERROR;
    }
    if (c->s.phase == PHASE_TERMINATED) {
        core_say(c, 1, "setRealInputDerivatives: terminated");
        return CORE_ERROR;
    }
    c->s.der_given[order - 1] = 1;
    c->s.der[order - 1] = value;
    return CORE_OK;
}

/* ---- variables ----------------------------------------------------------------------------- */

/* Outputs of a Model Exchange instance at its states and input, if not current. */
static int me_outputs(Core *c) {
    CoreState *s = &c->s;
    double y[CLAMP_N_OUT];
    if (!c->stale || s->phase != PHASE_STEPPING) return 1;
    if (!isfinite(s->r[VR_X_CMD])) {
        core_say(c, 1, "input x_cmd = %.6g m is not finite", s->r[VR_X_CMD]);
        return 0;
    }
    double a = core_lag_acceleration(s), xvaz[4] = {s->drive[0], s->drive[1], a, s->slip[1]};
    if (!core_plant(c, s, xvaz, y)) {
        core_say(c, 1, "no finite plant solution at x = %.6g m", s->drive[0]);
        return 0;
    }
    s->drive[2] = a;
    memcpy(&s->r[VR_OUT0], y, sizeof y);
    c->stale = 0;
    return 1;
}

int core_get_real(Core *c, const unsigned vr[], size_t n, double value[]) {
    CoreState *s = &c->s;
    int init_mode = s->phase == PHASE_INITIALISING || s->phase == PHASE_FAILED;
    for (size_t i = 0; i < n; i++)
        if (vr[i] >= CORE_N_REAL || (vr[i] >= CLAMP_N_REAL && !CLAMP_HAS_ME)) {
            core_say(c, 1, "getReal: unknown value reference %u", vr[i]);
            return CORE_ERROR;
        }
    if (init_mode && c->stale) {  /* outputs of the values set so far (InitialUnknowns) */
        CoreState n0 = *s;
        if (!core_initial_state(c, &n0)) {
            core_say(c, 1, "initialisation failed: %s", c->failure);
            return CORE_ERROR;
        }
        memcpy(&s->r[VR_OUT0], &n0.r[VR_OUT0], CLAMP_N_OUT * sizeof(double));
        c->stale = 0;
    }
    if (s->me && !me_outputs(c)) return CORE_ERROR;
    double v = s->drive[1];
    for (size_t i = 0; i < n; i++) {
        switch (vr[i]) {
        case VR_SLIP: value[i] = s->slip[1]; break;
        case VR_DER_X: value[i] = init_mode ? 0.0 : v; break;
        case VR_DER_V:
            value[i] = init_mode ? 0.0 : s->me ? core_lag_acceleration(s) : s->drive[2];
            break;
        case VR_DER_SLIP: value[i] = init_mode ? 0.0 : core_slip_rate(s->slip[1], v); break;
        default: value[i] = s->r[vr[i]];
        }
    }
    return CORE_OK;
}

int core_set_real(Core *c, const unsigned vr[], size_t n, const double value[]) {
    int before_init = c->s.phase == PHASE_INSTANTIATED || c->s.phase == PHASE_INITIALISING ||
                      c->s.phase == PHASE_FAILED;
    for (size_t i = 0; i < n; i++) {
        int ok = vr[i] < VR_OUT0 && (vr[i] == VR_X_CMD ? c->s.phase != PHASE_TERMINATED
                                                       : before_init);
        if (!ok) {
            core_say(c, 1, "setReal: %s (value reference %u) cannot be set %s",
                     vr[i] < CLAMP_N_REAL ? CLAMP_NAMES[vr[i]] : "unknown variable", vr[i],
                     vr[i] >= VR_OUT0 ? "(not a parameter or input)"
                     : c->s.phase == PHASE_TERMINATED ? "after terminate"
                     : "after initialisation (a fixed parameter)");
            return CORE_ERROR;
        }
    }
    for (size_t i = 0; i < n; i++) c->s.r[vr[i]] = value[i];
    if (n) c->stale = 1;
    return CORE_OK;
}

int core_get_string(Core *c, const unsigned vr[], size_t n, const char *value[]) {
    for (size_t i = 0; i < n; i++) {
        if (vr[i] != CLAMP_VR_PRESET) {
            core_say(c, 1, "getString: unknown value reference %u", vr[i]);
            return CORE_ERROR;
        }
        value[i] = CLAMP_PRESET;
    }
    return CORE_OK;
}

int core_set_string(Core *c, const unsigned vr[], size_t n, const char *const value[]) {
    for (size_t i = 0; i < n; i++)
        if (vr[i] != CLAMP_VR_PRESET || !value[i] || strcmp(value[i], CLAMP_PRESET) != 0) {
            core_say(c, 1, "parameter preset: this FMU is built for '%s', not '%s'; build one "
                     "with toggle build-fmu --native --preset", CLAMP_PRESET,
                     value[i] ? value[i] : "");
            return CORE_ERROR;
        }
    return CORE_OK;
}

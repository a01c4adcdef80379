/* The native core's saved states (see clamp_core.h): a copy of the instance's sealed with
 * its checksum, and the checks a state passes before it is restored. */
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "clamp_core_internal.h"

static uint64_t checksum(const CoreState *s) {
    const unsigned char *p = (const unsigned char *)s;
    uint64_t h = 1469598103934665603ull;
    for (size_t i = 0; i < offsetof(CoreState, checksum); i++) h = (h ^ p[i]) * 1099511628211ull;
    return h;
}

/* ---- saved states ------------------------------------------------------------------------- */

void core_save(const Core *c, CoreState *out) {
    *out = c->s;
    out->checksum = checksum(out);
}

/* Whether the bytes of s from offset `from` to offset `to` are all zero. */
static int zero_between(const CoreState *s, size_t from, size_t to) {
    const unsigned char *b = (const unsigned char *)s;
    for (size_t i = from; i < to; i++)
        if (b[i]) return 0;
    return 1;
}

static int all_finite(const double *v, size_t n) {
    for (size_t i = 0; i < n; i++)
        if (!isfinite(v[i])) return 0;
    return 1;
}

/* Why s is not a state this instance could have handed out, or NULL. Uses c's work arrays
 * and caches only. */
static const char *state_problem(Core *c, const CoreState *s) {
    if (s->version != CORE_STATE_VERSION || s->size != sizeof(CoreState) ||
        s->checksum != checksum(s))
        return "not a state of this FMU (version, size or checksum)";
    if (!(s->phase >= 0 && s->phase < PHASE_COUNT)) return "unknown phase";
    if (s->me != c->s.me) return "taken in the other interface (Model Exchange / Co-Simulation)";
    if ((s->initialised != 0 && s->initialised != 1) || s->spare != 0 ||
        (s->mold != 0 && s->mold != 1) || (s->unequal != 0 && s->unequal != 1))
        return "a flag out of range";
    for (int k = 0; k < 2; k++)
        if ((s->der_given[k] != 0 && s->der_given[k] != 1) || !isfinite(s->der[k]) ||
            (!s->der_given[k] && s->der[k] != 0))
            return "x_cmd's derivatives invalid";
    if (!all_finite(&s->r[VR_OUT0], CLAMP_N_OUT)) return "a non-finite output";
    if (!isfinite(s->time)) return "a non-finite time";
    if (!s->initialised) {  /* the values set so far, checked when initialisation ends */
        if (s->phase == PHASE_STEPPING) return "a stepping state without initialisation";
        if (s->mold || s->unequal || !zero_between(s, offsetof(CoreState, drive), offsetof(CoreState, der)) ||
            !zero_between(s, offsetof(CoreState, dims), offsetof(CoreState, checksum)))
            return "data of an initialisation in a state before it";
        return NULL;
    }
    if (s->phase != PHASE_STEPPING && s->phase != PHASE_TERMINATED)
        return "initialised data in a state before initialisation";
    if (!core_in_ranges(c, s->r, 0)) return c->failure;
    int unequal = 0, cheap = s->mu == s->r[VR_MU];  /* what needs no toggle search, first */
    for (int i = 0; i < CLAMP_N_MASSES; i++) cheap &= s->masses[i] == s->r[VR_MASS0 + i];
    for (int i = 0; i < 2 * CLAMP_N_DIMS; i++)
        cheap &= s->dims[i] == CLAMP_NOMINAL[i] + s->r[VR_DELTA0 + i];
    for (int i = 0; i < CLAMP_N_DIMS; i++) unequal |= s->dims[i] != s->dims[CLAMP_N_DIMS + i];
    if (!cheap || unequal != s->unequal)
        return "derived data (dimensions, masses, friction) not those of its parameters";
    CoreState d = *s;
    if (!core_derive(c, s->r, &d)) return c->failure;
    if (d.mold != s->mold || d.unequal != s->unequal || d.mu != s->mu || d.x_lo != s->x_lo ||
        d.x_hi != s->x_hi || memcmp(d.dims, s->dims, sizeof d.dims) != 0 ||
        memcmp(d.masses, s->masses, sizeof d.masses) != 0)
        return "derived data (dimensions, masses, friction, range, mold) not those of its "
               "parameters";
    const double *dr = s->drive;
    if (!all_finite(dr, 7) || !all_finite(s->slip, 2)) return "a non-finite drive or slip state";
    if (!(s->x_lo <= dr[0] && dr[0] <= s->x_hi) || !(s->x_lo <= dr[3] && dr[3] <= s->x_hi))
        return "a drive position outside the assemblable range";
    if (!(dr[5] >= 0) || !(dr[6] >= 0) || s->slip[0] != dr[0] || !(fabs(s->slip[1]) <= 1))
        return "an invalid step, slip position or slip state (|z| <= 1)";
    if (!(fabs(dr[1]) <= MAX_SPEED)) return "a drive velocity beyond 10 m/s";
    if (s->me) return NULL;  /* outputs follow the states and x_cmd; recomputed when read */
    if (!(fabs(dr[2]) <= MAX_ACCELERATION)) return "a drive acceleration beyond 10000 m/s^2";
    double y[CLAMP_N_OUT], xvaz[4] = {dr[0], dr[1], dr[2], s->slip[1]};
    if (!core_plant(c, s, xvaz, y) || memcmp(y, &s->r[VR_OUT0], sizeof y) != 0)
        return "outputs that are not the plant's at the state's motion";
    return NULL;
}

int core_check_state(Core *c, const CoreState *s, const char *who) {
    const char *problem = state_problem(c, s);
    if (problem) {
        core_say(c, 1, "%s: state refused: %s", who, problem);
        return CORE_ERROR;
    }
    return CORE_OK;
}

int core_restore(Core *c, const CoreState *s, const char *who) {
    char failure[sizeof c->failure];
    memcpy(failure, c->failure, sizeof failure);
    if (core_check_state(c, s, who) != CORE_OK) {
        memcpy(c->failure, failure, sizeof failure);
        return CORE_ERROR;
    }
    c->s = *s;
    c->stale = 1;
    snprintf(c->failure, sizeof c->failure, "(a restored state's initialisation had failed; set "
             "the parameters and exit Initialization Mode again)");
    if (s->phase != PHASE_FAILED) memcpy(c->failure, failure, sizeof failure);
    return CORE_OK;
}

int core_read_state(Core *c, const void *bytes, size_t size, CoreState *out, const char *who) {
    if (size != sizeof(CoreState)) {
        core_say(c, 1, "%s: state refused: %zu bytes, a state has %zu", who, size,
                 sizeof(CoreState));
        return CORE_ERROR;
    }
    memcpy(out, bytes, sizeof *out);
    char failure[sizeof c->failure];
    memcpy(failure, c->failure, sizeof failure);
    int status = core_check_state(c, out, who);
    memcpy(c->failure, failure, sizeof failure);
    return status;
}

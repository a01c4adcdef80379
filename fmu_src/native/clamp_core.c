/* The toggle clamp's native core: see clamp_core.h. */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <string.h>

#include "clamp_core.h"
#include "drive_lag.h"

#define GRID 4001
#define N_IN 6
#define PI 3.14159265358979323846
/* Bounds of a commanded motion (toggle.plant.MAX_INPUT_SPEED, MAX_INPUT_ACCELERATION). */
#define MAX_SPEED 10.0
#define MAX_ACCELERATION 1e4

const char *const CORE_CATEGORIES[] = {"logStatusError", "logAll"};
#define N_CATEGORIES 2

typedef int (*PlantFn)(const double **, double **, casadi_int *, double *, int);

void core_say(Core *c, int error, const char *fmt, ...) {
    char msg[1024];
    va_list ap;
    if (!c->log || (!error && !c->logging)) return;
    va_start(ap, fmt);
    vsnprintf(msg, sizeof msg, fmt, ap);
    va_end(ap);
    c->log(c->log_env, error, msg);
}

static uint64_t checksum(const CoreState *s) {
    const unsigned char *p = (const unsigned char *)s;
    uint64_t h = 1469598103934665603ull;
    for (size_t i = 0; i < offsetof(CoreState, checksum); i++) h = (h ^ p[i]) * 1099511628211ull;
    return h;
}

/* ---- the generated plant ---------------------------------------------------------------- */

static void evaluate(Core *c, PlantFn f, const double **in, int n_in, double *y) {
    for (int i = 0; i < n_in; i++) c->arg[i] = in[i];
    c->res[0] = y;
    f(c->arg, c->res, c->iw, c->w, 0);
}

/* Outputs at xvaz (position, velocity, acceleration, slip state) for the derived data of
 * s; 0 unless all finite. The variant is chosen by tests, never by indexing with data. */
static int plant(Core *c, const CoreState *s, const double xvaz[4], double y[CLAMP_N_OUT]) {
    const double *in[N_IN] = {xvaz, s->dims, s->dims + CLAMP_N_DIMS, &s->mu, s->masses,
                              &s->r[VR_X_CONTACT]};
    PlantFn f = s->mold ? (s->unequal ? tgc_mold_unequal : tgc_mold_equal)
                        : (s->unequal ? tgc_free_unequal : tgc_free_equal);
    evaluate(c, f, in, N_IN, y);
    for (int i = 0; i < CLAMP_N_OUT; i++)
        if (!isfinite(y[i])) return 0;
    return 1;
}

static void geometry(Core *c, double x, const double *dims, double g[2]) {
    const double *in[2] = {&x, dims};
    evaluate(c, tgc_geometry, in, 2, g);
}

static double grid_x(double reach, int k) { return -reach + 2 * reach * k / (GRID - 1); }

/* The toggle (first root of theta4 - target) and the assemblable range around it, as
 * toggle.kinematics does: a 4001-point scan, roots and edges refined by bisection. Without
 * a toggle: 0, and [lo, hi] the first and last assemblable grid points (if any). */
static int half_limits(Core *c, const double *dims, double *x_tp, double *lo, double *hi) {
    double reach = dims[2] + dims[3], g[2], prev_x = 0, prev_f = 0;
    int have_prev = 0, found = 0, k_tp = 0, first = -1, last = -1;
    for (int k = 0; k < GRID && !found; k++) {
        double x = grid_x(reach, k);
        geometry(c, x, dims, g);
        if (!isfinite(g[0]) || !isfinite(g[1])) continue;
        if (first < 0) first = k;
        last = k;
        if (have_prev && (prev_f < 0) != (g[1] < 0) && prev_f != 0 && g[1] != 0) {
            double a = prev_x, b = x, fa = prev_f;
            for (int i = 0; i < 200 && b - a > 1e-16; i++) {
                double m = 0.5 * (a + b);
                geometry(c, m, dims, g);
                if ((g[1] < 0) == (fa < 0)) { a = m; fa = g[1]; } else b = m;
            }
            *x_tp = 0.5 * (a + b);
            k_tp = k;
            found = 1;
        }
        prev_x = x; prev_f = g[1]; have_prev = 1;
    }
    if (!found) {
        *lo = first < 0 ? NAN : grid_x(reach, first);
        *hi = last < 0 ? NAN : grid_x(reach, last);
        return 0;
    }
    int klo = k_tp, khi = k_tp;
    while (klo > 0) {  /* the contiguous assemblable run of grid points around the toggle */
        geometry(c, grid_x(reach, klo - 1), dims, g);
        if (!isfinite(g[0])) break;
        klo--;
    }
    while (khi < GRID - 1) {
        geometry(c, grid_x(reach, khi + 1), dims, g);
        if (!isfinite(g[0])) break;
        khi++;
    }
    for (int side = 0; side < 2; side++) {
        int k = side ? khi : klo, edge = side ? GRID - 1 : 0;
        double good = grid_x(reach, k);
        if (k != edge) {
            double bad = grid_x(reach, side ? k + 1 : k - 1);
            while (fabs(bad - good) > 1e-12) {
                double mid = 0.5 * (good + bad);
                geometry(c, mid, dims, g);
                if (isfinite(g[0])) good = mid; else bad = mid;
            }
        }
        *(side ? hi : lo) = good;
    }
    return 1;
}

/* ---- parameters and initialisation ------------------------------------------------------- */

static const char *unit_text(int vr) { return strcmp(CLAMP_UNITS[vr], "1") ? CLAMP_UNITS[vr] : ""; }

/* Every Real parameter (and the input, if with_input) finite and within its min/max; the
 * message of the first that is not in c->failure (the pythonfmu build's words). */
static int in_ranges(Core *c, const double *r, int with_input) {
    for (int vr = 0; vr < VR_OUT0; vr++) {
        double v = r[vr];
        if (vr == VR_X_CMD && !with_input) continue;
        if (!(isfinite(v) && CLAMP_MIN[vr] <= v && v <= CLAMP_MAX[vr])) {
            const char *u = unit_text(vr), *sp = *u ? " " : "";
            snprintf(c->failure, sizeof c->failure, "%s %s = %.6g%s%s is outside [%g, %g]%s%s",
                     vr == VR_X_CMD ? "input" : "parameter", CLAMP_NAMES[vr], v, sp, u,
                     CLAMP_MIN[vr], CLAMP_MAX[vr], sp, u);
            return 0;
        }
    }
    return 1;
}

/* The dimensional errors in use, as toggle.plant.with_errors lists them. */
static void errors_text(const double *r, char *out, size_t size) {
    size_t used = 0;
    out[0] = '\0';
    for (int i = 0; i < 2 * CLAMP_N_DIMS && used < size; i++) {
        double d = r[VR_DELTA0 + i];
        if (d != 0)
            used += (size_t)snprintf(out + used, size - used, "%s%s = %.6g m", used ? ", " : "",
                                     CLAMP_NAMES[VR_DELTA0 + i], d);
    }
    if (!used) snprintf(out, size, "its nominal dimensions");
}

/* The data derived from the parameters r (in range): dims, mu, masses, mold, unequal and
 * the assemblable range, into d; cached for the last parameters. */
static int derive(Core *c, const double *r, CoreState *d) {
    static const char *const half_names[] = {"lower", "upper"};
    size_t key = VR_X_CMD * sizeof(double);  /* the parameters precede the input */
    for (int k = 0; k < CORE_DERIVED_CACHE; k++) {
        const CoreState *hit = &c->derived[k];
        if (!c->derived_valid[k] || memcmp(c->derived_key[k], r, key) != 0) continue;
        d->mold = hit->mold; d->unequal = hit->unequal;
        memcpy(d->dims, hit->dims, sizeof d->dims);
        d->mu = hit->mu;
        memcpy(d->masses, hit->masses, sizeof d->masses);
        d->x_lo = hit->x_lo; d->x_hi = hit->x_hi;
        return 1;
    }
    double tp[2], lo[2], hi[2];
    char errors[300];
    d->mu = r[VR_MU];
    for (int i = 0; i < CLAMP_N_MASSES; i++) d->masses[i] = r[VR_MASS0 + i];
    for (int i = 0; i < 2 * CLAMP_N_DIMS; i++) d->dims[i] = CLAMP_NOMINAL[i] + r[VR_DELTA0 + i];
    for (int h = 0; h < 2; h++) {
        const double *dim = d->dims + h * CLAMP_N_DIMS;
        if (!half_limits(c, dim, &tp[h], &lo[h], &hi[h])) {
            errors_text(r, errors, sizeof errors);
            if (isfinite(lo[h]))
                snprintf(c->failure, sizeof c->failure, "the %s half with %s: no toggle: links "
                         "4b and 5 never become collinear in the assemblable range [%.6g, "
                         "%.6g] m", half_names[h], errors, lo[h], hi[h]);
            else
                snprintf(c->failure, sizeof c->failure, "the %s half with %s: the half cannot "
                         "assemble at any input position", half_names[h], errors);
            return 0;
        }
    }
    d->unequal = 0;
    for (int i = 0; i < CLAMP_N_DIMS; i++) d->unequal |= d->dims[i] != d->dims[CLAMP_N_DIMS + i];
    d->x_lo = fmax(lo[0], lo[1]);
    d->x_hi = fmin(hi[0], hi[1]);
    double xc = r[VR_X_CONTACT];
    d->mold = !(xc >= tp[0] - CLAMP_NO_MOLD_TOLERANCE);  /* toggle.plant.configure's rule */
    if (d->mold && !(d->x_lo <= xc && xc <= d->x_hi)) {
        snprintf(c->failure, sizeof c->failure, "mold-contact position x_contact = %.6g m is "
                 "outside the assemblable range [%.6g, %.6g] m", xc, d->x_lo, d->x_hi);
        return 0;
    }
    int slot = c->derived_next;
    c->derived_next = (slot + 1) % CORE_DERIVED_CACHE;
    memcpy(c->derived_key[slot], r, key);
    c->derived[slot] = *d;
    c->derived_valid[slot] = 1;
    return 1;
}

/* The state after a successful initialisation from the values in n->r, into n. */
static int initial_state(Core *c, CoreState *n) {
    double y[CLAMP_N_OUT];
    if (!in_ranges(c, n->r, 1)) return 0;
    if (n->me && !(n->r[VR_BANDWIDTH] > 0)) {
        snprintf(c->failure, sizeof c->failure, "parameter drive_bandwidth = %.6g Hz: Model "
                 "Exchange needs drive_bandwidth > 0 Hz (the drive's lag is its continuous "
                 "state; the ideal drive has none)", n->r[VR_BANDWIDTH]);
        return 0;
    }
    if (!derive(c, n->r, n)) return 0;
    double x0 = n->r[VR_X_CMD], xvaz[4] = {x0, 0.0, 0.0, 0.0};
    if (!(n->x_lo <= x0 && x0 <= n->x_hi)) {
        snprintf(c->failure, sizeof c->failure, "input position x = %.6g m outside the "
                 "assemblable range [%.6g, %.6g] m", x0, n->x_lo, n->x_hi);
        return 0;
    }
    if (!plant(c, n, xvaz, y)) {
        snprintf(c->failure, sizeof c->failure, "no finite plant solution at x = %.6g m", x0);
        return 0;
    }
    double drive[7] = {x0, 0.0, 0.0, x0, 0.0, 0.0, 0.0};
    memcpy(n->drive, drive, sizeof drive);
    n->slip[0] = x0; n->slip[1] = 0.0;  /* the slip state starts relaxed */
    memcpy(&n->r[VR_OUT0], y, sizeof y);
    n->initialised = 1;
    return 1;
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
    if (!initial_state(c, &n)) {
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

/* ---- the drive ------------------------------------------------------------------------- */

/* Slip state after a move dx from z (toggle.asymmetry.advance_slip_state, Dahl's law). */
static double advance_slip(double z, double dx) {
    double target = (dx > 0) - (dx < 0);
    return target - (target - z) * exp(-fabs(dx) / CLAMP_SLIP_DISTANCE);
}

/* exp(A h) of the lag for (bandwidth, damping, h), cached. */
static const double *lag_matrix(Core *c, double bw, double zeta, double h) {
    if (c->lag_key[0] != bw || c->lag_key[1] != zeta || c->lag_key[2] != h) {
        drive_lag_transition(2.0 * PI * bw, zeta, h, c->lag);
        c->lag_key[0] = bw; c->lag_key[1] = zeta; c->lag_key[2] = h;
    }
    return c->lag;
}

/* The drive's motion after a step h, the command over the step being the parabola
 * u0 + du0 s + ddu s^2 / 2 (toggle.plant drive_step/follow). */
static void respond(Core *c, double u0, double du0, double ddu, double h, double out[3]) {
    const CoreState *s = &c->s;
    double bw = s->r[VR_BANDWIDTH], zeta = s->r[VR_DAMPING];
    drive_lag_response(lag_matrix(c, bw, zeta, h), 2.0 * PI * bw, zeta, s->drive, u0, du0, ddu,
                       h, out);
}

/* The drive's motion after the step [t, t + h] (toggle.plant.drive_step): u is x_cmd at
 * t, the master's derivatives (if given) are its derivatives at t, and over the step the
 * command is that polynomial (without derivatives the lag's command is extrapolated from
 * the last commands). The ideal drive without derivatives is at u, with the velocity and
 * acceleration of the parabola through the last three commands (toggle.plant.follow). 0 if
 * the motion exceeds MAX_SPEED or MAX_ACCELERATION. */
static int follow(Core *c, double u, double h, double out[7]) {
    const CoreState *s = &c->s;
    const double *d = s->drive;
    double bw = s->r[VR_BANDWIDTH];
    int given = s->der_given[0] || s->der_given[1];
    double dd[2] = {s->der_given[0] ? s->der[0] : 0.0, s->der_given[1] ? s->der[1] : 0.0};
    if (bw > 0) {
        if (!given) drive_extrapolate(d, u, h, s->x_lo, s->x_hi, dd);
        respond(c, u, dd[0], dd[1], h, out);
    } else if (given) {
        out[0] = u + dd[0] * h + dd[1] * h * h / 2; out[1] = dd[0] + dd[1] * h; out[2] = dd[1];
    } else {  /* a stop is not read as a reversal (nor doubles back) */
        double rate = (u - d[3]) / h;
        double curvature = 2 * (rate - d[4]) / (d[5] + h), du1 = rate + curvature * h / 2;
        double lo = fmin(0.0, 2 * rate), hi = fmax(0.0, 2 * rate);
        out[0] = u; out[1] = fmin(fmax(du1, lo), hi); out[2] = curvature;
        out[3] = u; out[4] = rate; out[5] = h; out[6] = h;
        return fabs(out[1]) <= MAX_SPEED && fabs(out[2]) <= MAX_ACCELERATION;
    }
    out[3] = u; out[4] = d[5] > 0 ? (u - d[3]) / d[5] : 0.0; out[5] = h; out[6] = d[5];
    return fabs(out[1]) <= MAX_SPEED && fabs(out[2]) <= MAX_ACCELERATION;
}

int core_step(Core *c, double t, double h) {
    CoreState *s = &c->s;
    double drive[7], y[CLAMP_N_OUT];
    if (s->phase != PHASE_STEPPING || s->me) {
        if (s->phase == PHASE_FAILED)
            core_say(c, 1, "doStep refused, initialisation failed: %s", c->failure);
        else
            core_say(c, 1, "doStep refused: %s", s->me ? "a Model Exchange instance"
                     : s->phase == PHASE_TERMINATED ? "terminated"
                     : "not initialised (call exitInitializationMode first)");
        return CORE_ERROR;
    }
    if (!(h > 0) || !isfinite(h)) {
        core_say(c, 1, "step at t=%g s rejected: step size must be > 0, got %.6g s", t, h);
        return CORE_ERROR;
    }
    double u = s->r[VR_X_CMD];
    if (!(s->x_lo <= u && u <= s->x_hi)) {
        core_say(c, 1, "step at t=%g s rejected: input position x = %.6g m outside the "
                 "assemblable range [%.6g, %.6g] m", t, u, s->x_lo, s->x_hi);
        return CORE_ERROR;
    }
    if (!follow(c, u, h, drive)) {
        double bw = s->r[VR_BANDWIDTH];
        char hint[160];
        if (bw > 0)
            snprintf(hint, sizeof hint, " (drive_bandwidth = %.6g Hz; a lower drive_bandwidth "
                     "follows larger setpoint jumps)", bw);
        else
            snprintf(hint, sizeof hint, " (drive_bandwidth = 0: an ideal drive follows a "
                     "setpoint jump within one step; a drive_bandwidth > 0 Hz follows it "
                     "through the drive's lag)");
        core_say(c, 1, "step at t=%g s rejected: the command x_cmd = %.6g m after %.6g s asks "
                 "for %.3g m/s and %.3g m/s^2; an input link moves within %g m/s and %g m/s^2"
                 "%s", t, u, h, drive[1], drive[2], MAX_SPEED, MAX_ACCELERATION, hint);
        return CORE_ERROR;
    }
    if (!(s->x_lo <= drive[0] && drive[0] <= s->x_hi)) {
        core_say(c, 1, "step at t=%g s rejected: input position x = %.6g m outside the "
                 "assemblable range [%.6g, %.6g] m", t, drive[0], s->x_lo, s->x_hi);
        return CORE_ERROR;
    }
    double xvaz[4] = {drive[0], drive[1], drive[2], advance_slip(s->slip[1], drive[0] - s->slip[0])};
    if (!plant(c, s, xvaz, y)) {
        core_say(c, 1, "step at t=%g s rejected: no finite plant solution at x = %.6g m", t,
                 drive[0]);
        return CORE_ERROR;
    }
    memcpy(s->drive, drive, sizeof drive);
    s->slip[0] = drive[0]; s->slip[1] = xvaz[3];
    memcpy(&s->r[VR_OUT0], y, sizeof y);
    s->time = t + h;
    s->der_given[0] = s->der_given[1] = 0;  /* derivatives apply to one step */
    s->der[0] = s->der[1] = 0;
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

/* ---- Model Exchange ------------------------------------------------------------------------ */

static double lag_acceleration(const CoreState *s) {
    double w = 2.0 * PI * s->r[VR_BANDWIDTH], zeta = s->r[VR_DAMPING];
    return w * w * (s->r[VR_X_CMD] - s->drive[0]) - 2.0 * zeta * w * s->drive[1];
}

static double slip_rate(double z, double v) {
    double sign = (v > 0) - (v < 0);
    return (sign - z) * fabs(v) / CLAMP_SLIP_DISTANCE;
}

/* Outputs of a Model Exchange instance at its states and input, if not current. */
static int me_outputs(Core *c) {
    CoreState *s = &c->s;
    double y[CLAMP_N_OUT];
    if (!c->stale || s->phase != PHASE_STEPPING) return 1;
    if (!isfinite(s->r[VR_X_CMD])) {
        core_say(c, 1, "input x_cmd = %.6g m is not finite", s->r[VR_X_CMD]);
        return 0;
    }
    double a = lag_acceleration(s), xvaz[4] = {s->drive[0], s->drive[1], a, s->slip[1]};
    if (!plant(c, s, xvaz, y)) {
        core_say(c, 1, "no finite plant solution at x = %.6g m", s->drive[0]);
        return 0;
    }
    s->drive[2] = a;
    memcpy(&s->r[VR_OUT0], y, sizeof y);
    c->stale = 0;
    return 1;
}

static int me_ready(Core *c, const char *who) {
    if (!c->s.me || (c->s.phase != PHASE_STEPPING && c->s.phase != PHASE_TERMINATED)) {
        core_say(c, 1, "%s: %s", who, c->s.me ? "not initialised" : "not a Model Exchange instance");
        return 0;
    }
    return 1;
}

int core_get_states(Core *c, double x[], size_t n) {
    if (!me_ready(c, "getContinuousStates")) return CORE_ERROR;
    if (n != CORE_N_STATES) {
        core_say(c, 1, "getContinuousStates: %zu states asked, there are %d", n, CORE_N_STATES);
        return CORE_ERROR;
    }
    x[0] = c->s.drive[0]; x[1] = c->s.drive[1]; x[2] = c->s.slip[1];
    return CORE_OK;
}

int core_set_states(Core *c, const double x[], size_t n) {
    CoreState *s = &c->s;
    if (!me_ready(c, "setContinuousStates")) return CORE_ERROR;
    if (n != CORE_N_STATES || !isfinite(x[0]) || !isfinite(x[1]) || !isfinite(x[2])) {
        core_say(c, 1, "setContinuousStates: %zu states (x, velocity, slip_state) must be 3 "
                 "and finite", n);
        return CORE_ERROR;
    }
    if (!(s->x_lo <= x[0] && x[0] <= s->x_hi)) {
        core_say(c, 1, "setContinuousStates: input position x = %.6g m outside the assemblable "
                 "range [%.6g, %.6g] m", x[0], s->x_lo, s->x_hi);
        return CORE_ERROR;
    }
    if (!(fabs(x[1]) <= MAX_SPEED)) {
        core_say(c, 1, "setContinuousStates: velocity = %.6g m/s; an input link moves within "
                 "%g m/s", x[1], MAX_SPEED);
        return CORE_ERROR;
    }
    /* |z| <= 1 holds for the exact solution; an integrator's trial may overshoot it */
    s->drive[0] = x[0]; s->drive[1] = x[1]; s->slip[0] = x[0];
    s->slip[1] = fmax(-1.0, fmin(1.0, x[2]));
    c->stale = 1;
    return CORE_OK;
}

int core_get_derivatives(Core *c, double dx[], size_t n) {
    const CoreState *s = &c->s;
    if (!me_ready(c, "getDerivatives")) return CORE_ERROR;
    if (n != CORE_N_STATES || !isfinite(s->r[VR_X_CMD])) {
        core_say(c, 1, "getDerivatives: %zu derivatives asked (3), input x_cmd = %.6g m", n,
                 s->r[VR_X_CMD]);
        return CORE_ERROR;
    }
    dx[0] = s->drive[1];
    dx[1] = lag_acceleration(s);
    dx[2] = slip_rate(s->slip[1], s->drive[1]);
    return CORE_OK;
}

/* ---- variables ----------------------------------------------------------------------------- */

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
        if (!initial_state(c, &n0)) {
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
        case VR_DER_V: value[i] = init_mode ? 0.0 : s->me ? lag_acceleration(s) : s->drive[2]; break;
        case VR_DER_SLIP: value[i] = init_mode ? 0.0 : slip_rate(s->slip[1], v); break;
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
    if (!in_ranges(c, s->r, 0)) return c->failure;
    int unequal = 0, cheap = s->mu == s->r[VR_MU];  /* what needs no toggle search, first */
    for (int i = 0; i < CLAMP_N_MASSES; i++) cheap &= s->masses[i] == s->r[VR_MASS0 + i];
    for (int i = 0; i < 2 * CLAMP_N_DIMS; i++)
        cheap &= s->dims[i] == CLAMP_NOMINAL[i] + s->r[VR_DELTA0 + i];
    for (int i = 0; i < CLAMP_N_DIMS; i++) unequal |= s->dims[i] != s->dims[CLAMP_N_DIMS + i];
    if (!cheap || unequal != s->unequal)
        return "derived data (dimensions, masses, friction) not those of its parameters";
    CoreState d = *s;
    if (!derive(c, s->r, &d)) return c->failure;
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
    if (!plant(c, s, xvaz, y) || memcmp(y, &s->r[VR_OUT0], sizeof y) != 0)
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

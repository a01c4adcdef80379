/* The native core's motion (see clamp_core.h): the drive and the Co-Simulation step
 * (toggle.plant.drive_step), and the Model Exchange states and derivatives. */
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "clamp_core_internal.h"
#include "drive_lag.h"

#define PI 3.14159265358979323846

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
    if (!core_plant(c, s, xvaz, y)) {
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

/* ---- Model Exchange ------------------------------------------------------------------------ */

double core_lag_acceleration(const CoreState *s) {
    double w = 2.0 * PI * s->r[VR_BANDWIDTH], zeta = s->r[VR_DAMPING];
    return w * w * (s->r[VR_X_CMD] - s->drive[0]) - 2.0 * zeta * w * s->drive[1];
}

double core_slip_rate(double z, double v) {
    double sign = (v > 0) - (v < 0);
    return (sign - z) * fabs(v) / CLAMP_SLIP_DISTANCE;
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
    dx[1] = core_lag_acceleration(s);
    dx[2] = core_slip_rate(s->slip[1], s->drive[1]);
    return CORE_OK;
}

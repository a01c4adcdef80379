/* The native core's initialisation (see clamp_core.h): the generated plant, the toggle
 * search and assemblable range, the parameter checks and the initial state. */
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "clamp_core_internal.h"

#define GRID 4001
#define N_IN 6

typedef int (*PlantFn)(const double **, double **, casadi_int *, double *, int);

/* ---- the generated plant ---------------------------------------------------------------- */

static void evaluate(Core *c, PlantFn f, const double **in, int n_in, double *y) {
    for (int i = 0; i < n_in; i++) c->arg[i] = in[i];
    c->res[0] = y;
    f(c->arg, c->res, c->iw, c->w, 0);
}

/* Outputs at xvaz (position, velocity, acceleration, slip state) for the derived data of
 * s; 0 unless all finite. The variant is chosen by tests, never by indexing with data. */
int core_plant(Core *c, const CoreState *s, const double xvaz[4], double y[CLAMP_N_OUT]) {
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
int core_in_ranges(Core *c, const double *r, int with_input) {
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
int core_derive(Core *c, const double *r, CoreState *d) {
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
int core_initial_state(Core *c, CoreState *n) {
    double y[CLAMP_N_OUT];
    if (!core_in_ranges(c, n->r, 1)) return 0;
    if (n->me && !(n->r[VR_BANDWIDTH] > 0)) {
        snprintf(c->failure, sizeof c->failure, "parameter drive_bandwidth = %.6g Hz: Model "
                 "Exchange needs drive_bandwidth > 0 Hz (the drive's lag is its continuous "
                 "state; the ideal drive has none)", n->r[VR_BANDWIDTH]);
        return 0;
    }
    if (!core_derive(c, n->r, n)) return 0;
    double x0 = n->r[VR_X_CMD], xvaz[4] = {x0, 0.0, 0.0, 0.0};
    if (!(n->x_lo <= x0 && x0 <= n->x_hi)) {
        snprintf(c->failure, sizeof c->failure, "input position x = %.6g m outside the "
                 "assemblable range [%.6g, %.6g] m", x0, n->x_lo, n->x_hi);
        return 0;
    }
    if (!core_plant(c, n, xvaz, y)) {
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

/* The drive lag's step (toggle.plant: lag_transition, _lag_response, extrapolation).
 *
 * exp(A h) of the drive lag A = [0 1; -w^2 -2 zeta w] without overflow anywhere in
 * w h >= 0, zeta >= 0 (toggle.plant.lag_transition is the same algorithm).
 *
 * Overdamped (zeta > 1): the eigenvalues l1 = -w h / (zeta + r), l2 = -w h (zeta + r),
 * r = sqrt(zeta^2 - 1), are both <= 0 (l1 written without cancellation), and
 *   exp(A h) = ((l1 E2 - l2 E1) I + D A h) / (l1 - l2) ... with E = e^l and
 *   D = (E1 - E2) / (l1 - l2) = E1 (-expm1(l2 - l1)) / (l1 - l2),
 * so no factor grows (e^m cosh q with m + q <= 0 taken apart would overflow for
 * q > 710). Underdamped: e^m (cos q, sin(q)/q) with m = -zeta w h <= 0. Near critical
 * damping (|q^2| < 1e-2) the series of cosh q and sinh(q)/q in q^2. */
#include <math.h>

#include "drive_lag.h"

void drive_lag_transition(double w, double zeta, double h, double p[4]) {
    double wh = w * h, q2 = wh * wh * (zeta - 1.0) * (zeta + 1.0);
    if (q2 >= 1e-2) {
        double r = sqrt((zeta - 1.0) * (zeta + 1.0));
        double l1 = -wh / (zeta + r), l2 = -wh * (zeta + r), d = l1 - l2;
        double e1 = exp(l1), e2 = exp(l2), dd = -e1 * expm1(-d) / d;  /* (E1 - E2) / d */
        p[0] = (l1 * e2 - l2 * e1) / d;
        p[1] = dd * h;
        p[2] = -dd * w * wh;
        p[3] = (l1 * e1 - l2 * e2) / d;
        return;
    }
    double c, s;
    if (q2 > -1e-2) {
        double term = 1.0;
        c = 1.0; s = 1.0;
        for (int k = 1; k <= 8; k++) {  /* q2^k / (2k)! and q2^k / (2k+1)! */
            term *= q2 / ((2.0 * k - 1.0) * (2.0 * k));
            c += term;
            s += term / (2.0 * k + 1.0);
        }
    } else {
        double q = sqrt(-q2);
        c = cos(q); s = sin(q) / q;
    }
    double e = exp(-zeta * wh);
    p[0] = e * (c + s * zeta * wh);
    p[1] = e * s * h;
    p[2] = -e * s * w * wh;
    p[3] = e * (c - s * zeta * wh);
}

void drive_lag_response(const double p[4], double w, double zeta, const double drive[7],
                        double u0, double du0, double ddu, double h, double out[3]) {
    /* exact for the parabola: the deviation from x_p = u - k1 u' + k2 u'' decays as exp(A h) */
    double k1 = 2 * zeta / w, k2 = (4 * zeta * zeta - 1) / (w * w);
    double u1 = u0 + du0 * h + ddu * h * h / 2, du1 = du0 + ddu * h;
    double e0 = drive[0] - (u0 - k1 * du0 + k2 * ddu), e1 = drive[1] - (du0 - k1 * ddu);
    out[0] = u1 - k1 * du1 + k2 * ddu + p[0] * e0 + p[1] * e1;
    out[1] = du1 - k1 * ddu + p[2] * e0 + p[3] * e1;
    out[2] = w * w * (u1 - out[0]) - 2.0 * zeta * w * out[1];
}

/* The parabola through the last three commands (the line through two, held before); its
 * move over the step between 0 and twice the last mean slope times h, at most twice the
 * last change of the command (a longer step extrapolates no further) and within [lo, hi],
 * the derivatives scaled down together if not. */
void drive_extrapolate(const double drive[7], double u, double h, double lo, double hi,
                       double d[2]) {
    d[0] = d[1] = 0.0;
    if (!(drive[5] > 0)) return;
    double rate = (u - drive[3]) / drive[5];
    d[1] = drive[6] > 0 ? 2 * (rate - drive[4]) / (drive[5] + drive[6]) : 0.0;
    d[0] = rate + d[1] * drive[5] / 2;
    double move = d[0] * h + d[1] * h * h / 2;
    double reach = 2 * rate * fmin(h, drive[5]);
    double low = fmin(0.0, fmax(fmin(0.0, reach), lo - u));
    double high = fmax(0.0, fmin(fmax(0.0, reach), hi - u));
    double limited = fmin(fmax(move, low), high);
    if (limited != move) {  /* move != 0: 0 lies within [low, high] */
        d[0] *= limited / move;
        d[1] *= limited / move;
    }
}

/* The drive's second-order tracking lag: exact discretisation over a step. */
#ifndef DRIVE_LAG_H
#define DRIVE_LAG_H

/* p = exp(A h), row-major, for A = [0 1; -w^2 -2 zeta w], w >= 0, zeta >= 0, h >= 0. */
void drive_lag_transition(double w, double zeta, double h, double p[4]);

#endif

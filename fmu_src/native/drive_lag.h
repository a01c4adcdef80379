/* The drive's second-order tracking lag: exact discretisation over a step, the response to
 * a command polynomial, and the command extrapolated from the last commands. A drive state
 * is {x, v, a, last command u, its mean slope, last step, the slope's span}. */
#ifndef DRIVE_LAG_H
#define DRIVE_LAG_H

/* p = exp(A h), row-major, for A = [0 1; -w^2 -2 zeta w], w >= 0, zeta >= 0, h >= 0. */
void drive_lag_transition(double w, double zeta, double h, double p[4]);

/* (x, v, a) after h from the state `drive` of the lag with transition p = exp(A h), natural
 * frequency w > 0 and damping zeta, driven by u0 + du0 s + ddu s^2 / 2 (exact for it). */
void drive_lag_response(const double p[4], double w, double zeta, const double drive[7],
                        double u0, double du0, double ddu, double h, double out[3]);

/* The command's first and second derivatives at the step's start read off the last
 * commands in `drive` and u, the command now (toggle.plant.extrapolation), its move over h
 * within the command range [lo, hi]. */
void drive_extrapolate(const double drive[7], double u, double h, double lo, double hi,
                       double d[2]);

#endif

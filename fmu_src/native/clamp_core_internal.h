/* What the files of the native core share and nothing else sees (clamp_core.c,
 * clamp_init.c, clamp_motion.c, clamp_state.c): the bounds of a motion and the functions
 * each file serves the others. The API files include clamp_core.h only. */
#ifndef CLAMP_CORE_INTERNAL_H
#define CLAMP_CORE_INTERNAL_H

#include "clamp_core.h"

/* Bounds of a commanded motion (toggle.plant.MAX_INPUT_SPEED, MAX_INPUT_ACCELERATION). */
#define MAX_SPEED 10.0
#define MAX_ACCELERATION 1e4

/* clamp_init.c: the generated plant, the parameter checks, the derived data. */
int core_plant(Core *c, const CoreState *s, const double xvaz[4], double y[CLAMP_N_OUT]);
int core_in_ranges(Core *c, const double *r, int with_input);
int core_derive(Core *c, const double *r, CoreState *d);
int core_initial_state(Core *c, CoreState *n);

/* clamp_motion.c: the Model Exchange right-hand side. */
double core_lag_acceleration(const CoreState *s);
double core_slip_rate(double z, double v);

#endif

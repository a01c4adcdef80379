/* What the files of the FMI guard share (fmi2_guard.c, guard_load.c, guard_state.c): the
 * functions forwarded to pythonfmu's library, the instance and its phases, the forwarding
 * of a call. */
#ifndef FMI2_GUARD_H
#define FMI2_GUARD_H

#include "fmi2Functions.h"
#include "guard_table.h"

/* The functions forwarded to pythonfmu's library: declared once, loaded once. */
#define INNER(X) X(fmi2Instantiate) X(fmi2FreeInstance) X(fmi2SetDebugLogging) \
    X(fmi2SetupExperiment) X(fmi2EnterInitializationMode) X(fmi2ExitInitializationMode) \
    X(fmi2Terminate) X(fmi2Reset) X(fmi2GetReal) X(fmi2GetString) X(fmi2SetReal) \
    X(fmi2SetString) X(fmi2GetFMUstate) X(fmi2SetFMUstate) X(fmi2FreeFMUstate) \
    X(fmi2SerializedFMUstateSize) X(fmi2SerializeFMUstate) X(fmi2DeSerializeFMUstate) \
    X(fmi2DoStep) X(fmi2GetStatus) X(fmi2GetRealStatus)
#define DECLARE(f) extern f##TYPE *in_##f;
INNER(DECLARE)

/* The phases, in the order of fmu_src.state.PHASES (their codes in a state's header). */
typedef enum { INSTANTIATED, INITIALISING, STEPPING, TERMINATED, N_PHASES } Phase;
typedef char phases_as_in_python[N_PHASES == GUARD_N_PHASES ? 1 : -1];

/* A state handed to the master: pythonfmu's, and the phase it was taken in. */
typedef struct {
    fmi2FMUstate inner;
    Phase phase;
} GuardState;

typedef struct {
    fmi2Component inner;
    fmi2CallbackFunctions host, mine;
    char name[128];
    fmi2Boolean logging;
    unsigned categories;     /* bit i: GUARD_CATEGORIES[i] enabled; all when none were given */
    Phase phase;
    fmi2Status worst;        /* worst status the slave logged during the current call */
} Guard;

/* Start of a forwarded call, and its status: the worse of pythonfmu's and the slave's log. */
static inline void begin(Guard *g) { g->worst = fmi2OK; }
static inline fmi2Status end(Guard *g, fmi2Status status) {
    fmi2Status logged = g->worst >= fmi2Warning && g->worst != fmi2Discard ? g->worst : fmi2OK;
    return logged > status ? logged : status;
}
#define CALL(g, expr) (begin(g), end(g, (expr)))

/* fmi2_guard.c: an error message to the host's logger; fmi2Error. */
fmi2Status refuse(Guard *g, const char *fmt, ...);

/* guard_load.c: load Python (when the host has none) and pythonfmu's library once, 0 if
 * that fails (logged through cb); register the exit handler that finalises Python. */
int guard_load(const fmi2CallbackFunctions *cb, fmi2String name, const char *resources);
void guard_hook_exit(void);

#endif

/* FMI 2.0 Co-Simulation and Model Exchange API of the toggle clamp: a thin layer over
 * clamp_core.c (one core under every interface). One allocation per instance and per
 * saved state, none per step; no globals but constants. Errors return fmi2Error with a
 * message delivered whatever loggingOn says, and leave the instance as it was. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"
#include "clamp_core.h"

typedef struct {
    Core core;
    fmi2CallbackFunctions cb;
    fmi2Type type;
    char name[64];
} Instance;

/* The message is passed as the logger's format with every % doubled, as loggers that do
 * not read varargs (fmpy's) print the format as it is. */
static void deliver(void *env, int error, const char *msg) {
    Instance *c = env;
    char escaped[2048];
    size_t j = 0;
    if (!c->cb.logger) return;
    for (size_t i = 0; msg[i] && j + 2 < sizeof escaped; i++) {
        if (msg[i] == '%') escaped[j++] = '%';
        escaped[j++] = msg[i];
    }
    escaped[j] = '\0';
    c->cb.logger(c->cb.componentEnvironment, c->name, error ? fmi2Error : fmi2OK,
                 error ? "logStatusError" : "logAll", escaped);
}

static fmi2Status status(int core_status) { return core_status == CORE_OK ? fmi2OK : fmi2Error; }
#define CORE(c) (&((Instance *)(c))->core)

const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Component fmi2Instantiate(fmi2String name, fmi2Type type, fmi2String guid,
                              fmi2String resources, const fmi2CallbackFunctions *cb,
                              fmi2Boolean visible, fmi2Boolean logging) {
    (void)resources; (void)visible;  /* the FMU reads no file: any unpack path works */
    if (!cb || !name) return NULL;
    int known = (type == fmi2CoSimulation && CLAMP_HAS_CS) ||
                (type == fmi2ModelExchange && CLAMP_HAS_ME);
    if (!known || !guid || strcmp(guid, CLAMP_GUID) != 0) {
        if (cb->logger) cb->logger(cb->componentEnvironment, name, fmi2Error, "logStatusError", "%s",
                   !known ? "this FMU does not declare that interface" : "GUID mismatch");
        return NULL;
    }
    Instance *c = calloc(1, sizeof *c);
    if (!c) return NULL;
    c->cb = *cb;
    c->type = type;
    snprintf(c->name, sizeof c->name, "%s", name);
    core_init(&c->core, type == fmi2ModelExchange, deliver, c, logging);
    return c;
}

void fmi2FreeInstance(fmi2Component c) { free(c); }

fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean on, size_t n,
                               const fmi2String categories[]) {
    return status(core_set_debug_logging(CORE(c), on, n, categories));
}

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean tol_defined, fmi2Real tol,
                               fmi2Real start, fmi2Boolean stop_defined, fmi2Real stop) {
    (void)tol_defined; (void)tol; (void)stop_defined; (void)stop;
    CORE(c)->s.time = start;
    return fmi2OK;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c) {
    return status(core_enter_initialisation(CORE(c)));
}

fmi2Status fmi2ExitInitializationMode(fmi2Component c) {
    return status(core_exit_initialisation(CORE(c)));
}

fmi2Status fmi2Terminate(fmi2Component c) { return status(core_terminate(CORE(c))); }

fmi2Status fmi2Reset(fmi2Component c) {
    core_reset(CORE(c));
    return fmi2OK;
}

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                       fmi2Real value[]) {
    return status(core_get_real(CORE(c), vr, n, value));
}

fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                       const fmi2Real value[]) {
    return status(core_set_real(CORE(c), vr, n, value));
}

fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                         fmi2String value[]) {
    return status(core_get_string(CORE(c), vr, n, value));
}

fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                         const fmi2String value[]) {
    return status(core_set_string(CORE(c), vr, n, value));
}

/* ---- Co-Simulation --------------------------------------------------------------------- */

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real t, fmi2Real h, fmi2Boolean new_step) {
    (void)new_step;
    return status(core_step(CORE(c), t, h));
}

/* x_cmd's velocity (order 1) and acceleration (order 2) at the point x_cmd applies to, the
 * end of the next step; they apply to that step only. */
fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[],
                                       size_t n, const fmi2Integer order[],
                                       const fmi2Real value[]) {
    for (size_t i = 0; i < n; i++)
        if (core_set_input_derivative(CORE(c), vr[i], order[i], value[i]) != CORE_OK)
            return fmi2Error;
    return fmi2OK;
}

fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean *value) {
    if (s != fmi2Terminated) {
        core_say(CORE(c), 1, "getBooleanStatus: only fmi2Terminated is answered");
        return fmi2Error;
    }
    *value = fmi2False;  /* the model never asks to stop */
    return fmi2OK;
}

/* ---- Model Exchange -------------------------------------------------------------------- */

fmi2Status fmi2EnterEventMode(fmi2Component c) { (void)c; return fmi2OK; }

fmi2Status fmi2NewDiscreteStates(fmi2Component c, fmi2EventInfo *info) {
    (void)c;
    memset(info, 0, sizeof *info);  /* no events, no discrete states */
    return fmi2OK;
}

fmi2Status fmi2EnterContinuousTimeMode(fmi2Component c) { (void)c; return fmi2OK; }

fmi2Status fmi2CompletedIntegratorStep(fmi2Component c, fmi2Boolean no_set_prior,
                                       fmi2Boolean *enter_event_mode, fmi2Boolean *terminate) {
    (void)c; (void)no_set_prior;
    *enter_event_mode = fmi2False;
    *terminate = fmi2False;
    return fmi2OK;
}

fmi2Status fmi2SetTime(fmi2Component c, fmi2Real time) {
    CORE(c)->s.time = time;
    return fmi2OK;
}

fmi2Status fmi2SetContinuousStates(fmi2Component c, const fmi2Real x[], size_t n) {
    return status(core_set_states(CORE(c), x, n));
}

fmi2Status fmi2GetDerivatives(fmi2Component c, fmi2Real dx[], size_t n) {
    return status(core_get_derivatives(CORE(c), dx, n));
}

fmi2Status fmi2GetEventIndicators(fmi2Component c, fmi2Real indicators[], size_t n) {
    (void)indicators;
    if (n) core_say(CORE(c), 1, "getEventIndicators: this FMU has none");
    return n ? fmi2Error : fmi2OK;
}

fmi2Status fmi2GetContinuousStates(fmi2Component c, fmi2Real x[], size_t n) {
    return status(core_get_states(CORE(c), x, n));
}

fmi2Status fmi2GetNominalsOfContinuousStates(fmi2Component c, fmi2Real nominal[], size_t n) {
    (void)c;  /* the declared nominals of x, velocity and slip_state */
    for (size_t i = 0; i < n; i++) nominal[i] = i < 3 ? CLAMP_STATE_NOMINAL[i] : 1.0;
    return fmi2OK;
}

/* ---- saved states ---------------------------------------------------------------------- */

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *state) {
    CoreState *copy = *state ? *state : malloc(sizeof *copy);
    if (!copy) return fmi2Error;
    core_save(CORE(c), copy);
    *state = copy;
    return fmi2OK;
}

fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate state) {
    if (!state) {
        core_say(CORE(c), 1, "setFMUstate: no state given");
        return fmi2Error;
    }
    return status(core_restore(CORE(c), state, "setFMUstate"));
}

fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *state) {
    (void)c;
    free(*state);
    *state = NULL;
    return fmi2OK;
}

fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate state, size_t *size) {
    (void)c; (void)state;
    *size = sizeof(CoreState);
    return fmi2OK;
}

fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate state, fmi2Byte bytes[],
                                 size_t size) {
    if (size < sizeof(CoreState)) {
        core_say(CORE(c), 1, "serializeFMUstate: buffer of %zu bytes, %zu needed", size,
                 sizeof(CoreState));
        return fmi2Error;
    }
    memcpy(bytes, state, sizeof(CoreState));
    return fmi2OK;
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte bytes[], size_t size,
                                   fmi2FMUstate *state) {
    CoreState *s = malloc(sizeof *s);
    if (!s) return fmi2Error;
    if (core_read_state(CORE(c), bytes, size, s, "deSerializeFMUstate") != CORE_OK) {
        free(s);
        return fmi2Error;
    }
    free(*state);
    *state = s;
    return fmi2OK;
}

/* ---- not supported --------------------------------------------------------------------- */

static fmi2Status unsupported(fmi2Component c, const char *what) {
    core_say(CORE(c), 1, "%s is not supported", what);
    return fmi2Error;
}

fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                          fmi2Integer value[]) {
    (void)vr; (void)value;
    return n ? unsupported(c, "getInteger (no Integer variables)") : fmi2OK;
}

fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                          fmi2Boolean value[]) {
    (void)vr; (void)value;
    return n ? unsupported(c, "getBoolean (no Boolean variables)") : fmi2OK;
}

fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                          const fmi2Integer value[]) {
    (void)vr; (void)value;
    return n ? unsupported(c, "setInteger (no Integer variables)") : fmi2OK;
}

fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                          const fmi2Boolean value[]) {
    (void)vr; (void)value;
    return n ? unsupported(c, "setBoolean (no Boolean variables)") : fmi2OK;
}

fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference u[],
                                        size_t nu, const fmi2ValueReference z[], size_t nz,
                                        const fmi2Real du[], fmi2Real dz[]) {
    (void)u; (void)nu; (void)z; (void)nz; (void)du; (void)dz;
    return unsupported(c, "getDirectionalDerivative");
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[],
                                        size_t n, const fmi2Integer order[],
                                        fmi2Real value[]) {
    (void)vr; (void)n; (void)order; (void)value;
    return unsupported(c, "getRealOutputDerivatives");
}

fmi2Status fmi2CancelStep(fmi2Component c) { return unsupported(c, "cancelStep"); }

fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *value) {
    (void)s; (void)value;
    return unsupported(c, "getStatus");
}

fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real *value) {
    (void)s; (void)value;
    return unsupported(c, "getRealStatus");
}

fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s,
                                fmi2Integer *value) {
    (void)s; (void)value;
    return unsupported(c, "getIntegerStatus");
}

fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String *value) {
    (void)s; (void)value;
    return unsupported(c, "getStringStatus");
}

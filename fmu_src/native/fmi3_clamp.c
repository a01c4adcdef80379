/* FMI 3.0 Co-Simulation and Model Exchange API of the toggle clamp: a thin layer over
 * clamp_core.c, the core under the FMI 2.0 API too. Co-Simulation steps exactly as FMI 2.0
 * Co-Simulation does without input derivatives (FMI 3.0 has no fmi2SetRealInputDerivatives):
 * x_cmd set before fmi3DoStep(t, h) is the command at t, extrapolated over the step from the
 * last commands (clamp_core.c). Value references: the Float64 variables from 0 as in FMI
 * 2.0, preset CLAMP_VR_PRESET, time TIME_VR. One allocation per instance and per saved
 * state, none per step. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi3Functions.h"
#include "clamp_core.h"

#define TIME_VR 1001u

/* Model Exchange's modes after initialisation (FMI 3.0 section 3.2): Event Mode first. */
typedef enum { MODE_EVENT, MODE_CONTINUOUS } MeMode;

typedef struct {
    Core core;
    fmi3InstanceEnvironment env;
    fmi3LogMessageCallback log;
    MeMode mode;
} Instance;

static void deliver(void *env, int error, const char *msg) {
    Instance *c = env;
    if (!c->log) return;  /* FMI 3.0 allows a NULL logMessage */
    c->log(c->env, error ? fmi3Error : fmi3OK, error ? "logStatusError" : "logAll", msg);
}

static fmi3Status status(int core_status) { return core_status == CORE_OK ? fmi3OK : fmi3Error; }
#define CORE(c) (&((Instance *)(c))->core)

static fmi3Status unsupported(fmi3Instance c, const char *what) {
    core_say(CORE(c), 1, "fmi3%s is not supported", what);
    return fmi3Error;
}

const char *fmi3GetVersion(void) { return fmi3Version; }

static Instance *instantiate(fmi3String name, fmi3String token, int me, fmi3Boolean logging,
                             fmi3InstanceEnvironment env, fmi3LogMessageCallback log) {
    (void)name;  /* the FMU reads no file: any resource path works */
    if (!token || strcmp(token, CLAMP_GUID) != 0 || !(me ? CLAMP_HAS_ME : CLAMP_HAS_CS)) {
        if (log) log(env, fmi3Error, "logStatusError", !token || strcmp(token, CLAMP_GUID)
            ? "instantiation token mismatch" : "this FMU does not declare that interface");
        return NULL;
    }
    Instance *c = calloc(1, sizeof *c);
    if (!c) return NULL;
    c->env = env;
    c->log = log;
    core_init(&c->core, me, deliver, c, logging);
    return c;
}

fmi3Instance fmi3InstantiateModelExchange(fmi3String instanceName, fmi3String instantiationToken,
                                          fmi3String resourcePath, fmi3Boolean visible,
                                          fmi3Boolean loggingOn,
                                          fmi3InstanceEnvironment instanceEnvironment,
                                          fmi3LogMessageCallback logMessage) {
    (void)resourcePath; (void)visible;
    return instantiate(instanceName, instantiationToken, 1, loggingOn, instanceEnvironment,
                       logMessage);
}

fmi3Instance fmi3InstantiateCoSimulation(
    fmi3String instanceName, fmi3String instantiationToken, fmi3String resourcePath,
    fmi3Boolean visible, fmi3Boolean loggingOn, fmi3Boolean eventModeUsed,
    fmi3Boolean earlyReturnAllowed, const fmi3ValueReference requiredIntermediateVariables[],
    size_t nRequiredIntermediateVariables, fmi3InstanceEnvironment instanceEnvironment,
    fmi3LogMessageCallback logMessage, fmi3IntermediateUpdateCallback intermediateUpdate) {
    (void)resourcePath; (void)visible; (void)earlyReturnAllowed;
    (void)requiredIntermediateVariables; (void)nRequiredIntermediateVariables;
    (void)intermediateUpdate;
    if (eventModeUsed) {  /* only for an FMU with hasEventMode="true" */
        if (logMessage)
            logMessage(instanceEnvironment, fmi3Error, "logStatusError",
                       "eventModeUsed: this FMU has no Event Mode (hasEventMode=\"false\")");
        return NULL;
    }
    return instantiate(instanceName, instantiationToken, 0, loggingOn, instanceEnvironment,
                       logMessage);
}

fmi3Instance fmi3InstantiateScheduledExecution(
    fmi3String instanceName, fmi3String instantiationToken, fmi3String resourcePath,
    fmi3Boolean visible, fmi3Boolean loggingOn, fmi3InstanceEnvironment instanceEnvironment,
    fmi3LogMessageCallback logMessage, fmi3ClockUpdateCallback clockUpdate,
    fmi3LockPreemptionCallback lockPreemption, fmi3UnlockPreemptionCallback unlockPreemption) {
    (void)instanceName; (void)instantiationToken; (void)resourcePath; (void)visible;
    (void)loggingOn; (void)clockUpdate; (void)lockPreemption; (void)unlockPreemption;
    if (logMessage)
        logMessage(instanceEnvironment, fmi3Error, "logStatusError",
                   "Scheduled Execution is not supported");
    return NULL;
}

void fmi3FreeInstance(fmi3Instance instance) { free(instance); }

fmi3Status fmi3SetDebugLogging(fmi3Instance instance, fmi3Boolean loggingOn, size_t nCategories,
                               const fmi3String categories[]) {
    return status(core_set_debug_logging(CORE(instance), loggingOn, nCategories, categories));
}

fmi3Status fmi3EnterInitializationMode(fmi3Instance instance, fmi3Boolean toleranceDefined,
                                       fmi3Float64 tolerance, fmi3Float64 startTime,
                                       fmi3Boolean stopTimeDefined, fmi3Float64 stopTime) {
    (void)toleranceDefined; (void)tolerance; (void)stopTimeDefined; (void)stopTime;
    CORE(instance)->s.time = startTime;
    return status(core_enter_initialisation(CORE(instance)));
}

fmi3Status fmi3ExitInitializationMode(fmi3Instance instance) {
    ((Instance *)instance)->mode = MODE_EVENT;  /* Model Exchange enters Event Mode */
    return status(core_exit_initialisation(CORE(instance)));
}

/* Model Exchange: 1 if the instance is initialised and in `mode`, else an error is logged. */
static int in_mode(fmi3Instance instance, MeMode mode, const char *who) {
    Core *c = CORE(instance);
    if (!c->s.me) {
        core_say(c, 1, "fmi3%s: a Co-Simulation instance (hasEventMode=\"false\": it has no "
                 "Event Mode)", who);
        return 0;
    }
    if (c->s.phase != PHASE_STEPPING || ((Instance *)instance)->mode != mode) {
        core_say(c, 1, "fmi3%s: only in %s", who, mode == MODE_EVENT ? "Event Mode"
                 : "Continuous-Time Mode");
        return 0;
    }
    return 1;
}

fmi3Status fmi3EnterEventMode(fmi3Instance instance) {
    Core *c = CORE(instance);
    if (c->s.me && c->s.phase == PHASE_STEPPING) {  /* from Continuous-Time Mode, or again */
        ((Instance *)instance)->mode = MODE_EVENT;
        return fmi3OK;
    }
    return in_mode(instance, MODE_EVENT, "EnterEventMode") ? fmi3OK : fmi3Error;
}
fmi3Status fmi3Terminate(fmi3Instance instance) { return status(core_terminate(CORE(instance))); }

fmi3Status fmi3Reset(fmi3Instance instance) {
    core_reset(CORE(instance));
    return fmi3OK;
}

fmi3Status fmi3GetFloat64(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                          size_t nValueReferences, fmi3Float64 values[], size_t nValues) {
    if (nValues != nValueReferences) return unsupported(instance, "GetFloat64 of arrays");
    for (size_t i = 0; i < nValueReferences; i++) {
        if (valueReferences[i] == TIME_VR) values[i] = CORE(instance)->s.time;
        else if (core_get_real(CORE(instance), &valueReferences[i], 1, &values[i]) != CORE_OK)
            return fmi3Error;
    }
    return fmi3OK;
}

fmi3Status fmi3SetFloat64(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                          size_t nValueReferences, const fmi3Float64 values[], size_t nValues) {
    if (nValues != nValueReferences) return unsupported(instance, "SetFloat64 of arrays");
    return status(core_set_real(CORE(instance), valueReferences, nValueReferences, values));
}

fmi3Status fmi3GetString(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                         size_t nValueReferences, fmi3String values[], size_t nValues) {
    if (nValues != nValueReferences) return unsupported(instance, "GetString of arrays");
    return status(core_get_string(CORE(instance), valueReferences, nValueReferences, values));
}

fmi3Status fmi3SetString(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                         size_t nValueReferences, const fmi3String values[], size_t nValues) {
    if (nValues != nValueReferences) return unsupported(instance, "SetString of arrays");
    return status(core_set_string(CORE(instance), valueReferences, nValueReferences, values));
}

/* ---- Co-Simulation --------------------------------------------------------------------- */

fmi3Status fmi3EnterStepMode(fmi3Instance instance) { (void)instance; return fmi3OK; }

fmi3Status fmi3DoStep(fmi3Instance instance, fmi3Float64 currentCommunicationPoint,
                      fmi3Float64 communicationStepSize,
                      fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                      fmi3Boolean *eventHandlingNeeded, fmi3Boolean *terminateSimulation,
                      fmi3Boolean *earlyReturn, fmi3Float64 *lastSuccessfulTime) {
    (void)noSetFMUStatePriorToCurrentPoint;
    int ok = core_step(CORE(instance), currentCommunicationPoint, communicationStepSize);
    *eventHandlingNeeded = fmi3False;
    *terminateSimulation = fmi3False;
    *earlyReturn = fmi3False;
    *lastSuccessfulTime = currentCommunicationPoint + (ok == CORE_OK ? communicationStepSize : 0);
    return status(ok);
}

/* ---- Model Exchange -------------------------------------------------------------------- */

fmi3Status fmi3UpdateDiscreteStates(fmi3Instance instance, fmi3Boolean *discreteStatesNeedUpdate,
                                    fmi3Boolean *terminateSimulation,
                                    fmi3Boolean *nominalsOfContinuousStatesChanged,
                                    fmi3Boolean *valuesOfContinuousStatesChanged,
                                    fmi3Boolean *nextEventTimeDefined,
                                    fmi3Float64 *nextEventTime) {
    if (!in_mode(instance, MODE_EVENT, "UpdateDiscreteStates")) return fmi3Error;
    /* no events, no discrete states */
    *discreteStatesNeedUpdate = *terminateSimulation = fmi3False;
    *nominalsOfContinuousStatesChanged = *valuesOfContinuousStatesChanged = fmi3False;
    *nextEventTimeDefined = fmi3False;
    *nextEventTime = 0.0;
    return fmi3OK;
}

fmi3Status fmi3EnterContinuousTimeMode(fmi3Instance instance) {
    if (!in_mode(instance, MODE_EVENT, "EnterContinuousTimeMode")) return fmi3Error;
    ((Instance *)instance)->mode = MODE_CONTINUOUS;
    return fmi3OK;
}

fmi3Status fmi3CompletedIntegratorStep(fmi3Instance instance,
                                       fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi3Boolean *enterEventMode,
                                       fmi3Boolean *terminateSimulation) {
    (void)noSetFMUStatePriorToCurrentPoint;
    if (!in_mode(instance, MODE_CONTINUOUS, "CompletedIntegratorStep")) return fmi3Error;
    *enterEventMode = *terminateSimulation = fmi3False;
    return fmi3OK;
}

fmi3Status fmi3SetTime(fmi3Instance instance, fmi3Float64 time) {
    CORE(instance)->s.time = time;
    return fmi3OK;
}

fmi3Status fmi3SetContinuousStates(fmi3Instance instance, const fmi3Float64 continuousStates[],
                                   size_t nContinuousStates) {
    return status(core_set_states(CORE(instance), continuousStates, nContinuousStates));
}

fmi3Status fmi3GetContinuousStateDerivatives(fmi3Instance instance, fmi3Float64 derivatives[],
                                             size_t nContinuousStates) {
    return status(core_get_derivatives(CORE(instance), derivatives, nContinuousStates));
}

fmi3Status fmi3GetEventIndicators(fmi3Instance instance, fmi3Float64 eventIndicators[],
                                  size_t nEventIndicators) {
    (void)eventIndicators;
    return nEventIndicators ? unsupported(instance, "GetEventIndicators (there are none)")
                            : fmi3OK;
}

fmi3Status fmi3GetContinuousStates(fmi3Instance instance, fmi3Float64 continuousStates[],
                                   size_t nContinuousStates) {
    return status(core_get_states(CORE(instance), continuousStates, nContinuousStates));
}

fmi3Status fmi3GetNominalsOfContinuousStates(fmi3Instance instance, fmi3Float64 nominals[],
                                             size_t nContinuousStates) {
    (void)instance;  /* the declared nominals of x, velocity and slip_state */
    for (size_t i = 0; i < nContinuousStates; i++)
        nominals[i] = i < 3 ? CLAMP_STATE_NOMINAL[i] : 1.0;
    return fmi3OK;
}

fmi3Status fmi3GetNumberOfEventIndicators(fmi3Instance instance, size_t *nEventIndicators) {
    (void)instance;
    *nEventIndicators = 0;
    return fmi3OK;
}

fmi3Status fmi3GetNumberOfContinuousStates(fmi3Instance instance, size_t *nContinuousStates) {
    *nContinuousStates = CORE(instance)->s.me ? CORE_N_STATES : 0;
    return fmi3OK;
}

/* ---- saved states ---------------------------------------------------------------------- */

fmi3Status fmi3GetFMUState(fmi3Instance instance, fmi3FMUState *FMUState) {
    CoreState *copy = *FMUState ? *FMUState : malloc(sizeof *copy);
    if (!copy) return fmi3Error;
    core_save(CORE(instance), copy);
    *FMUState = copy;
    return fmi3OK;
}

fmi3Status fmi3SetFMUState(fmi3Instance instance, fmi3FMUState FMUState) {
    if (!FMUState) {
        core_say(CORE(instance), 1, "fmi3SetFMUState: no state given");
        return fmi3Error;
    }
    return status(core_restore(CORE(instance), FMUState, "fmi3SetFMUState"));
}

fmi3Status fmi3FreeFMUState(fmi3Instance instance, fmi3FMUState *FMUState) {
    (void)instance;
    free(*FMUState);
    *FMUState = NULL;
    return fmi3OK;
}

fmi3Status fmi3SerializedFMUStateSize(fmi3Instance instance, fmi3FMUState FMUState,
                                      size_t *size) {
    (void)instance; (void)FMUState;
    *size = sizeof(CoreState);
    return fmi3OK;
}

fmi3Status fmi3SerializeFMUState(fmi3Instance instance, fmi3FMUState FMUState,
                                 fmi3Byte serializedState[], size_t size) {
    if (size < sizeof(CoreState)) {
        core_say(CORE(instance), 1, "fmi3SerializeFMUState: buffer of %zu bytes, %zu needed",
                 size, sizeof(CoreState));
        return fmi3Error;
    }
    memcpy(serializedState, FMUState, sizeof(CoreState));
    return fmi3OK;
}

fmi3Status fmi3DeserializeFMUState(fmi3Instance instance, const fmi3Byte serializedState[],
                                   size_t size, fmi3FMUState *FMUState) {
    CoreState *s = malloc(sizeof *s);
    if (!s) return fmi3Error;
    if (core_read_state(CORE(instance), serializedState, size, s, "fmi3DeserializeFMUState") !=
        CORE_OK) {
        free(s);
        return fmi3Error;
    }
    free(*FMUState);
    *FMUState = s;
    return fmi3OK;
}

/* ---- not supported --------------------------------------------------------------------- */

fmi3Status fmi3GetFloat32(fmi3Instance instance, const fmi3ValueReference valueReferences[], size_t nValueReferences, fmi3Float32 values[], size_t nValues) {
    (void)valueReferences; (void)nValueReferences; (void)values; (void)nValues;
    return nValueReferences ? unsupported(instance, "GetFloat32 (no such variables)") : fmi3OK;
}

fmi3Status fmi3GetInt8(fmi3Instance instance, const fmi3ValueReference valueReferences[], size_t nValueReferences, fmi3Int8 values[], size_t nValues) {
    (void)valueReferences; (void)nValueReferences; (void)values; (void)nValues;
    return nValueReferences ? unsupported(instance, "GetInt8 (no such variables)") : fmi3OK;
}

fmi3Status fmi3GetUInt8(fmi3Instance instance, const fmi3ValueReference valueReferences[], size_t nValueReferences, fmi3UInt8 values[], size_t nValues) {
    (void)valueReferences; (void)nValueReferences; (void)values; (void)nValues;
    return nValueReferences ? unsupported(instance, "GetUInt8 (no such variables)") : fmi3OK;
}

fmi3Status fmi3GetInt16(fmi3Instance instance, const fmi3ValueReference valueReferences[], size_t nValueReferences, fmi3Int16 values[], size_t nValues) {
    (void)valueReferences; (void)nValueReferences; (void)values; (void)nValues;
    return nValueReferences ? unsupported(instance, "GetInt16 (no such variables)") : fmi3OK;
}

fmi3Status fmi3GetUInt16(fmi3Instance instance, const fmi3ValueReference valueReferences[], size_t nValueReferences, fmi3UInt16 values[], size_t nValues) {
    (void)valueReferences; (void)nValueReferences; (void)values; (void)nValues;
    return nValueReferences ? unsupported(instance, "GetUInt16 (no such variables)") : fmi3OK;
}

fmi3Status fmi3GetInt32(fmi3Instance instance, const fmi3ValueReference valueReferences[], size_t nValueReferences, fmi3Int32 values[], size_t nValues) {
    (void)valueReferences; (void)nValueReferences; (void)values; (void)nValues;
    return nValueReferences ? unsupported(instance, "GetInt32 (no such variables)") : fmi3OK;
}

fmi3Status fmi3GetUInt32(fmi3Instance instance, const fmi3ValueReference valueReferences[], size_t nValueReferences, fmi3UInt32 values[], size_t nValues) {
    (void)valueReferences; (void)nValueReferences; (void)values; (void)nValues;
    return nValueReferences ? unsupported(instance, "GetUInt32 (no such variables)") : fmi3OK;
}

fmi3Status fmi3GetInt64(fmi3Instance instance, const fmi3ValueReference valueReferences[], size_t nValueReferences, fmi3Int64 values[], size_t nValues) {
    (void)valueReferences; (void)nValueReferences; (void)values; (void)nValues;
    return nValueReferences ? unsupported(instance, "GetInt64 (no such variables)") : fmi3OK;
}

fmi3Status fmi3GetUInt64(fmi3Instance instance, const fmi3ValueReference valueReferences[], size_t nValueReferences, fmi3UInt64 values[], size_t nValues) {
    (void)valueReferences; (void)nValueReferences; (void)values; (void)nValues;
    return nValueReferences ? unsupported(instance, "GetUInt64 (no such variables)") : fmi3OK;
}

fmi3Status fmi3GetBoolean(fmi3Instance instance, const fmi3ValueReference valueReferences[], size_t nValueReferences, fmi3Boolean values[], size_t nValues) {
    (void)valueReferences; (void)nValueReferences; (void)values; (void)nValues;
    return nValueReferences ? unsupported(instance, "GetBoolean (no such variables)") : fmi3OK;
}

fmi3Status fmi3GetBinary(fmi3Instance instance, const fmi3ValueReference valueReferences[], size_t nValueReferences, size_t valueSizes[], fmi3Binary values[], size_t nValues) {
    (void)valueReferences; (void)nValueReferences; (void)valueSizes; (void)values; (void)nValues;
    return nValueReferences ? unsupported(instance, "GetBinary (no such variables)") : fmi3OK;
}

fmi3Status fmi3GetClock(fmi3Instance instance, const fmi3ValueReference valueReferences[], size_t nValueReferences, fmi3Clock values[]) {
    (void)valueReferences; (void)nValueReferences; (void)values;
    return nValueReferences ? unsupported(instance, "GetClock (no such variables)") : fmi3OK;
}

fmi3Status fmi3SetFloat32(fmi3Instance instance, const fmi3ValueReference valueReferences[], size_t nValueReferences, const fmi3Float32 values[], size_t nValues) {
    (void)valueReferences; (void)nValueReferences; (void)values; (void)nValues;
    return nValueReferences ? unsupported(instance, "SetFloat32 (no such variables)") : fmi3OK;
}

fmi3Status fmi3SetInt8(fmi3Instance instance, const fmi3ValueReference valueReferences[], size_t nValueReferences, const fmi3Int8 values[], size_t nValues) {
    (void)valueReferences; (void)nValueReferences; (void)values; (void)nValues;
    return nValueReferences ? unsupported(instance, "SetInt8 (no such variables)") : fmi3OK;
}

fmi3Status fmi3SetUInt8(fmi3Instance instance, const fmi3ValueReference valueReferences[], size_t nValueReferences, const fmi3UInt8 values[], size_t nValues) {
    (void)valueReferences; (void)nValueReferences; (void)values; (void)nValues;
    return nValueReferences ? unsupported(instance, "SetUInt8 (no such variables)") : fmi3OK;
}

fmi3Status fmi3SetInt16(fmi3Instance instance, const fmi3ValueReference valueReferences[], size_t nValueReferences, const fmi3Int16 values[], size_t nValues) {
    (void)valueReferences; (void)nValueReferences; (void)values; (void)nValues;
    return nValueReferences ? unsupported(instance, "SetInt16 (no such variables)") : fmi3OK;
}

fmi3Status fmi3SetUInt16(fmi3Instance instance, const fmi3ValueReference valueReferences[], size_t nValueReferences, const fmi3UInt16 values[], size_t nValues) {
    (void)valueReferences; (void)nValueReferences; (void)values; (void)nValues;
    return nValueReferences ? unsupported(instance, "SetUInt16 (no such variables)") : fmi3OK;
}

fmi3Status fmi3SetInt32(fmi3Instance instance, const fmi3ValueReference valueReferences[], size_t nValueReferences, const fmi3Int32 values[], size_t nValues) {
    (void)valueReferences; (void)nValueReferences; (void)values; (void)nValues;
    return nValueReferences ? unsupported(instance, "SetInt32 (no such variables)") : fmi3OK;
}

fmi3Status fmi3SetUInt32(fmi3Instance instance, const fmi3ValueReference valueReferences[], size_t nValueReferences, const fmi3UInt32 values[], size_t nValues) {
    (void)valueReferences; (void)nValueReferences; (void)values; (void)nValues;
    return nValueReferences ? unsupported(instance, "SetUInt32 (no such variables)") : fmi3OK;
}

fmi3Status fmi3SetInt64(fmi3Instance instance, const fmi3ValueReference valueReferences[], size_t nValueReferences, const fmi3Int64 values[], size_t nValues) {
    (void)valueReferences; (void)nValueReferences; (void)values; (void)nValues;
    return nValueReferences ? unsupported(instance, "SetInt64 (no such variables)") : fmi3OK;
}

fmi3Status fmi3SetUInt64(fmi3Instance instance, const fmi3ValueReference valueReferences[], size_t nValueReferences, const fmi3UInt64 values[], size_t nValues) {
    (void)valueReferences; (void)nValueReferences; (void)values; (void)nValues;
    return nValueReferences ? unsupported(instance, "SetUInt64 (no such variables)") : fmi3OK;
}

fmi3Status fmi3SetBoolean(fmi3Instance instance, const fmi3ValueReference valueReferences[], size_t nValueReferences, const fmi3Boolean values[], size_t nValues) {
    (void)valueReferences; (void)nValueReferences; (void)values; (void)nValues;
    return nValueReferences ? unsupported(instance, "SetBoolean (no such variables)") : fmi3OK;
}

fmi3Status fmi3SetBinary(fmi3Instance instance, const fmi3ValueReference valueReferences[], size_t nValueReferences, const size_t valueSizes[], const fmi3Binary values[], size_t nValues) {
    (void)valueReferences; (void)nValueReferences; (void)valueSizes; (void)values; (void)nValues;
    return nValueReferences ? unsupported(instance, "SetBinary (no such variables)") : fmi3OK;
}

fmi3Status fmi3SetClock(fmi3Instance instance, const fmi3ValueReference valueReferences[], size_t nValueReferences, const fmi3Clock values[]) {
    (void)valueReferences; (void)nValueReferences; (void)values;
    return nValueReferences ? unsupported(instance, "SetClock (no such variables)") : fmi3OK;
}

fmi3Status fmi3GetNumberOfVariableDependencies(fmi3Instance instance, fmi3ValueReference valueReference, size_t* nDependencies) {
    (void)valueReference; (void)nDependencies;
    return unsupported(instance, "GetNumberOfVariableDependencies");
}

fmi3Status fmi3GetVariableDependencies(fmi3Instance instance, fmi3ValueReference dependent, size_t elementIndicesOfDependent[], fmi3ValueReference independents[], size_t elementIndicesOfIndependents[], fmi3DependencyKind dependencyKinds[], size_t nDependencies) {
    (void)dependent; (void)elementIndicesOfDependent; (void)independents; (void)elementIndicesOfIndependents; (void)dependencyKinds; (void)nDependencies;
    return unsupported(instance, "GetVariableDependencies");
}

fmi3Status fmi3GetDirectionalDerivative(fmi3Instance instance, const fmi3ValueReference unknowns[], size_t nUnknowns, const fmi3ValueReference knowns[], size_t nKnowns, const fmi3Float64 seed[], size_t nSeed, fmi3Float64 sensitivity[], size_t nSensitivity) {
    (void)unknowns; (void)nUnknowns; (void)knowns; (void)nKnowns; (void)seed; (void)nSeed; (void)sensitivity; (void)nSensitivity;
    return unsupported(instance, "GetDirectionalDerivative");
}

fmi3Status fmi3GetAdjointDerivative(fmi3Instance instance, const fmi3ValueReference unknowns[], size_t nUnknowns, const fmi3ValueReference knowns[], size_t nKnowns, const fmi3Float64 seed[], size_t nSeed, fmi3Float64 sensitivity[], size_t nSensitivity) {
    (void)unknowns; (void)nUnknowns; (void)knowns; (void)nKnowns; (void)seed; (void)nSeed; (void)sensitivity; (void)nSensitivity;
    return unsupported(instance, "GetAdjointDerivative");
}

fmi3Status fmi3EnterConfigurationMode(fmi3Instance instance) {
    
    return unsupported(instance, "EnterConfigurationMode");
}

fmi3Status fmi3ExitConfigurationMode(fmi3Instance instance) {
    
    return unsupported(instance, "ExitConfigurationMode");
}

fmi3Status fmi3GetIntervalDecimal(fmi3Instance instance, const fmi3ValueReference valueReferences[], size_t nValueReferences, fmi3Float64 intervals[], fmi3IntervalQualifier qualifiers[]) {
    (void)valueReferences; (void)nValueReferences; (void)intervals; (void)qualifiers;
    return unsupported(instance, "GetIntervalDecimal");
}

fmi3Status fmi3GetIntervalFraction(fmi3Instance instance, const fmi3ValueReference valueReferences[], size_t nValueReferences, fmi3UInt64 counters[], fmi3UInt64 resolutions[], fmi3IntervalQualifier qualifiers[]) {
    (void)valueReferences; (void)nValueReferences; (void)counters; (void)resolutions; (void)qualifiers;
    return unsupported(instance, "GetIntervalFraction");
}

fmi3Status fmi3GetShiftDecimal(fmi3Instance instance, const fmi3ValueReference valueReferences[], size_t nValueReferences, fmi3Float64 shifts[]) {
    (void)valueReferences; (void)nValueReferences; (void)shifts;
    return unsupported(instance, "GetShiftDecimal");
}

fmi3Status fmi3GetShiftFraction(fmi3Instance instance, const fmi3ValueReference valueReferences[], size_t nValueReferences, fmi3UInt64 counters[], fmi3UInt64 resolutions[]) {
    (void)valueReferences; (void)nValueReferences; (void)counters; (void)resolutions;
    return unsupported(instance, "GetShiftFraction");
}

fmi3Status fmi3SetIntervalDecimal(fmi3Instance instance, const fmi3ValueReference valueReferences[], size_t nValueReferences, const fmi3Float64 intervals[]) {
    (void)valueReferences; (void)nValueReferences; (void)intervals;
    return unsupported(instance, "SetIntervalDecimal");
}

fmi3Status fmi3SetIntervalFraction(fmi3Instance instance, const fmi3ValueReference valueReferences[], size_t nValueReferences, const fmi3UInt64 counters[], const fmi3UInt64 resolutions[]) {
    (void)valueReferences; (void)nValueReferences; (void)counters; (void)resolutions;
    return unsupported(instance, "SetIntervalFraction");
}

fmi3Status fmi3SetShiftDecimal(fmi3Instance instance, const fmi3ValueReference valueReferences[], size_t nValueReferences, const fmi3Float64 shifts[]) {
    (void)valueReferences; (void)nValueReferences; (void)shifts;
    return unsupported(instance, "SetShiftDecimal");
}

fmi3Status fmi3SetShiftFraction(fmi3Instance instance, const fmi3ValueReference valueReferences[], size_t nValueReferences, const fmi3UInt64 counters[], const fmi3UInt64 resolutions[]) {
    (void)valueReferences; (void)nValueReferences; (void)counters; (void)resolutions;
    return unsupported(instance, "SetShiftFraction");
}

fmi3Status fmi3EvaluateDiscreteStates(fmi3Instance instance) {
    
    return unsupported(instance, "EvaluateDiscreteStates");
}

fmi3Status fmi3GetOutputDerivatives(fmi3Instance instance, const fmi3ValueReference valueReferences[], size_t nValueReferences, const fmi3Int32 orders[], fmi3Float64 values[], size_t nValues) {
    (void)valueReferences; (void)nValueReferences; (void)orders; (void)values; (void)nValues;
    return unsupported(instance, "GetOutputDerivatives");
}

fmi3Status fmi3ActivateModelPartition(fmi3Instance instance, fmi3ValueReference clockReference, fmi3Float64 activationTime) {
    (void)clockReference; (void)activationTime;
    return unsupported(instance, "ActivateModelPartition");
}

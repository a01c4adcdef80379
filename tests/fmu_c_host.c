/* A minimal FMI 2.0 co-simulation master in C, for tests/test_fmu_masters.py.
 *
 * usage: host LIBRARY GUID RESOURCE_URI VR_X_CMD VR_FORCE VR_M_PLATEN M_PLATEN LOADS
 *
 * LOADS times: dlopen the binary, instantiate with logging off, set m_platen in
 * Initialization Mode, exit it, ramp x_cmd over 500 steps of 1 ms, print
 * "<exitInitializationMode status> <input_force>", terminate, free, dlclose.
 * Logged messages go to stderr as "[status] message". Exit 0 unless the API misbehaves.
 */
#include <dlfcn.h>
#include <stdio.h>
#include <stdlib.h>
#include "fmi2Functions.h"

static void log_message(fmi2ComponentEnvironment env, fmi2String name, fmi2Status status,
                        fmi2String category, fmi2String message, ...) {
    (void)env; (void)name; (void)category;
    fprintf(stderr, "[%d] %s\n", (int)status, message);
}

#define LOAD(f) f##TYPE *f = (f##TYPE *)dlsym(lib, #f); if (!f) return 3

static int run(char **argv) {
    void *lib = dlopen(argv[1], RTLD_NOW | RTLD_LOCAL);
    if (!lib) { fprintf(stderr, "%s\n", dlerror()); return 3; }
    LOAD(fmi2Instantiate); LOAD(fmi2SetupExperiment); LOAD(fmi2EnterInitializationMode);
    LOAD(fmi2ExitInitializationMode); LOAD(fmi2SetReal); LOAD(fmi2GetReal);
    LOAD(fmi2DoStep); LOAD(fmi2Terminate); LOAD(fmi2FreeInstance);
    fmi2CallbackFunctions cb = {log_message, calloc, free, NULL, NULL};
    fmi2ValueReference x_cmd = atoi(argv[4]), force = atoi(argv[5]), m_platen = atoi(argv[6]);
    double mass = atof(argv[7]), x0 = -3.4386e-3, x1 = 0.04, y = 0.0;
    fmi2Component c = fmi2Instantiate("host", fmi2CoSimulation, argv[2], argv[3], &cb,
                                      fmi2False, fmi2False);
    if (!c) return 4;
    if (fmi2SetupExperiment(c, fmi2False, 0, 0, fmi2False, 0) != fmi2OK) return 5;
    if (fmi2EnterInitializationMode(c) != fmi2OK) return 5;
    if (fmi2SetReal(c, &x_cmd, 1, &x0) != fmi2OK) return 5;
    if (fmi2SetReal(c, &m_platen, 1, &mass) != fmi2OK) return 5;
    fmi2Status init = fmi2ExitInitializationMode(c);
    if (init == fmi2OK) {
        for (int k = 1; k <= 500; k++) {
            double x = x0 + (x1 - x0) * k / 500.0;
            if (fmi2SetReal(c, &x_cmd, 1, &x) != fmi2OK) return 6;
            if (fmi2DoStep(c, (k - 1) * 1e-3, 1e-3, fmi2True) != fmi2OK) return 6;
        }
        if (fmi2GetReal(c, &force, 1, &y) != fmi2OK) return 7;
        if (fmi2Terminate(c) != fmi2OK) return 8;
    }
    printf("%d %.17g\n", (int)init, y);
    fflush(stdout);
    fmi2FreeInstance(c);
    return dlclose(lib) == 0 ? 0 : 9;
}

int main(int argc, char **argv) {
    if (argc != 9) return 2;
    for (int i = 0; i < atoi(argv[8]); i++) {
        int status = run(argv);
        if (status) return status;
    }
    return 0;
}

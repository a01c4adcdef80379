/* The FMI guard's loading (see fmi2_guard.c): a Python for a host without one, pythonfmu's
 * library and the functions forwarded to it, and the exit handler that finalises Python. */
#define _GNU_SOURCE  /* dladdr, RTLD_NODELETE */
#include <dlfcn.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2_guard.h"

#define DEFINE(f) f##TYPE *in_##f;
INNER(DEFINE)

static void *library;       /* pythonfmu-export.so, loaded once, never unloaded (its thread) */
static int exit_hook;       /* at_exit registered */

/* pythonfmu's library finalises Python from a static object's destructor at exit, after
 * C++ libraries loaded later (casadi) have destroyed their statics, and frees that
 * object twice (static destructor, then its unload hook): a crash at exit in every
 * non-Python host. Finalising first, from an exit handler registered after the slave's
 * imports (so it runs before their destructors), avoids both. */
static void at_exit(void) {
    void (*finalize)(void) = (void (*)(void))dlsym(library, "finalizePythonInterpreter");
    if (finalize) finalize();
}

/* Register at_exit once, with this library pinned so the handler outlives a dlclose. */
void guard_hook_exit(void) {
    Dl_info self;
    if (exit_hook || !dladdr((void *)&guard_hook_exit, &self) ||
        !dlopen(self.dli_fname, RTLD_NOW | RTLD_NOLOAD | RTLD_NODELETE))
        return;
    exit_hook = atexit(at_exit) == 0;
}

/* An interpreter started here sets LC_CTYPE from the environment, and pythonfmu then
 * encodes the resource path in that locale's character set: ASCII where none is set (an
 * empty environment), which fails for a non-ASCII path. As Python's own start-up does
 * (PEP 538), a host that sets no locale gets LC_CTYPE=C.UTF-8. 0 if setenv fails. */
static int utf8_locale(void) {
    const char *names[] = {"LC_ALL", "LC_CTYPE", "LANG"};
    for (size_t i = 0; i < sizeof names / sizeof *names; i++) {
        const char *value = getenv(names[i]);
        if (value && *value) return 1;  /* the host's choice */
    }
    return setenv("LC_CTYPE", "C.UTF-8", 1) == 0;
}

/* libpython of the venv VIRTUAL_ENV names (pyvenv.cfg: "home = <bin>", the library in
 * <bin>/../lib), else GUARD_LIBPYTHON by name (LD_LIBRARY_PATH, the loader's cache). */
static void *open_libpython(void) {
    const char *venv = getenv("VIRTUAL_ENV");
    char cfg[4096], line[4096], lib[4096 + 64];
    if (venv && *venv && snprintf(cfg, sizeof cfg, "%s/pyvenv.cfg", venv) < (int)sizeof cfg) {
        FILE *f = fopen(cfg, "r");
        while (f && fgets(line, sizeof line, f)) {
            char *home = line + strspn(line, " \t");
            if (strncmp(home, "home", 4) != 0) continue;
            home += 4 + strspn(home + 4, " \t");
            if (*home != '=') continue;
            home += 1 + strspn(home + 1, " \t");
            home[strcspn(home, "\r\n")] = '\0';
            if (snprintf(lib, sizeof lib, "%s/../lib/" GUARD_LIBPYTHON, home) < (int)sizeof lib) {
                void *h = dlopen(lib, RTLD_NOW | RTLD_GLOBAL);
                if (h) {  /* its own standard library, not one found on PATH */
                    fclose(f);
                    home[strlen(home) - (strlen(home) > 4 && !strcmp(home + strlen(home) - 4,
                                                                      "/bin") ? 4 : 0)] = '\0';
                    if (!getenv("PYTHONHOME")) setenv("PYTHONHOME", home, 1);
                    return h;
                }
            }
        }
        if (f) fclose(f);
    }
    return dlopen(GUARD_LIBPYTHON, RTLD_NOW | RTLD_GLOBAL);
}

int guard_load(const fmi2CallbackFunctions *cb, fmi2String name, const char *resources) {
    char path[4096];
    if (library) return 1;
    if (!dlsym(RTLD_DEFAULT, "Py_IsInitialized") && (!utf8_locale() || !open_libpython())) {
        cb->logger(cb->componentEnvironment, name, fmi2Error, "logStatusError",
                   "cannot load Python " GUARD_PYTHON " (" GUARD_LIBPYTHON "): set VIRTUAL_ENV to "
                   "a venv of CPython " GUARD_PYTHON " with toggle-clamp installed, or put "
                   GUARD_LIBPYTHON " on the library path");
        return 0;
    }
    if (snprintf(path, sizeof path, "%s/../binaries/" GUARD_PLATFORM "/pythonfmu-export.so",
                 resources) >= (int)sizeof path)
        return 0;
    library = dlopen(path, RTLD_NOW | RTLD_LOCAL);
    if (!library) {
        cb->logger(cb->componentEnvironment, name, fmi2Error, "logStatusError",
                   "cannot load pythonfmu-export.so next to the guard");
        return 0;
    }
#define LOAD(f) if (!(in_##f = (f##TYPE *)dlsym(library, #f))) return 0;
    INNER(LOAD)
    return 1;
}

/*
 * fmi2_status_shim.c: a thin FMI 2.0 co-simulation wrapper around the pythonfmu
 * export library, so that a Python facade can report fmi2Warning / fmi2Error.
 *
 * Why: pythonfmu 0.7 turns every Python exception into fmi2Fatal, and a fatal status
 * forbids the host to call the instance again. A serious FMU rejects a bad parameter
 * with fmi2Error and a message naming it. Our facades never raise into the bridge;
 * they log the problem with status warning or error through the FMU logger. This shim
 * sits in binaries/<platform>/<modelIdentifier>.so, loads the real pythonfmu library
 * (renamed pythonfmu-export.so next to it), forwards every call, watches the log
 * messages emitted during the call, and returns the worst status logged (capped at
 * fmi2Error) when the call itself returned fmi2OK. A real fmi2Fatal from the bridge
 * (an exception that escaped a facade) stays fatal.
 *
 * The inner library only delivers log messages while debug logging is on, so the shim
 * keeps it on and filters itself: messages of status warning and worse always reach the
 * host (the FMI standard expects errors to be reported whatever the debug setting),
 * others only while the host has debug logging on.
 *
 * It also forwards log messages as "%s" arguments: pythonfmu passes the message as the
 * format string, which would make a '%' in a traceback undefined behaviour in the host.
 */
#define _GNU_SOURCE
#include <dlfcn.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"

#define REAL_LIB_NAME "pythonfmu-export.so"

typedef struct {
    fmi2Component inner;
    fmi2CallbackFunctions host;  /* copy of the host's callbacks */
    fmi2CallbackFunctions mine;  /* handed to the inner library */
    fmi2Status worst;            /* worst status logged during the current call */
    int host_logging;            /* host asked for debug logging */
} Shim;

static void *real_lib = NULL;

/*
 * pythonfmu 0.7 keeps its interpreter guard in a namespace-scope
 * std::shared_ptr<PyState> and also resets that pointer from an
 * __attribute__((destructor)) (finalizePythonInterpreter). When the process exits with
 * the library still loaded, exit() first runs the shared_ptr's static destructor (an
 * atexit entry registered when the library was loaded), which frees the control block
 * but leaves the pointer in place, and then _dl_fini runs the ELF destructor, which
 * decrements the use count inside the freed block: a write into a free heap chunk
 * (its "bk" link when the chunk is in an unsorted/small bin), reported by glibc as
 * "corrupted double-linked list" at some later free() during exit. Calling
 * finalizePythonInterpreter from an atexit entry registered after the library was loaded
 * runs it first (exit handlers run last-registered first), so the pointer is already
 * null when the static and ELF destructors run and both become no-ops.
 */
static void (*real_finalize)(void) = NULL;

static void finalize_real_at_exit(void)
{
    if (real_finalize) real_finalize();
}

/* Keep this library mapped until exit: the atexit entry above belongs to it, and the
 * real library is never unloaded either (a dlclose by the host must not run the entry
 * early, while other instances of the FMU may still be alive). */
static void pin_self(const char *self_path)
{
    (void)dlopen(self_path, RTLD_NOW | RTLD_NOLOAD | RTLD_NODELETE);
}

/* Every FMI 2.0 co-simulation function, listed once (X-macro). */
#define FMI2_FUNCTIONS(X) \
    X(fmi2GetTypesPlatform) X(fmi2GetVersion) X(fmi2SetDebugLogging) \
    X(fmi2Instantiate) X(fmi2FreeInstance) X(fmi2SetupExperiment) \
    X(fmi2EnterInitializationMode) X(fmi2ExitInitializationMode) X(fmi2Terminate) \
    X(fmi2Reset) X(fmi2GetReal) X(fmi2GetInteger) X(fmi2GetBoolean) \
    X(fmi2GetString) X(fmi2SetReal) X(fmi2SetInteger) X(fmi2SetBoolean) \
    X(fmi2SetString) X(fmi2GetFMUstate) X(fmi2SetFMUstate) X(fmi2FreeFMUstate) \
    X(fmi2SerializedFMUstateSize) X(fmi2SerializeFMUstate) \
    X(fmi2DeSerializeFMUstate) X(fmi2GetDirectionalDerivative) \
    X(fmi2SetRealInputDerivatives) X(fmi2GetRealOutputDerivatives) X(fmi2DoStep) \
    X(fmi2CancelStep) X(fmi2GetStatus) X(fmi2GetRealStatus) \
    X(fmi2GetIntegerStatus) X(fmi2GetBooleanStatus) X(fmi2GetStringStatus)

#define REAL(name) static name##TYPE *real_##name = NULL;
FMI2_FUNCTIONS(REAL)
#undef REAL

static int load_real(void)
{
    if (real_lib) return 1;
    Dl_info info;
    if (!dladdr((void *)&load_real, &info) || !info.dli_fname) return 0;
    char path[4096];
    const char *slash = strrchr(info.dli_fname, '/');
    size_t dir_len = slash ? (size_t)(slash - info.dli_fname + 1) : 0;
    if (dir_len + strlen(REAL_LIB_NAME) + 1 > sizeof path) return 0;
    memcpy(path, info.dli_fname, dir_len);
    strcpy(path + dir_len, REAL_LIB_NAME);
    void *lib = dlopen(path, RTLD_NOW | RTLD_LOCAL);
    if (!lib) return 0;
#define LOAD(name) real_##name = (name##TYPE *)dlsym(lib, #name); if (!real_##name) return 0;
    FMI2_FUNCTIONS(LOAD)
#undef LOAD
    real_lib = lib;
    real_finalize = (void (*)(void))dlsym(lib, "finalizePythonInterpreter");
    if (real_finalize) {
        pin_self(info.dli_fname);
        atexit(finalize_real_at_exit);
    }
    return 1;
}

static void shim_logger(fmi2ComponentEnvironment env, fmi2String instance_name,
                        fmi2Status status, fmi2String category, fmi2String message, ...)
{
    Shim *s = (Shim *)env;
    fmi2Status counted = status == fmi2Fatal ? fmi2Error : status;
    if ((counted == fmi2Warning || counted == fmi2Error) && counted > s->worst)
        s->worst = counted;
    if (status < fmi2Warning && !s->host_logging) return;
    if (s->host.logger)
        s->host.logger(s->host.componentEnvironment, instance_name, status, category,
                       "%s", message ? message : "");
}

static fmi2Status merge(Shim *s, fmi2Status real)
{
    fmi2Status worst = s->worst;
    s->worst = fmi2OK;
    if (real == fmi2OK && worst > fmi2OK) return worst;
    return real;
}

#define CALL(expr) do { s->worst = fmi2OK; fmi2Status _st = (expr); return merge(s, _st); } while (0)
#define SHIM(c) Shim *s = (Shim *)(c); if (!s) return fmi2Error;

const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation,
                              const fmi2CallbackFunctions *functions, fmi2Boolean visible,
                              fmi2Boolean loggingOn)
{
    if (!load_real()) {
        if (functions && functions->logger)
            functions->logger(functions->componentEnvironment, instanceName, fmi2Fatal,
                              "logStatusFatal", "%s",
                              "cannot load " REAL_LIB_NAME " next to the FMU binary");
        return NULL;
    }
    Shim *s = (Shim *)calloc(1, sizeof(Shim));
    if (!s) return NULL;
    if (functions) s->host = *functions;
    s->mine = s->host;
    s->mine.logger = shim_logger;
    s->mine.componentEnvironment = s;
    s->host_logging = loggingOn == fmi2True;
    s->inner = real_fmi2Instantiate(instanceName, fmuType, fmuGUID, fmuResourceLocation,
                                    &s->mine, visible, fmi2True);
    if (!s->inner) {
        free(s);
        return NULL;
    }
    return s;
}

void fmi2FreeInstance(fmi2Component c)
{
    Shim *s = (Shim *)c;
    if (!s) return;
    real_fmi2FreeInstance(s->inner);
    free(s);
}

fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean on, size_t n, const fmi2String cats[])
{
    /* The inner library keeps logging everything; the shim filters (see above). */
    SHIM(c)
    (void)n; (void)cats;
    s->host_logging = on == fmi2True;
    CALL(real_fmi2SetDebugLogging(s->inner, fmi2True, 0, NULL));
}
fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean td, fmi2Real tol, fmi2Real t0,
                               fmi2Boolean sd, fmi2Real t1)
{ SHIM(c) CALL(real_fmi2SetupExperiment(s->inner, td, tol, t0, sd, t1)); }
fmi2Status fmi2EnterInitializationMode(fmi2Component c)
{ SHIM(c) CALL(real_fmi2EnterInitializationMode(s->inner)); }
fmi2Status fmi2ExitInitializationMode(fmi2Component c)
{ SHIM(c) CALL(real_fmi2ExitInitializationMode(s->inner)); }
fmi2Status fmi2Terminate(fmi2Component c) { SHIM(c) CALL(real_fmi2Terminate(s->inner)); }
fmi2Status fmi2Reset(fmi2Component c) { SHIM(c) CALL(real_fmi2Reset(s->inner)); }
fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Real v[])
{ SHIM(c) CALL(real_fmi2GetReal(s->inner, vr, n, v)); }
fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Integer v[])
{ SHIM(c) CALL(real_fmi2GetInteger(s->inner, vr, n, v)); }
fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Boolean v[])
{ SHIM(c) CALL(real_fmi2GetBoolean(s->inner, vr, n, v)); }
fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2String v[])
{ SHIM(c) CALL(real_fmi2GetString(s->inner, vr, n, v)); }
fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Real v[])
{ SHIM(c) CALL(real_fmi2SetReal(s->inner, vr, n, v)); }
fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Integer v[])
{ SHIM(c) CALL(real_fmi2SetInteger(s->inner, vr, n, v)); }
fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Boolean v[])
{ SHIM(c) CALL(real_fmi2SetBoolean(s->inner, vr, n, v)); }
fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2String v[])
{ SHIM(c) CALL(real_fmi2SetString(s->inner, vr, n, v)); }
fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *st)
{ SHIM(c) CALL(real_fmi2GetFMUstate(s->inner, st)); }
fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate st)
{ SHIM(c) CALL(real_fmi2SetFMUstate(s->inner, st)); }
fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *st)
{ SHIM(c) CALL(real_fmi2FreeFMUstate(s->inner, st)); }
fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate st, size_t *size)
{ SHIM(c) CALL(real_fmi2SerializedFMUstateSize(s->inner, st, size)); }
fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate st, fmi2Byte b[], size_t size)
{ SHIM(c) CALL(real_fmi2SerializeFMUstate(s->inner, st, b, size)); }
fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte b[], size_t size, fmi2FMUstate *st)
{ SHIM(c) CALL(real_fmi2DeSerializeFMUstate(s->inner, b, size, st)); }
fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference u[], size_t nu,
                                        const fmi2ValueReference z[], size_t nz,
                                        const fmi2Real dv[], fmi2Real dz[])
{ SHIM(c) CALL(real_fmi2GetDirectionalDerivative(s->inner, u, nu, z, nz, dv, dz)); }
fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                                       const fmi2Integer order[], const fmi2Real v[])
{ SHIM(c) CALL(real_fmi2SetRealInputDerivatives(s->inner, vr, n, order, v)); }
fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                                        const fmi2Integer order[], fmi2Real v[])
{ SHIM(c) CALL(real_fmi2GetRealOutputDerivatives(s->inner, vr, n, order, v)); }
fmi2Status fmi2DoStep(fmi2Component c, fmi2Real t, fmi2Real h, fmi2Boolean noPrior)
{ SHIM(c) CALL(real_fmi2DoStep(s->inner, t, h, noPrior)); }
fmi2Status fmi2CancelStep(fmi2Component c) { SHIM(c) CALL(real_fmi2CancelStep(s->inner)); }
fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind k, fmi2Status *v)
{ SHIM(c) CALL(real_fmi2GetStatus(s->inner, k, v)); }
fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind k, fmi2Real *v)
{ SHIM(c) CALL(real_fmi2GetRealStatus(s->inner, k, v)); }
fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind k, fmi2Integer *v)
{ SHIM(c) CALL(real_fmi2GetIntegerStatus(s->inner, k, v)); }
fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind k, fmi2Boolean *v)
{ SHIM(c) CALL(real_fmi2GetBooleanStatus(s->inner, k, v)); }
fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind k, fmi2String *v)
{ SHIM(c) CALL(real_fmi2GetStringStatus(s->inner, k, v)); }

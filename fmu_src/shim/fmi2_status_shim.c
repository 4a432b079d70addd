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
 *
 * Hosts that are not Python processes (docs/methods.md §6.5, §6.12): pythonfmu's library expects
 * the Python C API to be loaded already (LD_PRELOAD of libpython) and initialises the
 * interpreter on a thread of its own, which it finalises at exit; finalising scipy's
 * extension modules there crashed C hosts at exit. At the first fmi2Instantiate the
 * shim therefore makes sure an interpreter is there: if the process has none, it asks a
 * Python executable where its libpython and its sys.path are (GYRODIAG_PYTHON, else
 * $VIRTUAL_ENV/bin/python, else python3 on PATH), loads that libpython with
 * RTLD_GLOBAL, initialises it on the calling thread without signal handlers, gives it
 * that sys.path, and releases the GIL. pythonfmu then finds an initialised interpreter
 * and, as in a Python host, neither initialises nor finalises it: the interpreter lives
 * until the process exits (no Py_Finalize, as is usual for embedded interpreters that
 * run extension modules).
 *
 * FMU states (docs/methods.md §6.14): pythonfmu hands out a Python object as fmi2FMUstate and
 * turns any problem with state bytes into fmi2Fatal (a dead instance). The shim wraps
 * every state it hands out (it only accepts its own, by address, so a state of another
 * FMU is refused without being touched) and frames serialized states with a header
 * (magic, the FMU's GUID, payload length, FNV-1a 64 checksum), checked before the bytes
 * reach Python: truncated, corrupt or foreign bytes give fmi2Error naming the problem,
 * and the instance is left as it was.
 */
#define _GNU_SOURCE
#include <dlfcn.h>
#include <pthread.h>
#include <spawn.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/wait.h>
#include <unistd.h>

#include "fmi2Functions.h"

#define REAL_LIB_NAME "pythonfmu-export.so"

typedef struct {
    fmi2Component inner;
    fmi2CallbackFunctions host;  /* copy of the host's callbacks */
    fmi2CallbackFunctions mine;  /* handed to the inner library */
    fmi2Status worst;            /* worst status logged during the current call */
    int host_logging;            /* host asked for debug logging */
    char *guid;                  /* the FMU's GUID, written into serialized states */
    char *name;                  /* instance name, for the shim's own messages */
} Shim;

/* The shim's own messages: through the host's logger, counted like the inner ones. */
static void shim_log(Shim *s, fmi2Status status, const char *fmt, ...)
{
    char text[2048];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(text, sizeof text, fmt, ap);
    va_end(ap);
    if (status > s->worst) s->worst = status;
    if (s->host.logger)
        s->host.logger(s->host.componentEnvironment, s->name, status,
                       status == fmi2Error ? "logStatusError" : "logStatusWarning", "%s", text);
}

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

/* ---------------------------------------------------------------------------------------
 * An interpreter for hosts that are not Python processes (see the top of this file).
 * Only stable-ABI functions of the C API are used, looked up by name.
 * ------------------------------------------------------------------------------------- */
static pthread_mutex_t python_lock = PTHREAD_MUTEX_INITIALIZER;
static int python_state = 0;          /* 0 not checked, 1 ready, -1 failed */
static char python_error[3072];

/* Asked of the Python executable: its version, its libpython candidates, its sys.path. */
static const char PYTHON_QUERY[] =
    "import os, sys, sysconfig\n"
    "v = sysconfig.get_config_var\n"
    "print('V %d.%d' % sys.version_info[:2])\n"
    "names = [n for n in (v('INSTSONAME'), v('LDLIBRARY')) if n and '.so' in n]\n"
    "dirs = [d for d in (v('LIBDIR'), os.path.join(sys.base_prefix, 'lib'), v('LIBPL')) if d]\n"
    "for n in names:\n"
    "    for d in dirs:\n"
    "        if os.path.exists(os.path.join(d, n)): print('L ' + os.path.join(d, n))\n"
    "    print('L ' + n)\n"
    "for p in sys.path[1:]: print('P ' + p)\n";

/* Run `python -c PYTHON_QUERY`; returns its output (malloc'd) or NULL. */
static char *query_python(const char *python, int search_path)
{
    int fds[2];
    if (pipe(fds) != 0) return NULL;
    posix_spawn_file_actions_t actions;
    posix_spawn_file_actions_init(&actions);
    posix_spawn_file_actions_adddup2(&actions, fds[1], 1);
    posix_spawn_file_actions_adddup2(&actions, fds[1], 2);
    posix_spawn_file_actions_addclose(&actions, fds[0]);
    char *argv[] = {(char *)python, (char *)"-c", (char *)PYTHON_QUERY, NULL};
    extern char **environ;
    pid_t pid;
    int rc = search_path ? posix_spawnp(&pid, python, &actions, NULL, argv, environ)
                         : posix_spawn(&pid, python, &actions, NULL, argv, environ);
    posix_spawn_file_actions_destroy(&actions);
    close(fds[1]);
    if (rc != 0) { close(fds[0]); return NULL; }
    size_t cap = 8192, len = 0;
    char *out = malloc(cap);
    ssize_t got;
    while (out && (got = read(fds[0], out + len, cap - len - 1)) > 0) {
        len += (size_t)got;
        if (len + 1 == cap) { char *more = realloc(out, cap *= 2); if (!more) { free(out); out = NULL; } else out = more; }
    }
    close(fds[0]);
    int status = 0;
    while (waitpid(pid, &status, 0) < 0) {}
    if (!out) return NULL;
    out[len] = '\0';
    if (!WIFEXITED(status) || WEXITSTATUS(status) != 0) {
        snprintf(python_error, sizeof python_error, "%.900s failed: %.2000s", python, out);
        free(out);
        return NULL;
    }
    return out;
}

typedef int (*py_int_void)(void);
typedef void (*py_void_int)(int);
typedef void *(*py_ptr_void)(void);
typedef const char *(*py_str_void)(void);

static int python_setup(void)
{
    py_int_void is_initialized = (py_int_void)dlsym(RTLD_DEFAULT, "Py_IsInitialized");
    if (is_initialized && is_initialized()) return 1;   /* a Python host: nothing to do */

    /* Which Python: GYRODIAG_PYTHON, the active virtual environment, python3 on PATH. */
    char chosen[4096];
    int search = 0;
    const char *env = getenv("GYRODIAG_PYTHON"), *venv = getenv("VIRTUAL_ENV");
    if (env && *env) snprintf(chosen, sizeof chosen, "%s", env);
    else if (venv && *venv) {
        snprintf(chosen, sizeof chosen, "%s/bin/python", venv);
        if (access(chosen, X_OK) != 0) { snprintf(chosen, sizeof chosen, "python3"); search = 1; }
    } else { snprintf(chosen, sizeof chosen, "python3"); search = 1; }
    python_error[0] = '\0';
    char *answer = query_python(chosen, search);
    if (!answer && !is_initialized) {
        if (!python_error[0])
            snprintf(python_error, sizeof python_error,
                     "cannot run %.900s to find the Python these FMUs need; set GYRODIAG_PYTHON "
                     "to a python executable that has the packages of "
                     "resources/requirements.txt", chosen);
        return 0;
    }
    char version[16] = "";
    if (answer && !is_initialized) {
        /* load a libpython with its symbols global, for pythonfmu's library */
        char *lines = strdup(answer), *save = NULL;
        for (char *line = lines ? strtok_r(lines, "\n", &save) : NULL; line;
             line = strtok_r(NULL, "\n", &save)) {
            if (strncmp(line, "L ", 2) == 0 && dlopen(line + 2, RTLD_NOW | RTLD_GLOBAL)) break;
        }
        free(lines);
        is_initialized = (py_int_void)dlsym(RTLD_DEFAULT, "Py_IsInitialized");
        if (!is_initialized) {
            snprintf(python_error, sizeof python_error,
                     "%.900s has no loadable shared libpython (a Python built with "
                     "--enable-shared, or the distribution's libpython3.X package); set "
                     "GYRODIAG_PYTHON to one that has", chosen);
            free(answer);
            return 0;
        }
    }
    if (is_initialized()) { free(answer); return 1; }

    py_void_int initialize = (py_void_int)dlsym(RTLD_DEFAULT, "Py_InitializeEx");
    py_ptr_void save_thread = (py_ptr_void)dlsym(RTLD_DEFAULT, "PyEval_SaveThread");
    py_str_void get_version = (py_str_void)dlsym(RTLD_DEFAULT, "Py_GetVersion");
    void *(*list_new)(long) = (void *(*)(long))dlsym(RTLD_DEFAULT, "PyList_New");
    int (*list_append)(void *, void *) = (int (*)(void *, void *))dlsym(RTLD_DEFAULT, "PyList_Append");
    long (*list_size)(void *) = (long (*)(void *))dlsym(RTLD_DEFAULT, "PyList_Size");
    void *(*list_get)(void *, long) = (void *(*)(void *, long))dlsym(RTLD_DEFAULT, "PyList_GetItem");
    int (*contains)(void *, void *) = (int (*)(void *, void *))dlsym(RTLD_DEFAULT, "PySequence_Contains");
    void *(*decode)(const char *) = (void *(*)(const char *))dlsym(RTLD_DEFAULT, "PyUnicode_DecodeFSDefault");
    void *(*sys_get)(const char *) = (void *(*)(const char *))dlsym(RTLD_DEFAULT, "PySys_GetObject");
    int (*sys_set)(const char *, void *) = (int (*)(const char *, void *))dlsym(RTLD_DEFAULT, "PySys_SetObject");
    void (*dec_ref)(void *) = (void (*)(void *))dlsym(RTLD_DEFAULT, "Py_DecRef");
    if (!initialize || !save_thread || !get_version || !list_new || !list_append || !list_size ||
        !list_get || !contains || !decode || !sys_get || !sys_set || !dec_ref) {
        snprintf(python_error, sizeof python_error, "the loaded libpython lacks C-API functions");
        free(answer);
        return 0;
    }
    initialize(0);   /* 0: leave the host's signal handlers alone */
    if (answer) {
        char *p = strstr(answer, "V ");
        if (p) sscanf(p + 2, "%15s", version);
    }
    size_t vlen = strlen(version);
    const char *running = get_version();
    if (answer && vlen && strncmp(running, version, vlen) == 0 && running[vlen] == '.') {
        /* the asked interpreter's sys.path first (its site-packages, .pth entries and
         * PYTHONPATH), then whatever else the embedded one found */
        void *path = list_new(0);
        char *save = NULL;
        for (char *line = strtok_r(answer, "\n", &save); line && path;
             line = strtok_r(NULL, "\n", &save)) {
            if (strncmp(line, "P ", 2) != 0) continue;
            void *item = decode(line + 2);
            if (item) { list_append(path, item); dec_ref(item); }
        }
        void *old = sys_get("path");
        for (long i = 0; old && path && i < list_size(old); i++) {
            void *item = list_get(old, i);
            if (contains(path, item) == 0) list_append(path, item);
        }
        if (path) { sys_set("path", path); dec_ref(path); }
    }
    free(answer);
    save_thread();   /* pythonfmu takes the GIL with PyGILState_Ensure on any thread */
    return 1;
}

static int python_ready(void)
{
    pthread_mutex_lock(&python_lock);
    if (python_state == 0) python_state = python_setup() ? 1 : -1;
    int ok = python_state == 1;
    pthread_mutex_unlock(&python_lock);
    return ok;
}

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
    const char *problem = NULL;
    if (!python_ready()) problem = python_error;
    else if (!load_real()) problem = "cannot load " REAL_LIB_NAME " next to the FMU binary";
    if (problem) {
        if (functions && functions->logger)
            functions->logger(functions->componentEnvironment, instanceName, fmi2Error,
                              "logStatusError", "%s", problem);
        return NULL;
    }
    Shim *s = (Shim *)calloc(1, sizeof(Shim));
    if (!s) return NULL;
    if (functions) s->host = *functions;
    s->mine = s->host;
    s->mine.logger = shim_logger;
    s->mine.componentEnvironment = s;
    s->host_logging = loggingOn == fmi2True;
    s->guid = strdup(fmuGUID ? fmuGUID : "");
    s->name = strdup(instanceName ? instanceName : "");
    s->inner = real_fmi2Instantiate(instanceName, fmuType, fmuGUID, fmuResourceLocation,
                                    &s->mine, visible, fmi2True);
    if (!s->inner || !s->guid || !s->name) {
        if (s->inner) real_fmi2FreeInstance(s->inner);
        free(s->guid);
        free(s->name);
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
    free(s->guid);
    free(s->name);
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
/* ---------------------------------------------------------------------------------------
 * FMU states (see the top of this file)
 * ------------------------------------------------------------------------------------- */
typedef struct ShimState {
    struct ShimState *next;
    char *guid;              /* FMU that made it */
    fmi2FMUstate inner;      /* pythonfmu's state object */
} ShimState;

static pthread_mutex_t states_lock = PTHREAD_MUTEX_INITIALIZER;
static ShimState *states = NULL;   /* every live state handed out by this library */

/* Serialized state: MAGIC, u32 GUID length, GUID, u64 payload length, u64 FNV-1a 64 of
 * GUID and payload, payload (pythonfmu's bytes). Integers little-endian. */
static const char STATE_MAGIC[8] = {'G', 'D', 'F', 'M', 'U', 'S', 'T', '1'};

static int state_is_ours(fmi2FMUstate st)
{
    pthread_mutex_lock(&states_lock);
    ShimState *p = states;
    while (p && (fmi2FMUstate)p != st) p = p->next;
    pthread_mutex_unlock(&states_lock);
    return p != NULL;
}

static ShimState *state_new(const char *guid, fmi2FMUstate inner)
{
    ShimState *st = calloc(1, sizeof *st);
    if (!st || !(st->guid = strdup(guid))) { free(st); return NULL; }
    st->inner = inner;
    pthread_mutex_lock(&states_lock);
    st->next = states;
    states = st;
    pthread_mutex_unlock(&states_lock);
    return st;
}

static void state_forget(ShimState *st)
{
    pthread_mutex_lock(&states_lock);
    for (ShimState **p = &states; *p; p = &(*p)->next)
        if (*p == st) { *p = st->next; break; }
    pthread_mutex_unlock(&states_lock);
    free(st->guid);
    free(st);
}

/* The state `st` if this FMU may use it, else NULL with an error logged. */
static ShimState *own_state(Shim *s, fmi2FMUstate st, const char *call)
{
    if (!st) {
        shim_log(s, fmi2Error, "%s: the FMU state is NULL", call);
        return NULL;
    }
    if (!state_is_ours(st)) {
        shim_log(s, fmi2Error, "%s: foreign FMU state: not a live state of this FMU (made by "
                 "another FMU, already freed, or not an FMU state); the instance is unchanged",
                 call);
        return NULL;
    }
    ShimState *mine = (ShimState *)st;
    if (strcmp(mine->guid, s->guid) != 0) {
        shim_log(s, fmi2Error, "%s: foreign FMU state: made by the FMU with GUID %s, this FMU "
                 "has GUID %s; the instance is unchanged", call, mine->guid, s->guid);
        return NULL;
    }
    return mine;
}

static uint64_t fnv1a64(uint64_t h, const unsigned char *p, size_t n)
{
    for (size_t i = 0; i < n; i++) { h ^= p[i]; h *= 1099511628211ull; }
    return h;
}
static void put_le(unsigned char *p, uint64_t v, int n) { for (int i = 0; i < n; i++) p[i] = (unsigned char)(v >> (8 * i)); }
static uint64_t get_le(const unsigned char *p, int n)
{
    uint64_t v = 0;
    for (int i = n - 1; i >= 0; i--) v = (v << 8) | p[i];
    return v;
}
static size_t state_header_size(const char *guid) { return 8 + 4 + strlen(guid) + 8 + 8; }

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *st)
{
    SHIM(c)
    s->worst = fmi2OK;
    if (!st) { shim_log(s, fmi2Error, "fmi2GetFMUstate: FMUstate pointer is NULL"); return merge(s, fmi2OK); }
    ShimState *old = NULL;
    if (*st) {  /* the standard lets the host pass a state to overwrite */
        if (!(old = own_state(s, *st, "fmi2GetFMUstate"))) return merge(s, fmi2OK);
    }
    fmi2FMUstate inner = NULL;
    fmi2Status status = real_fmi2GetFMUstate(s->inner, &inner);
    if (status > fmi2Warning || !inner) return merge(s, status > fmi2Warning ? status : fmi2Error);
    if (old) {
        fmi2FMUstate previous = old->inner;
        real_fmi2FreeFMUstate(s->inner, &previous);
        old->inner = inner;
        return merge(s, status);
    }
    ShimState *fresh = state_new(s->guid, inner);
    if (!fresh) {
        real_fmi2FreeFMUstate(s->inner, &inner);
        shim_log(s, fmi2Error, "fmi2GetFMUstate: out of memory");
        return merge(s, fmi2OK);
    }
    *st = (fmi2FMUstate)fresh;
    return merge(s, status);
}

fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate st)
{
    SHIM(c)
    s->worst = fmi2OK;
    ShimState *mine = own_state(s, st, "fmi2SetFMUstate");
    if (!mine) return merge(s, fmi2OK);
    CALL(real_fmi2SetFMUstate(s->inner, mine->inner));
}

fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *st)
{
    SHIM(c)
    s->worst = fmi2OK;
    if (!st || !*st) return fmi2OK;
    ShimState *mine = own_state(s, *st, "fmi2FreeFMUstate");
    if (!mine) return merge(s, fmi2OK);
    fmi2FMUstate inner = mine->inner;
    fmi2Status status = real_fmi2FreeFMUstate(s->inner, &inner);
    state_forget(mine);
    *st = NULL;
    return merge(s, status);
}

fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate st, size_t *size)
{
    SHIM(c)
    s->worst = fmi2OK;
    ShimState *mine = own_state(s, st, "fmi2SerializedFMUstateSize");
    if (!mine) return merge(s, fmi2OK);
    size_t payload = 0;
    fmi2Status status = real_fmi2SerializedFMUstateSize(s->inner, mine->inner, &payload);
    if (status <= fmi2Warning) *size = state_header_size(mine->guid) + payload;
    return merge(s, status);
}

fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate st, fmi2Byte b[], size_t size)
{
    SHIM(c)
    s->worst = fmi2OK;
    ShimState *mine = own_state(s, st, "fmi2SerializeFMUstate");
    if (!mine) return merge(s, fmi2OK);
    size_t payload = 0;
    fmi2Status status = real_fmi2SerializedFMUstateSize(s->inner, mine->inner, &payload);
    if (status > fmi2Warning) return merge(s, status);
    size_t guid_len = strlen(mine->guid), header = state_header_size(mine->guid);
    if (size < header + payload) {
        shim_log(s, fmi2Error, "fmi2SerializeFMUstate: buffer of %zu bytes, the state needs %zu "
                 "(ask fmi2SerializedFMUstateSize)", size, header + payload);
        return merge(s, fmi2OK);
    }
    unsigned char *out = (unsigned char *)b;
    status = real_fmi2SerializeFMUstate(s->inner, mine->inner, b + header, payload);
    if (status > fmi2Warning) return merge(s, status);
    memcpy(out, STATE_MAGIC, 8);
    put_le(out + 8, guid_len, 4);
    memcpy(out + 12, mine->guid, guid_len);
    put_le(out + 12 + guid_len, payload, 8);
    uint64_t sum = fnv1a64(14695981039346656037ull, (const unsigned char *)mine->guid, guid_len);
    sum = fnv1a64(sum, out + header, payload);
    put_le(out + 20 + guid_len, sum, 8);
    return merge(s, status);
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte b[], size_t size,
                                   fmi2FMUstate *st)
{
    SHIM(c)
    s->worst = fmi2OK;
    const char *call = "fmi2DeSerializeFMUstate";
    const unsigned char *in = (const unsigned char *)b;
    if (!st || (!b && size)) { shim_log(s, fmi2Error, "%s: NULL argument", call); return merge(s, fmi2OK); }
    if (size < 12) {
        shim_log(s, fmi2Error, "%s: truncated serialized state: %zu bytes, a serialized state of "
                 "this FMU has at least %zu; the instance is unchanged", call, size,
                 state_header_size(s->guid));
        return merge(s, fmi2OK);
    }
    if (memcmp(in, STATE_MAGIC, 8) != 0) {
        shim_log(s, fmi2Error, "%s: not a serialized state of a gyrodiag FMU (no 'GDFMUST1' "
                 "header%s); the instance is unchanged", call,
                 in[0] == '{' ? ": bytes of an FMU without the gyrodiag shim?" : "");
        return merge(s, fmi2OK);
    }
    size_t guid_len = (size_t)get_le(in + 8, 4);
    if (guid_len > 4096 || size < 12 + guid_len + 16) {
        shim_log(s, fmi2Error, "%s: truncated or corrupt serialized state: header of %zu bytes "
                 "announced, %zu bytes given; the instance is unchanged", call,
                 guid_len <= 4096 ? 12 + guid_len + 16 : (size_t)0, size);
        return merge(s, fmi2OK);
    }
    if (guid_len != strlen(s->guid) || memcmp(in + 12, s->guid, guid_len) != 0) {
        shim_log(s, fmi2Error, "%s: foreign serialized state: made by the FMU with GUID %.*s, "
                 "this FMU has GUID %s; the instance is unchanged", call,
                 (int)(guid_len < 200 ? guid_len : 200), (const char *)(in + 12), s->guid);
        return merge(s, fmi2OK);
    }
    size_t header = 12 + guid_len + 16;
    uint64_t payload = get_le(in + 12 + guid_len, 8);
    if (payload != size - header) {
        shim_log(s, fmi2Error, "%s: %s serialized state: %llu payload bytes announced, %zu given; "
                 "the instance is unchanged", call, payload > size - header ? "truncated" : "corrupt",
                 (unsigned long long)payload, size - header);
        return merge(s, fmi2OK);
    }
    uint64_t sum = fnv1a64(14695981039346656037ull, in + 12, guid_len);
    sum = fnv1a64(sum, in + header, (size_t)payload);
    if (sum != get_le(in + 20 + guid_len, 8)) {
        shim_log(s, fmi2Error, "%s: corrupt serialized state: checksum mismatch; the instance "
                 "is unchanged", call);
        return merge(s, fmi2OK);
    }
    fmi2FMUstate inner = NULL;
    fmi2Status status = real_fmi2DeSerializeFMUstate(s->inner, b + header, (size_t)payload, &inner);
    if (status > fmi2Warning || !inner) return merge(s, status > fmi2Warning ? status : fmi2Error);
    if (*st && state_is_ours(*st) && strcmp(((ShimState *)*st)->guid, s->guid) == 0) {
        /* a state of this FMU given for re-use */
        ShimState *old = (ShimState *)*st;
        fmi2FMUstate previous = old->inner;
        real_fmi2FreeFMUstate(s->inner, &previous);
        old->inner = inner;
        return merge(s, status);
    }
    ShimState *fresh = state_new(s->guid, inner);
    if (!fresh) {
        real_fmi2FreeFMUstate(s->inner, &inner);
        shim_log(s, fmi2Error, "%s: out of memory", call);
        return merge(s, fmi2OK);
    }
    *st = (fmi2FMUstate)fresh;
    return merge(s, status);
}

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

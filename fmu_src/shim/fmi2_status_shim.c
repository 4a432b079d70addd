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
 * fmi2Error) when the call itself returned fmi2OK.
 *
 * Wrong calls from a host (issue 32; docs/fmu.md "Errors"): no call of these FMUs returns
 * fmi2Fatal. pythonfmu turns an exception into fmi2Fatal and releases the instance's
 * Python objects on the way (later calls then use freed memory: the Diagnoser crashed
 * in the next call), so the shim refuses, before any Python runs, with fmi2Error and a
 * message naming the problem, leaving the instance as it was:
 *   - a get/set of a value reference this FMU does not have, or of another type (the
 *     table of modelDescription.xml, read at fmi2Instantiate from the directory above
 *     the resources location: it is the interface the host was given);
 *   - a set of a constant, or after fmi2ExitInitializationMode of anything but an input
 *     or a tunable parameter; any set after fmi2Terminate;
 *   - NULL value-reference or value arrays with nvr > 0, a NULL string to set;
 *   - calls in the wrong state: fmi2SetupExperiment or fmi2EnterInitializationMode after
 *     initialisation began, fmi2ExitInitializationMode outside initialisation mode,
 *     fmi2DoStep outside step mode, fmi2Terminate before initialisation or twice;
 *   - fmi2Instantiate with a NULL or empty name, NULL GUID or resources, another GUID
 *     than modelDescription.xml's, or model exchange (NULL, with a message).
 * Without a readable model description the facades check types and value references
 * themselves (gd_fmu_base.py). Should an exception still reach pythonfmu (a bug), the
 * call returns fmi2Error and the instance is marked unusable: every later call except
 * fmi2FreeInstance is refused with fmi2Error, and fmi2FreeInstance frees only the shim's
 * part (pythonfmu's destructor would release the Python objects a second time).
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
 * and the instance is left as it was. fmi2FreeInstance frees the states of the instance
 * that the host did not free (issue 37: a host that forgets states in thousands of
 * instances must not grow the process); later use of such a state is refused like that
 * of any freed state.
 */
#define _GNU_SOURCE
#include <ctype.h>
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

/* One variable of modelDescription.xml (the interface the host was given). */
typedef struct {
    fmi2ValueReference vr;
    char type;          /* 'R' Real, 'I' Integer or Enumeration, 'B' Boolean, 'S' String */
    char causality;     /* 'p' parameter, 'c' calculatedParameter, 'i' input, 'o' output,
                         * 'l' local, 'n' independent */
    char variability;   /* 'k' constant, 'f' fixed, 't' tunable, 'd' discrete, 'c' continuous */
    char *name;
} VarInfo;

/* Where the instance is in the FMI 2.0 co-simulation state machine. */
typedef enum { MODE_INSTANTIATED, MODE_INIT, MODE_STEP, MODE_TERMINATED, MODE_DEAD } Mode;

typedef struct {
    fmi2Component inner;
    fmi2CallbackFunctions host;  /* copy of the host's callbacks */
    fmi2CallbackFunctions mine;  /* handed to the inner library */
    fmi2Status worst;            /* worst status logged during the current call */
    int host_logging;            /* host asked for debug logging */
    char *guid;                  /* the FMU's GUID, written into serialized states */
    char *name;                  /* instance name, for the shim's own messages */
    VarInfo *vars;               /* modelDescription.xml's variables sorted by vr, or NULL */
    size_t n_vars;
    Mode mode;
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
        s->host.logger(s->host.componentEnvironment, s->name ? s->name : "", status,
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
static char python_used[4096];        /* the executable whose interpreter the shim started */

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
    void *(*decode)(const char *) = (void *(*)(const char *))dlsym(RTLD_DEFAULT, "PyUnicode_DecodeFSDefault");
    int (*sys_set)(const char *, void *) = (int (*)(const char *, void *))dlsym(RTLD_DEFAULT, "PySys_SetObject");
    void (*dec_ref)(void *) = (void (*)(void *))dlsym(RTLD_DEFAULT, "Py_DecRef");
    if (!initialize || !save_thread || !get_version || !list_new || !list_append || !decode ||
        !sys_set || !dec_ref) {
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
        /* exactly the asked interpreter's sys.path (its site-packages, .pth entries and
         * PYTHONPATH): the embedded one also found the base installation's site-packages,
         * which would hand a virtual environment without system site packages packages
         * it does not have (issue 37: a missing numpy went unnoticed) */
        void *path = list_new(0);
        char *save = NULL;
        long n = 0;
        for (char *line = strtok_r(answer, "\n", &save); line && path;
             line = strtok_r(NULL, "\n", &save)) {
            if (strncmp(line, "P ", 2) != 0) continue;
            void *item = decode(line + 2);
            if (item) { n += list_append(path, item) == 0; dec_ref(item); }
        }
        if (path && n > 0) sys_set("path", path);
        if (path) dec_ref(path);
    }
    free(answer);
    snprintf(python_used, sizeof python_used, "%s", chosen);
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
    /* no call of this FMU returns fmi2Fatal (see merge), nor does its log say so */
    if (s->host.logger)
        s->host.logger(s->host.componentEnvironment, instance_name, counted, category,
                       "%s", message ? message : "");
}

/* ---------------------------------------------------------------------------------------
 * Wrong calls (see the top of this file): the variables of modelDescription.xml, the
 * state machine, and an instance that pythonfmu has given up.
 * ------------------------------------------------------------------------------------- */
static const char *mode_name(Mode m)
{
    switch (m) {
    case MODE_INSTANTIATED: return "instantiated (before fmi2EnterInitializationMode)";
    case MODE_INIT: return "initialisation mode";
    case MODE_STEP: return "step mode (after fmi2ExitInitializationMode)";
    case MODE_TERMINATED: return "terminated";
    default: return "unusable after an internal error";
    }
}

static fmi2Status merge(Shim *s, fmi2Status real)
{
    fmi2Status worst = s->worst;
    s->worst = fmi2OK;
    if (real == fmi2Fatal && s->mode != MODE_DEAD) {
        /* A Python exception reached pythonfmu, which then released the instance's Python
         * objects: any further call into it would use freed memory. The instance is
         * refused from now on (fmi2Error); fmi2FreeInstance only frees the shim. Other
         * instances are unaffected, so this is no fmi2Fatal. */
        s->mode = MODE_DEAD;
        shim_log(s, fmi2Error, "internal error (see the message above): pythonfmu has "
                 "released this instance's Python object, so the instance cannot continue; "
                 "every further call except fmi2FreeInstance is refused with fmi2Error");
        s->worst = fmi2OK;
        return fmi2Error;
    }
    if (real == fmi2Fatal) return fmi2Error;
    if (real == fmi2OK && worst > fmi2OK) return worst;
    return real;
}

#define CALL(expr) do { s->worst = fmi2OK; fmi2Status _st = (expr); return merge(s, _st); } while (0)
#define SHIM(c) Shim *s = (Shim *)(c); if (!s) return fmi2Error;
/* refuse every call to an instance pythonfmu has given up (see merge) */
#define LIVE(call) if (s->mode == MODE_DEAD) return refuse(s, "%s: refused: this instance is " \
    "unusable since an earlier internal error; call fmi2FreeInstance", call);

/* Log an error for a refused call; the instance is unchanged. */
static fmi2Status refuse(Shim *s, const char *fmt, ...)
{
    char text[2048];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(text, sizeof text, fmt, ap);
    va_end(ap);
    s->worst = fmi2OK;
    shim_log(s, fmi2Error, "%s", text);
    s->worst = fmi2OK;
    return fmi2Error;
}

/* -- modelDescription.xml -------------------------------------------------------------- */
/* The file next to the resources directory given at fmi2Instantiate (a file URI, as
 * pythonfmu reads it, or a plain path). malloc'd, or NULL. */
static char *model_description_path(const char *location)
{
    const char *p = location;
    if (strncmp(p, "file://", 7) == 0) {
        p += 7;
        if (strncmp(p, "localhost/", 10) == 0) p += 9;
    } else if (strncmp(p, "file:", 5) == 0) {
        p += 5;
    }
    size_t n = strlen(p);
    char *path = malloc(n + sizeof "/modelDescription.xml");
    if (!path) return NULL;
    size_t k = 0;
    for (size_t i = 0; i < n; i++) {  /* percent-decoding */
        unsigned int byte;
        if (p[i] == '%' && i + 2 < n && isxdigit((unsigned char)p[i + 1]) &&
            isxdigit((unsigned char)p[i + 2]) && sscanf(p + i + 1, "%2x", &byte) == 1) {
            path[k++] = (char)byte;
            i += 2;
        } else {
            path[k++] = p[i];
        }
    }
    while (k > 1 && path[k - 1] == '/') k--;       /* .../resources/ */
    while (k > 0 && path[k - 1] != '/') k--;       /* drop "resources" */
    strcpy(path + k, "modelDescription.xml");
    return path;
}

static char *read_file(const char *path)
{
    FILE *f = fopen(path, "rb");
    if (!f) return NULL;
    size_t cap = 1 << 16, len = 0, got;
    char *buf = malloc(cap);
    while (buf && (got = fread(buf + len, 1, cap - len - 1, f)) > 0) {
        len += got;
        if (len + 1 == cap) {
            char *more = realloc(buf, cap *= 2);
            if (!more) { free(buf); buf = NULL; } else buf = more;
        }
    }
    fclose(f);
    if (buf) buf[len] = '\0';
    return buf;
}

/* Attribute `name` of the start tag beginning at `tag` (up to its '>'), unescaped into
 * `out` (size `size`); 1 if found. */
static int xml_attribute(const char *tag, const char *end, const char *name, char *out, size_t size)
{
    size_t nlen = strlen(name);
    const char *p = tag;
    while (p < end && *p != ' ' && *p != '\t' && *p != '\n' && *p != '\r') p++;  /* tag name */
    while (p < end) {
        while (p < end && (*p == ' ' || *p == '\t' || *p == '\n' || *p == '\r')) p++;
        const char *a = p;
        while (p < end && *p != '=' && *p != ' ' && *p != '>' && *p != '/') p++;
        size_t alen = (size_t)(p - a);
        while (p < end && *p == ' ') p++;
        if (p >= end || *p != '=') { if (p < end) p++; continue; }
        p++;
        while (p < end && *p == ' ') p++;
        if (p >= end || (*p != '"' && *p != '\'')) return 0;
        char q = *p++;
        const char *v = p;
        while (p < end && *p != q) p++;
        if (alen == nlen && strncmp(a, name, nlen) == 0) {
            size_t k = 0;
            for (const char *x = v; x < p && k + 1 < size; x++) {
                static const struct { const char *ent; char ch; } ents[] = {
                    {"&amp;", '&'}, {"&lt;", '<'}, {"&gt;", '>'}, {"&quot;", '"'}, {"&apos;", '\''}};
                int done = 0;
                for (size_t e = 0; e < sizeof ents / sizeof ents[0] && !done; e++) {
                    size_t el = strlen(ents[e].ent);
                    if ((size_t)(p - x) >= el && strncmp(x, ents[e].ent, el) == 0) {
                        out[k++] = ents[e].ch;
                        x += el - 1;
                        done = 1;
                    }
                }
                if (!done) out[k++] = *x;
            }
            out[k] = '\0';
            return 1;
        }
        if (p < end) p++;
    }
    return 0;
}

static int by_vr(const void *a, const void *b)
{
    fmi2ValueReference x = ((const VarInfo *)a)->vr, y = ((const VarInfo *)b)->vr;
    return x < y ? -1 : x > y;
}

static void free_vars(VarInfo *vars, size_t n)
{
    for (size_t i = 0; vars && i < n; i++) free(vars[i].name);
    free(vars);
}

/* The variables of the model description `xml`; its GUID into `guid`. 1 on success. */
static int parse_model_description(const char *xml, char *guid, size_t guid_size,
                                   VarInfo **vars_out, size_t *n_out)
{
    size_t cap = 256, n = 0;
    VarInfo *vars = calloc(cap, sizeof *vars);
    int open_var = 0;   /* the last ScalarVariable still lacks its type element */
    guid[0] = '\0';
    if (!vars) return 0;
    for (const char *p = strchr(xml, '<'); p; p = strchr(p + 1, '<')) {
        if (strncmp(p, "<!--", 4) == 0) { p = strstr(p, "-->"); if (!p) break; continue; }
        if (p[1] == '?' || p[1] == '/' || p[1] == '!') continue;
        const char *end = p + 1;
        char q = 0;
        while (*end && (q || *end != '>')) {   /* the tag's end, quotes respected */
            if (q && *end == q) q = 0;
            else if (!q && (*end == '"' || *end == '\'')) q = *end;
            end++;
        }
        if (!*end) break;
        const char *tag = p + 1;
        size_t tlen = strcspn(tag, " \t\r\n/>");
        char value[1024];
#define IS(lit) (tlen == sizeof lit - 1 && strncmp(tag, lit, tlen) == 0)
        if (IS("fmiModelDescription")) {
            xml_attribute(tag, end, "guid", guid, guid_size);
        } else if (IS("ScalarVariable")) {
            if (n == cap) {
                VarInfo *more = realloc(vars, (cap *= 2) * sizeof *vars);
                if (!more) { free_vars(vars, n); return 0; }
                vars = more;
            }
            VarInfo *v = &vars[n];
            memset(v, 0, sizeof *v);
            if (!xml_attribute(tag, end, "valueReference", value, sizeof value)) continue;
            v->vr = (fmi2ValueReference)strtoul(value, NULL, 10);
            v->causality = 'l';
            if (xml_attribute(tag, end, "causality", value, sizeof value))
                v->causality = strcmp(value, "calculatedParameter") == 0 ? 'c'
                             : strcmp(value, "independent") == 0 ? 'n' : value[0];
            v->variability = 'c';
            if (xml_attribute(tag, end, "variability", value, sizeof value))
                v->variability = strcmp(value, "constant") == 0 ? 'k' : value[0];
            v->name = strdup(xml_attribute(tag, end, "name", value, sizeof value) ? value : "?");
            if (!v->name) { free_vars(vars, n); return 0; }
            n++;
            open_var = 1;
        } else if (open_var && (IS("Real") || IS("Integer") || IS("Boolean") || IS("String") ||
                                IS("Enumeration"))) {
            vars[n - 1].type = IS("Enumeration") ? 'I' : tag[0];
            open_var = 0;
        }
#undef IS
        p = end;
    }
    size_t k = 0;   /* keep the variables whose type was found */
    for (size_t i = 0; i < n; i++) {
        if (vars[i].type) vars[k++] = vars[i];
        else free(vars[i].name);
    }
    if (k == 0 || !guid[0]) { free_vars(vars, k); return 0; }
    qsort(vars, k, sizeof *vars, by_vr);
    *vars_out = vars;
    *n_out = k;
    return 1;
}

static const VarInfo *find_var(const Shim *s, fmi2ValueReference vr)
{
    VarInfo key = {0};
    key.vr = vr;
    return bsearch(&key, s->vars, s->n_vars, sizeof key, by_vr);
}

static const char *type_name(char t)
{
    return t == 'R' ? "Real" : t == 'I' ? "Integer" : t == 'B' ? "Boolean" : "String";
}

static const char *causality_name(char c)
{
    switch (c) {
    case 'p': return "parameter";
    case 'c': return "calculatedParameter";
    case 'i': return "input";
    case 'o': return "output";
    case 'n': return "independent";
    default: return "local";
    }
}

static const char *variability_name(char v)
{
    switch (v) {
    case 'k': return "constant";
    case 'f': return "fixed";
    case 't': return "tunable";
    case 'd': return "discrete";
    default: return "continuous";
    }
}

/* "a" or "an" before a type name */
static const char *article(char t) { return t == 'I' ? "an" : "a"; }

/* 1 if `text` is well-formed UTF-8 (pythonfmu decodes set strings as UTF-8; a failure
 * there would hand Python a NULL list item) */
static int utf8_ok(const char *text)
{
    const unsigned char *p = (const unsigned char *)text;
    while (*p) {
        int more = *p < 0x80 ? 0 : (*p & 0xE0) == 0xC0 && *p >= 0xC2 ? 1
                 : (*p & 0xF0) == 0xE0 ? 2 : (*p & 0xF8) == 0xF0 && *p <= 0xF4 ? 3 : -1;
        if (more < 0) return 0;
        unsigned cp = more ? *p & (0x3F >> more) : *p;
        p++;
        for (int k = 0; k < more; k++, p++) {
            if ((*p & 0xC0) != 0x80) return 0;
            cp = (cp << 6) | (*p & 0x3F);
        }
        if ((more == 2 && (cp < 0x800 || (cp >= 0xD800 && cp <= 0xDFFF))) ||
            (more == 3 && (cp < 0x10000 || cp > 0x10FFFF)))
            return 0;
    }
    return 1;
}

/* 1 if a get (`set` 0) or set (`set` 1) of type `type` on vr[0..n) may reach Python;
 * else 0 with an error naming each offending value reference logged. */
static int check_access(Shim *s, const char *call, char type, int set,
                        const fmi2ValueReference vr[], size_t n, const void *values)
{
    if (s->mode == MODE_DEAD) {
        refuse(s, "%s: refused: this instance is unusable since an earlier internal error; "
               "call fmi2FreeInstance", call);
        return 0;
    }
    if (set && s->mode == MODE_TERMINATED) {
        refuse(s, "%s: refused: the instance is terminated (fmi2Reset or fmi2FreeInstance "
               "only); nothing was set", call);
        return 0;
    }
    if (n == 0) return 1;
    if (!vr || !values) {
        refuse(s, "%s: the %s array is NULL with nvr = %zu; nothing was %s", call,
               !vr ? "value reference" : "value", n, set ? "set" : "read");
        return 0;
    }
    if (!s->vars) return 1;   /* no table: the Python facade checks (gd_fmu_base.py) */
    size_t bad = 0;
    for (size_t i = 0; i < n; i++) {
        const VarInfo *v = find_var(s, vr[i]);
        char problem[1024];   /* not zero-filled: this loop runs for every value */
        problem[0] = '\0';
        if (!v) {
            snprintf(problem, sizeof problem, "unknown value reference %u (vr[%zu]): this "
                     "FMU has no such variable", vr[i], i);
        } else if (v->type != type) {
            snprintf(problem, sizeof problem, "value reference %u (vr[%zu]) is the %s "
                     "variable '%s' (%s, %s), not %s %s: use fmi2%s%s", vr[i], i,
                     type_name(v->type), v->name, causality_name(v->causality),
                     variability_name(v->variability), article(type), type_name(type),
                     set ? "Set" : "Get",
                     type_name(v->type));
        } else if (set && v->variability == 'k') {
            snprintf(problem, sizeof problem, "value reference %u (vr[%zu]) is the constant "
                     "'%s': a constant cannot be set", vr[i], i, v->name);
        } else if (set && s->mode == MODE_STEP && !(v->causality == 'i' ||
                   (v->causality == 'p' && v->variability == 't'))) {
            snprintf(problem, sizeof problem, "value reference %u (vr[%zu]) is the %s %s %s "
                     "'%s': after fmi2ExitInitializationMode only inputs and tunable "
                     "parameters can be set", vr[i], i, variability_name(v->variability),
                     type_name(v->type), causality_name(v->causality), v->name);
        } else if (set && type == 'S' && !((const fmi2String *)values)[i]) {
            snprintf(problem, sizeof problem, "value[%zu] for value reference %u ('%s') is "
                     "a NULL string", i, vr[i], v->name);
        } else if (set && type == 'S' && !utf8_ok(((const fmi2String *)values)[i])) {
            snprintf(problem, sizeof problem, "value[%zu] for value reference %u ('%s') is "
                     "not valid UTF-8", i, vr[i], v->name);
        }
        if (!problem[0]) continue;
        if (++bad <= 5) shim_log(s, fmi2Error, "%s: %s; nothing was %s", call, problem,
                                 set ? "set" : "read");
    }
    if (bad > 5) shim_log(s, fmi2Error, "%s: %zu value references refused in all (the first "
                          "5 are reported above)", call, bad);
    if (bad) s->worst = fmi2OK;
    return bad == 0;
}

/* 1 if the instance is in one of `allowed` (a bit set of modes), else 0 with an error. */
static int check_mode(Shim *s, const char *call, unsigned allowed, const char *rule)
{
    if (allowed & (1u << s->mode)) return 1;
    if (s->mode == MODE_DEAD)
        refuse(s, "%s: refused: this instance is unusable since an earlier internal error; "
               "call fmi2FreeInstance", call);
    else
        refuse(s, "%s: refused in %s: %s; the instance is unchanged", call,
               mode_name(s->mode), rule);
    return 0;
}
#define M(x) (1u << (x))

const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation,
                              const fmi2CallbackFunctions *functions, fmi2Boolean visible,
                              fmi2Boolean loggingOn)
{
    char problem_text[1200];
    const char *problem = NULL;
    VarInfo *vars = NULL;
    size_t n_vars = 0;
    if (!functions) return NULL;   /* no logger to say why: FMI requires the callbacks */
    if (!instanceName || !*instanceName) problem = "fmi2Instantiate: the instance name is "
        "NULL or empty (FMI requires a non-empty name)";
    else if (fmuType != fmi2CoSimulation) problem = "fmi2Instantiate: this FMU supports "
        "co-simulation only (fmuType must be fmi2CoSimulation)";
    else if (!fmuGUID) problem = "fmi2Instantiate: fmuGUID is NULL";
    else if (!fmuResourceLocation || !*fmuResourceLocation) problem = "fmi2Instantiate: "
        "fmuResourceLocation is NULL or empty: the FMU needs its resources directory";
    if (!problem) {
        char *md_path = model_description_path(fmuResourceLocation);
        char *xml = md_path ? read_file(md_path) : NULL;
        char md_guid[256];
        if (xml && parse_model_description(xml, md_guid, sizeof md_guid, &vars, &n_vars) &&
            strcmp(md_guid, fmuGUID) != 0) {
            snprintf(problem_text, sizeof problem_text, "fmi2Instantiate: fmuGUID %.300s is "
                     "not this FMU's GUID %.300s (modelDescription.xml); instantiate the FMU "
                     "with the GUID of its own model description", fmuGUID, md_guid);
            problem = problem_text;
        }
        free(xml);
        free(md_path);
    }
    if (!problem && !python_ready()) problem = python_error;
    else if (!problem && !load_real()) problem = "cannot load " REAL_LIB_NAME " next to the FMU binary";
    if (problem) {
        free_vars(vars, n_vars);
        if (functions->logger)
            functions->logger(functions->componentEnvironment, instanceName ? instanceName : "",
                              fmi2Error, "logStatusError", "%s", problem);
        return NULL;
    }
    Shim *s = (Shim *)calloc(1, sizeof(Shim));
    if (!s) { free_vars(vars, n_vars); return NULL; }
    s->host = *functions;
    s->mine = s->host;
    s->mine.logger = shim_logger;
    s->mine.componentEnvironment = s;
    s->host_logging = loggingOn == fmi2True;
    s->guid = strdup(fmuGUID);
    s->name = strdup(instanceName);
    s->vars = vars;
    s->n_vars = n_vars;
    s->mode = MODE_INSTANTIATED;
    s->inner = real_fmi2Instantiate(instanceName, fmuType, fmuGUID, fmuResourceLocation,
                                    &s->mine, visible, fmi2True);
    if (!s->inner || !s->guid || !s->name) {
        if (!s->inner)   /* pythonfmu logged why (an ImportError names a missing package) */
            shim_log(s, fmi2Error, "fmi2Instantiate: the model could not be started in %s%s "
                     "(see the message above); it needs the packages of "
                     "resources/requirements.txt there%s", python_used[0] ? "the Python of " :
                     "the host's own Python", python_used, python_used[0] ? ": install them, "
                     "or set GYRODIAG_PYTHON to a python executable that has them" : "");
        if (s->inner) real_fmi2FreeInstance(s->inner);
        free_vars(s->vars, s->n_vars);
        free(s->guid);
        free(s->name);
        free(s);
        return NULL;
    }
    return s;
}

static void free_owned_states(Shim *s);

/* Frees everything the instance holds (issue 37: a host that instantiates and frees an FMU
 * thousands of times in one process must not grow): its FMU states the host did not free,
 * pythonfmu's instance, the shim's table and names. */
void fmi2FreeInstance(fmi2Component c)
{
    Shim *s = (Shim *)c;
    if (!s) return;
    free_owned_states(s);
    /* an instance pythonfmu gave up is not freed by it again: its destructor would release
     * the Python objects a second time (a use after free); its few bytes are leaked */
    if (s->mode != MODE_DEAD) real_fmi2FreeInstance(s->inner);
    free_vars(s->vars, s->n_vars);
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
    if (s->mode == MODE_DEAD) return fmi2OK;
    CALL(real_fmi2SetDebugLogging(s->inner, fmi2True, 0, NULL));
}
fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean td, fmi2Real tol, fmi2Real t0,
                               fmi2Boolean sd, fmi2Real t1)
{
    SHIM(c)
    if (!check_mode(s, "fmi2SetupExperiment", M(MODE_INSTANTIATED), "call it after "
                    "fmi2Instantiate or fmi2Reset, before fmi2EnterInitializationMode"))
        return fmi2Error;
    CALL(real_fmi2SetupExperiment(s->inner, td, tol, t0, sd, t1));
}
fmi2Status fmi2EnterInitializationMode(fmi2Component c)
{
    SHIM(c)
    if (!check_mode(s, "fmi2EnterInitializationMode", M(MODE_INSTANTIATED), "call it once, "
                    "after fmi2Instantiate (or fmi2Reset) and fmi2SetupExperiment"))
        return fmi2Error;
    s->mode = MODE_INIT;
    CALL(real_fmi2EnterInitializationMode(s->inner));
}
fmi2Status fmi2ExitInitializationMode(fmi2Component c)
{
    SHIM(c)
    if (!check_mode(s, "fmi2ExitInitializationMode", M(MODE_INIT), "call it once, after "
                    "fmi2EnterInitializationMode"))
        return fmi2Error;
    s->mode = MODE_STEP;   /* a refused initialisation is reported by each fmi2DoStep */
    CALL(real_fmi2ExitInitializationMode(s->inner));
}
fmi2Status fmi2Terminate(fmi2Component c)
{
    SHIM(c)
    if (!check_mode(s, "fmi2Terminate", M(MODE_INIT) | M(MODE_STEP), "fmi2Terminate ends a "
                    "simulation that was initialised, once (then fmi2Reset or "
                    "fmi2FreeInstance)"))
        return fmi2Error;
    s->mode = MODE_TERMINATED;
    CALL(real_fmi2Terminate(s->inner));
}
fmi2Status fmi2Reset(fmi2Component c)
{
    SHIM(c)
    LIVE("fmi2Reset")
    s->mode = MODE_INSTANTIATED;
    CALL(real_fmi2Reset(s->inner));
}
#define GET_SET(kind, letter, set, ...) \
    SHIM(c) \
    if (!check_access(s, "fmi2" #kind, letter, set, vr, n, v)) return fmi2Error; \
    CALL(real_fmi2##kind(s->inner, vr, n, v));
fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Real v[])
{ GET_SET(GetReal, 'R', 0) }
fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Integer v[])
{ GET_SET(GetInteger, 'I', 0) }
fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Boolean v[])
{ GET_SET(GetBoolean, 'B', 0) }
fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2String v[])
{ GET_SET(GetString, 'S', 0) }
fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Real v[])
{ GET_SET(SetReal, 'R', 1) }
fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Integer v[])
{ GET_SET(SetInteger, 'I', 1) }
fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Boolean v[])
{ GET_SET(SetBoolean, 'B', 1) }
fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2String v[])
{ GET_SET(SetString, 'S', 1) }

/* From here on every call to an instance pythonfmu has given up is refused. */
#undef SHIM
#define SHIM(c) Shim *s = (Shim *)(c); if (!s) return fmi2Error; LIVE(__func__)
/* ---------------------------------------------------------------------------------------
 * FMU states (see the top of this file)
 * ------------------------------------------------------------------------------------- */
typedef struct ShimState {
    struct ShimState *next;
    char *guid;              /* FMU that made it */
    Shim *owner;             /* instance that made it (or last wrote it): freed with it */
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

static ShimState *state_new(Shim *owner, fmi2FMUstate inner)
{
    ShimState *st = calloc(1, sizeof *st);
    if (!st || !(st->guid = strdup(owner->guid))) { free(st); return NULL; }
    st->owner = owner;
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

/* Free every state instance `s` made and the host did not free (fmi2FreeInstance frees
 * all the instance's resources; a host that forgets states must not grow the process). */
static void free_owned_states(Shim *s)
{
    ShimState *mine = NULL;
    pthread_mutex_lock(&states_lock);
    for (ShimState **p = &states; *p;) {
        ShimState *st = *p;
        if (st->owner == s) { *p = st->next; st->next = mine; mine = st; }
        else p = &st->next;
    }
    pthread_mutex_unlock(&states_lock);
    while (mine) {
        ShimState *next = mine->next;
        fmi2FMUstate inner = mine->inner;
        if (inner) real_fmi2FreeFMUstate(s->inner, &inner);   /* a reference drop only */
        free(mine->guid);
        free(mine);
        mine = next;
    }
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
        old->owner = s;
        return merge(s, status);
    }
    ShimState *fresh = state_new(s, inner);
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
    if (!size) {
        shim_log(s, fmi2Error, "fmi2SerializedFMUstateSize: the size pointer is NULL");
        return merge(s, fmi2OK);
    }
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
    if (!b) {
        shim_log(s, fmi2Error, "fmi2SerializeFMUstate: the byte array is NULL");
        return merge(s, fmi2OK);
    }
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
        old->owner = s;
        return merge(s, status);
    }
    ShimState *fresh = state_new(s, inner);
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
{
    SHIM(c)
    if (!check_mode(s, "fmi2DoStep", M(MODE_STEP), "fmi2DoStep is allowed between "
                    "fmi2ExitInitializationMode and fmi2Terminate; the step was not taken"))
        return fmi2Error;
    CALL(real_fmi2DoStep(s->inner, t, h, noPrior));
}
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

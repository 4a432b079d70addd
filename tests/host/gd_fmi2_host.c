/*
 * gd_fmi2_host.c: a minimal FMI 2.0 co-simulation master in plain C, in the spirit of
 * the Reference-FMUs' fmusim, to check that gyrodiag's FMUs run in a host that is not a
 * Python process (docs/methods.md §6.5, §6.12; issue 13).
 *
 *   gd_fmi2_host [--stop S] [--step H] [--set NAME=VALUE]... [--out-dir DIR] FMU_DIR...
 *
 * Each FMU_DIR is an extracted FMU (modelDescription.xml, binaries/linux64/<id>.so,
 * resources/). The FMUs are run one after the other in this one process, as a host
 * that opens several models would: dlopen the binary, instantiate, set the --set start
 * values the model has, initialise, step from 0 to --stop with a fixed step (default:
 * the model's DefaultExperiment stepSize, else 1e-3 s) while every Real input follows
 * the test signal below, terminate, free the instance, dlclose. With --out-dir, the
 * time and every Real/Integer/Boolean output after each step are written to
 * DIR/<modelIdentifier>.csv ("%.17g", so that a test can compare them exactly with
 * another master's run of the same inputs).
 *
 * Test signal of the j-th Real input (j = 0, 1, ... in modelDescription order) at step k:
 *     u_j(k) = ((k * (j + 3)) % 11 - 5) * 0.01 * (j + 1)
 * integer arithmetic then two double products: bit-identical in any language.
 *
 * Exit status: 0 success; 1 an FMI call returned fmi2Error/fmi2Fatal or a model could
 * not be loaded; 2 bad command line. Messages of status warning or worse are printed to
 * stderr as "[STATUS] instance: message".
 *
 * Deliberately nothing Python-specific: no LD_PRELOAD, no PYTHONPATH. The gyrodiag FMU
 * binary finds and loads the Python it needs itself (see the FMU documentation).
 */
#define _GNU_SOURCE
#include <ctype.h>
#include <dlfcn.h>
#include <errno.h>
#include <limits.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"

#define MAX_SETS 256

typedef enum { T_REAL, T_INTEGER, T_BOOLEAN, T_STRING, T_OTHER } VarType;

typedef struct {
    char *name;
    unsigned vr;
    VarType type;
    int is_input, is_output;
} Var;

typedef struct {
    char *guid, *model_identifier;
    double default_step;
    Var *vars;
    size_t n_vars;
} Model;

static const char *STATUS_NAMES[] = {"OK", "WARNING", "DISCARD", "ERROR", "FATAL", "PENDING"};

static void host_logger(fmi2ComponentEnvironment env, fmi2String instance, fmi2Status status,
                        fmi2String category, fmi2String message, ...)
{
    (void)env; (void)category;
    if (status < fmi2Warning) return;
    char text[8192];
    va_list ap;
    va_start(ap, message);
    vsnprintf(text, sizeof text, message ? message : "", ap);
    va_end(ap);
    fprintf(stderr, "[%s] %s: %s\n", status <= fmi2Pending ? STATUS_NAMES[status] : "?",
            instance ? instance : "", text);
}

static char *read_file(const char *path)
{
    FILE *f = fopen(path, "rb");
    if (!f) return NULL;
    if (fseek(f, 0, SEEK_END) != 0) { fclose(f); return NULL; }
    long size = ftell(f);
    rewind(f);
    char *buf = size >= 0 ? malloc((size_t)size + 1) : NULL;
    if (buf && fread(buf, 1, (size_t)size, f) != (size_t)size) { free(buf); buf = NULL; }
    if (buf) buf[size] = '\0';
    fclose(f);
    return buf;
}

/* Value of attribute `key` inside the start tag [tag, end), XML entities decoded. */
static char *attribute(const char *tag, const char *end, const char *key)
{
    size_t klen = strlen(key);
    for (const char *p = tag; p && p + klen + 2 < end; p++) {
        if (!isspace((unsigned char)p[0]) || strncmp(p + 1, key, klen) != 0) continue;
        const char *q = p + 1 + klen;
        while (q < end && isspace((unsigned char)*q)) q++;
        if (q >= end || *q != '=') continue;
        q++;
        while (q < end && isspace((unsigned char)*q)) q++;
        if (q >= end || (*q != '"' && *q != '\'')) continue;
        char quote = *q++;
        const char *stop = memchr(q, quote, (size_t)(end - q));
        if (!stop) return NULL;
        char *out = malloc((size_t)(stop - q) + 1), *o = out;
        static const char *ent[][2] = {{"&quot;", "\""}, {"&apos;", "'"}, {"&lt;", "<"},
                                       {"&gt;", ">"}, {"&amp;", "&"}};
        while (q < stop) {
            int done = 0;
            for (size_t e = 0; e < 5 && *q == '&'; e++) {
                size_t n = strlen(ent[e][0]);
                if ((size_t)(stop - q) >= n && strncmp(q, ent[e][0], n) == 0) {
                    *o++ = ent[e][1][0];
                    q += n;
                    done = 1;
                    break;
                }
            }
            if (!done) *o++ = *q++;
        }
        *o = '\0';
        return out;
    }
    return NULL;
}

/* Start tag "<name ..." at or after `from`: returns its '<', sets *end to its '>'. */
static const char *find_tag(const char *from, const char *name, const char **end)
{
    size_t n = strlen(name);
    for (const char *p = strchr(from, '<'); p; p = strchr(p + 1, '<')) {
        if (strncmp(p + 1, name, n) == 0 && (isspace((unsigned char)p[1 + n]) ||
                                             p[1 + n] == '>' || p[1 + n] == '/')) {
            *end = strchr(p, '>');
            return *end ? p : NULL;
        }
    }
    return NULL;
}

static int parse_model(const char *dir, Model *m)
{
    char path[PATH_MAX];
    snprintf(path, sizeof path, "%s/modelDescription.xml", dir);
    char *xml = read_file(path);
    if (!xml) { fprintf(stderr, "cannot read %s: %s\n", path, strerror(errno)); return 0; }
    const char *end, *tag = find_tag(xml, "fmiModelDescription", &end);
    m->guid = tag ? attribute(tag, end, "guid") : NULL;
    tag = find_tag(xml, "CoSimulation", &end);
    m->model_identifier = tag ? attribute(tag, end, "modelIdentifier") : NULL;
    m->default_step = 0.0;
    tag = find_tag(xml, "DefaultExperiment", &end);
    char *step = tag ? attribute(tag, end, "stepSize") : NULL;
    if (step) { m->default_step = strtod(step, NULL); free(step); }
    if (!m->guid || !m->model_identifier) {
        fprintf(stderr, "%s: no guid or CoSimulation modelIdentifier\n", path);
        free(xml);
        return 0;
    }
    size_t cap = 64;
    m->vars = malloc(cap * sizeof(Var));
    m->n_vars = 0;
    for (const char *p = find_tag(xml, "ScalarVariable", &end); p;
         p = find_tag(end, "ScalarVariable", &end)) {
        const char *tag_end = end;
        if (m->n_vars == cap) m->vars = realloc(m->vars, (cap *= 2) * sizeof(Var));
        Var *v = &m->vars[m->n_vars++];
        v->name = attribute(p, tag_end, "name");
        char *vr = attribute(p, tag_end, "valueReference");
        char *causality = attribute(p, tag_end, "causality");
        v->vr = vr ? (unsigned)strtoul(vr, NULL, 10) : 0;
        v->is_input = causality && strcmp(causality, "input") == 0;
        v->is_output = causality && strcmp(causality, "output") == 0;
        free(vr);
        free(causality);
        /* the type element is the first child, unless the ScalarVariable is empty */
        v->type = T_OTHER;
        if (tag_end[-1] != '/') {
            const char *child = strchr(tag_end, '<');
            while (child && (strncmp(child, "<!--", 4) == 0)) child = strchr(child + 1, '<');
            if (child) {
                if (strncmp(child, "<Real", 5) == 0) v->type = T_REAL;
                else if (strncmp(child, "<Integer", 8) == 0) v->type = T_INTEGER;
                else if (strncmp(child, "<Boolean", 8) == 0) v->type = T_BOOLEAN;
                else if (strncmp(child, "<String", 7) == 0) v->type = T_STRING;
            }
        }
    }
    free(xml);
    return 1;
}

#define CHECK(call) do { fmi2Status st_ = (call); if (st_ > fmi2Warning) { \
    fprintf(stderr, "%s: %s returned %s\n", m.model_identifier, #call, \
            st_ <= fmi2Pending ? STATUS_NAMES[st_] : "?"); goto fail; } } while (0)

typedef struct {
#define MEMBER(name) name##TYPE *name;
    MEMBER(fmi2Instantiate) MEMBER(fmi2FreeInstance) MEMBER(fmi2SetupExperiment)
    MEMBER(fmi2EnterInitializationMode) MEMBER(fmi2ExitInitializationMode)
    MEMBER(fmi2Terminate) MEMBER(fmi2SetReal) MEMBER(fmi2SetInteger) MEMBER(fmi2SetBoolean)
    MEMBER(fmi2GetReal) MEMBER(fmi2GetInteger) MEMBER(fmi2GetBoolean) MEMBER(fmi2DoStep)
#undef MEMBER
} Api;

static int set_value(const Api *api, fmi2Component c, const Var *v, const char *text)
{
    fmi2Status st;
    if (v->type == T_REAL) {
        fmi2Real x = strtod(text, NULL);
        st = api->fmi2SetReal(c, &v->vr, 1, &x);
    } else if (v->type == T_INTEGER) {
        fmi2Integer x = (fmi2Integer)strtol(text, NULL, 10);
        st = api->fmi2SetInteger(c, &v->vr, 1, &x);
    } else if (v->type == T_BOOLEAN) {
        fmi2Boolean x = (strcmp(text, "true") == 0 || strcmp(text, "1") == 0) ? fmi2True : fmi2False;
        st = api->fmi2SetBoolean(c, &v->vr, 1, &x);
    } else {
        fprintf(stderr, "--set %s: only Real, Integer and Boolean variables\n", v->name);
        return 0;
    }
    return st <= fmi2Warning;
}

static int run_fmu(const char *dir, double stop, double step_opt, char **sets, int n_sets,
                   int *set_used, const char *out_dir)
{
    Model m;
    if (!parse_model(dir, &m)) return 0;
    char real_dir[PATH_MAX], lib_path[PATH_MAX + 64], resources[PATH_MAX + 32];
    if (!realpath(dir, real_dir)) { perror(dir); return 0; }
    snprintf(lib_path, sizeof lib_path, "%s/binaries/linux64/%s.so", real_dir,
             m.model_identifier);
    snprintf(resources, sizeof resources, "file://%s/resources", real_dir);
    void *lib = dlopen(lib_path, RTLD_NOW | RTLD_LOCAL);
    if (!lib) { fprintf(stderr, "dlopen %s: %s\n", lib_path, dlerror()); return 0; }
    Api api;
#define LOAD(name) api.name = (name##TYPE *)dlsym(lib, #name); \
    if (!api.name) { fprintf(stderr, "%s: no symbol %s\n", lib_path, #name); return 0; }
    LOAD(fmi2Instantiate) LOAD(fmi2FreeInstance) LOAD(fmi2SetupExperiment)
    LOAD(fmi2EnterInitializationMode) LOAD(fmi2ExitInitializationMode) LOAD(fmi2Terminate)
    LOAD(fmi2SetReal) LOAD(fmi2SetInteger) LOAD(fmi2SetBoolean) LOAD(fmi2GetReal)
    LOAD(fmi2GetInteger) LOAD(fmi2GetBoolean) LOAD(fmi2DoStep)
#undef LOAD

    double h = step_opt > 0 ? step_opt : (m.default_step > 0 ? m.default_step : 1e-3);
    long n_steps = (long)(stop / h + 0.5);
    int ok = 0;
    FILE *out = NULL;
    fmi2CallbackFunctions cb = {host_logger, calloc, free, NULL, NULL};
    fmi2Component c = api.fmi2Instantiate(m.model_identifier, fmi2CoSimulation, m.guid,
                                          resources, &cb, fmi2False, fmi2False);
    if (!c) { fprintf(stderr, "%s: fmi2Instantiate failed\n", m.model_identifier); goto unload; }
    CHECK(api.fmi2SetupExperiment(c, fmi2False, 0.0, 0.0, fmi2True, stop));
    for (int s = 0; s < n_sets; s++) {
        const char *eq = strchr(sets[s], '=');
        for (size_t i = 0; i < m.n_vars; i++) {
            const Var *v = &m.vars[i];
            if (v->name && strlen(v->name) == (size_t)(eq - sets[s]) &&
                strncmp(v->name, sets[s], (size_t)(eq - sets[s])) == 0) {
                if (!set_value(&api, c, v, eq + 1)) {
                    fprintf(stderr, "%s: setting %s failed\n", m.model_identifier, sets[s]);
                    goto fail;
                }
                set_used[s] = 1;
            }
        }
    }
    CHECK(api.fmi2EnterInitializationMode(c));
    CHECK(api.fmi2ExitInitializationMode(c));
    if (out_dir) {
        char path[PATH_MAX + 256];
        snprintf(path, sizeof path, "%s/%s.csv", out_dir, m.model_identifier);
        out = fopen(path, "w");
        if (!out) { perror(path); goto fail; }
        fprintf(out, "time");
        for (size_t i = 0; i < m.n_vars; i++)
            if (m.vars[i].is_output && m.vars[i].type != T_STRING && m.vars[i].type != T_OTHER)
                fprintf(out, ",\"%s\"", m.vars[i].name);
        fprintf(out, "\n");
    }
    for (long k = 0; k < n_steps; k++) {
        double t = k * h;
        long j = 0;
        for (size_t i = 0; i < m.n_vars; i++) {
            const Var *v = &m.vars[i];
            if (!v->is_input || v->type != T_REAL) continue;
            fmi2Real u = (double)((k * (j + 3)) % 11 - 5) * 0.01 * (double)(j + 1);
            CHECK(api.fmi2SetReal(c, &v->vr, 1, &u));
            j++;
        }
        CHECK(api.fmi2DoStep(c, t, h, fmi2True));
        if (!out) continue;
        fprintf(out, "%.17g", (k + 1) * h);
        for (size_t i = 0; i < m.n_vars; i++) {
            const Var *v = &m.vars[i];
            if (!v->is_output) continue;
            if (v->type == T_REAL) {
                fmi2Real x;
                CHECK(api.fmi2GetReal(c, &v->vr, 1, &x));
                fprintf(out, ",%.17g", x);
            } else if (v->type == T_INTEGER) {
                fmi2Integer x;
                CHECK(api.fmi2GetInteger(c, &v->vr, 1, &x));
                fprintf(out, ",%d", x);
            } else if (v->type == T_BOOLEAN) {
                fmi2Boolean x;
                CHECK(api.fmi2GetBoolean(c, &v->vr, 1, &x));
                fprintf(out, ",%d", x ? 1 : 0);
            }
        }
        fprintf(out, "\n");
    }
    CHECK(api.fmi2Terminate(c));
    ok = 1;
fail:
    if (out) fclose(out);
    api.fmi2FreeInstance(c);
unload:
    dlclose(lib);
    for (size_t i = 0; i < m.n_vars; i++) free(m.vars[i].name);
    free(m.vars);
    free(m.guid);
    free(m.model_identifier);
    if (ok) printf("%s: %ld steps of %g s OK\n", dir, n_steps, h);
    return ok;
}

static void usage(void)
{
    fprintf(stderr, "usage: gd_fmi2_host [--stop S] [--step H] [--set NAME=VALUE]... "
                    "[--out-dir DIR] FMU_DIR...\n");
}

int main(int argc, char **argv)
{
    double stop = 1.0, step = 0.0;
    const char *out_dir = NULL;
    char *sets[MAX_SETS];
    int set_used[MAX_SETS] = {0};
    int n_sets = 0, n_dirs = 0;
    char **dirs = calloc((size_t)argc, sizeof(char *));
    for (int i = 1; i < argc; i++) {
        if (strcmp(argv[i], "--stop") == 0 && i + 1 < argc) stop = strtod(argv[++i], NULL);
        else if (strcmp(argv[i], "--step") == 0 && i + 1 < argc) step = strtod(argv[++i], NULL);
        else if (strcmp(argv[i], "--out-dir") == 0 && i + 1 < argc) out_dir = argv[++i];
        else if (strcmp(argv[i], "--set") == 0 && i + 1 < argc && n_sets < MAX_SETS &&
                 strchr(argv[i + 1], '=')) sets[n_sets++] = argv[++i];
        else if (argv[i][0] == '-') { usage(); return 2; }
        else dirs[n_dirs++] = argv[i];
    }
    if (n_dirs == 0 || !(stop > 0)) { usage(); return 2; }
    int ok = 1;
    for (int d = 0; d < n_dirs && ok; d++)
        ok = run_fmu(dirs[d], stop, step, sets, n_sets, set_used, out_dir);
    for (int s = 0; s < n_sets && ok; s++)
        if (!set_used[s]) { fprintf(stderr, "--set %s: no FMU has this variable\n", sets[s]); ok = 0; }
    free(dirs);
    return ok ? 0 : 1;
}

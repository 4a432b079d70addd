/* gyrodiag.common._ckernels: compiled per-sample kernels of the gyrodiag algorithms.
 *
 * The same classes and function as gyrodiag/common/_pykernels.py, with the same arithmetic in
 * the same order (compile with -ffp-contract=off: no fused multiply-add), so that the
 * compiled kernels and the plain-Python fallback give the same outputs to rounding.
 * Written against the CPython stable ABI (Py_LIMITED_API 3.11) and without numpy, so one
 * binary serves every CPython >= 3.11 and every numpy on the platform it is built for.
 * No argument checks beyond types and lengths: the Python classes validate once at
 * their boundary.
 */
#define Py_LIMITED_API 0x030B0000
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

/* Copy a sequence of n floats into out; -1 with an exception on error. */
static int read_doubles(PyObject *seq, double *out, Py_ssize_t n, const char *what)
{
    if (PyTuple_Check(seq) || PyList_Check(seq)) {
        int is_tuple = PyTuple_Check(seq);
        Py_ssize_t len = is_tuple ? PyTuple_Size(seq) : PyList_Size(seq);
        if (len != n) {
            PyErr_Format(PyExc_ValueError, "%s must hold %zd values, got %zd", what, n, len);
            return -1;
        }
        for (Py_ssize_t i = 0; i < n; i++) {
            PyObject *item = is_tuple ? PyTuple_GetItem(seq, i) : PyList_GetItem(seq, i);
            out[i] = PyFloat_AsDouble(item);
            if (out[i] == -1.0 && PyErr_Occurred()) return -1;
        }
        return 0;
    }
    Py_ssize_t len = PySequence_Size(seq);
    if (len < 0) return -1;
    if (len != n) {
        PyErr_Format(PyExc_ValueError, "%s must hold %zd values, got %zd", what, n, len);
        return -1;
    }
    for (Py_ssize_t i = 0; i < n; i++) {
        PyObject *item = PySequence_GetItem(seq, i);
        if (item == NULL) return -1;
        out[i] = PyFloat_AsDouble(item);
        Py_DECREF(item);
        if (out[i] == -1.0 && PyErr_Occurred()) return -1;
    }
    return 0;
}

static PyObject *tuple_of(const double *v, Py_ssize_t n)
{
    PyObject *t = PyTuple_New(n);
    if (t == NULL) return NULL;
    for (Py_ssize_t i = 0; i < n; i++) {
        PyObject *f = PyFloat_FromDouble(v[i]);
        if (f == NULL) { Py_DECREF(t); return NULL; }
        PyTuple_SetItem(t, i, f);
    }
    return t;
}

static PyObject *list_of(const double *v, Py_ssize_t n)
{
    PyObject *t = PyList_New(n);
    if (t == NULL) return NULL;
    for (Py_ssize_t i = 0; i < n; i++) {
        PyObject *f = PyFloat_FromDouble(v[i]);
        if (f == NULL) { Py_DECREF(t); return NULL; }
        PyList_SetItem(t, i, f);
    }
    return t;
}

/* ------------------------------------------------------------------ SosCascade */
typedef struct {
    PyObject_HEAD
    Py_ssize_t n_sections, n_channels;
    double *coef; /* 5 per section: b0 b1 b2 a1 a2 */
    double *z;    /* [section][channel][2] */
    double *x;    /* scratch, n_channels */
} SosObject;

static int Sos_init(SosObject *self, PyObject *args, PyObject *kwds)
{
    PyObject *coef;
    Py_ssize_t ns, nc;
    static char *kwlist[] = {"coefficients", "n_sections", "n_channels", NULL};
    if (!PyArg_ParseTupleAndKeywords(args, kwds, "Onn", kwlist, &coef, &ns, &nc)) return -1;
    if (ns < 1 || nc < 1) {
        PyErr_SetString(PyExc_ValueError, "n_sections and n_channels must be >= 1");
        return -1;
    }
    free(self->coef); free(self->z); free(self->x);
    self->coef = malloc(sizeof(double) * 5 * ns);
    self->z = calloc(2 * ns * nc, sizeof(double));
    self->x = malloc(sizeof(double) * nc);
    if (!self->coef || !self->z || !self->x) { PyErr_NoMemory(); return -1; }
    self->n_sections = ns;
    self->n_channels = nc;
    return read_doubles(coef, self->coef, 5 * ns, "coefficients");
}

static void Sos_dealloc(SosObject *self)
{
    free(self->coef); free(self->z); free(self->x);
    PyTypeObject *tp = Py_TYPE((PyObject *)self);
    freefunc tp_free = PyType_GetSlot(tp, Py_tp_free);
    tp_free((void *)self);
    Py_DECREF(tp);
}

static PyObject *Sos_step(SosObject *self, PyObject *x)
{
    Py_ssize_t nc = self->n_channels, ns = self->n_sections;
    if (read_doubles(x, self->x, nc, "x") < 0) return NULL;
    for (Py_ssize_t s = 0; s < ns; s++) {
        const double *c = self->coef + 5 * s;
        double b0 = c[0], b1 = c[1], b2 = c[2], a1 = c[3], a2 = c[4];
        for (Py_ssize_t ch = 0; ch < nc; ch++) {
            double *z = self->z + 2 * (s * nc + ch);
            double v = self->x[ch];
            double y = b0 * v + z[0];
            z[0] = b1 * v - a1 * y + z[1];
            z[1] = b2 * v - a2 * y;
            self->x[ch] = y;
        }
    }
    return tuple_of(self->x, nc);
}

static PyObject *Sos_reset(SosObject *self, PyObject *unused)
{
    memset(self->z, 0, sizeof(double) * 2 * self->n_sections * self->n_channels);
    Py_RETURN_NONE;
}

/* state in the order of an array (n_sections, 2, n_channels) */
static PyObject *Sos_get_state(SosObject *self, PyObject *unused)
{
    Py_ssize_t ns = self->n_sections, nc = self->n_channels, n = 2 * ns * nc;
    double *flat = malloc(sizeof(double) * n);
    if (!flat) return PyErr_NoMemory();
    for (Py_ssize_t s = 0; s < ns; s++)
        for (int j = 0; j < 2; j++)
            for (Py_ssize_t ch = 0; ch < nc; ch++)
                flat[(s * 2 + j) * nc + ch] = self->z[2 * (s * nc + ch) + j];
    PyObject *out = list_of(flat, n);
    free(flat);
    return out;
}

static PyObject *Sos_set_state(SosObject *self, PyObject *seq)
{
    Py_ssize_t ns = self->n_sections, nc = self->n_channels, n = 2 * ns * nc;
    double *flat = malloc(sizeof(double) * n);
    if (!flat) return PyErr_NoMemory();
    if (read_doubles(seq, flat, n, "state") < 0) { free(flat); return NULL; }
    for (Py_ssize_t s = 0; s < ns; s++)
        for (int j = 0; j < 2; j++)
            for (Py_ssize_t ch = 0; ch < nc; ch++)
                self->z[2 * (s * nc + ch) + j] = flat[(s * 2 + j) * nc + ch];
    free(flat);
    Py_RETURN_NONE;
}

static PyMethodDef Sos_methods[] = {
    {"step", (PyCFunction)Sos_step, METH_O, "Filter one sample per channel."},
    {"reset", (PyCFunction)Sos_reset, METH_NOARGS, "Zero state."},
    {"get_state", (PyCFunction)Sos_get_state, METH_NOARGS, "State, (n_sections, 2, n_channels) order."},
    {"set_state", (PyCFunction)Sos_set_state, METH_O, "Restore a state from get_state."},
    {NULL, NULL, 0, NULL},
};

static PyType_Slot Sos_slots[] = {
    {Py_tp_doc, "Second-order sections (direct form II transposed) on parallel channels."},
    {Py_tp_init, Sos_init},
    {Py_tp_dealloc, Sos_dealloc},
    {Py_tp_methods, Sos_methods},
    {Py_tp_new, PyType_GenericNew},
    {0, NULL},
};

static PyType_Spec Sos_spec = {
    "gyrodiag.common._ckernels.SosCascade", sizeof(SosObject), 0, Py_TPFLAGS_DEFAULT, Sos_slots,
};

/* ------------------------------------------------------------------ PotterRLS */
typedef struct {
    PyObject_HEAD
    Py_ssize_t n;
    double forgetting, sqrt_lambda, max_trace;
    double *S, *theta, *work; /* S row-major n*n; work: phi f sf g new (5n) */
} RlsObject;

static int Rls_init(RlsObject *self, PyObject *args, PyObject *kwds)
{
    Py_ssize_t n;
    double lam, max_trace;
    static char *kwlist[] = {"n", "forgetting", "max_trace", NULL};
    if (!PyArg_ParseTupleAndKeywords(args, kwds, "ndd", kwlist, &n, &lam, &max_trace)) return -1;
    if (n < 1) { PyErr_SetString(PyExc_ValueError, "n must be >= 1"); return -1; }
    free(self->S); free(self->theta); free(self->work);
    self->S = calloc(n * n, sizeof(double));
    self->theta = calloc(n, sizeof(double));
    self->work = calloc(5 * n, sizeof(double));
    if (!self->S || !self->theta || !self->work) { PyErr_NoMemory(); return -1; }
    self->n = n;
    self->forgetting = lam;
    self->sqrt_lambda = sqrt(lam);
    self->max_trace = max_trace;
    return 0;
}

static void Rls_dealloc(RlsObject *self)
{
    free(self->S); free(self->theta); free(self->work);
    PyTypeObject *tp = Py_TYPE((PyObject *)self);
    freefunc tp_free = PyType_GetSlot(tp, Py_tp_free);
    tp_free((void *)self);
    Py_DECREF(tp);
}

static PyObject *Rls_step(RlsObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    if (nargs != 2) {
        PyErr_SetString(PyExc_TypeError, "step(phi, y) takes 2 arguments");
        return NULL;
    }
    Py_ssize_t n = self->n;
    double *S = self->S, *theta = self->theta;
    double *phi = self->work, *f = phi + n, *sf = f + n, *g = sf + n, *nt = g + n;
    if (read_doubles(args[0], phi, n, "phi") < 0) return NULL;
    double y = PyFloat_AsDouble(args[1]);
    if (y == -1.0 && PyErr_Occurred()) return NULL;
    double lam = self->forgetting;
    for (Py_ssize_t j = 0; j < n; j++) {
        double acc = S[j] * phi[0];
        for (Py_ssize_t i = 1; i < n; i++) acc = acc + S[i * n + j] * phi[i];
        f[j] = acc;
    }
    double ff = f[0] * f[0];
    for (Py_ssize_t j = 1; j < n; j++) ff = ff + f[j] * f[j];
    double alpha = lam + ff;
    double pt = phi[0] * theta[0];
    for (Py_ssize_t i = 1; i < n; i++) pt = pt + phi[i] * theta[i];
    double err = y - pt;
    double gamma = 1.0 / (alpha + sqrt(lam * alpha));
    double step = 0.0;
    for (Py_ssize_t i = 0; i < n; i++) {
        double acc = S[i * n] * f[0];
        for (Py_ssize_t j = 1; j < n; j++) acc = acc + S[i * n + j] * f[j];
        sf[i] = acc;
        nt[i] = theta[i] + (acc / alpha) * err;
        g[i] = gamma * acc;
        double d = fabs(nt[i] - theta[i]);
        if (d > step || i == 0) step = d;
    }
    memcpy(theta, nt, sizeof(double) * n);
    if (lam == 1.0) {
        for (Py_ssize_t i = 0; i < n; i++)
            for (Py_ssize_t j = 0; j < n; j++) S[i * n + j] = S[i * n + j] - g[i] * f[j];
    } else {
        double r = self->sqrt_lambda;
        for (Py_ssize_t i = 0; i < n; i++)
            for (Py_ssize_t j = 0; j < n; j++) S[i * n + j] = (S[i * n + j] - g[i] * f[j]) / r;
    }
    if (self->max_trace < INFINITY) {
        double tr = S[0] * S[0];
        for (Py_ssize_t k = 1; k < n * n; k++) tr = tr + S[k] * S[k];
        if (tr > self->max_trace) {
            double scale = sqrt(self->max_trace / tr);
            for (Py_ssize_t k = 0; k < n * n; k++) S[k] = S[k] * scale;
        }
    }
    return PyFloat_FromDouble(step);
}

static PyObject *Rls_set(RlsObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    if (nargs != 2) {
        PyErr_SetString(PyExc_TypeError, "set(theta, S) takes 2 arguments");
        return NULL;
    }
    Py_ssize_t n = self->n;
    double *t = malloc(sizeof(double) * (n + n * n));
    if (!t) return PyErr_NoMemory();
    if (read_doubles(args[0], t, n, "theta") < 0 || read_doubles(args[1], t + n, n * n, "S") < 0) {
        free(t);
        return NULL;
    }
    memcpy(self->theta, t, sizeof(double) * n);
    memcpy(self->S, t + n, sizeof(double) * n * n);
    free(t);
    Py_RETURN_NONE;
}

static PyObject *Rls_get_S(RlsObject *self, PyObject *unused)
{
    return list_of(self->S, self->n * self->n);
}

static PyObject *Rls_theta(RlsObject *self, void *closure)
{
    return tuple_of(self->theta, self->n);
}

static PyMethodDef Rls_methods[] = {
    {"step", (PyCFunction)(void (*)(void))Rls_step, METH_FASTCALL,
     "One update with (phi, y); returns max |dtheta|."},
    {"set", (PyCFunction)(void (*)(void))Rls_set, METH_FASTCALL, "Set theta and S (row-major)."},
    {"get_S", (PyCFunction)Rls_get_S, METH_NOARGS, "S row-major."},
    {NULL, NULL, 0, NULL},
};

static PyGetSetDef Rls_getset[] = {
    {"theta", (getter)Rls_theta, NULL, "theta (a tuple)", NULL},
    {NULL, NULL, NULL, NULL, NULL},
};

static PyType_Slot Rls_slots[] = {
    {Py_tp_doc, "Square-root (Potter) RLS step with forgetting and a trace cap."},
    {Py_tp_init, Rls_init},
    {Py_tp_dealloc, Rls_dealloc},
    {Py_tp_methods, Rls_methods},
    {Py_tp_getset, Rls_getset},
    {Py_tp_new, PyType_GenericNew},
    {0, NULL},
};

static PyType_Spec Rls_spec = {
    "gyrodiag.common._ckernels.PotterRLS", sizeof(RlsObject), 0, Py_TPFLAGS_DEFAULT, Rls_slots,
};

/* ------------------------------------------------------------------ LinearObserver */
typedef struct {
    PyObject_HEAD
    Py_ssize_t n, p, m;
    double *phi, *gamma, *c, *l; /* row-major: n*n, n*p, m*n, n*m */
    double *z, *u, *y, *r, *nz;
} ObsObject;

static int Obs_init(ObsObject *self, PyObject *args, PyObject *kwds)
{
    PyObject *phi, *gamma, *c, *l;
    Py_ssize_t n, p, m;
    static char *kwlist[] = {"phi", "gamma", "C", "L", "n", "p", "m", NULL};
    if (!PyArg_ParseTupleAndKeywords(args, kwds, "OOOOnnn", kwlist, &phi, &gamma, &c, &l,
                                     &n, &p, &m))
        return -1;
    if (n < 1 || p < 0 || m < 1) {
        PyErr_SetString(PyExc_ValueError, "need n >= 1, p >= 0, m >= 1");
        return -1;
    }
    free(self->phi);
    Py_ssize_t total = n * n + n * p + m * n + n * m + n + p + m + m + n;
    self->phi = calloc(total + 1, sizeof(double));
    if (!self->phi) { PyErr_NoMemory(); return -1; }
    self->gamma = self->phi + n * n;
    self->c = self->gamma + n * p;
    self->l = self->c + m * n;
    self->z = self->l + n * m;
    self->u = self->z + n;
    self->y = self->u + p;
    self->r = self->y + m;
    self->nz = self->r + m;
    self->n = n; self->p = p; self->m = m;
    if (read_doubles(phi, self->phi, n * n, "phi") < 0 || read_doubles(gamma, self->gamma, n * p, "gamma") < 0
        || read_doubles(c, self->c, m * n, "C") < 0 || read_doubles(l, self->l, n * m, "L") < 0)
        return -1;
    return 0;
}

static void Obs_dealloc(ObsObject *self)
{
    free(self->phi);
    PyTypeObject *tp = Py_TYPE((PyObject *)self);
    freefunc tp_free = PyType_GetSlot(tp, Py_tp_free);
    tp_free((void *)self);
    Py_DECREF(tp);
}

static PyObject *Obs_step(ObsObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    if (nargs != 2) {
        PyErr_SetString(PyExc_TypeError, "step(u, y) takes 2 arguments");
        return NULL;
    }
    Py_ssize_t n = self->n, p = self->p, m = self->m;
    if (read_doubles(args[0], self->u, p, "u") < 0 || read_doubles(args[1], self->y, m, "y") < 0)
        return NULL;
    const double *z = self->z;
    for (Py_ssize_t i = 0; i < m; i++) {
        const double *row = self->c + i * n;
        double acc = row[0] * z[0];
        for (Py_ssize_t j = 1; j < n; j++) acc = acc + row[j] * z[j];
        self->r[i] = self->y[i] - acc;
    }
    for (Py_ssize_t k = 0; k < n; k++) {
        const double *row = self->phi + k * n;
        double a = row[0] * z[0];
        for (Py_ssize_t j = 1; j < n; j++) a = a + row[j] * z[j];
        if (p > 0) {
            const double *g = self->gamma + k * p;
            double b = g[0] * self->u[0];
            for (Py_ssize_t j = 1; j < p; j++) b = b + g[j] * self->u[j];
            a = a + b;
        }
        const double *lr = self->l + k * m;
        double e = lr[0] * self->r[0];
        for (Py_ssize_t i = 1; i < m; i++) e = e + lr[i] * self->r[i];
        self->nz[k] = a + e;
    }
    memcpy(self->z, self->nz, sizeof(double) * n);
    return tuple_of(self->r, m);
}

static PyObject *Obs_get_z(ObsObject *self, PyObject *unused)
{
    return list_of(self->z, self->n);
}

static PyObject *Obs_set_z(ObsObject *self, PyObject *seq)
{
    if (read_doubles(seq, self->z, self->n, "z") < 0) return NULL;
    Py_RETURN_NONE;
}

static PyMethodDef Obs_methods[] = {
    {"step", (PyCFunction)(void (*)(void))Obs_step, METH_FASTCALL,
     "One sample: returns the residual y - Cz and advances z."},
    {"get_z", (PyCFunction)Obs_get_z, METH_NOARGS, "Observer state z."},
    {"set_z", (PyCFunction)Obs_set_z, METH_O, "Set the observer state z."},
    {NULL, NULL, 0, NULL},
};

static PyType_Slot Obs_slots[] = {
    {Py_tp_doc, "Discrete observer step z <- Phi z + Gamma u + L (y - C z)."},
    {Py_tp_init, Obs_init},
    {Py_tp_dealloc, Obs_dealloc},
    {Py_tp_methods, Obs_methods},
    {Py_tp_new, PyType_GenericNew},
    {0, NULL},
};

static PyType_Spec Obs_spec = {
    "gyrodiag.common._ckernels.LinearObserver", sizeof(ObsObject), 0, Py_TPFLAGS_DEFAULT, Obs_slots,
};

/* ------------------------------------------------------------------ grey */
#define GREY_STACK 64

static PyObject *improved_grey_predict(PyObject *module, PyObject *const *args, Py_ssize_t nargs)
{
    if (nargs != 5) {
        PyErr_SetString(PyExc_TypeError,
                        "improved_grey_predict(window, level_ratio, a_min, poly_weights, "
                        "residual_weights) takes 5 arguments");
        return NULL;
    }
    Py_ssize_t m = PySequence_Size(args[0]);
    if (m < 0) return NULL;
    if (m < 4) {
        PyErr_SetString(PyExc_ValueError, "window must hold at least 4 samples");
        return NULL;
    }
    double level_ratio = PyFloat_AsDouble(args[1]);
    if (level_ratio == -1.0 && PyErr_Occurred()) return NULL;
    double a_min = PyFloat_AsDouble(args[2]);
    if (a_min == -1.0 && PyErr_Occurred()) return NULL;
    double stack[4 * GREY_STACK];
    double *buf = m <= GREY_STACK ? stack : malloc(sizeof(double) * 4 * m);
    if (!buf) return PyErr_NoMemory();
    double *w = buf, *lifted = buf + m, *pw = lifted + m, *rw = pw + m;
    PyObject *result = NULL;
    if (read_doubles(args[0], w, m, "window") < 0 || read_doubles(args[3], pw, m, "poly_weights") < 0
        || read_doubles(args[4], rw, m - 1, "residual_weights") < 0)
        goto done;
    double lo = w[0], hi = w[0];
    for (Py_ssize_t k = 1; k < m; k++) {
        if (w[k] < lo) lo = w[k];
        if (w[k] > hi) hi = w[k];
    }
    double span = hi - lo, level;
    if (span > 0.0) level = level_ratio * span;
    else level = lo != 0.0 ? fabs(lo) : 1.0;
    for (Py_ssize_t k = 0; k < m; k++) lifted[k] = (w[k] - lo) + level;
    /* z(k) in w[1..m-1] (w no longer needed) */
    double x1 = lifted[0], zsum = 0.0, lsum = 0.0;
    for (Py_ssize_t k = 1; k < m; k++) {
        double v = lifted[k];
        x1 = x1 + v;
        w[k] = x1 - 0.5 * v;
        zsum = zsum + w[k];
        lsum = lsum + v;
    }
    double rows = (double)(m - 1);
    double z_mean = zsum / rows, l_mean = lsum / rows, szz = 0.0, szl = 0.0;
    for (Py_ssize_t k = 1; k < m; k++) {
        double dz = w[k] - z_mean;
        szz = szz + dz * dz;
        szl = szl + dz * (lifted[k] - l_mean);
    }
    double a = -szl / szz;
    double b = l_mean + a * z_mean;
    if (fabs(a) < a_min) {
        double pred = 0.0;
        for (Py_ssize_t k = 0; k < m; k++) pred = pred + pw[k] * lifted[k];
        result = Py_BuildValue("ddO", (pred - level) + lo, a, Py_True);
        goto done;
    }
    double q = exp(-a);
    double h = a == 0.0 ? 1.0 : -expm1(-a) / a;
    double u = 1.0, num = 0.0, den = 0.0;
    x1 = 0.0;
    for (Py_ssize_t k = 0; k < m; k++) {
        x1 = x1 + lifted[k];
        double g = a == 0.0 ? (double)k : -expm1(-a * (double)k) / a;
        num = num + u * (x1 - b * g);
        den = den + u * u;
        u = u * q;
    }
    double c = num / den;
    double amp = (b - a * c) * h;
    double corr = 0.0, e = amp;
    for (Py_ssize_t k = 1; k < m; k++) {
        corr = corr + rw[k - 1] * (lifted[k] - e);
        e = e * q;
    }
    result = Py_BuildValue("ddO", ((e + corr) - level) + lo, a, Py_False);
done:
    if (buf != stack) free(buf);
    return result;
}

static PyMethodDef module_methods[] = {
    {"improved_grey_predict", (PyCFunction)(void (*)(void))improved_grey_predict, METH_FASTCALL,
     "Improved grey one-step prediction of a full window: (prediction, a, fallback)."},
    {NULL, NULL, 0, NULL},
};

static int module_exec(PyObject *module)
{
    PyObject *sos = PyType_FromSpec(&Sos_spec);
    if (sos == NULL || PyModule_AddObject(module, "SosCascade", sos) < 0) {
        Py_XDECREF(sos);
        return -1;
    }
    PyObject *rls = PyType_FromSpec(&Rls_spec);
    if (rls == NULL || PyModule_AddObject(module, "PotterRLS", rls) < 0) {
        Py_XDECREF(rls);
        return -1;
    }
    PyObject *obs = PyType_FromSpec(&Obs_spec);
    if (obs == NULL || PyModule_AddObject(module, "LinearObserver", obs) < 0) {
        Py_XDECREF(obs);
        return -1;
    }
    return 0;
}

static PyModuleDef_Slot module_slots[] = {
    {Py_mod_exec, module_exec},
    {0, NULL},
};

static struct PyModuleDef module_def = {
    PyModuleDef_HEAD_INIT, "gyrodiag.common._ckernels",
    "Compiled per-sample kernels of gyrodiag (see gyrodiag.common._pykernels for the fallback).",
    0, module_methods, module_slots, NULL, NULL, NULL,
};

PyMODINIT_FUNC PyInit__ckernels(void)
{
    return PyModuleDef_Init(&module_def);
}

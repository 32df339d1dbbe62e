/* The loopback sim plant's per-tick step in C (pmctl.hal.sim does the same arithmetic; this is its
 * fast path): drive (ideal or first-order lag, exact for the ramp inside a tick), the flexible
 * chain modes (exact transition matrices), the gravity strain of the load-side pose (the compiled
 * core's FK and statics, exact every N ticks and secant-extrapolated between), and the feedback
 * sample. Buffers belong to the caller; nothing is allocated per tick. */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include "pymodule.h"
#include <math.h>
#include <string.h>

#include "ncore.h"

/* double state */
enum { D_CMD = 0, D_MOTOR = 5, D_VM = 10, D_Y = 15, D_YD = 18, D_Q = 21, D_P = 26, D_R = 29, D_T = 38,
       D_QFK = 56, D_GAQ = 61, D_GAG = 66, D_GBQ = 69, D_GBG = 74, D_HAS_T = 77, D_HAVE_A = 78,
       D_HAVE_B = 79, D_MOFF = 80, D_LOFF = 85, D_LEN = 90 };
/* constants */
enum { K_PPM = 0, K_DT = 5, K_TAU_ON = 6, K_TAU = 7, K_LAG = 12, K_PH = 17, K_FLEX = 29, K_SPM = 30,
       K_LOST_TICK = 33, K_LOST_AXIS = 34, K_LOST_MM = 35, K_ENC_NOISE = 36, K_STRAIN_NOISE = 37,
       K_N_UPDATE = 38, K_N_ENC = 39, K_LEN = 40 };

typedef struct {
    PyObject_HEAD
    nc_const c;
    double k[K_LEN];
    Py_buffer b[5];          /* d state, counts, fb.enc, fb.strain, fb.counts */
    int have;
} PlantObject;

static int get_buf(PyObject *o, Py_buffer *v, Py_ssize_t n, int writable, int is_int, const char *what)
{
    const char *f;
    if (PyObject_GetBuffer(o, v, PyBUF_C_CONTIGUOUS | PyBUF_FORMAT | (writable ? PyBUF_WRITABLE : 0)) < 0)
        return -1;
    f = v->format ? v->format : "B";
    if (*f == '<' || *f == '=' || *f == '@')
        f++;
    if (v->itemsize != 8 || v->len != n * 8 ||
        (is_int ? !(f[0] == 'q' || f[0] == 'l') : f[0] != 'd') || f[1] != '\0') {
        PyErr_Format(PyExc_ValueError, "%s: need a contiguous %s buffer of %zd items", what,
                     is_int ? "int64" : "float64", n);
        PyBuffer_Release(v);
        return -1;
    }
    return 0;
}

static void release(PlantObject *self)
{
    int i;
    for (i = 0; i < self->have; i++)
        PyBuffer_Release(&self->b[i]);
    self->have = 0;
}

static int Plant_init(PlantObject *self, PyObject *args, PyObject *kw)
{
    static char *kwlist[] = {"fk_consts", "consts", "d", "counts", "enc", "strain", "fb_counts", NULL};
    static const Py_ssize_t len[5] = {D_LEN, 5, 5, 3, 5};
    static const int isint[5] = {0, 1, 0, 0, 1};
    static const char *names[5] = {"d", "counts", "enc", "strain", "fb_counts"};
    PyObject *fo, *ko, *o[5];
    Py_buffer cb;
    int i;
    if (!PyArg_ParseTupleAndKeywords(args, kw, "OOOOOOO", kwlist, &fo, &ko, &o[0], &o[1], &o[2], &o[3], &o[4]))
        return -1;
    if (get_buf(fo, &cb, NC_C_LEN, 0, 0, "fk_consts") < 0)
        return -1;
    i = nc_setup(&self->c, cb.buf, (int)(cb.len / 8));
    PyBuffer_Release(&cb);
    if (i != 0) {
        PyErr_SetString(PyExc_ValueError, "fk_consts: wrong layout");
        return -1;
    }
    if (get_buf(ko, &cb, K_LEN, 0, 0, "consts") < 0)
        return -1;
    memcpy(self->k, cb.buf, sizeof self->k);
    PyBuffer_Release(&cb);
    release(self);
    for (i = 0; i < 5; i++) {
        if (get_buf(o[i], &self->b[i], len[i], 1, isint[i], names[i]) < 0) {
            release(self);
            return -1;
        }
        self->have = i + 1;
    }
    return 0;
}

static void Plant_dealloc(PlantObject *self)
{
    release(self);
    Py_TYPE(self)->tp_free((PyObject *)self);
}

/* Gravity strain of the load-side pose q (D_Q) at tick `tick` into g; returns 0 or an NC_EV_FK_* event. */
static int gravity(PlantObject *self, double *d, long tick, double g[3], double ev[6])
{
    const double *q = d + D_Q;
    long n = (long)self->k[K_N_UPDATE];
    int i, r;
    if (d[D_HAVE_A] != 0.0 && n > 1 && tick % n) {
        double dq[5], dd = 0.0, f = 0.0;
        if (d[D_HAVE_B] == 0.0) {
            memcpy(g, d + D_GAG, 3 * sizeof(double));
            return 0;
        }
        for (i = 0; i < 5; i++)
            dq[i] = d[D_GAQ + i] - d[D_GBQ + i];
        dd = dq[0] * dq[0] + dq[1] * dq[1] + dq[2] * dq[2] + dq[3] * dq[3] + dq[4] * dq[4];
        if (dd <= 0.0) {
            memcpy(g, d + D_GAG, 3 * sizeof(double));
            return 0;
        }
        for (i = 0; i < 5; i++)
            f += (q[i] - d[D_GAQ + i]) * dq[i];
        f /= dd;
        for (i = 0; i < 3; i++)
            g[i] = d[D_GAG + i] + (d[D_GAG + i] - d[D_GBG + i]) * f;
        return 0;
    }
    {
        double dL[3], tip[3], axis[3], J[30], T[18];
        int64_t it;
        for (i = 0; i < 3; i++)
            dL[i] = q[i] - d[D_QFK + i];
        r = nc_fk(&self->c, q, d + D_P, d + D_R, d[D_HAS_T] != 0.0 ? dL : NULL, d + D_T, tip, axis, J, T, &it, ev);
        if (r)
            return r;
        memcpy(d + D_T, T, sizeof T);
        memcpy(d + D_QFK, q, 5 * sizeof(double));
        d[D_HAS_T] = 1.0;
        nc_static_strain(&self->c, d + D_R, d + D_T, g);
        if (d[D_HAVE_A] != 0.0) {
            memcpy(d + D_GBQ, d + D_GAQ, 5 * sizeof(double));
            memcpy(d + D_GBG, d + D_GAG, 3 * sizeof(double));
            d[D_HAVE_B] = 1.0;
        }
        memcpy(d + D_GAQ, q, 5 * sizeof(double));
        memcpy(d + D_GAG, g, 3 * sizeof(double));
        d[D_HAVE_A] = 1.0;
        return 0;
    }
}

/* The feedback sample at tick `tick`: encoders (motor side + noise), strain (spring + gravity + noise).
 * D_MOFF: the effects' motor-side offsets (friction: the encoders see them), D_LOFF: their
 * load-side offsets (backlash, screw errors: only the load sees them); both 0 without effects. */
static int sample(PlantObject *self, long tick, const double *nz, double ev[6])
{
    double *d = self->b[0].buf, *enc = self->b[2].buf, *strain = self->b[3].buf, g[3];
    const double *k = self->k;
    int64_t *counts = self->b[1].buf, *fbc = self->b[4].buf;
    int i, r, ne = (int)k[K_N_ENC];
    for (i = 0; i < 5; i++) {
        fbc[i] = counts[i];
        enc[i] = d[D_MOTOR + i] + d[D_MOFF + i];
        if (ne)
            enc[i] += k[K_ENC_NOISE] * nz[i];
    }
    for (i = 0; i < 5; i++)
        d[D_Q + i] = d[D_MOTOR + i] + d[D_MOFF + i] + d[D_LOFF + i] + (i < 3 ? d[D_Y + i] : 0.0);
    r = gravity(self, d, tick, g, ev);
    if (r)
        return r;
    for (i = 0; i < 3; i++) {
        double s = k[K_SPM + i] * d[D_Y + i] + g[i];
        if (k[K_STRAIN_NOISE] > 0)
            s = s + k[K_STRAIN_NOISE] * nz[ne + i];
        strain[i] = s;
    }
    return 0;
}

static int noise_arg(PyObject *o, Py_buffer *v, int *got)
{
    *got = 0;
    if (o == Py_None)
        return 0;
    if (PyObject_GetBuffer(o, v, PyBUF_C_CONTIGUOUS | PyBUF_FORMAT) < 0)
        return -1;
    if (v->itemsize != 8 || v->len < 8 * 8) {
        PyErr_SetString(PyExc_ValueError, "noise: need a float64 row of 8");
        PyBuffer_Release(v);
        return -1;
    }
    *got = 1;
    return 0;
}

/* step(pulses int64[5], noise row or None, tick[, advance_only]) -> 0, or the NC_EV_* event of a lost
 * load-side pose. `tick` is the plant's tick before this step (lost steps), the sample is taken at
 * tick + 1; with advance_only true the drive and modes move but no sample is taken (the caller sets
 * the effects' offsets from the new motor position, then calls sample(noise, tick + 1)). */
static PyObject *Plant_step(PlantObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    Py_buffer pb, nb;
    double *d, *k, c_new[5], m_new[5], vm[5], ev[6];
    int64_t *counts;
    const int64_t *p;
    long tick;
    int i, gotn, r, advance_only = 0;
    if (nargs != 3 && nargs != 4) {
        PyErr_SetString(PyExc_TypeError, "step(pulses, noise, tick[, advance_only])");
        return NULL;
    }
    if (self->have != 5) {
        PyErr_SetString(PyExc_RuntimeError, "Plant not initialised");
        return NULL;
    }
    tick = PyLong_AsLong(args[2]);
    if (tick == -1 && PyErr_Occurred())
        return NULL;
    if (nargs == 4 && (advance_only = PyObject_IsTrue(args[3])) < 0)
        return NULL;
    if (get_buf(args[0], &pb, 5, 0, 1, "pulses") < 0)
        return NULL;
    if (noise_arg(args[1], &nb, &gotn) < 0) {
        PyBuffer_Release(&pb);
        return NULL;
    }
    d = self->b[0].buf;
    k = self->k;
    counts = self->b[1].buf;
    p = pb.buf;
    for (i = 0; i < 5; i++) {
        counts[i] += p[i];
        c_new[i] = (double)counts[i] / k[K_PPM + i];
    }
    PyBuffer_Release(&pb);
    for (i = 0; i < 5; i++) {
        if (k[K_TAU_ON] != 0.0) {
            double tv = k[K_TAU + i] * ((c_new[i] - d[D_CMD + i]) / k[K_DT]);
            m_new[i] = c_new[i] - tv + (d[D_MOTOR + i] - d[D_CMD + i] + tv) * k[K_LAG + i];
        } else {
            m_new[i] = c_new[i];
        }
    }
    if ((double)tick == k[K_LOST_TICK])
        m_new[(int)k[K_LOST_AXIS]] += k[K_LOST_MM];
    for (i = 0; i < 5; i++)
        vm[i] = (m_new[i] - d[D_MOTOR + i]) / k[K_DT];
    if (k[K_FLEX] != 0.0)
        for (i = 0; i < 3; i++) {
            const double *ph = k + K_PH + 4 * i;
            double yd = d[D_YD + i] - (vm[i] - d[D_VM + i]), y = d[D_Y + i];
            d[D_Y + i] = ph[0] * y + ph[1] * yd;
            d[D_YD + i] = ph[2] * y + ph[3] * yd;
        }
    memcpy(d + D_CMD, c_new, sizeof c_new);
    memcpy(d + D_MOTOR, m_new, sizeof m_new);
    memcpy(d + D_VM, vm, sizeof vm);
    r = advance_only ? 0 : sample(self, tick + 1, gotn ? nb.buf : NULL, ev);
    if (gotn)
        PyBuffer_Release(&nb);
    return PyLong_FromLong(r);
}

/* sample(noise row or None, tick) -> 0 or event: the feedback at the current plant state. */
static PyObject *Plant_sample(PlantObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    Py_buffer nb;
    double ev[6];
    long tick;
    int gotn, r;
    if (nargs != 2) {
        PyErr_SetString(PyExc_TypeError, "sample(noise, tick)");
        return NULL;
    }
    if (self->have != 5) {
        PyErr_SetString(PyExc_RuntimeError, "Plant not initialised");
        return NULL;
    }
    tick = PyLong_AsLong(args[1]);
    if (tick == -1 && PyErr_Occurred())
        return NULL;
    if (noise_arg(args[0], &nb, &gotn) < 0)
        return NULL;
    r = sample(self, tick, gotn ? nb.buf : NULL, ev);
    if (gotn)
        PyBuffer_Release(&nb);
    return PyLong_FromLong(r);
}

static PyMethodDef Plant_methods[] = {
    {"step", (PyCFunction)(void (*)(void))Plant_step, METH_FASTCALL,
     "step(pulses, noise, tick) -> 0 or event: take one tick's pulses, then sample"},
    {"sample", (PyCFunction)(void (*)(void))Plant_sample, METH_FASTCALL,
     "sample(noise, tick) -> 0 or event: the feedback at the current state"},
    {NULL, NULL, 0, NULL}};

static PyTypeObject PlantType = {
    PyVarObject_HEAD_INIT(NULL, 0)
    .tp_name = "pmctl.hal._simplant.Plant",
    .tp_basicsize = sizeof(PlantObject),
    .tp_flags = Py_TPFLAGS_DEFAULT,
    .tp_doc = "Plant(fk_consts, consts, d, counts, enc, strain, fb_counts): the sim plant's tick",
    .tp_new = PyType_GenericNew,
    .tp_init = (initproc)Plant_init,
    .tp_dealloc = (destructor)Plant_dealloc,
    .tp_methods = Plant_methods,
};

static struct PyModuleDef moddef = {PyModuleDef_HEAD_INIT, "_simplant", "pmctl sim plant tick", -1, NULL};

PyMODINIT_FUNC PyInit__simplant(void)
{
    PyObject *m = pmctl_module_with_type(&moddef, &PlantType, "Plant");
    if (m == NULL)
        return NULL;
#define C(name, v) PyModule_AddIntConstant(m, name, v)
    C("D_LEN", D_LEN); C("K_LEN", K_LEN); C("D_CMD", D_CMD); C("D_MOTOR", D_MOTOR); C("D_VM", D_VM);
    C("D_Y", D_Y); C("D_YD", D_YD); C("D_Q", D_Q); C("D_P", D_P); C("D_R", D_R);
    C("D_MOFF", D_MOFF); C("D_LOFF", D_LOFF);
#undef C
    return m;
}

/* CPython binding of the compiled NC core (ncore.c): a Core object holds the constants and pins
 * the caller's state buffers (any writable C-contiguous float64 / int64 buffer: numpy arrays,
 * or memory shared with another process); step() runs one tick on them. No allocation per tick. */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include "pymodule.h"
#include <string.h>

#include "ncore.h"

typedef struct {
    PyObject_HEAD
    nc_const c;
    Py_buffer sbuf, nbuf, cbuf;
    int have_s, have_n, have_c;
} CoreObject;

/* A C-contiguous buffer of exactly n items of 8 bytes with format code `code` ('d' or 'q'/'l'). */
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

static int Core_init(CoreObject *self, PyObject *args, PyObject *kw)
{
    PyObject *co, *so, *no, *tab = Py_None;
    Py_buffer cb;
    int fmt_ok = 0;
    static char *kwlist[] = {"consts", "s", "n", "comp", NULL};
    if (!PyArg_ParseTupleAndKeywords(args, kw, "OOO|O", kwlist, &co, &so, &no, &tab))
        return -1;
    if (get_buf(co, &cb, NC_C_LEN, 0, 0, "consts") < 0)
        return -1;
    if (nc_setup(&self->c, (const double *)cb.buf, (int)(cb.len / 8)) != 0) {
        PyBuffer_Release(&cb);
        PyErr_SetString(PyExc_ValueError, "consts: wrong layout");
        return -1;
    }
    PyBuffer_Release(&cb);
    if (self->have_s) { PyBuffer_Release(&self->sbuf); self->have_s = 0; }
    if (self->have_n) { PyBuffer_Release(&self->nbuf); self->have_n = 0; }
    if (self->have_c) { PyBuffer_Release(&self->cbuf); self->have_c = 0; }
    if (tab != Py_None) {          /* the compensation table (pinned: the core reads it every tick) */
        if (PyObject_GetBuffer(tab, &self->cbuf, PyBUF_C_CONTIGUOUS | PyBUF_FORMAT) < 0)
            return -1;
        self->have_c = 1;
        {
            const char *f = self->cbuf.format ? self->cbuf.format : "B";
            if (*f == '<' || *f == '=' || *f == '@')
                f++;
            fmt_ok = strcmp(f, "d") == 0;
        }
        if (self->cbuf.itemsize != 8 || !fmt_ok ||
            self->cbuf.len / 8 > 0x7fffffff ||
            nc_setup_comp(&self->c, (const double *)self->cbuf.buf, (int)(self->cbuf.len / 8)) != 0) {
            PyBuffer_Release(&self->cbuf);
            self->have_c = 0;
            PyErr_SetString(PyExc_ValueError, "comp: wrong layout (see pmctl.core.compensation.Compensation.flat)");
            return -1;
        }
    }
    if (get_buf(so, &self->sbuf, NC_S_LEN, 1, 0, "s") < 0)
        return -1;
    self->have_s = 1;
    if (get_buf(no, &self->nbuf, NC_N_LEN, 1, 1, "n") < 0)
        return -1;
    self->have_n = 1;
    return 0;
}

static void Core_dealloc(CoreObject *self)
{
    if (self->have_s) PyBuffer_Release(&self->sbuf);
    if (self->have_n) PyBuffer_Release(&self->nbuf);
    if (self->have_c) PyBuffer_Release(&self->cbuf);
    Py_TYPE(self)->tp_free((PyObject *)self);
}

static int ready(CoreObject *self)
{
    if (!self->have_s || !self->have_n) {
        PyErr_SetString(PyExc_RuntimeError, "Core not initialised");
        return 0;
    }
    return 1;
}

static PyObject *Core_step(CoreObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    Py_buffer t, e, g, o;
    int ev, have_o = 0;
    if (nargs != 3 && nargs != 4) {
        PyErr_SetString(PyExc_TypeError, "step(target, enc, strain, offset=None)");
        return NULL;
    }
    if (!ready(self))
        return NULL;
    if (get_buf(args[0], &t, 12, 0, 0, "target") < 0)
        return NULL;
    if (get_buf(args[1], &e, 5, 0, 0, "enc") < 0) {
        PyBuffer_Release(&t);
        return NULL;
    }
    if (get_buf(args[2], &g, 3, 0, 0, "strain") < 0) {
        PyBuffer_Release(&t);
        PyBuffer_Release(&e);
        return NULL;
    }
    if (nargs == 4 && args[3] != Py_None) {
        if (get_buf(args[3], &o, 3, 0, 0, "offset") < 0) {
            PyBuffer_Release(&t);
            PyBuffer_Release(&e);
            PyBuffer_Release(&g);
            return NULL;
        }
        have_o = 1;
    }
    ev = nc_step(&self->c, (double *)self->sbuf.buf, (int64_t *)self->nbuf.buf, (const double *)t.buf,
                 (const double *)e.buf, (const double *)g.buf, have_o ? (const double *)o.buf : NULL);
    PyBuffer_Release(&t);
    PyBuffer_Release(&e);
    PyBuffer_Release(&g);
    if (have_o)
        PyBuffer_Release(&o);
    return PyLong_FromLong((long)ev * 16 + (long)((int64_t *)self->nbuf.buf)[NC_N_MODE]);
}

/* fk(q[5], P[3], R[9], dL[3] or None, T0[18], tip[3], axis[3], J[30], T[18], ev[6]) -> iterations >= 0
 * or -event. P and R are updated in place on success. */
static PyObject *Core_fk(CoreObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    static const Py_ssize_t len[10] = {5, 3, 9, 3, 18, 3, 3, 30, 18, 6};
    static const int wr[10] = {0, 1, 1, 0, 0, 1, 1, 1, 1, 1};
    static const char *names[10] = {"q", "P", "R", "dL", "T0", "tip", "axis", "J", "T", "ev"};
    Py_buffer b[10];
    int i, k, got = 0;
    int64_t iters = 0;
    if (nargs != 10) {
        PyErr_SetString(PyExc_TypeError, "fk(q, P, R, dL, T0, tip, axis, J, T, ev)");
        return NULL;
    }
    for (i = 0; i < 10; i++) {
        if (i == 3 && args[i] == Py_None) {
            b[i].buf = NULL;
            b[i].obj = NULL;
            continue;
        }
        if (i == 4 && args[3] == Py_None && args[i] == Py_None) {
            b[i].buf = NULL;
            b[i].obj = NULL;
            continue;
        }
        if (get_buf(args[i], &b[i], len[i], wr[i], 0, names[i]) < 0)
            goto fail;
        got |= 1 << i;
    }
    k = nc_fk(&self->c, b[0].buf, b[1].buf, b[2].buf, b[3].buf, b[4].buf, b[5].buf, b[6].buf, b[7].buf,
              b[8].buf, &iters, b[9].buf);
    for (i = 0; i < 10; i++)
        if (got & (1 << i)) PyBuffer_Release(&b[i]);
    return PyLong_FromLongLong(k ? -(long long)k : (long long)iters);
fail:
    for (i = 0; i < 10; i++)
        if (got & (1 << i)) PyBuffer_Release(&b[i]);
    return NULL;
}

/* static_strain(R[9], T[18], out[3]) */
static PyObject *Core_static_strain(CoreObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    Py_buffer r, t, o;
    if (nargs != 3) {
        PyErr_SetString(PyExc_TypeError, "static_strain(R, T, out)");
        return NULL;
    }
    if (get_buf(args[0], &r, 9, 0, 0, "R") < 0)
        return NULL;
    if (get_buf(args[1], &t, 18, 0, 0, "T") < 0) {
        PyBuffer_Release(&r);
        return NULL;
    }
    if (get_buf(args[2], &o, 3, 1, 0, "out") < 0) {
        PyBuffer_Release(&r);
        PyBuffer_Release(&t);
        return NULL;
    }
    nc_static_strain(&self->c, r.buf, t.buf, o.buf);
    PyBuffer_Release(&r);
    PyBuffer_Release(&t);
    PyBuffer_Release(&o);
    Py_RETURN_NONE;
}

static PyMethodDef Core_methods[] = {
    {"step", (PyCFunction)(void (*)(void))Core_step, METH_FASTCALL,
     "step(target, enc, strain, offset=None) -> 16 * event + mode: one NC tick on the state buffers "
     "(offset: the chain-length offset input, 3 mm)"},
    {"fk", (PyCFunction)(void (*)(void))Core_fk, METH_FASTCALL,
     "fk(q, P, R, dL, T0, tip, axis, J, T, ev) -> Newton iterations, or -event on failure"},
    {"static_strain", (PyCFunction)(void (*)(void))Core_static_strain, METH_FASTCALL,
     "static_strain(R, T, out): gravity strain of the platform, microstrain"},
    {NULL, NULL, 0, NULL}};

static PyTypeObject CoreType = {
    PyVarObject_HEAD_INIT(NULL, 0)
    .tp_name = "pmctl.motion.ncore._ncore.Core",
    .tp_basicsize = sizeof(CoreObject),
    .tp_flags = Py_TPFLAGS_DEFAULT,
    .tp_doc = "Core(consts, s, n, comp=None): the compiled NC tick on caller-owned state buffers "
              "(comp: the flat compensation table, pmctl.core.compensation)",
    .tp_new = PyType_GenericNew,
    .tp_init = (initproc)Core_init,
    .tp_dealloc = (destructor)Core_dealloc,
    .tp_methods = Core_methods,
};

static struct PyModuleDef moddef = {PyModuleDef_HEAD_INIT, "_ncore", "pmctl compiled NC core", -1, NULL};

PyMODINIT_FUNC PyInit__ncore(void)
{
    PyObject *m = pmctl_module_with_type(&moddef, &CoreType, "Core");
    if (m == NULL)
        return NULL;
#define C(name) PyModule_AddIntConstant(m, #name, name)
    C(NC_C_LEN); C(NC_S_LEN); C(NC_N_LEN);
    C(NC_S_ACC); C(NC_S_QDOT); C(NC_S_P); C(NC_S_R); C(NC_S_TIP); C(NC_S_AXIS); C(NC_S_PERR);
    C(NC_S_QM); C(NC_S_T); C(NC_S_EV); C(NC_S_CDIR); C(NC_S_CBL); C(NC_S_COMP); C(NC_S_KTH); C(NC_S_OFF);
    C(NC_N_COUNTS); C(NC_N_PULSES); C(NC_N_MODE); C(NC_N_EVENT); C(NC_N_HAS_QM); C(NC_N_ITER);
    C(NC_EV_NONE); C(NC_EV_ENC_NONFINITE); C(NC_EV_STRAIN_NONFINITE); C(NC_EV_FERROR); C(NC_EV_FK_NOCONV);
    C(NC_EV_FK_BRANCH); C(NC_EV_FK_SINGULAR); C(NC_EV_SVD); C(NC_EV_PATH_ERROR); C(NC_EV_TILT);
    C(NC_EV_SOFT_LIMIT);
    C(NC_RUN); C(NC_STOPPING); C(NC_HALTED); C(NC_DONE);
#undef C
    if (PyModule_AddObject(m, "NC_REST_FF", PyFloat_FromDouble(NC_REST_FF)) < 0) {
        Py_DECREF(m);
        return NULL;
    }
    if (PyModule_AddObject(m, "NC_COMP_STILL", PyFloat_FromDouble(NC_COMP_STILL)) < 0) {
        Py_DECREF(m);
        return NULL;
    }
    if (PyModule_AddObject(m, "NC_VF_TIE", PyFloat_FromDouble(NC_VF_TIE)) < 0) {
        Py_DECREF(m);
        return NULL;
    }
    return m;
}

/* CPython binding of the compiled path follower (follow.c): a Follower object holds the constants
 * and pins the caller's buffers (state, the source ring's counters and rows, the target); next()
 * runs one tick on them and returns the target object. No allocation per tick. */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include "pymodule.h"

#include "follow.h"

typedef struct {
    PyObject_HEAD
    fl_const c;
    fl_src src;
    Py_buffer bst, bctr, bdata, btg;
    int have;                /* how many of the four buffers are held */
    PyObject *tg;            /* the target object, returned by next() */
} FollowerObject;

/* A C-contiguous buffer of 8-byte items, format 'd' (or 'q'/'l' with is_int); n < 0: any length. */
static int get_buf(PyObject *o, Py_buffer *v, Py_ssize_t n, int writable, int is_int, const char *what)
{
    const char *f;
    if (PyObject_GetBuffer(o, v, PyBUF_C_CONTIGUOUS | PyBUF_FORMAT | (writable ? PyBUF_WRITABLE : 0)) < 0)
        return -1;
    f = v->format ? v->format : "B";
    if (*f == '<' || *f == '=' || *f == '@')
        f++;
    if (v->itemsize != 8 || (n >= 0 && v->len != n * 8) ||
        (is_int ? !(f[0] == 'q' || f[0] == 'l') : f[0] != 'd') || f[1] != '\0') {
        if (n >= 0)
            PyErr_Format(PyExc_ValueError, "%s: need a contiguous %s buffer of %zd items", what,
                         is_int ? "int64" : "float64", n);
        else
            PyErr_Format(PyExc_ValueError, "%s: need a contiguous %s buffer", what, is_int ? "int64" : "float64");
        PyBuffer_Release(v);
        return -1;
    }
    return 0;
}

static void release(FollowerObject *self)
{
    Py_buffer *b[4] = {&self->bst, &self->bctr, &self->bdata, &self->btg};
    int i;
    for (i = 0; i < self->have; i++)
        PyBuffer_Release(b[i]);
    self->have = 0;
    Py_CLEAR(self->tg);
}

static int Follower_init(FollowerObject *self, PyObject *args, PyObject *kw)
{
    PyObject *co, *so, *ctro, *datao, *tgo;
    Py_buffer cb;
    int width, r;
    static char *kwlist[] = {"consts", "state", "ctr", "data", "width", "target", NULL};
    if (!PyArg_ParseTupleAndKeywords(args, kw, "OOOOiO", kwlist, &co, &so, &ctro, &datao, &width, &tgo))
        return -1;
    release(self);
    if (width < 6) {
        PyErr_SetString(PyExc_ValueError, "width: rows need at least 6 columns (tip, axis)");
        return -1;
    }
    if (get_buf(co, &cb, FLC_LEN, 0, 0, "consts") < 0)
        return -1;
    r = fl_setup(&self->c, (const double *)cb.buf, (int)(cb.len / 8), width);
    PyBuffer_Release(&cb);
    if (r != 0) {
        PyErr_SetString(PyExc_ValueError, "consts: wrong layout (columns outside the row, or dt/k not > 0)");
        return -1;
    }
    if (get_buf(so, &self->bst, FL_LEN, 1, 0, "state") < 0)
        return -1;
    self->have = 1;
    if (get_buf(ctro, &self->bctr, 2, 1, 1, "ctr") < 0)
        goto fail;
    self->have = 2;
    if (get_buf(datao, &self->bdata, -1, 0, 0, "data") < 0)
        goto fail;
    self->have = 3;
    if (self->bdata.len % (8 * (Py_ssize_t)width) != 0) {
        PyErr_SetString(PyExc_ValueError, "data: not a whole number of rows of that width");
        goto fail;
    }
    if (get_buf(tgo, &self->btg, 12, 1, 0, "target") < 0)
        goto fail;
    self->have = 4;
    self->src.ctr = (int64_t *)self->bctr.buf;
    self->src.data = (const double *)self->bdata.buf;
    self->src.width = width;
    self->src.capacity = (int64_t)(self->bdata.len / (8 * (Py_ssize_t)width));
    Py_INCREF(tgo);
    self->tg = tgo;
    return 0;
fail:
    release(self);
    return -1;
}

static void Follower_dealloc(FollowerObject *self)
{
    release(self);
    Py_TYPE(self)->tp_free((PyObject *)self);
}

static int ready(FollowerObject *self)
{
    if (self->have != 4) {
        PyErr_SetString(PyExc_RuntimeError, "Follower not initialised");
        return 0;
    }
    return 1;
}

static PyObject *Follower_next(FollowerObject *self, PyObject *unused)
{
    (void)unused;
    if (!ready(self))
        return NULL;
    fl_next(&self->c, (double *)self->bst.buf, &self->src, (double *)self->btg.buf);
    Py_INCREF(self->tg);
    return self->tg;
}

static PyObject *Follower_clear(FollowerObject *self, PyObject *unused)
{
    (void)unused;
    if (!ready(self))
        return NULL;
    fl_clear(&self->c, (double *)self->bst.buf, &self->src);
    Py_RETURN_NONE;
}

static int five(PyObject *o, double *out, const char *what)
{
    PyObject *seq = PySequence_Fast(o, what);
    Py_ssize_t j;
    if (seq == NULL)
        return -1;
    if (PySequence_Fast_GET_SIZE(seq) != 5) {
        Py_DECREF(seq);
        PyErr_Format(PyExc_ValueError, "%s: need 5 values", what);
        return -1;
    }
    for (j = 0; j < 5; j++) {
        out[j] = PyFloat_AsDouble(PySequence_Fast_GET_ITEM(seq, j));
        if (out[j] == -1.0 && PyErr_Occurred()) {
            Py_DECREF(seq);
            return -1;
        }
    }
    Py_DECREF(seq);
    return 0;
}

static PyObject *Follower_sigma_step(FollowerObject *self, PyObject *args)
{
    double goal, qt[5], qtt[5];
    PyObject *qto, *qtto;
    if (!PyArg_ParseTuple(args, "dOO", &goal, &qto, &qtto))
        return NULL;
    if (!ready(self) || five(qto, qt, "qt") < 0 || five(qtto, qtt, "qtt") < 0)
        return NULL;
    return PyFloat_FromDouble(fl_sigma_step(&self->c, (double *)self->bst.buf, goal, qt, qtt));
}

static PyMethodDef Follower_methods[] = {
    {"next", (PyCFunction)Follower_next, METH_NOARGS, "next() -> target: one tick (PathFollower.next_target)"},
    {"clear", (PyCFunction)Follower_clear, METH_NOARGS, "clear(): drop the queued samples (PathFollower.clear)"},
    {"sigma_step", (PyCFunction)Follower_sigma_step, METH_VARARGS,
     "sigma_step(goal, qt, qtt) -> sigma (TimeScaler.step)"},
    {NULL, NULL, 0, NULL}
};

static PyTypeObject FollowerType = {
    PyVarObject_HEAD_INIT(NULL, 0)
    .tp_name = "pmctl.motion._follow.Follower",
    .tp_basicsize = sizeof(FollowerObject),
    .tp_dealloc = (destructor)Follower_dealloc,
    .tp_flags = Py_TPFLAGS_DEFAULT,
    .tp_doc = "Follower(consts, state, ctr, data, width, target): the compiled path follower",
    .tp_methods = Follower_methods,
    .tp_init = (initproc)Follower_init,
    .tp_new = PyType_GenericNew,
};

static struct PyModuleDef followmodule = {
    PyModuleDef_HEAD_INIT, "_follow", "The compiled path follower (pmctl.motion.timescale).", -1, NULL,
    NULL, NULL, NULL, NULL
};

PyMODINIT_FUNC PyInit__follow(void)
{
    PyObject *m = pmctl_module_with_type(&followmodule, &FollowerType, "Follower");
    if (m == NULL)
        return NULL;
#define C(name) PyModule_AddIntConstant(m, #name, name)
    C(FL_SIGMA); C(FL_DSIGMA); C(FL_FEED_OV); C(FL_RAPID_OV); C(FL_HOLD); C(FL_ACCEL); C(FL_JERK);
    C(FL_FRAC); C(FL_LINE); C(FL_STATE); C(FL_S_TOTAL); C(FL_ENDED); C(FL_AT_END); C(FL_HAS_REST);
    C(FL_REST); C(FL_REASON); C(FL_LEN);
    C(FLC_DT); C(FLC_K); C(FLC_AMAX); C(FLC_COL_CAP); C(FLC_COL_LINE); C(FLC_COL_FLAGS); C(FLC_COL_QT);
    C(FLC_COL_QTT); C(FLC_FLAG_RAPID); C(FLC_FLAG_END); C(FLC_LEN);
    C(FL_R_NONE); C(FL_R_DRY); C(FL_R_STARVED);
#undef C
    return m;
}

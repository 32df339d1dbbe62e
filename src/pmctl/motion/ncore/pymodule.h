/* The CPython module boilerplate the compiled parts share (the NC core, the sim plant's tick, the
 * path follower): a module holding one type. Header only; include after Python.h. */
#ifndef PMCTL_PYMODULE_H
#define PMCTL_PYMODULE_H

/* The module of ``def`` with ``type`` added as ``name``; NULL with a Python error set on failure. */
static PyObject *pmctl_module_with_type(PyModuleDef *def, PyTypeObject *type, const char *name)
{
    PyObject *m;
    if (PyType_Ready(type) < 0)
        return NULL;
    m = PyModule_Create(def);
    if (m == NULL)
        return NULL;
    Py_INCREF(type);
    if (PyModule_AddObject(m, name, (PyObject *)type) < 0) {
        Py_DECREF(type);
        Py_DECREF(m);
        return NULL;
    }
    return m;
}

#endif

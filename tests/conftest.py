"""Imported by pytest before the test modules: pmctl first, so that its one-BLAS-thread default
(pmctl/__init__.py) is in place before any test module imports numpy."""

import sys

_numpy_first = "numpy" in sys.modules
import pmctl  # noqa: E402,F401

if _numpy_first:                     # pragma: no cover -- a plugin imported numpy before us
    sys.stderr.write("tests/conftest.py: numpy was imported before pmctl; BLAS threads as the environment says\n")

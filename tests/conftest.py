"""Imported by pytest before the test modules: pmctl first, so that its one-BLAS-thread default
(pmctl/__init__.py) is in place before any test module imports numpy."""

import sys

_numpy_first = "numpy" in sys.modules
import pmctl  # noqa: E402,F401

if _numpy_first:                     # pragma: no cover -- a plugin imported numpy before us
    sys.stderr.write("tests/conftest.py: numpy was imported before pmctl; BLAS threads as the environment says\n")

# The tests sit in one folder per layer (tests/core, hal, motion, task, interfaces, tools,
# integration); the support modules beside this file and a few helpers of one test module used by
# another (test_loop's line_traj, test_canopen's Listener, ...) are imported by module name, so
# every folder is on the path, as the flat folder was.
import os as _os  # noqa: E402

_here = _os.path.dirname(_os.path.abspath(__file__))
for _d in ("core", "hal", "motion", "task", "interfaces", "tools", "integration"):
    _p = _os.path.join(_here, _d)
    if _p not in sys.path:
        sys.path.append(_p)
if _here not in sys.path:
    sys.path.insert(0, _here)

"""pmctl: controller and digital twin for the 3-RPS + XY-table hybrid milling machine."""

import os as _os

# One BLAS thread unless the user says otherwise. pmctl's linear algebra is small matrices (a
# 2 x 2 mode transition, least squares of a few columns) many times over: OpenBLAS's worker threads
# only add hand-offs there, and they spin. On a 2-core controller that also runs the real-time
# loop they take its CPU. Measured: one diagnosis took 10.9 s with the default threads next to
# two other busy processes and 2.6 s with one (docs/service.md, "BLAS threads"). Set before numpy is imported
# (pmctl's own entry points import pmctl first); OPENBLAS_NUM_THREADS in the environment wins.
_os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

__version__ = "0.1.0"

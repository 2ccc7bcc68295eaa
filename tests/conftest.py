"""Shared test setup: one BLAS thread per process.

The kernel matrices are small (hundreds); multi-threaded OpenBLAS made them up to 10x slower on a
busy 2-core machine (measured), and tests run beside other processes.
"""

import os

for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(var, "1")

"""Shared test setup: one BLAS thread per process; a free loopback endpoint per Zenoh test.

The kernel matrices are small (hundreds); multi-threaded OpenBLAS made them up to 10x slower on a
busy 2-core machine (measured), and tests run beside other processes.

Zenoh tests take their ports and robot names from ``loopback`` (plain functions, for module-scoped
fixtures and helpers too); ``endpoint`` is the fixture form for a test that needs one hub or listener.
"""

import os

import pytest
from loopback import free_endpoint

for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(var, "1")


@pytest.fixture
def endpoint() -> str:
    """A Zenoh endpoint on a free loopback port, for this test alone."""
    return free_endpoint()

"""pytest configuration.  The README's test command runs the suite on every core (pytest-xdist, ``-n auto``): each
worker then keeps to one BLAS thread, so that two workers on two cores do not oversubscribe them (set before the
test modules import numpy; a variable set by the caller is kept)."""

import os

if os.environ.get("PYTEST_XDIST_WORKER"):
    for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(var, "1")

"""pytest configuration.

* The slow tier: tests marked ``slow`` (the fifteen heaviest validation runs, 0.3-1.7 min each) are left out of a plain
  ``pytest`` run, which must take under 10 minutes on 2 cores; ``--slow`` runs them too, ``-m slow`` only them, and a
  test named by its node id (``file.py::test``) always runs.  CI (.ci/run) runs both tiers.
* The README's test command runs the suite on every core (pytest-xdist, ``-n auto``): each worker then keeps to one
  BLAS thread, so that two workers on two cores do not oversubscribe them (set before the test modules import numpy;
  a variable set by the caller is kept).
"""

import os

import pytest

if os.environ.get("PYTEST_XDIST_WORKER"):
    for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(var, "1")


def pytest_addoption(parser):
    parser.addoption("--slow", action="store_true", help="also run the slow tier (tests marked slow)")


def pytest_collection_modifyitems(config, items):
    if config.getoption("--slow") or config.option.markexpr or any("::" in str(a) for a in config.args):
        return
    slow = [item for item in items if item.get_closest_marker("slow") is not None]
    if slow:
        config.hook.pytest_deselected(items=slow)
        items[:] = [item for item in items if item.get_closest_marker("slow") is None]

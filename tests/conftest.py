import os
import sys

import numpy as np
import pytest
from hypothesis import settings

from mpmref.backends import BACKENDS
from mpmref.backends.numba import twin

# the repository root, for the exercises' worked solutions (exercises/, not an installed package)
sys.path.append(os.path.normpath(os.path.join(os.path.dirname(os.path.abspath(__file__)), "..")))
# Numba's cache: mpmref's own per-user folder (mpmref/__init__.py, imported above), or NUMBA_CACHE_DIR if set
# the thread-count determinism test needs at least two Numba threads, even on a one-core machine
os.environ.setdefault("NUMBA_NUM_THREADS", str(max(2, os.cpu_count() or 1)))
# the tests run the Numba kernels' serial builds, which compile in about 60 % of the time of the parallel builds and
# give the same bits (tests/test_numba_backend.py compares them step by step); the tests whose point is threads run the
# parallel builds (the fixture parallel_builds). MPMREF_KERNEL_BUILDS=parallel runs every test on the parallel builds.
# Set in the environment, so that the processes a test starts (verify's, study's, the command line's) do the same.
os.environ.setdefault(twin.BUILDS_VARIABLE, "serial")
twin.choose_again(twin.mode_from_environment())
settings.register_profile("mpmref", derandomize=True, deadline=None, max_examples=25)
settings.load_profile("mpmref")


@pytest.fixture
def parallel_builds():
    """The Numba kernels run their parallel builds within the test (what a test of thread counts needs)."""
    with twin.builds("parallel"):
        yield


@pytest.fixture
def rng():
    return np.random.default_rng(20181101)


@pytest.fixture(params=BACKENDS)
def backend(request):
    """Every backend of ``mpmref.backends.BACKENDS`` in turn: a test taking it runs on each, and on any added."""
    return request.param


@pytest.fixture(params=[b for b in BACKENDS if b != "numpy"])
def candidate(request):
    """Every backend but the NumPy reference, each to be compared with it."""
    return request.param


@pytest.fixture(autouse=True)
def no_chosen_thread_count(monkeypatch):
    """No test inherits a thread count chosen by another (``--threads`` in an in-process command line sets it for
    the process): each starts with none chosen (an empty value), and the value before it is restored after it;
    tests that compare thread counts set them with Numba themselves."""
    from mpmref.backends.numba.threads import THREADS_VARIABLE

    monkeypatch.setenv(THREADS_VARIABLE, "")

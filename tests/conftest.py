import os
import sys

import numpy as np
import pytest
from hypothesis import settings

# the repository root, for the exercises' worked solutions (exercises/, not an installed package)
sys.path.append(os.path.normpath(os.path.join(os.path.dirname(os.path.abspath(__file__)), "..")))
os.environ.setdefault("NUMBA_CACHE_DIR", os.path.join(os.path.dirname(__file__), "..", ".numba_cache"))
# the thread-count determinism test needs at least two Numba threads, even on a one-core machine
os.environ.setdefault("NUMBA_NUM_THREADS", str(max(2, os.cpu_count() or 1)))
settings.register_profile("mpmref", derandomize=True, deadline=None, max_examples=25)
settings.load_profile("mpmref")


@pytest.fixture
def rng():
    return np.random.default_rng(20181101)

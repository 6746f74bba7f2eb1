import os

import numpy as np
import pytest
from hypothesis import settings

os.environ.setdefault("NUMBA_CACHE_DIR", os.path.join(os.path.dirname(__file__), "..", ".numba_cache"))
# the thread-count determinism test needs at least two Numba threads, even on a one-core machine
os.environ.setdefault("NUMBA_NUM_THREADS", str(max(2, os.cpu_count() or 1)))
settings.register_profile("mpmref", derandomize=True, deadline=None, max_examples=25)
settings.load_profile("mpmref")


@pytest.fixture
def rng():
    return np.random.default_rng(20181101)

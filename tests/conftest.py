import os

import numpy as np
import pytest
from hypothesis import settings

os.environ.setdefault("NUMBA_CACHE_DIR", os.path.join(os.path.dirname(__file__), "..", ".numba_cache"))
settings.register_profile("mpmref", derandomize=True, deadline=None, max_examples=25)
settings.load_profile("mpmref")


@pytest.fixture
def rng():
    return np.random.default_rng(20181101)

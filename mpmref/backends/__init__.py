"""Execution backends. Each exposes the same stages: ``p2g``, ``grid_update``, ``g2p``."""

BACKENDS = ("numpy", "numba")


def make_backend(name, scene):
    """Instantiate the backend called ``name`` for ``scene``."""
    if name == "numpy":
        from .numpy import NumpyBackend

        return NumpyBackend(scene)
    if name == "numba":
        from .numba import NumbaBackend

        return NumbaBackend(scene)
    raise ValueError(f"unknown backend {name!r}: available backends are {list(BACKENDS)}")

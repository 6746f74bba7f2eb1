"""Execution backends. Each exposes the same stages: ``p2g``, ``grid_update``, ``g2p``."""

BACKENDS = ("numpy",)


def make_backend(name, scene):
    """Instantiate the backend called ``name`` for ``scene``."""
    if name == "numpy":
        from .numpy import NumpyBackend

        return NumpyBackend(scene)
    raise ValueError(f"unknown backend {name!r}: available backends are {list(BACKENDS)}")

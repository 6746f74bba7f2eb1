"""Execution backends. Each exposes the same stages: ``p2g``, ``grid_update``, ``g2p``."""

from ..errors import SceneError

BACKENDS = ("numpy",)


def make_backend(name, scene):
    """Instantiate the backend called ``name`` for ``scene``."""
    if name == "numpy":
        from .numpy import NumpyBackend

        return NumpyBackend(scene)
    raise SceneError("backend", name, f"one of {list(BACKENDS)}")

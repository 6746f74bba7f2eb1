"""Execution backends: each fulfils the contract of :mod:`mpmref.backends.base` (its stages), which
:func:`make_backend` checks."""

BACKENDS = ("numpy", "numba")


def make_backend(name, scene):
    """Instantiate the backend called ``name`` for ``scene``; a :class:`~.base.Backend`, and a
    :class:`~.base.CoupledBackend` where the scene has rigid bodies (else ``TypeError`` naming what is missing)."""
    if name == "numpy":
        from .numpy import NumpyBackend as backend_class
    elif name == "numba":
        from .numba import NumbaBackend as backend_class
    else:
        raise ValueError(f"unknown backend {name!r}: available backends are {list(BACKENDS)}")
    return checked(backend_class(scene), name)


def checked(backend, name):
    """``backend`` if it has every stage its scene needs (:mod:`.base`); ``TypeError`` otherwise."""
    from .base import ASYNC_BACKEND_STAGES, BACKEND_STAGES, CPIC_BACKEND_STAGES

    needed = BACKEND_STAGES + ASYNC_BACKEND_STAGES + ("running",)
    needed += CPIC_BACKEND_STAGES if backend.scene.rigid_bodies else ()
    missing = [stage for stage in needed if not callable(getattr(backend, stage, None))]
    if missing:
        raise TypeError(f"backend {name!r} lacks the stage(s) {missing} (the contract: mpmref.backends.base)")
    return backend

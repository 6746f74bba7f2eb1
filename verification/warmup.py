"""Compile the kernels of the cases still to come, in a background process, while the earlier cases run.

A compiled backend (Numba) compiles a scene's kernels on its first step, about 25 s on a fresh cache
for the ``backends`` case's five schemes. ``mpmref verify`` runs the NumPy-only cases first and they
leave a core idle much of the time, so :func:`start` compiles the kernels of every scene that a case
declares through its ``compiled_scenes(params, backend)`` into Numba's on-disk cache (the folder that
``NUMBA_CACHE_DIR`` names, inherited by the child process); the cases then load them instead of
compiling. The result of a case never depends on this: a kernel that is not yet in the cache when a case
needs it is compiled there as before.

Numba has no lock between processes: a case that starts while the warm-up is still compiling its kernels
would compile them a second time, on the other core (measured: the ``backends`` quick preset took 134 s of
CPU that way against 64 s alone). So ``mpmref verify`` runs the cases that declare compiled scenes after
the others, and :func:`wait` for the warm-up before the first of them: every kernel compiles once.
"""

import multiprocessing

from mpmref.backends import make_backend
from mpmref.bodies import sample_particles

from . import registry


def scenes_to_compile(names, preset, backend):
    """``[(backend name, scene)]`` that the cases ``names`` will run on a compiled backend."""
    out = []
    for name in names:
        module = registry.load(name)
        if hasattr(module, "compiled_scenes"):
            out += module.compiled_scenes(registry.preset_params(module, preset), backend)
    return out


def compile_scenes(names, preset, backend):
    """Compile (or load) every kernel of :func:`scenes_to_compile` with one Δt = 0 step of each scene."""
    for name, scene in scenes_to_compile(names, preset, backend):
        compiled = make_backend(name, scene)
        compiled.warm_up(sample_particles(scene))


def start(names, preset, backend):
    """Start :func:`compile_scenes` in a daemon process (spawned: no state shared); ``None`` when no case
    declares a compiled scene. The caller ends it with :func:`stop`."""
    if not scenes_to_compile(names, preset, backend):
        return None
    process = multiprocessing.get_context("spawn").Process(target=compile_scenes, args=(names, preset, backend),
                                                           daemon=True, name="mpmref-warm-up")
    process.start()
    return process


def compiles(name, preset, backend):
    """Whether case ``name`` runs scenes on a compiled backend (it declares them in ``compiled_scenes``)."""
    return bool(scenes_to_compile([name], preset, backend))


def wait(process, progress):
    """Wait for the warm-up to finish (a line through ``progress`` when it is still running)."""
    if process is None or not process.is_alive():
        return
    progress("waiting for the background compilation to finish (each kernel compiles once)")
    process.join()


def stop(process):
    """End the warm-up process if it is still running (every case has run)."""
    if process is not None and process.is_alive():
        process.terminate()
    if process is not None:
        process.join()

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

The scenes form a queue that two workers take from, one from each end, each scene claimed under a lock:
the background process from the front from the start, and, once the NumPy cases are done and the core
they used is free, the main process from the back (:func:`wait`). No scene is compiled twice, and the
kernels the main process compiles stay in its memory for the cases that follow.
"""

import multiprocessing
from dataclasses import dataclass

from mpmref.backends import make_backend
from mpmref.bodies import sample_particles

from . import registry


def scenes_to_compile(names, preset, backend):
    """``[(backend name, scene)]`` that the cases ``names`` will run on a compiled backend, without the scenes
    whose kernels the scenes before them already compile (``compiled_kernels()`` of the backend: such a scene
    would only load them from the cache, or, taken by the other worker at the same time, compile them twice)."""
    out, covered = [], set()
    for name in names:
        module = registry.load(name)
        for backend_name, scene in getattr(module, "compiled_scenes", lambda *_: [])(
                registry.preset_params(module, preset), backend):
            compiled = make_backend(backend_name, scene)
            kernels = compiled.compiled_kernels() if hasattr(compiled, "compiled_kernels") else {id(scene)}
            if not kernels <= covered:
                covered |= kernels
                out.append((backend_name, scene))
    return out


def compile_scenes(names, preset, backend, queue=None, from_back=False):
    """Compile (or load) every kernel of :func:`scenes_to_compile` with one Δt = 0 step of each scene; with a
    ``queue`` (shared ``[front, back)`` bounds, see :func:`start`), only the scenes this worker claims."""
    scenes = scenes_to_compile(names, preset, backend)
    queue = queue if queue is not None else multiprocessing.Array("i", [0, len(scenes)])
    while (index := claim(queue, from_back)) is not None:
        name, scene = scenes[index]
        make_backend(name, scene).warm_up(sample_particles(scene))


def claim(queue, from_back):
    """Index of the next scene to compile from the front or the back of ``queue``, or ``None`` when empty."""
    with queue.get_lock():
        front, back = queue[0], queue[1]
        if front >= back:
            return None
        if from_back:
            queue[1] = back - 1
            return back - 1
        queue[0] = front + 1
        return front


@dataclass
class WarmUp:
    """The background compilation: its process, the shared queue bounds, and what :func:`wait` needs to
    take the other end of the queue."""

    process: multiprocessing.Process
    queue: object
    job: tuple

    def is_alive(self):
        return self.process.is_alive()


def start(names, preset, backend):
    """Start :func:`compile_scenes` in a daemon process (spawned: no state shared) on the front of a shared
    queue of the scenes; ``None`` when no case declares a compiled scene. The caller ends it with
    :func:`stop`."""
    scenes = scenes_to_compile(names, preset, backend)
    if not scenes:
        return None
    context = multiprocessing.get_context("spawn")
    queue = context.Array("i", [0, len(scenes)])
    job = (names, preset, backend)
    process = context.Process(target=compile_scenes, args=(*job, queue), daemon=True, name="mpmref-warm-up")
    process.start()
    return WarmUp(process, queue, job)


def compiles(name, preset, backend):
    """Whether case ``name`` runs scenes on a compiled backend (it declares them in ``compiled_scenes``)."""
    return bool(scenes_to_compile([name], preset, backend))


def wait(warm_up, progress):
    """Compile the scenes still queued from the back here, beside the background process, then wait for it
    (a line through ``progress`` when it is still running)."""
    if warm_up is None or not warm_up.is_alive():
        return
    progress("compiling the rest of the kernels here and in the background process (each kernel compiles once)")
    compile_scenes(*warm_up.job, queue=warm_up.queue, from_back=True)
    warm_up.process.join()


def stop(warm_up):
    """End the warm-up process if it is still running (every case has run)."""
    if warm_up is not None and warm_up.is_alive():
        warm_up.process.terminate()
    if warm_up is not None:
        warm_up.process.join()

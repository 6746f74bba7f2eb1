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
CPU that way against 64 s alone). So a case that declares compiled scenes starts only once every scene it
needs is compiled (:func:`can_start`: then, between two NumPy cases, while the warm-up goes on with the
others) or after :func:`wait` for the whole warm-up; every kernel compiles once. A case that times its
runs (``runs_alone=True`` in its :class:`~verification.framework.case.VerificationCase`) always waits for the whole
warm-up: compilation on the other core would slow what it measures.

The queue (:func:`plan`) holds one scene per set of kernels not yet compiled by the scenes before it
(``compiled_kernels()`` of the backend), the scenes of cases that may start early first, fewest first,
and within a case the scene compiling the most kernels first (the short ones are left for the end).
Two workers take from it, one from each end, each scene claimed under a lock: the background process
from the front from the start, and, once the NumPy cases are done and the core they used is free, the
main process from the back (:func:`wait`). No scene is compiled twice, and the kernels the main process
compiles stay in its memory for the cases that follow.
"""

import multiprocessing
from dataclasses import dataclass

from mpmref import Simulation
from mpmref.backends import make_backend, resolve

from . import registry
from .executor import interrupts_held, worker_signals


def declared_scenes(name, preset, backend):
    """``[(backend name, scene)]`` that case ``name`` runs on a compiled backend (its ``compiled_scenes``), for the
    backends that can compile ahead (a ``warm_up`` method, as the Numba backend has; a user's backend without one
    compiles, if it does, in the case itself)."""
    case = registry.load(name)
    return [(b, scene) for b, scene in case.compiled_scenes(case.params(preset), backend) if warms_up(b)]


def warms_up(reference):
    """Whether the backend ``reference`` names has a ``warm_up(particles, step)`` to compile ahead."""
    return callable(getattr(resolve(reference), "warm_up", None))


def runs_alone(name):
    """Whether case ``name`` times its runs and so starts only after the whole warm-up (its ``runs_alone``)."""
    return registry.load(name).runs_alone


def plan(names, preset, backend):
    """The compile queue ``[(backend name, scene)]`` of the cases ``names``, and per case the queue positions
    that compile its kernels (``{name: set}``).

    Cases that may start early come first, the one needing the fewest scenes first (it is ready soonest);
    within a case, the scene that compiles the most kernels not yet queued comes first, so that the scenes
    left at the end, which the two workers take from the two ends of the queue, are short ones. A scene
    enters the queue only if it compiles something the scenes before it do not (the kernels a backend's
    ``compiled_kernels()`` names; a backend without it always enters).
    """
    declared = {name: declared_scenes(name, preset, backend) for name in names}
    queue, first = [], {}  # first: kernel -> position of the first scene that compiles it
    needs = {}
    for name in sorted((n for n in names if declared[n]), key=lambda n: (runs_alone(n), len(declared[n]))):
        needs[name] = set()
        pending = [(backend_name, scene, _kernels(backend_name, scene)) for backend_name, scene in declared[name]]
        while pending:  # the scene compiling the most kernels not yet queued first: the short ones come last
            backend_name, scene, kernels = pending.pop(max(range(len(pending)),
                                                           key=lambda i: len(pending[i][2] - first.keys())))
            if not kernels <= first.keys():
                for kernel in kernels - first.keys():
                    first[kernel] = len(queue)
                queue.append((backend_name, scene))
            needs[name] |= {first[kernel] for kernel in kernels}
    return queue, needs


def _kernels(backend_name, scene):
    """The compiled kernels a scene runs (``compiled_kernels()`` of its backend; the scene itself without it), and
    its stepping: an asynchronous scene compiles its stepper's bookkeeping and the backend's row stages too, and
    their kernels depend on the particle fields the scene allocates (:meth:`~mpmref.run.Simulation.warm_up`)."""
    compiled = make_backend(backend_name, scene)
    kernels = compiled.compiled_kernels() if hasattr(compiled, "compiled_kernels") else {id(scene)}
    if scene.time.stepping == "async":
        kernels = kernels | {("async", scene.dtype.str, scene.transfer.transfer, scene.tracks("F"), scene.tracks("J"),
                              scene.tracks("Jp"))}
    return kernels


def scenes_to_compile(names, preset, backend):
    """The compile queue of :func:`plan`: ``[(backend name, scene)]`` that the cases ``names`` run on a
    compiled backend, one for each set of kernels that the scenes before it do not compile."""
    return plan(names, preset, backend)[0]


def compile_scenes(names, preset, backend, queue=None, from_back=False, done=None):
    """Compile (or load) every kernel of :func:`scenes_to_compile` as a run of each scene does before it is timed
    (:meth:`mpmref.run.Simulation.warm_up`: one Δt = 0 step, and an asynchronous stepper's bookkeeping); with a
    ``queue`` (shared ``[front, back)`` bounds, see :func:`start`), only the scenes this worker claims, each
    marked in the shared flags ``done`` once compiled."""
    scenes = scenes_to_compile(names, preset, backend)
    queue = queue if queue is not None else multiprocessing.Array("i", [0, len(scenes)])
    while (index := claim(queue, from_back)) is not None:
        name, scene = scenes[index]
        Simulation(scene, backend=name).warm_up()  # the backend's kernels and, if asynchronous, its stepper's
        if done is not None:
            done[index] = 1


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
    """The background compilation: its process, the shared queue bounds and per-scene ``done`` flags, what
    :func:`wait` needs to take the other end of the queue, and the queue positions each case needs."""

    process: multiprocessing.Process
    queue: object
    done: object
    job: tuple
    needs: dict

    def is_alive(self):
        return self.process.is_alive()


def start(names, preset, backend):
    """Start :func:`compile_scenes` in a daemon process (spawned: no state shared) on the front of a shared
    queue of the scenes; ``None`` when no case declares a compiled scene. The caller ends it with
    :func:`stop`."""
    scenes, needs = plan(names, preset, backend)
    if not scenes:
        return None
    context = multiprocessing.get_context("spawn")
    queue = context.Array("i", [0, len(scenes)])
    done = context.Array("b", len(scenes))
    job = (names, preset, backend)
    process = context.Process(target=compile_in_background, args=(*job, queue, done), daemon=True,
                              name="mpmref-warm-up")
    with interrupts_held():  # the new interpreter starts with SIGINT blocked: Ctrl-C is the main process's to take
        process.start()
    return WarmUp(process, queue, done, job, needs)


def compile_in_background(names, preset, backend, queue, done):
    """:func:`compile_scenes` from the front of ``queue`` in the background process, which leaves Ctrl-C to the main
    process and, ended by :func:`stop`, exits without leaking (:func:`~.executor.worker_signals`)."""
    worker_signals()
    compile_scenes(names, preset, backend, queue, False, done)


def compiles(name, preset, backend):
    """Whether case ``name`` runs scenes on a compiled backend (it declares them in ``compiled_scenes``)."""
    return bool(declared_scenes(name, preset, backend))


def can_start(warm_up, name):
    """Whether case ``name`` may start while the warm-up goes on: it does not run alone and every scene it
    needs is compiled."""
    if warm_up is None or runs_alone(name):
        return False
    return all(warm_up.done[index] for index in warm_up.needs.get(name, ()))


def wait(warm_up, progress):
    """Compile the scenes still queued from the back here, beside the background process, then wait until
    every scene is compiled (a line through ``progress`` when the background process is still running). The
    process itself may still be shutting down; :func:`stop` ends it."""
    if warm_up is None or not warm_up.is_alive():
        return
    progress("compiling the rest of the kernels here and in the background process (each kernel compiles once)")
    compile_scenes(*warm_up.job, queue=warm_up.queue, from_back=True, done=warm_up.done)
    while warm_up.is_alive() and not all(warm_up.done):
        warm_up.process.join(timeout=0.05)


def stop(warm_up):
    """End the warm-up process if it is still running (every case has run, or Ctrl-C stopped them)."""
    if warm_up is not None and warm_up.is_alive():
        warm_up.process.terminate()
    if warm_up is not None:
        warm_up.process.join()

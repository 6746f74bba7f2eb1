"""A first run that starts on serial kernels while another process compiles the parallel ones.

On a fresh cache most of a first run's time is compiling (about 30 s of a 32 s first run of ``examples/mpm88.toml``),
and a parallel kernel costs Numba about twice the compile time of the same kernel compiled serially
(:mod:`mpmref.backends.numba.twin`). :func:`warm_up` compiles a scene's kernels as :meth:`Simulation.warm_up
<mpmref.run.simulation.Simulation.warm_up>` does, except that a kernel whose parallel build is not yet in Numba's
disk cache is compiled serially; at the first kernel it has to compile, it starts a :class:`ParallelBuild`: another
process, on the other cores, which first helps with the serial builds, from the end of the step back while this
process compiles them from its start (:mod:`mpmref.backends.numba.shared_builds`), then compiles the parallel builds
of the same scene into the cache. The run steps on the serial kernels meanwhile and,
at the first step after that process has finished, goes on with the parallel kernels, loaded from the cache. A run
shorter than the parallel compilation ends on the serial kernels and stops the process (a later run compiles again
what it had not cached). The results are the same bits either way: the kernels do not depend on the number of
threads, and a serial build is one thread.
"""

import contextlib
import multiprocessing
import shutil
import tempfile

from ..backends.numba import shared_builds, twin


def warm_up(sim, backend):
    """Compile (or load) the kernels of ``sim``, serial builds for the parallel ones not cached yet; a started
    :class:`ParallelBuild` of the scene on ``backend`` (the name or reference ``sim`` was made with) if any kernel
    runs serially, else ``None``. Only where kernels run their parallel builds (the default mode of
    :mod:`~mpmref.backends.numba.twin`); in another mode, the kernels of that mode.

    The :class:`ParallelBuild` starts at the first kernel this process has to compile, and compiles the serial builds
    from the end of the step back while this process compiles them from its start
    (:mod:`~mpmref.backends.numba.shared_builds`)."""
    chosen = twin.mode()
    if chosen != "parallel":
        sim.warm_up()
        return None
    started = []

    def start():
        started.append(ParallelBuild(sim.scene, backend))
        return started[0]

    twin.choose_again("serial-until-cached")
    try:
        with twin.sharing(shared_builds.Leader(start)):
            sim.warm_up()
    except BaseException:
        twin.choose_again(chosen)
        for build in started:
            build.stop()
        raise
    if not twin.serial_kernels():
        twin.choose_again(chosen)
        for build in started:  # started for a new build of a kernel that runs in parallel: nothing runs serially
            build.stop()
        return None
    return started[0] if started else ParallelBuild(sim.scene, backend)


def compile_parallel(scene, backend, folder):
    """The helper process's work: help compile the serial builds of ``scene``'s step on ``backend`` from its last
    kernel back (the kernels the backend's warm-up step calls, recorded without running them), then compile the
    parallel builds of them, and of everything else the scene runs, into Numba's disk cache."""
    from ..backends.numba.backend import NumbaBackend
    from ..steppers.pipeline import substep
    from .simulation import Simulation

    sim = Simulation(scene, backend=backend)
    recorder = shared_builds.Recorder()
    if isinstance(sim.backend, NumbaBackend):  # the backend whose kernels are twins (the GPU's would run, not record)
        # a step whose kernels are skipped may fail where it reads what they did not write: what was recorded
        # before is compiled, and the warm-up below compiles the rest (and meets any real error)
        with twin.builds("serial"), twin.sharing(recorder), contextlib.suppress(Exception):
            sim.backend.warm_up(sim.particles, substep)
    shared_builds.compile_recorded(recorder.calls, shared_builds.Claims(folder))
    with twin.builds("parallel"):
        sim.warm_up()


class ParallelBuild:
    """The process compiling a scene's parallel kernels into the disk cache while this one runs serial builds (and
    first helping with the serial ones; :func:`compile_parallel`). Its :attr:`claims` are the two processes' claims on
    the builds they compile, in a temporary folder removed when the process has ended."""

    def __init__(self, scene, backend):
        #: the two processes' claims (:class:`~mpmref.backends.numba.shared_builds.Claims`)
        self.claims = shared_builds.Claims(tempfile.mkdtemp(prefix="mpmref-claims-"))
        self.process = multiprocessing.get_context("spawn").Process(
            target=compile_parallel, args=(scene, backend, self.claims.folder), daemon=True,
            name="mpmref-parallel-kernels")
        self.process.start()
        #: whether the kernels run their parallel builds now
        self.switched = False

    def alive(self):
        """Whether the process still compiles."""
        return self.process.is_alive()

    def poll(self):
        """Once the process has finished, every kernel runs its parallel build from its next call. Returns whether
        that happened at this call (once; a failed compilation leaves the serial builds running: the same bits)."""
        if self.switched or self.process.is_alive():
            return False
        self.switched = True
        shutil.rmtree(self.claims.folder, ignore_errors=True)
        if self.process.exitcode != 0:
            return False
        twin.use_parallel()
        return True

    def stop(self):
        """End the process if it still compiles (what it cached so far stays: Numba writes each file whole); kernels
        choose their parallel builds again from their next call."""
        if self.process.is_alive():
            self.process.terminate()
        self.process.join()
        shutil.rmtree(self.claims.folder, ignore_errors=True)
        twin.use_parallel()

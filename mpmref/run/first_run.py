"""A first run that starts on serial kernels while another process compiles the parallel ones.

On a fresh cache most of a first run's time is compiling (about 30 s of a 32 s first run of ``examples/mpm88.toml``),
and a parallel kernel costs Numba about twice the compile time of the same kernel compiled serially
(:mod:`mpmref.backends.numba.twin`). :func:`warm_up` compiles a scene's kernels as :meth:`Simulation.warm_up
<mpmref.run.simulation.Simulation.warm_up>` does, except that a kernel whose parallel build is not yet in Numba's
disk cache is compiled serially; if any is, it starts a :class:`ParallelBuild`: another process, on the other cores,
compiles the parallel builds of the same scene into the cache. The run steps on the serial kernels meanwhile and,
at the first step after that process has finished, goes on with the parallel kernels, loaded from the cache. A run
shorter than the parallel compilation ends on the serial kernels and stops the process (a later run compiles again
what it had not cached). The results are the same bits either way: the kernels do not depend on the number of
threads, and a serial build is one thread.
"""

import multiprocessing

from ..backends.numba import twin


def warm_up(sim, backend):
    """Compile (or load) the kernels of ``sim``, serial builds for the parallel ones not cached yet; a started
    :class:`ParallelBuild` of the scene on ``backend`` (the name or reference ``sim`` was made with) if any kernel
    runs serially, else ``None``. Only where kernels run their parallel builds (the default mode of
    :mod:`~mpmref.backends.numba.twin`); in another mode, the kernels of that mode."""
    chosen = twin.mode()
    if chosen != "parallel":
        sim.warm_up()
        return None
    twin.choose_again("serial-until-cached")
    try:
        sim.warm_up()
    except BaseException:
        twin.choose_again(chosen)
        raise
    if not twin.serial_kernels():
        twin.choose_again(chosen)
        return None
    return ParallelBuild(sim.scene, backend)


def compile_parallel(scene, backend):
    """Compile the parallel kernels of ``scene`` on ``backend`` into Numba's disk cache (the other process's work)."""
    from .simulation import Simulation

    Simulation(scene, backend=backend).warm_up()


class ParallelBuild:
    """The process compiling a scene's parallel kernels into the disk cache while this one runs serial builds."""

    def __init__(self, scene, backend):
        self.process = multiprocessing.get_context("spawn").Process(target=compile_parallel, args=(scene, backend),
                                                                     daemon=True, name="mpmref-parallel-kernels")
        self.process.start()
        #: whether the kernels run their parallel builds now
        self.switched = False

    def poll(self):
        """Once the process has finished, every kernel runs its parallel build from its next call. Returns whether
        that happened at this call (once; a failed compilation leaves the serial builds running: the same bits)."""
        if self.switched or self.process.is_alive():
            return False
        self.switched = True
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
        twin.use_parallel()

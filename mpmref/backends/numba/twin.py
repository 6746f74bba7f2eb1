r"""Parallel kernels a first run need not wait for: each can run compiled serially until its parallel build is cached.

Numba compiles a kernel with ``parallel=True`` in about twice the time of the same loop compiled serially: it
compiles the ``prange`` body a second time, as the function the threads run (measured on a first run of
``examples/mpm88.toml`` from empty caches: 31.7 s with the parallel kernels, 19.4 s with the same kernels serial;
docs/performance.md). A serial build gives the same bits: every kernel is written so that its result does not depend
on the number of threads (particles gathered by their own thread, scatters coloured so that no two threads write
a node in one pass, every sum in a fixed order), and one thread running the loop in order is such a count.

:func:`parallel_kernel` declares a kernel as both: a :class:`TwinKernel` runs its parallel build unless told
otherwise. With :func:`serial_until_cached`, a kernel whose parallel build is not in Numba's on-disk cache for the
arguments it is first called with runs its serial build (compiled once, and cached apart: its copy of the function
has its own name, ``NAME_serial``) until :func:`use_parallel` says the parallel builds have been compiled, by
another process, into the cache; it then loads them from there (:mod:`mpmref.backends.numba.first_run`).
"""

import types

from numba import njit

#: whether kernels whose parallel build is not cached run serially for now (:func:`serial_until_cached`)
_SERIAL_UNTIL_CACHED = [False]
#: the kernels declared so far (:func:`use_parallel` switches them)
_KERNELS = []


class TwinKernel:
    """A kernel compiled in parallel (``parallel``), and serially (``serial``, built when first needed); called like
    either, it runs the one :func:`serial_until_cached` and :func:`use_parallel` choose."""

    def __init__(self, function, options):
        self.function, self.options = function, options
        self.parallel = njit(parallel=True, **options)(function)
        self._serial = None
        self._run = None  # the build that runs: chosen at the first call
        _KERNELS.append(self)

    @property
    def serial(self):
        """The serial build: the function compiled without ``parallel`` (a copy named ``NAME_serial``, so that Numba's
        disk cache, which does not key on the options, keeps it apart from the parallel build)."""
        if self._serial is None:
            f = self.function
            copy = types.FunctionType(f.__code__, f.__globals__, f.__name__, f.__defaults__, f.__closure__)
            copy.__qualname__ = f.__qualname__ + "_serial"
            copy.__module__ = f.__module__
            self._serial = njit(**self.options)(copy)
        return self._serial

    def __call__(self, *args):
        run = self._run
        if run is None:
            run = self._run = self._choose(args)
        return run(*args)

    def _choose(self, args):
        """The build to run: the parallel one, unless serial runs are allowed and its parallel build for these
        arguments' types is neither compiled here nor in the disk cache."""
        if not _SERIAL_UNTIL_CACHED[0] or cached_build(self.parallel, args):
            return self.parallel
        return self.serial

    def use_parallel(self):
        """Run the parallel build from the next call on."""
        self._run = self.parallel


def cached_build(dispatcher, args):
    """Whether ``dispatcher`` has a build for the types of ``args``, compiled in this process or loaded now from
    Numba's disk cache (never compiled here)."""
    signature = tuple(dispatcher.typeof_pyval(a) for a in args)
    if signature in dispatcher.overloads:
        return True
    compiled = dispatcher._cache.load_overload(signature, dispatcher.targetctx)
    if compiled is None:
        return False
    dispatcher.targetctx.insert_user_function(compiled.entry_point, compiled.fndesc, [compiled.library])
    dispatcher.add_overload(compiled)
    return True


def parallel_kernel(function=None, **options):
    """Declare a parallel kernel (a :class:`TwinKernel`): ``@parallel_kernel(cache=True)`` in place of
    ``@njit(parallel=True, cache=True)``, or ``parallel_kernel(function, cache=True)``."""
    if function is None:
        return lambda f: TwinKernel(f, options)
    return TwinKernel(function, options)


def serial_until_cached(on=True):
    """From now on, a kernel first called with arguments whose parallel build is not cached runs serially (``on``),
    or every kernel runs its parallel build (``on=False``, the default). Kernels already called keep their choice."""
    _SERIAL_UNTIL_CACHED[0] = on


def serial_kernels():
    """The kernels that run their serial build now."""
    return [k for k in _KERNELS if k._run is not None and k._run is not k.parallel]


def use_serial():
    """Every kernel runs its serial build from its next call: what a first run does where nothing is cached (the
    tests compare its bits with the parallel builds')."""
    for kernel in _KERNELS:
        kernel._run = kernel.serial


def use_parallel():
    """Every kernel runs its parallel build from its next call (loaded from the disk cache, where another process put
    it, or compiled)."""
    for kernel in _KERNELS:
        kernel.use_parallel()

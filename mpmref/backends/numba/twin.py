r"""Parallel kernels a first run need not wait for: each can run compiled serially until its parallel build is cached.

Numba compiles a kernel with ``parallel=True`` in about twice the time of the same loop compiled serially: it
compiles the ``prange`` body a second time, as the function the threads run (measured on a first run of
``examples/mpm88.toml`` from empty caches: 31.7 s with the parallel kernels, 19.4 s with the same kernels serial;
docs/performance.md). A serial build gives the same bits: every kernel is written so that its result does not depend
on the number of threads (particles gathered by their own thread, scatters coloured so that no two threads write
a node in one pass, every sum in a fixed order), and one thread running the loop in order is such a count.

:func:`parallel_kernel` declares a kernel as both: a :class:`TwinKernel` runs its parallel build unless told
otherwise (:data:`MODES`): in the mode ``serial``, every kernel runs its serial build (compiled once, and cached apart:
its copy of the function has its own name, ``NAME_serial``); in the mode ``serial-until-cached``, a kernel whose
parallel build is not in Numba's on-disk cache for the arguments it is first called with runs its serial build
until :func:`use_parallel` says the parallel builds have been compiled, by another process, into the cache; it then
loads them from there (:mod:`mpmref.run.first_run`). The mode is ``parallel`` unless the environment variable
:data:`BUILDS_VARIABLE` says otherwise (the test suite runs in the mode ``serial``, but where threads are the point)
or :func:`builds` changes it for a block. Within :func:`sharing`, a kernel asks a *share* before it runs: the two
processes of a first run split its serial builds between them that way (:mod:`.shared_builds`).
"""

import os
import types
from contextlib import contextmanager

from numba import njit

from ...errors import ArgumentError

#: the environment variable that chooses the builds kernels run (:data:`MODES`); unset, ``parallel``
BUILDS_VARIABLE = "MPMREF_KERNEL_BUILDS"
#: the builds a kernel may run: ``parallel`` (the default), ``serial`` (every kernel compiled and run serially: a
#: shorter compilation for runs that gain nothing from threads, such as the tests), or ``serial-until-cached`` (a
#: kernel whose parallel build is not cached runs serially: :mod:`mpmref.run.first_run`)
MODES = ("parallel", "serial", "serial-until-cached")
#: the kernels declared so far (:func:`builds` makes them choose again)
_KERNELS = []
#: what a kernel asks before it runs, while two processes share a first run's compilation
#: (:mod:`~mpmref.backends.numba.shared_builds`, :func:`sharing`); ``None`` otherwise
_SHARE = [None]


def mode_from_environment(environ=os.environ):
    """The mode :data:`BUILDS_VARIABLE` names (``parallel`` when unset); another value is refused with the allowed
    ones."""
    mode = environ.get(BUILDS_VARIABLE) or "parallel"
    if mode not in MODES:
        raise ArgumentError(f"the environment variable {BUILDS_VARIABLE}", mode, "one of " + ", ".join(MODES))
    return mode


#: the mode kernels choose their build by, at their first call after it is set (:func:`builds`)
_MODE = [mode_from_environment()]


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

    @property
    def py_func(self):
        """The Python function both builds compile (as a Numba dispatcher's ``py_func``)."""
        return self.function

    @property
    def signatures(self):
        """The argument types compiled so far, by either build (as a Numba dispatcher's ``signatures``)."""
        serial = self._serial.signatures if self._serial is not None else []
        return list(self.parallel.signatures) + list(serial)

    def __call__(self, *args):
        run = self._run
        if run is None:
            run = self._run = self._choose(args)
        share = _SHARE[0]
        if share is not None and not share.admit(self, run, args):
            return None
        return run(*args)

    def _choose(self, args):
        """The build to run in the current mode: the parallel one, the serial one, or (``serial-until-cached``) the
        parallel one if its build for these arguments' types is compiled here or in the disk cache."""
        mode = _MODE[0]
        if mode == "parallel" or mode == "serial-until-cached" and cached_build(self.parallel,
                                                                                signature_of(self.parallel, args)):
            return self.parallel
        return self.serial


def signature_of(dispatcher, args):
    """The argument types ``dispatcher`` compiles for ``args``."""
    return tuple(dispatcher.typeof_pyval(a) for a in args)


def cached_build(dispatcher, signature):
    """Whether ``dispatcher`` has a build for the argument types ``signature`` (:func:`signature_of`), compiled in
    this process or loaded now from Numba's disk cache (never compiled here)."""
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


@contextmanager
def builds(mode):
    """Within the block, every kernel chooses its build by ``mode`` (one of :data:`MODES`) at its next call; after
    it, by the mode before."""
    if mode not in MODES:
        raise ArgumentError("mode", mode, "one of " + ", ".join(MODES))
    before = _MODE[0]
    choose_again(mode)
    try:
        yield
    finally:
        choose_again(before)


@contextmanager
def builds_everywhere(mode):
    """:func:`builds` for the block, here and in the processes started within it (which read
    :data:`BUILDS_VARIABLE`); the environment and the mode before are restored after it."""
    before = os.environ.get(BUILDS_VARIABLE)
    os.environ[BUILDS_VARIABLE] = mode
    try:
        with builds(mode):
            yield
    finally:
        if before is None:
            os.environ.pop(BUILDS_VARIABLE, None)
        else:
            os.environ[BUILDS_VARIABLE] = before


@contextmanager
def sharing(share):
    """Within the block, every kernel call asks ``share.admit(kernel, build, args)`` before it runs ``build`` on
    ``args``, and is skipped (returning ``None``) where the answer is ``False``: the two sides of a first run's
    shared compilation (:mod:`~mpmref.backends.numba.shared_builds`)."""
    before = _SHARE[0]
    _SHARE[0] = share
    try:
        yield share
    finally:
        _SHARE[0] = before


def mode():
    """The mode kernels choose their build by now (one of :data:`MODES`)."""
    return _MODE[0]


def choose_again(mode):
    """From now on, kernels choose their build by ``mode``, each at its next call."""
    _MODE[0] = mode
    for kernel in _KERNELS:
        kernel._run = None


def serial_kernels():
    """The kernels that run their serial build now."""
    return [k for k in _KERNELS if k._run is not None and k._run is not k.parallel]


def use_parallel():
    """Every kernel runs its parallel build from its next call (loaded from the disk cache, where another process put
    it, or compiled): what a first run does once they are cached."""
    choose_again("parallel")

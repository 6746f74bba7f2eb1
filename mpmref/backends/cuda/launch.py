"""Kernels with declared argument types, launched over a number of threads; device functions.

Every kernel of the backend is a :class:`DeviceKernel`: a Python function and the Numba types of its arguments,
declared where the kernel is made. The types are the kernel's signature on the GPU (it is compiled for exactly
them, at its first launch, so an argument of another type is an error there, not a second specialisation), what
:meth:`DeviceKernel.ptx` compiles for a compute capability without a GPU (``numba.cuda.compile_ptx``), and what
the simulator checks each launch's arguments against (it runs the Python function and checks no types itself).
"""

from contextlib import contextmanager
from types import SimpleNamespace

import numpy as np
from numba import from_dtype, types

from ..pointwise import on_device
from .runtime import load, simulated

#: threads per block of every launch; the simulator, which runs each thread of a block as a Python thread, gets
#: blocks of 32 (the kernels' reductions and scans work for any power of two)
BLOCK = 32 if simulated() else 128
#: whether the simulator runs the kernels (set before Numba is imported, so fixed for the process)
SIMULATED = simulated()

# the decorator of every device function: compiled once per argument types and inlined into each kernel that calls
# it by NVVM (``forceinline``). Inlining at Numba's IR level instead (``inline="always"``) types and lowers a
# function again at every call site: a 3D step's kernels then compiled in about 60 s instead of 21 s (measured here
# with ``compile_ptx``, sand in 3D). The simulator, which runs them as Python, takes no such option.
def device_function(fn):
    """``fn`` as a numba-cuda device function, inlined into its callers by NVVM (see above)."""
    cuda = load()
    return (cuda.jit(device=True) if SIMULATED else cuda.jit(device=True, forceinline=True))(fn)


def device(function):
    """The device version of a pointwise function (:func:`mpmref.backends.pointwise.on_device`), made with
    :func:`device_function`: the same source the Numba backend compiles for the CPU."""
    return on_device(function, device_function)


def array(dtype, ndim):
    """The Numba type of a C-contiguous array of ``dtype`` with ``ndim`` dimensions."""
    return types.Array(from_dtype(np.dtype(dtype)), ndim, "C")


def real_types(dtype):
    """``(T, nb)``: the NumPy scalar type of ``dtype`` (for a kernel's constants) and its Numba type (for its local
    arrays)."""
    return np.dtype(dtype).type, from_dtype(np.dtype(dtype))


def scalar(dtype):
    """The Numba type of a scalar of ``dtype``."""
    return from_dtype(np.dtype(dtype))


class DeviceKernel:
    """A CUDA kernel: ``fn`` (a Python function written for ``numba.cuda``) with its argument ``types``.

    ``kernel(threads, *args)`` launches it over ``threads`` threads (at least; ``fn`` returns early for the
    threads past its range) in blocks of :data:`BLOCK`.
    """

    def __init__(self, name, fn, argument_types):
        self.name, self.fn, self.types = name, fn, tuple(argument_types)
        self._kernel = None

    def __repr__(self):
        return f"DeviceKernel({self.name})"

    def compiled(self):
        """The numba-cuda dispatcher, compiled for :attr:`types` on first use."""
        if self._kernel is None:
            self._kernel = load().jit(types.void(*self.types))(self.fn)
        return self._kernel

    def __call__(self, threads, *args):
        if threads <= 0:
            return
        if SIMULATED:
            self.check(args)
        self.compiled()[(threads + BLOCK - 1) // BLOCK, BLOCK](*args)

    def check(self, args):
        """:class:`TypeError` naming the first argument whose dtype or dimensions differ from the declared type (the
        simulator's check; a GPU refuses such a launch by itself)."""
        if len(args) != len(self.types):
            raise TypeError(f"{self.name}: {len(args)} arguments given, {len(self.types)} declared")
        for k, (arg, declared) in enumerate(zip(args, self.types)):
            if isinstance(declared, types.Array):
                got = (np.dtype(getattr(arg, "dtype", None) or type(arg)), getattr(arg, "ndim", 0))
                want = (np.dtype(declared.dtype.name), declared.ndim)
            else:
                got = (np.dtype(type(arg)) if not hasattr(arg, "dtype") else arg.dtype, 0)
                want = (np.dtype(declared.name), 0)
                if got[0].kind == want[0].kind:  # Python floats and ints are the declared kind's widest type
                    continue
            if got != want:
                raise TypeError(f"{self.name}: argument {k} is {got}, declared {want}")

    def ptx(self, cc=(9, 0)):
        """PTX of the kernel for compute capability ``cc`` (``numba.cuda.compile_ptx``; no GPU needed)."""
        with target_capability(cc):
            ptx, _ = load().compile_ptx(self.fn, self.types, cc=cc)
        return ptx


@contextmanager
def target_capability(cc):
    """Device functions compiled for compute capability ``cc`` inside the block. numba-cuda compiles a device function
    a kernel calls for the current device's capability, which it asks the driver for; ``compile_ptx`` names the
    kernel's own capability but not its device functions', so without a GPU (or for another GPU than this one) the
    question is answered with ``cc`` here."""
    from numba.cuda import dispatcher

    asked = dispatcher.get_current_device
    dispatcher.get_current_device = lambda: SimpleNamespace(compute_capability=tuple(cc))
    try:
        yield
    finally:
        dispatcher.get_current_device = asked


def kernel_set(**made):
    """A namespace of :class:`DeviceKernel` from ``name=(function, argument types)``."""
    return SimpleNamespace(**{name: DeviceKernel(name, fn, argument_types)
                              for name, (fn, argument_types) in made.items()})

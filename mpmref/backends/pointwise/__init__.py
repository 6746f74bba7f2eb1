r"""The pointwise physics of the compiled backends, written once: what one particle or one node needs.

The Numba backend (CPU) and the GPU backend (numba-cuda) run the same equations as the NumPy reference, one particle
or one node at a time. What a particle or a node computes by itself, apart from the loops and the memory layout of
each backend, is written here once, as plain functions of scalars and small arrays:

* :mod:`.svd`: the signed SVD and the polar decomposition of one matrix (closed form in 2D, Jacobi and Givens in 3D;
  the method of :mod:`mpmref.physics.svd`);
* :mod:`.laws`: every material's Kirchhoff stress, return map and wave speed, each material's law named by the
  material's own declaration (:class:`mpmref.physics.materials.CompiledLaw`, next to its reference class);
* :mod:`.stencil`: the B-spline weights and slopes of one axis and PolyPIC's orthogonal polynomials of one axis;
* :mod:`.boundary`: talk Eq. 25 at a wall, with Coulomb friction, and the level-set colliders.

Each function is declared with :func:`pointwise`, which compiles it for the CPU with Numba (``njit``, cached; what the
Numba kernels call) and keeps its source for the device: :func:`on_device` compiles the same source with the GPU
backend's decorator, every pointwise function it calls replaced by that function's device version. So one source
runs on both targets, and in numba-cuda's simulator, which runs the device version as Python.

Written for both targets: ``math`` functions (``math.sqrt``, ``math.floor``, ``math.hypot``; not NumPy's), no
allocation (the caller passes work arrays: Numba kernels allocate them once per chunk of particles, CUDA threads in
local memory), and every constant of the run's real type, ``real(0.5)``, with ``real`` the type of an array
argument (``tau.dtype.type``) or an argument of its own: a float literal is float64 and would promote a float32 run's
arithmetic to float64.
"""

import hashlib
import types
from pathlib import Path

from numba import njit
from numba.core.dispatcher import Dispatcher


def pointwise(function=None, *, inline=False):
    """``function`` compiled for the CPU by Numba (``njit``, cached on disk; inlined into its callers before typing
    with ``inline=True``, for the small functions of the transfers' inner loops), its source kept for the device
    (:func:`on_device`). Use as ``@pointwise`` or ``@pointwise(inline=True)``."""

    def declare(source):
        compiled = njit(cache=True, inline="always" if inline else "never")(source)
        compiled.pointwise = True
        return compiled

    return declare if function is None else declare(function)


def is_pointwise(value):
    """Whether ``value`` is a function declared with :func:`pointwise`."""
    return isinstance(value, Dispatcher) and getattr(value, "pointwise", False)


_ON_DEVICE = {}


def on_device(function, device_function):
    """The device version of the pointwise ``function``: its source compiled by ``device_function`` (the GPU backend's
    decorator of device functions), reading the pointwise functions it calls as their own device versions. Made once
    per pair and compiled when a kernel first calls it."""
    key = (function, device_function)
    if key not in _ON_DEVICE:
        source = function.py_func
        names = dict(source.__globals__)
        copy = types.FunctionType(source.__code__, names, source.__name__, source.__defaults__, source.__closure__)
        _ON_DEVICE[key] = device_function(copy)  # before its callees, so that a cycle of names ends here
        for name, value in source.__globals__.items():
            if is_pointwise(value):
                names[name] = on_device(value, device_function)
    return _ON_DEVICE[key]


def source_digest(*paths):
    """SHA-256 of the Python files under ``paths`` (folders or files), in a fixed order: a compiled kernel's closure
    constant, so that Numba's disk cache, which checks only the kernel's own file, recompiles it when a function it
    calls changes (:mod:`mpmref.backends.numba.source_digest`)."""
    h = hashlib.sha256()
    for path in paths:
        path = Path(path)
        for file in sorted(path.rglob("*.py")) if path.is_dir() else [path]:
            h.update(file.read_bytes())
    return h.hexdigest()

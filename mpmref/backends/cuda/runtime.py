"""numba-cuda for the GPU backend: importing it, and saying in one line what is missing when it cannot run.

The backend needs the package ``numba-cuda`` (the extra ``[gpu]``: ``pip install -e '.[gpu]'``, which also brings
CUDA 13's compiler libraries) and a CUDA GPU with its driver. Without a GPU, numba-cuda's simulator
(``NUMBA_ENABLE_CUDASIM=1`` in the environment before Numba is imported) runs the same kernels as Python threads:
the test suite runs the stages that way on tiny cases, and compiles every kernel for a given compute capability
with ``numba.cuda.compile_ptx`` (:meth:`mpmref.backends.cuda.launch.DeviceKernel.ptx`), which needs the compiler
libraries but no GPU.
"""

import numpy as np

from ...errors import BackendError

#: the install command that brings what the backend needs
INSTALL = "pip install -e '.[gpu]'"


if not hasattr(np, "row_stack"):
    # numba-cuda 0.30 registers np.row_stack, which NumPy 2.5 removed (it was an alias of np.vstack): the alias is
    # restored before numba-cuda is imported, so that it imports on every NumPy the project supports
    np.row_stack = np.vstack

# The kernels refer to ``cuda`` as a global of their module (``from .runtime import cuda``): the simulator swaps a
# kernel's global ``cuda`` for its own while it runs it (closure variables it does not swap). Where Numba has no
# CUDA target at all, ``cuda`` is None and making the backend says what to install (:func:`load`).
try:
    from numba import cuda
except ImportError:  # pragma: no cover - a Numba without any CUDA target
    cuda = None


def load():
    """The module ``numba.cuda`` of the package numba-cuda (its simulator where ``NUMBA_ENABLE_CUDASIM=1``);
    :class:`~mpmref.errors.BackendError` naming what is missing otherwise (Numba's own deprecated CUDA target,
    which Numba still ships, is not used)."""
    if cuda is None or getattr(cuda, "implementation", "") == "Built-in":
        raise BackendError(f"backend 'cuda' needs the package numba-cuda, which is not installed: {INSTALL}")
    return cuda


def simulated():
    """Whether numba-cuda's simulator stands in for a GPU (``NUMBA_ENABLE_CUDASIM=1``)."""
    from numba.core import config

    return bool(config.ENABLE_CUDASIM)


def require_device():
    """``numba.cuda``, checked to have a usable GPU (or the simulator); :class:`~mpmref.errors.BackendError` in one
    line naming what is missing otherwise: numba-cuda, or a CUDA GPU with its driver."""
    cuda = load()
    if simulated() or cuda.is_available():
        return cuda
    reason = " ".join(str(cuda.cuda_error()).split()) or "no CUDA device found"
    raise BackendError(f"backend 'cuda' needs a CUDA GPU, and none is usable here ({reason.rstrip('.:')}); "
                       "run on a machine with an NVIDIA GPU and its driver, or choose --backend numba")


def device_name():
    """The GPU's name, for reports (``"simulator"`` under the simulator)."""
    cuda = load()
    if simulated():
        return "simulator"
    name = cuda.get_current_device().name
    return name.decode() if isinstance(name, bytes) else str(name)

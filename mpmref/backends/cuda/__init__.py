"""The GPU backend, ``--backend cuda``: the stages as numba-cuda kernels, the particles resident on the GPU.

Modules: :mod:`.runtime` (importing numba-cuda; what is missing), :mod:`.launch` (kernels with declared argument
types), the device versions of the pointwise physics
(:mod:`mpmref.backends.pointwise`: stencils, SVD, material laws, walls), :mod:`.materials` (each material's law
dispatched on the device), :mod:`.sort` (the deterministic
counting sort by cell), :mod:`.p2g`, :mod:`.grid_update`, :mod:`.g2p` and :mod:`.particles` (the kernels),
:mod:`.kernels` (a scene's configuration and its kernels) and :mod:`.backend` (the backend object). Importing this
package needs Numba only; making the backend needs numba-cuda and a GPU (or numba-cuda's simulator). docs/gpu.md.
"""

from .backend import P2G_MODES, CudaBackend


def atomic(scene):
    """The GPU backend with the opt-in atomic P2G (reproducible only to round-off; docs/gpu.md), as a factory:
    ``--backend mpmref.backends.cuda:atomic``."""
    return CudaBackend(scene, p2g="atomic")


atomic.implements = CudaBackend.implements

__all__ = ["P2G_MODES", "CudaBackend", "atomic"]

r"""The grid update of the GPU backend, one node per thread (:func:`mpmref.backends.numpy.transfers.grid_update`):
the node's velocity, then talk Eq. 25 at each wall whose band holds it, the lower wall of each axis first, and at each
level-set collider it lies in at the step's time, in the scene's order: the pointwise functions of
:mod:`mpmref.backends.pointwise.grid`, which the Numba backend runs too. Nodes without mass get zero velocity.
"""

from functools import lru_cache

import numpy as np
from numba import types

from ..pointwise.grid import collide, node_velocity, project_in_bands
from .launch import array, device, kernel_set, scalar
from .runtime import cuda, load


@lru_cache(maxsize=None)
def grid_update_kernel(dtype, dim, colliders):
    """The grid update of nodes of ``dtype`` in ``dim`` dimensions, with ``colliders`` or without: a namespace with the
    :class:`~.launch.DeviceKernel` ``grid_update`` (after a fused P2G, ``force`` has no rows and ``v_tilde`` is not
    written)."""
    load()
    D = dim
    velocity, walls, collider_pass = device(node_velocity), device(project_in_bands), device(collide)

    def grid_update(mass, momentum, force, node_shape, dt, time, gravity, wall_type, wall_friction, wall_width,
                    table, n_colliders, origin, dx, v, v_tilde):
        """Node ``i``'s velocity after the forces, gravity, walls and colliders (the module doc)."""
        i = cuda.grid(1)
        if i >= mass.shape[0] or not velocity(i, mass, momentum, force, dt, gravity, v, v_tilde):
            return
        rest = i
        index = cuda.local.array(3, types.int64)
        for a in range(D - 1, -1, -1):
            index[a] = rest % node_shape[a]
            rest //= node_shape[a]
        for a in range(D):
            walls(v, i, a, index[a], node_shape[a], wall_width, wall_type, wall_friction)
        if colliders:
            node = cuda.local.array(3, types.float64)
            work = cuda.local.array((3, 3), types.float64)
            for a in range(D):
                node[a] = float(origin[a]) + float(index[a]) * dx
            collider_pass(v, i, node, table, n_colliders, time, work)

    real1, real2, f64 = array(dtype, 1), array(dtype, 2), scalar(np.float64)
    return kernel_set(grid_update=(grid_update, (real1, real2, real2, array(np.int64, 1), f64, f64, real1,
                                                 array(np.int64, 1), real1, scalar(np.int64), array(np.float64, 2),
                                                 scalar(np.int64), array(np.float64, 1), f64, real2, real2)))

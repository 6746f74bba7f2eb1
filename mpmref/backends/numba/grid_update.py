r"""The grid update of the Numba backend (:func:`mpmref.backends.numpy.transfers.grid_update`): node velocities
from mass, momentum and force, gravity, the talk's Eq. 25 walls and the level-set colliders, on the dense grid or
the rows of the sparse grid's active blocks (:mod:`.sparse`). Written once for 2D and 3D: the per-node loops run over
the columns of the node arrays, and a node's index along each axis comes from its row. What a node computes is
pointwise (:mod:`mpmref.backends.pointwise.grid`).
"""

import numpy as np
from numba import prange

from ..pointwise.grid import collide, node_velocity, project_in_bands
from .twin import parallel_kernel

#: nodes per task of the colliders' parallel loop
NODE_CHUNK = 256


@parallel_kernel(cache=True)
def grid_velocity(mass, momentum, force, dt, gravity, node_shape, strides, wall_width, wall_type, wall_friction,
                  v, v_tilde):
    r"""Grid update with Eq. 25 walls on the dense grid (node ``i`` at C-order index ``i``); see
    :func:`~mpmref.backends.pointwise.grid.node_velocity` for the equations."""
    for i in prange(mass.shape[0]):
        if node_velocity(i, mass, momentum, force, dt, gravity, v, v_tilde):
            for a in range(momentum.shape[1]):
                project_in_bands(v, i, a, (i // strides[a]) % node_shape[a], node_shape[a], wall_width, wall_type,
                                 wall_friction)


@parallel_kernel(cache=True)
def block_grid_velocity(mass, momentum, force, dt, gravity, node_shape, block, blocks, wall_width, wall_type,
                        wall_friction, v, v_tilde):
    r"""Grid update with Eq. 25 walls on the sparse grid (row ``r`` of the active blocks ``blocks`` of a
    :class:`~.sparse.BlockLayout`); the same per-node arithmetic as :func:`grid_velocity`."""
    d = momentum.shape[1]
    block_nodes = block**d
    for r in prange(mass.shape[0]):
        if node_velocity(r, mass, momentum, force, dt, gravity, v, v_tilde):
            slot, local = r // block_nodes, r % block_nodes
            for a in range(d):
                index = blocks[slot, a] * block + (local // block ** (d - 1 - a)) % block
                project_in_bands(v, r, a, index, node_shape[a], wall_width, wall_type, wall_friction)


@parallel_kernel(cache=True)
def collider_velocity(mass, node_x, table, n_colliders, time, v):
    r"""Every collider of the float64 ``table`` (:func:`~mpmref.backends.pointwise.grid.collider_table`) at each
    node with mass, at its position ``node_x`` (float64) and time ``time``, in place on ``v``
    (:func:`~mpmref.backends.pointwise.grid.collide`), after the walls, as the reference applies them."""
    n = mass.shape[0]
    for chunk in prange((n + NODE_CHUNK - 1) // NODE_CHUNK):
        work = np.empty((3, 3))  # one per chunk of nodes
        for i in range(chunk * NODE_CHUNK, min(n, (chunk + 1) * NODE_CHUNK)):
            if mass[i] > 0:
                collide(v, i, node_x[i], table, n_colliders, time, work)

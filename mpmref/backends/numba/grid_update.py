r"""The grid update of the Numba backend (:func:`mpmref.backends.numpy.transfers.grid_update`): node velocities
from mass, momentum and force, gravity, and the talk's Eq. 25 walls, on the dense grid or the rows of the sparse
grid's active blocks (:mod:`.sparse`). Written once for 2D and 3D: the per-node loops run over the columns of
the node arrays, and a node's index along each axis comes from its row.
"""

import numpy as np
from numba import njit, prange


@njit(parallel=True, cache=True)
def grid_velocity(mass, momentum, force, dt, gravity, node_shape, strides, wall_width, wall_type, wall_friction,
                  v, v_tilde):
    r"""Grid update with Eq. 25 walls on the dense grid (node ``i`` at C-order index ``i``); see
    :func:`node_velocity` for the equations."""
    for i in prange(mass.shape[0]):
        if node_velocity(i, mass, momentum, force, dt, gravity, v, v_tilde):
            for a in range(momentum.shape[1]):
                project_in_bands(v, i, a, (i // strides[a]) % node_shape[a], node_shape[a], wall_width, wall_type,
                                 wall_friction)


@njit(parallel=True, cache=True)
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


@njit(cache=True, inline="always")
def node_velocity(i, mass, momentum, force, dt, gravity, v, v_tilde):
    r"""Velocity of node ``i`` before the walls (see :func:`mpmref.backends.numpy.transfers.grid_update`):

    .. math:: \tilde v_i = (mv)_i / m_i, \qquad v_i = \tilde v_i + \Delta t\,(f_i / m_i + g)

    or, with ``force`` empty (a fused P2G's momentum :math:`(mv)_i + \Delta t f_i`), :math:`v_i = ((mv)_i +
    \Delta t f_i)/m_i + \Delta t g` and no :math:`\tilde v_i`. Nodes without mass get zero velocity; returns
    whether the node has mass.
    """
    d = momentum.shape[1]
    folded = force.shape[0] == 0  # a fused P2G's momentum already holds dt f: no v_tilde
    if mass[i] <= 0:
        for a in range(d):
            v[i, a] = 0.0
            if not folded:
                v_tilde[i, a] = 0.0
        return False
    inv_m = 1.0 / mass[i]
    for a in range(d):
        if folded:
            v[i, a] = momentum[i, a] * inv_m + dt * gravity[a]
        else:
            v_tilde[i, a] = momentum[i, a] * inv_m
            v[i, a] = (momentum[i, a] + dt * force[i, a]) * inv_m + dt * gravity[a]
    return True


@njit(cache=True, inline="always")
def project_in_bands(v, i, axis, index, n_axis, wall_width, wall_type, wall_friction):
    """The walls of ``axis`` at node ``i``, whose node index along it is ``index`` (of ``n_axis``): the talk's
    Eq. 25 projection with the wall's inward normal where the node lies within ``wall_width`` cells of it, the
    lower wall first (the reference's order; a corner node is projected by each of its walls in turn).
    ``wall_type[2a + side]``: 0 open, 1 sticky, 2 slip, 3 separate; ``wall_friction`` the Coulomb μ."""
    if index < wall_width:
        project_at_wall(v, i, axis, 1.0, wall_type[2 * axis], wall_friction[2 * axis])
    if index > n_axis - 1 - wall_width:
        project_at_wall(v, i, axis, -1.0, wall_type[2 * axis + 1], wall_friction[2 * axis + 1])


@njit(cache=True)
def project_at_wall(v, i, axis, sign, kind, friction):
    r"""Talk Eq. 25 at an axis-aligned wall with inward normal ``sign * e_axis`` (see
    :func:`mpmref.physics.boundary.project_velocity`)."""
    d = v.shape[1]
    if kind == 0:
        return
    if kind == 1:
        for a in range(d):
            v[i, a] = 0.0
        return
    vn = v[i, axis] * sign
    if kind == 2:
        v[i, axis] -= vn * sign
        return
    if vn >= 0.0:
        return
    vt_norm2 = 0.0
    for a in range(d):
        if a != axis:
            vt_norm2 += v[i, a] ** 2
    vt_norm = np.sqrt(vt_norm2)
    if vt_norm <= -friction * vn:
        for a in range(d):
            v[i, a] = 0.0
        return
    scale = 1.0 + friction * vn / vt_norm
    v[i, axis] = 0.0
    for a in range(d):
        if a != axis:
            v[i, a] *= scale

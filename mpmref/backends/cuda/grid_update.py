r"""The grid update of the GPU backend, one node per thread (:func:`mpmref.backends.numpy.transfers.grid_update`).

.. math:: \tilde v_i = (mv)_i / m_i, \qquad v_i = \tilde v_i + \Delta t\,(f_i / m_i + g)

(or, after a fused P2G, :math:`v_i = ((mv)_i + \Delta t f_i)/m_i + \Delta t\,g` and no :math:`\tilde v_i`), then
talk Eq. 25 (:func:`mpmref.physics.boundary.project_velocity`) at each wall whose band holds the node, the lower
wall of each axis first, and at each level-set collider (:mod:`mpmref.physics.colliders`) the node lies in at the
step's time, in the scene's order. Nodes without mass get zero velocity. Colliders are rows of a float64 table
(:func:`collider_table`), evaluated in float64 as the reference does (its node positions are float64).
"""

import math
from functools import lru_cache

import numpy as np
from numba import types

from ...physics.colliders import Ball, Box, Cylinder, Plane
from ..base import WALL_CODES
from .launch import array, device_function, kernel_set, scalar
from .runtime import cuda, load

#: collider shapes as the kernels code them
SHAPE_CODES = {Plane: 0, Ball: 1, Box: 2, Cylinder: 3}
#: a collider's row: shape, type, friction, velocity (3), then its shape's numbers (up to 7)
COLLIDER_WIDTH = 13


def collider_table(colliders):
    """The float64 rows (k, :data:`COLLIDER_WIDTH`) of a scene's colliders: shape code, type code, friction, velocity
    padded to 3, then a plane's point and unit normal, a ball's centre and radius, a box's lower and upper corners,
    or a cylinder's point, unit axis and radius (each vector padded to 3)."""
    table = np.zeros((max(len(colliders), 1), COLLIDER_WIDTH))
    for k, c in enumerate(colliders):
        numbers = shape_numbers(c.shape)
        table[k, :6] = [SHAPE_CODES[type(c.shape)], WALL_CODES[c.type], c.friction] + padded(c.velocity)
        table[k, 6:6 + len(numbers)] = numbers
    return table


def padded(vector):
    """A 2- or 3-vector as a list of 3 floats (zero last)."""
    values = [float(v) for v in vector]
    return values + [0.0] * (3 - len(values))


def shape_numbers(shape):
    """The numbers of a collider's shape in its row (see :func:`collider_table`)."""
    if isinstance(shape, Plane):
        return padded(shape.point) + padded(shape.normal / np.linalg.norm(shape.normal))
    if isinstance(shape, Ball):
        return padded(shape.center) + [float(shape.radius)]
    if isinstance(shape, Box):
        return padded(shape.lower) + padded(shape.upper)
    return padded(shape.point) + padded(shape.axis / np.linalg.norm(shape.axis)) + [float(shape.radius)]


@lru_cache(maxsize=None)
def grid_update_kernel(dtype, dim, folded, colliders):
    """The grid update of nodes of ``dtype`` in ``dim`` dimensions, after a fused P2G (``folded``) or not, with
    ``colliders`` or without: a namespace with the :class:`~.launch.DeviceKernel` ``grid_update``."""
    load()
    T = np.dtype(dtype).type
    D = dim
    one, zero = T(1.0), T(0.0)

    @device_function
    def project_at_wall(v, i, axis, sign, kind, friction):
        r"""Talk Eq. 25 at an axis-aligned wall with inward normal ``sign`` :math:`e_{axis}`: sticky zeroes,
        slip removes the normal part, separate (only when approaching, :math:`v_n < 0`) sticks where
        :math:`|v_t| \le -\mu v_n`, else scales :math:`v_t` by :math:`1 + \mu v_n/|v_t|`."""
        if kind == 1:
            for a in range(D):
                v[i, a] = zero
            return
        vn = v[i, axis] * sign
        if kind == 2:
            v[i, axis] -= vn * sign
            return
        if kind != 3 or vn >= zero:
            return
        vt2 = zero
        for a in range(D):
            if a != axis:
                vt2 += v[i, a] * v[i, a]
        vt = math.sqrt(vt2)
        if vt <= -friction * vn:
            for a in range(D):
                v[i, a] = zero
            return
        scale = one + friction * vn / vt
        v[i, axis] = zero
        for a in range(D):
            if a != axis:
                v[i, a] *= scale

    @device_function
    def signed_distance(row, x, normal):
        r""":math:`\phi(x)` of collider ``row`` at ``x`` (float64, moved back by the collider's motion) and its
        gradient into ``normal`` (:mod:`mpmref.physics.colliders`: plane, ball, box, cylinder)."""
        shape = int(row[0])
        if shape == 0:
            phi = 0.0
            for a in range(D):
                phi += (x[a] - row[6 + a]) * row[9 + a]
                normal[a] = row[9 + a]
            return phi
        if shape == 2:
            return box_distance(row, x, normal)
        r2 = 0.0
        along = 0.0
        if shape == 3:
            for a in range(D):
                along += (x[a] - row[6 + a]) * row[9 + a]
        for a in range(D):
            normal[a] = (x[a] - row[6 + a]) - (along * row[9 + a] if shape == 3 else 0.0)
            r2 += normal[a] * normal[a]
        r = math.sqrt(r2)
        for a in range(D):
            normal[a] = normal[a] / r if r > 0.0 else 0.0
        return r - row[9 if shape == 1 else 12]

    @device_function
    def box_distance(row, x, normal):
        r"""The exact distance of an axis-aligned box, :math:`|\max(q, 0)| + \min(\max_a q_a, 0)`,
        :math:`q = |x - c| - h`, and its gradient (the nearest face's normal inside)."""
        out2 = 0.0
        largest = -math.inf
        face = 0
        for a in range(D):
            c = 0.5 * (row[6 + a] + row[9 + a])
            q = abs(x[a] - c) - 0.5 * (row[9 + a] - row[6 + a])
            sign = 1.0 if x[a] > c else (-1.0 if x[a] < c else 0.0)
            normal[a] = max(q, 0.0) * sign
            out2 += max(q, 0.0) * max(q, 0.0)
            if q > largest:
                largest, face = q, a
        outside = math.sqrt(out2)
        for a in range(D):
            if outside > 0.0:
                normal[a] = normal[a] / outside
            else:
                c = 0.5 * (row[6 + a] + row[9 + a])
                normal[a] = (1.0 if a == face else 0.0) * (1.0 if x[a] > c else (-1.0 if x[a] < c else 0.0))
        return outside + min(largest, 0.0)

    @device_function
    def project_at_collider(v, i, row, normal):
        r"""Talk Eq. 25 with the collider's normal, type, friction and velocity :math:`v_{co}` on the relative
        velocity :math:`v - v_{co}` (:func:`mpmref.physics.boundary.project_velocity`), in float64."""
        kind = int(row[1])
        rel = cuda.local.array(3, types.float64)
        vn = 0.0
        for a in range(D):
            rel[a] = float(v[i, a]) - row[3 + a]
            vn += rel[a] * normal[a]
        vt2 = 0.0
        for a in range(D):
            rel[a] = 0.0 if kind == 1 else rel[a]
            tangent = rel[a] - vn * normal[a]
            vt2 += tangent * tangent
        vt = math.sqrt(vt2)
        for a in range(D):
            tangent = rel[a] - vn * normal[a]
            if kind == 2:
                rel[a] = tangent
            elif kind == 3 and vn < 0.0:
                rel[a] = 0.0 if vt <= -row[2] * vn else tangent * (1.0 + row[2] * vn / vt)
            v[i, a] = T(rel[a] + row[3 + a])

    def grid_update(mass, momentum, force, node_shape, dt, time, gravity, wall_type, wall_friction, wall_width,
                    table, n_colliders, origin, dx, v, v_tilde):
        """Node ``i``'s velocity after the forces, gravity, walls and colliders (the module doc)."""
        i = cuda.grid(1)
        if i >= mass.shape[0]:
            return
        h = T(dt)
        m = mass[i]
        if m <= zero:
            for a in range(D):
                v[i, a] = zero
                if not folded:
                    v_tilde[i, a] = zero
            return
        inv_m = one / m
        for a in range(D):
            p_a = momentum[i, a]
            if not folded:  # v~ = (mv)/m before the force; v from (mv) + dt f
                v_tilde[i, a] = p_a * inv_m
                p_a = p_a + h * force[i, a]
            v[i, a] = p_a * inv_m + h * gravity[a]
        rest = i
        index = cuda.local.array(3, types.int64)
        for a in range(D - 1, -1, -1):
            index[a] = rest % node_shape[a]
            rest //= node_shape[a]
        for a in range(D):
            if index[a] < wall_width:
                project_at_wall(v, i, a, one, wall_type[2 * a], wall_friction[2 * a])
            if index[a] > node_shape[a] - 1 - wall_width:
                project_at_wall(v, i, a, -one, wall_type[2 * a + 1], wall_friction[2 * a + 1])
        if colliders:
            x = cuda.local.array(3, types.float64)
            normal = cuda.local.array(3, types.float64)
            for c in range(n_colliders):
                row = table[c]
                for a in range(D):
                    x[a] = float(origin[a]) + float(index[a]) * dx - row[3 + a] * time
                if signed_distance(row, x, normal) <= 0.0:
                    project_at_collider(v, i, row, normal)

    real1, real2, f64 = array(dtype, 1), array(dtype, 2), scalar(np.float64)
    return kernel_set(grid_update=(grid_update, (real1, real2, real2, array(np.int64, 1), f64, f64, real1,
                                                 array(np.int64, 1), real1, scalar(np.int64), array(np.float64, 2),
                                                 scalar(np.int64), array(np.float64, 1), f64, real2, real2)))

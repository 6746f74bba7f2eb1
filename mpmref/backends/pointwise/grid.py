r"""The grid update at one node, for both compiled backends (:func:`mpmref.backends.numpy.transfers.grid_update`):
its velocity from mass, momentum, force and gravity, then talk Eq. 25 at the domain's walls, with Coulomb friction,
and at the level-set colliders (:mod:`mpmref.physics.boundary`, :mod:`mpmref.physics.colliders` for the equations
and sources).

For a boundary with unit normal :math:`n` pointing into the material and velocity :math:`v_{co}`, the relative
velocity :math:`v - v_{co}` has the normal part :math:`v_n` and the tangential part :math:`v_t`: ``sticky`` sets it to
0, ``slip`` keeps :math:`v_t`, ``separate`` (only while approaching, :math:`v_n < 0`) sticks where
:math:`\|v_t\| \le -\mu v_n` and otherwise scales :math:`v_t` by :math:`1 + \mu v_n/\|v_t\|`. The velocity and the
walls compute in the dtype of the node velocities; colliders in float64, as the reference does (its node positions are
float64), from a float64 table of their shapes (:func:`collider_table`).
"""

import math

import numpy as np

from ...physics.colliders import Ball, Box, Cylinder, Plane
from ..base import WALL_CODES
from . import pointwise

#: collider shapes as the kernels code them
SHAPE_CODES = {Plane: 0, Ball: 1, Box: 2, Cylinder: 3}
#: a collider's row: shape, type, friction, velocity (3), then its shape's numbers (up to 7)
COLLIDER_WIDTH = 13


# ------------------------------------------------------------------------------------------- node velocity
@pointwise(inline=True)
def node_velocity(i, mass, momentum, force, dt, gravity, v, v_tilde):
    r"""Velocity of node ``i`` before the walls, in the dtype of ``v``:

    .. math:: \tilde v_i = (mv)_i / m_i, \qquad v_i = \tilde v_i + \Delta t\,(f_i / m_i + g)

    or, with ``force`` empty (a fused P2G's momentum :math:`(mv)_i + \Delta t f_i`), :math:`v_i = ((mv)_i +
    \Delta t f_i)/m_i + \Delta t g` and no :math:`\tilde v_i`. Nodes without mass get zero velocity; returns whether
    the node has mass.
    """
    real = v.dtype.type
    d = momentum.shape[1]
    h = real(dt)
    folded = force.shape[0] == 0  # a fused P2G's momentum already holds dt f: no v_tilde
    if mass[i] <= real(0.0):
        for a in range(d):
            v[i, a] = real(0.0)
            if not folded:
                v_tilde[i, a] = real(0.0)
        return False
    inv_m = real(1.0) / mass[i]
    for a in range(d):
        if folded:
            v[i, a] = momentum[i, a] * inv_m + h * gravity[a]
        else:
            v_tilde[i, a] = momentum[i, a] * inv_m
            v[i, a] = (momentum[i, a] + h * force[i, a]) * inv_m + h * gravity[a]
    return True


# ----------------------------------------------------------------------------------------------------- walls
@pointwise
def project_at_wall(v, i, axis, sign, kind, friction):
    r"""Talk Eq. 25 at an axis-aligned wall with inward normal ``sign`` :math:`e_{axis}`, on node ``i`` of ``v``
    (``kind``: 0 open, 1 sticky, 2 slip, 3 separate, :data:`mpmref.backends.base.WALL_CODES`)."""
    real = v.dtype.type
    d = v.shape[1]
    if kind == 0:
        return
    if kind == 1:
        for a in range(d):
            v[i, a] = real(0.0)
        return
    vn = v[i, axis] * sign
    if kind == 2:
        v[i, axis] -= vn * sign
        return
    if vn >= real(0.0):
        return
    vt_norm2 = real(0.0)
    for a in range(d):
        if a != axis:
            vt_norm2 += v[i, a] * v[i, a]
    vt_norm = math.sqrt(vt_norm2)
    if vt_norm <= -friction * vn:
        for a in range(d):
            v[i, a] = real(0.0)
        return
    scale = real(1.0) + friction * vn / vt_norm
    v[i, axis] = real(0.0)
    for a in range(d):
        if a != axis:
            v[i, a] *= scale


@pointwise(inline=True)
def project_in_bands(v, i, axis, index, n_axis, wall_width, wall_type, wall_friction):
    """The walls of ``axis`` at node ``i``, whose node index along it is ``index`` (of ``n_axis``): Eq. 25 with the
    wall's inward normal where the node lies within ``wall_width`` cells of it, the lower wall first (the reference's
    order; a corner node is projected by each of its walls in turn). ``wall_type[2a + side]`` the wall's code,
    ``wall_friction[2a + side]`` its Coulomb :math:`\\mu` (in the dtype of ``v``)."""
    real = v.dtype.type
    if index < wall_width:
        project_at_wall(v, i, axis, real(1.0), wall_type[2 * axis], wall_friction[2 * axis])
    if index > n_axis - 1 - wall_width:
        project_at_wall(v, i, axis, -real(1.0), wall_type[2 * axis + 1], wall_friction[2 * axis + 1])


# ------------------------------------------------------------------------------------------------- colliders
def collider_table(colliders):
    """The float64 rows (k, :data:`COLLIDER_WIDTH`) of a scene's colliders: shape code, type code, friction, velocity
    padded to 3, then a plane's point and unit normal, a ball's centre and radius, a box's lower and upper corners, or
    a cylinder's point, unit axis and radius (each vector padded to 3); one row of zeros without colliders."""
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


@pointwise
def signed_distance(row, x, normal, d):
    r""":math:`\phi(x)` of the collider ``row`` at the ``d``-vector ``x`` and its gradient into ``normal``: plane
    :math:`(x - p)\cdot n`, ball :math:`|x - c| - r`, box (:func:`box_distance`), cylinder
    :math:`|(x - p) - ((x - p)\cdot a)a| - r` (:mod:`mpmref.physics.colliders`)."""
    shape = int(row[0])
    if shape == 0:
        phi = 0.0
        for a in range(d):
            phi += (x[a] - row[6 + a]) * row[9 + a]
            normal[a] = row[9 + a]
        return phi
    if shape == 2:
        return box_distance(row, x, normal, d)
    along = 0.0
    if shape == 3:
        for a in range(d):
            along += (x[a] - row[6 + a]) * row[9 + a]
    r2 = 0.0
    for a in range(d):
        normal[a] = (x[a] - row[6 + a]) - (along * row[9 + a] if shape == 3 else 0.0)
        r2 += normal[a] * normal[a]
    r = math.sqrt(r2)
    for a in range(d):
        normal[a] = normal[a] / r if r > 0.0 else 0.0
    return r - row[9 if shape == 1 else 12]


@pointwise
def box_distance(row, x, normal, d):
    r"""The exact distance of an axis-aligned box, :math:`|\max(q, 0)| + \min(\max_a q_a, 0)`,
    :math:`q = |x - c| - h` (:math:`c` the centre, :math:`h` the half-size), and its gradient (inside: the nearest
    face's normal)."""
    out2 = 0.0
    largest = -math.inf
    face = 0
    for a in range(d):
        c = 0.5 * (row[6 + a] + row[9 + a])
        q = abs(x[a] - c) - 0.5 * (row[9 + a] - row[6 + a])
        sign = 1.0 if x[a] > c else (-1.0 if x[a] < c else 0.0)
        normal[a] = max(q, 0.0) * sign
        out2 += max(q, 0.0) * max(q, 0.0)
        if q > largest:
            largest, face = q, a
    outside = math.sqrt(out2)
    for a in range(d):
        if outside > 0.0:
            normal[a] = normal[a] / outside
        else:
            c = 0.5 * (row[6 + a] + row[9 + a])
            normal[a] = (1.0 if a == face else 0.0) * (1.0 if x[a] > c else (-1.0 if x[a] < c else 0.0))
    return outside + min(largest, 0.0)


@pointwise
def project_at_collider(v, i, row, normal, rel):
    r"""Talk Eq. 25 on node ``i`` of ``v`` with the collider's normal, type, friction and velocity :math:`v_{co}`,
    on the relative velocity :math:`v - v_{co}` (:func:`mpmref.physics.boundary.project_velocity`), in float64;
    ``rel`` a work vector."""
    real = v.dtype.type
    d = v.shape[1]
    kind = int(row[1])
    vn = 0.0
    for a in range(d):
        rel[a] = float(v[i, a]) - row[3 + a]
        vn += rel[a] * normal[a]
    vt2 = 0.0
    for a in range(d):
        rel[a] = 0.0 if kind == 1 else rel[a]
        tangent = rel[a] - vn * normal[a]
        vt2 += tangent * tangent
    vt = math.sqrt(vt2)
    for a in range(d):
        tangent = rel[a] - vn * normal[a]
        if kind == 2:
            rel[a] = tangent
        elif kind == 3 and vn < 0.0:
            rel[a] = 0.0 if vt <= -row[2] * vn else tangent * (1.0 + row[2] * vn / vt)
        v[i, a] = real(rel[a] + row[3 + a])


@pointwise
def collide(v, i, node, table, n_colliders, time, work):
    r"""Every collider at node ``i`` of ``v``, at position ``node`` (float64) and time ``time``, in the scene's order:
    where :math:`\phi(x_i - v_{co} t) \le 0`, Eq. 25 with its normal (:func:`signed_distance`,
    :func:`project_at_collider`). ``work``: a (3, 3) float64 work array."""
    d = v.shape[1]
    moved, normal, rel = work[0], work[1], work[2]
    for c in range(n_colliders):
        row = table[c]
        for a in range(d):
            moved[a] = node[a] - row[3 + a] * time
        if signed_distance(row, moved, normal, d) <= 0.0:
            project_at_collider(v, i, row, normal, rel)

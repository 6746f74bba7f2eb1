r"""Rigid-body motion for CPIC in 3D: orientation, scripts, impulses and integration of triangle-mesh bodies.

The 3D motion behind :mod:`mpmref.rigid.dynamics` (chosen once, when a
:class:`~mpmref.rigid.dynamics.RigidState` of :class:`~mpmref.rigid.trimesh.TriMesh` bodies is made);
its functions are the 3D :class:`~mpmref.rigid.dynamics.RigidMechanics` (the same names and arguments as
those of :mod:`mpmref.rigid.dynamics2d`). A body is declared at time 0 with a reference
point :math:`\mathbf c_0` (its centre of mass for a dynamic body, the declared ``center`` or the vertex
centroid otherwise). Its pose at a later time is a translation of the reference point to :math:`\mathbf c`
and a rotation :math:`R(\mathbf q)` about it, given by a unit quaternion :math:`\mathbf q = (w, x, y, z)`:

.. math:: \mathbf x = \mathbf c + R(\mathbf q)(\mathbf x^0 - \mathbf c_0), \qquad
          \mathbf v_r(\mathbf x) = \mathbf v + \boldsymbol\omega \times (\mathbf x - \mathbf c).

The state arrays are those of :class:`~mpmref.rigid.dynamics.RigidState` with 3D shapes: ``position``
and ``velocity`` (nb, 3), ``angle`` the orientation quaternion (nb, 4), ``angular_velocity`` and
``angular_impulse`` (nb, 3). A declared body keeps its inertia tensor :math:`\mathbf I_0` (3, 3) about
:math:`\mathbf c_0` in the reference pose; at orientation :math:`R` it is :math:`R \mathbf I_0 R^T`.

Motions (as in 2D): ``fixed``; ``scripted`` with a constant velocity and angular velocity vector or
piecewise-linear keyframes of offset and rotation vector (infinite mass and inertia; velocity over a step is
the finite difference of the script); ``dynamic`` with mass and inertia tensor from a density over the
enclosed volume (closed mesh) or the area (open, zero-thickness mesh), moved by the material's impulses and
gravity.

Source: Hu et al. 2018, SIGGRAPH, "A Moving Least Squares Material Point Method with Displacement
Discontinuity and Two-Way Rigid Body Coupling", §5 (two-way coupling: the rigid body receives the momentum
the material could not give to the grid); the quaternion exponential and the torque-free update with
conserved angular momentum are the standard rigid-body formulas of Goldstein, Poole & Safko, *Classical
Mechanics* (3rd ed.), §4.9 and §5.1.
"""

import numpy as np

from .trimesh import TriMesh


# ------------------------------------------------------------------------------------------ quaternions
def quaternion_multiply(p, q):
    r"""Hamilton product :math:`\mathbf p \otimes \mathbf q` of quaternions :math:`(w, x, y, z)`, (..., 4).

    .. math:: (p_w q_w - \mathbf p_v\cdot\mathbf q_v,\ p_w \mathbf q_v + q_w \mathbf p_v
              + \mathbf p_v \times \mathbf q_v)
    """
    pw, pv = p[..., :1], p[..., 1:]
    qw, qv = q[..., :1], q[..., 1:]
    w = pw * qw - np.sum(pv * qv, axis=-1, keepdims=True)
    return np.concatenate([w, pw * qv + qw * pv + np.cross(pv, qv)], axis=-1)


def quaternion_from_rotation_vector(phi):
    r"""The unit quaternion of the rotation by :math:`|\boldsymbol\phi|` about
    :math:`\boldsymbol\phi/|\boldsymbol\phi|`.

    .. math:: \mathbf q = \exp(\boldsymbol\phi/2) = \big(\cos\tfrac{|\boldsymbol\phi|}{2},\
              \tfrac{\sin(|\boldsymbol\phi|/2)}{|\boldsymbol\phi|}\,\boldsymbol\phi\big)

    (Goldstein §4.9); the ratio is evaluated as :math:`\tfrac12\operatorname{sinc}` so that it is exact at 0.
    ``phi`` is (..., 3); returns (..., 4).
    """
    phi = np.asarray(phi, dtype=np.float64)
    angle = np.linalg.norm(phi, axis=-1, keepdims=True)
    return np.concatenate([np.cos(0.5 * angle), 0.5 * np.sinc(angle / (2.0 * np.pi)) * phi], axis=-1)


def rotation_vector_from_quaternion(q):
    r"""The rotation vector :math:`\boldsymbol\phi` with :math:`\exp(\boldsymbol\phi/2) = \pm\mathbf q`,
    :math:`|\boldsymbol\phi| \le \pi`.

    .. math:: \boldsymbol\phi = 2 \operatorname{atan2}(|\mathbf q_v|, q_w)\, \mathbf q_v / |\mathbf q_v|,

    with :math:`\mathbf q` first turned to :math:`q_w \ge 0` (the shorter of the two equal rotations).
    """
    q = np.where(q[..., :1] < 0.0, -q, q)
    s = np.linalg.norm(q[..., 1:], axis=-1, keepdims=True)
    angle = 2.0 * np.arctan2(s, q[..., :1])
    return np.where(s > 0.0, angle / np.where(s > 0.0, s, 1.0), 2.0) * q[..., 1:]


def rotation_matrix(q):
    r"""The rotation matrix :math:`R(\mathbf q)` of a unit quaternion :math:`(w, x, y, z)`, (..., 3, 3).

    .. math:: R = (w^2 - \mathbf q_v\cdot\mathbf q_v)\mathbf 1 + 2\mathbf q_v\mathbf q_v^T + 2w[\mathbf q_v]_\times

    (Goldstein §4.9). It is orthonormal to round-off for a unit quaternion.
    """
    q = np.asarray(q, dtype=np.float64)
    w, v = q[..., 0, None, None], q[..., 1:]
    cross = np.zeros(q.shape[:-1] + (3, 3))
    cross[..., 0, 1], cross[..., 0, 2], cross[..., 1, 2] = -v[..., 2], v[..., 1], -v[..., 0]
    cross = cross - np.swapaxes(cross, -1, -2)
    eye = np.eye(3)
    return ((w[..., 0, 0] ** 2 - np.sum(v * v, axis=-1))[..., None, None] * eye
            + 2.0 * v[..., :, None] * v[..., None, :] + 2.0 * w * cross)


def rotate(q, dt_omega):
    r"""The orientation after turning by the rotation vector ``dt_omega`` (world frame):
    :math:`\exp(\Delta t\boldsymbol\omega/2)\otimes\mathbf q`.

    Exact for a constant angular velocity over the step; the result is renormalised so that it stays a
    unit quaternion (and :math:`R(\mathbf q)` orthonormal) to round-off over any number of steps.
    """
    out = quaternion_multiply(quaternion_from_rotation_vector(dt_omega), q)
    return out / np.linalg.norm(out, axis=-1, keepdims=True)


# ------------------------------------------------------------------------------------------ state
IDENTITY = np.array([1.0, 0.0, 0.0, 0.0])


def initial_arrays(bodies):
    """The :class:`~mpmref.rigid.dynamics.RigidState` arrays at time 0 of 3D ``bodies`` (a dict)."""
    nb = len(bodies)

    def moving(b, value):
        return np.zeros(3) if b.motion == "fixed" else np.asarray(value, dtype=np.float64)

    return dict(position=np.array([b.center for b in bodies], dtype=np.float64).reshape(nb, 3),
                angle=np.tile(IDENTITY, (nb, 1)),
                velocity=np.array([moving(b, b.velocity) for b in bodies]).reshape(nb, 3),
                angular_velocity=np.array([moving(b, b.angular_velocity) for b in bodies]).reshape(nb, 3),
                impulse=np.zeros((nb, 3)), angular_impulse=np.zeros((nb, 3)))


def posed_shape(body, position, angle):
    r"""The body's mesh at pose (``position``, ``angle``, the orientation quaternion :math:`\mathbf q`):
    :math:`\mathbf x = \mathbf c + R(\mathbf q)(\mathbf x^0 - \mathbf c_0)`."""
    vertices = position + (body.shape.vertices - body.center) @ rotation_matrix(angle).T
    return TriMesh(vertices=vertices, triangles=body.shape.triangles, closed=body.shape.closed)


def scripted_pose(body, t):
    r"""Offset of the reference point from :math:`\mathbf c_0` and rotation vector of a scripted body at ``t``.

    Constant rates: :math:`(\mathbf v t,\ \boldsymbol\omega t)`. Keyframes :math:`(t_k, \mathbf o_k,
    \boldsymbol\phi_k)`: offset and rotation vector interpolated linearly between them (exact for rotations
    about one fixed axis), held constant before the first and after the last.
    """
    if not body.keyframes:
        return body.velocity * t, body.angular_velocity * t
    times = np.array([k[0] for k in body.keyframes])
    offsets = np.array([k[1] for k in body.keyframes])
    angles = np.array([k[2] for k in body.keyframes])
    return (np.array([np.interp(t, times, offsets[:, a]) for a in range(3)]),
            np.array([np.interp(t, times, angles[:, a]) for a in range(3)]))


def begin_step(bodies, state, time, dt):
    r"""The state with each scripted body's velocity over ``[time, time + dt]`` (finite difference).

    :math:`\mathbf v = (\mathbf o(t + \Delta t) - \mathbf o(t))/\Delta t` and
    :math:`\boldsymbol\omega = \boldsymbol\phi(\mathbf q_1 \otimes \mathbf q_0^{-1})/\Delta t`, the rotation
    vector that turns the script's orientation at :math:`t` into the one at :math:`t + \Delta t`.
    """
    velocity, omega = state.velocity.copy(), state.angular_velocity.copy()
    for r, body in enumerate(bodies):
        if body.motion == "scripted":
            (o0, a0), (o1, a1) = scripted_pose(body, time), scripted_pose(body, time + dt)
            q0, q1 = quaternion_from_rotation_vector(a0), quaternion_from_rotation_vector(a1)
            q0_inverse = q0 * np.array([1.0, -1.0, -1.0, -1.0])
            velocity[r] = (o1 - o0) / dt
            omega[r] = rotation_vector_from_quaternion(quaternion_multiply(q1, q0_inverse)) / dt
    return state.with_(velocity=velocity, angular_velocity=omega)


def point_velocity(state, body_ids, x):
    r"""Velocity :math:`\mathbf v_r + \boldsymbol\omega_r \times (\mathbf x - \mathbf c_r)` of body ``body_ids`` at
    ``x`` (..., 3)."""
    return state.velocity[body_ids] + np.cross(state.angular_velocity[body_ids], x - state.position[body_ids])


def body_impulses(n_bodies, body_ids, x, impulse, position):
    r"""Sum impulses :math:`\mathbf J` applied at points ``x`` to bodies ``body_ids``: linear and angular.

    Returns ``(J (nb, 3), L (nb, 3))``: :math:`\mathbf J_r = \sum \mathbf J` and
    :math:`\mathbf L_r = \sum (\mathbf x - \mathbf c_r)\times\mathbf J` about each body's reference point.
    """
    torque = np.cross(x - position[body_ids], impulse)

    def total(values):
        return np.stack([np.bincount(body_ids, weights=values[:, a], minlength=n_bodies) for a in range(3)], axis=1)

    return total(impulse), total(torque)


def world_inverse_inertia(body, q):
    r""":math:`(R \mathbf I_0 R^T)^{-1} = R \mathbf I_0^{-1} R^T` of a dynamic body at orientation ``q`` (zero
    otherwise)."""
    if body.motion != "dynamic":
        return np.zeros((3, 3))
    R = rotation_matrix(q)
    return R @ np.linalg.inv(body.inertia) @ R.T


def apply_impulses(bodies, state, J, L):
    r"""Record impulses ``J`` (nb, 3) and angular impulses ``L`` (nb, 3); change the dynamic bodies' velocities.

    .. math:: \mathbf v_r \mathrel{+}= \mathbf J_r / M_r, \qquad
              \boldsymbol\omega_r \mathrel{+}= (R_r \mathbf I_{0,r} R_r^T)^{-1} \mathbf L_r .

    Fixed and scripted bodies have infinite mass and inertia: they only record what they received.
    """
    inv_m = np.array([1.0 / b.mass for b in bodies])
    d_omega = np.array([world_inverse_inertia(b, state.angle[r]) @ L[r] for r, b in enumerate(bodies)])
    return state.with_(velocity=state.velocity + J * inv_m[:, None],
                       angular_velocity=state.angular_velocity + d_omega.reshape(len(bodies), 3),
                       impulse=state.impulse + J, angular_impulse=state.angular_impulse + L)


def end_step(bodies, state, time, dt, gravity):
    r"""Move every body to ``time + dt``.

    Dynamic: :math:`\mathbf c \mathrel{+}= \Delta t\,\mathbf v`; the orientation turns by
    :math:`\Delta t\boldsymbol\omega` (:func:`rotate`); the angular momentum
    :math:`\mathbf L = R\mathbf I_0 R^T\boldsymbol\omega` is kept (no torque acts in the rigid step) and
    :math:`\boldsymbol\omega` is recomputed from it in the new orientation, so a free asymmetric body keeps its
    angular momentum exactly and precesses (Goldstein §5.1, Euler's equations without torque); then the
    gravity impulse :math:`\mathbf v \mathrel{+}= \mathbf g\Delta t` (if the body feels gravity).
    Scripted: the script's pose at ``time + dt``. Fixed: unchanged.
    """
    position, angle = state.position.copy(), state.angle.copy()
    velocity, omega = state.velocity.copy(), state.angular_velocity.copy()
    for r, body in enumerate(bodies):
        if body.motion == "dynamic":
            position[r] += dt * velocity[r]
            R0 = rotation_matrix(angle[r])
            momentum = R0 @ body.inertia @ R0.T @ omega[r]
            angle[r] = rotate(angle[r], dt * omega[r])
            omega[r] = world_inverse_inertia(body, angle[r]) @ momentum
            if body.gravity:
                velocity[r] += dt * np.asarray(gravity)
        elif body.motion == "scripted":
            offset, phi = scripted_pose(body, time + dt)
            position[r] = body.center + offset
            angle[r] = quaternion_from_rotation_vector(phi)
    return state.with_(position=position, angle=angle, velocity=velocity, angular_velocity=omega)


def kinetic_energy(bodies, state):
    r"""Kinetic energy of each dynamic body,
    :math:`\tfrac12 M_r |\mathbf v_r|^2 + \tfrac12 \boldsymbol\omega_r \cdot R \mathbf I_0 R^T \boldsymbol\omega_r`
    (nb,); zero for fixed and scripted bodies (infinite mass: they are the scene's drive, not part of its energy).

    :math:`M_r` mass, :math:`\mathbf I_0` inertia tensor about the centre of mass in the declared pose,
    :math:`R` the rotation of the orientation quaternion, :math:`\mathbf v_r`, :math:`\boldsymbol\omega_r` the
    velocity and angular velocity (Goldstein §5.1).
    """
    energy = np.zeros(len(bodies))
    for r, body in enumerate(bodies):
        if body.motion == "dynamic":
            R = rotation_matrix(state.angle[r])
            omega = state.angular_velocity[r]
            energy[r] = (0.5 * body.mass * state.velocity[r] @ state.velocity[r]
                         + 0.5 * omega @ R @ body.inertia @ R.T @ omega)
    return energy


def diagnostics(bodies, state):
    """Per body ``r``: ``rigid{r}_`` position, orientation quaternion, velocity, angular velocity and impulses
    (dict)."""
    out = {}
    for r in range(len(bodies)):
        for name, values, axes in (("", state.position[r], "xyz"), ("q", state.angle[r], "wxyz"),
                                   ("v", state.velocity[r], "xyz"), ("omega_", state.angular_velocity[r], "xyz"),
                                   ("impulse_", state.impulse[r], "xyz"),
                                   ("angular_impulse_", state.angular_impulse[r], "xyz")):
            out.update({f"rigid{r}_{name}{a}": values[k] for k, a in enumerate(axes)})
    return out

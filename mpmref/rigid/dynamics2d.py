r"""Rigid-body motion for CPIC in 2D: the pose, scripts, impulses and integration of polyline bodies.

The 2D motion behind :mod:`mpmref.rigid.dynamics` (chosen once, when a
:class:`~mpmref.rigid.dynamics.RigidState` is made, from its arrays' shapes). A body is a
:class:`~mpmref.rigid.polyline.Polyline` declared at time 0 with a reference point :math:`\mathbf c_0`; its pose
at a later time is a translation of the reference point to :math:`\mathbf c` and a rotation by :math:`\theta`
about it,

.. math:: \mathbf x = \mathbf c + R(\theta)(\mathbf x^0 - \mathbf c_0), \qquad
          \mathbf v_r(\mathbf x) = \mathbf v + \omega \hat{\mathbf z} \times (\mathbf x - \mathbf c).

The state arrays: ``position`` and ``velocity`` (nb, 2), ``angle`` and ``angular_velocity`` (nb,), ``impulse``
(nb, 2), ``angular_impulse`` (nb,). The functions here are the 2D
:class:`~mpmref.rigid.dynamics.RigidMechanics` (the same names and arguments as those of
:mod:`mpmref.rigid.dynamics3d`).

Source: Hu et al. 2018, SIGGRAPH, "A Moving Least Squares Material Point Method with Displacement
Discontinuity and Two-Way Rigid Body Coupling", §5; the integration order is the authors' reference
implementation's (docs/cpic.md).
"""

import numpy as np

from .polyline import Polyline


def initial_arrays(bodies):
    """The :class:`~mpmref.rigid.dynamics.RigidState` arrays at time 0 of 2D ``bodies`` (a dict)."""
    nb = len(bodies)
    return dict(position=np.array([b.center for b in bodies], dtype=np.float64).reshape(nb, 2),
                angle=np.zeros(nb),
                velocity=np.array([b.velocity if b.motion != "fixed" else np.zeros(2) for b in bodies],
                                  dtype=np.float64).reshape(nb, 2),
                angular_velocity=np.array([b.angular_velocity if b.motion != "fixed" else 0.0 for b in bodies],
                                          dtype=np.float64),
                impulse=np.zeros((nb, 2)), angular_impulse=np.zeros(nb))


def rotation(theta):
    """The 2D rotation matrix :math:`R(\\theta)`."""
    c, s = np.cos(theta), np.sin(theta)
    return np.array([[c, -s], [s, c]])


def posed_shape(body, position, angle):
    r"""The body's polyline at pose (``position``, ``angle``):
    :math:`\mathbf x = \mathbf c + R(\theta)(\mathbf x^0 - \mathbf c_0)`."""
    vertices = position + (body.shape.vertices - body.center) @ rotation(angle).T
    return Polyline(vertices=vertices, segments=body.shape.segments, closed=body.shape.closed)


def scripted_pose(body, t):
    r"""Offset of the reference point from :math:`\mathbf c_0` and angle of a scripted body at time ``t``.

    Constant rates: :math:`(\mathbf v t,\ \omega t)`. Keyframes :math:`(t_k, \mathbf o_k, \theta_k)`:
    linear interpolation between them, held constant before the first and after the last.
    """
    if not body.keyframes:
        return body.velocity * t, body.angular_velocity * t
    times = np.array([k[0] for k in body.keyframes])
    offsets = np.array([k[1] for k in body.keyframes])
    angles = np.array([k[2] for k in body.keyframes])
    offset = np.array([np.interp(t, times, offsets[:, a]) for a in range(2)])
    return offset, float(np.interp(t, times, angles))


def begin_step(bodies, state, time, dt):
    """The state with each scripted body's velocity over the step ``[time, time + dt]`` (finite difference)."""
    velocity, omega = state.velocity.copy(), state.angular_velocity.copy()
    for r, body in enumerate(bodies):
        if body.motion == "scripted":
            (o0, a0), (o1, a1) = scripted_pose(body, time), scripted_pose(body, time + dt)
            velocity[r], omega[r] = (o1 - o0) / dt, (a1 - a0) / dt
    return state.with_(velocity=velocity, angular_velocity=omega)


def point_velocity(state, body_ids, x):
    r"""Velocity :math:`\mathbf v_r + \omega_r \hat{\mathbf z}\times(\mathbf x - \mathbf c_r)` of body ``body_ids`` at
    ``x`` (..., 2)."""
    r = state.position[body_ids]
    w = state.angular_velocity[body_ids][..., None]
    rel = x - r
    return state.velocity[body_ids] + w * np.stack([-rel[..., 1], rel[..., 0]], axis=-1)


def body_impulses(n_bodies, body_ids, x, impulse, position):
    r"""Sum impulses :math:`\mathbf J` applied at points ``x`` to bodies ``body_ids``: linear and angular.

    Returns ``(J, L)``: :math:`\mathbf J_r = \sum \mathbf J` and
    :math:`L_r = \sum (\mathbf x - \mathbf c_r)\times\mathbf J` about each body's reference point (docs/cpic.md, "after
    all particles").
    """
    rel = x - position[body_ids]
    torque = rel[:, 0] * impulse[:, 1] - rel[:, 1] * impulse[:, 0]
    J = np.stack([np.bincount(body_ids, weights=impulse[:, a], minlength=n_bodies) for a in range(2)], axis=1)
    return J, np.bincount(body_ids, weights=torque, minlength=n_bodies)


def apply_impulses(bodies, state, J, L):
    r"""Record impulses ``J`` (nb, 2) and angular impulses ``L`` (nb,) and change the dynamic bodies' velocities.

    .. math:: \mathbf v_r \mathrel{+}= \mathbf J_r / M_r, \qquad \omega_r \mathrel{+}= L_r / I_r

    (docs/cpic.md). Fixed and scripted bodies have infinite mass: they only record what they received. A
    pinned body's linear impulse goes to its pin (:math:`1/M_r = 0`); welded bodies then share one angular
    velocity (:func:`weld`).
    """
    inv_m = np.array([0.0 if b.pinned else 1.0 / b.mass for b in bodies])
    inv_i = np.array([1.0 / b.inertia for b in bodies])
    return state.with_(velocity=state.velocity + J * inv_m[:, None],
                       angular_velocity=weld(bodies, state.angular_velocity + L * inv_i),
                       impulse=state.impulse + J, angular_impulse=state.angular_impulse + L)


def weld(bodies, omega):
    r"""The angular velocities ``omega`` (nb,) with every group of welded bodies turning as one.

    Pinned bodies welded at a common centre form one rigid body of inertia :math:`\sum_r I_r`; its angular
    velocity keeps their total angular momentum about the centre,

    .. math:: \omega_G = \frac{\sum_{r \in G} I_r \omega_r}{\sum_{r \in G} I_r}.

    This is the reference implementation's rotation articulation (Hu et al. 2018's sand wheel joins its
    blades to its ring so; docs/cpic.md), which for two bodies pinned at one point is a weld.
    """
    roots = np.array([r if b.welded_to < 0 else b.welded_to for r, b in enumerate(bodies)], dtype=np.int64)
    out = omega
    for root in np.unique(roots[roots != np.arange(len(bodies))]):
        group = np.nonzero(roots == root)[0]
        inertia = np.array([bodies[r].inertia for r in group])
        out = out.copy()
        out[group] = np.sum(inertia * omega[group]) / np.sum(inertia)
    return out


def end_step(bodies, state, time, dt, gravity):
    r"""Move every body to ``time + dt`` (docs/cpic.md, the rigid step after G2P).

    Dynamic: :math:`\mathbf c \mathrel{+}= \Delta t\,\mathbf v`, :math:`\theta \mathrel{+}= \Delta t\,\omega`,
    then the gravity impulse :math:`\mathbf v \mathrel{+}= \mathbf g \Delta t` (if the body feels gravity; a
    pinned body's centre stays), then the angular damping :math:`\omega \mathrel{*}= e^{-c\Delta t}` (the exact
    decay of :math:`\dot\omega = -c\,\omega` over the step) and the welds (:func:`weld`).
    Scripted: the script's pose at ``time + dt``. Fixed: unchanged.
    """
    position, angle, velocity = state.position.copy(), state.angle.copy(), state.velocity.copy()
    omega = state.angular_velocity.copy()
    for r, body in enumerate(bodies):
        if body.motion == "dynamic":
            angle[r] += dt * omega[r]
            omega[r] *= np.exp(-body.angular_damping * dt)
            if body.pinned:
                continue
            position[r] += dt * velocity[r]
            if body.gravity:
                velocity[r] += dt * gravity
        elif body.motion == "scripted":
            offset, angle[r] = scripted_pose(body, time + dt)
            position[r] = body.center + offset
    return state.with_(position=position, angle=angle, velocity=velocity, angular_velocity=weld(bodies, omega))


def kinetic_energy(bodies, state):
    r"""Kinetic energy of each dynamic body, :math:`\tfrac12 M_r |\mathbf v_r|^2 + \tfrac12 I_r \omega_r^2` (nb,);
    zero for fixed and scripted bodies (infinite mass: they are the scene's drive, not part of its energy), and
    no translation for a pinned one.

    :math:`M_r` mass, :math:`I_r` moment of inertia about the reference point (the centre of mass),
    :math:`\mathbf v_r` and :math:`\omega_r` the body's velocity and angular velocity (Goldstein §5.1).
    """
    dynamic = np.array([b.motion == "dynamic" for b in bodies])
    mass = np.array([b.mass if b.motion == "dynamic" and not b.pinned else 0.0 for b in bodies])
    inertia = np.array([b.inertia if b.motion == "dynamic" else 0.0 for b in bodies])
    energy = 0.5 * mass * np.sum(state.velocity**2, axis=1) + 0.5 * inertia * state.angular_velocity**2
    return np.where(dynamic, energy, 0.0)


def diagnostics(bodies, state):
    """Per body ``r``: ``rigid{r}_`` position, angle, velocity, angular velocity and impulse received (dict)."""
    out = {}
    for r in range(len(bodies)):
        out.update({f"rigid{r}_x": state.position[r, 0], f"rigid{r}_y": state.position[r, 1],
                    f"rigid{r}_angle": state.angle[r], f"rigid{r}_vx": state.velocity[r, 0],
                    f"rigid{r}_vy": state.velocity[r, 1], f"rigid{r}_omega": state.angular_velocity[r],
                    f"rigid{r}_impulse_x": state.impulse[r, 0], f"rigid{r}_impulse_y": state.impulse[r, 1],
                    f"rigid{r}_angular_impulse": state.angular_impulse[r]})
    return out

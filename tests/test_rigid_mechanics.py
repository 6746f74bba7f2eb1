"""The declared rigid-body mechanics (mpmref.rigid.dynamics.RigidMechanics): both dimensions have every
function with the declared arguments, and each dimension's impulses and steps keep a free body's linear and angular
momentum as an independent computation of them says."""

import inspect

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from mpmref.rigid.dynamics import MECHANICS, RigidBody, RigidMechanics, initial_state
from mpmref.rigid.polyline import Polyline
from mpmref.rigid.trimesh import box

DECLARED = {name: inspect.signature(f) for name, f in vars(RigidMechanics).items()
            if inspect.isfunction(f) and not name.startswith("_")}


def arguments(signature, drop_self=False):
    """Names, kinds and defaults of a signature's parameters (annotations aside)."""
    params = list(signature.parameters.values())[1 if drop_self else 0:]
    return [(p.name, p.kind, p.default) for p in params]


def test_the_declaration_names_what_the_state_and_the_simulation_call():
    assert set(DECLARED) == {"initial_arrays", "posed_shape", "begin_step", "point_velocity", "body_impulses",
                             "apply_impulses", "end_step", "kinetic_energy", "diagnostics"}


@pytest.mark.parametrize("dim", [2, 3])
def test_each_dimension_has_every_declared_function_with_its_arguments(dim):
    mechanics = MECHANICS[dim]
    for name, signature in DECLARED.items():
        function = getattr(mechanics, name, None)
        assert callable(function), f"{mechanics.__name__} lacks {name}"
        assert arguments(inspect.signature(function)) == arguments(signature, drop_self=True), (dim, name)
        assert function.__doc__, (dim, name)


# ------------------------------------------------------------------------------------------- free bodies
def square(center, half):
    """A closed square polyline (counter-clockwise) around ``center``."""
    c = np.asarray(center)
    vertices = c + half * np.array([[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]])
    return Polyline(vertices=vertices, segments=np.array([[0, 1], [1, 2], [2, 3], [3, 0]]), closed=True)


def free_body(dim):
    """A dynamic body, no gravity, moving and turning: in 3D with an inertia tensor whose principal axes are not
    the coordinate axes, so that it tumbles."""
    if dim == 2:
        return RigidBody(shape=square([0.4, 0.6], 0.1), motion="dynamic", center=np.array([0.4, 0.6]), mass=2.5,
                         inertia=0.03, velocity=np.array([0.3, -0.2]), angular_velocity=4.0)
    turn = Rotation.from_rotvec([0.3, -0.5, 0.2]).as_matrix()
    inertia = turn @ np.diag([0.01, 0.02, 0.035]) @ turn.T
    return RigidBody(shape=box([0.3, 0.4, 0.5], [0.5, 0.5, 0.6]), motion="dynamic", center=np.array([0.4, 0.45, 0.55]),
                     mass=1.5, inertia=inertia, velocity=np.array([0.1, 0.2, -0.3]),
                     angular_velocity=np.array([3.0, 20.0, -5.0]))


def world_inertia(body, angle):
    """The body's inertia about its centre in the world frame, from scipy's own quaternion rotation (scalar last)."""
    if np.ndim(angle) == 0:
        return body.inertia
    R = Rotation.from_quat(np.roll(angle, -1)).as_matrix()
    return R @ body.inertia @ R.T


def cross(a, b):
    """The cross product, the scalar one of 2-vectors."""
    return np.cross(a, b) if len(a) == 3 else a[0] * b[1] - a[1] * b[0]


def momenta(body, state):
    r"""Linear momentum :math:`M\mathbf v` and angular momentum about the origin :math:`\mathbf I\boldsymbol\omega +
    \mathbf c\times M\mathbf v` of body 0."""
    p = body.mass * state.velocity[0]
    inertia, omega = world_inertia(body, state.angle[0]), state.angular_velocity[0]
    spin = inertia @ omega if np.ndim(inertia) else inertia * omega
    return p, spin + cross(state.position[0], p)


@pytest.mark.parametrize("dim", [2, 3])
def test_impulses_change_a_free_bodys_momenta_by_what_they_carry(dim):
    body = free_body(dim)
    state = initial_state([body])
    mechanics = state.mechanics
    assert mechanics is MECHANICS[dim]
    rng = np.random.default_rng(dim)
    x = state.position[0] + rng.uniform(-0.1, 0.1, (5, dim))
    impulse = rng.normal(size=(5, dim)) * 1e-2
    J, L = mechanics.body_impulses(1, np.zeros(5, dtype=np.int64), x, impulse, state.position)
    after = mechanics.apply_impulses([body], state, J, L)
    p0, l0 = momenta(body, state)
    p1, l1 = momenta(body, after)
    assert np.allclose(p1 - p0, impulse.sum(axis=0), rtol=0, atol=1e-15)
    moment_about_origin = sum(cross(xi, ji) for xi, ji in zip(x, impulse))
    assert np.allclose(l1 - l0, moment_about_origin, rtol=0, atol=1e-14)
    assert np.allclose(after.impulse[0], impulse.sum(axis=0)) and np.allclose(after.angular_impulse[0], L[0])


@pytest.mark.parametrize("dim", [2, 3])
def test_a_free_body_keeps_its_momenta_over_many_steps(dim):
    body, dt = free_body(dim), 1e-3
    state = initial_state([body])
    p0, l0 = momenta(body, state)
    for k in range(500):
        state = state.mechanics.end_step([body], state, k * dt, dt, np.zeros(dim))
    p1, l1 = momenta(body, state)
    assert np.array_equal(p1, p0)
    assert np.allclose(l1, l0, rtol=1e-12, atol=0)
    assert np.allclose(state.position[0], body.center + 500 * dt * body.velocity, rtol=1e-12)
    if dim == 3:  # not a rotation about a fixed axis: the body tumbles, its angular velocity changes
        assert not np.allclose(state.angular_velocity[0], body.angular_velocity, atol=1e-2)


@pytest.mark.parametrize("dim", [2, 3])
def test_a_step_moves_the_body_at_its_point_velocity(dim):
    """The pose (``posed_shape``) after one short step, less the pose before, over the step: each vertex's
    velocity, which ``point_velocity`` gives to first order in the step."""
    body, dt = free_body(dim), 1e-7
    state = initial_state([body])
    mechanics = state.mechanics
    after = mechanics.end_step([body], state, 0.0, dt, np.zeros(dim))
    before_x = mechanics.posed_shape(body, state.position[0], state.angle[0]).vertices
    after_x = mechanics.posed_shape(body, after.position[0], after.angle[0]).vertices
    v = mechanics.point_velocity(state, np.zeros(len(before_x), dtype=np.int64), before_x)
    assert np.allclose((after_x - before_x) / dt, v, rtol=0, atol=1e-4 * np.abs(v).max())

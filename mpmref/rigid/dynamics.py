r"""Rigid-body motion for CPIC in 2D: the declared bodies, their state, scripts, impulses and integration.

A body is a :class:`~mpmref.rigid.polyline.Polyline` declared at time 0 with a reference point
:math:`\mathbf c_0` (its centre of mass for a dynamic body, the declared ``center`` or the vertex centroid
otherwise). Its pose at a later time is a translation of the reference point to :math:`\mathbf c` and a
rotation by :math:`\theta` about it:

.. math:: \mathbf x = \mathbf c + R(\theta)(\mathbf x^0 - \mathbf c_0),

and the velocity of a point :math:`\mathbf x` of the body is
:math:`\mathbf v_r(\mathbf x) = \mathbf v + \omega \hat{\mathbf z} \times (\mathbf x - \mathbf c)`.

Motions:

* ``fixed``: never moves (infinite mass and inertia);
* ``scripted``: a constant velocity and angular velocity, or piecewise-linear keyframes of offset and
  angle; infinite mass and inertia (Hu et al. 2018 §6; docs/cpic.md). Its velocity over a step is the finite
  difference of the script over that step;
* ``dynamic``: mass and inertia from a density per unit length (an open, zero-thickness body) or per unit
  area (a closed one); moved by the impulses it receives from the material and by gravity (docs/cpic.md).

Source: Hu et al. 2018, SIGGRAPH, "A Moving Least Squares Material Point Method with Displacement
Discontinuity and Two-Way Rigid Body Coupling", §5 (two-way coupling: the rigid body receives the momentum
the material could not give to the grid); the integration order is the authors' reference implementation's
(docs/cpic.md).
"""

from dataclasses import dataclass, field, fields, replace
from typing import Protocol

import numpy as np

from . import dynamics2d, dynamics3d
from .polyline import Polyline


class RigidMechanics(Protocol):
    r"""The rigid-body mechanics of one dimension: what :data:`MECHANICS` holds for 2D
    (:mod:`.dynamics2d`) and 3D (:mod:`.dynamics3d`), each a module with these functions, the same
    names and arguments (tests/test_rigid_mechanics.py checks both against this declaration).

    Per dimension ``d``, the state's arrays (:class:`RigidState`) are: ``position``, ``velocity`` and ``impulse``
    (nb, d); ``angle`` the orientation, :math:`\theta` (nb,) in 2D, a unit quaternion (w, x, y, z) (nb, 4) in 3D;
    ``angular_velocity`` and ``angular_impulse`` (nb,) in 2D (about :math:`\hat{\mathbf z}`), (nb, 3) in 3D.
    ``bodies`` is a sequence of :class:`RigidBody`; a function that changes the state returns a new one.
    """

    def initial_arrays(self, bodies):
        """The :class:`RigidState` arrays at time 0 of ``bodies`` (a dict of the state's fields)."""

    def posed_shape(self, body, position, angle):
        r"""The body's shape (:class:`~mpmref.rigid.polyline.Polyline` or :class:`~mpmref.rigid.trimesh.TriMesh`)
        at the pose ``position`` :math:`\mathbf c`, ``angle`` (a row of ``RigidState.angle``):
        :math:`\mathbf x = \mathbf c + R(\text{angle})(\mathbf x^0 - \mathbf c_0)`."""

    def begin_step(self, bodies, state, time, dt):
        """The state with each scripted body's velocity and angular velocity over ``[time, time + dt]``."""

    def point_velocity(self, state, body_ids, x):
        r"""Velocity :math:`\mathbf v_r + \boldsymbol\omega_r \times (\mathbf x - \mathbf c_r)` of bodies
        ``body_ids`` at points ``x`` (..., d)."""

    def body_impulses(self, n_bodies, body_ids, x, impulse, position):
        r"""Impulses ``impulse`` applied at points ``x`` to bodies ``body_ids``, summed per body: ``(J, L)``,
        :math:`\mathbf J_r = \sum \mathbf J` and :math:`\mathbf L_r = \sum (\mathbf x - \mathbf c_r)\times
        \mathbf J` about each body's reference point ``position[r]``."""

    def apply_impulses(self, bodies, state, J, L):
        r"""The state with impulses ``J`` and angular impulses ``L`` recorded and the dynamic bodies'
        velocities changed: :math:`\mathbf v_r \mathrel{+}= \mathbf J_r / M_r`,
        :math:`\boldsymbol\omega_r \mathrel{+}= \mathbf I_r^{-1}\mathbf L_r`."""

    def end_step(self, bodies, state, time, dt, gravity):
        """The state moved to ``time + dt``: dynamic bodies by their velocities and gravity, scripted ones to their
        script's pose, fixed ones unchanged."""

    def kinetic_energy(self, bodies, state):
        """Kinetic energy of each dynamic body (nb,), zero for fixed and scripted bodies."""

    def diagnostics(self, bodies, state):
        """Per body ``r``: ``rigid{r}_`` pose, velocity, angular velocity and impulses received (a dict)."""


#: The rigid-body mechanics of each dimension (:class:`RigidMechanics`), chosen once per :class:`RigidState` from
#: its arrays' shapes.
MECHANICS: dict[int, RigidMechanics] = {2: dynamics2d, 3: dynamics3d}

MOTIONS = ("fixed", "scripted", "dynamic")
CONTACT_TYPES = ("sticky", "slip", "separate")


@dataclass(frozen=True)
class RigidBody:
    """A declared rigid body (static facts; what moves is in :class:`RigidState`).

    Attributes
    ----------
    shape : Polyline            the geometry at time 0
    motion : str                ``"fixed"``, ``"scripted"`` or ``"dynamic"``
    center : (2,) array         reference point :math:`\\mathbf c_0` (centre of mass if dynamic)
    mass, inertia : float       :math:`M` and :math:`I` about the centre (``inf`` unless dynamic)
    velocity : (2,) array       initial (dynamic) or constant (scripted) velocity
    angular_velocity : float    initial (dynamic) or constant (scripted) angular velocity
    keyframes : tuple           scripted keyframes ``(time, offset (2,), angle)``, sorted; empty if none
    gravity : bool              a dynamic body feels the scene's gravity
    friction : (2,) array       the encoded friction value :math:`\\mu` of side 0 and side 1 (:func:`encode_friction`)
    pinned : bool               a dynamic body whose centre of mass is held fixed: it only turns (infinite mass,
                                finite inertia; the reference code's constant scripted position)
    angular_damping : float     :math:`c` of :math:`\\dot\\omega = -c\\,\\omega` (1/s; :func:`damp_and_weld`)
    welded_to : int             the body this pinned body turns with (same centre, one angular velocity), or -1

    Notes
    -----
    A 3D body (shape a :class:`~mpmref.rigid.trimesh.TriMesh`) has ``center``, ``velocity`` and
    ``angular_velocity`` of shape (3,), ``inertia`` the (3, 3) tensor about the centre in the declared pose,
    and keyframes ``(time, offset (3,), rotation vector (3,))`` (:mod:`mpmref.rigid.dynamics3d`).
    """

    shape: Polyline
    motion: str
    center: np.ndarray
    mass: float = np.inf
    inertia: float = np.inf
    velocity: np.ndarray = field(default_factory=lambda: np.zeros(2))
    angular_velocity: float = 0.0
    keyframes: tuple = ()
    gravity: bool = False
    friction: np.ndarray = field(default_factory=lambda: np.zeros(2))
    pinned: bool = False
    angular_damping: float = 0.0
    welded_to: int = -1


@dataclass
class RigidState:
    """What changes of every body, as arrays over bodies (saved bit for bit in checkpoints).

    Attributes
    ----------
    position : (nb, 2)          reference point :math:`\\mathbf c`
    angle : (nb,)               rotation :math:`\\theta` since time 0
    velocity : (nb, 2)          :math:`\\mathbf v` (over the current step, for a scripted body)
    angular_velocity : (nb,)    :math:`\\omega`
    impulse : (nb, 2)           linear impulse received from the material since time 0
    angular_impulse : (nb,)     angular impulse about the reference point received since time 0
    mechanics : RigidMechanics  the dimension's motion (:data:`MECHANICS`: :mod:`.dynamics2d` or
                                :mod:`.dynamics3d`), chosen when the state is made; not an array

    Notes
    -----
    For 3D bodies (:mod:`mpmref.rigid.dynamics3d`) ``position``, ``velocity``, ``impulse``,
    ``angular_velocity`` and ``angular_impulse`` are (nb, 3) and ``angle`` is the orientation, a unit
    quaternion (w, x, y, z) of shape (nb, 4).
    """

    position: np.ndarray
    angle: np.ndarray
    velocity: np.ndarray
    angular_velocity: np.ndarray
    impulse: np.ndarray
    angular_impulse: np.ndarray
    mechanics: object = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        self.mechanics = MECHANICS[np.shape(self.position)[1]]

    def arrays(self):
        """Mapping of field name to array (what a checkpoint stores)."""
        return {f.name: getattr(self, f.name) for f in fields(self) if f.init}

    def with_(self, **changes):
        return replace(self, **changes)


def encode_friction(kind, coefficient):
    r"""The one number :math:`\mu` of the friction projection (:func:`friction_projection`) for a contact type.

    ``sticky`` -> :math:`-1`; ``separate`` with coefficient :math:`c` -> :math:`c \ge 0`; ``slip`` with
    coefficient :math:`c` -> :math:`-c - 2 \le -2` (docs/cpic.md encoding of the talk's Eq. 25 types).
    """
    if kind == "sticky":
        return -1.0
    return float(coefficient) if kind == "separate" else -float(coefficient) - 2.0


def friction_projection(v, v_body, normal, mu):
    r"""The friction projection :math:`\Pi(\mathbf v; \mathbf v_b, \mathbf n, \mu)` of velocities against a body.

    With :math:`\mathbf u = \mathbf v - \mathbf v_b`, :math:`u_n = \mathbf n\cdot\mathbf u`,
    :math:`\mathbf u_t = \mathbf u - u_n \mathbf n`:

    * :math:`\mu = -1` (sticky): :math:`\Pi = \mathbf v_b`;
    * otherwise, with :math:`\mu' = \mu` if :math:`\mu \ge 0` (separate) and :math:`\mu' = -\mu - 2` if
      :math:`\mu \le -2` (slip),

      .. math:: \mathbf u_t' = \max(|\mathbf u_t| + \mu' \min(u_n, 0),\ 0)\, \frac{\mathbf u_t}{|\mathbf u_t|},
                \qquad \Pi = \mathbf v_b + \mathbf u_t' + \begin{cases} \max(u_n, 0)\,\mathbf n & \mu \ge 0 \\
                0 & \mu \le -2. \end{cases}

    This is the talk's Eq. 25 (sticky, slip, separate with Coulomb friction) applied to a particle's
    velocity relative to a body (Hu et al. 2018 §5; docs/cpic.md).

    Parameters
    ----------
    v, v_body : (..., 2) arrays     velocity :math:`\mathbf v` and body velocity :math:`\mathbf v_b`
    normal : (..., 2) array         unit normal :math:`\mathbf n` pointing to the particle's side (or 0)
    mu : (...) array                encoded friction (:func:`encode_friction`)
    """
    u = v - v_body
    un = np.einsum("...d,...d->...", normal, u)
    ut = u - un[..., None] * normal
    ut_norm = np.linalg.norm(ut, axis=-1)
    coeff = np.where(mu >= 0.0, mu, -mu - 2.0)
    scale = np.maximum(ut_norm + coeff * np.minimum(un, 0.0), 0.0) / np.where(ut_norm > 0.0, ut_norm, 1.0)
    normal_part = np.where((mu >= 0.0)[..., None], np.maximum(un, 0.0)[..., None] * normal, 0.0)
    out = v_body + scale[..., None] * ut + normal_part
    return np.where((mu == -1.0)[..., None], v_body, out)


# ------------------------------------------------------------------------------------ mass properties
def line_mass_properties(shape, density):
    r"""Mass, centre and inertia of a zero-thickness polyline of linear density :math:`\rho`.

    .. math:: M = \rho \sum_k \ell_k, \quad \mathbf c = \frac{\rho}{M}\sum_k \ell_k \mathbf m_k, \quad
              I = \rho \sum_k \left(\frac{\ell_k^3}{12} + \ell_k |\mathbf m_k - \mathbf c|^2\right)

    (:math:`\mathbf m_k` the segment midpoints; a thin rod's inertia plus the parallel-axis term). Hu et al. 2018:
    thin shells take mass and inertia from their length.
    """
    lengths = shape.lengths
    mid = 0.5 * (shape.starts + shape.ends)
    mass = density * lengths.sum()
    center = density * (lengths[:, None] * mid).sum(axis=0) / mass
    inertia = density * np.sum(lengths**3 / 12.0 + lengths * np.sum((mid - center) ** 2, axis=1))
    return float(mass), center, float(inertia)


def area_mass_properties(shape, density):
    r"""Mass, centre and inertia of the region enclosed by a closed polyline of areal density :math:`\rho`.

    With :math:`\mathbf a_k \times \mathbf b_k` the cross product of segment :math:`k`'s end points
    (Green's theorem, the shoelace formulas):

    .. math:: A = \tfrac12 \sum_k \mathbf a_k\times\mathbf b_k, \quad
              \mathbf c = \frac{1}{6A}\sum_k (\mathbf a_k + \mathbf b_k)(\mathbf a_k\times\mathbf b_k), \quad
              I_0 = \frac{\rho}{12}\sum_k (\mathbf a_k\times\mathbf b_k)(|\mathbf a_k|^2 + \mathbf a_k\cdot\mathbf b_k
              + |\mathbf b_k|^2),

    :math:`M = \rho |A|`, :math:`I = |I_0| - M|\mathbf c|^2` (parallel axis). The segments must be
    consistently oriented (each vertex starts one segment and ends one). Hu et al. 2018: solid bodies take
    mass from their enclosed area.
    """
    a, b = shape.starts, shape.ends
    cross = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
    area = 0.5 * cross.sum()
    center = ((a + b) * cross[:, None]).sum(axis=0) / (6.0 * area)
    i0 = density / 12.0 * np.sum(cross * (np.sum(a * a, axis=1) + np.sum(a * b, axis=1) + np.sum(b * b, axis=1)))
    mass = density * abs(area)
    return float(mass), center, float(abs(i0) - mass * center @ center)


# ------------------------------------------------------------------------ state and motion, any dimension
def initial_state(bodies):
    """The :class:`RigidState` at time 0 of the declared ``bodies``: 3D if they are triangle meshes, 2D
    (polylines, or no body) otherwise; the state's ``mechanics`` are that dimension's from then on."""
    mechanics = dynamics3d if bodies and not isinstance(bodies[0].shape, Polyline) else dynamics2d
    return RigidState(**mechanics.initial_arrays(bodies))


def current_shapes(bodies, state):
    """Every body's shape (polyline or triangle mesh) where the state puts it (``posed_shape``)."""
    return [state.mechanics.posed_shape(b, state.position[r], state.angle[r]) for r, b in enumerate(bodies)]


def begin_step(bodies, state, time, dt):
    """The state with each scripted body's velocity over the step ``[time, time + dt]`` (finite difference of
    its script; :func:`mpmref.rigid.dynamics2d.begin_step`, :func:`~.dynamics3d.begin_step`)."""
    return state.mechanics.begin_step(bodies, state, time, dt)


def point_velocity(state, body_ids, x):
    r"""Velocity :math:`\mathbf v_r + \boldsymbol\omega_r \times (\mathbf x - \mathbf c_r)` of body ``body_ids``
    at ``x`` (..., d) (in 2D :math:`\boldsymbol\omega_r = \omega_r\hat{\mathbf z}`)."""
    return state.mechanics.point_velocity(state, body_ids, x)


def body_impulses(state, body_ids, x, impulse):
    r"""Impulses :math:`\mathbf J` applied at points ``x`` to bodies ``body_ids``, summed per body: ``(J, L)``,
    :math:`\mathbf J_r = \sum \mathbf J` and :math:`\mathbf L_r = \sum (\mathbf x - \mathbf c_r)\times\mathbf J`
    about each body's reference point (docs/cpic.md, "after all particles")."""
    return state.mechanics.body_impulses(len(state.angle), body_ids, x, impulse, state.position)


def apply_impulses(bodies, state, J, L):
    r"""Record impulses ``J`` and angular impulses ``L`` and change the dynamic bodies' velocities,
    :math:`\mathbf v_r \mathrel{+}= \mathbf J_r / M_r`, :math:`\boldsymbol\omega_r \mathrel{+}= I_r^{-1}\mathbf L_r`
    (docs/cpic.md; :func:`mpmref.rigid.dynamics2d.apply_impulses`, :func:`~.dynamics3d.apply_impulses`)."""
    return state.mechanics.apply_impulses(bodies, state, J, L)


def end_step(bodies, state, time, dt, gravity):
    """Move every body to ``time + dt`` (docs/cpic.md, the rigid step after G2P;
    :func:`mpmref.rigid.dynamics2d.end_step`, :func:`~.dynamics3d.end_step`)."""
    return state.mechanics.end_step(bodies, state, time, dt, gravity)


def diagnostics(bodies, state):
    """Per body ``r``: ``rigid{r}_`` pose, velocity, angular velocity and impulses received, then the dynamic
    bodies' linear momentum ``rigid_momentum_x``, ``_y`` (and ``_z``) (a dict)."""
    p = momentum(bodies, state)
    return state.mechanics.diagnostics(bodies, state) | {f"rigid_momentum_{a}": v for a, v in zip("xyz", p)}




def mechanical_energy(bodies, state, gravity):
    r"""Kinetic plus gravitational energy of each body (nb,): the dimension's ``kinetic_energy`` and
    :math:`-M_r\, \mathbf g \cdot \mathbf c_r` for a dynamic body that feels gravity and is not pinned
    (:math:`\mathbf c_r` its centre of mass, :math:`\mathbf g` gravity); zero for fixed and scripted bodies."""
    falls = np.array([b.motion == "dynamic" and b.gravity and not b.pinned for b in bodies])
    mass = np.array([b.mass if f else 0.0 for b, f in zip(bodies, falls)])
    return (state.mechanics.kinetic_energy(bodies, state)
            - mass * (state.position @ np.asarray(gravity, dtype=np.float64)))


def momentum(bodies, state):
    """Linear momentum :math:`\\sum_r M_r \\mathbf v_r` of the dynamic bodies (finite mass), shape (2,)."""
    return sum((b.mass * state.velocity[r] for r, b in enumerate(bodies) if b.motion == "dynamic"),
               np.zeros(state.velocity.shape[1]))



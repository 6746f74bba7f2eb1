r"""Conformance of the CPIC stages (2D and 3D): the colored distance field, the tagging and reconstruction, P2G and
G2P with bodies, and whole coupled steps.

A backend provides CPIC through its methods ``cpic_contact``, ``p2g(particles, prepared, contact)``,
``cpic_impulses`` and ``cpic_g2p`` (:mod:`mpmref.backends.numpy.cpic`). Because the contact object between
them is the backend's own, each conformance stage runs a backend from flat inputs to flat outputs:

* ``cpic_field``: the bodies' state ``rigid_*`` -> the field on every node: ``cdf_d`` (the unsigned distance
  to the nearest body, 0 where no body is near), ``cdf_body`` (its id, -1 if none), ``cdf_A`` and ``cdf_T``
  (N, nb) affinity and side bits;
* ``cpic_tags``: particles with their previous tags ``tag_A``, ``tag_T`` (n, nb) and the bodies -> new tags,
  ``phi``, ``normal``, ``near`` and ``compatible`` (K, n): node ``base + offset_k`` of the transfer stencil is
  compatible with the particle (offsets in C order over the stencil); with the per-body fit also ``fit_phi``,
  ``fit_normal``, ``fit_near`` (n, nb): each body's fit of the particles tagged by several bodies;
* ``cpic_p2g``: the same inputs and ``dt`` -> ``grid_mass``, ``grid_momentum``, ``grid_force``, the rejected
  momentum and force of incompatible nodes ``grid_rejected_momentum``, ``grid_rejected_force`` (N, 2), and the
  impulses they give the bodies ``impulse_J`` (nb, 2), ``impulse_L`` (nb,);
* ``cpic_g2p``: the same inputs and the grid velocity ``grid_v`` -> the evolving particle fields and the
  penalty's impulses ``penalty_J``, ``penalty_L`` (the bodies seen by G2P are ``rigid_*``);
* ``cpic_step``: the same inputs and ``time`` -> one coupled step (:func:`mpmref.steppers.pipeline.substep`):
  the evolving particle fields, the tags, ``phi``, ``normal``, ``near`` and the bodies' new state ``rigid_*``.

The bodies' state is flat too: ``rigid_position`` (nb, 2), ``rigid_angle``, ``rigid_velocity``,
``rigid_angular_velocity``, ``rigid_impulse``, ``rigid_angular_impulse`` (the fields of
:class:`~mpmref.rigid.dynamics.RigidState`). Booleans are compared as 0/1.

The scene is the conformance box (8 × 8 cells) with three bodies crossing it: a dynamic open polyline (a
"V"), a scripted closed triangle that turns, and a fixed segment; each side has its own contact type
(separate with friction, slip, sticky). The state: particles of :func:`~.cases.random_particles`, each
body's previous tag set with probability 1/2 on a random side (so that some particles have "penetrated",
with :math:`\phi_p < 0`, and the penalty acts), the bodies moved and turned a little from where they were
declared and given random velocities. Source of the equations: Hu et al. 2018 §4–5, docs/cpic.md.

In 3D (:data:`BODIES_3D`, the conformance box of 8³ cells) the bodies are triangle meshes of the same three
kinds: a dynamic open "V" sheet of four triangles, a scripted closed tetrahedron turning about an oblique axis,
and a fixed, slightly warped vertical quadrilateral; vectors have 3 components, ``rigid_angle`` is the
orientation quaternion (nb, 4) and ``rigid_angular_velocity``, ``rigid_angular_impulse``, ``impulse_L``,
``penalty_L`` are (nb, 3) (:mod:`mpmref.rigid.dynamics3d`).
"""

from dataclasses import fields

import numpy as np

from ..rigid.dynamics import RigidState
from ..rigid.dynamics3d import quaternion_from_rotation_vector
from ..state import CPIC_FIELDS
from .stages import particle_outputs, particles_from, with_running

#: the fields of the bodies' state (:class:`~mpmref.rigid.dynamics.RigidState`), flat as ``rigid_<field>``
RIGID_STATE_FIELDS = tuple(f.name for f in fields(RigidState) if f.init)

#: the bodies of every CPIC case (unit box, 8 cells): a dynamic "V", a scripted turning triangle, a fixed segment
BODIES = (
    {"vertices": [[0.26, 0.62], [0.5, 0.41], [0.74, 0.63]], "segments": [[0, 1], [1, 2]], "motion": "dynamic",
     "density": 2.0, "type": ["separate", "slip"], "friction": [0.3, 0.2]},
    {"vertices": [[0.44, 0.3], [0.62, 0.33], [0.52, 0.45]], "segments": [[0, 1], [1, 2], [2, 0]], "closed": True,
     "motion": "scripted", "velocity": [0.2, -0.1], "angular_velocity": 1.5, "type": "sticky"},
    {"vertices": [[0.3, 0.28], [0.37, 0.7]], "segments": [[0, 1]], "type": ["separate", "sticky"], "friction": 0.0},
)
#: the 3D bodies of every 3D CPIC case (unit box, 8³ cells): a dynamic open "V" sheet, a scripted closed
#: tetrahedron that turns about an oblique axis, a fixed warped quadrilateral
BODIES_3D = (
    {"vertices": [[0.25, 0.62, 0.3], [0.5, 0.42, 0.3], [0.75, 0.63, 0.3], [0.25, 0.6, 0.72], [0.5, 0.41, 0.7],
                  [0.74, 0.62, 0.71]], "triangles": [[0, 1, 4], [0, 4, 3], [1, 2, 5], [1, 5, 4]],
     "motion": "dynamic", "density": 2.0, "type": ["separate", "slip"], "friction": [0.3, 0.2]},
    {"vertices": [[0.42, 0.25, 0.42], [0.62, 0.27, 0.45], [0.5, 0.26, 0.62], [0.52, 0.42, 0.5]],
     "triangles": [[0, 1, 2], [0, 3, 1], [1, 3, 2], [2, 3, 0]], "closed": True, "motion": "scripted",
     "velocity": [0.2, -0.1, 0.1], "angular_velocity": [0.5, 1.5, -0.7], "type": "sticky"},
    {"vertices": [[0.33, 0.28, 0.3], [0.35, 0.28, 0.7], [0.36, 0.7, 0.68], [0.32, 0.7, 0.31]],
     "triangles": [[0, 1, 2], [0, 2, 3]], "type": ["separate", "sticky"], "friction": 0.0},
)
#: CPIC's options in the cases: a pushing force and a penalty large enough to matter in one step
COUPLING = {"coupling": "cpic", "pushing_force": 2.0e4, "penalty": 1.0e3}


def cpic_scene_dict(scene_dict, method):
    """``scene_dict`` (from :func:`~.cases.scene_dict`) with the CPIC bodies and ``method`` plus :data:`COUPLING`."""
    coupling = {**COUPLING, **({"pushing_force": 0.0} if method.get("momentum_exact") else {})}
    bodies = BODIES_3D if scene_dict["dim"] == 3 else BODIES
    return {**scene_dict, "method": {**scene_dict["method"], **coupling, **method},
            "rigid_bodies": [dict(b) for b in bodies]}


def random_cpic_state(scene, rng, flat, scales=None):
    r"""Add previous tags and a random state of the bodies to the particle state ``flat`` (in place): poses near the
    declared ones (positions within N(0, (0.08 Δx)²) per axis, angles N(0, 0.05²)), velocities N(0, s²) and angular
    velocities N(0, (2 s / 8 Δx)²) (zero for a fixed body), with :math:`s` the speed of ``scales`` (default
    :func:`~.states.catalogue_scales`, 1 on the unit box of 8 cells); in 3D the orientation is the quaternion of a
    rotation vector N(0, 0.05²) per axis."""
    from .states import catalogue_scales

    speed = (scales or catalogue_scales(scene)).speed
    dx = scene.grid.dx
    n, nb = len(flat["x"]), len(scene.rigid_bodies)
    flat["tag_A"] = rng.random((n, nb)) < 0.5
    flat["tag_T"] = flat["tag_A"] & (rng.random((n, nb)) < 0.5)
    center = np.array([b.center for b in scene.rigid_bodies])
    moving = np.array([b.motion != "fixed" for b in scene.rigid_bodies])
    spin = 2.0 * speed / (8.0 * dx)
    if scene.dim == 3:
        return _random_state_3d(flat, rng, center, moving, 0.08 * dx, speed, spin)
    flat.update({"rigid_position": center + 0.08 * dx * rng.standard_normal((nb, 2)),
                 "rigid_angle": 0.05 * rng.standard_normal(nb),
                 "rigid_velocity": speed * rng.standard_normal((nb, 2)) * moving[:, None],
                 "rigid_angular_velocity": spin * rng.standard_normal(nb) * moving,
                 "rigid_impulse": np.zeros((nb, 2)), "rigid_angular_impulse": np.zeros(nb)})
    return flat


def _random_state_3d(flat, rng, center, moving, shift, speed, spin):
    """The bodies' part of :func:`random_cpic_state` in 3D."""
    nb = len(center)
    flat.update({"rigid_position": center + shift * rng.standard_normal((nb, 3)),
                 "rigid_angle": quaternion_from_rotation_vector(0.05 * rng.standard_normal((nb, 3))),
                 "rigid_velocity": speed * rng.standard_normal((nb, 3)) * moving[:, None],
                 "rigid_angular_velocity": spin * rng.standard_normal((nb, 3)) * moving[:, None],
                 "rigid_impulse": np.zeros((nb, 3)), "rigid_angular_impulse": np.zeros((nb, 3))})
    return flat


def rigid_from(flat):
    return RigidState(**{k: np.array(flat[f"rigid_{k}"]) for k in RIGID_STATE_FIELDS})


def rigid_outputs(rigid):
    return {f"rigid_{k}": getattr(rigid, k) for k in RIGID_STATE_FIELDS}


def cpic_particles(flat):
    """The particles of ``flat`` with their previous tags (distance, normal and ``near`` start at zero)."""
    n, d = flat["x"].shape
    return particles_from(flat).with_(tag_A=np.array(flat["tag_A"]), tag_T=np.array(flat["tag_T"]), phi=np.zeros(n),
                                      normal=np.zeros((n, d)), near=np.zeros(n, dtype=bool))


def _contact(backend, flat):
    particles = cpic_particles(flat)
    prepared = backend.prepare(particles)
    particles, contact = backend.cpic_contact(particles, prepared, rigid_from(flat), float(flat["dt"]))
    return particles, prepared, contact


def field_stage(backend, flat):
    _, _, contact = _contact(backend, flat)
    cdf = contact.cdf
    return {"cdf_d": np.where(cdf.body >= 0, cdf.d, 0.0), "cdf_body": cdf.body, "cdf_A": cdf.A, "cdf_T": cdf.T}


def tags_stage(backend, flat):
    particles, _, contact = _contact(backend, flat)
    fit = contact.per_body_fit
    per_body = {} if fit is None else {"fit_phi": fit[0], "fit_normal": fit[1], "fit_near": fit[2]}
    return {**{k: getattr(particles, k) for k in CPIC_FIELDS}, "compatible": contact.compatible, **per_body}


def p2g_stage(backend, flat):
    particles, prepared, contact = _contact(backend, flat)
    gs = backend.p2g(particles, prepared, contact)
    J, L = backend.cpic_impulses(gs, contact, rigid_from(flat), float(flat["dt"]))
    return {"grid_mass": gs.mass, "grid_momentum": gs.momentum, "grid_force": gs.force,
            "grid_rejected_momentum": gs.rejected_momentum, "grid_rejected_force": gs.rejected_force,
            "impulse_J": J, "impulse_L": L}


def g2p_stage(backend, flat):
    particles, prepared, contact = _contact(backend, flat)
    new, (J, L) = backend.cpic_g2p(particles, np.array(flat["grid_v"]), float(flat["dt"]), prepared, contact,
                                   rigid_from(flat))
    return {**particle_outputs(new), "penalty_J": J, "penalty_L": L}


def step_stage(backend, flat):
    from ..steppers.pipeline import substep

    new, rigid = substep(with_running(backend), cpic_particles(flat), float(flat["dt"]), float(flat["time"]),
                         rigid=rigid_from(flat))
    return {**particle_outputs(new), **{k: getattr(new, k) for k in CPIC_FIELDS}, **rigid_outputs(rigid)}


#: each CPIC stage as ``runner(backend, flat) -> flat outputs``
RUNNERS = {"cpic_field": field_stage, "cpic_tags": tags_stage, "cpic_p2g": p2g_stage, "cpic_g2p": g2p_stage,
           "cpic_step": step_stage}
#: the backend methods the CPIC stages need
CPIC_METHODS = ("prepare", "cpic_contact", "p2g", "cpic_impulses", "cpic_g2p")


def has_cpic(backend):
    """Whether ``backend`` has the methods of the CPIC stages."""
    return all(callable(getattr(backend, m, None)) for m in CPIC_METHODS)


def reference_grid_velocity(scene, flat):
    """``grid_v`` of the reference's CPIC P2G and grid update of the state ``flat``."""
    from ..backends import make_backend

    backend = make_backend("numpy", scene)
    particles, prepared, contact = _contact(backend, flat)
    v, _ = backend.grid_update(backend.p2g(particles, prepared, contact), float(flat["dt"]), float(flat["time"]))
    return v

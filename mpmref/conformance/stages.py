"""The six stages a backend exposes, the energy ledger of a step and the stages asynchronous stepping adds, with their
inputs and outputs as flat dicts of named arrays.

A flat dict (``{"x": ..., "grid_mass": ..., "dt": ...}``) is the one form of a case's data: ``check``
turns it into :class:`~mpmref.state.Particles` / :class:`~mpmref.state.GridState` to call a stage, and
``export`` writes it as the ``in_`` / ``out_`` arrays of a ``.npz`` file. Names:

* particles: ``x (n,d)``, ``v (n,d)``, ``mass (n,)``, ``vol0 (n,)``, ``material (n,) int32`` and, where the
  scene needs them, ``C (n,d,d)``, ``F (n,d,d)``, ``J (n,)``, ``Jp (n,)``, ``modes (n,M,d)``;
* grid nodes (C order, see :mod:`mpmref.conformance`): ``grid_mass (N,)``, ``grid_momentum (N,d)``,
  ``grid_force (N,d)``, ``grid_momentum_after_force (N,d)`` (the fused P2G's (mv)_i + Δt f_i),
  ``grid_v (N,d)``, ``grid_v_tilde (N,d)``;
* the return map's second output ``wave_speed (n,)`` (float64): each particle's wave speed in its new state, where the
  backend gives it (:func:`mpmref.backends.base.gives_wave_speeds`; :func:`optional_outputs`);
* scalars (0-d arrays): ``dt``, ``time``; the stress stage's output ``tau (n,d,d)``, which is also an input of the
  P2G cases, fused or not (for a P2G that takes the stress, :func:`takes_stress`);
* the stages of asynchronous stepping (:mod:`mpmref.physics.interface`): ``idx (m,) int64`` and the output
  ``wave_speed (m,)`` of ``wave_speeds``; the particle ``classes (n,) int64`` (0 active, 1 finer ghost, 2 coarser
  shadow), each class's node sums ``class_sums (K, N, 1 + 2d)`` (mass, momentum, force), ``kappa`` (0-d), the node
  kicks ``kicks (2, N, d)`` and each particle's impulse and its moment about the origin, ``impulse_P (n, d)`` and
  ``impulse_L (n, 1)`` in 2D or ``(n, 3)`` in 3D;
* the ledger stage's outputs (0-d, float64): ``ledger_<column>`` for each column of
  :data:`mpmref.observe.ledger.COLUMNS` (the terms, flows, energy change and closure of one step, docs/energy_ledger.md)
  and ``energy_scale`` (:func:`mpmref.observe.ledger.energy_scale` of the input state, the denominator of the terms'
  errors).
"""

import inspect
from contextlib import nullcontext

import numpy as np

from ..observe.ledger import COLUMNS, EnergyLedger
from ..state import EVOLVING_FIELDS, GridState, Particles, fields_with_role

CONFORMANCE_STAGES = ("stress", "return_map", "p2g", "p2g_fused", "grid_update", "g2p", "step", "ledger")
#: the stages asynchronous stepping adds (:mod:`mpmref.steppers.asynchronous`): the particles' wave speeds (the
#: blocks' step limits), P2G by particle classes, the node kicks of conservative interfaces, and G2P gathering them
ASYNC_CONFORMANCE_STAGES = ("wave_speeds", "p2g_classes", "interface_kicks", "g2p_kicks")
#: the stages of backends that couple rigid bodies by CPIC (run through :mod:`mpmref.conformance.cpic`)
CPIC_CONFORMANCE_STAGES = ("cpic_field", "cpic_tags", "cpic_p2g", "cpic_g2p", "cpic_step")
#: the stages every backend has (the six of a step, and the step's energy ledger), then those of asynchronous
#: stepping, then the CPIC stages of backends that couple rigid bodies (:mod:`mpmref.conformance.cpic`)
ALL_CONFORMANCE_STAGES = CONFORMANCE_STAGES + ASYNC_CONFORMANCE_STAGES + CPIC_CONFORMANCE_STAGES
#: the optional stages: a backend that lacks them still runs every scene (the steppers use ``p2g_fused`` where a
#: backend has it)
OPTIONAL_STAGES = ("p2g_fused",)
#: the backend method each stage of asynchronous stepping calls (the others call the method of their own name)
STAGE_METHODS = {"p2g_classes": "p2g", "g2p_kicks": "g2p"}
#: the stages of every backend that take a time step ``dt``, and those that take the ``time`` (where the colliders
#: are); of the stages of asynchronous stepping, ``interface_kicks`` and ``g2p_kicks`` take ``dt``, and every CPIC
#: stage takes both
STAGES_WITH_DT = ("p2g_fused", "grid_update", "g2p", "step", "ledger")
STAGES_WITH_TIME = ("grid_update", "step", "ledger")
#: the outputs of the ledger stage: one step's ledger columns, then the energy scale of its input state
LEDGER_OUTPUTS = (*(f"ledger_{c}" for c in COLUMNS), "energy_scale")
#: the particle fields of a case's flat dicts: the evolving and the constant ones (:data:`mpmref.state.ROLES`); the
#: evolving ones are those a stage may change, the outputs of ``return_map``, ``g2p`` and ``step``
CASE_PARTICLE_FIELDS = fields_with_role("evolving", "constant")


def particles_from(flat):
    """A fresh :class:`~mpmref.state.Particles` (copied arrays) from the particle entries of ``flat``."""
    return Particles(**{k: np.array(flat[k]) for k in CASE_PARTICLE_FIELDS if k in flat})


def particle_outputs(particles):
    """The evolving fields of ``particles`` that are allocated, as a flat dict."""
    return {k: getattr(particles, k) for k in EVOLVING_FIELDS if getattr(particles, k) is not None}


def takes_wave_speed(fn):
    """Whether the return-map callable ``fn`` declares the optional output ``wave_speed``
    (:func:`mpmref.backends.base.gives_wave_speeds`)."""
    try:
        return "wave_speed" in inspect.signature(fn).parameters
    except (TypeError, ValueError):
        return False


def optional_outputs(stage, fn):
    """The outputs of ``stage`` that the stage callable ``fn`` does not give, by design: ``wave_speed`` of a return
    map without that optional output. The harness leaves them out of the comparison; every other output it
    compares."""
    return ("wave_speed",) if stage == "return_map" and not takes_wave_speed(fn) else ()


def _return_map(fn, flat):
    """``return_map(particles)``: the evolving fields after the projection and, where ``fn`` takes the optional output
    ``wave_speed`` (:func:`takes_wave_speed`), each particle's wave speed in its new state (float64)."""
    if not takes_wave_speed(fn):
        return _particle_stage(fn, flat)
    particles = particles_from(flat)
    speeds = np.full(particles.n, np.nan)
    return {**particle_outputs(fn(particles, wave_speed=speeds)), "wave_speed": speeds}


def _stress(fn, flat):
    return {"tau": fn(particles_from(flat))}


def _particle_stage(fn, flat):
    return particle_outputs(fn(particles_from(flat)))


def stage_method(stage):
    """The name of the backend method that ``stage`` calls (``p2g`` for ``p2g_classes``, ``g2p`` for ``g2p_kicks``)."""
    return STAGE_METHODS.get(stage, stage)


def _given_stress(fn, flat):
    """``{"stress": tau}`` for a P2G with a ``stress`` argument, given the reference's Kirchhoff stress ``tau`` of the
    inputs, so that a code can check its transfer without every constitutive model (docs/conformance.md); else
    ``{}``."""
    return {"stress": np.array(flat["tau"])} if "tau" in flat and takes_stress(fn) else {}


def _p2g(fn, flat):
    """P2G of the particles (given the stress if it takes it, :func:`_given_stress`)."""
    gs = fn(particles_from(flat), **_given_stress(fn, flat))
    return {"grid_mass": gs.mass, "grid_momentum": gs.momentum, "grid_force": gs.force}


def takes_stress(fn):
    """Whether the P2G callable ``fn`` declares a parameter named ``stress``."""
    try:
        return "stress" in inspect.signature(fn).parameters
    except (TypeError, ValueError):
        return False


def _p2g_fused(fn, flat):
    """P2G with the force folded in: node mass and the momentum after the force, ``grid_momentum_after_force``
    (given the stress if it takes it, :func:`_given_stress`)."""
    gs = fn(particles_from(flat), float(flat["dt"]), **_given_stress(fn, flat))
    return {"grid_mass": gs.mass, "grid_momentum_after_force": gs.momentum}


def unfused_then_force(backend):
    r"""The truth of the ``p2g_fused`` stage: ``backend``'s (unfused) P2G, then :math:`(mv)_i + \Delta t f_i` from its
    momentum and force, as a callable ``(particles, dt) -> GridState`` with ``force = None``."""
    def p2g_fused(particles, dt):
        gs = backend.p2g(particles)
        return GridState(mass=gs.mass, momentum=gs.momentum + dt * gs.force)

    return p2g_fused


def _grid_update(fn, flat):
    gs = GridState(mass=np.array(flat["grid_mass"]), momentum=np.array(flat["grid_momentum"]),
                   force=np.array(flat["grid_force"]))
    v, v_tilde = fn(gs, float(flat["dt"]), float(flat["time"]))
    return {"grid_v": v, "grid_v_tilde": v_tilde}


def _g2p(fn, flat):
    p = fn(particles_from(flat), np.array(flat["grid_v"]), np.array(flat["grid_v_tilde"]), float(flat["dt"]))
    return particle_outputs(p)


def _step(fn, flat):
    """One step, or ``steps`` steps (a multi-step case, :data:`mpmref.conformance.extremes.FROM_REST_STEPS`), each at
    its own time."""
    particles, dt, time = particles_from(flat), float(flat["dt"]), float(flat["time"])
    for k in range(int(flat.get("steps", 1))):
        particles = fn(particles, dt, time + k * dt)
    return particle_outputs(particles)


def _ledger(fn, flat):
    return {k: np.asarray(v, dtype=np.float64) for k, v in fn(particles_from(flat), float(flat["dt"]),
                                                            float(flat["time"])).items()}


def _flat_stage(fn, flat):
    return fn(flat)


def _wave_speeds(fn, flat):
    """``wave_speeds(particles, idx)``: the P-wave speed of the particles ``idx`` (float64)."""
    return {"wave_speed": np.asarray(fn(particles_from(flat), np.array(flat["idx"])), dtype=np.float64)}


def _p2g_classes(fn, flat):
    """``p2g(particles, classes=classes)``: each class's node sums ``class_sums`` and their totals (given the stress if
    it takes it, :func:`_given_stress`)."""
    gs = fn(particles_from(flat), classes=np.array(flat["classes"]), **_given_stress(fn, flat))
    return {"grid_mass": gs.mass, "grid_momentum": gs.momentum, "grid_force": gs.force, "class_sums": gs.class_sums}


def _interface_kicks(fn, flat):
    """``interface_kicks(grid_state, dt, kappa)`` of a P2G by classes: the node kicks (2, N, d)."""
    gs = GridState(mass=np.array(flat["grid_mass"]), momentum=np.array(flat["grid_momentum"]),
                   force=np.array(flat["grid_force"]), class_sums=np.array(flat["class_sums"]))
    return {"kicks": fn(gs, float(flat["dt"]), float(flat["kappa"]))}


def _g2p_kicks(fn, flat):
    """``g2p(particles, v, v_tilde, dt, kicks=(classes, kicks))``: the particles and each one's impulse and moment."""
    new, (impulse, moment) = fn(particles_from(flat), np.array(flat["grid_v"]), np.array(flat["grid_v_tilde"]),
                                float(flat["dt"]), kicks=(np.array(flat["classes"]), np.array(flat["kicks"])))
    return {**particle_outputs(new), "impulse_P": impulse, "impulse_L": moment}


_CALLERS = {"stress": _stress, "return_map": _return_map, "p2g": _p2g, "p2g_fused": _p2g_fused,
            "grid_update": _grid_update, "g2p": _g2p, "step": _step, "ledger": _ledger,
            "wave_speeds": _wave_speeds, "p2g_classes": _p2g_classes, "interface_kicks": _interface_kicks,
            "g2p_kicks": _g2p_kicks, **{stage: _flat_stage for stage in CPIC_CONFORMANCE_STAGES}}


def composed_step(stages, particles, dt, time):
    """A whole step of an object with the six backend stages: the steppers' one pipeline over them.

    Objects without a ``running`` context (see :mod:`mpmref.backends.base`) run their stages as they are.
    """
    from ..steppers.pipeline import substep

    return substep(with_running(stages), particles, dt, time)


def ledger_step(stages, particles, dt, time, rigid=None):
    """The energy ledger of one step of an object with the six backend stages (the pipeline over them, observed by a
    fresh :class:`~mpmref.observe.ledger.EnergyLedger` of ``stages.scene``), as the ledger stage's outputs
    (:data:`LEDGER_OUTPUTS`: ``{"ledger_<column>": float, ..., "energy_scale": float}``). With rigid bodies,
    ``rigid`` is their state (:func:`mpmref.steppers.substep`)."""
    from ..steppers.pipeline import substep

    ledger = EnergyLedger(stages.scene)
    substep(with_running(stages), particles, dt, time, rigid=rigid, ledger=ledger)
    return {**{f"ledger_{c}": ledger.last[c] for c in COLUMNS}, "energy_scale": ledger.scale}


def with_running(stages):
    """``stages``, given the trivial ``running`` context if it has none."""
    return stages if callable(getattr(stages, "running", None)) else _WithRunning(stages)


class _WithRunning:
    """A stage object given the trivial ``running`` context."""

    def __init__(self, stages):
        self._stages = stages
        self.scene = getattr(stages, "scene", None)

    def __getattr__(self, name):
        return getattr(self._stages, name)

    @staticmethod
    def running(n_particles):
        return nullcontext()


def run_stage(stage, fn, flat):
    """Call the stage function ``fn`` on copies of the inputs ``flat``; return its outputs as a flat dict.

    ``fn`` has the backend signature of ``stage`` (see :mod:`mpmref.conformance`), or for a CPIC stage takes
    the flat inputs (:mod:`mpmref.conformance.cpic`); the inputs are copied, so a stage that writes into its arguments
    cannot change the case.
    """
    return _CALLERS[stage](fn, flat)

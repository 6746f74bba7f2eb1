"""The six stages a backend exposes and the energy ledger of a step, with their inputs and outputs as flat dicts
of named arrays.

A flat dict (``{"x": ..., "grid_mass": ..., "dt": ...}``) is the one form of a case's data: ``check``
turns it into :class:`~mpmref.state.Particles` / :class:`~mpmref.state.GridState` to call a stage, and
``export`` writes it as the ``in_`` / ``out_`` arrays of a ``.npz`` file. Names:

* particles: ``x (n,d)``, ``v (n,d)``, ``mass (n,)``, ``vol0 (n,)``, ``material (n,) int32`` and, where the
  scene needs them, ``C (n,d,d)``, ``F (n,d,d)``, ``J (n,)``, ``Jp (n,)``, ``modes (n,M,d)``;
* grid nodes (C order, see :mod:`mpmref.conformance`): ``grid_mass (N,)``, ``grid_momentum (N,d)``,
  ``grid_force (N,d)``, ``grid_momentum_after_force (N,d)`` (the fused P2G's (mv)_i + Δt f_i),
  ``grid_v (N,d)``, ``grid_v_tilde (N,d)``;
* scalars (0-d arrays): ``dt``, ``time``; the stress stage's output ``tau (n,d,d)``, which is also an input of the
  P2G cases (for a P2G that takes the stress, :func:`takes_stress`);
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
#: the stages of backends that couple rigid bodies by CPIC (run through :mod:`mpmref.conformance.cpic`)
CPIC_CONFORMANCE_STAGES = ("cpic_field", "cpic_tags", "cpic_p2g", "cpic_g2p", "cpic_step")
#: the stages every backend has (the six of a step, and the step's energy ledger), then the CPIC stages of backends
#: that couple rigid bodies (:mod:`mpmref.conformance.cpic`)
ALL_CONFORMANCE_STAGES = CONFORMANCE_STAGES + CPIC_CONFORMANCE_STAGES
#: the stages that take a time step ``dt``, and those that take the ``time`` (where the colliders are)
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


def _stress(fn, flat):
    return {"tau": fn(particles_from(flat))}


def _particle_stage(fn, flat):
    return particle_outputs(fn(particles_from(flat)))


def _p2g(fn, flat):
    """P2G of the particles; a P2G with a ``stress`` argument is given the reference's Kirchhoff stress ``tau`` of
    the inputs, so that a code can check its transfer without every constitutive model (docs/conformance.md)."""
    given = {"stress": np.array(flat["tau"])} if "tau" in flat and takes_stress(fn) else {}
    gs = fn(particles_from(flat), **given)
    return {"grid_mass": gs.mass, "grid_momentum": gs.momentum, "grid_force": gs.force}


def takes_stress(fn):
    """Whether the P2G callable ``fn`` declares a parameter named ``stress``."""
    try:
        return "stress" in inspect.signature(fn).parameters
    except (TypeError, ValueError):
        return False


def _p2g_fused(fn, flat):
    """P2G with the force folded in: node mass and the momentum after the force, ``grid_momentum_after_force``."""
    gs = fn(particles_from(flat), float(flat["dt"]))
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
    return particle_outputs(fn(particles_from(flat), float(flat["dt"]), float(flat["time"])))


def _ledger(fn, flat):
    return {k: np.asarray(v, dtype=np.float64) for k, v in fn(particles_from(flat), float(flat["dt"]),
                                                            float(flat["time"])).items()}


def _flat_stage(fn, flat):
    return fn(flat)


_CALLERS = {"stress": _stress, "return_map": _particle_stage, "p2g": _p2g, "p2g_fused": _p2g_fused,
            "grid_update": _grid_update, "g2p": _g2p, "step": _step, "ledger": _ledger,
            **{stage: _flat_stage for stage in CPIC_CONFORMANCE_STAGES}}


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

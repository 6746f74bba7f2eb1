"""Time steppers: they own the MPM step (:mod:`.pipeline`) and decide who advances, by how much, when.

* :class:`SynchronousStepper`: every particle, one Δt (fixed or CFL);
* :class:`AsynchronousStepper`: regional power-of-two steps per block (Fang et al. 2018).

Both fulfil :class:`Stepper` (:mod:`.protocol`), the contract the simulation and the command line use.
"""

from ..errors import MpmrefError
from ..observe.ledger import EnergyLedger, LevelLedger
from .asynchronous import AsynchronousStepper, AsyncInterval, AsyncSchedule, LevelUpdate, WorkRecord
from .pipeline import NO_HOOKS, Hooks, substep
from .protocol import Stepper
from .synchronous import SynchronousStepper

__all__ = ["AsyncInterval", "AsyncSchedule", "AsynchronousStepper", "Hooks", "LevelUpdate", "NO_HOOKS", "Stepper",
           "SynchronousStepper", "WorkRecord", "make_stepper", "substep"]


def make_stepper(scene, backend, hooks=None):
    """The stepper ``scene.time.stepping`` asks for, composing ``backend``'s stages; it books an energy ledger when
    ``[output] energy_ledger`` asks for it (:class:`mpmref.observe.ledger.EnergyLedger` for synchronous steps,
    :class:`mpmref.observe.ledger.LevelLedger` for asynchronous level updates)."""
    hooks = hooks or NO_HOOKS
    if scene.output.energy_ledger and hooks.body_force is not None:
        raise MpmrefError("the energy ledger has no term for a body force hook's work (it would book it as "
                          "integration error): run without the hook or without [output] energy_ledger")
    if scene.time.stepping == "async":
        ledger = LevelLedger(scene) if scene.output.energy_ledger else None
        return AsynchronousStepper(scene, backend, hooks, ledger)
    ledger = EnergyLedger(scene) if scene.output.energy_ledger else None
    return SynchronousStepper(scene, backend, hooks, ledger)

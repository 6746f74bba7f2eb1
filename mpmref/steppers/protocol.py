"""The stepper contract: what :class:`~mpmref.run.simulation.Simulation` and the command line use of a stepper.

A stepper owns the time stepping of a run: it composes the backend's stages through the one step,
:func:`~mpmref.steppers.pipeline.substep`, and decides who advances, by how much and when. Its state between steps
lives in :attr:`mpmref.state.State.stepper` (arrays, so that checkpoints carry it); what it measured of its own work
is its own business (the asynchronous stepper's :class:`~mpmref.steppers.asynchronous.WorkRecord`).

**A step** of a run is one call of :meth:`Stepper.advance`: from one synchronised time (every particle at the same
time) to the next. For synchronous stepping that is one Δt; for asynchronous stepping one interval, in which each
particle takes its own steps. **A particle step** is one particle advancing by one of its own steps: a synchronous
step makes one per particle; an asynchronous interval makes each particle's own updates (ghost updates, which
only feed their neighbours, are not particle steps). ``particle-steps/s`` in a run's summary counts these.
"""

from typing import Protocol, runtime_checkable


@runtime_checkable
class Stepper(Protocol):
    """What every stepper gives (:class:`~mpmref.steppers.SynchronousStepper`,
    :class:`~mpmref.steppers.AsynchronousStepper`)."""

    #: the ``time.stepping`` value that selects it
    name: str
    #: whether a step advances every particle by one Δt (then the first step's CFL warning and the per-step
    #: velocity bound of :mod:`mpmref.run.stability` apply)
    uniform_step: bool
    #: whether :meth:`warm_up` compiles anything
    compiles: bool

    def initial_state(self, particles):
        """The :class:`~mpmref.state.State` of a run starting from ``particles``."""

    def advance(self, state, dt=None, t_end=None):
        """The state one step later, not passing ``t_end``; ``dt`` only for a stepper with a uniform step."""

    def time_step(self, particles):
        """The next step's Δt from ``particles`` (``None`` when the stepper has no single Δt)."""

    def cfl_number(self, particles, dt):
        """The CFL number ``dt max_p(c_p + |v_p|) / dx`` of a step ``dt`` from ``particles``."""

    def updates(self, old, new):
        """The particle steps done between two states (the module docstring)."""

    def diagnostics(self, state):
        """The stepper's columns of ``diagnostics.csv`` at ``state``."""

    def summary(self, state):
        """The stepper's figures for a run's summary."""

    def warm_up(self, particles):
        """Compile what the stepper compiles for these particles' fields; ``particles`` is not modified."""

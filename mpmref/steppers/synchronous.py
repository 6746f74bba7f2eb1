"""Synchronous stepping: every particle advances with the same Δt (fixed, or from a CFL number)."""

from dataclasses import replace

import numpy as np

from ..observe.ledger import accumulate, ledger_columns
from ..rigid import dynamics as rigid_dynamics
from ..state import State
from .limits import cfl_time_step, signal_speeds
from .pipeline import NO_HOOKS, substep


class SynchronousStepper:
    """A :class:`~mpmref.steppers.Stepper` that chooses one Δt for the whole domain and applies
    :func:`~.pipeline.substep` to every particle.

    The clock counts one tick per step; ``tick_length`` is the fixed Δt (``None`` with a CFL step). With a
    ``ledger`` (:class:`~mpmref.observe.ledger.EnergyLedger`) every step is booked by it, and the cumulative ledger is
    kept in the state (``stepper["energy_ledger"]``, so checkpoints carry it).
    """

    name = "sync"
    uniform_step = True
    compiles = False

    def __init__(self, scene, backend, hooks=NO_HOOKS, ledger=None):
        self.scene, self.backend, self.hooks, self.ledger = scene, backend, hooks, ledger

    def initial_state(self, particles):
        bodies = self.scene.rigid_bodies
        if not bodies:
            return State(particles=particles, tick_length=self.scene.time.dt)
        return State(particles=with_cpic_tags(particles, len(bodies)), tick_length=self.scene.time.dt,
                     rigid=rigid_dynamics.initial_state(bodies))

    def time_step(self, particles):
        t = self.scene.time
        if t.dt is not None:
            return t.dt
        return cfl_time_step(t.cfl, self.scene.grid.dx, signal_speeds(self.scene.material_list, particles))

    def cfl_number(self, particles, dt):
        """The CFL number ``dt max_p(c_p + |v_p|) / dx`` of a step of size ``dt`` from ``particles``."""
        speed = signal_speeds(self.scene.material_list, particles)
        return dt * float(speed.max(initial=0.0)) / self.scene.grid.dx

    def advance(self, state, dt=None, t_end=None):
        """The state one step later (``dt``: default the scene's; shortened so as not to pass ``t_end``)."""
        if dt is None:
            dt = self.time_step(state.particles)
            if t_end is not None:
                dt = min(dt, t_end - state.time)
        rigid = state.rigid
        if rigid is None:
            particles = substep(self.backend, state.particles, dt, state.time, self.hooks, ledger=self.ledger)
        else:
            particles, rigid = substep(self.backend, state.particles, dt, state.time, self.hooks, rigid, self.ledger)
        stepper = state.stepper
        if self.ledger is not None:
            stepper = {**stepper, "energy_ledger": accumulate(stepper.get("energy_ledger"), self.ledger.last)}
        return replace(state, particles=particles, step=state.step + 1, time=state.time + dt, tick=state.tick + 1,
                       rigid=rigid, stepper=stepper)

    def updates(self, old, new):
        """Particle updates made between two states: every particle once per step."""
        return old.particles.n * (new.step - old.step)

    def diagnostics(self, state):
        """Stepper columns of ``diagnostics.csv``: the rigid bodies' (none without bodies) and, with a ledger, the
        cumulative energy ledger's (``ledger_<term>``, :func:`mpmref.observe.ledger.ledger_columns`)."""
        out = {} if state.rigid is None else rigid_dynamics.diagnostics(self.scene.rigid_bodies, state.rigid)
        if self.ledger is not None:
            out |= ledger_columns(state.stepper.get("energy_ledger"))
        return out

    def summary(self, state):
        """Stepper figures for the run summary (none for synchronous stepping)."""
        return {}

    def warm_up(self, particles):
        """Nothing to compile: the backend's stages are all a synchronous step runs."""


def with_cpic_tags(particles, n_bodies):
    """``particles`` with CPIC's per-particle state allocated where it is missing (no tags, not near)."""
    if particles.tag_A is not None:
        return particles
    n, d = particles.x.shape
    return particles.with_(tag_A=np.zeros((n, n_bodies), dtype=bool), tag_T=np.zeros((n, n_bodies), dtype=bool),
                           phi=np.zeros(n), normal=np.zeros((n, d)), near=np.zeros(n, dtype=bool))

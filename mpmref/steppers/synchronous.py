"""Synchronous stepping: every particle advances with the same Δt (fixed, or from a CFL number)."""

from dataclasses import replace

from ..state import State
from .limits import cfl_time_step, signal_speeds
from .pipeline import NO_HOOKS, substep


class SynchronousStepper:
    """Chooses one Δt for the whole domain and applies :func:`~.pipeline.substep` to every particle.

    The clock counts one tick per step; ``tick_length`` is the fixed Δt (``None`` with a CFL step).
    """

    name = "sync"

    def __init__(self, scene, backend, hooks=NO_HOOKS):
        self.scene, self.backend, self.hooks = scene, backend, hooks

    def initial_state(self, particles):
        return State(particles=particles, tick_length=self.scene.time.dt)

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
        particles = substep(self.backend, state.particles, dt, state.time, self.hooks)
        return replace(state, particles=particles, step=state.step + 1, time=state.time + dt, tick=state.tick + 1)

    def updates(self, old, new):
        """Particle updates made between two states: every particle once per step."""
        return old.particles.n * (new.step - old.step)

    def diagnostics(self, state):
        """Stepper columns of ``diagnostics.csv`` (none for synchronous stepping)."""
        return {}

    def summary(self, state):
        """Stepper figures for the run summary (none for synchronous stepping)."""
        return {}

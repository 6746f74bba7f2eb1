"""Synchronous stepping: every particle advances with the same Δt (fixed, or from a CFL number)."""

import numpy as np


def cfl_time_step(cfl, dx, wave_speed, v_max):
    r"""CFL time step :math:`\Delta t = C\,\Delta x / (c + |v|_{max})`.

    :math:`C` is the CFL number, :math:`c` the largest material wave speed (elastic P-wave or fluid sound
    speed), :math:`|v|_{max}` the largest particle speed (Courant, Friedrichs & Lewy 1928; its use for MPM time steps: Fang et al. 2018 §3).
    """
    return cfl * dx / (wave_speed + v_max)


class SynchronousStepper:
    """Chooses Δt for the whole domain and applies one backend step (symplectic Euler)."""

    def __init__(self, scene, backend):
        self.scene, self.backend = scene, backend
        self.wave_speed = scene.max_wave_speed()

    def max_speed(self, particles):
        return float(np.sqrt(np.max(np.sum(particles.v.astype(np.float64) ** 2, axis=1), initial=0.0)))

    def time_step(self, particles):
        t = self.scene.time
        if t.dt is not None:
            return t.dt
        return cfl_time_step(t.cfl, self.scene.grid.dx, self.wave_speed, self.max_speed(particles))

    def cfl_number(self, particles, dt):
        """The CFL number ``dt (c + |v|max) / dx`` of a step of size ``dt`` from ``particles``."""
        return dt * (self.wave_speed + self.max_speed(particles)) / self.scene.grid.dx

    def advance(self, particles, dt, time):
        return self.backend.step(particles, dt, time)

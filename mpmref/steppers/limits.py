r"""Step-size limits shared by the steppers: per-particle signal speed and the CFL rule."""

import numpy as np

from ..physics.materials import material_groups, wave_speed_of


def particle_speeds(particles):
    """:math:`|v_p|` of each particle, in float64."""
    return np.sqrt(np.sum(particles.v.astype(np.float64) ** 2, axis=1))


def wave_speeds(materials, particles):
    r"""Current wave speed :math:`c_p` of each particle from its material and state (float64)."""
    c = np.zeros(particles.n)
    for material, idx in material_groups(materials, particles):
        c[idx] = wave_speed_of(material, particles, idx)
    return c


def signal_speeds(materials, particles):
    r""":math:`c_p + |v_p|` per particle: how fast information leaves particle :math:`p`."""
    return wave_speeds(materials, particles) + particle_speeds(particles)


def cfl_time_step(cfl, dx, signal_speed):
    r"""CFL time step :math:`\Delta t = C\,\Delta x / \max_p (c_p + |v_p|)`.

    :math:`C` is the CFL number, :math:`c_p` each particle's current wave speed (elastic P-wave or fluid
    sound speed in its current state), :math:`|v_p|` its speed (Courant, Friedrichs & Lewy 1928; per
    particle as in Fang et al. 2018 §3). ``signal_speed`` is :math:`c_p + |v_p|` (array) or its maximum.

    Docs: docs/mpm_cycle.md#time-step-cfl-rule, docs/scenes.md#time
    """
    return cfl * dx / float(np.max(signal_speed, initial=1e-300))

"""The stages of an MPM step, each a method with the signature mpmref's steppers call.

This is where your code goes. Every stage below delegates to mpmref's NumPy reference, so the package passes every
check as it stands: replace one stage at a time by your own implementation (or a call into your C++/CUDA/Fortran
code through its Python binding) and run

    mpmref conformance check --backend my_mpm_backend.backend:factory --stage p2g

to see that stage compared with the reference on seeded random states, then the trajectory cases:

    mpmref verify --quick --backend my_mpm_backend.backend:factory

The contract (what each stage receives and returns) is mpmref.backends.base; the particle and grid containers
are mpmref.state.Particles and mpmref.state.GridState.
"""

from mpmref.backends.base import serial_context
from mpmref.backends.numpy import NumpyBackend

from . import __version__


class MyBackend:
    """An MPM backend for one scene: the six stages of a step, the two of asynchronous stepping and the three of
    CPIC coupling (each needed only by scenes that use it), and ``running``."""

    name = "my_mpm"
    version = __version__
    #: the context the stages of one step run in (a thread pool, a device stream...); none needed here
    running = staticmethod(serial_context)

    def __init__(self, scene):
        self.scene = scene
        self.reference = NumpyBackend(scene)  # the stages not yet replaced by your own

    # the six stages of every step
    def prepare(self, particles):
        return self.reference.prepare(particles)

    def stress(self, particles):
        return self.reference.stress(particles)

    def p2g(self, particles, prepared=None, contact=None, classes=None):
        return self.reference.p2g(particles, prepared, contact, classes)

    def grid_update(self, grid_state, dt, time=0.0):
        return self.reference.grid_update(grid_state, dt, time)

    def g2p(self, particles, v_grid, v_tilde, dt, prepared=None, kicks=None):
        return self.reference.g2p(particles, v_grid, v_tilde, dt, prepared, kicks)

    def return_map(self, particles):
        return self.reference.return_map(particles)

    # optional: P2G with the step's internal force folded into the momentum, (m v)_i + dt f_i, in one scatter; the
    # steppers use it when it is there and nothing in the run reads the force apart (mpmref.backends.base)
    def p2g_fused(self, particles, dt, prepared=None):
        return self.reference.p2g_fused(particles, dt, prepared)

    # asynchronous stepping (scenes with time.stepping = "async")
    def wave_speeds(self, particles, idx):
        return self.reference.wave_speeds(particles, idx)

    def interface_kicks(self, grid_state, dt, kappa):
        return self.reference.interface_kicks(grid_state, dt, kappa)

    # CPIC coupling to rigid bodies (scenes with [[rigid_bodies]])
    def cpic_contact(self, particles, prepared, rigid, dt):
        return self.reference.cpic_contact(particles, prepared, rigid, dt)

    def cpic_impulses(self, grid_state, contact, rigid, dt):
        return self.reference.cpic_impulses(grid_state, contact, rigid, dt)

    def cpic_g2p(self, particles, v_grid, dt, prepared, contact, rigid):
        return self.reference.cpic_g2p(particles, v_grid, dt, prepared, contact, rigid)


def factory(scene):
    """The backend for ``scene`` (what ``--backend my_mpm_backend.backend:factory`` and the entry point name)."""
    return MyBackend(scene)

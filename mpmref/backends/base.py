"""The contract every backend fulfils: six stages, and nothing that loops over steps.

A backend turns the equations of one MPM step into code, stage by stage; the steppers of
:mod:`mpmref.steppers` compose the stages into a step (synchronous, or per block for asynchronous
stepping), so the order P2G → grid update → G2P → return map is written once. The stages:

``prepare(particles)``
    what P2G and G2P of one step share (the NumPy reference: kernel stencils; Numba: the block sort);
``stress(particles)``
    Kirchhoff stress (n, d, d) of every particle, through :class:`MaterialTable`;
``p2g(particles, prepared=None)``
    node mass, momentum and internal force, a :class:`~mpmref.state.GridState`;
``grid_update(grid_state, dt, time)``
    node velocities after forces, gravity, walls and colliders: ``(v, v_tilde)``;
``g2p(particles, v_grid, v_tilde, dt, prepared=None)``
    new particles (velocity, affine matrix or modes, deformation, position);
``return_map(particles)``
    the plastic projection of the plastic materials' particles (new particles).

``running(n_particles)`` is a context manager in which a step's stages run (the Numba backend picks its
thread count there); it is not a stage.
"""

from contextlib import nullcontext
from typing import Protocol, runtime_checkable

import numpy as np

from ..physics.materials import material_groups

STAGES = ("prepare", "stress", "p2g", "grid_update", "g2p", "return_map")


@runtime_checkable
class Backend(Protocol):
    """Structural type of a backend (see the module docstring for each stage's meaning)."""

    name: str
    scene: object

    def prepare(self, particles): ...

    def stress(self, particles): ...

    def p2g(self, particles, prepared=None): ...

    def grid_update(self, grid_state, dt, time=0.0): ...

    def g2p(self, particles, v_grid, v_tilde, dt, prepared=None): ...

    def return_map(self, particles): ...

    def running(self, n_particles): ...


def serial_context(n_particles):
    """The ``running`` of a backend with nothing to set up."""
    return nullcontext()


class MaterialTable:
    """Per-material dispatch, written once: a backend's ``{material class: (stress, return_map)}`` kernels
    applied to each material's particles.

    A kernel table maps a material class to ``(stress, return_map)``:

    * ``stress(material, particles, idx, tau)`` writes the Kirchhoff stress of particles ``idx`` into ``tau``;
    * ``return_map(material, F, Jp, idx)`` projects ``F`` and ``Jp`` of particles ``idx`` in place, or is
      ``None`` for elastic materials.

    Adding a material adds one entry to each backend's table; no caller tests material types.
    """

    def __init__(self, materials, kernels):
        self.materials = list(materials)
        missing = sorted({type(m).__name__ for m in self.materials if type(m) not in kernels})
        if missing:
            raise TypeError(f"no kernels for material(s) {missing} in this backend")
        self.kernels = [kernels[type(m)] for m in self.materials]

    def groups(self, particles):
        """``(material, kernels, idx)`` for each material that has particles (:func:`~mpmref.physics.materials.material_groups`)."""
        kernels = {id(m): k for m, k in zip(self.materials, self.kernels)}
        return [(m, kernels[id(m)], idx) for m, idx in material_groups(self.materials, particles)]

    def stress(self, particles):
        """Kirchhoff stress (n, d, d) of every particle."""
        n, d = particles.x.shape
        tau = np.zeros((n, d, d), dtype=particles.x.dtype)
        for material, (stress, _), idx in self.groups(particles):
            stress(material, particles, idx, tau)
        return tau

    def return_map(self, particles):
        """Plastic projection of every plastic material's particles (a new state; the others untouched)."""
        if particles.Jp is None:
            return particles
        F, Jp = particles.F.copy(), particles.Jp.copy()
        for material, (_, return_map), idx in self.groups(particles):
            if return_map is not None:
                return_map(material, F, Jp, idx)
        return particles.with_(F=F, Jp=Jp)

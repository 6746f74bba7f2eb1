"""Candidates with a bug planted on purpose, built on the example third-party backend (examples/my_mpm_backend):
what real MPM codes get wrong, each of which the conformance harness must catch at the stage that is wrong
(tests/test_own_backend.py). Importable by name (``planted_backends:IgnoresDt``) when ``tests/`` and the example
package are on the path, as the command-line tests arrange."""

import dataclasses
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "examples" / "my_mpm_backend"))

from my_mpm_backend.backend import MyBackend

from mpmref.backends.numpy import NumpyBackend
from mpmref.physics.kernels import compute_stencil

#: the Δt a code that ignores its argument uses instead
FIXED_DT = 1.0e-3


class IgnoresDt(MyBackend):
    """G2P advects and updates F and J with a fixed Δt of 1e-3 whatever Δt it is given."""

    def g2p(self, particles, v_grid, v_tilde, dt, prepared=None, kicks=None):
        return super().g2p(particles, v_grid, v_tilde, FIXED_DT, prepared, kicks)


class DropsGravity(MyBackend):
    """The grid update of a scene without gravity: forces, walls and colliders, but no g."""

    def __init__(self, scene):
        super().__init__(scene)
        self.weightless = NumpyBackend(dataclasses.replace(scene, gravity=np.zeros_like(scene.gravity)))

    def grid_update(self, grid_state, dt, time=0.0):
        return self.weightless.grid_update(grid_state, dt, time)


class WrongMlsInertia(MyBackend):
    """The MLS force with D_p = Δx²/3 (the cubic B-spline's) whatever the kernel, in both P2Gs: with the quadratic one
    (D_p = Δx²/4) every force is 3/4 of the right one; G2P keeps the right D_p."""

    def wrong_inertia(self, particles, prepared):
        stencil, basis = prepared or self.prepare(particles)
        return dataclasses.replace(stencil, inertia=stencil.dx * stencil.dx / 3.0), basis

    def p2g(self, particles, prepared=None, contact=None, classes=None):
        return super().p2g(particles, self.wrong_inertia(particles, prepared), contact, classes)

    def p2g_fused(self, particles, dt, prepared=None):
        return super().p2g_fused(particles, dt, self.wrong_inertia(particles, prepared))


class Float32Mass(MyBackend):
    """Both P2Gs sum the node masses in float32 (momentum and force as the reference)."""

    def float32_mass(self, particles, grid_state):
        grid = self.scene.grid
        stencil = compute_stencil(self.scene.kernel, particles.x, grid.origin, grid.dx)
        mass = np.zeros(grid.n_nodes, dtype=np.float32)
        for offset in stencil.offsets:
            node = (stencil.base + offset) @ grid.strides
            np.add.at(mass, node, (stencil.node_weight(offset) * particles.mass).astype(np.float32))
        return dataclasses.replace(grid_state, mass=mass.astype(grid_state.mass.dtype))

    def p2g(self, particles, prepared=None, contact=None, classes=None):
        return self.float32_mass(particles, super().p2g(particles, prepared, contact, classes))

    def p2g_fused(self, particles, dt, prepared=None):
        return self.float32_mass(particles, super().p2g_fused(particles, dt, prepared))


class PerMaterialFields(MyBackend):
    """A correct code that evolves F only for the solids and J only for the fluid: the other rows of those arrays
    come back as they went in."""

    def g2p(self, particles, v_grid, v_tilde, dt, prepared=None, kicks=None):
        new = super().g2p(particles, v_grid, v_tilde, dt, prepared, kicks)
        fluid = np.array([m.tracks == "J" for m in self.scene.material_list])[particles.material]
        changes = {}
        if new.F is not None:
            changes["F"] = np.where(fluid[:, None, None], particles.F, new.F)
        if new.J is not None:
            changes["J"] = np.where(fluid, new.J, particles.J)
        return new.with_(**changes)


class NoStages:
    """Not a backend: an object for the scene with none of the stages."""

    def __init__(self, scene):
        self.scene = scene

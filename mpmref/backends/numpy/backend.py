"""The NumPy backend object: binds the reference stages to one scene."""

import numpy as np

from ...physics.materials import kirchhoff_stress_of
from . import transfers


class NumpyBackend:
    """Reference implementation of the three stages for ``scene``.

    ``stress(particles)`` evaluates every particle's Kirchhoff stress through its material;
    ``p2g``, ``grid_update`` and ``g2p`` are the stages of :mod:`.transfers`; ``return_map`` applies
    each plastic material's projection after G2P.
    """

    name = "numpy"

    def __init__(self, scene):
        self.scene = scene
        self.kernel = scene.kernel
        self.bands = transfers.wall_bands(scene.grid, scene.boundary.width)
        self.gravity = scene.gravity.astype(scene.dtype)
        self.node_x = scene.grid.node_positions() if scene.colliders else None

    def stress(self, particles):
        """Kirchhoff stress (n, d, d) of every particle, material by material."""
        n, d = particles.x.shape
        tau = np.zeros((n, d, d), dtype=particles.x.dtype)
        for mat_id, material in enumerate(self.scene.material_list):
            sel = particles.material == mat_id
            if not sel.any():
                continue
            tau[sel] = kirchhoff_stress_of(material, particles, sel)
        return tau

    def return_map(self, particles):
        """Plastic projection of every plastic material's particles (a new state; others untouched)."""
        if particles.Jp is None:
            return particles
        F, Jp = particles.F.copy(), particles.Jp.copy()
        for mat_id, material in enumerate(self.scene.material_list):
            sel = particles.material == mat_id
            if getattr(material, "plastic", False) and sel.any():
                F[sel], Jp[sel] = material.return_map(F[sel], Jp[sel])
        return particles.with_(F=F, Jp=Jp)

    def prepare(self, particles):
        return transfers.prepare(particles, self.scene.grid, self.kernel, self.scene.method)

    def p2g(self, particles, prepared=None):
        return transfers.p2g(particles, self.stress(particles), self.scene.grid, self.kernel, self.scene.method,
                             prepared)

    def grid_update(self, grid_state, dt, time=0.0):
        return transfers.grid_update(grid_state, self.scene.grid, dt, self.gravity, self.scene.boundary.walls,
                                     self.bands, self.scene.colliders, time, self.node_x)

    def g2p(self, particles, v_grid, v_tilde, dt, prepared=None):
        return transfers.g2p(particles, v_grid, v_tilde, self.scene.grid, self.kernel, self.scene.method, dt,
                             prepared)

    def step(self, particles, dt, time=0.0):
        """One full MPM step from ``time`` (P2G, grid update, G2P, return map); returns new particles."""
        prepared = self.prepare(particles)  # the stencil is shared: particles do not move until G2P
        grid_state = self.p2g(particles, prepared)
        v_grid, v_tilde = self.grid_update(grid_state, dt, time)
        return self.return_map(self.g2p(particles, v_grid, v_tilde, dt, prepared))

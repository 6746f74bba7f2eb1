"""The NumPy backend object: binds the reference stages to one scene."""

from ...physics.catalogue import MATERIALS
from ...physics.interface import interface_kicks
from ...physics.materials import kirchhoff_stress_of, wave_speeds_of
from ..base import MaterialTable, serial_context
from . import cpic, transfers


def _stress_kernel(material, particles, idx, tau):
    tau[idx] = kirchhoff_stress_of(material, particles, idx)


def _return_map_kernel(material, F, Jp, idx):
    F[idx], Jp[idx] = material.return_map(F[idx], Jp[idx])


#: the reference's material kernels: every material's own NumPy methods
MATERIAL_KERNELS = {cls: (_stress_kernel, _return_map_kernel if getattr(cls, "plastic", False) else None)
                    for cls in MATERIALS.values()}


class NumpyBackend:
    """Reference implementation of the stages of :mod:`mpmref.backends.base` for ``scene``.

    ``stress`` and ``return_map`` go through the scene's :class:`~mpmref.backends.base.MaterialTable`;
    ``prepare``, ``p2g``, ``grid_update`` and ``g2p`` are the functions of :mod:`mpmref.backends.numpy.transfers`.
    """

    name = "numpy"
    running = staticmethod(serial_context)

    def __init__(self, scene):
        self.scene = scene
        self.kernel = scene.kernel
        self.materials = MaterialTable(scene.material_list, MATERIAL_KERNELS)
        self.bands = transfers.wall_bands(scene.grid, scene.boundary.width)
        self.gravity = scene.gravity.astype(scene.dtype)
        self.node_x = scene.grid.node_positions() if scene.colliders else None

    def stress(self, particles):
        """Kirchhoff stress (n, d, d) of every particle, material by material."""
        return self.materials.stress(particles)

    def return_map(self, particles):
        """Plastic projection of every plastic material's particles (a new state; others untouched)."""
        return self.materials.return_map(particles)

    def wave_speeds(self, particles, idx):
        """Current wave speed (the CFL rule's :math:`c_p`) of the particles ``idx``, float64: each material's
        ``wave_speeds`` (:func:`mpmref.physics.materials.wave_speeds_of`)."""
        return wave_speeds_of(self.scene.material_list, particles, idx)

    def prepare(self, particles):
        return transfers.prepare(particles, self.scene.grid, self.kernel, self.scene.transfer)

    def p2g(self, particles, prepared=None, contact=None, classes=None):
        tau = self.stress(particles) if contact is None else contact.tau  # CPIC computed it for the ghosts
        return transfers.p2g(particles, tau, self.scene.grid, self.kernel, self.scene.transfer,
                             prepared, contact, classes)

    def p2g_fused(self, particles, dt, prepared=None):
        """P2G with the internal force folded into the momentum (:func:`.transfers.p2g_fused`)."""
        return transfers.p2g_fused(particles, self.stress(particles), self.scene.grid, self.kernel, self.scene.transfer,
                                   dt, prepared)

    def interface_kicks(self, grid_state, dt, kappa):
        """The node kicks of impulse refluxing (:func:`mpmref.physics.interface.interface_kicks`)."""
        return interface_kicks(grid_state.class_sums, dt, kappa)

    def grid_update(self, grid_state, dt, time=0.0):
        return transfers.grid_update(grid_state, self.scene.grid, dt, self.gravity, self.scene.boundary.walls,
                                     self.bands, self.scene.colliders, time, self.node_x)

    def g2p(self, particles, v_grid, v_tilde, dt, prepared=None, kicks=None):
        return transfers.g2p(particles, v_grid, v_tilde, self.scene.grid, self.kernel, self.scene.transfer, dt,
                             prepared, kicks=kicks)

    # CPIC stages (scenes with rigid bodies; :mod:`.cpic`)
    def cpic_contact(self, particles, prepared, rigid, dt):
        return cpic.contact(particles, prepared, self.scene.rigid_bodies, rigid, self.scene.grid, dt, self.gravity,
                            self.stress(particles), transfers.GRADIENT_WEIGHTS[self.scene.transfer.force],
                            self.scene.cpic.ghost_force, self.scene.cpic.fit == "per_body")

    def cpic_impulses(self, grid_state, contact, rigid, dt):
        return cpic.impulses(grid_state, contact, rigid, dt)

    def cpic_g2p(self, particles, v_grid, dt, prepared, contact, rigid):
        m = self.scene.cpic
        return cpic.g2p(particles, v_grid, self.scene.grid, self.kernel, self.scene.transfer, dt, prepared, contact,
                        rigid, m.pushing_force, m.penalty)

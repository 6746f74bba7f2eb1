"""The NumPy backend object: binds the reference stages to one scene."""

from ...physics.catalogue import MATERIALS
from ...physics.interface import interface_kicks
from ...physics.materials import evolved_fields, kirchhoff_stress_of, wave_speeds_of
from ..base import MaterialTable, serial_context
from . import cpic, transfers


def _stress_kernel(material, particles, idx, tau):
    tau[idx] = kirchhoff_stress_of(material, particles, idx)


def _return_map_kernel(material, F, Jp, idx, wave_speed=None):
    F[idx], Jp[idx] = material.return_map(F[idx], Jp[idx])
    if wave_speed is not None:
        _wave_speed_kernel(material, F, None, Jp, idx, wave_speed)


def _wave_speed_kernel(material, F, J, Jp, idx, out):
    r"""The wave speed :math:`c_p` of the particles ``idx`` of ``material`` in their current state, into ``out[idx]``
    (float64): the material's own rule (``material.wave_speeds``, :func:`mpmref.physics.materials.wave_speed_of`),
    of the fields it evolves (:func:`~mpmref.physics.materials.evolved_fields`). For the elastic solids and sand the
    P-wave speed at the current volume ratio :math:`J_p = \det F_p`,

    .. math:: c_p^2 = \frac{4\mu}{3\rho_p} + \frac{K\,(1 - \ln J_p)}{\rho_0}, \qquad K = \tfrac23\mu + \lambda,
              \qquad \rho_p = \rho_0 / J_p

    (:math:`\sqrt{(\lambda + 2\mu)/\rho_0}` at rest; :func:`~mpmref.physics.materials.elastic_wave_speeds`); for
    snow the same at its hardened Lamé parameters (:meth:`~mpmref.physics.plasticity.SnowPlasticity.wave_speeds`); for
    the fluid the Tait sound speed :math:`c_p^2 = \gamma K / (\rho_0 J_p^{\gamma - 1})`
    (:meth:`~mpmref.physics.materials.WeaklyCompressibleFluid.wave_speeds`). Fang et al. 2018 §4 (the rules of regional
    time stepping); :math:`\mu, \lambda` Lamé parameters, :math:`\rho_0` rest density, :math:`\gamma, K` the Tait
    exponent and stiffness.
    """
    fields = {"F": F, "J": J, "Jp": Jp}
    out[idx] = material.wave_speeds(*(fields[name][idx] for name in evolved_fields(material)))


#: the reference's material kernels: every material's own NumPy methods (stress, return map, wave speed)
MATERIAL_KERNELS = {cls: (_stress_kernel, _return_map_kernel if getattr(cls, "plastic", False) else None,
                          _wave_speed_kernel)
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

    def return_map(self, particles, wave_speed=None):
        """Plastic projection of every plastic material's particles (a new state; others untouched).

        With ``wave_speed`` (float64, (n,)), the stage's second output: each particle's current wave speed :math:`c_p`
        (the level rule's, :meth:`wave_speeds`' value) of its new state, written there, material by material
        (:func:`_wave_speed_kernel`, which gives the equations): of the projected ``F`` and ``Jp`` for snow and sand,
        of G2P's ``F`` or ``J`` for the others (:mod:`mpmref.backends.base`)."""
        return self.materials.return_map(particles, wave_speed)

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

r"""A code that implements a part: the physics of the talk's 88-line MLS-MPM program, as an mpmref backend.

2D, the quadratic B-spline, MLS-MPM (APIC transfer, MLS force), one weakly compressible fluid that carries its
volume ratio :math:`J` and no deformation gradient, gravity and frictionless ``separate`` walls: what such a program
has, and nothing else. The class says so in its ``implements`` declaration, and mpmref checks it on exactly that
(docs/checking_your_code.md, "Codes that implement a part")::

    cd examples
    mpmref conformance check --backend mpm88_backend:factory --scene mpm88.toml
    mpmref conformance check --backend mpm88_backend:factory
    mpmref verify --quick --backend mpm88_backend:factory
    mpmref verify --scene mpm88.toml --backend mpm88_backend:factory

Written here from the equations (Hu et al. 2018 §4, Eq. 18; Jiang et al. 2015 §5; talk Eq. 25), in the style of
such programs: a loop over the 3 x 3 stencil, ``np.add.at`` for the scatter, the fused P2G with the stress folded
into the affine matrix. Like the 88-line program, the grid update leaves :math:`\Delta t\,g` on nodes without mass;
G2P never reads them, and the harness does not compare them.
"""

import numpy as np

from mpmref.backends.base import serial_context
from mpmref.backends.capabilities import Implements
from mpmref.state import GridState

#: the stencil offsets of the quadratic B-spline in 2D, in C order
OFFSETS = [(i, j) for i in range(3) for j in range(3)]


class Mpm88Backend:
    """The stages of one MLS-MPM step of a 2D fluid (:mod:`mpmref.backends.base`), for one scene."""

    name = "mpm88"
    version = "1.0"
    implements = Implements(dims=(2,), schemes=("mls",), forces=("mls",), kernels=("quadratic",),
                            materials=("fluid",), walls=("separate",), friction=False, colliders=(),
                            evolves=("C", "J"), stepping=("sync",), rigid_bodies=False)
    running = staticmethod(serial_context)

    def __init__(self, scene):
        self.scene = scene
        (self.fluid,) = scene.material_list  # the declaration admits one fluid
        self.origin, self.dx = scene.grid.origin, scene.grid.dx
        self.node_shape = scene.grid.node_shape
        self.gravity = scene.gravity
        self.width = scene.boundary.width

    # ------------------------------------------------------------------------------------ the stencil
    def stencil(self, x):
        r"""Base node, and weights and offsets :math:`x_i - x_p` for each of the nine nodes of each particle.

        .. math:: N(f) = \left(\tfrac12(\tfrac32 - f)^2,\; \tfrac34 - (f - 1)^2,\; \tfrac12(f - \tfrac12)^2\right)

        at :math:`f = (x_p - o)/\Delta x - \lfloor (x_p - o)/\Delta x - \tfrac12 \rfloor`.
        """
        xi = (x - self.origin) / self.dx
        base = np.floor(xi - 0.5).astype(np.int64)
        f = xi - base
        w = [0.5 * (1.5 - f) ** 2, 0.75 - (f - 1.0) ** 2, 0.5 * (f - 0.5) ** 2]
        for i, j in OFFSETS:
            yield (base[:, 0] + i, base[:, 1] + j), w[i][:, 0] * w[j][:, 1], (np.array([i, j]) - f) * self.dx

    def prepare(self, particles):
        return None

    # ---------------------------------------------------------------------------------- constitutive
    def stress(self, particles):
        r"""Kirchhoff stress of the Tait fluid, :math:`\tau = -pJ\,I = K (J - J^{1-\gamma})\,I`."""
        J = particles.J
        p_times_J = self.fluid.K * (J ** (1.0 - self.fluid.gamma) - J)
        return -p_times_J[:, None, None] * np.eye(2)

    def return_map(self, particles):
        return particles

    # ----------------------------------------------------------------------------------------- P2G
    def p2g(self, particles, prepared=None, contact=None, classes=None):
        r"""Node mass, momentum and force: :math:`m_i = \sum_p w_{ip} m_p`,
        :math:`(mv)_i = \sum_p w_{ip} m_p (v_p + C_p (x_i - x_p))`,
        :math:`f_i = -\sum_p V_p^0 \tau_p\, w_{ip} \tfrac{4}{\Delta x^2} (x_i - x_p)` (Hu et al. 2018 Eq. 18)."""
        tau = self.stress(particles)
        mass, momentum, force = self.zeros(1), self.zeros(2), self.zeros(2)
        for node, w, dpos in self.stencil(particles.x):
            np.add.at(mass, node, w * particles.mass)
            affine = particles.v + np.einsum("pab,pb->pa", particles.C, dpos)
            np.add.at(momentum, node, (w * particles.mass)[:, None] * affine)
            gradient = (w * 4.0 / self.dx**2)[:, None] * dpos
            np.add.at(force, node, -particles.vol0[:, None] * np.einsum("pab,pb->pa", tau, gradient))
        return GridState(mass.ravel(), momentum.reshape(-1, 2), force.reshape(-1, 2))

    def p2g_fused(self, particles, dt, prepared=None):
        r"""The 88-line program's P2G: :math:`(mv)_i + \Delta t f_i = \sum_p w_{ip}(m_p v_p + A_p (x_i - x_p))` with
        :math:`A_p = m_p C_p - \Delta t\, V_p^0 \tfrac{4}{\Delta x^2} \tau_p`."""
        A = particles.mass[:, None, None] * particles.C
        A = A - (dt * particles.vol0 * 4.0 / self.dx**2)[:, None, None] * self.stress(particles)
        mass, momentum = self.zeros(1), self.zeros(2)
        for node, w, dpos in self.stencil(particles.x):
            np.add.at(mass, node, w * particles.mass)
            node_momentum = particles.mass[:, None] * particles.v + np.einsum("pab,pb->pa", A, dpos)
            np.add.at(momentum, node, w[:, None] * node_momentum)
        return GridState(mass.ravel(), momentum.reshape(-1, 2), None)

    def zeros(self, components):
        shape = self.node_shape if components == 1 else (*self.node_shape, components)
        return np.zeros(shape, dtype=self.scene.dtype)

    # --------------------------------------------------------------------------------- grid update
    def grid_update(self, grid_state, dt, time=0.0):
        r"""Velocity, force and gravity, then frictionless ``separate`` walls on the band of ``width`` nodes: a node
        whose velocity points into a wall loses that component (talk Eq. 25 with :math:`\mu = 0`)."""
        has_mass = grid_state.mass > 0
        inverse = np.where(has_mass, 1.0 / np.where(has_mass, grid_state.mass, 1.0), 0.0)[:, None]
        momentum = grid_state.momentum
        v_tilde = None
        if grid_state.force is not None:
            v_tilde = momentum * inverse
            momentum = momentum + dt * grid_state.force
        v = (momentum * inverse + dt * self.gravity).reshape(*self.node_shape, 2)  # empty nodes keep dt g
        return self.walls(v).reshape(-1, 2), v_tilde

    def walls(self, v):
        """Zero the normal component of velocities moving into a wall, in the wall's band of nodes."""
        cells = np.array(self.node_shape) - 1
        index = np.indices(self.node_shape)
        for axis in range(2):
            into_low = (index[axis] < self.width) & (v[..., axis] < 0)
            into_high = (index[axis] > cells[axis] - self.width) & (v[..., axis] > 0)
            v[..., axis] = np.where(into_low | into_high, 0.0, v[..., axis])
        return v

    # ----------------------------------------------------------------------------------------- G2P
    def g2p(self, particles, v_grid, v_tilde, dt, prepared=None, kicks=None):
        r""":math:`v_p = \sum_i w_{ip} v_i`, :math:`C_p = \tfrac{4}{\Delta x^2} \sum_i w_{ip} v_i (x_i - x_p)^T`,
        :math:`J_p \leftarrow J_p (1 + \Delta t \operatorname{tr} C_p)`, :math:`x_p \leftarrow x_p + \Delta t v_p`."""
        v_nodes = v_grid.reshape(*self.node_shape, 2)
        v = np.zeros_like(particles.v)
        C = np.zeros_like(particles.C)
        for node, w, dpos in self.stencil(particles.x):
            vi = v_nodes[node]
            v += w[:, None] * vi
            C += (4.0 / self.dx**2) * np.einsum("pa,pb->pab", w[:, None] * vi, dpos)
        J = particles.J * (1.0 + dt * (C[:, 0, 0] + C[:, 1, 1]))
        return particles.with_(x=particles.x + dt * v, v=v, C=C, J=J)


def factory(scene):
    """The backend for ``scene`` (what ``--backend mpm88_backend:factory`` names)."""
    return Mpm88Backend(scene)

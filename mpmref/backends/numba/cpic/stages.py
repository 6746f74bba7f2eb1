r"""The CPIC stages of the Numba backend (``cpic_contact``, P2G with a contact, ``cpic_impulses``,
``cpic_g2p``), one code path for 2D and 3D over the dimension's kernels, chosen once per step when the
contact is formed (:data:`CPIC_KERNELS_BY_DIM`; :mod:`.field2d`, :mod:`.transfer2d`, :mod:`.field3d`,
:mod:`.transfer3d`)."""

from dataclasses import dataclass

import numpy as np
from numba import njit

from ....physics.cdf import ColoredDistanceField
from ....rigid.dynamics import initial_state
from ....state import GridState
from ...pointwise.stencil import KERNEL_CODES
from ..kernel_args import (
    Bodies,
    BodyFits,
    ContactArrays,
    DenseLayout,
    DistanceFit,
    G2POutput,
    Groups,
    NodeField,
    SideTags,
)
from . import field2d, field3d, transfer2d, transfer3d


@dataclass(frozen=True)
class DimensionKernels:
    """The kernels of one dimension that the stages call: the field (``build_cdf``, ``tag_kernel``) and the
    transfers (``p2g_kernel``, ``node_impulses``, ``g2p_kernel``)."""

    build_cdf: object
    tag_kernel: object
    p2g_kernel: object
    node_impulses: object
    g2p_kernel: object


#: The kernels of each dimension, chosen once per step by :func:`contact` (``Contact.kernels``).
CPIC_KERNELS_BY_DIM = {d: DimensionKernels(field.build_cdf, field.tag_kernel, transfer.p2g_kernel,
                                           transfer.node_impulses, transfer.g2p_kernel)
                       for d, field, transfer in ((2, field2d, transfer2d), (3, field3d, transfer3d))}


@dataclass
class Contact:
    r"""What the Numba CPIC transfers of one step need.

    Attributes
    ----------
    cdf : ColoredDistanceField  the field of the bodies at the start of the step
    incompatible : (n,) int64   bit ``k`` set iff node ``base + offset_k`` of the transfer stencil is incompatible
                                with the particle (0 for most particles: those far from every body)
    support : int               nodes per axis of the transfer stencil (``K = support**2`` offsets)
    friction : (nb, 2)          encoded friction of each body's side 0 and side 1
    gravity_dv : (2,)           this step's gravity velocity :math:`\mathbf g\Delta t` (a particle's
                                :math:`\mathbf v^*_p = \mathbf v_p + \mathbf g\Delta t` is formed where needed)
    rigid : RigidState          the bodies as P2G sees them (their velocities give P2G's ghost velocities)
    tau : (n, 2, 2)             the particles' Kirchhoff stress (computed once for the step)
    dt : float                  the step
    ghost_force : bool          ghost velocities include the particle's own internal force (``scene.cpic.ghost_force``)
    dim : int                   2, or 3 (vectors then have 3 components)
    kernels : DimensionKernels  the kernels of ``dim`` (:data:`CPIC_KERNELS_BY_DIM`), which the step's stages call
    fits : BodyFits             what the transfer kernels read of the per-body fit (``scene.cpic.fit``): the
                                field's ``A``, ``T``, ``d_body``, the new tags ``tag_A`` and the per-body fits
                                ``phi``, ``normal``, ``near`` (``per_body_fits`` of the field kernels; no rows
                                with the single fit)
    """

    cdf: ColoredDistanceField
    incompatible: np.ndarray
    support: int
    friction: np.ndarray
    gravity_dv: np.ndarray
    rigid: object
    tau: np.ndarray
    dt: float
    ghost_force: bool
    dim: int = 2
    kernels: DimensionKernels = CPIC_KERNELS_BY_DIM[2]
    fits: BodyFits = None

    @property
    def per_body_fit(self):
        """The per-body fit ``(phi, normal, near)``, each ``(n, nb, ...)``, or None with the single fit."""
        fits = self.fits
        return (fits.phi, fits.normal, fits.near) if fits is not None and fits.per_body else None

    @property
    def compatible(self):
        """``(K, n)`` bool: node ``k`` of particle ``p``'s stencil is compatible (the reference's layout)."""
        k = np.arange(self.support**self.dim, dtype=np.int64)
        return ((self.incompatible[None, :] >> k[:, None]) & 1) == 0


def contact(backend, particles, blocks, rigid, dt):
    """The step's :class:`Contact` and the particles with their new tags, distance, normal and ``near`` flag
    (the stage ``cpic_contact``; see :func:`mpmref.backends.numpy.cpic.contact`)."""
    scene, transfer = backend.scene, backend.transfer
    bodies, d = scene.rigid_bodies, particles.dim
    k = CPIC_KERNELS_BY_DIM[d]
    cdf = k.build_cdf(bodies, rigid, backend.node_shape, backend.origin, backend.dx)
    x = np.ascontiguousarray(particles.x, dtype=np.float64)
    n, nb = particles.n, len(bodies)
    A, T = np.zeros((n, nb), dtype=np.bool_), np.zeros((n, nb), dtype=np.bool_)
    phi, normal, near = np.zeros(n), np.zeros((n, d)), np.zeros(n, dtype=np.bool_)
    incompatible = np.zeros(n, dtype=np.int64)
    per_body = scene.cpic.fit == "per_body"
    m = n if per_body else 0
    body_fit = DistanceFit(np.zeros((m, nb)), np.zeros((m, nb, d)), np.zeros((m, nb), dtype=np.bool_))
    k.tag_kernel(KERNEL_CODES[transfer.kernel], transfer.support, per_body)(
        x, cdf.origin, cdf.dx, backend.node_shape, backend.strides, NodeField(cdf.d, cdf.A, cdf.T, cdf.d_body),
        SideTags(np.ascontiguousarray(particles.tag_A), np.ascontiguousarray(particles.tag_T)), SideTags(A, T),
        DistanceFit(phi, normal, near), incompatible, Groups(blocks.order, blocks.block_start, *blocks.block_colours),
        backend.block, backend.blocks_per_axis, body_fit)
    fits = BodyFits(per_body, cdf.A, cdf.T, cdf.d_body, A, *body_fit)
    friction = np.array([b.friction for b in bodies], dtype=np.float64).reshape(nb, 2)
    c = Contact(cdf=cdf, incompatible=incompatible, support=transfer.support, friction=friction,
                gravity_dv=dt * backend.gravity.astype(particles.v.dtype), rigid=rigid, tau=backend.stress(particles),
                dt=float(dt), ghost_force=bool(scene.cpic.ghost_force), dim=d, kernels=k, fits=fits)
    return particles.with_(tag_A=A, tag_T=T, phi=phi, normal=normal, near=near), c


def p2g(backend, particles, blocks, contact):
    """CPIC P2G (the dimension's ``p2g_kernel``, :func:`.transfer2d.p2g_kernel`): a
    :class:`~mpmref.state.GridState` with ``rejected_momentum`` and ``rejected_force``."""
    transfer, N = backend.transfer, backend.scene.grid.n_nodes
    d = particles.dim
    gs = GridState(mass=np.zeros(N, dtype=backend.dtype), momentum=np.zeros((N, d), dtype=backend.dtype),
                   force=np.zeros((N, d), dtype=backend.dtype), rejected_momentum=np.zeros((N, d)),
                   rejected_force=np.zeros((N, d)))
    kernel = contact.kernels.p2g_kernel(KERNEL_CODES[transfer.kernel], transfer.support, transfer.affine,
                                        transfer.mls_force, contact.fits.per_body)
    kernel(particles.x, particles.v, backend._or_empty(particles.C, 0, d, d), particles.mass, particles.vol0,
           contact.tau, dense_layout(backend), Groups(blocks.order, blocks.block_start, *blocks.block_colours),
           contact_arrays(contact, particles), bodies_of(contact.rigid, contact), contact.gravity_dv,
           contact.ghost_force, contact.dt, gs.mass, gs.momentum, gs.force, gs.rejected_momentum, gs.rejected_force,
           contact.fits)
    return gs


def dense_layout(backend):
    """The dense grid's :class:`~mpmref.backends.numba.kernel_args.DenseLayout` that the CPIC kernels read."""
    return DenseLayout(backend.origin, backend.dx, backend.inertia, backend.strides)


def contact_arrays(contact, particles):
    """The particle–node contact of the step (:class:`~mpmref.backends.numba.kernel_args.ContactArrays`)."""
    return ContactArrays(contact.incompatible, contact.cdf.body, contact.cdf.d, particles.near, particles.phi,
                         particles.normal, particles.tag_T)


def bodies_of(rigid, contact):
    """The bodies ``rigid`` as a kernel reads them (:class:`~mpmref.backends.numba.kernel_args.Bodies`)."""
    return Bodies(rigid.position, rigid.velocity, rigid.angular_velocity, contact.friction)


def impulses(grid_state, contact, rigid, dt):
    """Impulses ``(J (nb, 2), L (nb,))`` (3D: ``(nb, 3)`` both) of the incompatible nodes on the bodies
    (the dimension's ``node_impulses``, :func:`.transfer2d.node_impulses`)."""
    nb, d = rigid.position.shape
    J, L = np.zeros((nb, d)), np.zeros((nb,) if d == 2 else (nb, 3))
    cdf = contact.cdf
    contact.kernels.node_impulses(grid_state.rejected_momentum, grid_state.rejected_force, dt, cdf.body,
                  np.array(cdf.shape, dtype=np.int64), cdf.origin, cdf.dx, rigid.position, J, L)
    return J, L


def g2p(backend, particles, v_grid, dt, blocks, contact, rigid):
    """CPIC G2P (the dimension's ``g2p_kernel``, :func:`.transfer2d.g2p_kernel`) with the bodies ``rigid`` as G2P
    sees them; returns ``(new particles, (J, L))``, the penalty's impulses on the bodies, summed per block by the
    kernel, then over blocks in order."""
    transfer, cpic = backend.transfer, backend.scene.cpic
    n, d = particles.x.shape

    def empty(*shape):
        return np.empty(shape, dtype=backend.dtype)

    x_new, v_new = empty(n, d), empty(n, d)
    C_new = empty(n, d, d) if particles.C is not None else empty(0, d, d)
    F_new = empty(n, d, d) if particles.F is not None else empty(0, d, d)
    J_new = empty(n) if particles.J is not None else empty(0)
    nb = len(rigid.angle)
    block_impulse = np.zeros((len(blocks.block_colours[0]), nb, 3 if d == 2 else 6))  # J, then L
    kernel = contact.kernels.g2p_kernel(KERNEL_CODES[transfer.kernel], transfer.support, transfer.affine,
                                        transfer.mls_force, transfer.mls_gradient, transfer.tracks_F, transfer.tracks_J,
                                        contact.fits.per_body)
    kernel(particles.x, particles.v, contact.gravity_dv, backend._or_empty(particles.F, 0, d, d),
           backend._or_empty(particles.J, 0), particles.mass, particles.vol0, contact.tau, contact.ghost_force,
           dense_layout(backend), dt, Groups(blocks.order, blocks.block_start, *blocks.block_colours), v_grid,
           contact_arrays(contact, particles), bodies_of(rigid, contact), float(cpic.pushing_force),
           float(cpic.penalty), G2POutput(x_new, v_new, C_new, F_new, J_new), block_impulse, contact.fits)
    total = sum_in_order(block_impulse)
    J, L = total[:, :d], (total[:, d] if d == 2 else total[:, d:])
    changes = {"x": x_new, "v": v_new}
    for name, array in (("C", C_new), ("F", F_new), ("J", J_new)):
        if getattr(particles, name) is not None:
            changes[name] = array
    return particles.with_(**changes), (J, L)


@njit(cache=True)
def sum_in_order(per_block):
    """``per_block`` (k, nb, 3) summed over its first axis, block after block (a fixed order)."""
    total = np.zeros(per_block.shape[1:])
    for b in range(per_block.shape[0]):
        total += per_block[b]
    return total


def warm_up(backend, particles):
    """Compile (or load) the CPIC kernels by running the contact, P2G, impulse and G2P stages once on
    ``particles`` with Δt = 0, the bodies where they were declared; nothing is returned or kept."""
    n, nb = particles.n, len(backend.scene.rigid_bodies)
    if particles.tag_A is None:
        particles = particles.with_(tag_A=np.zeros((n, nb), dtype=np.bool_), tag_T=np.zeros((n, nb), dtype=np.bool_))
    rigid = initial_state(backend.scene.rigid_bodies)
    blocks = backend.prepare(particles)
    particles, c = contact(backend, particles, blocks, rigid, 0.0)
    gs = p2g(backend, particles, blocks, c)
    impulses(gs, c, rigid, 0.0)
    g2p(backend, particles, np.zeros_like(gs.momentum), 0.0, blocks, c, rigid)

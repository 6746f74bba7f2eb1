r"""P2G, grid update and G2P of the Numba backend: the equations of
:mod:`mpmref.backends.numpy.transfers`, one particle at a time with the stencil inside.

Files, by stage, with one 2D/3D convention (the one of the CPIC stages, :mod:`mpmref.backends.numba.cpic`): the kernels
whose loops run over a particle's stencil are written once per dimension, in :mod:`.transfers2d` and
:mod:`.transfers3d`, behind one declared interface (:class:`DimensionTransfers`; the table :data:`TRANSFER_KERNELS`,
from which :func:`make_p2g`, :func:`make_g2p` and :func:`make_kick_gather` take the scene's dimension's); what both
dimensions share is in a module per stage, :mod:`~mpmref.backends.numba.p2g` (the per-node scatter) and
:mod:`~mpmref.backends.numba.g2p` (the mode projections and the per-particle update), and in
:mod:`~mpmref.backends.numba.stencil` (a particle's stencil along one axis), :mod:`.sparse` (the rows of the stencil's
nodes) and :mod:`.tuple_math`. The grid update (:mod:`~mpmref.backends.numba.grid_update`) and the node kicks of
conservative interfaces (:mod:`.kicks`) are written once for both dimensions: their loops run over the columns of the
node arrays.

Each kernel is built for one transfer configuration (of a :class:`~mpmref.physics.scheme.TransferSpec`):
dimension (the file), kernel, block size, scheme features (affine matrix, PolyPIC modes, FLIP in G2P) and force
discretisation. These are closure constants, so Numba compiles only the branches the scene uses, and each
configuration is cached on disk like any other ``cache=True`` function: Numba keys a closure's cache entry on
the pickled values of its constants, which is why they are plain ints, bools and a string and never other
compiled functions (a dispatcher pickles differently in every process, which would defeat the cache). Two
choices are made at run time instead, so that one compiled kernel serves more scenes (each kernel takes
seconds to compile): the material laws (P2G reads the solids' stress from the stress stage) and whether G2P
updates F or J (measured cost in docs/performance.md, "Compile time against run time").

P2G runs in parallel over the colour classes of :mod:`.blocks`, slabs or single blocks (no atomics, bitwise
the same for any thread count); G2P gathers, so it runs in parallel over the particles in their storage
order. Both address the nodes on the sparse grid of :mod:`.sparse`: per particle, the first rows of its
owner block and of that block's upper neighbours (:func:`~.sparse.block_rows_2d`, :func:`~.sparse.block_rows_3d`:
:math:`2^{d-1}` look-ups in the block-pointer table), and per axis which of them each stencil node falls in
and its offset inside; per node only a sum and a choice between two registers remain, as cheap as the
strides of a dense grid.
"""

from typing import Callable, NamedTuple

from ..pointwise.stencil import KERNEL_CODES
from . import transfers2d, transfers3d


class DimensionTransfers(NamedTuple):
    """The transfer kernels of one dimension: three factories, each cached per configuration (``lru_cache``),
    with the same arguments and returning compiled kernels with the same arguments in 2D and 3D.

    Attributes
    ----------
    p2g_kernel : Callable   ``p2g_kernel(KERNEL, S, AFFINE, POLY, MLS_FORCE, BLOCK, STRESS_LAW, FUSED=False)``
                            -> ``p2g(x, v, C, modes, mass, vol0, stress, J, material, params, layout,
                            mode_index, particle_groups, class_rows, dt, grid)`` (:func:`.transfers2d.p2g_kernel`)
    g2p_kernel : Callable   ``g2p_kernel(KERNEL, S, AFFINE, POLY, FLIP, MLS_GRADIENT, BLOCK)`` -> ``g2p(x, v, F, J,
                            rows, layout, dt, flip_alpha, mode_index, v_grid, v_tilde, x_new, v_new, C_new, F_new,
                            J_new, modes_new)``
                            (:func:`.transfers2d.g2p_kernel`)
    kick_gather_kernel : Callable   ``kick_gather_kernel(KERNEL, S, BLOCK)`` -> ``gather(x, mass, rows, layout,
                            kick_rows, kicks, kicked, impulse, moment)`` (:func:`.transfers2d.kick_gather_kernel`)
    """

    p2g_kernel: Callable
    g2p_kernel: Callable
    kick_gather_kernel: Callable


#: The transfer kernels of each dimension (tests/test_numba_layout.py checks that both have the interface's
#: arguments).
TRANSFER_KERNELS = {d: DimensionTransfers(m.p2g_kernel, m.g2p_kernel, m.kick_gather_kernel)
                    for d, m in ((2, transfers2d), (3, transfers3d))}


def make_p2g(transfer, block, stress_law, fused=False):
    """P2G kernel for a :class:`~mpmref.physics.scheme.TransferSpec` on a grid of ``block``-cell blocks, computing the
    stress by ``stress_law`` (the one law of :math:`J` of a scene's materials, :func:`inline_stress_law`) or reading the
    stress stage's (``None``: FLIP, the tracked deformation and which solids are invisible to P2G, so those variants
    share one compiled kernel), ``fused`` or not (the internal force folded into the momentum); see
    :func:`.transfers2d.p2g_kernel`."""
    return TRANSFER_KERNELS[transfer.dim].p2g_kernel(KERNEL_CODES[transfer.kernel], transfer.support, transfer.affine,
                                                     transfer.polypic, transfer.mls_force, block, stress_law, fused)


def inline_stress_law(materials):
    """The law P2G computes the stress by itself: the one law of every material of ``materials`` when it is a law of
    the volume ratio :math:`J` alone (``tracks == "J"``: a function of one number per particle, cheaper to compute
    there than to store and read back); ``None`` otherwise (P2G reads the stress stage's)."""
    laws = {type(m).compiled for m in materials}
    return laws.pop() if len(laws) == 1 and all(m.tracks == "J" for m in materials) else None


def make_g2p(transfer, block):
    """G2P kernel for a :class:`~mpmref.physics.scheme.TransferSpec` on a grid of ``block``-cell blocks (the tracked
    deformation, F or J, is a run-time choice, so those variants share one compiled kernel); see
    :func:`.transfers2d.g2p_kernel`."""
    return TRANSFER_KERNELS[transfer.dim].g2p_kernel(KERNEL_CODES[transfer.kernel], transfer.support, transfer.affine,
                                                     transfer.polypic, transfer.flip, transfer.mls_gradient, block)


def make_kick_gather(transfer, block):
    """The kick gather of conservative level interfaces for a configuration; see
    :func:`.transfers2d.kick_gather_kernel`."""
    return TRANSFER_KERNELS[transfer.dim].kick_gather_kernel(KERNEL_CODES[transfer.kernel], transfer.support, block)

"""Named groups of the compiled kernels' arguments.

A transfer kernel reads the grid's layout, the order in which particles are visited and, with CPIC, the
bodies and the particle–node contact: a few dozen arrays and numbers. Numba passes a named tuple of them
as one argument (its type is part of the compiled signature, like an array's), and a kernel unpacks it in
its first lines, so the arithmetic that follows reads the same names as before and compiles to the same
code. The groups are built once per stage call by the backend (:mod:`mpmref.backends.numba.backend`,
:mod:`mpmref.backends.numba.cpic.stages`).
"""

from typing import NamedTuple

import numpy as np


class SparseLayout(NamedTuple):
    """A sparse grid's layout (:class:`~mpmref.backends.numba.sparse.BlockLayout`): grid origin, cell size, the
    APIC inertia :math:`D_p`, the block-pointer table ``slot_of`` and its strides."""

    origin: np.ndarray
    dx: float
    inertia: float
    slot_of: np.ndarray
    table_strides: np.ndarray


class DenseLayout(NamedTuple):
    """A dense grid's layout (the CPIC stages): grid origin, cell size, :math:`D_p` and the node strides."""

    origin: np.ndarray
    dx: float
    inertia: float
    strides: np.ndarray


class Groups(NamedTuple):
    """The order in which a kernel visits the particles (:mod:`mpmref.backends.numba.blocks`):
    ``order[start[g]:start[g + 1]]`` are the particles of group (slab or block) ``g``;
    ``groups[colour_start[c]:colour_start[c + 1]]`` the groups of colour ``c``."""

    order: np.ndarray
    start: np.ndarray
    groups: np.ndarray
    colour_start: np.ndarray


class Bodies(NamedTuple):
    """The rigid bodies as a CPIC stage sees them: reference points, velocities, angular velocities (scalars in
    2D, vectors in 3D) and the encoded friction of each body's two sides."""

    position: np.ndarray
    velocity: np.ndarray
    omega: np.ndarray
    friction: np.ndarray


class ContactArrays(NamedTuple):
    """The particle–node contact of a CPIC step: the mask of each particle's incompatible stencil nodes, each
    node's nearest body and distance, and each particle's ``near`` flag, distance, normal and side tags."""

    incompatible: np.ndarray
    node_body: np.ndarray
    node_d: np.ndarray
    near: np.ndarray
    phi: np.ndarray
    normal: np.ndarray
    tag_T: np.ndarray


class G2POutput(NamedTuple):
    """The particle arrays a G2P kernel writes: positions, velocities, affine matrices :math:`C_p`, deformation
    gradients :math:`F_p` and volume ratios :math:`J_p`; ``C``, ``F`` and ``J`` have no rows ((0, d, d), (0,)) where
    the state does not hold them."""

    x: np.ndarray
    v: np.ndarray
    C: np.ndarray
    F: np.ndarray
    J: np.ndarray

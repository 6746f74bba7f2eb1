"""Named groups of the compiled kernels' arguments.

A transfer kernel reads the grid's layout, the order in which particles are visited, the arrays it writes
and, with CPIC, the bodies, the particle–node contact, the colored distance field and the particles' tags and
fits: a few dozen arrays and numbers. Numba passes a named tuple of them as one argument (its type is part of
the compiled signature, like an array's; the classes are defined here, at module level, so that a kernel that
takes them is cached on disk), and a kernel unpacks it in its first lines or reads its fields by name, so the
arithmetic that follows reads the same names as before and compiles to the same code; no compiled kernel
takes more than 20 arguments (tests/test_numba_layout.py). The groups are built once per stage call by the
backend (:mod:`mpmref.backends.numba.backend`, :mod:`mpmref.backends.numba.cpic.stages`).
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
    """The particle arrays a CPIC G2P kernel writes: positions, velocities, affine matrices :math:`C_p`, deformation
    gradients :math:`F_p` and volume ratios :math:`J_p`; ``C``, ``F`` and ``J`` have no rows ((0, d, d), (0,)) where
    the state does not hold them."""

    x: np.ndarray
    v: np.ndarray
    C: np.ndarray
    F: np.ndarray
    J: np.ndarray


class NodeField(NamedTuple):
    r"""A colored distance field on the nodes (:class:`~mpmref.physics.cdf.ColoredDistanceField`): each node's
    distance :math:`d_i` to its nearest body (the field's ``d``), :math:`A_{ir}` (node in body :math:`r`'s band),
    :math:`T_{ir}` (its side of body :math:`r`) and its distance :math:`d_{ir}` to each body."""

    distance: np.ndarray
    A: np.ndarray
    T: np.ndarray
    d_body: np.ndarray


class SideTags(NamedTuple):
    r"""The particles' tags of each body: :math:`A_{pr}` (tagged by body :math:`r`) and :math:`T_{pr}` (its side)."""

    A: np.ndarray
    T: np.ndarray


class DistanceFit(NamedTuple):
    r"""A least-squares fit of the field at the particles (:func:`mpmref.physics.cdf.reconstruct`): distances
    :math:`\phi_p`, normals :math:`\mathbf n_p` and whether the fit was accepted (``near``); per particle, or per
    particle and body for the per-body fit."""

    phi: np.ndarray
    normal: np.ndarray
    near: np.ndarray


class BodyFits(NamedTuple):
    r"""What the CPIC transfer kernels read of the per-body fit (:func:`mpmref.physics.cdf.reconstruct_per_body`):
    whether the scene uses it (``per_body``), the field's :math:`A_{ir}`, :math:`T_{ir}` and :math:`d_{ir}`, the
    particles' new tags :math:`A_{pr}`, and the fits of the particles tagged by several bodies, :math:`\phi_{pr}`,
    :math:`\mathbf n_{pr}` and ``near`` (shapes (n, nb, ...); no rows with the single fit)."""

    per_body: bool
    A: np.ndarray
    T: np.ndarray
    d_body: np.ndarray
    tag_A: np.ndarray
    phi: np.ndarray
    normal: np.ndarray
    near: np.ndarray
